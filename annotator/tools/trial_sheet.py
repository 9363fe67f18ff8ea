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

FORMAT = "rg2-annotator trials 1"  # the value of every row's ``format`` column
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
    rows = select_grasps(labels, settings)
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
    if settings.repeats < 1:
        raise ToolError(f"--repeats {settings.repeats}: must be at least 1")
    sheet = sheet.loc[sheet.index.repeat(settings.repeats)].reset_index(drop=True)
    sheet["repeat"] = np.tile(np.arange(settings.repeats, dtype=np.int64), len(rows))
    sheet["trial_id"] = np.arange(len(sheet), dtype=np.int64)
    sheet["format"] = FORMAT
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
    left out. ``labels``: every trial must name one of their grasps, on the same mesh (its
    ``mesh_sha256``). One-line :class:`ToolError` naming the row otherwise."""
    from annotator.tools.common import ToolError

    path = Path(path)
    try:
        sheet = pd.read_csv(path, dtype={"real_success": str, "notes": str}, keep_default_na=False)
    except FileNotFoundError:
        raise ToolError(f"no trial sheet at {path}") from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise ToolError(f"{path}: not a CSV file ({exc})") from None
    missing = [c for c in ("object_id", "grasp_id", "real_success") if c not in sheet.columns]
    if missing:
        raise ToolError(f"{path}: missing column(s) {missing}; is it a sheet of 'annotator trials sheet'?")
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
    if labels is not None:
        _match_labels(out, filled, labels, path)
    return ReadSheet(out.reset_index(drop=True), int((~done).sum()))


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
