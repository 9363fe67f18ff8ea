"""``annotate``: N candidates sampled per object, labelled with the floating gripper or, with
``--cell``, in the robot cell (the object resting on the seed's table in its placements, the UR3's
reachability, ``--views K`` Kinect views per placement)."""

from __future__ import annotations

from dataclasses import dataclass

from annotator.config import AnnotatorConfig
from annotator.pipeline.execution import UsageError
from annotator.pipeline.modes import CellMode, FloatingMode, Mode
from annotator.pipeline.object_units import ObjectUnitsJob
from annotator.pipeline.options import RunOptions


@dataclass(frozen=True)
class ObjectOptions:
    """``annotate``'s own options: ``cell``: objects rest on the seed's table (UR3 reachability
    columns); ``views``: Kinect views per placement (``--cell`` only); ``mode``: any registered
    mode of objects instead (:data:`annotator.pipeline.modes.REGISTRY`; None: the flags')."""

    cell: bool = False
    views: int = 0
    mode: Mode | None = None

    def chosen(self) -> Mode:
        """The mode the options ask for."""
        if self.mode is not None:
            return self.mode
        return CellMode(self.views) if self.cell else FloatingMode()


class ObjectJob(ObjectUnitsJob):
    """Sampled candidates per object (:class:`ObjectUnitsJob`), floating or in the cell."""

    def __init__(self, config: AnnotatorConfig, own: ObjectOptions | None = None) -> None:
        own = own or ObjectOptions()
        super().__init__(config, mode=own.chosen())
        self.own = own

    def check(self, options: RunOptions) -> None:
        if not self.own.cell and self.own.views:
            raise UsageError("--views renders the robot cell's Kinect: it needs --cell")
        if self.own.views < 0:
            raise UsageError(f"--views must be 0 or more, got {self.own.views}")
        super().check(options)
