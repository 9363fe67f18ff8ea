"""The learned policy: vision-sampled candidates scored by the model, best first.

``annotator clutter-removal --policy learned --policy-arg model=model.npz`` (or ``--policy
annotator.learn.policy:learned``; without ``model=`` the path in the environment variable
``RG2_LEARNED_MODEL``). At every attempt: up to ``candidates`` grasps of
:func:`annotator.policies.vision.sample_grasps` (antipodal pairs on the observed cloud that the
open gripper clears; SEEDS first contacts drawn, three times vision-random's, since a pile's views
give only ~3-30 clear grasps of 600 and the model can only choose among what it is given), each
scored by the model's probability of a hold (:mod:`annotator.learn.model`) from its features
(:mod:`annotator.learn.features`); the arm takes the best-scored one it reaches. The model is
trained on such candidates too (:mod:`annotator.learn.candidates`).
"""

from __future__ import annotations

import os

from annotator.learn.features import grasp_features
from annotator.learn.model import Model, load_model
from annotator.policies.records import Grasps, Observation, PolicyError
from annotator.policies.vision import observed_surface, sample_grasps
from annotator.rng import keyed_rng

MODEL_ENV = "RG2_LEARNED_MODEL"
CANDIDATES = 100  # vision candidates scored per attempt at most
SEEDS = 1800  # first contacts drawn per attempt (module docstring)


def learned_model(model: str | None = None) -> Model:
    """The model the learned policy scores with: at ``model``, else at ``$RG2_LEARNED_MODEL``;
    PolicyError (one line) when none is given or the file is not a whole model (the clutter-removal
    command checks it before any work)."""
    path = model or os.environ.get(MODEL_ENV)
    if not path:
        raise PolicyError(f"the learned policy needs its model: --policy-arg model=PATH (or {MODEL_ENV})")
    try:
        return load_model(str(path))
    except ValueError as exc:
        raise PolicyError(str(exc)) from None


def learned(observation: Observation, model: str | None = None, candidates: str | int = CANDIDATES) -> Grasps:
    """Score up to ``candidates`` vision candidates with the model at ``model`` (module docstring)."""
    fitted = learned_model(model)
    rng = keyed_rng("learned", observation.seed, observation.round_id, observation.attempt)
    surface = observed_surface(observation)
    grasps = sample_grasps(observation, rng, seeds=SEEDS, limit=int(candidates), surface=surface)
    if not len(grasps):
        return grasps
    score = fitted.probability(grasp_features(surface, grasps.T_table_tcp, grasps.width))
    return Grasps(grasps.T_table_tcp, grasps.width, score)
