"""annotator trials: labels -> a sheet of trials -> filled with real outcomes -> read back ->
exactly the rows calibrate replays, with the outcomes filled in."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from annotator.cli import main
from annotator.geometry import quat_to_matrix
from annotator.tools import calibrate as cal
from annotator.tools.export import TcpDepth
from annotator.tools.given import CMD_COLUMNS
from annotator.tools.trial_sheet import FORMAT, SHEET_COLUMNS

REPO = Path(__file__).resolve().parents[2]
OBJECT_POSE = "0.4 -0.1 0.02 0 0 0.3826834324 0.9238795325"  # 45 deg about z, on the table's top


def _run(*args: str):
    return CliRunner().invoke(main, list(args))


def _matrices(df: pd.DataFrame, prefix: str) -> np.ndarray:
    names = [f"{prefix}{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
    v = df[names].to_numpy(dtype=np.float64)
    T = np.tile(np.eye(4), (len(df), 1, 1))
    T[:, :3, :3] = quat_to_matrix(v[:, 3:]).reshape(-1, 3, 3)
    T[:, :3, 3] = v[:, :3]
    return T


def test_sheet_filled_and_read_back_is_what_calibrate_replays(labelled, tmp_path: Path) -> None:
    sheet_csv, real_csv = tmp_path / "sheet.csv", tmp_path / "real.csv"
    made = _run(
        "trials", "sheet", str(labelled.labels_dir), "--n", "6", "--repeats", "2",
        "--object-pose", OBJECT_POSE, "--out", str(sheet_csv),
    )  # fmt: skip
    assert made.exit_code == 0, made.output
    sheet = pd.read_csv(sheet_csv, keep_default_na=False)
    assert list(sheet.columns) == list(SHEET_COLUMNS) and (sheet["format"] == FORMAT).all()
    labels = labelled.df.set_index(["object_id", "grasp_id"])
    keys = list(zip(sheet.object_id, sheet.grasp_id, strict=True))
    rows = labels.loc[keys]
    # never a collision; balanced: both simulated outcomes of each object where it has both
    assert not (rows.outcome == "collision").any()
    assert sheet.trial_id.tolist() == list(range(len(sheet))) and set(sheet.repeat) == {0, 1}
    assert (sheet.groupby("object_id").size() == 12).all()
    for oid, group in rows.reset_index().groupby("object_id"):
        if labelled.df[labelled.df.object_id == oid].success.any():
            assert group.success.any()
    # the grasp in the object's frame is the commanded one; the base pose goes through the gripper's FK
    np.testing.assert_allclose(
        sheet[list("xyz")].to_numpy(), rows[["cmd_x", "cmd_y", "cmd_z"]].to_numpy(), atol=1e-9
    )
    np.testing.assert_allclose(sheet.width, rows.cmd_width, atol=1e-9)
    depth = TcpDepth("rg2")
    T_obj_tcp = _matrices(sheet, "")
    np.testing.assert_allclose(
        _matrices(sheet, "base_") @ depth.T_base_tcp(sheet.width), T_obj_tcp, atol=1e-7
    )
    np.testing.assert_allclose(sheet.open_width, np.minimum(0.11, sheet.width + 0.02), atol=1e-9)
    assert (sheet.grip_force == 40.0).all() and (sheet.mesh_sha256 == rows.mesh_sha256.to_numpy()).all()
    # in the robot's base frame: where the object was put, times the grasp
    T_robot_obj = _matrices(sheet, "robot_obj_")
    np.testing.assert_allclose(T_robot_obj[0, :3, 3], [0.4, -0.1, 0.02], atol=1e-9)
    np.testing.assert_allclose(_matrices(sheet, "robot_tcp_"), T_robot_obj @ T_obj_tcp, atol=1e-7)

    # the operator fills the outcomes (1/0 and words), notes, and skips the last two trials
    filled = sheet.copy()
    truth = (filled.grasp_id + filled.repeat) % 3 != 0
    filled["real_success"] = np.where(truth, "1", "no")
    filled.loc[filled.index[-2:], "real_success"] = ""
    filled.loc[0, "notes"] = "slid 5 mm, held"
    filled.to_csv(sheet_csv, index=False)
    read = _run(
        "trials", "read", str(sheet_csv), "--labels", str(labelled.labels_dir), "--out", str(real_csv)
    )
    assert read.exit_code == 0, read.output
    assert "2 not executed" in read.output
    executed = filled.iloc[:-2]

    # calibrate's own reading of LABELS and REAL.csv: the labels' grasps, the filled outcomes
    source = cal.calibration_grasps(labelled.labels_dir, labelled.objects_dir)
    trials = cal.read_real_trials(real_csv, source.grasps)
    assert len(trials) == len(executed)
    assert trials.object_id.tolist() == executed.object_id.tolist()
    assert trials.grasp_id.tolist() == executed.grasp_id.tolist()
    assert trials.real_success.tolist() == truth.iloc[:-2].tolist()
    assert trials.repeat.tolist() == executed.repeat.tolist()
    assert (trials.grip_force == 40.0).all()
    want = labels.loc[list(zip(executed.object_id, executed.grasp_id, strict=True))]
    for column in CMD_COLUMNS:
        assert np.array_equal(trials[column].to_numpy(), want[column].to_numpy()), column
    assert (trials.outcome.to_numpy() == want.outcome.to_numpy()).all()


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: s.assign(real_success=["maybe"] + ["1"] * (len(s) - 1)), "row 0: real_success 'maybe'"),
        (lambda s: s.assign(grasp_id=[999] + s.grasp_id.tolist()[1:], real_success="1"), "is no grasp of"),
        (lambda s: s.assign(mesh_sha256="0" * 64, real_success="1"), "mesh_sha256 is not the labels'"),
        (lambda s: s.assign(real_success=""), "no outcome filled in"),
    ],
)
def test_a_bad_filled_sheet_is_one_line(labelled, tmp_path: Path, edit, message: str) -> None:
    sheet_csv = tmp_path / "sheet.csv"
    assert (
        _run("trials", "sheet", str(labelled.labels_dir), "--n", "2", "--out", str(sheet_csv)).exit_code == 0
    )
    sheet = pd.read_csv(sheet_csv, keep_default_na=False, dtype={"real_success": str})
    assert sheet["robot_tcp_x"].eq("").all()  # floating labels without --object-pose: no robot frame
    edit(sheet).to_csv(sheet_csv, index=False)
    result = _run(
        "trials",
        "read",
        str(sheet_csv),
        "--labels",
        str(labelled.labels_dir),
        "--out",
        str(tmp_path / "r.csv"),
    )
    assert result.exit_code == 2 and message in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_cell_sheet_gives_the_flange_the_arm_reaches(tmp_path: Path) -> None:
    """Cell labels: the sheet's flange pose in the UR3's base_link is the arm's FK of the label's
    joints (q_grasp_*), through the placement where the object rests."""
    from annotator.sim import ur3

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects / "box.obj")
    out = tmp_path / "cell"
    made = _run(
        "annotate", "--objects", str(objects), "--n", "8", "--cell", "--out", str(out), "-q", "--workers", "1"
    )
    assert made.exit_code == 0, made.output
    sheet_csv = tmp_path / "sheet.csv"
    assert _run("trials", "sheet", str(out), "--select", "all", "--out", str(sheet_csv)).exit_code == 0
    sheet = pd.read_csv(sheet_csv)
    assert len(sheet) >= 3
    flange = _matrices(sheet, "robot_flange_")
    for k in range(len(sheet)):
        q = sheet.loc[k, [f"q_grasp_{i}" for i in range(6)]].to_numpy(dtype=np.float64)
        T_baselink_tool0 = np.asarray(ur3.T_BASELINK_BASE) @ ur3.dh_forward_kinematics(q)
        np.testing.assert_allclose(flange[k], T_baselink_tool0, atol=1e-6)


def test_scene_labels_and_labels_without_commands_are_refused(labelled) -> None:
    from annotator.config import AnnotatorConfig
    from annotator.tools.common import ToolError
    from annotator.tools.trial_sheet import SheetSettings, make_sheet

    depth = TcpDepth("rg2")
    with pytest.raises(ToolError, match="scene labels"):
        make_sheet(labelled.df.assign(scene_id=0), SheetSettings(), config=AnnotatorConfig(), depth=depth)
    with pytest.raises(ToolError, match="do not record their commanded grasps"):
        make_sheet(labelled.df.drop(columns="cmd_x"), SheetSettings(), config=AnnotatorConfig(), depth=depth)
    collisions = labelled.df.assign(outcome="collision", success=False)
    with pytest.raises(ToolError, match="no grasp to execute"):
        make_sheet(collisions, SheetSettings(), config=AnnotatorConfig(), depth=depth)


def _sheet(labelled, tmp_path: Path, *args: str) -> Path:
    sheet_csv = tmp_path / "sheet.csv"
    made = _run("trials", "sheet", str(labelled.labels_dir), "--n", "3", *args, "--out", str(sheet_csv))
    assert made.exit_code == 0, made.output
    return sheet_csv


def _filled(sheet_csv: Path) -> pd.DataFrame:
    sheet = pd.read_csv(sheet_csv, keep_default_na=False, dtype={"real_success": str})
    return sheet.assign(real_success=np.where(sheet.index % 2 == 0, "1", "0"))


def _read(sheet_csv: Path, labels, tmp_path: Path):
    out = str(tmp_path / "real.csv")
    result = _run("trials", "read", str(sheet_csv), "--labels", str(labels), "--out", out)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    return result, errors


def _other_run(labelled, tmp_path: Path) -> Path:
    """Labels of another run of the same objects: the same ids and meshes, every pose 1 mm away."""
    other = tmp_path / "other.parquet"
    labelled.df.assign(cmd_x=labelled.df.cmd_x + 0.001).to_parquet(other)
    return other


def test_a_sheet_naming_real_success_twice_is_refused(labelled, tmp_path: Path) -> None:
    """Stale zeros first, the user's outcomes second: it read '24 trials (0 held)'."""
    sheet_csv = _sheet(labelled, tmp_path)
    _filled(sheet_csv).assign(real_success="1").to_csv(sheet_csv, index=False)
    lines = sheet_csv.read_text().splitlines()
    sheet_csv.write_text("\n".join(["real_success," + lines[0], *("0," + line for line in lines[1:])]) + "\n")
    result, errors = _read(sheet_csv, labelled.labels_dir, tmp_path)
    assert result.exit_code == 2 and len(errors) == 1
    assert "column 'real_success' appears 2 times" in errors[0]
    assert not (tmp_path / "real.csv").exists()


def test_a_sheet_read_with_the_labels_of_another_run_is_refused(labelled, tmp_path: Path) -> None:
    """Every pose differs: calibrate would replay grasps the robot never executed."""
    sheet_csv = _sheet(labelled, tmp_path)
    _filled(sheet_csv).to_csv(sheet_csv, index=False)
    other = _other_run(labelled, tmp_path)
    result, errors = _read(sheet_csv, other, tmp_path)
    assert result.exit_code == 2 and len(errors) == 1 and "was made from other labels" in errors[0]
    # a sheet of the first format (no labels_sha256): its poses are not the labels' commanded grasps
    _filled(sheet_csv).drop(columns="labels_sha256").to_csv(sheet_csv, index=False)
    result, errors = _read(sheet_csv, other, tmp_path)
    assert result.exit_code == 2 and "is not its label's commanded grasp" in errors[0]
    # read without --labels, the REAL.csv carries the digest and calibrate checks it
    filled = _filled(_sheet(labelled, tmp_path / "b"))
    filled.to_csv(tmp_path / "b" / "sheet.csv", index=False)
    real = tmp_path / "b" / "real.csv"
    assert _run("trials", "read", str(tmp_path / "b" / "sheet.csv"), "--out", str(real)).exit_code == 0
    result = _run("calibrate", str(other), str(real), "--objects", str(labelled.objects_dir))
    assert result.exit_code == 2 and "was made from other labels" in result.output
    assert not (tmp_path / "calibrated.toml").exists()


def test_duplicated_or_contradicting_trial_ids_are_refused(labelled, tmp_path: Path) -> None:
    sheet_csv = _sheet(labelled, tmp_path)
    filled = _filled(sheet_csv)
    pd.concat([filled, filled.iloc[[1]]], ignore_index=True).to_csv(sheet_csv, index=False)
    result, errors = _read(sheet_csv, labelled.labels_dir, tmp_path)
    assert result.exit_code == 2 and f"rows 1 and {len(filled)} both have trial_id 1" in errors[0]
    twice = filled.iloc[[1]].assign(trial_id=len(filled), real_success="0")  # the same trial, held and not
    pd.concat([filled, twice], ignore_index=True).to_csv(sheet_csv, index=False)
    result, errors = _read(sheet_csv, labelled.labels_dir, tmp_path)
    assert result.exit_code == 2 and "are both repeat 0 of object" in errors[0]
    filled.assign(trial_id=["x"] + filled.trial_id.tolist()[1:]).to_csv(sheet_csv, index=False)
    result, errors = _read(sheet_csv, labelled.labels_dir, tmp_path)
    assert result.exit_code == 2 and "row 0: trial_id 'x' is not a whole number" in errors[0]


def test_every_count_of_a_sheet_is_bounded(labelled, tmp_path: Path) -> None:
    """--repeats 1000000000 tried to build an 89 GiB array."""
    from helpers import synthetic_labels

    from annotator.config import AnnotatorConfig
    from annotator.tools.common import ToolError
    from annotator.tools.trial_sheet import MAX_TRIALS, SheetSettings, make_sheet

    out = tmp_path / "sheet.csv"
    result = _run("trials", "sheet", str(labelled.labels_dir), "--repeats", "1000000000", "--out", str(out))
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1 and "1<=x<=1000" in errors[0] and not out.exists()
    many = synthetic_labels("box", 2000).assign(outcome="success", success=True)
    many[list(CMD_COLUMNS)] = many[["x", "y", "z", "qx", "qy", "qz", "qw", "width"]].to_numpy()
    with pytest.raises(ToolError, match=f"more than the {MAX_TRIALS:,} a sheet may hold"):
        make_sheet(many, SheetSettings(repeats=1000), config=AnnotatorConfig(), depth=TcpDepth("rg2"))
