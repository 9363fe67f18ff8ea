"""The cost of robust labels: candidates per CPU-second of ``--trials K`` against ``--trials 1``.

    python -m bench.trials_cost                    # the sample objects, 30 candidates each, K = 5
    python -m bench.trials_cost --n 50 --trials 3 --repeat 2
    python -m bench.trials_cost --config execution.toml   # e.g. a simulated approach
    python -m bench.trials_cost --config execution.toml --profile profile.toml  # a fitted execution's price

Every sample object's first N candidates are labelled with ``--trials 1`` and with ``--trials K``,
alternately, ``--repeat`` times, through the runner's execution
(:func:`annotator.pipeline.in_memory.run_in_memory`: one task per object and variant, the worker's
own ``label_span`` run by a :class:`~annotator.pipeline.tasks.Call` after the checks every task
gets). The CPU time of each span is measured in the worker, around its ``label_span``
(``time.process_time`` of the worker process, carried back in :class:`TimedSpan`), not in this
process, which only waits; summed over the objects it gives candidates per CPU-second, and the
ratio is the cost of the extra trials in the same run. With ``--workers 1`` (the default) every
span runs in the one worker process, which loaded (and decomposed, cold) every object beforehand:
a warm worker, as the figures have always been measured. With more workers a span may meet an
object its worker has not loaded yet, and its CPU then includes the load: keep 1 for the figures.

The rows of trial 0 are checked equal between the two (trial 0 is the ``--trials 1`` label). Where
the extra time goes: the physics steps of all K trials (``sim_steps``) against trial 0's, overall
and by trial 0's outcome (a ``collision`` runs no perturbed trial; a candidate that holds runs every
perturbed trial through close and lift, and through the shake with ``[robust] shake = true``). The
same K is also run with the perturbed trials shaken (``--no-shaken`` skips it): its cost, and how
its scores differ from the default's on the same candidates; and with the perturbed closes stalled
by the drive's speed alone (``[robust] stall_by_travel = false``). With a simulated approach
(``--config`` setting ``[protocol] approach = "simulated"``), the same K is also run with the
perturbed trials' approaches in full as well (``[robust] approach_from_contact = false``; its cost,
and the scores against it). With ``--profile``, the profile's K with the profile against the same K
with the model before (``--before``), in the same run: what labels made with a fitted execution cost
per candidate. Prints figures and writes a record (bench/harness.py); asserts nothing.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.objects import ObjectSource, discover_objects
from annotator.pipeline.in_memory import ExecutionOptions, Failed, run_in_memory
from annotator.pipeline.tasks import Call, Span, SpanResult, SpanTask
from annotator.pipeline.worker import label_span_within
from bench.arguments import (
    N_MAX,
    REPEAT_MAX,
    WORKERS_MAX,
    Parser,
    count,
    existing_file,
    existing_folder,
)
from bench.harness import ROOT, Run

TRIAL0 = ["outcome", "width", "x", "y", "z", "qx", "qy", "qz", "qw"]


@dataclass(frozen=True)
class TimedSpan:
    """A span's labels as the worker returned them (``result``) and the CPU seconds the worker
    process spent labelling it (``cpu_s``, its ``time.process_time``)."""

    result: SpanResult
    cpu_s: float


def timed_span(task: SpanTask) -> TimedSpan:
    """In a worker (a :class:`Call`'s function): label ``task``'s span as a worker does, timed in
    CPU seconds of this process."""
    t0 = time.process_time()
    result = label_span_within(task)
    return TimedSpan(result, time.process_time() - t0)


def label(
    sources: list[ObjectSource], n: int, trials: int, config: AnnotatorConfig, execution: ExecutionOptions
) -> tuple[pd.DataFrame, float]:
    """Every object's first ``n`` candidates with ``--trials trials``, one task per object in the
    workers of ``execution``; (rows in the objects' order, the workers' CPU seconds over the spans)."""
    tasks = [
        Call(
            fn=timed_span,
            args=(
                SpanTask(span=Span(s.object_id, s, None, 0, n), config=config, seed=0, n=n, trials=trials),
            ),
            config=config,
        )
        for s in sources
    ]
    parts, cpu = [], 0.0
    for source, timed in zip(
        sources, run_in_memory(tasks, execution, [s.object_id for s in sources]), strict=True
    ):
        if isinstance(timed, Failed):
            print(f"{source.object_id}: {timed.error}")
            continue
        cpu += timed.cpu_s
        if timed.result.error is None:
            parts.append(timed.result.rows)
        else:
            print(f"{source.object_id}: {timed.result.error}")
    return pd.concat(parts, ignore_index=True), cpu


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument("--n", type=count(1, N_MAX), default=30, help="candidates per object")
    ap.add_argument("--trials", type=count(2, 100), default=5, help="the K compared with --trials 1")
    ap.add_argument("--repeat", type=count(1, REPEAT_MAX), default=2)
    ap.add_argument(
        "--workers",
        type=count(1, WORKERS_MAX),
        default=1,
        help="worker processes (1: one warm worker, as the figures are measured)",
    )
    ap.add_argument(
        "--no-shaken", action="store_true", help="skip the K trials with the perturbed ones shaken too"
    )
    ap.add_argument(
        "--config", type=existing_file, default=None, help="a TOML of overrides (annotate --config)"
    )
    ap.add_argument(
        "--profile",
        type=existing_file,
        default=None,
        help="also label at this profile's --trials with the profile (calibrate --fit-ranges), against the "
        "model before (--before) at the same K, in the same run: the price of a fitted execution",
    )
    ap.add_argument(
        "--before",
        type=existing_file,
        default=ROOT / "bench" / "before_stages.toml",
        help="the model before, for --profile's comparison: its changes over --config "
        "[default: bench/before_stages.toml]",
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    config = AnnotatorConfig.from_toml(args.config) if args.config else AnnotatorConfig()
    sources = discover_objects(args.objects)
    execution = ExecutionOptions(workers=args.workers)
    label(sources, 1, 1, config, execution)  # load (and decompose, cold) every object first
    k = args.trials
    # (trials, configuration, name, what the name says in the output)
    variants = [(1, config, "1", ""), (k, config, str(k), "")]
    if not args.no_shaken:
        shaken = dataclasses.replace(config, robust=dataclasses.replace(config.robust, shake=True))
        variants.append((k, shaken, f"{k}_shaken", " (perturbed shaken)"))
    by_speed = dataclasses.replace(config, robust=dataclasses.replace(config.robust, stall_by_travel=False))
    variants.append((k, by_speed, f"{k}_by_speed", " (perturbed closes stalled by speed alone)"))
    simulated = config.protocol.approach == "simulated"
    if simulated:
        in_full = dataclasses.replace(
            by_speed, robust=dataclasses.replace(by_speed.robust, approach_from_contact=False)
        )
        variants.append((k, in_full, f"{k}_in_full", " (perturbed approach in full, stalled by speed)"))
    if args.profile is not None:
        profile = AnnotatorConfig.from_toml(args.profile)
        pk = profile.confidence.trials or k
        before = _overlaid(config, args.before)  # --config with the model before's changes
        variants.append((pk, profile, f"{pk}_profile", f" (the profile {args.profile.name})"))
        variants.append((pk, before, f"{pk}_before", f" (the model before, {args.before.name})"))
    rates: dict[str, list[float]] = {name: [] for _, _, name, _ in variants}
    rows: dict[str, pd.DataFrame] = {}
    settings = vars(args) | {"objects": args.objects.name, "config": config.to_dict(trials=args.trials)}
    with Run("trials_cost", config=settings) as run:
        for r in range(args.repeat):
            for trials, cfg, name, what in variants:
                table, cpu = label(sources, args.n, trials, cfg, execution)
                rates[name].append(len(table) / cpu)
                rows[name] = table
                print(
                    f"run {r + 1}: --trials {trials}{what}: "
                    f"{len(table)} candidates in {cpu:.1f} CPU-s, {len(table) / cpu:.2f} per CPU-s",
                    flush=True,
                )
        one, many = rows["1"], rows[str(args.trials)]
        same = bool(one[TRIAL0].equals(many[TRIAL0]))
        held = many["success"].mean()
        ratio = np.median(rates[str(args.trials)]) / np.median(rates["1"])
        print(
            f"--trials {args.trials} / --trials 1, candidates per CPU-second: {ratio:.3f} "
            f"(trial 0 identical: {same}; {held:.1%} held at trial 0)"
        )
        for name, values in rates.items():
            run.figure(
                f"candidates_per_cpu_s_k{name}",
                float(np.median(values)),
                "1/CPU-s",
                spread=(min(values), max(values)),
            )
        run.ratio(f"k{args.trials}_over_k1", ratio, note="candidates per CPU-second, --trials K / --trials 1")
        run.figure("trial0_identical", int(same), note="trial 0's outcome, width and pose equal at K and 1")
        steps1, stepsk = int(one["sim_steps"].sum()), int(many["sim_steps"].sum())
        run.ratio(
            f"steps_k{args.trials}_over_k1",
            stepsk / steps1,
            note="physics steps of all K trials / of trial 0, the same candidates",
        )
        print(f"physics steps, --trials {args.trials} / --trials 1: {stepsk / steps1:.3f}")
        run.table("steps_by_outcome", steps_by_outcome(one, many, args.trials))
        if not args.no_shaken:
            compare(run, rows, rates, args.trials, "shaken", "with the perturbed trials shaken")
        compare(run, rows, rates, args.trials, "by_speed", "with the perturbed closes stalled by speed alone")
        if simulated:
            what = "with the perturbed trials' approaches in full and closes stalled by speed"
            compare(run, rows, rates, args.trials, "in_full", what)
        if args.profile is not None:
            ratio = np.median(rates[f"{pk}_before"]) / np.median(rates[f"{pk}_profile"])
            steps = int(rows[f"{pk}_profile"]["sim_steps"].sum()) / int(
                rows[f"{pk}_before"]["sim_steps"].sum()
            )
            note = (
                f"CPU per candidate at --trials {pk}, the profile over the model before ({args.before.name})"
            )
            run.ratio(f"profile_k{pk}_cpu_over_before", ratio, note=note)
            run.ratio(f"profile_k{pk}_steps_over_before", steps, note="physics steps, the same candidates")
            print(
                f"the profile at --trials {pk}: {ratio:.3f} x the CPU per candidate of the model before "
                f"({steps:.3f} x the steps)"
            )


def _overlaid(config: AnnotatorConfig, path: Path) -> AnnotatorConfig:
    """``config`` with the fields the TOML file ``path`` sets, section by section."""
    import tomllib

    data = config.to_dict()
    with open(path, "rb") as fh:
        for section, values in tomllib.load(fh).items():
            data.setdefault(section, {}).update(values)
    return AnnotatorConfig.from_dict(data)


def compare(
    run: Run, rows: dict[str, pd.DataFrame], rates: dict[str, list[float]], k: int, name: str, what: str
) -> None:
    """Record the cost of variant ``name`` of the K trials (``what`` says what it changes) against
    ``--trials 1``, and how the default's scores differ from its scores on the candidates past
    the kinematic check."""
    many, other = rows[str(k)], rows[f"{k}_{name}"]
    ratio = np.median(rates[f"{k}_{name}"]) / np.median(rates["1"])
    note = f"candidates per CPU-second, --trials K {what} / --trials 1"
    run.ratio(f"k{k}_{name}_over_k1", ratio, note=note)
    tried = many["outcome"].ne("collision").to_numpy()
    diff = (many["score"] - other["score"]).to_numpy()[tried]
    run.figure(
        f"score_same_as_{name}",
        float(np.mean(diff == 0)),
        note=f"candidates past the kinematic check whose score equals the one {what}",
    )
    run.figure(f"score_minus_{name}_mean", float(np.mean(diff)), note="the same candidates")
    steps = int(other["sim_steps"].sum()) / int(rows["1"]["sim_steps"].sum())
    run.ratio(f"steps_k{k}_{name}_over_k1", steps, note=f"physics steps of all K trials {what} / of trial 0")
    print(
        f"{what}: --trials {k} / --trials 1 {ratio:.3f} (steps {steps:.3f}); scores equal to the "
        f"default's on {np.mean(diff == 0):.1%} of the {tried.sum()} candidates past the kinematic "
        f"check, mean difference {np.mean(diff):+.3f}"
    )


def steps_by_outcome(one: pd.DataFrame, many: pd.DataFrame, k: int) -> list[dict]:
    """Per trial 0 outcome: candidates, mean steps of trial 0, mean steps of each perturbed trial
    (``(all K - trial 0) / (K - 1)``), and the outcome's share of the extra steps."""
    extra = many["sim_steps"].to_numpy() - one["sim_steps"].to_numpy()
    total = max(1, int(extra.sum()))
    out = []
    for outcome, idx in one.groupby("outcome").indices.items():
        out.append(
            {
                "trial0_outcome": str(outcome),
                "candidates": len(idx),
                "held_share_at_k": float(many["score"].iloc[idx].mean()),
                "steps_trial0": float(one["sim_steps"].iloc[idx].mean()),
                "steps_per_perturbed_trial": float(extra[idx].mean() / max(1, k - 1)),
                "share_of_extra_steps": float(extra[idx].sum() / total),
            }
        )
    return out


if __name__ == "__main__":
    # main of the module imported by name: the functions its tasks name are pickled by reference
    from bench.trials_cost import main as importable_main

    importable_main()
