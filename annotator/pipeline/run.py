"""Run the job: objects -> decomposition tasks and spans on local worker processes (or a Dask
cluster) -> one writer.

The main process only discovers the objects, checks the output folder and hands out work
(:mod:`annotator.pipeline.schedule`: each object's decomposition task, then its spans); it never
loads a mesh, so work starts at once and every object's decomposition runs in a worker, in
parallel with the others and with the labelling. Workers return labels; the store alone writes them.

Faults (README "Reliability"): a worker process that dies costs the spans it had one retry each,
run alone on a fresh worker; a span that kills its worker again fails its object with the reason
and the run goes on. A full disk, a read-only or forbidden folder stops the run with one line and
exit code 3; a lost Dask scheduler with one line and exit code 4; both keep what was written, and
the same command resumes. Local workers exit within about a second of the main process.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import logging
import os
import shutil
import signal
import tempfile
import time
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.grippers import (
    DescriptionError,
    GripperDescription,
    GripperFiles,
    gripper_record,
    is_shipped,
    load_gripper,
)
from annotator.objects import (
    ObjectDiscoveryError,
    ObjectError,
    default_cache_dir,
    discover_objects,
    source_digest,
)
from annotator.pipeline import status
from annotator.pipeline.plan import (
    MAX_N,
    PlannedObject,
    candidates_to_do,
    chunk_size_for,
    spans_to_do,
)
from annotator.pipeline.progress import Progress
from annotator.pipeline.schedule import Schedule, Stream
from annotator.pipeline.source import GivenCandidates, SampledCandidates
from annotator.pipeline.summary import ObjectStats, Summary, format_summary
from annotator.pipeline.worker import (
    CellOptions,
    Prepare,
    Span,
    SpanResult,
    SpanTask,
    WorkerStats,
    label_span,
)
from annotator.store import OutputError, RunSpec, Store, StoreError

log = logging.getLogger(__name__)

# Resident memory one local worker may reach (MB): measured peak 274 MB on the shipped objects
# (bench/throughput.py), with headroom for larger meshes. --workers beyond what the machine's
# available memory holds at this size is refused instead of swapping or being OOM-killed.
WORKER_MEMORY_MB = 400
# While waiting for results the display is refreshed this often (s); a status line appears when
# a worker has been loading (decomposing) an object for longer than STATUS_AFTER seconds.
TICK_SECONDS = 0.5
STATUS_AFTER = 2.0


class UsageError(Exception):
    """The command cannot start (folder, manifest, lock, options): exit code 2."""


class SchedulerLost(Exception):
    """The Dask scheduler went away during the run: exit code 4 (the same command resumes)."""


class Terminated(BaseException):
    """SIGTERM: stop like Ctrl-C (what was written stays), exit code 143."""


@dataclass(frozen=True)
class RunOptions:
    objects_dir: Path
    n: int
    out_dir: Path = Path("labels")
    workers: int = 1
    seed: int = 0
    trials: int = 1
    scheduler: str | None = None
    scale: float | None = None
    overwrite: bool = False
    repair: bool = False
    quiet: bool = False
    cell: bool = False  # objects rest on the seed's table; UR3 reachability columns
    views: int = 0  # Kinect views per placement (--cell only), per scene with --scenes
    # the gripper simulated: a description, a shipped name or a folder (None: the RG2)
    gripper: GripperDescription | str | None = None
    # given grasps on objects resting on the table (evaluate --resting): False, True / "object" (the
    # grasps move with the settling object) or "table" (they stay in the table frame)
    resting: bool | str = False
    # annotate --scenes N: N scenes of per_scene (min, max) objects in the arrangement, n grasps
    # per scene (annotator.scenes.run)
    scenes: int = 0
    per_scene: tuple[int, int] = (5, 5)
    arrangement: str = "pile"
    cache_dir: Path | None = None  # --cache: the decomposition cache of every worker (None: default)

    def cell_options(self) -> CellOptions | None:
        return CellOptions(self.views) if self.cell else None


# --- where spans run --------------------------------------------------------------------------------


def _worker_died_errors() -> tuple[type[BaseException], ...]:
    from joblib.externals.loky.process_executor import BrokenProcessPool, TerminatedWorkerError

    errors: list[type[BaseException]] = [TerminatedWorkerError, BrokenProcessPool]
    errors.append(cf.process.BrokenProcessPool)
    with contextlib.suppress(ImportError):
        from distributed import KilledWorker

        errors.append(KilledWorker)
    return tuple(errors)


class Workers:
    """Local worker processes (joblib's loky executor) or a Dask cluster's, behind one interface.

    Both are ``concurrent.futures`` executors, which tell which task's process died (joblib's
    ``Parallel`` does not): the runner retries exactly those tasks, alone.
    """

    # After an interrupt, how long (s) the local workers get to end themselves (they poll for the
    # stop request every PARENT_CHECK_SECONDS) before the pool is shut down by force.
    STOP_SECONDS = 3.0

    def __init__(self, options: RunOptions, status_dir: str | None = None) -> None:
        self.client = None
        self.status_dir = status_dir
        self._futures: weakref.WeakSet[cf.Future] = weakref.WeakSet()
        self.count = options.workers
        if options.scheduler:
            try:
                from distributed import Client
            except ImportError as exc:
                raise UsageError("--scheduler needs Dask: pip install 'rg2-annotator[cluster]'") from exc
            try:
                self.client = Client(options.scheduler)
            except (OSError, ValueError, TypeError) as exc:  # unreachable, timed out, malformed
                raise UsageError(f"--scheduler {options.scheduler}: cannot connect ({exc})") from exc
            info = self.client.scheduler_info()["workers"].values()
            self.count = max(1, sum(w.get("nthreads", 1) for w in info))
            self.parent_pid = None
        else:
            self.parent_pid = os.getpid()
        self._executor: cf.Executor | None = None

    def executor(self) -> cf.Executor:
        if self._executor is None:
            if self.client is not None:
                self._executor = self.client.get_executor(pure=False)
            else:
                # joblib's own reusable process pool (the one joblib.Parallel uses): workers, with
                # their worlds and loaded objects, are kept between runs of one process
                from joblib.executor import get_memmapping_executor

                self._executor = get_memmapping_executor(self.count)
        return self._executor

    def submit(self, task: SpanTask, fn: Callable[[SpanTask], SpanResult] = label_span) -> cf.Future:
        future = self.executor().submit(fn, task)
        self._futures.add(future)
        return future

    def restart(self) -> None:
        """After a worker died: a fresh pool (loky) for what follows."""
        if self.client is None:
            self._executor = None

    def lost(self) -> bool:
        """The Dask scheduler is gone (the client lost it, or is trying to reconnect)."""
        return self.client is not None and self.client.status != "running"

    def close(self, *, kill: bool) -> None:
        if self.client is not None:
            with contextlib.suppress(Exception):
                self.client.close()
        elif kill and self._executor is not None:
            self._stop_local()

    def _stop_local(self) -> None:
        """Interrupted: the workers end their own processes on the stop request (the pool sees
        them gone and fails what was out), then the pool is shut down. Only if they do not end in
        time is it shut down killing them, where loky's manager thread can meet a task it has
        already dropped and print a traceback."""
        executor, self._executor = self._executor, None
        out = [f for f in self._futures if not f.done()]
        for future in out:
            future.cancel()
        status.request_stop(self.status_dir)
        _, not_done = cf.wait(out, timeout=self.STOP_SECONDS)
        log.debug("stopping: %d of %d spans out ended by themselves", len(out) - len(not_done), len(out))
        with contextlib.suppress(Exception):
            executor.shutdown(wait=False, kill_workers=bool(not_done))


Unit = Span | Prepare


def execute(
    work: Schedule | Stream | Iterator[Unit],
    make_task: Callable[[Unit], SpanTask],
    workers: Workers,
    on_result: Callable[[SpanResult], None],
    on_tick: Callable[[], None] = lambda: None,
    fn: Callable[[SpanTask], SpanResult] = label_span,
) -> None:
    """Run every unit of ``work`` (``fn``, in a worker) and hand each result to ``on_result`` (in
    this process). ``work``: a :class:`Schedule` (units wait for their object's decomposition), or
    an iterator of units handed out in its order.

    At most twice as many units as workers are out at once. When a worker process dies, every unit
    that was out is retried once, alone on a fresh worker, so the one that kills its worker is
    known; it then fails its object (an error result) and the run goes on.
    """
    source = work if isinstance(work, (Schedule, Stream)) else Stream(iter(work))
    _Execution(source, make_task, workers, on_result, on_tick, fn).run()


@dataclass
class _Execution:
    """The state of :func:`execute`: work still to hand out, futures out, units whose worker died."""

    source: Schedule | Stream
    make_task: Callable[[Unit], SpanTask]
    workers: Workers
    on_result: Callable[[SpanResult], None]
    on_tick: Callable[[], None]
    fn: Callable[[SpanTask], SpanResult]

    def __post_init__(self) -> None:
        self.died = _worker_died_errors()
        self.out: dict[cf.Future, Unit] = {}

    def run(self) -> None:
        while True:
            crashed = self._submit()
            if not self.out and not crashed:
                if self.source.exhausted:
                    return
                raise RuntimeError("work is left that nothing out can unblock")  # pragma: no cover
            if crashed:  # what finished before the pool broke is handed on as usual
                done = {future for future in self.out if future.done()}
            else:
                done, _ = cf.wait(self.out, timeout=TICK_SECONDS, return_when=cf.FIRST_COMPLETED)
                self.on_tick()
            if not done and not crashed and self.workers.lost():
                raise SchedulerLost("lost the Dask scheduler")
            crashed += self._collect(done)
            if crashed:
                self._retry(crashed)

    def _submit(self) -> list[Unit]:
        """Submit units up to capacity; a unit the pool refuses (a worker died) is returned."""
        capacity = 2 * self.workers.count
        while len(self.out) < capacity:
            unit = self.source.next()
            if unit is None:
                break
            try:
                self.out[self.workers.submit(self.make_task(unit), self.fn)] = unit
            except self.died:  # a worker died since the last wait: the pool refuses work
                return [unit]
        return []

    def _deliver(self, result: SpanResult) -> None:
        self.source.record(result)
        self.on_result(result)

    def _collect(self, done) -> list[Unit]:
        """Hand on the results of ``done``; returns the units whose worker died."""
        crashed = []
        for future in done:
            unit = self.out.pop(future)
            try:
                result = future.result()
            except (Exception, cf.CancelledError) as exc:
                if self.workers.lost():
                    raise SchedulerLost("lost the Dask scheduler") from exc
                if isinstance(exc, (*self.died, cf.CancelledError)):
                    crashed.append(unit)
                    continue
                # the task itself failed in a way the worker did not catch
                result = _failed(unit, f"internal error: {type(exc).__name__}: {exc}")
            self._deliver(result)
        return crashed

    def _retry(self, crashed: list[Unit]) -> None:
        """The pool is broken: every unit still out is lost with it; each is retried alone."""
        for future, unit in list(self.out.items()):
            future.cancel()
            crashed.append(unit)
        self.out.clear()
        log.warning("a worker process died; retrying its %d task(s) one at a time", len(crashed))
        self.workers.restart()
        for unit in sorted(crashed, key=lambda s: s.key):
            self._deliver(_retry_alone(unit, self.make_task, self.workers, self.died, self.on_tick, self.fn))


def _retry_alone(span: Unit, make_task, workers: Workers, died, on_tick, fn) -> SpanResult:
    future = workers.submit(make_task(span), fn)
    while True:
        done, _ = cf.wait([future], timeout=TICK_SECONDS)
        on_tick()
        if done:
            break
        if workers.lost():
            raise SchedulerLost("lost the Dask scheduler")
    try:
        return future.result()
    except (Exception, cf.CancelledError) as exc:
        if workers.lost():
            raise SchedulerLost("lost the Dask scheduler") from exc
        if not isinstance(exc, (*died, cf.CancelledError)):
            return _failed(span, f"internal error: {type(exc).__name__}: {exc}")
        workers.restart()
        what = str(exc).split("\n")[0][:160]
        return _failed(span, f"a worker process died twice while {_doing(span)} ({what})")


def _doing(unit) -> str:
    """What a worker was doing with ``unit`` (a span of another kind says it by its candidates)."""
    describe = getattr(unit, "describe", None)
    return describe() if describe is not None else f"simulating candidates {unit.start}-{unit.stop - 1}"


def _failed(unit: Unit, error: str) -> SpanResult:
    return SpanResult(unit, None, error, WorkerStats(0.0, 0.0, 0.0, 0, ""))


# --- the run ------------------------------------------------------------------------------------------


def _check_workers(options: RunOptions) -> None:
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


def _check_cache(options: RunOptions) -> RunOptions:
    """``--cache DIR`` made absolute (workers may start elsewhere) and, on this machine, created and
    checked writable: a folder the workers cannot write is a usage error, not a failure per object.
    A cluster's workers are trusted to see the folder (a shared filesystem) when this machine does
    not."""
    if options.cache_dir is None:
        if not options.scheduler:  # the default cache ($RG2_CACHE_DIR): checked the same way
            default = default_cache_dir()
            try:
                default.mkdir(parents=True, exist_ok=True)
                with tempfile.NamedTemporaryFile(dir=default, prefix=".rg2-write-check-"):
                    pass
            except OSError as exc:
                raise UsageError(
                    f"the decomposition cache {default} cannot be written ({exc.strerror or exc}); set "
                    "RG2_CACHE_DIR or --cache to a writable folder"
                ) from exc
        return options
    folder = Path(os.path.abspath(os.path.expanduser(options.cache_dir)))
    if options.scheduler and not folder.exists():
        return dataclasses.replace(options, cache_dir=folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".rg2-write-check-"):
            pass
    except OSError as exc:
        raise UsageError(f"--cache {options.cache_dir}: cannot write there ({exc.strerror or exc})") from exc
    return dataclasses.replace(options, cache_dir=folder)


def run(
    options: RunOptions,
    config: AnnotatorConfig,
    candidates: SampledCandidates | GivenCandidates | None = None,
) -> Summary:
    """The whole job; returns the summary (also printed). Raises UsageError (exit 2); OutputError
    (3) and SchedulerLost (4) after printing the summary of what was done; KeyboardInterrupt (130)
    and Terminated (143) after saving.

    ``candidates``: where the candidates come from, by default ``options.n`` sampled per object
    (``annotate``); :class:`GivenCandidates` simulates given poses instead (``evaluate``).
    """
    options = _check_cache(options)
    if options.scenes:  # scenes are their own units of work (annotator.scenes.run)
        return _run_scenes(options, config, candidates)
    summary = Summary()
    candidates = candidates or SampledCandidates(options.n)
    _check_options(options, candidates)
    gripper = _loaded(options.gripper)
    _check_workers(options)
    try:
        sources = discover_objects(options.objects_dir, config.objects)
    except ObjectDiscoveryError as exc:
        raise UsageError(str(exc)) from exc
    sources, missing = candidates.select(sources)
    summary.failed.update(missing)

    digests: dict[str, str] = {}
    for source in sources:
        try:
            digests[source.object_id] = source_digest(source, config.objects.memory_budget)
        except ObjectError as exc:
            summary.failed[source.object_id] = str(exc)
    chunk = chunk_size_for(options.n)
    spec = RunSpec(
        options.seed,
        options.n,
        options.trials,
        options.scale,
        chunk,
        config.to_dict(),
        inputs=_inputs(options, candidates),
        gripper=gripper_record(gripper),
    )
    store, resume = open_store(options, spec, digests)
    with running(store, summary) as status_dir:
        _run(options, config, summary, store, resume, sources, digests, status_dir, candidates, gripper)
    return summary


def open_store(options: RunOptions, spec: RunSpec, units: dict[str, str]):
    """The output folder opened for ``spec`` and reconciled with the run's units of work (object
    or scene id -> digest); returns ``(store, what to resume)``. A folder that cannot be opened or
    reconciled is a usage error."""
    store = Store(options.out_dir, spec)
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
        _print_summary(summary)


def _run_scenes(options: RunOptions, config: AnnotatorConfig, candidates) -> Summary:
    """``annotate --scenes``: sampled candidates with the RG2 (annotator.scenes.run)."""
    if candidates is not None:
        raise UsageError("--scenes labels sampled candidates only")
    named = _loaded(options.gripper).name
    if named != "rg2":
        raise UsageError(f"--scenes simulates the RG2 only; --gripper {named} labels objects one by one")
    from annotator.scenes.run import run_scenes

    return run_scenes(options, config)


def _check_options(options: RunOptions, candidates: SampledCandidates | GivenCandidates) -> None:
    """The options that exclude each other or the candidates' source; UsageError (exit 2)."""
    if not 1 <= options.n <= MAX_N:
        raise UsageError(f"--n must be between 1 and {MAX_N:,} candidates per object, got {options.n}")
    if options.views and not options.cell:
        raise UsageError("--views renders the robot cell's Kinect: it needs --cell")
    if options.views < 0:
        raise UsageError(f"--views must be 0 or more, got {options.views}")
    if options.cell and not isinstance(candidates, SampledCandidates):
        raise UsageError("--cell labels sampled candidates only")
    if options.resting and not isinstance(candidates, GivenCandidates):
        raise UsageError("--resting simulates given grasps only (annotator evaluate)")
    if options.resting and options.cell:
        raise UsageError("--resting and --cell exclude each other")


def _inputs(options: RunOptions, candidates: SampledCandidates | GivenCandidates) -> dict:
    """RunSpec.inputs: the candidate source's, and the cell mode when on (a floating run records
    nothing new, so folders made before the cell existed still resume; a floating folder never
    resumes as a cell run or the other way round)."""
    inputs = dict(candidates.inputs())
    cell = options.cell_options()
    if cell is not None:
        inputs["cell"] = cell.to_json()
    if options.resting:
        from annotator.cell.resting import resting_mode

        mode = resting_mode(options.resting)
        inputs["resting"] = True if mode == "object" else mode  # True: as folders before "table" existed
    return inputs


def _loaded(spec: GripperDescription | str | None) -> GripperDescription:
    """The gripper description ``spec`` names; a bad one is a usage error (exit 2)."""
    try:
        return load_gripper(spec)
    except DescriptionError as exc:
        raise UsageError(f"--gripper: {exc}") from exc


def _gripper_files(gripper: GripperDescription) -> GripperFiles:
    try:
        return GripperFiles.of(gripper)
    except DescriptionError as exc:
        raise UsageError(f"--gripper: {exc}") from exc


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def _run(
    options,
    config,
    summary: Summary,
    store: Store,
    resume,
    sources,
    digests,
    status_dir: str,
    candidates,
    gripper: GripperDescription,
) -> None:
    """The body of :func:`run` once the folder is open and matched to the objects (``resume``)."""
    store.manifest.objects_planned = sorted(set(digests) | set(summary.failed))
    store.manifest.gripper_folder = None if is_shipped(gripper) else str(gripper.folder.resolve())
    for oid, error in summary.failed.items():
        store.fail_object(oid, error)
    for oid in sorted(resume.done):
        summary.resumed[oid] = ObjectStats.from_json(store.manifest.objects_done[oid]["stats"], None)
    chunk = store.spec.chunk_size
    planned = [
        PlannedObject(
            s,
            frozenset(resume.chunks.get(s.object_id, set())),
            candidates.count(s.object_id),
            candidates.given,
        )
        for s in sources
        if s.object_id in digests and s.object_id not in resume.done
    ]
    remaining = {p.source.object_id: spans_to_do(p, options.n, chunk) for p in planned}
    for p in planned:
        if remaining[p.source.object_id] == 0:  # every chunk on disk: only the merge was missing
            oid = p.source.object_id
            summary.done[oid] = ObjectStats.from_json(store.finish_object(oid, digests[oid]), 0.0)
    total = sum(candidates_to_do(p, options.n, chunk) for p in planned)
    if resume.done or any(p.done for p in planned):
        log.info(
            "resuming %s: %d objects done earlier, %d chunks of unfinished objects kept; %d candidates to do",
            options.out_dir,
            len(resume.done),
            sum(len(p.done) for p in planned),
            total,
        )
    if total > 0:
        _label(options, config, summary, store, digests, status_dir, planned, remaining, total, gripper)


def _label(
    options: RunOptions,
    config: AnnotatorConfig,
    summary: Summary,
    store: Store,
    digests: dict[str, str],
    status_dir: str,
    planned: list[PlannedObject],
    remaining: dict[str, int],
    total: int,
    gripper: GripperDescription,
) -> None:
    """Decompose and label the ``planned`` objects with spans ``remaining`` on the run's workers
    with ``gripper``."""
    n, chunk = options.n, store.spec.chunk_size
    workers = Workers(options, status_dir)
    todo = [p for p in planned if remaining[p.source.object_id] > 0]
    progress = Progress(total, len(planned), quiet=options.quiet, decompositions=len(todo))
    versions = store.spec.versions
    cell = options.cell_options()
    # read here, not in reused workers started under another env; a cluster's workers use their
    # own default unless --cache names a folder (a shared filesystem)
    cache_dir = options.cache_dir or (default_cache_dir() if workers.client is None else None)
    collect = _Collect(
        summary,
        store,
        progress,
        digests,
        remaining,
        {p.source.object_id: candidates_to_do(p, n, chunk) for p in todo},
    )
    # a cluster's workers may not see the gripper's folder: they get its files (GripperFiles)
    sent = gripper if workers.client is None else _gripper_files(gripper)

    def make_task(unit: Span | Prepare) -> SpanTask:
        return SpanTask(
            unit,
            config,
            options.seed,
            n,
            options.trials,
            source_sha256=digests[unit.object_id],
            versions=versions,
            parent_pid=workers.parent_pid,
            status_dir=status_dir if workers.client is None else None,
            cache_dir=None if cache_dir is None else str(cache_dir),
            cell=cell,
            gripper=sent,
            resting=options.resting,
        )

    def on_tick() -> None:
        if progress.bar is not None:
            busy = status.read(status_dir, older_than=STATUS_AFTER)
            progress.status("; ".join(busy) if busy else "")

    interrupted = True
    try:
        schedule = Schedule(todo, n, chunk, options.scale, workers.count)
        execute(schedule, make_task, workers, collect.on_result, on_tick)
        interrupted = False
    except (KeyboardInterrupt, Terminated):
        log.info("interrupted: %d candidates written this run", summary.candidates)
        raise
    finally:
        progress.close()
        workers.close(kill=interrupted)


@dataclass
class _Collect:
    """The main process's side of the results: decompositions reported, labels written, objects
    finished or failed. ``remaining``: spans still to come per object; ``left``: its candidates not
    yet shown on the progress bar."""

    summary: Summary
    store: Store
    progress: Progress
    digests: dict[str, str]
    remaining: dict[str, int]
    left: dict[str, int]
    object_seconds: dict[str, float] = field(default_factory=dict)

    def on_result(self, result: SpanResult) -> None:
        oid = result.span.object_id
        self.summary.peak_rss_mb[result.stats.pid] = result.stats.peak_rss_mb
        self.summary.worker_seconds += result.stats.seconds
        if oid in self.summary.failed:  # another task of it failed first: the object is failed
            return
        if result.error is not None:
            self._fail(oid, result.error, decomposing=isinstance(result.span, Prepare))
        elif isinstance(result.span, Prepare):
            self._prepared(oid, result)
        else:
            self._labelled(oid, result)

    def _fail(self, oid: str, error: str, decomposing: bool) -> None:
        self.summary.failed[oid] = error
        self.store.fail_object(oid, error)
        named = error.startswith(f"{oid}:")  # an ObjectError names its object
        log.error("%s", error if named else f"{oid}: {error}")
        self.progress.advance(self.left.pop(oid, 0))
        if decomposing:
            self.progress.prepared(oid, None)
        self.progress.object_done(oid, "failed")

    def _prepared(self, oid: str, result: SpanResult) -> None:
        prepared = result.prepared
        self.summary.prepare_seconds += result.stats.seconds
        self.object_seconds[oid] = self.object_seconds.get(oid, 0.0) + result.stats.seconds
        if prepared is not None:
            self.summary.prepared[oid] = prepared
            if prepared.warnings:
                self.summary.warnings[oid] = list(prepared.warnings)
        self.summary.ready_seconds = time.perf_counter() - self.summary.started
        self.progress.prepared(oid, prepared.line() if prepared is not None and prepared.decomposed else None)

    def _labelled(self, oid: str, result: SpanResult) -> None:
        summary, store, span, df = self.summary, self.store, result.span, result.rows
        self.progress.advance(span.size)
        self.left[oid] = self.left.get(oid, 0) - span.size
        self.object_seconds[oid] = self.object_seconds.get(oid, 0.0) + result.stats.seconds
        summary.step_seconds += result.stats.step_seconds
        summary.sim_steps += int(df["sim_steps"].sum())
        summary.candidates += len(df)
        summary.physics_trials += int((df["outcome"] != Outcome.COLLISION.label).sum())
        if result.info is not None and oid not in store.manifest.objects_info:
            store.record_info(oid, result.info)
        # the span's artifacts first, then its labels, which vouch for them
        artifacts = {
            name: store.write_artifact(oid, name, data) for name, data in (result.artifacts or {}).items()
        }
        store.write_chunk(oid, df, span.start, self.digests[oid], artifacts)
        if summary.first_label_seconds is None:
            summary.first_label_seconds = time.perf_counter() - summary.started
        self.remaining[oid] -= 1
        if self.remaining[oid] == 0:
            stats = store.finish_object(oid, self.digests[oid])
            summary.done[oid] = done = ObjectStats.from_json(stats, self.object_seconds[oid])
            self.progress.object_done(oid, done.line())


def _print_summary(summary: Summary) -> None:
    # the summary is the command's result: printed to stdout even with --quiet
    import click

    click.echo(format_summary(summary))
