"""The UR3's closed-form IK: speed (one pose, a batch), round-trip error, solutions per pose.

    python -m bench.experiments.ur3_ik                 # 20,000 random configurations, 1,000 one at a time
    python -m bench.experiments.ur3_ik --n 2000 --single 200

Prints figures and writes a record (bench/harness.py); never a test. The speed comes first as the
ratio of one pose at a time to the batched solver, both timed in this run.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from annotator.sim import ur3
from bench.arguments import Parser, count, seed
from bench.harness import Run


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--n", type=count(1, 10_000_000), default=20000, help="random configurations solved in one batch"
    )
    ap.add_argument(
        "--single", type=count(0, 10_000_000), default=1000, help="of them solved one pose at a time"
    )
    ap.add_argument("--seed", type=seed, default=0)
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("ur3_ik", config=vars(args)) as run:
        rng = np.random.default_rng(args.seed)
        n, m = args.n, min(args.single, args.n)
        q = rng.uniform(ur3.JOINT_LIMITS[:, 0], ur3.JOINT_LIMITS[:, 1], size=(n, 6))
        T = ur3.dh_forward_kinematics_batch(q)
        t0 = time.perf_counter()
        branches = ur3.ik_branches(T)
        batch = (time.perf_counter() - t0) / n
        found = branches.stage == 0
        err = ur3.pose_error(
            ur3.dh_forward_kinematics_batch(branches.q[found]), np.repeat(T[:, None], 8, 1)[found]
        )
        gap = np.abs(np.mod(branches.q - q[:, None] + np.pi, 2 * np.pi) - np.pi).max(axis=2)
        gap = np.where(found, gap, np.inf).min(axis=1)
        t0 = time.perf_counter()
        counts = [len(ur3.solve_ik(T[k]).solutions) for k in range(m)]
        single = (time.perf_counter() - t0) / m
        print(f"ik_branches on {n} random configurations: {batch * 1e6:.1f} us per pose (batched)")
        print(f"solve_ik one pose at a time: {single * 1e3:.2f} ms per pose")
        print(
            f"round trip: max pose error {err.max():.1e} (m / rotation entry); "
            f"generating q found within {gap.max():.1e} rad"
        )
        histogram = np.bincount(counts)
        print(
            f"solutions per pose (first {m}): " + ", ".join(f"{k}: {c}" for k, c in enumerate(histogram) if c)
        )
        run.ratio(
            "single_vs_batched", single / batch, note="time per pose, solve_ik one at a time / ik_branches"
        )
        run.figure("batched_us_per_pose", batch * 1e6, "us", note=f"ik_branches on {n} poses")
        run.figure("single_ms_per_pose", single * 1e3, "ms", note=f"solve_ik, {m} poses one at a time")
        run.figure("max_pose_error", float(err.max()), "m", note="FK(IK(T)) - T, largest entry")
        run.figure("max_joint_gap", float(gap.max()), "rad", note="generating q to the nearest solution")
        run.table(
            "solutions_per_pose",
            [{"solutions": k, "poses": int(c)} for k, c in enumerate(histogram) if c],
            note=f"the first {m} poses",
        )


if __name__ == "__main__":
    main()
