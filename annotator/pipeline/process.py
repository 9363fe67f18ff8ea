"""What a worker process does whatever it labels (objects or scenes), once per process: watch the
main process that started it (and end soon after it is gone or asks its workers to stop), check
that its label-shaping versions are the run's, and measure a task's time and memory."""

from __future__ import annotations

import os
import socket
import threading
import time
from dataclasses import dataclass

from annotator.objects import ObjectError
from annotator.pipeline import status
from annotator.pipeline.tasks import WorkerStats
from annotator.store.manifest import bound_versions
from annotator.versions import machine_kind

# How often (s) a local worker checks that the process that started it is still alive and has not
# asked it to stop: a worker outlives a killed or interrupted main process by at most this long.
PARENT_CHECK_SECONDS = 0.2


@dataclass
class _Process:
    """This process's watched parent, the stop folder of its current run, the versions checked."""

    watched_parent: int | None = None
    stop_folder: str | None = None
    versions_ok: dict[str, str] | None = None


_PROCESS = _Process()


def watch_parent(parent_pid: int | None, status_dir: str | None) -> None:
    """End this worker's process soon after the local main process is gone (killed, even by
    SIGKILL) or has asked its workers to stop (:func:`status.request_stop`, on Ctrl-C/SIGTERM)."""
    _PROCESS.stop_folder = status_dir  # the current run's; a reused worker serves several runs
    if parent_pid is None or _PROCESS.watched_parent == parent_pid:
        return
    _PROCESS.watched_parent = parent_pid

    def watch() -> None:
        while True:
            time.sleep(PARENT_CHECK_SECONDS)
            if os.getppid() != parent_pid or status.stop_requested(_PROCESS.stop_folder):
                os._exit(0)

    threading.Thread(target=watch, name="rg2-parent-watch", daemon=True).start()


def current_watch() -> tuple[int | None, str | None]:
    """(the main process this worker watches, its current run's stop folder), as the last task set
    them (:func:`watch_parent`): what work started within a task gives its own tasks, so that a
    stop request reaches them as it reaches the task."""
    return _PROCESS.watched_parent, _PROCESS.stop_folder


def check_versions(expected: dict[str, str] | None) -> None:
    """ObjectError when this process's label-shaping versions differ from the run's ``expected``
    (a cluster worker with others fails the unit instead of mixing)."""
    if expected is None or _PROCESS.versions_ok == expected:
        return
    mine = bound_versions()
    diffs = [f"{k} {mine.get(k)} (run: {v})" for k, v in sorted(expected.items()) if mine.get(k) != v]
    if diffs:
        raise ObjectError(f"worker on {socket.gethostname()} has other versions: {', '.join(diffs)}")
    _PROCESS.versions_ok = expected


def task_stats(t0: float, step_seconds: float) -> WorkerStats:
    """A task's worker time since ``t0`` (``time.perf_counter``), of which ``step_seconds`` in
    stepSimulation, this process's peak memory, its pid, host and kind of machine."""
    seconds = time.perf_counter() - t0
    host = socket.gethostname()
    return WorkerStats(seconds, step_seconds, peak_rss_mb(), os.getpid(), host, machine_kind())


def cpu_seconds() -> float:
    """CPU seconds of this process and of the children it waited for (the decompositions)."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def peak_rss_mb() -> float:
    """This process's peak resident memory (MB); 0 where the platform does not say."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    except (ImportError, OSError):  # pragma: no cover - Windows
        return 0.0
