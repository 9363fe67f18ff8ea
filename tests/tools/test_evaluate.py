"""annotator evaluate: given grasps through the job's pipeline (resume, workers, determinism)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from annotator.cli import main
from annotator.dataset import load_labels, poses_as_matrices
from annotator.schema import REASON_COLUMNS
from annotator.tools.common import ToolError
from annotator.tools.evaluate import expected_width, read_grasps


def _evaluate(grasps: Path, objects: Path, out: Path, *extra: str):
    args = ["evaluate", str(grasps), "--objects", str(objects), "--out", str(out), "--quiet", *extra]
    return CliRunner().invoke(main, args)


@pytest.mark.slow
def test_evaluating_a_dataset_reproduces_it_exactly(labelled, tmp_path: Path) -> None:
    """Every row of a labelled dataset, evaluated again (2 workers, rows shuffled), is the same row."""
    grasps = tmp_path / "grasps.parquet"
    labelled.df.sample(frac=1.0, random_state=3).to_parquet(grasps)  # order must not matter
    result = _evaluate(grasps, labelled.objects_dir, tmp_path / "out", "--workers", "2")
    assert result.exit_code == 0, result.output
    again = load_labels(tmp_path / "out")
    want = labelled.df
    # the label's columns, and why a collision is one (evaluate's rows say it)
    assert list(again.columns) == [*want.columns, *REASON_COLUMNS]
    collided = again["outcome"].to_numpy() == "collision"
    assert (again["collision_stage"].to_numpy()[collided] != "").all()
    assert (again["collided_with"].to_numpy()[~collided] == "").all()
    assert (again["outcome"].to_numpy() == want["outcome"].to_numpy()).all()
    for column in want.columns:
        a, b = again[column].to_numpy(), want[column].to_numpy()
        if a.dtype.kind == "f":
            assert np.array_equal(a, b, equal_nan=True), column
        else:
            assert (a == b).all(), column
    # resume: the same command finds everything done; another input asks for --overwrite
    assert _evaluate(grasps, labelled.objects_dir, tmp_path / "out").exit_code == 0
    other = tmp_path / "other.parquet"
    labelled.df.iloc[:5].to_parquet(other)
    refused = _evaluate(other, labelled.objects_dir, tmp_path / "out")
    assert refused.exit_code == 2 and "--overwrite" in refused.output


def test_proposed_poses_without_width(labelled, tmp_path: Path) -> None:
    """A network's output: poses only (CSV), ids absent, one unknown object; widths measured."""
    rows = labelled.df[labelled.df.object_id == "box"]
    predicted = rows[["object_id", "x", "y", "z", "qx", "qy", "qz", "qw"]].iloc[::-1].copy()
    predicted[["qx", "qy", "qz", "qw"]] *= -1.0000001  # a sign flip and float32-like noise
    ghost = predicted.iloc[:1].assign(object_id="ghost")
    csv = tmp_path / "predicted.csv"
    pd.concat([predicted, ghost]).to_csv(csv, index=False)
    result = _evaluate(csv, labelled.objects_dir, tmp_path / "out", "--workers", "1")
    assert result.exit_code == 1, result.output  # the ghost object failed, the box is labelled
    assert "ghost" in result.output and "no such object" in result.output
    out = load_labels(tmp_path / "out")
    assert list(out.object_id.unique()) == ["box"] and len(out) == len(predicted)
    # numbered in file order: grasp k is row k of the file (the reversed labels)
    want = rows.iloc[::-1].reset_index(drop=True)
    collision = want.outcome.to_numpy() == "collision"
    # simulated grasps hold where they held (the poses are the end-of-close poses, chords measured)
    assert (out.outcome.to_numpy()[collision] == "collision").mean() > 0.8
    assert (out.success.to_numpy()[~collision] == want.success.to_numpy()[~collision]).mean() >= 0.8


def test_expected_width_is_the_chord_the_pads_meet(labelled) -> None:
    import trimesh

    box = trimesh.creation.box(extents=(0.06, 0.04, 0.12))
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, :3, 3] = [0.0, 0.0, 0.2]  # nothing between the pads
    T[2, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # closing along y
    assert np.allclose(expected_width(box, T, 0.11), [0.06, 0.0, 0.04])
    # on real labels, successes' widths are their chords within a millimetre
    ok = labelled.df[labelled.df.success & (labelled.df.object_id == "box")]
    mesh = trimesh.load(labelled.objects_dir / "box.obj", force="mesh")
    assert np.abs(expected_width(mesh, poses_as_matrices(ok), 0.11) - ok.width.to_numpy()).max() < 1e-3


@pytest.mark.parametrize(
    "text, message",
    [
        ("object_id,x,y,z\nbox,0,0,0\n", "missing column(s) ['qx', 'qy', 'qz', 'qw']"),
        ("object_id,x,y,z,qx,qy,qz,qw\nbox,0,0,0,0,0,0,2\n", "norm 2, not 1"),
        ("object_id,x,y,z,qx,qy,qz,qw\nbox,0,0,,0,0,0,1\n", "row 0: z is missing or not a finite number"),
        ("object_id,x,y,z,qx,qy,qz,qw,width\nbox,0,0,0,0,0,0,1,-1\n", "width must be >= 0"),
        ("object_id,grasp_id,x,y,z,qx,qy,qz,qw\nbox,1,0,0,0,0,0,0,1\nbox,1,0,0,0,0,0,0,1\n", "appears twice"),
    ],
)
def test_bad_grasp_files_are_one_line(tmp_path: Path, text: str, message: str) -> None:
    csv = tmp_path / "g.csv"
    csv.write_text(text)
    with pytest.raises(ToolError, match=None) as err:
        read_grasps(csv)
    assert message in err.value.message
    result = _evaluate(csv, tmp_path, tmp_path / "out")
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1


def test_grasp_ids_a_table_names_are_kept_or_the_table_is_refused(labelled, tmp_path: Path) -> None:
    """Part of a user's real trials (ids 10 .. 14) were numbered 0 .. 4 in file order with one line
    among the progress: joined by the user's own ids, every row met another grasp."""
    pose = ["object_id", "x", "y", "z", "qx", "qy", "qz", "qw", "width"]
    box = labelled.df[labelled.df.object_id == "box"].iloc[:5][pose].reset_index(drop=True)
    named = tmp_path / "named.csv"
    box.assign(grasp_id=range(10, 15)).to_csv(named, index=False)
    result = _evaluate(named, labelled.objects_dir, tmp_path / "out")
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert "the grasp_ids of 'box' (10, 11, 12, 13 ...) are not 0..4" in errors[0]
    assert not (tmp_path / "out").exists()
    # ids 0 .. 4 in another order are kept: grasp k is the row the table called k
    order = [3, 0, 4, 1, 2]
    shuffled = tmp_path / "shuffled.csv"
    box.assign(grasp_id=order).to_csv(shuffled, index=False)
    result = _evaluate(shuffled, labelled.objects_dir, tmp_path / "out", "--workers", "1")
    assert result.exit_code == 0, result.output
    out = load_labels(tmp_path / "out").set_index("grasp_id")
    for row, gid in enumerate(order):
        assert np.allclose(
            out.loc[gid, ["cmd_x", "cmd_y", "cmd_z"]].to_numpy(float), box.loc[row, ["x", "y", "z"]]
        )
