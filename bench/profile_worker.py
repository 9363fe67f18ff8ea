"""Where a worker's time goes: py-spy samples the README's command, stepSimulation against the rest.

    python -m bench.profile_worker                 # annotate --objects objects/ --n 100, 2 workers, twice
    python -m bench.profile_worker --n 50 --repeat 1 --top 20

``py-spy record --subprocesses --nonblocking`` samples every process of ``annotate`` (the main
process and its loky workers) at ``--rate`` Hz without pausing them. A sample of a worker is "in
stepSimulation" when its innermost Python frame is the line of ``World.step`` that calls
``pb.stepSimulation`` (py-spy without ``--native`` shows a C call as the Python line calling it);
everything else a worker does (starting up, sampling candidates, loading objects, the trial's Python, writing
results back) is "outside". Idle threads are not sampled, so the share is of a worker's busy time.
Printed per run: samples and the share outside per worker, over all workers, the load average
before and after, and where a span's time outside stepSimulation goes (by phase: loading, sampling,
each step of a trial; and by innermost function, as shares of the spans' samples); with
``--repeat`` the spread of the share. Decompositions are cached (RG2_CACHE_DIR): run it twice on a
fresh machine and read the second. The shares are ratios of samples of the same run, so they need
no reference; they go into a record (bench/harness.py) with the spread over runs.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import inspect
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from annotator.sim.world import World
from bench.arguments import N_MAX, REPEAT_MAX, WORKERS_MAX, Parser, count, existing_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
SPAN = "WorkerState.label (annotator/pipeline/worker.py"  # py-spy's frame of a span's work
FRAME = re.compile(r"^(?P<func>.*) \((?P<file>[^()]*):(?P<line>\d+)\)$")


def step_line() -> tuple[str, int]:
    """(file suffix, line) of the ``pb.stepSimulation`` call inside ``World.step``."""
    lines, first = inspect.getsourcelines(World.step)
    for k, text in enumerate(lines):
        if "stepSimulation" in text:
            return "annotator/sim/world.py", first + k
    raise SystemExit("World.step does not call stepSimulation: update this script")


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min) {five:.2f} (5 min)"


def profile(n: int, workers: int, rate: int, objects: Path) -> dict[str, collections.Counter]:
    """Collapsed stacks of one run: {process label: Counter(stack tuple -> samples)}."""
    pyspy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or shutil.which("py-spy")
    annotate = shutil.which("annotate", path=str(Path(sys.executable).parent)) or shutil.which("annotate")
    if pyspy is None or annotate is None:
        raise SystemExit("needs py-spy and the annotate command: pip install -e '.[bench]'")
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "stacks.txt"
        cmd = [pyspy, "record", "--subprocesses", "--nonblocking", "--rate", str(rate), "--format", "raw"]
        cmd += ["--output", str(raw), "--", annotate, "--objects", str(objects), "--n", str(n)]
        cmd += ["--out", str(Path(tmp) / "labels"), "--workers", str(workers), "--quiet"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"py-spy/annotate exited {proc.returncode}: {proc.stderr[-1500:]}")
        stacks: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        for row in raw.read_text().splitlines():
            text, _, count = row.rpartition(" ")
            frames = text.split(";")
            # py-spy nests a child's stack under its parents' "process PID:cmdline" frames
            k = max(i for i, f in enumerate(frames) if f.startswith("process "))
            stacks[frames[k]][tuple(frames[k + 1 :])] += int(count)
    return stacks


def owner(stack: tuple[str, ...]) -> str:
    """The innermost frame of the project's code in ``stack`` (else the innermost frame)."""
    ours = [f for f in stack if "annotator/" in f or "bench/" in f] or [stack[-1]]
    return FRAME.sub(r"\g<func> (\g<file>)", ours[-1])


def phase(stack: tuple[str, ...]) -> str:
    """What a span was doing: the call under ``WorkerState.label``, and under a trial's ``run``."""
    names = [FRAME.sub(r"\g<func>", f) for f in stack]
    k = next(i for i, f in enumerate(stack) if f.startswith(SPAN))
    below = names[k + 1] if k + 1 < len(names) else "WorkerState.label"
    if "GraspTrial.run" in names:
        r = names.index("GraspTrial.run")
        return f"trial: {names[r + 1] if r + 1 < len(names) else 'GraspTrial.run'}"
    return below


def is_worker(label: str, counter: collections.Counter) -> bool:
    """loky's worker processes (not its resource tracker); py-spy sometimes reads no command line
    for one, so a process that ran a span is one too."""
    return "popen_loky" in label or any(f.startswith(SPAN) for s in counter for f in s)


@dataclasses.dataclass
class Shares:
    """One run's worker samples: all, in stepSimulation, inside spans; per scope [samples, outside];
    outside stepSimulation inside spans by innermost project function and by phase."""

    total: int = 0
    inside: int = 0
    in_span: int = 0
    per: dict[str, list[int]] = dataclasses.field(
        default_factory=lambda: {"simulate": [0, 0], "GraspTrial.run": [0, 0]}
    )
    outside: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    phases: collections.Counter = dataclasses.field(default_factory=collections.Counter)

    def add_worker(self, counter: collections.Counter, in_step: Callable[[tuple[str, ...]], bool]) -> None:
        n_all = sum(counter.values())
        self.total += n_all
        self.inside += sum(c for s, c in counter.items() if in_step(s))
        for s, c in counter.items():
            if not any(f.startswith(SPAN) for f in s):
                continue
            self.in_span += c
            names = {FRAME.sub(r"\g<func>", f) for f in s}
            for scope, counts in self.per.items():
                if scope in names:
                    counts[0] += c
                    counts[1] += 0 if in_step(s) else c
            if not in_step(s):
                self.outside[owner(s)] += c
                self.phases[phase(s)] += c

    def share(self, scope: str) -> float:
        n_scope, n_out = self.per[scope]
        return n_out / max(1, n_scope)

    @property
    def outside_share(self) -> float:
        return 1 - self.inside / max(1, self.total)

    @property
    def span_outside_share(self) -> float:
        return 1 - self.inside / max(1, self.in_span)


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--n", type=count(1, N_MAX), default=100)
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=os.cpu_count() or 1)
    ap.add_argument("--rate", type=count(1, 10_000), default=250, help="samples per second per process")
    ap.add_argument("--repeat", type=count(1, REPEAT_MAX), default=2)
    ap.add_argument("--top", type=count(0, 1000), default=12, help="functions outside stepSimulation to list")
    return ap


def main() -> None:
    args = parser().parse_args()
    step_file, step_no = step_line()

    def in_step(stack: tuple[str, ...]) -> bool:
        m = FRAME.match(stack[-1]) if stack else None
        return bool(m and m["file"].endswith(step_file) and int(m["line"]) == step_no)

    with Run("profile_worker", config=vars(args)) as run:
        runs: list[Shares] = []
        for r in range(args.repeat):
            print(f"\n== run {r + 1}: annotate --objects objects/ --n {args.n} --workers {args.workers} ==")
            print(f"before: {load()}")
            stacks = profile(args.n, args.workers, args.rate, args.objects)
            print(f"after:  {load()}")
            runs.append(tally(stacks, in_step, args.top))
        record(run, runs)


def tally(
    stacks: dict[str, collections.Counter], in_step: Callable[[tuple[str, ...]], bool], top: int
) -> Shares:
    """Count one run's samples and print its shares."""
    shares = Shares()
    for label, counter in sorted(stacks.items()):
        n_all = sum(counter.values())
        n_in = sum(c for s, c in counter.items() if in_step(s))
        worker = is_worker(label, counter)
        kind = "worker" if worker else "other "
        print(f"{kind} {label[:60]:<60} {n_all:7d} samples, outside stepSimulation {1 - n_in / n_all:6.1%}")
        if worker:
            shares.add_worker(counter, in_step)
    if not shares.total:
        raise SystemExit("no worker process was sampled")
    print(
        f"all workers: {shares.total} samples, {shares.inside} in stepSimulation; "
        f"share outside {shares.outside_share:.1%}"
    )
    print(
        f"of which inside a span (WorkerState.label: loading, sampling, trials): {shares.in_span} samples, "
        f"share outside stepSimulation {shares.span_outside_share:.1%}"
    )
    for scope, what in (
        ("simulate", "per candidate (simulate: trials and label rows)"),
        ("GraspTrial.run", "per trial (GraspTrial.run)"),
    ):
        print(
            f"{what}: {shares.per[scope][0]} samples, share outside stepSimulation {shares.share(scope):.1%}"
        )
    print("outside stepSimulation inside spans, by phase (share of the spans' samples):")
    for where, c in shares.phases.most_common():
        print(f"  {c / max(1, shares.in_span):6.1%}  {where}")
    print(f"outside stepSimulation inside spans, by innermost project function, top {top}:")
    for where, c in shares.outside.most_common(top):
        print(f"  {c / max(1, shares.in_span):6.1%}  {where}")
    return shares


def record(run: Run, runs: list[Shares]) -> None:
    """The shares as ratios (median over runs, with their range) and the phases of all runs."""
    for name, what, values in (
        (
            "outside_step_in_spans",
            "inside spans (loading, sampling, trials)",
            [s.span_outside_share for s in runs],
        ),
        ("outside_step_per_candidate", "per candidate (simulate)", [s.share("simulate") for s in runs]),
        ("outside_step_per_trial", "per trial (GraspTrial.run)", [s.share("GraspTrial.run") for s in runs]),
        ("outside_step_all", "all the workers' samples, start-up included", [s.outside_share for s in runs]),
    ):
        run.ratio(
            name,
            statistics.median(values),
            spread=(min(values), max(values)),
            note=f"share of the workers' samples outside stepSimulation, {what}; median of {len(runs)} runs",
        )
    if len(runs) > 1:
        shares = [s.outside_share for s in runs]
        print(
            f"\nshare outside stepSimulation over {len(shares)} runs: min {min(shares):.1%} / median "
            f"{statistics.median(shares):.1%} / max {max(shares):.1%}"
        )
    in_span = sum(s.in_span for s in runs)
    phases = sum((s.phases for s in runs), collections.Counter())
    run.table(
        "phases",
        [{"phase": where, "share_of_spans": c / max(1, in_span)} for where, c in phases.most_common()],
        note="samples outside stepSimulation inside spans, by phase, over all runs",
    )
    functions = sum((s.outside for s in runs), collections.Counter())
    run.table(
        "functions",
        [
            {"function": where, "share_of_spans": c / max(1, in_span)}
            for where, c in functions.most_common(20)
        ],
        note="samples outside stepSimulation inside spans, by innermost project function (top 20, all runs)",
    )
    run.figure("worker_samples", sum(s.total for s in runs), note="all runs")


if __name__ == "__main__":
    main()
