"""The run manifest (``_manifest.json``): what the folder's run is and how far it got.

``RunSpec`` is everything that changes a label; the manifest binds it, so a resume with other
settings is refused instead of mixing datasets. The manifest's shape is one schema
(:data:`MANIFEST_SCHEMA`): a manifest of any other shape, nesting or size is one line
(:class:`ManifestUnreadableError`), never a traceback later, and every file name it holds is a
name the tool itself gives (no path can lead outside the folder).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import importlib.metadata
import json
import platform
import re
import stat
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from annotator import __version__
from annotator import versions as label_versions
from annotator.store.errors import ManifestUnreadableError
from annotator.store.files import atomic_write
from annotator.store.names import (
    MANIFEST_NAME,
    chunk_filename,
    is_artifact_relpath,
    is_label_filename,
    object_filename,
)
from annotator.store.schema import Any_, Int, Invalid, Map, Num, Record, Seq, Str

TOOL = "rg2-annotator"
MANIFEST_VERSION = 3  # 3: run binding, per-file checksums, source digests, marked files
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


def collect_versions() -> dict[str, str]:
    """Every version worth recording (no pybullet import): bound ones, Python, platform, others."""
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    versions.update(bound_versions())
    versions.update({k: _version(d) for k, d in OTHER_DISTRIBUTIONS.items()})
    return versions


def canonical(obj: Any) -> Any:
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

    @property
    def key(self) -> str:
        """SHA-256 of the canonical JSON: files written by this run carry it."""
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
        "run_id": Str(lambda s: len(s) == 32 and all(c in "0123456789abcdef" for c in s), "a run id"),
        # every object id of the run's inputs, so readers can tell a finished run from one that stopped
        "objects_planned": Seq(Str()),
        # where the run's gripper description was read from when it is not a shipped one (informative:
        # the run binds the gripper by name and digest, run.gripper; the tools look for it here)
        "gripper_folder": Str(),
    },
    required={
        "tool": Str(lambda s: s == TOOL, f"{TOOL!r}"),
        "manifest_version": Int(MANIFEST_VERSION, MANIFEST_VERSION),
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


def _check_names(data: dict[str, Any]) -> None:
    """Every label file is the one the tool names for its object (and range): a manifest can
    point the tool at no other file, in the folder or outside it."""
    for oid, entry in data["objects_done"].items():
        if entry["file"] != object_filename(oid):
            raise Invalid(f"objects_done[{oid!r}].file: {entry['file']!r} is not this object's file")
    for oid, entry in data["chunks_done"].items():
        for key, rec in entry["files"].items():
            start, stop = _range(key)  # type: ignore[misc]  # the schema checked the key
            if rec["file"] != chunk_filename(oid, start, stop) or rec["n"] != stop - start:
                raise Invalid(f"chunks_done[{oid!r}][{key!r}]: {rec['file']!r} is not that chunk's file")


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

    def to_json(self) -> dict[str, Any]:
        data = canonical(dataclasses.asdict(self))
        for name in MANIFEST_SCHEMA.optional:  # absent rather than null (folders of earlier versions)
            if data.get(name) is None:
                data.pop(name, None)
        return data

    def save(self, out_dir: Path) -> None:
        """Write atomically (OutputError if the folder cannot be written)."""
        self.updated = utc_now()
        text = json.dumps(self.to_json(), indent=1, sort_keys=True)
        atomic_write(self.path(out_dir), lambda fh: fh.write(text.encode("utf-8") + b"\n"))

    @classmethod
    def load(cls, out_dir: Path) -> Manifest | None:
        """The folder's manifest, None if there is none, ManifestUnreadableError if it is broken."""
        path = cls.path(out_dir)
        try:
            data = read_manifest_json(path)
        except FileNotFoundError:
            return None
        return cls.from_json(data, path)

    @classmethod
    def from_json(cls, data: Any, path: Path) -> Manifest:
        """Check the whole document against :data:`MANIFEST_SCHEMA`; one line naming the first bad place."""
        try:
            if isinstance(data, dict) and data.get("tool") != TOOL:
                raise Invalid("not a manifest of rg2-annotator")
            if isinstance(data, dict) and data.get("manifest_version") != MANIFEST_VERSION:
                found = data.get("manifest_version")
                raise Invalid(f"manifest version {found!r}, this version reads {MANIFEST_VERSION}")
            MANIFEST_SCHEMA.check(data, "manifest")
            _check_names(data)
        except Invalid as exc:
            raise ManifestUnreadableError(f"{path}: {exc}") from None
        return cls(**data)

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
