"""Floating verdicts against the UR3 arm: how often the arm's replay holds what the label says.

For each object, up to K labels that reached the physics (every outcome but ``collision``) are
replayed on the UR3 + RG2 in the cell (annotator.tools.replay places the object so that the grasp
comes most from above while reachable, annotator.cell.execute runs the arm); the floating
``success`` is compared with the replay's *held*. Unreachable labels are counted apart, with their reasons.

    python -m bench.experiments.arm_agreement                      # labels objects/ with --n 40 first
    python -m bench.experiments.arm_agreement --labels labels/ --objects objects/ --per-object 8

Prints figures and writes a record (bench/harness.py); never a test. (Replaying labels through
``annotator evaluate`` bit for bit is ``bench.experiments.evaluate_replay``.)
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import time
from pathlib import Path

from annotator.cell import build_cell
from annotator.cell.execute import execute_plan
from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels
from annotator.objects import create_body, discover_objects, load_object
from annotator.pipeline.run import RunOptions, run
from annotator.tools.replay import plan_replay, replay_world
from bench.arguments import N_MAX, Parser, count, existing_folder
from bench.harness import Run

REPO = Path(__file__).resolve().parents[2]


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--labels", type=existing_folder)
    ap.add_argument("--objects", type=existing_folder, default=REPO / "objects")
    ap.add_argument("--per-object", type=count(1, N_MAX), default=6)
    ap.add_argument(
        "--n", type=count(1, N_MAX), default=40, help="candidates per object when labelling first"
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    config = AnnotatorConfig()
    with Run("arm_agreement", config=vars(args), annotator=config) as record:
        measure(args, config, record)


def measure(args: argparse.Namespace, config: AnnotatorConfig, record: Run) -> None:
    labels_dir = args.labels
    if labels_dir is None:
        labels_dir = Path(tempfile.mkdtemp()) / "labels"
        run(RunOptions(objects_dir=args.objects, n=args.n, out_dir=labels_dir, workers=2, quiet=True), config)
    labels = load_labels(labels_dir)
    sources = {s.object_id: s for s in discover_objects(args.objects)}
    totals = collections.Counter()
    reasons = collections.Counter()
    per_object = []
    t0 = time.perf_counter()
    for object_id, rows in labels[labels.outcome != "collision"].groupby("object_id"):
        rows = rows.head(args.per_object)
        model = load_object(sources[object_id], config.objects, scale=float(rows.iloc[0]["object_scale"]))
        counts = collections.Counter()
        for _, row in rows.iterrows():
            with replay_world(model, config) as world:
                cell = build_cell(world, config.cell, gripper=config.gripper, kinect=False)
                obj = create_body(world.client, model)
                plan = plan_replay(cell, model, obj, row, config)
                if not plan.reach.reachable:
                    counts["unreachable"] += 1
                    reasons[plan.reach.reason] += 1
                    continue
                result = execute_plan(cell, obj, plan, config)
            held = result.held(config.protocol.lift_height, config.protocol.max_slip)
            counts[("agree" if held == bool(row["success"]) else "disagree")] += 1
            floating = "success" if row["success"] else "failure"
            counts[f"floating {floating} -> arm {'held' if held else 'not held'}"] += 1
        totals.update(counts)
        per_object.append({"object": object_id} | {str(k): v for k, v in sorted(counts.items())})
        print(f"{object_id:24s} " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    compared = totals["agree"] + totals["disagree"]
    print(
        f"\nreplayed {compared} reachable labels in {time.perf_counter() - t0:.0f} s: "
        f"agreement {100 * totals['agree'] / max(1, compared):.1f} % ({totals['agree']}/{compared})"
    )
    for key in sorted(k for k in totals if isinstance(k, str) and k.startswith("floating")):
        print(f"  {key}: {totals[key]}")
    print(f"unreachable in every placement tried: {totals['unreachable']} " + str(dict(reasons)))
    record.ratio(
        "agreement",
        totals["agree"] / max(1, compared),
        note="floating success == the arm held, over the reachable labels replayed",
    )
    record.figure("replayed", compared, note="reachable labels replayed on the arm")
    record.figure("unreachable", totals["unreachable"], note="labels no placement tried could reach")
    record.figure("seconds", time.perf_counter() - t0, "s", note="the replays, wall")
    for key in sorted(k for k in totals if isinstance(k, str) and k.startswith("floating")):
        record.figure(key.replace(" -> ", "_").replace(" ", "_"), totals[key], note=key)
    record.table(
        "objects", per_object, note=f"up to {args.per_object} labels per object that reached the physics"
    )
    record.table("unreachable_reasons", [{"reason": k, "labels": v} for k, v in sorted(reasons.items())])


if __name__ == "__main__":
    main()
