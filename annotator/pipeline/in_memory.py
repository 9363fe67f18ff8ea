"""Simulation that wants no output folder (a calibration's grid, the gripper check, clutter removal's
rounds, a bench's spans) through the runner's one execution: local worker processes or a Dask
cluster (:class:`annotator.pipeline.execution.Workers`), a worker that dies costs its tasks one
retry each, alone (:func:`annotator.pipeline.execution.execute`), local workers say what they do
in a status folder and end with the main process, and every task carries the label-shaping
versions its worker checks before it simulates. The results are kept in memory, in the order of
the tasks (the in-memory sink; a run that writes labels has the store instead,
:mod:`annotator.pipeline.lifecycle`).

A task is a :class:`~annotator.pipeline.tasks.WorkerTask`: a labelling task
(:class:`~annotator.pipeline.tasks.SpanTask`, run by the worker's
:func:`~annotator.pipeline.worker.label_span`) or a :class:`~annotator.pipeline.tasks.Call` of a
module-level function (run by :func:`~annotator.pipeline.worker.perform`, after the same checks).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from annotator.objects import default_cache_dir
from annotator.pipeline.execution import Workers, execute
from annotator.pipeline.tasks import Call, Performed, SpanResult, WorkerTask
from annotator.pipeline.worker import perform
from annotator.store.manifest import bound_versions


@dataclass(frozen=True)
class ExecutionOptions:
    """Where in-memory work runs: ``workers`` local processes, or the Dask cluster at
    ``scheduler``; ``cache_dir``, the decomposition cache of every worker (None: the default, as
    a run's)."""

    workers: int = 1
    scheduler: str | None = None
    cache_dir: Path | None = None


@dataclass(frozen=True)
class Work:
    """A task as the execution hands it out: its position ``index`` among the tasks, a ``name``
    (an object's id, ``round 3``) for its errors, the ``call`` that carries it."""

    index: int
    name: str
    call: Call

    @property
    def unit_id(self) -> str:
        return self.name

    @property
    def key(self) -> tuple[int]:
        return (self.index,)

    @property
    def size(self) -> int:
        return 1

    def describe(self) -> str:
        return f"running {self.name}"


@dataclass(frozen=True)
class Failed:
    """A task that did not come back: ``error``, one line (its worker died twice, or it raised), and
    ``exception``, what a :class:`Call`'s function raised (None otherwise)."""

    error: str
    exception: Exception | None = None


def run_in_memory(
    tasks: Sequence[WorkerTask], execution: ExecutionOptions | None = None, names: Sequence[str] | None = None
) -> list[Any]:
    """Run every task in the workers of ``execution``; their results in the order of ``tasks``: a
    :class:`SpanResult` for a :class:`SpanTask`, a :class:`Call`'s function's value, or
    :class:`Failed`. ``names``: what each task is called in an error (default: its span's object,
    else its position). The context every task carries (versions, the local main process, the
    status folder, the cache) is filled in here."""
    execution = execution or ExecutionOptions()
    status_dir = tempfile.mkdtemp(prefix="rg2-status-")
    results: list[Any] = [None] * len(tasks)
    try:
        workers = Workers(execution, status_dir)
        local = workers.client is None
        cache = execution.cache_dir or (default_cache_dir() if local else None)
        context = {
            "versions": bound_versions(),
            "parent_pid": workers.parent_pid,
            "status_dir": status_dir if local else None,
            "cache_dir": None if cache is None else str(cache),
        }
        work = [Work(i, _name(task, i, names), _call(task, i, context)) for i, task in enumerate(tasks)]

        def take(result: Performed | SpanResult) -> None:
            if isinstance(result, Performed):
                exc = result.error
                results[result.index] = result.value if exc is None else Failed(_line(exc), exc)
            else:  # what execute says of a task that did not come back
                assert isinstance(result.span, Work) and result.error is not None
                results[result.span.index] = Failed(result.error)

        interrupted = True
        try:
            execute(iter(work), lambda w: w.call, workers, take, fn=perform)
            interrupted = False
        finally:
            workers.close(kill=interrupted)
    finally:
        shutil.rmtree(status_dir, ignore_errors=True)
    return results


def call_values(
    calls: Sequence[Call], execution: ExecutionOptions | None = None, names: Sequence[str] | None = None
) -> list[Any]:
    """:func:`run_in_memory` of ``calls``: each function's value, in their order. What a function
    raised is raised here again; a call whose worker died twice is a RuntimeError naming it
    (``names``, else its position)."""
    results = run_in_memory(calls, execution, names)
    for i, result in enumerate(results):
        if isinstance(result, Failed):
            if result.exception is not None:
                raise result.exception
            raise RuntimeError(f"{names[i] if names else f'task {i}'}: {result.error}")
    return results


def _line(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}"


def _with_context(task: WorkerTask, context: dict[str, Any]) -> WorkerTask:
    """``task`` with the context it does not carry yet (a field it sets is kept)."""
    missing = {k: v for k, v in context.items() if getattr(task, k) is None}
    return dataclasses.replace(task, **missing) if missing else task


def _call(task: WorkerTask, index: int, context: dict[str, Any]) -> Call:
    filled = _with_context(task, context)
    if isinstance(filled, Call):
        return dataclasses.replace(filled, index=index)
    from annotator.pipeline.worker import label_span

    labelled = filled
    return Call(fn=label_span, args=(labelled,), index=index, config=task.config, **context)


def _name(task: WorkerTask, index: int, names: Sequence[str] | None) -> str:
    if names is not None:
        return names[index]
    span = getattr(task, "span", None)
    return str(getattr(span, "object_id", f"task {index}"))
