"""The execution's uncertainty fitted to real trials (``calibrate --fit-ranges``,
annotator/tools/ranges.py): the exploration's draws are the trials' own, the score's distribution
and its mapping, and the fit recovering the ranges that drew the "real" outcomes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
import trimesh

from annotator import confidence as conf
from annotator.config import AnnotatorConfig
from annotator.dataset import pose_columns
from annotator.geometry import Transform
from annotator.objects import ObjectSource, create_body, load_object
from annotator.rng import object_rng, trial_rng
from annotator.sampler import sample_candidates
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.tools import calibrate as cal
from annotator.tools import ranges
from annotator.trial import GraspTrial, Perturbation

CONFIG = AnnotatorConfig()


@pytest.fixture(scope="module")
def brick_grasps(tmp_path_factory):
    """A 50 x 40 x 100 mm box in an objects folder and a table of 30 of its candidates."""
    folder = tmp_path_factory.mktemp("ranges")
    objects = folder / "objects"
    objects.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.10)).export(objects / "brick.obj")
    model = load_object(ObjectSource("brick", objects / "brick.obj"), CONFIG.objects)
    c = sample_candidates(model.mesh, 30, object_rng(3, "brick"), CONFIG.sampler, 0.11)
    table = pose_columns(c.T_obj_tcp)
    table.insert(0, "object_id", "brick")
    table.insert(1, "grasp_id", np.arange(len(table)))
    table["width"] = c.width_expected
    path = folder / "grasps.csv"
    table.to_csv(path, index=False, float_format="%.17g")
    return folder, objects, path, model


def test_the_score_s_distribution_is_trial_0_plus_a_binomial_of_the_perturbed_trials():
    first = np.array([True, False, True])
    p = np.array([0.0, 0.5, 1.0])
    pmf = ranges.score_pmf(first, p, 5)
    assert pmf.shape == (3, 6) and np.allclose(pmf.sum(axis=1), 1.0)
    assert pmf[0, 1] == pytest.approx(1.0)  # trial 0 held, the four perturbed ones never: 1 of 5
    assert pmf[2, 5] == pytest.approx(1.0)  # all five
    assert np.allclose(pmf[1, :5], [1 / 16, 4 / 16, 6 / 16, 4 / 16, 1 / 16]) and pmf[1, 5] == 0.0


def test_the_expected_mapping_is_the_isotonic_fit_when_each_score_is_certain():
    """Each grasp weighted by the probability of each score value: with one certain value per
    grasp it pools the same blocks as the plain isotonic regression of annotator.confidence (the
    same rates), each score value taking its block's rate, and no other monotone mapping fits
    the real outcomes better (least squares)."""
    rng = np.random.default_rng(4)
    k = 5
    scores = rng.integers(0, k + 1, 300)
    real = rng.random(300) < (0.1 + 0.8 * scores / k) ** 2
    pmf = np.eye(k + 1)[scores]
    m = ranges.expected_mapping(pmf, real)
    iso = conf.fit_isotonic(scores / k, real, k)
    assert sorted(set(np.round(m.p, 12))) == sorted(set(np.round(iso.p, 12)))
    assert np.all(np.diff(m.p) >= 0)
    loss = np.sum((m.p[scores] - real) ** 2)
    for _ in range(200):
        other = np.sort(np.clip(m.p + rng.normal(0, 0.05, k + 1), 0, 1))
        assert np.sum((other[scores] - real) ** 2) >= loss - 1e-9
    knots, p = m.knots()
    assert np.allclose(np.interp(np.arange(k + 1) / k, knots, p), m.p)
    # a score value no grasp reaches takes its neighbour's: the mapping stays monotone
    gap = ranges.expected_mapping(np.eye(k + 1)[np.where(scores == 2, 3, scores)], real)
    assert gap.p[2] == gap.p[1] and np.all(np.diff(gap.p) >= 0)


def test_importance_weights_give_the_share_each_level_would_hold():
    """The weighted share of the exploration's trials that held equals, within noise, the share
    of trials drawn at that level directly (a rule on the draws standing in for the physics)."""
    explore = ranges.exploration_config(CONFIG)
    n, m = 40, 400
    keys = [("rule", i) for i in range(n)]
    draws = ranges.draws_of(explore.robust, 0, keys, m)
    margin = np.linspace(0.001, 0.012, n)[:, None]
    held = np.abs(draws.values["object_position_sigma"][:, :, 0]) < margin
    exp = ranges.Exploration.of(
        ["4" + "".join("3" if h else "1" for h in row) for row in held], draws, ranges.LEVELS, CONFIG.robust
    )
    ratios = exp.ratios()
    for level in (0, 2, 4):
        robust = dataclasses.replace(
            CONFIG.robust, **{c.field: c.unit * ranges.LEVELS[level] for c in ranges.COMPONENTS}
        )
        rng = np.random.default_rng(11)
        shifts = np.array(
            [[Perturbation.sample(rng, robust).object_shift[0] for _ in range(400)] for _ in range(n)]
        )
        direct = np.mean(np.abs(shifts) < margin, axis=1)
        estimate = ranges.held_share(ratios, (level, 2), held)
        assert np.abs(estimate - direct).mean() < 0.06, (level, np.abs(estimate - direct).mean())
        assert ranges.effective_trials(ratios, (level, 2)).mean() > m / 15


def test_the_exploration_s_draws_are_the_ones_its_trials_ran(brick_grasps):
    """Drawn again from the same keyed generator, a grasp's perturbation run in a fresh world
    holds exactly as far as the exploration recorded (nothing but the stages comes back from the
    workers, so the two must be the same draws)."""
    folder, objects, path, model = brick_grasps
    src = cal.calibration_grasps(path, objects)
    real = pd.DataFrame({"object_id": "brick", "grasp_id": np.arange(8), "real_success": 1})
    real_path = folder / "real_8.csv"
    real.to_csv(real_path, index=False)
    trials = cal.read_real_trials(real_path, src.grasps)
    m = 6
    exp = cal.explore(trials, src.config, objects, workers=1, seed=5, m=m)
    config = ranges.exploration_config(src.config)
    checked = 0
    with World(config.physics) as world:
        hand = FloatingGripper(world, config.gripper)
        hand.teleport(Transform([0, 0, 2.0], [0, 0, 0, 1]), hand.gripper.max_width)
        trial = GraspTrial(world, hand, create_body(world.client, model), config)
        for i in range(len(trials)):
            row = src.grasps.iloc[i]
            T = Transform.exact(
                [row.cmd_x, row.cmd_y, row.cmd_z], [row.cmd_qx, row.cmd_qy, row.cmd_qz, row.cmd_qw]
            )
            rng = trial_rng(5, "brick", i)
            for j in range(m):
                p = Perturbation.sample(rng, trial.robust)
                assert trial.run(T, float(row.cmd_width), p).stage == exp.stages[i, j], (i, j)
                assert p.object_shift[0] == exp.draws.values["object_position_sigma"][i, j, 0]
                checked += 1
        trial.close()
    assert checked == 8 * m and len(set(exp.stages.ravel().tolist())) >= 2


@pytest.mark.slow
def test_the_fit_recovers_the_pose_error_that_drew_the_real_outcomes(brick_grasps):
    """ "Real" outcomes drawn by the simulation itself, each of 20 grasps executed four times, with
    the pose errors at 4 times their units (8 mm and 8 deg of placement, 4 mm of hand across and
    8 mm along it): the fit identifies the pose errors at that level. The same executions drawn
    at the units' own sizes: the fit does not put them at 4 times."""
    folder, objects, path, _ = brick_grasps
    src = cal.calibration_grasps(path, objects)
    grasps = src.grasps.iloc[:20]
    repeats = 10
    found = {}
    table = pd.DataFrame(
        {"object_id": "brick", "grasp_id": np.repeat(grasps["grasp_id"].to_numpy(), repeats)}
    )
    table.assign(real_success=1).to_csv(folder / "executions.csv", index=False)
    trials = cal.read_real_trials(folder / "executions.csv", src.grasps)
    exp = cal.explore(trials, src.config, objects, workers=2, seed=0, m=32)  # the outcomes play no part
    for level in (3, 1):
        sizes = {
            c.field: c.unit * ranges.LEVELS[level] for c in ranges.COMPONENTS if c.field != "friction_delta"
        }
        truth = dataclasses.replace(
            src.config, robust=dataclasses.replace(src.config.robust, **sizes, perturb_collisions=True)
        )
        # each grasp's ten executions: the perturbed trials of a run with another seed
        drawn = cal.simulate_grid(
            grasps, [None], truth, objects, 2, 7, None, False, repeats + 1, "trial_stages"
        )[None]
        real = np.array([int(d) >= 3 for stages in drawn for d in stages[1:]])
        found[level] = ranges.fit_execution(exp, real)
    assert found[3].execution.theta[0] == 3 and found[3].identified["pose"], found[3]
    assert found[1].execution.theta[0] < 3 or found[1].execution.theta[0] == exp.own_index, found[1]
