"""The small learner: features of labelled grasps read from a real (tiny) scene run, a model
trained and saved, and the learned policy scoring vision candidates."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers import run_annotate
from scene_helpers import REPO

from annotator.cli import main
from annotator.dataset import load_scenes, scene_labels
from annotator.learn.data import commanded_grasps, load_training_set, scene_observation, scene_views
from annotator.learn.features import FEATURE_NAMES
from annotator.learn.model import auc, load_model, train
from annotator.learn.policy import learned
from annotator.policies import Grasps, PolicyError
from annotator.policies.gripper_boxes import gripper_boxes
from annotator.scenes.records import scenes_from_table


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """``annotate --scenes 2 --n 20 --views 1`` on piles of boxes and cans (both outcomes occur)."""
    root = tmp_path_factory.mktemp("learn")
    objects = root / "objects"
    objects.mkdir()
    for name in ("box.obj", "can.stl"):
        shutil.copy(REPO / "objects" / name, objects)
    (root / "views.toml").write_text("[kinect]\nviews_color_scale = 0.1\n")
    out = root / "labels"
    run_annotate(
        "--objects", objects, "--scenes", 2, "--per-scene", 3, "--n", 20, "--views", 1,
        "--config", root / "views.toml", "--workers", 1, "--out", out, "--quiet",
    )  # fmt: skip
    return out


@pytest.mark.slow
def test_the_learner_trains_on_a_tiny_run_and_scores_vision_candidates(tiny_run, tmp_path):
    data = load_training_set(tiny_run)
    assert data.X.shape == (40, len(FEATURE_NAMES)) and np.isfinite(data.X).all()
    assert sorted(set(data.scene_id)) == [0, 1] and 0 < data.y.sum() < 40
    # the features see the cloud: a held grasp has observed points between its pads
    between = FEATURE_NAMES.index("between")
    assert (data.X[data.y, between] > 0).all()
    # the rows are the labels' commanded grasps, in order
    record = scenes_from_table(load_scenes(tiny_run))[0]
    labels = scene_labels(tiny_run, 0)
    T, width = commanded_grasps(record, labels)
    assert T.shape == (20, 4, 4) and np.array_equal(width, labels["cmd_width"].to_numpy())
    np.testing.assert_allclose(T[:, :3, 3], labels[[f"table_tcp_{c}" for c in "xyz"]], atol=0.05)

    model = train(data.X, data.y)
    p = model.probability(data.X)
    assert ((p > 0) & (p < 1)).all() and auc(p, data.y) > 0.9  # it fits what it was shown
    path = tmp_path / "model.npz"
    model.save(path)
    again = load_model(str(path))
    np.testing.assert_array_equal(again.probability(data.X), p)

    observation = scene_observation(record, scene_views(tiny_run, 0), gripper_boxes().max_width)
    grasps = learned(observation, model=str(path), candidates="30")
    assert isinstance(grasps, Grasps) and len(grasps) > 0
    assert ((grasps.score > 0) & (grasps.score < 1)).all() and len(set(grasps.score)) > 1
    with pytest.raises(PolicyError, match="needs its model"):
        learned(observation)

    runner = CliRunner()
    out = tmp_path / "cli_model.npz"
    result = runner.invoke(main, ["learn", "train", str(tiny_run), "--out", str(out), "--holdout", "0.5"])
    assert result.exit_code == 0, result.output
    assert (
        "40 grasps of 2 scenes (0 vision candidates)" in result.output
        and "held-out 1 scenes" in result.output
    )
    np.testing.assert_allclose(load_model(str(out)).coef, model.coef, rtol=1e-6, atol=1e-9)
    result = runner.invoke(main, ["learn", "train", str(tiny_run), "--out", str(out)])
    assert result.exit_code == 2 and "exists" in result.output


@pytest.mark.slow
def test_the_learner_is_also_shown_the_policys_own_candidates_tried_in_simulation(tiny_run):
    """The labels are grasps around the true meshes (mostly collisions); the policy scores vision
    candidates that clear the observed cloud. Training adds those candidates, each tried by the
    floating gripper on the object nearest its TCP, so the model learns what it will score."""
    from annotator.config import AnnotatorConfig
    from annotator.learn.candidates import load_models, simulated_candidates
    from annotator.learn.policy import CANDIDATES, SEEDS
    from annotator.policies.vision import clear_of_observed, observed_surface, sample_grasps
    from annotator.rng import keyed_rng

    objects = tiny_run.parent / "objects"
    labels_only = load_training_set(tiny_run)
    data = load_training_set(tiny_run, objects, draws=1)
    assert not labels_only.vision.any() and data.vision.any()
    # the labels' rows are unchanged and come first in each scene; the candidates name no object
    np.testing.assert_array_equal(data.X[~data.vision], labels_only.X)
    np.testing.assert_array_equal(data.y[~data.vision], labels_only.y)
    assert set(data.object_id[data.vision]) == {""} and np.isfinite(data.X).all()

    record = scenes_from_table(load_scenes(tiny_run))[0]
    config = AnnotatorConfig()
    observation = scene_observation(record, scene_views(tiny_run, 0), gripper_boxes().max_width)
    surface = observed_surface(observation)
    tried = simulated_candidates(record, observation, surface, load_models(objects, config), config, draws=1)
    # the candidates are the policy's own: the same sampler, seeds and limit, each clearing the cloud
    expected = sample_grasps(
        observation,
        keyed_rng("learn-candidates", 0, record.scene_id, 0),
        seeds=SEEDS,
        limit=CANDIDATES,
        surface=surface,
    )
    np.testing.assert_array_equal(tried.T_table_tcp, expected.T_table_tcp)
    assert clear_of_observed(surface, tried.T_table_tcp, tried.width, config.protocol).all()
    # every one was tried on an object (a candidate's TCP lies between two observed contacts)
    assert set(tried.outcome) <= {"success", "collision", "no_contact", "slipped_lift", "slipped_shake"}
    np.testing.assert_array_equal(tried.held, tried.outcome == "success")

    out = tiny_run.parent / "with_candidates.npz"
    result = CliRunner().invoke(
        main,
        ["learn", "train", str(tiny_run), "--objects", str(objects), "--out", str(out), "--holdout", "0"],
    )
    assert result.exit_code == 0, result.output
    assert f"{len(data.y)} grasps of 2 scenes ({int(data.vision.sum())} vision candidates)" in result.output
