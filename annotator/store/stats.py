"""Per-object figures for the run's summary, from an object's label table."""

from __future__ import annotations

from typing import Any

import pandas as pd


def object_stats(df: pd.DataFrame) -> dict[str, Any]:
    """Per-object figures for the summary: rows, successes, mean score, outcome counts (and, for
    cell labels, the successes the arm can execute)."""
    stats: dict[str, Any] = {
        "n": int(len(df)),
        "successes": int(df["success"].sum()),
        "mean_score": float(df["score"].mean()) if len(df) else 0.0,
        "outcomes": {str(k): int(v) for k, v in df["outcome"].value_counts().items()},
    }
    if "reachable" in df.columns:
        stats["reachable_successes"] = int((df["success"] & df["reachable"]).sum())
    return stats
