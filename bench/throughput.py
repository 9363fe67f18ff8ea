"""Throughput of the annotation job on the sample objects, as ratios to a free step of the gripper.

    python -m bench.throughput            # --n 200 on all cores, the 1- vs 2-worker scaling, the
                                          # modes, then the README's main command, 3 times
    python -m bench.throughput --n 50 --main-n 0    # quicker, without the main command
    python -m bench.throughput --n 0 --scaling-n 0 --modes-n 0 --repeat 5   # only the main command
    python -m bench.throughput --n 0 --scaling-n 0 --modes-n 0 --versus bench/before_speed.toml
                                          # main command runs alternate: default, the model before
    python -m bench.throughput --modes-only         # floating vs --cell vs --cell --views 1
    python -m bench.throughput --n 0 --scaling-n 0 --modes-n 0 --main-n 100 \
        --versus-install ../old --versus-cache ../old-cache --cache ./cache
                                          # main command runs alternate: this code, another version

Every throughput figure comes first as a ratio to a reference measured in the same run
(bench/reference.py): the cost of a candidate in free steps, one free step being
``stepSimulation`` of the gripper squeezing the sample box, timed before each part and each run
of the main command. A slower or busier machine makes both dearer, so the ratio stays where
candidates per second do not. ``--versus`` adds the ratio to the model before;
``--versus-install DIR`` the ratio to another version of the code: DIR is a checkout of it,
installed in its own ``DIR/.venv`` (``git worktree add DIR COMMIT``, then ``python3 -m venv
DIR/.venv`` and ``DIR/.venv/bin/pip install -e DIR``), whose ``annotate`` runs alternate with this
one's on the same objects. Give each version its own warm decomposition cache (``--cache``,
``--versus-cache``) when their cache keys differ, or the first runs pay for decompositions.

The modes are run alternately, --repeat times each, with the load average printed before each run.
The main command also reports candidates per CPU-second (user + system time of the command and its
workers), what one core delivers when it is not shared, and is repeated for its spread.
Convex decompositions are cached (RG2_CACHE_DIR or ~/.cache/rg2-annotator); the first run on a
fresh machine pays for them, so run it twice and read the second. Prints figures and writes a
record (bench/harness.py); asserts nothing.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects
from annotator.pipeline.run import ObjectOptions, RunOptions, run
from bench.arguments import (
    N_MAX,
    REPEAT_MAX,
    WORKERS_MAX,
    Parser,
    count,
    existing_file,
    existing_folder,
    writable_folder,
)
from bench.harness import Run
from bench.reference import FreeStep, free_step, median_step

ROOT = Path(__file__).resolve().parents[1]


def timed_run(
    objects: Path, n: int, workers: int, config: AnnotatorConfig, cell: bool = False, views: int = 0
):
    with tempfile.TemporaryDirectory() as out:
        options = RunOptions(objects_dir=objects, n=n, out_dir=Path(out), workers=workers, quiet=True)
        t0 = time.perf_counter()
        summary = run(options, config, ObjectOptions(cell=cell, views=views))
        return summary, time.perf_counter() - t0


MODES = {"floating": {}, "--cell": {"cell": True}, "--cell --views 1": {"cell": True, "views": 1}}
MODE_KEYS = {"floating": "floating", "--cell": "cell", "--cell --views 1": "cell_views"}


def compare_modes(
    objects: Path, n: int, workers: int, config: AnnotatorConfig, repeat: int, record: Run
) -> None:
    """Wall time of the same job floating, in the cell, and in the cell with one view per placement."""
    print(f"\n== modes: --n {n}, {workers} workers, each run {repeat} times, alternating ==")
    walls: dict[str, list[float]] = {m: [] for m in MODES}
    for k in range(repeat):
        for mode, extra in MODES.items():
            load = os.getloadavg()
            summary, wall = timed_run(objects, n, workers, config, **extra)
            walls[mode].append(wall)
            print(
                f"run {k + 1} {mode:<17} {wall:7.1f} s  {summary.candidates / wall:6.2f} candidates/s  "
                f"{summary.physics_trials:5d} physics trials  load {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}"
            )
    base = float(np.median(walls["floating"]))
    for mode, times in walls.items():
        wall = float(np.median(times))
        print(f"median {mode:<17} {wall:7.1f} s  x{wall / base:4.2f} of floating")
        key = MODE_KEYS[mode]
        if mode != "floating":
            record.ratio(
                f"modes_{key}_vs_floating", wall / base, note=f"wall, {mode} / floating, medians of {repeat}"
            )
        record.figure(
            f"modes_{key}_s", wall, "s", spread=(min(times), max(times)), note=f"{mode}, --n {n}, wall"
        )


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


@dataclass(frozen=True)
class MainCommand:
    """One run of the main command: seconds from the launch to the first label file and to the exit,
    CPU seconds of the command and its workers, the summary's last line."""

    first_label_s: float
    exit_s: float
    cpu_s: float
    last_line: str


@dataclass(frozen=True)
class Contender:
    """One side of the main command's alternating runs: a label, a ``--config`` file, an install.

    ``exe`` is the ``annotate`` executable to run (None: this installation's); ``cache`` the
    decomposition cache it runs with (``RG2_CACHE_DIR``; None: the environment's).
    """

    label: str
    config_file: Path | None = None
    exe: Path | None = None
    cache: Path | None = None


def _this_annotate() -> Path:
    exe = shutil.which("annotate", path=str(Path(sys.executable).parent)) or shutil.which("annotate")
    if exe is None:
        raise SystemExit("the annotate command is not installed (pip install -e .)")
    return Path(exe)


def _install_commit(install: Path) -> str:
    """The commit ``install`` (a git checkout) is at, with ``+changes`` if its tree is dirty."""
    git = ["git", "-C", str(install)]
    head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        return "unknown commit"
    dirty = subprocess.run(
        [*git, "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True
    )
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def main_command(
    objects: Path,
    n: int,
    workers: int | None,
    config_file: Path | None = None,
    contender: Contender | None = None,
) -> MainCommand:
    """The README's ``annotate --objects objects/ --n N`` as a subprocess (all cores by default).

    Its CPU time is what ``os.wait4`` reports for that process: its own and that of the workers it
    waited for, nothing else. (This process's children-wide counter would also collect, whenever
    they end, the workers of the in-process runs before it, which joblib keeps for reuse.)
    """
    exe = contender.exe if contender is not None and contender.exe is not None else _this_annotate()
    env = dict(os.environ)
    if contender is not None and contender.cache is not None:
        env["RG2_CACHE_DIR"] = str(contender.cache)
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile("w+") as log:
        out = Path(tmp) / "labels"
        extra = ["--workers", str(workers)] if workers else []
        extra += ["--config", str(config_file)] if config_file else []
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [exe, "--objects", str(objects), "--n", str(n), "--out", str(out), "--quiet", *extra],
            stdout=log,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        first = None
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if first is None and out.is_dir() and any(out.glob("*.parquet")):
                first = time.perf_counter() - t0
            time.sleep(0.01)
        total = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        text = log.read()
        if proc.returncode != 0:
            raise SystemExit(f"annotate exited {proc.returncode}:\n{text[-2000:]}")
        cpu = usage.ru_utime + usage.ru_stime
        return MainCommand(first if first is not None else total, total, cpu, text.strip().splitlines()[-1])


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--n", type=count(0, N_MAX), default=200, help="N of the in-process run (0: skip)")
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=os.cpu_count() or 1)
    ap.add_argument(
        "--scaling-n", type=count(0, N_MAX), default=80, help="candidates per object for 1 vs 2 workers"
    )
    ap.add_argument(
        "--main-n", type=count(0, N_MAX), default=500, help="N of the README main command (0: skip)"
    )
    ap.add_argument(
        "--modes-n", type=count(0, N_MAX), default=100, help="candidates per object for the modes (0: skip)"
    )
    ap.add_argument(
        "--repeat", type=count(1, REPEAT_MAX), default=3, help="runs of each mode and of the main command"
    )
    ap.add_argument("--modes-only", action="store_true", help="only compare floating, --cell, --views 1")
    ap.add_argument("--config", type=existing_file, help="a --config FILE.toml for every run (default: none)")
    ap.add_argument(
        "--versus", type=existing_file, help="FILE.toml: main command runs alternate with this config"
    )
    ap.add_argument(
        "--versus-install",
        type=existing_folder,
        help="DIR: a checkout of another version, installed in DIR/.venv; the main command's runs "
        "alternate with its annotate",
    )
    ap.add_argument("--cache", type=writable_folder, help="RG2_CACHE_DIR of this version's main command runs")
    ap.add_argument("--versus-cache", type=writable_folder, help="RG2_CACHE_DIR of the --versus-install runs")
    return ap


def main() -> None:
    ap = parser()
    args = ap.parse_args()
    if args.versus and args.versus_install:
        ap.error("--versus and --versus-install compare one thing each: give one")
    if args.versus_install is not None:
        exe = args.versus_install / ".venv" / "bin" / "annotate"
        if not exe.is_file():
            ap.error(f"--versus-install {args.versus_install}: no {exe} (install it in DIR/.venv first)")
    logging.basicConfig(level=logging.WARNING)
    config = AnnotatorConfig.from_toml(args.config) if args.config else AnnotatorConfig()
    if args.modes_only:
        args.n = args.scaling_n = args.main_n = 0
    # a run with a configuration of its own, or against another version, keeps its record beside the
    # default's (the newest plain record stays the figures of this code alone)
    tag = None
    if args.config is not None:
        tag = "config-" + re.sub(r"[^a-z0-9]+", "-", args.config.stem.lower()).strip("-")
    if args.versus_install is not None:
        versus = re.sub(r"[^a-z0-9]+", "-", _install_commit(args.versus_install).lower()).strip("-")
        tag = "-".join(t for t in (tag, f"versus-{versus}") if t)
    with Run("throughput", config=vars(args), annotator=config, tag=tag) as record:
        references = [free_step(config)]
        if args.n:
            in_process(args, config, record, references)
        if args.scaling_n:
            scaling(args, config, record)
        if args.modes_n:
            compare_modes(args.objects, args.modes_n, args.workers, config, args.repeat, record)
        if args.main_n:
            main_command_runs(args, record, references)
        references.append(free_step(config))
        ref = median_step(references)
        cpu = [r.cpu_ms for r in references]
        record.figure(
            "free_step_cpu_ms",
            ref.cpu_ms,
            "ms",
            spread=(min(cpu), max(cpu)),
            note=f"the reference: CPU ms per free step, median of {len(references)} measured over the run",
        )


def in_process(
    args: argparse.Namespace, config: AnnotatorConfig, record: Run, references: list[FreeStep]
) -> None:
    """``annotate --n N`` in this process: rates, steps, the share outside stepSimulation."""
    cores = min(args.workers, os.cpu_count() or 1)
    n_objects = len(discover_objects(args.objects))
    print(f"\n== annotate --n {args.n} on {n_objects} sample objects, {args.workers} workers ==")
    print(f"before: {load()}")
    summary, wall = timed_run(args.objects, args.n, args.workers, config)
    print(f"after:  {load()}")
    ref = free_step(config)
    references.append(ref)
    outside = 1.0 - summary.step_seconds / summary.worker_seconds
    step_ms = summary.step_seconds / max(summary.sim_steps, 1) * 1e3
    core_ms = wall * cores / summary.candidates * 1e3  # core-wall ms per candidate
    print(f"wall time                      {wall:8.1f} s")
    print(f"candidates/s                   {summary.candidates / wall:8.2f}")
    print(f"candidates/s per core          {summary.candidates / wall / cores:8.2f}   ({cores} cores)")
    print(
        f"physics trials/s               {summary.physics_trials / wall:8.2f}   "
        f"({summary.physics_trials} of {summary.candidates} candidates simulated)"
    )
    print(f"mean simulated steps/candidate {summary.sim_steps / summary.candidates:8.1f}")
    print(f"time to first label file       {summary.first_label_seconds:8.1f} s (from the run's start)")
    print(f"worker time in stepSimulation  {summary.step_seconds:8.1f} s of {summary.worker_seconds:.1f} s")
    print(f"share outside stepSimulation   {outside:8.1%}")
    print(f"mean cost of one step in runs  {step_ms:8.3f} ms")
    print(f"free step, RG2 + box           {ref.wall_ms:8.3f} ms (bench/reference.py)")
    print(f"one candidate costs            {core_ms / ref.wall_ms:8.1f} free steps (core-wall)")
    rss = list(summary.peak_rss_mb.values())
    print(
        f"peak memory per worker         {max(rss):8.0f} MB (workers: {', '.join(f'{r:.0f}' for r in rss)})"
    )
    record.ratio(
        "free_steps_per_candidate",
        core_ms / ref.wall_ms,
        note=f"annotate --n {args.n} in-process: core-wall time per candidate / wall time of a free step",
    )
    record.ratio(
        "mean_step_vs_free_step",
        step_ms / ref.wall_ms,
        note="a step inside the run's trials / a free step (contacts and constraints of the trials)",
    )
    record.ratio("outside_step_share", outside, note="share of the workers' span time outside stepSimulation")
    record.figure(
        "candidates_per_s_per_core", summary.candidates / wall / cores, "1/s", note=f"{cores} cores"
    )
    record.figure(
        "candidates_per_s", summary.candidates / wall, "1/s", note=f"annotate --n {args.n}, in-process"
    )
    record.figure("wall_s", wall, "s")
    record.figure("physics_trials_per_s", summary.physics_trials / wall, "1/s")
    record.figure("steps_per_candidate", summary.sim_steps / summary.candidates)
    record.figure("first_label_s", summary.first_label_seconds, "s", note="from the run's start")
    record.figure("mean_step_ms", step_ms, "ms", note="wall, inside the trials")
    record.figure("free_step_wall_ms", ref.wall_ms, "ms", note="wall, right after the run")
    record.figure("peak_rss_per_worker", max(rss), "MB", note="the largest worker")


def scaling(args: argparse.Namespace, config: AnnotatorConfig, record: Run) -> None:
    """The same job on 1 and on 2 workers."""
    print(f"\n== scaling: --n {args.scaling_n}, 1 vs 2 workers == ({load()})")
    s1, w1 = timed_run(args.objects, args.scaling_n, 1, config)
    s2, w2 = timed_run(args.objects, args.scaling_n, 2, config)
    print(
        f"1 worker {w1:6.1f} s, 2 workers {w2:6.1f} s: speed-up {w1 / w2:.2f}, "
        f"efficiency {w1 / (2 * w2):.1%} ({load()})"
    )
    record.ratio("scaling_speedup", w1 / w2, note=f"--n {args.scaling_n}: wall with 1 worker / with 2")
    record.ratio("scaling_efficiency", w1 / (2 * w2), note="the speed-up / 2")


def main_command_runs(args: argparse.Namespace, record: Run, references: list[FreeStep]) -> None:
    """The README's main command as a user runs it, ``--repeat`` times (alternating with ``--versus``)."""
    cores = min(args.workers, os.cpu_count() or 1)
    total_n = args.main_n * len(discover_objects(args.objects))
    contenders = [Contender("", args.config, cache=args.cache)]
    versus_what = ""
    if args.versus:
        contenders.append(Contender("versus ", args.versus, cache=args.cache))
        versus_what = f"--config {args.versus}"
    elif args.versus_install:
        exe = args.versus_install / ".venv" / "bin" / "annotate"
        contenders.append(Contender("versus ", args.config, exe=exe, cache=args.versus_cache))
        versus_what = f"the code at {_install_commit(args.versus_install)}"
    configs = [(c.label, c.config_file) for c in contenders]
    print(
        f"\n== README main command: annotate --objects objects/ --n {args.main_n} "
        f"({args.workers} workers), {args.repeat} runs"
        + (f", alternating with {versus_what}" if versus_what else "")
        + " =="
    )
    per_core: dict[str, list[float]] = {label: [] for label, _ in configs}
    per_cpu: dict[str, list[float]] = {label: [] for label, _ in configs}
    free_steps: dict[str, list[float]] = {label: [] for label, _ in configs}
    rows = []
    # one reference for both configurations: the ratio of their free steps per candidate is theirs
    base = AnnotatorConfig.from_toml(args.config) if args.config else AnnotatorConfig()
    for r in range(args.repeat):
        for contender in contenders:
            label, config_file = contender.label, contender.config_file
            before, load0 = load(), os.getloadavg()[0]
            ref = free_step(base)
            references.append(ref)
            result = main_command(args.objects, args.main_n, args.workers, config_file, contender)
            first, total, cpu, last = result.first_label_s, result.exit_s, result.cpu_s, result.last_line
            per_core[label].append(total_n / total / cores)
            per_cpu[label].append(total_n / cpu)
            free_steps[label].append(cpu / total_n / ref.cpu)
            print(
                f"{label}run {r + 1}: first label file {first:5.1f} s, finished {total:6.1f} s after "
                f"launch: {total_n / total:5.1f} candidates/s, {per_core[label][-1]:5.1f} per core; "
                f"{cpu:6.1f} CPU-s, {per_cpu[label][-1]:5.1f} candidates per CPU-second, "
                f"{free_steps[label][-1]:5.1f} free steps per candidate"
            )
            print(f"       {before} before, {load()} after")
            print(f"       {last}")
            rows.append(
                {
                    "run": r + 1,
                    "config": str(config_file or "default"),
                    "code": "this" if contender.exe is None else str(args.versus_install),
                    "first_label_s": first,
                    "exit_s": total,
                    "cpu_s": cpu,
                    "candidates_per_cpu_s": per_cpu[label][-1],
                    "free_steps_per_candidate": free_steps[label][-1],
                    "free_step_cpu_ms": ref.cpu_ms,
                    "load_before": load0,
                }
            )
    for label, _ in configs:
        a, b = per_core[label], per_cpu[label]
        print(
            f"{label or 'base '}candidates/s per core (wall): min {min(a):.1f} / median "
            f"{statistics.median(a):.1f} / max {max(a):.1f}; per CPU-second: min {min(b):.1f} / "
            f"median {statistics.median(b):.1f} / max {max(b):.1f}"
        )
    what = f"annotate --objects objects/ --n {args.main_n}, {total_n} candidates"
    steps = free_steps[""]
    record.ratio(
        "main_free_steps_per_candidate",
        statistics.median(steps),
        spread=(min(steps), max(steps)),
        note=f"{what}: CPU time per candidate / CPU time of a free step measured just before; "
        f"median of {args.repeat} runs",
    )
    if versus_what:
        ratio = statistics.median(per_cpu["versus "]) / statistics.median(per_cpu[""])
        print(f"versus / base, median candidates per CPU-second: {ratio:.2f}")
        record.ratio(
            "main_versus_vs_base",
            ratio,
            note=f"candidates per CPU-second, {versus_what} / this code's default (medians; runs alternate)",
        )
        vs = free_steps["versus "]
        record.ratio(
            "main_versus_free_steps_per_candidate",
            statistics.median(vs),
            spread=(min(vs), max(vs)),
            note=f"as main_free_steps_per_candidate, with {versus_what}",
        )
    b = per_cpu[""]
    record.figure(
        "main_candidates_per_cpu_s",
        statistics.median(b),
        "1/s",
        spread=(min(b), max(b)),
        note=f"{what}: candidates per CPU-second of the command and its workers",
    )
    a = per_core[""]
    record.figure(
        "main_candidates_per_s_per_core",
        statistics.median(a),
        "1/s",
        spread=(min(a), max(a)),
        note=f"launch to exit, {cores} cores",
    )
    record.table("main_command", rows, note=what)


if __name__ == "__main__":
    main()
