"""The small learner: features of labelled grasps read from a real (tiny) scene run, a model
trained and saved, and the learned policy scoring vision candidates."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers import mount_tmpfs, run_annotate, umount
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
    assert result.exit_code == 0, result.output  # its own model, unchanged: replaced
    out.write_bytes(out.read_bytes() + b"edited")
    result = runner.invoke(main, ["learn", "train", str(tiny_run), "--out", str(out)])
    assert (
        result.exit_code == 2
        and "was written by this tool" in result.output
        and "--overwrite" in result.output
    )


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


@pytest.mark.slow
def test_learn_train_refuses_objects_whose_mesh_is_not_the_labels(tiny_run, tmp_path):
    """The policy's candidates would be simulated on the wrong shape."""
    import trimesh

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "can.stl", objects)
    trimesh.load(REPO / "objects" / "box.obj").apply_scale(1.2).export(objects / "box.obj")
    out = tmp_path / "model.npz"
    result = CliRunner().invoke(
        main, ["learn", "train", str(tiny_run), "--objects", str(objects), "--out", str(out)]
    )
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert "box's mesh" in errors[0] and "is not the one" in errors[0] and not out.exists()


@pytest.mark.slow
def test_a_holdout_that_leaves_no_figure_says_so(tiny_run, tmp_path):
    out = tmp_path / "model.npz"
    result = CliRunner().invoke(
        main, ["learn", "train", str(tiny_run), "--holdout", "0.9", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "no held-out figure: --holdout 0.9 of 2 scenes keeps every scene out" in result.output
    assert "held-out 2 scenes" not in result.output and out.exists()


def test_a_damaged_model_is_one_line_before_any_work(tmp_path, convex_objects):
    """A model cut short by a full disk crashed --policy learned with BadZipFile."""
    from annotator.learn.model import Model

    model = Model(np.zeros(3), np.ones(3), np.ones(3), 0.0, ("a", "b", "c"))
    whole = tmp_path / "model.npz"
    model.save(whole)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(whole.read_bytes()[:300])
    with pytest.raises(ValueError, match="is not a model of annotator learn train"):
        load_model(str(cut))
    result = CliRunner().invoke(
        main,
        ["clutter-removal", "--objects", str(convex_objects), "--rounds", "1", "--policy", "learned",
         "--policy-arg", f"model={cut}", "--workers", "1"],
    )  # fmt: skip
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert f"{cut} is not a model of annotator learn train" in errors[0]
    assert "Traceback" not in result.output


@pytest.mark.slow
@pytest.mark.root
def test_a_model_on_a_full_disk_or_a_read_only_folder_is_one_line_and_leaves_nothing(tiny_run, tmp_path):
    """np.savez wrote in place: a full disk left a truncated model, which the re-run called
    existing and the learned policy could not read."""
    import subprocess

    disk = tmp_path / "disk"
    mount_tmpfs(disk, "64k")
    try:
        (disk / "filler").write_bytes(b"\0" * (60 * 1024))  # leaves a few kB: less than a model
        out = disk / "model.npz"
        result = CliRunner().invoke(main, ["learn", "train", str(tiny_run), "--out", str(out)])
        errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
        assert result.exit_code == 3 and len(errors) == 1, result.output
        assert "No space left on device" in errors[0] and "Traceback" not in result.output
        assert sorted(p.name for p in disk.iterdir()) == ["filler"]  # no model, no temporary file
        (disk / "filler").unlink()
        result = CliRunner().invoke(main, ["learn", "train", str(tiny_run), "--out", str(out)])
        assert result.exit_code == 0, result.output
        load_model.cache_clear()
        assert load_model(str(out)).coef.size > 0
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        result = CliRunner().invoke(main, ["learn", "train", str(tiny_run), "--out", str(disk / "m2.npz")])
        errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
        assert result.exit_code == 3 and len(errors) == 1 and "Read-only file system" in errors[0]
    finally:
        umount(disk)
