"""The run's summary: one line per object (rate, mean score, outcome counts), failures, totals."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from annotator.dataset import OUTCOMES
from annotator.pipeline.tasks import PreparedObject


@dataclass
class ObjectStats:
    """One object's labels: rows, successes, mean score, outcome counts, worker seconds."""

    n: int
    successes: int
    mean_score: float
    outcomes: dict[str, int]
    seconds: float | None = None  # None: labelled by an earlier run
    reachable_successes: int | None = None  # --cell: successes the UR3 can execute

    @classmethod
    def from_json(cls, stats: dict[str, Any], seconds: float | None) -> ObjectStats:
        n, successes, score = int(stats["n"]), int(stats["successes"]), float(stats["mean_score"])
        reach = stats.get("reachable_successes")
        reachable = None if reach is None else int(reach)
        return cls(n, successes, score, dict(stats["outcomes"]), seconds, reachable)

    def line(self) -> str:
        """One line of figures: ``500 labels, 41.2 % held, 12.3 s``."""
        rate = self.successes / self.n if self.n else 0.0
        when = f", {self.seconds:.1f} s" if self.seconds is not None else ""
        reach = "" if self.reachable_successes is None else f" ({self.reachable_successes} reachable)"
        return f"{self.n} labels, {rate:.1%} held{reach}{when}"


@dataclass
class Summary:
    """Everything the run reports; ``done`` and ``resumed`` hold per-object statistics;
    ``prepared``: each object's decomposition task; ``warnings``: each object's warnings, once."""

    done: dict[str, ObjectStats] = field(default_factory=dict)  # labelled by this run
    resumed: dict[str, ObjectStats] = field(default_factory=dict)  # labelled by an earlier run
    failed: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # redone, removed, retried: one line each
    stopped: str | None = None  # why the run stopped early (disk full, lost scheduler, ...)
    seconds: float = 0.0
    candidates: int = 0  # simulated by this run
    physics_trials: int = 0  # candidates past the kinematic check (trial 0 ran physics)
    trials: int = 1  # K of --trials K: every such candidate ran K trials
    sim_steps: int = 0
    worker_seconds: float = 0.0  # summed over workers
    step_seconds: float = 0.0  # of which inside stepSimulation
    first_label_seconds: float | None = None  # from start to the first label file written
    peak_rss_mb: dict[int, float] = field(default_factory=dict)  # per worker pid
    prepared: dict[str, PreparedObject] = field(default_factory=dict)  # decomposition tasks, by object
    warnings: dict[str, list[str]] = field(default_factory=dict)  # one line each, per object
    prepare_seconds: float = 0.0  # worker seconds of the decomposition tasks (in worker_seconds)
    ready_seconds: float | None = None  # from start until the last decomposition task finished
    started: float = field(default_factory=time.perf_counter)
    unit: str = "object"  # what a row of the table is: an object, or a scene (annotate --scenes)

    @property
    def skipped(self) -> list[str]:
        return sorted(self.resumed)


def format_summary(summary: Summary) -> str:
    """A per-object table (full column names), then failures, notes and totals."""
    cols = list(OUTCOMES)
    widths = [max(len(c), 5) for c in cols]
    name_w = max([28, *(len(o) for o in [*summary.done, *summary.resumed, *summary.failed])])
    name_w = min(name_w, 48)
    rows = sorted([(o, s) for o, s in summary.done.items()] + [(o, s) for o, s in summary.resumed.items()])
    cell = any(st.reachable_successes is not None for _, st in rows)
    head = (
        f"{summary.unit:<{name_w}} {'n':>6} {'rate':>6} {'score':>6} "
        + " ".join(f"{c:>{w}}" for c, w in zip(cols, widths, strict=True))
        + (f" {'reachable':>9}" if cell else "")
        + f" {'time':>7}"
    )
    lines = [head, "-" * len(head)]
    for oid, st in rows:
        rate = st.successes / st.n if st.n else 0.0
        counts = " ".join(f"{st.outcomes.get(c, 0):>{w}}" for c, w in zip(cols, widths, strict=True))
        if cell:
            counts += f" {'' if st.reachable_successes is None else st.reachable_successes:>9}"
        when = f"{st.seconds:>6.1f}s" if st.seconds is not None else "earlier"
        figures = f"{st.n:>6} {rate:>6.1%} {st.mean_score:>6.3f} {counts} {when:>7}"
        lines.append(f"{_cut(oid, name_w):<{name_w}} {figures}")
    if cell:
        lines.append("reachable: successes the UR3 can execute (IK along the approach, no arm collision)")
    return "\n".join(lines + _tail(summary, name_w))


def _tail(summary: Summary, name_w: int) -> list[str]:
    """What follows the table: failures, each object's warnings once, notes, decompositions, totals."""
    lines = [f"{_cut(oid, name_w):<{name_w}} FAILED: {err}" for oid, err in sorted(summary.failed.items())]
    lines += [f"warning: {oid}: {w}" for oid, warnings in sorted(summary.warnings.items()) for w in warnings]
    lines += [f"note: {note}" for note in summary.notes]
    lines += _decompositions(summary)
    if summary.stopped:
        lines.append(f"STOPPED: {summary.stopped}")
    rate = summary.candidates / summary.seconds if summary.seconds else 0.0
    physics = (
        f"{summary.physics_trials} physics trials"
        if summary.trials == 1
        else f"{summary.physics_trials} past the kinematic check, {summary.trials} trials each"
    )
    lines.append(
        f"{len(summary.done)} {summary.unit}s labelled, {len(summary.resumed)} done earlier, "
        f"{len(summary.failed)} failed; {summary.candidates} candidates simulated in "
        f"{summary.seconds:.1f} s ({rate:.1f} candidates/s, {physics})"
    )
    return lines


def _decompositions(summary: Summary) -> list[str]:
    """One line on the decompositions this run made, when it made any."""
    made = {oid: p for oid, p in summary.prepared.items() if p.decomposed}
    if not made:
        return []
    cpu = sum(p.decomposition_cpu_s for p in made.values())
    slowest = max(made, key=lambda oid: made[oid].decomposition_cpu_s)
    ready = summary.ready_seconds
    ready_text = "" if ready is None else f"; every object ready {ready:.1f} s after the start"
    return [
        f"{len(made)} object(s) decomposed in {cpu:.1f} CPU-s (the slowest {slowest}, "
        f"{made[slowest].decomposition_cpu_s:.1f} CPU-s){ready_text}"
    ]


def _cut(text: str, width: int) -> str:
    return text if len(text) <= width else "…" + text[-(width - 1) :]
