"""First-run cost of each shipped object: loading it with an empty decomposition cache, then cached.

    python -m bench.cold_start              # the objects in objects/, twice each
    python -m bench.cold_start --repeat 1

For each object, ``annotator.objects.load_object`` runs with a new, empty cache folder (what the
first ``annotate`` on a machine pays, in the worker that loads the object: a concave object's CoACD
decomposition runs in a child process) and then again with that folder filled. Printed: wall
seconds and CPU seconds (this process and its children) of each, the convex parts, and the load
average; ``--repeat`` gives the spread. The job decomposes each object once, in one worker, never
twice in parallel (a lock per cache entry), so a run's cold start is about the largest of these
costs per worker, not their sum. A record (bench/harness.py) keeps every load and, as the ratio
that survives a slower machine, the empty cache's CPU seconds over the filled cache's.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

from annotator.config import AnnotatorConfig
from annotator.objects import ObjectError, discover_objects, load_object
from bench.arguments import REPEAT_MAX, Parser, count, existing_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]


def cpu() -> float:
    """CPU seconds (user + system) of this process and its finished children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def timed_load(source, config: AnnotatorConfig, cache: Path) -> tuple[float, float, int]:
    """(wall s, CPU s, convex parts) of one load_object with ``cache``."""
    t0, c0 = time.perf_counter(), cpu()
    model = load_object(source, config.objects, cache_dir=cache)
    return time.perf_counter() - t0, cpu() - c0, len(model.parts)


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--repeat", type=count(1, REPEAT_MAX), default=2)
    return ap


def main() -> None:
    args = parser().parse_args()
    config = AnnotatorConfig()
    with Run("cold_start", config=vars(args), annotator=config) as run:
        measure(args, config, run)


def measure(args: argparse.Namespace, config: AnnotatorConfig, run: Run) -> None:
    cold: dict[str, list[tuple[float, float]]] = {}
    cached: dict[str, list[float]] = {}
    rows = []
    for r in range(args.repeat):
        print(f"\n== round {r + 1} ==")
        for source in discover_objects(args.objects):
            with tempfile.TemporaryDirectory() as tmp:
                load = os.getloadavg()
                try:
                    wall, cpu_s, parts = timed_load(source, config, Path(tmp))
                    wall_c, cpu_c, _ = timed_load(source, config, Path(tmp))
                except ObjectError as exc:
                    print(f"{source.object_id}: {exc}")
                    continue
            cold.setdefault(source.object_id, []).append((wall, cpu_s))
            cached.setdefault(source.object_id, []).append(cpu_c)
            print(
                f"{source.object_id:<22} {parts:3d} parts  empty cache {wall:6.2f} s wall {cpu_s:6.2f} CPU-s "
                f"cached {wall_c:5.2f} s wall {cpu_c:5.2f} CPU-s  load {load[0]:.2f} {load[1]:.2f}"
            )
            rows.append(
                {
                    "round": r + 1,
                    "object": source.object_id,
                    "parts": parts,
                    "cold_wall_s": wall,
                    "cold_cpu_s": cpu_s,
                    "cached_wall_s": wall_c,
                    "cached_cpu_s": cpu_c,
                    "load": load[0],
                }
            )
    print("\nempty cache, CPU seconds per object (min / median / max over rounds)")
    total = total_cached = 0.0
    for name, runs in cold.items():
        c = [x[1] for x in runs]
        total += statistics.median(c)
        total_cached += statistics.median(cached[name])
        print(f"{name:<22} {min(c):6.2f} / {statistics.median(c):6.2f} / {max(c):6.2f}")
    print(f"all objects, medians summed: {total:.1f} CPU-s")
    run.ratio(
        "cold_vs_cached",
        total / max(total_cached, 1e-9),
        note="CPU seconds to load every object, empty cache / filled cache (medians over rounds, summed)",
    )
    run.figure("cold_cpu_s", total, "s", note="CPU seconds to load every object with an empty cache")
    run.figure("cached_cpu_s", total_cached, "s", note="the same with the cache filled")
    run.table("loads", rows, note="each object loaded with an empty cache, then with it filled")


if __name__ == "__main__":
    main()
