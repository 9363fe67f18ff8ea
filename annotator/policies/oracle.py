"""The policies that see the true scene (its meshes and poses): ``labels`` and ``random``.

- ``labels`` (an oracle: the best a learner of the labels can do): the scene is labelled on the fly
  among its neighbours (:mod:`annotator.scenes.labels`, the floating gripper, candidates drawn anew
  per attempt) and the best-scored success the arm can reach is executed (ties: the lowest grasp
  id). Candidates are labelled in grasp-id order and the search stops at the first reachable
  success whose score is the highest possible, which picks the same grasp as labelling all of them;
  120 more are drawn (up to 5 x 120) while none is found.
- ``random`` (a baseline): the same candidates, antipodal ones only, in a random order; the first
  that the kinematic check lets through (no gripper collision with anything, along the approach or
  closed) and the arm can reach is executed. No physics decides it.

Each is a :data:`RoundPolicy`: called with the round (:class:`annotator.policies.round_world.Round`), the
attempt's index and the set of what it tried (its own bookkeeping), it returns a
:class:`annotator.policies.records.Proposal` or None.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from annotator.geometry import Transform
from annotator.policies.records import Proposal
from annotator.rng import keyed_rng
from annotator.scenes.labels import SceneCandidates, SceneTrials, label_scene
from annotator.scenes.records import SceneRecord

if TYPE_CHECKING:
    from annotator.policies.round_world import Round

# Candidates drawn per look of the ``labels`` and ``random`` policies at the scene as it is (VGN's
# 120 per scene), labelled in batches of 20 before the search may stop, and drawn anew up to
# POLICY_DRAWS times while none is found: on a pile the cell's sampler gives some objects (a mug, a
# bowl upside down) few grasps that miss the object itself, and 120 left graspable objects behind.
POLICY_CANDIDATES = 120
POLICY_BATCH = 20
POLICY_DRAWS = 5

RoundPolicy = Callable[["Round", int, set[int]], Proposal | None]


def _trials(round_: Round, now: SceneRecord) -> SceneTrials:
    return SceneTrials(now, round_.models, round_.config, round_.gripper)


def labels_policy(seed: int, trials_per_grasp: int = 1) -> RoundPolicy:
    """The ``labels`` policy (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        now = round_.now()
        trials = _trials(round_, now)
        best: Proposal | None = None
        try:
            for draw in range(POLICY_DRAWS):
                cands = trials.candidates(POLICY_CANDIDATES, seed, attempt=attempt, draw=draw)
                best = _best_reachable(round_, now, trials, cands, (seed, trials_per_grasp), best)
                if best is not None:
                    break
        finally:
            trials.close()
        return best

    return propose


def _best_reachable(
    round_: Round,
    now: SceneRecord,
    trials: SceneTrials,
    cands: SceneCandidates,
    labelling: tuple[int, int],
    best: Proposal | None,
) -> Proposal | None:
    """The best-scored reachable success of ``cands`` (or ``best`` if none beats it), labelled in
    batches (``labelling``: seed, trials per grasp) until one has the highest possible score."""
    seed, k = labelling
    for start in range(0, len(cands), POLICY_BATCH):
        rows = label_scene(trials, cands, start, min(len(cands), start + POLICY_BATCH), seed, k)
        held = rows[rows["success"]].sort_values(["score", "grasp_id"], ascending=[False, True])
        for row in held.itertuples():
            if best is not None and row.score <= best.score:
                break
            proposal = _reachable(round_, now, row)
            if proposal is not None:
                best = proposal
                break
        if best is not None and best.score >= 1.0:
            return best
    return best


def _reachable(round_: Round, now: SceneRecord, row) -> Proposal | None:
    """The label ``row`` (its commanded grasp) as a proposal, if the arm reaches it."""
    inst = now.instance(int(row.instance_id))
    T_obj_tcp = Transform.exact(
        [row.cmd_x, row.cmd_y, row.cmd_z], [row.cmd_qx, row.cmd_qy, row.cmd_qz, row.cmd_qw]
    )
    assert inst.T_table_obj is not None
    T_table_tcp = inst.T_table_obj * T_obj_tcp
    reach = round_.reach(T_table_tcp, float(row.cmd_width), inst.instance_id)
    if not reach.reachable:
        return None
    return Proposal(inst.instance_id, T_table_tcp, float(row.cmd_width), float(row.score), reach)


def random_policy(seed: int) -> RoundPolicy:
    """The random antipodal baseline (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        now = round_.now()
        trials = _trials(round_, now)
        try:
            for draw in range(POLICY_DRAWS):
                cands = trials.candidates(POLICY_CANDIDATES, seed, attempt=attempt, draw=draw)
                order = keyed_rng("clutter-random", int(seed), now.scene_id, attempt, draw).permutation(
                    len(cands)
                )
                proposal = _first_free(round_, now, trials, cands, order)
                if proposal is not None:
                    return proposal
        finally:
            trials.close()
        return None

    return propose


def _first_free(
    round_: Round, now: SceneRecord, trials: SceneTrials, cands: SceneCandidates, order: np.ndarray
) -> Proposal | None:
    """The first antipodal candidate in ``order`` that the kinematic check lets through (the scene as
    it is) and the arm reaches."""
    for k in order:
        if not cands.antipodal[k]:
            continue
        instance_id = int(cands.instance_id[k])
        T_obj_tcp = Transform.from_matrix(cands.T_obj_tcp[k])
        width = float(cands.width_expected[k])
        trials.reset()
        if trials.trials[instance_id].collides(T_obj_tcp, width).collided:
            continue
        inst = now.instance(instance_id)
        assert inst.T_table_obj is not None
        T_table_tcp = inst.T_table_obj * T_obj_tcp
        reach = round_.reach(T_table_tcp, width, instance_id)
        if reach.reachable:
            return Proposal(instance_id, T_table_tcp, width, 0.0, reach)
    return None
