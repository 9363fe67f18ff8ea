"""Label files on disk: atomic writes with a checksum, the tool's mark, reading back.

Every Parquet file the tool writes carries a key-value entry ``rg2_annotator`` in its schema
metadata (the run key, the object id and the grasp range), so the tool can tell its own files from
a user's (``--overwrite`` and clean-ups touch only marked files) and rebuild a lost manifest from
the files themselves. pyarrow's dataset discovery skips names starting with ``.`` or ``_``: the
manifest is ``_manifest.json`` and temporary files start with ``.``.
"""

from __future__ import annotations

import enum
import errno
import hashlib
import io
import json
import logging
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from annotator import files
from annotator.label_table import COLUMNS, SchemaError, validate_labels
from annotator.schema import STRING
from annotator.store.names import (
    chunk_filename,
    is_label_filename,
    is_temp_file_name,
    object_filename,
    scene_unit,
)

log = logging.getLogger(__name__)

MARK_KEY = b"rg2_annotator"  # schema metadata key of every label file the tool writes
_ARROW_TYPES = {STRING: pa.string(), "int64": pa.int64(), "float64": pa.float64(), "bool": pa.bool_()}


class OutputError(OSError):
    """The output folder cannot be written (disk full, read-only, permissions): exit code 3."""

    def __str__(self) -> str:  # the one line, without OSError's "[Errno N] ...: 'path'" dressing
        return str(self.strerror or super().__str__())


def output_error(path: Path | str, exc: OSError) -> OutputError:
    """One line naming the path and the system's reason, e.g. ``No space left on device``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    err = OutputError(exc.errno or errno.EIO, f"cannot write {path}: {reason}")
    err.filename = str(path)
    return err


def atomic_write(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Write ``path`` whole or not at all (:func:`annotator.files.atomic_write`: a hidden temporary
    file in the same folder, fsync, os.replace).

    An OSError (disk full, read-only, permission) becomes :class:`OutputError` naming ``path``;
    the temporary file is removed.
    """
    try:
        files.atomic_write(path, write)
    except OSError as exc:
        raise output_error(path, exc) from exc


def is_temp_file(path: Path) -> bool:
    """A leftover temporary file of :func:`atomic_write` (from a killed run)."""
    return is_temp_file_name(path.name)


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (meshes for ``mesh_sha256``, label files for the manifest)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class FileRecord:
    """A label file as written: its name in the output folder, SHA-256 of its bytes, rows."""

    name: str
    sha256: str
    n: int

    def to_json(self) -> dict[str, Any]:
        return {"file": self.name, "sha256": self.sha256, "n": self.n}


def arrow_table(df: pd.DataFrame, mark: dict[str, Any] | None = None) -> pa.Table:
    """Required columns with fixed Arrow types first, extra columns after, no index.

    Built column by column from numpy (``pa.Table.from_pandas`` plus a cast costs ~20 ms per
    table, which the writer pays for every chunk). ``mark`` goes into the schema metadata.
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
    metadata = {MARK_KEY: json.dumps(mark, sort_keys=True).encode()} if mark is not None else None
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=metadata))


def unit_ids(df: pd.DataFrame) -> np.ndarray:
    """The unit of work each row belongs to, (n,) str: its ``object_id``, or for the labels of a
    scene (rows with a ``scene_id`` column, ``annotate --scenes``) the scene's unit id
    (:func:`annotator.store.names.scene_unit`), whose rows name several objects."""
    if "scene_id" in df.columns:
        return np.array([scene_unit(s) for s in df["scene_id"].to_numpy()], dtype=object)
    return df["object_id"].to_numpy(dtype=object)


def write_labels(
    out_dir: Path,
    df: pd.DataFrame,
    start: int,
    stop: int,
    name: str,
    run_key: str,
    source_sha256: str,
    artifacts: dict[str, dict[str, str]] | None = None,
    *,
    run_id: str | None = None,
) -> FileRecord:
    """Validate rows of ONE object (or scene: :func:`unit_ids`) with ``grasp_id`` exactly
    ``start..stop-1``; write them atomically
    as ``out_dir / name``, marked as the tool's (``run_key``, the folder's ``run_id``, the object's
    ``source_sha256`` and the records of the ``artifacts`` that came with these labels, so a lost
    manifest can be rebuilt from the files and another run's files are never taken for this
    run's); return the file's record."""
    out = validate_labels(df)
    ids = pd.unique(unit_ids(out))
    if len(ids) != 1:
        raise SchemaError(f"a label file holds one object's labels, got object_ids {list(ids)[:5]}")
    grasp_ids = np.sort(out["grasp_id"].to_numpy())
    if not np.array_equal(grasp_ids, np.arange(start, stop)):
        raise SchemaError(f"grasp_id of {ids[0]!r} must be exactly {start}..{stop - 1}")
    out = out.sort_values("grasp_id", kind="stable").reset_index(drop=True)
    mark = {
        "run_key": run_key,
        "object_id": str(ids[0]),
        "start": int(start),
        "stop": int(stop),
        "source_sha256": source_sha256,
    }
    if artifacts:
        mark["artifacts"] = artifacts
    if run_id is not None:
        mark["run_id"] = run_id
    buffer = io.BytesIO()
    pq.write_table(arrow_table(out, mark), buffer)
    data = buffer.getvalue()
    atomic_write(out_dir / name, lambda fh: fh.write(data))
    log.debug("wrote %d labels of %s to %s", len(out), ids[0], name)
    return FileRecord(name, hashlib.sha256(data).hexdigest(), len(out))


def is_regular_file(path: Path) -> bool:
    """``path`` is a regular file itself (not a link, a FIFO, a device or a folder): the only kind
    of file the tool opens in an output folder (opening a FIFO would hang the run)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def read_mark(path: Path) -> dict[str, Any] | None:
    """The tool's mark of a Parquet file (footer only), or None for anything else or unreadable."""
    if not is_regular_file(path):
        return None
    try:
        metadata = pq.read_schema(path).metadata or {}
        mark = json.loads(metadata[MARK_KEY])
    except Exception:  # not Parquet, truncated, not ours: all mean "not a file we can vouch for"
        return None
    return mark if isinstance(mark, dict) else None


@dataclass(frozen=True)
class MarkedSpan:
    """What a label file's mark says it holds: rows ``start`` .. ``stop - 1`` of ``object_id``."""

    object_id: str
    start: int
    stop: int


def marked_span(mark: dict[str, Any]) -> MarkedSpan | None:
    """The object and rows ``mark`` names; None when its id is not a string or a bound not an
    integer (a mark this tool did not write)."""
    oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
    if isinstance(oid, str) and isinstance(start, int) and isinstance(stop, int):
        return MarkedSpan(oid, start, stop)
    return None


class Owner(enum.Enum):
    """Who wrote a file found in an output folder, as far as the file itself can tell."""

    THIS_RUN = "this run"  # marked by the folder's run, under the name its mark gives
    OTHER_RUN = "another run"  # marked by the tool, but by another run (or renamed)
    CORRUPT = "corrupt"  # named as the tool names label files, and no longer readable
    USER = "the user"  # anything else: a user's own file
    NOT_A_FILE = "not a regular file"  # a link, a FIFO, a folder: never opened, never touched


def owner_of(path: Path, run_id: str | None) -> Owner:
    """Who wrote ``path``: only :attr:`Owner.THIS_RUN` and :attr:`Owner.CORRUPT` files are ever
    removed or replaced by the tool (``run_id``: the folder's run, None for folders of versions
    that did not record one)."""
    if not is_regular_file(path):
        return Owner.NOT_A_FILE
    mark = read_mark(path)
    if mark is not None:
        oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
        named = (
            isinstance(oid, str)
            and isinstance(start, int)
            and isinstance(stop, int)
            and path.name in (object_filename(oid), chunk_filename(oid, start, stop))
        )
        return Owner.THIS_RUN if named and mark.get("run_id") == run_id else Owner.OTHER_RUN
    if is_label_filename(path.name):
        try:
            pq.read_schema(path)
        except Exception:
            return Owner.CORRUPT
    return Owner.USER


def read_labels(out_dir: Path, names: list[str]) -> pd.DataFrame:
    """Rows of the named files in ``out_dir``, concatenated and sorted by (object_id, grasp_id)."""
    table = pa.concat_tables([pq.read_table(out_dir / n) for n in names])
    return table.to_pandas().sort_values(["object_id", "grasp_id"], kind="stable", ignore_index=True)


def verify_labels(path: Path, run_key: str, object_id: str, start: int, stop: int) -> str | None:
    """Why ``path`` cannot be trusted as rows ``start..stop-1`` of ``object_id`` of this run, or None.

    Used when the manifest is lost: the file must be the tool's, of this run, readable, and hold
    exactly the promised rows, valid against the schema.
    """
    mark = read_mark(path)
    if mark is None:
        return "not a label file of this tool (unreadable or unmarked)"
    if mark.get("run_key") != run_key:
        return "written by a run with other settings"
    if (mark.get("object_id"), mark.get("start"), mark.get("stop")) != (object_id, start, stop):
        return "its mark does not match its name"
    try:
        df = validate_labels(pq.read_table(path).to_pandas())
    except Exception as exc:
        return f"unreadable ({type(exc).__name__}: {exc})"
    if set(unit_ids(df)) != {object_id} or sorted(df["grasp_id"]) != list(range(start, stop)):
        return "holds other rows than its name says"
    return None
