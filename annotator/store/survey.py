"""What an output folder holds, read without changing anything: the facts a reconcile plan needs.

:func:`survey` lists the folder and reads what the plan will ask about (the checksum of each file
a manifest vouches for, the mark of each file it does not, the artifacts present); everything it
reads is in the returned :class:`Listing`, so :mod:`annotator.store.reconcile` decides from it
alone. How much it reads depends on the question (:class:`Need`): a resume hashes the files its
manifest vouches for and reads the marks of the others only; ``--overwrite`` and ``--repair`` read
every file's mark.
"""

from __future__ import annotations

import contextlib
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from annotator.store.artifacts import written_names
from annotator.store.files import (
    Owner,
    file_sha256,
    is_regular_file,
    is_temp_file,
    marked_span,
    read_labels,
    read_mark,
    verify_labels,
)
from annotator.store.manifest import Manifest, read_manifest_json
from annotator.store.names import (
    ARTIFACTS_DIR,
    JOURNAL_NAME,
    MANIFEST_NAME,
    STALE_DIR,
    chunk_filename,
    is_artifact_relpath,
    is_label_filename,
    is_object_stem,
    merging_name,
    object_filename,
)
from annotator.store.stats import object_stats

# why a marked file is not trusted when its mark names no object id or no integer rows
NO_SPAN = "its mark names no object and rows"


class Need(enum.Enum):
    """What the survey is for."""

    RESUME = "resume"  # check a manifest's records; marks of the files it does not vouch for
    SOURCES = "sources"  # marks of the files the manifest does not vouch for (no checksums)
    OVERWRITE = "overwrite"  # every file's mark, the stale folder, the recorded manifest's run id
    MARKS = "marks"  # every file's mark (a folder without a manifest: does it hold labels?)
    REPAIR = "repair"  # every file's mark; each marked file verified as the record its mark says


@dataclass
class Recorded:
    """A manifest as far as it can be read (schema or not): for ``--overwrite``."""

    readable: bool
    run_id: str | None
    listed: set[str]


@dataclass
class Listing:
    """An output folder as :func:`survey` read it (names relative to the folder, ``/``-separated).

    parquet : every ``*.parquet`` entry (present: the same as a set); regular : the regular files
    marks : the tool's mark of the entries read (None: unmarked or unreadable)
    unreadable : label-named regular files without a readable Parquet footer (the tool's, corrupt)
    digests : SHA-256 of the files hashed; problems : why a file to hash could not be ("missing")
    merging : hidden merged files present (``.<name>.merging``)
    temp : leftover temporary files; artifacts : artifact files (and temporaries) present;
        artifact_dirs : the folders the tool names an object's artifacts, present
    stale_parquet, stale_artifacts : the same in ``_stale/`` (``--overwrite``)
    recorded : the manifest as far as it reads (``--overwrite``)
    labels_why : per file of this run, why it cannot be trusted as its mark says, None if it can;
        stats : each such object file's figures (``--repair``)
    """

    out_dir: Path
    parquet: list[str] = field(default_factory=list)
    regular: set[str] = field(default_factory=set)
    marks: dict[str, dict[str, Any] | None] = field(default_factory=dict)
    unreadable: set[str] = field(default_factory=set)
    digests: dict[str, str] = field(default_factory=dict)
    problems: dict[str, str] = field(default_factory=dict)
    merging: set[str] = field(default_factory=set)
    temp: list[str] = field(default_factory=list)
    artifacts: list[str] = field(default_factory=list)
    artifact_dirs: list[str] = field(default_factory=list)
    manifest_files: list[str] = field(default_factory=list)
    stale_parquet: list[str] = field(default_factory=list)
    stale_artifacts: list[str] = field(default_factory=list)
    recorded: Recorded | None = None
    labels_why: dict[str, str | None] = field(default_factory=dict)
    stats: dict[str, dict[str, Any]] = field(default_factory=dict)
    present: set[str] = field(default_factory=set)  # parquet as a set

    def owner(self, name: str, run_id: str | None) -> Owner:
        """Who wrote ``name`` (as :func:`annotator.store.files.owner_of`); its mark must have been read."""
        if name not in self.regular:
            return Owner.NOT_A_FILE
        mark = self.marks[name]
        if mark is not None:
            oid, start, stop = mark.get("object_id"), mark.get("start"), mark.get("stop")
            leaf = name.rsplit("/", 1)[-1]
            named = (
                isinstance(oid, str)
                and isinstance(start, int)
                and isinstance(stop, int)
                and leaf in (object_filename(oid), chunk_filename(oid, start, stop))
            )
            return Owner.THIS_RUN if named and mark.get("run_id") == run_id else Owner.OTHER_RUN
        return Owner.CORRUPT if name in self.unreadable else Owner.USER

    def check(self, relpath: str, sha256: str) -> str | None:
        """Why the file does not hold bytes with this checksum, or None (it must have been hashed)."""
        if relpath in self.problems:
            return self.problems[relpath]
        return None if self.digests[relpath] == sha256 else "corrupt: checksum mismatch"

    def check_record(self, record: dict[str, Any], name: str | None = None) -> str | None:
        """Why a label file record (read as ``name`` if given) and its artifacts cannot be trusted."""
        name = name or record["file"]
        if name in self.present and name not in self.regular:
            return "is not a regular file"
        why = self.check(name, record["sha256"])
        if why:
            return why
        for a in record.get("artifacts", {}).values():
            why = self.check(a["file"], a["sha256"])
            if why:
                return f"(its {a['file']} {why})"
        return None


def survey(
    out_dir: Path,
    need: Need,
    manifest: Manifest | None = None,
    *,
    run_key: str | None = None,
) -> Listing:
    """Read what ``need`` asks about ``out_dir`` (``manifest``: the one to check, for RESUME and
    SOURCES; ``run_key``: the run's key, for REPAIR). Changes nothing."""
    listing = _list(Path(out_dir))
    if need in (Need.RESUME, Need.SOURCES):
        assert manifest is not None
        _read_for_resume(listing, manifest, resume=need is Need.RESUME)
        return listing
    for name in listing.parquet:
        _read_mark(listing, name)
    if need is Need.OVERWRITE:
        _read_for_overwrite(listing)
    elif need is Need.REPAIR:
        assert run_key is not None
        _verify_for_repair(listing, run_key)
    return listing


def _list(out: Path) -> Listing:
    """The folder's label files, temporaries, manifest files and artifacts, by name."""
    listing = Listing(out)
    entries = sorted(out.iterdir(), key=lambda p: p.name)
    listing.parquet = [p.name for p in entries if p.suffix == ".parquet"]
    listing.present = set(listing.parquet)
    listing.regular = {name for name in listing.parquet if is_regular_file(out / name)}
    listing.temp = [p.name for p in entries if is_temp_file(p) and is_regular_file(p)]
    listing.merging = {name for name in listing.temp if name.endswith(".merging")}
    listing.manifest_files = [n for n in (MANIFEST_NAME, JOURNAL_NAME) if is_regular_file(out / n)]
    listing.artifacts, listing.artifact_dirs = _artifacts(out, ARTIFACTS_DIR)
    return listing


def _read_for_resume(listing: Listing, manifest: Manifest, *, resume: bool) -> None:
    """The marks of the files the manifest does not vouch for (or that are not what it says) and,
    to ``resume``, the checksum of every file it does."""
    vouched = manifest.referenced_files()
    if resume:
        _hash_records(listing, manifest)
    for name in listing.parquet:
        if name not in vouched or (name in listing.problems or name not in listing.regular):
            _read_mark(listing, name)
    if resume:  # a recorded file whose bytes differ: whose is it?
        for rec in manifest.label_records():
            if rec["file"] in listing.regular and listing.check_record(rec):
                _read_mark(listing, rec["file"])


def _read_for_overwrite(listing: Listing) -> None:
    """What the manifest (readable or not) records, and the files set aside in ``_stale/``."""
    out = listing.out_dir
    listing.recorded = _recorded(out)
    stale = out / STALE_DIR
    if stale.is_dir() and not stale.is_symlink():
        for p in sorted(stale.iterdir()):
            if p.suffix == ".parquet":
                name = f"{STALE_DIR}/{p.name}"
                listing.stale_parquet.append(name)
                if is_regular_file(p):
                    listing.regular.add(name)
                _read_mark(listing, name)
        listing.stale_artifacts, dirs = _artifacts(out, f"{STALE_DIR}/{ARTIFACTS_DIR}")
        listing.artifact_dirs += dirs


def _verify_for_repair(listing: Listing, run_key: str) -> None:
    """Each marked file verified as the record its mark says (of the run ``run_key``), hashed with
    its artifacts, and a finished object's file's statistics."""
    out = listing.out_dir
    for name in listing.parquet:
        mark = listing.marks.get(name)
        if not mark:
            continue
        span = marked_span(mark)
        if span is None:
            listing.labels_why[name] = NO_SPAN
            continue
        why = verify_labels(out / name, run_key, span.object_id, span.start, span.stop)
        listing.labels_why[name] = why
        if why is not None:
            continue
        _hash(listing, name)
        artifacts = mark.get("artifacts")
        for a in artifacts.values() if isinstance(artifacts, dict) else []:
            if isinstance(a, dict) and is_artifact_relpath(a.get("file")):
                _hash(listing, a["file"])
        if name == object_filename(span.object_id):
            listing.stats[name] = object_stats(read_labels(out, [name]))


def _read_mark(listing: Listing, name: str) -> None:
    if name in listing.marks:
        return
    path = listing.out_dir / name
    mark = read_mark(path)
    listing.marks[name] = mark
    if mark is None and name in listing.regular and is_label_filename(path.name):
        try:
            pq.read_schema(path)
        except Exception:
            listing.unreadable.add(name)


def _hash(listing: Listing, relpath: str) -> None:
    if relpath in listing.digests or relpath in listing.problems:
        return
    path = listing.out_dir / relpath
    try:
        listing.digests[relpath] = file_sha256(path)
    except FileNotFoundError:
        listing.problems[relpath] = "missing"
    except OSError as exc:
        listing.problems[relpath] = f"unreadable ({exc.strerror or exc})"


def _hash_records(listing: Listing, manifest: Manifest) -> None:
    """The checksum of every file the manifest vouches for (and of the artifacts), and of each
    hidden merged file whose object's file is not in place."""
    for rec in manifest.label_records():
        name = rec["file"]
        if name in listing.regular or name not in listing.present:
            _hash(listing, name)
        for a in rec.get("artifacts", {}).values():
            _hash(listing, a["file"])
    for rec in manifest.objects_done.values():
        hidden = merging_name(rec["file"])
        if rec["file"] not in listing.present and hidden in listing.merging:
            _hash(listing, hidden)


def _artifacts(out: Path, under: str) -> tuple[list[str], list[str]]:
    """Artifact files (and temporaries) the tool may have written under ``under``, and the folders
    holding them (the object folders, then ``under``), relative paths."""
    root = out / under
    found: list[str] = []
    if not root.is_dir():
        return found, []
    dirs: list[str] = []
    for folder in sorted(root.iterdir()):
        if not (folder.is_dir() and is_object_stem(folder.name)):
            continue
        dirs.append(f"{under}/{folder.name}")
        written = written_names(folder)  # only what the tool wrote there: a user's file stays
        for p in sorted(folder.iterdir()):
            relpath = f"{ARTIFACTS_DIR}/{folder.name}/{p.name}"
            ours = p.name in written and is_artifact_relpath(relpath)
            if p.is_file() and (ours or is_temp_file(p)):
                found.append(f"{under}/{folder.name}/{p.name}")
    return found, [*dirs, under]


def _recorded(out: Path) -> Recorded:
    """(readable, run id, listed label files) of the folder's manifest, schema or not."""
    with contextlib.suppress(Exception):
        data = read_manifest_json(Manifest.path(out))
        run_id = data.get("run_id") if isinstance(data.get("run_id"), str) else None
        listed = {e["file"] for e in data.get("objects_done", {}).values()}
        for entry in data.get("chunks_done", {}).values():
            listed |= {r["file"] for r in entry["files"].values()}
        return Recorded(True, run_id, {name for name in listed if is_label_filename(name)})
    return Recorded(False, None, set())
