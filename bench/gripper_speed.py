"""Candidates per CPU-second of each shipped gripper on the sample objects, as ratios to the RG2.

    python -m bench.gripper_speed [--n 100] [--rounds 2] [--objects objects/] [--workers 1]

Labels every sample object's first N candidates (sampled for each gripper's own stroke) through the
runner's execution (:func:`annotator.pipeline.in_memory.run_in_memory`: one task per object and
gripper, the worker's entry point ``label_span`` run by a :class:`~annotator.pipeline.tasks.Call`
after the checks every task gets; the default configuration), gripper after gripper, in
``--rounds`` rounds; a round's ratios compare runs made minutes apart on the same machine. Per
gripper and round: candidates per CPU-second of the spans (loading, sampling and simulating, as
``annotate`` counts them), the share simulated (not ``collision``), simulated trials per
CPU-second, and the ratio of candidates per second to the RG2's in that round.

The CPU time is the worker's: measured in the worker process around each span's ``label_span``
(``time.process_time``) and carried back with its labels (:class:`bench.trials_cost.TimedSpan`);
this process only waits. With ``--workers 1`` (the default) every span runs in the one worker
process, whose objects were decomposed (cached) and loaded before any timing, as the figures have
always been measured; with more workers the spans share the machine's cores and a worker may load
an object for the first time inside a timed span: keep 1 for the figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.grippers import load_gripper
from annotator.objects import ObjectSource, discover_objects
from annotator.pipeline.in_memory import ExecutionOptions, Failed, run_in_memory
from annotator.pipeline.tasks import Call, Span, SpanTask
from bench.arguments import N_MAX, REPEAT_MAX, WORKERS_MAX, Parser, count, existing_folder
from bench.harness import Run
from bench.trials_cost import TimedSpan, timed_span

GRIPPERS = ("rg2", "panda", "robotiq_2f85")


@dataclass(frozen=True)
class Labelled:
    """One gripper's pass over the objects: the workers' CPU seconds over its spans (``cpu_s``),
    its ``candidates`` and its ``simulated`` trials (candidates not rejected as ``collision``)."""

    cpu_s: float
    candidates: int
    simulated: int


def label_all(
    sources: list[ObjectSource], gripper: str, n: int, config: AnnotatorConfig, execution: ExecutionOptions
) -> Labelled:
    """Every object's first ``n`` candidates (seed 0) with ``gripper`` (a shipped gripper's name),
    one task per object in the workers of ``execution``; RuntimeError naming an object that failed."""
    description = load_gripper(gripper)
    tasks = []
    for source in sources:
        span = Span(source.object_id, source, None, 0, n)
        task = SpanTask(span=span, config=config, seed=0, n=n, gripper=description)
        tasks.append(Call(fn=timed_span, args=(task,), config=config))
    results = run_in_memory(tasks, execution, names=[s.object_id for s in sources])
    cpu, rows, simulated = 0.0, 0, 0
    for source, timed in zip(sources, results, strict=True):
        labels = _labels(source, timed)
        cpu += timed.cpu_s
        rows += len(labels)
        simulated += int((labels["outcome"] != "collision").sum())
    return Labelled(cpu, rows, simulated)


def _labels(source: ObjectSource, timed: TimedSpan | Failed) -> pd.DataFrame:
    """The rows of ``source``'s span, or RuntimeError with its error."""
    if isinstance(timed, Failed):
        raise RuntimeError(f"{source.object_id}: {timed.error}")
    if timed.result.error is not None or timed.result.rows is None:
        raise RuntimeError(f"{source.object_id}: {timed.result.error}")
    return timed.result.rows


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=count(1, N_MAX), default=100, help="candidates per object")
    ap.add_argument("--rounds", type=count(1, REPEAT_MAX), default=2)
    ap.add_argument(
        "--objects", type=existing_folder, default=Path(__file__).resolve().parents[1] / "objects"
    )
    ap.add_argument(
        "--workers",
        type=count(1, WORKERS_MAX),
        default=1,
        help="worker processes (1: one warm worker, as the figures are measured)",
    )
    return ap


def processes(workers: int) -> str:
    """Where the spans ran, as the header says it: ``one process`` (one worker), ``2 processes``."""
    return "one process" if workers == 1 else f"{workers} processes"


def main() -> None:
    args = parser().parse_args()
    sources = discover_objects(args.objects)
    config = AnnotatorConfig()
    execution = ExecutionOptions(workers=args.workers)
    label_all(sources, "rg2", 2, config, execution)  # objects decomposed (cached) before any timing
    print(f"{len(sources)} objects x {args.n} candidates, {processes(args.workers)}")
    print(
        f"{'round':>5} {'gripper':>13} {'cand/CPU-s':>10} {'simulated':>9} {'trials/CPU-s':>12} {'vs rg2':>7}"
    )
    with Run("gripper_speed", config=vars(args), annotator=config) as record:
        table, ratios = [], {g: [] for g in GRIPPERS}
        for r in range(args.rounds):
            rates = {}
            for gripper in GRIPPERS:
                done = label_all(sources, gripper, args.n, config, execution)
                seconds, rows, simulated = done.cpu_s, done.candidates, done.simulated
                rates[gripper] = rows / seconds
                ratios[gripper].append(rates[gripper] / rates["rg2"])
                table.append(
                    {
                        "round": r,
                        "gripper": gripper,
                        "candidates_per_cpu_s": rows / seconds,
                        "simulated_share": simulated / rows,
                        "trials_per_cpu_s": simulated / seconds,
                        "vs_rg2": rates[gripper] / rates["rg2"],
                    }
                )
                print(
                    f"{r:>5} {gripper:>13} {rows / seconds:>10.1f} {simulated / rows:>9.1%} "
                    f"{simulated / seconds:>12.1f} {rates[gripper] / rates['rg2']:>7.2f}",
                    flush=True,
                )
        for gripper in GRIPPERS[1:]:
            values = sorted(ratios[gripper])
            record.ratio(
                f"{gripper}_vs_rg2_candidates_per_cpu_s",
                values[len(values) // 2],
                spread=(values[0], values[-1]),
                note="same objects, candidates and process, rounds alternating; target >= 0.5",
            )
        record.table("rounds", table)


if __name__ == "__main__":
    main()
