"""A learner's predictions file as a policy: rows per round, read once, executed best first.

The file is a CSV or Parquet table with PREDICTION_COLUMNS: ``round`` (int, the round = scene id),
the TCP pose in the table frame ``x y z`` (m) ``qx qy qz qw`` (xyzw), the ``width`` (m) the gripper
closes from, and ``score`` (higher first). Each attempt executes the best-scored prediction of the
round not tried yet that the arm can reach (predictions for the scene as built; objects moved or
taken since are simply where they are now). A policy that sees the pile change is a callable
(:mod:`annotator.policies.vision`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from annotator.geometry import Transform
from annotator.policies.oracle import RoundPolicy
from annotator.policies.records import Proposal
from annotator.scenes.records import Workspace

if TYPE_CHECKING:
    from annotator.policies.round_world import Round

PREDICTION_COLUMNS = ("round", "x", "y", "z", "qx", "qy", "qz", "qw", "width", "score")
# How far (m) a TCP may lie outside the workspace's box: a grasp on an object at the box's edge
# has its TCP inside it, and the arm's approach starts 10 cm behind (ProtocolConfig's
# approach_distance); farther than that no grasp of the pile's objects can be meant.
WORKSPACE_MARGIN = 0.1


def read_predictions(path: Path) -> pd.DataFrame:
    """A learner's predictions (module docstring). ValueError naming what is wrong."""
    path = Path(path)
    try:
        df = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read predictions ({exc})") from None
    if path.suffix != ".parquet":  # pandas renames a repeated CSV header "x" to "x.1"
        import csv

        with path.open(newline="") as f:
            header = next(csv.reader(f), [])
        repeated = sorted({c for c in header if header.count(c) > 1})
        if repeated:
            raise ValueError(f"{path}: column(s) {repeated} appear more than once")
    missing = [c for c in PREDICTION_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; predictions need {list(PREDICTION_COLUMNS)}")
    values = df[list(PREDICTION_COLUMNS)].to_numpy(dtype=np.float64)
    if not np.isfinite(values).all():
        raise ValueError(f"{path}: every prediction needs finite {list(PREDICTION_COLUMNS)}")
    if (np.abs(np.linalg.norm(values[:, 4:8], axis=1) - 1.0) > 1e-6).any():
        raise ValueError(f"{path}: quaternions qx..qw must be unit (xyzw)")
    return df.reset_index(drop=True)


def check_predictions(
    df: pd.DataFrame, rounds: int, workspace: Workspace, max_width: float, name: str = "predictions"
) -> list[int]:
    """Refuse predictions that cannot mean the piles of this run: ValueError (one line) when no
    row is for any of the rounds 0..rounds-1, when a width lies outside the gripper's stroke
    0..``max_width`` (m), or a TCP more than WORKSPACE_MARGIN outside the workspace's box. Returns
    the rounds that have no row (they end at once: 'no grasp proposed')."""
    round_ids = df["round"].to_numpy()
    if not np.array_equal(round_ids, np.round(round_ids)):
        raise ValueError(f"{name}: round must be a whole number")
    used = set(int(r) for r in round_ids) & set(range(rounds))
    if not used:
        shown = sorted(set(int(r) for r in round_ids))[:5]
        raise ValueError(
            f"{name}: no row for any of the rounds 0-{rounds - 1} (its rounds: {shown}"
            f"{', ...' if len(set(round_ids)) > 5 else ''})"
        )
    width = df["width"].to_numpy(dtype=np.float64)
    bad = np.flatnonzero((width < 0) | (width > max_width))
    if len(bad):
        k = int(bad[0])
        raise ValueError(
            f"{name}: row {k} has width {width[k]:.4g} m, outside the gripper's stroke 0-{max_width:.4g} m"
            f" ({len(bad)} such rows)"
        )
    p = df[["x", "y", "z"]].to_numpy(dtype=np.float64)
    out = np.flatnonzero(
        ((p < workspace.lower - WORKSPACE_MARGIN) | (p > workspace.upper + WORKSPACE_MARGIN)).any(axis=1)
    )
    if len(out):
        k = int(out[0])
        raise ValueError(
            f"{name}: row {k} has its TCP at {np.round(p[k], 3).tolist()} m, more than "
            f"{WORKSPACE_MARGIN} m outside the workspace (table frame) ({len(out)} such rows)"
        )
    return sorted(set(range(rounds)) - used)


def file_policy(predictions: pd.DataFrame) -> RoundPolicy:
    """The best-scored untried prediction of the round that the arm can reach (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        rows = predictions[predictions["round"] == round_.record.scene_id]
        order = np.lexsort((rows.index.to_numpy(), -rows["score"].to_numpy(dtype=np.float64)))
        for k in order:
            index = int(rows.index[k])
            if index in tried:
                continue
            tried.add(index)
            row = rows.loc[index]
            T = Transform(row[["x", "y", "z"]].to_numpy(float), row[["qx", "qy", "qz", "qw"]].to_numpy(float))
            reach = round_.reach(T, float(row["width"]), -1)
            if reach.reachable:
                return Proposal(-1, T, float(row["width"]), float(row["score"]), reach)
        return None

    return propose
