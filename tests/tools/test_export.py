"""annotator export: ACRONYM-style HDF5 and GraspGen JSON, read back to our TCP poses to 1e-9."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from annotator.cli import main
from annotator.dataset import poses_as_matrices
from annotator.tools.common import object_mesh
from annotator.tools.export import TcpDepth


@pytest.fixture(scope="module")
def depth() -> TcpDepth:
    return TcpDepth()


def tcp_poses(T_obj_base: np.ndarray, width: np.ndarray, depth: TcpDepth) -> np.ndarray:
    """The inverse of :func:`annotator.tools.export.base_poses`: label poses ``T_obj_tcp`` (n, 4, 4)."""
    return np.asarray(T_obj_base) @ depth.T_base_tcp(width)


def _export(labelled, fmt: str, out: Path) -> None:
    args = ["export", str(labelled.labels_dir), "--format", fmt, "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--objects", str(labelled.objects_dir)])
    assert result.exit_code == 0, result.output


def test_acronym_round_trip(labelled, depth: TcpDepth, tmp_path: Path) -> None:
    _export(labelled, "acronym", tmp_path)
    files = sorted(tmp_path.glob("*.h5"))
    assert len(files) == labelled.df.object_id.nunique()
    for path in files:
        with h5py.File(path, "r") as f:  # read as ACRONYM's own loader does
            T_obj_base = np.array(f["grasps/transforms"])
            held = np.array(f["grasps/qualities/flex/object_in_gripper"])
            width = np.array(f["grasps/width"])
            oid = f["object/id"][()].decode()
            mesh_file, scale = f["object/file"][()].decode(), float(f["object/scale"][()])
            assert f["gripper/type"][()].decode() == "onrobot_rg2"
            mass = float(f["object/mass"][()])
            commanded = np.array(f["grasps/commanded_transforms"])
            cmd_width = np.array(f["grasps/commanded_width"])
        rows = labelled.df[labelled.df.object_id == oid].sort_values("grasp_id")
        assert T_obj_base.shape == (len(rows), 4, 4)
        assert np.abs(tcp_poses(T_obj_base, width, depth) - poses_as_matrices(rows)).max() < 1e-9
        assert np.array_equal(held.astype(bool), rows.success.to_numpy())
        assert mass == pytest.approx(rows.object_mass.iloc[0])
        T_cmd = tcp_poses(commanded, cmd_width, depth)
        assert np.allclose(T_cmd[:, :3, 3], rows[["cmd_x", "cmd_y", "cmd_z"]].to_numpy(), atol=1e-9)
        # the transform is the flange (gripper base): 161..200 mm behind the TCP along its +z
        back = np.einsum("nij,nj->ni", np.linalg.inv(T_obj_base), poses_as_matrices(rows)[:, :, 3])[:, :3]
        assert np.allclose(back[:, :2], 0.0, atol=1e-9) and np.all((back[:, 2] > 0.16) & (back[:, 2] < 0.201))
        # object/file at object/scale is the mesh the poses refer to
        mesh = trimesh.load(tmp_path / mesh_file, force="mesh").apply_scale(scale)
        want = object_mesh(labelled.labels_dir, oid, labelled.objects_dir, rows)
        assert np.allclose(mesh.bounds, want.bounds, atol=1e-7) and len(mesh.faces) == len(want.faces)


def test_graspgen_round_trip(labelled, depth: TcpDepth, tmp_path: Path) -> None:
    _export(labelled, "graspgen", tmp_path)
    files = sorted((tmp_path / "grasps").glob("*.json"))
    assert len(files) == labelled.df.object_id.nunique()
    for path in files:
        data = json.loads(path.read_text())  # as GraspGen's README loads it
        grasps = np.array(data["grasps"]["transforms"])
        mask = np.array(data["grasps"]["object_in_gripper"])
        assert mask.dtype == bool and (tmp_path / data["object"]["file"]).is_file()
        rows = labelled.df[labelled.df.object_id == data["object"]["id"]].sort_values("grasp_id")
        T = tcp_poses(grasps, np.array(data["grasps"]["width"]), depth)
        assert np.abs(T - poses_as_matrices(rows)).max() < 1e-9
        assert np.array_equal(mask, rows.success.to_numpy())
    splits = {n: (tmp_path / "splits" / f"{n}.txt").read_text().split() for n in ("train", "valid")}
    assert len(splits["train"]) + len(splits["valid"]) == 2 and not set(splits["train"]) & set(
        splits["valid"]
    )


def test_export_errors(labelled, tmp_path: Path) -> None:
    bare = tmp_path / "bare"  # label files without the run's manifest: no record of the meshes
    bare.mkdir()
    for path in labelled.labels_dir.glob("*.parquet"):
        shutil.copy(path, bare / path.name)
    bad = CliRunner().invoke(main, ["export", str(bare), "--out", str(tmp_path / "x"), "--format", "acronym"])
    assert bad.exit_code == 2 and "pass --objects" in bad.output
    args = ["export", str(labelled.labels_dir), "--out", str(tmp_path)]
    bad = CliRunner().invoke(main, [*args, "--format", "npz", "--objects", str(labelled.objects_dir)])
    assert bad.exit_code == 2 and "'npz'" in bad.output


def graspgen_gripper_info(folder: Path, name: str) -> dict:
    """What GraspGen's ``get_gripper_info`` takes from ``<name>.yaml`` (grasp_gen/robot.py): the
    offset transform ([xyz], [xyzw]) applied to the collision mesh, ``depth`` as the base-to-TCP
    translation, and the far pair of its canonical control points from ``width`` and ``depth``."""
    import yaml

    config = yaml.safe_load((folder / f"{name}.yaml").read_text())
    translation, quat = config["transform_offset_from_asset_to_graspgen_convention"]
    assert len(translation) == 3 and len(quat) == 4
    offset = trimesh.transformations.quaternion_matrix([quat[-1], *quat[:-1]])
    offset[:3, 3] = translation
    width, depth = config["width"], config["depth"]
    mesh = trimesh.load(folder / config["collision_mesh_fname"], force="mesh").apply_transform(offset)
    return {
        "config": config,
        "offset": offset,
        "collision_mesh": mesh,
        "tcp": trimesh.transformations.translation_matrix([0, 0, np.abs(depth)]),
        "finger_tips": np.array([[width / 2, 0, depth], [-width / 2, 0, depth]]),  # its control points
    }


def test_graspgen_export_writes_the_grippers_description(labelled, depth: TcpDepth, tmp_path: Path) -> None:
    """gripper/<type>.yaml and its collision mesh, read as GraspGen reads them: the numbers are the
    gripper description's (stroke, FK depths), and GraspGen's visibility filter (the tool tip within
    3 cm of the object's points) keeps the successes."""
    _export(labelled, "graspgen", tmp_path)
    name = json.loads(next((tmp_path / "grasps").glob("*.json")).read_text())["gripper"]["name"]
    assert name == "onrobot_rg2"
    info = graspgen_gripper_info(tmp_path / "gripper", name)
    config, d = info["config"], depth.description
    assert config["width"] == pytest.approx(d.stroke_max, abs=1e-6)
    open_, closed = depth.T_base_tcp(np.array([depth.max_width, 0.0]))[:, 2, 3]
    assert config["depth_open"] == open_ and config["depth_closed"] == closed
    assert config["depth"] == pytest.approx((open_ + closed) / 2) and 0.16 < open_ < closed < 0.201
    np.testing.assert_array_equal(info["offset"], np.eye(4))
    assert config["symmetric_antipodal"] is True
    # the collision mesh: the open gripper in its base frame, fingers outside the open pads
    lo, hi = info["collision_mesh"].bounds
    # GraspGen's control points at the tool tip: the TCP the gripper has at some opening
    assert (open_ <= info["finger_tips"][:, 2]).all() and (info["finger_tips"][:, 2] <= closed).all()
    assert lo[0] < -config["width"] / 2 and hi[0] > config["width"] / 2 and lo[2] > -0.01 and hi[2] > open_
    # GraspGen's filter_grasps_by_point_cloud_visibility on the object's surface points
    passed = total = 0
    for path in sorted((tmp_path / "grasps").glob("*.json")):
        data = json.loads(path.read_text())
        grasps = np.array(data["grasps"]["transforms"])[np.array(data["grasps"]["object_in_gripper"])]
        mesh = trimesh.load(tmp_path / data["object"]["file"], force="mesh")
        points = trimesh.sample.sample_surface(mesh, 2000, seed=0)[0]
        tips = np.array([g @ info["tcp"] for g in grasps])[:, :3, 3]
        l1 = np.abs(tips[:, None, :] - points[None]).sum(axis=2)
        passed += int((np.sort(l1, axis=1)[:, :5].mean(axis=1) < 0.03).sum())
        total += len(grasps)
    assert total > 0 and passed >= 0.9 * total


@pytest.mark.parametrize("name", ["rg2", "panda", "robotiq_2f85"])
def test_graspgen_description_numbers_come_from_the_gripper_description(name: str) -> None:
    from annotator.grippers import load_gripper
    from annotator.tools.export_graspgen import graspgen_gripper

    d = load_gripper(name)
    depth = TcpDepth(name)
    gg = graspgen_gripper(depth)
    # the model's widest opening: the description's stroke, which its FK reaches (the 2F-85's 86 mm)
    assert gg.name == d.export_type and gg.width == depth.max_width
    assert d.stroke_max - 1e-4 <= gg.width < d.stroke_max + 0.002
    table = depth.T_base_tcp(np.array([gg.width, 0.0]))[:, 2, 3]
    assert (gg.depth_open, gg.depth_closed) == tuple(table) and gg.depth == pytest.approx(table.mean())
    if name == "panda":  # the fingers slide: the TCP stays 103.65 mm out of the mounting face
        assert gg.depth == pytest.approx(0.10365, abs=1e-8)
