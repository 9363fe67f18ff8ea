"""The worker's modes, one small object each: ``floating`` (the gripper alone around the object),
``cell`` (the object resting on the seed's table in its placements, the UR3's reachability) and
``resting`` (the object resting on the table in given orientations). A mode builds its part of
the worker's world (:meth:`WorkerMode.build`) and places an object the worker loaded
(:meth:`WorkerMode.place`); the placed object (:class:`PlacedObject`) makes its candidates and
gives each grasp its trial, the pose to run it at and its row's extra columns. The worker state
(:mod:`annotator.pipeline.worker`) and the span's trials (:mod:`annotator.pipeline.simulate`) are
the same for every mode.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import ObjectError, ObjectModel
from annotator.pipeline import status
from annotator.pipeline.simulate import object_candidates
from annotator.sampler import Candidates
from annotator.trial import GraspTrial

if TYPE_CHECKING:
    from annotator.sim.hand import FloatingGripper
    from annotator.sim.world import World

# The orientation an object rests in when none is given: its mesh frame's own (+z up), xyzw.
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


class PlacedObject(Protocol):
    """An object in a mode's world. ``mode``: its rows' mode (:data:`annotator.schema.MODES`)."""

    mode: str

    def candidates(
        self, model: ObjectModel, n: int, seed: int, config: AnnotatorConfig, max_width: float
    ) -> Candidates:
        """The object's N candidates (the same on every worker)."""
        ...

    def trial_for(
        self, T: Transform, placement: int | None, rest: np.ndarray | None
    ) -> tuple[GraspTrial, int]:
        """The trial the grasp ``T`` (object mesh frame) runs in, and its cell placement (0 outside
        the cell); ``placement``: the one it was sampled for (None: given), ``rest``: the
        orientation it rests in (resting only)."""
        ...

    def grasp(self, rest: np.ndarray | None, T: Transform) -> Transform:
        """The pose the trial runs the grasp ``T`` at."""
        ...

    def columns(
        self, placement: int, T: Transform, width: float, grasp_id: int, rest: np.ndarray | None
    ) -> dict[str, Any] | None:
        """The row's columns of the mode (None: none)."""
        ...

    def views(
        self, start: int, stop: int, n: int, views: int, seed: int, status_dir: str | None
    ) -> dict[str, bytes] | None:
        """The files of the Kinect views a span of grasps ``start..stop-1`` (of ``n``) renders."""
        ...

    def info(self) -> dict[str, Any]:
        """What the manifest records of the object placed, beside the object itself."""
        ...

    def release(self) -> None:
        """Free its trials and snapshots (the body in the trial world is the worker's)."""


class WorkerMode(Protocol):
    """A mode of the worker's world: ``key`` identifies it (a change rebuilds the world)."""

    key: tuple

    def place(self, model: ObjectModel, uid: int) -> PlacedObject:
        """The object (body ``uid`` in the trial world) placed in the mode; ObjectError when it
        cannot be (no stable placement on the table)."""
        ...

    def close(self) -> None:
        """Free what the mode added to the world (the world itself is the worker's)."""


# --- floating ---------------------------------------------------------------------------------------


class FloatingMode:
    """The floating gripper alone: the object at the origin, no gravity, one trial."""

    key = (False, None)

    def __init__(self, world: World, hand: FloatingGripper, config: AnnotatorConfig) -> None:
        self.world, self.hand, self.config = world, hand, config

    def place(self, model: ObjectModel, uid: int) -> FloatingObject:
        self.world.set_gravity(False)
        return FloatingObject(GraspTrial(self.world, self.hand, uid, self.config))

    def close(self) -> None:
        pass


class FloatingObject:
    mode = "object"

    def __init__(self, trial: GraspTrial) -> None:
        self.trial = trial

    def candidates(self, model, n, seed, config, max_width) -> Candidates:
        return object_candidates(model, n, seed, config, max_width)

    def trial_for(self, T, placement, rest) -> tuple[GraspTrial, int]:
        return self.trial, 0

    def grasp(self, rest, T: Transform) -> Transform:
        return T

    def columns(self, placement, T, width, grasp_id, rest) -> None:
        return None

    def views(self, start, stop, n, views, seed, status_dir) -> None:
        return None

    def info(self) -> dict[str, Any]:
        return {}

    def release(self) -> None:
        self.trial.close()


# --- the robot cell ---------------------------------------------------------------------------------


class CellMode:
    """``annotate --cell``: the seed's table and the UR3's world (:class:`annotator.cell.batch.
    CellWorlds`); an object settles in its placements."""

    key = (True, None)

    def __init__(self, world: World, hand: FloatingGripper, config: AnnotatorConfig) -> None:
        from annotator.cell.batch import CellWorlds

        self.worlds = CellWorlds(world, hand, config)

    def place(self, model: ObjectModel, uid: int) -> CellPlaced:
        return CellPlaced(self.worlds.load(model, uid))

    def close(self) -> None:
        self.worlds.close()


class CellPlaced:
    """An object in its placements on the table (:class:`annotator.cell.batch.CellObject`)."""

    mode = "cell"

    def __init__(self, cell) -> None:
        self.cell = cell  # annotator.cell.batch.CellObject

    def candidates(self, model, n, seed, config, max_width) -> Candidates:
        return self.cell.candidates(n, seed)  # per placement, knowing the table

    def trial_for(self, T: Transform, placement: int | None, rest) -> tuple[GraspTrial, int]:
        if placement is None:  # a given grasp: where it comes most from above
            placement = self.cell.placement_for(T)
        return self.cell.trials[placement], placement  # else the placement it was sampled for

    def grasp(self, rest, T: Transform) -> Transform:
        return T

    def columns(self, placement: int, T: Transform, width: float, grasp_id: int, rest) -> dict[str, Any]:
        return self.cell.columns(placement, T, width, grasp_id)  # placement, settled pose, reachability

    def views(
        self, start: int, stop: int, n: int, views: int, seed: int, status_dir: str | None
    ) -> dict[str, bytes]:
        """Placement ``p``'s views come with the span holding grasp ``min(p, n - 1)``: exactly one
        span renders each placement, whatever the spans are (the first, unless P > chunk size)."""
        files: dict[str, bytes] = {}
        for p in range(len(self.cell.placements)):
            if start <= min(p, n - 1) < stop:
                status.write(status_dir, f"rendering {self.cell.model.object_id}")
                files.update(self.cell.render_views(p, views, seed))
        return files

    def info(self) -> dict[str, Any]:
        placements = [
            {
                "placement_id": p.placement_id,
                "stable_pose": p.pose_index,
                "probability": float(p.probability),
                "settle_drift": float(p.drift),
            }
            for p in self.cell.placements
        ]
        return {"placements": placements}

    def release(self) -> None:
        self.cell.close()


# --- resting on the table ---------------------------------------------------------------------------


class RestingMode:
    """``evaluate --resting``: the seed's table beside the floating gripper; an object settles in
    each orientation its grasps give. ``grasps``: ``"object"`` (they move with the settling
    object) or ``"table"`` (they stay where given in the table frame)."""

    def __init__(self, world: World, hand: FloatingGripper, config: AnnotatorConfig, grasps: str) -> None:
        from annotator.cell.resting import RestingWorld

        self.key = (False, grasps)
        self.worlds = RestingWorld(world, hand, config, grasps)

    def place(self, model: ObjectModel, uid: int) -> RestingPlaced:
        return RestingPlaced(self.worlds.load(model, uid))

    def close(self) -> None:
        pass


class RestingPlaced:
    """An object resting on the table (:class:`annotator.cell.resting.RestingObject`)."""

    mode = "resting"

    def __init__(self, resting) -> None:
        self.resting = resting  # annotator.cell.resting.RestingObject

    def candidates(self, model, n, seed, config, max_width) -> Candidates:
        raise ObjectError("--resting simulates given grasps only")

    def trial_for(self, T, placement, rest: np.ndarray | None) -> tuple[GraspTrial, int]:
        return self.resting.trial_for(UPRIGHT if rest is None else rest)[0], 0

    def grasp(self, rest: np.ndarray | None, T: Transform) -> Transform:
        return self.resting.grasp(UPRIGHT if rest is None else rest, T)

    def columns(self, placement, T, width, grasp_id, rest: np.ndarray | None) -> dict[str, Any]:
        return self.resting.columns(UPRIGHT if rest is None else rest)  # the settled pose on the table

    def views(self, start, stop, n, views, seed, status_dir) -> None:
        return None

    def info(self) -> dict[str, Any]:
        return {}

    def release(self) -> None:
        self.resting.close()


def build_mode(key: tuple, world: World, hand: FloatingGripper, config: AnnotatorConfig) -> WorkerMode:
    """The mode of ``key`` (``(cell, resting mode)`` of a task) built in the worker's world."""
    cell, resting = key
    if cell:
        return CellMode(world, hand, config)
    if resting:
        return RestingMode(world, hand, config, resting)
    return FloatingMode(world, hand, config)
