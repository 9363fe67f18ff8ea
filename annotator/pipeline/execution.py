"""Where a run's units of work run: local worker processes (joblib's loky) or a Dask cluster, behind
one interface (:class:`Workers`), and the loop that hands units out, collects their results and
retries the units of a worker that died (:func:`execute`). Written once for every job.

Faults: a worker process that dies costs the units it had one retry each, run alone on a fresh
worker; a unit that kills its worker again fails with the reason and the run goes on. A lost Dask
scheduler raises :class:`SchedulerLost` (exit code 4). Local workers exit within about a second of
the main process (they watch it: :mod:`annotator.pipeline.status`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import os
import weakref
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

from annotator.pipeline import status
from annotator.pipeline.schedule import Schedule, Stream
from annotator.pipeline.tasks import SpanResult, WorkerStats
from annotator.pipeline.worker import label_span
from annotator.pipeline.worker_spawn import detach_local_workers

log = logging.getLogger(__name__)

# While waiting for results the display is refreshed this often (s).
TICK_SECONDS = 0.5


class UsageError(Exception):
    """The command cannot start (folder, manifest, lock, options): exit code 2."""


class SchedulerLost(Exception):
    """The Dask scheduler went away during the run: exit code 4 (the same command resumes)."""


def _worker_died_errors() -> tuple[type[BaseException], ...]:
    from joblib.externals.loky.process_executor import BrokenProcessPool, TerminatedWorkerError

    errors: list[type[BaseException]] = [TerminatedWorkerError, BrokenProcessPool]
    errors.append(cf.process.BrokenProcessPool)
    with contextlib.suppress(ImportError):
        from distributed import KilledWorker

        errors.append(KilledWorker)
    return tuple(errors)


class WorkerOptions(Protocol):
    """Where the work runs: ``workers`` local processes, or the Dask cluster at ``scheduler``
    (:class:`annotator.pipeline.options.RunOptions`, ``annotator.pipeline.in_memory.ExecutionOptions``)."""

    @property
    def workers(self) -> int: ...

    @property
    def scheduler(self) -> str | None: ...


class Workers:
    """Local worker processes (joblib's loky executor) or a Dask cluster's, behind one interface.

    Both are ``concurrent.futures`` executors, which tell which task's process died (joblib's
    ``Parallel`` does not): the runner retries exactly those tasks, alone.
    """

    # After an interrupt, how long (s) the local workers get to end themselves (they poll for the
    # stop request every PARENT_CHECK_SECONDS) before the pool is shut down by force.
    STOP_SECONDS = 3.0

    def __init__(self, options: WorkerOptions, status_dir: str | None = None) -> None:
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

                detach_local_workers()  # a Ctrl-C reaches the main process only
                self._executor = get_memmapping_executor(self.count)
        return self._executor

    def submit(self, task: Task, fn: Callable[[Task], Any] = label_span) -> cf.Future:
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
        from joblib.externals.loky.process_executor import ProcessPoolExecutor as LokyExecutor

        if not isinstance(executor, LokyExecutor):  # None, or not the local pool: nothing to kill
            return
        with contextlib.suppress(Exception):
            executor.shutdown(wait=False, kill_workers=bool(not_done))


# A unit of work (an object's Span or Prepare, a scene's SceneSpan): it has a ``key`` (its order
# when retried), a ``size`` and a ``unit_id`` (the store's unit it belongs to); a task carries
# it to a worker.
Unit = Any
Task = Any


def execute(
    work: Schedule | Stream | Iterator[Unit],
    make_task: Callable[[Unit], Task],
    workers: Workers,
    on_result: Callable[[Any], None],
    on_tick: Callable[[], None] = lambda: None,
    fn: Callable[[Task], Any] = label_span,
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
    make_task: Callable[[Unit], Task]
    workers: Workers
    on_result: Callable[[Any], None]
    on_tick: Callable[[], None]
    fn: Callable[[Task], Any]

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

    def _deliver(self, result: Any) -> None:
        self.source.record(result)
        self.on_result(result)

    def _collect(self, done: Iterable[cf.Future]) -> list[Unit]:
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


def _retry_alone(
    span: Unit,
    make_task: Callable[[Unit], Task],
    workers: Workers,
    died: tuple[type[BaseException], ...],
    on_tick: Callable[[], None],
    fn: Callable[[Task], Any],
) -> Any:
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


def _doing(unit: Unit) -> str:
    """What a worker was doing with ``unit`` (a span of another kind says it by its candidates)."""
    describe = getattr(unit, "describe", None)
    return describe() if describe is not None else f"simulating candidates {unit.start}-{unit.stop - 1}"


def _failed(unit: Unit, error: str) -> SpanResult:
    return SpanResult(unit, None, error, WorkerStats(0.0, 0.0, 0.0, 0, ""))
