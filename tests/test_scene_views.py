"""Scene views: cameras on VGN's sphere, depth and segmentation against the scene's geometry, the
fused cloud, seeded noise, files; the TSDF against planes and a rendered scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scene_helpers import CONVEX, load_models

from annotator.cell.kinect import Intrinsics, look_at
from annotator.config import PhysicsConfig, SceneConfig
from annotator.geometry import Transform
from annotator.scenes import SceneBuilder, SceneSpec
from annotator.scenes.tsdf import TSDFVolume, fuse
from annotator.scenes.views import (
    SEG_TABLE,
    fused_point_cloud,
    read_views,
    render_views,
    view_pose,
    write_views,
)
from annotator.scenes.world import load_scene
from annotator.sim.world import World


@pytest.fixture(scope="module")
def scene():
    """A table scene of the convex sample objects and three views of it (no colour, exact depth)."""
    models = load_models(CONVEX)
    record = SceneBuilder(models).build(
        SceneSpec(5, seed=2, arrangement="table", min_objects=4, max_objects=4)
    )
    with World(PhysicsConfig()) as world:
        views = render_views(load_scene(world, record, models), 3, color=False)
    return models, record, views


def surface_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distance (n,) from each point to ``mesh``'s surface, to within ~0.5 mm: to the nearest of
    a dense sample of the surface (about one point per 0.7 mm square; no rtree needed)."""
    from scipy.spatial import cKDTree

    count = max(20_000, int(mesh.area / 0.7e-3**2))
    samples, _ = trimesh.sample.sample_surface(mesh, count, seed=0)
    return cKDTree(samples).query(points)[0]


def _scene_mesh(record, models, instance_id) -> trimesh.Trimesh:
    inst = record.instance(instance_id)
    return models[inst.object_id].mesh.copy().apply_transform(inst.T_table_obj.as_matrix())


def test_views_lie_on_vgns_sphere_and_look_at_the_workspace(scene):
    _, record, _ = scene
    config = SceneConfig()
    target = np.array([*record.workspace.center, 0.0])
    poses = [view_pose(record, v, config) for v in range(50)]
    for T in poses:
        offset = T.pos - target
        r = np.linalg.norm(offset)
        assert config.view_radius_min <= r <= config.view_radius_max
        assert math.degrees(math.acos(offset[2] / r)) <= config.view_max_polar
        z = T.rotation[:, 2]
        np.testing.assert_allclose(z, -offset / r, atol=1e-12)  # the optical axis through the target
        assert T.rotation[2, 1] <= 1e-12  # image down (+y) never points up: +z is image-up
    # keyed on (seed, scene, view): the same view again, another view elsewhere, another seed elsewhere
    assert view_pose(record, 7, config).pos.tolist() == poses[7].pos.tolist()
    assert len({tuple(np.round(T.pos, 9)) for T in poses}) == 50
    other = type(record)(record.scene_id, record.seed + 1, record.arrangement, record.instances,
                         record.workspace, record.T_world_table)  # fmt: skip
    assert view_pose(other, 7, config).pos.tolist() != poses[7].pos.tolist()


def test_depth_and_segmentation_match_the_scene(scene):
    """Every pixel labelled with an instance back-projects onto that instance's mesh, every table
    pixel onto the table top, and every kept instance is seen in some view."""
    models, record, views = scene
    seen = set()
    for view in views:
        pts = view.T_table_camera.apply(view.point_cloud(organized=True).reshape(-1, 3))
        seg = view.segmentation.reshape(-1)
        valid = view.depth.reshape(-1) > 0
        table = valid & (seg == SEG_TABLE)
        assert table.sum() > 1000
        assert np.abs(pts[table, 2]).max() < 0.002
        for inst in record.kept:
            mine = valid & (seg == inst.instance_id + 1)
            if not mine.any():
                continue
            seen.add(inst.instance_id)
            distance = surface_distance(_scene_mesh(record, models, inst.instance_id), pts[mine])
            assert np.percentile(distance, 99) < 0.002, (inst.object_id, np.percentile(distance, 99))
        assert set(np.unique(seg)) <= {0, SEG_TABLE, *(i.instance_id + 1 for i in record.kept)}
    assert seen == {i.instance_id for i in record.kept}


def test_fused_cloud_is_in_the_table_frame_and_cropped(scene):
    _, record, views = scene
    full = fused_point_cloud(views)
    assert len(full.points) == sum(int((v.depth > 0).sum()) for v in views)
    cropped = fused_point_cloud(views, crop=record.workspace)
    assert 0 < len(cropped.points) < len(full.points)
    assert record.workspace.contains(cropped.points).all()
    assert set(np.unique(cropped.view_id)) == {0, 1, 2}
    objects = cropped.points[(cropped.segmentation > 0) & (cropped.segmentation < 254)]
    assert len(objects) > 500 and objects[:, 2].min() > -0.002  # nothing below the table top


def test_depth_noise_is_seeded_and_in_millimetres(scene):
    models, record, views = scene
    with World(PhysicsConfig()) as world:
        loaded = load_scene(world, record, models)
        a = render_views(loaded, 2, color=False, noise=True)
        b = render_views(loaded, 2, color=False, noise=True)
    for noisy, again, exact in zip(a, b, views, strict=False):
        assert np.array_equal(noisy.depth, again.depth)
        valid = exact.depth > 0
        assert np.array_equal(noisy.depth > 0, valid)
        mm = noisy.depth[valid].astype(np.float64) * 1000
        np.testing.assert_allclose(mm, np.round(mm), atol=1e-3)
        assert 0 < np.abs(noisy.depth - exact.depth)[valid].mean() < 0.005


def test_view_files_round_trip(scene, tmp_path):
    models, record, _ = scene
    with World(PhysicsConfig()) as world:
        views = render_views(load_scene(world, record, models), 2, color=True, color_scale=0.1)
    write_views(tmp_path, views)
    back = read_views(tmp_path)
    for v, w in zip(views, back, strict=True):
        assert (w.scene_id, w.view_id) == (v.scene_id, v.view_id)
        assert w.T_table_camera.pos.tolist() == v.T_table_camera.pos.tolist()
        assert w.depth_K == v.depth_K and w.color_K == v.color_K
        assert np.array_equal(w.segmentation, v.segmentation) and np.array_equal(w.color, v.color)
        assert np.abs(w.depth - v.depth).max() <= 0.0005 + 1e-6


# --- TSDF ------------------------------------------------------------------------------------------


def _plane_view(height: float, size: float) -> tuple[np.ndarray, Intrinsics, Transform]:
    """A camera 1 m above the volume's centre looking straight down at the plane z = height
    (volume frame): depth is 1 - height everywhere (a fronto-parallel plane)."""
    K = Intrinsics.from_fov(160, 120, 60.0, 47.0)
    T_volume_camera = look_at(np.array([size / 2, size / 2, 1.0]), np.array([size / 2, size / 2, 0.0]))
    return np.full((K.height, K.width), 1.0 - height, np.float32), K, T_volume_camera.inverse()


def test_tsdf_of_a_plane():
    size, res, height = 0.2, 20, 0.0525  # the plane a quarter voxel above a layer of centres
    volume = TSDFVolume(size, res)
    depth, K, T_camera_volume = _plane_view(height, size)
    volume.integrate(depth, K, T_camera_volume)
    z = (np.arange(res) + 0.5) * volume.voxel_size
    column = volume.tsdf[10, 10]  # one column of voxels, near the optical axis
    # above the plane: the distance along the ray, truncated; below by more than the truncation: unseen
    seen = volume.weight[10, 10] > 0
    assert not seen[z < height - volume.trunc].any() and seen[z >= height - volume.trunc + 1e-9].all()
    near_axis = seen & (z - height < volume.trunc)
    np.testing.assert_allclose(column[near_axis], (z[near_axis] - height) / volume.trunc, atol=2e-3)
    assert np.all(column[seen & (z - height >= volume.trunc)] == 1.0)
    surface = volume.surface_points()
    assert len(surface) >= (res - 2) ** 2
    assert np.abs(surface[:, 2] - height).max() < 0.05 * volume.voxel_size
    grid = volume.vgn_grid()
    assert grid.dtype == np.float32 and grid.shape == (res, res, res)
    near = (grid > 0) & (grid < 1)
    assert np.array_equal(near, volume.observed_near_surface())
    np.testing.assert_allclose(grid[near], (volume.tsdf[near] + 1) / 2)
    # a second identical view: the same values, twice the weight
    before = volume.tsdf.copy()
    volume.integrate(depth, K, T_camera_volume)
    assert np.array_equal(volume.tsdf, before) and volume.weight.max() == 2.0


def test_tsdf_of_a_scene_has_its_surface_where_the_objects_are(scene):
    models, record, views = scene
    ws = record.workspace
    volume = fuse(views, ws.size, 60, ws.T_table_task)
    surface = ws.T_table_task.apply(volume.surface_points())
    assert len(surface) > 1000
    meshes = [_scene_mesh(record, models, i.instance_id) for i in record.kept]
    objects = trimesh.util.concatenate(meshes)
    on_table = np.abs(surface[:, 2]) < volume.voxel_size
    d = surface_distance(objects, surface[~on_table])
    assert np.percentile(d, 95) < volume.voxel_size, np.percentile(d, 95)
    grid = volume.vgn_grid()
    assert 0 < grid.min() + 1 and grid.max() < 0.99 + 1e-6 and (grid > 0).sum() > 1000
