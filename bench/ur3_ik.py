"""Measure the UR3's closed-form IK: speed (one pose, a batch), round-trip error, solutions per pose.
Prints figures; never a test.

    python bench/ur3_ik.py
"""

from __future__ import annotations

import time

import numpy as np

from annotator.sim import ur3


def main(n: int = 20000) -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(ur3.JOINT_LIMITS[:, 0], ur3.JOINT_LIMITS[:, 1], size=(n, 6))
    T = ur3.dh_forward_kinematics_batch(q)
    t0 = time.perf_counter()
    branches = ur3.ik_branches(T)
    batch = time.perf_counter() - t0
    found = branches.stage == 0
    err = ur3.pose_error(
        ur3.dh_forward_kinematics_batch(branches.q[found]), np.repeat(T[:, None], 8, 1)[found]
    )
    gap = np.abs(np.mod(branches.q - q[:, None] + np.pi, 2 * np.pi) - np.pi).max(axis=2)
    gap = np.where(found, gap, np.inf).min(axis=1)
    m = 1000
    t0 = time.perf_counter()
    counts = [len(ur3.solve_ik(T[k]).solutions) for k in range(m)]
    single = (time.perf_counter() - t0) / m
    print(f"ik_branches on {n} random configurations: {batch * 1e6 / n:.1f} us per pose (batched)")
    print(f"solve_ik one pose at a time: {single * 1e3:.2f} ms per pose")
    print(
        f"round trip: max pose error {err.max():.1e} (m / rotation entry); "
        f"generating q found within {gap.max():.1e} rad"
    )
    print(
        f"solutions per pose (first {m}): "
        + ", ".join(f"{k}: {c}" for k, c in enumerate(np.bincount(counts)) if c)
    )


if __name__ == "__main__":
    main()
