"""Reading grasp labels: the required columns, validation, loading and splitting.

Every column of every mode is declared in :mod:`annotator.schema`; this module checks the
required ones. The outcomes (``Outcome``, ``OUTCOMES``) are :mod:`annotator.outcome`, re-exported here.

This is the side of the dataset a learner uses; it does not import pybullet. Writing labels (atomic
files, the manifest, the lock, resume) is :mod:`annotator.store`.

``pandas.read_parquet("labels/")`` reads every label: pyarrow's dataset discovery skips names
starting with ``.`` or ``_``, which is why the manifest is ``_manifest.json`` and temporary files
start with ``.``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from annotator.geometry import matrix_to_quat, quat_to_matrix

# the required columns and the table check live below the store; a learner finds them here
from annotator.label_table import (  # noqa: F401  (re-exported)
    COLUMNS,
    POSE_COLUMNS,
    SchemaError,
    mode_errors,
    validate_labels,
)
from annotator.outcome import OUTCOMES, STAGES, Outcome, Stage  # noqa: F401  (re-exported: the schema's)
from annotator.rng import keyed_rng

if TYPE_CHECKING:
    import trimesh  # loaded with the objects, only by load_object_mesh

log = logging.getLogger(__name__)


def pose_columns(T_obj_tcp: np.ndarray) -> pd.DataFrame:
    """Columns x, y, z, qx, qy, qz, qw (xyzw, w >= 0) from poses ``T_obj_tcp`` : (N, 4, 4)."""
    T = np.asarray(T_obj_tcp, dtype=np.float64).reshape(-1, 4, 4)
    q = matrix_to_quat(T[:, :3, :3]).reshape(-1, 4)
    data = np.concatenate([T[:, :3, 3], q], axis=1)
    return pd.DataFrame(data, columns=list(POSE_COLUMNS))


def poses_as_matrices(df: pd.DataFrame) -> np.ndarray:
    """``T_obj_tcp`` : (N, 4, 4) float64 in each object's mesh frame, in the row order of ``df``."""
    pos = df[["x", "y", "z"]].to_numpy(dtype=np.float64)
    quat = df[["qx", "qy", "qz", "qw"]].to_numpy(dtype=np.float64)
    T = np.zeros((len(df), 4, 4))
    if len(df):
        T[:, :3, :3] = quat_to_matrix(quat)
    T[:, :3, 3] = pos
    T[:, 3, 3] = 1.0
    return T


def load_labels(path: str | Path) -> pd.DataFrame:
    """Every label under ``path`` (an output directory or one Parquet file), validated.

    Sorted by (object_id, grasp_id) with a fresh index. Raises FileNotFoundError for a missing
    path or a directory without label files, :class:`SchemaError` for a table off the schema.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no labels at {path}")
    if path.is_dir() and not any(p.suffix == ".parquet" and p.name[0] not in "._" for p in path.iterdir()):
        raise FileNotFoundError(f"no label files (*.parquet) in {path}")
    df = pd.read_parquet(path)
    df = validate_labels(df)
    return df.sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def split_by_object(
    df: pd.DataFrame, val_fraction: float = 0.2, seed: int = 0
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Split labels into (train, val) by object so no object is in both.

    ``round(val_fraction * n_objects)`` objects go to val, at least one when ``0 < val_fraction``
    and there are two or more objects, and never all of them unless ``val_fraction == 1``. The
    choice depends only on the sorted object ids and ``seed``.
    """
    if not 0.0 <= val_fraction <= 1.0:
        raise ValueError(f"val_fraction must be in [0, 1], got {val_fraction}")
    objects = np.array(sorted(df["object_id"].unique()), dtype=object)
    n_val = int(round(val_fraction * len(objects)))
    if val_fraction > 0 and len(objects) >= 2:
        n_val = max(n_val, 1)
    if val_fraction < 1:
        n_val = min(n_val, max(len(objects) - 1, 0))
    perm = np.random.default_rng(seed).permutation(len(objects))
    val_ids = set(objects[perm[:n_val]].tolist())
    in_val = df["object_id"].isin(val_ids)
    return df[~in_val].copy(), df[in_val].copy()


# ------------------------------------------------------------------------------ dataset helpers
#
# What learners otherwise write by hand on every dataset: class balance, a score threshold and
# near-duplicate removal. Each works per object, keeps the original rows (all columns, index
# reset) and depends only on its arguments, never on row order or the global RNG.

# The RG2 is a parallel gripper: turned 180 degrees about its approach axis (TCP +z) it is the
# same grasp, finger 1 and finger 2 swapped. In the TCP frame that turn is diag(-1, -1, 1).
RG2_SYMMETRY = np.diag([-1.0, -1.0, 1.0])
# Length (m) that converts a rotation into a distance in grasp_distance: the RG2's half stroke
# (110 mm / 2). Turning the gripper by theta about its TCP moves a pad centre, at most 55 mm
# from the TCP, by at most 55 mm x theta, so the two terms are both "how far a pad moves".
ROTATION_LENGTH = 0.055


def balance_outcomes(df: pd.DataFrame, seed: int = 0, per_object: bool = True) -> pd.DataFrame:
    """As many failures as successes: the larger class is subsampled to the smaller one's size.

    ``per_object``: balance within each object (an object without successes or without failures
    then contributes no rows); otherwise over the whole table. The rows kept depend on
    ``seed``, the object id and each row's ``grasp_id`` only (not on the row order). Returns the
    kept rows sorted by (object_id, grasp_id).
    """
    groups = df.groupby("object_id", sort=True) if per_object else [("*", df)]
    kept = []
    for key, group in groups:
        group = group.sort_values(["object_id", "grasp_id"], kind="stable")
        rng = keyed_rng("balance", int(seed), key)
        success = group["success"].to_numpy(dtype=bool)
        n = int(min(success.sum(), (~success).sum()))
        for mask in (success, ~success):
            idx = np.flatnonzero(mask)
            kept.append(group.iloc[np.sort(rng.permutation(idx)[:n]) if len(idx) else idx])
    if not kept:
        return df.iloc[:0].copy()
    out = pd.concat(kept)
    return out.sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def held_through(df: pd.DataFrame, stage: str) -> pd.Series:
    """Did trial 0 hold through ``stage`` (a :class:`Stage` name, ``"lifted"``, or its gate,
    ``"lift"``)? A bool per row from the ``stage`` column: labels by any stage of the protocol
    (docs/protocol.md, "Stages"), e.g. ``df[held_through(df, "lift")]``. Labels written before
    stages were recorded have no ``stage`` column: ValueError."""
    if "stage" not in df.columns:
        raise ValueError("these labels record no stage (written before stages were recorded)")
    wanted = Stage.from_label(stage)
    order = {s.label: int(s) for s in Stage}
    reached = df["stage"].astype(str).map(order)
    if reached.isna().any():
        bad = sorted(set(df["stage"].astype(str)) - set(order))
        raise ValueError(f"unknown stage value(s) {bad}; expected one of {list(order)}")
    return (reached >= int(wanted)).rename(f"held_{wanted.label}")


def filter_by_score(df: pd.DataFrame, min_score: float) -> pd.DataFrame:
    """The grasps whose ``score`` (fraction of the K robust trials that held) is ``>= min_score``.

    With ``--trials 1`` the score is 0 or 1, so ``min_score`` in (0, 1] keeps the successes.
    """
    if not 0.0 <= min_score <= 1.0:
        raise ValueError(f"min_score must be in [0, 1], got {min_score}")
    return df[df["score"].to_numpy() >= min_score].reset_index(drop=True)


def grasp_distance(
    T_a: np.ndarray, T_b: np.ndarray, rotation_length: float = ROTATION_LENGTH, symmetric: bool = True
) -> np.ndarray:
    """Distance (m) between TCP poses, ``||p_a - p_b|| + rotation_length x angle(R_a, R_b)``.

    ``T_a`` : (n, 4, 4) or (4, 4), ``T_b`` : (m, 4, 4) or (4, 4) float -> (n, m) float (scalars
    squeezed away as the inputs were single poses). ``angle`` is the geodesic angle (rad) of
    ``R_a^T R_b``; with ``symmetric`` it is the smaller of that and the angle to ``R_b`` turned
    180 degrees about its approach axis (:data:`RG2_SYMMETRY`): the same grasp for the RG2.
    """
    A = np.asarray(T_a, dtype=np.float64)
    B = np.asarray(T_b, dtype=np.float64)
    a1, b1 = A.ndim == 2, B.ndim == 2
    A, B = A.reshape(-1, 4, 4), B.reshape(-1, 4, 4)
    dpos = np.linalg.norm(A[:, None, :3, 3] - B[None, :, :3, 3], axis=-1)
    # trace(R_a^T R_b) = sum over columns k of dot(a_k, b_k); the turned R_b negates columns x, y
    dots = np.einsum("aik,bik->abk", A[:, :3, :3], B[:, :3, :3])  # (n, m, 3)
    trace = dots.sum(axis=-1)
    if symmetric:
        trace = np.maximum(trace, -dots[..., 0] - dots[..., 1] + dots[..., 2])
    angle = np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
    d = dpos + rotation_length * angle
    if a1 and b1:
        return d[0, 0]
    return d[0] if a1 else (d[:, 0] if b1 else d)


def drop_near_duplicates(
    df: pd.DataFrame,
    min_distance: float = 0.01,
    rotation_length: float = ROTATION_LENGTH,
    same_success_only: bool = True,
) -> pd.DataFrame:
    """Keep one grasp of each cluster of near-identical ones (per object).

    Two grasps are duplicates when :func:`grasp_distance` (position plus ``rotation_length`` x
    angle, the RG2's 180-degree symmetry included) is below ``min_distance`` (m; the default
    10 mm is e.g. 5 mm apart and 5 degrees turned). Greedy and deterministic: grasps are visited
    best first (higher ``score``, then successes, then lower ``grasp_id``) and one is kept if it
    is at least ``min_distance`` from every grasp kept so far. ``same_success_only``: a success
    and a failure at nearly the same pose are not duplicates (both are kept: that boundary is
    what a learner needs to see). Returns the kept rows sorted by (object_id, grasp_id).
    """
    if min_distance < 0:
        raise ValueError(f"min_distance must be >= 0, got {min_distance}")
    keep = np.zeros(len(df), dtype=bool)
    T_all = poses_as_matrices(df)
    keys = ["object_id", "success"] if same_success_only else ["object_id"]
    for _, rows in df.reset_index(drop=True).groupby(keys, sort=True).indices.items():
        sub = df.iloc[rows]
        order = np.lexsort(
            (sub["grasp_id"].to_numpy(), ~sub["success"].to_numpy(dtype=bool), -sub["score"].to_numpy())
        )
        kept: list[int] = []
        for i in rows[order]:
            if not kept or grasp_distance(T_all[i], T_all[kept], rotation_length).min() >= min_distance:
                kept.append(i)
        keep[kept] = True
    out = df[keep]
    return out.sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def load_geometry(labels_dir: str | Path) -> pd.DataFrame:
    """The geometry record of every labelled object, indexed by object_id.

    The run manifest (``_manifest.json`` and its journal) keeps one record per object as the worker
    simulated it (``objects_info.<id>.geometry``, from ``annotator.objects.ObjectModel.geometry_record``).

    Columns: objects_dir, source_files (JSON list, relative to objects_dir), source_node, scale,
    pose_frame, pose_units, mass, mass_model, friction, volume, watertight, faces, cleaning,
    collision_method, collision_parts, collision_threshold, collision_error_mean,
    collision_error_max (m), collision_approximate, properties (JSON), digest.
    """
    path = Path(labels_dir) / "_manifest.json"
    info = _run_manifest(labels_dir).get("objects_info", {})
    rows = []
    for entry in (v for v in info.values() if isinstance(v, dict)):
        # an object's entry, or a scene's (annotate --scenes: the objects it holds)
        for record in [entry, *(entry.get("objects") or {}).values()]:
            if isinstance(record, dict) and "geometry" in record:
                rows.append(record["geometry"])
    if not rows:
        raise FileNotFoundError(f"no geometry record in {path}")
    return pd.DataFrame(rows).drop_duplicates("object_id").set_index("object_id").sort_index()


def load_object_mesh(labels_dir: str | Path, object_id: str) -> trimesh.Trimesh:
    """The mesh of ``object_id`` exactly as its poses see it: read from the source the labels name,
    scaled and cleaned the same way, in the pose frame (metres).

    Raises ``FileNotFoundError`` when the record or the source is gone and ``ValueError`` when
    the source changed since it was labelled (its digest differs). Imports pybullet (through
    ``annotator.objects``) only when called.
    """
    import json

    from annotator.objects import ObjectProperties, ObjectSource, read_object_mesh, source_digest

    record = load_geometry(labels_dir)
    if object_id not in record.index:
        raise KeyError(f"{object_id!r} is not in the geometry record of {labels_dir}")
    row = record.loc[object_id]
    root = Path(row["objects_dir"])
    path = root / json.loads(row["source_files"])[0]
    if not path.is_file():
        raise FileNotFoundError(f"{object_id}: its source {path} is gone")
    node = int(row["source_node"])
    props = ObjectProperties(**json.loads(row["properties"]))
    source = ObjectSource(object_id, path, root, None if node < 0 else node, props)
    if source_digest(source) != row["digest"]:
        raise ValueError(f"{object_id}: {path} changed since it was labelled (digest differs)")
    from annotator.config import AnnotatorConfig, ObjectConfig

    config = ObjectConfig()
    manifest = Path(labels_dir) / "_manifest.json"
    try:  # the run's own object settings (face budget) when its manifest says them
        config = AnnotatorConfig.from_dict(json.loads(manifest.read_text())["config"]).objects
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return read_object_mesh(source, config, float(row["scale"]))


# --------------------------------------------------------------------------------------- scenes


def _run_manifest(labels_dir: str | Path) -> dict:
    """The run's manifest with the journal of what changed since applied
    (:func:`annotator.store.manifest.load_state`), as a dict; FileNotFoundError if none reads."""
    from annotator.store.errors import ManifestUnreadableError
    from annotator.store.manifest import load_state

    try:
        manifest = load_state(Path(labels_dir)).manifest
    except (OSError, ManifestUnreadableError) as exc:
        raise FileNotFoundError(f"no readable run manifest in {labels_dir} ({exc})") from None
    if manifest is None:
        raise FileNotFoundError(f"no readable run manifest in {labels_dir} (no _manifest.json)")
    return manifest.to_json()


def _scene_manifest(labels_dir: str | Path) -> dict:
    manifest = _run_manifest(labels_dir)
    if not isinstance(manifest, dict) or "scenes" not in (manifest.get("run") or {}).get("inputs", {}):
        raise ValueError(f"{labels_dir} holds no scenes (made without annotate --scenes)")
    return manifest


def _scene_records(manifest: dict) -> dict[str, list[dict]]:
    """Each scene unit's label file records (its merged file, or its chunks), from the manifest."""
    out: dict[str, list[dict]] = {}
    for unit, entry in (manifest.get("objects_done") or {}).items():
        out.setdefault(unit, []).append(entry)
    for unit, entry in (manifest.get("chunks_done") or {}).items():
        out.setdefault(unit, []).extend(entry["files"].values())
    return out


def load_scenes(labels_dir: str | Path) -> pd.DataFrame:
    """The scene table of an ``annotate --scenes`` run: one row per instance of every scene whose
    labels the run's manifest vouches for (the columns of :data:`annotator.scenes.records.
    SCENE_COLUMNS`; :func:`annotator.scenes.scenes_from_table` turns it into records), by scene id
    and instance id. Each scene's table is the ``scene.parquet`` artifact its labels came with.

    Raises FileNotFoundError without a manifest, ValueError for a folder of object labels."""
    manifest = _scene_manifest(labels_dir)
    frames = []
    for records in _scene_records(manifest).values():
        for record in records:
            artifact = (record.get("artifacts") or {}).get("scene.parquet")
            if artifact is not None:
                frames.append(pd.read_parquet(Path(labels_dir) / artifact["file"]))
                break
    if not frames:
        raise FileNotFoundError(f"{labels_dir}: its run has labelled no scene yet")
    table = pd.concat(frames, ignore_index=True)
    return table.sort_values(["scene_id", "instance_id"], kind="stable", ignore_index=True)


def scene_labels(labels_dir: str | Path, scene_id: int) -> pd.DataFrame:
    """The labels of scene ``scene_id`` of an ``annotate --scenes`` run (validated), by grasp id;
    KeyError if the run has none of it."""
    manifest = _scene_manifest(labels_dir)
    unit = f"scene_{int(scene_id):06d}"  # annotator.store.names.scene_unit
    records = _scene_records(manifest).get(unit)
    if not records:
        raise KeyError(f"{labels_dir} has no labels of scene {scene_id}")
    df = pd.concat([pd.read_parquet(Path(labels_dir) / r["file"]) for r in records], ignore_index=True)
    return validate_labels(df).sort_values("grasp_id", kind="stable").reset_index(drop=True)
