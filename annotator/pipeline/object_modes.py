"""The object modes (:mod:`annotator.pipeline.modes`), one small object each: ``floating`` (the
gripper alone around the object), ``cell`` (the object resting on the seed's table in its
placements, the UR3's reachability) and ``resting`` (the object resting on the table in given
orientations). Each builds its world (:class:`ObjectMode`: a PyBullet DIRECT world, the floating
gripper, and the mode's part: the table, the UR3's world) and places an object the worker state
loaded (:meth:`ObjectMode.place`); the placed object makes its candidates and gives each grasp its
trial, the pose to run it at and its row's extra columns. A span of it (:class:`ObjectSpan`) makes
its rows through :func:`annotator.pipeline.simulate.simulate`, the same loop for every mode.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription
from annotator.objects import ObjectError, ObjectModel
from annotator.pipeline import status
from annotator.pipeline.loaded import LoadedObject, object_info
from annotator.pipeline.modes import Labelled
from annotator.pipeline.simulate import TrialSettings, object_candidates, simulate
from annotator.pipeline.tasks import Span, SpanGrasps, SpanTask
from annotator.sampler import Candidates
from annotator.trial import GraspTrial

if TYPE_CHECKING:
    from annotator.pipeline.modes import PlacedObject
    from annotator.pipeline.worker import WorkerState

# The orientation an object rests in when none is given: its mesh frame's own (+z up), xyzw.
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


class ObjectMode:
    """What the object modes share: the world (PyBullet DIRECT, ``config.physics``) with the
    floating gripper, built at once; an object loaded through the worker state's objects
    (:meth:`annotator.pipeline.worker.WorkerState.object_for`) and placed by the mode
    (:meth:`place`); its candidates, sampled once per (seed, N) and kept; a span's grasps."""

    key: tuple = ("object", False, None)

    def __init__(self, config: AnnotatorConfig, gripper: GripperDescription) -> None:
        from annotator.sim.hand import FloatingGripper
        from annotator.sim.world import World

        self.config = config
        self.world = World(config.physics)
        self.hand = FloatingGripper(self.world, config.gripper, gripper)

    def place(self, model: ObjectModel, uid: int) -> PlacedObject:
        """The object (body ``uid`` in the trial world) placed in the mode; ObjectError when it
        cannot be (no stable placement on the table)."""
        raise NotImplementedError

    def load(self, state: WorkerState, task: SpanTask) -> ObjectSpan:
        """The span's object placed in this world and the grasps it simulates; ObjectError."""
        loaded = state.object_for(task, self)
        assert isinstance(task.span, Span)
        return ObjectSpan(self, loaded, self._grasps(task, task.span, loaded))

    def candidates(self, loaded: LoadedObject, seed: int, n: int, config: AnnotatorConfig) -> Candidates:
        """The object's N candidates, sampled once per (seed, N) and kept."""
        cands = loaded.candidates.get((seed, n))
        if cands is None:
            cands = loaded.placed.candidates(loaded.model, n, seed, config, self.hand.gripper.max_width)
            loaded.candidates[(seed, n)] = cands
        return cands

    def _grasps(self, task: SpanTask, span: Span, loaded: LoadedObject) -> SpanGrasps:
        """What the span simulates: its share of the object's sampled candidates, or its given grasps."""
        if span.given is not None:
            g = span.given
            if loaded.placed.mode != "resting" and g.rest_quat is not None:
                raise ObjectError("grasps given with resting orientations, but the run is not --resting")
            return SpanGrasps(
                object_id=span.object_id,
                first_id=span.start,
                T_obj_tcp=g.T_obj_tcp,
                width=g.width,
                quat=g.quat,
                rest_quat=g.rest_quat,
            )
        cands = self.candidates(loaded, task.seed, task.n, task.config)
        placements = None if cands.placement is None else cands.placement[span.start : span.stop]
        return SpanGrasps(
            object_id=span.object_id,
            first_id=span.start,
            T_obj_tcp=cands.T_obj_tcp[span.start : span.stop],
            width=cands.width_expected[span.start : span.stop],
            placements=placements,
        )

    def close(self) -> None:
        """Free the mode's part of the world, then the world."""
        self.world.close()


class ObjectSpan:
    """A span of an object loaded in an object mode: its trials and rows
    (:func:`annotator.pipeline.simulate.simulate`) and, in the cell with ``--views``, its views."""

    def __init__(self, mode: ObjectMode, loaded: LoadedObject, grasps: SpanGrasps) -> None:
        self.mode, self.loaded, self.grasps = mode, loaded, grasps

    def label(self, task: SpanTask) -> Labelled:
        span, loaded, world = task.span, self.loaded, self.mode.world
        assert isinstance(span, Span)
        status.write(task.status_dir, f"simulating {span.object_id}")
        steps0 = world.step_seconds
        run = TrialSettings(
            config=task.config,
            seed=task.seed,
            trials=task.trials,
            gripper=self.mode.hand.description.name,
            # why a collision is one: for given grasps, and wherever a collision's perturbed trials
            # run (its score need not be 0)
            reasons=span.given is not None or (task.trials > 1 and task.config.robust.perturb_collisions),
        )
        rows = simulate(loaded, grasps=self.grasps, run=run)
        artifacts = None
        if task.cell is not None and task.cell.views > 0:
            views, seed = task.cell.views, task.seed
            artifacts = loaded.placed.views(span.start, span.stop, task.n, views, seed, task.status_dir)
        info = {**object_info(loaded.model), **loaded.placed.info()}
        return Labelled(rows, artifacts, info, world.step_seconds - steps0)


# --- floating ---------------------------------------------------------------------------------------


class FloatingMode(ObjectMode):
    """The floating gripper alone: the object at the origin, no gravity, one trial."""

    key = ("object", False, None)

    def place(self, model: ObjectModel, uid: int) -> FloatingObject:
        self.world.set_gravity(False)
        return FloatingObject(GraspTrial(self.world, self.hand, uid, self.config))


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


class CellMode(ObjectMode):
    """``annotate --cell``: the seed's table and the UR3's world (:class:`annotator.cell.batch.
    CellWorlds`); an object settles in its placements."""

    key = ("object", True, None)

    def __init__(self, config: AnnotatorConfig, gripper: GripperDescription) -> None:
        from annotator.cell.batch import CellWorlds

        super().__init__(config, gripper)
        self.worlds = CellWorlds(self.world, self.hand, config)

    def place(self, model: ObjectModel, uid: int) -> CellPlaced:
        return CellPlaced(self.worlds.load(model, uid))

    def close(self) -> None:
        self.worlds.close()
        super().close()


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


class RestingMode(ObjectMode):
    """``evaluate --resting``: the seed's table beside the floating gripper; an object settles in
    each orientation its grasps give. ``grasps``: ``"object"`` (they move with the settling
    object) or ``"table"`` (they stay where given in the table frame)."""

    def __init__(self, config: AnnotatorConfig, gripper: GripperDescription, grasps: str) -> None:
        from annotator.cell.resting import RestingWorld

        super().__init__(config, gripper)
        self.key = ("object", False, grasps)
        self.worlds = RestingWorld(self.world, self.hand, config, grasps)

    def place(self, model: ObjectModel, uid: int) -> RestingPlaced:
        return RestingPlaced(self.worlds.load(model, uid))


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


def build_object_mode(key: tuple, config: AnnotatorConfig, gripper: GripperDescription) -> ObjectMode:
    """The object mode of ``key`` (``("object", cell, resting mode)``, a ``SpanTask``'s mode key)."""
    _, cell, resting = key
    if cell:
        return CellMode(config, gripper)
    if resting:
        return RestingMode(config, gripper, resting)
    return FloatingMode(config, gripper)
