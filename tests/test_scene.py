"""The seed scene: headless recording, the seed's own control loop on the combined model, the GUI."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import sys

import numpy as np
import pybullet as pb
import pybullet_data
import pytest
from click.testing import CliRunner
from PIL import Image

from annotator import paths
from annotator.cli.scene import scene_command
from annotator.config import GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import default_gripper
from annotator.seed_scene import SeedSceneConfig, build_scene
from annotator.sim.ur3 import JOINT_NAMES
from annotator.sim.width_table import fk_table
from annotator.sim.world import World

# The seed script's gripper loop: the driven joint and each follower's multiplier (the seed's
# joint names, docs/grippers.md).
SEED_DRIVEN = "gripper_finger1_joint"
SEED_FOLLOWERS = {
    "gripper_finger2_joint": -1.0,
    "gripper_finger1_inner_knuckle_joint": 1.0,
    "gripper_finger2_inner_knuckle_joint": -1.0,
    "gripper_finger1_finger_tip_joint": -1.0,
    "gripper_finger2_finger_tip_joint": 1.0,
}
PADS = ("gripper_finger1_pad_link", "gripper_finger2_pad_link")
PAD_THICKNESS = 0.01145  # m, the RG2 pad box along the closing axis (docs/grippers.md)
SEED_GRIPPER_LIMITS = (-0.04547, 1.268131)  # the driven joint's URDF limits (rad)


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


class SeedScript:
    """The seed script, as written: raw PyBullet calls, joints read with getJointInfo, no annotator code.

    ``loadURDF`` without ``useFixedBase`` and with the seed's only flag; every step each arm joint
    and each gripper joint is position-controlled with its own ``maxForce`` and ``maxVelocity``
    from ``getJointInfo`` (followers at multiplier x the gripper angle), then ``stepSimulation``.
    """

    def __init__(self, client: int, urdf, position, orientation) -> None:
        self.client = client
        data = pybullet_data.getDataPath()
        pb.setGravity(0, 0, -9.8, physicsClientId=client)
        pb.loadURDF(f"{data}/table/table.urdf", [0.5, 0, -0.65], [0, 0, 0, 1], physicsClientId=client)
        self.robot = pb.loadURDF(
            str(urdf),
            position,
            orientation,
            flags=pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT,
            physicsClientId=client,
        )
        self.joints = {}
        for i in range(pb.getNumJoints(self.robot, physicsClientId=client)):
            info = pb.getJointInfo(self.robot, i, physicsClientId=client)
            self.joints[info[1].decode()] = (i, info[10], info[11])  # id, maxForce, maxVelocity

    def control(self, name: str, target: float) -> None:
        i, max_force, max_velocity = self.joints[name]
        pb.setJointMotorControl2(
            self.robot,
            i,
            pb.POSITION_CONTROL,
            targetPosition=target,
            force=max_force,
            maxVelocity=max_velocity,
            physicsClientId=self.client,
        )

    def step(self, arm_sliders: np.ndarray, gripper_opening_angle: float) -> None:
        for name, q in zip(JOINT_NAMES, arm_sliders, strict=True):
            self.control(name, q)
        self.control(SEED_DRIVEN, gripper_opening_angle)
        for name, multiplier in SEED_FOLLOWERS.items():
            self.control(name, multiplier * gripper_opening_angle)
        pb.stepSimulation(physicsClientId=self.client)

    def position(self, name: str) -> float:
        return pb.getJointState(self.robot, self.joints[name][0], physicsClientId=self.client)[0]

    def link_pose(self, name: str) -> Transform:
        s = pb.getLinkState(
            self.robot, self.joints[name][0], computeForwardKinematics=1, physicsClientId=self.client
        )
        return Transform(s[4], s[5])

    def base_pose(self) -> Transform:
        return Transform(*pb.getBasePositionAndOrientation(self.robot, physicsClientId=self.client))

    def pad_width(self) -> float:
        """Pad-face separation along the gripper's closing axis (m), as the RG2 FK table measures it."""
        p1, p2 = (self.link_pose(n.replace("_link", "_joint")).pos for n in PADS)
        x_axis = self.link_pose("rg2_mount_joint").rotation[:, 0]
        return float(np.dot(p2 - p1, x_axis)) - PAD_THICKNESS


@pytest.mark.parametrize(
    "position, yaw", [((0.0, 0.0, 0.0), 0.0), ((0.1, -0.2, 0.0), 0.7)], ids=["origin", "moved"]
)
def test_seed_script_runs_on_combined_model_as_written(position, yaw):
    """The seed's loop, verbatim: the base stays put, the arm reaches the sliders, the fingers follow."""
    urdf = paths.ur3_rg2_urdf()
    rg2, samples = default_gripper(), GripperConfig().width_table_samples
    lower, upper = SEED_GRIPPER_LIMITS
    table = fk_table(
        str(urdf),
        drive=rg2.drive_joint,
        pads=rg2.pad_links,
        base_link=rg2.base_link,
        pad_thickness=None,
        lower=lower,
        upper=upper,
        samples=samples,
    )
    orientation = [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]
    with World(PhysicsConfig(gravity=-9.8)) as world:
        seed = SeedScript(world.client, urdf, position, orientation)
        base0 = seed.base_pose()
        target = np.asarray(SeedSceneConfig().initial_arm) + np.array([0.5, 0.4, -0.8, 0.3, -0.4, 0.6])
        widths = {}
        for angle in (0.8, 0.0, 0.4):  # the seed's slider spans 0 .. 0.8 rad
            for _ in range(480):  # 2 s: the gripper moves at most 1.2 rad/s
                seed.step(target, angle)
            np.testing.assert_allclose([seed.position(n) for n in JOINT_NAMES], target, atol=1e-3)
            assert seed.position(SEED_DRIVEN) == pytest.approx(angle, abs=1e-3)
            for name, multiplier in SEED_FOLLOWERS.items():
                assert seed.position(name) == pytest.approx(multiplier * angle, abs=2e-3), name
            widths[angle] = seed.pad_width()
            assert widths[angle] == pytest.approx(table.width_of(angle), abs=5e-4), angle
        # base where it was put (a 2 kg free base fell off the table in the first second)
        np.testing.assert_allclose(seed.base_pose().pos, base0.pos, atol=1e-9)
        np.testing.assert_allclose(seed.base_pose().quat, base0.quat, atol=1e-9)
        assert widths[0.8] > 0.08 and widths[0.0] < 0.006 and widths[0.0] < widths[0.4] < widths[0.8]


@pytest.mark.slow
@pytest.mark.gui
def test_gui_under_xvfb(tmp_path):
    """`annotator scene` in a real GUI window: the demo moves the arm, the screenshot shows it."""
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not on PATH (Debian: apt-get install xvfb xauth)")
    png = tmp_path / "window.png"
    command = [
        "xvfb-run", "-a", "-s", "-screen 0 1280x1024x24",
        sys.executable, "-m", "annotator.seed_scene",
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
    assert np.abs(q - np.asarray(SeedSceneConfig().initial_arm)).max() > 0.3
    with Image.open(png) as im:
        assert im.size == (width, height)
        pixels = np.asarray(im.convert("RGB"))
    colours = np.unique(pixels.reshape(-1, 3), axis=0)
    assert len(colours) > 50, "the screenshot is (nearly) a single flat colour"


def test_build_scene_matches_seed_numbers():
    config = SeedSceneConfig()
    with World(config.physics) as world:
        scene = build_scene(world, config)
        assert pb.getPhysicsEngineParameters(physicsClientId=world.client)["gravityAccelerationZ"] == -9.8
        np.testing.assert_allclose(scene.robot.base_pose().pos, 0.0, atol=1e-9)
        np.testing.assert_allclose(scene.arm_positions(), config.initial_arm, atol=1e-9)
        np.testing.assert_allclose(scene.kinect.base_pose().pos, (0.4, 0.0, 1.57), atol=1e-9)  # the seed's
        # The Kinect's optical axis (+z of its optical frame) points straight down at the table.
        optical_z = scene.kinect.link_pose("camera_optical_frame").rotation[:, 2]
        np.testing.assert_allclose(optical_z, [0.0, 0.0, -1.0], atol=1e-9)
        assert scene.gripper_range() == pytest.approx((-0.04547, 1.268131), abs=1e-6)
        assert scene.gripper.max_width == pytest.approx(0.110, abs=0.001)  # the full stroke, not 0.8 rad's
        # One simulated second: the arm holds the initial pose, the cube rests on the table.
        for _ in range(240):
            scene.command_arm(config.initial_arm)
            scene.command_gripper(0.0)
            world.step()
        np.testing.assert_allclose(scene.arm_positions(), config.initial_arm, atol=0.01)
        np.testing.assert_allclose(scene.cube.base_pose().pos, config.cube_pos, atol=0.002)
        np.testing.assert_allclose(scene.table.base_pose().pos, (0.5, 0.0, -0.65), atol=1e-9)
        assert scene.cell.top.z == pytest.approx(-0.025, abs=1e-9)
        # The Kinect sees the table top 1.562 m below it and the cube on it, in its 512 x 424 frame.
        view = scene.cell.render_kinect(color=True, color_scale=0.25)
        assert view.depth.shape == (424, 512) and view.color.shape == (270, 480, 3)
        table_px = view.segmentation == scene.table.uid
        assert table_px.mean() > 0.3  # 1.5 x 1 m of a 2.2 x 1.8 m footprint
        np.testing.assert_allclose(np.median(view.depth[table_px]), 1.562, atol=0.002)
        assert (view.segmentation == scene.cube.uid).any()
        assert len(np.unique(view.color.reshape(-1, 3), axis=0)) > 50


@pytest.mark.slow
@pytest.mark.gui
def test_gui_replaces_a_users_screenshot_only_with_overwrite(tmp_path):
    """--screenshot goes through the one output writer: a user's file is refused before the window
    opens (tests/test_capture.py), and with --overwrite it is replaced by the window's picture,
    marked as this tool's; the capture file is claimed and released (no lock left)."""
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not on PATH (Debian: apt-get install xvfb xauth)")
    from annotator.store.outputs import written_here

    png = tmp_path / "window.png"
    png.write_bytes(b"the user's picture")
    command = [
        "xvfb-run", "-a", "-s", "-screen 0 640x480x24",
        sys.executable, "-m", "annotator.seed_scene", "--seconds", "0.5", "--screenshot-at", "0.2",
        "--screenshot", str(png), "--capture-out", str(tmp_path / "captures.parquet"), "--overwrite",
    ]  # fmt: skip
    proc = subprocess.run(command, capture_output=True, text=True, timeout=180)
    if "Xvfb failed to start" in proc.stderr or "xauth command not found" in proc.stderr:
        pytest.skip(f"Xvfb cannot start here: {proc.stderr.strip()[-300:]}")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert f"-> {png}" in proc.stdout and written_here(png)
    with Image.open(png) as im:
        assert im.size[0] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [".window.png.rg2-annotator", "window.png"]
