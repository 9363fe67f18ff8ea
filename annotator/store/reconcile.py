"""Opening an output folder: check what it holds against its manifest and the run, and resume.

Every file the manifest vouches for is verified against its checksum before it is trusted;
files of this tool that no manifest vouches for (written just before a kill) are removed and
redone; objects whose source changed are redone; objects no longer among the inputs are set aside
in ``_stale/``. ``--overwrite`` and ``--repair`` act on the tool's own files only.
"""

from __future__ import annotations

import contextlib
import json
import logging
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
from annotator.store.errors import ManifestUnreadableError, RunMismatchError
from annotator.store.files import (
    file_sha256,
    is_own_file,
    is_temp_file,
    output_error,
    read_labels,
    read_mark,
    verify_labels,
)
from annotator.store.manifest import Manifest, utc_now
from annotator.store.names import (
    ARTIFACTS_DIR,
    MANIFEST_NAME,
    STALE_DIR,
    chunk_filename,
    object_filename,
    object_stem,
)

if TYPE_CHECKING:
    from annotator.store.store import Store

log = logging.getLogger(__name__)


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
    return sorted(p for p in out_dir.iterdir() if p.is_file() and p.suffix == ".parquet")


def load_folder(store: Store, *, overwrite: bool, repair: bool) -> None:
    """Read, check and clean the folder's manifest and files for ``store``'s run."""
    out = store.out_dir
    if overwrite:
        store.require_writable()
        remove_own_files(out)
        store.manifest = Manifest.fresh(store.spec)
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
        own = [p for p in parquet_files(out) if is_own_file(p)]
        if own and not repair:
            raise ManifestUnreadableError(
                f"{out} holds {len(own)} label file(s) but no {MANIFEST_NAME}; pass --repair to rebuild "
                "it from the files that verify, or --overwrite to start over"
            )
        manifest = rebuild(store) if own else Manifest.fresh(store.spec)
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


def remove_own_files(out_dir: Path) -> None:
    """--overwrite: the tool's files only (marked, or listed by an older manifest), never a user's."""
    listed: set[str] = set()
    with contextlib.suppress(Exception):
        data = json.loads(Manifest.path(out_dir).read_text())
        listed |= {e["file"] for e in data.get("objects_done", {}).values()}
        for entry in data.get("chunks_done", {}).values():
            listed |= {r["file"] if isinstance(r, dict) else r for r in entry["files"].values()}
    removed = 0
    for p in parquet_files(out_dir):
        if p.name in listed or is_own_file(p):
            p.unlink()
            removed += 1
    for p in out_dir.iterdir():
        if p.is_file() and is_temp_file(p):
            p.unlink()
    removed += remove_artifacts(out_dir / ARTIFACTS_DIR, keep=set())
    stale = out_dir / STALE_DIR
    if stale.is_dir():
        for p in stale.iterdir():
            if p.suffix == ".parquet" and read_mark(p) is not None:
                p.unlink()
                removed += 1
        removed += remove_artifacts(stale / ARTIFACTS_DIR, keep=set())
        with contextlib.suppress(OSError):
            stale.rmdir()
    Manifest.path(out_dir).unlink(missing_ok=True)
    if removed:
        log.info("--overwrite: removed %d label files from %s", removed, out_dir)


def rebuild(store: Store) -> Manifest:
    """--repair: a manifest from the marked files of this run that verify; the rest removed."""
    store.require_writable()
    out, spec = store.out_dir, store.spec
    manifest = Manifest.fresh(spec)
    kept = dropped = 0
    for p in parquet_files(out):
        if not is_own_file(p):
            continue
        mark = read_mark(p) or {}
        oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
        why = verify_labels(p, spec.key, oid, start, stop) if isinstance(oid, str) else "no id"
        artifacts = mark.get("artifacts", {})
        if why is None and not artifacts_ok(mark):
            why = "its mark lists artifacts the tool does not write"
        if why is None:
            why = check_artifacts(out, artifacts)
        is_object = why is None and p.name == object_filename(oid) and start == 0 and stop == spec.count(oid)
        is_chunk = why is None and p.name == chunk_filename(oid, start, stop)
        if not (is_object or is_chunk):
            why = why or "unexpected name"
            log.warning("--repair: %s cannot be trusted (%s); removing it", p.name, why)
            p.unlink()
            dropped += 1
            continue
        record: dict[str, Any] = {"file": p.name, "sha256": file_sha256(p), "n": stop - start}
        if artifacts:
            record["artifacts"] = artifacts
        source = str(mark.get("source_sha256", ""))
        if is_object:
            from annotator.store.store import object_stats

            stats = object_stats(read_labels(out, [p.name]))
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
    store.notes.append(f"manifest rebuilt from {kept} label files that verify ({dropped} removed)")
    log.warning("rebuilt %s from %d label files (%d removed)", Manifest.path(out), kept, dropped)
    return manifest


def verify(store: Store) -> None:
    """Every file the manifest vouches for must exist and match its checksum; else redo it."""
    m = store.manifest
    for oid, entry in list(m.objects_done.items()):
        why = check_record(store.out_dir, entry)
        if why:
            _distrust(store, entry, why, oid)
            del m.objects_done[oid]
    for oid, entry in list(m.chunks_done.items()):
        for key, rec in list(entry["files"].items()):
            why = check_record(store.out_dir, rec)
            if why:
                _distrust(store, rec, why, oid)
                del entry["files"][key]


def _distrust(store: Store, record: dict[str, Any], why: str, oid: str) -> None:
    line = f"{record['file']} {why}: redoing those labels of {oid}"
    log.warning("%s", line)
    store.notes.append(line)
    if not store.read_only:
        delete_record(store.out_dir, record)


def clean_unvouched(store: Store) -> None:
    """The tool's files the manifest does not vouch for (a chunk written just before a kill,
    a run stopped between writing and recording) go, and leftover temporary files."""
    if store.read_only:
        return
    out = store.out_dir
    vouched = store.manifest.referenced_files()
    for p in parquet_files(out):
        if p.name in vouched:
            continue
        if is_own_file(p):
            p.unlink()
            log.info("removed %s: written but never recorded, or unreadable (redone)", p.name)
        else:
            log.warning("%s is not a label file of this tool; read_parquet will read it too", p)
    for p in out.iterdir():
        if p.is_file() and is_temp_file(p):
            p.unlink(missing_ok=True)
    removed = remove_artifacts(out / ARTIFACTS_DIR, keep=store.manifest.referenced_artifacts())
    if removed:
        log.info("removed %d artifact files that were written but never recorded (redone)", removed)


def match_sources(store: Store, sources: dict[str, str]) -> Resume:
    """Match the folder to the objects of this run, ``sources``: object id -> source digest.

    Objects whose source changed lose their labels (redone); objects no longer present have
    their labels moved to ``_stale/`` (left out of the dataset); failed ones are retried.
    """
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
    for oid in list(m.objects_info):
        if oid not in sources:
            del m.objects_info[oid]
    if (stale or changed) and not store.read_only:
        store.save(force=True)
    chunks = {
        oid: {tuple(int(v) for v in key.split("-")) for key in entry["files"]}
        for oid, entry in m.chunks_done.items()
    }
    return Resume(set(m.objects_done), chunks, stale, changed)


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
            if (out / name).exists():
                shutil.move(out / name, stale / name)
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
