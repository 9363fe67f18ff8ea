"""``annotate``: N candidates sampled per object, labelled with the floating gripper or, with
``--cell``, in the robot cell (the object resting on the seed's table in its placements, the UR3's
reachability, ``--views K`` Kinect views per placement)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from annotator.config import AnnotatorConfig
from annotator.pipeline.execution import UsageError
from annotator.pipeline.object_units import ObjectUnitsJob
from annotator.pipeline.options import RunOptions
from annotator.pipeline.tasks import CellOptions


@dataclass(frozen=True)
class ObjectOptions:
    """``annotate``'s own options: ``cell``: objects rest on the seed's table (UR3 reachability
    columns); ``views``: Kinect views per placement (``--cell`` only)."""

    cell: bool = False
    views: int = 0


class ObjectJob(ObjectUnitsJob):
    """Sampled candidates per object (:class:`ObjectUnitsJob`), floating or in the cell."""

    def __init__(self, config: AnnotatorConfig, own: ObjectOptions | None = None) -> None:
        own = own or ObjectOptions()
        super().__init__(config, cell=CellOptions(own.views) if own.cell else None)
        self.own = own

    def check(self, options: RunOptions) -> None:
        if not self.own.cell and self.own.views:
            raise UsageError("--views renders the robot cell's Kinect: it needs --cell")
        if self.own.views < 0:
            raise UsageError(f"--views must be 0 or more, got {self.own.views}")
        super().check(options)

    def inputs(self) -> dict[str, Any]:
        inputs = super().inputs()
        if self.cell is not None:
            inputs["cell"] = self.cell.to_json()
        return inputs
