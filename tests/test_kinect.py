"""Kinect v2 views: depth against known geometry, projection onto the segmentation, files, noise."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from annotator.cell import kinect
from annotator.config import KinectConfig
from annotator.geometry import Transform
from annotator.sim.world import World

BOX_HALF = np.array([0.06, 0.04, 0.05])  # m


def add_box(world: World, centre, half=BOX_HALF, quat=(0, 0, 0, 1)) -> int:
    client = world.client
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=client)
    vis = pb.createVisualShape(
        pb.GEOM_BOX, halfExtents=list(half), rgbaColor=[0.8, 0.2, 0.2, 1], physicsClientId=client
    )
    return pb.createMultiBody(0, col, vis, list(centre), list(quat), physicsClientId=client)


def add_floor(world: World) -> int:
    plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=world.client)
    return pb.createMultiBody(0, plane, -1, [0, 0, 0], physicsClientId=world.client)


def test_intrinsics_follow_the_published_fields_of_view():
    K = kinect.depth_intrinsics(KinectConfig())
    assert (K.width, K.height) == (512, 424)
    assert math.degrees(2 * math.atan(K.width / 2 / K.fx)) == pytest.approx(70.6)
    assert math.degrees(2 * math.atan(K.height / 2 / K.fy)) == pytest.approx(60.0)
    # the published sample calibration (fx = fy = 365.456) is within 1.2 %
    assert K.fx == pytest.approx(365.456, rel=0.012) and K.fy == pytest.approx(365.456, rel=0.012)
    C = kinect.color_intrinsics(KinectConfig())
    assert (C.width, C.height) == (1920, 1080)
    assert math.degrees(2 * math.atan(C.height / 2 / C.fy)) == pytest.approx(53.8)
    # with square pixels and a centred principal point K's projection is PyBullet's own (vertical FOV)
    square = kinect.Intrinsics.from_fov(
        400, 300, 2 * math.degrees(math.atan(4 / 3 * math.tan(math.radians(25)))), 50.0
    )
    assert square.fx == pytest.approx(square.fy)
    ours = np.array(square.projection_matrix(0.1, 5.0))
    theirs = np.array(pb.computeProjectionMatrixFOV(fov=50.0, aspect=400 / 300, nearVal=0.1, farVal=5.0))
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


@pytest.mark.parametrize("distance", [0.8, 1.6, 3.0])
def test_rendered_depth_of_a_box_matches_its_geometry(distance):
    """The top face of a box seen from above, off-axis and tilted: depth within 5 mm at its centre,
    and every top-face pixel back-projects onto the face's plane."""
    with World() as world:
        add_floor(world)
        centre = np.array([0.15, -0.1, BOX_HALF[2]])
        box = add_box(world, centre)
        eye = centre + np.array([0.2 * distance, 0.1 * distance, distance])
        T = kinect.look_at(eye, centre)
        view = kinect.render_view(world.client, T, color=False)
        top_centre = T.inverse().apply(centre + [0, 0, BOX_HALF[2]])
        ((u, v),) = np.round(kinect.project(top_centre, view.depth_K)).astype(int)
        assert view.segmentation[v, u] == box
        assert view.depth[v, u] == pytest.approx(top_centre[2], abs=0.005)
        # every pixel whose ray meets the top face (1 mm inside its edges) sees it at the right depth
        K = view.depth_K
        v_idx, u_idx = np.indices(view.depth.shape)
        rays_cam = np.stack([(u_idx - K.cx) / K.fx, (v_idx - K.cy) / K.fy, np.ones_like(view.depth)], -1)
        rays_world = rays_cam.reshape(-1, 3) @ T.rotation.T
        top_z = 2 * BOX_HALF[2]
        t = (top_z - eye[2]) / rays_world[:, 2]  # ray parameter = depth along the optical axis
        hit = eye + t[:, None] * rays_world
        on_face = np.all(np.abs(hit[:, :2] - centre[:2]) < BOX_HALF[:2] - 0.001, axis=1)
        assert on_face.sum() > 50
        measured = view.depth.reshape(-1)[on_face]
        assert np.all(view.segmentation.reshape(-1)[on_face] == box)
        np.testing.assert_allclose(measured, t[on_face], atol=0.001 + 0.001 * distance)


def test_look_at_keeps_the_world_up_at_the_image_top():
    """A camera looking down at 45 deg: a point above the target is higher in the image (smaller v),
    one to the camera's right (its right hand, facing the view) has a larger u."""
    eye, target = np.array([1.0, 0.0, 1.0]), np.zeros(3)
    T = kinect.look_at(eye, target)
    K = kinect.depth_intrinsics(KinectConfig())
    np.testing.assert_allclose(T.rotation[:, 2], -eye / np.linalg.norm(eye), atol=1e-12)
    assert np.linalg.det(T.rotation) == pytest.approx(1.0)
    (u0, v0), (_, v_up), (u_right, _) = kinect.project(
        T.inverse().apply(np.array([[0, 0, 0], [0, 0, 0.1], [0, 0.1, 0]])), K
    )
    assert v_up < v0 - 10  # above the target: nearer the image top
    assert u_right > u0 + 10  # facing -x, the right hand points to +y


def test_out_of_range_depth_is_zero_and_background_is_minus_one():
    with World() as world:
        box = add_box(world, [0, 0, 0])
        # 0.3 m away: closer than the Kinect's 0.5 m minimum range
        near = kinect.render_view(world.client, kinect.look_at([0, 0, 0.35], [0, 0, 0]), color=False)
        assert (near.segmentation == box).any() and np.all(near.depth == 0)
        far = kinect.render_view(world.client, kinect.look_at([0, 0, 2.0], [0, 0, 0]), color=False)
        assert (far.segmentation == kinect.BACKGROUND).any()
        assert np.all(far.depth[far.segmentation == kinect.BACKGROUND] == 0)
        assert np.all(far.depth[far.segmentation == box] > 1.9)


def test_a_label_tcp_projects_onto_the_objects_mask():
    """A TCP inside a rotated box (as a grasp label is), moved into the camera frame with
    poses_in_camera, projects onto the box's segmentation mask; one beside it does not."""
    with World() as world:
        add_floor(world)
        quat = (0.0, 0.0, math.sin(0.35), math.cos(0.35))
        T_world_obj = Transform([0.3, 0.2, BOX_HALF[2]], quat)
        box = add_box(world, T_world_obj.pos, quat=quat)
        T = kinect.look_at([0.9, -0.4, 1.3], T_world_obj.pos)
        view = kinect.render_view(world.client, T, color=True, color_scale=0.2)
        T_obj_tcp = np.tile(np.eye(4), (3, 1, 1))
        T_obj_tcp[0, :3, 3] = (0.0, 0.0, 0.0)  # the centre
        T_obj_tcp[1, :3, 3] = (0.04, -0.02, 0.03)  # off centre, inside
        T_obj_tcp[2, :3, 3] = (0.20, 0.0, 0.0)  # beside the box
        T_cam_tcp = kinect.poses_in_camera(T, T_world_obj, T_obj_tcp)
        np.testing.assert_allclose(T_cam_tcp[0, :3, 3], T.inverse().apply(T_world_obj.pos), atol=1e-12)
        uv = np.round(kinect.project(T_cam_tcp[:, :3, 3], view.depth_K)).astype(int)
        hits = [view.segmentation[v, u] == box for u, v in uv]
        assert hits == [True, True, False]
        # the colour image is the same view: the box's pixels are red there too
        cu, cv = np.round(kinect.project(T_cam_tcp[0, :3, 3], view.color_K)).astype(int)[0]
        r, g, b = view.color[cv, cu].astype(int)
        assert r > g + 50 and r > b + 50


def test_depth_png_round_trip_in_millimetres(tmp_path):
    depth = np.array([[0.0, 0.5], [1.2344, 4.5]], dtype=np.float32)
    path = tmp_path / "depth.png"
    kinect.write_depth_png(depth, path)
    from PIL import Image

    with Image.open(path) as im:
        raw = np.asarray(im)
    assert raw.dtype == np.uint16 or im.mode.startswith("I;16")
    np.testing.assert_array_equal(raw, [[0, 500], [1234, 4500]])
    np.testing.assert_allclose(kinect.read_depth_png(path), [[0, 0.5], [1.234, 4.5]], atol=1e-6)


def test_depth_noise_model_is_documented_size_and_seeded():
    config = KinectConfig()
    depth = np.full((200, 200), 2.0)
    depth[:10] = 0.0
    a = kinect.apply_depth_noise(depth, config, np.random.default_rng(3))
    b = kinect.apply_depth_noise(depth, config, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert np.all(a[:10] == 0)
    err = a[10:] - 2.0
    assert np.std(err) == pytest.approx(config.noise_sigma_1m * 4.0, rel=0.1)  # sigma z^2 at 2 m
    np.testing.assert_allclose(np.round(a[10:] / 0.001) * 0.001, a[10:], atol=1e-12)  # 1 mm steps


def test_camera_row_holds_intrinsics_and_extrinsics():
    with World() as world:
        add_box(world, [0, 0, 0])
        T = kinect.look_at([0.5, 0.5, 1.0], [0, 0, 0])
        row = kinect.render_view(world.client, T, color=False).camera_row()
    K = kinect.depth_intrinsics(KinectConfig())
    assert row["fx"] == K.fx and row["cy"] == K.cy and row["width"] == 512
    back = Transform([row["x"], row["y"], row["z"]], [row["qx"], row["qy"], row["qz"], row["qw"]])
    np.testing.assert_allclose(back.as_matrix(), T.as_matrix(), atol=1e-12)
