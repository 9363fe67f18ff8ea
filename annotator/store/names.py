"""What the tool names the files of an output folder, and how it recognises its own names.

Neutral: no pandas, no pyarrow, no pipeline. The cell's views and the tools use these names too.

    labels/
      _manifest.json                          the run, and how far it got when last compacted
      _journal.jsonl                          what finished since (annotator.store.journal)
      .rg2-annotator.lock                     held by the run writing here (annotator.store.lock)
      mug-3f2a9c01d4.parquet                  one file per finished object
      can-8c1e0b77aa.000050-000060.parquet    a finished chunk of an object still running
      _views/mug-3f2a9c01d4/p00_v00_depth.png an artifact that came with the object's labels
      _stale/                                 labels of objects no longer among the inputs

pyarrow's dataset discovery skips names starting with ``.`` or ``_``, so
``pandas.read_parquet(OUT)`` reads label files only.
"""

from __future__ import annotations

import hashlib
import re

MANIFEST_NAME = "_manifest.json"
JOURNAL_NAME = "_journal.jsonl"
LOCK_NAME = ".rg2-annotator.lock"
STALE_DIR = "_stale"
# Per-object artifacts (the Kinect views of ``annotate --cell --views``) live in
# ``ARTIFACTS_DIR/<object stem>/<name>``.
ARTIFACTS_DIR = "_views"

_TEMP_RE = re.compile(r"^\..+\.([A-Za-z0-9_]+\.tmp|merging)$")  # atomic_write's temporaries, merges
_LABEL_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*-[0-9a-f]{10}(\.\d{6}-\d{6})?\.parquet$")
_ARTIFACT_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_OBJECT_STEM_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*-[0-9a-f]{10}$")


def scene_unit(scene_id: int) -> str:
    """The unit id of scene ``scene_id`` of ``annotate --scenes`` (its files are named from it as an
    object's are): ``scene_000003``."""
    return f"scene_{int(scene_id):06d}"


def is_scene_unit(unit: str) -> bool:
    """Whether ``unit`` is a scene's unit id (:func:`scene_unit`), not an object's."""
    prefix, _, digits = unit.partition("_")
    return prefix == "scene" and digits.isdigit() and scene_unit(int(digits)) == unit


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


def object_stem(object_id: str) -> str:
    """``object_filename`` without ``.parquet``: the object's chunk prefix and artifact folder."""
    return object_filename(object_id)[: -len(".parquet")]


def chunk_filename(object_id: str, start: int, stop: int) -> str:
    """File name of candidates ``start..stop-1`` of an object: ``<object stem>.SSSSSS-EEEEEE.parquet``."""
    return f"{object_stem(object_id)}.{start:06d}-{stop:06d}.parquet"


def merging_name(name: str) -> str:
    """Where an object's merged file is written before it replaces its chunks: hidden, so
    ``read_parquet`` never sees the merged rows and the chunks at once."""
    return f".{name}.merging"


def is_label_filename(name: object) -> bool:
    """``name`` is a plain file name (no folder) of the form the tool gives label files."""
    return isinstance(name, str) and _LABEL_NAME_RE.match(name) is not None


def is_temp_file_name(name: str) -> bool:
    """A temporary file name of :func:`annotator.store.files.atomic_write` or a merge (left by a
    killed run)."""
    return _TEMP_RE.match(name) is not None


def is_object_stem(name: str) -> bool:
    """A folder name the tool gives an object's artifacts."""
    return _OBJECT_STEM_RE.match(name) is not None


def is_artifact_relpath(path: object) -> bool:
    """``path`` names a file the tool would write as an artifact (``_views/<object stem>/<name>``),
    so a manifest or a mark can never point the tool at another file to check or delete."""
    if not isinstance(path, str):
        return False
    parts = path.split("/")
    return (
        len(parts) == 3
        and parts[0] == ARTIFACTS_DIR
        and is_object_stem(parts[1])
        and _ARTIFACT_NAME_RE.match(parts[2]) is not None
    )


def artifact_relpath(object_id: str, name: str) -> str:
    """Where artifact ``name`` of ``object_id`` lives, relative to the output folder (``/``-separated).

    ``name``: a plain file name (letters, digits, ``.``, ``_``, ``-``; not hidden); ValueError else.
    """
    if not _ARTIFACT_NAME_RE.match(name):
        raise ValueError(f"artifact name {name!r}: use letters, digits, '.', '_' and '-' only")
    return f"{ARTIFACTS_DIR}/{object_stem(object_id)}/{name}"
