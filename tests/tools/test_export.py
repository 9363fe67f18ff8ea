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
from annotator.tools.export import TcpDepth, tcp_poses


@pytest.fixture(scope="module")
def depth() -> TcpDepth:
    return TcpDepth()


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
