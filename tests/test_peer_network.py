"""The pieces of ``bench.peer_network`` that need no VGN checkout: the hand written for VGN's
simulation from our Panda, the training objects, VGN's data cleanup of a raw folder, and the
frames of ``bench.vgn_policy`` (VGN's grasps back to our TCP). The bench itself runs VGN's code
from a checkout given on its command line; these tests do not."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pybullet as pb
import pytest

from annotator.geometry import Transform, axis_angle_to_matrix, matrix_to_quat
from annotator.tools.export_vgn import fingertip_reach, tcp_to_vgn
from bench import peer_network, vgn_policy


def test_the_hand_for_vgn_has_its_palm_22_mm_ahead_of_its_centre_of_mass(tmp_path):
    """VGN's gripper loads data/urdfs/panda/hand.urdf, places the base's centre of mass 22 mm
    behind its TCP (the palm) along z, expects the fingertips finger_depth (50 mm) ahead of the
    palm, closes along its y, and drives panda_finger_joint1/2 (couples panda_leftfinger and
    panda_rightfinger). Loaded in PyBullet with the base's centre of mass at the origin: so it is."""
    urdf = tmp_path / "hand.urdf"
    peer_network.write_hand(urdf)
    client = pb.connect(pb.DIRECT)
    try:
        uid = pb.loadURDF(str(urdf), physicsClientId=client)
        pb.resetBasePositionAndOrientation(uid, [0, 0, 0], [0, 0, 0, 1], physicsClientId=client)
        joints = {
            pb.getJointInfo(uid, i, physicsClientId=client)[1].decode(): i
            for i in range(pb.getNumJoints(uid, physicsClientId=client))
        }
        links = {pb.getJointInfo(uid, i, physicsClientId=client)[12].decode(): i for i in joints.values()}
        assert {"panda_finger_joint1", "panda_finger_joint2"} <= set(joints)
        assert {"panda_leftfinger", "panda_rightfinger"} <= set(links)
        for name in ("panda_finger_joint1", "panda_finger_joint2"):
            info = pb.getJointInfo(uid, joints[name], physicsClientId=client)
            assert info[10] == pytest.approx(20.0) and info[9] == pytest.approx(0.04)  # effort, upper limit
            pb.resetJointState(uid, joints[name], 0.03, physicsClientId=client)  # 60 mm open
        tips, centres = [], []
        for pad in ("panda_leftfinger_pad", "panda_rightfinger_pad"):
            lo, hi = pb.getAABB(uid, links[pad], physicsClientId=client)
            tips.append(hi[2])
            centres.append((np.asarray(lo) + np.asarray(hi)) / 2)
        palm = 0.022
        assert max(tips) == pytest.approx(palm + 0.05, abs=1e-4)
        gap = centres[1] - centres[0]
        assert abs(gap[0]) < 1e-6 and abs(gap[1]) == pytest.approx(0.06 + 0.0152, abs=1e-4)  # along y
    finally:
        pb.disconnect(client)


def test_training_objects_are_closed_and_graspable_by_both_grippers():
    """Every generated training object is a closed solid standing on z = 0 with a part narrower
    than the Panda's 80 mm (its smallest extent, or a rim or handle); the same seed, the same shapes."""
    meshes = peer_network.training_meshes(2, seed=5)
    assert len(meshes) == 2 * len(peer_network.FAMILIES)
    for name, mesh in meshes.items():
        assert mesh.is_watertight, name
        assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
        assert np.sort(mesh.extents)[0] < 0.08, name
    again = peer_network.training_meshes(2, seed=5)
    for name, mesh in meshes.items():
        np.testing.assert_array_equal(mesh.vertices, again[name].vertices)


def test_vgn_raw_cleanup_keeps_referenced_scenes_and_balances(tmp_path):
    """The bench cleans VGN's own raw folder as the data notebook does: rows near the sides and
    excess negatives go, then scenes no row refers to."""
    raw = tmp_path / "raw"
    (raw / "scenes").mkdir(parents=True)
    rng = np.random.default_rng(0)
    rows = []
    for scene, inside in (("a", True), ("b", False)):
        np.savez_compressed(raw / "scenes" / f"{scene}.npz", depth_imgs=np.zeros((1, 2, 2), np.float32))
        for k in range(10):
            p = rng.uniform(0.05, 0.25, 3) if inside else np.array([0.01, 0.1, 0.1])
            rows.append({"scene_id": scene, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0,
                         "x": p[0], "y": p[1], "z": p[2], "width": 0.05, "label": int(k < 3)})  # fmt: skip
    pd.DataFrame(rows).to_csv(raw / "grasps.csv", index=False)
    counts = peer_network.clean_vgn_raw(raw, 0.3)
    df = pd.read_csv(raw / "grasps.csv")
    assert counts == {
        "grasps": 20,
        "positives": 6,
        "near_side": 10,
        "dropped": 4,
        "kept": 6,
        "kept_positives": 3,
    }
    assert len(df) == 6 and df["label"].sum() == 3 and set(df["scene_id"]) == {"a"}
    assert sorted(p.name for p in (raw / "scenes").iterdir()) == ["a.npz"]


def test_vgn_policy_returns_the_grasp_the_export_wrote(tmp_path):
    """A grasp written as VGN writes it (the export's frame: palm origin, closing along y, in the
    task frame; position and width in voxels, as VGN's detection answers) comes back from the
    policy's conversion as our TCP in the table frame, with its width."""
    voxel = 0.3 / 40
    T_table_task = Transform(np.array([0.3, -0.1, -0.05]), np.array([0.0, 0.0, 0.0, 1.0]))
    R = axis_angle_to_matrix(np.array([1.0, 0.2, -0.3]) / np.linalg.norm([1.0, 0.2, -0.3]), 2.5)
    T_table_tcp = np.eye(4)
    T_table_tcp[:3, :3], T_table_tcp[:3, 3] = R, [0.42, -0.02, 0.07]
    width = np.array([0.046])
    offset = fingertip_reach("panda")(width) - 0.05
    assert offset[0] == pytest.approx(
        0.00925 - 0.05, abs=1e-6
    )  # the Panda's fingertips: 9.25 mm beyond its TCP
    T_task_vgn = T_table_task.inverse().as_matrix() @ T_table_tcp @ tcp_to_vgn(offset)[0]
    row = np.r_[T_task_vgn[:3, 3] / voxel, matrix_to_quat(T_task_vgn[:3, :3]), width / voxel, 0.97]
    observation = SimpleNamespace(
        voxel_size=voxel, T_table_volume=T_table_task, gripper="panda", max_width=0.08
    )
    grasps = vgn_policy.to_tcp(row[None], observation)
    np.testing.assert_allclose(grasps.T_table_tcp[0], T_table_tcp, atol=1e-9)
    assert grasps.width[0] == pytest.approx(0.046) and grasps.score[0] == pytest.approx(0.97)
    assert len(vgn_policy.to_tcp(np.zeros((0, 9)), observation)) == 0


def test_the_bench_records_the_checkouts_commit_and_licence(tmp_path):
    """vgn_provenance reads a checkout's commit and its licence's first line (no VGN needed: a
    git repository made here)."""
    import subprocess

    repo = tmp_path / "checkout"
    repo.mkdir()
    (repo / "LICENSE").write_text("BSD 3-Clause License\n\nCopyright (c) someone\n")
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "LICENSE"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "x"], check=True)
    info = peer_network.vgn_provenance(Path(repo))
    assert len(info["commit"]) == 40 and info["licence"] == "BSD 3-Clause License" and not info["dirty"]


def test_steps_keep_each_commands_cpu_and_are_not_run_again(tmp_path):
    """Commands run side by side, each with its own CPU (from its own resource usage); a step
    that finished is not run again by a later run of the same folder (its row is kept); a failing
    command stops the bench with the end of its log."""
    import sys
    from types import SimpleNamespace as NS

    steps = peer_network.Steps(NS(nice=0), tmp_path)
    burn = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass\nprint('ran')"
    cpu = steps.run_many(
        [
            ("burn", [sys.executable, "-c", burn], None, None, None),
            ("idle", [sys.executable, "-c", "0"], None, None, None),
        ]
    )
    assert cpu[0] >= 0.3 and cpu[1] < 0.3
    assert (tmp_path / "logs" / "burn.log").read_text().strip() == "ran"
    again = peer_network.Steps(NS(nice=0), tmp_path)
    marker = tmp_path / "ran-again"
    assert again.run("burn", [sys.executable, "-c", f"open({str(marker)!r}, 'w')"]) == pytest.approx(
        cpu[0], abs=0.05
    )
    assert not marker.exists() and again.rows[0]["resumed"]
    with pytest.raises(SystemExit, match="exit 3"):
        again.run("fails", [sys.executable, "-c", "import sys; print('why'); sys.exit(3)"])


def test_our_judging_is_tabled_by_the_object_each_attempt_went_for(tmp_path):
    """ours_by_object: a finished policy's attempts per target object, its successes and failures by
    cause; a policy that made no attempt (an empty grasps.csv) and one not finished are left out."""
    sim = tmp_path / "sim_ours"
    columns = "round_id,attempt,target_object,label,failure\n"
    done = sim / "pile_vgn_net_ours"
    done.mkdir(parents=True)
    (done / "grasps.csv").write_text(
        columns + "0,0,mug,0,slipped\n0,1,mug,1,\n1,0,can,0,collision\n1,1,mug,0,slipped\n"
    )
    (done / "row.json").write_text("{}")
    empty = sim / "pile_vgn_net_vgn"
    empty.mkdir()
    (empty / "grasps.csv").write_text("")
    (empty / "row.json").write_text("{}")
    unfinished = sim / "pile_vision_random"
    unfinished.mkdir()
    (unfinished / "grasps.csv").write_text(columns + "0,0,can,1,\n")
    rows = peer_network.ours_by_object(tmp_path, ["pile", "packed"])
    assert rows == [
        {"arrangement": "pile", "policy": "vgn_net_ours", "object": "can", "attempts": 1, "successes": 0,
         "failures": "collision: 1"},
        {"arrangement": "pile", "policy": "vgn_net_ours", "object": "mug", "attempts": 3, "successes": 1,
         "failures": "slipped: 2"},
    ]  # fmt: skip


def test_the_whole_bench_sums_every_step_and_our_judging_across_runs():
    """whole_bench: resumed steps count as they were measured; a judging row without a wall (none
    kept) adds nothing."""
    commands = [
        {"step": "labels_vgn", "cpu_s": 100.0, "seconds": 60.0, "resumed": True},
        {"step": "train_ours", "cpu_s": 50.5, "seconds": 30.0},
    ]
    judged = [
        {"policy": "vgn_net_ours", "cpu_s": 10.0, "seconds": 12.5},
        {"policy": "vgn_net_vgn", "cpu_s": 4.0},
    ]
    assert peer_network.whole_bench(commands, judged) == {"cpu_s": 160.5, "seconds": 102.5, "steps": 3}


def test_best_first_detection_hands_clutter_removal_the_best_rated_grasp_at_any_rating(tmp_path):
    """The launcher's ``best`` detection: VGN.__call__ becomes predict, process and select at
    threshold 0, best-rated first (VGN's clutter removal executes the first); ``vgn`` leaves VGN's
    own. A stand-in ``vgn.detection`` module, written here, records what select was asked."""
    import subprocess
    import sys

    package = tmp_path / "src" / "vgn"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "detection.py").write_text(
        "asked = []\n"
        "def predict(grid, net, device): return 'q', 'r', 'w'\n"
        "def process(grid, q, r, w): return [0.5, 0.8, 0.7], r, w\n"
        "def select(qual, rot, width, threshold=0.9):\n"
        "    asked.append(threshold)\n"
        "    kept = [i for i, q in enumerate(qual) if q >= threshold]\n"
        "    return [f'g{i}' for i in kept], [qual[i] for i in kept]\n"
        "def from_voxel_coordinates(g, voxel_size): return g + '@' + str(voxel_size)\n"
        "class VGN:\n"
        "    net, device = None, 'cpu'\n"
        "    def __call__(self, state): return 'vgn own', [], 0.0\n"
    )
    script = tmp_path / "judge.py"
    script.write_text(
        "import types\n"
        "from vgn import detection\n"
        "tsdf = types.SimpleNamespace(get_grid=lambda: 'grid', voxel_size=0.0075)\n"
        "grasps, scores, _ = detection.VGN()(types.SimpleNamespace(tsdf=tsdf))\n"
        "print(grasps, list(map(float, scores)) if len(scores) else scores, detection.asked)\n"
    )
    env = {"PYTHONPATH": str(tmp_path / "src"), "PATH": "/usr/bin:/bin"}

    def judged(detect: str) -> str:
        cmd = [sys.executable, "-c", peer_network.LAUNCHER, "0", "1", detect, str(script)]
        return subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout.strip()

    assert judged("best") == "['g1@0.0075', 'g2@0.0075', 'g0@0.0075'] [0.8, 0.7, 0.5] [0.0]"
    assert judged("vgn") == "vgn own [] []"


def test_targets_compare_each_detection_and_count_no_attempt_as_losing():
    """targets: one line per simulation and arrangement for each detection judged; a network that
    made no attempt (success NaN) is beaten by one that held anything, and fewer than 100
    attempts never meet the target."""

    def row(sim, policy, attempts, successes, objects=200, arrangement="pile"):
        return peer_network._row(sim, arrangement, policy, 40, objects, attempts, successes)

    rows = [
        row("vgn", "vgn_net_vgn", 0, 0),
        row("vgn", "vgn_net_ours", 15, 4),
        row("vgn", "vgn_net_vgn_best", 150, 60),
        row("vgn", "vgn_net_ours_best", 140, 70),
        row("ours", "vgn_net_vgn_best", 120, 30),
        row("ours", "vgn_net_ours_best", 130, 80),
        row("ours", "vision_random", 150, 60),
        row("vgn_seen", "vgn_net_vgn_best", 150, 140),
        row("vgn_seen", "vgn_net_ours_best", 150, 10),
    ]
    assert math.isnan(rows[0]["success"])
    lines = peer_network.targets(rows)
    assert not any("vgn_seen" in line for line in lines)  # the training objects judge no target
    assert lines[0].startswith("vgn pile (VGN's detection)") and lines[0].endswith("target NOT met")
    assert "on VGN's nan %, 0.0 %; 0 attempts (>= 100)" in lines[0]
    best = [line for line in lines if "(best-first)" in line]
    assert best[0].startswith("ours pile") and best[0].endswith("target met")  # 80/130 vs 30/120
    assert best[1].startswith("vgn pile") and best[1].endswith("target met")  # 50 % vs 40 %, 140 attempts
    assert (
        best[2]
        == "ours pile (best-first): network trained on ours clears +10.0 points vs vision-random (>= 10): met"
    )  # noqa: E501
    assert best[3].endswith("-15.0 points vs vision-random (>= 10): NOT met")
    assert not peer_network._at_least(rows[0], rows[1], "success") and peer_network._at_least(
        rows[1], rows[0], "success"
    )


def test_ratings_of_the_executed_grasps(tmp_path):
    """ratings: the median of the executed grasps' qualities and the share VGN's 0.9 keeps; a
    kept grasps.csv with no attempt (empty) gives NaN."""
    grasps = pd.DataFrame(
        {"score": [0.95, 0.85, 0.9, 0.5], "label": [1, 0, 1, 0], "width": [0.03, 0.05, 0.04, 0.02]}
    )
    assert peer_network.ratings(grasps) == {
        "rating_median": 0.875,
        "rated_0_9": 50.0,
        "width_median_mm": 35.0,
    }
    (tmp_path / "grasps.csv").write_text("")
    empty = peer_network._kept_ratings(tmp_path / "grasps.csv")
    assert all(math.isnan(v) for v in empty.values()) and len(empty) == 3


def test_every_judged_row_is_a_figure_the_record_takes(tmp_path):
    """record_judged: the rows of every simulation the bench judges in (VGN's, ours, VGN's on the
    training objects) become figures of a real record, named by simulation, arrangement and
    policy; a row of no attempt is kept with no value."""
    import json

    from bench.harness import Run

    rows = [
        peer_network._row(sim, arrangement, policy, 40, 150, attempts, successes)
        for sim, arrangement, policy, attempts, successes in (
            ("vgn", "pile", "vgn_net_vgn", 0, 0),
            ("vgn_seen", "pile", "vgn_net_ours_best", 50, 10),
            ("ours", "packed", "vision_random", 117, 90),
        )
    ]
    with Run("demo", results=tmp_path, command="demo") as run:
        peer_network.record_judged(run, rows)
    figures = {f["name"]: f for f in json.loads(run.path.read_text())["figures"]}
    assert list(figures) == [
        "vgn_pile_vgn_net_vgn_success",
        "vgn_pile_vgn_net_vgn_cleared",
        "vgn_seen_pile_vgn_net_ours_best_success",
        "vgn_seen_pile_vgn_net_ours_best_cleared",
        "ours_packed_vision_random_success",
        "ours_packed_vision_random_cleared",
    ]
    assert figures["vgn_pile_vgn_net_vgn_success"]["value"] is None
    assert figures["vgn_seen_pile_vgn_net_ours_best_success"]["value"] == 20.0
    assert figures["ours_packed_vision_random_cleared"]["note"] == "95 % Wilson, 90 of 150 objects"


def test_the_widths_a_network_learns_are_those_of_the_positives(tmp_path):
    """positive_widths: percentiles (mm) of the positives' widths only (VGN's width loss weighs
    positives only; its negatives carry the open width); no positive gives NaN."""
    csv = tmp_path / "grasps.csv"
    widths = [0.01 * k for k in range(1, 8)]  # 10 to 70 mm
    pd.DataFrame({"width": [*widths, 0.08, 0.08], "label": [1] * 7 + [0, 0]}).to_csv(csv, index=False)
    got = peer_network.positive_widths(csv)
    assert got == {
        "positive_width_p05_mm": 13.0,
        "positive_width_median_mm": 40.0,
        "positive_width_p95_mm": 67.0,
    }
    pd.DataFrame({"width": [0.08], "label": [0]}).to_csv(csv, index=False)
    assert all(math.isnan(v) for v in peer_network.positive_widths(csv).values())


def test_our_positives_widths_by_training_object_family():
    """widths_by_family: positives only, grouped by the family of the training object's name."""
    labels = pd.DataFrame(
        {
            "object_id": ["bowl_0", "bowl_3", "box_1", "box_1", "box_2", "mug_0"],
            "success": [True, True, True, True, False, False],
            "width": [0.006, 0.008, 0.040, 0.044, 0.010, 0.030],
        }
    )
    assert peer_network.widths_by_family(labels) == [
        {"family": "bowl", "positives": 2, "share": 50.0, "width_q1_mm": 6.5, "width_median_mm": 7.0,
         "width_q3_mm": 7.5},
        {"family": "box", "positives": 2, "share": 50.0, "width_q1_mm": 41.0, "width_median_mm": 42.0,
         "width_q3_mm": 43.0},
    ]  # fmt: skip


def test_a_judging_kept_for_other_rounds_runs_again(tmp_path):
    """rounds_of reads a kept sim_grasp.py command's rounds; Steps.forget drops a kept step so that
    the next run runs it (judging asked for other --rounds on the same --work)."""
    import sys
    from types import SimpleNamespace as NS

    shown = "python scripts/sim_grasp.py --model m.pt --num-rounds 40 --seed 1  (seeded 0)"
    assert peer_network.rounds_of(shown) == 40 and peer_network.rounds_of("python x.py") is None
    steps = peer_network.Steps(NS(nice=0), tmp_path)
    steps.run("judge", [sys.executable, "-c", "0"])
    assert peer_network.Steps(NS(nice=0), tmp_path).saved("judge") is not None
    steps.forget("judge")
    assert peer_network.Steps(NS(nice=0), tmp_path).saved("judge") is None


def test_quick_and_partial_runs_are_tagged_apart_from_the_full_run():
    """run_tag: a full run has no tag; --quick, --until and both are told apart."""
    last = peer_network.STAGES[-1]
    assert peer_network.run_tag(False, last) is None
    assert peer_network.run_tag(True, last) == "quick"
    assert peer_network.run_tag(False, "labels") == "until-labels"
    assert peer_network.run_tag(True, "training") == "quick-until-training"
