"""Throughput of the annotation job on the sample objects; prints figures, asserts nothing.

    python bench/throughput.py            # --n 200 on all cores, the 1- vs 2-worker scaling,
                                          # then the README's main command as a user runs it, 3 times
    python bench/throughput.py --n 50 --main-n 0    # quicker, without the main command
    python bench/throughput.py --n 0 --scaling-n 0 --repeat 5   # only the main command, 5 times
    python bench/throughput.py --n 0 --scaling-n 0 --versus other.toml   # runs alternate: default, other
    python bench/throughput.py --modes-only         # floating vs --cell vs --cell --views 1

The modes are run alternately, --repeat times each, with the load average printed before each run:
a figure is only comparable with one taken under the same load.

Convex decompositions are cached (RG2_CACHE_DIR or ~/.cache/rg2-annotator); the first run on a
fresh machine pays for them, so run it twice and read the second.

Every timing is printed with the machine's load average. This machine is shared: wall-clock
candidates/s per core fall when other processes want the cores, so the main command also reports
candidates per CPU-second (user + system time of the command and its workers), which is what one
core delivers when it is not shared; the main command is repeated and its spread printed.
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pybullet as pb

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import create_body, discover_objects, load_object
from annotator.pipeline.run import RunOptions, run
from annotator.sim.hand import FloatingRG2
from annotator.sim.world import World

ROOT = Path(__file__).resolve().parents[1]


def raw_step_cost(objects: Path, config: AnnotatorConfig, steps: int = 480) -> float:
    """Seconds per stepSimulation of the RG2 squeezing the sample box (no Python in the loop)."""
    with World(config.physics) as world:
        hand = FloatingRG2(world, config.gripper)
        model = load_object(objects / "box.obj", config.objects)
        uid = create_body(world.client, model)
        world.set_gravity(False)
        top = model.mesh.bounds[1][2] - 0.015  # pads on the top 30 mm, closing along the 60 mm side
        T_world_tcp = Transform([*model.center_mass[:2], top], np.array([1.0, 0.0, 0.0, 0.0]))
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, 0.06), 0.08)
        hand.close(config.gripper.grip_force, 240)
        assert all(hand.rg2.pad_contacts(uid)), "the bench grasp does not touch the box"
        t0 = time.perf_counter()
        for _ in range(steps):
            pb.stepSimulation(physicsClientId=world.client)
        return (time.perf_counter() - t0) / steps


def timed_run(
    objects: Path, n: int, workers: int, config: AnnotatorConfig, cell: bool = False, views: int = 0
):
    with tempfile.TemporaryDirectory() as out:
        options = RunOptions(
            objects_dir=objects, n=n, out_dir=Path(out), workers=workers, quiet=True, cell=cell, views=views
        )
        t0 = time.perf_counter()
        summary = run(options, config)
        return summary, time.perf_counter() - t0


MODES = {"floating": {}, "--cell": {"cell": True}, "--cell --views 1": {"cell": True, "views": 1}}


def compare_modes(objects: Path, n: int, workers: int, config: AnnotatorConfig, repeat: int) -> None:
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


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


def children_cpu() -> float:
    """User + system CPU seconds of this process's finished children (and their reaped children)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main_command(
    objects: Path, n: int, workers: int | None, config_file: Path | None = None
) -> tuple[float, float, float, str]:
    """The README's ``annotate --objects objects/ --n N`` as a subprocess (all cores by default).

    Returns (seconds to the first label file, seconds to exit, both from the launch; CPU seconds of
    the command and its workers; the summary's last line).
    """
    exe = shutil.which("annotate", path=str(Path(sys.executable).parent)) or shutil.which("annotate")
    if exe is None:
        raise SystemExit("the annotate command is not installed (pip install -e .)")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "labels"
        extra = ["--workers", str(workers)] if workers else []
        extra += ["--config", str(config_file)] if config_file else []
        cpu0 = children_cpu()
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [exe, "--objects", str(objects), "--n", str(n), "--out", str(out), "--quiet", *extra],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        first = None
        while proc.poll() is None:
            if first is None and out.is_dir() and any(out.glob("*.parquet")):
                first = time.perf_counter() - t0
            time.sleep(0.01)
        total = time.perf_counter() - t0
        stdout, stderr = proc.communicate()
        cpu = children_cpu() - cpu0
        if proc.returncode != 0:
            raise SystemExit(f"annotate exited {proc.returncode}:\n{stderr[-2000:]}")
        return (first if first is not None else total), total, cpu, stdout.splitlines()[-1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=Path, default=ROOT / "objects")
    ap.add_argument("--n", type=int, default=200, help="N of the in-process run (0: skip)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--scaling-n", type=int, default=80, help="candidates per object for 1 vs 2 workers")
    ap.add_argument("--main-n", type=int, default=500, help="N of the README main command (0: skip)")
    ap.add_argument("--modes-n", type=int, default=100, help="candidates per object for the modes (0: skip)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each mode and of the main command")
    ap.add_argument("--modes-only", action="store_true", help="only compare floating, --cell, --views 1")
    ap.add_argument("--config", type=Path, help="a --config FILE.toml for every run (default: none)")
    ap.add_argument("--versus", type=Path, help="FILE.toml: main command runs alternate with this config")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    config = AnnotatorConfig.from_toml(args.config) if args.config else AnnotatorConfig()
    cores = min(args.workers, os.cpu_count() or 1)
    if args.modes_only:
        compare_modes(args.objects, args.modes_n, args.workers, config, args.repeat)
        return

    n_objects = len(discover_objects(args.objects))
    if args.n:
        print(f"\n== annotate --n {args.n} on {n_objects} sample objects, {args.workers} workers ==")
        print(f"before: {load()}")
        summary, wall = timed_run(args.objects, args.n, args.workers, config)
        print(f"after:  {load()}")
        outside = 1.0 - summary.step_seconds / summary.worker_seconds
        print(f"wall time                      {wall:8.1f} s")
        print(f"candidates/s                   {summary.candidates / wall:8.2f}")
        print(f"candidates/s per core          {summary.candidates / wall / cores:8.2f}   ({cores} cores)")
        print(
            f"physics trials/s               {summary.physics_trials / wall:8.2f}   "
            f"({summary.physics_trials} of {summary.candidates} candidates simulated)"
        )
        print(f"mean simulated steps/candidate {summary.sim_steps / summary.candidates:8.1f}")
        print(f"time to first label file       {summary.first_label_seconds:8.1f} s (from the run's start)")
        print(
            f"worker time in stepSimulation  {summary.step_seconds:8.1f} s of {summary.worker_seconds:.1f} s"
        )
        print(f"share outside stepSimulation   {outside:8.1%}")
        step_ms = summary.step_seconds / max(summary.sim_steps, 1) * 1e3
        print(f"mean cost of one step in runs  {step_ms:8.3f} ms")
        print(f"raw stepSimulation, RG2 + box  {raw_step_cost(args.objects, config) * 1e3:8.3f} ms")
        rss = list(summary.peak_rss_mb.values())
        print(
            f"peak memory per worker         {max(rss):8.0f} MB "
            f"(workers: {', '.join(f'{r:.0f}' for r in rss)})"
        )

    if args.scaling_n:
        print(f"\n== scaling: --n {args.scaling_n}, 1 vs 2 workers == ({load()})")
        s1, w1 = timed_run(args.objects, args.scaling_n, 1, config)
        s2, w2 = timed_run(args.objects, args.scaling_n, 2, config)
        print(
            f"1 worker {w1:6.1f} s, 2 workers {w2:6.1f} s: speed-up {w1 / w2:.2f}, "
            f"efficiency {w1 / (2 * w2):.1%} ({load()})"
        )

    if args.modes_n:
        compare_modes(args.objects, args.modes_n, args.workers, config, args.repeat)

    if args.main_n:
        total_n = args.main_n * n_objects
        configs = [("", args.config)] + ([("versus ", args.versus)] if args.versus else [])
        print(
            f"\n== README main command: annotate --objects objects/ --n {args.main_n} "
            f"({args.workers} workers), {args.repeat} runs"
            + (f", alternating with --config {args.versus}" if args.versus else "")
            + " =="
        )
        per_core: dict[str, list[float]] = {label: [] for label, _ in configs}
        per_cpu: dict[str, list[float]] = {label: [] for label, _ in configs}
        for r in range(args.repeat):
            for label, config_file in configs:
                before = load()
                first, total, cpu, last = main_command(args.objects, args.main_n, args.workers, config_file)
                per_core[label].append(total_n / total / cores)
                per_cpu[label].append(total_n / cpu)
                print(
                    f"{label}run {r + 1}: first label file {first:5.1f} s, finished {total:6.1f} s after "
                    f"launch: {total_n / total:5.1f} candidates/s, {per_core[label][-1]:5.1f} per core; "
                    f"{cpu:6.1f} CPU-s, {per_cpu[label][-1]:5.1f} candidates per CPU-second"
                )
                print(f"       {before} before, {load()} after")
                print(f"       {last}")
        for label, _ in configs:
            a, b = per_core[label], per_cpu[label]
            print(
                f"{label or 'base '}candidates/s per core (wall): min {min(a):.1f} / median "
                f"{statistics.median(a):.1f} / max {max(a):.1f}; per CPU-second: min {min(b):.1f} / "
                f"median {statistics.median(b):.1f} / max {max(b):.1f}"
            )
        if args.versus:
            ratio = statistics.median(per_cpu["versus "]) / statistics.median(per_cpu[""])
            print(f"versus / base, median candidates per CPU-second: {ratio:.2f}")


if __name__ == "__main__":
    main()
