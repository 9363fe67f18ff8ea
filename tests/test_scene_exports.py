"""Scene exports read back: VGN's raw and dataset layouts, Contact-GraspNet's scene contacts.

VGN's and Contact-GraspNet's own reading code needs Open3D / torch / TensorFlow, so the files are
read here the way their code reads them (the same calls, keys and column slices, written from
their documented layouts: see annotator/tools/export_vgn.py and export_cgn.py)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import trimesh
from scene_helpers import CONVEX, grasps_on, load_models

from annotator.cell.kinect import depth_intrinsics, point_cloud
from annotator.config import KinectConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.scenes import SceneBuilder, SceneSpec
from annotator.scenes.tsdf import fuse
from annotator.scenes.views import render_views
from annotator.scenes.world import load_scene
from annotator.sim.world import World
from annotator.tools import export_cgn, export_vgn
from annotator.tools.export import TcpDepth


@pytest.fixture(scope="module")
def scenes():
    """Two scenes of the convex sample objects, two noisy views each, synthetic grasps on them."""
    models = load_models(CONVEX)
    builder = SceneBuilder(models)
    out = []
    for sid, arrangement in ((4, "table"), (11, "pile")):
        record = builder.build(SceneSpec(sid, seed=1, arrangement=arrangement, min_objects=3, max_objects=4))
        with World(PhysicsConfig()) as world:
            views = render_views(load_scene(world, record, models), 2, color=False, noise=True)
        out.append((record, views, grasps_on(record, models, 5, seed=sid)))
    return models, out


@pytest.fixture(scope="module")
def setup():
    return export_vgn.VgnSetup(0.3, depth_intrinsics(KinectConfig()), 0.11)


def test_vgn_raw_files_read_back_as_vgn_reads_them(scenes, setup, tmp_path):
    _, items = scenes
    export_vgn.write_vgn_raw(tmp_path, setup, items)
    data = json.loads((tmp_path / "setup.json").read_text())
    assert set(data) == {"size", "intrinsic", "max_opening_width", "finger_depth"}
    assert set(data["intrinsic"]) == {"width", "height", "K"} and len(data["intrinsic"]["K"]) == 9
    back = export_vgn.read_setup(tmp_path)
    assert back["intrinsic"] == setup.intrinsic and np.isclose(back["size"], 6 * back["finger_depth"])
    header = (tmp_path / "grasps.csv").read_text().splitlines()[0]
    assert header == "scene_id,qx,qy,qz,qw,x,y,z,width,label"
    df = export_vgn.read_grasps(tmp_path)
    assert len(df) == sum(len(g.width) for _, _, g in items)
    assert not pd.api.types.is_numeric_dtype(df["scene_id"])  # VGN appends ".npz" to it
    assert set(df["scene_id"]) == {"scene_000004", "scene_000011"}
    for record, views, grasps in items:
        rows = df[df["scene_id"] == export_vgn.scene_name(record.scene_id)].reset_index(drop=True)
        for i, row in rows.iterrows():
            T_task_vgn, width, label = export_vgn.grasp_in_task(row)
            T_table_tcp = export_vgn.tcp_in_table(T_task_vgn.as_matrix(), record)
            np.testing.assert_allclose(T_table_tcp, grasps.T_table_tcp[i], atol=1e-12)
            # VGN's fingers close along its y axis: ours along x
            np.testing.assert_allclose(T_task_vgn.rotation[:, 1], T_table_tcp[:3, 0], atol=1e-12)
            assert width == grasps.width[i] and label == int(grasps.success[i])
        depth_imgs, extrinsics = export_vgn.read_sensor_data(tmp_path, export_vgn.scene_name(record.scene_id))
        assert depth_imgs.dtype == np.float32 and depth_imgs.shape == (2, 424, 512)
        assert extrinsics.dtype == np.float32 and extrinsics.shape == (2, 7)
        for view, depth, extrinsic in zip(views, depth_imgs, extrinsics, strict=True):
            assert np.array_equal(depth, view.depth)
            # a depth pixel's point, in VGN's task frame, projects back onto that pixel
            v, u = 300, 250
            p_camera = point_cloud(view.depth, view.depth_K, organized=True)[v, u]
            p_task = record.workspace.T_table_task.inverse().apply(view.T_table_camera.apply(p_camera))
            T_cam_task = Transform(extrinsic[4:], extrinsic[:4])  # VGN: Transform.from_list, [q, t]
            x, y, z = T_cam_task.apply(p_task)
            K = back["intrinsic"]
            np.testing.assert_allclose([x / z * K.fx + K.cx, y / z * K.fy + K.cy], [u, v], atol=0.05)


def test_vgn_dataset_holds_vgns_grid_and_voxel_units(scenes, setup, tmp_path):
    _, items = scenes
    export_vgn.write_vgn_raw(tmp_path / "raw", setup, items)
    export_vgn.write_vgn_dataset(tmp_path / "ds", setup, items)
    raw = export_vgn.read_grasps(tmp_path / "raw")
    ds = export_vgn.read_grasps(tmp_path / "ds")
    assert list(ds.columns) == list(export_vgn.DATASET_COLUMNS)
    voxel = setup.size / export_vgn.DATASET_RESOLUTION
    np.testing.assert_allclose(
        ds[["i", "j", "k", "width"]].to_numpy(), raw[["x", "y", "z", "width"]].to_numpy() / voxel
    )
    assert ds[["scene_id", "qx", "qy", "qz", "qw", "label"]].equals(
        raw[["scene_id", "qx", "qy", "qz", "qw", "label"]]
    )
    for record, views, _ in items:
        grid = export_vgn.read_grid(tmp_path / "ds", export_vgn.scene_name(record.scene_id))
        assert grid.dtype == np.float32 and grid.shape == (1, 40, 40, 40)
        expected = fuse(views, setup.size, 40, record.workspace.T_table_task).vgn_grid()
        assert np.array_equal(grid[0], expected)
        assert (grid > 0).sum() > 500 and grid.max() < 0.99
        # VGN's Dataset rounds the position to a voxel index: each grasp's index is inside the grid
        rows = ds[ds["scene_id"] == export_vgn.scene_name(record.scene_id)]
        index = np.round(rows[["i", "j", "k"]].to_numpy()).astype(int)
        assert (index >= 0).all() and (index < 40).all()


def test_vgn_writers_leave_out_grasps_outside_the_grid(scenes, setup, tmp_path):
    """A grasp whose voxel index (VGN's Dataset: round of the float32 position in voxels) is
    outside [0, 40) is in neither layout; the others are, in order."""
    _, items = scenes
    record, views, grasps = items[0]
    T = grasps.T_table_tcp.copy()
    lower, size = np.asarray(record.workspace.lower), record.workspace.size
    T[0, :3, 3] = lower + [-0.005, 0.1, 0.1]  # index -1 along x
    T[1, :3, 3] = lower + [0.1, size + 0.002, 0.1]  # index 40 along y
    T[2, :3, 3] = lower + [0.1, 0.1, size - 0.004]  # index 39 along z: inside
    moved = export_vgn.SceneGrasps(
        grasps.scene_id, T, grasps.width, grasps.success, grasps.instance_id, grasps.grasp_id
    )
    inside = export_vgn.inside_grid(record, moved, size)
    assert inside[:3].tolist() == [False, False, True] and inside[3:].all()
    export_vgn.write_vgn_raw(tmp_path / "raw", setup, [(record, views, moved)])
    export_vgn.write_vgn_dataset(tmp_path / "ds", setup, [(record, views, moved)])
    voxel = setup.size / export_vgn.DATASET_RESOLUTION
    for root, unit in (("raw", 1.0), ("ds", voxel)):  # the dataset's widths are in voxels
        df = export_vgn.read_grasps(tmp_path / root)
        np.testing.assert_allclose(df["width"].to_numpy() * unit, grasps.width[2:], rtol=1e-12)
    index = np.round(export_vgn.read_grasps(tmp_path / "ds")[["i", "j", "k"]].to_numpy(np.single))
    assert (index >= 0).all() and (index < 40).all() and index[0, 2] == 39


@pytest.fixture(scope="module")
def depth():
    return TcpDepth()


def test_contact_graspnet_scene_contacts_read_back(scenes, depth, tmp_path):
    models, items = scenes
    meshes = {oid: m.mesh for oid, m in models.items()}
    result = export_cgn.write_cgn(tmp_path, items, meshes, depth.T_base_tcp)
    infos = export_cgn.load_scene_contacts(tmp_path)
    written = []
    assert len(infos) == 2 and sorted(p.name for p in (tmp_path / "scene_contacts").iterdir()) == [
        "000004.npz",
        "000011.npz",
    ]
    for (record, _, grasps), info in zip(items, infos, strict=True):
        kept = record.kept
        assert info["obj_paths"].dtype.kind == "U" and len(info["obj_paths"]) == len(kept)
        assert info["obj_transforms"].shape == (len(kept), 4, 4) and info["obj_scales"].tolist() == [
            1.0
        ] * len(kept)
        # the meshes posed as Contact-GraspNet's renderer poses them are ours, where the scene has them
        T_cgn_table = export_cgn.T_cgn_table(record)
        lowest = []
        for inst, posed in zip(kept, export_cgn.scene_meshes(tmp_path, info), strict=True):
            ours = (
                models[inst.object_id].mesh.copy().apply_transform(T_cgn_table @ inst.T_table_obj.as_matrix())
            )
            np.testing.assert_allclose(
                np.sort(posed.vertices, axis=0), np.sort(ours.vertices, axis=0), atol=1e-9
            )
            lowest.append(posed.bounds[0, 2])
        # on Contact-GraspNet's table top: nothing below it, something standing on it
        assert (
            min(lowest) > export_cgn.TABLE_TOP_Z - 0.003 and abs(min(lowest) - export_cgn.TABLE_TOP_Z) < 0.003
        )
        with np.load(
            tmp_path / "scene_contacts" / export_cgn.scene_file(record.scene_id), allow_pickle=False
        ) as f:
            widths, ids, ends = f["grasp_widths"], f["grasp_ids"], f["obj_grasp_idcs"]
        # the positives: the successes whose closing line meets their mesh on both sides
        n = len(ids)
        assert grasps.success[ids].all() and len(set(ids.tolist())) == n
        assert info["grasp_transforms"].shape == (n, 4, 4) and info["scene_contact_points"].shape == (n, 2, 3)
        assert ends[-1] == n and np.all(np.diff(ends) >= 0)
        T_tcp = T_cgn_table @ grasps.T_table_tcp[ids]
        np.testing.assert_allclose(info["grasp_transforms"] @ depth.T_base_tcp(widths), T_tcp, atol=1e-9)
        labels = export_cgn.contact_labels(info)
        np.testing.assert_allclose(labels["directions"][1::2], -T_tcp[:, :3, 0], atol=1e-9)
        np.testing.assert_allclose(labels["approach"][0::2], T_tcp[:, :3, 2], atol=1e-12)
        assert (labels["finger_distance"] <= np.repeat(widths, 2) + 2 * export_cgn.CONTACT_RAY_MARGIN).all()
    written.append(sum(len(i["grasp_transforms"]) for i in infos))
    # synthetic grasps at the centre of mass in any orientation: some miss their object's surface
    n_success = sum(int(g.success.sum()) for _, _, g in items)
    assert 0 < written[0] < n_success
    assert result.positives == written[0] and result.no_contact == n_success - written[0]


def test_contact_points_are_where_the_closing_line_enters_the_mesh():
    """Rays along +/-x from outside the pads: the first points where they enter the mesh, NaN
    (and left out) where the line misses it or starts inside it."""
    box = trimesh.creation.box(extents=(0.04, 0.06, 0.08))
    T = np.repeat(np.eye(4)[None], 4, axis=0)
    T[1, :3, 3] = [0.005, 0.01, 0.0]  # off centre: the same faces
    T[2, :3, 3] = [0.0, 0.05, 0.0]  # beside the box: the line misses it
    width = np.array([0.04, 0.04, 0.04, 0.02])  # the last: pads inside the box, rays start inside
    contacts, ok = export_cgn.surface_contacts(box, T, width)
    assert ok.tolist() == [True, True, False, False] and np.isnan(contacts[2:]).all()
    np.testing.assert_allclose(contacts[0], [[-0.02, 0, 0], [0.02, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(contacts[1], [[-0.02, 0.01, 0], [0.02, 0.01, 0]], atol=1e-12)


def test_contact_graspnet_views_are_its_inference_input(scenes, depth, tmp_path):
    models, items = scenes
    export_cgn.write_cgn(tmp_path, items, {oid: m.mesh for oid, m in models.items()}, depth.T_base_tcp)
    record, views, _ = items[0]
    with np.load(tmp_path / "views" / "000004_01.npz", allow_pickle=True) as data:  # as its loader opens it
        assert {"depth", "K", "segmap", "camera_pose", "camera_pose_opencv"} <= set(data.files)
        depth_img, K, segmap, camera_pose = (
            data["depth"],
            data["K"].reshape(3, 3),
            data["segmap"],
            data["camera_pose_opencv"],  # the optical frame; camera_pose is OpenGL's: y, z negated
        )
        np.testing.assert_array_equal(data["camera_pose"][:3, 1:3], -camera_pose[:3, 1:3])
        np.testing.assert_array_equal(data["camera_pose"][:, [0, 3]], camera_pose[:, [0, 3]])
    view = views[1]
    assert np.array_equal(depth_img, view.depth) and np.array_equal(K, view.depth_K.K)
    assert set(np.unique(segmap)) <= {0, *(i.instance_id + 1 for i in record.kept)}
    v, u = 212, 256
    z = depth_img[v, u]
    p_camera = np.array([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z, 1.0])
    p_table = view.T_table_camera.apply(p_camera[:3])
    np.testing.assert_allclose(
        (camera_pose @ p_camera)[:3], (export_cgn.T_cgn_table(record) @ np.r_[p_table, 1])[:3]
    )


def test_exports_refuse_mismatched_input(scenes, setup, depth, tmp_path):
    models, items = scenes
    (record, views, grasps), (_, _, other) = items
    with pytest.raises(ValueError, match="grasps of scene"):
        export_vgn.write_vgn_raw(tmp_path, setup, [(record, views, other)])
    with pytest.raises(KeyError, match="no mesh"):
        export_cgn.write_cgn(tmp_path, [(record, views, grasps)], {}, depth.T_base_tcp)
    assert not pd.io.common.file_exists(str(tmp_path / "grasps.csv"))
