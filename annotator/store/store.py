"""The output folder of one run: open it (lock, manifest, verification, resume), write to it.

Promises (docs/reliability.md): one run per folder at a time; the manifest binds the run's
settings and each object's source digest, so a resume never mixes; every file is checked against
its checksum before it is trusted; only files the tool wrote are ever deleted.

Bookkeeping: the manifest is written whole only when the store compacts (when it opens a folder a
run did not close, and when the run ends); every change in between is a journal line
(:mod:`annotator.store.journal`), so a save costs what changed and a resume reads the folder's
records once. Opening a folder surveys it (:mod:`annotator.store.survey`), plans what to do
(:mod:`annotator.store.reconcile`, pure) and applies the plan here.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import time
import uuid
from pathlib import Path
from typing import Any

import pandas as pd

import annotator.store.reconcile as reconcile
from annotator.store.artifacts import delete_record, tidy, write_artifact
from annotator.store.errors import JournalUnreadableError, ManifestUnreadableError, RunMismatchError
from annotator.store.files import (
    FileRecord,
    OutputError,
    Owner,
    atomic_write,
    is_regular_file,
    output_error,
    owner_of,
    read_labels,
    write_labels,
)
from annotator.store.journal import JournalWriter
from annotator.store.lock import RunLock, sigint_deferred
from annotator.store.manifest import (
    LoadedState,
    Manifest,
    RunSpec,
    canonical,
    journal_path,
    load_state,
    utc_now,
)
from annotator.store.names import (
    ARTIFACTS_DIR,
    MANIFEST_NAME,
    STALE_DIR,
    chunk_filename,
    merging_name,
    object_filename,
    object_stem,
)
from annotator.store.reconcile import FolderPlan, Resume
from annotator.store.stats import object_stats
from annotator.store.survey import Need, survey

log = logging.getLogger(__name__)

# Errors of the file system that mean "this folder cannot be written", not a bug.
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}

__all__ = ["Store", "object_stats"]


class Store:
    """One output folder for one run. ``open()`` locks and checks it; the runner then writes
    chunks, finishes and fails objects through it; ``close()`` saves, compacts and unlocks."""

    # The journal is written at most this often while chunks come in, always when an object is
    # merged or fails and when the run ends; a hard kill loses at most this many seconds of
    # chunks (unvouched chunk files are redone on resume).
    SAVE_SECONDS = 2.0

    def __init__(self, out_dir: Path, spec: RunSpec, *, labelled_here: bool = True) -> None:
        """``labelled_here``: this process's machine labels (its kind is recorded when the folder
        opens); False for a Dask run, whose workers' kinds are recorded as their results come
        (:meth:`note_machine`)."""
        self.out_dir = Path(out_dir)
        self.spec = spec
        self.labelled_here = labelled_here
        # the kinds of machine that labelled the folder before this run, and those of this run
        # (kind -> the host of the worker it was first seen on; None: this process's machine)
        self._machines_before: list[str] = []
        self._machines_now: dict[str, str | None] = {}
        self._mixed_note: str | None = None
        self._opened = False
        self.manifest = Manifest.fresh(spec)
        self.lock = RunLock(self.out_dir)
        self.read_only = False  # the folder cannot be written: only a finished run can be read
        self.notes: list[str] = []  # one line per thing the user should know (redone, removed)
        self._saved_at = 0.0
        self._journal: JournalWriter | None = None  # None: the next save compacts
        self._header: tuple[Any, Any] = (None, None)  # (objects_planned, gripper_folder) recorded
        # object id -> the stats of the one chunk of all its rows this process wrote: such an
        # object is finished without reading its rows back (finish_object)
        self._written_stats: dict[str, dict[str, Any]] = {}

    # --- opening -------------------------------------------------------------------------------

    def open(self, *, overwrite: bool = False, repair: bool = False) -> None:
        """Lock the folder and load, check and clean what it holds.

        Raises LockedError, RunMismatchError, ManifestUnreadableError (usage errors) or
        OutputError (the folder cannot be created).
        """
        out = self.out_dir
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise output_error(out, exc) from exc
        try:
            self.lock.acquire()
        except OutputError as exc:
            if exc.errno not in _READ_ONLY:
                raise
            self.read_only = True  # nobody can write here, so nobody needs the lock
            log.warning("%s", exc)
        try:
            self._load(overwrite=overwrite, repair=repair)
        except BaseException:
            self._close_journal()
            self.lock.release()
            raise
        self._opened = True

    def _load(self, *, overwrite: bool, repair: bool) -> None:
        out, spec = self.out_dir, self.spec
        if overwrite:
            self.require_writable()
            run_id, plan = reconcile.plan_overwrite(survey(out, Need.OVERWRITE))
            self.apply(plan)
            self.manifest = Manifest.fresh(spec, run_id)
            self._open_machines()
            self.compact()
            return
        try:
            state = load_state(out, repair=repair)
        except JournalUnreadableError:
            raise
        except ManifestUnreadableError as exc:
            if not repair:
                raise ManifestUnreadableError(
                    f"{exc}; pass --repair to rebuild it from the label files that verify, or --overwrite "
                    "to start over"
                ) from exc
            state = LoadedState(None)
        for line in state.skipped:
            self._note(line)
        manifest = state.manifest
        if manifest is None:
            listing = survey(out, Need.REPAIR if repair else Need.MARKS, run_key=spec.key)
            marked = [name for name in listing.parquet if listing.marks.get(name) is not None]
            if marked and not repair:
                raise ManifestUnreadableError(
                    f"{out} holds {len(marked)} label file(s) but no {MANIFEST_NAME}; pass --repair to "
                    "rebuild it from the files that verify, or --overwrite to start over"
                )
            if marked:
                self.require_writable()
                manifest, plan = reconcile.plan_rebuild(listing, spec)
                self.apply(plan)
                log.warning("rebuilt %s from the label files that verify", Manifest.path(out))
            else:
                manifest = Manifest.fresh(spec)
            state = LoadedState(manifest)
        else:
            diffs = spec.differences(manifest.run)
            if diffs:
                shown = "; ".join(diffs[:4]) + (f"; and {len(diffs) - 4} more" if len(diffs) > 4 else "")
                raise RunMismatchError(
                    f"{out} holds a run with other settings ({shown}); pass --overwrite to start over or "
                    "choose another --out"
                )
        self.manifest = manifest
        self._open_machines()
        self._header = (self.manifest.objects_planned, self.manifest.gripper_folder)
        if not self.read_only and state.journal_current and state.pending == 0:
            self._journal = JournalWriter(journal_path(out))  # a closed run's: appended to
        listing = survey(out, Need.RESUME, self.manifest)
        plan = reconcile.plan_resume(listing, self.manifest, read_only=self.read_only)
        self.apply(plan)
        if not self.read_only:
            self.save(force=True)  # without a journal to append to: a compaction

    def _open_machines(self) -> None:
        """The kinds of machine (:func:`annotator.versions.machine_kind`) the folder records as
        having labelled it; a folder with no labels yet records none (the manifest was made by the
        command's process, which in a Dask run labels nothing). Then this process's kind when it
        labels (``labelled_here``); a Dask run's workers report theirs with their results."""
        from annotator.store.manifest import MACHINES_SEPARATOR
        from annotator.versions import machine_kind

        m = self.manifest
        if not (m.objects_done or m.chunks_done or m.objects_failed):
            m.versions.pop("machine", None)
        recorded = m.versions.get("machine")
        self._machines_before = recorded.split(MACHINES_SEPARATOR) if recorded else []
        if self.labelled_here:
            self.note_machine(machine_kind())

    def note_machine(self, kind: str, host: str | None = None) -> None:
        """A process of kind ``kind`` labels for this run (``host``: the worker's; None: this
        process): added to the manifest's ``versions.machine`` (at once, for a worker's), and said
        in the summary when the folder was labelled so far on another kind, or when this run's
        processes are of more than one kind (a mixed Dask cluster): the same seed can settle a
        pile differently on them."""
        from annotator.store.manifest import MACHINES_SEPARATOR

        if not kind or kind in self._machines_now:
            return
        self._machines_now[kind] = host
        versions = self.manifest.versions
        kinds = versions["machine"].split(MACHINES_SEPARATOR) if versions.get("machine") else []
        if kind not in kinds:
            versions["machine"] = MACHINES_SEPARATOR.join([*kinds, kind])
            if self._opened and not self.read_only and self.lock.fd is not None:
                self.compact()  # a run killed later still records who labelled its chunks
        who = "this one" if host is None else f"the worker on {host}"
        if len(self._machines_now) > 1:
            seen = "; ".join(
                f"{k} ({'this machine' if h is None else h})" for k, h in self._machines_now.items()
            )
            line = (
                f"this run's workers are of {len(self._machines_now)} kinds of machine ({seen}): the same "
                "seed can settle a pile differently on them (docs/reliability.md), so scene labels may "
                "depend on which worker ran them"
            )
            if self._mixed_note in self.notes:
                self.notes[self.notes.index(self._mixed_note)] = line
            else:
                self._note(line)
            self._mixed_note = line
        elif self._machines_before and kind not in self._machines_before:
            before = MACHINES_SEPARATOR.join(self._machines_before)
            self._note(
                f"labelled so far on another kind of machine ({before}); "
                f"{who} is {kind}: the same seed can settle a pile differently on the two "
                "(docs/reliability.md), so scene labels may differ"
            )

    def require_writable(self) -> None:
        if self.read_only:
            raise output_error(self.out_dir, OSError(errno.EROFS, "the folder is read-only"))

    def reconcile(self, sources: dict[str, str]) -> Resume:
        """Match the folder to this run's objects (object id -> source digest); see
        :func:`annotator.store.reconcile.plan_sources`."""
        listing = survey(self.out_dir, Need.SOURCES, self.manifest)
        plan = reconcile.plan_sources(listing, self.manifest, sources)
        self.apply(plan)
        if not self.read_only:
            self.save(force=True)
        return reconcile.resume_of(self.manifest, plan)

    def apply(self, plan: FolderPlan) -> None:
        """Do what a reconcile plan says (:class:`annotator.store.reconcile.FolderPlan`)."""
        out = self.out_dir
        if plan.touches_files:
            self.require_writable()
        for name in plan.complete:
            os.replace(out / merging_name(name), out / name)
        for oid in plan.set_aside:
            self._set_aside(oid)
        for relpath in plan.unlink:
            try:
                (out / relpath).unlink(missing_ok=True)
            except OSError as exc:
                raise output_error(out / relpath, exc) from exc
        for relpath in plan.rmdirs:  # once empty of anything but the tool's list of what it wrote
            tidy(out / relpath)
        for op in plan.ops:
            self.record(op)
        for line in plan.notes:
            self._note(line)
        for line in plan.logs:
            log.info("%s", line)

    def _note(self, line: str) -> None:
        if line not in self.notes:
            self.notes.append(line)
            log.warning("%s", line)

    def _set_aside(self, oid: str) -> None:
        """Move the object's label files and artifacts to ``_stale/``."""
        out = self.out_dir
        stale = out / STALE_DIR
        try:
            stale.mkdir(exist_ok=True)
            for record in reconcile.records_of(self.manifest, oid):
                name = record["file"]
                if is_regular_file(out / name):
                    _move_keeping(out / name, stale / name, self.manifest.run_id)
            views = out / ARTIFACTS_DIR / object_stem(oid)
            if views.is_dir():  # the object's artifacts go with its labels
                target = stale / ARTIFACTS_DIR / views.name
                target.parent.mkdir(parents=True, exist_ok=True)
                if target.exists():
                    shutil.rmtree(target)
                shutil.move(views, target)
        except OSError as exc:
            raise output_error(stale, exc) from exc

    # --- writing -------------------------------------------------------------------------------

    def write_artifact(self, oid: str, name: str, data: bytes) -> dict[str, str]:
        """Write ``data`` atomically as artifact ``name`` of ``oid`` and return its record for
        :meth:`write_chunk`, which binds it to the labels it came with. An artifact written but
        never bound (the run stopped in between) is removed on resume. ``name``: a plain file name
        (ValueError otherwise)."""
        self.require_writable()
        return write_artifact(self.out_dir, oid, name, data)

    def write_chunk(
        self,
        oid: str,
        df: pd.DataFrame,
        start: int,
        source_sha256: str,
        artifacts: dict[str, dict[str, str]] | None = None,
    ) -> None:
        """Write and record one chunk (candidates ``start..start+len(df)-1``) with the records of
        the ``artifacts`` (name -> :meth:`write_artifact`'s record) written for it."""
        self.require_writable()
        stop = start + len(df)
        name = chunk_filename(oid, start, stop)
        rec = write_labels(
            self.out_dir,
            df,
            start,
            stop,
            name,
            self.spec.key,
            source_sha256,
            artifacts,
            run_id=self.manifest.run_id,
        )
        record: dict[str, Any] = rec.to_json()
        if artifacts:
            record["artifacts"] = dict(artifacts)
        key = f"{start}-{stop}"
        self.record({"op": "chunk", "oid": oid, "key": key, "source_sha256": source_sha256, "record": record})
        if start == 0 and stop == self.spec.count(oid):  # in the file's order, as read back
            self._written_stats[oid] = object_stats(df.sort_values("grasp_id", kind="stable"))
        self.save()

    def finish_object(self, oid: str, source_sha256: str) -> dict[str, Any]:
        """Merge the object's chunks into its file, record it, delete the chunks; returns its stats.

        In an order that never shows ``read_parquet`` the merged rows and the chunks at once,
        whatever stops the run (Ctrl-C waits for the steps; a full disk or a kill may not): the
        merged file is written hidden, recorded, the chunks removed, then it is renamed into place.
        A run stopped between the last two steps is completed on resume
        (:func:`annotator.store.reconcile.verify`).
        """
        self.require_writable()
        chunks = sorted(self.manifest.chunks_done[oid]["files"].items(), key=_start)
        files = [rec["file"] for _, rec in chunks]
        artifacts = {name: a for _, rec in chunks for name, a in rec.get("artifacts", {}).items()}
        written = self._written_stats.pop(oid, None) if len(chunks) == 1 else None
        df: pd.DataFrame | None = None
        if written is not None:
            stats = written
        else:
            df = read_labels(self.out_dir, files)
            stats = object_stats(df)
        final = object_filename(oid)
        with sigint_deferred():
            if len(chunks) == 1 and chunks[0][1].get("n") == stats["n"] and _start(chunks[0]) == 0:
                # one chunk of all the rows: it is the merged file already (the same rows, sorted,
                # and the same mark, rows 0..n-1), so it is linked under the merged file's name
                rec: FileRecord = _same_file(self.out_dir, chunks[0][1], merging_name(final))
            else:
                assert df is not None  # read above: more than one chunk
                rec = write_labels(
                    self.out_dir,
                    df,
                    0,
                    len(df),
                    merging_name(final),
                    self.spec.key,
                    source_sha256,
                    artifacts,
                    run_id=self.manifest.run_id,
                )
            done = {
                **rec.to_json(),
                "file": final,
                "source_sha256": source_sha256,
                "stats": stats,
                "time": utc_now(),
                **({"artifacts": artifacts} if artifacts else {}),
            }
            chunk_entry = self.manifest.chunks_done[oid]
            line = self.record({"op": "done", "oid": oid, "record": done})
            try:
                self.save(force=True)
            except BaseException:  # not recorded: the chunks stay the object's labels
                if self._journal is not None and line is not None:
                    self._journal.withdraw(line)
                self.manifest.objects_done.pop(oid)
                self.manifest.chunks_done[oid] = chunk_entry
                (self.out_dir / merging_name(final)).unlink(missing_ok=True)
                raise
            for name in files:
                (self.out_dir / name).unlink(missing_ok=True)
            os.replace(self.out_dir / merging_name(final), self.out_dir / final)
        return stats

    def fail_object(self, oid: str, error: str) -> None:
        """Record the failure (one line) and remove the object's chunk files: no partial labels stay."""
        self._written_stats.pop(oid, None)
        for rec in self.manifest.chunks_done.get(oid, {"files": {}})["files"].values():
            delete_record(self.out_dir, rec)
        self.record({"op": "failed", "oid": oid, "error": " ".join(str(error).split())[:500]})
        if not self.read_only:
            self.save(force=True)

    def record_info(self, oid: str, info: dict[str, Any]) -> None:
        """What the object was simulated as (geometry, mass, friction), kept in the manifest."""
        self.record({"op": "info", "oid": oid, "info": canonical(info)})

    # --- bookkeeping ---------------------------------------------------------------------------

    def record(self, op: dict[str, Any]) -> bytes | None:
        """Apply one manifest operation (:data:`annotator.store.manifest.OP_SCHEMAS`) and keep it
        for the journal (written at the next :meth:`save`); returns its journal line, if any."""
        op = {**op, "at": utc_now()}
        self.manifest.apply(op)
        if op["op"] == "header":
            self._header = (self.manifest.objects_planned, self.manifest.gripper_folder)
        return self._journal.add(op) if self._journal is not None else None

    def save(self, force: bool = False) -> None:
        """Write what changed (at most every SAVE_SECONDS unless ``force``) to the journal, first
        checking that this run still holds the folder (LockLostError otherwise); with no journal
        to append to, compact. Costs what changed since the last save, not what the folder holds."""
        now = time.monotonic()
        if force or now - self._saved_at >= self.SAVE_SECONDS:
            self.lock.check()
            m = self.manifest
            if m.objects_planned is not self._header[0] or m.gripper_folder != self._header[1]:
                # the runner set what it plans: one line (the object ids), once per run
                header = {"objects_planned": m.objects_planned, "gripper_folder": m.gripper_folder}
                self.record({"op": "header", **header})
            if self._journal is None:
                self.compact()
            else:
                self._journal.flush()
            self._saved_at = now

    def compact(self) -> None:
        """Write the whole manifest (every change so far folded in) and start an empty journal.

        Safe whenever it stops: the journal's pending lines are flushed first; the manifest names
        its new journal, so a kill before the new journal replaces the old one leaves an old
        journal that the manifest already holds, which is not applied again."""
        self.lock.check()
        if self._journal is not None:
            self._journal.flush()
        old = self.manifest.journal
        self.manifest.journal = uuid.uuid4().hex
        try:
            self.manifest.save(self.out_dir)
        except BaseException:
            self.manifest.journal = old
            raise
        self._close_journal()
        self._header = (self.manifest.objects_planned, self.manifest.gripper_folder)
        self._journal = JournalWriter.start(journal_path(self.out_dir), self.manifest.journal)

    def _close_journal(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None

    def close(self) -> None:
        """Save and compact (if anything can be written) and release the lock."""
        try:
            if not self.read_only and self.lock.fd is not None:
                self.save(force=True)
                self.compact()
        finally:
            self._close_journal()
            self.lock.release()


def _start(item: tuple[str, Any]) -> int:
    return int(item[0].split("-")[0])


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


def _same_file(out_dir: Path, chunk: dict[str, Any], name: str) -> FileRecord:
    """The chunk file of ``chunk`` (its record: file, sha256, n) also under ``name``: a hard link,
    or a copy written atomically where the file system has none; the new name's record."""
    source, target = out_dir / chunk["file"], out_dir / name
    target.unlink(missing_ok=True)
    try:
        os.link(source, target)
    except OSError:  # no hard links here (some network and FAT file systems)
        data = source.read_bytes()
        atomic_write(target, lambda fh: fh.write(data))
    return FileRecord(name, chunk["sha256"], int(chunk["n"]))
