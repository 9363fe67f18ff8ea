"""Opening an output folder: check what it holds against its manifest and the run, and resume.

Every file the manifest vouches for is verified against its checksum before it is trusted;
files this folder's run wrote that no manifest vouches for (written just before a kill) are
removed and redone; objects whose source changed are redone; objects no longer among the inputs
are set aside in ``_stale/``.

What the tool may touch (:func:`annotator.store.files.owner_of`): files marked by this folder's
run, under the names their marks give, and files named as it names label files that can no longer
be read (its own, corrupted). Everything else -- a user's files, another run's label files copied
in, links, FIFOs -- is never opened, deleted, moved or adopted, in any mode: it is named in the
run's notes (its summary), and a run that would have to write where such a file lies is refused.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from annotator.store.artifacts import (
    artifacts_ok,
    check_artifacts,
    check_record,
    delete_record,
    remove_artifacts,
)
from annotator.store.errors import ManifestUnreadableError, RunMismatchError, StoreError
from annotator.store.files import (
    Owner,
    file_sha256,
    is_regular_file,
    is_temp_file,
    output_error,
    owner_of,
    read_labels,
    read_mark,
    verify_labels,
)
from annotator.store.manifest import Manifest, read_manifest_json, utc_now
from annotator.store.names import (
    ARTIFACTS_DIR,
    MANIFEST_NAME,
    STALE_DIR,
    is_label_filename,
    merging_name,
    object_filename,
    object_stem,
)

if TYPE_CHECKING:
    from annotator.store.store import Store

log = logging.getLogger(__name__)

_CHUNK_RANGE = re.compile(r"\.\d{6,7}-\d{6,7}$")  # a chunk file's range after its object's stem


class ForeignFileError(StoreError):
    """The run would have to write where a file it did not write lies (exit code 2)."""


@dataclass
class Resume:
    """What an opened folder already holds for the current objects.

    done : finished object ids; chunks : object id -> set of (start, stop) finished;
    stale : ids no longer among the objects (their labels moved to ``_stale/``);
    changed : ids whose source changed (their labels deleted, to be redone).
    """

    done: set[str]
    chunks: dict[str, set[tuple[int, int]]]
    stale: list[str]
    changed: list[str]


def parquet_files(out_dir: Path) -> list[Path]:
    """Every ``.parquet`` entry of the folder (files or not: the caller asks who owns each)."""
    return sorted(p for p in out_dir.iterdir() if p.suffix == ".parquet")


def _note_foreign(store: Store, path: Path, owner: Owner) -> None:
    what = {
        Owner.OTHER_RUN: "written by another run",
        Owner.USER: "not a label file of this tool",
        Owner.NOT_A_FILE: "not a regular file",
    }[owner]
    line = f"{path.name}: {what}; left as it is"
    if owner is not Owner.NOT_A_FILE:
        line += " (pandas.read_parquet of the folder reads it too)"
    if line not in store.notes:
        store.notes.append(line)
        log.warning("%s", line)


def load_folder(store: Store, *, overwrite: bool, repair: bool) -> None:
    """Read, check and clean the folder's manifest and files for ``store``'s run."""
    out = store.out_dir
    if overwrite:
        store.require_writable()
        run_id = remove_own_files(store)
        store.manifest = Manifest.fresh(store.spec, run_id)
        store.save(force=True)
        return
    try:
        manifest = Manifest.load(out)
    except ManifestUnreadableError as exc:
        if not repair:
            raise ManifestUnreadableError(
                f"{exc}; pass --repair to rebuild it from the label files that verify, or --overwrite "
                "to start over"
            ) from exc
        manifest = None
    if manifest is None:
        marked = [p for p in parquet_files(out) if read_mark(p) is not None]
        if marked and not repair:
            raise ManifestUnreadableError(
                f"{out} holds {len(marked)} label file(s) but no {MANIFEST_NAME}; pass --repair to rebuild "
                "it from the files that verify, or --overwrite to start over"
            )
        manifest = rebuild(store) if marked else Manifest.fresh(store.spec)
    else:
        diffs = store.spec.differences(manifest.run)
        if diffs:
            shown = "; ".join(diffs[:4]) + (f"; and {len(diffs) - 4} more" if len(diffs) > 4 else "")
            raise RunMismatchError(
                f"{out} holds a run with other settings ({shown}); pass --overwrite to start over or "
                "choose another --out"
            )
    store.manifest = manifest
    verify(store)
    clean_unvouched(store)
    if not store.read_only:
        store.save(force=True)


def _folder_run_id(out_dir: Path, run_key: str | None = None) -> str | None:
    """Without a readable manifest: the run most of the folder's marked label files belong to
    (only those of ``run_key`` if given); None if none carries a run id."""
    counts: collections.Counter[str] = collections.Counter()
    for p in parquet_files(out_dir):
        mark = read_mark(p)
        if (
            mark
            and isinstance(mark.get("run_id"), str)
            and (run_key is None or mark.get("run_key") == run_key)
        ):
            counts[mark["run_id"]] += 1
    if not counts:
        return None
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[0][0]


def _recorded_run_id(out_dir: Path) -> tuple[bool, str | None, set[str]]:
    """(readable, run id, listed label files) of the folder's manifest, schema or not."""
    with contextlib.suppress(Exception):
        data = read_manifest_json(Manifest.path(out_dir))
        run_id = data.get("run_id") if isinstance(data.get("run_id"), str) else None
        listed = {e["file"] for e in data.get("objects_done", {}).values()}
        for entry in data.get("chunks_done", {}).values():
            listed |= {r["file"] for r in entry["files"].values()}
        return True, run_id, {name for name in listed if is_label_filename(name)}
    return False, None, set()


def remove_own_files(store: Store) -> str | None:
    """--overwrite: remove the files of this folder's run (its manifest's, or, without one, the run
    most of its marked files belong to), leftovers and the manifest; never a user's file or another
    run's. Returns the folder's run id, which the new run keeps."""
    out = store.out_dir
    readable, run_id, listed = _recorded_run_id(out)
    if not readable:
        run_id = _folder_run_id(out)
    removed = 0
    for p in parquet_files(out):
        owner = owner_of(p, run_id)
        if owner in (Owner.THIS_RUN, Owner.CORRUPT) or (owner is Owner.OTHER_RUN and p.name in listed):
            p.unlink()
            removed += 1
        else:
            _note_foreign(store, p, owner)
    for p in out.iterdir():
        if is_temp_file(p) and is_regular_file(p):
            p.unlink()
    removed += remove_artifacts(out / ARTIFACTS_DIR, keep=set())
    stale = out / STALE_DIR
    if stale.is_dir() and not stale.is_symlink():
        for p in stale.iterdir():
            if p.suffix == ".parquet" and owner_of(p, run_id) in (Owner.THIS_RUN, Owner.CORRUPT):
                p.unlink()
                removed += 1
        removed += remove_artifacts(stale / ARTIFACTS_DIR, keep=set())
        with contextlib.suppress(OSError):
            stale.rmdir()
    manifest = Manifest.path(out)
    if is_regular_file(manifest):
        manifest.unlink()
    if removed:
        log.info("--overwrite: removed %d label files from %s", removed, out)
    return run_id


def rebuild(store: Store) -> Manifest:
    """--repair: a manifest from the files of this run (its settings; the run id most of them carry)
    that verify. Files that do not are left as they are and named."""
    store.require_writable()
    out, spec = store.out_dir, store.spec
    run_id = _folder_run_id(out, spec.key)
    manifest = Manifest.fresh(spec, run_id)
    kept = left = 0
    for p in parquet_files(out):
        owner = owner_of(p, run_id)
        if owner is not Owner.THIS_RUN:
            if owner is Owner.CORRUPT:
                p.unlink()  # named as the tool names its files, and unreadable: its own, broken
                store.notes.append(f"{p.name}: unreadable; removed (its labels are redone)")
            else:
                _note_foreign(store, p, owner)
                left += owner is Owner.OTHER_RUN
            continue
        record = _verified_record(out, p, spec)
        if isinstance(record, str):
            _note_foreign(store, p, Owner.OTHER_RUN)
            log.warning("--repair: %s cannot be trusted (%s); left as it is", p.name, record)
            left += 1
            continue
        oid, start, stop, source = record.pop("_object")
        if p.name == object_filename(oid):
            stats = _stats(read_labels(out, [p.name]))
            manifest.objects_done[oid] = {
                **record,
                "source_sha256": source,
                "stats": stats,
                "time": utc_now(),
            }
        else:
            entry = manifest.chunks_done.setdefault(oid, {"source_sha256": source, "files": {}})
            entry["files"][f"{start}-{stop}"] = record
        kept += 1
    for oid in manifest.objects_done:  # an object's file supersedes its chunks
        manifest.chunks_done.pop(oid, None)
    store.notes.append(f"manifest rebuilt from {kept} label files that verify ({left} left as they are)")
    log.warning("rebuilt %s from %d label files (%d left as they are)", Manifest.path(out), kept, left)
    return manifest


def _verified_record(out: Path, path: Path, spec) -> dict[str, Any] | str:
    """The manifest record of a marked file of this run that verifies, or why it does not."""
    mark = read_mark(path) or {}
    oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
    why = verify_labels(path, spec.key, oid, start, stop) if isinstance(oid, str) else "no id"
    artifacts = mark.get("artifacts", {})
    if why is None and not artifacts_ok(mark):
        why = "its mark lists artifacts the tool does not write"
    if why is None:
        why = check_artifacts(out, artifacts)
    if why is None and path.name == object_filename(oid) and not (start == 0 and stop == spec.count(oid)):
        why = "not all of its object's candidates"
    if why is not None:
        return why
    record: dict[str, Any] = {"file": path.name, "sha256": file_sha256(path), "n": stop - start}
    if artifacts:
        record["artifacts"] = artifacts
    record["_object"] = (oid, start, stop, str(mark.get("source_sha256", "")))
    return record


def _stats(df) -> dict[str, Any]:
    from annotator.store.store import object_stats

    return object_stats(df)


def verify(store: Store) -> None:
    """Every file the manifest vouches for must be a regular file matching its checksum; else
    its labels are redone. A merge that stopped after its chunks were removed is completed."""
    m = store.manifest
    for oid, entry in list(m.objects_done.items()):
        _complete_merge(store, entry)
        why = _check(store, entry)
        if why:
            _distrust(store, entry, why, oid)
            del m.objects_done[oid]
    for oid, entry in list(m.chunks_done.items()):
        for key, rec in list(entry["files"].items()):
            why = _check(store, rec)
            if why:
                _distrust(store, rec, why, oid)
                del entry["files"][key]


def _check(store: Store, record: dict[str, Any]) -> str | None:
    path = store.out_dir / record["file"]
    if (path.exists() or path.is_symlink()) and not is_regular_file(path):
        return "is not a regular file"
    return check_record(store.out_dir, record)


def _complete_merge(store: Store, record: dict[str, Any]) -> None:
    """A merged file written and recorded, its chunks removed, but not yet renamed into place
    (the run stopped in between): put it in place."""
    out = store.out_dir
    final, hidden = out / record["file"], out / merging_name(record["file"])
    if store.read_only or final.exists() or not is_regular_file(hidden):
        return
    if check_record(out, {**record, "file": hidden.name}) is None:
        os.replace(hidden, final)
        log.info("%s: completed a merge the last run stopped in", record["file"])


def _distrust(store: Store, record: dict[str, Any], why: str, oid: str) -> None:
    path = store.out_dir / record["file"]
    owner = owner_of(path, store.manifest.run_id) if path.exists() or path.is_symlink() else None
    if owner in (Owner.OTHER_RUN, Owner.USER, Owner.NOT_A_FILE):
        _note_foreign(store, path, owner)  # recorded name, but not this run's file: never touched
        return
    line = f"{record['file']} {why}: redoing those labels of {oid}"
    log.warning("%s", line)
    store.notes.append(line)
    if not store.read_only:
        delete_record(store.out_dir, record)


def clean_unvouched(store: Store) -> None:
    """Files of this run the manifest does not vouch for (a chunk written just before a kill, a run
    stopped between writing and recording), and leftover temporary files, go; every other file is
    left as it is and named."""
    if store.read_only:
        return
    out = store.out_dir
    vouched = store.manifest.referenced_files()
    for p in parquet_files(out):
        if p.name in vouched:
            continue
        owner = owner_of(p, store.manifest.run_id)
        if owner in (Owner.THIS_RUN, Owner.CORRUPT):
            p.unlink()
            log.info("removed %s: written but never recorded, or unreadable (redone)", p.name)
        else:
            _note_foreign(store, p, owner)
    for p in out.iterdir():
        if is_temp_file(p) and is_regular_file(p):
            p.unlink(missing_ok=True)
    removed = remove_artifacts(out / ARTIFACTS_DIR, keep=store.manifest.referenced_artifacts())
    if removed:
        log.info("removed %d artifact files that were written but never recorded (redone)", removed)


def match_sources(store: Store, sources: dict[str, str]) -> Resume:
    """Match the folder to the objects of this run, ``sources``: object id -> source digest.

    Objects whose source changed lose their labels (redone); objects no longer present have
    their labels moved to ``_stale/`` (left out of the dataset); failed ones are retried. A file
    this run did not write lying where it must write an object's labels refuses the run
    (:class:`ForeignFileError`).
    """
    _refuse_foreign_at(store, sources)
    m = store.manifest
    stale, changed = [], []
    for oid in sorted(set(m.objects_done) | set(m.chunks_done)):
        recorded = (m.objects_done.get(oid) or m.chunks_done.get(oid))["source_sha256"]
        if oid not in sources:
            stale.append(oid)
            _set_aside(store, oid)
        elif recorded != sources[oid]:
            changed.append(oid)
            _forget(store, oid)
            store.notes.append(f"{oid}: its source changed since its labels were made; redone")
    for oid in stale:
        store.notes.append(f"{oid}: no longer among the objects; its labels moved to {STALE_DIR}/")
    m.objects_failed.clear()
    m.objects_planned = sorted(sources)
    for oid in list(m.objects_info):
        if oid not in sources:
            del m.objects_info[oid]
    if not store.read_only:
        store.save(force=True)
    chunks = {
        oid: {tuple(int(v) for v in key.split("-")) for key in entry["files"]}
        for oid, entry in m.chunks_done.items()
    }
    return Resume(set(m.objects_done), chunks, stale, changed)


def _refuse_foreign_at(store: Store, sources: dict[str, str]) -> None:
    """Refuse the run if a file it did not write lies under a name it writes for its objects."""
    stems = {object_stem(oid) for oid in sources}
    vouched = store.manifest.referenced_files()
    blocking = []
    for p in parquet_files(store.out_dir):
        stem = _CHUNK_RANGE.sub("", p.name[: -len(".parquet")])
        if stem not in stems or (p.name in vouched and is_regular_file(p)):
            continue
        if owner_of(p, store.manifest.run_id) not in (Owner.THIS_RUN, Owner.CORRUPT):
            blocking.append(p.name)
    if blocking:
        shown = ", ".join(blocking[:3]) + (f" and {len(blocking) - 3} more" if len(blocking) > 3 else "")
        raise ForeignFileError(
            f"{store.out_dir} holds {shown}, where this run writes labels, but this run did not write "
            "it; move it away or choose another --out (the tool never deletes a file it did not write)"
        )


def records_of(manifest: Manifest, oid: str) -> list[dict[str, Any]]:
    """The label file records of ``oid`` (its merged file, or its chunks)."""
    records = [manifest.objects_done[oid]] if oid in manifest.objects_done else []
    if oid in manifest.chunks_done:
        records += list(manifest.chunks_done[oid]["files"].values())
    return records


def _forget(store: Store, oid: str) -> None:
    store.require_writable()
    m = store.manifest
    for record in records_of(m, oid):
        delete_record(store.out_dir, record)
    m.objects_done.pop(oid, None)
    m.chunks_done.pop(oid, None)
    m.objects_info.pop(oid, None)


def _set_aside(store: Store, oid: str) -> None:
    store.require_writable()
    out = store.out_dir
    stale = out / STALE_DIR
    m = store.manifest
    try:
        stale.mkdir(exist_ok=True)
        for record in records_of(m, oid):
            name = record["file"]
            if is_regular_file(out / name):
                _move_keeping(out / name, stale / name, m.run_id)
        views = out / ARTIFACTS_DIR / object_stem(oid)
        if views.is_dir():  # the object's artifacts go with its labels
            target = stale / ARTIFACTS_DIR / views.name
            target.parent.mkdir(parents=True, exist_ok=True)
            if target.exists():
                shutil.rmtree(target)
            shutil.move(views, target)
    except OSError as exc:
        raise output_error(stale, exc) from exc
    m.objects_done.pop(oid, None)
    m.chunks_done.pop(oid, None)
    m.objects_info.pop(oid, None)


def _move_keeping(source: Path, target: Path, run_id: str | None) -> None:
    """Move ``source`` to ``target``; a file already there that this run did not write is kept
    (the moved file takes a numbered name beside it)."""
    k = 1
    while target.exists() or target.is_symlink():
        if owner_of(target, run_id) in (Owner.THIS_RUN, Owner.CORRUPT):
            break
        target = target.with_name(f"{source.stem}.{k}{source.suffix}")
        k += 1
    os.replace(source, target)
