"""Reconciling an output folder with its manifest and the run: pure functions, a plan out.

Each function takes what the folder holds (a :class:`annotator.store.survey.Listing`, read
beforehand) and the manifest, and returns a :class:`FolderPlan`: the files to remove, put in place or set
aside, the manifest operations (journal operations, :data:`annotator.store.manifest.OP_SCHEMAS`)
and the lines to tell the user. Nothing here reads or writes a file; the store
(:class:`annotator.store.Store`) applies the plan.

Every file the manifest vouches for is verified against its checksum before it is trusted;
files this folder's run wrote that no manifest vouches for (written just before a kill) are
removed and redone; objects whose source changed are redone; objects no longer among the inputs
are set aside in ``_stale/``.

What the tool may touch (:func:`annotator.store.files.owner_of`): files marked by this folder's
run, under the names their marks give, and files named as it names label files that can no longer
be read (its own, corrupted). Everything else -- a user's files, another run's label files copied
in, links, FIFOs -- is never opened, deleted, moved or adopted, in any mode: it is named in the
run's notes (its summary), and a run that would have to write where such a file lies is refused.
"""

from __future__ import annotations

import collections
import re
from dataclasses import dataclass, field
from typing import Any

from annotator.store.artifacts import artifacts_ok
from annotator.store.errors import StoreError
from annotator.store.files import Owner, marked_span
from annotator.store.manifest import Manifest, RunSpec, chunk_range, utc_now
from annotator.store.names import STALE_DIR, merging_name, object_filename, object_stem
from annotator.store.survey import NO_SPAN, Listing

_CHUNK_RANGE = re.compile(r"\.\d{6,7}-\d{6,7}$")  # a chunk file's range after its object's stem


class ForeignFileError(StoreError):
    """The run would have to write where a file it did not write lies (exit code 2)."""


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


@dataclass
class FolderPlan:
    """What the store does to a folder, in this order: put ``complete`` merges in place (hidden
    merged file -> object file), move the files of ``set_aside`` objects (and their artifacts) to
    ``_stale/``, remove ``unlink`` (paths relative to the folder), remove ``rmdirs`` if empty,
    apply ``ops`` to the manifest (journalled), tell ``notes`` (the summary) and log ``logs``."""

    complete: list[str] = field(default_factory=list)
    set_aside: list[str] = field(default_factory=list)
    unlink: list[str] = field(default_factory=list)
    rmdirs: list[str] = field(default_factory=list)
    ops: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    logs: list[str] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)

    @property
    def touches_files(self) -> bool:
        return bool(self.complete or self.set_aside or self.unlink)

    def note(self, line: str) -> None:
        if line not in self.notes:
            self.notes.append(line)

    def note_foreign(self, name: str, owner: Owner) -> None:
        what = {
            Owner.OTHER_RUN: "written by another run",
            Owner.USER: "not a label file of this tool",
            Owner.NOT_A_FILE: "not a regular file",
        }[owner]
        line = f"{name}: {what}; left as it is"
        if owner is not Owner.NOT_A_FILE:
            line += " (pandas.read_parquet of the folder reads it too)"
        self.note(line)

    def remove_record(self, record: dict[str, Any]) -> None:
        """Remove a label file and the artifacts that came with it (their folders once empty)."""
        self.unlink.append(record["file"])
        for a in record.get("artifacts", {}).values():
            self.unlink.append(a["file"])
            self.rmdirs.append(a["file"].rsplit("/", 1)[0])


_KEEP_OWNERS = (Owner.OTHER_RUN, Owner.USER, Owner.NOT_A_FILE)


def folder_run_id(listing: Listing, run_key: str | None = None) -> str | None:
    """Without a readable manifest: the run most of the folder's marked label files belong to
    (only those of ``run_key`` if given); None if none carries a run id."""
    counts: collections.Counter[str] = collections.Counter()
    for name in listing.parquet:
        mark = listing.marks.get(name)
        if (
            mark
            and isinstance(mark.get("run_id"), str)
            and (run_key is None or mark.get("run_key") == run_key)
        ):
            counts[mark["run_id"]] += 1
    if not counts:
        return None
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[0][0]


# ---------------------------------------------------------------------------------- --overwrite


def plan_overwrite(listing: Listing) -> tuple[str | None, FolderPlan]:
    """--overwrite: remove the files of this folder's run (its manifest's, or, without one, the run
    most of its marked files belong to), leftovers, the manifest and its journal; never a user's
    file or another run's. Returns the folder's run id, which the new run keeps, and the plan."""
    recorded = listing.recorded
    assert recorded is not None, "survey with Need.OVERWRITE"
    run_id = recorded.run_id if recorded.readable else folder_run_id(listing)
    plan = FolderPlan()
    removed = 0
    for name in listing.parquet:
        owner = listing.owner(name, run_id)
        if owner in (Owner.THIS_RUN, Owner.CORRUPT) or (owner is Owner.OTHER_RUN and name in recorded.listed):
            plan.unlink.append(name)
            removed += 1
        else:
            plan.note_foreign(name, owner)
    plan.unlink += listing.temp + listing.artifacts + listing.stale_artifacts
    removed += len(listing.artifacts) + len(listing.stale_artifacts)
    for name in listing.stale_parquet:
        if listing.owner(name, run_id) in (Owner.THIS_RUN, Owner.CORRUPT):
            plan.unlink.append(name)
            removed += 1
    plan.rmdirs += [*listing.artifact_dirs, STALE_DIR]
    plan.unlink += listing.manifest_files
    if removed:
        plan.logs.append(f"--overwrite: removed {removed} label files from {listing.out_dir}")
    return run_id, plan


# ------------------------------------------------------------------------------------- --repair


def plan_rebuild(listing: Listing, spec: RunSpec) -> tuple[Manifest, FolderPlan]:
    """--repair: a manifest from the files of this run (its settings; the run id most of them carry)
    that verify. Files that do not are left as they are and named; unreadable ones named as the
    tool names its files are its own, broken: removed."""
    run_id = folder_run_id(listing, spec.key)
    manifest = Manifest.fresh(spec, run_id)
    plan = FolderPlan()
    kept = left = 0
    now = utc_now()
    for name in listing.parquet:
        owner = listing.owner(name, run_id)
        if owner is not Owner.THIS_RUN:
            if owner is Owner.CORRUPT:
                plan.unlink.append(name)
                plan.notes.append(f"{name}: unreadable; removed (its labels are redone)")
            else:
                plan.note_foreign(name, owner)
                left += owner is Owner.OTHER_RUN
            continue
        record = _verified_record(listing, name, spec)
        if isinstance(record, str):
            plan.note_foreign(name, Owner.OTHER_RUN)
            plan.logs.append(f"--repair: {name} cannot be trusted ({record}); left as it is")
            left += 1
            continue
        oid, start, stop, source = record.pop("_object")
        if name == object_filename(oid):
            manifest.objects_done[oid] = {
                **record,
                "source_sha256": source,
                "stats": listing.stats[name],
                "time": now,
            }
        else:
            entry = manifest.chunks_done.setdefault(oid, {"source_sha256": source, "files": {}})
            entry["files"][f"{start}-{stop}"] = record
        kept += 1
    for oid in manifest.objects_done:  # an object's file supersedes its chunks
        manifest.chunks_done.pop(oid, None)
    plan.notes.append(f"manifest rebuilt from {kept} label files that verify ({left} left as they are)")
    return manifest, plan


def _verified_record(listing: Listing, name: str, spec: RunSpec) -> dict[str, Any] | str:
    """The manifest record of a marked file of this run that verifies, or why it does not."""
    mark = listing.marks.get(name) or {}
    span = marked_span(mark)
    if span is None:
        return NO_SPAN
    oid, start, stop = span.object_id, span.start, span.stop
    why = listing.labels_why.get(name, "not verified")
    artifacts = mark.get("artifacts", {})
    if why is None and not artifacts_ok(mark):
        why = "its mark lists artifacts the tool does not write"
    if why is None:
        for a in artifacts.values():
            problem = listing.check(a["file"], a["sha256"])
            if problem:
                why = f"(its {a['file']} {problem})"
                break
    if why is None and name == object_filename(oid) and not (start == 0 and stop == spec.count(oid)):
        why = "not all of its object's candidates"
    if why is not None:
        return why
    record: dict[str, Any] = {"file": name, "sha256": listing.digests[name], "n": stop - start}
    if artifacts:
        record["artifacts"] = artifacts
    record["_object"] = (oid, start, stop, str(mark.get("source_sha256", "")))
    return record


# ------------------------------------------------------------------------------------- resuming


def plan_resume(listing: Listing, manifest: Manifest, *, read_only: bool) -> FolderPlan:
    """Every file the manifest vouches for must be a regular file matching its checksum; else its
    labels are redone (a merge that stopped after its chunks were removed is completed). Then files
    of this run the manifest does not vouch for (a chunk written just before a kill, a run stopped
    between writing and recording) and leftover temporary files go; every other file is left as it
    is and named. ``read_only``: the folder cannot be written: the manifest alone is corrected."""
    plan = FolderPlan()
    dropped = _check_records(plan, listing, manifest, read_only)
    if read_only:
        return plan
    kept = [rec for rec in manifest.label_records() if rec["file"] not in dropped]
    _remove_unvouched(plan, listing, manifest, kept)
    return plan


def _check_records(plan: FolderPlan, listing: Listing, manifest: Manifest, read_only: bool) -> set[str]:
    """The manifest's records checked against the files (a merge a run stopped in completed, a
    record that cannot be trusted dropped, its labels redone); returns the dropped files' names."""
    dropped: set[str] = set()
    for oid, entry in manifest.objects_done.items():
        name, hidden = entry["file"], merging_name(entry["file"])
        if (
            not read_only
            and name not in listing.present
            and hidden in listing.merging
            and listing.check_record(entry, hidden) is None
        ):
            plan.complete.append(name)
            plan.logs.append(f"{name}: completed a merge the last run stopped in")
            continue
        why = listing.check_record(entry)
        if why:
            _distrust(plan, listing, manifest, entry, why, oid, read_only)
            plan.ops.append({"op": "drop_done", "oid": oid})
            dropped.add(name)
    for oid, entry in manifest.chunks_done.items():
        for key, rec in entry["files"].items():
            why = listing.check_record(rec)
            if why:
                _distrust(plan, listing, manifest, rec, why, oid, read_only)
                plan.ops.append({"op": "drop_chunk", "oid": oid, "key": key})
                dropped.add(rec["file"])
    return dropped


def _remove_unvouched(
    plan: FolderPlan, listing: Listing, manifest: Manifest, kept: list[dict[str, Any]]
) -> None:
    """This run's files and artifacts that no ``kept`` record vouches for, and the temporaries
    (but a completed merge's), removed; other files named."""
    vouched = {rec["file"] for rec in kept}
    removing = set(plan.unlink)
    for name in listing.parquet:
        if name in vouched:
            continue
        owner = listing.owner(name, manifest.run_id)
        if owner in (Owner.THIS_RUN, Owner.CORRUPT):
            if name not in removing:
                plan.unlink.append(name)
                plan.logs.append(f"removed {name}: written but never recorded, or unreadable (redone)")
        else:
            plan.note_foreign(name, owner)
    completed = {merging_name(name) for name in plan.complete}
    plan.unlink += [name for name in listing.temp if name not in completed]
    keep = {a["file"] for rec in kept for a in rec.get("artifacts", {}).values()}
    unbound = [relpath for relpath in listing.artifacts if relpath not in keep]
    plan.unlink += unbound
    plan.rmdirs += listing.artifact_dirs
    if unbound:
        plan.logs.append(f"removed {len(unbound)} artifact files written but never recorded (redone)")


def _distrust(
    plan: FolderPlan,
    listing: Listing,
    manifest: Manifest,
    record: dict[str, Any],
    why: str,
    oid: str,
    read_only: bool,
) -> None:
    name = record["file"]
    owner = listing.owner(name, manifest.run_id) if name in listing.present else None
    if owner is not None and owner in _KEEP_OWNERS:  # a recorded name, not this run's file
        plan.note_foreign(name, owner)
        return
    plan.note(f"{name} {why}: redoing those labels of {oid}")
    if not read_only:
        plan.remove_record(record)


def plan_sources(listing: Listing, manifest: Manifest, sources: dict[str, str]) -> FolderPlan:
    """Match the folder to the objects of this run, ``sources``: object id -> source digest.

    Objects whose source changed lose their labels (redone); objects no longer present have
    their labels moved to ``_stale/`` (left out of the dataset); failed ones are retried. A file
    this run did not write lying where it must write an object's labels refuses the run
    (:class:`ForeignFileError`).
    """
    _refuse_foreign_at(listing, manifest, sources)
    m = manifest
    plan = FolderPlan()
    for oid in sorted(set(m.objects_done) | set(m.chunks_done)):
        recorded = (m.objects_done.get(oid) or m.chunks_done[oid])["source_sha256"]
        if oid not in sources:
            plan.stale.append(oid)
            plan.set_aside.append(oid)
            plan.ops.append({"op": "forget", "oid": oid})
        elif recorded != sources[oid]:
            plan.changed.append(oid)
            for record in records_of(m, oid):
                plan.remove_record(record)
            plan.ops.append({"op": "forget", "oid": oid})
            plan.notes.append(f"{oid}: its source changed since its labels were made; redone")
    for oid in plan.stale:
        plan.notes.append(f"{oid}: no longer among the objects; its labels moved to {STALE_DIR}/")
    if m.objects_failed:
        plan.ops.append({"op": "unfail"})
    plan.ops.append({"op": "header", "objects_planned": sorted(sources), "gripper_folder": m.gripper_folder})
    forgotten = set(plan.stale) | set(plan.changed)
    gone = [oid for oid in m.objects_info if oid not in sources and oid not in forgotten]
    plan.ops += [{"op": "drop_info", "oid": oid} for oid in gone]
    return plan


def resume_of(manifest: Manifest, plan: FolderPlan) -> Resume:
    """What the folder holds once ``plan`` (of :func:`plan_sources`) is applied to ``manifest``."""
    chunks = {
        oid: {chunk_range(key) for key in entry["files"]} for oid, entry in manifest.chunks_done.items()
    }
    return Resume(set(manifest.objects_done), chunks, plan.stale, plan.changed)


def _refuse_foreign_at(listing: Listing, manifest: Manifest, sources: dict[str, str]) -> None:
    """Refuse the run if a file it did not write lies under a name it writes for its objects."""
    stems = {object_stem(oid) for oid in sources}
    vouched = manifest.referenced_files()
    blocking = []
    for name in listing.parquet:
        stem = _CHUNK_RANGE.sub("", name[: -len(".parquet")])
        if stem not in stems or (name in vouched and name in listing.regular):
            continue
        if listing.owner(name, manifest.run_id) not in (Owner.THIS_RUN, Owner.CORRUPT):
            blocking.append(name)
    if blocking:
        shown = ", ".join(blocking[:3]) + (f" and {len(blocking) - 3} more" if len(blocking) > 3 else "")
        raise ForeignFileError(
            f"{listing.out_dir} holds {shown}, where this run writes labels, but this run did not write "
            "it; move it away or choose another --out (the tool never deletes a file it did not write)"
        )


def records_of(manifest: Manifest, oid: str) -> list[dict[str, Any]]:
    """The label file records of ``oid`` (its merged file, or its chunks)."""
    records = [manifest.objects_done[oid]] if oid in manifest.objects_done else []
    if oid in manifest.chunks_done:
        records += list(manifest.chunks_done[oid]["files"].values())
    return records
