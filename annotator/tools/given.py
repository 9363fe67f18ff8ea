"""Simulating grasps that are given (a network's predictions, labels replayed, real-trial grasps).

A given grasp is a TCP pose in the object's mesh frame and an opening ``width`` (m), as in the
labels: the RG2 is placed so that its TCP at that opening is at the pose (the base pose follows
from the model's FK), opened ``2 x pregrasp_clearance`` wider, checked along the approach and
closed from ``width + 2 x preclose_gap``, exactly as a sampled candidate whose expected chord is
``width``. For a ``collision`` label the width stored is the open width, so its chord is that
minus ``2 x pregrasp_clearance`` (:func:`chord_width`).

The trial itself is the job's (:mod:`annotator.pipeline.worker`, in a worker's world), so a given
grasp and a sampled one are judged by the same code.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GivenSpan:
    """Given grasps of one object: ``T_obj_tcp`` (n, 4, 4), ``width`` (n,) m, ``grasp_id`` (n,)."""

    object_id: str
    source: object  # an annotator.objects.ObjectSource
    scale: float | None
    T_obj_tcp: np.ndarray
    width: np.ndarray
    grasp_id: np.ndarray


def chord_width(labels: pd.DataFrame, config: AnnotatorConfig, max_width: float) -> np.ndarray:
    """The expected chord of each label row to replay it: its ``width``, except for collisions,
    whose stored width is the open width ``min(max_width, chord + 2 x clearance)``."""
    width = labels["width"].to_numpy(dtype=np.float64).copy()
    collision = labels["outcome"].to_numpy() == "collision"
    width[collision] = np.minimum(width[collision], max_width) - 2 * config.protocol.pregrasp_clearance
    return np.maximum(width, 0.0)


def simulate_given(span: GivenSpan, config: AnnotatorConfig, seed: int = 0, trials: int = 1):
    """Label rows (the job's columns) for the given grasps of one object; runs in a worker.

    Returns ``(rows, error)``: rows with ``grasp_id`` from the span, or ``(None, reason)`` when the
    object cannot be loaded. The worker's world is the job's (:mod:`annotator.pipeline.worker`).
    """
    from annotator.pipeline.worker import GivenGrasps, Span, SpanTask, label_span

    k = len(span.width)
    given = GivenGrasps(np.asarray(span.T_obj_tcp), np.asarray(span.width, dtype=np.float64))
    task = SpanTask(Span(span.object_id, span.source, span.scale, 0, k, given), config, seed, k, trials)
    result = label_span(task)
    if result.error is not None:
        return None, result.error
    rows = result.rows
    rows["grasp_id"] = np.asarray(span.grasp_id, dtype=np.int64)
    return rows, None
