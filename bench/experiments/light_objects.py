"""Face-to-face grasps on a light, thin plate: how many hold and how deep the pads end, per object
mass and simulation time step (the measurement behind PhysicsConfig.light_object_mass).

    python -m bench.experiments.light_objects                         # 4 g and 40 g, 1/240 s and as simulated
    python -m bench.experiments.light_objects --grams 4 14 27 --hz 240 480 760 1000

The plate is 48 x 24 x 6.35 mm (a domino); its candidates come from the sampler (seed 0) and only
those closing across the 6.35 mm faces that pass the collision check are simulated. "as
simulated" is the step the annotator uses for that mass (time_step / contact_substeps). Prints a
line per mass and step and writes a record (bench/harness.py). Every step of a trial is at the
given rate, the lift and shake included (the annotator lifts and shakes an object of
``light_hold_mass`` or more at ``time_step``: ``bench.experiments.light_threshold --own-step``).

Each mass and step is a task of the runner's execution
(:func:`annotator.pipeline.in_memory.run_in_memory`): :func:`held_on_plate` run by a
:class:`~annotator.pipeline.tasks.Call` in a worker process (``--workers`` of them, or a Dask
cluster's), after the checks every task gets, in a temporary folder of its own (the plate's mesh
and its collision shape); a worker that dies costs its task one retry. A task depends on its mass,
step and candidates only, so the lines do not depend on the workers.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import (
    ObjectProperties,
    ObjectSource,
    contact_substeps,
    create_body,
    load_object,
    physics_for,
)
from annotator.outcome import Outcome
from annotator.pipeline.in_memory import ExecutionOptions, call_values
from annotator.pipeline.object_modes import PARKED
from annotator.pipeline.tasks import Call
from annotator.sampler import object_rng, sample_candidates
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial, TrialResult
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, number
from bench.harness import Run

EXTENTS = (0.048, 0.024, 0.00635)


def simulated_trials(
    mesh: trimesh.Trimesh,
    name: str,
    grams: float,
    seed: int,
    n: int,
    config: AnnotatorConfig,
    folder: Path,
    keep: Callable[[Transform], bool] | None = None,
    own_step: bool = False,
) -> Iterator[TrialResult]:
    """Trials of the first ``n`` sampled candidates on ``mesh`` (metres) of ``grams``, floating
    gripper, simulated at ``config.physics`` as given (no light-object substeps), or with
    ``own_step`` at the annotator's own steps for that mass (``physics_for``: the close at its finer
    step, the lift and shake as ``PhysicsConfig.held`` says); those ``keep`` rejects (by pose) are
    not run, those the collision check rejects are not yielded."""
    path = folder / f"{name}.obj"
    if not path.exists():
        mesh.export(path)
    source = ObjectSource(name, path, properties=ObjectProperties(mass=grams / 1000.0))
    model = load_object(source, config.objects, cache_dir=folder / "cache")
    cands = sample_candidates(model.mesh, n, object_rng(seed, name), config.sampler, 0.110)
    with World(physics_for(model, config.physics) if own_step else config.physics) as world:
        hand = FloatingGripper(world, config.gripper)
        hand.teleport(PARKED, hand.gripper.max_width)
        uid = create_body(world.client, model)
        world.set_gravity(False)
        trial = GraspTrial(world, hand, uid, config)
        for k in range(n):
            T = Transform.from_matrix(cands.T_obj_tcp[k])
            if keep is not None and not keep(T):
                continue
            r = trial.run(T, float(cands.width_expected[k]))
            if r.outcome != Outcome.COLLISION:
                yield r


@dataclasses.dataclass(frozen=True)
class Held:
    """Face-to-face grasps on the plate at one mass and step: how many held, the pads' depth (mm)."""

    grams: float
    hz: float
    held: int
    simulated: int
    mean_depth_mm: float | None
    max_depth_mm: float | None

    def line(self) -> str:
        deep = (
            f"pads {self.mean_depth_mm:.2f} mm deep on average, {self.max_depth_mm:.2f} max"
            if self.held
            else "no success"
        )
        return (
            f"{self.grams:5.1f} g at 1/{self.hz:.0f} s: {self.held:2d} of {self.simulated} "
            f"face-to-face grasps held, {deep}"
        )


def across_thin_faces(T: Transform) -> bool:
    """The closing axis along the plate's thickness."""
    return abs(T.rotation[2, 0]) >= 0.95


def measure(grams: float, hz: float, n: int, folder: Path) -> Held:
    config = AnnotatorConfig()
    config = dataclasses.replace(config, physics=dataclasses.replace(config.physics, time_step=1.0 / hz))
    outcomes, depths = [], []
    for r in simulated_trials(
        trimesh.creation.box(EXTENTS), "domino", grams, 0, n, config, folder, across_thin_faces
    ):
        outcomes.append(r.outcome)
        if r.outcome == Outcome.SUCCESS:
            depths.append(EXTENTS[2] - r.width)
    d = np.array(depths) * 1e3
    return Held(
        grams,
        hz,
        sum(o == Outcome.SUCCESS for o in outcomes),
        len(outcomes),
        float(d.mean()) if len(d) else None,
        float(d.max()) if len(d) else None,
    )


@dataclass(frozen=True)
class Plate:
    """One measurement: the plate at ``grams``, simulated at ``hz`` steps per second, its first
    ``candidates`` sampled candidates (seed 0)."""

    grams: float
    hz: float
    candidates: int

    def name(self) -> str:
        """What the measurement is called in an error: ``4 g at 1/240 s``."""
        return f"{self.grams:g} g at 1/{self.hz:.0f} s"


def held_on_plate(plate: Plate) -> Held:
    """In a worker (a :class:`Call`'s function): :func:`measure` of ``plate`` in a temporary
    folder of this process (the plate's mesh and collision shape)."""
    with tempfile.TemporaryDirectory(prefix="rg2-plate-") as tmp:
        return measure(plate.grams, plate.hz, plate.candidates, Path(tmp))


def measure_all(plates: list[Plate], workers: int) -> list[Held]:
    """Every plate's measurement, through the runner's execution on ``workers`` processes, in the
    order of ``plates``; what a task raised is raised here, a task whose worker died twice is a
    RuntimeError naming it."""
    config = AnnotatorConfig()  # what every task carries; each plate makes its own from it
    tasks = [Call(fn=held_on_plate, args=(plate,), config=config) for plate in plates]
    return call_values(tasks, ExecutionOptions(workers=workers), names=[p.name() for p in plates])


def plates(grams: list[float], hz: list[float] | None, candidates: int) -> list[Plate]:
    """The measurements asked for: each mass at each rate of ``hz`` (None: at 1/time_step and at
    the step the annotator simulates that mass at, once if they are the same)."""
    physics = AnnotatorConfig().physics
    out: list[Plate] = []
    for g in grams:
        rates = hz or sorted(
            {1.0 / physics.time_step, contact_substeps(g / 1000.0, physics) / physics.time_step}
        )
        out.extend(Plate(g, rate, candidates) for rate in rates)
    return out


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grams", type=number(0.0, 100_000.0, low_open=True), nargs="+", default=[4.0, 40.0])
    ap.add_argument(
        "--hz",
        type=number(1.0, 1_000_000.0),
        nargs="+",
        default=None,
        help="steps per second (default 240 and as simulated)",
    )
    ap.add_argument("--candidates", type=count(1, N_MAX), default=90)
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=1, help="worker processes")
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("light_objects", config=vars(args)) as run:
        rows = []
        for held in measure_all(plates(args.grams, args.hz, args.candidates), args.workers):
            print(held.line(), flush=True)
            rows.append(dataclasses.asdict(held))
        run.table("held", rows, note="face-to-face grasps of a 48 x 24 x 6.35 mm plate, seed 0")


if __name__ == "__main__":
    # main of the module imported by name: the functions its tasks name are pickled by reference
    from bench.experiments.light_objects import main as importable_main

    importable_main()
