"""The seed scene: headless recording, the seed's own control loop on the combined model, the GUI."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import numpy as np
import pybullet as pb
import pytest
from click.testing import CliRunner
from PIL import Image

from annotator import paths
from annotator.config import PhysicsConfig
from annotator.geometry import Transform
from annotator.render import render_rgb
from annotator.scene import ROBOT_FLAGS, SceneConfig, build_scene, scene_command
from annotator.sim.body import Body
from annotator.sim.ur3 import JOINT_NAMES
from annotator.sim.world import World

# The seed script's gripper loop: the driven joint and each follower's multiplier (ROBOT_FACTS
# "Seed naming").
SEED_DRIVEN = "gripper_finger1_joint"
SEED_FOLLOWERS = {
    "gripper_finger2_joint": -1.0,
    "gripper_finger1_inner_knuckle_joint": 1.0,
    "gripper_finger2_inner_knuckle_joint": -1.0,
    "gripper_finger1_finger_tip_joint": -1.0,
    "gripper_finger2_finger_tip_joint": 1.0,
}
PADS = ("gripper_finger1_pad_link", "gripper_finger2_pad_link")


def frames_of(path) -> list[np.ndarray]:
    with Image.open(path) as im:
        out = []
        for k in range(im.n_frames):
            im.seek(k)
            out.append(np.asarray(im.convert("RGB")))
        return out


def test_headless_gif(tmp_path):
    gif = tmp_path / "scene.gif"
    png = tmp_path / "last.png"
    result = CliRunner().invoke(
        scene_command, ["--headless", "--gif", str(gif), "--png", str(png), "--frames", "12"]
    )
    assert result.exit_code == 0, result.output
    with Image.open(gif) as im:
        assert im.format == "GIF"
        assert im.n_frames >= 2
        assert im.size == (320, 240)
    frames = frames_of(gif)
    assert any(not np.array_equal(frames[0], f) for f in frames[1:])
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size == (320, 240)
    # The scripted grasp lifts the cube off the table (it starts resting at z = 0).
    cube_z = float(re.search(r"cube at \[[^,]+, [^,]+, ([-\d.e]+)\]", result.output).group(1))
    assert cube_z > 0.05, result.output


def seed_loop_step(body: Body, arm_target: np.ndarray, angle: float) -> None:
    """One iteration of the seed script's loop (its slider values replaced by fixed targets)."""
    for name, q in zip(JOINT_NAMES, arm_target, strict=True):
        j = body.joints[name]
        pb.setJointMotorControl2(
            body.uid,
            j.index,
            pb.POSITION_CONTROL,
            targetPosition=q,
            force=j.max_force,
            physicsClientId=body.client,
        )
    driven = body.joints[SEED_DRIVEN]
    pb.setJointMotorControl2(
        body.uid,
        driven.index,
        pb.POSITION_CONTROL,
        targetPosition=angle,
        force=driven.max_force,
        physicsClientId=body.client,
    )
    for name, multiplier in SEED_FOLLOWERS.items():
        # The followers' URDF effort is 0 (they are passive); the seed drove them like the driven joint.
        pb.setJointMotorControl2(
            body.uid,
            body.joints[name].index,
            pb.POSITION_CONTROL,
            targetPosition=multiplier * angle,
            force=driven.max_force,
            physicsClientId=body.client,
        )


def pad_separation(body: Body) -> float:
    p1, p2 = (body.link_pose(n).pos for n in PADS)
    return float(np.linalg.norm(p2 - p1))


def test_seed_control_loop_runs_on_combined_model():
    """The seed's loop (no gear constraints, followers position-controlled by name) drives the model."""
    with World(PhysicsConfig(gravity=-9.8)) as world:
        body = Body.load(
            world.client, paths.ur3_rg2_urdf(), Transform.identity(), fixed_base=True, flags=ROBOT_FLAGS
        )
        q0 = np.asarray(SceneConfig().initial_arm)
        body.reset_joints(dict(zip(JOINT_NAMES, q0, strict=True)))
        target = q0 + np.array([0.5, 0.4, -0.8, 0.3, -0.4, 0.6])
        separations = {}
        for angle, steps in ((0.8, 300), (0.0, 300)):
            for _ in range(steps):
                seed_loop_step(body, target, angle)
                world.step()
            separations[angle] = pad_separation(body)
            np.testing.assert_allclose(body.joint_positions(JOINT_NAMES), target, atol=0.02)
            assert body.joint_position(SEED_DRIVEN) == pytest.approx(angle, abs=0.02)
            for name, multiplier in SEED_FOLLOWERS.items():
                assert body.joint_position(name) == pytest.approx(multiplier * angle, abs=0.03), name
        # Pad centres: 0.8 rad opens the pads ~ 84 mm apart (+ one pad thickness); 0 nearly closes them.
        assert separations[0.8] > 0.07, separations
        assert separations[0.0] < 0.03, separations


def test_gui_under_xvfb(tmp_path):
    """`annotator scene` in a real GUI window: the demo moves the arm, the screenshot shows it."""
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not on PATH (Debian: apt-get install xvfb xauth)")
    png = tmp_path / "window.png"
    command = [
        "xvfb-run", "-a", "-s", "-screen 0 1280x1024x24",
        sys.executable, "-m", "annotator.scene",
        "--demo", "--seconds", "1.5", "--screenshot-at", "1", "--screenshot", str(png),
    ]  # fmt: skip
    # Slow part: in GUI mode every PyBullet call waits for the window thread, and building the RG2's
    # FK table takes ~3000 calls (1 s on an idle machine, up to ~40 s on a loaded 2-core one).
    proc = subprocess.run(command, capture_output=True, text=True, timeout=180)
    if "Xvfb failed to start" in proc.stderr or "xauth command not found" in proc.stderr:
        pytest.skip(f"Xvfb cannot start here: {proc.stderr.strip()[-300:]}")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    match = re.search(r"screenshot (\d+)x(\d+) at t=[\d.]+ s, arm q = \[([^\]]+)\]", proc.stdout)
    assert match, proc.stdout[-2000:]
    width, height = int(match.group(1)), int(match.group(2))
    q = np.array([float(v) for v in match.group(3).split(",")])
    # The demo had moved the arm away from the seed's initial pose when the screenshot was taken.
    assert np.abs(q - np.asarray(SceneConfig().initial_arm)).max() > 0.3
    with Image.open(png) as im:
        assert im.size == (width, height)
        pixels = np.asarray(im.convert("RGB"))
    colours = np.unique(pixels.reshape(-1, 3), axis=0)
    assert len(colours) > 50, "the screenshot is (nearly) a single flat colour"


def test_build_scene_matches_seed_numbers():
    config = SceneConfig()
    with World(config.physics) as world:
        scene = build_scene(world, config)
        assert pb.getPhysicsEngineParameters(physicsClientId=world.client)["gravityAccelerationZ"] == -9.8
        np.testing.assert_allclose(scene.robot.base_pose().pos, 0.0, atol=1e-9)
        np.testing.assert_allclose(scene.arm_positions(), config.initial_arm, atol=1e-9)
        np.testing.assert_allclose(scene.kinect.base_pose().pos, config.kinect_pos, atol=1e-9)
        # The Kinect's optical axis (+z of its optical frame) points straight down at the table.
        optical_z = scene.kinect.link_pose("camera_optical_frame").rotation[:, 2]
        np.testing.assert_allclose(optical_z, [0.0, 0.0, -1.0], atol=1e-9)
        assert scene.gripper_range() == pytest.approx((-0.04547, 1.268131), abs=1e-6)
        assert scene.rg2.max_width == pytest.approx(0.110, abs=0.001)  # the full stroke, not 0.8 rad's
        # One simulated second: the arm holds the initial pose, the cube rests on the table.
        for _ in range(240):
            scene.command_arm(config.initial_arm)
            scene.command_gripper(0.0)
            world.step()
        np.testing.assert_allclose(scene.arm_positions(), config.initial_arm, atol=0.01)
        np.testing.assert_allclose(scene.cube.base_pose().pos, config.cube_pos, atol=0.002)
        np.testing.assert_allclose(scene.table.base_pose().pos, config.table_pos, atol=1e-9)
        # The Kinect sees the table (not a flat picture) from its 512 x 424 frame.
        image = render_rgb(world.client, scene.kinect_camera())
        assert image.shape == (424, 512, 3)
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50
