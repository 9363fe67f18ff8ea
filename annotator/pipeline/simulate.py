"""The trials of a span and its label rows: each grasp runs in the trial of its mode (floating, a
cell placement, resting on the table), trial 0 unperturbed and K-1 perturbed, and becomes one row
(:func:`annotator.label_row.label_row`). :func:`simulate` takes what the span is
(:class:`annotator.pipeline.tasks.SpanGrasps`) and the run's settings (:class:`TrialSettings`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from annotator.confidence import mapping_of, trials_mismatch
from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.geometry import Transform, matrix_to_quat
from annotator.grippers import DEFAULT_GRIPPER
from annotator.k_trials import run_k_trials
from annotator.label_row import TrialsResult, label_row
from annotator.objects import ObjectModel
from annotator.pipeline.tasks import SpanGrasps
from annotator.rng import object_rng
from annotator.sampler import sample_candidates
from annotator.schema import REASON_COLUMNS  # noqa: F401  (named in the docstring; the workers' import)
from annotator.trial import CollisionCheck, GraspTrial

if TYPE_CHECKING:
    from annotator.pipeline.loaded import LoadedObject

log = logging.getLogger(__name__)


def object_candidates(model: ObjectModel, n: int, seed: int, config: AnnotatorConfig, max_width: float):
    """The object's N candidates: the same for every worker (Generator keyed on seed and id)."""
    return sample_candidates(model.mesh, n, object_rng(seed, model.object_id), config.sampler, max_width)


@dataclass(frozen=True, kw_only=True)
class TrialSettings:
    """The run's settings every trial of a span shares: the ``config``, the run's ``seed``,
    ``trials`` per grasp (trial 0 unperturbed), the ``gripper``'s name written in every row's
    ``gripper`` column, and ``reasons``: each row also says why a ``collision`` is one
    (:data:`REASON_COLUMNS`; given grasps only: sampled labels keep their columns)."""

    config: AnnotatorConfig
    seed: int
    trials: int
    gripper: str = DEFAULT_GRIPPER
    reasons: bool = False


def simulate(loaded: LoadedObject, *, grasps: SpanGrasps, run: TrialSettings) -> pd.DataFrame:
    """Label rows of the span's ``grasps`` (:class:`annotator.pipeline.tasks.SpanGrasps`): poses
    ``T_obj_tcp`` (k, 4, 4) in the object's mesh frame with expected chords ``width`` (k,) in m,
    numbered from ``first_id``; ``quat`` (k, 4) xyzw: their rotations bit for bit (see
    :class:`GivenGrasps`); ``placements`` (k,): in the cell, the placement each was sampled for
    (None: the placement where it approaches most from above,
    :meth:`annotator.cell.batch.CellObject.placement_for`); ``rest_quat`` (k, 4): resting, the
    orientation each grasp's object rests in (None: upright). ``run``: the run's settings
    (:class:`TrialSettings`). The object ``placed`` in the worker's mode
    (:mod:`annotator.pipeline.modes`) gives each grasp its trial, the pose to run it at and the
    row's columns of the mode.

    Trial 0 of each candidate is unperturbed and gives ``success``, ``outcome``, ``width`` and the
    pose; trials 1..K-1 are perturbed from the candidate's own Generator (``trial_rng``) and
    ``score`` is the fraction of all K trials that held. A candidate whose unperturbed pose
    collides is never simulated: its score is 0 and no perturbed trial runs (the pose as given
    cannot be executed), unless ``[robust] perturb_collisions``: then its perturbed trials run, as
    a real execution of it may miss the object where it really lies.
    """
    config, seed, trials, gripper = run.config, run.seed, run.trials, run.gripper
    object_id, first_id, T_obj_tcp, widths = grasps.object_id, grasps.first_id, grasps.T_obj_tcp, grasps.width
    quats, placements, rest_quats = grasps.quat, grasps.placements, grasps.rest_quat
    model = loaded.model
    mapping = mapping_of(config.confidence)  # a calibration: rows carry p_success
    mismatch = trials_mismatch(config, trials)  # the commands refuse it first; a worker never maps
    if mismatch is not None:
        raise ValueError(f"[confidence]: {mismatch}")
    rows = []
    # the rotations of all poses in one batch: row for row the floats of Transform.from_matrix
    sampled_quats = (
        matrix_to_quat(np.asarray(T_obj_tcp)[:, :3, :3]) if quats is None and len(widths) else None
    )
    placed = loaded.placed
    for k in range(len(widths)):
        grasp_id = first_id + k
        if sampled_quats is not None:
            T = Transform(T_obj_tcp[k][:3, 3], sampled_quats[k])
        else:  # a recorded commanded pose: the very transform of the trial that recorded it
            assert quats is not None
            T = Transform.exact(T_obj_tcp[k][:3, 3], quats[k])
        width_expected = float(widths[k])
        rest = None if rest_quats is None else rest_quats[k]
        trial, placement = placed.trial_for(T, None if placements is None else int(placements[k]), rest)
        run_T = placed.grasp(rest, T)
        result = _run_trials(trial, run_T, width_expected, seed, trials, object_id, grasp_id)
        rows.append(
            label_row(
                placed.mode,
                object_id=object_id,
                grasp_id=grasp_id,
                result=result,
                trials=trials,
                T_cmd=T,
                cmd_width=width_expected,
                model=model,
                seed=seed,
                gripper=gripper,
                extra=placed.columns(placement, T, width_expected, grasp_id, rest),
                reasons=_reasons(result.check, trial) if run.reasons else None,
                p_success=None if mapping is None else float(mapping.p_success(result.held / trials)),
            )
        )
    return pd.DataFrame(rows)


def _reasons(check: CollisionCheck | None, trial: GraspTrial) -> dict[str, str]:
    """The :data:`REASON_COLUMNS` of one row from trial 0's kinematic check (None after an error)."""
    if check is None or not check.collided:
        return {"collided_with": "", "collision_stage": ""}
    hit = "object" if check.hit == trial.obj else "table" if check.hit in trial.obstacles else "other"
    return {"collided_with": hit, "collision_stage": check.stage or ""}


def _run_trials(
    trial: GraspTrial,
    T: Transform,
    width_expected: float,
    seed: int,
    trials: int,
    object_id: str,
    grasp_id: int,
) -> TrialsResult:
    """Trial 0 unperturbed, then the perturbed ones (none after a collision); a physics failure is
    an ``error`` row, never the loss of the other candidates."""
    try:
        k = run_k_trials(
            lambda p: trial.run(T, width_expected, p),
            lambda r: r,
            trials,
            trial.robust,
            seed,
            object_id,
            grasp_id,
            trial.gate,
        )
        r = k.first
        return TrialsResult(
            r.outcome, r.T_obj_tcp, r.width, k.steps, r.slip, k.held, r.check, k.success, k.stages
        )
    except Exception as exc:  # a physics failure on one candidate must not lose the others
        log.warning("%s grasp %d: %s: %s", object_id, grasp_id, type(exc).__name__, exc)
        return TrialsResult(Outcome.ERROR, T, width_expected, 0, np.nan, 0)
