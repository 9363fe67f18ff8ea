"""The cold start in parallel: each object's decomposition task runs in a worker before its label
spans, once; the main process never loads or decomposes an object; runs that share one ``--cache``
decompose each object once between them; each object's warnings are reported once per run; the
progress shows the decomposition stage. Real workers, real CoACD on small concave blocks."""

from __future__ import annotations

import io
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import trimesh
from helpers import mount_tmpfs, run_annotate, umount, write_l

import annotator.objects
import annotator.objects.decomposition
import annotator.objects.decomposition_child
import annotator.objects.model
import annotator.objects.reading
import annotator.pipeline.loaded
from annotator.config import AnnotatorConfig
from annotator.objects import ObjectSource, discover_objects
from annotator.pipeline.plan import PlannedObject
from annotator.pipeline.progress import Progress
from annotator.pipeline.run import RunOptions, Workers, execute, run
from annotator.pipeline.schedule import Schedule
from annotator.pipeline.summary import Summary, format_summary
from annotator.pipeline.tasks import Prepare, PreparedObject, SpanResult, SpanTask
from annotator.pipeline.worker import label_span
from annotator.store import MANIFEST_NAME


def _objects(folder: Path) -> Path:
    """Two concave blocks (CoACD decomposes each in about a second) and a convex box."""
    write_l(folder / "corner.obj")
    write_l(folder / "large_corner.obj", size=1.3)
    trimesh.creation.box((0.05, 0.04, 0.10)).export(folder / "box.obj")
    return folder


def _ok(unit) -> SpanResult:
    return SpanResult(unit, None, None, None)  # type: ignore[arg-type]  # the schedule reads span, error


def _planned(k: int, done: dict[int, frozenset] | None = None) -> list[PlannedObject]:
    sources = [ObjectSource(f"o{i}", Path(f"/nowhere/o{i}.obj")) for i in range(k)]
    return [PlannedObject(s, (done or {}).get(i, frozenset())) for i, s in enumerate(sources)]


def _key(unit) -> tuple[str, str, int]:
    return ("prepare" if isinstance(unit, Prepare) else "span", unit.object_id, getattr(unit, "start", -1))


# ------------------------------------------------------------------------------------------ the plan


def _first(unit) -> tuple[str, str, int] | None:
    """The first span a decomposition task labels, as :func:`_key` names it."""
    return None if unit.first is None else _key(unit.first)


def test_each_object_is_decomposed_before_its_spans_and_one_worker_keeps_decomposing():
    """Two workers: both decompose first (the first objects in plan order), each task labelling its
    object's first span; an object's other spans start when its decomposition has finished, first
    ready object in plan order first; while objects wait, one decomposition runs alongside the
    labelling; a failed decomposition hands out none of its spans; a resumed object only its
    missing ones."""
    schedule = Schedule(_planned(4, {3: frozenset({(0, 10)})}), 30, 10, None, workers=2)
    first = [schedule.next() for _ in range(2)]
    assert [_key(u) for u in first] == [("prepare", "o0", -1), ("prepare", "o1", -1)]
    assert [_first(u) for u in first] == [("span", "o0", 0), ("span", "o1", 0)]
    assert [u.size for u in first] == [10, 10]
    assert schedule.next() is None  # no span before its object is ready, no third decomposition
    schedule.record(_ok(Prepare("o1", None, None)))  # o1 ready first: its spans, o0 still decomposing
    assert _key(schedule.next()) == ("span", "o1", 10)
    schedule.record(_ok(Prepare("o0", None, None)))
    # no decomposition out any more: the next one first, then o0's spans (before o1's, plan order)
    got = [schedule.next() for _ in range(4)]
    assert [_key(u) for u in got] == [
        ("prepare", "o2", -1),
        ("span", "o0", 10),
        ("span", "o0", 20),
        ("span", "o1", 20),
    ]
    assert _first(got[0]) == ("span", "o2", 0)
    # nothing ready to label: the last decomposition (with o3's first missing span), then nothing
    # until a result comes back
    last = schedule.next()
    assert _key(last) == ("prepare", "o3", -1) and _first(last) == ("span", "o3", 10)
    assert schedule.next() is None and not schedule.exhausted
    schedule.record(SpanResult(Prepare("o2", None, None), None, "o2: degenerate mesh", None))  # type: ignore[arg-type]
    assert schedule.next() is None
    schedule.record(_ok(Prepare("o3", None, None)))
    assert [_key(schedule.next()) for _ in range(1)] == [("span", "o3", 20)]
    assert schedule.next() is None and schedule.exhausted


def test_one_worker_labels_an_object_before_decomposing_the_next():
    """With one worker nothing runs alongside: decompose (and label the first span), label the
    rest, decompose the next (the first labels come with the first decomposition)."""
    schedule = Schedule(_planned(2), 30, 10, None, workers=1)
    order = []
    while not schedule.exhausted:
        unit = schedule.next()
        assert unit is not None
        order.append(_key(unit))
        if isinstance(unit, Prepare):
            order.append(_first(unit))
            schedule.record(_ok(unit))
    assert order == [
        ("prepare", "o0", -1),
        ("span", "o0", 0),
        ("span", "o0", 10),
        ("span", "o0", 20),
        ("prepare", "o1", -1),
        ("span", "o1", 0),
        ("span", "o1", 10),
        ("span", "o1", 20),
    ]


def test_an_object_of_one_span_is_one_task():
    """n no larger than a span: the decomposition task labels it all; nothing follows it."""
    schedule = Schedule(_planned(2), 5, 10, None, workers=2)
    units = [schedule.next(), schedule.next()]
    assert [(_key(u), _first(u)) for u in units] == [
        (("prepare", "o0", -1), ("span", "o0", 0)),
        (("prepare", "o1", -1), ("span", "o1", 0)),
    ]
    assert units[0].first.stop == 5
    for unit in units:
        schedule.record(_ok(unit))
    assert schedule.next() is None and schedule.exhausted


def test_a_warm_cache_keeps_the_decompositions_no_further_ahead_than_one_object_per_worker():
    """Decomposition tasks that come back at once (a warm cache: each only reads its object and
    labels its first span) do not run through every object ahead of the labelling (a worker keeps
    only so many objects, so the labelling would load them again): with two objects ready and none
    of their other spans handed out, a free worker labels; one more decomposition goes out as soon
    as the labelling starts one of them."""
    schedule = Schedule(_planned(5), 30, 10, None, workers=2)
    for unit in [schedule.next(), schedule.next()]:  # both workers decompose first
        schedule.record(_ok(unit))  # o0 and o1 ready, no other span of either handed out
    assert _key(schedule.next()) == ("span", "o0", 10)  # not the decomposition of o2
    assert _key(schedule.next()) == ("prepare", "o2", -1)  # o0 started: one object waits unstarted
    schedule.record(_ok(Prepare("o2", None, None)))
    got = [_key(schedule.next()) for _ in range(3)]  # o1 and o2 ready and unstarted: labelling
    assert got == [("span", "o0", 20), ("span", "o1", 10), ("prepare", "o3", -1)]
    # nothing left to label: a second decomposition alongside the first, as without a warm cache
    order = [_key(u) for u in iter(schedule.next, None)]
    assert order == [("span", "o1", 20), ("span", "o2", 10), ("span", "o2", 20), ("prepare", "o4", -1)]
    schedule.record(_ok(Prepare("o3", None, None)))
    schedule.record(_ok(Prepare("o4", None, None)))
    order = [_key(u) for u in iter(schedule.next, None)]
    assert order == [("span", "o3", 10), ("span", "o3", 20), ("span", "o4", 10), ("span", "o4", 20)]
    assert schedule.exhausted


def test_a_span_that_fails_stops_its_objects_other_spans():
    schedule = Schedule(_planned(1), 40, 10, None, workers=1)
    prepare = schedule.next()
    schedule.record(_ok(prepare))
    span = schedule.next()
    schedule.record(SpanResult(span, None, "worker on x has other versions", None))  # type: ignore[arg-type]
    assert schedule.next() is None and schedule.exhausted


def test_a_decomposition_whose_first_span_fails_hands_out_no_other_span():
    schedule = Schedule(_planned(1), 40, 10, None, workers=1)
    prepare = schedule.next()
    schedule.record(SpanResult(prepare, None, "o0: no stable placement", None))  # type: ignore[arg-type]
    assert schedule.next() is None and schedule.exhausted


# ------------------------------------------------------------------------------ the decomposition stage


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


DECOMPOSED = PreparedObject("coacd", 2, True, 1.25, 1.5, 1e-4, 1.2e-3, "coacd kept (threshold 0.05)")
CACHED = PreparedObject("coacd", 2, False, 0.0, 0.2, 1e-4, 1.2e-3, "coacd kept (threshold 0.05)")
HULL = PreparedObject("hull", 1, True, 0.0, 0.1, 0.0, 0.0)


def test_the_bar_counts_the_decomposition_stage_and_a_log_has_a_line_per_decomposed_object():
    assert DECOMPOSED.decomposed and not CACHED.decomposed and not HULL.decomposed
    terminal = _Terminal()
    progress = Progress(60, 3, quiet=False, stream=terminal, decompositions=3)
    for oid, prepared in (("corner", DECOMPOSED), ("box", HULL), ("mug", CACHED)):
        progress.prepared(oid, prepared.line() if prepared.decomposed else None)
    progress.advance(60)
    progress.close()
    drawn = terminal.getvalue()
    assert "decomposing 0/3" in drawn and "decomposing 2/3" in drawn and "[decomposed" not in drawn

    log = io.StringIO()  # not a terminal: one line per object decomposed, none for the others
    progress = Progress(60, 3, quiet=False, stream=log, decompositions=3)
    for oid, prepared in (("corner", DECOMPOSED), ("box", HULL), ("mug", CACHED)):
        progress.prepared(oid, prepared.line() if prepared.decomposed else None)
    assert log.getvalue().splitlines() == [
        "[decomposed, 1/3 objects ready] corner: decomposed by coacd into 2 parts in 1.2 CPU-s "
        "(collision error 0.10 / 1.20 mm)"
    ]
    assert CACHED.line() == "coacd, 2 parts, from the cache (collision error 0.10 / 1.20 mm)"


def test_the_summary_gives_each_warning_once_and_the_decompositions():
    summary = Summary(seconds=10.0)
    summary.warnings = {"open_box": ["mesh was open; filled 1 hole(s)"]}
    summary.prepared = {"corner": DECOMPOSED, "box": HULL}
    summary.ready_seconds = 4.0
    text = format_summary(summary)
    assert text.count("mesh was open") == 1
    assert "warning: open_box: mesh was open; filled 1 hole(s)" in text
    line = "1 object(s) decomposed in 1.2 CPU-s (the slowest corner, 1.2 CPU-s); every object ready 4.0 s"
    assert line in text


# ------------------------------------------------------------------------------------ with real workers


def recorded_label_span(task: SpanTask) -> SpanResult:
    """``label_span``, noting in the run's status folder what ran, when, where, and the CPU time
    of the processes the task waited for (a decomposition runs in such a child process)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    begin = time.time()
    result = label_span(task)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    note = {
        "unit": _key(task.span),
        "begin": begin,
        "end": time.time(),
        "pid": os.getpid(),
        "child_cpu": after.ru_utime + after.ru_stime - children.ru_utime - children.ru_stime,
        "made": result.prepared.made if result.prepared is not None else None,
        "error": result.error,
    }
    with open(Path(task.status_dir) / "tasks.jsonl", "a") as fh:
        fh.write(json.dumps(note) + "\n")
    return result


@pytest.mark.slow
def test_each_object_is_decomposed_once_by_a_worker_before_any_of_its_spans(tmp_path):
    objs = _objects(tmp_path / "objs")
    config = AnnotatorConfig()
    planned = [PlannedObject(s) for s in discover_objects(objs)]
    cache, notes = tmp_path / "cache", tmp_path / "status"
    notes.mkdir()
    workers = Workers(RunOptions(objs, 20, workers=2))
    results: list[SpanResult] = []
    try:
        execute(
            Schedule(planned, 20, 10, None, workers.count),
            lambda unit: SpanTask(
                span=unit,
                config=config,
                seed=0,
                n=20,
                parent_pid=os.getpid(),
                status_dir=str(notes),
                cache_dir=str(cache),
            ),
            workers,
            results.append,
            fn=recorded_label_span,
        )
    finally:
        workers.close(kill=True)
    ran = [json.loads(line) for line in (notes / "tasks.jsonl").read_text().splitlines()]
    # a decomposition task (that labels the first span) and the other span, each
    assert all(r["error"] is None for r in ran) and len(ran) == 3 * 2
    for oid in ("box", "corner", "large_corner"):
        (prepare,) = [r for r in ran if r["unit"][:2] == ["prepare", oid]]
        spans = [r for r in ran if r["unit"][:2] == ["span", oid]]
        assert sorted(r["unit"][2] for r in spans) == [10]
        assert all(r["begin"] >= prepare["end"] for r in spans), oid  # no span before it was ready
        assert prepare["pid"] != os.getpid() and prepare["made"] is True
        assert all(abs(r["child_cpu"]) < 1e-6 for r in spans), oid  # no span ran a decomposition
        if oid != "box":
            assert prepare["child_cpu"] > 0  # the decomposition ran, in its child process
    assert len(list(cache.glob("*.npz"))) == 2  # one entry per concave object; the box is its own hull
    prepared = {r.span.object_id: r.prepared for r in results if isinstance(r.span, Prepare)}
    assert prepared["corner"].decomposed and prepared["corner"].method == "coacd"
    assert not prepared["box"].decomposed and prepared["box"].method == "hull"
    assert all(len(r.rows) == 10 and r.labelled.start == 0 for r in results if isinstance(r.span, Prepare))
    assert sum(len(r.rows) for r in results if r.rows is not None) == 3 * 20


def _forbid(monkeypatch, module, name: str) -> None:
    def forbidden(*args, **kwargs):
        raise AssertionError(f"the main process called {module.__name__}.{name}")

    monkeypatch.setattr(module, name, forbidden)


DECOMPOSING = (
    (annotator.objects, "load_object"),
    (annotator.objects.model, "load_object"),
    (annotator.objects.model, "collision_geometry"),
    (annotator.objects.decomposition, "collision_geometry"),
    (annotator.objects.decomposition_child, "run_limited"),
    (annotator.pipeline.loaded, "load_object"),
)
READING = (
    (annotator.objects, "read_object_mesh"),
    (annotator.objects.model, "_read"),
    (annotator.objects.reading, "read_triangles"),
)


@pytest.mark.slow
def test_the_main_process_never_loads_or_decomposes_an_object(tmp_path, monkeypatch):
    """annotate and evaluate with an empty cache, every way this process could decompose an
    object made to raise (worker processes import their own, untouched): the workers decompose
    and the run reports it. annotate does not even read a mesh here; evaluate reads (never
    decomposes) the meshes of grasps without a width, to measure their chords."""
    from click.testing import CliRunner

    from annotator.cli import main

    for module, name in DECOMPOSING:
        _forbid(monkeypatch, module, name)
    objs = _objects(tmp_path / "objs")
    out, cache = tmp_path / "labels", tmp_path / "c"
    options = RunOptions(objs, 20, out_dir=out, workers=2, quiet=True, cache_dir=cache)
    with pytest.MonkeyPatch.context() as reading:
        for module, name in READING:
            _forbid(reading, module, name)
        summary = run(options, AnnotatorConfig())
    assert sorted(summary.done) == ["box", "corner", "large_corner"] and not summary.failed
    assert {oid for oid, p in summary.prepared.items() if p.decomposed} == {"corner", "large_corner"}
    assert summary.ready_seconds is not None and summary.ready_seconds <= summary.seconds

    labels = pd.read_parquet(out)
    poses = labels[["object_id", "x", "y", "z", "qx", "qy", "qz", "qw"]]  # no width: measured
    poses.to_parquet(tmp_path / "poses.parquet")
    # elsewhere: reused workers keep the objects they loaded, by file, and would not load them again
    objs = shutil.copytree(objs, tmp_path / "copy")
    args = ["evaluate", str(tmp_path / "poses.parquet"), "--objects", str(objs), "--out", str(tmp_path / "e")]
    args += ["--workers", "2", "--cache", str(tmp_path / "c2"), "--quiet"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert len(pd.read_parquet(tmp_path / "e")) == len(labels)
    assert "2 object(s) decomposed" in result.output  # an empty cache of its own: its workers made it


def _labels(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out).sort_values(["object_id", "grasp_id"]).reset_index(drop=True)


def _annotate(objs: Path, out: Path, cache: Path, *extra: str) -> subprocess.Popen:
    exe = Path(sys.executable).with_name("annotate")
    cmd = [str(exe), "--objects", str(objs), "--n", "20", "--out", str(out), "--cache", str(cache), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_two_runs_sharing_one_cache_decompose_each_object_once(tmp_path):
    """Two annotate processes started together on different --out with one empty --cache: each
    concave object is decomposed by one of them, the other waits for its entry; same labels."""
    objs = _objects(tmp_path / "objs")
    cache = tmp_path / "shared-cache"
    runs = [_annotate(objs, tmp_path / f"out{k}", cache, "--workers", "1") for k in (1, 2)]
    outputs = [p.communicate(timeout=600) for p in runs]
    for p, (out, err) in zip(runs, outputs, strict=True):
        assert p.returncode == 0, out + err
    decomposed = [
        line.split("] ", 1)[1].split(":")[0]
        for _, err in outputs
        for line in err.splitlines()
        if line.startswith("[decomposed")
    ]
    assert sorted(decomposed) == ["corner", "large_corner"], outputs  # once each, in one run or the other
    assert len(list(cache.glob("*.npz"))) == 2 and not list(cache.glob("*.tmp"))  # the box: no entry
    first, second = (_labels(tmp_path / f"out{k}") for k in (1, 2))
    pd.testing.assert_frame_equal(first, second, check_exact=True)


@pytest.mark.slow
def test_an_objects_warnings_are_reported_once_per_run_and_kept_in_the_manifest(tmp_path):
    """An open box (a face missing: its hole is filled, with a warning) labelled by 2 workers in 4
    spans: the warning is printed once, in the summary, and recorded in the manifest."""
    objs = tmp_path / "objs"
    objs.mkdir()
    box = trimesh.creation.box((0.05, 0.04, 0.10))
    trimesh.Trimesh(box.vertices, box.faces[2:], process=False).export(objs / "open_box.obj")
    box.export(objs / "box.obj")
    p = _annotate(objs, tmp_path / "out", tmp_path / "c", "--workers", "2", "--n", "40")
    out, err = p.communicate(timeout=600)
    assert p.returncode == 0, out + err
    text = out + err
    assert text.count("filled 1 hole") == 1, text
    assert "warning: open_box: mesh was open; filled 1 hole(s)" in out
    info = json.loads((tmp_path / "out" / MANIFEST_NAME).read_text())["objects_info"]
    assert info["open_box"]["warnings"] == ["mesh was open; filled 1 hole(s)"]
    assert info["box"]["warnings"] == []


def test_a_cache_folder_that_cannot_be_written_is_a_usage_error(tmp_path):
    objs = tmp_path / "objs"
    objs.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.10)).export(objs / "box.obj")
    (tmp_path / "file").write_text("not a folder")
    cache = tmp_path / "file" / "c"
    result = run_annotate("--objects", objs, "--n", 10, "--out", tmp_path / "o", "--cache", cache, check=2)
    assert "--cache" in result.output and "cannot write" in result.output
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.cluster
def test_cache_reaches_the_dask_workers(tmp_path, monkeypatch):
    """--cache names the folder every cluster worker uses (not its own default)."""
    distributed = pytest.importorskip("dask.distributed")
    objs = _objects(tmp_path / "objs")
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "default"))  # what the workers would use
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        run_annotate(
            "--objects", objs, "--n", 10, "--out", tmp_path / "o", "--scheduler", cluster.scheduler_address,
            "--cache", tmp_path / "shared", "--quiet",
        )  # fmt: skip
    assert len(list((tmp_path / "shared").glob("*.npz"))) == 2  # the concave blocks (the box: none)
    assert not (tmp_path / "default").exists()


def _annotate_process(*args) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def _read_labels(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out).sort_values(["object_id", "grasp_id"], kind="stable", ignore_index=True)


@pytest.mark.slow
@pytest.mark.root
def test_a_read_only_cache_is_read_and_what_it_lacks_is_made_aside(tmp_path):
    """A cluster's shared cache is often read-only: one holding every entry failed every run
    before any work ("cannot be written"). It is read; an object it lacks is decomposed and
    labelled as with a writable cache, the cache left as it was."""
    objs = _objects(tmp_path / "objs")
    disk = tmp_path / "cache"
    mount_tmpfs(disk, "16m")
    try:
        args = ["--n", 10, "--workers", 1, "--quiet", "--cache", disk]
        first = _annotate_process("--objects", objs, "--out", tmp_path / "first", *args)
        assert first.returncode == 0, first.stderr
        entries = sorted(p.name for p in disk.iterdir())
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        again = _annotate_process("--objects", objs, "--out", tmp_path / "again", *args)
        assert again.returncode == 0, again.stderr
        assert (
            f"the decomposition cache {disk} cannot be written" in again.stderr
            and "Traceback" not in again.stderr
        )
        pd.testing.assert_frame_equal(_read_labels(tmp_path / "again"), _read_labels(tmp_path / "first"))
        # an object the read-only cache lacks: decomposed aside, the same labels as a writable cache gives
        write_l(objs / "wide_corner.obj", size=1.6)
        lacking = _annotate_process("--objects", objs, "--out", tmp_path / "lacking", *args)
        assert lacking.returncode == 0, lacking.stderr
        assert sorted(p.name for p in disk.iterdir()) == entries
        writable = ["--n", 10, "--workers", 1, "--quiet", "--cache", tmp_path / "writable"]
        assert (
            _annotate_process("--objects", objs, "--out", tmp_path / "reference", *writable).returncode == 0
        )
        pd.testing.assert_frame_equal(
            _read_labels(tmp_path / "lacking"), _read_labels(tmp_path / "reference")
        )
    finally:
        umount(disk)
