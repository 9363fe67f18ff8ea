"""Clutter removal's rounds through the runner's execution (:mod:`annotator.pipeline.in_memory`):
each round a task of its own on local worker processes or a Dask cluster, with the checks every
task gets (the label-shaping versions, the watch on the main process) and a round whose worker
died retried alone. The rounds are :mod:`annotator.policies.clutter`'s; a round depends on (seed,
round, policy) only, so the figures do not depend on the workers.
"""

from __future__ import annotations

from annotator.pipeline.in_memory import ExecutionOptions, call_values
from annotator.pipeline.tasks import Call
from annotator.policies.clutter import ClutterSetup, ClutterSummary, run_round


def run_clutter_removal(
    job: ClutterSetup, rounds: int, execution: ExecutionOptions | None = None
) -> ClutterSummary:
    """Rounds ``0..rounds-1`` of ``job``, in the workers of ``execution`` (default one local
    process). What a round raises (an object that cannot be loaded, a policy's error) is raised
    here; a round whose worker died twice is a RuntimeError naming it."""
    tasks = [Call(fn=run_round, args=(job, r), config=job.config) for r in range(rounds)]
    results = call_values(tasks, execution, names=[f"round {r}" for r in range(rounds)])
    return ClutterSummary(sorted(results, key=lambda x: x.round_id))
