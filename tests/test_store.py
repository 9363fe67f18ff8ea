"""The store: atomic marked files, the manifest that binds a run, verification, the lock, resume.

Unit tests of annotator.store on label tables from the real sampler (no simulation);
the end-to-end faults are in tests/test_reliability.py.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest
from helpers import synthetic_labels

import annotator.dataset as ds
import annotator.store.store as store_module
from annotator.config import AnnotatorConfig
from annotator.store import (
    LOCK_NAME,
    MANIFEST_NAME,
    STALE_DIR,
    LockedError,
    ManifestUnreadableError,
    RunMismatchError,
    RunSpec,
    Store,
    files,
    names,
)
from annotator.store.lock import LockLostError
from annotator.store.manifest import Manifest
from annotator.store.reconcile import ForeignFileError

N = 10
SRC = "ab" * 32


def _spec(**changes) -> RunSpec:
    args = {
        "seed": 0,
        "n": N,
        "trials": 1,
        "scale": None,
        "chunk_size": 5,
        "config": AnnotatorConfig().to_dict(),
    }
    return RunSpec(**(args | changes))


def _finished(folder: Path, oids=("a", "b"), spec: RunSpec | None = None) -> Store:
    """A folder with every object written chunk by chunk and merged; the store closed."""
    store = Store(folder, spec or _spec())
    store.open()
    for oid in oids:
        whole = synthetic_labels(oid)
        store.write_chunk(oid, whole.iloc[:5], 0, SRC)
        store.write_chunk(oid, whole.iloc[5:], 5, SRC)
        store.finish_object(oid, SRC)
    store.close()
    return store


def _open(folder: Path, spec: RunSpec | None = None, **kwargs) -> Store:
    store = Store(folder, spec or _spec())
    store.open(**kwargs)
    return store


# --- files ---------------------------------------------------------------------------------------


def test_object_filename_is_safe_and_collision_free() -> None:
    ids = ["ycb/mug", "ycb__mug", "ycb_mug", "YCB/mug", "a/b/c", "_hidden", ".dot", "with space/ü"]
    written = [names.object_filename(i) for i in ids]
    assert len(set(written)) == len(ids)
    for name in written:
        assert "/" not in name and "\\" not in name and " " not in name
        assert name.endswith(".parquet") and name[0] not in "._"
    assert names.object_filename("ycb/mug").startswith("ycb__mug-")
    assert names.chunk_filename("ycb/mug", 0, 4).endswith(".000000-000004.parquet")


def test_write_is_atomic_and_names_the_path_on_os_errors(tmp_path: Path) -> None:
    good = tmp_path / "good.bin"
    files.atomic_write(good, lambda fh: fh.write(b"whole"))

    def disk_full(fh) -> None:
        fh.write(b"PAR1 partial bytes")  # some bytes reach the disk, then the device is full
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(files.OutputError, match=r"cannot write .*bad.bin: No space left on device"):
        files.atomic_write(tmp_path / "bad.bin", disk_full)

    def interrupted(fh) -> None:
        fh.write(b"garbage")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        files.atomic_write(good, interrupted)
    assert good.read_bytes() == b"whole"  # a failed overwrite keeps the old file whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.bin"]  # no partial or temp file


def test_label_files_have_fixed_types_a_mark_and_the_recorded_checksum(tmp_path: Path) -> None:
    rec = files.write_labels(tmp_path, synthetic_labels("typed", 4), 0, 4, "t.parquet", "key", SRC)
    path = tmp_path / "t.parquet"
    schema = pq.read_schema(path)
    assert str(schema.field("object_id").type) == "string" and str(schema.field("grasp_id").type) == "int64"
    assert str(schema.field("success").type) == "bool" and str(schema.field("qw").type) == "double"
    assert files.read_mark(path) == {
        "run_key": "key",
        "object_id": "typed",
        "start": 0,
        "stop": 4,
        "source_sha256": SRC,
    }
    assert rec.sha256 == files.file_sha256(path) and rec.n == 4
    pd.DataFrame({"a": [1]}).to_parquet(tmp_path / "user.parquet")
    assert files.read_mark(tmp_path / "user.parquet") is None
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    assert files.read_mark(tmp_path / "junk.parquet") is None


def test_write_rejects_several_objects_and_gappy_ids(tmp_path: Path) -> None:
    both = pd.concat([synthetic_labels("a", 3), synthetic_labels("b", 3)])
    with pytest.raises(ds.SchemaError, match="one object"):
        files.write_labels(tmp_path, both, 0, 6, "x.parquet", "k", SRC)
    with pytest.raises(ds.SchemaError, match=r"exactly 4\.\.7"):  # rows must be the span they claim
        files.write_labels(tmp_path, synthetic_labels("a", 4), 4, 8, "x.parquet", "k", SRC)
    assert list(tmp_path.iterdir()) == []


# --- a run in a folder -----------------------------------------------------------------------------


def test_chunks_are_readable_at_once_merged_and_resumed(tmp_path: Path) -> None:
    store = _open(tmp_path)
    whole = synthetic_labels("ycb/mug")
    store.write_chunk("ycb/mug", whole.iloc[:5], 0, SRC)
    got = pd.read_parquet(tmp_path)  # the user's one-liner reads chunks of an unfinished object
    assert sorted(got["grasp_id"]) == [0, 1, 2, 3, 4]
    store.close()

    store = _open(tmp_path)
    resume = store.reconcile({"ycb/mug": SRC})
    assert resume.done == set() and resume.chunks == {"ycb/mug": {(0, 5)}}
    store.write_chunk("ycb/mug", whole.iloc[5:], 5, SRC)
    stats = store.finish_object("ycb/mug", SRC)
    store.close()
    assert stats["n"] == N and stats["successes"] == int(whole["success"].sum())
    assert sorted(p.name for p in tmp_path.glob("*.parquet")) == [names.object_filename("ycb/mug")]
    pd.testing.assert_frame_equal(
        ds.load_labels(tmp_path), ds.load_labels(tmp_path / names.object_filename("ycb/mug"))
    )
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    entry = data["objects_done"]["ycb/mug"]
    assert entry["sha256"] == files.file_sha256(tmp_path / entry["file"]) and entry["source_sha256"] == SRC
    assert data["run"]["seed"] == 0 and data["run"]["n"] == N and data["run"]["chunk_size"] == 5
    assert data["run"]["config"]["sampler"]["n_rotations"] == AnnotatorConfig().sampler.n_rotations
    assert {"annotator", "pybullet", "numpy", "trimesh", "coacd"} <= set(data["run"]["versions"])


@pytest.mark.parametrize("links", [True, False], ids=["hard-link", "no-hard-links"])
def test_an_object_of_one_chunk_becomes_its_file_without_a_rewrite(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, links: bool
) -> None:
    """One span of every row: its chunk file is the object's file (linked, or copied where the file
    system has no hard links), recorded with its own digest, and resumed as done."""
    if not links:

        def no_link(*args, **kwargs):
            raise OSError(errno.EPERM, "hard links not supported")

        monkeypatch.setattr(os, "link", no_link)
    spec = _spec(chunk_size=N)
    store = Store(tmp_path, spec)
    store.open()
    whole = synthetic_labels("ycb/mug")
    store.write_chunk("ycb/mug", whole, 0, SRC)
    chunk = tmp_path / names.chunk_filename("ycb/mug", 0, N)
    chunk_bytes = chunk.read_bytes()
    rewrites, reads = [], []
    monkeypatch.setattr(store_module, "write_labels", lambda *a, **k: rewrites.append(a))
    read = store_module.read_labels
    monkeypatch.setattr(store_module, "read_labels", lambda *a: reads.append(a) or read(*a))
    stats = store.finish_object("ycb/mug", SRC)
    assert rewrites == [] and reads == []  # not read back (its stats are the written rows') nor rewritten
    store.close()
    final = tmp_path / names.object_filename("ycb/mug")
    assert sorted(p.name for p in tmp_path.glob("*.parquet")) == [final.name]
    assert final.read_bytes() == chunk_bytes and final.stat().st_nlink == 1
    mark = files.read_mark(final)
    assert mark is not None and (mark["object_id"], mark["start"], mark["stop"]) == ("ycb/mug", 0, N)
    entry = json.loads((tmp_path / MANIFEST_NAME).read_text())["objects_done"]["ycb/mug"]
    assert entry["sha256"] == files.file_sha256(final) and entry["n"] == N
    assert stats["n"] == N and stats["successes"] == int(whole["success"].sum())
    assert stats == store_module.object_stats(ds.load_labels(final))
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.load_labels(final))
    store = Store(tmp_path, spec)
    store.open()
    assert store.reconcile({"ycb/mug": SRC}).done == {"ycb/mug"}
    store.close()


def test_an_object_whose_one_chunk_an_earlier_run_wrote_is_finished_from_its_file(tmp_path: Path) -> None:
    """The stats of a chunk written before a resume come from its file, equal to the ones the
    writing process would have given (rows out of order in the chunk, as workers may send them)."""
    spec = _spec(chunk_size=N)
    whole = synthetic_labels("ycb/mug")
    shuffled = whole.iloc[::-1].reset_index(drop=True)
    at_once = Store(tmp_path / "at_once", spec)
    at_once.open()
    at_once.write_chunk("ycb/mug", shuffled, 0, SRC)
    stats = at_once.finish_object("ycb/mug", SRC)
    at_once.close()
    first = Store(tmp_path / "resumed", spec)
    first.open()
    first.write_chunk("ycb/mug", shuffled, 0, SRC)
    first.close()  # stopped before the object was finished
    again = Store(tmp_path / "resumed", spec)
    again.open()
    again.reconcile({"ycb/mug": SRC})
    assert again.finish_object("ycb/mug", SRC) == stats
    again.close()


@pytest.mark.parametrize(
    "changes, named",
    [
        ({"seed": 1}, "seed 0 in the folder, 1 now"),
        ({"n": 12}, "n 10 in the folder, 12 now"),
        ({"trials": 3}, "trials 1 in the folder, 3 now"),
        ({"scale": 0.001}, "scale None in the folder, 0.001 now"),
        (
            {"config": AnnotatorConfig.from_dict({"gripper": {"stall_steps": 20}}).to_dict()},
            "[gripper] stall_steps 12 in the folder, 20 now",
        ),
        ({"versions": {"annotator": "9.9"}}, "annotator"),
    ],
)
def test_other_settings_are_refused_naming_what_differs(tmp_path: Path, changes, named) -> None:
    _finished(tmp_path)
    with pytest.raises(RunMismatchError) as info:
        _open(tmp_path, _spec(**changes))
    assert named in str(info.value) and "--overwrite" in str(info.value)
    assert "\n" not in str(info.value)


def test_overwrite_removes_only_the_tools_files(tmp_path: Path) -> None:
    _finished(tmp_path)
    pd.DataFrame({"mine": [1, 2]}).to_parquet(tmp_path / "my_notes.parquet")
    (tmp_path / "README.txt").write_text("keep me")
    store = _open(tmp_path, _spec(seed=1), overwrite=True)
    store.close()
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith((".", "_"))) == [
        "README.txt",
        "my_notes.parquet",
    ]
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["run"]["seed"] == 1


# --- state that rots -------------------------------------------------------------------------------


def test_a_truncated_object_file_is_named_removed_and_redone(tmp_path: Path) -> None:
    _finished(tmp_path)
    path = tmp_path / names.object_filename("a")
    path.write_bytes(path.read_bytes()[:100])
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": SRC})
    store.close()
    assert resume.done == {"b"} and "a" not in resume.chunks
    assert not path.exists()
    assert any(path.name in note and "checksum" in note for note in store.notes)
    pd.read_parquet(tmp_path)  # the folder is readable again


def test_a_truncated_chunk_the_manifest_lists_is_redone(tmp_path: Path) -> None:
    store = _open(tmp_path)
    whole = synthetic_labels("a")
    store.write_chunk("a", whole.iloc[:5], 0, SRC)
    store.write_chunk("a", whole.iloc[5:], 5, SRC)
    store.close()
    chunk = tmp_path / names.chunk_filename("a", 5, 10)
    chunk.write_bytes(chunk.read_bytes()[:50])
    store = _open(tmp_path)
    assert store.reconcile({"a": SRC}).chunks == {"a": {(0, 5)}}
    store.close()
    assert not chunk.exists()


def test_unvouched_files_of_this_run_go_and_nothing_else_is_touched(tmp_path: Path) -> None:
    store = _open(tmp_path)
    store.close()
    run_id = store.manifest.run_id
    # a chunk this folder's run wrote just before a kill (never recorded), a temp file, a user's own
    # file, and label files of another run copied in: renamed, and under the tool's own name
    files.write_labels(
        tmp_path,
        synthetic_labels("a", 5),
        0,
        5,
        names.chunk_filename("a", 0, 5),
        _spec().key,
        SRC,
        run_id=run_id,
    )
    (tmp_path / ".x.parquet.abc123.tmp").write_bytes(b"half")
    pd.DataFrame({"mine": [1]}).to_parquet(tmp_path / "mine.parquet")
    other = "f" * 32
    b5 = synthetic_labels("b", 5)
    files.write_labels(tmp_path, b5, 0, 5, "ok_copy_from_run_B.parquet", _spec().key, SRC, run_id=other)
    files.write_labels(tmp_path, b5, 0, 5, names.chunk_filename("z", 0, 5), _spec().key, SRC, run_id=other)
    store = _open(tmp_path)
    store.close()
    left = sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith((".", "_")))
    assert left == sorted(["mine.parquet", "ok_copy_from_run_B.parquet", names.chunk_filename("z", 0, 5)])
    named = "\n".join(store.notes)
    assert "ok_copy_from_run_B.parquet: written by another run; left as it is" in named
    assert "mine.parquet: not a label file of this tool; left as it is" in named


@pytest.mark.parametrize(
    "content, reason",
    [
        (b"[]", "expected a JSON object"),
        (b"null", "expected a JSON object"),
        (bytes(range(256)), "not valid JSON"),
        (
            b'{"tool": "rg2-annotator", "manifest_version": 3, "run": 5}',
            "manifest.run: expected a JSON object",
        ),
        (b"{", "not valid JSON"),
    ],
)
def test_an_unreadable_manifest_is_one_line_and_repair_rebuilds_it(tmp_path: Path, content, reason) -> None:
    _finished(tmp_path)
    before = ds.load_labels(tmp_path)
    (tmp_path / MANIFEST_NAME).write_bytes(content)
    with pytest.raises(ManifestUnreadableError) as info:
        _open(tmp_path)
    text = str(info.value)
    assert reason in text and "--repair" in text and "\n" not in text
    store = _open(tmp_path, repair=True)
    resume = store.reconcile({"a": SRC, "b": SRC})
    store.close()
    assert resume.done == {"a", "b"}
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), before)


def test_repair_keeps_only_files_that_verify(tmp_path: Path) -> None:
    _finished(tmp_path)
    (tmp_path / MANIFEST_NAME).unlink()
    bad = tmp_path / names.object_filename("b")
    bad.write_bytes(bad.read_bytes()[:-40])  # truncated: its rows cannot be read
    with pytest.raises(ManifestUnreadableError, match="no _manifest.json.*--repair"):
        _open(tmp_path)
    store = _open(tmp_path, repair=True)
    assert store.reconcile({"a": SRC, "b": SRC}).done == {"a"}
    store.close()
    assert not bad.exists()


def test_other_runs_files_are_neither_adopted_nor_deleted_by_repair(tmp_path: Path) -> None:
    _finished(tmp_path, spec=_spec(seed=5))
    before = sorted(p.name for p in tmp_path.glob("*.parquet"))
    (tmp_path / MANIFEST_NAME).unlink()
    store = _open(tmp_path, repair=True)  # this run has seed 0: the seed-5 files are another run's
    with pytest.raises(ForeignFileError, match="did not write it; move it away") as info:
        store.reconcile({"a": SRC, "b": SRC})  # they lie where this run writes a's and b's labels
    store.close()
    assert "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.glob("*.parquet")) == before
    store = _open(tmp_path)  # the folder still serves a run that writes other objects
    assert store.reconcile({"c": SRC}).done == set()
    store.close()


# --- inputs that change ------------------------------------------------------------------------------


def test_changed_source_is_redone_and_removed_object_set_aside(tmp_path: Path) -> None:
    _finished(tmp_path, oids=("a", "b", "c"))
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": "ef" * 32})  # b's file changed, c is gone
    store.close()
    assert resume.done == {"a"} and resume.changed == ["b"] and resume.stale == ["c"]
    assert set(pd.read_parquet(tmp_path)["object_id"]) == {"a"}  # c is left out of the dataset
    assert (tmp_path / STALE_DIR / names.object_filename("c")).exists()  # but not lost
    assert any("c: no longer among the objects" in n for n in store.notes)
    assert any("b: its source changed" in n for n in store.notes)


# --- one run per folder --------------------------------------------------------------------------------

_HOLD = """
import sys, time
from pathlib import Path
from annotator.config import AnnotatorConfig
from annotator.store import RunSpec, Store
store = Store(Path(sys.argv[1]), RunSpec(0, 10, 1, None, 5, AnnotatorConfig().to_dict()))
store.open()
print("locked", flush=True)
time.sleep(60)
"""


def test_a_second_run_is_refused_naming_the_holder_and_a_crash_releases(tmp_path: Path) -> None:
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(LockedError) as info:
            _open(tmp_path)
        assert f"pid {holder.pid}" in str(info.value) and "another --out" in str(info.value)
        holder.send_signal(signal.SIGKILL)  # the holder crashes: the OS releases its lock
        holder.wait(timeout=10)
        _open(tmp_path).close()
    finally:
        holder.kill()
        holder.wait()
    assert (tmp_path / LOCK_NAME).exists()


@pytest.mark.root
def test_a_read_only_folder_reads_a_finished_run_and_refuses_writes(tmp_path: Path) -> None:
    mount = tmp_path / "ro"
    mount.mkdir()
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mount)], capture_output=True
    ).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        _finished(mount, oids=("a",))
        subprocess.run(["mount", "-o", "remount,ro", str(mount)], check=True)
        store = _open(mount)
        assert store.read_only and store.reconcile({"a": SRC}).done == {"a"}
        with pytest.raises(files.OutputError, match="read-only"):
            store.write_chunk("b", synthetic_labels("b", 5), 0, SRC)
        store.close()
    finally:
        time.sleep(0.1)
        subprocess.run(["umount", "-l", str(mount)], check=False)
    assert os.path.isdir(mount)


# --- artifacts (per-object files bound to the labels they came with) -----------------------------------


def _with_artifacts(folder: Path, oids=("a", "b"), finish: bool = True) -> dict[str, dict[str, str]]:
    """Objects written in two chunks, the first with two artifacts; returns every artifact record."""
    store = _open(folder)
    records: dict[str, dict[str, str]] = {}
    for oid in oids:
        whole = synthetic_labels(oid)
        made = {
            name: store.write_artifact(oid, name, f"{oid} {name}".encode()) for name in ("v.png", "c.parquet")
        }
        records.update({f"{oid}/{n}": r for n, r in made.items()})
        store.write_chunk(oid, whole.iloc[:5], 0, SRC, made)
        store.write_chunk(oid, whole.iloc[5:], 5, SRC)
        if finish:
            store.finish_object(oid, SRC)
    store.close()
    return records


def test_artifacts_are_written_atomically_recorded_with_their_labels_and_ignored_by_read_parquet(tmp_path):
    records = _with_artifacts(tmp_path)
    rec = records["a/v.png"]
    assert rec["file"] == f"{names.ARTIFACTS_DIR}/{names.object_stem('a')}/v.png"
    assert (tmp_path / rec["file"]).read_bytes() == b"a v.png"
    manifest = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert manifest["objects_done"]["a"]["artifacts"]["v.png"] == rec  # merged with the object's file
    mark = files.read_mark(tmp_path / names.object_filename("a"))
    assert mark["artifacts"]["c.parquet"] == records["a/c.parquet"]  # the file vouches for them too
    assert len(pd.read_parquet(tmp_path)) == 2 * N  # labels only: _views/ is skipped
    with pytest.raises(ValueError, match="artifact name"):
        _open(tmp_path).write_artifact("a", "../escape.png", b"x")


@pytest.mark.parametrize("finish", [True, False])
def test_a_corrupt_or_missing_artifact_redoes_the_labels_it_came_with(tmp_path: Path, finish: bool) -> None:
    records = _with_artifacts(tmp_path, finish=finish)
    (tmp_path / records["a/v.png"]["file"]).write_bytes(b"rotten")
    (tmp_path / records["b/c.parquet"]["file"]).unlink()
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": SRC})
    store.close()
    if finish:  # a finished object is redone whole, its other artifacts removed with it
        assert resume.done == set() and resume.chunks == {}
    else:  # only the chunk the artifacts came with
        assert resume.chunks == {"a": {(5, 10)}, "b": {(5, 10)}}
    assert not (tmp_path / records["a/c.parquet"]["file"]).exists()
    assert any("v.png corrupt" in n for n in store.notes) and any(
        "c.parquet missing" in n for n in store.notes
    )


def test_unbound_artifacts_go_on_resume_and_foreign_files_stay(tmp_path: Path) -> None:
    _with_artifacts(tmp_path, oids=("a",))
    store = _open(tmp_path)
    stray = store.write_artifact("a", "written-before-a-kill.png", b"x")  # never bound to labels
    store.close()
    views = tmp_path / names.ARTIFACTS_DIR
    (views / "mine").mkdir()
    (views / "mine" / "notes.txt").write_text("keep")
    _open(tmp_path).close()
    assert not (tmp_path / stray["file"]).exists()
    assert (views / names.object_stem("a") / "v.png").exists()
    assert (views / "mine" / "notes.txt").exists()


def test_a_users_file_in_a_view_folder_stays_on_resume_and_overwrite(tmp_path: Path) -> None:
    """Only the files the tool wrote (listed in the folder) are ever removed from _views/<stem>/."""
    _with_artifacts(tmp_path, oids=("a",))
    store = _open(tmp_path)
    stray = store.write_artifact("a", "written-before-a-kill.png", b"x")  # the tool's, never bound
    store.close()
    views = tmp_path / names.ARTIFACTS_DIR / names.object_stem("a")
    (views / "notes.txt").write_text("mine")
    (views / "v_mine.png").write_bytes(b"my own picture, named like a view")
    _open(tmp_path).close()  # a plain resume
    assert not (tmp_path / stray["file"]).exists() and (views / "v.png").exists()
    assert (views / "notes.txt").read_text() == "mine" and (views / "v_mine.png").exists()
    _open(tmp_path, overwrite=True).close()
    assert sorted(p.name for p in views.iterdir()) == ["notes.txt", "v_mine.png"]


def test_overwrite_removes_artifacts_and_stale_objects_take_theirs_along(tmp_path: Path) -> None:
    records = _with_artifacts(tmp_path, oids=("a", "b"))
    store = _open(tmp_path)
    assert store.reconcile({"a": SRC}).stale == ["b"]
    store.close()
    moved = tmp_path / STALE_DIR / records["b/v.png"]["file"]
    assert moved.read_bytes() == b"b v.png" and not (tmp_path / records["b/v.png"]["file"]).exists()
    (tmp_path / names.ARTIFACTS_DIR / "mine").mkdir()
    (tmp_path / names.ARTIFACTS_DIR / "mine" / "notes.txt").write_text("keep")
    _open(tmp_path, overwrite=True).close()
    left = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert left == [LOCK_NAME, names.JOURNAL_NAME, MANIFEST_NAME, f"{names.ARTIFACTS_DIR}/mine/notes.txt"]


def test_repair_rebuilds_artifact_records_from_the_marks_and_drops_what_does_not_verify(tmp_path: Path):
    records = _with_artifacts(tmp_path)
    before = json.loads((tmp_path / MANIFEST_NAME).read_text())["objects_done"]["a"]["artifacts"]
    (tmp_path / MANIFEST_NAME).unlink()
    (tmp_path / records["b/v.png"]["file"]).write_bytes(b"rotten")
    store = _open(tmp_path, repair=True)
    assert store.reconcile({"a": SRC, "b": SRC}).done == {"a"}
    store.close()
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["objects_done"]["a"]["artifacts"] == before
    assert not (tmp_path / names.object_filename("b")).exists()


def test_a_manifest_cannot_point_the_tool_at_other_files(tmp_path: Path) -> None:
    """An artifact record outside _views/<object>/ (a tampered manifest) is a malformed manifest,
    never a file the tool checks or deletes."""
    _with_artifacts(tmp_path, oids=("a",))
    victim = tmp_path / "precious.txt"
    victim.write_text("keep")
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    data["objects_done"]["a"]["artifacts"]["v.png"]["file"] = "precious.txt"
    (tmp_path / MANIFEST_NAME).write_text(json.dumps(data))
    with pytest.raises(ManifestUnreadableError, match=r"objects_done\['a'\]\.artifacts\['v.png'\]\.file"):
        _open(tmp_path)
    assert victim.exists()


# --- the store's edges: paths, links, FIFOs, the lock, merges, malformed manifests ----------------------


def _tamper(folder: Path, change) -> None:
    data = json.loads((folder / MANIFEST_NAME).read_text())
    change(data)
    (folder / MANIFEST_NAME).write_text(json.dumps(data))


@pytest.mark.parametrize("target", ["../../victim.txt", "ABSOLUTE"])
def test_a_manifest_entry_outside_the_folder_is_refused_and_deletes_nothing(tmp_path: Path, target) -> None:
    out = tmp_path / "a" / "b" / "out"
    out.mkdir(parents=True)
    _finished(out)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    name = str(victim) if target == "ABSOLUTE" else target

    def point_away(data):
        data["objects_done"]["a"]["file"] = name

    _tamper(out, point_away)
    with pytest.raises(ManifestUnreadableError, match=r"objects_done\['a'\]\.file") as info:
        _open(out)
    assert "\n" not in str(info.value)
    assert victim.read_text() == "keep"


def test_a_fifo_where_a_label_file_was_is_never_opened_or_removed(tmp_path: Path) -> None:
    _finished(tmp_path)
    path = tmp_path / names.object_filename("a")
    path.unlink()
    os.mkfifo(path)  # opening it for reading would block the run forever
    store = _open(tmp_path)
    assert any("not a regular file; left as it is" in note for note in store.notes)
    with pytest.raises(ForeignFileError, match="did not write it"):
        store.reconcile({"a": SRC, "b": SRC})
    store.close()
    assert stat.S_ISFIFO(os.lstat(path).st_mode)


def test_a_symlinked_label_file_is_not_followed(tmp_path: Path) -> None:
    _finished(tmp_path)
    victim = tmp_path.parent / f"{tmp_path.name}-victim.parquet"
    path = tmp_path / names.object_filename("a")
    path.rename(victim)
    path.symlink_to(victim)
    store = _open(tmp_path)
    with pytest.raises(ForeignFileError):
        store.reconcile({"a": SRC, "b": SRC})
    store.close()
    assert path.is_symlink() and victim.is_file()


def test_the_lock_survives_its_file_being_removed(tmp_path: Path) -> None:
    first = _open(tmp_path)
    (tmp_path / LOCK_NAME).unlink()
    with pytest.raises(LockedError, match="in use by another run"):
        _open(tmp_path)
    first.write_chunk("a", synthetic_labels("a", 5), 0, SRC)  # the first run goes on
    first.save(force=True)
    first.close()
    _open(tmp_path).close()  # and the folder is free once it ends


def test_a_run_whose_lock_file_is_replaced_stops_with_one_line(tmp_path: Path, monkeypatch) -> None:
    """Where folders cannot be locked (some network file systems), the lock file is the lock and
    its inode is checked at every save."""
    from annotator.store import lock as lock_module

    real_open = os.open

    def no_folder_locks(path, flags, *args):
        if flags & os.O_DIRECTORY:
            raise OSError(errno.EINVAL, "no directory locks here")
        return real_open(path, flags, *args)

    monkeypatch.setattr(lock_module.os, "open", no_folder_locks)
    store = _open(tmp_path)
    assert store.lock.on_file
    (tmp_path / LOCK_NAME).unlink()
    (tmp_path / LOCK_NAME).write_text("{}")  # another run's, say
    store.write_chunk("a", synthetic_labels("a", 5), 0, SRC)
    with pytest.raises(LockLostError, match="was removed or replaced while this run held it") as info:
        store.save(force=True)  # every manifest save checks the lock first
    assert "\n" not in str(info.value)
    with pytest.raises(LockLostError):
        store.close()  # nothing more is written, and the lock is released
    assert store.lock.fd is None


def _no_duplicates(folder: Path) -> None:
    df = pd.read_parquet(folder)
    assert not df.duplicated(["object_id", "grasp_id"]).any(), df.groupby("object_id").size()


def _chunked(folder: Path, chunks: int) -> tuple[Store, RunSpec, pd.DataFrame]:
    """A store with object "a" written as ``chunks`` chunks (1: one chunk linked at its merge) and
    not merged yet; its spec and the rows."""
    spec = _spec(chunk_size=N // chunks)
    store, whole = _open(folder, spec), synthetic_labels("a")
    for start in range(0, N, N // chunks):
        store.write_chunk("a", whole.iloc[start : start + N // chunks], start, SRC)
    return store, spec, whole


@pytest.mark.parametrize("chunks", [2, 1])
def test_a_merge_that_cannot_record_leaves_the_chunks_and_no_duplicates(
    tmp_path: Path, monkeypatch, chunks: int
) -> None:
    store, spec, whole = _chunked(tmp_path, chunks)
    real_write = os.write

    def disk_full(fd, data):  # the journal's append (and any manifest write) finds the disk full
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", disk_full)
    monkeypatch.setattr(Manifest, "save", lambda self, out: disk_full(0, b""))
    with pytest.raises(files.OutputError, match="No space left on device"):
        store.finish_object("a", SRC)
    _no_duplicates(tmp_path)
    assert len(pd.read_parquet(tmp_path)) == N  # the chunks
    monkeypatch.setattr(os, "write", real_write)
    monkeypatch.undo()
    store.close()
    store = _open(tmp_path, spec)
    expected = {(0, 5), (5, 10)} if chunks == 2 else {(0, 10)}
    assert store.reconcile({"a": SRC}).chunks == {"a": expected}
    store.finish_object("a", SRC)
    store.close()
    _no_duplicates(tmp_path)
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.validate_labels(whole))


@pytest.mark.parametrize("chunks", [2, 1])
def test_a_merge_stopped_before_its_rename_is_completed_on_resume(
    tmp_path: Path, monkeypatch, chunks: int
) -> None:
    store, spec, whole = _chunked(tmp_path, chunks)
    real_replace = os.replace

    def killed_before_the_rename(source, target):
        if Path(target).name == names.object_filename("a"):
            raise SystemExit("killed")
        return real_replace(source, target)

    monkeypatch.setattr(os, "replace", killed_before_the_rename)
    with pytest.raises(SystemExit):
        store.finish_object("a", SRC)
    monkeypatch.undo()
    store.lock.release()
    assert not list(tmp_path.glob("*.parquet"))  # neither chunks nor merged rows are visible
    store = _open(tmp_path, spec)
    assert store.reconcile({"a": SRC}).done == {"a"}
    store.close()
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.validate_labels(whole))


@pytest.mark.parametrize(
    "change, where",
    [
        (lambda d: d["run"].__setitem__("config", 1), "manifest.run.config"),
        (lambda d: d["run"].__setitem__("versions", 5), "manifest.run.versions"),
        (lambda d: d["run"].__setitem__("seed", 2**64), "manifest.run.seed"),
        (lambda d: d["objects_done"]["a"].pop("stats"), "'stats' is missing"),
        (lambda d: d["objects_done"]["a"]["stats"].__setitem__("n", "ten"), "stats.n"),
        (lambda d: d["objects_failed"].__setitem__("x", 3), "objects_failed['x']"),
    ],
)
def test_a_manifest_of_any_other_shape_is_one_line(tmp_path: Path, change, where) -> None:
    _finished(tmp_path)
    _tamper(tmp_path, change)
    with pytest.raises(ManifestUnreadableError) as info:
        _open(tmp_path)
    assert where in str(info.value) and "\n" not in str(info.value)


def test_a_renamed_chunk_key_and_a_deeply_nested_manifest_are_one_line(tmp_path: Path) -> None:
    store = _open(tmp_path)
    store.write_chunk("a", synthetic_labels("a", 5), 0, SRC)
    store.close()

    def rename(data):
        files_ = data["chunks_done"]["a"]["files"]
        files_["0-6"] = files_.pop("0-5")

    _tamper(tmp_path, rename)
    with pytest.raises(ManifestUnreadableError, match=r"chunks_done\['a'\]\['0-6'\]"):
        _open(tmp_path)
    (tmp_path / MANIFEST_NAME).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ManifestUnreadableError, match="nested too deep|expected a JSON object"):
        _open(tmp_path)


def test_a_resume_on_another_kind_of_machine_says_so_and_records_both(tmp_path):
    """The same seed can settle a pile differently where the C library's maths differ (another
    glibc, another variant of its functions): the manifest names the kind of machine that
    labelled a folder, and a resume elsewhere says so rather than mixing two kinds silently."""
    import shutil

    from helpers import run_annotate

    from annotator.versions import machine_kind

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "objects" / "box.obj", objects)
    out = tmp_path / "labels"
    args = ["--objects", objects, "--n", 4, "--workers", 1, "--out", out]
    run_annotate(*args)
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["versions"]["machine"] == machine_kind()
    other = "x86_64, glibc 2.39, libm fma, numpy AVX512_SKX"
    manifest["versions"]["machine"] = other
    (out / "_manifest.json").write_text(json.dumps(manifest))
    result = run_annotate(*args)
    assert (
        f"labelled so far on another kind of machine ({other}); this one is {machine_kind()}" in result.output
    )
    again = json.loads((out / "_manifest.json").read_text())
    assert again["versions"]["machine"] == f"{other} | {machine_kind()}"
    assert "another kind of machine" not in run_annotate(*args).output  # both kinds known now


def test_a_dask_run_records_each_worker_s_kind_of_machine_and_says_when_they_differ(tmp_path):
    """A Dask run's labels are made by its workers, not by the command's process: the folder
    records the kinds of machine its workers report (none of the command's own), and a run whose
    workers are of two kinds says so in its summary (the same seed can settle a pile differently on
    each); the record survives a kill (written when a new kind appears, not only at the end)."""
    from annotator.versions import machine_kind

    here = machine_kind()
    other = "x86_64, glibc 2.39, libm sse2, numpy AVX512_SKX"
    store = Store(tmp_path, _spec(), labelled_here=False)
    store.open()
    assert "machine" not in store.manifest.versions  # the command's process labels nothing
    store.note_machine(other, "node-1")
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["versions"]["machine"] == other
    assert store.notes == []  # one kind so far, and nothing labelled before
    store.note_machine(other, "node-2")  # another worker of the same kind
    store.note_machine(here, "node-3")
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["versions"]["machine"] == f"{other} | {here}"
    assert store.notes == [
        f"this run's workers are of 2 kinds of machine ({other} (node-1); {here} (node-3)): the same seed "
        "can settle a pile differently on them (docs/reliability.md), so scene labels may depend on which "
        "worker ran them"
    ]
    store.close()
    # a local run's process labels: its kind is recorded as the folder opens, and a worker of that
    # kind (its own pool's) adds nothing
    local = _open(tmp_path / "local")
    assert local.manifest.versions["machine"] == here
    local.note_machine(here, "this-host")
    assert local.notes == []
    local.close()


@pytest.mark.slow
@pytest.mark.cluster
def test_a_dask_cluster_s_workers_kind_of_machine_is_recorded_not_the_command_s(tmp_path, monkeypatch):
    """Workers of another kind than the command's machine (glibc's maths without FMA, as
    GLIBC_TUNABLES selects it in their environment): the manifest records the workers' kind; a
    resume on the command's machine, whose kind labelled nothing of the folder, says so."""
    import shutil

    from helpers import run_annotate

    from annotator.versions import machine_kind

    distributed = pytest.importorskip("dask.distributed")
    here = machine_kind()
    if ", libm fma," not in here:
        pytest.skip(f"this machine's C library takes no FMA variant ({here})")
    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "objects" / "box.obj", objects)
    out = tmp_path / "labels"
    args = ["--objects", objects, "--n", 4, "--out", out]
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.cpu.hwcaps=-AVX2,-FMA")  # the workers' environment
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        workers_kind = cluster.get_client().run(machine_kind).popitem()[1]
        result = run_annotate(*args, "--scheduler", cluster.scheduler_address)
    monkeypatch.delenv("GLIBC_TUNABLES")
    assert workers_kind != here and ", libm fma," not in workers_kind
    assert "kind of machine" not in result.output  # one kind labelled the folder
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["versions"]["machine"] == workers_kind
    again = run_annotate(*args, "--workers", 1)
    assert f"labelled so far on another kind of machine ({workers_kind}); this one is {here}" in again.output
    assert (
        json.loads((out / "_manifest.json").read_text())["versions"]["machine"] == f"{workers_kind} | {here}"
    )
