"""The output folder of one run: lock, manifest, verified label files, resume.

Layout::

    labels/
      _manifest.json                          what the run is (every label-affecting input) and
                                              how far it got, with a checksum per file
      .rg2-annotator.lock                     held (flock) by the run writing here
      mug-3f2a9c01d4.parquet                  one file per finished object, exactly N rows
      can-8c1e0b77aa.000050-000060.parquet    a finished chunk of an object still running
      _views/mug-3f2a9c01d4/p00_v00_depth.png per-object artifacts (--views), bound to the labels
                                              they came with
      _stale/                                 labels (and _views/) of objects no longer in --objects

Promises (README "Reliability"): one run per folder at a time; the manifest binds the run's
settings (seed, N, trials, scale, chunk size, the whole configuration, the versions that shape
labels) and each object's source digest, so a resume never mixes; every file is checked against
its checksum before it is trusted; only files the tool wrote are ever deleted.

Artifacts (:meth:`Store.write_artifact`): files that belong with an object's labels, e.g. the
Kinect views rendered with them. Each is written atomically and recorded, with its checksum, in
the record of the label file it came with (the manifest's and the file's own mark), so it is
verified with it (a missing or corrupt artifact redoes those labels), removed with it (--overwrite,
a failed or changed object) and set aside with it (an object no longer present).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import errno
import fcntl
import hashlib
import importlib.metadata
import json
import logging
import os
import platform
import shutil
import signal
import socket
import sys
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from annotator import __version__
from annotator.pipeline.files import (
    ARTIFACTS_DIR,
    FileRecord,
    OutputError,
    artifact_relpath,
    atomic_write,
    chunk_filename,
    file_sha256,
    is_artifact_relpath,
    is_object_stem,
    is_own_file,
    is_temp_file,
    object_filename,
    object_stem,
    output_error,
    read_labels,
    read_mark,
    verify_labels,
    write_labels,
)

log = logging.getLogger(__name__)

TOOL = "rg2-annotator"
MANIFEST_NAME = "_manifest.json"
MANIFEST_VERSION = 3  # 3: run binding, per-file checksums, source digests, marked files
LOCK_NAME = ".rg2-annotator.lock"
STALE_DIR = "_stale"
# Libraries whose version can change a label: a resume with another version would mix datasets.
BOUND_DISTRIBUTIONS = {"pybullet": "pybullet", "numpy": "numpy", "trimesh": "trimesh", "coacd": "coacd"}
# Informative only (recorded, never compared).
OTHER_DISTRIBUTIONS = {"pandas": "pandas", "pyarrow": "pyarrow", "joblib": "joblib"}
# Errors of the file system that mean "this folder cannot be written", not a bug.
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}


class StoreError(Exception):
    """The run cannot start on this output folder (a usage error: exit code 2); one line."""


class LockedError(StoreError):
    """Another run holds the folder."""


class RunMismatchError(StoreError):
    """The folder holds a run with other settings."""


class ManifestUnreadableError(StoreError):
    """The manifest is missing (with label files present) or cannot be read."""


# ------------------------------------------------------------------------------------ the run


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def bound_versions() -> dict[str, str]:
    """Versions that shape labels: this package and the libraries in BOUND_DISTRIBUTIONS."""
    return {"annotator": __version__, **{k: _version(d) for k, d in BOUND_DISTRIBUTIONS.items()}}


def collect_versions() -> dict[str, str]:
    """Every version worth recording (no pybullet import): bound ones, Python, platform, others."""
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    versions.update(bound_versions())
    versions.update({k: _version(d) for k, d in OTHER_DISTRIBUTIONS.items()})
    return versions


def _canonical(obj: Any) -> Any:
    """JSON round trip so tuples/lists and numpy scalars compare equal after a reload."""
    return json.loads(json.dumps(obj, sort_keys=True, default=_json_default))


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


@dataclass(frozen=True)
class RunSpec:
    """Everything that changes a label, bound by the manifest: a resume must match it exactly.

    ``inputs``: more inputs of a command (e.g. the digest of the grasps ``evaluate`` simulates).
    """

    seed: int
    n: int
    trials: int
    scale: float | None
    chunk_size: int
    config: dict[str, Any]
    versions: dict[str, str] = field(default_factory=bound_versions)
    inputs: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return _canonical(dataclasses.asdict(self))

    def count(self, object_id: str) -> int:
        """Candidates of one object: N, or its own count when the run's grasps are given."""
        return int(self.inputs.get("counts", {}).get(object_id, self.n))

    @property
    def key(self) -> str:
        """SHA-256 of the canonical JSON: files written by this run carry it."""
        return hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()

    def differences(self, recorded: dict[str, Any]) -> list[str]:
        """What differs between the run recorded in a manifest and this one, one item each."""
        mine = self.to_json()
        diffs = []
        for name in ("seed", "n", "trials", "scale", "chunk_size"):
            if recorded.get(name) != mine[name]:
                diffs.append(f"{name} {recorded.get(name)} in the folder, {mine[name]} now")
        for section, values in sorted(mine["config"].items()):
            old = (recorded.get("config") or {}).get(section) or {}
            for key in sorted(set(values) | set(old)):
                if old.get(key) != values.get(key):
                    diffs.append(f"[{section}] {key} {old.get(key)} in the folder, {values.get(key)} now")
        for name in ("versions", "inputs"):
            old = recorded.get(name) or {}
            for key in sorted(set(mine[name]) | set(old)):
                if old.get(key) != mine[name].get(key):
                    diffs.append(f"{key} {old.get(key)} in the folder, {mine[name].get(key)} now")
        return diffs


# ------------------------------------------------------------------------------------ manifest


@dataclass
class Manifest:
    """What the folder's run is and how far it got; ``_manifest.json``.

    objects_done : object_id -> {"file", "sha256", "n", "source_sha256", "stats", "time"}
    objects_failed : object_id -> one-line error (retried on resume)
    chunks_done : object_id -> {"source_sha256", "files": {"start-stop": {"file", "sha256", "n"}}}
        for objects not finished yet; an object's entry goes when its chunks are merged
    A label file's record may hold ``"artifacts": {name: {"file", "sha256"}}``: the files that
    came with those labels (``file`` relative to the folder).
    objects_info : object_id -> what the object was simulated as (geometry, mass, friction)
    """

    run: dict[str, Any]
    run_key: str
    versions: dict[str, str] = field(default_factory=collect_versions)
    objects_done: dict[str, dict[str, Any]] = field(default_factory=dict)
    objects_failed: dict[str, str] = field(default_factory=dict)
    chunks_done: dict[str, dict[str, Any]] = field(default_factory=dict)
    objects_info: dict[str, dict[str, Any]] = field(default_factory=dict)
    created: str = field(default_factory=_now)
    updated: str = field(default_factory=_now)
    manifest_version: int = MANIFEST_VERSION
    tool: str = TOOL

    @classmethod
    def fresh(cls, spec: RunSpec) -> Manifest:
        return cls(run=spec.to_json(), run_key=spec.key)

    @staticmethod
    def path(out_dir: Path) -> Path:
        return Path(out_dir) / MANIFEST_NAME

    def to_json(self) -> dict[str, Any]:
        return _canonical(dataclasses.asdict(self))

    def save(self, out_dir: Path) -> None:
        """Write atomically (OutputError if the folder cannot be written)."""
        self.updated = _now()
        text = json.dumps(self.to_json(), indent=1, sort_keys=True)
        atomic_write(self.path(out_dir), lambda fh: fh.write(text.encode("utf-8") + b"\n"))

    @classmethod
    def load(cls, out_dir: Path) -> Manifest | None:
        """The folder's manifest, None if there is none, ManifestUnreadableError if it is broken."""
        path = cls.path(out_dir)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise ManifestUnreadableError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
        try:
            data = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ManifestUnreadableError(f"{path} is not valid JSON ({exc})") from exc
        return cls.from_json(data, path)

    @classmethod
    def from_json(cls, data: Any, path: Path) -> Manifest:
        """Check every field's type; one line naming the first bad one."""

        def bad(what: str) -> ManifestUnreadableError:
            return ManifestUnreadableError(f"{path}: {what}")

        if not isinstance(data, dict):
            raise bad(f"expected a JSON object, found {type(data).__name__}")
        if data.get("tool") != TOOL:
            raise bad("not a manifest of rg2-annotator")
        if data.get("manifest_version") != MANIFEST_VERSION:
            found = data.get("manifest_version")
            raise bad(f"manifest version {found!r}, this version reads {MANIFEST_VERSION}")
        kinds: dict[str, type] = {
            "run": dict,
            "run_key": str,
            "versions": dict,
            "objects_done": dict,
            "objects_failed": dict,
            "chunks_done": dict,
            "objects_info": dict,
            "created": str,
            "updated": str,
        }
        for name, kind in kinds.items():
            if not isinstance(data.get(name), kind):
                raise bad(f"field {name!r} is missing or not a {kind.__name__}")
        for oid, entry in data["objects_done"].items():
            if not (
                isinstance(entry, dict)
                and all(isinstance(entry.get(k), str) for k in ("file", "sha256", "source_sha256"))
                and isinstance(entry.get("n"), int)
                and _artifacts_ok(entry)
            ):
                raise bad(f"objects_done[{oid!r}] is malformed")
        for oid, entry in data["chunks_done"].items():
            files = entry.get("files") if isinstance(entry, dict) else None
            if not (isinstance(files, dict) and isinstance(entry.get("source_sha256"), str)):
                raise bad(f"chunks_done[{oid!r}] is malformed")
            for key, rec in files.items():
                parts = key.split("-")
                if not (
                    len(parts) == 2
                    and all(p.isdigit() for p in parts)
                    and isinstance(rec, dict)
                    and isinstance(rec.get("file"), str)
                    and isinstance(rec.get("sha256"), str)
                    and _artifacts_ok(rec)
                ):
                    raise bad(f"chunks_done[{oid!r}] entry {key!r} is malformed")
        if not all(isinstance(v, str) for v in data["objects_failed"].values()):
            raise bad("objects_failed holds a non-text reason")
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    def label_records(self) -> list[dict[str, Any]]:
        """Every label file record (finished objects and chunks)."""
        records = list(self.objects_done.values())
        for entry in self.chunks_done.values():
            records += list(entry["files"].values())
        return records

    def referenced_files(self) -> set[str]:
        """Every label file name the manifest vouches for."""
        return {rec["file"] for rec in self.label_records()}

    def referenced_artifacts(self) -> set[str]:
        """Every artifact (path relative to the folder) the manifest vouches for."""
        return {a["file"] for rec in self.label_records() for a in rec.get("artifacts", {}).values()}


def _artifacts_ok(record: dict[str, Any]) -> bool:
    """A record's optional ``artifacts``: name -> {"file" (a path the tool writes), "sha256"}."""
    artifacts = record.get("artifacts", {})
    return isinstance(artifacts, dict) and all(
        isinstance(a, dict) and is_artifact_relpath(a.get("file")) and isinstance(a.get("sha256"), str)
        for a in artifacts.values()
    )


# ------------------------------------------------------------------------------------ the lock


@dataclass
class RunLock:
    """An exclusive ``flock`` on ``LOCK_NAME`` in the folder: the OS releases it when the process
    ends, however it ends (a crash or SIGKILL included); the file tells who holds it."""

    out_dir: Path
    fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, LockedError naming the holder, or OutputError if the folder is not writable."""
        path = self.out_dir / LOCK_NAME
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise output_error(path, exc) from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise LockedError(
                f"{self.out_dir} is in use by another run ({holder}); wait for it to finish or choose "
                "another --out"
            ) from None
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": _now(),
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])[:300],
        }
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(info).encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def _read_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode())
        return f"pid {info['pid']} on {info['host']}, started {info['started']}: {info['command']}"
    except Exception:
        return "a process that has not said who it is yet"


@contextlib.contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold back Ctrl-C (in the main thread) until the block is done, then raise it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            raise KeyboardInterrupt


# ------------------------------------------------------------------------------------ the store


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
            self._load(overwrite=overwrite, repair=repair)
        except BaseException:
            self.lock.release()
            raise

    def _load(self, *, overwrite: bool, repair: bool) -> None:
        out = self.out_dir
        if overwrite:
            self._require_writable()
            self._remove_own_files()
            self.manifest = Manifest.fresh(self.spec)
            self.save(force=True)
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
            own = [p for p in self._parquet_files() if is_own_file(p)]
            if own and not repair:
                raise ManifestUnreadableError(
                    f"{out} holds {len(own)} label file(s) but no {MANIFEST_NAME}; pass --repair to rebuild "
                    "it from the files that verify, or --overwrite to start over"
                )
            manifest = self._rebuild() if own else Manifest.fresh(self.spec)
        else:
            diffs = self.spec.differences(manifest.run)
            if diffs:
                shown = "; ".join(diffs[:4]) + (f"; and {len(diffs) - 4} more" if len(diffs) > 4 else "")
                raise RunMismatchError(
                    f"{out} holds a run with other settings ({shown}); pass --overwrite to start over or "
                    "choose another --out"
                )
        self.manifest = manifest
        self._verify()
        self._clean_unvouched()
        if not self.read_only:
            self.save(force=True)

    def _require_writable(self) -> None:
        if self.read_only:
            raise output_error(self.out_dir, OSError(errno.EROFS, "the folder is read-only"))

    def _parquet_files(self) -> list[Path]:
        return sorted(p for p in self.out_dir.iterdir() if p.is_file() and p.suffix == ".parquet")

    def _remove_own_files(self) -> None:
        """--overwrite: the tool's files only (marked, or listed by an older manifest), never a user's."""
        listed: set[str] = set()
        with contextlib.suppress(Exception):
            data = json.loads(Manifest.path(self.out_dir).read_text())
            listed |= {e["file"] for e in data.get("objects_done", {}).values()}
            for entry in data.get("chunks_done", {}).values():
                listed |= {r["file"] if isinstance(r, dict) else r for r in entry["files"].values()}
        removed = 0
        for p in self._parquet_files():
            if p.name in listed or is_own_file(p):
                p.unlink()
                removed += 1
        for p in self.out_dir.iterdir():
            if p.is_file() and is_temp_file(p):
                p.unlink()
        removed += _remove_artifacts(self.out_dir / ARTIFACTS_DIR, keep=set())
        stale = self.out_dir / STALE_DIR
        if stale.is_dir():
            for p in stale.iterdir():
                if p.suffix == ".parquet" and read_mark(p) is not None:
                    p.unlink()
                    removed += 1
            removed += _remove_artifacts(stale / ARTIFACTS_DIR, keep=set())
            with contextlib.suppress(OSError):
                stale.rmdir()
        Manifest.path(self.out_dir).unlink(missing_ok=True)
        if removed:
            log.info("--overwrite: removed %d label files from %s", removed, self.out_dir)

    def _rebuild(self) -> Manifest:
        """--repair: a manifest from the marked files of this run that verify; the rest removed."""
        self._require_writable()
        manifest = Manifest.fresh(self.spec)
        kept = dropped = 0
        for p in self._parquet_files():
            if not is_own_file(p):
                continue
            mark = read_mark(p) or {}
            oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
            why = verify_labels(p, self.spec.key, oid, start, stop) if isinstance(oid, str) else "no id"
            artifacts = mark.get("artifacts", {})
            if why is None and not _artifacts_ok(mark):
                why = "its mark lists artifacts the tool does not write"
            if why is None:
                why = self._check_artifacts(artifacts)
            is_object = (
                why is None and p.name == object_filename(oid) and start == 0 and stop == self.spec.count(oid)
            )
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
                stats = object_stats(read_labels(self.out_dir, [p.name]))
                done = {**record, "source_sha256": source, "stats": stats, "time": _now()}
                manifest.objects_done[oid] = done
            else:
                entry = manifest.chunks_done.setdefault(oid, {"source_sha256": source, "files": {}})
                entry["files"][f"{start}-{stop}"] = record
            kept += 1
        for oid in manifest.objects_done:  # an object's file supersedes its chunks
            manifest.chunks_done.pop(oid, None)
        self.notes.append(f"manifest rebuilt from {kept} label files that verify ({dropped} removed)")
        log.warning("rebuilt %s from %d label files (%d removed)", Manifest.path(self.out_dir), kept, dropped)
        return manifest

    def _verify(self) -> None:
        """Every file the manifest vouches for must exist and match its checksum; else redo it."""
        m = self.manifest
        for oid, entry in list(m.objects_done.items()):
            why = self._check_file(entry)
            if why:
                self._distrust(entry, why, oid)
                del m.objects_done[oid]
        for oid, entry in list(m.chunks_done.items()):
            for key, rec in list(entry["files"].items()):
                why = self._check_file(rec)
                if why:
                    self._distrust(rec, why, oid)
                    del entry["files"][key]

    def _check_file(self, record: dict[str, Any]) -> str | None:
        """Why a label file (and the artifacts that came with it) cannot be trusted, or None."""
        why = _check_sha256(self.out_dir / record["file"], record["sha256"])
        return why or self._check_artifacts(record.get("artifacts", {}))

    def _check_artifacts(self, artifacts: dict[str, dict[str, str]]) -> str | None:
        for a in artifacts.values():
            why = _check_sha256(self.out_dir / a["file"], a["sha256"])
            if why:
                return f"(its {a['file']} {why})"
        return None

    def _distrust(self, record: dict[str, Any], why: str, oid: str) -> None:
        line = f"{record['file']} {why}: redoing those labels of {oid}"
        log.warning("%s", line)
        self.notes.append(line)
        if not self.read_only:
            self._delete(record)

    def _delete(self, record: dict[str, Any]) -> None:
        """Remove a label file and the artifacts that came with it."""
        (self.out_dir / record["file"]).unlink(missing_ok=True)
        for a in record.get("artifacts", {}).values():
            path = self.out_dir / a["file"]
            path.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                path.parent.rmdir()  # once empty

    def _clean_unvouched(self) -> None:
        """The tool's files the manifest does not vouch for (a chunk written just before a kill,
        a run stopped between writing and recording) go, and leftover temporary files."""
        if self.read_only:
            return
        vouched = self.manifest.referenced_files()
        for p in self._parquet_files():
            if p.name in vouched:
                continue
            if is_own_file(p):
                p.unlink()
                log.info("removed %s: written but never recorded, or unreadable (redone)", p.name)
            else:
                log.warning("%s is not a label file of this tool; read_parquet will read it too", p)
        for p in self.out_dir.iterdir():
            if p.is_file() and is_temp_file(p):
                p.unlink(missing_ok=True)
        removed = _remove_artifacts(self.out_dir / ARTIFACTS_DIR, keep=self.manifest.referenced_artifacts())
        if removed:
            log.info("removed %d artifact files that were written but never recorded (redone)", removed)

    # --- resuming ------------------------------------------------------------------------------

    def reconcile(self, sources: dict[str, str]) -> Resume:
        """Match the folder to the objects of this run, ``sources``: object id -> source digest.

        Objects whose source changed lose their labels (redone); objects no longer present have
        their labels moved to ``_stale/`` (left out of the dataset); failed ones are retried.
        """
        m = self.manifest
        stale, changed = [], []
        for oid in sorted(set(m.objects_done) | set(m.chunks_done)):
            recorded = (m.objects_done.get(oid) or m.chunks_done.get(oid))["source_sha256"]
            if oid not in sources:
                stale.append(oid)
                self._set_aside(oid)
            elif recorded != sources[oid]:
                changed.append(oid)
                self._forget(oid)
                self.notes.append(f"{oid}: its source changed since its labels were made; redone")
        for oid in stale:
            self.notes.append(f"{oid}: no longer among the objects; its labels moved to {STALE_DIR}/")
        m.objects_failed.clear()
        for oid in list(m.objects_info):
            if oid not in sources:
                del m.objects_info[oid]
        if (stale or changed) and not self.read_only:
            self.save(force=True)
        chunks = {
            oid: {tuple(int(v) for v in key.split("-")) for key in entry["files"]}
            for oid, entry in m.chunks_done.items()
        }
        return Resume(set(m.objects_done), chunks, stale, changed)

    def _forget(self, oid: str) -> None:
        self._require_writable()
        m = self.manifest
        for record in self._records_of(oid):
            self._delete(record)
        m.objects_done.pop(oid, None)
        m.chunks_done.pop(oid, None)
        m.objects_info.pop(oid, None)

    def _set_aside(self, oid: str) -> None:
        self._require_writable()
        stale = self.out_dir / STALE_DIR
        try:
            stale.mkdir(exist_ok=True)
            for record in self._records_of(oid):
                name = record["file"]
                if (self.out_dir / name).exists():
                    shutil.move(self.out_dir / name, stale / name)
            views = self.out_dir / ARTIFACTS_DIR / object_stem(oid)
            if views.is_dir():  # the object's artifacts go with its labels
                target = stale / ARTIFACTS_DIR / views.name
                target.parent.mkdir(parents=True, exist_ok=True)
                if target.exists():
                    shutil.rmtree(target)
                shutil.move(views, target)
        except OSError as exc:
            raise output_error(stale, exc) from exc
        m = self.manifest
        m.objects_done.pop(oid, None)
        m.chunks_done.pop(oid, None)
        m.objects_info.pop(oid, None)

    def _records_of(self, oid: str) -> list[dict[str, Any]]:
        """The label file records of ``oid`` (its merged file, or its chunks)."""
        m = self.manifest
        records = [m.objects_done[oid]] if oid in m.objects_done else []
        if oid in m.chunks_done:
            records += list(m.chunks_done[oid]["files"].values())
        return records

    # --- writing -------------------------------------------------------------------------------

    def write_artifact(self, oid: str, name: str, data: bytes) -> dict[str, str]:
        """Write ``data`` atomically as artifact ``name`` of ``oid`` (``_views/<object stem>/<name>``)
        and return its record for :meth:`write_chunk`, which binds it to the labels it came with.

        An artifact written but never bound (the run stopped in between) is removed on resume.
        ``name``: a plain file name (ValueError otherwise).
        """
        self._require_writable()
        relpath = artifact_relpath(oid, name)
        path = self.out_dir / relpath
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise output_error(path.parent, exc) from exc
        atomic_write(path, lambda fh: fh.write(data))
        return {"file": relpath, "sha256": hashlib.sha256(data).hexdigest()}

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
        self._require_writable()
        stop = start + len(df)
        name = chunk_filename(oid, start, stop)
        rec = write_labels(self.out_dir, df, start, stop, name, self.spec.key, source_sha256, artifacts)
        entry = self.manifest.chunks_done.setdefault(oid, {"source_sha256": source_sha256, "files": {}})
        record: dict[str, Any] = rec.to_json()
        if artifacts:
            record["artifacts"] = dict(artifacts)
        entry["files"][f"{start}-{stop}"] = record
        self.save()

    def finish_object(self, oid: str, source_sha256: str) -> dict[str, Any]:
        """Merge the object's chunks into its file, record it, delete the chunks; returns its stats.

        Ctrl-C waits for the three steps, so the folder never holds an object's file and its chunks.
        """
        self._require_writable()
        chunks = sorted(self.manifest.chunks_done[oid]["files"].items(), key=_start)
        files = [rec["file"] for _, rec in chunks]
        artifacts = {name: a for _, rec in chunks for name, a in rec.get("artifacts", {}).items()}
        df = read_labels(self.out_dir, files)
        stats = object_stats(df)
        with sigint_deferred():
            rec: FileRecord = write_labels(
                self.out_dir, df, 0, len(df), object_filename(oid), self.spec.key, source_sha256, artifacts
            )
            self.manifest.objects_done[oid] = {
                **rec.to_json(),
                "source_sha256": source_sha256,
                "stats": stats,
                "time": _now(),
                **({"artifacts": artifacts} if artifacts else {}),
            }
            self.manifest.chunks_done.pop(oid, None)
            self.save(force=True)
            for name in files:
                (self.out_dir / name).unlink(missing_ok=True)
        return stats

    def fail_object(self, oid: str, error: str) -> None:
        """Record the failure (one line) and remove the object's chunk files: no partial labels stay."""
        m = self.manifest
        for rec in m.chunks_done.pop(oid, {"files": {}})["files"].values():
            self._delete(rec)
        m.objects_failed[oid] = " ".join(str(error).split())[:500]
        m.objects_done.pop(oid, None)
        if not self.read_only:
            self.save(force=True)

    def record_info(self, oid: str, info: dict[str, Any]) -> None:
        """What the object was simulated as (geometry, mass, friction), kept in the manifest."""
        self.manifest.objects_info[oid] = _canonical(info)

    def save(self, force: bool = False) -> None:
        import time

        now = time.monotonic()
        if force or now - self._saved_at >= self.SAVE_SECONDS:
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


def iter_ranges(n: int, chunk_size: int) -> Iterable[tuple[int, int]]:
    """The chunks of N candidates: (0, c), (c, 2c), ..., the last one shorter."""
    return ((a, min(n, a + chunk_size)) for a in range(0, n, chunk_size))


def _check_sha256(path: Path, sha256: str) -> str | None:
    """Why ``path`` does not hold bytes with this checksum ("missing", "corrupt: ..."), or None."""
    try:
        digest = file_sha256(path)
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return None if digest == sha256 else "corrupt: checksum mismatch"


def _remove_artifacts(root: Path, keep: set[str]) -> int:
    """Remove the tool's artifact files under ``root`` (``<root>/<object stem>/<file>``) whose path
    relative to the output folder is not in ``keep``, with emptied folders; returns how many.
    Folders not named as the tool names an object's, and anything in them deeper down, stay."""
    if not root.is_dir():
        return 0
    removed = 0
    for folder in root.iterdir():
        if not (folder.is_dir() and is_object_stem(folder.name)):
            continue
        for p in folder.iterdir():
            relpath = f"{ARTIFACTS_DIR}/{folder.name}/{p.name}"
            if p.is_file() and relpath not in keep and (is_artifact_relpath(relpath) or is_temp_file(p)):
                p.unlink(missing_ok=True)
                removed += 1
        with contextlib.suppress(OSError):
            folder.rmdir()
    with contextlib.suppress(OSError):
        root.rmdir()
    return removed
