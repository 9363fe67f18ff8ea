"""Capture by hand: the code path of the scene's capture key, and the key itself under Xvfb."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels, mode_errors, poses_as_matrices
from annotator.geometry import Transform
from annotator.seed_scene import SeedSceneConfig, build_scene
from annotator.seed_scene.capture import Candidate, Capturer, capture_now, load_capture_object
from annotator.seed_scene.demo import CUBE_SIZE
from annotator.sim.world import World

SAMPLES = Path(__file__).resolve().parent.parent / "objects"
# the demo's side grasp: approach +x tilted 10 deg down, closing along world y
SIDE = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
TILT = np.array(
    [[math.cos(0.1745), 0, math.sin(0.1745)], [0, 1, 0], [-math.sin(0.1745), 0, math.cos(0.1745)]]
)


def _pose_gripper(scene, T_world_tcp: Transform, width: float, opening: float) -> None:
    """Put the arm so the TCP (at ``width``) is at ``T_world_tcp``, the pads ``opening`` apart."""
    q = scene.solve_ik(T_world_tcp, width)
    scene.cell.reset_arm(q)
    scene.gripper.reset_width(opening)


def test_capture_key_path_appends_a_label_row(tmp_path):
    config = SeedSceneConfig()
    labels_config = AnnotatorConfig()
    out = tmp_path / "captures.parquet"
    capturer = Capturer(load_capture_object(None, labels_config), labels_config, out)
    try:
        with World(config.physics) as world:
            scene = build_scene(world, config)
            cube = scene.cube.base_pose().pos
            # 1: the gripper open around the cube's middle, as a user leaves it before pressing Enter
            _pose_gripper(scene, Transform.from_rotation(TILT @ SIDE, cube), CUBE_SIZE, 0.09)
            candidate, row = capture_now(scene, capturer)
            assert candidate.chord_found and candidate.width == pytest.approx(CUBE_SIZE, abs=1e-4)
            assert row.iloc[0]["outcome"] == "success" and bool(row.iloc[0]["success"])
            assert row.iloc[0]["width"] == pytest.approx(CUBE_SIZE, abs=0.002)
            # the stored pose is the TCP in the cube's frame: the cube's centre, approach tilted down
            T = poses_as_matrices(row)[0]
            np.testing.assert_allclose(T[:3, 3], 0.0, atol=0.003)
            assert T[2, 2] == pytest.approx(-math.sin(0.1745), abs=0.01)
            # 2: the gripper beside the cube, not around it: no chord, the opening is used
            beside = Transform.from_rotation(TILT @ SIDE, cube + np.array([0.0, 0.12, 0.0]))
            _pose_gripper(scene, beside, 0.06, 0.06)
            candidate, row = capture_now(scene, capturer)
            assert not candidate.chord_found
            assert row.iloc[0]["outcome"] in ("no_contact", "collision")
    finally:
        capturer.close()
    labels = load_labels(out)  # the label schema, readable as labels
    assert labels["grasp_id"].tolist() == [0, 1]
    assert set(labels["object_id"]) == {"cube_small"}
    assert pd.read_parquet(out).shape[0] == 2
    # complete rows: every column of the batch job's, the commanded grasp and collision error included
    assert mode_errors(pd.read_parquet(out), "capture") == []
    assert np.isfinite(labels[["cmd_x", "cmd_qw", "cmd_width", "collision_error"]].to_numpy()).all()
    np.testing.assert_allclose(labels["cmd_width"].iloc[0], CUBE_SIZE, atol=1e-4)


def test_capture_on_a_chosen_object(tmp_path):
    labels_config = AnnotatorConfig()
    model = load_capture_object(SAMPLES / "box.obj", labels_config)
    config = SeedSceneConfig()
    out = tmp_path / "box.parquet"
    capturer = Capturer(model, labels_config, out)
    try:
        with World(config.physics) as world:
            scene = build_scene(world, config, model)  # the box instead of the cube, on the table
            T_world_obj = scene.cube.base_pose()
            assert T_world_obj.pos[2] > scene.cell.top.z
            # from the top, closing across the box's shortest horizontal extent
            vertices = T_world_obj.apply(np.asarray(model.mesh.vertices))
            aabb = np.array([vertices.min(axis=0), vertices.max(axis=0)])
            centre = aabb.mean(axis=0)
            down = np.diag([1.0, -1.0, -1.0])
            x_extent, y_extent = aabb[1, :2] - aabb[0, :2]
            R = down if x_extent <= y_extent else down @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
            T_world_tcp = Transform.from_rotation(R, centre)
            _pose_gripper(scene, T_world_tcp, min(x_extent, y_extent), 0.1)
            candidate, row = capture_now(scene, capturer)
            assert candidate.chord_found
            assert row.iloc[0]["object_id"] == "box" and row.iloc[0]["outcome"] == "success"
            assert row.iloc[0]["mesh_sha256"] == model.mesh_sha256
    finally:
        capturer.close()


def test_a_light_objects_capture_is_the_batch_jobs_label(tmp_path):
    """A 10 g block is simulated at a third of the time step in the batch job
    (``[physics] light_object_mass``); a capture of the same commanded grasp runs at the same step
    and gives the same row: outcome, width and simulated steps bit for bit (at 1/240 s, 2 of these
    6 simulated grasps got another outcome and every width differed)."""
    import trimesh

    from annotator.objects import discover_objects
    from annotator.pipeline.tasks import Span, SpanTask
    from annotator.pipeline.worker import label_span
    from annotator.seed_scene.capture import Candidate

    config = AnnotatorConfig()
    trimesh.creation.box((0.03, 0.03, 0.022)).export(tmp_path / "block.obj")
    (source,) = discover_objects(tmp_path)
    n = 8
    batch = label_span(SpanTask(span=Span("block", source, None, 0, n), config=config, seed=0, n=n)).rows
    assert (batch["outcome"] != "collision").sum() >= 4
    model = load_capture_object(tmp_path / "block.obj", config)
    assert model.substeps(config.physics) == 3
    capturer = Capturer(model, config, tmp_path / "captures.parquet")
    try:
        for _, row in batch.iterrows():
            pos = row[["cmd_x", "cmd_y", "cmd_z"]].to_numpy(float)
            quat = row[["cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw"]].to_numpy(float)
            result = capturer.run(Candidate(Transform.exact(pos, quat), float(row["cmd_width"]), True))
            assert result.outcome.label == row["outcome"]
            assert (result.width, result.steps) == (row["width"], row["sim_steps"])
    finally:
        capturer.close()


@pytest.mark.slow
@pytest.mark.gui
def test_enter_key_captures_in_the_gui(tmp_path):
    """`annotator scene` under Xvfb; xdotool presses Enter in the window; a row appears."""
    if shutil.which("xvfb-run") is None or shutil.which("xdotool") is None:
        pytest.skip("needs xvfb-run and xdotool")
    out = tmp_path / "captures.parquet"
    script = tmp_path / "press.sh"
    script.write_text(
        "#!/bin/sh\n"
        f"{sys.executable} -m annotator.seed_scene --seconds 60 --capture-out {out}"
        f" > {tmp_path}/log.txt 2>&1 &\n"
        "pid=$!\n"
        "w=''\n"
        "for i in $(seq 1 240); do\n"
        '  w=$(xdotool search --name Bullet | head -1); [ -n "$w" ] && break; sleep 0.5\n'
        "done\n"
        "for i in $(seq 1 20); do\n"  # the loop may still be loading: press until a row is written
        '  sleep 2; xdotool key --window "$w" Return\n'  # no window manager under Xvfb: to the window
        f"  sleep 1; [ -f {out} ] && break\n"
        "done\n"
        "kill $pid; wait $pid\n"
    )
    script.chmod(0o755)
    t0 = time.monotonic()
    proc = subprocess.run(
        ["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", str(script)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    log = (tmp_path / "log.txt").read_text() if (tmp_path / "log.txt").exists() else proc.stderr
    if "cannot open display" in log.lower() or "Xvfb failed" in proc.stderr:
        pytest.skip(f"Xvfb cannot start here: {log[-300:]}")
    assert out.exists(), f"no capture after {time.monotonic() - t0:.0f} s: {log[-2000:]}"
    assert "capture cube_small #0" in log
    assert load_labels(out).shape[0] >= 1


def _top_grasp(model) -> Candidate:
    """A top-down grasp across the middle of ``model`` (the seed's cube), at its extent."""
    width = float(np.ptp(np.asarray(model.mesh.vertices)[:, 0]))
    return Candidate(Transform.from_rotation(np.diag([1.0, -1.0, -1.0]), np.zeros(3)), width, True)


def test_a_capture_file_is_an_output_appended_only_when_this_tool_wrote_it(tmp_path):
    """--capture-out goes through the one output writer: a file the tool did not write, or one edited
    since, is refused before any capture unless overwrite, which starts it anew; one it wrote is
    appended to; a second capture of one file at once is refused (it replaced the file and each
    read the other's rows)."""
    from annotator.store import LockedError
    from annotator.store.outputs import OutputRefusedError, written_here

    config = AnnotatorConfig()
    model = load_capture_object(None, config)
    out = tmp_path / "captures.parquet"
    out.write_bytes(b"a user's file")
    with pytest.raises(OutputRefusedError, match="was not written by this tool; pass --overwrite"):
        Capturer(model, config, out)
    assert out.read_bytes() == b"a user's file"
    capturer = Capturer(model, config, out, overwrite=True)
    try:
        with pytest.raises(LockedError, match="is being written by another command"):
            Capturer(model, config, out, overwrite=True)
        capturer.capture(_top_grasp(model))  # the user's file replaced, not read
    finally:
        capturer.close()
    assert written_here(out) and load_labels(out)["grasp_id"].tolist() == [0]
    again = Capturer(model, config, out)  # its own, unchanged: appended to
    try:
        again.capture(_top_grasp(model))
    finally:
        again.close()
    assert load_labels(out)["grasp_id"].tolist() == [0, 1]
    pd.read_parquet(out).iloc[:1].to_parquet(out, index=False)  # edited since: one row removed
    with pytest.raises(OutputRefusedError, match="has changed since; pass --overwrite"):
        Capturer(model, config, out)
    assert len(pd.read_parquet(out)) == 1


@pytest.mark.parametrize("option", ["--capture-out", "--screenshot"])
def test_the_gui_refuses_a_capture_file_or_screenshot_it_did_not_write_before_its_window_opens(
    option, tmp_path, monkeypatch
):
    """Claimed before the window opens: one line, exit 2 (the GUI would need a display)."""
    from click.testing import CliRunner

    from annotator.cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    path = tmp_path / ("captures.parquet" if option == "--capture-out" else "window.png")
    path.write_bytes(b"a user's file")
    args = ["scene", option, str(path), "--seconds", "0.1"]
    if option == "--screenshot":
        args += ["--capture-out", str(tmp_path / "captures.parquet")]
    result = CliRunner().invoke(main, args)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert f"{option} {path} exists and was not written by this tool; pass --overwrite" in errors[0]
    assert path.read_bytes() == b"a user's file" and "Traceback" not in result.output
