"""Scene exports of a small real run read back as the peers' own code reads them: VGN's ``Dataset``
and ``construct_dataset.py``, GIGA's ``get_scene_from_mesh_pose_list``, Contact-GraspNet's
``load_scene_contacts`` and ``center_pc_convert_cam``. Their code needs Open3D, torch or
TensorFlow; each reader here is the few lines of theirs that touch the files, written from their
published code (the sources in docs/scenes.md), never imported."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh
from helpers import SCENE_RUN_N, run_annotator

from annotator.tools import export_cgn
from annotator.tools.common import object_mesh
from annotator.tools.scene_labels import SceneLabels, open_scene_labels

N = SCENE_RUN_N


# --- VGN --------------------------------------------------------------------------------------------


def vgn_dataset_items(root: Path) -> list[tuple[str, np.ndarray]]:
    """Every row of a VGN dataset as its ``Dataset.__getitem__`` takes it: the scene id and the
    voxel index ``np.round(df.loc[i, "i":"k"].to_numpy(np.single))``; the grid read as its
    ``read_voxel_grid`` reads it (checked to exist)."""
    df = pd.read_csv(root / "grasps.csv")
    out = []
    for i in range(len(df.index)):
        scene_id = df.loc[i, "scene_id"]
        pos = df.loc[i, "i":"k"].to_numpy(np.single)
        grid = np.load(root / "scenes" / (scene_id + ".npz"))["grid"]
        assert grid.shape == (1, 40, 40, 40)
        out.append((scene_id, np.round(pos).astype(np.int64)))
    return out


def palm_voxels(scenes: SceneLabels, scene_id: int, T_table_tcp: np.ndarray) -> np.ndarray:
    """(n, 3) int: the voxel VGN's Dataset reads for each grasp of the scene: its origin (the
    palm, finger_depth = 0.05 m behind the gripper's fingertips along the approach, from the
    labels' TCPs ``T_table_tcp`` (n, 4, 4) and widths) in the task frame, in voxels, float32, rounded."""
    from annotator.tools.export_vgn import fingertip_reach

    rows = scenes.rows(scene_id)
    back = fingertip_reach(scenes.gripper)(rows["width"].to_numpy()) - 0.05
    palm = T_table_tcp[:, :3, 3] + back[:, None] * T_table_tcp[:, :3, 2]
    T_task_table = scenes.records[scene_id].workspace.T_table_task.inverse().as_matrix()
    in_task = palm @ T_task_table[:3, :3].T + T_task_table[:3, 3]
    return np.round((in_task / (0.3 / 40)).astype(np.float32)).astype(np.int64)


def test_vgn_export_leaves_out_grasps_outside_the_workspace(convex_scene_run, tmp_path, monkeypatch):
    """A grasp placed 2 cm outside the workspace cube is left out of both layouts and reported
    (the command's output and _export.json), with every grasp whose origin (VGN's palm) lies
    outside the grid; every row VGN's Dataset reads has its voxel in the grid."""
    scenes = open_scene_labels(convex_scene_run, "test")
    record = scenes.records[0]
    moved = 7  # grasp id moved outside: below the cube's lower x side
    real_grasps = SceneLabels.grasps

    def grasps(self, scene_id):
        g = real_grasps(self, scene_id)
        if scene_id == 0:
            g.T_table_tcp[moved, 0, 3] = record.workspace.lower[0] - 0.02
        return g

    monkeypatch.setattr(SceneLabels, "grasps", grasps)
    inside = {
        s: np.all((palm_voxels(scenes, s, scenes.grasps(s).T_table_tcp) >= 0), axis=1)
        & np.all(palm_voxels(scenes, s, scenes.grasps(s).T_table_tcp) < 40, axis=1)
        for s in (0, 1)
    }
    assert not inside[0][moved]
    outside = sum(int((~m).sum()) for m in inside.values())
    out = tmp_path / "vgn"
    result = run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    assert f"left out {outside} grasps: outside the 0.3 m workspace cube" in result.output
    assert "wrote" in result.output and f"({2 * N - outside} grasps)" in result.output
    recorded = json.loads((out / "_export.json").read_text())["left_out"]
    assert len(recorded) == 1 and recorded[0]["grasps"] == outside and "workspace" in recorded[0]["reason"]
    raw = pd.read_csv(out / "grasps.csv")
    assert len(raw) == 2 * N - outside
    # the raw layout without the grasps outside: its other rows are the labels' own, in order
    rows0 = scenes.rows(0)
    kept_widths = rows0["width"].to_numpy()[inside[0]]
    np.testing.assert_array_equal(raw.loc[raw.scene_id == "scene_000000", "width"].to_numpy(), kept_widths)
    assert (raw[["x", "y", "z"]].to_numpy() >= -0.5 * 0.3 / 40).all()
    items = vgn_dataset_items(out / "dataset")
    assert len(items) == 2 * N - outside
    index = np.array([i for _, i in items])
    assert (index >= 0).all() and (index < 40).all()
    # construct_dataset.py's grasps from the raw layout index the same voxels
    voxel = 0.3 / 40
    np.testing.assert_array_equal(
        np.round((raw[["x", "y", "z"]].to_numpy() / voxel).astype(np.single)).astype(np.int64), index
    )


def test_vgn_dataset_csv_is_construct_datasets_with_round_trip_parsing(convex_scene_run, tmp_path):
    """construct_dataset.py reads the raw CSV (read_df), divides x, y, z, width by the voxel and
    writes it with DataFrame.to_csv: with every number parsed exactly (round trip: Python's
    float(), what pandas' float_precision="round_trip" does) that is our dataset CSV byte for byte."""
    out = tmp_path / "vgn"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    voxel = 0.3 / 40
    columns = ["qx", "qy", "qz", "qw", "x", "y", "z", "width"]
    df = pd.read_csv(out / "grasps.csv", converters={c: float for c in columns})
    for c in ("x", "y", "z", "width"):
        df[c] /= voxel
    df = df.rename(columns={"x": "i", "y": "j", "z": "k"})
    df.to_csv(tmp_path / "constructed.csv", index=False)
    assert (tmp_path / "constructed.csv").read_bytes() == (out / "dataset" / "grasps.csv").read_bytes()
    # every value written is the shortest repr of its float64: it reads back to the same float
    text = (out / "grasps.csv").read_text().splitlines()[1:]
    for line in text[:20]:
        for value in line.split(",")[1:9]:
            assert repr(float(value)) == value


def vgn_rows(root: Path) -> list[dict]:
    """Every row of a VGN raw layout as VGN's ``read_grasp`` takes it (the quaternion by the
    column slice qx..qw, the position x..z) and its ``Dataset`` would label it: the grasp frame
    (4, 4) in the task frame, its width and its integer label."""
    from annotator.geometry import quat_to_matrix

    df = pd.read_csv(root / "grasps.csv")
    out = []
    for i in range(len(df.index)):
        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(df.loc[i, "qx":"qw"].to_numpy(np.double))
        T[:3, 3] = df.loc[i, "x":"z"].to_numpy(np.double)
        out.append(
            {
                "scene_id": df.loc[i, "scene_id"],
                "T": T,
                "width": df.loc[i, "width"],
                "label": df.loc[i, "label"],
            }
        )
    return out


def test_vgn_grasp_origin_is_the_palm_finger_depth_behind_the_fingertips(convex_scene_run, tmp_path):
    """VGN's grasp frame has its origin at the palm, its fingertips finger_depth (setup.json) ahead
    along its z, closing along its y. Read back as VGN reads a row: the origin moved finger_depth
    along z is where the labelling gripper's fingertips end at the label's width (its collision
    model), on our TCP's approach line; VGN's y is our closing x."""
    from annotator.geometry import quat_to_matrix
    from annotator.tools.export_vgn import fingertip_reach, scene_name, tcp_in_table

    out = tmp_path / "vgn"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    scenes = open_scene_labels(convex_scene_run, "test")
    finger_depth = json.loads((out / "setup.json").read_text())["finger_depth"]
    assert finger_depth == pytest.approx(0.05)
    reach = fingertip_reach(scenes.gripper)
    rows = vgn_rows(out)
    offsets = []
    for scene_id in (0, 1):
        record = scenes.records[scene_id]
        index = palm_voxels(scenes, scene_id, scenes.grasps(scene_id).T_table_tcp)
        labels = scenes.rows(scene_id)[np.all((index >= 0) & (index < 40), axis=1)].reset_index(drop=True)
        mine = [r for r in rows if r["scene_id"] == scene_name(scene_id)]
        assert len(mine) == len(labels) > N // 2
        T_table_task = record.workspace.T_table_task.as_matrix()
        for k, row in enumerate(mine):
            T_table_vgn = T_table_task @ row["T"]
            tcp = labels.loc[k, [f"table_tcp_{c}" for c in "xyz"]].to_numpy(float)
            q = labels.loc[k, [f"table_tcp_q{c}" for c in "xyzw"]].to_numpy(float)
            R = quat_to_matrix(q)
            tips = T_table_vgn[:3, 3] + finger_depth * T_table_vgn[:3, 2]
            want = tcp + reach(np.array([row["width"]]))[0] * R[:, 2]
            np.testing.assert_allclose(tips, want, atol=1e-9)
            np.testing.assert_allclose(T_table_vgn[:3, 1], R[:, 0], atol=1e-9)  # VGN's y: our closing x
            np.testing.assert_allclose(T_table_vgn[:3, 2], R[:, 2], atol=1e-9)  # the same approach
            offset = reach(np.array([row["width"]]))[0] - finger_depth
            offsets.append(offset)
            back = tcp_in_table(row["T"], record, offset)
            np.testing.assert_allclose(back[:3, 3], tcp, atol=1e-12)
    # the RG2's fingertips end a few mm beyond its TCP: VGN's origin lies 4 to 5 cm behind it
    assert -0.05 < min(offsets) and max(offsets) < -0.035


def vgn_detectable(grid: np.ndarray) -> np.ndarray:
    """(40, 40, 40) bool: the voxels VGN's detection may pick a grasp at, as its documented rule
    reads: voxels whose TSDF value is above 0.5 (outside the surface), grown by two voxels into
    voxels that are not inside (value in (0.001, 0.5)); the quality elsewhere is set to zero."""
    from scipy import ndimage

    tsdf = grid.reshape(40, 40, 40)
    inside = (tsdf > 1e-3) & (tsdf < 0.5)
    return ndimage.binary_dilation(tsdf > 0.5, iterations=2, mask=~inside)


def test_vgn_labels_lie_in_the_voxels_vgn_detects_from(convex_scene_run, tmp_path):
    """VGN trains the quality of the voxel at a grasp's origin, and detects only in voxels
    outside the observed surface or near it. Read as its Dataset reads the dataset layout (index
    = round of the float32 position in voxels, the scene's grid): the held grasps' voxels lie
    where VGN's detection looks; our TCP's own voxels (between the pads, inside what they hold)
    mostly do not."""
    from annotator.tools.export_vgn import VgnSetup, task_poses

    out = tmp_path / "vgn"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    df = pd.read_csv(out / "dataset" / "grasps.csv")
    held = df[df["label"] == 1].reset_index(drop=True)
    assert len(held) >= 5
    valid = []
    for i in range(len(held)):
        grid = np.load(out / "dataset" / "scenes" / (held.loc[i, "scene_id"] + ".npz"))["grid"]
        index = np.round(held.loc[i, "i":"k"].to_numpy(np.single)).astype(np.int64)
        valid.append(bool(vgn_detectable(grid)[tuple(index)]))
    scenes = open_scene_labels(convex_scene_run, "test")
    at_tcp = []
    setup = VgnSetup(0.3, scenes.views(0)[0].depth_K, 0.11)  # no fingertip: the TCP itself
    for scene_id in (0, 1):
        grasps = scenes.grasps(scene_id)
        grasps = grasps.take(np.asarray(grasps.success, dtype=bool))
        grid = np.load(out / "dataset" / "scenes" / f"scene_{scene_id:06d}.npz")["grid"]
        detectable = vgn_detectable(grid)
        for p in task_poses(scenes.records[scene_id], grasps, setup.offset(grasps.width))[:, :3, 3]:
            index = np.round((p / (0.3 / 40)).astype(np.float32)).astype(np.int64)
            at_tcp.append(bool(np.all((index >= 0) & (index < 40)) and detectable[tuple(index)]))
    assert np.mean(valid) >= 0.75, f"{np.mean(valid):.2f} of the held grasps' voxels are detectable"
    assert np.mean(at_tcp) < np.mean(valid) - 0.3, (
        f"at the TCP {np.mean(at_tcp):.2f}, at the palm {np.mean(valid):.2f}"
    )


def test_vgn_clean_drops_grasps_near_the_sides_and_balances():
    """VGN's data notebook: positions within 2 cm of the cube's sides go, then negatives at random
    until as many as the positives remain; the same seed, the same choice."""
    from annotator.tools.export_vgn import vgn_clean

    rng = np.random.default_rng(3)
    positions = rng.uniform(0.0, 0.3, size=(400, 3))
    labels = rng.uniform(size=400) < 0.2
    side, dropped = vgn_clean(positions, labels, 0.3)
    near = np.any((positions < 0.02) | (positions > 0.28), axis=1)
    np.testing.assert_array_equal(side, near)
    kept = ~side & ~dropped
    assert not (dropped & labels).any() and not (dropped & side).any()
    assert labels[kept].sum() == (~labels[kept]).sum() == labels[~near].sum()
    again = vgn_clean(positions, labels, 0.3)[1]
    np.testing.assert_array_equal(again, dropped)
    assert not vgn_clean(positions, labels, 0.3, balance=False)[1].any()
    # more positives than negatives: nothing to drop
    assert not vgn_clean(positions, rng.uniform(size=400) < 0.8, 0.3)[1].any()


def test_vgn_balance_reads_back_as_vgn_trains_on_it(convex_scene_run, tmp_path, monkeypatch):
    """``--balance``: both layouts hold the same rows, none within 2 cm of the cube's sides, as
    many negatives as positives, every positive kept; read as VGN's Dataset reads them (labels
    cast to int, widths and positions in voxels as float32, the grid float32 (1, 40, 40, 40)); the
    counts of what was left out in _export.json; a second export writes the same bytes. (Two of
    every three held grasps are read as failures here, so that the negatives outnumber the
    positives as in a pile's labels.)"""
    real_grasps = SceneLabels.grasps

    def grasps(self, scene_id):
        g = real_grasps(self, scene_id)
        keep = np.zeros(len(g.success), dtype=bool)
        keep[np.flatnonzero(g.success)[::3]] = True
        return dataclasses.replace(g, success=keep)

    monkeypatch.setattr(SceneLabels, "grasps", grasps)
    plain = tmp_path / "plain"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", plain)
    before = pd.read_csv(plain / "grasps.csv")
    near = np.any((before[["x", "y", "z"]] < 0.02) | (before[["x", "y", "z"]] > 0.28), axis=1).to_numpy()
    positives = before[(before["label"] == 1).to_numpy() & ~near]
    assert ((before["label"] == 0).to_numpy() & ~near).sum() > len(positives) > 0
    out = tmp_path / "vgn"
    result = run_annotator("export", convex_scene_run, "--format", "vgn", "--balance", "--out", out)
    assert "VGN's balance" in result.output
    raw = pd.read_csv(out / "grasps.csv")
    pd.testing.assert_frame_equal(
        raw[raw["label"] == 1].reset_index(drop=True), positives.reset_index(drop=True)
    )
    dataset = pd.read_csv(out / "dataset" / "grasps.csv")
    assert len(raw) == len(dataset) > 0
    voxel = 0.3 / 40
    labels = dataset["label"].to_numpy().astype(np.int64)  # Dataset: .astype(np.long)
    assert set(np.unique(labels)) <= {0, 1} and labels.sum() == (labels == 0).sum()
    position = raw[["x", "y", "z"]].to_numpy()
    assert (position >= 0.02).all() and (position <= 0.28).all()
    np.testing.assert_allclose(dataset[["i", "j", "k"]].to_numpy() * voxel, position, rtol=1e-12)
    width = dataset["width"].to_numpy(np.single)  # Dataset: .astype(np.single), in voxels
    np.testing.assert_allclose(width * voxel, raw["width"].to_numpy(), rtol=1e-6)
    for scene_id, index in vgn_dataset_items(out / "dataset"):
        assert scene_id.startswith("scene_") and ((index >= 0) & (index < 40)).all()
    grid = np.load(out / "dataset" / "scenes" / (dataset.loc[0, "scene_id"] + ".npz"))["grid"]
    assert grid.dtype == np.float32 and grid.shape == (1, 40, 40, 40)
    recorded = {x["reason"]: x["grasps"] for x in json.loads((out / "_export.json").read_text())["left_out"]}
    everything = sum(len(open_scene_labels(convex_scene_run, "test").rows(s)) for s in (0, 1))
    assert sum(recorded.values()) + len(raw) == everything
    assert any("balance" in reason for reason in recorded)
    assert recorded[next(r for r in recorded if "balance" in r)] > 0
    again = tmp_path / "again"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--balance", "--out", again)
    assert (again / "grasps.csv").read_bytes() == (out / "grasps.csv").read_bytes()


def test_balance_is_refused_for_formats_that_are_not_vgn(convex_scene_run, tmp_path):
    result = run_annotator(
        "export",
        convex_scene_run,
        "--format",
        "contact_graspnet",
        "--balance",
        "--out",
        tmp_path / "c",
        check=2,
    )
    assert "--balance" in result.output and "vgn" in result.output


# --- GIGA -------------------------------------------------------------------------------------------


def giga_scene(mesh_pose_list: np.ndarray) -> list[trimesh.Trimesh]:
    """GIGA's get_scene_from_mesh_pose_list (return_list): load, scale, pose each row's mesh."""
    meshes = []
    for mesh_path, scale, pose in mesh_pose_list:
        mesh = trimesh.load(mesh_path)
        mesh.apply_scale(scale)
        mesh.apply_transform(pose)
        meshes.append(mesh)
    return meshes


def test_giga_mesh_pose_list_rebuilds_each_scene(convex_scene_run, tmp_path, monkeypatch):
    out = tmp_path / "vgn"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    monkeypatch.chdir(tmp_path)  # GIGA loads the mesh paths as given, from wherever it runs
    scenes = open_scene_labels(convex_scene_run, "test")
    raw = pd.read_csv(out / "grasps.csv")
    for scene_id in sorted(raw["scene_id"].unique()):
        # GIGA's dataset_voxel: raw_root / "mesh_pose_list" / (scene_id + ".npz"), key "pc"
        mesh_pose_list = np.load(out / "mesh_pose_list" / (scene_id + ".npz"), allow_pickle=True)["pc"]
        record = scenes.records[int(scene_id.split("_")[1])]
        meshes = giga_scene(mesh_pose_list)
        assert len(meshes) == len(record.kept) > 0
        T_task_table = record.workspace.T_table_task.inverse().as_matrix()
        for mesh, inst in zip(meshes, record.kept, strict=True):
            want = object_mesh(convex_scene_run, inst.object_id).apply_transform(
                T_task_table @ inst.T_table_obj.as_matrix()
            )
            np.testing.assert_allclose(mesh.bounds, want.bounds, atol=1e-8)
            assert len(mesh.faces) == len(want.faces)
        # in VGN's task frame: standing on the table s/6 = 5 cm above the cube's floor, inside the cube
        scene = trimesh.util.concatenate(meshes)
        assert abs(scene.bounds[0, 2] - 0.05) < 0.003
        assert (scene.bounds[0, :2] > -0.02).all() and (scene.bounds[1, :2] < 0.32).all()


# --- Contact-GraspNet ---------------------------------------------------------------------------------


def distance_to_mesh(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(n,) m: each point's distance to the nearest triangle (trimesh's closest point on a triangle)."""
    tri = np.asarray(mesh.triangles)
    pairs = np.repeat(points, len(tri), axis=0), np.tile(tri, (len(points), 1, 1))
    closest = trimesh.triangles.closest_point(pairs[1], pairs[0])
    return np.linalg.norm(closest - pairs[0], axis=1).reshape(len(points), len(tri)).min(axis=1)


def test_contact_graspnet_contacts_lie_on_the_mesh_where_the_pads_close(convex_scene_run, tmp_path):
    out = tmp_path / "cgn"
    result = run_annotator("export", convex_scene_run, "--format", "contact_graspnet", "--out", out)
    scenes = open_scene_labels(convex_scene_run, "test")
    left_out = json.loads((out / "_export.json").read_text())["left_out"]
    no_contact = left_out[1]["grasps"]
    assert "failures" in left_out[0]["reason"] and "closing line" in left_out[1]["reason"]
    infos = export_cgn.load_scene_contacts(out)  # load_scene_contacts: the five keys, no pickle
    n_positive = 0
    for scene_id, info in enumerate(infos):
        record, rows = scenes.records[scene_id], scenes.rows(scene_id)
        with np.load(out / "scene_contacts" / export_cgn.scene_file(scene_id)) as f:
            ends, ids, widths = f["obj_grasp_idcs"], f["grasp_ids"], f["grasp_widths"]
        meshes = export_cgn.scene_meshes(out, info)  # posed as its renderer poses them
        T_tcp = export_cgn.T_cgn_table(record) @ scenes.grasps(scene_id).T_table_tcp[ids]
        contacts = info["scene_contact_points"]
        assert len(contacts) == len(ids) > 0 and rows.loc[ids, "success"].all()
        starts = np.r_[0, ends[:-1]]
        for mesh, a, b in zip(meshes, starts, ends, strict=True):
            if b > a:
                assert distance_to_mesh(mesh, contacts[a:b].reshape(-1, 3)).max() < 1e-4
        # on the pads' closing line, within the pads' reach, finger 1 on the -x side
        offset = contacts - T_tcp[:, None, :3, 3]
        x = T_tcp[:, :3, 0]
        along = np.einsum("nck,nk->nc", offset, x)
        np.testing.assert_allclose(offset, along[..., None] * x[:, None], atol=1e-9)
        reach = widths / 2 + export_cgn.CONTACT_RAY_MARGIN
        assert (along[:, 0] >= -reach - 1e-9).all() and (along[:, 1] <= reach + 1e-9).all()
        assert (along[:, 0] < along[:, 1]).all()
        # what its load_contact_grasps derives: the distance between the contacts, about the width
        labels = export_cgn.contact_labels(info)
        assert (labels["finger_distance"][::2] <= widths + 2 * export_cgn.CONTACT_RAY_MARGIN).all()
        n_positive += len(ids)
    n_success = int(scenes.labels["success"].sum())
    assert n_positive + no_contact == n_success
    assert no_contact <= 0.1 * n_success  # almost every success has both contacts
    assert "wrote" in result.output


def test_contact_graspnet_camera_pose_is_opengl_as_its_training_converts_it(convex_scene_run, tmp_path):
    """``camera_pose`` in views/ goes through Contact-GraspNet's center_pc_convert_cam (negate the
    y and z columns, invert) to the transform from its scene frame into the camera's OpenCV frame:
    a depth pixel's point in the scene projects back onto that pixel with ``K``."""
    out = tmp_path / "cgn"
    run_annotator("export", convex_scene_run, "--format", "contact_graspnet", "--out", out)
    scenes = open_scene_labels(convex_scene_run, "test")
    record, view = scenes.records[1], scenes.views(1)[0]
    with np.load(out / "views" / "000001_00.npz", allow_pickle=True) as data:
        depth, K, camera_pose = data["depth"], data["K"].reshape(3, 3), data["camera_pose"]
        opencv = data["camera_pose_opencv"]
    cam = camera_pose.copy()
    cam[:3, 1] = -cam[:3, 1]
    cam[:3, 2] = -cam[:3, 2]
    T_cam_scene = np.linalg.inv(cam)
    np.testing.assert_allclose(np.linalg.inv(T_cam_scene), opencv, atol=1e-12)
    v, u = np.argwhere(depth > 0)[len(np.argwhere(depth > 0)) // 2]
    z = depth[v, u]
    p_camera = np.array([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    p_scene = export_cgn.T_cgn_table(record) @ np.r_[view.T_table_camera.apply(p_camera), 1.0]
    x, y, zc = (T_cam_scene @ p_scene)[:3]
    np.testing.assert_allclose([x / zc * K[0, 0] + K[0, 2], y / zc * K[1, 1] + K[1, 2]], [u, v], atol=1e-6)
    # OpenGL's camera looks along its -z: the scene point lies ahead of it
    assert (np.linalg.inv(camera_pose) @ p_scene)[2] < 0


# --- refusals -----------------------------------------------------------------------------------------


def test_scene_exports_refuse_a_run_with_a_failed_scene_without_partial(convex_scene_run, tmp_path):
    """A run whose manifest records a failed scene (as annotate writes one: objects_failed) is
    refused in one line, exit 2; --partial exports the scenes that were labelled."""
    run = tmp_path / "labels"
    shutil.copytree(convex_scene_run, run)
    manifest = json.loads((run / "_manifest.json").read_text())
    manifest["objects_failed"]["scene_000002"] = "the scene kept no object: every object left the workspace"
    (run / "_manifest.json").write_text(json.dumps(manifest))
    for fmt in ("vgn", "contact_graspnet"):
        result = run_annotator("export", run, "--format", fmt, "--out", tmp_path / fmt, check=2)
        assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
        assert "1 of its scenes failed (scene_000002" in result.output and "--partial" in result.output
        assert not (tmp_path / fmt / "_export.json").exists()
        result = run_annotator("export", run, "--format", fmt, "--out", tmp_path / fmt, "--partial")
        assert (tmp_path / fmt / "_export.json").is_file()


@pytest.mark.parametrize(
    ("fmt", "name"),
    [
        ("vgn", "mesh_pose_list/scene_000001.npz"),
        ("vgn", "setup.json"),
        ("vgn", "dataset/grasps.csv"),
        ("contact_graspnet", "views/000000_00.npz"),
    ],
)
def test_scene_exports_never_replace_a_file_they_did_not_write(convex_scene_run, tmp_path, fmt, name):
    out = tmp_path / "out"
    (out / name).parent.mkdir(parents=True)
    (out / name).write_text("mine")
    for extra in ((), ("--overwrite",)):
        result = run_annotator("export", convex_scene_run, "--format", fmt, "--out", out, *extra, check=2)
        assert len(result.output.strip().splitlines()) == 1
        assert "was not written by an export" in result.output
        assert (out / name).read_text() == "mine" and not (out / "_export.json").exists()
