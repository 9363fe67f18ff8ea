"""``--trials K``: perturbations are applied inside their trial, undone for the next, and counted.

A score is the fraction of the K trials that held; a candidate whose nominal pose collides gets
score 0 and no perturbed trial (docs/protocol.md, "Robust labels").
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pybullet as pb
import pytest
import trimesh

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import ObjectSource, create_body, load_object
from annotator.outcome import Outcome
from annotator.pipeline.worker import GivenGrasps, Span, SpanTask, label_span
from annotator.rng import object_rng
from annotator.sampler import sample_candidates
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial, Perturbation

CONFIG = AnnotatorConfig()


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
        perturbed = trial.run(T, cands.width_expected[k], p)
        # inside the trial: the object weighed and slid as perturbed (the state it ended in) ...
        mass, friction = _dynamics(world.client, uid)
        assert mass == pytest.approx(nominal_mass * 1.25) and friction == pytest.approx(
            nominal_friction - 0.3
        )
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
    return label_span(SpanTask(span, config, 0, len(cands), trials)).rows


@pytest.mark.slow
def test_perturbed_trials_are_counted(brick):
    source, _, cands = brick
    still = dataclasses.replace(
        CONFIG,
        robust=dataclasses.replace(
            CONFIG.robust, position_sigma=0.0, rotation_sigma=0.0, friction_delta=0.0, mass_delta=0.0
        ),
    )
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
