"""Label dataset: schema, atomic per-object Parquet files, manifest and resume, loading, splits."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
import trimesh

import annotator.dataset as ds
import annotator.pipeline.store as st
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.sampler import object_rng, sample_candidates


def _labels(object_id: str, n: int = 10, seed: int = 0) -> pd.DataFrame:
    """A realistic label table: poses from the real sampler on a 40 mm box, mixed outcomes."""
    rng = object_rng(seed, object_id)
    cand = sample_candidates(
        trimesh.creation.box(extents=(0.04, 0.04, 0.04)), n, rng, AnnotatorConfig().sampler, 0.11
    )
    outcomes = np.array(ds.OUTCOMES)[rng.integers(len(ds.OUTCOMES), size=n)]
    df = ds.pose_columns(cand.T_obj_tcp)
    df.insert(0, "object_id", object_id)
    df.insert(1, "grasp_id", np.arange(n, dtype=np.int64))
    df["width"] = cand.width_expected
    df["success"] = outcomes == "success"
    df["outcome"] = outcomes
    df["score"] = df["success"].astype(np.float64)
    df["object_scale"] = 1.0
    df["mesh_sha256"] = "ab" * 32
    df["seed"] = np.int64(seed)
    df["antipodal"] = cand.antipodal  # an extra column is kept
    return df


def test_outcomes_and_enum() -> None:
    assert ds.OUTCOMES == ("success", "collision", "no_contact", "slipped_lift", "slipped_shake", "error")
    assert ds.Outcome.SLIPPED_LIFT.label == "slipped_lift"
    assert ds.Outcome.from_label("no_contact") is ds.Outcome.NO_CONTACT
    with pytest.raises(ValueError, match="unknown outcome"):
        ds.Outcome.from_label("dropped")
    assert list(ds.COLUMNS)[:2] == ["object_id", "grasp_id"] and len(ds.COLUMNS) == 16


def test_object_filename_is_safe_and_collision_free() -> None:
    ids = ["ycb/mug", "ycb__mug", "ycb_mug", "YCB/mug", "a/b/c", "_hidden", ".dot", "with space/ü"]
    names = [st.object_filename(i) for i in ids]
    assert len(set(names)) == len(ids)
    for name in names:
        assert "/" not in name and "\\" not in name and " " not in name
        assert name.endswith(".parquet") and name[0] not in "._"
    assert st.object_filename("ycb/mug") == st.object_filename("ycb/mug")
    assert st.object_filename("ycb/mug").startswith("ycb__mug-")


def test_round_trip_read_parquet_directory(tmp_path: Path) -> None:
    frames = {oid: _labels(oid, n=12) for oid in ["ycb/mug", "ycb/bowl", "cube"]}
    manifest = st.open_run(tmp_path, AnnotatorConfig().to_dict(), seed=0, n=12, trials=1)
    for oid, df in frames.items():
        path = st.write_object_labels(tmp_path, df)
        manifest.mark_done(oid, path, len(df), "ab" * 32)
    manifest.save(tmp_path)
    (tmp_path / ".leftover.parquet.x.tmp").write_bytes(b"half a file")  # a crashed writer's debris
    assert (tmp_path / st.MANIFEST_NAME).exists()

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
    one = ds.load_labels(tmp_path / st.object_filename("cube"))
    assert set(one["object_id"]) == {"cube"} and len(one) == 12


def test_write_is_atomic_when_writer_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    st.write_object_labels(tmp_path, _labels("good", 5))
    before = sorted(p.name for p in tmp_path.iterdir())

    def broken_write_table(table, where, **kwargs) -> None:
        where.write(b"PAR1 partial bytes")  # some bytes reach the disk, then the writer dies
        raise OSError("disk full")

    monkeypatch.setattr(st.pq, "write_table", broken_write_table)
    with pytest.raises(OSError, match="disk full"):
        st.write_object_labels(tmp_path, _labels("bad", 5))
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no partial file, no temp file
    assert not (tmp_path / st.object_filename("bad")).exists()
    monkeypatch.undo()
    assert set(pd.read_parquet(tmp_path)["object_id"]) == {"good"}


def test_failed_overwrite_keeps_the_old_file_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = st.write_object_labels(tmp_path, _labels("obj", 6, seed=1))
    old = path.read_bytes()

    def dies(table, where, **kwargs) -> None:
        where.write(b"garbage")
        raise KeyboardInterrupt

    monkeypatch.setattr(st.pq, "write_table", dies)
    with pytest.raises(KeyboardInterrupt):
        st.write_object_labels(tmp_path, _labels("obj", 6, seed=2))
    assert path.read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_written_file_has_fixed_arrow_types(tmp_path: Path) -> None:
    path = st.write_object_labels(tmp_path, _labels("typed", 4))
    schema = pq.read_schema(path)
    assert str(schema.field("object_id").type) == "string"
    assert str(schema.field("grasp_id").type) == "int64"
    assert str(schema.field("success").type) == "bool"
    assert str(schema.field("qw").type) == "double"


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
        st.write_object_labels(tmp_path, mutate(_labels("o", 6)))
    assert list(tmp_path.iterdir()) == []


def test_write_rejects_several_objects_and_gappy_ids(tmp_path: Path) -> None:
    both = pd.concat([_labels("a", 3), _labels("b", 3)])
    with pytest.raises(ds.SchemaError, match="one object"):
        st.write_object_labels(tmp_path, both)
    gappy = _labels("a", 4)
    gappy["grasp_id"] = np.array([0, 1, 2, 5], dtype=np.int64)
    with pytest.raises(ds.SchemaError, match=r"exactly 0\.\.3"):
        st.write_object_labels(tmp_path, gappy)


def test_load_labels_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        ds.load_labels(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="no label files"):
        ds.load_labels(tmp_path)
    bad = _labels("x", 3).drop(columns=["mesh_sha256"])
    bad.to_parquet(tmp_path / "foreign.parquet", index=False)
    with pytest.raises(ds.SchemaError, match="mesh_sha256"):
        ds.load_labels(tmp_path)


def test_poses_round_trip_through_transform() -> None:
    df = _labels("p", 25)
    T = ds.poses_as_matrices(df)
    assert T.shape == (25, 4, 4)
    for row, Ti in zip(df.itertuples(), T, strict=True):
        tf = Transform(np.array([row.x, row.y, row.z]), np.array([row.qx, row.qy, row.qz, row.qw]))
        np.testing.assert_allclose(tf.as_matrix(), Ti, atol=1e-12)
    again = ds.pose_columns(T)
    np.testing.assert_allclose(again.to_numpy(), df[list(ds.POSE_COLUMNS)].to_numpy(), atol=1e-12)
    assert ds.poses_as_matrices(df.iloc[:0]).shape == (0, 4, 4)


def test_split_by_object_has_no_leakage() -> None:
    df = pd.concat([_labels(f"obj{i}", 4) for i in range(10)], ignore_index=True)
    train, val = ds.split_by_object(df, val_fraction=0.2, seed=3)
    assert set(train["object_id"]).isdisjoint(val["object_id"])
    assert len(train) + len(val) == len(df)
    assert val["object_id"].nunique() == 2
    again = ds.split_by_object(df.sample(frac=1.0, random_state=0), val_fraction=0.2, seed=3)[1]
    assert set(again["object_id"]) == set(val["object_id"])  # row order does not matter
    tiny_train, tiny_val = ds.split_by_object(df[df["object_id"].isin(["obj0", "obj1"])], 0.01)
    assert tiny_val["object_id"].nunique() == 1 and tiny_train["object_id"].nunique() == 1


def test_manifest_resume_and_mismatch(tmp_path: Path) -> None:
    config = AnnotatorConfig().to_dict()
    m = st.open_run(tmp_path, config, seed=0, n=4, trials=1)
    path = st.write_object_labels(tmp_path, _labels("a", 4))
    m.mark_done("a", path, 4, "ab" * 32)
    m.mark_failed("b", ValueError("mesh is in millimetres:\n  scale it"))
    m.save(tmp_path)

    data = json.loads((tmp_path / st.MANIFEST_NAME).read_text())
    assert data["objects_done"]["a"]["file"] == path.name
    assert data["objects_done"]["a"]["sha256"] == st.file_sha256(path)
    assert data["objects_failed"]["b"] == "ValueError: mesh is in millimetres: scale it"
    assert {"python", "pybullet", "numpy", "trimesh", "annotator"} <= set(data["versions"])
    assert data["config"]["sampler"]["n_rotations"] == AnnotatorConfig().sampler.n_rotations

    resumed = st.open_run(tmp_path, config, seed=0, n=4, trials=1)
    assert resumed.pending(["a", "b", "c"], tmp_path) == ["b", "c"]
    assert resumed.pending(["a"], tmp_path, mesh_sha256={"a": "cd" * 32}) == ["a"]  # mesh changed

    for kwargs, what in [({"seed": 1}, "seed"), ({"n": 5}, "n: 4"), ({"trials": 3}, "trials")]:
        args = {"seed": 0, "n": 4, "trials": 1} | kwargs
        with pytest.raises(st.ManifestMismatchError, match=f"{what}.*--overwrite"):
            st.open_run(tmp_path, config, **args)
    other = AnnotatorConfig.from_dict({"sampler": {"n_rotations": 4}}).to_dict()
    with pytest.raises(st.ManifestMismatchError, match="config differs.*--overwrite"):
        st.open_run(tmp_path, other, seed=0, n=4, trials=1)

    fresh = st.open_run(tmp_path, other, seed=0, n=4, trials=1, overwrite=True)
    assert fresh.objects_done == {} and not list(tmp_path.glob("*.parquet"))
    assert st.Manifest.load(tmp_path).config["sampler"]["n_rotations"] == 4


def test_labels_without_manifest_need_overwrite(tmp_path: Path) -> None:
    st.write_object_labels(tmp_path, _labels("a", 3))
    with pytest.raises(st.ManifestMismatchError, match="--overwrite"):
        st.open_run(tmp_path, {}, seed=0, n=3, trials=1)


def test_chunk_files_are_read_with_the_rest_merged_and_cleaned_up(tmp_path: Path) -> None:
    """A run writes each span as it comes back; read_parquet sees them; the merge is the same rows."""
    config = AnnotatorConfig().to_dict()
    m = st.open_run(tmp_path, config, seed=0, n=10, trials=1)
    whole = _labels("ycb/mug", 10)
    first = st.write_chunk_labels(tmp_path, whole.iloc[0:4], 0)
    second = st.write_chunk_labels(tmp_path, whole.iloc[4:10], 4)
    assert first.name == st.chunk_filename("ycb/mug", 0, 4) and first.name.startswith("ycb__mug-")
    assert first.name.endswith(".000000-000004.parquet") and second.name.endswith(".000004-000010.parquet")
    with pytest.raises(ds.SchemaError, match="4..7"):  # rows must be exactly the span they claim
        st.write_chunk_labels(tmp_path, whole.iloc[0:4], 4)
    m.mark_chunk("ycb/mug", 0, first, 4, "ab" * 32)
    m.mark_chunk("ycb/mug", 4, second, 6, "ab" * 32)
    m.save(tmp_path)

    # the user's one-liner reads chunks of an unfinished object like any label file
    got = pd.read_parquet(tmp_path).sort_values("grasp_id", ignore_index=True)
    pd.testing.assert_frame_equal(ds.validate_labels(got), ds.validate_labels(whole), check_dtype=False)

    resumed = st.open_run(tmp_path, config, seed=0, n=10, trials=1)
    assert resumed.chunks_of("ycb/mug", tmp_path, "ab" * 32) == {(0, 4): first.name, (4, 10): second.name}
    assert resumed.chunks_of("ycb/mug", tmp_path, "cd" * 32) == {}  # the mesh changed: redo all
    second.unlink()
    assert resumed.chunks_of("ycb/mug", tmp_path, "ab" * 32) == {(0, 4): first.name}  # file gone: redo
    st.write_chunk_labels(tmp_path, whole.iloc[4:10], 4)

    merged = st.merge_chunks(tmp_path, "ycb/mug", [first.name, second.name])
    path = st.write_object_labels(tmp_path, merged)
    resumed.mark_done("ycb/mug", path, 10, "ab" * 32)
    resumed.save(tmp_path)
    assert resumed.chunks_done == {}
    # a stop between the merge and the clean-up leaves chunks of a done object: removed on resume
    assert first.exists() and second.exists()
    st.open_run(tmp_path, config, seed=0, n=10, trials=1)
    assert sorted(p.name for p in tmp_path.glob("*.parquet")) == [path.name]
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.load_labels(path))


def test_reading_labels_does_not_import_the_simulator() -> None:
    """A learner's process loads labels without pybullet (the reader is apart from the store)."""
    import subprocess
    import sys

    code = "import sys, annotator.dataset; print('pybullet' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
