"""The reference a throughput figure is divided by: one free step of the gripper squeezing an object.

A machine that is slower, or busier, makes a candidate and a step dearer alike; the number of
free steps a candidate costs stays. ``free_step()`` times ``stepSimulation`` of the annotation
gripper (the configuration's ``gripper`` and ``physics``) holding the sample box (objects/box.obj,
60 x 40 x 120 mm) with the squeeze force, pads on its top 30 mm across the 60 mm side: nothing but
the engine in the loop. It is measured in the same run as the figure it divides, a few times over
the run, and the median is used.

What the ratio cannot see: a change of the step itself (solver iterations, contact settings)
moves the reference with the candidate; compare such changes with the model before
(``bench/before_speed.toml``, ``python -m bench.throughput --versus``).
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import create_body, load_object
from annotator.sim import pb
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World

ROOT = Path(__file__).resolve().parents[1]
BOX = ROOT / "objects" / "box.obj"
TCP_BELOW_TOP = 0.015  # m: the pads' centres 15 mm below the box's top, their 29.8 mm on its side
BOX_WIDTH = 0.06  # m, the side the pads close across
DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # xyzw: the TCP's z (approach) along world -z


@dataclasses.dataclass(frozen=True)
class FreeStep:
    """Seconds per ``stepSimulation`` of the gripper squeezing the box: median of ``blocks``
    blocks of ``steps`` steps each."""

    cpu: float  # CPU seconds (time.process_time) per step
    wall: float  # wall seconds per step
    steps: int
    blocks: int

    @property
    def cpu_ms(self) -> float:
        return self.cpu * 1e3

    @property
    def wall_ms(self) -> float:
        return self.wall * 1e3


def free_step(config: AnnotatorConfig | None = None, steps: int = 240, blocks: int = 3) -> FreeStep:
    """Time ``blocks`` x ``steps`` steps of the gripper holding the box (module docstring)."""
    config = config or AnnotatorConfig()
    with World(config.physics) as world:
        hand = FloatingGripper(world, config.gripper)
        model = load_object(BOX, config.objects)
        uid = create_body(world.client, model)
        world.set_gravity(False)
        top = model.mesh.bounds[1][2] - TCP_BELOW_TOP
        T_world_tcp = Transform([*model.center_mass[:2], top], DOWN)
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, BOX_WIDTH), BOX_WIDTH + 0.02)
        hand.close(force=config.gripper.grip_force, max_steps=240)
        if not pb.getContactPoints(hand.uid, uid, physicsClientId=world.client):
            raise SystemExit("the reference grasp does not touch the box: update bench/reference.py")
        cpu, wall = [], []
        for _ in range(blocks):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(steps):
                pb.stepSimulation(physicsClientId=world.client)
            cpu.append((time.process_time() - c0) / steps)
            wall.append((time.perf_counter() - t0) / steps)
    return FreeStep(statistics.median(cpu), statistics.median(wall), steps, blocks)


def median_step(samples: list[FreeStep]) -> FreeStep:
    """One reference of several measured over a run (the medians of their CPU and wall costs)."""
    return FreeStep(
        statistics.median(s.cpu for s in samples),
        statistics.median(s.wall for s in samples),
        sum(s.steps for s in samples),
        sum(s.blocks for s in samples),
    )
