"""Do the widths of successful grasps match the mesh? Per object, label N candidates as `annotate`
does and compare each success's width with the opening the mesh implies for the RG2's flat pads.

    python -m bench.experiments.widths                                 # bowl, mug and banana of objects/
    python -m bench.experiments.widths --objects DIR --only mug --n 400
    python -m bench.experiments.widths --coarse          # CoACD once at 0.05, as before the threshold ladder

Three columns per object, in mm, over its successes (mean and max of |difference| or signed range):

- ``width - pads on mesh``: width against :func:`annotator.sampler.pad_opening` on the mesh (two
  29.8 x 20.2 mm pads closing along the TCP's x axis): the error the label carries (target
  <= 2 mm, DecompositionConfig.collision_max_limit);
- ``width - pads on parts``: the same against the collision parts PyBullet simulates: the pads'
  depth in the simulated shape under the 40 N squeeze;
- ``width - chord``: against the chord of the mesh along the closing axis through the TCP (as
  tests/test_protocol.py measures convex boxes and cans): on concave walls a flat pad rests on its
  edges, so this is geometry, not error.

The table goes into a record (bench/harness.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.dataset import poses_as_matrices
from annotator.objects import discover_objects, load_object
from annotator.pipeline.in_memory import ExecutionOptions, run_in_memory
from annotator.pipeline.tasks import Span, SpanTask
from annotator.sampler import _first_hits, pad_opening
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, existing_folder, seed
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[2]


def chord(triangles: np.ndarray, T: np.ndarray, reach: float) -> float:
    """Mesh chord along the TCP's x axis through the TCP, from +-``reach`` inwards."""
    x, p = T[:3, 0], T[:3, 3]
    t, _ = _first_hits(triangles, np.array([p - reach * x, p + reach * x]), np.array([x, -x]))
    return float(2 * reach - t.sum())


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--only", nargs="*", default=["bowl", "mug", "banana"], help="object ids (none: all)")
    ap.add_argument("--n", type=count(1, N_MAX), default=200, help="candidates per object")
    ap.add_argument("--seed", type=seed, default=0)
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=os.cpu_count() or 1)
    ap.add_argument("--coarse", action="store_true", help="CoACD once at threshold 0.05")
    return ap


def main() -> None:
    args = parser().parse_args()
    config = AnnotatorConfig()
    if args.coarse:
        ladder = dataclasses.replace(config.objects.decomposition, min_threshold=0.05)
        objects = dataclasses.replace(config.objects, decomposition=ladder)
        config = dataclasses.replace(config, objects=objects)
    with World(config.physics) as world:
        pad_face = FloatingGripper(world, config.gripper).gripper.pad_face
    sources = [
        s for s in discover_objects(args.objects, config.objects) if not args.only or s.object_id in args.only
    ]
    print(f"pads {pad_face[0] * 1e3:.1f} x {pad_face[1] * 1e3:.1f} mm; {args.n} candidates per object")
    head = (
        f"{'object':<20} {'parts':>5} {'succ':>5}  {'width - pads on mesh':>21}  "
        f"{'width - pads on parts':>21}  {'width - chord':>15}  over 2 mm"
    )
    print(
        head + "\n" + " " * 34 + "mean|d| max|d|        min    max            min    max\n" + "-" * len(head)
    )
    with Run("widths", config=vars(args), annotator=config) as run:
        rows = [measure(source, args, config, pad_face) for source in sources]
        run.table(
            "objects",
            rows,
            note="over each object's successes, mm: width - pads on the mesh (|d|), "
            "- pads on the parts, - chord",
        )


def measure(source, args: argparse.Namespace, config: AnnotatorConfig, pad_face) -> dict:
    """Label ``source``'s candidates, print its line; its table row."""
    model = load_object(source, config.objects)
    tasks = [
        SpanTask(
            span=Span(source.object_id, source, None, a, min(args.n, a + 25)),
            config=config,
            seed=args.seed,
            n=args.n,
        )
        for a in range(0, args.n, 25)
    ]
    t0 = time.perf_counter()
    rows = pd.concat([r.rows for r in run_in_memory(tasks, ExecutionOptions(args.workers))])
    wins = rows[rows["success"]]
    mesh_tri = np.asarray(model.mesh.triangles)
    part_tri = np.concatenate([np.asarray(p.triangles) for p in model.parts])
    d_mesh, d_parts, d_chord = [], [], []
    for T, r in zip(poses_as_matrices(wins), wins.itertuples(), strict=True):
        d_mesh.append(r.width - pad_opening(mesh_tri, T, r.width, pad_face))
        d_parts.append(r.width - pad_opening(part_tri, T, r.width, pad_face))
        d_chord.append(r.width - chord(mesh_tri, T, r.width / 2 + 0.01))
    if not d_mesh:
        print(f"{source.object_id:<20} {len(model.parts):>5} {0:>5}  no successes")
        return {"object": source.object_id, "parts": len(model.parts), "successes": 0}
    dm, dp, dc = (np.array(d) * 1e3 for d in (d_mesh, d_parts, d_chord))
    print(
        f"{source.object_id:<20} {len(model.parts):>5} {len(dm):>5}"
        f"  {np.abs(dm).mean():7.2f} {np.abs(dm).max():6.2f}  {dp.min():9.2f} {dp.max():6.2f}"
        f"  {dc.min():9.2f} {dc.max():6.2f}  {int((np.abs(dm) > 2).sum()):>5}"
        f"   ({time.perf_counter() - t0:.0f} s)"
    )
    return {
        "object": source.object_id,
        "parts": len(model.parts),
        "successes": len(dm),
        "mesh_mean_abs": float(np.abs(dm).mean()),
        "mesh_max_abs": float(np.abs(dm).max()),
        "parts_min": float(dp.min()),
        "parts_max": float(dp.max()),
        "chord_min": float(dc.min()),
        "chord_max": float(dc.max()),
        "over_2mm": int((np.abs(dm) > 2).sum()),
        "seconds": time.perf_counter() - t0,
    }


if __name__ == "__main__":
    main()
