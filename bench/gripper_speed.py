"""Candidates per CPU-second of each shipped gripper on the sample objects, as ratios to the RG2.

    python -m bench.gripper_speed [--n 100] [--rounds 2] [--objects objects/]

Labels every sample object's first N candidates (sampled for each gripper's own stroke) through the
worker's entry point (``label_span``, one process, the default configuration), gripper after
gripper, in ``--rounds`` rounds; a round's ratios compare runs made minutes apart on the same
machine. Per gripper and round: candidates per CPU-second of the spans (loading, sampling and
simulating, as ``annotate`` counts them), the share simulated (not ``collision``), simulated trials
per CPU-second, and the ratio of candidates per second to the RG2's in that round.
"""

from __future__ import annotations

import time
from pathlib import Path

from annotator.config import AnnotatorConfig
from annotator.grippers import load_gripper
from annotator.objects import discover_objects
from annotator.pipeline.tasks import Span, SpanTask
from annotator.pipeline.worker import label_span
from bench.arguments import N_MAX, REPEAT_MAX, Parser, count, existing_folder
from bench.harness import Run

GRIPPERS = ("rg2", "panda", "robotiq_2f85")


def label_all(sources, gripper, n: int, config: AnnotatorConfig) -> tuple[float, int, int]:
    """(CPU seconds, candidates, simulated trials) of labelling every object's first ``n`` candidates."""
    description = load_gripper(gripper)
    cpu0 = time.process_time()
    rows = simulated = 0
    for source in sources:
        span = Span(source.object_id, source, None, 0, n)
        result = label_span(SpanTask(span=span, config=config, seed=0, n=n, gripper=description))
        if result.error is not None:
            raise RuntimeError(f"{source.object_id}: {result.error}")
        rows += len(result.rows)
        simulated += int((result.rows["outcome"] != "collision").sum())
    return time.process_time() - cpu0, rows, simulated


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=count(1, N_MAX), default=100, help="candidates per object")
    ap.add_argument("--rounds", type=count(1, REPEAT_MAX), default=2)
    ap.add_argument(
        "--objects", type=existing_folder, default=Path(__file__).resolve().parents[1] / "objects"
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    sources = discover_objects(args.objects)
    config = AnnotatorConfig()
    label_all(sources, "rg2", 2, config)  # objects decomposed (cached) before any timing
    print(f"{len(sources)} objects x {args.n} candidates, one process")
    print(
        f"{'round':>5} {'gripper':>13} {'cand/CPU-s':>10} {'simulated':>9} {'trials/CPU-s':>12} {'vs rg2':>7}"
    )
    with Run("gripper_speed", config=vars(args), annotator=config) as record:
        table, ratios = [], {g: [] for g in GRIPPERS}
        for r in range(args.rounds):
            rates = {}
            for gripper in GRIPPERS:
                seconds, rows, simulated = label_all(sources, gripper, args.n, config)
                rates[gripper] = rows / seconds
                ratios[gripper].append(rates[gripper] / rates["rg2"])
                table.append(
                    {
                        "round": r,
                        "gripper": gripper,
                        "candidates_per_cpu_s": rows / seconds,
                        "simulated_share": simulated / rows,
                        "trials_per_cpu_s": simulated / seconds,
                        "vs_rg2": rates[gripper] / rates["rg2"],
                    }
                )
                print(
                    f"{r:>5} {gripper:>13} {rows / seconds:>10.1f} {simulated / rows:>9.1%} "
                    f"{simulated / seconds:>12.1f} {rates[gripper] / rates['rg2']:>7.2f}",
                    flush=True,
                )
        for gripper in GRIPPERS[1:]:
            values = sorted(ratios[gripper])
            record.ratio(
                f"{gripper}_vs_rg2_candidates_per_cpu_s",
                values[len(values) // 2],
                spread=(values[0], values[-1]),
                note="same objects, candidates and process, rounds alternating; target >= 0.5",
            )
        record.table("rounds", table)


if __name__ == "__main__":
    main()
