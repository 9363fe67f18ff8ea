"""Running a command in a child process under a CPU limit: RLIMIT_CPU (so a loaded machine slows
the child down but does not stop it), a checkpoint it must earn to go on, a stop when it uses no
CPU for a while (a hang), one OpenMP thread; and how it ended (:class:`ChildRun`)."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

# How often (s) the parent looks at its child.
POLL_SECONDS = 0.05


@dataclass(frozen=True)
class ChildRun:
    """How a limited child process ended: its exit code (negative: the signal), CPU seconds (its
    own and its waited-for children's), whether a limit stopped it, the end of its stderr."""

    returncode: int
    cpu_seconds: float
    over_cpu: bool
    stalled: bool  # stopped after using no CPU for the stall limit (a hang, not work)
    stderr: str = ""


def _limit_cpu(pid: int, seconds: float) -> None:
    """RLIMIT_CPU of process ``pid``: SIGXCPU at ``seconds`` (whole, at least 1), SIGKILL a second
    later; no core file. Linux (prlimit); elsewhere the child limits itself (limit_own_cpu)."""
    import resource

    soft = max(1, math.ceil(seconds))
    resource.prlimit(pid, resource.RLIMIT_CORE, (0, 0))
    resource.prlimit(pid, resource.RLIMIT_CPU, (soft, soft + 1))


def _cpu_ticks(pid: int) -> int | None:
    """CPU clock ticks (user + system) process ``pid`` has used so far; None where /proc cannot say."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        return int(fields[11]) + int(fields[12])  # utime, stime: fields 14 and 15 of stat(5)
    except (OSError, IndexError, ValueError):
        return None


@dataclass(frozen=True)
class Checkpoint:
    """Stop a child at ``seconds`` of CPU unless ``keep_going()`` says it has earned the rest of
    its limit (CoACD: it has finished a threshold, so V-HACD's reserve is no longer needed)."""

    seconds: float
    keep_going: Callable[[], bool]


@dataclass
class _Watch:
    """The parent's view of a running child: its CPU ticks, when they last moved, and why it was
    stopped (a checkpoint it had not earned, or a stall)."""

    stall_seconds: float
    checkpoint: Checkpoint | None
    tick: float
    last_ticks: int | None = None
    progress: float = field(default_factory=time.monotonic)
    stopped: bool = False
    stalled: bool = False

    def must_stop(self, pid: int) -> bool:
        ticks, now = _cpu_ticks(pid), time.monotonic()
        if ticks is not None and ticks != self.last_ticks:
            self.last_ticks, self.progress = ticks, now
        if self.checkpoint is not None and ticks is not None and ticks / self.tick >= self.checkpoint.seconds:
            self.stopped = not self.checkpoint.keep_going()
            self.checkpoint = None  # earned, or stopped now: decided once
        self.stalled = now - self.progress > self.stall_seconds
        return self.stopped or self.stalled


def run_limited(
    cmd: list[str], cpu_seconds: float, stall_seconds: float, cwd: Path, checkpoint: Checkpoint | None = None
) -> ChildRun:
    """Run ``cmd`` with at most ``cpu_seconds`` of CPU time (and at most ``checkpoint.seconds``
    unless it has earned more), stopped too when it uses no CPU for ``stall_seconds`` (a hang;
    where /proc cannot tell, after ``stall_seconds`` of wall time), one OpenMP thread; returns how it
    ended. A loaded machine slows it down but does not stop it."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with open(cwd / "stderr.txt", "w+b") as err:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, env=env)
        watched = _cpu_ticks(proc.pid) is not None  # /proc tells its CPU: the checkpoint can be kept
        try:
            _limit_cpu(proc.pid, cpu_seconds if watched or checkpoint is None else checkpoint.seconds)
        except (AttributeError, OSError, ValueError):  # pragma: no cover - no prlimit: the child's own
            pass
        watch = _Watch(stall_seconds, checkpoint, float(os.sysconf("SC_CLK_TCK")))
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if watch.must_stop(proc.pid):
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(POLL_SECONDS)
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        tail = err.read().decode(errors="replace").strip().splitlines()[-1:]
    cpu = usage.ru_utime + usage.ru_stime
    # SIGXCPU comes from the CPU limit alone; SIGKILL from its hard limit a second later, or from
    # this function at the checkpoint or after a stall. rusage's user + system time is sampled and
    # can read a second short of the limit the kernel enforced.
    hard_limit = proc.returncode == -signal.SIGKILL and cpu >= max(1, math.ceil(cpu_seconds)) - 1.5
    over_cpu = watch.stopped or (not watch.stalled and (proc.returncode == -signal.SIGXCPU or hard_limit))
    return ChildRun(proc.returncode, cpu, over_cpu, watch.stalled, tail[0][:160] if tail else "")


def describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def limit_own_cpu(seconds: float) -> None:
    """The CPU limit on this process itself, where the parent could not set it (no prlimit)."""
    import resource

    soft = max(1, math.ceil(seconds))
    current, _ = resource.getrlimit(resource.RLIMIT_CPU)
    if current == resource.RLIM_INFINITY or current > soft:
        try:
            resource.setrlimit(resource.RLIMIT_CPU, (soft, soft + 1))
        except (ValueError, OSError):  # pragma: no cover - a hard limit below it: keep that
            pass
