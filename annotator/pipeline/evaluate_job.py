"""``annotator evaluate``: given grasps per object (a learner's predictions, hand-picked poses, a
label table replayed) simulated with the floating gripper or, with ``--resting``, on the object
resting on the table; the same resume, determinism and workers as ``annotate``."""

from __future__ import annotations

from dataclasses import dataclass

from annotator.config import AnnotatorConfig
from annotator.pipeline.modes import FloatingMode, Mode
from annotator.pipeline.object_units import ObjectUnitsJob
from annotator.pipeline.source import GivenCandidates


@dataclass(frozen=True)
class EvaluateOptions:
    """``evaluate``'s own options: the ``candidates`` given (:func:`annotator.tools.evaluate.
    given_candidates`) and the ``mode`` they are simulated in (:mod:`annotator.pipeline.modes`:
    floating, or resting on the table with the grasps moving with the settling object or staying
    in the table frame)."""

    candidates: GivenCandidates
    mode: Mode = FloatingMode()


class EvaluateJob(ObjectUnitsJob):
    """Given grasps per object (:class:`ObjectUnitsJob`), floating or resting."""

    def __init__(self, config: AnnotatorConfig, own: EvaluateOptions) -> None:
        super().__init__(config, own.candidates, mode=own.mode)
