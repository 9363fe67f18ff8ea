"""The run manifest (``_manifest.json``) and its journal: what the folder's run is and how far it got.

``RunSpec`` is everything that changes a label; the manifest binds it, so a resume with other
settings is refused instead of mixing datasets. The manifest's shape is one schema
(:data:`MANIFEST_SCHEMA`): a manifest of any other shape, nesting or size is one line
(:class:`ManifestUnreadableError`), never a traceback later, and every file name it holds is a
name the tool itself gives (no path can lead outside the folder).

The manifest holds the run's progress as of its last compaction; every change since is an
operation in the journal (:mod:`annotator.store.journal`, :data:`OP_SCHEMAS`), applied in order by
:meth:`Manifest.apply`. :func:`load_state` reads both: the folder's run as of its last recorded
change.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import functools
import hashlib
import importlib.metadata
import json
import logging
import platform
import re
import stat
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, cast

import numpy as np

from annotator import __version__
from annotator import versions as label_versions
from annotator.store.errors import JournalUnreadableError, ManifestUnreadableError
from annotator.store.files import atomic_write
from annotator.store.journal import read_journal
from annotator.store.names import (
    JOURNAL_NAME,
    MANIFEST_NAME,
    chunk_filename,
    is_artifact_relpath,
    is_label_filename,
    object_filename,
)
from annotator.store.schema import Any_, Int, Invalid, Map, Nullable, Num, Record, Seq, Str

log = logging.getLogger(__name__)

TOOL = "rg2-annotator"
# 3: run binding, per-file checksums, source digests, marked files; 4: the journal that continues it
MANIFEST_VERSION = 4
# Versions this one reads: a folder of version 3 is the same document without a journal; it
# resumes, and its first compaction writes it as version 4.
READABLE_VERSIONS = (3, 4)
# Libraries whose version can change a label (a resume with another version would mix datasets):
# annotator.versions.LABEL_LIBRARIES, the list the decomposition cache's key uses too.
# Informative only (recorded, never compared).
OTHER_DISTRIBUTIONS = {"pandas": "pandas", "pyarrow": "pyarrow", "joblib": "joblib"}
# A manifest larger than this is not one the tool wrote (a million objects take ~0.5 GB).
MAX_MANIFEST_BYTES = 1 << 30


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def bound_versions() -> dict[str, str]:
    """Versions that shape labels: this package and :data:`annotator.versions.LABEL_LIBRARIES`."""
    return {"annotator": __version__, **label_versions.library_versions()}


# ``versions["machine"]``: the kinds of machine (annotator.versions.machine_kind) that labelled the
# folder, joined by this; recorded, not bound: a resume on another kind is said, not refused.
MACHINES_SEPARATOR = " | "


def collect_versions() -> dict[str, str]:
    """Every version worth recording (no pybullet import): bound ones, Python, platform, the kind
    of machine, others."""
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    versions["machine"] = label_versions.machine_kind()
    versions.update(bound_versions())
    versions.update({k: _version(d) for k, d in OTHER_DISTRIBUTIONS.items()})
    return versions


def canonical(obj: Any) -> Any:
    """JSON round trip so tuples/lists and numpy scalars compare equal after a reload."""
    return json.loads(json.dumps(obj, sort_keys=True, default=_json_default))


def _write_by_line(fh: IO[bytes], data: dict[str, Any]) -> None:
    """Write ``data`` as JSON, sorted: one line per top-level field, and one line per entry of the
    fields that are maps of records (an object's record on its own line, for grep and diff).
    Written entry by entry: no copy of the whole text is held."""

    def dump(value: Any) -> bytes:
        return json.dumps(value, sort_keys=True, default=_json_default).encode("utf-8")

    fh.write(b"{")
    for i, key in enumerate(sorted(data)):
        value = data[key]
        fh.write(b"\n " if i == 0 else b",\n ")
        fh.write(dump(key) + b": ")
        if isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
            fh.write(b"{")
            for j, k in enumerate(sorted(value)):
                fh.write((b"\n  " if j == 0 else b",\n  ") + dump(k) + b": " + dump(value[k]))
            fh.write(b"\n }")
        else:
            fh.write(dump(value))
    fh.write(b"\n}\n")


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

    ``inputs``: more inputs of a command (e.g. the digest of the grasps ``evaluate`` simulates);
    ``gripper``: the gripper simulated, ``{"name": ..., "digest": ...}`` (its description's name and
    content digest, :mod:`annotator.grippers`); None in folders written before grippers were data.
    """

    seed: int
    n: int
    trials: int
    scale: float | None
    chunk_size: int
    config: dict[str, Any]
    versions: dict[str, str] = field(default_factory=bound_versions)
    inputs: dict[str, Any] = field(default_factory=dict)
    gripper: dict[str, str] | None = None

    def to_json(self) -> dict[str, Any]:
        data = canonical(dataclasses.asdict(self))
        if data.get("gripper") is None:  # absent rather than null, as folders of earlier versions
            data.pop("gripper", None)
        return data

    def count(self, object_id: str) -> int:
        """Candidates of one object: N, or its own count when the run's grasps are given."""
        return int(self.inputs.get("counts", {}).get(object_id, self.n))

    @functools.cached_property
    def key(self) -> str:
        """SHA-256 of the canonical JSON: files written by this run carry it (computed once: every
        label file written asks for it; the spec's dicts are never changed after it is made)."""
        return hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()

    def differences(self, recorded: dict[str, Any]) -> list[str]:
        """What differs between the run recorded in a manifest and this one, one item each."""
        mine = self.to_json()
        diffs = []
        if recorded.get("gripper") != mine.get("gripper"):
            diffs.append(
                f"gripper {gripper_text(recorded.get('gripper'))} in the folder, "
                f"{gripper_text(mine.get('gripper'))} now"
            )
        for name in ("seed", "n", "trials", "scale", "chunk_size"):
            if recorded.get(name) != mine[name]:
                diffs.append(f"{name} {recorded.get(name)} in the folder, {mine[name]} now")
        for section, values in sorted(mine["config"].items()):
            old = recorded["config"].get(section) or {}
            for key in sorted(set(values) | set(old)):
                if old.get(key) != values.get(key):
                    diffs.append(f"[{section}] {key} {old.get(key)} in the folder, {values.get(key)} now")
        for name in ("versions", "inputs"):
            old = recorded[name]
            for key in sorted(set(mine[name]) | set(old)):
                if old.get(key) != mine[name].get(key):
                    diffs.append(f"{key} {old.get(key)} in the folder, {mine[name].get(key)} now")
        return diffs


def gripper_text(record: dict[str, str] | None) -> str:
    """A recorded gripper for people: ``panda (digest 1a2b3c4d5e6f)``, or ``none recorded``."""
    if not record:
        return "none recorded"
    return f"{record.get('name')} (digest {str(record.get('digest'))[:12]})"


# ------------------------------------------------------------------------------------ the schema

_HEX64 = Str(lambda s: len(s) == 64 and all(c in "0123456789abcdef" for c in s), "a SHA-256 hex digest")
_LABEL_FILE = Str(is_label_filename, "a label file name the tool gives (no folder)")
_ARTIFACTS = Map(
    Record({"file": Str(is_artifact_relpath, "an artifact path the tool gives"), "sha256": _HEX64})
)
_COUNT = Int(0, 1_000_000)
_FILE_RECORD = Record(
    {"file": _LABEL_FILE, "sha256": _HEX64, "n": _COUNT}, optional={"artifacts": _ARTIFACTS}
)
_STATS = Record(
    {"n": _COUNT, "successes": _COUNT, "mean_score": Num(), "outcomes": Map(_COUNT)},
    optional={"reachable_successes": _COUNT},
)
_DONE = Record(
    {**_FILE_RECORD.required, "source_sha256": Str(), "stats": _STATS, "time": Str()},
    optional=_FILE_RECORD.optional,
)
_CHUNKS = Record(
    {
        "source_sha256": Str(),
        "files": Map(_FILE_RECORD, key=Str(lambda k: _range(k) is not None, "start-stop")),
    }
)
_GRIPPER = Record(
    {
        "name": Str(lambda s: re.fullmatch(r"[a-z0-9_]+", s) is not None, "a gripper name ([a-z0-9_])"),
        "digest": _HEX64,
    }
)
_ID32 = Str(lambda s: len(s) == 32 and all(c in "0123456789abcdef" for c in s), "a 32-digit hex id")
_RUN = Record(
    {
        "seed": Int(),
        "n": Int(1),
        "trials": Int(1),
        "scale": Num(optional=True),
        "chunk_size": Int(1),
        "config": Map(Map(Any_())),
        "versions": Map(Str()),
        "inputs": Map(Any_()),
    },
    # the gripper simulated (absent in folders written before grippers were data)
    optional={"gripper": _GRIPPER},
)
MANIFEST_SCHEMA = Record(
    optional={
        # this folder's run: every label file it writes carries it, so another run's files copied
        # into the folder are never taken for its own (absent in folders of earlier versions)
        "run_id": _ID32,
        # the journal that continues this manifest (absent in version 3, which had none)
        "journal": _ID32,
        # every object id of the run's inputs, so readers can tell a finished run from one that stopped
        "objects_planned": Seq(Str()),
        # where the run's gripper description was read from when it is not a shipped one (informative:
        # the run binds the gripper by name and digest, run.gripper; the tools look for it here)
        "gripper_folder": Str(),
    },
    required={
        "tool": Str(lambda s: s == TOOL, f"{TOOL!r}"),
        "manifest_version": Int(min(READABLE_VERSIONS), max(READABLE_VERSIONS)),
        "run": _RUN,
        "run_key": _HEX64,
        "versions": Map(Str()),
        "objects_done": Map(_DONE),
        "objects_failed": Map(Str()),
        "chunks_done": Map(_CHUNKS),
        "objects_info": Map(Map(Any_())),
        "created": Str(),
        "updated": Str(),
    },
)


def _range(key: str) -> tuple[int, int] | None:
    """``"start-stop"`` as two ints, or None."""
    parts = key.split("-")
    if len(parts) != 2 or not all(p.isdigit() and len(p) <= 7 for p in parts):
        return None
    start, stop = int(parts[0]), int(parts[1])
    return (start, stop) if start < stop else None


def chunk_range(key: str) -> tuple[int, int]:
    """A chunk's key ``"start-stop"`` as (start, stop); Invalid when it is not one."""
    bounds = _range(key)
    if bounds is None:
        raise Invalid(f"{key!r} is not a chunk's range")
    return bounds


def _check_names(data: dict[str, Any]) -> None:
    """Every label file is the one the tool names for its object (and range): a manifest can
    point the tool at no other file, in the folder or outside it."""
    for oid, entry in data["objects_done"].items():
        if entry["file"] != object_filename(oid):
            raise Invalid(f"objects_done[{oid!r}].file: {entry['file']!r} is not this object's file")
    for oid, entry in data["chunks_done"].items():
        for key, rec in entry["files"].items():
            start, stop = chunk_range(key)
            if rec["file"] != chunk_filename(oid, start, stop) or rec["n"] != stop - start:
                raise Invalid(f"chunks_done[{oid!r}][{key!r}]: {rec['file']!r} is not that chunk's file")


# ------------------------------------------------------------------------------ journal operations

_OID = Str()
_KEY = Str(lambda k: _range(k) is not None, "start-stop")
# Every operation a journal line may hold, with its fields ("at": when it was recorded, UTC).
OP_SCHEMAS: dict[str, Record] = {
    # a chunk written: chunks_done[oid].files[key] = record
    "chunk": Record({"oid": _OID, "key": _KEY, "source_sha256": Str(), "record": _FILE_RECORD, "at": Str()}),
    # an object merged: objects_done[oid] = record; its chunks' entry goes
    "done": Record({"oid": _OID, "record": _DONE, "at": Str()}),
    # an object failed: objects_failed[oid] = error; its chunks and its file's entry go
    "failed": Record({"oid": _OID, "error": Str(), "at": Str()}),
    # what the object was simulated as: objects_info[oid] = info
    "info": Record({"oid": _OID, "info": Map(Any_()), "at": Str()}),
    # the object's labels are no longer the run's (source changed, set aside): done, chunks, info go
    "forget": Record({"oid": _OID, "at": Str()}),
    # its merged file is not trusted (redone)
    "drop_done": Record({"oid": _OID, "at": Str()}),
    # one of its chunks is not trusted (redone)
    "drop_chunk": Record({"oid": _OID, "key": _KEY, "at": Str()}),
    # no longer among the objects: its record of what it was simulated as goes
    "drop_info": Record({"oid": _OID, "at": Str()}),
    # a resume retries every failed object
    "unfail": Record({"at": Str()}),
    # the objects this run plans and where its gripper was read from
    "header": Record(
        {"objects_planned": Nullable(Seq(Str())), "gripper_folder": Nullable(Str()), "at": Str()}
    ),
}


# ------------------------------------------------------------------------------------ the manifest


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
    created: str = field(default_factory=utc_now)
    updated: str = field(default_factory=utc_now)
    manifest_version: int = MANIFEST_VERSION
    tool: str = TOOL
    run_id: str | None = None
    objects_planned: list[str] | None = None
    gripper_folder: str | None = None
    journal: str | None = None

    @classmethod
    def fresh(cls, spec: RunSpec, run_id: str | None = None) -> Manifest:
        return cls(run=spec.to_json(), run_key=spec.key, run_id=run_id or uuid.uuid4().hex)

    def unfinished(self) -> list[str]:
        """Planned objects neither done nor failed (every planned one still running or never started)."""
        planned = self.objects_planned or []
        return sorted(set(planned) - set(self.objects_done) - set(self.objects_failed))

    @staticmethod
    def path(out_dir: Path) -> Path:
        return Path(out_dir) / MANIFEST_NAME

    def _fields(self) -> dict[str, Any]:
        """The fields as they are (no copy), optional ones absent rather than null (as folders of
        earlier versions have them)."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name in MANIFEST_SCHEMA.optional:
            if data.get(name) is None:
                data.pop(name, None)
        return data

    def to_json(self) -> dict[str, Any]:
        """A JSON copy of the manifest (what ``json.load`` of the file gives)."""
        return canonical(self._fields())

    def save(self, out_dir: Path) -> None:
        """Write the whole manifest atomically, as this version writes it (OutputError if the folder
        cannot be written). Only a compaction does (:meth:`annotator.store.Store.compact`): every
        other change goes to the journal. One line per object in the per-object maps, written by
        the C encoder (no copy of the manifest is made)."""
        self.updated = utc_now()
        self.manifest_version = MANIFEST_VERSION
        fields = self._fields()
        atomic_write(self.path(out_dir), lambda fh: _write_by_line(fh, fields))

    @classmethod
    def load(cls, out_dir: Path) -> Manifest | None:
        """The folder's run as of its last recorded change (the manifest and its journal), None if
        there is no manifest, ManifestUnreadableError if either is broken (a journal's last line cut
        short is not: a kill mid-write leaves one, and it is ignored)."""
        return load_state(out_dir).manifest

    def apply(self, op: dict[str, Any]) -> None:
        """Apply one journal operation (:data:`OP_SCHEMAS`, already checked)."""
        kind, oid = op["op"], cast(str, op.get("oid"))  # every operation but the run's own names its unit
        if kind == "chunk":
            entry = self.chunks_done.setdefault(oid, {"source_sha256": op["source_sha256"], "files": {}})
            entry["files"][op["key"]] = op["record"]
        elif kind == "done":
            self.objects_done[oid] = op["record"]
            self.chunks_done.pop(oid, None)
        elif kind == "failed":
            self.chunks_done.pop(oid, None)
            self.objects_failed[oid] = op["error"]
            self.objects_done.pop(oid, None)
        elif kind == "info":
            self.objects_info[oid] = op["info"]
        elif kind == "forget":
            self.objects_done.pop(oid, None)
            self.chunks_done.pop(oid, None)
            self.objects_info.pop(oid, None)
        elif kind == "drop_done":
            self.objects_done.pop(oid, None)
        elif kind == "drop_chunk":
            self.chunks_done.get(oid, {"files": {}})["files"].pop(op["key"], None)
        elif kind == "drop_info":
            self.objects_info.pop(oid, None)
        elif kind == "unfail":
            self.objects_failed.clear()
        elif kind == "header":
            self.objects_planned = op["objects_planned"]
            self.gripper_folder = op["gripper_folder"]
        else:  # pragma: no cover - check_op admits no other
            raise ValueError(f"unknown journal operation {kind!r}")
        if "at" in op:
            self.updated = op["at"]

    @classmethod
    def from_json(cls, data: Any, path: Path) -> Manifest:
        """Check the whole document against :data:`MANIFEST_SCHEMA`; one line naming the first bad place."""
        try:
            if isinstance(data, dict) and data.get("tool") != TOOL:
                raise Invalid("not a manifest of rg2-annotator")
            if isinstance(data, dict) and data.get("manifest_version") not in READABLE_VERSIONS:
                found = data.get("manifest_version")
                readable = " or ".join(str(v) for v in READABLE_VERSIONS)
                raise Invalid(f"manifest version {found!r}, this version reads {readable}")
            MANIFEST_SCHEMA.check(data, "manifest")
            _check_names(data)
        except Invalid as exc:
            raise ManifestUnreadableError(f"{path}: {exc}") from None
        return cls(**data)

    def check(self, path: Path) -> None:
        """The whole state against the manifest's schema (after a journal was applied)."""
        self.from_json(self.to_json(), path)

    def label_records(self) -> list[dict[str, Any]]:
        """Every label file record (finished objects and chunks)."""
        records = list(self.objects_done.values())
        for entry in self.chunks_done.values():
            records += list(entry["files"].values())
        return records

    def referenced_files(self) -> set[str]:
        """Every label file name the manifest vouches for."""
        return {rec["file"] for rec in self.label_records()}


def check_op(op: dict[str, Any]) -> None:
    """Invalid unless ``op`` is an operation of :data:`OP_SCHEMAS` with the fields it takes."""
    schema = OP_SCHEMAS.get(op["op"])
    if schema is None:
        raise Invalid(f"unknown operation {op['op']!r}")
    schema.check({k: v for k, v in op.items() if k != "op"}, op["op"])
    if op["op"] == "chunk":
        start, stop = chunk_range(op["key"])
        rec = op["record"]
        if rec["file"] != chunk_filename(op["oid"], start, stop) or rec["n"] != stop - start:
            raise Invalid(f"chunk {op['oid']!r} {op['key']}: {rec['file']!r} is not that chunk's file")
    elif op["op"] == "done" and op["record"]["file"] != object_filename(op["oid"]):
        raise Invalid(f"done {op['oid']!r}: {op['record']['file']!r} is not this object's file")


@dataclass
class LoadedState:
    """A folder's run as :func:`load_state` read it.

    manifest : the manifest with its journal applied, None if the folder has none
    journal_current : the journal on disk continues this manifest and every line of it verified:
        the run may append to it; otherwise the next save compacts
    pending : operations applied from the journal (a compaction folds them into the manifest)
    skipped : one line per journal line that did not verify and was left out
    """

    manifest: Manifest | None
    journal_current: bool = False
    pending: int = 0
    skipped: list[str] = field(default_factory=list)


def journal_path(out_dir: Path) -> Path:
    return Path(out_dir) / JOURNAL_NAME


def load_state(out_dir: Path, *, repair: bool = False) -> LoadedState:
    """Read the folder's manifest and apply the journal that continues it.

    The journal's last line, if it does not verify, is a write a kill cut short: it is left out
    (what it recorded is redone). Any other line that does not verify (a flipped byte, a garbage
    line, an operation of another shape) makes the journal unreadable, as a corrupt manifest is:
    ManifestUnreadableError in one line, unless ``repair``, which leaves such lines out too (the
    files their records vouched for are then not vouched for: checked from their marks, or redone).
    A journal another compaction already folded in (it names another journal than the manifest
    does) is not applied.
    """
    path = Manifest.path(out_dir)
    try:
        data = read_manifest_json(path)
    except FileNotFoundError:
        return LoadedState(None)
    manifest = Manifest.from_json(data, path)
    state = LoadedState(manifest)
    jpath = journal_path(out_dir)
    text = read_journal(jpath) if manifest.journal else None
    if text is not None and text.journal_id is None and text.last > 1:
        # its first line is damaged: whose journal it is cannot be told, but it holds records
        line = f"{jpath.name} line 1 does not verify (the journal's name)"
        if not repair:
            raise JournalUnreadableError(
                f"{jpath}: line 1 does not verify (the journal's name); pass --repair to apply the lines "
                "that do (what they vouch for is verified) or --overwrite to start over"
            )
        state.skipped.append(f"{line}; its other lines applied")
        text.journal_id = manifest.journal
        text.lines = [(number, op) for number, op in text.lines if number != 1]
    if text is None or text.journal_id != manifest.journal:
        return state  # none yet, or one this manifest already holds
    state.journal_current = not state.skipped
    for number, op in text.lines:
        if op is None:
            why = "does not verify (cut short, a flipped byte or not a record)"
        else:
            try:
                check_op(op)
            except Invalid as exc:
                why = f"is not a record of this tool ({exc})"
            else:
                manifest.apply(op)
                state.pending += 1
                continue
        state.journal_current = False
        line = f"{jpath.name} line {number} {why}; left out"
        if number != text.last and not repair:
            raise JournalUnreadableError(
                f"{jpath}: line {number} {why}; pass --repair to leave it out and redo what it recorded, "
                "or --overwrite to start over"
            )
        state.skipped.append(line)
        log.warning("%s", line)
    if state.pending:
        manifest.check(jpath)
    return state


def read_manifest_json(path: Path) -> Any:
    """The parsed JSON of a manifest file; FileNotFoundError if there is none;
    ManifestUnreadableError for a file that is not a regular file (a FIFO, a folder, a link), too
    large, not UTF-8, not JSON or nested too deep."""
    try:
        info = path.lstat()
        if not stat.S_ISREG(info.st_mode):
            raise ManifestUnreadableError(f"{path} is not a regular file")
        if info.st_size > MAX_MANIFEST_BYTES:
            raise ManifestUnreadableError(f"{path} is larger than any manifest this tool writes")
        raw = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise ManifestUnreadableError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    try:
        return json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ManifestUnreadableError(f"{path} is not valid JSON ({exc})") from exc
    except RecursionError:
        raise ManifestUnreadableError(f"{path} is not a manifest (nested too deep)") from None
