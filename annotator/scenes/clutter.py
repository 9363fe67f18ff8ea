"""Clutter removal on the UR3 (VGN's benchmark, ``experiments/clutter_removal.py``, on the seed's arm).

A round is a pile scene (:class:`annotator.scenes.SceneSpec` ``(round, seed, "pile", k, k)``: round
``r`` is scene ``r`` of ``annotate --scenes`` with the same seed and count, so a learner can be
given that scene's views), settled in a world with the UR3 and the run's gripper (its whole
linkage). Then, while objects remain and fewer than ``[scenes] clutter_max_failures`` (VGN: 2)
attempts in a row failed: the policy proposes a grasp; the arm executes it as ``annotator replay``
does (:func:`annotator.tools.replay.replay`: the IK path along the approach from the pregrasp,
close with the gripper's force, lift ``[scenes] clutter_lift_height`` straight up, hold); held (both
pads on the object, risen, moved less than ``[protocol] max_slip`` in the hand) counts as a success
and the object is taken away; then the gripper opens, the arm goes back to READY, the scene
settles and objects that left the workspace are removed (VGN's ``remove_and_wait``). A round also
ends when the policy proposes nothing. Every attempt starts from a snapshot of the scene as it is
(no contact memory), so a round depends on (seed, round, policy) only.

Policies (each proposes for the scene as it is now):

- ``labels`` (an oracle: the best a learner of the labels can do): the scene is labelled on the fly
  among its neighbours (:mod:`annotator.scenes.labels`, the floating gripper, candidates drawn anew
  per attempt) and the best-scored success the arm can reach is executed (ties: the lowest grasp
  id). Candidates are labelled in grasp-id order and the search stops at the first reachable
  success whose score is the highest possible, which picks the same grasp as labelling all of them;
  120 more are drawn (up to 5 x 120) while none is found.
- ``random`` (a baseline): the same candidates, antipodal ones only, in a random order; the first
  that the kinematic check lets through (no gripper collision with anything, along the approach or
  closed) and the arm can reach is executed. No physics decides it.
- a file: a learner's predictions (:func:`read_predictions`), the best-scored of the round's rows
  not tried yet that the arm can reach.

Metrics (VGN's): grasp success rate = successes / attempts; percent cleared = successes / objects
in the settled scenes; each with a 95 % Wilson score interval.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.cell.reach import READY, Reach, check_reach
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.objects import ObjectModel, get_object_pose, physics_for
from annotator.rng import keyed_rng
from annotator.scenes.arrange import SceneBuilder
from annotator.scenes.labels import SceneCandidates, SceneTrials, label_scene
from annotator.scenes.records import KEPT, Instance, SceneRecord, SceneSpec
from annotator.scenes.world import LoadedScene, load_scene
from annotator.sim import pb
from annotator.sim.world import World

log = logging.getLogger(__name__)

POLICIES = ("labels", "random")
# Candidates drawn per look of the ``labels`` and ``random`` policies at the scene as it is (VGN's
# 120 per scene), labelled in batches of 20 before the search may stop, and drawn anew up to
# POLICY_DRAWS times while none is found: on a pile the cell's sampler gives some objects (a mug, a
# bowl upside down) few grasps that miss the object itself, and 120 left graspable objects behind.
POLICY_CANDIDATES = 120
POLICY_BATCH = 20
POLICY_DRAWS = 5
PREDICTION_COLUMNS = ("round", "x", "y", "z", "qx", "qy", "qz", "qw", "width", "score")
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
class Proposal:
    """A grasp to execute: the target ``instance_id`` (-1: not known, a file's), the TCP pose
    ``T_table_tcp`` (table frame) with the pads ``width`` apart, the policy's ``score``, and the
    arm's path (:class:`annotator.cell.reach.Reach`)."""

    instance_id: int
    T_table_tcp: Transform
    width: float
    score: float
    reach: Reach


@dataclass(frozen=True)
class Attempt:
    """One executed grasp: its proposal, whether it held, the object it held (-1: none)."""

    round_id: int
    attempt: int
    proposal: Proposal
    success: bool
    held_instance: int
    object_id: str


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
        """The figures as printed: rate, counts and 95 % intervals."""
        lo, hi = wilson(self.successes, self.attempts)
        clo, chi = wilson(self.successes, self.objects)
        return [
            f"clutter removal, policy {policy}: {len(self.rounds)} rounds, {self.objects} objects",
            f"grasp success rate  {100 * self.success_rate:5.1f} %  ({self.successes} of {self.attempts} "
            f"attempts; 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)",
            f"percent cleared     {100 * self.percent_cleared:5.1f} %  ({self.successes} of {self.objects} "
            f"objects; 95 % interval {100 * clo:.1f}-{100 * chi:.1f} %)",
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
                    }
                )
        return rounds, pd.DataFrame(grasps)


def read_predictions(path: Path) -> pd.DataFrame:
    """A learner's predictions: a CSV or Parquet file with PREDICTION_COLUMNS: ``round`` (int, the
    round = scene id), the TCP pose in the table frame ``x y z`` (m) ``qx qy qz qw`` (xyzw), the
    opening ``width`` (m) the gripper closes from, and ``score`` (higher first). ValueError naming
    what is wrong."""
    path = Path(path)
    try:
        df = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read predictions ({exc})") from None
    missing = [c for c in PREDICTION_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; predictions need {list(PREDICTION_COLUMNS)}")
    values = df[list(PREDICTION_COLUMNS)].to_numpy(dtype=np.float64)
    if not np.isfinite(values).all():
        raise ValueError(f"{path}: every prediction needs finite {list(PREDICTION_COLUMNS)}")
    if (np.abs(np.linalg.norm(values[:, 4:8], axis=1) - 1.0) > 1e-6).any():
        raise ValueError(f"{path}: quaternions qx..qw must be unit (xyzw)")
    return df.reset_index(drop=True)


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
            self.scene: LoadedScene = load_scene(
                self.world,
                record,
                models,
                cell_config=config.cell,
                robot=True,
                gripper=config.gripper,
                kinect_config=config.kinect,
                description=gripper,
            )
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

    def execute(self, proposal: Proposal) -> tuple[bool, int]:
        """Execute ``proposal`` on the arm from a snapshot of the scene as it is; (held, instance held)."""
        from annotator.cell.execute import Plan
        from annotator.cell.execute import execute_plan as replay

        target = proposal.instance_id if proposal.instance_id in self.present else self._nearest(proposal)
        if target < 0:
            return False, -1
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
        return held, target if held else -1

    def _nearest(self, proposal: Proposal) -> int:
        """The object nearest the proposal's TCP (a file's grasp names none); -1 if none is within
        the gripper's reach of it."""
        point = (self.record.T_world_table * proposal.T_table_tcp).pos
        best, who = self.cell.gripper.max_width, -1
        probe = pb.createCollisionShape(pb.GEOM_SPHERE, radius=1e-4, physicsClientId=self.world.client)
        body = pb.createMultiBody(0.0, probe, -1, point.tolist(), physicsClientId=self.world.client)
        try:
            for instance_id, uid in sorted(self.present.items()):
                pts = pb.getClosestPoints(body, uid, best, physicsClientId=self.world.client)
                if pts and min(p[8] for p in pts) < best:
                    best, who = min(p[8] for p in pts), instance_id
        finally:
            pb.removeBody(body, physicsClientId=self.world.client)
        return who

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


# --- policies -------------------------------------------------------------------------------------------


Policy = Callable[[Round, int, set[int]], Proposal | None]


def _trials(round_: Round, now: SceneRecord) -> SceneTrials:
    return SceneTrials(now, round_.models, round_.config, round_.gripper)


def labels_policy(seed: int, trials_per_grasp: int = 1) -> Policy:
    """The ``labels`` policy (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        now = round_.now()
        trials = _trials(round_, now)
        best: Proposal | None = None
        try:
            for draw in range(POLICY_DRAWS):
                cands = trials.candidates(POLICY_CANDIDATES, seed, attempt=attempt, draw=draw)
                best = _best_reachable(round_, now, trials, cands, (seed, trials_per_grasp), best)
                if best is not None:
                    break
        finally:
            trials.close()
        return best

    return propose


def _best_reachable(
    round_: Round,
    now: SceneRecord,
    trials: SceneTrials,
    cands: SceneCandidates,
    labelling: tuple[int, int],
    best: Proposal | None,
) -> Proposal | None:
    """The best-scored reachable success of ``cands`` (or ``best`` if none beats it), labelled in
    batches (``labelling``: seed, trials per grasp) until one has the highest possible score."""
    seed, k = labelling
    for start in range(0, len(cands), POLICY_BATCH):
        rows = label_scene(trials, cands, start, min(len(cands), start + POLICY_BATCH), seed, k)
        held = rows[rows["success"]].sort_values(["score", "grasp_id"], ascending=[False, True])
        for row in held.itertuples():
            if best is not None and row.score <= best.score:
                break
            proposal = _reachable(round_, now, row)
            if proposal is not None:
                best = proposal
                break
        if best is not None and best.score >= 1.0:
            return best
    return best


def _reachable(round_: Round, now: SceneRecord, row) -> Proposal | None:
    """The label ``row`` (its commanded grasp) as a proposal, if the arm reaches it."""
    inst = now.instance(int(row.instance_id))
    T_obj_tcp = Transform.exact(
        [row.cmd_x, row.cmd_y, row.cmd_z], [row.cmd_qx, row.cmd_qy, row.cmd_qz, row.cmd_qw]
    )
    assert inst.T_table_obj is not None
    T_table_tcp = inst.T_table_obj * T_obj_tcp
    reach = round_.reach(T_table_tcp, float(row.cmd_width), inst.instance_id)
    if not reach.reachable:
        return None
    return Proposal(inst.instance_id, T_table_tcp, float(row.cmd_width), float(row.score), reach)


def random_policy(seed: int) -> Policy:
    """The random antipodal baseline (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        now = round_.now()
        trials = _trials(round_, now)
        try:
            for draw in range(POLICY_DRAWS):
                cands = trials.candidates(POLICY_CANDIDATES, seed, attempt=attempt, draw=draw)
                order = keyed_rng("clutter-random", int(seed), now.scene_id, attempt, draw).permutation(
                    len(cands)
                )
                proposal = _first_free(round_, now, trials, cands, order)
                if proposal is not None:
                    return proposal
        finally:
            trials.close()
        return None

    return propose


def _first_free(
    round_: Round, now: SceneRecord, trials: SceneTrials, cands: SceneCandidates, order: np.ndarray
) -> Proposal | None:
    """The first antipodal candidate in ``order`` that the kinematic check lets through (the scene as
    it is) and the arm reaches."""
    for k in order:
        if not cands.antipodal[k]:
            continue
        instance_id = int(cands.instance_id[k])
        T_obj_tcp = Transform.from_matrix(cands.T_obj_tcp[k])
        width = float(cands.width_expected[k])
        trials.reset()
        if trials.trials[instance_id].collides(T_obj_tcp, width).collided:
            continue
        inst = now.instance(instance_id)
        assert inst.T_table_obj is not None
        T_table_tcp = inst.T_table_obj * T_obj_tcp
        reach = round_.reach(T_table_tcp, width, instance_id)
        if reach.reachable:
            return Proposal(instance_id, T_table_tcp, width, 0.0, reach)
    return None


def file_policy(predictions: pd.DataFrame) -> Policy:
    """The best-scored untried prediction of the round that the arm can reach (module docstring)."""

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        rows = predictions[predictions["round"] == round_.record.scene_id]
        order = np.lexsort((rows.index.to_numpy(), -rows["score"].to_numpy(dtype=np.float64)))
        for k in order:
            index = int(rows.index[k])
            if index in tried:
                continue
            tried.add(index)
            row = rows.loc[index]
            T = Transform(row[["x", "y", "z"]].to_numpy(float), row[["qx", "qy", "qz", "qw"]].to_numpy(float))
            reach = round_.reach(T, float(row["width"]), -1)
            if reach.reachable:
                return Proposal(-1, T, float(row["width"]), float(row["score"]), reach)
        return None

    return propose


# --- the benchmark -----------------------------------------------------------------------------------------


def play_round(
    round_id: int,
    models: Mapping[str, ObjectModel],
    config: AnnotatorConfig,
    policy: Policy,
    *,
    seed: int,
    objects: int,
    gripper: GripperDescription | str | None = None,
) -> RoundResult:
    """One round (module docstring) on a pile of ``objects`` drawn from ``models``."""
    description = load_gripper(gripper)
    builder = SceneBuilder(models, scenes=config.scenes, physics=config.physics, cell=config.cell)
    record = builder.build(SceneSpec(round_id, seed, "pile", objects, objects))
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
            held, instance = round_.execute(proposal)
            oid = record.instance(instance).object_id if instance >= 0 else ""
            result.attempts.append(Attempt(round_id, len(result.attempts), proposal, held, instance, oid))
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
    (``labels``, ``random``, or a predictions table), trials per label, the gripper."""

    sources: tuple
    objects: int
    seed: int
    policy: str | pd.DataFrame
    config: AnnotatorConfig
    trials: int = 1
    gripper: GripperDescription | None = None
    cache_dir: str | None = None

    def make_policy(self) -> Policy:
        if isinstance(self.policy, pd.DataFrame):
            return file_policy(self.policy)
        if self.policy == "labels":
            return labels_policy(self.seed, self.trials)
        return random_policy(self.seed)


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
    )


def clutter_removal(job: ClutterJob, rounds: int, workers: int = 1) -> ClutterSummary:
    """Rounds 0..rounds-1 of ``job``, on ``workers`` processes (the figures do not depend on it)."""
    if workers <= 1:
        return ClutterSummary([run_round(job, r) for r in range(rounds)])
    from joblib import Parallel, delayed

    results = Parallel(n_jobs=workers)(delayed(run_round)(job, r) for r in range(rounds))
    return ClutterSummary(sorted(results, key=lambda r: r.round_id))
