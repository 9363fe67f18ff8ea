"""Where a light object stops needing a finer time step: labels at 1/240 s against a fine step,
per object mass, over several shapes and seeds (the derivation of PhysicsConfig.light_object_mass).

    python -m bench.experiments.light_threshold                               # the default grid, 2 processes
    python -m bench.experiments.light_threshold --grams 24 32 40 --seeds 0 --shapes domino cube40
    python -m bench.experiments.light_threshold --grams 40 80 --set physics.contact_breaking_threshold=0.01

For every (shape, mass, seed) the object's sampled candidates that pass the kinematic collision
check are simulated twice with the current default gripper and protocol: at ``time_step`` (one
step per 1/240 s) and at ``time_step / --fine`` (the fine reference; 4 is finer than the annotator
uses for any mass >= 2.5 g). Printed per row: the successes at each step, the success agreement
between the two, and how many successes' widths differ by more than 0.2 mm. A heavy mass (80 g by
default) is in the grid as the control: 1/240 s against the fine step disagrees there too, because
a grasp that is decided by a hair flips with any change of step. A mass needs no finer step when
its agreement is within the control's. ``--set FIELD=VALUE[,...]`` changes the configuration of
both runs (as bench.fidelity's ``--variant``). Prints the rows and the totals per mass and writes a
record (bench/harness.py); asserts nothing.

Shapes (the first four are the default set; ``--shapes all`` adds eleven more):
  domino   48 x 24 x 6.35 mm plate (thin faces: the case that sank at 1/240 s)
  cube40   40 mm cube (bench.peers' cube)
  rod      cylinder 12 mm across, 80 mm long
  disc     cylinder 60 mm across, 5 mm thick
  card     85 x 54 x 3 mm plate          slab10   80 x 60 x 10 mm plate
  box642   60 x 40 x 20 mm box           cube30, cube60   30 and 60 mm cubes
  can40    cylinder 40 mm across, 80 mm  rod20    cylinder 20 mm across, 100 mm
  sphere40 sphere 40 mm across           stick    100 x 15 x 8 mm bar
  mug, banana   the sample objects' meshes (objects/), at the masses of the grid

    python -m bench.experiments.light_threshold --shapes all --grams 24 32 40 80   # 15 shapes, ~12 min

``--variant NAME:FIELD=VALUE[,...]`` (repeatable) also labels with those changes, against the same
fine reference, which is simulated once per shape, mass and seed. ``--own-step`` labels at the
annotator's own steps instead of 1/240 s: a light object's close at
its finer step (``annotator.objects.physics_for``), its lift and shake as ``PhysicsConfig.held``
says (at 1/240 s with ``light_hold_contact_erp`` from ``light_hold_mass`` up); the fine reference
stays at its step throughout. ``--variant "before:physics.light_hold_mass=0.04"`` is the finer step
throughout, the model before decision 0025:

    python -m bench.experiments.light_threshold --own-step --grams 14 20 24 28 32 38 \\
        --shapes domino cube40 rod disc card box642 can40 stick --variant "before:light_hold_mass=0.04"
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import AnnotatorConfig
from annotator.outcome import Outcome
from annotator.pipeline.in_memory import ExecutionOptions, call_values
from annotator.pipeline.tasks import Call
from bench._variants import parse_variant
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, number, seed
from bench.experiments.light_objects import simulated_trials
from bench.harness import Run

OBJECTS = Path(__file__).resolve().parents[2] / "objects"
box, cylinder = trimesh.creation.box, trimesh.creation.cylinder
SHAPES = {
    "domino": lambda: box((0.048, 0.024, 0.00635)),
    "cube40": lambda: box((0.04, 0.04, 0.04)),
    "rod": lambda: cylinder(radius=0.006, height=0.08, sections=32),
    "disc": lambda: cylinder(radius=0.03, height=0.005, sections=48),
    "card": lambda: box((0.085, 0.054, 0.003)),
    "slab10": lambda: box((0.08, 0.06, 0.01)),
    "box642": lambda: box((0.06, 0.04, 0.02)),
    "cube30": lambda: box((0.03, 0.03, 0.03)),
    "cube60": lambda: box((0.06, 0.06, 0.06)),
    "can40": lambda: cylinder(radius=0.02, height=0.08, sections=40),
    "sphere40": lambda: trimesh.creation.icosphere(subdivisions=3, radius=0.02),
    "rod20": lambda: cylinder(radius=0.01, height=0.1, sections=32),
    "stick": lambda: box((0.1, 0.015, 0.008)),
    "mug": lambda: trimesh.load(OBJECTS / "mug.obj", force="mesh"),
    "banana": lambda: trimesh.load(OBJECTS / "banana.obj", force="mesh"),
}
DEFAULT_SHAPES = ("domino", "cube40", "rod", "disc")
WIDTH_TOLERANCE = 0.0002  # m: a width beyond this from the fine step's counts as moved (as bench.fidelity)
WIDTHS = (8, 5, 4, 4, 6, 7, 6, 7)  # printed column widths


def run_at(
    shape: str,
    grams: float,
    seed: int,
    n: int,
    substeps: int,
    folder: Path,
    config: AnnotatorConfig,
    own_step: bool = False,
):
    """(successes (K,) bool, widths (K,) float m) of the simulated candidates at time_step / substeps
    throughout, or at the annotator's own steps (``own_step``, substeps 1)."""
    physics = dataclasses.replace(config.physics, time_step=config.physics.time_step / substeps)
    config = dataclasses.replace(config, physics=physics)  # as given: no light-object substeps
    success, widths = [], []
    for r in simulated_trials(SHAPES[shape](), shape, grams, seed, n, config, folder, own_step=own_step):
        success.append(r.outcome == Outcome.SUCCESS)
        widths.append(r.width)
    return np.array(success, bool), np.array(widths, float)


def row(args: tuple) -> list[tuple[str, str, float, int, int, int, int, int, int]]:
    """One (shape, mass, seed): the fine reference once, then each labelled configuration
    (``(name, spec)``: "default" is ``--set``, a variant is ``--set`` and its own changes) against
    it; per configuration ``(name, shape, grams, seed, simulated, successes, successes fine, agree,
    widths beyond the tolerance)``."""
    shape, grams, seed, n, fine, changes, own_step, labelled = args
    config = parse_variant(changes)[1]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        sf, wf = run_at(shape, grams, seed, n, fine, Path(tmp), config)
        for name, spec in labelled:
            variant = parse_variant(spec, base=config)[1] if spec else config
            s1, w1 = run_at(shape, grams, seed, n, 1, Path(tmp), variant, own_step)
            both = s1 & sf
            wide = int(np.sum(np.abs(w1[both] - wf[both]) > WIDTH_TOLERANCE))
            out.append(
                (name, shape, grams, seed, len(s1), int(s1.sum()), int(sf.sum()), int(np.sum(s1 == sf)), wide)
            )
    return out


def measure_grid(grid: list[tuple], config: AnnotatorConfig, workers: int) -> list[list[tuple]]:
    """:func:`row` of every (shape, mass, seed) of ``grid``, in its order, through the runner's
    execution on ``workers`` processes (:func:`annotator.pipeline.in_memory.run_in_memory`: a dead
    worker's task retried alone, the version check); what a task raised is raised here."""
    tasks = [Call(fn=row, args=(cell,), config=config) for cell in grid]
    names = [f"{shape} {grams:g} g seed {seed}" for shape, grams, seed, *_ in grid]
    return call_values(tasks, ExecutionOptions(workers=workers), names=names)


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=list(DEFAULT_SHAPES), choices=[*SHAPES, "all"])
    ap.add_argument(
        "--grams",
        type=number(0.0, 100_000.0, low_open=True),
        nargs="+",
        default=[12.0, 16.0, 20.0, 24.0, 28.0, 32.0, 40.0, 80.0],
    )
    ap.add_argument("--seeds", type=seed, nargs="+", default=[0, 1])
    ap.add_argument(
        "--candidates",
        type=count(1, N_MAX),
        default=60,
        help="sampled per (shape, seed); colliding ones skipped",
    )
    ap.add_argument("--fine", type=count(1, 1000), default=4, help="substeps of the fine reference step")
    ap.add_argument("--jobs", type=count(1, WORKERS_MAX), default=2)
    ap.add_argument("--set", default="", help="FIELD=VALUE[,FIELD=VALUE] for both runs")
    ap.add_argument(
        "--own-step", action="store_true", help="label at the annotator's own steps, not 1/240 s throughout"
    )
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help="NAME:FIELD=VALUE[,...]: also label with these changes on top of --set, against the same "
        "fine reference (repeatable)",
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    config = parse_variant(args.set)[1]  # an unknown field exits here, not in a worker
    labelled = [("default", "")] + [(parse_variant(v, base=config)[0], v) for v in args.variant]
    if "all" in args.shapes:
        args.shapes = list(SHAPES)
    grid = [
        (s, g, seed, args.candidates, args.fine, args.set, args.own_step, labelled)
        for s in args.shapes
        for g in args.grams
        for seed in args.seeds
    ]
    totals: dict[tuple[str, float], np.ndarray] = {}
    steps = "the annotator's own steps" if args.own_step else "1/240 s"
    print(f"{steps} against 1/{240 * args.fine} s, default gripper and protocol {args.set}", flush=True)
    header = ("shape", "g", "seed", "sim", "ok@240", "ok@fine", "agree", "w>0.2mm")
    print(
        "variant  "
        + " ".join(
            f"{h:8s}" if k == 0 else f"{h:>{w}s}" for k, (h, w) in enumerate(zip(header, WIDTHS, strict=True))
        )
    )
    with Run("light_threshold", config=vars(args), annotator=config) as run:
        rows = []
        for results in measure_grid(grid, config, args.jobs):
            for name, shape, grams, seed, sim, ok1, okf, agree, wide in results:
                print(
                    f"{name:8s} {shape:8s} {grams:5.1f} {seed:4d} {sim:4d} {ok1:6d} {okf:7d} {agree:6d} "
                    f"{wide:7d}",
                    flush=True,
                )
                totals.setdefault((name, grams), np.zeros(5, int))
                totals[name, grams] += (sim, ok1, okf, agree, wide)
                rows.append(
                    {
                        "variant": name,
                        "shape": shape,
                        "grams": grams,
                        "seed": seed,
                        "simulated": sim,
                        "success_240": ok1,
                        "success_fine": okf,
                        "agree": agree,
                        "widths_over_0p2mm": wide,
                    }
                )
        print("\nper mass, all shapes and seeds:")
        per_mass = []
        for name, _ in labelled:
            for grams in sorted(g for n, g in totals if n == name):
                sim, ok1, okf, agree, wide = (int(v) for v in totals[name, grams])
                print(
                    f"{name}: {grams:5.1f} g: {agree} of {sim} agree ({100.0 * agree / max(sim, 1):.1f} %), "
                    f"successes {ok1} at {steps} vs {okf} fine, {wide} widths beyond 0.2 mm"
                )
                per_mass.append(
                    {
                        "variant": name,
                        "grams": grams,
                        "simulated": sim,
                        "agree": agree,
                        "agree_pct": 100.0 * agree / max(sim, 1),
                        "success_240": ok1,
                        "success_fine": okf,
                        "widths_over_0p2mm": wide,
                    }
                )
        run.table(
            "per_mass",
            per_mass,
            note=f"all shapes and seeds; {steps} (success_240) against 1/{240 * args.fine} s",
        )
        run.table("rows", rows, note="per variant, shape, mass and seed")


if __name__ == "__main__":
    # main of the module imported by name: the function its tasks name is pickled by reference
    from bench.experiments.light_threshold import main as importable_main

    importable_main()
