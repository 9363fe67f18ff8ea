"""The object modes' strategies (:mod:`annotator.pipeline.strategies`), one small class each:
floating (the gripper alone around the object), the cell (the object resting on the seed's table in
its placements, the UR3's reachability, Kinect views) and resting (the object resting on the table
in given orientations). Each builds its world (:class:`ObjectLabeller`: a PyBullet DIRECT world,
the floating gripper, and the mode's part: the table, the UR3's world), places an object the
worker's object cache loaded (:meth:`ObjectLabeller.place`), and the placed object sets each grasp
up (:class:`annotator.pipeline.loaded.PlacedObject`). A span of it (:class:`ObjectSpan`) makes its
rows through :func:`annotator.pipeline.simulate.simulate`, the same loop for every mode.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription
from annotator.objects import ObjectError, ObjectModel, create_body, physics_for
from annotator.pipeline import status
from annotator.pipeline.loaded import GraspSetup, LoadedObject, PlacedObject, model_record
from annotator.pipeline.modes import CellMode, Mode, RestingMode
from annotator.pipeline.object_cache import ObjectCache
from annotator.pipeline.simulate import TrialSettings, object_candidates, simulate
from annotator.pipeline.strategies import Labelled
from annotator.pipeline.tasks import Span, SpanGrasps, SpanTask
from annotator.sampler import Candidates
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial

# The orientation an object rests in when none is given: its mesh frame's own (+z up), xyzw.
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])
# Where the floating gripper waits while no trial runs: 2 m above the object's mesh frame.
PARKED = Transform([0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0])


class ObjectLabeller:
    """What the object modes share: the world (PyBullet DIRECT, ``config.physics``) with the
    floating gripper, built at once; the object of a span taken from the worker's object cache,
    its body created in the world once and placed by the mode (:meth:`place`); its candidates,
    sampled once per (seed, N) and kept with it; a span's grasps, its views and what the manifest
    records of it."""

    def __init__(self, mode: Mode, config: AnnotatorConfig, gripper: GripperDescription) -> None:
        self.mode = mode
        self.world_key: Hashable = mode.world()
        self.config = config
        self.world = World(config.physics)
        self.hand = FloatingGripper(self.world, config.gripper, gripper)
        self.worlds: Any = self.part()  # the mode's part of the world (the table, the arm's world)
        self.current: LoadedObject | None = None
        # objects that cannot be placed in this mode (no stable placement): key -> the error
        self.failed: dict[tuple[Hashable, ...], str] = {}

    # --- what a mode gives ------------------------------------------------------------------------

    def part(self) -> Any:
        """The mode's part of the world beside the floating gripper (None: none)."""
        return None

    def place(self, model: ObjectModel, uid: int) -> PlacedObject:
        """The object (body ``uid`` in the trial world) placed in the mode; ObjectError when it
        cannot be (no stable placement on the table)."""
        raise NotImplementedError

    def sample(self, loaded: LoadedObject, n: int, seed: int) -> Candidates:
        """The object's N candidates (the same on every worker); ObjectError for a mode of given
        grasps only."""
        raise ObjectError(f"{self.mode.flags()} simulates given grasps only")

    def artifacts(self, loaded: LoadedObject, task: SpanTask) -> dict[str, bytes] | None:
        """The files a span renders beside its rows (None: none)."""
        return None

    def info(self, loaded: LoadedObject) -> dict[str, Any]:
        """What the manifest records of the object placed, beside the object itself."""
        return {}

    # --- the span's object --------------------------------------------------------------------

    def load(self, objects: ObjectCache, task: SpanTask) -> ObjectSpan:
        """The span's object placed in this world and the grasps it simulates; ObjectError."""
        loaded = self.object_for(objects, task)
        assert isinstance(task.span, Span)
        return ObjectSpan(self, loaded, self._grasps(objects, task, task.span, loaded))

    def object_for(self, objects: ObjectCache, task: SpanTask) -> LoadedObject:
        """The task's object placed in this world (its body is created once per object); ObjectError."""
        unit = task.span
        key = objects.key(unit.source, task.source_sha256, unit.scale, task.config.objects)
        if key in self.failed:
            raise ObjectError(self.failed[key])
        if self.current is not None and self.current.key == key:
            return self.current
        got = objects.of(task)
        if self.current is not None:
            self.current.placed.release()
            self.world.remove_body(self.current.uid)
            self.current = None
        self.current = self._create(got.model, key, got.candidates)
        return self.current

    def _create(
        self, model: ObjectModel, key: tuple[Hashable, ...], candidates: dict[Hashable, Candidates]
    ) -> LoadedObject:
        """The object's body in the world, placed in the mode (its trial, or its placements)."""
        world, hand = self.world, self.hand
        physics = physics_for(model, self.config.physics)  # a light object needs a finer time step
        if world.physics != physics:
            world.physics = physics
            world.configure()
        hand.teleport(PARKED, hand.gripper.max_width)
        uid = create_body(world.client, model)
        try:
            placed = self.place(model, uid)
        except ObjectError as exc:  # no stable placement on the table
            world.remove_body(uid)
            self.failed[key] = str(exc)
            raise
        except BaseException:
            world.remove_body(uid)
            raise
        return LoadedObject(key, model, uid, placed, candidates)

    def _grasps(self, objects: ObjectCache, task: SpanTask, span: Span, loaded: LoadedObject) -> SpanGrasps:
        """What the span simulates: its share of the object's sampled candidates, or its given grasps."""
        if span.given is not None:
            g = span.given
            if not isinstance(self.mode, RestingMode) and g.rest_quat is not None:
                raise ObjectError("grasps given with resting orientations, but the run is not --resting")
            return SpanGrasps(
                object_id=span.object_id,
                first_id=span.start,
                T_obj_tcp=g.T_obj_tcp,
                width=g.width,
                quat=g.quat,
                rest_quat=g.rest_quat,
            )
        config = task.config
        # what the candidates depend on besides seed and N: a calibration grid, which changes the
        # gripper's or the protocol's numbers from task to task, keeps them
        on = (config.sampler, config.cell, self.hand.description.key, self.world_key, task.seed, task.n)
        cands = loaded.candidates.get(on)
        if cands is None:
            cands = loaded.candidates[on] = self.sample(loaded, task.n, task.seed)
            objects.measure(loaded.key)
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
        self.current = None
        if self.worlds is not None:
            self.worlds.close()
        self.world.close()


class ObjectSpan:
    """A span of an object loaded in an object mode: its trials and rows
    (:func:`annotator.pipeline.simulate.simulate`), and the files the mode renders with them."""

    def __init__(self, labeller: ObjectLabeller, loaded: LoadedObject, grasps: SpanGrasps) -> None:
        self.labeller, self.loaded, self.grasps = labeller, loaded, grasps

    def label(self, task: SpanTask) -> Labelled:
        span, loaded, world = task.span, self.loaded, self.labeller.world
        assert isinstance(span, Span)
        status.write(task.status_dir, f"simulating {span.object_id}")
        steps0 = world.step_seconds
        run = TrialSettings(
            config=task.config,
            seed=task.seed,
            trials=task.trials,
            gripper=self.labeller.hand.description.name,
            mode=task.mode.row_mode(),
            # why a collision is one: for given grasps, and wherever a collision's perturbed trials
            # run (its score need not be 0)
            reasons=span.given is not None or (task.trials > 1 and task.config.robust.perturb_collisions),
        )
        rows = simulate(loaded, grasps=self.grasps, run=run)
        artifacts = self.labeller.artifacts(loaded, task)
        info = {**model_record(loaded.model), **self.labeller.info(loaded)}
        return Labelled(rows, artifacts, info, world.step_seconds - steps0)


# --- floating ---------------------------------------------------------------------------------------


class FloatingLabeller(ObjectLabeller):
    """:class:`annotator.pipeline.modes.FloatingMode`: the object at the origin, no gravity, one trial."""

    def place(self, model: ObjectModel, uid: int) -> FloatingObject:
        self.world.set_gravity(False)
        return FloatingObject(GraspTrial(self.world, self.hand, uid, self.config))

    def sample(self, loaded: LoadedObject, n: int, seed: int) -> Candidates:
        return object_candidates(loaded.model, n, seed, self.config, self.hand.gripper.max_width)


class FloatingObject:
    """An object floating at the origin: every grasp in its one trial, as given."""

    def __init__(self, trial: GraspTrial) -> None:
        self.trial = trial

    def setup(
        self, T: Transform, width: float, grasp_id: int, placement: int | None, rest: np.ndarray | None
    ) -> GraspSetup:
        return GraspSetup(self.trial, T)

    def release(self) -> None:
        self.trial.close()


# --- the robot cell ---------------------------------------------------------------------------------


class CellLabeller(ObjectLabeller):
    """:class:`annotator.pipeline.modes.CellMode`: the seed's table and the UR3's world
    (:class:`annotator.cell.batch.CellWorlds`); an object settles in its placements."""

    def part(self) -> Any:
        from annotator.cell.batch import CellWorlds

        return CellWorlds(self.world, self.hand, self.config)

    def place(self, model: ObjectModel, uid: int) -> CellPlaced:
        return CellPlaced(self.worlds.load(model, uid))

    def sample(self, loaded: LoadedObject, n: int, seed: int) -> Candidates:
        assert isinstance(loaded.placed, CellPlaced)
        return loaded.placed.on.candidates(n, seed)  # per placement, knowing the table

    def artifacts(self, loaded: LoadedObject, task: SpanTask) -> dict[str, bytes] | None:
        """With ``views``, placement ``p``'s views come with the span holding grasp ``min(p, n - 1)``:
        exactly one span renders each placement, whatever the spans are (the first, unless P > chunk
        size)."""
        mode = task.mode
        assert isinstance(mode, CellMode) and isinstance(loaded.placed, CellPlaced)
        span = task.span
        assert isinstance(span, Span)  # a decomposition task's first span is labelled as a span
        if mode.views <= 0:
            return None
        cell = loaded.placed.on
        files: dict[str, bytes] = {}
        for p in range(len(cell.placements)):
            if span.start <= min(p, task.n - 1) < span.stop:
                status.write(task.status_dir, f"rendering {cell.model.object_id}")
                files.update(cell.render_views(p, mode.views, task.seed))
        return files

    def info(self, loaded: LoadedObject) -> dict[str, Any]:
        assert isinstance(loaded.placed, CellPlaced)
        placements = [
            {
                "placement_id": p.placement_id,
                "stable_pose": p.pose_index,
                "probability": float(p.probability),
                "settle_drift": float(p.drift),
            }
            for p in loaded.placed.on.placements
        ]
        return {"placements": placements}


class PlacedOnPart:
    """An object placed by the mode's part of the world: ``on``, what the part made of it (its
    trials and snapshots), freed with it."""

    def __init__(self, on: Any) -> None:
        self.on = on

    def release(self) -> None:
        self.on.close()


class CellPlaced(PlacedOnPart):
    """An object in its placements on the table (``on``: :class:`annotator.cell.batch.CellObject`)."""

    def setup(
        self, T: Transform, width: float, grasp_id: int, placement: int | None, rest: np.ndarray | None
    ) -> GraspSetup:
        # a given grasp: where it comes most from above; else the placement it was sampled for
        chosen = self.on.placement_for(T) if placement is None else placement
        # placement, settled pose, reachability
        return GraspSetup(self.on.trials[chosen], T, lambda: self.on.columns(chosen, T, width, grasp_id))


# --- resting on the table ---------------------------------------------------------------------------


class RestingLabeller(ObjectLabeller):
    """:class:`annotator.pipeline.modes.RestingMode`: the seed's table beside the floating gripper;
    an object settles in each orientation its grasps give, the grasps moving with it or staying in
    the table frame (the record's ``grasps``)."""

    def part(self) -> Any:
        from annotator.cell.resting import RestingWorld

        assert isinstance(self.mode, RestingMode)
        return RestingWorld(self.world, self.hand, self.config, self.mode.grasps)

    def place(self, model: ObjectModel, uid: int) -> RestingPlaced:
        return RestingPlaced(self.worlds.load(model, uid))


class RestingPlaced(PlacedOnPart):
    """An object resting on the table (``on``: :class:`annotator.cell.resting.RestingObject`)."""

    def setup(
        self, T: Transform, width: float, grasp_id: int, placement: int | None, rest: np.ndarray | None
    ) -> GraspSetup:
        orientation = UPRIGHT if rest is None else rest
        trial = self.on.trial_for(orientation)[0]
        pose = self.on.grasp(orientation, T)
        return GraspSetup(trial, pose, lambda: self.on.columns(orientation))  # the settled pose
