"""The store's journal: saves append what changed, kills and corrupt lines, compaction, old folders.

Unit tests of annotator.store on label tables from the real sampler (no simulation), as
tests/test_store.py; a kill is a real SIGKILL of a child process in the middle of a journal write.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from helpers import synthetic_labels

import annotator.dataset as ds
from annotator.config import AnnotatorConfig
from annotator.store import (
    JOURNAL_NAME,
    MANIFEST_NAME,
    LockedError,
    ManifestUnreadableError,
    RunSpec,
    Store,
    names,
)
from annotator.store.journal import decode, encode
from annotator.store.manifest import MANIFEST_VERSION, Manifest, load_state

N = 10
SRC = "ab" * 32


def _spec() -> RunSpec:
    return RunSpec(seed=0, n=N, trials=1, scale=None, chunk_size=5, config=AnnotatorConfig().to_dict())


def _open(folder: Path, **kwargs) -> Store:
    store = Store(folder, _spec())
    store.open(**kwargs)
    return store


def _write(store: Store, oid: str, finish: bool = True) -> None:
    whole = synthetic_labels(oid)
    store.write_chunk(oid, whole.iloc[:5], 0, SRC)
    store.write_chunk(oid, whole.iloc[5:], 5, SRC)
    if finish:
        store.finish_object(oid, SRC)


def _lines(folder: Path) -> list[bytes]:
    return (folder / JOURNAL_NAME).read_bytes().splitlines(keepends=True)


def _ops(folder: Path) -> list[str]:
    return [decode(line)["op"] for line in _lines(folder)]


def test_a_save_appends_what_changed_and_leaves_the_manifest_alone(tmp_path: Path) -> None:
    store = _open(tmp_path)
    manifest_before = (tmp_path / MANIFEST_NAME).read_bytes()
    _write(store, "a")
    store.record_info("a", {"geometry": {"object_id": "a", "mass": 0.1}})
    store.fail_object("b", "no triangles")
    store.save(force=True)
    assert (tmp_path / MANIFEST_NAME).read_bytes() == manifest_before  # not rewritten by any save
    assert _ops(tmp_path) == ["begin", "chunk", "chunk", "done", "info", "failed"]
    # a reader during the run sees what was saved: the manifest with its journal applied
    seen = Manifest.load(tmp_path)
    assert set(seen.objects_done) == {"a"} and seen.objects_failed == {"b": "no triangles"}
    assert seen.objects_done == store.manifest.objects_done and not seen.chunks_done
    assert ds.load_geometry(tmp_path).loc["a", "mass"] == 0.1  # annotator.dataset reads it too
    store.close()


def test_closing_compacts_into_the_manifest_and_a_clean_resume_appends(tmp_path: Path) -> None:
    store = _open(tmp_path)
    _write(store, "a")
    _write(store, "b", finish=False)
    store.close()
    assert _ops(tmp_path) == ["begin"]  # folded into the manifest
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert data["manifest_version"] == MANIFEST_VERSION and set(data["objects_done"]) == {"a"}
    assert set(data["chunks_done"]["b"]["files"]) == {"0-5", "5-10"}
    assert decode(_lines(tmp_path)[0])["journal"] == data["journal"]
    inode = (tmp_path / MANIFEST_NAME).stat().st_ino
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": SRC})
    assert resume.done == {"a"} and resume.chunks == {"b": {(0, 5), (5, 10)}}
    assert (tmp_path / MANIFEST_NAME).stat().st_ino == inode  # opening a closed run rewrote nothing
    store.finish_object("b", SRC)
    assert _ops(tmp_path) == ["begin", "header", "done"]
    store.close()
    assert _ops(tmp_path) == ["begin"] and set(Manifest.load(tmp_path).objects_done) == {"a", "b"}


_KILLED = """
import os, signal, sys
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from helpers import synthetic_labels
from annotator.config import AnnotatorConfig
from annotator.store import RunSpec, Store
store = Store(Path(sys.argv[1]), RunSpec(0, 10, 1, None, 5, AnnotatorConfig().to_dict()))
store.open()
for oid in ("a", "b"):
    whole = synthetic_labels(oid)
    store.write_chunk(oid, whole.iloc[:5], 0, "ab" * 32)
    store.write_chunk(oid, whole.iloc[5:], 5, "ab" * 32)
    store.finish_object(oid, "ab" * 32)
whole = synthetic_labels("c")
store.write_chunk("c", whole.iloc[:5], 0, "ab" * 32)
store.write_chunk("c", whole.iloc[5:], 5, "ab" * 32)
real_write = os.write
def half_then_killed(fd, data):  # the journal's append of c's merge: half of it, then SIGKILL
    real_write(fd, bytes(data)[: len(data) // 2])
    os.kill(os.getpid(), signal.SIGKILL)
os.write = half_then_killed
store.finish_object("c", "ab" * 32)
"""


def test_a_run_killed_mid_journal_write_resumes_losing_nothing_finished(tmp_path: Path) -> None:
    tests = str(Path(__file__).parent)
    proc = subprocess.run([sys.executable, "-c", _KILLED, str(tmp_path), tests], capture_output=True)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    last = _lines(tmp_path)[-1]
    assert not last.endswith(b"\n") and decode(last) is None  # a torn line
    seen = Manifest.load(tmp_path)  # a reader ignores the torn line
    # c's second chunk was written with its merge (at most SAVE_SECONDS of chunks go with a kill)
    assert set(seen.objects_done) == {"a", "b"} and set(seen.chunks_done["c"]["files"]) == {"0-5"}
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": SRC, "c": SRC})
    assert resume.done == {"a", "b"} and resume.chunks == {"c": {(0, 5)}}
    assert not (tmp_path / names.chunk_filename("c", 5, 10)).exists()  # unvouched: removed, redone
    assert _ops(tmp_path) == ["begin", "header"]  # the torn journal was compacted away at opening
    store.write_chunk("c", synthetic_labels("c").iloc[5:], 5, SRC)
    store.finish_object("c", SRC)
    store.close()
    want = pd.concat([synthetic_labels(o) for o in "abc"], ignore_index=True)
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.validate_labels(want))


def _three_finished(folder: Path) -> None:
    """a, b, c finished in a run that was killed before it closed (the journal holds them)."""
    store = _open(folder)
    for oid in "abc":
        _write(store, oid)
    store._close_journal()
    store.lock.release()  # a kill: no compaction


def _flip(line: bytes) -> bytes:
    i = line.index(b'"oid"')
    return line[:i] + b'"OID"' + line[i + 5 :]


@pytest.mark.parametrize(
    "damage, named",
    [
        (lambda lines, i: lines.__setitem__(i, _flip(lines[i])), "does not verify"),
        (lambda lines, i: lines.insert(i, b"\x00\xffgarbage that is not a record\n"), "does not verify"),
        (
            lambda lines, i: lines.insert(i, encode({"op": "done", "oid": "a", "record": {"file": "../x"}})),
            "is not a record of this tool",
        ),
    ],
    ids=["flipped-byte", "garbage-line", "checksummed-nonsense"],
)
def test_a_corrupt_journal_line_is_one_line_and_repair_redoes_what_it_recorded(tmp_path, damage, named):
    _three_finished(tmp_path)
    lines = _lines(tmp_path)
    i = next(k for k, line in enumerate(lines) if decode(line)["op"] == "done" and b'"oid":"b"' in line)
    damage(lines, i)
    (tmp_path / JOURNAL_NAME).write_bytes(b"".join(lines))
    expected = f"{JOURNAL_NAME}: line {i + 1} {named}.*--repair"
    with pytest.raises(ManifestUnreadableError, match=expected) as info:
        _open(tmp_path)
    assert "\n" not in str(info.value)
    store = _open(tmp_path, repair=True)
    resume = store.reconcile({"a": SRC, "b": SRC, "c": SRC})
    assert {"a", "c"} <= resume.done
    if "b" not in resume.done:  # its merge's record was the line lost: b's file is not vouched, redone
        assert not (tmp_path / names.object_filename("b")).exists()
        assert any(JOURNAL_NAME in note for note in store.notes)
        _write(store, "b")
    store.close()
    want = pd.concat([synthetic_labels(o) for o in "abc"], ignore_index=True)
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.validate_labels(want))
    assert _ops(tmp_path) == ["begin"]


def test_a_damaged_first_line_is_one_line_and_repair_applies_the_rest(tmp_path: Path) -> None:
    _three_finished(tmp_path)
    lines = _lines(tmp_path)
    (tmp_path / JOURNAL_NAME).write_bytes(b"garbage\n" + b"".join(lines[1:]))
    with pytest.raises(ManifestUnreadableError, match=f"{JOURNAL_NAME}: line 1 does not verify.*--repair"):
        _open(tmp_path)
    store = _open(tmp_path, repair=True)
    assert store.reconcile({"a": SRC, "b": SRC, "c": SRC}).done == {"a", "b", "c"}
    store.close()


def test_a_torn_last_line_is_ignored_without_repair(tmp_path: Path) -> None:
    _three_finished(tmp_path)
    lines = _lines(tmp_path)
    (tmp_path / JOURNAL_NAME).write_bytes(b"".join(lines[:-1]) + lines[-1][:-9])  # c's merge, cut short
    store = _open(tmp_path)
    resume = store.reconcile({"a": SRC, "b": SRC, "c": SRC})
    # c's chunks were removed by its merge, whose record is the line cut short: c is redone whole
    assert resume.done == {"a", "b"} and not resume.chunks.get("c")
    assert not (tmp_path / names.object_filename("c")).exists()  # its unvouched file went: redone
    _write(store, "c")
    store.close()
    want = pd.concat([synthetic_labels(o) for o in "abc"], ignore_index=True)
    pd.testing.assert_frame_equal(ds.load_labels(tmp_path), ds.validate_labels(want))


def test_a_journal_the_manifest_already_holds_is_not_applied_again(tmp_path: Path) -> None:
    store = _open(tmp_path)
    _write(store, "a")
    store.fail_object("b", "bad mesh")
    store.save(force=True)
    old_journal = (tmp_path / JOURNAL_NAME).read_bytes()
    store.compact()  # the manifest now holds a and b's failure and names a new journal ...
    store._close_journal()
    store.lock.release()
    fail_a = encode({"op": "failed", "oid": "a", "error": "x", "at": "t"})
    (tmp_path / JOURNAL_NAME).write_bytes(old_journal + fail_a)
    # ... and a kill left the old journal in place (here with a line that would fail a): not applied
    state = load_state(tmp_path)
    assert set(state.manifest.objects_done) == {"a"} and state.pending == 0


def test_a_folder_of_the_previous_version_resumes_and_is_written_as_this_one(tmp_path: Path) -> None:
    store = _open(tmp_path)
    _write(store, "a")
    _write(store, "b", finish=False)
    store.close()
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    del data["journal"]
    data["manifest_version"] = 3  # as the previous version wrote it: no journal
    (tmp_path / MANIFEST_NAME).write_text(json.dumps(data))
    (tmp_path / JOURNAL_NAME).unlink()
    assert set(Manifest.load(tmp_path).objects_done) == {"a"}  # the tools read it as it is
    store = _open(tmp_path)
    assert store.reconcile({"a": SRC, "b": SRC}).chunks == {"b": {(0, 5), (5, 10)}}
    store.finish_object("b", SRC)
    store.close()
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert data["manifest_version"] == MANIFEST_VERSION and set(data["objects_done"]) == {"a", "b"}


def test_a_second_run_is_refused_while_the_first_appends(tmp_path: Path) -> None:
    store = _open(tmp_path)
    _write(store, "a")
    with pytest.raises(LockedError):
        _open(tmp_path)
    _write(store, "b")
    store.close()
    assert set(Manifest.load(tmp_path).objects_done) == {"a", "b"}


def test_the_scale_bench_drives_the_store_and_resumes_every_object(tmp_path: Path) -> None:
    """bench.scale store-one at 30 objects: recorded, compacted, resumed with every object done."""
    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "bench.scale", "store-one", "--objects", "30", "--tmp", str(tmp_path)]
    proc = subprocess.run(cmd, cwd=root, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    figures = json.loads(proc.stdout.strip().splitlines()[-1])
    assert figures["objects"] == 30 and figures["manifest_mb"] > 0
    assert not list(tmp_path.iterdir())  # its folder of objects and labels is gone
