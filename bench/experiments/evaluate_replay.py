"""Labels replayed through ``annotator evaluate``: how many rows come back bit for bit.

    python -m bench.experiments.evaluate_replay               # --n 60 per object
    python -m bench.experiments.evaluate_replay --n 20        # a quick look

Runs the real commands as subprocesses: ``annotate`` into a temporary folder, then ``annotator
evaluate`` on the label table (replaying each row's commanded grasp, ``cmd_*``), and, for
comparison, on the same table without the ``cmd_*`` columns (replaying the end-of-close pose and
width instead). Prints rows identical, outcomes equal and the wall time of each evaluation, and
writes a record (bench/harness.py) with each evaluation's time as a ratio to the labelling's.
(Replaying labels on the UR3 arm instead is ``bench.experiments.arm_agreement``.)
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
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[2]


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


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=count(1, N_MAX), default=60)
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=os.cpu_count() or 1)
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("evaluate_replay", config=vars(args)) as run_, tempfile.TemporaryDirectory() as tmp:
        measure(args, Path(tmp), run_)


def measure(args: argparse.Namespace, tmp: Path, record: Run) -> None:
    bin_dir = Path(sys.executable).parent
    common = ["--objects", str(ROOT / "objects"), "--workers", str(args.workers), "--quiet"]
    labelling = run(str(bin_dir / "annotate"), *common, "--n", str(args.n), "--out", str(tmp / "labels"))
    labels = load_labels(tmp / "labels")
    print(f"annotate: {len(labels)} labels of {labels.object_id.nunique()} objects in {labelling:.1f} s")
    record.figure("labels", len(labels), note=f"{labels.object_id.nunique()} objects")
    record.figure("annotate_s", labelling, "s", note="annotate, wall")
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
        what = name.replace("_", " ")
        print(
            f"evaluate ({what}): {rows.sum()}/{len(rows)} rows identical, "
            f"{outcome.sum()}/{len(outcome)} outcomes equal, {seconds:.1f} s"
        )
        for _, r in labels[~outcome].iterrows():
            got = again.loc[(again.object_id == r.object_id) & (again.grasp_id == r.grasp_id), "outcome"]
            print(f"    {r.object_id} grasp {r.grasp_id}: {r.outcome} -> {got.iloc[0]}")
        record.ratio(
            f"evaluate_{name}_vs_annotate", seconds / labelling, note=f"wall, evaluate ({what}) / annotate"
        )
        record.figure(f"identical_rows_{name}", int(rows.sum()), note=f"of {len(rows)}, evaluate ({what})")
        record.figure(
            f"equal_outcomes_{name}", int(outcome.sum()), note=f"of {len(outcome)}, evaluate ({what})"
        )
        record.figure(f"evaluate_{name}_s", seconds, "s", note=f"evaluate ({what}), wall")


if __name__ == "__main__":
    main()
