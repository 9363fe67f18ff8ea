"""Simulating given grasps (a network's predictions, labels replayed, real-trial grasps).

A given grasp is a TCP pose in the object's mesh frame and the expected chord ``width`` (m): the
RG2 is placed so that its TCP at that opening is at the pose (the base pose follows from the
model's FK), opened ``2 x pregrasp_clearance`` wider, checked along the approach and closed from
``width + 2 x preclose_gap``, exactly as a sampled candidate whose expected chord is ``width``.

Label rows are replayed from the grasp they record as commanded (``cmd_x`` .. ``cmd_qw``,
``cmd_width``), bit for bit, so a replay is the label's own trial. Labels written before those
columns existed fall back to the label pose (where the pads ended: the object may have moved
during the close) with its width as the chord; a ``collision`` row's width is the open width, so
its chord is that minus ``2 x pregrasp_clearance``.

The trial itself is the job's (:mod:`annotator.pipeline.worker`, in a worker's world, through the
runner's execution: :mod:`annotator.pipeline.in_memory`), so a given grasp and a sampled one are
judged by the same code.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig

if TYPE_CHECKING:
    from annotator.objects import ObjectSource

log = logging.getLogger(__name__)

# The commanded grasp a label records (annotator.pipeline.simulate.simulate).
CMD_COLUMNS = ("cmd_x", "cmd_y", "cmd_z", "cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw", "cmd_width")


@dataclass(frozen=True)
class GivenSpan:
    """Given grasps of one object: ``T_obj_tcp`` (n, 4, 4), ``width`` (n,) m, ``grasp_id`` (n,);
    ``quat`` (n, 4) the rotations bit for bit, or None; ``rest_quat`` (n, 4): the orientation the
    object rests in for each grasp (resting trials; None: upright)."""

    object_id: str
    source: ObjectSource
    scale: float | None
    T_obj_tcp: np.ndarray
    width: np.ndarray
    grasp_id: np.ndarray
    quat: np.ndarray | None = None
    rest_quat: np.ndarray | None = None


def records_commands(rows: pd.DataFrame) -> bool:
    """Do these label rows carry their commanded grasps (all ``cmd_*`` columns, finite)?"""
    if not set(CMD_COLUMNS) <= set(rows.columns):
        return False
    return bool(np.isfinite(rows[list(CMD_COLUMNS)].to_numpy(dtype=np.float64)).all())


def replay_grasps(
    rows: pd.DataFrame, config: AnnotatorConfig, max_width: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """What to simulate to replay label rows: ``(T_obj_tcp (n, 4, 4), width (n,), quat (n, 4) or
    None)``; see the module docstring."""
    from annotator.dataset import poses_as_matrices
    from annotator.geometry import quat_to_matrix

    if records_commands(rows):
        cmd = rows[list(CMD_COLUMNS)].to_numpy(dtype=np.float64)
        T = np.tile(np.eye(4), (len(rows), 1, 1))
        T[:, :3, :3] = quat_to_matrix(cmd[:, 3:7]).reshape(-1, 3, 3)
        T[:, :3, 3] = cmd[:, :3]
        return T, cmd[:, 7].copy(), cmd[:, 3:7].copy()
    width = rows["width"].to_numpy(dtype=np.float64).copy()
    if "outcome" in rows.columns:
        collision = rows["outcome"].astype(str).to_numpy() == "collision"
        width[collision] = np.minimum(width[collision], max_width) - 2 * config.protocol.pregrasp_clearance
    return poses_as_matrices(rows), np.maximum(width, 0.0), None


def given_task(
    span: GivenSpan,
    config: AnnotatorConfig,
    seed: int = 0,
    trials: int = 1,
    gripper=None,
    resting: bool | str | None = False,
):
    """The labelling task (:class:`annotator.pipeline.tasks.SpanTask`) of the given grasps of one
    object: grasps ``0..k-1`` of ``span.object_id`` (a grasp's position in the span keys its
    perturbed trials' generator, :func:`annotator.rng.trial_rng`).

    ``gripper``: the gripper simulated (a description, name or folder; None: the RG2); ``resting``:
    the object rests on the table (:mod:`annotator.cell.resting`) in ``span.rest_quat``, the
    grasps moving with it (True, ``"object"``) or staying in the table frame (``"table"``)."""
    from annotator.pipeline.modes import resting as resting_mode
    from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask

    k = len(span.width)
    rest = None
    if resting:
        rest = np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)) if span.rest_quat is None else np.asarray(span.rest_quat)
    given = GivenGrasps(np.asarray(span.T_obj_tcp), np.asarray(span.width, dtype=np.float64), span.quat, rest)
    return SpanTask(
        span=Span(span.object_id, span.source, span.scale, 0, k, given),
        config=config,
        seed=seed,
        n=k,
        trials=trials,
        gripper=gripper,
        mode=resting_mode(resting),
    )


def given_rows(span: GivenSpan, result) -> tuple[pd.DataFrame | None, str | None]:
    """``(rows, None)`` of a given span's result (a :class:`annotator.pipeline.tasks.SpanResult`, or
    what :func:`annotator.pipeline.in_memory.run_in_memory` says of a task that did not come back),
    ``grasp_id`` from the span; ``(None, reason)`` when the object could not be simulated."""
    error = getattr(result, "error", None)
    if error is not None:
        return None, error
    rows = result.rows
    assert rows is not None  # a span without an error has its rows
    rows["grasp_id"] = np.asarray(span.grasp_id, dtype=np.int64)
    return rows, None


def simulate_given(span: GivenSpan, config: AnnotatorConfig, *args: Any, **kwargs: Any):
    """Label rows (the job's columns) for the given grasps of one object (:func:`given_task`, of
    ``span``, ``config`` and its other arguments), simulated by a worker of the runner's execution
    (:func:`annotator.pipeline.in_memory.run_in_memory`). Returns ``(rows, error)``: rows with
    ``grasp_id`` from the span, or ``(None, reason)`` when the object cannot be loaded."""
    from annotator.pipeline.in_memory import run_in_memory

    (result,) = run_in_memory([given_task(span, config, *args, **kwargs)])
    return given_rows(span, result)
