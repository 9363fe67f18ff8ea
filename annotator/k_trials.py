"""The K trials of one candidate (``--trials K``): trial 0 unperturbed, then ``K - 1`` perturbed
ones drawn from the candidate's own Generator, none after a trial 0 that collides unless
``[robust] perturb_collisions``.

The one loop every labelling path runs (the object workers, annotator.pipeline.simulate; the
scene labels, annotator.scenes.labels): what a path adds around a trial (a resting pose, the
neighbours' disturbance) is in the ``run`` it passes, never in a copy of this loop. The draws
depend on (seed, object or scene unit, grasp id) only (annotator.rng.trial_rng), so a score is
the same whatever worker runs the candidate and whatever ran before it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from annotator.config import RobustConfig
from annotator.outcome import Outcome, Stage
from annotator.rng import trial_rng
from annotator.trial import Perturbation, TrialResult

R = TypeVar("R")


@dataclass(frozen=True)
class KTrials(Generic[R]):
    """What the K trials of one candidate gave: trial 0's own result ``first`` (whatever ``run``
    returns), how many of the K ``held`` (trial 0 through the gate, a perturbed trial through its
    last stage), the physics ``steps`` of all K, whether trial 0 held through the gate
    (``success``) and how far each trial that ran held (``stages``: one digit per trial, trial 0
    first, :class:`annotator.outcome.Stage` values)."""

    first: R
    held: int
    steps: int
    success: bool = False
    stages: str = ""


def run_k_trials(
    run: Callable[[Perturbation | None], R],
    result_of: Callable[[R], TrialResult],
    k: int,
    robust: RobustConfig,
    seed: int,
    unit: str,
    grasp_id: int,
    gate: Stage = Stage.SHAKEN,
) -> KTrials[R]:
    """Run trial 0 (``run(None)``), then, unless it collided (and ``robust.perturb_collisions`` is
    off), ``k - 1`` trials ``run(p)`` with ``p`` drawn from ``robust``'s ranges by the Generator of
    (``seed``, ``unit``, ``grasp_id``); ``result_of`` reads a :class:`TrialResult` from what
    ``run`` returns. Trial 0 holds when it held through ``gate`` or through every stage it ran;
    a perturbed trial when it held through its last stage. Exceptions propagate (the caller's row
    says ``error``)."""
    first = run(None)
    r = result_of(first)
    success = r.outcome == Outcome.SUCCESS or r.stage >= gate
    held, steps, stages = int(success), r.steps, [r.stage]
    if k > 1 and (r.outcome != Outcome.COLLISION or robust.perturb_collisions):
        rng = trial_rng(seed, unit, grasp_id)
        for _ in range(k - 1):
            p = result_of(run(Perturbation.sample(rng, robust)))
            held += int(p.outcome == Outcome.SUCCESS)
            steps += p.steps
            stages.append(p.stage)
    return KTrials(first, held, steps, bool(success), "".join(str(int(s)) for s in stages))
