"""Our grasp trial against two peers' trials on the same candidates, taking turns: CPU time per
candidate, per trial and per step, steps per trial and agreement on success.

    python -m bench.peers                          # 3 objects x 100 candidates, 2 rounds
    python -m bench.peers --per-object 40 --rounds 1
    python -m bench.peers --variant solver_iterations=100   # also time a changed configuration of ours

Every object of a round is a task of the runner's execution
(:func:`annotator.pipeline.in_memory.run_in_memory`): :func:`object_turns` run by a
:class:`~annotator.pipeline.tasks.Call` in a worker process (``--workers`` of them, default 1, or a
Dask cluster's) after the checks every task gets, a worker that dies costing its object one retry.
In the task every tool runs in its own PyBullet DIRECT client, all in that one worker process, on
the product's own object bodies (``annotator.objects.load_object`` + ``create_body``: same mass,
inertia, friction, convex parts) and on our sampler's candidates; for each candidate the tools take
turns (the order rotates per candidate), so machine load hits all of them alike; the CPU and wall
times are the worker process's, taken in it around each tool's run and carried back in the tallies
(this process only waits). With more than one worker, objects run side by side, each with all its
tools. Printed per tool: ms per candidate (collision rejection included), ms per simulated trial,
steps per trial, ms per step (time inside ``stepSimulation`` only), and the agreement of ``success``
with ours; per object, and over the objects at or above ``physics.light_object_mass`` apart from the
light ones ours substeps. ``os.getloadavg()`` is printed with every timing; ``--rounds R`` repeats
the whole set and prints the spread. After each round the free step of our gripper
(bench/reference.py) is timed, a task of its own, in a worker: a candidate's cost in free steps is
the figure a slower machine does not move. The record (bench/harness.py) holds the ratios (median
and range over rounds), each tool's figures, and the rounds' tables.

Objects: a 40 mm cube, a 66 x 120 mm cylinder and a generated duck (a star-shaped union of
ellipsoids: body, head, beak, tail; concave at the neck and under the tail; several convex parts).

How faithful the re-creations are (nothing was copied from either project: the models below are
written here from the numbers in their sources, as primitives):

* **vgn** -- VGN's grasp trial (ethz-asl/vgn, branch corl2020, ``src/vgn/simulation.py`` and
  ``utils/btsim.py``). Faithful: 1/240 s, 150 solver iterations; the hand loaded from its URDF for
  every grasp at the pregrasp 5 cm back along the approach, held by a fixed constraint (max force
  300 N) that is moved in 2 mm increments at 0.1 m/s (4 steps each), aborting on any contact;
  fingers reset open to 4 cm each and position-controlled at their 20 N effort, coupled by a
  ``JOINT_GEAR`` constraint (ratio -1, erp 0.1, max force 50); close = targets 0 for 0.5 s;
  retreat 10 cm (along -approach for top grasps, world +z if the approach is more than 60 deg from
  straight down); success = any contact of the hand and width > 10 % of the 80 mm maximum; the
  contact check right after loading, before any step, sees no contacts (as in VGN). Approximated:
  VGN's hand.urdf comes from its data download, not the repository; the numbers used are those of
  the copies of that file in public repositories (hand 0.81 kg, fingers 0.1 kg, prismatic 0..0.04 m,
  effort 20 N, velocity 0.2 m/s, finger contact stiffness 30000 / damping 1000, lateral friction
  1.0, spinning 0.1, friction anchor; inertia computed by PyBullet as VGN loads without
  ``URDF_USE_INERTIA_FROM_FILE``). Its collision meshes are replaced by boxes: the hand by its
  60 x 200 x 58.4 mm bounding box, each finger by the four boxes of Franka's published finger
  collision primitives. Adapted to our setting: no table, so gravity is off while approaching and
  closing (the object floats, as in our trial) and on for the retreat; the hand is placed with
  its fingertip centres (103.4 mm out) on our TCP and its closing axis on ours. VGN's grasps have
  no shake.
* **adagrasp** -- AdaGrasp's RG2 (real-stanford/adagrasp ``gripper_module/gripper_rg2.py``,
  ``assets/gripper/rg2/model.urdf``) as BURG ported it (mrudorfer/burg-toolkit
  ``burg_toolkit/gripper/rg2.py``, ``base.py``, ``sim.py``). Faithful: AdaGrasp's joint layout
  (palm; left inner, left outer = driver, left finger, right inner, right outer, right finger; the
  URDF's joint origins, rpy of +-0.43 rad and limits 0..0.86), followers position-controlled every
  step to sign x driver (signs +1, -1, -1, -1, +1; force 1000, gain 1.5), the driver velocity-
  controlled closed at 0.5 rad/s with force 1000 for 2 s (480 steps), BURG's 100 solver
  iterations, self-collision off, BURG's masses (palm 0.4 kg, 0.1 kg over the six links, set after
  loading so PyBullet's inertias are those of 1 kg links), friction 1.0 / spinning 1.0 / rolling
  1e-4 with friction anchor on every link, gripper loaded fully open for every grasp, collision =
  closest points deeper than 1 mm at the grasp pose (no approach), success = both finger links
  touch the object after the lift. Approximated: the meshes are replaced by boxes inside the
  meshes' bounding boxes (palm 68.5 x 52.3 x 132.6 mm; 55 mm links; each finger a 14 mm bar plus a
  10 x 20 x 29.8 mm pad whose face is where the mesh's inner face is, 83 mm apart fully open),
  centred on y = 0 (the meshes sit 9 mm off it). Adapted: BURG's xyz mount robot is a fixed
  constraint (max force 1000 N) and the lift is our 10 cm at BURG's 0.2 m/s mount speed (BURG
  lifts 30 cm); gravity off while closing, on for the lift; the pad centre at the candidate's
  width (from the model's own FK) is placed on our TCP (BURG's 163 mm grasp centre is the closed
  fingertips' end).
* **ours** -- ``annotator.trial.GraspTrial`` as the annotator's worker runs it (collision check,
  close, lift, shake), the world built once per object's task and restored by snapshot, a light
  object's time step divided as the worker divides it (``annotator.objects.physics_for``) and, from
  ``light_hold_mass`` up, lifted and shaken at the run's own (``PhysicsConfig.held``).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import ObjectModel, ObjectSource, create_body, load_object, physics_for
from annotator.outcome import Outcome
from annotator.pipeline.in_memory import ExecutionOptions, call_values
from annotator.pipeline.simulate import object_candidates
from annotator.pipeline.tasks import Call
from annotator.sampler import Candidates
from annotator.sim import pb
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial
from bench._variants import parse_variant
from bench.arguments import N_MAX, REPEAT_MAX, WORKERS_MAX, Parser, count, seed
from bench.harness import Run
from bench.reference import FreeStep, free_step

DOWN = np.array([0.0, 0.0, -1.0])


# --- objects ---------------------------------------------------------------------------------------


def duck_mesh(subdivisions: int = 4) -> trimesh.Trimesh:
    """A duck-like watertight mesh: the star-shaped hull (seen from inside the body) of four
    ellipsoids, so the neck and the tail leave concavities. Stands on z = 0; about 150 x 80 x 110 mm."""
    # (centre (3,), semi-axes (3,)) in metres
    parts = [
        (np.array([0.0, 0.0, 0.035]), np.array([0.060, 0.040, 0.035])),  # body
        (np.array([0.045, 0.0, 0.085]), np.array([0.025, 0.025, 0.025])),  # head
        (np.array([0.075, 0.0, 0.082]), np.array([0.020, 0.012, 0.006])),  # beak
        (np.array([-0.060, 0.0, 0.050]), np.array([0.022, 0.016, 0.012])),  # tail
    ]
    centre = np.array([0.01, 0.0, 0.045])
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sphere.vertices)  # (n, 3) unit directions
    radius = np.zeros(len(d))
    for c, axes in parts:
        # far intersection of the ray centre + t d with the ellipsoid |(p - c) / axes| = 1
        o, v = (centre - c) / axes, d / axes
        a = np.einsum("ij,ij->i", v, v)
        b = 2 * v @ o
        disc = b * b - 4 * a * (o @ o - 1)
        t = np.where(disc >= 0, (-b + np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)
        radius = np.maximum(radius, t)
    mesh = trimesh.Trimesh(centre + d * radius[:, None], sphere.faces, process=True)
    mesh.apply_translation([0, 0, -mesh.bounds[0][2]])
    return mesh


BENCH_OBJECTS = {
    "cube40": lambda: trimesh.creation.box((0.04, 0.04, 0.04)),
    "cylinder66x120": lambda: trimesh.creation.cylinder(radius=0.033, height=0.12, sections=48),
    "duck": duck_mesh,
}


def bench_objects(folder: Path, names: tuple[str, ...] = tuple(BENCH_OBJECTS)) -> list[ObjectSource]:
    """The bench objects ``names`` (all three by default) written as meshes into ``folder``."""
    out = []
    for name in names:
        path = folder / f"{name}.obj"
        BENCH_OBJECTS[name]().export(path)
        out.append(ObjectSource(name, path))
    return out


# --- a stepping clock shared by the peers ---------------------------------------------------------------


def cpu_timed_steps(client: int, n: int) -> float:
    """Step ``client`` ``n`` times; the CPU seconds spent in ``stepSimulation``."""
    t0 = time.process_time()
    for _ in range(n):
        pb.stepSimulation(physicsClientId=client)
    return time.process_time() - t0


class Sim:
    """A bare PyBullet DIRECT client with a step counter and the CPU time spent in ``stepSimulation``."""

    def __init__(self, time_step: float, solver_iterations: int) -> None:
        self.client = pb.connect(pb.DIRECT)
        self.dt = time_step
        pb.setPhysicsEngineParameter(
            fixedTimeStep=time_step, numSolverIterations=solver_iterations, physicsClientId=self.client
        )
        self.steps = 0
        self.step_seconds = 0.0

    def step(self, n: int = 1) -> None:
        self.step_seconds += cpu_timed_steps(self.client, n)
        self.steps += n

    def gravity(self, on: bool) -> None:
        pb.setGravity(0, 0, -9.81 if on else 0.0, physicsClientId=self.client)

    def close(self) -> None:
        pb.disconnect(physicsClientId=self.client)


class FloatingObject:
    """The product's body of ``model`` at the origin of ``client``, reset to rest before each trial."""

    def __init__(self, client: int, model: ObjectModel) -> None:
        self.client = client
        self.uid = create_body(client, model)
        self.pose0 = pb.getBasePositionAndOrientation(self.uid, physicsClientId=client)

    def reset(self) -> None:
        pb.resetBasePositionAndOrientation(self.uid, *self.pose0, physicsClientId=self.client)
        pb.resetBaseVelocity(self.uid, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)

    def remove(self) -> None:
        pb.removeBody(self.uid, physicsClientId=self.client)


def carrier(client: int, body: int, pos, quat) -> int:
    """A fixed constraint holding ``body``'s base (its COM frame) at ``pos`` / ``quat`` in the world,
    as both peers carry their grippers; moved with ``changeConstraint``."""
    return pb.createConstraint(
        body,
        -1,
        -1,
        -1,
        pb.JOINT_FIXED,
        [0, 0, 0],
        parentFramePosition=[0, 0, 0],
        childFramePosition=pos,
        childFrameOrientation=quat,
        physicsClientId=client,
    )


# --- results ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Result:
    """One candidate as a tool saw it: ``simulated`` False for a collision found kinematically (ours,
    adagrasp) or during the simulated approach (vgn)."""

    simulated: bool
    success: bool
    steps: int
    step_seconds: float
    width: float = float("nan")


# PyBullet's contact breaking threshold (m) when none is set, as the peers' code leaves it.
PYBULLET_CONTACT_BREAKING_THRESHOLD = 0.02


class Tool:
    """A grasp trial in its own client; ``load`` an object, ``run`` candidates, ``unload``."""

    name = "tool"
    client: int
    contact_breaking_threshold = PYBULLET_CONTACT_BREAKING_THRESHOLD

    def enter(self) -> None:
        """Make this tool's contact breaking threshold the process's before its turn: PyBullet keeps
        one for all clients of a process (gContactBreakingThreshold), so the tools taking turns
        here would otherwise all run with the one set last."""
        pb.setPhysicsEngineParameter(
            contactBreakingThreshold=self.contact_breaking_threshold, physicsClientId=self.client
        )

    def load(self, model: ObjectModel) -> None:
        raise NotImplementedError

    def run(self, T_obj_tcp: Transform, width: float) -> Result:
        raise NotImplementedError

    def unload(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class PeerTool(Tool):
    """A peer's trial in its own ``Sim`` (``self.sim``) on a :class:`FloatingObject` of ours."""

    sim: Sim
    obj: FloatingObject | None = None

    @property
    def client(self) -> int:
        return self.sim.client

    def load(self, model: ObjectModel) -> None:
        self.obj = FloatingObject(self.sim.client, model)

    def unload(self) -> None:
        self.obj.remove()

    def close(self) -> None:
        self.sim.close()


# --- ours ------------------------------------------------------------------------------------------


class CpuWorld(World):
    """The product's World, timing ``stepSimulation`` in CPU seconds like :class:`Sim`."""

    def step(self, n: int = 1) -> None:
        self.step_seconds += cpu_timed_steps(self.client, n)
        self.steps += n


class Ours(Tool):
    """``annotator.trial.GraspTrial`` exactly as a worker runs it."""

    def __init__(self, config: AnnotatorConfig, name: str = "ours") -> None:
        self.name = name
        self.config = config
        self.world = CpuWorld(config.physics)
        self.client = self.world.client
        self.contact_breaking_threshold = config.physics.contact_breaking_threshold
        self.hand = FloatingGripper(self.world, config.gripper)
        self.trial: GraspTrial | None = None
        self.uid: int | None = None

    def load(self, model: ObjectModel) -> None:
        physics = physics_for(model, self.config.physics)  # as the worker: light objects substep
        if self.world.physics != physics:
            self.world.physics = physics
            self.world.configure()
        self.hand.teleport(Transform([0.0, 0.0, 2.0], [0, 0, 0, 1]), self.hand.gripper.max_width)  # parked
        self.uid = create_body(self.world.client, model, config=self.config.objects)
        self.world.set_gravity(False)
        self.trial = GraspTrial(self.world, self.hand, self.uid, self.config)

    def run(self, T_obj_tcp: Transform, width: float) -> Result:
        steps0, seconds0 = self.world.steps, self.world.step_seconds
        r = self.trial.run(T_obj_tcp, width)
        return Result(
            r.outcome != Outcome.COLLISION,
            r.outcome == Outcome.SUCCESS,
            self.world.steps - steps0,
            self.world.step_seconds - seconds0,
            r.width,
        )

    def unload(self) -> None:
        self.trial.close()
        self.world.remove_body(self.uid)

    def close(self) -> None:
        self.world.close()


# --- VGN -------------------------------------------------------------------------------------------

PANDA_FINGER_JOINT_Z = 0.0584  # finger joints below the hand frame (Franka description)
PANDA_PAD_Z = PANDA_FINGER_JOINT_Z + 0.04525  # centre of the fingertip box: the 103.4 mm TCP
# Franka's finger collision primitives (finger frame, left finger; metres): (centre, size, roll)
PANDA_FINGER_BOXES = [
    ((0.0, 0.0185, 0.011), (0.022, 0.015, 0.020), 0.0),
    ((0.0, 0.0068, 0.0022), (0.022, 0.0088, 0.0038), 0.0),
    ((0.0, 0.0159, 0.02835), (0.0175, 0.007, 0.0235), math.pi / 6),
    ((0.0, 0.00758, 0.04525), (0.0175, 0.0152, 0.0185), 0.0),
]


def panda_hand_urdf() -> str:
    """The Panda hand as VGN loads it, of boxes (see the module docstring for the numbers)."""

    def finger(side: float) -> str:
        out = ""
        for (x, y, z), (sx, sy, sz), roll in PANDA_FINGER_BOXES:
            out += (
                f'<collision><origin xyz="{x} {side * y} {z}" rpy="{side * roll} 0 0"/>'
                f'<geometry><box size="{sx} {sy} {sz}"/></geometry></collision>'
            )
        return out

    contact = (
        '<contact><friction_anchor/><stiffness value="30000.0"/><damping value="1000.0"/>'
        '<spinning_friction value="0.1"/><lateral_friction value="1.0"/></contact>'
    )
    inertia = '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>'
    joints = ""
    for name, link, axis, side in (
        ("panda_finger_joint1", "panda_leftfinger", "0 1 0", 1.0),
        ("panda_finger_joint2", "panda_rightfinger", "0 -1 0", -1.0),
    ):
        joints += (
            f'<joint name="{name}" type="prismatic"><parent link="panda_hand"/><child link="{link}"/>'
            f'<origin xyz="0 0 {PANDA_FINGER_JOINT_Z}"/><axis xyz="{axis}"/>'
            '<limit effort="20" lower="0.0" upper="0.04" velocity="0.2"/></joint>'
            f'<link name="{link}">{contact}<inertial><origin xyz="0 {side * 0.01} 0.02"/>'
            f'<mass value="0.1"/>{inertia}</inertial>{finger(side)}</link>'
        )
    return (
        '<?xml version="1.0"?><robot name="panda_hand_boxes"><link name="panda_hand">'
        f'<inertial><origin xyz="0 0 0"/><mass value="0.81"/>{inertia}</inertial>'
        '<collision><origin xyz="0 0 0.0292"/><geometry><box size="0.06 0.2 0.0584"/></geometry>'
        f"</collision></link>{joints}</robot>"
    )


class VGN(PeerTool):
    """VGN's ``ClutterRemovalSim.execute_grasp`` with its ``Gripper`` (corl2020), on our candidates."""

    name = "vgn"
    MAX_WIDTH = 0.08
    # our TCP frame (x closing, z approach) -> VGN's hand frame (y closing, z approach)
    T_tcp_grasp = Transform([0.0, 0.0, 0.0], [0.0, 0.0, -math.sin(math.pi / 4), math.cos(math.pi / 4)])
    T_grasp_body = Transform([0.0, 0.0, -PANDA_PAD_Z], [0, 0, 0, 1])  # hand frame behind the pads

    def __init__(self, folder: Path) -> None:
        self.sim = Sim(1.0 / 240.0, 150)
        self.urdf = folder / "panda_hand_boxes.urdf"
        self.urdf.write_text(panda_hand_urdf())
        self.obj: FloatingObject | None = None

    # the Gripper of simulation.py ---------------------------------------------------------------
    def _reset(self, T_world_body: Transform) -> None:
        c = self.sim.client
        self.body = pb.loadURDF(str(self.urdf), *T_world_body.to_pybullet(), physicsClientId=c)
        pos, quat = T_world_body.to_pybullet()
        self.constraint = carrier(c, self.body, pos, quat)
        self._update_constraint(T_world_body)
        gear = pb.createConstraint(
            self.body, 0, self.body, 1, pb.JOINT_GEAR, [1, 0, 0], [0, 0, 0], [0, 0, 0], physicsClientId=c
        )
        pb.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50, physicsClientId=c)
        for j in (0, 1):
            pb.resetJointState(self.body, j, 0.5 * self.MAX_WIDTH, physicsClientId=c)
        self._set_width(self.MAX_WIDTH)

    def _set_width(self, width: float) -> None:
        for j in (0, 1):
            pb.setJointMotorControl2(
                self.body,
                j,
                pb.POSITION_CONTROL,
                targetPosition=0.5 * width,
                force=20.0,
                physicsClientId=self.sim.client,
            )

    def _update_constraint(self, T_world_body: Transform) -> None:
        pos, quat = T_world_body.to_pybullet()
        pb.changeConstraint(
            self.constraint,
            jointChildPivot=pos,
            jointChildFrameOrientation=quat,
            maxForce=300,
            physicsClientId=self.sim.client,
        )

    def _contact(self) -> bool:
        return len(pb.getContactPoints(self.body, physicsClientId=self.sim.client)) > 0

    def _move_linear(self, pos_goal: np.ndarray, quat: np.ndarray, abort_on_contact: bool) -> None:
        """``move_tcp_xyz``: 2 mm increments at 0.1 m/s (int(0.02 s / dt) steps each)."""
        pos = np.asarray(pb.getBasePositionAndOrientation(self.body, physicsClientId=self.sim.client)[0])
        diff = pos_goal - pos
        n = int(np.linalg.norm(diff) / 0.002)
        dist_step = diff / n
        dur_step = np.linalg.norm(dist_step) / 0.10
        for _ in range(n):
            pos = pos + dist_step
            self._update_constraint(Transform(pos, quat))
            self.sim.step(int(dur_step / self.sim.dt))
            if abort_on_contact and self._contact():
                return

    def _width(self) -> float:
        s = pb.getJointStates(self.body, [0, 1], physicsClientId=self.sim.client)
        return s[0][0] + s[1][0]

    def run(self, T_obj_tcp: Transform, width: float) -> Result:
        steps0, seconds0 = self.sim.steps, self.sim.step_seconds
        self.obj.reset()
        self.sim.gravity(False)
        T_world_grasp = T_obj_tcp * self.T_tcp_grasp  # the object's mesh frame is the world's
        T_world_body = T_world_grasp * self.T_grasp_body
        approach = T_world_grasp.rotation[:, 2]
        T_world_pregrasp = Transform(T_world_body.pos - 0.05 * approach, T_world_body.quat)
        if np.arccos(np.clip(approach @ DOWN, -1, 1)) > np.pi / 3:
            retreat = T_world_body.pos + np.array([0.0, 0.0, 0.1])  # side grasp: lift
        else:
            retreat = T_world_body.pos - 0.1 * approach
        self._reset(T_world_pregrasp)
        simulated, success, w = True, False, self.MAX_WIDTH
        if self._contact():  # no step since loading: never true, as in VGN
            simulated = False
        else:
            self._move_linear(T_world_body.pos, T_world_body.quat, abort_on_contact=True)
            if self._contact():
                simulated = False
            else:
                self._set_width(0.0)
                self.sim.step(int(0.5 / self.sim.dt))
                self.sim.gravity(True)
                self._move_linear(retreat, T_world_body.quat, abort_on_contact=False)
                w = self._width()
                success = self._contact() and w > 0.1 * self.MAX_WIDTH
        pb.removeBody(self.body, physicsClientId=self.sim.client)
        return Result(simulated, success, self.sim.steps - steps0, self.sim.step_seconds - seconds0, w)


# --- AdaGrasp / BURG RG2 ---------------------------------------------------------------------------

RG2_LINK = np.array([-0.025592, 0.0, 0.048677])  # outer link, pivot to finger pivot (left side)
RG2_FINGER_BAR = ((-0.00506, 0.00906), (-0.00505, 0.05275))  # x, z ranges from the finger pivot
RG2_PAD = ((0.00906, 0.01906), (0.05275 - 0.0298, 0.05275))  # the pad: inner 10 mm, lowest 29.8 mm


def adagrasp_rg2_urdf() -> str:
    """AdaGrasp's RG2 joint layout of boxes (numbers in the module docstring)."""

    def box(centre, size, pitch: float = 0.0) -> str:
        return (
            f'<collision><origin xyz="{centre[0]:.6f} {centre[1]:.6f} {centre[2]:.6f}" '
            f'rpy="0 {pitch:.6f} 0"/><geometry><box size="{size[0]:.6f} {size[1]:.6f} {size[2]:.6f}"/>'
            "</geometry></collision>"
        )

    heavy = '<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'

    def link(name: str, body: str) -> str:
        return f'<link name="{name}">{heavy}{body}</link>'

    def joint(name: str, parent: str, child: str, xyz, pitch: float, lower: float, upper: float) -> str:
        return (
            f'<joint name="{name}" type="revolute"><origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" '
            f'rpy="0 {pitch} 0"/><axis xyz="0 1 0"/><limit effort="20" lower="{lower}" upper="{upper}" '
            f'velocity="0.2"/><parent link="{parent}"/><child link="{child}"/></joint>'
        )

    def bar(side: float) -> str:  # a 55 mm link from its pivot to the finger pivot
        v = RG2_LINK * np.array([side, 1, 1])
        return box(v / 2, (0.008, 0.02, float(np.linalg.norm(v))), math.atan2(v[0], v[2]))

    def finger(side: float) -> str:
        out = ""
        for (x0, x1), (z0, z1) in (RG2_FINGER_BAR, RG2_PAD):
            out += box((side * -(x0 + x1) / 2, 0.0, (z0 + z1) / 2), (x1 - x0, 0.02, z1 - z0))
        return out

    palm = box((0.0001, 0.0, 0.0111), (0.0685, 0.0523, 0.1326))
    parts = [link("palm", palm)]
    # in AdaGrasp's order: indices 0..5 = left inner, left outer (driver), left finger, right inner,
    # right outer, right finger; side -1 is the left finger's (-x), the finger offsets mirror
    parts.append(joint("palm_left_inner_joint", "palm", "left_inner", (-0.0075, 0, 0.0715), -0.43, 0, 0.86))
    parts.append(link("left_inner", bar(1.0)))
    parts.append(joint("palm_left_outer_joint", "palm", "left_outer", (-0.017, 0, 0.055), -0.43, 0, 0.86))
    parts.append(link("left_outer", bar(1.0)))
    parts.append(joint("left_finger_joint", "left_outer", "left_finger", tuple(RG2_LINK), 0.43, -0.86, 0))
    parts.append(link("left_finger", finger(-1.0)))
    parts.append(joint("palm_right_inner_joint", "palm", "right_inner", (0.0075, 0, 0.0715), 0.43, -0.86, 0))
    parts.append(link("right_inner", bar(-1.0)))
    parts.append(joint("palm_right_outer_joint", "palm", "right_outer", (0.017, 0, 0.055), 0.43, -0.86, 0))
    parts.append(link("right_outer", bar(-1.0)))
    right = tuple(RG2_LINK * np.array([-1, 1, 1]))
    parts.append(joint("right_finger_joint", "right_outer", "right_finger", right, -0.43, 0, 0.86))
    parts.append(link("right_finger", finger(1.0)))
    return '<?xml version="1.0"?><robot name="adagrasp_rg2_boxes">' + "".join(parts) + "</robot>"


class AdaGrasp(PeerTool):
    """BURG's ``GraspSimulator.execute_grasp`` with AdaGrasp's RG2, on our candidates."""

    name = "adagrasp"
    DRIVER, FOLLOWERS, SIGNS = 1, [0, 2, 3, 4, 5], np.array([1.0, -1.0, -1.0, -1.0, 1.0])
    FINGERS = (2, 5)
    UPPER = 0.86
    FORCE = 2 * 500.0  # BURG doubles AdaGrasp's 500
    GAIN = 1.5
    SPEED = 0.5  # rad/s
    LIFT, LIFT_SPEED = 0.10, 0.2  # m, m/s

    def __init__(self, folder: Path) -> None:
        self.sim = Sim(1.0 / 240.0, 100)
        self.urdf = folder / "adagrasp_rg2_boxes.urdf"
        self.urdf.write_text(adagrasp_rg2_urdf())
        self.obj: FloatingObject | None = None
        self._tabulate()

    def _tabulate(self) -> None:
        """Pad-face separation and pad-centre midpoint over the driver's range (the model's own FK)."""
        c = self.sim.client
        body = pb.loadURDF(str(self.urdf), useFixedBase=True, physicsClientId=c)
        q = np.linspace(0.0, self.UPPER, 200)
        widths, mids = [], []
        pad_centre = np.array([(RG2_PAD[0][0] + RG2_PAD[0][1]) / 2, 0, (RG2_PAD[1][0] + RG2_PAD[1][1]) / 2])
        for a in q:
            self._reset_joints(body, a)
            p = []
            for link, side in ((2, 1.0), (5, -1.0)):
                s = pb.getLinkState(body, link, computeForwardKinematics=1, physicsClientId=c)
                p.append(Transform(s[4], s[5]).apply(pad_centre * np.array([side, 1, 1])))
            pad_thickness = RG2_PAD[0][1] - RG2_PAD[0][0]
            widths.append(p[1][0] - p[0][0] - pad_thickness)
            mids.append((p[0] + p[1]) / 2)
        pb.removeBody(body, physicsClientId=c)
        order = np.argsort(widths)
        self.q_table, self.w_table = q[order], np.asarray(widths)[order]
        self.mid_table = np.asarray(mids)[order]
        self.max_width = float(self.w_table[-1])

    def _reset_joints(self, body: int, driver: float) -> None:
        pb.resetJointState(body, self.DRIVER, driver, physicsClientId=self.sim.client)
        for j, s in zip(self.FOLLOWERS, self.SIGNS, strict=True):
            pb.resetJointState(body, j, s * driver, physicsClientId=self.sim.client)

    def T_base_tcp(self, width: float) -> Transform:
        mid = [np.interp(width, self.w_table, self.mid_table[:, i]) for i in range(3)]
        return Transform(mid, [0, 0, 0, 1])

    def _step_constraints(self) -> None:
        c = self.sim.client
        pos = pb.getJointState(self.body, self.DRIVER, physicsClientId=c)[0]
        pb.setJointMotorControlArray(
            self.body,
            self.FOLLOWERS,
            pb.POSITION_CONTROL,
            targetPositions=(pos * self.SIGNS).tolist(),
            forces=[self.FORCE] * 5,
            positionGains=[self.GAIN] * 5,
            physicsClientId=c,
        )

    def _step(self, n: int, each: Callable[[int], None] | None = None) -> None:
        for i in range(n):
            if each is not None:
                each(i)
            self._step_constraints()
            self.sim.step()

    def _fingers_touch(self) -> bool:
        c = self.sim.client
        return all(
            pb.getContactPoints(self.body, self.obj.uid, link, -1, physicsClientId=c) for link in self.FINGERS
        )

    def run(self, T_obj_tcp: Transform, width: float) -> Result:
        c = self.sim.client
        steps0, seconds0 = self.sim.steps, self.sim.step_seconds
        self.obj.reset()
        self.sim.gravity(False)
        T_world_base = T_obj_tcp * self.T_base_tcp(width).inverse()
        pos, quat = T_world_base.to_pybullet()
        # gripper.load: loadURDF (no self-collision), configure_friction, configure_mass, open fully
        self.body = pb.loadURDF(str(self.urdf), pos, quat, physicsClientId=c)
        for j in range(6):
            pb.changeDynamics(
                self.body,
                j,
                lateralFriction=1.0,
                spinningFriction=1.0,
                rollingFriction=0.0001,
                frictionAnchor=True,
                physicsClientId=c,
            )
        pb.changeDynamics(self.body, -1, mass=0.4, physicsClientId=c)
        for j in range(6):
            pb.changeDynamics(self.body, j, mass=0.1 / 6, physicsClientId=c)
        self._reset_joints(self.body, 0.0)
        mount = carrier(c, self.body, pos, quat)
        pb.changeConstraint(
            mount, jointChildPivot=pos, jointChildFrameOrientation=quat, maxForce=1000, physicsClientId=c
        )
        close = pb.getClosestPoints(self.body, self.obj.uid, 0.01, physicsClientId=c)
        simulated, success = True, False
        if any(p[8] < -0.001 for p in close):
            simulated = False
        else:
            pb.setJointMotorControl2(
                self.body,
                self.DRIVER,
                pb.VELOCITY_CONTROL,
                targetVelocity=self.SPEED,
                force=self.FORCE,
                physicsClientId=c,
            )
            self._step(int(2.0 / self.sim.dt))
            if self._fingers_touch():
                self.sim.gravity(True)
                n = int(self.LIFT / self.LIFT_SPEED / self.sim.dt)
                start = np.asarray(pos)

                def lift(i: int) -> None:
                    p = start + np.array([0.0, 0.0, self.LIFT * (i + 1) / n])
                    pb.changeConstraint(
                        mount,
                        jointChildPivot=p.tolist(),
                        jointChildFrameOrientation=quat,
                        maxForce=1000,
                        physicsClientId=c,
                    )

                self._step(n, lift)
                success = self._fingers_touch()
        pb.removeBody(self.body, physicsClientId=c)
        return Result(simulated, success, self.sim.steps - steps0, self.sim.step_seconds - seconds0)


# --- the bench -------------------------------------------------------------------------------------


@dataclass
class Tally:
    """One tool's figures over one round."""

    seconds: list[float] = field(default_factory=list)  # CPU time per candidate
    wall: list[float] = field(default_factory=list)  # wall time per candidate
    results: list[Result] = field(default_factory=list)

    def add(self, seconds: float, wall: float, result: Result) -> None:
        self.seconds.append(seconds)
        self.wall.append(wall)
        self.results.append(result)

    def figures(self) -> dict[str, float]:
        sim = [r.simulated for r in self.results]
        n_sim = sum(sim)
        steps = sum(r.steps for r in self.results)
        trial_seconds = sum(s for s, k in zip(self.seconds, sim, strict=True) if k)
        trial_steps = sum(r.steps for r in self.results if r.simulated)
        return {
            "candidates": len(self.results),
            "simulated": sum(sim),
            "successes": sum(r.success for r in self.results),
            "ms_candidate": 1e3 * sum(self.seconds) / max(1, len(self.seconds)),
            "ms_trial": over(1e3 * trial_seconds, n_sim),  # NaN: no trial simulated
            "ms_reject": over(1e3 * (sum(self.seconds) - trial_seconds), len(sim) - n_sim),
            "steps_trial": over(trial_steps, n_sim),
            "ms_step": 1e3 * sum(r.step_seconds for r in self.results) / max(1, steps),
            "outside_step": 1.0 - sum(r.step_seconds for r in self.results) / max(1e-12, sum(self.seconds)),
            "wall_ms_candidate": 1e3 * sum(self.wall) / max(1, len(self.wall)),
        }


def load(label: str) -> str:
    one, five, _ = os.getloadavg()
    return f"{label} load average {one:.2f} (1 min) {five:.2f} (5 min)"


Work = list[tuple[ObjectModel, Candidates]]


@dataclass
class Round:
    """One pass of every tool over every candidate, and the free step measured right after it."""

    tallies: dict[str, Tally]  # per tool
    by_object: dict[tuple[str, str], Tally]  # per (object id, tool)
    free_step: FreeStep


def take_turns(tools: list[Tool], work: Work) -> tuple[dict[str, Tally], dict[tuple[str, str], Tally]]:
    """Every tool runs every candidate of ``work``, taking turns per candidate (the order rotates
    by one each candidate, so load hits all tools alike); CPU and wall time are taken around
    ``Tool.run``. Returns the tallies per tool and per (object id, tool)."""
    tallies = {t.name: Tally() for t in tools}
    by_object: dict[tuple[str, str], Tally] = {}
    for model, cands in work:
        for t in tools:
            t.enter()
            t.load(model)
        for k in range(len(cands)):
            T = Transform.from_matrix(cands.T_obj_tcp[k])
            w = float(cands.width_expected[k])
            for i in range(len(tools)):
                t = tools[(i + k) % len(tools)]
                t.enter()
                t0, c0 = time.perf_counter(), time.process_time()
                res = t.run(T, w)
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                tallies[t.name].add(cpu, wall, res)
                by_object.setdefault((model.object_id, t.name), Tally()).add(cpu, wall, res)
        for t in tools:
            t.unload()
    return tallies, by_object


@dataclass(frozen=True)
class ObjectTurns:
    """One object's part of a round, what a worker is asked (:func:`object_turns`): the bench
    object ``object_id`` (a key of :data:`BENCH_OBJECTS`), its first ``candidates`` sampled
    candidates (``seed``), ours at ``config`` and at each of the ``variants`` (tool name,
    configuration), the peers unless ``peers`` is False; ``cache_dir``: the decomposition cache
    (None: the default)."""

    object_id: str
    candidates: int
    seed: int
    config: AnnotatorConfig
    variants: tuple[tuple[str, AnnotatorConfig], ...] = ()
    peers: bool = True
    cache_dir: Path | None = None


@dataclass(frozen=True)
class ObjectTallies:
    """What a worker reports of one object's turns: the object (``parts`` convex parts, ``mass``
    in kg, ``substepped``: ours divides its time step, a light object) and each tool's tally, in
    the tools' order (ours first)."""

    object_id: str
    parts: int
    mass: float
    substepped: bool
    tallies: dict[str, Tally]

    @property
    def candidates(self) -> int:
        """The object's candidates (each tool ran every one)."""
        return len(next(iter(self.tallies.values())).results)


def make_tools(turns: ObjectTurns, folder: Path) -> list[Tool]:
    """Ours, its variants and (unless ``turns.peers`` is False) the peers, their models in ``folder``."""
    tools: list[Tool] = [Ours(turns.config)]
    tools += [Ours(variant, name=name) for name, variant in turns.variants]
    if turns.peers:
        tools += [VGN(folder), AdaGrasp(folder)]
    return tools


def object_turns(turns: ObjectTurns) -> ObjectTallies:
    """In a worker (a :class:`Call`'s function): the tools of ``turns`` built in this process,
    the object written and loaded (its collision shape from the cache), its candidates sampled for
    our gripper, every tool running every candidate in turns (:func:`take_turns`)."""
    with tempfile.TemporaryDirectory(prefix="rg2-peers-") as tmp:
        folder = Path(tmp)
        (source,) = bench_objects(folder, (turns.object_id,))
        model = load_object(source, turns.config.objects, cache_dir=turns.cache_dir)
        tools = make_tools(turns, folder)
        try:
            ours = tools[0]
            assert isinstance(ours, Ours)  # make_tools puts ours first
            max_width = ours.hand.gripper.max_width
            cands = object_candidates(model, turns.candidates, turns.seed, turns.config, max_width)
            tallies, _ = take_turns(tools, [(model, cands)])
        finally:
            for tool in tools:
                tool.close()
    substepped = model.substeps(turns.config.physics) > 1
    return ObjectTallies(model.object_id, len(model.parts), float(model.mass), substepped, tallies)


def run_round(units: list[ObjectTurns], execution: ExecutionOptions) -> list[ObjectTallies]:
    """Every object's turns through the runner's execution, in the order of ``units``; what a task
    raised is raised here, a task whose worker died twice is a RuntimeError naming its object."""
    tasks = [Call(fn=object_turns, args=(unit,), config=unit.config) for unit in units]
    return call_values(tasks, execution, names=[u.object_id for u in units])


def measured_free_step(config: AnnotatorConfig, execution: ExecutionOptions) -> FreeStep:
    """The free step of our gripper (bench/reference.py), timed in a worker as a task of its own."""
    (result,) = call_values([Call(fn=free_step, args=(config,), config=config)], execution, ["free step"])
    return result


def round_of(objects: list[ObjectTallies], step: FreeStep) -> Round:
    """A round from its objects' tallies (in the objects' order): per tool, its tallies merged over
    the objects in that order; per (object id, tool), as the worker counted them."""
    names = list(objects[0].tallies)
    by_object = {(o.object_id, name): tally for o in objects for name, tally in o.tallies.items()}
    tallies = {name: merged([o.tallies[name] for o in objects]) for name in names}
    return Round(tallies, by_object, step)


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--per-object", type=count(1, N_MAX), default=100, help="candidates per object (3 objects)"
    )
    ap.add_argument(
        "--rounds", type=count(1, REPEAT_MAX), default=2, help="repeat the whole set this many times"
    )
    ap.add_argument("--seed", type=seed, default=0)
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help="also run ours with FIELD=VALUE[,FIELD=VALUE] (repeatable)",
    )
    ap.add_argument("--no-peers", action="store_true", help="only ours and its variants")
    ap.add_argument(
        "--workers",
        type=count(1, WORKERS_MAX),
        default=1,
        help="worker processes; each runs an object's turns with every tool (default 1)",
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    logging.basicConfig(level=logging.WARNING)
    config = AnnotatorConfig()
    variants = []
    for spec in args.variant:
        label, variant = parse_variant(spec, config)
        variants.append((f"ours[{label}]", variant))
    units = [
        ObjectTurns(name, args.per_object, args.seed, config, tuple(variants), not args.no_peers)
        for name in BENCH_OBJECTS
    ]
    execution = ExecutionOptions(workers=args.workers)
    reference = "ours"
    boundary = config.physics.light_object_mass
    with Run("peers", config=vars(args), annotator=config) as run:
        rounds: list[Round] = []
        light: set[str] = set()
        for r in range(args.rounds):
            print(load(f"\nround {r + 1}: start,"))
            objects = run_round(units, execution)
            rounds.append(round_of(objects, measured_free_step(config, execution)))
            if r == 0:
                light = describe(objects)
            print(load(f"round {r + 1}: end,"))
            report(rounds[-1].tallies, reference, rounds[-1].free_step)
            per_object(rounds[-1].by_object, reference)
            for label, group in light_groups(rounds[-1].by_object, light, boundary):
                by_light_boundary(rounds[-1].by_object, reference, label, group)
        if args.rounds > 1:
            spread([r.tallies for r in rounds])
        record(run, rounds, reference, light, boundary)


def describe(objects: list[ObjectTallies]) -> set[str]:
    """Print each object (convex parts, grams) and the candidates; the objects ours substeps."""
    for o in objects:
        print(f"{o.object_id}: {o.parts} convex part(s), {o.mass * 1000:.0f} g")
    print(f"{sum(o.candidates for o in objects)} candidates; tools take turns per candidate")
    return {o.object_id for o in objects if o.substepped}


def slug(name: str) -> str:
    """A tool's name as part of a figure's name: ``ours[it100]`` -> ``ours_it100``."""
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def over(a: float, b: float) -> float:
    """a / b; NaN when b is 0 (a tool that simulated none of a group's candidates)."""
    return a / b if b else float("nan")


def median_spread(values: list[float]) -> tuple[float, tuple[float, float] | None]:
    """Median and (min, max) of the values that are numbers; NaN and no range if none is."""
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return float("nan"), None
    return statistics.median(values), (min(values), max(values))


def record(run: Run, rounds: list[Round], reference: str, light: set[str], boundary: float) -> None:
    """The rounds as a record: ratios of ours to each tool and of each tool to the free step
    (medians over rounds, with their range), each tool's figures, the per-round tables."""
    names = list(rounds[0].tallies)
    figs = [{n: r.tallies[n].figures() for n in names} for r in rounds]
    n = len(rounds)
    for name in names:
        if name == reference:
            continue
        for key, what in (("ms_candidate", "candidate"), ("ms_trial", "trial"), ("ms_step", "step")):
            value, range_ = median_spread([over(f[reference][key], f[name][key]) for f in figs])
            run.ratio(
                f"{slug(reference)}_over_{slug(name)}_per_{what}",
                value,
                spread=range_,
                note=f"CPU ms per {what}, {reference} / {name}; median of {n} rounds",
            )
        for label, group in light_groups(rounds[0].by_object, light, boundary):
            key = "light" if group[0] in light else "heavy"
            for fig, what in (("ms_candidate", "candidate"), ("ms_trial", "trial")):
                ratios = []
                for r in rounds:
                    ref = merged([r.by_object[(o, reference)] for o in group]).figures()
                    other = merged([r.by_object[(o, name)] for o in group]).figures()
                    ratios.append(over(ref[fig], other[fig]))
                value, range_ = median_spread(ratios)
                run.ratio(
                    f"{slug(reference)}_over_{slug(name)}_per_{what}_{key}",
                    value,
                    spread=range_,
                    note=f"as above, objects {label}: {', '.join(group)}",
                )
    for name in names:
        for key, what in (("ms_candidate", "candidate"), ("ms_trial", "simulated trial")):
            value, range_ = median_spread(
                [over(f[name][key], r.free_step.cpu_ms) for f, r in zip(figs, rounds, strict=True)]
            )
            run.ratio(
                f"{slug(name)}_free_steps_per_{what.split()[-1]}",
                value,
                spread=range_,
                note=f"{name}: CPU time per {what} / CPU time of a free step measured after the round",
            )
    for name in names:
        for key, unit, what in (
            ("ms_candidate", "ms", "CPU ms per candidate"),
            ("ms_trial", "ms", "CPU ms per simulated trial"),
            ("ms_step", "ms", "CPU ms per step, inside stepSimulation"),
            ("steps_trial", "", "steps per simulated trial"),
        ):
            value, range_ = median_spread([f[name][key] for f in figs])
            run.figure(f"{slug(name)}_{key}", value, unit, spread=range_, note=f"{name}: {what}")
        agree_all, agree_sim = agreement(rounds[0].tallies[name], rounds[0].tallies[reference])
        if name != reference:
            run.figure(
                f"{slug(name)}_agree_sim",
                100 * agree_sim,
                "%",
                note=f"success as {reference}, both simulated",
            )
    value, range_ = median_spread([r.free_step.cpu_ms for r in rounds])
    run.figure("free_step_cpu_ms", value, "ms", spread=range_, note="the reference, after each round")
    run.table(
        "rounds",
        [
            {"round": k + 1, "tool": name, **{key: f[name][key] for key in TABLE_KEYS}}
            for k, f in enumerate(figs)
            for name in names
        ],
        note="CPU ms; outside_step: share of a candidate's CPU time outside stepSimulation",
    )
    run.table(
        "per_object",
        [
            {"round": k + 1, "object": o, "tool": name, **{key: t.figures()[key] for key in TABLE_KEYS}}
            for k, r in enumerate(rounds)
            for (o, name), t in r.by_object.items()
        ],
    )


TABLE_KEYS = ("candidates", "simulated", "successes", "ms_candidate", "ms_trial", "steps_trial", "ms_step")


def agreement(tally: Tally, ref: Tally) -> tuple[float, float]:
    """Share of candidates whose success is ``ref``'s: all, and those both simulated (NaN if none)."""
    a = np.array([x.success for x in tally.results])
    b = np.array([x.success for x in ref.results])
    both = np.array([x.simulated and y.simulated for x, y in zip(tally.results, ref.results, strict=True)])
    return float((a == b).mean()), float((a[both] == b[both]).mean()) if both.any() else float("nan")


def report(tallies: dict[str, Tally], reference: str, step: FreeStep) -> None:
    """The table of one round: CPU milliseconds (``time.process_time``), agreement with ``reference``,
    and the cost of a candidate in free steps (``step``)."""
    ref = tallies[reference]
    ref_fig = ref.figures()
    head = (
        f"{'tool':<34} {'ms/cand':>8} {'ms/trial':>9} {'ms/reject':>9} {'steps/trial':>11} {'ms/step':>8} "
        f"{'outside':>8} "
        f"{'simulated':>9} {'success':>7} {'agree all':>9} {'agree sim':>9}"
    )
    print("CPU time per candidate / per simulated trial / per candidate rejected without a trial (a")
    print("kinematic collision for ours and adagrasp, contact on the simulated approach for vgn) / per step")
    print("inside stepSimulation;")
    print("'outside': share of the candidate's CPU time spent outside stepSimulation")
    print(head + "\n" + "-" * len(head))
    for name, tally in tallies.items():
        f = tally.figures()
        agree_all, agree_sim = agreement(tally, ref)
        print(
            f"{name:<34} {f['ms_candidate']:8.1f} {f['ms_trial']:9.1f} {f['ms_reject']:9.1f} "
            f"{f['steps_trial']:11.0f} "
            f"{f['ms_step']:8.3f} {f['outside_step']:8.1%} {f['simulated']:9d} {f['successes']:7d} "
            f"{agree_all:9.1%} {agree_sim:9.1%}"
        )
    print(
        f"free step (bench/reference.py) {step.cpu_ms:.3f} CPU ms: a candidate costs "
        + ", ".join(f"{name} {t.figures()['ms_candidate'] / step.cpu_ms:.0f}" for name, t in tallies.items())
        + " free steps"
    )
    for name, tally in tallies.items():
        if name == reference:
            continue
        f = tally.figures()
        print(
            f"{reference} / {name}: per candidate {over(ref_fig['ms_candidate'], f['ms_candidate']):.2f} "
            f"(wall {over(ref_fig['wall_ms_candidate'], f['wall_ms_candidate']):.2f}), "
            f"per trial {over(ref_fig['ms_trial'], f['ms_trial']):.2f}, "
            f"per step {over(ref_fig['ms_step'], f['ms_step']):.2f}"
        )


def per_object(by_object: dict[tuple[str, str], Tally], reference: str) -> None:
    """CPU ms per simulated trial and steps per trial of each tool on each object, and the ratio."""
    print("per object: CPU ms per simulated trial (steps per trial); ratio of ours to each")
    for obj in dict.fromkeys(o for o, _ in by_object):
        ref = by_object[(obj, reference)].figures()
        cells = []
        for (o, name), tally in by_object.items():
            if o == obj:
                f = tally.figures()
                ratio = "" if name == reference else f" x{over(ref['ms_trial'], f['ms_trial']):.2f}"
                cells.append(f"{name} {f['ms_trial']:.1f} ({f['steps_trial']:.0f}){ratio}")
        print(f"  {obj:<16} " + ", ".join(cells))


def merged(tallies: list[Tally]) -> Tally:
    """One tally of several (the candidates of several objects)."""
    out = Tally()
    for t in tallies:
        for seconds, wall, result in zip(t.seconds, t.wall, t.results, strict=True):
            out.add(seconds, wall, result)
    return out


def light_groups(
    by_object: dict[tuple[str, str], Tally], light: set[str], boundary: float
) -> list[tuple[str, list[str]]]:
    """(label, object ids) of the objects ours simulates at time_step (at or above ``boundary``,
    PhysicsConfig.light_object_mass) and of the light ones it substeps; empty groups left out."""
    objects = list(dict.fromkeys(o for o, _ in by_object))
    groups = [
        (f"at or above {boundary * 1000:.0f} g", [o for o in objects if o not in light]),
        (f"below {boundary * 1000:.0f} g (substepped)", [o for o in objects if o in light]),
    ]
    return [(label, group) for label, group in groups if group]


def by_light_boundary(
    by_object: dict[tuple[str, str], Tally], reference: str, label: str, group: list[str]
) -> None:
    """Ours / each tool per candidate and per trial over the objects of ``group``."""
    tools = list(dict.fromkeys(n for _, n in by_object))
    ref = merged([by_object[(o, reference)] for o in group]).figures()
    cells = []
    for name in tools:
        if name != reference:
            f = merged([by_object[(o, name)] for o in group]).figures()
            cells.append(
                f"/ {name} per candidate {over(ref['ms_candidate'], f['ms_candidate']):.2f}, "
                f"per trial {over(ref['ms_trial'], f['ms_trial']):.2f}"
            )
    print(f"  objects {label} ({', '.join(group)}): {reference} " + "; ".join(cells))


def spread(rounds: list[dict[str, Tally]]) -> None:
    print(f"\nspread over {len(rounds)} rounds (min / median / max)")
    for name in rounds[0]:
        figs = [r[name].figures() for r in rounds]
        cells = []
        for key, fmt in (("ms_candidate", ".1f"), ("ms_trial", ".1f"), ("ms_step", ".3f")):
            v = [f[key] for f in figs]
            cells.append(f"{key} {min(v):{fmt}} / {statistics.median(v):{fmt}} / {max(v):{fmt}}")
        print(f"{name:<34} " + ", ".join(cells))
    reference = next(iter(rounds[0]))
    for name in list(rounds[0])[1:]:
        cells = []
        for key in ("ms_candidate", "ms_trial"):
            v = [over(r[reference].figures()[key], r[name].figures()[key]) for r in rounds]
            cells.append(f"per {key[3:]} {min(v):.2f} / {statistics.median(v):.2f} / {max(v):.2f}")
        print(f"{reference} / {name:<26} " + ", ".join(cells))


if __name__ == "__main__":
    # main of the module imported by name: the functions its tasks name are pickled by reference
    from bench.peers import main as importable_main

    importable_main()
