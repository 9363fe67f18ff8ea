"""Labels among neighbours: candidates on every object of a settled scene, tried where it rests.

Per scene (:class:`SceneTrials`):

* **candidates** (:func:`scene_candidates`): each kept instance gets an equal share of the scene's N
  candidates, sampled in its mesh frame for where it rests, as the cell samples an object on the
  table (:func:`annotator.cell.candidates.sample_placement`: approaches from above within
  ``[cell] approach_cone``, fingers clear of the table top), from a Generator keyed on (seed,
  scene, instance); the scene's rows are then shuffled with one keyed on (seed, scene), so grasp
  ids 0..N-1 are a fair prefix whatever the instances are.
* **the kinematic collision check** against the whole scene: the open gripper at the grasp and
  every ``approach_step`` back along the approach, then closed on the expected chord with only
  its pads allowed on the target; the target, the table and every other instance are checked
  (:meth:`annotator.trial.GraspTrial.collides`: the target first, then the table, then the
  neighbours by instance id, at the first pose from the grasp backwards that touches anything).
  A grasp that touches a neighbour is a ``collision`` whose row names it (``collided_with``
  ``neighbour``, ``collided_instance``).
* **the physics trial** in the settled scene: every trial starts from a snapshot of the scene at
  rest (the gripper parked) with no contact memory (:meth:`annotator.sim.world.World.restore_state`),
  gravity on, the target resting among its neighbours; close, lift, shake (or lift only,
  ``[scenes] shake``); the outcome as the label schema says, and how far the neighbours moved
  (``disturbance``: the largest displacement of any bounding-box corner of any neighbour between
  the settled scene and the end of the trial).
* **light objects**: the world is simulated at the step the *target* needs
  (:func:`annotator.objects.physics_for`: ``[physics] light_object_mass``), set before each trial;
  ``[scenes] substeps = "lightest"`` uses the lightest object's in the scene instead
  (docs/decisions/0302-scene-substeps.md measures both).

A row depends on (seed, scene, grasp id) only: never on the worker, the span or the order.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from annotator.cell.batch import JOINT_COLUMNS, PARKED, REACH_ERROR
from annotator.cell.candidates import TableSide, allocate, sample_placement
from annotator.cell.reach import READY, Reach, check_reach
from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.geometry import Transform, matrix_to_quat
from annotator.grippers import GripperDescription
from annotator.k_trials import run_k_trials
from annotator.label_row import TrialsResult, canonical, label_row
from annotator.objects import ObjectModel, get_object_pose, physics_for
from annotator.rng import keyed_rng
from annotator.scenes.records import SceneRecord
from annotator.scenes.world import LoadedScene, load_scene, load_scene_with_arm
from annotator.schema import MODES, OBJECT_COLUMNS
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.store.names import scene_unit
from annotator.trial import CollisionCheck, GraspTrial, Perturbation, TrialResult

log = logging.getLogger(__name__)

# collided_with: what the gripper touched in the kinematic check of a ``collision`` row.
HIT_NONE, HIT_TARGET, HIT_TABLE, HIT_NEIGHBOUR = "", "object", "table", "neighbour"
TABLE_TCP_COLUMNS = tuple(c for c in MODES["scene"] if c.startswith("table_tcp_"))  # T_table_tcp
# The columns a scene row adds to an object label's (docs/labels.md, "Columns of annotate --scenes").
SCENE_LABEL_COLUMNS = tuple(c for c in MODES["scene"] if c not in OBJECT_COLUMNS) + ("gripper",)


@dataclass(frozen=True)
class SceneCandidates:
    """A scene's N candidates, by grasp id. ``T_obj_tcp`` (n, 4, 4): TCP poses in the target
    instance's mesh frame; ``width_expected`` (n,) m, the chord between the contacts;
    ``instance_id`` (n,) int64, the target; ``antipodal`` (n,) bool."""

    T_obj_tcp: np.ndarray
    width_expected: np.ndarray
    instance_id: np.ndarray
    antipodal: np.ndarray

    def __len__(self) -> int:
        return int(self.width_expected.shape[0])


def scene_candidates(
    record: SceneRecord,
    models: Mapping[str, ObjectModel],
    n: int,
    seed: int,
    config: AnnotatorConfig,
    sides: Mapping[int, TableSide],
    attempt: int | None = None,
    draw: int = 0,
) -> SceneCandidates:
    """Exactly ``n`` candidates over the kept instances of ``record`` (module docstring); ``sides``:
    each kept instance's :class:`TableSide` (its pose, the table, the fingers). ``attempt`` and
    ``draw``: further keys (clutter removal draws new candidates for each attempt on a scene, and
    more of them while it finds no grasp)."""
    more = () if attempt is None else ("attempt", int(attempt))
    more += ("draw", int(draw)) if draw else ()
    kept = record.kept
    if not kept:
        raise ValueError(f"scene {record.scene_id} has no object left on the table")
    counts = allocate(n, [1.0] * len(kept), "even")
    parts, instances = [], []
    for inst, count in zip(kept, counts, strict=True):
        rng = keyed_rng("scene-candidates", int(seed), int(record.scene_id), inst.instance_id, *more)
        mesh = models[inst.object_id].mesh
        parts.append(sample_placement(mesh, int(count), rng, config, sides[inst.instance_id]))
        instances.append(np.full(int(count), inst.instance_id, dtype=np.int64))
    order = keyed_rng("scene-order", int(seed), int(record.scene_id), *more).permutation(n)
    return SceneCandidates(
        T_obj_tcp=np.concatenate([c.T_obj_tcp for c in parts])[order],
        width_expected=np.concatenate([c.width_expected for c in parts])[order],
        instance_id=np.concatenate(instances)[order],
        antipodal=np.concatenate([c.antipodal for c in parts])[order],
    )


@dataclass(frozen=True)
class NeighbourTrial:
    """One trial among neighbours: the trial's result, its kinematic check, and ``disturbance``
    (m), how far the neighbour that moved most (``disturbed_instance``, -1 without neighbours) was
    moved (the largest displacement of a corner of its bounding box)."""

    result: TrialResult
    check: CollisionCheck
    disturbance: float
    disturbed_instance: int


def _corners(model: ObjectModel) -> np.ndarray:
    """The mesh's bounding-box corners (8, 3), mesh frame."""
    return np.array(np.meshgrid(*np.asarray(model.mesh.bounds).T, indexing="ij")).reshape(3, -1).T


class SceneTrials:
    """``record`` loaded in a fresh world with the floating gripper parked: one
    :class:`GraspTrial` per kept instance, the others and the table its obstacles.

    ``models``: object id -> loaded model of every object in the scene; ``gripper``: the gripper
    simulated (default the RG2). Call :meth:`close` (or use as a context manager) to free the world.
    """

    def __init__(
        self,
        record: SceneRecord,
        models: Mapping[str, ObjectModel],
        config: AnnotatorConfig,
        gripper: GripperDescription | str | None = None,
    ) -> None:
        self.record = record
        self.models = models
        self.config = config
        self.world = World(config.physics)
        try:
            self.hand = FloatingGripper(self.world, config.gripper, gripper)
            self.hand.teleport(PARKED, self.hand.gripper.max_width)
            self.scene: LoadedScene = load_scene(self.world, record, models, cell_config=config.cell)
            self.world.set_gravity(True)
            self._corners = {i: _corners(models[record.instance(i).object_id]) for i in self.scene.uids}
            table = self.scene.cell.table.uid
            self.trials: dict[int, GraspTrial] = {}
            for instance_id, uid in self.scene.uids.items():
                others = [u for i, u in sorted(self.scene.uids.items()) if i != instance_id]
                self.trials[instance_id] = GraspTrial(
                    self.world,
                    self.hand,
                    uid,
                    config,
                    obstacles=(table, *others),
                    resting=True,
                    shake=config.scenes.shake,
                    obstacle_margin=config.scenes.neighbour_clearance,
                )
        except BaseException:
            self.world.close()
            raise

    @property
    def description(self) -> GripperDescription:
        return self.hand.description

    def table_sides(self) -> dict[int, TableSide]:
        """Each kept instance's :class:`TableSide` for the candidate sampler."""
        envelope = self.hand.gripper.finger_envelope()
        top_z = self.scene.cell.top.z
        clearance, max_width = self.config.protocol.pregrasp_clearance, self.hand.gripper.max_width
        return {
            i: TableSide(self.record.T_world_obj(i), top_z, envelope, clearance, max_width)
            for i in self.scene.uids
        }

    def reset(self) -> None:
        """Back to the settled scene, the gripper parked (a trial leaves the world where it ended)."""
        first = next(iter(self.trials.values()))
        self.world.restore_state(first.state)

    def candidates(self, n: int, seed: int, attempt: int | None = None, draw: int = 0) -> SceneCandidates:
        """The scene's N candidates (:func:`scene_candidates`)."""
        sides = self.table_sides()
        return scene_candidates(self.record, self.models, n, seed, self.config, sides, attempt, draw)

    def close(self) -> None:
        """Free the snapshots and the world."""
        for trial in self.trials.values():
            trial.close()
        self.trials = {}
        self.world.close()

    def __enter__(self) -> SceneTrials:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- one trial ------------------------------------------------------------------------------

    def _use_physics_of(self, instance_id: int) -> None:
        """The world's step for a trial on ``instance_id``: the target's (light objects substep), or
        the lightest object's in the scene (``[scenes] substeps``)."""
        if self.config.scenes.substeps == "lightest":
            model = min((self.models[i.object_id] for i in self.record.kept), key=lambda m: m.mass)
        else:
            model = self.models[self.record.instance(instance_id).object_id]
        physics = physics_for(model, self.config.physics)
        if self.world.physics != physics:
            self.world.physics = physics
            self.world.configure()

    def run(
        self, instance_id: int, T_obj_tcp: Transform, width: float, perturbation: Perturbation | None = None
    ) -> NeighbourTrial:
        """Try grasp ``T_obj_tcp`` (target's mesh frame, expected chord ``width`` m) on instance
        ``instance_id`` where it rests among its neighbours."""
        trial = self.trials[instance_id]
        self._use_physics_of(instance_id)
        result = trial.run(T_obj_tcp, width, perturbation)
        assert result.check is not None
        check = result.check
        disturbance, who = self.disturbance(instance_id)
        return NeighbourTrial(result, check, disturbance, who)

    def disturbance(self, target: int) -> tuple[float, int]:
        """(metres, instance) of the neighbour of ``target`` moved most from its settled pose, now."""
        worst, who = 0.0, -1
        for instance_id, uid in sorted(self.scene.uids.items()):
            if instance_id == target:
                continue
            corners = self._corners[instance_id]
            now = get_object_pose(self.world.client, uid).apply(corners)
            settled = self.record.T_world_obj(instance_id).apply(corners)
            moved = float(np.linalg.norm(now - settled, axis=1).max())
            if who < 0 or moved > worst:
                worst, who = moved, instance_id
        return worst, who

    def hit_of(self, check: CollisionCheck, target: int) -> tuple[str, int]:
        """What a collision check touched: (collided_with, the neighbour's instance id or -1)."""
        if not check.collided:
            return HIT_NONE, -1
        if check.hit == self.scene.uids[target]:
            return HIT_TARGET, -1
        if check.hit == self.scene.cell.table.uid:
            return HIT_TABLE, -1
        instance = self.scene.instance_of(check.hit) if check.hit is not None else None
        return HIT_NEIGHBOUR, -1 if instance is None else int(instance)


class SceneArm:
    """``annotate --scenes --cell``: the scene with the UR3 and the same gripper, in its own world
    (whole linkage), for the reachability of every grasp: closed-form IK along the approach from
    the arm's READY branch, no arm link on the table or on any object of the scene
    (:func:`annotator.cell.reach.check_reach`). Also where the views are rendered (the arm in them)."""

    def __init__(
        self,
        record: SceneRecord,
        models: Mapping[str, ObjectModel],
        config: AnnotatorConfig,
        gripper: GripperDescription | str | None = None,
    ) -> None:
        self.record = record
        self.config = config
        self.world = World(config.physics.whole_linkage())
        try:
            self.scene = load_scene_with_arm(self.world, record, models, config, gripper)
            cell = self.scene.cell
            assert cell.gripper is not None
            cell.reset_arm(READY)
            cell.gripper.reset_width(cell.gripper.max_width)
            self.state = self.world.save_state()
        except BaseException:
            self.world.close()
            raise

    def reset(self) -> None:
        """Back to the scene at rest with the arm at READY, the gripper open."""
        self.world.restore_state(self.state)

    def reach(self, instance_id: int, T_obj_tcp: Transform, width: float) -> Reach:
        """Can the arm execute grasp ``T_obj_tcp`` (pads ``width`` apart) on ``instance_id``?"""
        cell, protocol = self.scene.cell, self.config.protocol
        assert cell.gripper is not None
        self.world.restore_state(self.state)
        target = self.scene.uids[instance_id]
        others = [u for i, u in sorted(self.scene.uids.items()) if i != instance_id]
        return check_reach(
            cell,
            self.record.T_world_obj(instance_id) * T_obj_tcp,
            width,
            open_width=min(cell.gripper.max_width, width + 2 * protocol.pregrasp_clearance),
            approach_distance=protocol.approach_distance,
            approach_step=protocol.approach_step,
            obj=(target, *others),
            q_seed=READY,
        )

    def columns(self, instance_id: int, T_obj_tcp: Transform, width: float, where: str) -> dict[str, object]:
        """The cell's columns of a commanded grasp: reachable, q_grasp_0..5, unreachable_reason."""
        try:
            reach = self.reach(instance_id, T_obj_tcp, width)
        except Exception as exc:  # one candidate's failure must not lose the others
            log.warning("%s: reachability check failed: %s: %s", where, type(exc).__name__, exc)
            reach = Reach(False, REACH_ERROR, str(exc))
        q = reach.q_grasp if reach.reachable else np.full(6, np.nan)
        return {
            "reachable": bool(reach.reachable),
            **dict(zip(JOINT_COLUMNS, map(float, q), strict=True)),
            "unreachable_reason": reach.reason,
        }

    def close(self) -> None:
        self.world.remove_state(self.state)
        self.world.close()


@dataclass(frozen=True)
class _Labelled:
    """What one candidate's trials gave (``trials``), and what trial 0 hit and disturbed."""

    trials: TrialsResult
    hit: tuple[str, int]
    stage: str
    disturbance: float
    disturbed_instance: int


def _try(
    trials: SceneTrials,
    instance_id: int,
    T: Transform,
    width: float,
    unit: str,
    grasp_id: int,
    k: int,
    seed: int,
) -> _Labelled:
    """Trial 0 unperturbed, then ``k - 1`` perturbed from the grasp's own Generator; an exception
    is this grasp's ``error``, never the scene's."""
    try:
        robust = trials.trials[instance_id].robust

        def run(p: Perturbation | None) -> NeighbourTrial:
            return trials.run(instance_id, T, width, p)

        gate = trials.trials[instance_id].gate
        ran = run_k_trials(run, lambda t: t.result, k, robust, seed, unit, grasp_id, gate)
        first, r = ran.first, ran.first.result
        return _Labelled(
            TrialsResult(
                r.outcome, r.T_obj_tcp, r.width, ran.steps, r.slip, ran.held, None, ran.success, ran.stages
            ),
            trials.hit_of(first.check, instance_id),
            first.check.stage or "",
            first.disturbance,
            first.disturbed_instance,
        )
    except Exception as exc:  # a physics failure on one candidate must not lose the others
        log.warning("%s grasp %d: %s: %s", unit, grasp_id, type(exc).__name__, exc)
        failed = TrialsResult(Outcome.ERROR, T, width, 0, float("nan"), 0)
        return _Labelled(failed, (HIT_NONE, -1), "", float("nan"), -1)


def label_scene(
    trials: SceneTrials,
    candidates: SceneCandidates,
    start: int,
    stop: int,
    seed: int,
    n_trials: int = 1,
    arm: SceneArm | None = None,
) -> pd.DataFrame:
    """The label rows of grasps ``start..stop-1`` of the scene (the object label schema plus
    SCENE_LABEL_COLUMNS; with ``arm`` the cell's reachability columns)."""
    record, config, models = trials.record, trials.config, trials.models
    unit = scene_unit(record.scene_id)
    rows = []
    quats = matrix_to_quat(candidates.T_obj_tcp[start:stop, :3, :3]).reshape(-1, 4)
    threshold = config.scenes.disturbance_threshold
    for k, grasp_id in enumerate(range(start, stop)):
        instance_id = int(candidates.instance_id[grasp_id])
        inst = record.instance(instance_id)
        model = models[inst.object_id]
        T = Transform(candidates.T_obj_tcp[grasp_id][:3, 3], quats[k])
        width_expected = float(candidates.width_expected[grasp_id])
        got = _try(trials, instance_id, T, width_expected, unit, grasp_id, n_trials, seed)
        assert inst.T_table_obj is not None
        T_table_tcp = inst.T_table_obj * got.trials.T_label
        T_table_tcp_pose = [*T_table_tcp.pos.tolist(), *canonical(T_table_tcp.quat).tolist()]
        extra = {
            "scene_id": int(record.scene_id),
            "instance_id": instance_id,
            **dict(zip(TABLE_TCP_COLUMNS, T_table_tcp_pose, strict=True)),
            "collided_with": got.hit[0],
            "collided_instance": got.hit[1],
            "collision_stage": got.stage,
            "disturbance": got.disturbance,
            "disturbed": bool(got.disturbance >= threshold),
            "disturbed_instance": got.disturbed_instance,
        }
        if arm is not None:
            extra.update(arm.columns(instance_id, T, width_expected, f"{unit} grasp {grasp_id}"))
        row = label_row(
            "scene" if arm is None else "scene_cell",
            object_id=inst.object_id,
            grasp_id=grasp_id,
            result=got.trials,
            trials=n_trials,
            T_cmd=T,
            cmd_width=width_expected,
            model=model,
            seed=seed,
            gripper=trials.description.name,
            extra=extra,
        )
        rows.append(row)
    return pd.DataFrame(rows)
