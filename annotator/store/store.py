"""The output folder of one run: open it (lock, manifest, verification, resume), write to it.

Promises (docs/reliability.md): one run per folder at a time; the manifest binds the run's
settings and each object's source digest, so a resume never mixes; every file is checked against
its checksum before it is trusted; only files the tool wrote are ever deleted.
"""

from __future__ import annotations

import errno
import logging
import os
import time
from pathlib import Path
from typing import Any

import pandas as pd

from annotator.store import reconcile
from annotator.store.artifacts import delete_record, write_artifact
from annotator.store.files import FileRecord, OutputError, output_error, read_labels, write_labels
from annotator.store.lock import RunLock, sigint_deferred
from annotator.store.manifest import Manifest, RunSpec, canonical, utc_now
from annotator.store.names import chunk_filename, merging_name, object_filename

log = logging.getLogger(__name__)

# Errors of the file system that mean "this folder cannot be written", not a bug.
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}


class Store:
    """One output folder for one run. ``open()`` locks and checks it; the runner then writes
    chunks, finishes and fails objects through it; ``close()`` saves and unlocks."""

    # The manifest is saved at most this often while chunks come in, always when an object is
    # merged or fails and when the run ends; a hard kill loses at most this many seconds of
    # chunks (unvouched chunk files are redone on resume).
    SAVE_SECONDS = 2.0

    def __init__(self, out_dir: Path, spec: RunSpec) -> None:
        self.out_dir = Path(out_dir)
        self.spec = spec
        self.manifest = Manifest.fresh(spec)
        self.lock = RunLock(self.out_dir)
        self.read_only = False  # the folder cannot be written: only a finished run can be read
        self.notes: list[str] = []  # one line per thing the user should know (redone, removed)
        self._saved_at = 0.0

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
            reconcile.load_folder(self, overwrite=overwrite, repair=repair)
        except BaseException:
            self.lock.release()
            raise

    def require_writable(self) -> None:
        if self.read_only:
            raise output_error(self.out_dir, OSError(errno.EROFS, "the folder is read-only"))

    def reconcile(self, sources: dict[str, str]) -> reconcile.Resume:
        """Match the folder to this run's objects (object id -> source digest); see
        :func:`annotator.store.reconcile.match_sources`."""
        return reconcile.match_sources(self, sources)

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
        entry = self.manifest.chunks_done.setdefault(oid, {"source_sha256": source_sha256, "files": {}})
        record: dict[str, Any] = rec.to_json()
        if artifacts:
            record["artifacts"] = dict(artifacts)
        entry["files"][f"{start}-{stop}"] = record
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
        df = read_labels(self.out_dir, files)
        stats = object_stats(df)
        final = object_filename(oid)
        with sigint_deferred():
            rec: FileRecord = write_labels(
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
            self.manifest.objects_done[oid] = {
                **rec.to_json(),
                "file": final,
                "source_sha256": source_sha256,
                "stats": stats,
                "time": utc_now(),
                **({"artifacts": artifacts} if artifacts else {}),
            }
            chunk_entry = self.manifest.chunks_done.pop(oid)
            try:
                self.save(force=True)
            except BaseException:  # not recorded: the chunks stay the object's labels
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
        m = self.manifest
        for rec in m.chunks_done.pop(oid, {"files": {}})["files"].values():
            delete_record(self.out_dir, rec)
        m.objects_failed[oid] = " ".join(str(error).split())[:500]
        m.objects_done.pop(oid, None)
        if not self.read_only:
            self.save(force=True)

    def record_info(self, oid: str, info: dict[str, Any]) -> None:
        """What the object was simulated as (geometry, mass, friction), kept in the manifest."""
        self.manifest.objects_info[oid] = canonical(info)

    def save(self, force: bool = False) -> None:
        """Save the manifest (at most every SAVE_SECONDS unless ``force``), first checking that
        this run still holds the folder (LockLostError otherwise)."""
        now = time.monotonic()
        if force or now - self._saved_at >= self.SAVE_SECONDS:
            self.lock.check()
            self.manifest.save(self.out_dir)
            self._saved_at = now

    def close(self) -> None:
        """Save (if anything can be written) and release the lock."""
        try:
            if not self.read_only and self.lock.fd is not None:
                self.save(force=True)
        finally:
            self.lock.release()


def _start(item: tuple[str, Any]) -> int:
    return int(item[0].split("-")[0])


def object_stats(df: pd.DataFrame) -> dict[str, Any]:
    """Per-object figures for the summary: rows, successes, mean score, outcome counts (and, for
    cell labels, the successes the arm can execute)."""
    stats: dict[str, Any] = {
        "n": int(len(df)),
        "successes": int(df["success"].sum()),
        "mean_score": float(df["score"].mean()) if len(df) else 0.0,
        "outcomes": {str(k): int(v) for k, v in df["outcome"].value_counts().items()},
    }
    if "reachable" in df.columns:
        stats["reachable_successes"] = int((df["success"] & df["reachable"]).sum())
    return stats
