"""Per object of any folder: how it loads (cleaning, mass model, load time) and the error of its
collision shape, the distance between the simulated shape and the mesh surface (mean and max, mm,
annotator/objects/fidelity.py).

    python -m bench.collision_error                          # the sample objects, before and after
    python -m bench.collision_error --objects DIR --no-before
    python -m bench.collision_error --objects DIR --only 'ycb/*' --cache /tmp/cache
    python -m bench.collision_error --objects DIR --no-before --first-cut-share 0.5
    python -m bench.collision_error --objects DIR --no-before --budget-basis cpu

Columns: faces as loaded (after cleaning and the face budget), what cleaning changed, the mass
model and mass, the collision method, parts and final CoACD threshold, the error mean and max
(mm) against the limits, and the load time (s; with an empty cache it is mostly the
decomposition: each run uses a fresh cache unless --cache is given).

"before" (with --before, the default for the sample objects): what the annotator simulated before
the collision-error refinement, CoACD once at threshold 0.05 with its default preprocessing
("auto"), or the hull of a convex object, measured on the same cleaned mesh. The table goes into a
record (bench/harness.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import ObjectConfig
from annotator.objects import ObjectError, discover_objects, load_object
from annotator.objects.collision_ladder import budget_factor
from annotator.objects.fidelity import collision_error
from bench.arguments import Parser, existing_folder, number, writable_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]


def before(model) -> list[trimesh.Trimesh]:
    """The old collision geometry: hull, or CoACD at 0.05 with preprocess "auto", seed 0."""
    if len(model.parts) == 1:
        return model.parts
    import coacd

    coacd.set_log_level("error")
    result = coacd.run_coacd(
        coacd.Mesh(np.asarray(model.mesh.vertices), np.asarray(model.mesh.faces)), threshold=0.05, seed=0
    )
    parts = [trimesh.Trimesh(v, f).convex_hull for v, f in result]
    return [p for p in parts if p.volume > 0]


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--only", nargs="*", default=[], help="object id globs")
    ap.add_argument(
        "--cache", type=writable_folder, default=None, help="decomposition cache (default: a fresh one)"
    )
    ap.add_argument("--before", action=argparse.BooleanOptionalAction, default=None)
    ap.add_argument("--scale", type=number(0.0, 1000.0, low_open=True), default=None)
    ap.add_argument(
        "--first-cut-share",
        type=number(0.0, 1.0, low_open=True),
        default=None,
        help="coacd_first_cut_share of the budget for CoACD on the mesh as it is (default: the config's)",
    )
    ap.add_argument(
        "--budget-basis",
        choices=("reference", "cpu"),
        default=None,
        help="budget_basis of the decomposition budget (default: the config's)",
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    with_before = args.before if args.before is not None else args.objects.resolve() == ROOT / "objects"
    config = ObjectConfig()
    if args.first_cut_share is not None:
        ladder = dataclasses.replace(config.decomposition, coacd_first_cut_share=args.first_cut_share)
        config = dataclasses.replace(config, decomposition=ladder)
    if args.budget_basis is not None:
        ladder = dataclasses.replace(config.decomposition, budget_basis=args.budget_basis)
        config = dataclasses.replace(config, decomposition=ladder)
    cache = args.cache or Path(tempfile.mkdtemp(prefix="rg2-bench-cache-"))
    print(
        f"limits: mean <= {config.decomposition.collision_mean_limit * 1e3:g} mm, "
        f"max <= {config.decomposition.collision_max_limit * 1e3:g} mm; cache {cache}"
    )
    head = (
        f"{'object':<34} {'faces':>7} {'mass model':>10} {'g':>7} {'method':>14} {'parts':>5} {'thr':>5}"
        f" {'mean':>6} {'max':>6} {'within':>6} {'load s':>7}"
        + ("  before: parts mean max" if with_before else "")
    )
    print(head + "\n" + "-" * len(head))
    with Run("collision_error", config=vars(args)) as run:
        factor = budget_factor(config)  # measured before the loads, so no load's time holds it
        rows, within = measure(args, config, cache, with_before)
        run.figure(
            "budget_factor",
            factor,
            note=(
                f"CPU-s per budget second (budget_basis {config.decomposition.budget_basis!r}, "
                "objects.machine_speed)"
            ),
        )
        run.figure(
            "within_limits",
            within,
            note=f"objects whose collision shape is within the limits, of {len(rows)}",
        )
        run.table("objects", rows, note="error of the collision shape against the mesh (mm); load time (s)")
    print(f"\n{within} of {len(rows)} objects within the limits", file=sys.stderr)


def measure(
    args: argparse.Namespace, config: ObjectConfig, cache: Path, with_before: bool
) -> tuple[list, int]:
    """Load every selected object and print its line; (table rows, objects within the limits)."""
    rows: list[dict] = []
    sources = [
        s
        for s in discover_objects(args.objects, config)
        if not args.only or any(fnmatch.fnmatch(s.object_id, g) for g in args.only)
    ]
    within = 0
    for source in sources:
        t0 = time.perf_counter()
        try:
            model = load_object(source, config, scale=args.scale, cache_dir=cache)
        except ObjectError as exc:
            print(f"{source.object_id:<34} failed: {exc}", flush=True)
            rows.append({"object": source.object_id, "failed": str(exc)})
            continue
        seconds = time.perf_counter() - t0
        err = model.collision_error
        threshold = model.collision_threshold or None  # a CoACD rung's; 0 for every other method
        within += not model.approximate
        line = (
            f"{source.object_id:<34} {len(model.mesh.faces):>7} {model.mass_model:>10}"
            f" {model.mass * 1e3:7.1f} {model.collision_method:>14} {len(model.parts):>5}"
            f" {threshold or '-':>5}"
            f" {err.mean * 1e3:6.2f} {err.max * 1e3:6.2f}"
            f" {'yes' if not model.approximate else 'NO':>6} {seconds:7.1f}"
        )
        row = {
            "object": source.object_id,
            "faces": len(model.mesh.faces),
            "mass_model": model.mass_model,
            "grams": model.mass * 1e3,
            "method": model.collision_method,
            "parts": len(model.parts),
            "threshold": threshold,
            "mean_mm": err.mean * 1e3,
            "max_mm": err.max * 1e3,
            "within": not model.approximate,
            "load_s": seconds,
            "ladder": model.collision_ladder,
        }
        if with_before:
            old_parts = before(model)
            old = collision_error(model.mesh, old_parts, config.decomposition.collision_error_samples)
            line += f"  {len(old_parts):>5} {old.mean * 1e3:6.2f} {old.max * 1e3:6.2f}"
            row |= {
                "before_parts": len(old_parts),
                "before_mean_mm": old.mean * 1e3,
                "before_max_mm": old.max * 1e3,
            }
        rows.append(row)
        print(line, flush=True)
        if model.cleaning.summary() != "clean":
            print(f"{'':<34}   cleaning: {model.cleaning.summary()}", flush=True)
    return rows, within


if __name__ == "__main__":
    main()
