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
from annotator.tools.given import CMD_COLUMNS, records_commands, replay_grasps

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
    if set(CMD_COLUMNS) <= set(df.columns):  # a label table: its commanded grasps, kept bit for bit
        cmd = df[list(CMD_COLUMNS)].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
        norm = np.linalg.norm(cmd[:, 3:7], axis=1)
        if np.isfinite(cmd).all() and np.all(np.abs(norm - 1.0) < 1e-9):
            out[list(CMD_COLUMNS)] = cmd
    if "outcome" in df.columns:
        out["outcome"] = df["outcome"].astype(str).to_numpy(dtype=object)
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


def given_candidates(grasps: pd.DataFrame, objects_dir: Path, config, scale: float | None, max_width: float):
    """The grasps as the pipeline's :class:`GivenCandidates`, and the renumbering applied.

    Per object the grasps keep their ``grasp_id`` when those are exactly 0..k-1 (a label table, or
    ids given so); otherwise they are numbered 0..k-1 in the order of the file. Rows of a label
    table (an ``outcome`` column) are replayed (:func:`annotator.tools.given.replay_grasps`: their
    commanded grasps bit for bit, so their outcomes are reproduced exactly). Missing widths are
    measured on the mesh (:func:`expected_width`).
    Returns ``(candidates, renumbered object ids)``.
    """
    import hashlib

    from annotator.dataset import poses_as_matrices
    from annotator.objects import ObjectError, discover_objects, load_object
    from annotator.pipeline.source import GivenCandidates
    from annotator.pipeline.worker import GivenGrasps
    from annotator.tools.common import ToolError

    sources = {s.object_id: s for s in discover_objects(Path(objects_dir))}
    out: dict[str, GivenGrasps] = {}
    renumbered: list[str] = []
    digest = hashlib.sha256()
    for oid, rows in grasps.groupby("object_id", sort=True):
        ids = rows["grasp_id"].to_numpy()
        if np.array_equal(np.sort(ids), np.arange(len(rows))):
            rows = rows.sort_values("grasp_id", kind="stable")
        else:
            renumbered.append(str(oid))
        if records_commands(rows) or "outcome" in rows.columns:  # label rows: replay them
            T, width, quat = replay_grasps(rows, config, max_width)
            out[str(oid)] = GivenGrasps(T, width, quat)
            digest.update(str(oid).encode() + b"\0" + T.tobytes() + width.tobytes())
            continue
        T = poses_as_matrices(rows)
        width = rows["width"].to_numpy(dtype=np.float64).copy()
        todo = ~np.isfinite(width)
        if todo.any() and oid in sources:
            try:
                mesh = load_object(sources[oid], config.objects, scale=scale).mesh
            except ObjectError as exc:
                raise ToolError(f"{oid}: {exc}") from None
            width[todo] = expected_width(mesh, T[todo], max_width)
        width = np.clip(np.nan_to_num(width, nan=0.0), 0.0, max_width)
        out[str(oid)] = GivenGrasps(T, width)
        digest.update(str(oid).encode() + b"\0" + T.tobytes() + width.tobytes())
    return GivenCandidates(out, digest.hexdigest()), renumbered
