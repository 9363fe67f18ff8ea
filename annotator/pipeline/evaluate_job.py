"""``annotator evaluate``: given grasps per object (a learner's predictions, hand-picked poses, a
label table replayed) simulated with the floating gripper or, with ``--resting``, on the object
resting on the table; the same resume, determinism and workers as ``annotate``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from annotator.config import AnnotatorConfig
from annotator.pipeline.object_units import ObjectUnitsJob
from annotator.pipeline.source import GivenCandidates


@dataclass(frozen=True)
class EvaluateOptions:
    """``evaluate``'s own options: the ``candidates`` given (:func:`annotator.tools.evaluate.
    given_candidates`) and ``resting``: False (floating), True or ``"object"`` (resting on the
    table, the grasps move with the settling object) or ``"table"`` (they stay in the table
    frame)."""

    candidates: GivenCandidates
    resting: bool | str = False


class EvaluateJob(ObjectUnitsJob):
    """Given grasps per object (:class:`ObjectUnitsJob`), floating or resting."""

    def __init__(self, config: AnnotatorConfig, own: EvaluateOptions) -> None:
        super().__init__(config, own.candidates, resting=own.resting)

    def inputs(self) -> dict[str, Any]:
        inputs = super().inputs()
        if self.resting:
            from annotator.cell.resting import resting_mode

            mode = resting_mode(self.resting)
            inputs["resting"] = True if mode == "object" else mode  # True: as folders before "table" existed
        return inputs
