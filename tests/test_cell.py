"""The cell: table, UR3 mount and Kinect defined once; arm IK in the world on a moved mount."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from annotator.cell import build_cell, kinect_pose, robot_mount_pose
from annotator.cell.world import T_kinect_optical
from annotator.config import CellConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import default_gripper
from annotator.sim.world import World


def test_table_only_cell_has_the_seed_table_top():
    with World(PhysicsConfig()) as world:
        cell = build_cell(world, robot=False, kinect=False)
        assert cell.robot is None and cell.kinect is None
        assert cell.top.z == pytest.approx(-0.025, abs=1e-12)  # 0.5 x 1 x 0.05 box at 0.6 above -0.65
        np.testing.assert_allclose(cell.top.T_world_top.pos[:2], (0.5, 0.0), atol=1e-12)
        np.testing.assert_allclose(cell.top.half_size, (0.75, 0.5))
        assert cell.top.contains(np.array([[1.2, 0.45, 0.0], [1.3, 0.0, 0.0]])).tolist() == [True, False]
        # without the arm loaded, its pose comes from the same configuration
        np.testing.assert_allclose(cell.T_world_baselink.as_matrix(), np.eye(4), atol=1e-12)
        # the Kinect's optical frame from the configuration equals the loaded body's link
        loaded = build_cell(world, robot=False, kinect=True)
        np.testing.assert_allclose(
            loaded.T_world_kinect_optical().as_matrix(), cell.T_world_kinect_optical().as_matrix(), atol=1e-6
        )
        np.testing.assert_allclose(cell.T_world_kinect_optical().rotation[:, 2], (0, 0, -1), atol=1e-9)


@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0, 0.0), (0.05, -0.1, 0.02, 30.0)], ids=["seed", "moved"])
def test_ik_in_the_world_puts_the_models_tcp_on_target(mount):
    """Closed-form IK through the cell's mount and the RG2's FK lands the URDF's pad midpoint."""
    x, y, z, yaw = mount
    config = dataclasses.replace(CellConfig(), robot_x=x, robot_y=y, robot_z=z, robot_yaw=yaw)
    with World(PhysicsConfig()) as world:
        cell = build_cell(world, config, kinect=False)
        np.testing.assert_allclose(
            cell.T_world_baselink.as_matrix(), robot_mount_pose(config).as_matrix(), atol=1e-9
        )
        down = np.diag([1.0, -1.0, -1.0])  # TCP z down: a top grasp
        width = 0.04
        for target in ([0.35, 0.1, 0.05], [0.3, -0.2, 0.15]):
            T_world_tcp = Transform.from_rotation(down, np.array(target))
            q = cell.nearest_ik(T_world_tcp, width, np.array([0, -1.5, 1.5, -1.5, -1.5, 0]))
            assert q is not None
            cell.reset_arm(q)
            cell.gripper.reset_width(width)
            mid = sum(cell.robot.link_pose(n).pos for n in default_gripper().pad_links) / 2
            np.testing.assert_allclose(mid, target, atol=2e-6)
            np.testing.assert_allclose(cell.robot.link_pose("tcp").rotation, down, atol=1e-6)
            np.testing.assert_allclose(
                cell.tcp_pose(q, width).as_matrix(), T_world_tcp.as_matrix(), atol=1e-9
            )
        # out of reach: a reason, no solution
        far = cell.ik(Transform.from_rotation(down, np.array([1.2, 0.0, 0.0])), width)
        assert not far and "reach" in far.reason


def test_kinect_pose_is_pitched_down_by_default():
    T = kinect_pose(CellConfig()) * T_kinect_optical()
    np.testing.assert_allclose(T.pos, (0.4, 0.0, 1.57 - 0.033), atol=1e-9)  # optical frame on the front face
    tilted = kinect_pose(dataclasses.replace(CellConfig(), kinect_pitch=60.0)) * T_kinect_optical()
    assert math.degrees(math.acos(-tilted.rotation[2, 2])) == pytest.approx(30.0)  # 30 deg off vertical
