"""evaluate --resting: objects settle on the cell's table as given, the grasps move with them and the
gripper closes with gravity on (annotator/cell/resting.py), with real physics.

The sample box is 60 x 40 x 120 mm, its mesh frame on its bottom face (z = 0 .. 0.12).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from annotator.cli import main
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform, quat_to_matrix
from annotator.objects import discover_objects
from annotator.tools.given import GivenSpan, simulate_given

REPO = Path(__file__).resolve().parents[1]
UPRIGHT = (0.0, 0.0, 0.0, 1.0)
UPSIDE_DOWN = (1.0, 0.0, 0.0, 0.0)  # half a turn about x: the mesh's +z points down
# A top-down grasp in the box's mesh frame: approach -z, closing along the 40 mm side (y).
FROM_TOP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# The same seen from the mesh's bottom face: approach +z, closing along y.
FROM_BOTTOM = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def box(tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("resting")
    shutil.copy(REPO / "objects" / "box.obj", folder)
    (source,) = discover_objects(folder)
    return source


def _pose(R: np.ndarray, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[2, 3] = R, z
    return T


def _simulate(box, poses, rests, resting: bool = True, gripper: str = "panda") -> pd.DataFrame:
    T = np.array(poses)
    span = GivenSpan(
        "box", box, None, T, np.full(len(T), 0.040), np.arange(len(T)), None, np.array(rests, dtype=float)
    )
    rows, error = simulate_given(span, AnnotatorConfig(), gripper=gripper, resting=resting)
    assert error is None, error
    return rows


def _table_top() -> float:
    config = AnnotatorConfig().cell
    return config.table_z + 0.6 + 0.025  # the seed's table: its top lands at z = -0.025


@pytest.mark.slow
def test_a_box_resting_on_its_face_is_held_from_above_with_gravity_on(box) -> None:
    rows = _simulate(box, [_pose(FROM_TOP, 0.10)], [UPRIGHT])
    row = rows.iloc[0]
    assert row["outcome"] == "success", row.to_dict()
    assert row["gripper"] == "panda" and row["width"] == pytest.approx(0.040, abs=5e-4)
    # it rests upright on the table top, where it was put: its mesh frame's origin on the top
    assert row["obj_z"] == pytest.approx(_table_top(), abs=1e-3)
    assert abs(row["obj_qw"]) == pytest.approx(1.0, abs=1e-4)
    assert row["settle_drift"] < 1e-3
    assert [row[f"rest_q{a}"] for a in "xyzw"] == list(UPRIGHT)


@pytest.mark.slow
def test_an_object_given_upside_down_rests_upside_down_and_its_grasps_move_with_it(box) -> None:
    # upside down, the mesh's bottom face (z = 0) is up: a grasp approaching the mesh's +z from its
    # z = 0 side comes from above and holds; the grasp from the mesh's top face now comes from under
    # the table and can never be executed
    rows = _simulate(box, [_pose(FROM_BOTTOM, 0.02), _pose(FROM_TOP, 0.10)], [UPSIDE_DOWN, UPSIDE_DOWN])
    above, below = rows.iloc[0], rows.iloc[1]
    R = quat_to_matrix(np.array([above[f"obj_q{a}"] for a in "xyzw"])).reshape(3, 3)
    assert R[2, 2] == pytest.approx(-1.0, abs=1e-4)  # the mesh's +z points down in the world
    assert above["obj_z"] == pytest.approx(_table_top() + 0.12, abs=1e-3)  # its 120 mm stand on the top
    assert above["outcome"] == "success", above.to_dict()
    assert below["outcome"] == "collision"
    # the TCP in the world is T_world_obj * T_obj_tcp: above the table for the first, below for the other
    T_world_obj = Transform([above[f"obj_{a}"] for a in "xyz"], [above[f"obj_q{a}"] for a in "xyzw"])
    assert (T_world_obj * Transform.from_matrix(_pose(FROM_BOTTOM, 0.02))).rotation[2, 2] == pytest.approx(-1)


@pytest.mark.slow
def test_resting_rows_do_not_depend_on_the_other_grasps_of_a_span(box) -> None:
    both = _simulate(box, [_pose(FROM_BOTTOM, 0.02), _pose(FROM_TOP, 0.10)], [UPSIDE_DOWN, UPRIGHT])
    alone = _simulate(box, [_pose(FROM_TOP, 0.10)], [UPRIGHT])
    columns = [c for c in alone.columns if c != "grasp_id"]
    pd.testing.assert_frame_equal(
        both.iloc[[1]][columns].reset_index(drop=True), alone[columns], check_exact=True
    )


@pytest.mark.slow
def test_evaluate_resting_from_the_command_line(box, tmp_path: Path) -> None:
    from annotator.geometry import matrix_to_quat

    grasps = pd.DataFrame(
        [
            {"object_id": "box", "x": 0.0, "y": 0.0, "z": z, **dict(zip(["qx", "qy", "qz", "qw"], q)), **rest}
            for z, q, rest in (
                (
                    0.10,
                    matrix_to_quat(FROM_TOP),
                    dict(zip(["rest_qx", "rest_qy", "rest_qz", "rest_qw"], UPRIGHT)),
                ),
                (
                    0.02,
                    matrix_to_quat(FROM_BOTTOM),
                    dict(zip(["rest_qx", "rest_qy", "rest_qz", "rest_qw"], UPSIDE_DOWN)),
                ),
            )
        ]
    )
    path = tmp_path / "grasps.csv"
    grasps.to_csv(path, index=False)
    out = tmp_path / "ev"
    args = ["evaluate", str(path), "--objects", str(box.path.parent), "--out", str(out), "--gripper", "panda"]
    result = CliRunner().invoke(main, [*args, "--resting", "--workers", "1", "-q"])
    assert result.exit_code == 0, result.output
    rows = pd.read_parquet(out).sort_values("grasp_id", ignore_index=True)
    assert rows["outcome"].tolist() == ["success", "success"]
    assert rows["width"].to_numpy() == pytest.approx([0.040, 0.040], abs=5e-4)  # chords measured on the mesh
    # floating, the same grasps are another run: the folder refuses it
    again = CliRunner().invoke(main, [*args, "--workers", "1", "-q"])
    assert again.exit_code == 2 and "resting True in the folder, None now" in again.output
