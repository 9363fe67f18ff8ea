"""annotator calibrate: recovers a hidden pad friction from "real" outcomes made by simulation.

The "real" trials are the physics-reaching grasps of a small heavy dataset, simulated with hidden
parameters (pad friction 0.45, 20 N) and with two outcomes flipped (a lab's mistakes or what the
simulator cannot know). Calibration over a friction grid, given the recorded 20 N, must find the
friction within +-0.1 (the grid's neighbours of the truth) and report an accuracy near the true
agreement (n - 2) / n, with a confidence interval that holds it.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from annotator.cli import annotate_command, main
from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels
from annotator.tools import calibrate as cal
from annotator.tools.common import labelling_config

REPO = Path(__file__).resolve().parents[2]
HIDDEN_FRICTION, HIDDEN_FORCE = 0.45, 20.0
GRID = (0.25, 0.35, 0.45, 0.55, 0.7)
TOLERANCE = 0.1  # recovered friction within this of the hidden one
FLIPS = 2


def test_agreement_statistics_and_intervals() -> None:
    real = np.array([1, 1, 1, 1, 0, 0, 0, 0, 1, 0], bool)
    sim = np.array([1, 1, 1, 0, 0, 0, 0, 1, 1, 0], bool)
    a = cal.agreement(real, sim, samples=500)
    assert (a.n, a.accuracy, a.precision, a.recall) == (10, 0.8, 0.8, 0.8)
    assert a.accuracy_ci[0] < 0.8 < a.accuracy_ci[1] and 0.4 <= a.accuracy_ci[0]
    perfect = cal.agreement(real, real, samples=200)
    assert perfect.accuracy == 1.0 and perfect.accuracy_ci == (1.0, 1.0)
    assert np.isnan(cal.agreement(real, np.zeros(10, bool)).precision)  # no simulated successes


@pytest.mark.slow
def test_calibration_recovers_hidden_friction(tmp_path: Path) -> None:
    objects = tmp_path / "objects"
    objects.mkdir()
    for name in ("box.obj", "can.stl"):
        shutil.copy(REPO / "objects" / name, objects / name)
    # heavy objects (1500 kg/m^3: box 0.43 kg, can 0.59 kg), so that friction decides grasps at 20 N
    (tmp_path / "heavy.toml").write_text("[objects]\ndensity = 1500.0\n")
    labels_dir = tmp_path / "labels"
    args = ["--objects", str(objects), "--n", "30", "--out", str(labels_dir), "--workers", "2", "--quiet"]
    result = CliRunner().invoke(annotate_command, [*args, "--config", str(tmp_path / "heavy.toml")])
    assert result.exit_code == 0, result.output
    labels = load_labels(labels_dir)
    trials = labels[labels.outcome != "collision"].reset_index(drop=True)  # what a robot can execute
    n = len(trials)
    assert n >= 15
    base = labelling_config(labels_dir).config

    hidden = cal.Setting(HIDDEN_FRICTION, HIDDEN_FORCE, 1.0)
    truth = cal.simulate_grid(trials.assign(real_success=False), [hidden], base, objects, workers=2)[hidden]
    assert 0.2 < truth.mean() < 0.8  # the hidden physics leaves both outcomes
    real = truth.copy()
    flipped = np.random.default_rng(7).choice(n, FLIPS, replace=False)
    real[flipped] = ~real[flipped]
    csv = tmp_path / "real.csv"
    trials.assign(real_success=real.astype(int), grip_force=HIDDEN_FORCE)[
        ["object_id", "grasp_id", "real_success", "grip_force"]
    ].to_csv(csv, index=False)

    out = tmp_path / "calibrated.toml"
    grid = ",".join(map(str, GRID))
    cmd = ["calibrate", str(labels_dir), str(csv), "--objects", str(objects), "--friction", grid]
    cmd += ["--trials", "2"]
    result = CliRunner().invoke(main, [*cmd, "--severity", "1", "--workers", "2", "--write-config", str(out)])
    assert result.exit_code == 0, result.output
    config = AnnotatorConfig.from_toml(out)
    recovered = config.gripper.pad_lateral_friction
    print(result.output)  # the table, for the record (pytest -s)
    assert abs(recovered - HIDDEN_FRICTION) <= TOLERANCE + 1e-9
    assert config.gripper.grip_force == HIDDEN_FORCE and config.objects.density == 1500.0
    best_line = next(line for line in result.output.splitlines() if line.startswith("best:"))
    accuracy = float(best_line.split("accuracy ")[1].split(" %")[0]) / 100
    low, high = (float(v) / 100 for v in best_line.split("[")[1].split("]")[0].split(","))
    true_agreement = (n - FLIPS) / n
    assert true_agreement - 1.5 / n <= accuracy <= 1.0
    assert low <= true_agreement <= high
    # the label's confidence: score of --trials 2 mapped to P(real success), written with the config
    c = config.confidence
    assert c.method == "isotonic" and c.trials == 2 and c.n == n
    assert 0.0 <= c.p_success[0] <= c.p_success[-1] <= 1.0 and 0.0 <= c.brier <= 0.25
    assert "Brier" in result.output and "AUC of score" in result.output
    assert (tmp_path / "calibrated.reliability.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("object_id,grasp_id\nbox,0\n", "missing column(s) ['real_success']"),
        ("object_id,grasp_id,real_success\nbox,0,maybe\n", "real_success must be 1/0 or true/false"),
        ("object_id,grasp_id,real_success\ncup,3,1\n", "name no label, e.g. object 'cup' grasp 3"),
        ("object_id,grasp_id,real_success,grip_force\nbox,0,1,strong\n", "grip_force must be a number"),
    ],
)
@pytest.mark.slow
def test_calibrate_bad_real_trials_are_one_line(labelled, tmp_path: Path, text: str, message: str) -> None:
    csv = tmp_path / "real.csv"
    csv.write_text(text)
    args = ["calibrate", str(labelled.labels_dir), str(csv), "--objects", str(labelled.objects_dir)]
    result = CliRunner().invoke(main, [*args, "--write-config", str(tmp_path / "c.toml")])
    assert result.exit_code == 2 and message in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1


def test_folds_split_by_object_and_cover_each_once() -> None:
    ids = [f"obj{i}" for i in range(14)]
    folds = cal.object_folds(ids * 3, 5, seed=0)  # repeated ids (one per trial) are one object
    assert len(folds) == 5 and sorted(o for f in folds for o in f) == sorted(ids)
    assert {len(f) for f in folds} == {2, 3}
    assert cal.object_folds(ids, 5, seed=0) == folds and cal.object_folds(ids, 5, seed=1) != folds
    assert len(cal.object_folds(["a", "b"], 5)) == 2  # at most one fold per object


def test_cross_validation_chooses_each_folds_setting_without_its_objects() -> None:
    """Setting A reproduces the real outcomes of objects a..d, B only those of object e: the fold
    holding e out must choose A (from a..d alone) and so predict e wrongly, while the setting
    fitted on everything would be judged on trials it was chosen with."""
    import pandas as pd

    objects = np.repeat(list("abcde"), 6)
    real = np.tile([True, True, True, False, False, True], 5)
    trials = pd.DataFrame({"object_id": objects, "grasp_id": np.arange(30) % 6, "real_success": real})
    a, b = cal.Setting(1.0, 40.0, 1.0), cal.Setting(0.5, 40.0, 1.0)
    sim_a = real.copy()
    sim_a[objects == "e"] = ~real[objects == "e"]
    sim_b = ~real
    sim_b[objects == "e"] = real[objects == "e"]
    labelled = cal._gripper_settings(AnnotatorConfig())
    cv = cal.cross_validate(trials, {a: sim_a, b: sim_b}, [a, b], labelled, folds=5, seed=0, bootstrap=100)
    assert len(cv.folds) == 5
    for fold in cv.folds:
        assert not set(fold.held_out) & set(fold.fitted_on)  # no object in both
        assert sorted(fold.held_out + fold.fitted_on) == list("abcde")
        assert fold.best == a  # four objects of A's against at most one of B's
        held = np.isin(objects, fold.held_out)
        assert fold.held.n == held.sum()
        np.testing.assert_array_equal(cv.predicted[held], sim_a[held])
    assert cv.pooled.accuracy == pytest.approx(24 / 30)
    assert "held out" in cal.format_folds(
        cv
    ) and "cross-validated by object, 30 held-out trials" in cal.format_folds(cv)
