"""Label the sample objects, evaluate the labels again, print how exactly they are reproduced.

    python bench/replay.py               # --n 60 per object, the README's figures
    python bench/replay.py --n 20        # a quick look

Runs the real commands as subprocesses: ``annotate`` into a temporary folder, then ``annotator
evaluate`` on the label table (replaying each row's commanded grasp, ``cmd_*``), and, for
comparison, on the same table without the ``cmd_*`` columns (replaying the end-of-close pose and
width instead). Prints rows identical, outcomes equal and the wall time of each evaluation.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import load_labels
from annotator.tools.given import CMD_COLUMNS

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run(args, check=False, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def identical(a: pd.DataFrame, b: pd.DataFrame) -> np.ndarray:
    """(n,) bool: row i of ``a`` equals row i of ``b`` in every column of ``a``, bit for bit."""
    same = np.ones(len(a), dtype=bool)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        same &= (x == y) | (pd.isna(x) & pd.isna(y)) if x.dtype.kind == "f" else (x == y)
    return same


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=60)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    bin_dir = Path(sys.executable).parent
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        common = ["--objects", str(ROOT / "objects"), "--workers", str(args.workers), "--quiet"]
        seconds = run(str(bin_dir / "annotate"), *common, "--n", str(args.n), "--out", str(tmp / "labels"))
        labels = load_labels(tmp / "labels")
        print(f"annotate: {len(labels)} labels of {labels.object_id.nunique()} objects in {seconds:.1f} s")
        labels.to_parquet(tmp / "with_cmd.parquet")
        labels.drop(columns=list(CMD_COLUMNS)).to_parquet(tmp / "without_cmd.parquet")
        for name in ("with_cmd", "without_cmd"):
            out = tmp / f"eval_{name}"
            seconds = run(
                str(bin_dir / "annotator"),
                "evaluate",
                str(tmp / f"{name}.parquet"),
                *common,
                "--out",
                str(out),
            )
            again = load_labels(out)
            columns = [c for c in labels.columns if c in again.columns and c not in CMD_COLUMNS]
            rows = identical(labels[columns], again[columns])
            outcome = labels.outcome.to_numpy() == again.outcome.to_numpy()
            print(
                f"evaluate ({name.replace('_', ' ')}): {rows.sum()}/{len(rows)} rows identical, "
                f"{outcome.sum()}/{len(outcome)} outcomes equal, {seconds:.1f} s"
            )
            for _, r in labels[~outcome].iterrows():
                got = again.loc[(again.object_id == r.object_id) & (again.grasp_id == r.grasp_id), "outcome"]
                print(f"    {r.object_id} grasp {r.grasp_id}: {r.outcome} -> {got.iloc[0]}")


if __name__ == "__main__":
    main()
