"""evaluate --frame base: grasps given as poses of the gripper's base link (ACRONYM's and GraspGen's
convention) are the same grasps as their TCP poses."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import trimesh
from click.testing import CliRunner

from annotator.cli import main
from annotator.dataset import pose_columns
from annotator.tools.evaluate import read_grasps, tcp_from_base
from annotator.tools.export import TcpDepth


def test_base_poses_without_widths_find_the_chord_and_the_tcp() -> None:
    # the RG2's TCP moves 38.6 mm along the approach over its stroke: the chord at the base pose is
    # found by measuring at the TCP of the opening found so far
    box = trimesh.creation.box(extents=(0.06, 0.04, 0.12))
    depth = TcpDepth("rg2")
    T_obj_tcp = np.eye(4)
    T_obj_tcp[:3, :3] = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]  # from above, across 40 mm
    T_obj_tcp[2, 3] = 0.03
    T_obj_base = T_obj_tcp @ np.linalg.inv(depth.T_base_tcp(np.array([0.04]))[0])
    T, width = tcp_from_base(T_obj_base[None], np.array([np.nan]), depth, box)
    assert width[0] == pytest.approx(0.04, abs=1e-9)
    np.testing.assert_allclose(T[0], T_obj_tcp, atol=1e-9)
    # given widths are used as they are
    T2, width2 = tcp_from_base(T_obj_base[None], np.array([0.05]), depth)
    assert width2[0] == 0.05 and not np.allclose(T2[0], T_obj_tcp)


def test_a_label_table_is_never_read_as_base_poses(labelled) -> None:
    from annotator.tools.common import ToolError

    with pytest.raises(ToolError, match="is a label table: its poses are TCP poses"):
        read_grasps(labelled.labels_dir, "base")


@pytest.mark.slow
def test_an_acronym_export_read_back_as_base_poses_evaluates_as_the_tcp_table(labelled, tmp_path) -> None:
    import h5py

    exported = tmp_path / "acronym"
    args = ["export", str(labelled.labels_dir), "--format", "acronym", "--out", str(exported)]
    result = CliRunner().invoke(main, [*args, "--objects", str(labelled.objects_dir)])
    assert result.exit_code == 0, result.output
    base_rows, tcp_rows = [], []
    for oid, rows in labelled.df.groupby("object_id"):
        rows = rows.sort_values("grasp_id")
        (h5,) = exported.glob(f"{oid}-*.h5")
        with h5py.File(h5) as f:
            T_obj_base = f["grasps/commanded_transforms"][()]
            width = f["grasps/commanded_width"][()]
        base = pose_columns(T_obj_base).assign(
            object_id=oid, grasp_id=rows["grasp_id"].to_numpy(), width=width
        )
        base_rows.append(base)
        cmd = rows[
            ["cmd_x", "cmd_y", "cmd_z", "cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw", "cmd_width"]
        ].to_numpy()
        tcp = pd.DataFrame(cmd, columns=["x", "y", "z", "qx", "qy", "qz", "qw", "width"])
        tcp_rows.append(tcp.assign(object_id=oid, grasp_id=rows["grasp_id"].to_numpy()))
    outcomes = {}
    for name, table, frame in (("base", base_rows, "base"), ("tcp", tcp_rows, "tcp")):
        path = tmp_path / f"{name}.csv"
        pd.concat(table).to_csv(path, index=False, float_format="%.17g")
        out = tmp_path / f"ev_{name}"
        cmd = ["evaluate", str(path), "--objects", str(labelled.objects_dir), "--out", str(out)]
        result = CliRunner().invoke(main, [*cmd, "--frame", frame, "--workers", "2", "-q"])
        assert result.exit_code == 0, result.output
        ev = pd.read_parquet(out).sort_values(["object_id", "grasp_id"], ignore_index=True)
        outcomes[name] = ev
    base, tcp = outcomes["base"], outcomes["tcp"]
    assert base["outcome"].tolist() == tcp["outcome"].tolist()
    np.testing.assert_allclose(base[["cmd_x", "cmd_y", "cmd_z"]], tcp[["cmd_x", "cmd_y", "cmd_z"]], atol=1e-9)
    np.testing.assert_allclose(base["cmd_width"], tcp["cmd_width"], atol=1e-12)
    # and both are the labels' own outcomes (the commanded grasps replayed)
    labels = labelled.df.sort_values(["object_id", "grasp_id"], ignore_index=True)
    agree = (base["outcome"].to_numpy() == labels["outcome"].to_numpy()).mean()
    assert agree >= 0.9, agree
