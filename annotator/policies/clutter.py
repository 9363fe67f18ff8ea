"""Clutter removal on the UR3 (VGN's benchmark, ``experiments/clutter_removal.py``, on the seed's arm).

A round is a pile scene (:class:`annotator.scenes.SceneSpec` ``(round, seed, "pile", k, k)``, or
``packed``: round ``r`` is scene ``r`` of ``annotate --scenes`` with the same seed and count, so a
learner can be given that scene's views), settled in a world with the UR3 and the run's gripper (its whole
linkage). Then, while objects remain and fewer than ``[scenes] clutter_max_failures`` (VGN: 2)
attempts in a row failed: the policy proposes a grasp; the arm executes it as ``annotator replay``
does (:func:`annotator.tools.replay.replay`: the IK path along the approach from the pregrasp,
close with the gripper's force, lift ``[scenes] clutter_lift_height`` straight up, hold); held (both
pads on the object, risen, moved less than ``[protocol] max_slip`` in the hand) counts as a success
and the object is taken away; then the gripper opens, the arm goes back to READY, the scene
settles and objects that left the workspace are removed (VGN's ``remove_and_wait``). A round also
ends when the policy proposes nothing. Every attempt starts from a snapshot of the scene as it is
(no contact memory), so a round depends on (seed, round, policy) only.

Policies (each proposes for the scene as it is now; :mod:`annotator.policies`): ``labels`` and
``random`` see the true scene (:mod:`annotator.policies.oracle`); a vision policy, ``vision-random``
or a learner's callable, sees only the Kinect's depth views of the pile as it is
(:mod:`annotator.policies.loop`); a predictions file is read once
(:mod:`annotator.policies.predictions`).

Metrics (VGN's): grasp success rate = successes / attempts; percent cleared = successes / objects
in the settled scenes; each with a 95 % Wilson score interval.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from annotator.cell.reach import READY, Reach, check_reach
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.objects import ObjectModel, get_object_pose, physics_for
from annotator.policies.oracle import RoundPolicy
from annotator.policies.predictions import PREDICTION_COLUMNS, read_predictions  # noqa: F401 (re-exported)
from annotator.policies.records import Proposal
from annotator.scenes.arrange import SceneBuilder
from annotator.scenes.records import KEPT, Instance, SceneRecord, SceneSpec
from annotator.scenes.world import LoadedScene, load_scene_with_arm
from annotator.sim import pb
from annotator.sim.world import World

log = logging.getLogger(__name__)

POLICIES = ("labels", "random", "vision-random")
Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile


def wilson(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (E. B. Wilson, JASA 22, 1927), (lo, hi)."""
    if trials <= 0:
        return float("nan"), float("nan")
    p = successes / trials
    d = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / d
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / d
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass(frozen=True)
class Executed:
    """What executing one proposal did: ``held``; ``target``, the instance the arm went for (the
    proposal's, or the one nearest its TCP; -1: none within the gripper's reach); ``why`` a failure
    failed (:data:`FAILURES`), empty for a held object."""

    held: bool
    target: int
    why: str = ""


# Why an attempt failed, in the order the execution meets them (grasps.csv's ``failure``).
FAILURES = {
    "nothing_there": "no object within the gripper's opening of the TCP",
    "arm_touched_table": "the arm or the gripper touched the table on the way in",
    "gripper_pushed_object": "a link other than a pad touched the object on the way in",
    "no_contact": "fewer than two pads on the object after the close",
    "not_lifted": "the object did not come up with the hand",
    "slipped": "it came up but lost a pad or moved in the hand",
}


@dataclass(frozen=True)
class Attempt:
    """One executed grasp: its proposal, whether it held, the object it held (-1: none), the
    instance the arm went for and why it failed (:class:`Executed`)."""

    round_id: int
    attempt: int
    proposal: Proposal
    success: bool
    held_instance: int
    object_id: str
    target: int = -1
    target_object: str = ""
    failure: str = ""


@dataclass
class RoundResult:
    """A round: objects in the settled scene, the attempts, and why it ended."""

    round_id: int
    object_count: int
    attempts: list[Attempt] = field(default_factory=list)
    ended: str = ""

    @property
    def successes(self) -> int:
        return sum(a.success for a in self.attempts)


@dataclass(frozen=True)
class ClutterSummary:
    """The benchmark's figures over ``rounds``."""

    rounds: list[RoundResult]

    @property
    def attempts(self) -> int:
        return sum(len(r.attempts) for r in self.rounds)

    @property
    def successes(self) -> int:
        return sum(r.successes for r in self.rounds)

    @property
    def objects(self) -> int:
        return sum(r.object_count for r in self.rounds)

    @property
    def success_rate(self) -> float:
        return self.successes / self.attempts if self.attempts else float("nan")

    @property
    def percent_cleared(self) -> float:
        return self.successes / self.objects if self.objects else float("nan")

    def lines(self, policy: str) -> list[str]:
        """The figures as printed: rate, counts and 95 % intervals; how the rounds ended and why
        the failed attempts failed (:data:`FAILURES`), each with its count."""
        lo, hi = wilson(self.successes, self.attempts)
        clo, chi = wilson(self.successes, self.objects)
        failures = (a.failure for r in self.rounds for a in r.attempts if not a.success)
        return [
            f"clutter removal, policy {policy}: {len(self.rounds)} rounds, {self.objects} objects",
            f"grasp success rate  {100 * self.success_rate:5.1f} %  ({self.successes} of {self.attempts} "
            f"attempts; 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)",
            f"percent cleared     {100 * self.percent_cleared:5.1f} %  ({self.successes} of {self.objects} "
            f"objects; 95 % interval {100 * clo:.1f}-{100 * chi:.1f} %)",
            f"rounds ended        {_counted(r.ended for r in self.rounds)}",
            f"failed attempts     {_counted(failures)}",
        ]

    def tables(self) -> tuple[pd.DataFrame, pd.DataFrame]:
        """(rounds: round_id, object_count, successes, attempts, ended; grasps: one row per attempt)."""
        rounds = pd.DataFrame(
            [
                {
                    "round_id": r.round_id,
                    "object_count": r.object_count,
                    "successes": r.successes,
                    "attempts": len(r.attempts),
                    "ended": r.ended,
                }
                for r in self.rounds
            ]
        )
        grasps = []
        for r in self.rounds:
            for a in r.attempts:
                T = a.proposal.T_table_tcp
                grasps.append(
                    {
                        "round_id": a.round_id,
                        "attempt": a.attempt,
                        "instance_id": a.proposal.instance_id,
                        "held_instance": a.held_instance,
                        "object_id": a.object_id,
                        **dict(zip(("x", "y", "z"), T.pos.tolist(), strict=True)),
                        **dict(zip(("qx", "qy", "qz", "qw"), T.quat.tolist(), strict=True)),
                        "width": a.proposal.width,
                        "score": a.proposal.score,
                        "label": int(a.success),
                        "target_instance": a.target,
                        "target_object": a.target_object,
                        "failure": a.failure,
                    }
                )
        return rounds, pd.DataFrame(grasps)


# --- one round ------------------------------------------------------------------------------------------


class Round:
    """One round's world: the settled scene with the UR3 and its gripper, objects dynamic."""

    def __init__(
        self,
        record: SceneRecord,
        models: Mapping[str, ObjectModel],
        config: AnnotatorConfig,
        gripper: GripperDescription,
    ) -> None:
        self.record = record
        self.models = models
        self.config = config
        self.gripper = gripper
        self.world = World(config.physics.whole_linkage())
        try:
            self.scene: LoadedScene = load_scene_with_arm(self.world, record, models, config, gripper)
            self.present: dict[int, int] = dict(self.scene.uids)  # instance -> body, still on the table
            self._home()
        except BaseException:
            self.world.close()
            raise

    @property
    def cell(self):
        return self.scene.cell

    def close(self) -> None:
        self.world.close()

    def _home(self) -> None:
        cell = self.cell
        cell.reset_arm(READY)
        cell.command_arm(READY)
        cell.gripper.reset_width(cell.gripper.max_width)

    def now(self) -> SceneRecord:
        """The scene as it is: the objects still present at their poses now (table frame)."""
        T_table_world = self.record.T_world_table.inverse()
        instances = []
        for inst in self.record.instances:
            uid = self.present.get(inst.instance_id)
            if uid is None:
                continue
            T = T_table_world * get_object_pose(self.world.client, uid)
            instances.append(
                Instance(
                    inst.instance_id,
                    inst.object_id,
                    KEPT,
                    Transform.exact(T.pos, T.quat),
                    inst.scale,
                    inst.mass,
                )
            )
        return dataclasses.replace(self.record, instances=tuple(instances))

    def reach(self, T_table_tcp: Transform, width: float, instance_id: int) -> Reach:
        """Can the arm execute the grasp in the scene as it is?"""
        protocol, cell = self.config.protocol, self.cell
        first = self.present.get(instance_id)
        bodies = ([first] if first is not None else []) + [
            u for i, u in sorted(self.present.items()) if i != instance_id
        ]
        return check_reach(
            cell,
            self.record.T_world_table * T_table_tcp,
            width,
            open_width=min(cell.gripper.max_width, width + 2 * protocol.pregrasp_clearance),
            approach_distance=protocol.approach_distance,
            approach_step=protocol.approach_step,
            obj=tuple(bodies),
            q_seed=READY,
        )

    def execute(self, proposal: Proposal) -> Executed:
        """Execute ``proposal`` on the arm from a snapshot of the scene as it is."""
        from annotator.cell.execute import Plan
        from annotator.cell.execute import execute_plan as replay

        target = proposal.instance_id if proposal.instance_id in self.present else self._nearest(proposal)
        if target < 0:
            return Executed(False, -1, "nothing_there")
        self._use_physics_of(target)
        state = self.world.save_state()
        self.world.restore_state(state)  # no contact memory: the attempt depends on the scene only
        self.world.remove_state(state)
        lift = dataclasses.replace(self.config.protocol, lift_height=self.config.scenes.clutter_lift_height)
        config = dataclasses.replace(self.config, protocol=lift)
        uid = self.present[target]
        T_world_tcp = self.record.T_world_table * proposal.T_table_tcp
        open_width = min(self.cell.gripper.max_width, proposal.width + 2 * lift.pregrasp_clearance)
        plan = Plan(
            get_object_pose(self.world.client, uid),
            T_world_tcp,
            proposal.width,
            open_width,
            proposal.reach,
            "",
        )
        result = replay(self.cell, uid, plan, config)
        held = result.held(lift.lift_height, lift.max_slip)
        if held:
            self.world.remove_body(uid)
            del self.present[target]
        self._home()
        self.settle()
        pads = self.cell.gripper.description.pad_links
        return Executed(held, target, "" if held else _failure(result, lift.lift_height, pads))

    def _nearest(self, proposal: Proposal) -> int:
        """The object nearest the proposal's TCP (a file's grasp names none); -1 if none is within
        the gripper's reach of it."""
        point = (self.record.T_world_table * proposal.T_table_tcp).pos
        return nearest_instance(self.world.client, self.present, point, self.cell.gripper.max_width)

    def _use_physics_of(self, instance_id: int) -> None:
        model = self.models[self.record.instance(instance_id).object_id]
        physics = physics_for(model, self.config.physics.whole_linkage())
        if self.world.physics != physics:
            self.world.physics = physics
            self.world.configure()

    def settle(self) -> None:
        """VGN's remove_and_wait: settle; remove objects whose centre of mass left the workspace."""
        scenes = self.config.scenes
        chunk = max(1, round(scenes.rest_check_time / self.world.dt))
        limit = round(scenes.settle_time / self.world.dt)
        T_table_world = self.record.T_world_table.inverse()
        self.world.set_gravity(True)
        for _ in range(scenes.settle_rounds):
            elapsed = 0
            while elapsed < limit and not self._at_rest():
                for _ in range(chunk):
                    self.cell.command_arm(READY)
                    self.world.step()
                elapsed += chunk
            gone = [
                i
                for i, uid in self.present.items()
                if not self.record.workspace.contains(
                    T_table_world.apply(get_object_pose(self.world.client, uid).pos)
                )[0]
            ]
            for instance_id in gone:
                self.world.remove_body(self.present.pop(instance_id))
            if not gone:
                return

    def _at_rest(self) -> bool:
        speed = self.config.scenes.rest_speed
        for uid in self.present.values():
            linear, angular = pb.getBaseVelocity(uid, physicsClientId=self.world.client)
            if math.sqrt(sum(v * v for v in (*linear, *angular))) >= speed:
                return False
        return True


def nearest_instance(client: int, bodies: Mapping[int, int], point_world, within: float) -> int:
    """The instance (of ``bodies``: instance -> body) whose body is nearest ``point_world`` (3,) m,
    world frame; -1 if none is within ``within`` m of it."""
    best, who = within, -1
    probe = pb.createCollisionShape(pb.GEOM_SPHERE, radius=1e-4, physicsClientId=client)
    body = pb.createMultiBody(0.0, probe, -1, list(map(float, point_world)), physicsClientId=client)
    try:
        for instance_id, uid in sorted(bodies.items()):
            pts = pb.getClosestPoints(body, uid, best, physicsClientId=client)
            if pts and min(p[8] for p in pts) < best:
                best, who = min(p[8] for p in pts), instance_id
    finally:
        pb.removeBody(body, physicsClientId=client)
    return who


def _counted(items) -> str:
    """``"a 3, b 1"``: each distinct item with its count, most frequent first (``"none"``)."""
    counts = Counter(items)
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))) or "none"


def _failure(result, lift_height: float, pads: tuple[str, ...]) -> str:
    """The :data:`FAILURES` key of an execution that did not hold (``result``: an Execution;
    ``pads``: the gripper's pad links, which may touch the object on the way in)."""
    if result.table_touched:
        return "arm_touched_table"
    if result.links_on_object - set(pads):
        return "gripper_pushed_object"
    if result.pads_touching < 2:
        return "no_contact"
    if not result.lifted(lift_height):
        return "not_lifted"
    return "slipped"


# --- the benchmark -----------------------------------------------------------------------------------------


def play_round(
    round_id: int,
    models: Mapping[str, ObjectModel],
    config: AnnotatorConfig,
    policy: RoundPolicy,
    *,
    seed: int,
    objects: int,
    gripper: GripperDescription | str | None = None,
    arrangement: str = "pile",
) -> RoundResult:
    """One round (module docstring) on a pile (or ``arrangement``) of ``objects`` drawn from ``models``."""
    description = load_gripper(gripper)
    builder = SceneBuilder(models, scenes=config.scenes, physics=config.physics, cell=config.cell)
    record = builder.build(SceneSpec(round_id, seed, arrangement, objects, objects))
    result = RoundResult(round_id, len(record.kept))
    round_ = Round(record, models, config, description)
    tried: set[int] = set()
    try:
        failures = 0
        while True:
            if not round_.present:
                result.ended = "cleared"
                break
            if failures >= config.scenes.clutter_max_failures:
                result.ended = f"{failures} failures in a row"
                break
            proposal = policy(round_, len(result.attempts), tried)
            if proposal is None:
                result.ended = "no grasp proposed"
                break
            done = round_.execute(proposal)
            held, instance = done.held, done.target if done.held else -1
            oid = record.instance(instance).object_id if instance >= 0 else ""
            aimed = record.instance(done.target).object_id if done.target >= 0 else ""
            result.attempts.append(
                Attempt(
                    round_id,
                    len(result.attempts),
                    proposal,
                    held,
                    instance,
                    oid,
                    target=done.target,
                    target_object=aimed,
                    failure=done.why,
                )  # fmt: skip
            )
            failures = 0 if held else failures + 1
            log.info(
                "round %d attempt %d: %s", round_id, len(result.attempts) - 1, "held" if held else "failed"
            )
    finally:
        round_.close()
    return result


_MODELS: dict[tuple, dict[str, ObjectModel]] = {}  # this process's loaded pools (workers reuse them)


def _pool(sources: tuple, config: AnnotatorConfig, cache_dir: str | None) -> dict[str, ObjectModel]:
    from annotator.objects import load_object

    key = (tuple((s.object_id, str(s.path), s.properties) for s in sources), config.objects, cache_dir)
    if key not in _MODELS:
        cache = Path(cache_dir) if cache_dir is not None else None
        _MODELS.clear()
        _MODELS[key] = {s.object_id: load_object(s, config.objects, cache_dir=cache) for s in sources}
    return _MODELS[key]


@dataclass(frozen=True)
class ClutterJob:
    """What every round shares: the pool (sorted sources), objects per pile, seed, the policy
    (a name of :mod:`annotator.policies.resolve` or a predictions table), trials per label, the
    gripper; for a vision policy its ``policy_args`` (KEY, VALUE) pairs and the depth ``views`` it
    sees; the ``arrangement`` of the scenes (``pile`` or ``packed``)."""

    sources: tuple
    objects: int
    seed: int
    policy: str | pd.DataFrame
    config: AnnotatorConfig
    trials: int = 1
    gripper: GripperDescription | None = None
    cache_dir: str | None = None
    policy_args: tuple[tuple[str, str], ...] = ()
    views: int = 1
    arrangement: str = "pile"

    def make_policy(self) -> RoundPolicy:
        from annotator.policies.predictions import file_policy
        from annotator.policies.resolve import round_policy

        if isinstance(self.policy, pd.DataFrame):
            return file_policy(self.policy)
        return round_policy(
            self.policy, seed=self.seed, trials=self.trials, args=dict(self.policy_args), views=self.views
        )


def run_round(job: ClutterJob, round_id: int) -> RoundResult:
    """Round ``round_id`` of ``job`` (in this process or a worker)."""
    models = _pool(job.sources, job.config, job.cache_dir)
    return play_round(
        round_id,
        models,
        job.config,
        job.make_policy(),
        seed=job.seed,
        objects=job.objects,
        gripper=job.gripper,
        arrangement=job.arrangement,
    )


def clutter_removal(job: ClutterJob, rounds: int, workers: int = 1) -> ClutterSummary:
    """Rounds 0..rounds-1 of ``job``, on ``workers`` processes (the figures do not depend on it)."""
    if workers <= 1:
        return ClutterSummary([run_round(job, r) for r in range(rounds)])
    from joblib import Parallel, delayed

    results = Parallel(n_jobs=workers)(delayed(run_round)(job, r) for r in range(rounds))
    return ClutterSummary(sorted(results, key=lambda r: r.round_id))
