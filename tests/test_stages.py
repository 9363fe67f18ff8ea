"""How far a trial held: the stages every trial records, the benchmark motion, the gate.

docs/protocol.md, "Stages": a trial closes, lifts, runs the benchmark's slow motion (when the
protocol has one) and shakes; each trial records the furthest stage it held through, the row's
``stage`` is trial 0's, ``trial_stages`` every trial's, and ``success`` is trial 0 held through
``[protocol] gate``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pybullet as pb
import pytest
import trimesh

from annotator.config import AnnotatorConfig, RobustConfig
from annotator.dataset import held_through
from annotator.geometry import Transform
from annotator.objects import ObjectSource, create_body, load_object
from annotator.outcome import Outcome, Stage
from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask
from annotator.pipeline.worker import label_span
from annotator.rng import object_rng
from annotator.sampler import sample_candidates
from annotator.sim.hand import BenchmarkMotion, FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial, Perturbation

CONFIG = AnnotatorConfig()
# GRASPA's stability motion: 45 deg about the approach axis, 30 deg about the closing axis
MOTION = {"motion_approach_angle": np.pi / 4, "motion_closing_angle": np.pi / 6}


def _with(config: AnnotatorConfig, **sections) -> AnnotatorConfig:
    """``config`` with fields replaced per section: ``_with(c, protocol={"gate": "lift"})``."""
    return dataclasses.replace(
        config, **{name: dataclasses.replace(getattr(config, name), **v) for name, v in sections.items()}
    )


@pytest.fixture(scope="module")
def brick(tmp_path_factory):
    """A 50 x 40 x 100 mm box on disk, its source and 24 candidates."""
    path = tmp_path_factory.mktemp("brick") / "brick.obj"
    trimesh.creation.box((0.05, 0.04, 0.10)).export(path)
    source = ObjectSource("brick", path)
    model = load_object(source, CONFIG.objects)
    cands = sample_candidates(model.mesh, 24, object_rng(0, "brick"), CONFIG.sampler, 0.11)
    return source, cands


def _rows(source, cands, config: AnnotatorConfig, trials: int):
    span = Span("brick", source, None, 0, len(cands), GivenGrasps(cands.T_obj_tcp, cands.width_expected))
    return label_span(SpanTask(span=span, config=config, seed=0, n=len(cands), trials=trials)).rows


def test_every_trial_records_how_far_it_held(brick):
    """A digit per trial, trial 0 first, its outcome's stage; a collision runs no perturbed trial."""
    source, cands = brick
    rows = _rows(source, cands, CONFIG, 3)
    by_outcome = {
        "success": "4",
        "slipped_shake": "3",  # no motion stage: holding through the lift passes it
        "slipped_lift": "1",  # closed on it, lost in the lift or found slipped as it ended
        "no_contact": "0",
        "collision": "0",
    }
    assert {"success", "collision"} <= set(rows["outcome"])
    for r in rows.itertuples():
        assert r.trial_stages[0] in by_outcome[r.outcome], (r.outcome, r.trial_stages)
        assert r.stage == Stage(int(r.trial_stages[0])).label
        if r.outcome == "collision":
            assert r.trial_stages == "0" and r.score == 0.0
        else:  # trial 0 and two perturbed trials, which end at the lift: at most "lifted", passed on
            assert len(r.trial_stages) == 3 and set(r.trial_stages[1:]) <= set("0123"), r.trial_stages
            held = int(r.trial_stages[0] == "4") + sum(d == "3" for d in r.trial_stages[1:])
            assert r.score == pytest.approx(held / 3)
    assert (rows["success"] == (rows["stage"] == "shaken")).all()
    assert (held_through(rows, "lift") == rows["stage"].isin(["lifted", "moved", "shaken"])).all()
    assert (held_through(rows, "shake") == rows["success"]).all()


def test_the_stages_change_nothing_of_a_trial_without_a_motion_stage(brick):
    """Without a motion stage the protocol is what it was: a success is shaken right after the
    lift, and a protocol whose motion is configured but not run (the trial's own plan ends at the
    lift) simulates the same steps as one without."""
    source, cands = brick
    motion = _with(CONFIG, protocol=MOTION)
    plain, moved = _rows(source, cands, CONFIG, 1), _rows(source, cands, motion, 1)
    assert (plain["stage"].isin(["none", "closed", "moved", "shaken"])).all()
    ok = plain["outcome"].eq("success") & moved["outcome"].eq("success")
    assert ok.sum() >= 3
    motion_steps = round(CONFIG.protocol.motion_duration / CONFIG.physics.time_step)
    extra = moved.loc[ok, "sim_steps"].to_numpy() - plain.loc[ok, "sim_steps"].to_numpy()
    assert np.all(np.abs(extra - motion_steps) <= 6), extra  # each move rounds to whole steps
    assert (moved.loc[ok, "stage"] == "shaken").all()
    # the closed pose and width are the close's: the stages after it cannot change them
    for c in ("x", "y", "z", "qx", "qy", "qz", "qw", "width"):
        assert (plain[c].to_numpy() == moved[c].to_numpy()).all(), c


@pytest.fixture(scope="module")
def post_file(tmp_path_factory):
    """A 30 x 30 x 240 mm post standing along z (108 g at the default density), on disk."""
    path = tmp_path_factory.mktemp("post") / "post.obj"
    trimesh.creation.box((0.03, 0.03, 0.24)).export(path)
    return ObjectSource("post", path)


# Grasped from the side 6 cm below its centre: approach along world +x, closing along world y.
POST_GRASP = Transform.from_rotation(np.column_stack([[0, 1, 0], [0, 0, 1], [1, 0, 0]]), [0.0, 0.0, -0.06])
# A light squeeze on a slippery post: the pads carry its weight (2 x 0.3 x 5 N = 3 N against 1.06 N)
# and, upright, nothing turns it; tilted 30 deg its weight's torque about the pads (m g 6 cm sin 30
# = 32 mN m) is more than the friction of the pads' contact patch resists at 5 N.
TWISTABLE = {"gripper": {"grip_force": 5.0}, "objects": {"lateral_friction": 0.3}}


def _post_trial(world: World, source: ObjectSource, config: AnnotatorConfig) -> GraspTrial:
    hand = FloatingGripper(world, config.gripper)
    hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
    model = load_object(source, config.objects)
    return GraspTrial(world, hand, create_body(world.client, model), config)


def test_the_benchmark_motion_turns_a_post_held_below_its_centre_out_of_the_grip(post_file):
    """A twist: lifted straight up, the post stays held; turned 30 deg about the closing axis its
    weight turns it in the pads and it is lost in the motion (``slipped_motion``, stage
    ``lifted``). With the gate at the lift the row is a success all the same, and without a
    motion stage the shake's turns lose it (``slipped_shake``, stage ``moved``: no motion to
    fail)."""
    twist = _with(CONFIG, **TWISTABLE, protocol=MOTION)
    lift_gate = _with(twist, protocol={"gate": "lift"})
    no_motion = _with(CONFIG, **TWISTABLE)
    results = {}
    for name, config in (("twist", twist), ("no_motion", no_motion), ("lift_gate", lift_gate)):
        with World(config.physics) as world:
            trial = _post_trial(world, post_file, config)
            result = trial.run(POST_GRASP, 0.03)
            orn = pb.getBasePositionAndOrientation(trial.obj, physicsClientId=world.client)[1]
            results[name] = (result, trial.gate, pb.getMatrixFromQuaternion(orn)[8])  # post axis . z
            trial.close()
    twisted, gate, tilt = results["twist"]
    assert twisted.outcome == Outcome.SLIPPED_MOTION and twisted.stage == Stage.LIFTED, twisted
    assert tilt < np.cos(np.radians(20)), tilt  # the post's axis turned away from the vertical
    shaken = results["no_motion"][0]
    assert shaken.outcome == Outcome.SLIPPED_SHAKE and shaken.stage == Stage.MOVED, shaken
    gated, lift_gate_stage, _ = results["lift_gate"]
    assert lift_gate_stage == Stage.LIFTED and gate == Stage.SHAKEN
    assert gated.outcome == Outcome.SLIPPED_MOTION and gated.stage >= lift_gate_stage


def test_the_gate_decides_success_and_trial_0_s_share_of_the_score(post_file):
    """The post's row with the gate at the lift: success, score 1 of 1 (trial 0 held through the
    gate) though the motion lost it; at the shake (the default): a failure."""
    source = post_file
    T = POST_GRASP.as_matrix()[None]
    given = GivenGrasps(T, np.array([0.03]))
    twist = _with(CONFIG, **TWISTABLE, protocol=MOTION)
    rows = {}
    for gate in ("lift", "shake"):
        config = _with(twist, protocol={"gate": gate})
        task = SpanTask(span=Span("post", source, None, 0, 1, given), config=config, seed=0, n=1, trials=1)
        rows[gate] = label_span(task).rows.iloc[0]
    for row in rows.values():
        assert row["outcome"] == "slipped_motion" and row["stage"] == "lifted", row
    assert rows["lift"]["success"] and rows["lift"]["score"] == 1.0
    assert not rows["shake"]["success"] and rows["shake"]["score"] == 0.0


def test_benchmark_motion_turns_about_the_tcp_and_comes_back():
    """The motion's moves (+a, -a, 0 about the approach; +b, -b, 0 about the closing axis) with one
    peak angular acceleration, and the carrier back where it started; nothing without angles."""
    m = BenchmarkMotion(np.pi / 4, np.pi / 6, 1.5)
    assert [(axis, round(a, 6), round(b, 6)) for axis, a, b in m.moves()] == [
        (2, 0.0, round(np.pi / 4, 6)),
        (2, round(np.pi / 4, 6), round(-np.pi / 4, 6)),
        (2, round(-np.pi / 4, 6), 0.0),
        (0, 0.0, round(np.pi / 6, 6)),
        (0, round(np.pi / 6, 6), round(-np.pi / 6, 6)),
        (0, round(-np.pi / 6, 6), 0.0),
    ]
    assert not BenchmarkMotion(0.0, 0.0, 1.5).active and BenchmarkMotion(0.0, 0.0, 1.5).moves() == []
    roots = sum(abs(b - a) ** 0.5 for _, a, b in m.moves())
    assert m.peak_angular_acceleration == pytest.approx(6 * roots**2 / 1.5**2)
    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper)
        start = Transform([0.1, 0.2, 0.5], [0, 0, 0, 1])
        hand.teleport(start, 0.05)
        T_base_tcp = hand.gripper.T_base_tcp(hand.gripper.measured_width())
        targets: list[Transform] = []

        def watch(i: int) -> bool:
            targets.append(hand.target)
            return False

        original = hand._follow

        def follow(pos, quat, force, on_step):  # record every carrier pose the motion commands
            targets.extend(Transform(p, q) for p, q in zip(pos, quat, strict=True))
            return original(pos, quat, force, None)

        hand._follow = follow
        steps = hand.benchmark_motion(m, force=10.0, on_step=watch)
    assert abs(steps - round(1.5 / CONFIG.physics.time_step)) <= 6 and len(targets) == steps
    assert np.array_equal(hand.target.pos, start.pos) and np.array_equal(hand.target.quat, start.quat)
    tcp = np.array([(t * T_base_tcp).pos for t in targets])
    assert np.abs(tcp - (start * T_base_tcp).pos).max() < 1e-9  # every pose turns about the TCP
    R = np.array([t.rotation for t in targets])
    about_z = np.degrees(np.arctan2(R[:, 1, 0], R[:, 0, 0]))  # the approach (z) turn
    about_x = np.degrees(np.arctan2(R[:, 2, 1], R[:, 2, 2]))  # the closing-axis (x) turn
    assert about_z.max() == pytest.approx(45, abs=1e-6) and about_z.min() == pytest.approx(-45, abs=1e-6)
    assert about_x.max() == pytest.approx(30, abs=1e-6) and about_x.min() == pytest.approx(-30, abs=1e-6)
    assert abs(about_z[-1]) < 1e-9 and abs(about_x[-1]) < 1e-9


def test_perturbed_trials_run_after_a_colliding_trial_0_when_asked(brick):
    """``[robust] perturb_collisions``: a candidate whose nominal pose collides still runs its
    perturbed trials (an execution that misses where the object lies may hold); by default none
    runs and it scores 0."""
    source, cands = brick
    wide = {"object_position_sigma": 0.02, "position_sigma": 0.01, "approach_sigma": 0.01}
    off = _rows(source, cands, _with(CONFIG, robust=wide), 4)
    on = _rows(source, cands, _with(CONFIG, robust={**wide, "perturb_collisions": True}), 4)
    hits = on["outcome"].eq("collision")
    assert hits.sum() >= 3 and off["outcome"].eq("collision").equals(hits)
    assert (off.loc[hits, "trial_stages"] == "0").all() and (off.loc[hits, "score"] == 0).all()
    assert (on.loc[hits, "trial_stages"].str.len() == 4).all()
    assert (on.loc[hits, "sim_steps"] > 0).any() and (on.loc[hits, "score"] > 0).any()
    # trial 0 and the other rows are untouched
    for c in ("outcome", "success", "width", "x", "qw", "stage"):
        assert on[c].equals(off[c]), c
    assert on.loc[~hits, "score"].equals(off.loc[~hits, "score"])


def test_scale_levels_scale_each_range_by_a_level_drawn_last():
    """Exploring the ranges: the pose errors (placement, yaw, hand across and along) are scaled by
    one level and the friction spread by another, both drawn after every other draw; without
    levels a perturbation is drawn exactly as before."""
    base = RobustConfig(object_position_sigma=0.002, object_yaw_sigma=0.03, position_sigma=0.001)
    levels = dataclasses.replace(base, scale_levels=(0.5, 1.0, 4.0))
    plain = [Perturbation.sample(np.random.default_rng(s), base) for s in range(200)]
    scaled = [Perturbation.sample(np.random.default_rng(s), levels) for s in range(200)]
    pose_levels, rub_levels = set(), set()
    for p, q in zip(plain, scaled, strict=True):
        ratios = {
            round(q.object_shift[0] / p.object_shift[0], 9),
            round(q.object_rotvec[2] / p.object_rotvec[2], 9),
            round(q.T_tcp_tcp.pos[0] / p.T_tcp_tcp.pos[0], 9),
            round(q.T_tcp_tcp.pos[2] / p.T_tcp_tcp.pos[2], 9),
        }
        assert len(ratios) == 1, ratios  # one level for every pose error of a trial
        pose_levels |= ratios
        rub_levels.add(round(q.friction_delta / p.friction_delta, 9))
        assert q.mass_scale == p.mass_scale and q.force_scale == p.force_scale
    assert pose_levels == rub_levels == {0.5, 1.0, 4.0}
    # the levels come after every other draw: the generator's state differs only by them
    rng = np.random.default_rng(3)
    Perturbation.sample(rng, base)
    rng.integers(0, 3, 2)
    other = np.random.default_rng(3)
    Perturbation.sample(other, levels)
    assert rng.bit_generator.state == other.bit_generator.state
    with pytest.raises(Exception, match="scale_levels"):
        RobustConfig(scale_levels=(0.0, 1.0))
    with pytest.raises(Exception, match="scale_levels"):
        RobustConfig(scale_levels=(1.0, 1e6))


def test_evaluate_compares_every_stage_with_a_real_outcome_column(tmp_path, brick):
    """A grasp table with a column of real outcomes: after the run, evaluate prints each stage held
    through against it, the gate marked; the figures are those of the rows it wrote. A column of
    anything but 1/0 or true/false is one line, exit 2, before any work."""
    from helpers import run_annotator

    from annotator.dataset import pose_columns
    from annotator.tools.calibrate import agreement

    source, cands = brick
    objects = tmp_path / "objects"
    objects.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.10)).export(objects / "brick.obj")
    table = pose_columns(cands.T_obj_tcp[:12])
    table.insert(0, "object_id", "brick")
    table["width"] = cands.width_expected[:12]
    truth = np.array([1, 0] * 6)
    table["held_on_robot"] = truth
    path = tmp_path / "grasps.csv"
    table.to_csv(path, index=False)
    out = tmp_path / "ev"
    result = run_annotator(
        "evaluate", path, "--objects", objects, "--out", out, "--workers", 1, "--real", "held_on_robot", "-q"
    )
    text = result.output
    assert "against the real outcomes (held_on_robot: 12 grasps, 50.0% held)" in text, text
    rows = pd.read_parquet(out).sort_values("grasp_id")
    for gate in ("close", "lift", "motion", "shake"):
        line = next(x for x in text.splitlines() if x.strip().startswith(f"{gate}:"))
        held = held_through(rows, gate).to_numpy()
        a = agreement(truth.astype(bool), held)
        assert f"{int(held.sum())} held" in line and f"balanced {100 * a.balanced:.1f} %" in line, line
        assert ("<- [protocol] gate" in line) == (gate == "shake")
    table["held_on_robot"] = ["yes"] * 11 + ["maybe"]
    table.to_csv(path, index=False)
    bad = run_annotator(
        "evaluate", path, "--objects", objects, "--out", tmp_path / "ev2", "--real", "held_on_robot", check=2
    )
    assert "row 11: held_on_robot must be 1/0 or true/false, got 'maybe'" in bad.output
    assert not (tmp_path / "ev2").exists()


def test_a_sampled_collision_s_perturbed_trials_come_with_why_trial_0_failed(brick):
    """Sampled candidates (annotate) whose perturbed trials run after a colliding trial 0 say why
    trial 0 failed (collided_with, collision_stage), as evaluate's rows do; without
    perturb_collisions their columns are the object mode's alone."""
    source, cands = brick
    wide = {"object_position_sigma": 0.02, "perturb_collisions": True}
    rows = {}
    for name, config in (("on", _with(CONFIG, robust=wide)), ("off", CONFIG)):
        task = SpanTask(span=Span("brick", source, None, 0, 24), config=config, seed=0, n=24, trials=3)
        rows[name] = label_span(task).rows
    on, off = rows["on"], rows["off"]
    assert {"collided_with", "collision_stage"} <= set(on.columns)
    assert not {"collided_with", "collision_stage"} & set(off.columns)
    hits = on["outcome"].eq("collision")
    assert hits.any() and (on.loc[hits, "collided_with"] == "object").all()
    assert set(on.loc[hits, "collision_stage"]) <= {"approach", "closed"}
    assert (on.loc[~hits, "collided_with"] == "").all()
    assert (on.loc[hits, "trial_stages"].str.len() == 3).all()
