"""Label file records and the artifacts bound to them: checking, writing and removing them.

Artifacts are files that belong with an object's labels (the Kinect views rendered with them).
Each is written atomically and recorded, with its checksum, in the record of the label file it
came with, so it is verified with it (a missing or corrupt artifact redoes those labels), removed
with it and set aside with it. Each view folder also lists the names the tool wrote in it
(:data:`WRITTEN_LIST`): only those are ever removed, so a user's file put beside them stays.
"""

from __future__ import annotations

import contextlib
import hashlib
from pathlib import Path
from typing import Any

from annotator.store.files import atomic_write, file_sha256, output_error
from annotator.store.names import artifact_relpath, is_artifact_relpath

# In each ``_views/<object stem>/`` folder: the names of the files the tool wrote there, one a
# line (hidden: never an artifact name, and skipped by pyarrow).
WRITTEN_LIST = ".rg2-annotator-written"


def written_names(folder: Path) -> set[str]:
    """The names the tool wrote in ``folder`` (its :data:`WRITTEN_LIST`)."""
    try:
        return set((folder / WRITTEN_LIST).read_text(encoding="utf-8").split("\n")) - {""}
    except (OSError, UnicodeDecodeError):
        return set()


def _list_written(folder: Path, names: set[str]) -> None:
    """Replace ``folder``'s list by ``names`` (removed when empty)."""
    path = folder / WRITTEN_LIST
    if names:
        atomic_write(path, lambda fh: fh.write("".join(f"{n}\n" for n in sorted(names)).encode()))
    else:
        path.unlink(missing_ok=True)


def tidy(folder: Path) -> None:
    """Forget the listed names no longer there; remove the folder once nothing else is in it."""
    with contextlib.suppress(OSError):
        listed = written_names(folder)
        present = {p.name for p in folder.iterdir()}
        if listed - present:
            _list_written(folder, listed & present)
        if present <= {WRITTEN_LIST}:
            (folder / WRITTEN_LIST).unlink(missing_ok=True)
            folder.rmdir()


def write_artifact(out_dir: Path, object_id: str, name: str, data: bytes) -> dict[str, str]:
    """Write ``data`` atomically as artifact ``name`` of ``object_id`` (``_views/<object stem>/<name>``)
    and return its record ``{"file", "sha256"}`` for the label file that vouches for it."""
    relpath = artifact_relpath(object_id, name)
    path = out_dir / relpath
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(path.parent, exc) from exc
    listed = written_names(path.parent)
    if name not in listed:  # listed before it exists: a kill between the two leaves no orphan
        _list_written(path.parent, listed | {name})
    atomic_write(path, lambda fh: fh.write(data))
    return {"file": relpath, "sha256": hashlib.sha256(data).hexdigest()}


def check_sha256(path: Path, sha256: str) -> str | None:
    """Why ``path`` does not hold bytes with this checksum ("missing", "corrupt: ..."), or None."""
    try:
        digest = file_sha256(path)
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return None if digest == sha256 else "corrupt: checksum mismatch"


def check_artifacts(out_dir: Path, artifacts: dict[str, dict[str, str]]) -> str | None:
    """Why one of a label file's artifacts cannot be trusted, or None."""
    for a in artifacts.values():
        why = check_sha256(out_dir / a["file"], a["sha256"])
        if why:
            return f"(its {a['file']} {why})"
    return None


def check_record(out_dir: Path, record: dict[str, Any]) -> str | None:
    """Why a label file (and the artifacts that came with it) cannot be trusted, or None."""
    why = check_sha256(out_dir / record["file"], record["sha256"])
    return why or check_artifacts(out_dir, record.get("artifacts", {}))


def delete_record(out_dir: Path, record: dict[str, Any]) -> None:
    """Remove a label file and the artifacts that came with it."""
    (out_dir / record["file"]).unlink(missing_ok=True)
    for a in record.get("artifacts", {}).values():
        path = out_dir / a["file"]
        path.unlink(missing_ok=True)
        tidy(path.parent)  # the folder goes once empty of anything but the tool's list


def artifacts_ok(record: dict[str, Any]) -> bool:
    """A record's optional ``artifacts``: name -> {"file" (a path the tool writes), "sha256"}."""
    artifacts = record.get("artifacts", {})
    return isinstance(artifacts, dict) and all(
        isinstance(a, dict) and is_artifact_relpath(a.get("file")) and isinstance(a.get("sha256"), str)
        for a in artifacts.values()
    )
