"""Simulating grasps someone else proposed (a network's predictions, hand-picked poses).

Input: a Parquet or CSV file with ``object_id``, the TCP pose as the labels give it (``x y z``,
``qx qy qz qw`` in the object's mesh frame, metres, xyzw) and optionally ``width`` (m, the opening
at the grasp: the chord between the pads) and ``grasp_id``. Output: the label columns for every
row, written by the job's own pipeline (spans of given poses instead of sampled candidates), with
the same resume, determinism and worker behaviour as ``annotate``.

A grasp is executed as a sampled candidate whose expected chord is ``width``: the RG2 is placed so
that its TCP at that opening is at the pose, opened ``2 x pregrasp_clearance`` wider, checked along
the approach and closed from ``width + 2 x preclose_gap``. Without a ``width`` column the chord is
measured on the mesh: the two pads, fully open, are moved towards the TCP along the closing axis
until they meet the surface (:func:`expected_width`); 0 when they meet nothing.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import POSE_COLUMNS

log = logging.getLogger(__name__)

# A quaternion this far from unit norm is renormalised silently (float32 predictions); further
# off is an error in the input, not noise.
QUAT_RENORMALISE_TOL = 1e-3


def read_grasps(path: str | Path) -> pd.DataFrame:
    """The proposed grasps, validated: ``object_id`` (str), pose columns (float64, unit xyzw),
    ``width`` (float64, NaN where not given) and ``grasp_id`` (int64, unique per object; the row
    number within its object when not given). Raises :class:`annotator.tools.common.ToolError`.
    """
    from annotator.tools.common import ToolError

    path = Path(path)
    if not path.exists():
        raise ToolError(f"no grasps file at {path}")
    try:
        df = pd.read_csv(path) if path.suffix.lower() == ".csv" else pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise ToolError(f"{path}: cannot read grasps ({exc}); give a Parquet or .csv file") from None
    missing = [c for c in ("object_id", *POSE_COLUMNS) if c not in df.columns]
    if missing:
        raise ToolError(
            f"{path}: missing column(s) {missing}; need object_id, {', '.join(POSE_COLUMNS)} [, width]"
        )
    if df.empty:
        raise ToolError(f"{path}: no grasps")
    out = pd.DataFrame({"object_id": df["object_id"].astype(str).to_numpy(dtype=object)})
    for c in POSE_COLUMNS:
        values = pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=np.float64)
        if not np.isfinite(values).all():
            row = int(np.argmin(np.isfinite(values)))
            raise ToolError(f"{path}: column {c} has missing or non-numeric values (row {row})")
        out[c] = values
    q = out[["qx", "qy", "qz", "qw"]].to_numpy()
    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > QUAT_RENORMALISE_TOL
    if bad.any():
        row = int(np.argmax(bad))
        raise ToolError(f"{path}: row {row}: quaternion (qx, qy, qz, qw) has norm {norm[row]:.4g}, not 1")
    q = q / norm[:, None]
    q[q[:, 3] < 0] *= -1.0  # w >= 0, as the labels
    out[["qx", "qy", "qz", "qw"]] = q
    if "width" in df.columns:
        width = pd.to_numeric(df["width"], errors="coerce").to_numpy(dtype=np.float64)
        if (width[np.isfinite(width)] < 0).any():
            raise ToolError(f"{path}: width must be >= 0 (metres)")
        out["width"] = width
    else:
        out["width"] = np.nan
    if "grasp_id" in df.columns:
        ids = pd.to_numeric(df["grasp_id"], errors="coerce")
        if ids.isna().any() or (ids < 0).any() or (ids != ids.round()).any():
            raise ToolError(f"{path}: grasp_id must be a non-negative integer")
        out["grasp_id"] = ids.astype(np.int64).to_numpy()
        if out.duplicated(["object_id", "grasp_id"]).any():
            first = out[out.duplicated(["object_id", "grasp_id"])].iloc[0]
            raise ToolError(f"{path}: grasp {int(first.grasp_id)} of {first.object_id!r} appears twice")
    else:
        out["grasp_id"] = out.groupby("object_id", sort=False).cumcount().astype(np.int64)
    return out


def expected_width(mesh, T_obj_tcp: np.ndarray, max_width: float) -> np.ndarray:
    """The chord each grasp closes on, (n,) m: the fully open pads (``max_width`` apart along the
    TCP's x axis) moved towards the TCP until each meets the mesh; 0 when one meets nothing before
    the TCP. ``mesh`` : trimesh.Trimesh in the object frame; ``T_obj_tcp`` : (n, 4, 4).
    """
    from annotator.sampler import _first_hits

    T = np.asarray(T_obj_tcp, dtype=np.float64).reshape(-1, 4, 4)
    x, p = T[:, :3, 0], T[:, :3, 3]
    half = max_width / 2
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    t1, _ = _first_hits(triangles, p - half * x, x)  # pad 1 moving along +x
    t2, _ = _first_hits(triangles, p + half * x, -x)  # pad 2 moving along -x
    width = max_width - t1 - t2
    ok = (t1 <= half) & (t2 <= half) & np.isfinite(width)
    return np.where(ok, np.clip(width, 0.0, max_width), 0.0)
