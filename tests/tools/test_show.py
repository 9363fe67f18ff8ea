"""annotator show: the RG2 at labelled poses around the object, and the overview of every grasp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from annotator.cli import main
from annotator.dataset import poses_as_matrices
from annotator.geometry import Transform
from annotator.tools import show as sh
from annotator.tools.common import object_mesh


def _not_blank(path: Path) -> np.ndarray:
    img = np.asarray(Image.open(path).convert("RGB")).astype(float)
    assert img.std() > 20.0  # not one flat colour
    drawn = (np.abs(img - 255.0).sum(axis=-1) > 30).mean()
    assert 0.05 < drawn < 0.9  # things drawn on a white background
    return img


def test_every_outcome_has_one_colour_in_pictures_and_pages() -> None:
    from annotator.dataset import OUTCOMES
    from annotator.tools.report import OUTCOME_HEX

    assert set(sh.OUTCOME_COLORS) == set(OUTCOME_HEX) == set(OUTCOMES)
    for outcome, (r, g, b) in sh.OUTCOME_COLORS.items():
        assert OUTCOME_HEX[outcome] == f"#{r:02x}{g:02x}{b:02x}"
    assert len(set(sh.OUTCOME_COLORS.values())) == len(OUTCOMES)  # no two outcomes look alike


def test_show_command_writes_pictures(labelled, tmp_path: Path) -> None:
    png = tmp_path / "box.png"
    args = ["show", str(labelled.labels_dir), "--object", "box", "--objects", str(labelled.objects_dir)]
    result = CliRunner().invoke(main, [*args, "--png", str(png), "--n", "3"])
    assert result.exit_code == 0, result.output
    _not_blank(png)
    _not_blank(tmp_path / "box-overview.png")
    # one line, exit 2, for the usual mistakes
    for extra, message in [
        (["--object", "cup"], "unknown object id 'cup'"),
        (["--object", "box", "--grasp", "999"], "no grasp(s) [999]"),
    ]:
        bad = CliRunner().invoke(
            main, [*args[:2], *extra, "--objects", str(labelled.objects_dir), "--png", str(png)]
        )
        assert bad.exit_code == 2 and message in bad.output and len(bad.output.strip().splitlines()) == 1
    missing = CliRunner().invoke(main, ["show", str(tmp_path / "nope"), "--object", "box", "--png", str(png)])
    assert missing.exit_code == 2 and "no labels at" in missing.output


def test_success_glyphs_fall_on_the_object(labelled) -> None:
    rows = labelled.df[labelled.df.object_id == "can"].reset_index(drop=True)
    mesh = object_mesh(labelled.labels_dir, "can", labelled.objects_dir, rows)
    T_all = poses_as_matrices(rows)  # rows sorted by grasp_id: row k is grasp k
    with sh.GraspRenderer(mesh) as renderer:
        ov = sh.overview(renderer, rows)
        success = rows.success.to_numpy()[ov.grasp_ids]
        assert success.sum() >= 2
        T_ok = T_all[ov.grasp_ids[success]]
        segs = sh.glyph_segments(T_ok, rows.width.to_numpy()[ov.grasp_ids[success]])  # (n, 4, 2, 3)
        t = np.linspace(0.0, 1.0, 12)[:, None]
        glyph = segs[:, :, None, 0] + t * (segs[:, :, None, 1] - segs[:, :, None, 0])  # (n, 4, 12, 3)
        for view in range(2):
            mask, frame, uv = ov.object_masks[view], ov.frames[view], ov.tcp_pixels[view]
            assert 0.02 < mask.mean() < 0.8
            col, row = np.round(uv[success]).astype(int).T
            # a success's TCP lies between the pads, inside the object: on its mask, behind its
            # front surface
            assert mask[row, col].all()
            _, depth = sh.project(frame.camera, T_ok[:, :3, 3])
            assert np.all(depth > frame.depth[row, col] - 1e-3)
            # and its glyph is drawn in its outcome colour: points of it clearly in front of the
            # object (or off it), with both neighbours so, are green
            g_uv, g_depth = sh.project(frame.camera, glyph.reshape(-1, 3))
            g_col, g_row = np.round(g_uv).astype(int).T
            front = (g_depth < frame.depth[g_row, g_col] - 0.003).reshape(glyph.shape[:3])
            clear = (front[..., 1:-1] & front[..., :-2] & front[..., 2:]).reshape(-1)
            inner = np.zeros(glyph.shape[:3], bool)
            inner[..., 1:-1] = True
            is_green = np.all(ov.images[view] == sh.OUTCOME_COLORS["success"], axis=-1)
            near_green = np.zeros_like(is_green)  # within a pixel: lines are drawn 2 px wide
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    near_green |= np.roll(is_green, (dr, dc), axis=(0, 1))
            green = near_green[g_row, g_col][inner.reshape(-1)]
            assert clear.sum() >= 10 and green[clear].mean() > 0.95
        # the sheet: gripper and object both in every view of a success, the pads around the TCP
        grasp = rows[rows.success].iloc[0]
        T = Transform.from_matrix(T_all[int(grasp.grasp_id)])
        renderer.pose_gripper(T, float(grasp.width))
        pads = [
            renderer.body.link_pose(n).pos for n in ("gripper_finger1_pad_link", "gripper_finger2_pad_link")
        ]
        assert np.linalg.norm((pads[0] + pads[1]) / 2 - T.pos) < 1e-6
        gap = abs(float(np.dot(pads[1] - pads[0], T.rotation[:, 0]))) - renderer.gripper.pad_thickness
        assert gap == pytest.approx(float(grasp.width), abs=1e-4)
        for camera in sh.grasp_cameras(T, mesh):
            seg = renderer.render(camera).segmentation
            assert (seg == renderer.body.uid).mean() > 0.02 and np.isin(
                seg, renderer.object_uids
            ).mean() > 0.02
