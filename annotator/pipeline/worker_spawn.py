"""Local worker processes start in a process group of their own, out of the terminal's reach.

A Ctrl-C in a terminal sends SIGINT to every process of its foreground process group. joblib's
loky starts each local worker as a fresh interpreter (``python -m ...popen_loky_posix``) in the
command's group, so a Ctrl-C in the second or two a worker spends importing joblib, NumPy and
PyBullet raised ``KeyboardInterrupt`` there and printed its traceback beside the command's one
line. The workers never needed that signal: the main process handles Ctrl-C and SIGTERM, asks
its workers to stop through the status folder (:mod:`annotator.pipeline.status`), and each worker
ends within a fraction of a second of its parent (:mod:`annotator.pipeline.process`).

:func:`detach_local_workers` makes loky start every worker with ``os.posix_spawn(...,
setsid=True)`` instead of its own fork-exec: the same command line and environment, every
descriptor not marked inheritable closed at the exec as before (the ones loky hands over are
marked so), but the worker leads a new process group (``setsid``), so the terminal's signals reach
the main process only. Where ``posix_spawn`` is missing, or loky's launcher is not where this
version expects it, nothing changes.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence

log = logging.getLogger(__name__)

_MARK = "_rg2_detached"


def _spawn_detached(cmd: Sequence[str], keep_fds: Sequence[int], env: dict | None = None) -> int:
    """loky's ``fork_exec(cmd, keep_fds, env)`` in a new process group: the worker's pid. ``keep_fds``
    are already inheritable (loky marks them), so they stay open in the child."""
    child_env = {**os.environ, **(env or {})}
    return os.posix_spawn(cmd[0], list(cmd), child_env, setsid=True)


setattr(_spawn_detached, _MARK, True)


def detach_local_workers() -> bool:
    """Start loky's local workers in their own process group from now on (module docstring); whether
    it is in force. Idempotent; the process's other children are not affected."""
    if not hasattr(os, "posix_spawn"):
        return False
    try:
        from joblib.externals.loky.backend import fork_exec as launcher
    except ImportError:
        return False
    if getattr(launcher.fork_exec, _MARK, False):
        return True
    if not callable(getattr(launcher, "fork_exec", None)):
        log.debug("loky has no fork_exec here: its workers start in the command's process group")
        return False
    launcher.fork_exec = _spawn_detached
    return True
