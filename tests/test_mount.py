"""The cell mounts the chosen gripper on the UR3's flange: one multibody, the gripper's base link on
tool0 at its description's [mount] transform, the arm's kinematics reaching the gripper's TCP."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from annotator import paths
from annotator.cell import build_cell
from annotator.cell.mount import mounted_urdf
from annotator.config import CellConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import DescriptionError, gripper_dir, load_gripper, shipped_grippers
from annotator.sim import pb
from annotator.sim.body import Body
from annotator.sim.world import World

GRIPPERS = tuple(sorted(shipped_grippers()))  # every shipped gripper


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "cache"))


def _model(client: int, urdf) -> dict:
    """Everything PyBullet loaded of a model: per joint its info, per link its dynamics and shapes."""
    uid = pb.loadURDF(str(urdf), flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
    joints = [
        pb.getJointInfo(uid, j, physicsClientId=client)
        for j in range(pb.getNumJoints(uid, physicsClientId=client))
    ]
    links = range(-1, len(joints))
    return {
        "joints": [(j[1], j[2], j[8:12], j[12], j[13], j[14], j[15], j[16]) for j in joints],
        "dynamics": [pb.getDynamicsInfo(uid, i, physicsClientId=client)[:6] for i in links],
        "shapes": [[s[1:] for s in pb.getCollisionShapeData(uid, i, physicsClientId=client)] for i in links],
    }


def test_the_rg2_on_the_flange_is_the_shipped_combined_model():
    """Element for element what the seed's ur3_visual_grabbing_with_rg2.urdf holds, so the cell
    simulates the RG2 on the arm as before."""
    with World() as world:
        mounted = _model(world.client, mounted_urdf("rg2"))
        shipped = _model(world.client, paths.ur3_rg2_urdf())
    assert mounted == shipped


@pytest.mark.parametrize("name", GRIPPERS)
def test_the_cell_reaches_each_grippers_tcp(name):
    """IK for a top grasp puts the pad-centre midpoint (the pads' FK) at the target, and the base
    link sits on tool0 at the description's [mount] transform."""
    description = load_gripper(name)
    config = dataclasses.replace(CellConfig(), robot_x=0.05, robot_yaw=20.0)
    with World(PhysicsConfig()) as world:
        cell = build_cell(world, config, kinect=False, description=description)
        robot, gripper = cell.robot, cell.gripper
        assert gripper.description is description and set(description.links) <= set(robot.links)
        T_tool0_base = robot.link_pose("tool0").inverse() * gripper.base_pose()
        # PyBullet keeps link frames in float32-ish precision along the arm: 1e-7 m
        np.testing.assert_allclose(T_tool0_base.as_matrix(), description.T_flange_base.as_matrix(), atol=1e-7)
        down = np.diag([1.0, -1.0, -1.0])
        width = 0.5 * gripper.max_width
        for target in ([0.35, 0.1, 0.05], [0.3, -0.2, 0.15]):
            T_world_tcp = Transform.from_rotation(down, np.array(target))
            q = cell.nearest_ik(T_world_tcp, width, np.array([0, -1.5, 1.5, -1.5, -1.5, 0]))
            assert q is not None
            cell.reset_arm(q)
            gripper.reset_width(width)
            mid = sum(robot.link_pose(n).pos for n in description.pad_links) / 2
            np.testing.assert_allclose(mid, target, atol=2e-6)
            np.testing.assert_allclose(gripper.measured_width(), width, atol=1e-6)
            np.testing.assert_allclose(gripper.base_pose().rotation, down, atol=1e-6)


def test_the_mounted_model_is_written_once_per_content(tmp_path):
    first = mounted_urdf("panda")
    stamp = first.stat().st_mtime_ns
    assert mounted_urdf("panda") == first and first.stat().st_mtime_ns == stamp
    assert str(first).startswith(str(tmp_path / "cache"))
    with World() as world:
        body = Body.load(world.client, first)
        assert {"tool0", "panda_hand_base", "panda_leftfinger_pad"} <= set(body.links)


def test_a_gripper_link_named_as_an_arm_link_cannot_be_mounted(tmp_path):
    folder = tmp_path / "clash"
    shutil.copytree(gripper_dir("panda"), folder, ignore=shutil.ignore_patterns("*.py", "*.md"))
    for name in ("panda.urdf", "gripper.toml"):
        path = folder / name
        text = path.read_text().replace("panda_tcp", "tool0")
        path.write_text(text.replace('name = "panda"', 'name = "clash"'))
    with pytest.raises(DescriptionError, match="'tool0' is also a link or joint of the UR3 model"):
        mounted_urdf(folder)
