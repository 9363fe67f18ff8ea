"""A run's life, written once for every job (:class:`Job`: the object job, evaluate, the scene job):
check the options, bind the run and open and reconcile its output folder, plan what is left,
execute it on the workers (:mod:`annotator.pipeline.execution`) while the results are written
(:class:`Collector`), and whatever happens close the folder and print the summary.

Exit conditions (the CLI's codes): :class:`UsageError` (2) before any work; ``OutputError`` (3)
and :class:`SchedulerLost` (4) after printing the summary of what was done; ``KeyboardInterrupt``
(130) and :class:`Terminated` (143, SIGTERM) after saving.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import signal
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any, Protocol

from annotator.dataset import Outcome
from annotator.files import probe_writable
from annotator.grippers import DescriptionError, GripperDescription, load_gripper
from annotator.objects import default_cache_dir
from annotator.objects.cache import UNWRITABLE
from annotator.pipeline import status
from annotator.pipeline.execution import SchedulerLost, UsageError, Workers, execute
from annotator.pipeline.options import RunOptions
from annotator.pipeline.progress import Progress
from annotator.pipeline.summary import ObjectStats, Summary, format_summary
from annotator.pipeline.tasks import SpanResult
from annotator.store import OutputError, Resume, RunSpec, Store, StoreError

log = logging.getLogger(__name__)

# Resident memory one local worker may reach (MB): measured peak 274 MB on the shipped objects
# (bench/throughput.py), with headroom for larger meshes. --workers beyond what the machine's
# available memory holds at this size is refused instead of swapping or being OOM-killed.
WORKER_MEMORY_MB = 400
# A status line appears when a worker has been loading (decomposing) an object or building a scene
# for longer than this (s).
STATUS_AFTER = 2.0


class Terminated(BaseException):
    """SIGTERM: stop like Ctrl-C (what was written stays), exit code 143."""


@dataclass(frozen=True)
class TaskContext:
    """What every task of a run carries besides its unit: the label-shaping ``versions`` the run
    expects, the local main process ``parent_pid`` (None on a cluster), the ``status_dir`` local
    workers report in, the decomposition ``cache_dir`` (None: a cluster worker's own default), and
    whether the workers are ``local`` processes."""

    versions: dict[str, str] | None
    parent_pid: int | None
    status_dir: str | None
    cache_dir: str | None
    local: bool

    def fields(self) -> dict[str, Any]:
        """What every task of the run carries of it (:class:`annotator.pipeline.tasks.WorkerTask`'s
        fields)."""
        return {
            "versions": self.versions,
            "parent_pid": self.parent_pid,
            "status_dir": self.status_dir,
            "cache_dir": self.cache_dir,
        }


@dataclass(frozen=True)
class Binding:
    """What a job's :meth:`Job.bind` found: the run's ``spec``, its ``units`` of work (id -> source
    digest), the units the manifest lists as ``planned`` and the user's gripper folder it records
    (None: a shipped gripper, or none)."""

    spec: RunSpec
    units: dict[str, str]
    planned: list[str]
    gripper_folder: str | None = None


@dataclass
class WorkPlan:
    """What a run has left to do: ``total`` candidates of ``units`` units (objects, scenes),
    ``remaining`` label spans per unit; ``work(workers)`` the units in the order to hand them out
    for that many workers; ``decompositions``: objects whose decomposition task runs first;
    ``left``: candidates per unit not yet shown as done (advanced on a failure); ``complete``:
    units whose every chunk is on disk (only their merge is missing); ``kept``: chunks of
    unfinished units an earlier run wrote."""

    total: int
    units: int
    remaining: dict[str, int]
    work: Callable[[int], Any]
    decompositions: int = 0
    left: dict[str, int] = field(default_factory=dict)
    complete: list[str] = field(default_factory=list)
    kept: int = 0


class Job(Protocol):
    """A kind of run. ``unit``: what its units of work are called in the summary (``object``,
    ``scene``); ``noun``: what it simulates (``candidates``); ``worker``: the function a worker
    runs on a task (module level, so that it pickles)."""

    unit: str
    noun: str

    @property
    def worker(self) -> Callable[[Any], SpanResult]:
        """The function a worker runs on this job's tasks."""
        ...

    def check(self, options: RunOptions) -> None:
        """UsageError for options the job cannot run with, before anything is read. Changes
        nothing."""

    def bind(self, options: RunOptions, summary: Summary) -> Binding:
        """Find the inputs and hash them: sets the job's inputs (what its tasks carry); inputs
        that cannot be used go into ``summary.failed``. Returns what the run binds."""
        ...

    def plan(self, options: RunOptions, store: Store, resume: Resume) -> WorkPlan:
        """The work left after what ``store`` holds (``resume``). Reads the store, changes nothing
        (the lifecycle records the plan: :func:`record_plan`)."""
        ...

    def make_task(self, unit: Any, context: TaskContext) -> Any:
        """The task that carries ``unit`` to a worker. Changes nothing."""
        ...

    def take(self, result: SpanResult, collector: Collector) -> None:
        """A result in the main process: written, or its unit failed (through ``collector``, the
        one writer of results)."""


@dataclass
class Collector:
    """The main process's side of the results, for every job: statistics, failures, label chunks
    and their artifacts written, units finished. ``units``: unit id -> its source digest;
    ``remaining``: label spans still to come per unit; ``left``: candidates per unit not yet shown
    as done; ``seconds``: worker seconds per unit."""

    summary: Summary
    store: Store
    progress: Progress
    units: dict[str, str]
    remaining: dict[str, int]
    left: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    def account(self, result: SpanResult) -> None:
        """The worker's time, memory and kind of machine (recorded by the store), whatever the result."""
        self.summary.peak_rss_mb[result.stats.pid] = result.stats.peak_rss_mb
        self.summary.worker_seconds += result.stats.seconds
        self.store.note_machine(result.stats.machine, result.stats.host)

    def fail(self, unit: str, error: str) -> None:
        """The unit failed: its reason in the summary and the manifest, one line logged."""
        self.summary.failed[unit] = error
        self.store.fail_object(unit, error)
        named = error.startswith(f"{unit}:")  # an ObjectError names its object
        log.error("%s", error if named else f"{unit}: {error}")

    def write(self, result: SpanResult) -> None:
        """A span's artifacts, then its labels (which vouch for them); the unit merged when it was
        its last span."""
        summary, store, df = self.summary, self.store, result.rows
        span: Any = result.labelled  # a Span (a decomposition task's first) or a scene's SceneSpan
        assert df is not None
        unit = span.unit_id
        self.seconds[unit] = self.seconds.get(unit, 0.0) + result.stats.seconds
        summary.step_seconds += result.stats.step_seconds
        summary.sim_steps += int(df["sim_steps"].sum())
        summary.candidates += len(df)
        summary.physics_trials += int((df["outcome"] != Outcome.COLLISION.label).sum())
        if result.info is not None and unit not in store.manifest.objects_info:
            store.record_info(unit, result.info)
        files = result.artifacts or {}
        artifacts = {name: store.write_artifact(unit, name, data) for name, data in files.items()}
        store.write_chunk(unit, df, span.start, self.units[unit], artifacts)
        if summary.first_label_seconds is None:
            summary.first_label_seconds = time.perf_counter() - summary.started
        self.remaining[unit] -= 1
        if self.remaining[unit] == 0:
            stats = store.finish_object(unit, self.units[unit])
            summary.done[unit] = done = ObjectStats.from_json(stats, self.seconds[unit])
            self.progress.object_done(unit, done.line())


def record_plan(
    options: RunOptions,
    job: Job,
    bound: Binding,
    plan: WorkPlan,
    store: Store,
    resume: Resume,
    summary: Summary,
) -> None:
    """Before any work: the manifest lists the units planned and the user's gripper folder, and
    fails the inputs that cannot be used; the units an earlier run finished go into the summary;
    a unit whose every chunk is on disk (only its merge was missing) is merged now."""
    store.manifest.objects_planned = bound.planned
    store.manifest.gripper_folder = bound.gripper_folder
    for unit, error in summary.failed.items():
        store.fail_object(unit, error)
    for unit in sorted(resume.done):
        summary.resumed[unit] = ObjectStats.from_json(store.manifest.objects_done[unit]["stats"], None)
    for unit in plan.complete:
        summary.done[unit] = ObjectStats.from_json(store.finish_object(unit, bound.units[unit]), 0.0)
    if resume.done or plan.kept:
        log.info(
            "resuming %s: %d %ss done earlier, %d chunks of unfinished %ss kept; %d %s to do",
            options.out_dir,
            len(resume.done),
            job.unit,
            plan.kept,
            job.unit,
            plan.total,
            job.noun,
        )


def run_job(options: RunOptions, job: Job) -> Summary:
    """The whole run of ``job``; returns the summary (also printed). Raises as the module says."""
    options = check_cache(options)
    job.check(options)
    check_workers(options)
    summary = Summary(unit=job.unit, trials=options.trials)
    bound = job.bind(options, summary)
    store, resume = open_store(options, bound.spec, bound.units)
    with running(store, summary) as status_dir:
        plan = job.plan(options, store, resume)
        record_plan(options, job, bound, plan, store, resume, summary)
        if plan.total > 0:
            _execute(options, job, plan, store, summary, bound.units, status_dir)
    return summary


def _execute(
    options: RunOptions,
    job: Job,
    plan: WorkPlan,
    store: Store,
    summary: Summary,
    units: dict[str, str],
    status_dir: str,
) -> None:
    """Hand out ``plan``'s work on the run's workers and take every result."""
    workers = Workers(options, status_dir)
    progress = Progress(plan.total, plan.units, quiet=options.quiet, decompositions=plan.decompositions)
    collector = Collector(summary, store, progress, units, plan.remaining, plan.left)
    local = workers.client is None
    # read here, not in reused workers started under another env; a cluster's workers use
    # --cache when given (a shared filesystem), else their own default folder
    cache_dir = options.cache_dir or (default_cache_dir() if local else None)
    context = TaskContext(
        versions=store.spec.versions,
        parent_pid=workers.parent_pid,
        status_dir=status_dir if local else None,
        cache_dir=None if cache_dir is None else str(cache_dir),
        local=local,
    )

    def on_tick() -> None:
        if progress.bar is not None:
            busy = status.read(status_dir, older_than=STATUS_AFTER)
            progress.status("; ".join(busy) if busy else "")

    interrupted = True
    try:
        make_task = lambda unit: job.make_task(unit, context)  # noqa: E731
        take = lambda result: job.take(result, collector)  # noqa: E731
        execute(plan.work(workers.count), make_task, workers, take, on_tick, job.worker)
        interrupted = False
    except (KeyboardInterrupt, Terminated):
        log.info("interrupted: %d %s written this run", collector.summary.candidates, job.noun)
        raise
    finally:
        progress.close()
        workers.close(kill=interrupted)


def loaded_gripper(spec: GripperDescription | str | None) -> GripperDescription:
    """The gripper description ``spec`` names; a bad one is a usage error (exit 2)."""
    try:
        return load_gripper(spec)
    except DescriptionError as exc:
        raise UsageError(f"--gripper: {exc}") from exc


def check_workers(options: RunOptions) -> None:
    """--workers above the cores is allowed with a warning; beyond what memory holds it is refused."""
    if options.scheduler:
        return
    cores = os.cpu_count() or 1
    try:
        available_mb = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (ValueError, OSError, AttributeError):  # pragma: no cover - platforms without sysconf
        available_mb = float("inf")
    most = max(1, int(available_mb // WORKER_MEMORY_MB))
    if options.workers > most:
        raise UsageError(
            f"--workers {options.workers}: each worker needs up to {WORKER_MEMORY_MB} MB and this machine "
            f"has {available_mb / 1024:.1f} GB available (at most {most}); use --scheduler for a cluster"
        )
    if options.workers > cores:
        log.warning(
            "--workers %d is more than the %d cores: workers will share cores (use --scheduler for more)",
            options.workers,
            cores,
        )


def check_cache(options: RunOptions) -> RunOptions:
    """``--cache DIR`` made absolute (workers may start elsewhere) and, on this machine, created and
    checked writable: a folder the workers cannot write is a usage error, not a failure per object.
    A cluster's workers are trusted to see the folder (a shared filesystem) when this machine does
    not."""
    if options.cache_dir is None:
        if not options.scheduler:  # the default cache ($RG2_CACHE_DIR): checked the same way
            default = default_cache_dir()
            problem = _cache_problem(default)
            if problem:
                raise UsageError(
                    f"the decomposition cache {default} cannot be written ({problem}); set "
                    "RG2_CACHE_DIR or --cache to a writable folder"
                )
        return options
    folder = Path(os.path.abspath(os.path.expanduser(options.cache_dir)))
    if options.scheduler and not folder.exists():
        return dataclasses.replace(options, cache_dir=folder)
    problem = _cache_problem(folder)
    if problem:
        raise UsageError(f"--cache {options.cache_dir}: cannot write there ({problem})")
    return dataclasses.replace(options, cache_dir=folder)


def _cache_problem(folder: Path) -> str:
    """Why ``folder`` cannot serve as the decomposition cache ("" when it can). A folder that
    exists and can be read but not written (a cluster's shared cache mounted read-only) serves: its
    entries are read and what it lacks is kept aside per process (:mod:`annotator.objects.cache`),
    said once here; one that cannot be made or read holds nothing to read."""
    try:
        probe_writable(folder)
        return ""
    except OSError as exc:
        if folder.is_dir() and os.access(folder, os.R_OK | os.X_OK) and exc.errno in UNWRITABLE:
            log.warning(
                "the decomposition cache %s cannot be written (%s): its entries are read; an object it "
                "lacks is decomposed where it is needed and not kept",
                folder,
                exc.strerror or exc,
            )
            return ""
        return str(exc.strerror or exc)


def open_store(options: RunOptions, spec: RunSpec, units: dict[str, str]) -> tuple[Store, Resume]:
    """The output folder opened for ``spec`` and reconciled with the run's units of work (object
    or scene id -> digest); returns ``(store, what to resume)``. A folder that cannot be opened or
    reconciled is a usage error."""
    store = Store(options.out_dir, spec, labelled_here=not options.scheduler)
    try:
        store.open(overwrite=options.overwrite, repair=options.repair)
    except StoreError as exc:
        raise UsageError(str(exc)) from exc
    try:
        return store, store.reconcile(units)
    except StoreError as exc:
        store.close()
        raise UsageError(str(exc)) from exc


@contextlib.contextmanager
def running(store: Store, summary: Summary) -> Iterator[str]:
    """The body of a run, object or scene: yields a status folder for its workers, with SIGTERM
    raised as :class:`Terminated`; however the body ends, the store is closed, the summary gets the
    store's notes and its time, and is printed. A lost output or scheduler is noted as stopping it."""
    status_dir = tempfile.mkdtemp(prefix="rg2-status-")
    previous_term = signal.getsignal(signal.SIGTERM)
    with contextlib.suppress(ValueError):  # not the main thread: leave SIGTERM alone
        signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield status_dir
    except (OutputError, SchedulerLost) as exc:
        summary.stopped = f"{exc}; what was written is kept: run the same command again to resume"
        raise
    finally:
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGTERM, previous_term)
        shutil.rmtree(status_dir, ignore_errors=True)
        with contextlib.suppress(OutputError):
            store.close()
        summary.notes = store.notes + summary.notes
        summary.seconds = time.perf_counter() - summary.started
        print_summary(summary)


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated()


def print_summary(summary: Summary) -> None:
    """The summary is the command's result: printed to stdout even with --quiet."""
    import click

    click.echo(format_summary(summary))
