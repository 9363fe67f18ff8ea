"""The label reader: schema, validation, loading, poses, splits (the store is tests/test_store.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import synthetic_labels

import annotator.dataset as ds
import annotator.store.files as files
import annotator.store.names as names
from annotator.geometry import Transform


def test_outcomes_and_enum() -> None:
    assert ds.OUTCOMES == (
        "success",
        "collision",
        "no_contact",
        "slipped_lift",
        "slipped_shake",
        "error",
        "slipped_motion",
    )
    assert ds.Outcome.SLIPPED_LIFT.label == "slipped_lift"
    assert ds.Outcome.from_label("no_contact") is ds.Outcome.NO_CONTACT
    with pytest.raises(ValueError, match="unknown outcome"):
        ds.Outcome.from_label("dropped")
    assert list(ds.COLUMNS)[:2] == ["object_id", "grasp_id"] and len(ds.COLUMNS) == 16


def _write(folder: Path, df: pd.DataFrame) -> Path:
    """One object's labels as the store writes them (marked, atomic)."""
    oid = str(df["object_id"].iloc[0])
    name = names.object_filename(oid)
    files.write_labels(folder, df, 0, len(df), name, "run-key", "cd" * 32)
    return folder / name


def test_round_trip_read_parquet_directory(tmp_path: Path) -> None:
    frames = {oid: synthetic_labels(oid, n=12) for oid in ["ycb/mug", "ycb/bowl", "cube"]}
    for df in frames.values():
        _write(tmp_path, df)
    (tmp_path / "_manifest.json").write_text("{}")
    (tmp_path / ".leftover.parquet.x.tmp").write_bytes(b"half a file")  # a crashed writer's debris

    got = pd.read_parquet(tmp_path)  # the user's one-liner, manifest and debris present
    assert len(got) == 36
    assert list(got.columns[: len(ds.COLUMNS)]) == list(ds.COLUMNS)
    got = got.sort_values(["object_id", "grasp_id"]).reset_index(drop=True)
    want = pd.concat(frames.values()).sort_values(["object_id", "grasp_id"]).reset_index(drop=True)
    for col in ds.COLUMNS:
        if ds.COLUMNS[col] == "string":
            assert got[col].tolist() == want[col].tolist()
        else:
            assert got[col].dtype == np.dtype(ds.COLUMNS[col]), col
            np.testing.assert_array_equal(got[col].to_numpy(), want[col].to_numpy())
    np.testing.assert_array_equal(got["antipodal"].to_numpy(), want["antipodal"].to_numpy())

    loaded = ds.load_labels(tmp_path)
    assert list(loaded["object_id"].unique()) == sorted(frames)
    assert loaded["object_id"].is_monotonic_increasing
    assert (loaded.groupby("object_id")["grasp_id"].apply(list) == [list(range(12))] * 3).all()
    one = ds.load_labels(tmp_path / names.object_filename("cube"))
    assert set(one["object_id"]) == {"cube"} and len(one) == 12


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda df: df.drop(columns=["qw", "seed"]), r"missing required column\(s\) \['qw', 'seed'\]"),
        (lambda df: df.assign(grasp_id=df["grasp_id"].astype(float)), "grasp_id: float64 \\(want int64\\)"),
        (lambda df: df.assign(success=df["success"].astype(int)), "success: int64"),
        (lambda df: df.assign(width=df["width"].astype(str)), "width: .* \\(want float64\\)"),
        (lambda df: df.assign(object_id=1), "object_id: int64 \\(want string\\)"),
        (lambda df: df.assign(outcome="dropped", success=False), "unknown value"),
        (lambda df: df.assign(qw=df["qw"] * 2.0), "quaternions must be unit"),
        (lambda df: df.assign(success=~df["success"]), "success must be True exactly"),
        (lambda df: df.assign(grasp_id=np.int64(0)), "unique"),
    ],
)
def test_schema_errors_are_clear(tmp_path: Path, mutate, message: str) -> None:
    with pytest.raises(ds.SchemaError, match=message):
        ds.validate_labels(mutate(synthetic_labels("o", 6)))
    with pytest.raises(ds.SchemaError, match=message):  # and nothing invalid reaches the disk
        _write(tmp_path, mutate(synthetic_labels("o", 6)))
    assert list(tmp_path.iterdir()) == []


def test_load_labels_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        ds.load_labels(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="no label files"):
        ds.load_labels(tmp_path)
    bad = synthetic_labels("x", 3).drop(columns=["mesh_sha256"])
    bad.to_parquet(tmp_path / "foreign.parquet", index=False)
    with pytest.raises(ds.SchemaError, match="mesh_sha256"):
        ds.load_labels(tmp_path)


def test_poses_round_trip_through_transform() -> None:
    df = synthetic_labels("p", 25)
    T = ds.poses_as_matrices(df)
    assert T.shape == (25, 4, 4)
    for row, Ti in zip(df.itertuples(), T, strict=True):
        tf = Transform(np.array([row.x, row.y, row.z]), np.array([row.qx, row.qy, row.qz, row.qw]))
        np.testing.assert_allclose(tf.as_matrix(), Ti, atol=1e-12)
    again = ds.pose_columns(T)
    np.testing.assert_allclose(again.to_numpy(), df[list(ds.POSE_COLUMNS)].to_numpy(), atol=1e-12)
    assert ds.poses_as_matrices(df.iloc[:0]).shape == (0, 4, 4)


def test_split_by_object_has_no_leakage() -> None:
    df = pd.concat([synthetic_labels(f"obj{i}", 4) for i in range(10)], ignore_index=True)
    train, val = ds.split_by_object(df, val_fraction=0.2, seed=3)
    assert set(train["object_id"]).isdisjoint(val["object_id"])
    assert len(train) + len(val) == len(df)
    assert val["object_id"].nunique() == 2
    again = ds.split_by_object(df.sample(frac=1.0, random_state=0), val_fraction=0.2, seed=3)[1]
    assert set(again["object_id"]) == set(val["object_id"])  # row order does not matter
    tiny_train, tiny_val = ds.split_by_object(df[df["object_id"].isin(["obj0", "obj1"])], 0.01)
    assert tiny_val["object_id"].nunique() == 1 and tiny_train["object_id"].nunique() == 1


def test_reading_labels_does_not_import_the_simulator() -> None:
    """A learner's process loads labels without pybullet (the reader is apart from the store)."""
    import subprocess
    import sys

    code = "import sys, annotator.dataset; print('pybullet' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
