"""The modes a unit of work is labelled in, as small frozen records both sides of the pipeline know:
:class:`FloatingMode` (the gripper alone around the object), :class:`CellMode` (the object resting
on the seed's table in its placements, the UR3's reachability, ``views`` Kinect views per
placement), :class:`RestingMode` (the object resting on the table in given orientations) and
:class:`SceneMode` (a cluttered scene, with ``cell`` the arm's reachability too).

A record says what the mode is to everyone but the worker: the mode of its rows
(:data:`annotator.schema.MODES`), what the run's manifest binds of it (so that a folder of one
mode never resumes as another) and what the command line calls it. The worker builds the mode's
strategy (its world, the unit loaded in it, the span's rows) from :attr:`Mode.strategy`, a
``module:Class`` path imported in the worker only: the main process never imports the worker's
code through a mode. Every record is in :data:`REGISTRY`, by name; a new mode is a record
registered with :func:`register` and its strategy (docs/architecture.md, "Adding a mode").
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

# How a resting object's grasps relate to it as it settles: "object", they move with it (the
# default); "table", they stay where they were given in the table frame, as a robot executing them
# in its own frame does when the object comes to rest elsewhere than it was believed to lie.
RESTING_GRASPS = ("object", "table")


@dataclass(frozen=True)
class Mode:
    """A mode of labelling. ``name``: its key in :data:`REGISTRY`; ``rows``: the mode of its rows
    (:data:`annotator.schema.MODES`); ``strategy``: ``module:Class`` of the worker's strategy
    (built with the record, the configuration and the gripper); ``unit``: what its units of work are
    (``object``, ``scene``); ``sampled``: its candidates can be sampled (else given only)."""

    name: ClassVar[str]
    rows: ClassVar[str]
    strategy: ClassVar[str]
    unit: ClassVar[str] = "object"
    sampled: ClassVar[bool] = True

    def row_mode(self) -> str:
        """The mode of its rows (:data:`annotator.schema.MODES`)."""
        return self.rows

    def world(self) -> Hashable:
        """What a worker's world of this mode depends on: a task whose mode gives another rebuilds
        the world (by default the record itself)."""
        return self

    def binds(self) -> dict[str, Any]:
        """What the run's manifest binds of the mode (``RunSpec.inputs``); nothing by default."""
        return {}

    def flags(self) -> str:
        """The mode as the command line asks for it (``--cell --views 2``)."""
        return ""


M = TypeVar("M", bound=type[Mode])

# Every mode, by name.
REGISTRY: dict[str, type[Mode]] = {}


def register(cls: M) -> M:
    """Put a mode's record class in :data:`REGISTRY` (a class decorator); a name is registered once."""
    known = REGISTRY.get(cls.name)
    if known is not None and known is not cls:
        raise ValueError(f"mode {cls.name!r} is registered already ({known.__module__}.{known.__qualname__})")
    REGISTRY[cls.name] = cls
    return cls


@register
@dataclass(frozen=True)
class FloatingMode(Mode):
    """``annotate``: the floating gripper alone, the object at the origin, no gravity. Binds nothing,
    so folders made before the modes existed still resume."""

    name: ClassVar[str] = "floating"
    rows: ClassVar[str] = "object"
    strategy: ClassVar[str] = "annotator.pipeline.object_modes:FloatingLabeller"


@register
@dataclass(frozen=True)
class CellMode(Mode):
    """``annotate --cell``: objects rest on the seed's table in their placements, rows gain the
    UR3's reachability; ``views``: Kinect views per placement (``--views``)."""

    name: ClassVar[str] = "cell"
    rows: ClassVar[str] = "cell"
    strategy: ClassVar[str] = "annotator.pipeline.object_modes:CellLabeller"
    views: int = 0

    def world(self) -> Hashable:
        return CellMode()  # the views do not change the world

    def binds(self) -> dict[str, Any]:
        return {"cell": {"views": int(self.views)}}

    def flags(self) -> str:
        return "--cell" + (f" --views {self.views}" if self.views else "")


@register
@dataclass(frozen=True)
class RestingMode(Mode):
    """``evaluate --resting``: the object rests on the table in each orientation its grasps give;
    ``grasps``: ``"object"``, they move with the settling object, or ``"table"``, they stay where
    given in the table frame (:data:`RESTING_GRASPS`). Given grasps only."""

    name: ClassVar[str] = "resting"
    rows: ClassVar[str] = "resting"
    strategy: ClassVar[str] = "annotator.pipeline.object_modes:RestingLabeller"
    sampled: ClassVar[bool] = False
    grasps: str = "object"

    def __post_init__(self) -> None:
        if self.grasps not in RESTING_GRASPS:
            raise ValueError(f"resting {self.grasps!r}: choose from {', '.join(RESTING_GRASPS)}")

    def binds(self) -> dict[str, Any]:
        # True: "object", as folders made before "table" existed bind it
        return {"resting": True if self.grasps == "object" else self.grasps}

    def flags(self) -> str:
        return "--resting" if self.grasps == "object" else f"--resting-grasps {self.grasps}"


@register
@dataclass(frozen=True)
class SceneMode(Mode):
    """``annotate --scenes``: a cluttered scene per unit; ``cell``: rows gain the UR3's reachability.
    What a scene run binds is its request's (:class:`annotator.pipeline.tasks.SceneRequest`)."""

    name: ClassVar[str] = "scene"
    rows: ClassVar[str] = "scene"
    strategy: ClassVar[str] = "annotator.pipeline.scene_mode:SceneLabeller"
    unit: ClassVar[str] = "scene"
    cell: bool = False

    def row_mode(self) -> str:
        """``scene``, or ``scene_cell`` with the arm's reachability."""
        return "scene_cell" if self.cell else "scene"

    def flags(self) -> str:
        return "--scenes" + (" --cell" if self.cell else "")


# The default mode: what a task or job labels in when it names none.
FLOATING = FloatingMode()


def resting(value: bool | str | None) -> FloatingMode | RestingMode:
    """``--resting`` as a mode: floating for False/None, resting with the grasps moving with the
    object for True, else ``value`` names how the grasps relate to it (:data:`RESTING_GRASPS`)."""
    if value is None or value is False:
        return FloatingMode()
    return RestingMode("object" if value is True else str(value))


def resting_grasps(value: bool | str | None) -> str | None:
    """``--resting`` as the resting grasps (:data:`RESTING_GRASPS`), None when floating."""
    mode = resting(value)
    return mode.grasps if isinstance(mode, RestingMode) else None


def bound_mode(inputs: dict[str, Any] | None) -> Mode:
    """The mode a run's bound inputs (``RunSpec.inputs``, as the manifest keeps them) name: what
    :meth:`Mode.binds` wrote, read back."""
    inputs = inputs or {}
    if "scenes" in inputs:
        return SceneMode(cell=bool(inputs["scenes"].get("cell", False)))
    if "cell" in inputs:
        return CellMode(views=int(inputs["cell"].get("views", 0)))
    if inputs.get("resting") not in (None, False):
        return resting(inputs["resting"])
    return FloatingMode()
