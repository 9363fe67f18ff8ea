"""evaluate without a width: the opening is measured over the pads' faces, and a collision row says
which check found it and what the gripper touched."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh
from click.testing import CliRunner

from annotator.cli import main
from annotator.dataset import load_labels
from annotator.geometry import matrix_to_quat
from annotator.schema import REASON_COLUMNS
from annotator.tools.evaluate import PadFace, expected_width, pad_face

REPO = Path(__file__).resolve().parents[2]
# box.obj: 60 x 40 x 120 mm, x in [-0.03, 0.03], y in [-0.02, 0.02], z in [0, 0.12]
# from above (TCP z = -z of the box), closing across its 40 mm (TCP x = +y), the TCP's y = +x
R_FROM_ABOVE = np.column_stack([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# m along the box's x: the TCP's line misses it (half 30 mm); the 20.2 mm pads overlap 5 mm
OFF_CENTRE = 0.035


def _pose(x: float, z: float = 0.10) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_FROM_ABOVE
    T[:3, 3] = [x, 0.0, z]
    return T


def test_an_off_centre_grasp_opens_over_the_pads() -> None:
    box = trimesh.load(REPO / "objects" / "box.obj", force="mesh")
    pads = pad_face("rg2")
    assert pads.width == pytest.approx(0.0202) and pads.length == pytest.approx(0.0298)
    T = np.stack([_pose(0.0), _pose(OFF_CENTRE), _pose(0.045), _pose(0.0, z=0.16)])
    # the TCP's own line: the off-centre grasp would be opened for nothing
    np.testing.assert_allclose(expected_width(box, T, 0.11), [0.04, 0.0, 0.0, 0.0], atol=1e-9)
    # over the pads: 40 mm where a pad overlaps the box; nothing beyond the pad or above the box
    np.testing.assert_allclose(expected_width(box, T, 0.11, pads), [0.04, 0.04, 0.0, 0.0], atol=1e-9)
    # a tilted box: its corners within the pad face, not on the TCP's line, set the opening
    tilted = box.copy()
    tilted.apply_transform(trimesh.transformations.rotation_matrix(np.radians(20), [1, 0, 0], [0, 0, 0.1]))
    line = expected_width(tilted, T[:1], 0.11)[0]
    swept = expected_width(tilted, T[:1], 0.11, pads)[0]
    half_chord = 0.02 / np.cos(np.radians(20)) + np.tan(np.radians(20)) * pads.length / 2
    assert line == pytest.approx(0.04 / np.cos(np.radians(20)), abs=1e-9)
    assert swept == pytest.approx(2 * half_chord, abs=1e-9)
    # the exact sweep is never narrower than a fine grid of lines over the pad face
    grid = max(
        expected_width(box, T[1:2] @ _shift(dy, dz), 0.11)[0]
        for dy in np.linspace(-pads.width / 2, pads.width / 2, 9)
        for dz in np.linspace(-pads.length / 2, pads.length / 2, 9)
    )
    assert expected_width(box, T[1:2], 0.11, pads)[0] >= grid - 1e-12
    assert expected_width(box, T[1:2], 0.11, PadFace(0.0202, 0.0298))[0] == pytest.approx(0.04)


def _shift(dy: float, dz: float) -> np.ndarray:
    S = np.eye(4)
    S[1, 3], S[2, 3] = dy, dz
    return S


@pytest.mark.slow
def test_evaluate_off_centre_grasp_and_collision_reasons(tmp_path: Path) -> None:
    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects / "box.obj")
    poses = [_pose(OFF_CENTRE), _pose(0.0), _pose(0.0)]
    q = matrix_to_quat(np.stack([T[:3, :3] for T in poses]))
    grasps = pd.DataFrame(
        {
            "object_id": "box",
            "x": [T[0, 3] for T in poses],
            "y": [T[1, 3] for T in poses],
            "z": [T[2, 3] for T in poses],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            # measured, measured, 10 mm: the pads open inside a 40 mm box
            "width": [np.nan, np.nan, 0.01],
        }
    )
    grasps.to_csv(tmp_path / "g.csv", index=False)
    args = ["evaluate", str(tmp_path / "g.csv"), "--objects", str(objects), "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(main, [*args, "--quiet", "--workers", "1"])
    assert result.exit_code == 0, result.output
    out = load_labels(tmp_path / "out").sort_values("grasp_id").reset_index(drop=True)
    assert set(REASON_COLUMNS) <= set(out.columns)
    # the off-centre grasp: opened for the 40 mm it closes on, not a collision
    assert out.cmd_width[0] == pytest.approx(0.04, abs=1e-6)
    assert out.outcome[0] != "collision"
    assert out.collided_with[0] == "" and out.collision_stage[0] == ""
    assert out.outcome[1] == "success" and out.cmd_width[1] == pytest.approx(0.04, abs=1e-6)
    # too narrow a width: the open pads are inside the box, and the row says so
    assert out.outcome[2] == "collision"
    assert out.collided_with[2] == "object" and out.collision_stage[2] == "approach"
