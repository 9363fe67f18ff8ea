"""Placements on the table (stable poses) and the arm's reachability with its reasons."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
import trimesh

from annotator.cell import build_cell
from annotator.cell.placement import placements, stable_poses
from annotator.cell.reach import ARM_OBJECT, ARM_TABLE, NO_IK, approach_waypoints, check_reach
from annotator.config import CellConfig
from annotator.geometry import Transform
from annotator.sim.world import World

DOWN = np.diag([1.0, -1.0, -1.0])  # TCP z pointing down: a top grasp
REACH = dict(open_width=0.06, approach_distance=0.10, approach_step=0.01)


def test_stable_poses_merge_a_cylinders_sides_and_keep_the_box_faces():
    box = trimesh.creation.box((0.06, 0.04, 0.12))
    poses = stable_poses(box, merge_angle=20.0)
    assert len(poses) == 6
    assert sum(p.probability for p in poses) == pytest.approx(1.0, abs=1e-6)
    # most probable first: lying on a large face (the 6 x 12 cm one)
    assert abs(poses[0].up_in_object[1]) == pytest.approx(1.0)
    can = trimesh.creation.cylinder(radius=0.033, height=0.115, sections=48)
    raw = len(trimesh.poses.compute_stable_poses(can)[1])
    merged = stable_poses(can, merge_angle=20.0)
    assert raw > 40
    # the whole ring of side facets is one placement (lying), then standing on either end: a can
    # must be placed upright among its top three (a one-radius cluster cut the ring into pieces
    # more probable than standing, so it never was)
    assert len(merged) == 3
    assert sum(p.probability for p in merged) == pytest.approx(1.0, abs=1e-6)
    assert abs(merged[0].up_in_object[2]) < 1e-6  # lying on its side
    sides = merged[0].each_member()  # any side facet down: what replay may choose among
    assert len(sides) == raw - 2 and all(abs(p.up_in_object[2]) < 1e-6 for p in sides)
    assert len({tuple(np.round(p.up_in_object, 6)) for p in sides}) == raw - 2
    assert sorted(round(float(p.up_in_object[2])) for p in merged[1:]) == [-1, 1]
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    assert len(stable_poses(ball, merge_angle=20.0)) == 1  # a ball rests one way


def test_placements_rest_on_the_table_in_front_of_the_arm():
    mesh = trimesh.creation.box((0.06, 0.04, 0.12))
    config = CellConfig()
    with World() as world:
        cell = build_cell(world, config, robot=False, kinect=False)
        found = placements(mesh, cell.top, config)
    assert [p.placement_id for p in found] == [0, 1, 2]
    assert [p.probability for p in found] == sorted((p.probability for p in found), reverse=True)
    for p in found:
        vertices = p.T_world_obj.apply(mesh.vertices)
        assert vertices[:, 2].min() == pytest.approx(cell.top.z, abs=1e-9)  # resting on the top
        com = p.T_world_obj.apply(mesh.center_mass)
        np.testing.assert_allclose(com[:2], (config.placement_x, config.placement_y), atol=1e-9)


def test_approach_waypoints_run_along_the_tcp_z():
    T = Transform.from_rotation(DOWN, [0.3, 0.0, 0.1])
    points = approach_waypoints(T, 0.10, 0.01)
    assert len(points) == 11
    np.testing.assert_allclose(points[0].pos, [0.3, 0.0, 0.2], atol=1e-12)  # 10 cm above (behind)
    np.testing.assert_allclose(points[-1].pos, T.pos, atol=1e-12)


@pytest.fixture
def cell():
    with World() as world:
        yield build_cell(world, kinect=False)


def _box(cell, centre, half) -> int:
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=cell.client)
    return pb.createMultiBody(0.1, col, -1, list(centre), physicsClientId=cell.client)


def test_a_top_grasp_in_front_of_the_arm_is_reachable_and_the_path_is_the_approach(cell):
    obj = _box(cell, [0.35, 0.0, cell.top.z + 0.05], [0.02, 0.03, 0.05])
    T = Transform.from_rotation(DOWN, [0.35, 0.0, cell.top.z + 0.07])
    q_before = cell.arm_positions()
    reach = check_reach(cell, T, 0.04, obj=obj, **REACH)
    assert reach.reachable and reach.reason == ""
    np.testing.assert_allclose(cell.arm_positions(), q_before)  # the arm is put back
    assert reach.path.shape == (11, 6)
    for q, target in zip(reach.path, approach_waypoints(T, 0.10, 0.01), strict=True):
        np.testing.assert_allclose(cell.tcp_pose(q, 0.04).pos, target.pos, atol=1e-9)
    assert np.abs(np.diff(reach.path, axis=0)).max() < 0.2  # one continuous branch


def test_unreachable_grasps_say_why(cell):
    far = check_reach(cell, Transform.from_rotation(DOWN, [0.9, 0.0, 0.05]), 0.04, **REACH)
    assert not far.reachable and far.reason == NO_IK and far.q_grasp is None
    # a side grasp at the table's surface: the lower finger goes through the table
    side = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # approach +x, closing along y
    low = check_reach(cell, Transform.from_rotation(side, [0.45, 0.0, cell.top.z + 0.005]), 0.04, **REACH)
    assert not low.reachable and low.reason == ARM_TABLE and "table" in low.detail


def test_an_object_where_the_wrist_passes_is_an_arm_object_collision(cell):
    T = Transform.from_rotation(DOWN, [0.35, 0.0, cell.top.z + 0.07])
    free = check_reach(cell, T, 0.04, **REACH)
    assert free.reachable
    cell.reset_arm(free.q_grasp)
    wrist = cell.robot.link_pose("wrist_2_link").pos
    cell.reset_arm(np.zeros(6))
    obstacle = _box(cell, wrist, [0.02, 0.02, 0.02])
    blocked = check_reach(cell, T, 0.04, obj=obstacle, **REACH)
    assert not blocked.reachable and blocked.reason == ARM_OBJECT, blocked
    assert "touches the object" in blocked.detail
