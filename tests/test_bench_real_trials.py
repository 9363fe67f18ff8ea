"""``bench.real_trials --profile``: a frozen profile applied to trials it was not fitted on, as a
user applies a calibration to new grasps: its configuration, its --trials, its mapping and its
threshold, nothing refitted. The trials here are a folder in the real data's format built from
two generated boxes (no real data is needed)."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from annotator import confidence as conf
from annotator.config import AnnotatorConfig
from annotator.objects import ObjectSource, load_object
from annotator.rng import object_rng
from annotator.sampler import sample_candidates

REPO = Path(__file__).resolve().parents[1]
POSE = [f"T_obj_tcp_{i}{j}" for i in range(3) for j in range(4)]
# Two boxes under the names of YCB objects the bench knows the masses of (its objects.toml).
BOXES = {"gelatin_box": (0.085, 0.07, 0.03), "foam_brick": (0.05, 0.075, 0.05)}
PROFILE = """# a profile written by hand: the execution's ranges, the gate and the mapping of --trials 3
[protocol]
approach = "simulated"
approach_speed = 0.1

[robust]
object_position_sigma = 0.004
object_yaw_sigma = 0.07
position_sigma = 0.001
approach_sigma = 0.002
friction_delta = 0.2
perturb_collisions = true

[confidence]
method = "isotonic"
trials = 3
scores = [0.0, 0.3333333333333333, 0.6666666666666666, 1.0]
p_success = [0.2, 0.45, 0.7, 0.9]
n = 40
threshold = 0.7
base_rate = 0.6
perturbed_shake = false
"""


def _layout(objects: dict[str, tuple[float, float, float]]) -> str:
    """A board layout: each object lying flat, 15 cm apart (millimetres, as the data's files)."""
    parts = []
    for k, (name, size) in enumerate(objects.items()):
        z = 1000 * size[2] / 2
        rows = [(1, 0, 0, 150.0 * k), (0, 1, 0, 0.0), (0, 0, 1, z), (0, 0, 0, 1)]
        cells = "".join(
            f'<row{i + 1} c1="{r[0]}" c2="{r[1]}" c3="{r[2]}" c4="{r[3]}" />' for i, r in enumerate(rows)
        )
        parts.append(
            f"<ManipulationObject name='{name}'><File>data/objects/YCB/{name}/nontextured.xml</File>"
            f"<GlobalPose><Transform><Matrix4x4>{cells}</Matrix4x4></Transform></GlobalPose>"
            "</ManipulationObject>"
        )
    return f"<Scene name='Benchmark_Layout_0'>{''.join(parts)}</Scene>"


@pytest.fixture(scope="module")
def data_folder(tmp_path_factory) -> Path:
    """Trials on two boxes in the real data's layout: 10 grasps each from the sampler (GRASPA's TCP
    is the Franka hand frame 105 mm out, its fingers closing along y), half of them called held."""
    folder = tmp_path_factory.mktemp("data")
    (folder / "layouts").mkdir()
    (folder / "meshes").mkdir()
    (folder / "layouts" / "layout_0.xml").write_text(_layout(BOXES))
    config = AnnotatorConfig()
    R_graspa_ours = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # our x = GRASPA's y
    rows = []
    rng = np.random.default_rng(1)
    for name, size in BOXES.items():
        mesh = trimesh.creation.box(size)
        with gzip.open(folder / "meshes" / f"{name}.stl.gz", "wb") as fh:
            fh.write(mesh.export(file_type="stl"))
        path = folder / f"{name}.stl"
        mesh.export(path)
        model = load_object(ObjectSource(name, path), config.objects)
        c = sample_candidates(model.mesh, 10, object_rng(0, name), config.sampler, 0.08)
        for k in range(10):
            T = c.T_obj_tcp[k].copy()
            T[:3, :3] = T[:3, :3] @ R_graspa_ours.T  # GRASPA's TCP axes
            rows.append(
                {
                    "planner": "test",
                    "layout": 0,
                    "object": name,
                    "grasp_name": f"Grasp {k}",
                    "grasped": int(rng.random() < 0.6),
                    "stability": 1.0,
                    **dict(zip(POSE, T[:3, :].reshape(-1), strict=True)),
                }
            )
    pd.DataFrame(rows).to_csv(folder / "trials.csv", index=False, float_format="%.17g")
    return folder


@pytest.mark.slow
def test_a_frozen_profile_is_applied_unchanged(tmp_path, data_folder):
    """The bench evaluates every trial with the profile as its --config at the profile's --trials,
    and scores the labels' p_success, which is the profile's own mapping of their score; calls at
    the profile's threshold; the record names the data by its digest and keeps the profile's K."""
    profile = tmp_path / "profile.toml"
    profile.write_text(PROFILE)
    work, results = tmp_path / "work", tmp_path / "results"
    cmd = [sys.executable, "-m", "bench.real_trials", "--data", str(data_folder), "--work", str(work)]
    cmd += ["--profile", str(profile), "--workers", "2", "--bootstrap", "100"]
    done = subprocess.run(
        cmd, cwd=REPO, capture_output=True, text=True, env={**_env(), "RG2_BENCH_RESULTS": str(results)}
    )
    assert done.returncode == 0, done.stdout + done.stderr
    records = list((results / "real_trials").glob("*.json"))
    assert len(records) == 1 and "-data-" in records[0].name
    assert records[0].name.endswith("-profile-profile.json")  # beside, never over, the fitted run's
    record = json.loads(records[0].read_text())
    figures = {f["name"]: f["value"] for f in record["figures"]}
    assert figures["profile_trials"] == 3 and figures["profile_threshold"] == 0.7
    rows = pd.read_parquet(work / "ev_profile")
    assert set(np.round(rows["score"] * 3, 9)) <= {0.0, 1.0, 2.0, 3.0}
    mapping = AnnotatorConfig.from_toml(profile).confidence
    expected = np.interp(rows["score"], mapping.scores, mapping.p_success)
    assert np.allclose(rows["p_success"], expected)  # the frozen mapping, not a refitted one
    trials = pd.read_csv(data_folder / "trials.csv")
    trials["object_id"] = trials["object"]
    trials["grasp_id"] = trials.groupby("object_id").cumcount()
    both = trials.merge(rows, on=["object_id", "grasp_id"])
    real = both["grasped"].to_numpy(dtype=bool)
    assert figures["profile_auc"] == pytest.approx(conf.auc(real, both["p_success"].to_numpy()))
    assert figures["profile_brier"] == pytest.approx(conf.brier(real, both["p_success"].to_numpy()))
    assert figures["profile_base_brier"] == pytest.approx(conf.brier(real, np.full(len(real), 0.6)))
    called = both["p_success"].to_numpy() >= 0.7
    precision = (called & real).sum() / max(1, called.sum())
    if called.any():
        assert figures["profile_precision"] == pytest.approx(precision)
    assert (work / "reliability_profile.png").is_file()
    assert not (work / "profile.toml").exists()  # nothing was fitted


def test_the_shipped_profile_is_a_profile():
    """bench/profiles' frozen profile reads as a --config: a mapping of --trials' scores rising to
    P(real success), its threshold inside it, the fitted ranges bounded and the collisions perturbed."""
    config = AnnotatorConfig.from_toml(REPO / "bench" / "profiles" / "graspa_panda_calibration.toml")
    c = config.confidence
    assert c.method == "isotonic" and c.trials == 5 and c.n == 200
    assert np.allclose(np.asarray(c.scores) * c.trials, np.round(np.asarray(c.scores) * c.trials))
    assert np.all(np.diff(c.p_success) >= 0) and 0 < c.p_success[0] < c.p_success[-1] < 1
    assert c.p_success[0] <= c.threshold <= c.p_success[-1] and 0 < c.base_rate < 1
    assert config.robust.perturb_collisions and config.protocol.approach == "simulated"
    assert 0 < config.robust.object_position_sigma <= 0.01 and 0 < config.robust.position_sigma <= 0.01


def _env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if k != "RG2_BENCH_RESULTS"}
