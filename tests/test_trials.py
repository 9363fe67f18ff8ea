"""``--trials K``: perturbations are applied inside their trial, undone for the next, and counted.

A score is the fraction of the K trials that held; a candidate whose nominal pose collides gets
score 0 and no perturbed trial (docs/protocol.md, "Robust labels").
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pybullet as pb
import pytest
import trimesh

from annotator.config import AnnotatorConfig, RobustConfig
from annotator.geometry import Transform
from annotator.objects import ObjectSource, create_body, load_object, physics_for
from annotator.outcome import Outcome
from annotator.pipeline.modes import RestingMode
from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask
from annotator.pipeline.worker import label_span
from annotator.rng import object_rng
from annotator.sampler import sample_candidates
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial, Perturbation, _OffsetMass

CONFIG = AnnotatorConfig()
OBJECTS = Path(__file__).resolve().parent.parent / "objects"


@pytest.fixture(scope="module")
def brick(tmp_path_factory):
    """A 50 x 40 x 100 mm box on disk, its model and 24 candidates."""
    path = tmp_path_factory.mktemp("brick") / "brick.obj"
    trimesh.creation.box((0.05, 0.04, 0.10)).export(path)
    source = ObjectSource("brick", path)
    model = load_object(source, CONFIG.objects)
    cands = sample_candidates(model.mesh, 24, object_rng(0, "brick"), CONFIG.sampler, 0.11)
    return source, model, cands


def _dynamics(client: int, uid: int) -> tuple[float, float]:
    info = pb.getDynamicsInfo(uid, -1, physicsClientId=client)
    return info[0], info[1]  # mass, lateral friction


def test_a_perturbation_applies_inside_its_trial_and_not_in_the_next(brick):
    source, model, cands = brick
    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper)
        hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
        uid = create_body(world.client, model)
        trial = GraspTrial(world, hand, uid, CONFIG)
        nominal_mass, nominal_friction = _dynamics(world.client, uid)
        # a candidate that holds nominally
        k = next(
            i
            for i in range(len(cands))
            if trial.run(Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]).outcome
            == Outcome.SUCCESS
        )
        T = Transform.from_matrix(cands.T_obj_tcp[k])
        shift = Transform([0.0, 0.004, 0.0], [0, 0, 0, 1])  # 4 mm along the TCP's y (along the pads)
        p = Perturbation(shift, friction_delta=-0.3, mass_scale=1.25)
        # inside the trial: the object weighs and slides as perturbed (the state _run ends in) ...
        trial._run(T, cands.width_expected[k], p)
        mass, friction = _dynamics(world.client, uid)
        assert mass == pytest.approx(nominal_mass * 1.25) and friction == pytest.approx(
            nominal_friction - 0.3
        )
        # ... and once run() returns it is nominal again, exactly
        perturbed = trial.run(T, cands.width_expected[k], p)
        assert _dynamics(world.client, uid) == (nominal_mass, nominal_friction)
        # ... and the gripper closed at the perturbed pose, not the nominal one
        T_p = T * shift
        closed = perturbed.T_obj_tcp
        assert np.linalg.norm(closed.pos - T_p.pos) < 0.002, (closed.pos, T_p.pos)
        assert np.linalg.norm(closed.pos - T.pos) > 0.003
        # the next (nominal) trial has the nominal object again and repeats the nominal result
        again = trial.run(T, cands.width_expected[k])
        assert _dynamics(world.client, uid) == pytest.approx((nominal_mass, nominal_friction))
        assert again.outcome == Outcome.SUCCESS
        trial.close()


def _scores(source, cands, config: AnnotatorConfig, trials: int):
    span = Span("brick", source, None, 0, len(cands), GivenGrasps(cands.T_obj_tcp, cands.width_expected))
    return label_span(SpanTask(span=span, config=config, seed=0, n=len(cands), trials=trials)).rows


@pytest.mark.slow
def test_perturbed_trials_are_counted(brick):
    source, _, cands = brick
    # every range of a perturbation at 0 (not the implicit settings of the perturbed trials' steps)
    fields = dataclasses.fields(CONFIG.robust)
    ranges = (f for f in fields if f.type == "float" and not f.metadata.get("implicit"))
    zero = {f.name: 0.0 for f in ranges}
    still = dataclasses.replace(CONFIG, robust=dataclasses.replace(CONFIG.robust, **zero))
    wild = dataclasses.replace(CONFIG, robust=dataclasses.replace(CONFIG.robust, position_sigma=0.08))
    one = _scores(source, cands, CONFIG, 1)
    assert one["success"].sum() >= 3
    # zero perturbation: all K trials repeat the nominal one, so a success scores 1 (counted)
    calm = _scores(source, cands, still, 3)
    assert (calm["score"] == one["success"].astype(float)).all()
    # 8 cm of pose noise: every perturbed trial misses, so a success scores exactly 1/3 (applied)
    shaken = _scores(source, cands, wild, 3)
    assert np.allclose(shaken.loc[shaken["success"], "score"], 1 / 3)
    assert (shaken["outcome"] == one["outcome"]).all()  # trial 0 is the nominal one


def test_collision_rows_score_zero_and_run_no_perturbed_trial(brick):
    source, _, cands = brick
    rows = _scores(source, cands, CONFIG, 4)
    hits = rows[rows["outcome"] == "collision"]
    assert len(hits) >= 3
    assert (hits["score"] == 0.0).all() and (hits["sim_steps"] == 0).all()
    assert set(np.round(rows["score"] * 4, 9)) <= {0.0, 1.0, 2.0, 3.0, 4.0}


# The columns trial 0 alone decides (docs/labels.md): its outcome, the closed pose and width, and,
# resting, where the object settled.
TRIAL0_COLUMNS = ["outcome", "success", "width", "x", "y", "z", "qx", "qy", "qz", "qw", "slip"]


@pytest.mark.slow
def test_trial_0_is_the_same_whatever_the_number_of_trials():
    """Trial 0 is unperturbed and equal to ``--trials 1`` for any K, bit for bit.

    Grasps from above on the sample box resting on the table, each in an orientation of its own
    (evaluate --resting-grasps table, as real trials are replayed): each new orientation settles
    the object in the world where the previous candidate's perturbed trials ran. A perturbed
    trial used to leave its mass and friction on the object, so the object settled and trial 0
    ran with them: 2 of 25 real grasps flipped and poses moved up to 1.9 mm between K = 1 and 5.
    """
    source = ObjectSource("box", OBJECTS / "box.obj")
    model = load_object(source, CONFIG.objects)
    cands = sample_candidates(model.mesh, 200, object_rng(0, "box"), CONFIG.sampler, 0.11)
    above = np.flatnonzero(cands.T_obj_tcp[:, 2, 2] < -0.6)[:15]  # approach pointing down
    yaw = 0.4 * np.arange(len(above))  # each grasp its own orientation, as GRASPA's layouts
    rest = np.stack([0 * yaw, 0 * yaw, np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    given = GivenGrasps(cands.T_obj_tcp[above], cands.width_expected[above], None, rest)
    rows = {}
    for trials in (3, 1, 5):  # each under its own id: a fresh body, settled afresh
        oid = f"box_k{trials}"
        span = Span(oid, source, None, 0, len(above), given)
        result = label_span(
            SpanTask(span=span, config=CONFIG, seed=0, n=len(above), trials=trials, mode=RestingMode("table"))
        )
        assert result.error is None, result.error
        rows[trials] = result.rows
    one = rows[1]
    assert one["success"].sum() >= 2 and (one["outcome"] != "collision").sum() >= 3
    for trials in (3, 5):
        pd.testing.assert_frame_equal(
            rows[trials][TRIAL0_COLUMNS + ["settle_drift"]],
            one[TRIAL0_COLUMNS + ["settle_drift"]],
            check_exact=True,
        )
        assert (rows[trials]["sim_steps"] > one["sim_steps"]).sum() >= 2  # perturbed trials ran


def test_the_object_s_placement_error_moves_the_grasp_against_it():
    """The robot grasps where the object was planned to be; it sits shifted and turned about the
    vertical through its centre of mass, so the grasp moves by the inverse in the object's frame."""
    T_world_obj = Transform([0.1, -0.2, 0.05], [0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    com = T_world_obj.apply(np.array([0.01, 0.0, 0.02]))
    T_obj_tcp = Transform([0.03, 0.01, 0.08], [1.0, 0.0, 0.0, 0.0])  # from above
    none = Perturbation.none()
    assert np.allclose(none.T_obj_tcp(T_obj_tcp, T_world_obj, com).as_matrix(), T_obj_tcp.as_matrix())
    shift = np.array([0.002, -0.001, 0.0])
    moved = Perturbation(Transform.identity(), 0.0, 1.0, object_shift=shift)
    T_world_tcp = T_world_obj * moved.T_obj_tcp(T_obj_tcp, T_world_obj, com)
    assert np.allclose(T_world_tcp.pos, (T_world_obj * T_obj_tcp).pos - shift)
    assert np.allclose(T_world_tcp.rotation, (T_world_obj * T_obj_tcp).rotation)
    yaw = 0.1
    turned = Perturbation(Transform.identity(), 0.0, 1.0, object_rotvec=np.array([0.0, 0.0, yaw]))
    planned, executed = T_world_obj * T_obj_tcp, T_world_obj * turned.T_obj_tcp(T_obj_tcp, T_world_obj, com)
    # the same distance from the vertical through the centre of mass, turned by -yaw about it
    r0, r1 = (planned.pos - com)[:2], (executed.pos - com)[:2]
    assert np.isclose(np.linalg.norm(r0), np.linalg.norm(r1))
    assert np.isclose(np.arctan2(r0[0] * r1[1] - r0[1] * r1[0], r0 @ r1), -yaw)
    assert np.isclose(executed.pos[2], planned.pos[2])
    # the TCP's own error composes in the TCP frame, after the object's
    tcp = Transform([0.0, 0.0, 0.001], [0.0, 0.0, 0.0, 1.0])
    both = Perturbation(tcp, 0.0, 1.0, object_rotvec=np.array([0.0, 0.0, yaw]))
    assert np.allclose(
        both.T_obj_tcp(T_obj_tcp, T_world_obj, com).as_matrix(),
        (turned.T_obj_tcp(T_obj_tcp, T_world_obj, com) * tcp).as_matrix(),
    )


def test_a_perturbed_grip_force_squeezes_with_it(brick):
    """``force_scale`` scales the squeeze of that trial: half the force, half the pads' normal force."""
    source, model, cands = brick
    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper)
        hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
        uid = create_body(world.client, model)
        trial = GraspTrial(world, hand, uid, CONFIG)
        k = next(
            i
            for i in range(len(cands))
            if trial.run(Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]).outcome
            == Outcome.SUCCESS
        )
        T, w = Transform.from_matrix(cands.T_obj_tcp[k]), cands.width_expected[k]
        forces = []
        for scale in (1.0, 0.5):
            trial._run(T, w, Perturbation(Transform.identity(), 0.0, 1.0, force_scale=scale))
            forces.append(float(np.sum(hand.gripper.pad_normal_forces(uid))))
        trial.close()
    assert forces[1] == pytest.approx(forces[0] / 2, rel=0.1), forces


def _brick_trial(world: World, model, config: AnnotatorConfig) -> GraspTrial:
    """The brick's trial in ``world``, set up as a floating worker sets it up (gripper parked)."""
    hand = FloatingGripper(world, config.gripper)
    hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
    return GraspTrial(world, hand, create_body(world.client, model), config)


def _same(a, b) -> bool:
    """Two trial results equal to the bit: outcome, width, steps, slip, closed pose."""
    return (
        a.outcome == b.outcome
        and a.width == b.width
        and a.steps == b.steps
        and (a.slip == b.slip or (np.isnan(a.slip) and np.isnan(b.slip)))
        and np.array_equal(a.T_obj_tcp.pos, b.T_obj_tcp.pos)
        and np.array_equal(a.T_obj_tcp.quat, b.T_obj_tcp.quat)
    )


@pytest.mark.slow
def test_a_perturbed_trial_in_the_shared_world_equals_it_in_a_fresh_world(brick):
    """The K trials of a candidate share the world and the object's saved state: a perturbed trial
    run after other candidates' trials and its own candidate's earlier trials gives, to the bit,
    what it gives alone in a world built for it."""
    _, model, cands = brick
    rng = np.random.default_rng(7)
    runs = []  # (pose, chord, perturbation, result) of every perturbed trial run in the shared world
    with World(CONFIG.physics) as world:
        trial = _brick_trial(world, model, CONFIG)
        for i in range(8):
            T, width = Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]
            if trial.run(T, width).outcome == Outcome.COLLISION:
                continue
            for _ in range(2):
                p = Perturbation.sample(rng, CONFIG.robust)
                runs.append((T, width, p, trial.run(T, width, p)))
    assert len(runs) >= 4 and any(r.outcome == Outcome.SUCCESS for *_, r in runs)
    for T, width, p, shared in runs[-1:] + runs[1::3]:
        with World(CONFIG.physics) as world:
            fresh = _brick_trial(world, model, CONFIG).run(T, width, p)
        assert _same(shared, fresh), (shared, fresh)


def test_a_perturbed_trial_ends_at_the_lift_unless_its_ranges_shake(brick):
    """``[robust] shake`` false (the default): a perturbed trial is trial 0's protocol up to the
    lift and judged there, to the bit the trial of a gripper that never shakes where its close
    stalls by speed as trial 0's (``[robust] stall_by_travel = false``), and the same outcome
    no later when it also stalls by travel (the default); true: it shakes as trial 0 does. Trial 0
    shakes either way."""
    _, model, cands = brick
    assert CONFIG.robust.shake is False
    shaking = dataclasses.replace(CONFIG, robust=dataclasses.replace(CONFIG.robust, shake=True))
    by_speed = dataclasses.replace(CONFIG, robust=dataclasses.replace(CONFIG.robust, stall_by_travel=False))
    nothing = Perturbation(Transform.identity(), 0.0, 1.0)  # a perturbed trial that changes nothing
    heavy = Perturbation(Transform.identity(), 0.0, 200.0)  # too heavy: it slides out on the lift
    with World(CONFIG.physics) as world:
        trial = _brick_trial(world, model, CONFIG)
        uid = trial.obj
        never = GraspTrial(world, trial.hand, uid, CONFIG, shake=False)
        both = GraspTrial(world, trial.hand, uid, shaking)
        speed = GraspTrial(world, trial.hand, uid, by_speed)
        k = next(
            i
            for i in range(len(cands))
            if trial.run(Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]).outcome
            == Outcome.SUCCESS
        )
        T, w = Transform.from_matrix(cands.T_obj_tcp[k]), cands.width_expected[k]
        first, lifted, unshaken = trial.run(T, w), speed.run(T, w, nothing), never.run(T, w)
        shaken = both.run(T, w, nothing)
        by_travel = trial.run(T, w, nothing)
        slid = trial.run(T, w, heavy)
        for t in (trial, never, both, speed):
            t.close()
    assert first.outcome == lifted.outcome == shaken.outcome == by_travel.outcome == Outcome.SUCCESS
    assert _same(lifted, unshaken) and _same(shaken, first), (lifted, unshaken, shaken, first)
    assert by_travel.steps <= lifted.steps and abs(by_travel.width - lifted.width) < 2e-4, (by_travel, lifted)
    shake_steps = round(CONFIG.protocol.shake_duration / CONFIG.physics.time_step)
    assert first.steps - lifted.steps >= shake_steps - CONFIG.protocol.check_every, (first, lifted)
    assert slid.outcome == Outcome.SLIPPED_LIFT


@pytest.mark.slow
def test_a_light_object_s_perturbed_trial_ends_at_the_lift_at_its_own_step(tmp_path):
    """A 19 g plate, simulated at its finer step (annotator.objects.physics_for), lifted and shaken
    there too (under light_hold_mass): a perturbed trial that changes nothing, its close stalled by
    speed as trial 0's, is, to the bit, the trial of a gripper that never shakes, and it is shorter
    than trial 0 by the shake's steps at that step."""
    path = tmp_path / "plate.obj"
    trimesh.creation.box((0.06, 0.04, 0.016)).export(path)
    model = load_object(ObjectSource("plate", path), CONFIG.objects)
    physics = physics_for(model, CONFIG.physics)
    assert model.mass < CONFIG.physics.light_object_mass and physics.time_step < CONFIG.physics.time_step
    cands = sample_candidates(model.mesh, 24, object_rng(0, "plate"), CONFIG.sampler, 0.11)
    nothing = Perturbation(Transform.identity(), 0.0, 1.0)
    with World(physics) as world:
        trial = _brick_trial(world, model, CONFIG)
        never = GraspTrial(world, trial.hand, trial.obj, CONFIG, shake=False)
        by_speed = dataclasses.replace(CONFIG.robust, stall_by_travel=False)
        speed = GraspTrial(world, trial.hand, trial.obj, dataclasses.replace(CONFIG, robust=by_speed))
        held = [
            i
            for i in range(len(cands))
            if trial.run(Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]).outcome
            == Outcome.SUCCESS
        ]
        assert held
        T, w = Transform.from_matrix(cands.T_obj_tcp[held[0]]), cands.width_expected[held[0]]
        first, lifted, unshaken = trial.run(T, w), speed.run(T, w, nothing), never.run(T, w)
        for t in (trial, never, speed):
            t.close()
    assert lifted.outcome == first.outcome == Outcome.SUCCESS and _same(lifted, unshaken), (lifted, unshaken)
    assert model.mass < CONFIG.physics.light_hold_mass
    shake_steps = round(CONFIG.protocol.shake_duration / physics.time_step)
    assert first.steps - lifted.steps >= shake_steps - CONFIG.protocol.check_every, (first, lifted)


def test_only_a_light_object_at_its_own_finer_step_is_held_at_the_run_s_time_step():
    """PhysicsConfig.held: an object of at least light_hold_mass simulated at its own finer step is
    lifted and shaken at the run's time step with the hold's contact ERP, everything else kept.
    The same settings throughout (None) for: a heavy object, one lighter than light_hold_mass, one
    in a world that steps finer for a lighter neighbour, and light_hold_mass >= light_object_mass."""
    base = CONFIG.physics
    assert base.light_hold_mass < base.light_object_mass
    for grams, n in ((39.9, 2), (20.0, 2), (10.0, 2), (9.9, 3), (4.0, 4), (40.0, 1)):
        assert base.substeps(grams / 1000) == n, grams
    finer = dataclasses.replace(base, time_step=base.time_step / 2)  # physics_for of 10-40 g
    held = finer.held(base, 0.032)
    hold_erp = base.light_hold_contact_erp
    assert held == dataclasses.replace(finer, time_step=base.time_step, contact_erp=hold_erp)
    assert held.contact_erp != base.contact_erp and held.solver_iterations == base.solver_iterations
    assert finer.held(base, base.light_hold_mass) is not None
    assert base.held(base, 0.2) is None  # heavy
    assert finer.held(base, 0.027) is None  # under light_hold_mass
    assert dataclasses.replace(base, time_step=base.time_step / 3).held(base, 0.008) is None  # 8 g
    assert dataclasses.replace(base, time_step=base.time_step / 4).held(base, 0.032) is None  # a neighbour's
    never = dataclasses.replace(base, light_hold_mass=base.light_object_mass)
    assert finer.held(never, 0.032) is None


@pytest.mark.slow
def test_a_light_object_is_closed_on_at_its_finer_step_then_lifted_and_shaken_at_the_run_s(tmp_path):
    """A 30 g plate (1/480 s): every step of the close is at its finer step and every step of the
    lift and shake at the run's time step with the hold's contact ERP; the world steps finer again
    for the next trial. With light_hold_mass = light_object_mass every step is at the finer step:
    the same close, so the same width to the bit, and twice the steps for the lift and shake. Only
    a floating object is held so: a trial of one resting on a table keeps the finer step."""
    path = tmp_path / "plate.obj"
    trimesh.creation.box((0.06, 0.04, 0.025)).export(path)
    model = load_object(ObjectSource("plate", path), CONFIG.objects)
    physics = physics_for(model, CONFIG.physics)
    assert physics.time_step == CONFIG.physics.time_step / 2 and model.mass >= CONFIG.physics.light_hold_mass
    never = dataclasses.replace(CONFIG.physics, light_hold_mass=CONFIG.physics.light_object_mass)
    finer = dataclasses.replace(CONFIG, physics=never)
    cands = sample_candidates(model.mesh, 24, object_rng(0, "plate"), CONFIG.sampler, 0.11)
    with World(physics) as world:
        trial = _brick_trial(world, model, CONFIG)
        throughout = GraspTrial(world, trial.hand, trial.obj, finer)
        steps: list[tuple[float, float]] = []
        world.before_step = lambda: steps.append((world.dt, world.physics.contact_erp))
        results = []
        for i in range(len(cands)):
            T, w = Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]
            steps.clear()
            held = trial.run(T, w)
            if held.outcome != Outcome.SUCCESS:
                continue
            held_steps = list(steps)
            assert world.physics == physics  # the next trial starts at the finer step
            steps.clear()
            results.append((held, held_steps, throughout.run(T, w), list(steps)))
            if len(results) == 2:
                break
        resting = GraspTrial(world, trial.hand, trial.obj, CONFIG, resting=True)
        assert trial._held_physics() is not None and resting._held_physics() is None  # the cell, scenes
        for t in (trial, throughout, resting):
            t.close()
    assert len(results) == 2
    lift_shake = round(CONFIG.protocol.lift_duration / CONFIG.physics.time_step) + round(
        CONFIG.protocol.shake_duration / CONFIG.physics.time_step
    )
    fine_step = (physics.time_step, CONFIG.physics.contact_erp)
    hold_step = (CONFIG.physics.time_step, CONFIG.physics.light_hold_contact_erp)
    for held, held_steps, fine, fine_steps in results:
        close = len(held_steps) - lift_shake
        assert close > 0 and held_steps == [fine_step] * close + [hold_step] * lift_shake
        assert fine_steps == [fine_step] * len(fine_steps) and len(fine_steps) == close + 2 * lift_shake
        assert fine.width == held.width and fine.outcome == Outcome.SUCCESS


@pytest.mark.slow
def test_leaving_a_trial_once_the_object_is_lost_gives_the_full_trial_s_verdict(brick):
    """The loss monitor ends a lift or shake once the object has left the pads, and a trial lost in
    the shake skips the settling before the verdict. With a check too rare to ever fire the same
    trials run to the end: the same candidates hold, and those lost in the shake end
    ``slipped_shake`` either way, in fewer steps when they leave early."""
    _, model, cands = brick
    settle = dataclasses.replace(CONFIG.protocol, settle_time=0.05)
    shaken = dataclasses.replace(CONFIG.robust, shake=True)  # the perturbed trials below shake
    early = dataclasses.replace(CONFIG, protocol=settle, robust=shaken)
    full = dataclasses.replace(early, protocol=dataclasses.replace(settle, check_every=1_000_000))
    slippery = Perturbation(Transform.identity(), friction_delta=-0.85, mass_scale=4.0)
    results = []
    for config in (early, full):
        with World(config.physics) as world:
            trial = _brick_trial(world, model, config)
            results.append(
                [
                    trial.run(Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i], slippery)
                    for i in range(12)
                ]
            )
    left_early = 0
    for a, b in zip(*results, strict=True):
        assert (a.outcome == Outcome.SUCCESS) == (b.outcome == Outcome.SUCCESS)
        if a.outcome == Outcome.SLIPPED_SHAKE:
            assert b.outcome == Outcome.SLIPPED_SHAKE and a.steps <= b.steps
            left_early += a.steps < b.steps
        elif a.outcome != Outcome.SLIPPED_LIFT:
            assert a.outcome == b.outcome and a.steps == b.steps
    assert left_early >= 2


# --- where the mass sits ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bar(tmp_path_factory):
    """A 240 x 30 x 30 mm bar's model (108 g at the default density)."""
    path = tmp_path_factory.mktemp("bar") / "bar.obj"
    trimesh.creation.box((0.24, 0.03, 0.03)).export(path)
    return load_object(ObjectSource("bar", path), CONFIG.objects)


def test_a_moved_centre_of_mass_pulls_with_its_weight_about_the_model_s(bar):
    """Pinned at the model's centre of mass, a bar whose mass sits 5 cm along +x swings as a
    pendulum: +x goes down (rotation about +y) at m g r / I, and with no offset it stays still."""
    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper)
        hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
        uid = create_body(world.client, bar)
        trial = GraspTrial(world, hand, uid, CONFIG)
        info = pb.getDynamicsInfo(uid, -1, physicsClientId=world.client)
        mass, inertia_y = info[0], info[2][1]
        spins = {}
        for offset in (0.05, 0.0):
            world.restore_state(trial.state)
            pb.resetBasePositionAndOrientation(uid, [0, 0, 1], [0, 0, 0, 1], physicsClientId=world.client)
            pin = pb.createConstraint(
                uid,
                -1,
                -1,
                -1,
                pb.JOINT_POINT2POINT,
                [0, 0, 0],
                [0, 0, 0],
                [0, 0, 1],
                physicsClientId=world.client,
            )
            p = Perturbation(Transform.identity(), 0.0, 1.0, com_offset=np.array([offset, 0.0, 0.0]))
            world.before_step = _OffsetMass(trial, p) if offset else None
            world.set_gravity(True)
            world.step(24)  # 0.1 s: the bar turns a few degrees
            world.before_step = None
            spins[offset] = np.asarray(pb.getBaseVelocity(uid, physicsClientId=world.client)[1])
            pb.removeConstraint(pin, physicsClientId=world.client)
        expected = mass * 9.81 * 0.05 / inertia_y * 0.1  # rad/s after 0.1 s, small angles
        assert spins[0.05][1] == pytest.approx(expected, rel=0.1)
        assert abs(spins[0.05][0]) < 1e-6 and abs(spins[0.05][2]) < 1e-6
        assert np.abs(spins[0.0]).max() < 1e-9


def test_a_moved_centre_of_mass_turns_the_lifted_object_in_the_grip_its_way(bar):
    """Grasped at its middle from above and lifted (no shake), a heavy slippery bar stays level
    with its mass where the model has it, and dips the end its mass is moved to otherwise. The lift
    is a fast one (0.2 s, 1.5 g): its inertial load, r x m (g - a), turns the bar within the trial,
    where the pads' torsion holds it against its weight alone at a real arm's pace."""
    R_obj_tcp = np.column_stack([[0, 1, 0], [1, 0, 0], [0, 0, -1]])  # close across y, approach down
    T = Transform.from_rotation(R_obj_tcp, [0, 0, 0])
    fast = dataclasses.replace(CONFIG, protocol=dataclasses.replace(CONFIG.protocol, lift_duration=0.2))
    with World(fast.physics) as world:
        hand = FloatingGripper(world, fast.gripper)
        hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
        uid = create_body(world.client, bar)
        trial = GraspTrial(world, hand, uid, fast, shake=False)
        dips = {}
        for offset in (0.0, 0.1, -0.1):
            p = Perturbation(Transform.identity(), -0.7, 3.0, com_offset=np.array([offset, 0.0, 0.0]))
            assert trial.run(T, 0.03, p).outcome == Outcome.SUCCESS  # turned in the grip, still held
            orn = pb.getBasePositionAndOrientation(uid, physicsClientId=world.client)[1]
            dips[offset] = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)[2, 0]  # bar x, world z
        assert abs(dips[0.0]) < 0.05
        assert dips[0.1] < -0.5 and dips[-0.1] > 0.5, dips
        assert world.before_step is None  # the load ends with its trial


def test_the_centre_of_mass_is_drawn_last_and_only_when_set():
    """Runs made without it draw exactly what they drew before it existed; with it, the other
    draws are the same."""
    without = Perturbation.sample(np.random.default_rng(7), RobustConfig())
    within = Perturbation.sample(np.random.default_rng(7), RobustConfig(com_offset_sigma=0.005))
    assert not np.any(without.com_offset) and np.all(within.com_offset != 0)
    assert np.abs(within.com_offset).max() < 0.05
    for name in ("friction_delta", "mass_scale", "force_scale"):
        assert getattr(without, name) == getattr(within, name)
    assert np.array_equal(without.object_shift, within.object_shift)
    assert np.array_equal(without.T_tcp_tcp.as_matrix(), within.T_tcp_tcp.as_matrix())
    rng = np.random.default_rng(7)
    Perturbation.sample(rng, RobustConfig())
    after = rng.bit_generator.state
    reference = np.random.default_rng(7)  # the nine draws of a perturbation without a centre of mass
    for draw in ("normal3", "normal3", "uniform", "uniform", "normal2", "normal2", "normal", "uniform"):
        if draw == "uniform":
            reference.uniform(0.0, 1.0)
        else:
            reference.normal(0.0, 1.0, int(draw[-1]) if draw[-1].isdigit() else None)
    assert after == reference.bit_generator.state


def test_a_trial_takes_its_gripper_s_robust_table(my_rg2):
    toml = my_rg2 / "gripper.toml"
    toml.write_text(toml.read_text() + "\n[robust]\ncom_offset_sigma = 0.004\nobject_yaw_sigma = 0.1\n")
    from annotator.grippers import load_gripper

    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper, load_gripper(my_rg2))
        uid = create_body(world.client, load_object(ObjectSource("box", OBJECTS / "box.obj"), CONFIG.objects))
        trial = GraspTrial(world, hand, uid, CONFIG)
        assert (trial.robust.com_offset_sigma, trial.robust.object_yaw_sigma) == (0.004, 0.1)
        assert trial.robust.friction_delta == CONFIG.robust.friction_delta


@pytest.mark.slow
def test_a_perturbed_trial_s_simulated_approach_starts_near_the_first_contact(brick):
    """A lift-only perturbed trial's simulated approach starts ``[robust] approach_lead`` before the first
    increment of the kinematic sweep that touches the brick, not ``approach_distance`` back: the
    free travel it skips changes nothing but time. Against the whole approach
    (``approach_from_contact = false``), the same trials hold and slip, close to the same width,
    in fewer steps; trial 0 approaches in full either way."""
    _, model, cands = brick
    simulated = AnnotatorConfig.from_dict({"protocol": {"approach": "simulated", "approach_speed": 0.1}})
    in_full = dataclasses.replace(simulated.robust, approach_from_contact=False)
    full = dataclasses.replace(simulated, robust=in_full)
    assert simulated.robust.approach_from_contact
    nothing = Perturbation(Transform.identity(), 0.0, 1.0)
    heavy = Perturbation(Transform.identity(), 0.0, 200.0)  # slides out on the lift
    p = simulated.protocol
    pairs, trial0 = [], []
    with World(simulated.physics) as world:
        near = _brick_trial(world, model, simulated)
        whole = GraspTrial(world, near.hand, near.obj, full)
        for i in range(10):
            T, w = Transform.from_matrix(cands.T_obj_tcp[i]), cands.width_expected[i]
            trial0.append((near.run(T, w), whole.run(T, w)))
            for perturbation in (nothing, heavy):
                pairs.append((near.run(T, w, perturbation), whole.run(T, w, perturbation)))
        # the sweep towards a pose 4 cm inside the brick: the distance it returns touches nothing,
        # the next increment touches the brick
        near.world.restore_state(near.state)
        deeper = Transform([0.0, 0.0, 0.04], [0.0, 0.0, 0.0, 1.0])
        T_world_tcp = near._T_world_obj() * Transform.from_matrix(cands.T_obj_tcp[0]) * deeper
        width = cands.width_expected[0]
        open_width = min(near.hand.gripper.max_width, width + 2 * p.pregrasp_clearance)
        T_world_base = near.hand.T_world_base_for_tcp(T_world_tcp, width)
        axis = T_world_tcp.rotation[:, 2]
        start = Transform(T_world_base.pos - axis * p.approach_distance, T_world_base.quat)
        near.hand.teleport(start, open_width)
        free = near._free_travel(start, axis)
        touched = []
        for d in (free, free + p.approach_step):
            near.hand.body.reset_base_pose(Transform(start.pos + axis * d, start.quat))
            touched.append(near._what_is_hit(skip_pads=False))
        near.close()
        whole.close()
    assert 0.0 < free < p.approach_distance and touched == [None, near.obj], (free, touched)
    assert all(_same(a, b) for a, b in trial0)  # trial 0 runs the whole approach either way
    tried = [(a, b) for a, b in pairs if b.outcome != Outcome.COLLISION]
    assert len(tried) >= 8 and {b.outcome for _, b in tried} >= {Outcome.SUCCESS, Outcome.SLIPPED_LIFT}
    for a, b in pairs:
        assert a.outcome == b.outcome, (a, b)
        if b.outcome != Outcome.COLLISION:
            assert a.steps < b.steps, (a, b)
        if b.outcome == Outcome.SUCCESS:  # held the same: the same width, the same slip
            assert abs(a.width - b.width) < 2e-4 and abs(a.slip - b.slip) < 2e-4, (a, b)
    saved = sum(b.steps - a.steps for a, b in tried) / len(tried)
    lead = round(RobustConfig().approach_lead / p.approach_speed / simulated.physics.time_step)
    assert saved > lead, saved  # more than the lead's steps saved on average
