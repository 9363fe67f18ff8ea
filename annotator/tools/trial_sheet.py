"""Trials on a user's own robot: a sheet of labelled grasps to execute, and its outcomes read back.

The sheet is the trial-record format of ``docs/trial_records.md``: one row per trial, the grasp
as the labels command it (in the object's frame, as the gripper base's pose in the object's frame,
and, where the object's pose in the robot's base frame is known, in the robot's base frame), the
width, the opening, the grip force, and two columns the operator fills: ``real_success`` (1 held,
0 not) and ``notes``. :func:`make_sheet` writes it from a labels folder; :func:`read_sheet` reads
the filled sheet back into exactly what ``annotator calibrate`` reads as REAL.csv (``object_id,
grasp_id, real_success[, grip_force]``), with the trial's ``repeat`` and ``trial_id``.

Frames (docs/frames.md): ``T_obj_tcp`` is the commanded TCP (``cmd_*``: what the simulation
executed), ``T_obj_base = T_obj_tcp · T_base_tcp(width)⁻¹`` the gripper's base link (ACRONYM's
and GraspGen's ``transforms``); the robot's base frame is the UR3's ``base_link``:
``T_robot_obj = T_world_baselink⁻¹ · T_world_obj`` for labels that record where the object rests
(cell and resting labels, ``obj_*``) or the pose the user gives, ``T_robot_tcp = T_robot_obj ·
T_obj_tcp`` and the flange ``T_robot_flange = T_robot_tcp · (T_flange_base · T_base_tcp(width))⁻¹``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

log = logging.getLogger(__name__)

FORMAT = "rg2-annotator trials 2"  # the value of every row's ``format`` column
FORMATS = ("rg2-annotator trials 1", FORMAT)  # read back: 1 had no labels_sha256
# A sheet is executed by hand, one trial at a time (tens of seconds each): a million trials is a
# year of a robot's time, and the sheet's arrays grow with the count (200 floats a row).
MAX_TRIALS = 1_000_000
MAX_REPEATS = 1000  # executions of one grasp on one sheet
POSE_TOLERANCE = 1e-6  # m and quaternion units: a sheet's pose against its label's (written to 9 digits)
XYZQ = ("x", "y", "z", "qx", "qy", "qz", "qw")
OBJ_TCP_COLUMNS = XYZQ  # T_obj_tcp, the label convention
OBJ_BASE_COLUMNS = tuple(f"base_{c}" for c in XYZQ)  # T_obj_base (GraspGen's transforms)
ROBOT_OBJ_COLUMNS = tuple(f"robot_obj_{c}" for c in XYZQ)  # T_robot_obj
ROBOT_TCP_COLUMNS = tuple(f"robot_tcp_{c}" for c in XYZQ)  # T_robot_tcp
ROBOT_FLANGE_COLUMNS = tuple(f"robot_flange_{c}" for c in XYZQ)  # T_robot_flange (tool0)
JOINT_COLUMNS = tuple(f"q_grasp_{i}" for i in range(6))
FILLED_COLUMNS = ("real_success", "notes")  # what the operator writes
SHEET_COLUMNS = (
    "format",
    "labels_sha256",
    "trial_id",
    "object_id",
    "grasp_id",
    "repeat",
    "gripper",
    "mesh_sha256",
    "object_scale",
    *ROBOT_OBJ_COLUMNS,
    *OBJ_TCP_COLUMNS,
    *OBJ_BASE_COLUMNS,
    *ROBOT_TCP_COLUMNS,
    *ROBOT_FLANGE_COLUMNS,
    "width",
    "open_width",
    "grip_force",
    *FILLED_COLUMNS,
)
SELECTIONS = ("balanced", "all", "success", "failure")
# calibrate's REAL.csv (annotator.tools.calibrate.REAL_COLUMNS) and what read_sheet adds
READ_COLUMNS = ("object_id", "grasp_id", "real_success", "grip_force", "repeat", "trial_id")
TRUE_WORDS = {"1": True, "0": False, "true": True, "false": False, "yes": True, "no": False}
TRUE_WORDS.update({"success": True, "failure": False, "1.0": True, "0.0": False})


@dataclass(frozen=True)
class SheetSettings:
    """What goes on a sheet: ``n`` grasps per object (None: every one selected), chosen by
    ``select`` (:data:`SELECTIONS`) with a Generator keyed on ``seed``; each executed ``repeats``
    times; ``objects`` (None: all); ``T_robot_obj`` (4, 4): where the objects of floating labels
    are put in the robot's base frame (None: unknown, those columns stay empty)."""

    n: int | None = None
    select: str = "balanced"
    repeats: int = 1
    seed: int = 0
    objects: tuple[str, ...] | None = None
    T_robot_obj: np.ndarray | None = None


@dataclass(frozen=True)
class ReadSheet:
    """A filled sheet read back: ``trials`` (:data:`READ_COLUMNS`, one row per executed trial) and
    ``skipped``, how many rows had no outcome (not executed)."""

    trials: pd.DataFrame
    skipped: int


def labels_digest(labels: pd.DataFrame) -> str:
    """SHA-256 of what a sheet's trials stand for in ``labels``: every row's object, grasp, mesh
    and commanded grasp (``cmd_*``, float64 bytes), in (object_id, grasp_id) order. The sheet
    carries it (``labels_sha256``); ``trials read --labels`` refuses labels of another digest."""
    import hashlib

    from annotator.tools.given import CMD_COLUMNS

    rows = labels.sort_values(["object_id", "grasp_id"], kind="stable")
    digest = hashlib.sha256()
    for column in ("object_id", "mesh_sha256"):
        digest.update("\0".join(rows[column].astype(str)).encode() + b"\1")
    digest.update(rows["grasp_id"].to_numpy(dtype="<i8").tobytes())
    present = [c for c in CMD_COLUMNS if c in rows.columns]
    digest.update(",".join(present).encode())
    digest.update(np.ascontiguousarray(rows[present].to_numpy(dtype="<f8")).tobytes())
    return digest.hexdigest()


def _executable(labels: pd.DataFrame) -> np.ndarray:
    """Rows a robot may execute: not a collision nor an error; in the cell, reachable."""
    ok = ~labels["outcome"].isin(["collision", "error"]).to_numpy()
    if "reachable" in labels.columns:
        ok &= labels["reachable"].to_numpy(dtype=bool)
    return ok


def select_grasps(labels: pd.DataFrame, settings: SheetSettings) -> pd.DataFrame:
    """The label rows on the sheet, by object then grasp id (see :class:`SheetSettings`).

    ``balanced``: up to ``n/2`` simulated successes and the rest other executable outcomes, filled
    from the other kind when one runs short; ``success`` / ``failure``: that kind only; ``all``:
    any executable row. Each object's choice is drawn from ``keyed_rng("trial-sheet", seed,
    object)``: the same whatever other objects the labels hold.
    """
    from annotator.rng import keyed_rng
    from annotator.tools.common import ToolError

    if settings.select not in SELECTIONS:
        raise ToolError(f"--select {settings.select!r}: choose from {', '.join(SELECTIONS)}")
    rows = labels[_executable(labels)]
    if settings.objects is not None:
        unknown = sorted(set(settings.objects) - set(labels["object_id"]))
        if unknown:
            raise ToolError(f"--object {unknown[0]!r}: no such object in the labels")
        rows = rows[rows["object_id"].isin(settings.objects)]
    parts = []
    for oid, group in rows.groupby("object_id", sort=True):
        group = group.sort_values("grasp_id", kind="stable")
        rng = keyed_rng("trial-sheet", int(settings.seed), str(oid))
        success = group["success"].to_numpy(dtype=bool)
        wins = group.index.to_numpy()[success][rng.permutation(int(success.sum()))]
        losses = group.index.to_numpy()[~success][rng.permutation(int((~success).sum()))]
        n = len(group) if settings.n is None else min(settings.n, len(group))
        if settings.select == "success":
            chosen = wins[:n]
        elif settings.select == "failure":
            chosen = losses[:n]
        elif settings.select == "all":
            chosen = group.index.to_numpy()[rng.permutation(len(group))][:n]
        else:
            k = min(len(wins), n - min(len(losses), n // 2))
            chosen = np.concatenate([wins[:k], losses[: n - k]])
        parts.append(group.loc[np.sort(chosen)])
    if not parts or sum(len(p) for p in parts) == 0:
        raise ToolError("no grasp to execute: every selected label is a collision, an error or unreachable")
    return pd.concat(parts).sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def _poses(rows: pd.DataFrame, columns) -> np.ndarray:
    from annotator.geometry import quat_to_matrix

    v = rows[list(columns)].to_numpy(dtype=np.float64)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = quat_to_matrix(v[:, 3:7]).reshape(-1, 3, 3)
    T[:, :3, 3] = v[:, :3]
    return T


def _columns(T: np.ndarray, names) -> dict[str, np.ndarray]:
    """Pose columns (xyz, xyzw with w >= 0) of matrices (n, 4, 4)."""
    from annotator.geometry import matrix_to_quat

    q = matrix_to_quat(T[:, :3, :3]).reshape(-1, 4)  # w >= 0
    values = np.column_stack([T[:, :3, 3], q])
    return {name: values[:, k] for k, name in enumerate(names)}


def make_sheet(labels: pd.DataFrame, settings: SheetSettings, *, config, depth) -> pd.DataFrame:
    """The sheet (:data:`SHEET_COLUMNS`, one row per trial) of ``labels`` (label rows with their
    commanded grasps ``cmd_*``); ``config``: the labels' :class:`AnnotatorConfig` (the cell's robot
    pose, the pregrasp clearance); ``depth``: the gripper's :class:`annotator.tools.export.TcpDepth`
    (its FK, stroke, grip force and mount)."""
    from annotator.cell.world import robot_mount_pose
    from annotator.tools.common import ToolError
    from annotator.tools.given import CMD_COLUMNS, records_commands

    if "scene_id" in labels.columns:
        raise ToolError("scene labels: a sheet takes object labels (annotate, annotate --cell, evaluate)")
    if not records_commands(labels):
        raise ToolError("the labels do not record their commanded grasps (cmd_*): label them again")
    if not 1 <= settings.repeats <= MAX_REPEATS:
        raise ToolError(f"--repeats {settings.repeats}: give 1 .. {MAX_REPEATS}")
    rows = select_grasps(labels, settings)
    if len(rows) * settings.repeats > MAX_TRIALS:
        raise ToolError(
            f"{len(rows)} grasps x --repeats {settings.repeats} is {len(rows) * settings.repeats:,} trials, "
            f"more than the {MAX_TRIALS:,} a sheet may hold (a year of a robot's time); give a smaller "
            "--n or --repeats"
        )
    width = rows["cmd_width"].to_numpy(dtype=np.float64)
    T_obj_tcp = _poses(rows, CMD_COLUMNS[:7])
    T_base_tcp = depth.T_base_tcp(width)
    T_obj_base = T_obj_tcp @ np.linalg.inv(T_base_tcp)
    if all(c in rows.columns for c in ("obj_x", "obj_qw")):  # cell or resting: where it rests
        T_world_obj = _poses(rows, ("obj_x", "obj_y", "obj_z", "obj_qx", "obj_qy", "obj_qz", "obj_qw"))
        T_robot_world = np.linalg.inv(robot_mount_pose(config.cell).as_matrix())
        T_robot_obj = T_robot_world @ T_world_obj
    elif settings.T_robot_obj is not None:
        T_robot_obj = np.broadcast_to(np.asarray(settings.T_robot_obj, dtype=np.float64), T_obj_tcp.shape)
    else:
        T_robot_obj = np.full(T_obj_tcp.shape, np.nan)
    T_robot_tcp = T_robot_obj @ T_obj_tcp
    T_flange_tcp = depth.description.T_flange_base.as_matrix() @ T_base_tcp
    T_robot_flange = T_robot_tcp @ np.linalg.inv(T_flange_tcp)
    sheet = pd.DataFrame(
        {
            "object_id": rows["object_id"].astype(str).to_numpy(dtype=object),
            "grasp_id": rows["grasp_id"].to_numpy(dtype=np.int64),
            "gripper": rows["gripper"].astype(str).to_numpy(dtype=object)
            if "gripper" in rows.columns
            else depth.description.name,
            "mesh_sha256": rows["mesh_sha256"].astype(str).to_numpy(dtype=object),
            "object_scale": rows["object_scale"].to_numpy(dtype=np.float64),
            **_columns(T_robot_obj, ROBOT_OBJ_COLUMNS),
            **dict(
                zip(OBJ_TCP_COLUMNS, rows[list(CMD_COLUMNS[:7])].to_numpy(dtype=np.float64).T, strict=True)
            ),
            **_columns(T_obj_base, OBJ_BASE_COLUMNS),
            **_columns(T_robot_tcp, ROBOT_TCP_COLUMNS),
            **_columns(T_robot_flange, ROBOT_FLANGE_COLUMNS),
            "width": width,
            "open_width": np.minimum(depth.max_width, width + 2 * config.protocol.pregrasp_clearance),
            "grip_force": float(depth.grip_force),
        }
    )
    sheet = sheet.loc[sheet.index.repeat(settings.repeats)].reset_index(drop=True)
    sheet["repeat"] = np.tile(np.arange(settings.repeats, dtype=np.int64), len(rows))
    sheet["trial_id"] = np.arange(len(sheet), dtype=np.int64)
    sheet["format"] = FORMAT
    sheet["labels_sha256"] = labels_digest(labels)
    sheet["real_success"] = ""
    sheet["notes"] = ""
    if any(c in rows.columns for c in JOINT_COLUMNS):  # the cell's arm joints at the grasp
        joints = rows[list(JOINT_COLUMNS)].to_numpy(dtype=np.float64)
        for k, c in enumerate(JOINT_COLUMNS):
            sheet[c] = np.repeat(joints[:, k], settings.repeats)
        return sheet[[*SHEET_COLUMNS[:-2], *JOINT_COLUMNS, *FILLED_COLUMNS]]
    return sheet[list(SHEET_COLUMNS)]


def read_sheet(path: str | Path, labels: pd.DataFrame | None = None) -> ReadSheet:
    """A filled sheet (CSV) read back; rows without ``real_success`` were not executed and are
    left out. One-line :class:`ToolError` naming the row or column for: a column named twice, a
    ``trial_id`` that is not a whole number or that two rows share, two rows that are one trial
    (object, grasp and repeat), an outcome that is not 1/0. ``labels``: the sheet must have been
    made from them (its ``labels_sha256``, and each trial's pose and width are its label's
    commanded grasp), and every trial names one of their grasps on the same mesh."""
    from annotator.tools.common import ToolError, csv_header, unique_columns

    path = Path(path)
    try:
        unique_columns(csv_header(path), path)  # a column named twice: which one was filled?
        sheet = pd.read_csv(path, dtype={"real_success": str, "notes": str}, keep_default_na=False)
    except FileNotFoundError:
        raise ToolError(f"no trial sheet at {path}") from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise ToolError(f"{path}: not a CSV file ({exc})") from None
    missing = [c for c in ("object_id", "grasp_id", "real_success") if c not in sheet.columns]
    if missing:
        raise ToolError(f"{path}: missing column(s) {missing}; is it a sheet of 'annotator trials sheet'?")
    _check_trial_ids(sheet, path)
    text = sheet["real_success"].astype(str).str.strip().str.lower()
    done = text != ""
    bad = done & ~text.isin(list(TRUE_WORDS))
    if bad.any():
        row = int(np.argmax(bad.to_numpy()))
        raise ToolError(
            f"{path}: row {row}: real_success {sheet['real_success'].iloc[row]!r}: write 1 (held) or 0 "
            "(not held), or leave it empty for a trial not executed"
        )
    filled = sheet[done.to_numpy()].copy()
    if filled.empty:
        raise ToolError(f"{path}: no outcome filled in (real_success is empty on every row)")
    out = pd.DataFrame({"object_id": filled["object_id"].astype(str).to_numpy(dtype=object)})
    ids = pd.to_numeric(filled["grasp_id"], errors="coerce")
    if ids.isna().any() or (ids != ids.round()).any() or (ids < 0).any():
        row = int(filled.index[np.argmax((ids.isna() | (ids != ids.round()) | (ids < 0)).to_numpy())])
        raise ToolError(f"{path}: row {row}: grasp_id is not a non-negative integer")
    out["grasp_id"] = ids.to_numpy(dtype=np.int64)
    out["real_success"] = text[done].map(TRUE_WORDS).to_numpy(dtype=bool)
    if "grip_force" in filled.columns:
        force = pd.to_numeric(filled["grip_force"], errors="coerce")
        if force.isna().any() or (force <= 0).any():
            row = int(filled.index[np.argmax((force.isna() | (force <= 0)).to_numpy())])
            raise ToolError(f"{path}: row {row}: grip_force must be the force used, in newtons")
        out["grip_force"] = force.to_numpy(dtype=np.float64)
    for column in ("repeat", "trial_id"):
        if column in filled.columns:
            out[column] = pd.to_numeric(filled[column], errors="coerce").fillna(-1).to_numpy(dtype=np.int64)
    _check_one_row_per_trial(out, filled, path)
    if labels is not None:
        _check_made_from(sheet, labels, path)
        _match_labels(out, filled, labels, path)
    if "labels_sha256" in filled.columns:
        out["labels_sha256"] = filled["labels_sha256"].astype(str).to_numpy(dtype=object)
    return ReadSheet(out.reset_index(drop=True), int((~done).sum()))


def _check_trial_ids(sheet: pd.DataFrame, path: Path) -> None:
    """Every row's ``trial_id`` (when the sheet has the column) a whole number >= 0, no two alike."""
    from annotator.tools.common import ToolError

    if "trial_id" not in sheet.columns:
        return
    ids = pd.to_numeric(sheet["trial_id"], errors="coerce")
    bad = (ids.isna() | (ids < 0) | (ids != ids.round())).to_numpy()
    if bad.any():
        row = int(np.argmax(bad))
        raise ToolError(
            f"{path}: row {row}: trial_id {sheet['trial_id'].iloc[row]!r} is not a whole number >= 0"
        )
    twice = ids.duplicated(keep=False).to_numpy()
    if twice.any():
        rows = np.flatnonzero(ids.to_numpy() == ids.to_numpy()[np.argmax(twice)])
        raise ToolError(
            f"{path}: rows {int(rows[0])} and {int(rows[1])} both have trial_id {int(ids.iloc[rows[0]])}: "
            "a trial is one row (a row copied or pasted twice?)"
        )


def _check_one_row_per_trial(out: pd.DataFrame, filled: pd.DataFrame, path: Path) -> None:
    """No two filled rows for one execution (object, grasp, repeat) of a sheet that numbers them."""
    from annotator.tools.common import ToolError

    if "repeat" not in out.columns:
        return
    key = out[["object_id", "grasp_id", "repeat"]]
    twice = key.duplicated(keep=False).to_numpy()
    if twice.any():
        first = key.iloc[int(np.argmax(twice))]
        same = np.flatnonzero((key == first).all(axis=1).to_numpy())
        a, b = (int(filled.index[k]) for k in same[:2])
        raise ToolError(
            f"{path}: rows {a} and {b} are both repeat {int(first['repeat'])} of object "
            f"{first['object_id']!r} grasp {int(first['grasp_id'])}: one execution is one row (a row "
            "copied with a new trial_id?)"
        )


def check_stamp(stamps: pd.Series, labels: pd.DataFrame, path: Path | str, option: str) -> None:
    """The ``labels_sha256`` of a sheet's rows (or of a REAL.csv read from one) is the digest of
    ``labels`` (:func:`labels_digest`); one-line :class:`ToolError` otherwise, asking ``option`` for
    the labels the sheet was made from."""
    from annotator.tools.common import ToolError

    stamped = sorted(set(stamps.astype(str)))
    if len(stamped) != 1:
        raise ToolError(f"{path}: rows of {len(stamped)} sheets (labels_sha256 differs between rows)")
    mine = labels_digest(labels)
    if stamped[0] != mine:
        raise ToolError(
            f"{path} was made from other labels (labels_sha256 {stamped[0][:12]}, these labels' "
            f"{mine[:12]}): give {option} the labels the sheet was made from"
        )


def _check_made_from(sheet: pd.DataFrame, labels: pd.DataFrame, path: Path) -> None:
    """The sheet was made from ``labels``: its ``labels_sha256`` (format 2) is theirs, and each
    row's grasp (``x .. qw``, ``width``) is its label's commanded grasp."""
    from annotator.tools.common import ToolError
    from annotator.tools.given import CMD_COLUMNS

    if "labels_sha256" in sheet.columns:
        check_stamp(sheet["labels_sha256"], labels, path, "--labels")
    columns = [*OBJ_TCP_COLUMNS, "width"]
    if not set(columns) <= set(sheet.columns) or not set(CMD_COLUMNS) <= set(labels.columns):
        return
    keyed = labels.astype({"object_id": str}).set_index(["object_id", "grasp_id"])[list(CMD_COLUMNS)]
    ids = pd.to_numeric(sheet["grasp_id"], errors="coerce").fillna(-1).astype(np.int64)
    index = pd.MultiIndex.from_arrays([sheet["object_id"].astype(str), ids])
    want = keyed.reindex(index).to_numpy(dtype=np.float64)
    got = sheet[columns].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
    known = np.isfinite(want).all(axis=1)
    # a quaternion and its negation are one rotation
    same_q = np.minimum(
        np.abs(got[:, 3:7] - want[:, 3:7]).max(axis=1), np.abs(got[:, 3:7] + want[:, 3:7]).max(axis=1)
    )
    off = np.maximum(np.abs(got[:, :3] - want[:, :3]).max(axis=1), np.abs(got[:, 7] - want[:, 7]))
    wrong = known & ~(np.maximum(off, same_q) <= POSE_TOLERANCE)
    if wrong.any():
        row = int(np.argmax(wrong))
        oid, gid = sheet["object_id"].iloc[row], int(ids.iloc[row])
        raise ToolError(
            f"{path}: row {row}: the grasp of object {oid!r} grasp {gid} is not its label's commanded "
            "grasp: the sheet was made from other labels"
        )


def _match_labels(out: pd.DataFrame, filled: pd.DataFrame, labels: pd.DataFrame, path: Path) -> None:
    """Every trial names a label's grasp, and was executed on the mesh the label was made on."""
    from annotator.tools.common import ToolError

    keys = labels[["object_id", "grasp_id", "mesh_sha256"]].astype({"object_id": str})
    merged = out[["object_id", "grasp_id"]].merge(keys, on=["object_id", "grasp_id"], how="left")
    unknown = merged["mesh_sha256"].isna().to_numpy()
    if unknown.any():
        k = int(np.argmax(unknown))
        raise ToolError(
            f"{path}: row {int(filled.index[k])}: object {out.object_id[k]!r} grasp {int(out.grasp_id[k])} "
            "is no grasp of the labels"
        )
    if "mesh_sha256" in filled.columns:
        changed = merged["mesh_sha256"].to_numpy() != filled["mesh_sha256"].astype(str).to_numpy()
        if changed.any():
            k = int(np.argmax(changed))
            raise ToolError(
                f"{path}: row {int(filled.index[k])}: {out.object_id[k]!r}'s mesh_sha256 is not the labels': "
                "the sheet was made from other labels or another mesh"
            )
