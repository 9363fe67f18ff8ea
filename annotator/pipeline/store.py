"""Writing the label dataset: atomic per-chunk and per-object Parquet files and the run manifest.

Layout of an output directory::

    labels/
      _manifest.json                          configuration, versions, objects and chunks done
      ycb__mug-3f2a9c01d4.parquet             one file per finished object, exactly N rows
      ycb__can-8c1e0b77aa.000050-000075.parquet   a finished chunk of an object still running
      ...

Each chunk of candidates is written as soon as it is simulated (so labels appear within seconds
and an interrupt loses at most the chunks in flight); when an object's last chunk is in, its
chunks are merged into the object's file and deleted.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import glob
import hashlib
import importlib.metadata
import json
import logging
import os
import platform
import re
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from annotator.dataset import COLUMNS, STRING, SchemaError, validate_labels

log = logging.getLogger(__name__)

MANIFEST_NAME = "_manifest.json"
MANIFEST_VERSION = 2  # 2: chunks_done (labels written per chunk)
_ARROW_TYPES = {STRING: pa.string(), "int64": pa.int64(), "float64": pa.float64(), "bool": pa.bool_()}


class ManifestMismatchError(RuntimeError):
    """The output directory holds a run with a different configuration."""


# ------------------------------------------------------------------------------------ files


def object_filename(object_id: str) -> str:
    """A safe file name for ``object_id`` (which may contain ``/``), unique per id.

    Readable part: ``/`` -> ``__``, other unsafe characters -> ``_``, no leading ``.``/``_``
    (pyarrow would skip the file), at most 80 characters; then 10 hex digits of the id's SHA-256,
    so distinct ids never collide even when their readable parts do (or differ only in case).
    """
    readable = re.sub(r"[^A-Za-z0-9.-]", "_", object_id.replace("/", "__").replace("\\", "__"))
    readable = readable.lstrip("._")[:80] or "object"
    digest = hashlib.sha256(object_id.encode("utf-8")).hexdigest()[:10]
    return f"{readable}-{digest}.parquet"


def chunk_filename(object_id: str, start: int, stop: int) -> str:
    """File name of candidates ``start..stop-1`` of an object: ``<object stem>.SSSSSS-EEEEEE.parquet``."""
    return f"{object_filename(object_id)[: -len('.parquet')]}.{start:06d}-{stop:06d}.parquet"


def _fsync_dir(path: Path) -> None:
    """Make a rename in ``path`` durable (a no-op where directories cannot be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write ``path`` whole or not at all: hidden temp file in the same dir, fsync, os.replace."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        # mkstemp creates 0600; a dataset is meant to be shared: the usual 0666 minus the umask
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def _arrow_table(df: pd.DataFrame) -> pa.Table:
    """Required columns with fixed Arrow types first, extra columns after, no index.

    Built column by column from numpy (``pa.Table.from_pandas`` plus a cast costs ~20 ms per
    table, which the writer pays for every chunk).
    """
    extra = [c for c in df.columns if c not in COLUMNS]
    arrays, fields = [], []
    for c, t in COLUMNS.items():
        values = df[c].to_numpy(dtype=object if t == STRING else t)
        arrays.append(pa.array(values, type=_ARROW_TYPES[t]))
        fields.append(pa.field(c, _ARROW_TYPES[t], nullable=False))
    for c in extra:
        column = df[c]
        values = column.to_numpy(dtype=object) if pd.api.types.is_string_dtype(column) else column.to_numpy()
        arrays.append(pa.array(values, from_pandas=True))
        fields.append(pa.field(c, arrays[-1].type))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def _write_range(
    out_dir: str | Path, df: pd.DataFrame, start: int, stop: int, name: Callable[[str], str]
) -> Path:
    """Validate rows of ONE object with ``grasp_id`` exactly ``start..stop-1``; write them atomically."""
    out = validate_labels(df)
    ids = out["object_id"].unique()
    if len(ids) != 1:
        raise SchemaError(f"a label file holds one object's labels, got object_ids {list(ids)[:5]}")
    grasp_ids = np.sort(out["grasp_id"].to_numpy())
    if not np.array_equal(grasp_ids, np.arange(start, stop)):
        raise SchemaError(f"grasp_id of {ids[0]!r} must be exactly {start}..{stop - 1}")
    out = out.sort_values("grasp_id", kind="stable").reset_index(drop=True)
    path = Path(out_dir) / name(str(ids[0]))
    table = _arrow_table(out)
    _atomic_write(path, lambda fh: pq.write_table(table, fh))
    log.debug("wrote %d labels of %s to %s", len(out), ids[0], path)
    return path


def write_object_labels(out_dir: str | Path, df: pd.DataFrame) -> Path:
    """Validate the labels of ONE object and write them atomically to ``out_dir``.

    ``df`` : N rows, one ``object_id``, ``grasp_id`` exactly 0..N-1. Extra columns are kept; write
    the same extra columns for every object (``read_parquet`` on the directory takes the first
    file's schema). Returns the path of the Parquet file, named by :func:`object_filename`.
    """
    return _write_range(out_dir, df, 0, len(df), object_filename)


def write_chunk_labels(out_dir: str | Path, df: pd.DataFrame, start: int) -> Path:
    """Write one chunk of one object: rows with ``grasp_id`` exactly ``start..start+len(df)-1``.

    The file is named by :func:`chunk_filename`; :func:`merge_chunks` later folds an object's
    chunks into its one file.
    """
    stop = start + len(df)
    return _write_range(out_dir, df, start, stop, lambda oid: chunk_filename(oid, start, stop))


def merge_chunks(out_dir: str | Path, object_id: str, files: Iterable[str]) -> pd.DataFrame:
    """One object's labels from its chunk files (names in ``out_dir``), sorted by grasp_id."""
    table = pa.concat_tables([pq.read_table(Path(out_dir) / f) for f in files])
    df = table.to_pandas().sort_values("grasp_id", kind="stable", ignore_index=True)
    if not (df["object_id"] == object_id).all():
        raise SchemaError(f"chunk files of {object_id!r} hold other objects' labels")
    return df


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (meshes for ``mesh_sha256``, label files for the manifest)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# --------------------------------------------------------------------------------- manifest


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def collect_versions() -> dict[str, str]:
    """Versions of Python and of the libraries that shape the labels (no pybullet import)."""
    versions = {"python": platform.python_version(), "platform": platform.platform()}
    for name, dist in [
        ("annotator", "rg2-annotator"),
        ("pybullet", "pybullet"),
        ("numpy", "numpy"),
        ("trimesh", "trimesh"),
        ("pandas", "pandas"),
        ("pyarrow", "pyarrow"),
    ]:
        versions[name] = _version(dist)
    return versions


def _normalise(obj: Any) -> Any:
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


@dataclass
class Manifest:
    """What a run was asked to do and how far it got; saved as ``_manifest.json`` beside the labels.

    objects_done : object_id -> {"file", "n", "sha256" (of the label file), "mesh_sha256", "time"}
    objects_failed : object_id -> one-line error
    chunks_done : object_id -> {"mesh_sha256", "files": {"start-stop": chunk file name}} for
        objects not finished yet; an object's entry goes when its chunks are merged.
    """

    config: dict[str, Any]
    seed: int
    n: int
    trials: int
    versions: dict[str, str] = field(default_factory=collect_versions)
    objects_done: dict[str, dict[str, Any]] = field(default_factory=dict)
    objects_failed: dict[str, str] = field(default_factory=dict)
    chunks_done: dict[str, dict[str, Any]] = field(default_factory=dict)
    created: str = field(default_factory=_now)
    updated: str = field(default_factory=_now)
    manifest_version: int = MANIFEST_VERSION

    def __post_init__(self) -> None:
        self.config = _normalise(self.config)
        self.seed, self.n, self.trials = int(self.seed), int(self.n), int(self.trials)

    # -- persistence
    @staticmethod
    def path(out_dir: str | Path) -> Path:
        return Path(out_dir) / MANIFEST_NAME

    @classmethod
    def load(cls, out_dir: str | Path) -> Manifest | None:
        """The manifest in ``out_dir``, or None if there is none."""
        path = cls.path(out_dir)
        if not path.exists():
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            known = {f.name for f in dataclasses.fields(cls)}
            return cls(**{k: v for k, v in data.items() if k in known})
        except (json.JSONDecodeError, TypeError) as exc:
            raise ManifestMismatchError(
                f"{path} is not a readable manifest ({exc}); pass --overwrite to start over"
            ) from exc

    def save(self, out_dir: str | Path) -> Path:
        """Write atomically; returns the path."""
        self.updated = _now()
        text = json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True, default=_json_default)
        path = self.path(out_dir)
        _atomic_write(path, lambda fh: fh.write(text.encode("utf-8") + b"\n"))
        return path

    # -- progress
    def mark_done(self, object_id: str, path: str | Path, n: int, mesh_sha256: str) -> None:
        """Record a label file just written: ``path`` as returned by :func:`write_object_labels`."""
        path = Path(path)
        self.objects_done[object_id] = {
            "file": path.name,
            "n": int(n),
            "sha256": file_sha256(path),
            "mesh_sha256": mesh_sha256,
            "time": _now(),
        }
        self.objects_failed.pop(object_id, None)
        self.chunks_done.pop(object_id, None)

    def mark_chunk(self, object_id: str, start: int, path: str | Path, n: int, mesh_sha256: str) -> None:
        """Record a chunk file just written (candidates ``start..start+n-1``) by write_chunk_labels."""
        entry = self.chunks_done.get(object_id)
        if entry is None or entry["mesh_sha256"] != mesh_sha256:
            entry = self.chunks_done[object_id] = {"mesh_sha256": mesh_sha256, "files": {}}
        entry["files"][f"{int(start)}-{int(start) + int(n)}"] = Path(path).name

    def chunks_of(
        self, object_id: str, out_dir: str | Path, mesh_sha256: str | None = None
    ) -> dict[tuple[int, int], str]:
        """Chunks of an unfinished object done earlier and still usable: (start, stop) -> file.

        A chunk counts if its file exists and (when given) the mesh hash is unchanged.
        """
        entry = self.chunks_done.get(object_id)
        if entry is None or (mesh_sha256 is not None and entry["mesh_sha256"] != mesh_sha256):
            return {}
        out: dict[tuple[int, int], str] = {}
        for key, name in entry["files"].items():
            start, stop = (int(v) for v in key.split("-"))
            if (Path(out_dir) / name).exists():
                out[(start, stop)] = name
        return out

    def mark_failed(self, object_id: str, error: BaseException | str) -> None:
        """Record a failure as one line (``Type: message``); the object is retried on resume."""
        if isinstance(error, BaseException):
            text = f"{type(error).__name__}: {error}"
        else:
            text = str(error)
        line = " ".join(text.split())[:500]
        self.objects_failed[object_id] = line
        self.objects_done.pop(object_id, None)
        self.chunks_done.pop(object_id, None)

    # -- resume
    def differences(self, config: Mapping[str, Any], seed: int, n: int, trials: int) -> list[str]:
        """Human-readable differences between this run and the requested one (empty if equal)."""
        diffs = []
        for name, mine, theirs in [
            ("seed", self.seed, seed),
            ("n", self.n, n),
            ("trials", self.trials, trials),
        ]:
            if int(mine) != int(theirs):
                diffs.append(f"{name}: {mine} in the manifest, {theirs} requested")
        if self.config != _normalise(dict(config)):
            diffs.append("config differs from the manifest's")
        return diffs

    def pending(
        self,
        object_ids: Iterable[str],
        out_dir: str | Path,
        mesh_sha256: Mapping[str, str] | None = None,
    ) -> list[str]:
        """The objects still to do, in the given order.

        An object is skipped only if it is done, its label file exists, and (when
        ``mesh_sha256`` is given) its mesh hash is unchanged. Failed objects are retried.
        """
        todo = []
        for oid in object_ids:
            done = self.objects_done.get(oid)
            if (
                done is None
                or not (Path(out_dir) / done["file"]).exists()
                or (mesh_sha256 is not None and done.get("mesh_sha256") != mesh_sha256.get(oid))
            ):
                todo.append(oid)
        return todo


def _remove_outputs(out_dir: Path) -> int:
    """Delete label files, leftover temp files and the manifest at the top of ``out_dir``."""
    removed = 0
    for p in out_dir.iterdir():
        if p.is_file() and (
            p.suffix == ".parquet"
            or p.name == MANIFEST_NAME
            or (p.name.startswith(".") and p.suffix == ".tmp")
        ):
            p.unlink()
            removed += 1
    return removed


def chunk_files(out_dir: str | Path, object_id: str) -> list[Path]:
    """Every chunk file of ``object_id`` in ``out_dir``, recorded in a manifest or not."""
    stem = object_filename(object_id)[: -len(".parquet")]
    return sorted(Path(out_dir).glob(f"{glob.escape(stem)}.*-*.parquet"))


def remove_chunks(out_dir: str | Path, object_id: str, keep: Iterable[str] = ()) -> int:
    """Delete ``object_id``'s chunk files except the names in ``keep``; returns how many."""
    keep = set(keep)
    stale = [p for p in chunk_files(out_dir, object_id) if p.name not in keep]
    for p in stale:
        p.unlink(missing_ok=True)
    return len(stale)


def _remove_merged_chunks(out_dir: Path, manifest: Manifest) -> None:
    """Delete chunk files of objects already merged into their file (a stop between the two steps)."""
    for oid in manifest.objects_done:
        if removed := remove_chunks(out_dir, oid):
            log.info("removed %d chunk files of %s: already merged into its file", removed, oid)


def open_run(
    out_dir: str | Path,
    config: Mapping[str, Any],
    seed: int,
    n: int,
    trials: int,
    overwrite: bool = False,
) -> Manifest:
    """Prepare ``out_dir`` for a run and return its manifest (already saved).

    * ``overwrite``: delete ``*.parquet``, stale temp files and the manifest there, start fresh.
    * an existing manifest with the same config, seed, n and trials: resume it (use
      :meth:`Manifest.pending` to choose the objects to run).
    * a manifest that differs, or label files without a manifest: raise
      :class:`ManifestMismatchError` telling the user to pass ``--overwrite``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if overwrite:
        removed = _remove_outputs(out)
        if removed:
            log.info("--overwrite: removed %d files from %s", removed, out)
        manifest = Manifest(config=dict(config), seed=seed, n=n, trials=trials)
        manifest.save(out)
        return manifest
    manifest = Manifest.load(out)
    if manifest is None:
        if any(p.suffix == ".parquet" for p in out.iterdir()):
            raise ManifestMismatchError(
                f"{out} holds label files but no {MANIFEST_NAME}; pass --overwrite to start over "
                "or choose another --out"
            )
        manifest = Manifest(config=dict(config), seed=seed, n=n, trials=trials)
        manifest.save(out)
        return manifest
    diffs = manifest.differences(config, seed, n, trials)
    if diffs:
        raise ManifestMismatchError(
            f"{out} holds a run with different settings ({'; '.join(diffs)}); pass --overwrite to "
            "start over or choose another --out"
        )
    _remove_merged_chunks(out, manifest)
    current = collect_versions()
    changed = {k: (manifest.versions.get(k), v) for k, v in current.items() if manifest.versions.get(k) != v}
    if changed:
        log.warning("resuming %s with different versions: %s", out, changed)
    log.info(
        "resuming %s: %d objects done, %d failed (failed ones are retried)",
        out,
        len(manifest.objects_done),
        len(manifest.objects_failed),
    )
    return manifest
