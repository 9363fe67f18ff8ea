"""How fast this machine cuts meshes: the reference cut that scales the decomposition budget.

    python -m bench.machine_speed                  # 5 cuts, the factor the ladder would use
    python -m bench.machine_speed --cuts 10

``annotator.objects.machine_speed`` times a fixed CoACD cut (a generated 16-sided ring) in a child
process with one OpenMP thread and divides by ``REFERENCE_CUT_SECONDS``, the cut's CPU time on the
machine the ladder's limits were measured on: with ``[objects.decomposition] budget_basis = "reference"`` the
ladder's budget and V-HACD's reserve are multiplied by that factor. This bench times the cut
``--cuts`` times in this process (one OpenMP thread), reports the fastest, the median and the
spread, the factor the product measures in its own child, and the free step of the annotation
gripper (bench/reference.py) for comparison with other records of the same day. The record
(bench/harness.py) holds them.
"""

from __future__ import annotations

import argparse
import os
import statistics

os.environ.setdefault("OMP_NUM_THREADS", "1")  # as the decomposition children run

from annotator.objects import machine_speed  # noqa: E402
from bench.arguments import REPEAT_MAX, Parser, count
from bench.harness import Run  # noqa: E402
from bench.reference import free_step  # noqa: E402


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--cuts", type=count(1, REPEAT_MAX), default=5, help="reference cuts timed in this process"
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("machine_speed", config=vars(args)) as run:
        seconds = machine_speed.reference_cut_seconds(args.cuts)
        factor = machine_speed.speed_factor()
        step = free_step()
        fastest, median = min(seconds), statistics.median(seconds)
        print(f"reference cut: fastest {fastest:.3f} CPU-s, median {median:.3f}, slowest {max(seconds):.3f}")
        print(f"reference machine: {machine_speed.REFERENCE_CUT_SECONDS:.3f} CPU-s; factor {factor:.3f}")
        print(f"free step of the annotation gripper: {step.cpu_ms:.4f} CPU-ms")
        run.figure("reference_cut_s", fastest, unit="s", note=f"fastest of {args.cuts} cuts, in this process")
        run.figure("reference_cut_median_s", median, unit="s", note=f"median of {args.cuts} cuts")
        run.figure(
            "budget_factor",
            factor,
            note="speed_factor(): the product's own measurement, in its child, over REFERENCE_CUT_SECONDS",
        )
        run.figure("free_step_cpu_ms", step.cpu_ms, unit="ms", note="bench/reference.py, for other records")
        run.table(
            "cuts", [{"cut": i + 1, "cpu_s": s} for i, s in enumerate(seconds)], note="CPU-s of each cut"
        )


if __name__ == "__main__":
    main()
