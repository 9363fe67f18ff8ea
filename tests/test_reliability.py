"""Faults injected on purpose, end to end: killed workers, two runs at once, a full or read-only
disk, a lost scheduler, a killed or terminated main process, changed inputs, rotten files.

Each test covers a line of the fault table in docs/reliability.md, which names it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import trimesh
from helpers import mount_tmpfs, run_annotate, umount

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects
from annotator.pipeline.plan import PlannedObject
from annotator.pipeline.run import RunOptions, Workers, execute
from annotator.pipeline.schedule import Schedule
from annotator.pipeline.tasks import Prepare, Span, SpanResult, SpanTask
from annotator.pipeline.worker import label_span
from annotator.store import LOCK_NAME, MANIFEST_NAME, STALE_DIR
from annotator.store.names import object_filename

N = 20  # two spans per object


@pytest.fixture(scope="module", autouse=True)
def _cache_dir(tmp_path_factory):
    """Decomposition cache in a tmp dir, set before any run (and inherited by worker processes)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RG2_CACHE_DIR", str(tmp_path_factory.mktemp("rg2-cache")))
        yield


def _objects(folder: Path, names=("box", "cylinder", "slab")) -> Path:
    makers = {
        "box": lambda: trimesh.creation.box((0.05, 0.04, 0.10)),
        "cylinder": lambda: trimesh.creation.cylinder(radius=0.03, height=0.09, sections=24),
        "slab": lambda: trimesh.creation.box((0.08, 0.03, 0.06)),
        "poison": lambda: trimesh.creation.box((0.04, 0.04, 0.04)),
    }
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        makers[name]().export(folder / f"{name}.obj")
    return folder


def _labels(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out).sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def _spawn(objs: Path, out: Path, *extra) -> subprocess.Popen:
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()"]
    cmd += ["--objects", str(objs), "--out", str(out), "--quiet", *map(str, extra)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=objs.parent)


def _wait_for_labels(proc: subprocess.Popen, out: Path, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not list(out.glob("*.parquet")):
        assert proc.poll() is None, f"finished before the first file:\n{proc.communicate()}"
        assert time.monotonic() < deadline, "no label file in time"
        time.sleep(0.02)


def _workers_of(pid: int) -> list[int]:
    """The loky worker processes of ``pid`` (not its resource trackers)."""
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(k) for k in (task / "children").read_text().split()]
    return [k for k in kids if b"popen_loky_posix" in Path(f"/proc/{k}/cmdline").read_bytes()]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.fixture(scope="module")
def objs(tmp_path_factory) -> Path:
    return _objects(tmp_path_factory.mktemp("objs"))


@pytest.fixture(scope="module")
def reference_out(objs, tmp_path_factory) -> Path:
    """The output folder of one whole run of the three objects (tests copy it before they change it)."""
    out = tmp_path_factory.mktemp("ref") / "labels"
    run_annotate("--objects", objs, "--n", N, "--workers", 1, "--out", out, "--quiet")
    return out


@pytest.fixture(scope="module")
def reference(reference_out) -> pd.DataFrame:
    return _labels(reference_out)


# --- 2. one run per output folder ----------------------------------------------------------------


@pytest.mark.slow
def test_a_second_run_on_the_same_out_is_a_usage_error_naming_the_first(objs, reference, tmp_path):
    out = tmp_path / "out"
    first = _spawn(objs, out, "--n", N, "--workers", 1)
    try:
        _wait_for_labels(first, out)
        second = run_annotate("--objects", objs, "--n", N, "--workers", 1, "--out", out, "--seed", 1, check=2)
        assert f"pid {first.pid}" in second.output and "in use by another run" in second.output
        _, stderr = first.communicate(timeout=180)
    finally:
        first.kill()
        first.wait()
    assert first.returncode == 0, stderr
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)  # nothing mixed in


@pytest.mark.slow
def test_removing_the_lock_file_during_a_run_frees_nothing(objs, reference, tmp_path):
    out = tmp_path / "out"
    first = _spawn(objs, out, "--n", N, "--workers", 1)
    try:
        _wait_for_labels(first, out)
        (out / LOCK_NAME).unlink()
        second = run_annotate("--objects", objs, "--n", N, "--workers", 1, "--out", out, "--seed", 1, check=2)
        assert "in use by another run" in second.output
        _, stderr = first.communicate(timeout=180)
    finally:
        first.kill()
        first.wait()
    assert first.returncode == 0 and "Traceback" not in stderr, stderr
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


# --- 3. resume binds every label-affecting input ---------------------------------------------------


@pytest.mark.slow
def test_changed_inputs_are_refused_or_redone(objs, reference, tmp_path):
    local = shutil.copytree(objs, tmp_path / "objs")
    out = tmp_path / "out"
    args = ["--objects", local, "--n", N, "--workers", 1, "--out", out, "--quiet"]
    run_annotate(*args)
    r = run_annotate(*args, "--scale", 1.5, check=2)
    assert "scale None in the folder, 1.5 now" in r.output
    cfg = tmp_path / "c.toml"
    cfg.write_text("[gripper]\nstall_steps = 20\n")
    r = run_annotate(*args, "--config", cfg, check=2)
    assert "[gripper] stall_steps 12 in the folder, 20 now" in r.output
    # one object's file changes: it alone is redone; another is removed: its labels are set aside
    trimesh.creation.box((0.05, 0.045, 0.10)).export(local / "box.obj")
    (local / "slab.obj").unlink()
    r = run_annotate(*args)
    assert "box: its source changed" in r.output and "slab: no longer among the objects" in r.output
    assert "1 objects labelled, 1 done earlier" in r.output
    df = _labels(out)
    assert set(df["object_id"]) == {"box", "cylinder"}
    cyl = df[df.object_id == "cylinder"].reset_index(drop=True)
    pd.testing.assert_frame_equal(cyl, reference[reference.object_id == "cylinder"].reset_index(drop=True))
    assert not df[df.object_id == "box"]["mesh_sha256"].isin(reference["mesh_sha256"]).any()
    assert (out / STALE_DIR / object_filename("slab")).exists()


@pytest.mark.slow
def test_a_mesh_changed_behind_an_unchanged_urdf_is_redone(tmp_path):
    objs = tmp_path / "objs"
    (objs / "thing").mkdir(parents=True)
    trimesh.creation.box((0.05, 0.04, 0.08)).export(objs / "thing" / "thing.obj")
    (objs / "thing" / "thing.urdf").write_text(
        '<robot name="thing"><link name="base"><collision><geometry><mesh filename="thing.obj"/>'
        "</geometry></collision></link></robot>"
    )
    out = tmp_path / "out"
    args = ["--objects", objs, "--n", 10, "--workers", 1, "--out", out, "--quiet"]
    run_annotate(*args)
    before = _labels(out)
    trimesh.creation.box((0.05, 0.05, 0.08)).export(objs / "thing" / "thing.obj")
    r = run_annotate(*args)
    assert "thing/thing: its source changed" in r.output
    after = _labels(out)
    assert len(after) == 10 and set(after["mesh_sha256"]).isdisjoint(before["mesh_sha256"])


# --- 4. state that rots --------------------------------------------------------------------------------


def test_a_truncated_label_file_is_named_and_redone(objs, reference_out, reference, tmp_path):
    out = tmp_path / "out"
    args = ["--objects", objs, "--n", N, "--workers", 1, "--out", out, "--quiet"]
    shutil.copytree(reference_out, out)  # a whole run of args
    victim = out / object_filename("cylinder")
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    r = run_annotate(*args)
    assert victim.name in r.output and "checksum" in r.output
    assert "1 objects labelled, 2 done earlier" in r.output
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


@pytest.mark.parametrize("content", [b"[]", b"null", b"\x00\xff\x10binary", b'{"tool": "rg2-annotator"}'])
def test_a_broken_manifest_is_one_line_and_repair_recovers(objs, reference_out, reference, tmp_path, content):
    out = tmp_path / "out"
    args = ["--objects", objs, "--n", N, "--workers", 1, "--out", out, "--quiet"]
    shutil.copytree(reference_out, out)  # a whole run of args
    (out / MANIFEST_NAME).write_bytes(content)
    r = run_annotate(*args, check=2)
    assert "--repair" in r.output and "Traceback" not in r.output
    r = run_annotate(*args, "--repair")
    assert (
        "manifest rebuilt from 3 label files" in r.output and "0 objects labelled, 3 done earlier" in r.output
    )
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


@pytest.mark.slow
def test_overwrite_keeps_a_users_own_files(objs, tmp_path):
    out = tmp_path / "out"
    args = ["--objects", objs, "--n", 10, "--workers", 1, "--out", out, "--quiet"]
    run_annotate(*args)
    out.joinpath("notes.txt").write_text("mine")
    pd.DataFrame({"mine": [1.0]}).to_parquet(out / "my_table.parquet")
    run_annotate(*args, "--seed", 3, "--overwrite")
    assert (out / "notes.txt").read_text() == "mine"
    assert pd.read_parquet(out / "my_table.parquet")["mine"].tolist() == [1.0]
    assert json.loads((out / MANIFEST_NAME).read_text())["run"]["seed"] == 3


@pytest.mark.slow
def test_another_runs_files_copied_into_out_are_never_deleted_or_adopted(objs, tmp_path):
    """A plain resume, an overwrite and a repair leave label files of another run alone and name
    them; a copy under the name this run writes refuses the run in one line."""
    a, b = tmp_path / "a", tmp_path / "b"
    args = ["--objects", objs, "--n", 10, "--workers", 1, "--quiet"]
    run_annotate(*args, "--out", a)
    run_annotate(*args, "--out", b, "--seed", 1)
    box_b = b / object_filename("box")
    copy = a / "ok_copy_from_run_B.parquet"
    shutil.copy(box_b, copy)
    for mode in ((), ("--overwrite",)):
        result = run_annotate(*args, "--out", a, *mode)
        assert copy.read_bytes() == box_b.read_bytes()
        assert "ok_copy_from_run_B.parquet: written by another run; left as it is" in result.output
    (a / MANIFEST_NAME).unlink()
    result = run_annotate(*args, "--out", a, "--repair")
    assert copy.read_bytes() == box_b.read_bytes()
    shutil.copy(box_b, a / "cylinder-placeholder.parquet")  # a user's name: fine
    own = a / object_filename("box")
    own.unlink()
    shutil.copy(box_b, own)  # another run's file exactly where this run writes box's labels
    result = run_annotate(*args, "--out", a, check=2)
    assert "did not write it; move it away" in result.output and own.read_bytes() == box_b.read_bytes()


# --- 6. faults --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_killed_worker_costs_a_retry_and_the_labels_are_the_same(objs, reference, tmp_path):
    out = tmp_path / "out"
    proc = _spawn(objs, out, "--n", N, "--workers", 2)
    try:
        _wait_for_labels(proc, out)
        workers = _workers_of(proc.pid)
        assert workers, "no worker processes found"
        os.kill(workers[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 0, stderr
    assert "a worker process died" in stderr and "Traceback" not in stderr
    assert "3 objects labelled" in stdout
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


def _execute_spans(objs: Path, workers: Workers, fn=label_span) -> list[SpanResult]:
    """Every object's decomposition task and 10-candidate span of ``objs`` (N = 20) through
    ``execute`` on ``workers`` (closed after), each run by ``fn`` in a worker. The results in the
    order they arrived."""
    config = AnnotatorConfig()
    planned = [PlannedObject(s) for s in discover_objects(objs)]
    results: list[SpanResult] = []
    try:
        execute(
            Schedule(planned, 20, 10, None, workers.count),
            lambda span: SpanTask(span=span, config=config, seed=0, n=20, parent_pid=os.getpid()),
            workers,
            results.append,
            fn=fn,
        )
    finally:
        workers.close(kill=True)
    return results


def crash_on_poison(task: SpanTask) -> SpanResult:
    """A worker function that dies (as a segfault would) on every task of the object 'poison'
    (its decomposition task first)."""
    if task.span.object_id == "poison":
        os._exit(11)
    return label_span(task)


@pytest.mark.slow
def test_a_span_that_kills_its_worker_twice_fails_its_object_only(tmp_path):
    objs = _objects(tmp_path / "objs", ("box", "poison"))
    results = _execute_spans(objs, Workers(RunOptions(objs, 20, workers=2)), fn=crash_on_poison)
    by_object: dict[str, list[SpanResult]] = {}
    for r in results:
        by_object.setdefault(r.span.object_id, []).append(r)
    box = [r for r in by_object["box"] if r.labelled is not None]  # its first span with its decomposition
    assert sorted(r.labelled.start for r in box) == [0, 10]
    assert all(r.error is None and len(r.rows) == 10 for r in box)
    # the poison's decomposition task killed its worker twice: the object failed, none of its
    # spans was handed out
    (poison,) = by_object["poison"]
    assert isinstance(poison.span, Prepare)
    assert "a worker process died twice while loading (decomposing) the object" in poison.error


class _RefusesOnce(Workers):
    """Local workers whose pool refuses one submission as loky does once a worker has died and
    before any waiting future has reported it (the race a killed worker hit under load)."""

    def __init__(self, options: RunOptions, refuse_at: int) -> None:
        super().__init__(options)
        self.calls, self.refuse_at = 0, refuse_at

    def submit(self, task, fn=label_span):
        from joblib.externals.loky.process_executor import TerminatedWorkerError

        self.calls += 1
        if self.calls == self.refuse_at:
            raise TerminatedWorkerError(
                "A worker process managed by the executor was unexpectedly terminated."
            )
        return super().submit(task, fn)


@pytest.mark.slow
def test_a_pool_that_refuses_a_submission_after_a_worker_died_costs_a_retry_not_the_run(tmp_path):
    objs = _objects(tmp_path / "objs", ("box", "slab"))
    results = _execute_spans(objs, _RefusesOnce(RunOptions(objs, 20, workers=1), refuse_at=2))
    keys = sorted(r.span.key for r in results)
    # each decomposition task (key -1, with the first span) and each other span once
    assert keys == [("box", -1), ("box", 10), ("slab", -1), ("slab", 10)]
    assert sorted(r.labelled.key for r in results) == [("box", 0), ("box", 10), ("slab", 0), ("slab", 10)]
    assert all(r.error is None and len(r.rows) == 10 for r in results)
    assert all(r.error is None and r.prepared is not None for r in results if isinstance(r.span, Prepare))


@pytest.mark.slow
@pytest.mark.root
def test_a_full_disk_is_one_line_with_the_summary_and_resume_completes(objs, reference, tmp_path):
    disk = tmp_path / "disk"
    mount_tmpfs(disk, "24k")
    try:
        out = disk / "labels"
        args = ["--objects", objs, "--n", N, "--workers", 1, "--out", out]
        r = run_annotate(*args, "--quiet", check=3)
        assert "No space left on device" in r.output and "Traceback" not in r.output
        assert "STOPPED" in r.output and "candidates simulated" in r.output  # the summary is printed
        subprocess.run(["mount", "-o", "remount,size=16m", str(disk)], check=True)
        run_annotate(*args, "--quiet")
        pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)
    finally:
        umount(disk)


@pytest.mark.slow
@pytest.mark.root
def test_a_read_only_out_reads_a_finished_run_and_refuses_the_rest(objs, tmp_path):
    disk = tmp_path / "disk"
    mount_tmpfs(disk, "16m")
    try:
        out = disk / "labels"
        args = ["--objects", objs, "--n", 10, "--workers", 1, "--out", out, "--quiet"]
        run_annotate(*args)
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        r = run_annotate(*args)  # finished: nothing to write, exit 0 with the statistics
        assert "0 objects labelled, 3 done earlier" in r.output
        r = run_annotate(*[a if a != 10 else 12 for a in args], "--overwrite", check=3)
        assert "Read-only file system" in r.output or "read-only" in r.output
        assert "Traceback" not in r.output
    finally:
        umount(disk)


@pytest.mark.slow
def test_workers_exit_soon_after_the_main_process_is_killed(objs, tmp_path):
    out = tmp_path / "out"
    proc = _spawn(objs, out, "--n", 60, "--workers", 2)
    try:
        _wait_for_labels(proc, out)
        workers = _workers_of(proc.pid)
        assert workers
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 5.0
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [w for w in workers if _alive(w)], "workers outlived the main process by 5 s"
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c_and_the_run_resumes(objs, reference, tmp_path):
    out = tmp_path / "out"
    proc = _spawn(objs, out, "--n", N, "--workers", 2)
    try:
        _wait_for_labels(proc, out)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 143, stderr
    assert "terminated" in stderr and "Traceback" not in stderr
    run_annotate("--objects", objs, "--n", N, "--workers", 2, "--out", out, "--quiet")
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_dask_worker(address: str, timeout: float = 60.0) -> None:
    """Poll until the scheduler at ``address`` has a worker (instead of sleeping a guessed time)."""
    from distributed import Client

    deadline = time.monotonic() + timeout
    while True:
        try:
            with Client(address, timeout=2) as client:
                client.wait_for_workers(1, timeout=max(1.0, deadline - time.monotonic()))
                return
        except (OSError, TimeoutError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.mark.slow
@pytest.mark.cluster
def test_a_lost_scheduler_is_one_line_and_exit_4(objs, tmp_path):
    pytest.importorskip("distributed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask_bin = Path(sys.executable).parent / "dask"
    scheduler = subprocess.Popen(
        [str(dask_bin), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    worker = subprocess.Popen(
        [str(dask_bin), "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    out = tmp_path / "out"
    proc = None
    try:
        _wait_for_dask_worker(address)
        proc = _spawn(objs, out, "--n", 60, "--scheduler", address)
        _wait_for_labels(proc, out)
        scheduler.kill()
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 4, stderr
        assert "lost the Dask scheduler" in stderr and "resume" in stderr
        assert "Traceback" not in stderr
    finally:
        for p in (proc, worker, scheduler):
            if p is not None:
                p.kill()
                p.wait()


# --- 8. bounded resources -----------------------------------------------------------------------------------


def test_absurd_workers_and_n_are_usage_errors(objs, tmp_path):
    r = run_annotate("--objects", objs, "--n", 4, "--workers", 100000, "--out", tmp_path / "o", check=2)
    assert "--workers 100000" in r.output and "GB available" in r.output
    r = run_annotate("--objects", objs, "--n", 10_000_000, "--out", tmp_path / "o", check=2)
    assert "--n" in r.output
    assert not (tmp_path / "o").exists()


def test_planning_is_lazy(objs):
    """A million candidates per object plan without building a list of spans: each object's
    decomposition task, then its spans one by one as workers take them."""
    import tracemalloc

    planned = [PlannedObject(s) for s in discover_objects(objs)]
    tracemalloc.start()
    schedule = Schedule(planned, 1_000_000, 500, None, workers=2)
    first = [schedule.next() for _ in range(3)]
    assert first[2] is None  # both workers decompose; no span before its object is ready
    schedule.record(SpanResult(first[0], None, None, None))
    spans = [schedule.next() for _ in range(3)]
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert [(type(u).__name__, u.object_id) for u in first[:2]] == [
        ("Prepare", "box"),
        ("Prepare", "cylinder"),
    ]
    assert (first[0].first.object_id, first[0].first.start) == ("box", 0)  # with its decomposition
    assert [(s.object_id, s.start) for s in spans] == [("box", 500), ("box", 1000), ("box", 1500)]
    assert peak < 1_000_000, peak  # bytes: nothing of size N
    assert isinstance(spans[0], Span)


def test_an_exit_after_an_interrupt_ends_even_when_an_exit_handler_never_returns():
    """The interrupted run's exit waits on joblib's pool shutdown; a pool that never winds down
    (here: an exit handler that blocks forever) must not keep the process alive: the watchdog ends
    it with the interrupt's exit code and says why."""
    code = (
        "import atexit, threading\n"
        "from annotator.cli import common\n"
        "common.EXIT_GRACE_SECONDS = 0.5\n"
        "atexit.register(threading.Event().wait)\n"
        "common._exit_soon('annotate', 130)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == "annotate: worker processes did not stop in time; exiting"


def _job() -> None:
    """In the child before it runs: a process group of its own, SIGINT at its default."""
    os.setpgrp()
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_a_ctrl_c_while_the_workers_start_prints_no_worker_traceback(objs, tmp_path):
    """A terminal's Ctrl-C signals its whole foreground process group: workers still importing
    joblib printed two KeyboardInterrupt tracebacks. Workers now start in a process group of their own:
    the signal reaches the command alone, which stops them (exit 130, one line)."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()"]
    cmd += ["--objects", str(objs), "--out", str(out), "--n", "400", "--workers", "2", "--quiet"]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_job,  # its own process group, as a shell's job, SIGINT as in a terminal
    )
    try:
        deadline = time.monotonic() + 120
        while not _workers_of(proc.pid):  # a worker has just been started: it is importing
            assert proc.poll() is None, f"finished before its workers started:\n{proc.communicate()}"
            assert time.monotonic() < deadline, "no worker started"
            time.sleep(0.005)
        workers = _workers_of(proc.pid)
        assert all(os.getpgid(w) == w for w in workers)  # each leads its group: out of the terminal's reach
        os.killpg(proc.pid, signal.SIGINT)  # what the terminal does on Ctrl-C
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=30)
    assert proc.returncode == 130, (proc.returncode, stderr)
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    assert [line for line in stderr.splitlines() if line.strip()] == [
        "annotate: interrupted; re-run the same command to resume"
    ], stderr
