"""Clutter-removal policies behind one interface: a callable in the loop sees only the Kinect's
depth (no meshes, no poses) and the arm executes its best reachable grasp; vision-random's grasps
clear the observed cloud and the table; predictions files that cannot mean the piles are refused."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from helpers import run_annotator

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import discover_objects
from annotator.policies import Grasp, Grasps, Observation, PolicyError
from annotator.policies.clutter import FAILURES, ClutterSetup, clutter_removal

SEEN: list[Observation] = []
TOP_DOWN = (1.0, 0.0, 0.0, 0.0)  # xyzw: the TCP's +z (approach) along the table's -z


def above_the_highest_point(observation: Observation, depth: str = "0.01") -> list[Grasp]:
    """A trivial vision policy: straight down onto the highest observed point, ``depth`` m below it,
    open wide; and a worse-scored copy 5 cm to the side."""
    SEEN.append(observation)
    top = observation.cloud[np.argmax(observation.cloud[:, 2])]
    best = Transform(top - [0.0, 0.0, float(depth)], TOP_DOWN)
    side = Transform(top + [0.05, 0.0, 0.0], TOP_DOWN)
    return [Grasp(side, 0.08, 0.1), Grasp(best, 0.08, 0.9)]


def test_a_callable_sees_the_kinect_only_and_the_arm_executes_its_best_grasp(convex_objects):
    SEEN.clear()
    config = AnnotatorConfig()
    sources = tuple(discover_objects(convex_objects))
    name = f"{__name__}:above_the_highest_point"
    job = ClutterSetup(sources, 2, 0, name, config, policy_args=(("depth", "0.02"),), views=2)
    summary = clutter_removal(job, 1)
    (round_,) = summary.rounds
    assert len(SEEN) == len(round_.attempts) >= 1
    fields = {f.name for f in dataclasses.fields(Observation)}
    assert fields == {
        "round_id", "attempt", "seed", "images", "cloud", "tsdf", "T_table_volume", "voxel_size",
        "workspace", "max_width", "gripper",
    }  # fmt: skip
    first = SEEN[0]
    assert (first.round_id, first.attempt, len(first.images)) == (0, 0, 2)
    assert not any(hasattr(first, a) for a in ("meshes", "models", "record", "instances", "segmentation"))
    assert first.images[0].depth.shape == (424, 512) and (first.images[0].depth > 0).any()
    assert first.workspace.contains(first.cloud).all() and (first.cloud[:, 2] > 0.02).any()
    assert first.tsdf.shape == (40, 40, 40) and (first.tsdf > 0).any()
    assert not first.cloud.flags.writeable and not first.images[0].depth.flags.writeable
    # the arm executed the best-scored grasp, at the pose the policy gave
    attempt = round_.attempts[0]
    top = first.cloud[np.argmax(first.cloud[:, 2])]
    np.testing.assert_allclose(attempt.proposal.T_table_tcp.pos, top - [0.0, 0.0, 0.02], atol=1e-12)
    assert attempt.proposal.score == pytest.approx(0.9) and attempt.proposal.width == pytest.approx(0.08)
    # a second look sees the pile as it is: a held object is gone from the cloud
    if attempt.success and len(SEEN) > 1:
        assert len(SEEN[1].cloud) != len(first.cloud)


def thin_air(observation: Observation) -> list[Grasp]:
    """Straight down at points of the workspace 13 cm or more from everything observed: nothing
    within the gripper's opening (the arm executes the first it reaches)."""
    lo, hi = np.asarray(observation.workspace.lower), np.asarray(observation.workspace.upper)
    grid = np.stack(np.meshgrid(*[np.linspace(lo[i] + 0.02, hi[i] - 0.02, 7) for i in range(3)]), -1)
    points = grid.reshape(-1, 3)
    gaps = np.linalg.norm(points[:, None] - observation.cloud[None, ::20], axis=2).min(axis=1)
    return [Grasp(Transform(p, TOP_DOWN), 0.08, 1.0) for p in points[gaps > 0.13]]


def test_every_attempt_says_what_it_went_for_and_why_it_failed(convex_objects):
    config = AnnotatorConfig()
    sources = tuple(discover_objects(convex_objects))
    for policy in ("above_the_highest_point", "thin_air"):
        job = ClutterSetup(sources, 2, 0, f"{__name__}:{policy}", config, views=1)
        summary = clutter_removal(job, 1)
        _, grasps = summary.tables()
        assert {"target_instance", "target_object", "failure"} <= set(grasps.columns)
        held, failed = grasps[grasps["label"] == 1], grasps[grasps["label"] == 0]
        assert (held["failure"] == "").all() and (held["target_object"] == held["object_id"]).all()
        assert failed["failure"].isin(list(FAILURES)).all() and (failed["held_instance"] == -1).all()
        if policy == "thin_air":  # two misses in a row end the round
            assert len(failed) == 2 and (failed["failure"] == "nothing_there").all()
            assert "failed attempts     nothing_there 2" in summary.lines("thin air")
            assert "rounds ended        2 failures in a row 1" in summary.lines("thin air")
            assert (failed["target_instance"] == -1).all() and (failed["target_object"] == "").all()
        else:
            assert (grasps["target_instance"] >= 0).all() and (grasps["target_object"] != "").all()


def nonsense(observation: Observation) -> Grasps:
    return Grasps.from_rows(np.array([[100.0, 0, 0.1, 1, 0, 0, 0, 0.05, 1.0]]))


def raises(observation: Observation) -> list[Grasp]:
    raise RuntimeError("my model file is\nmissing")


def exits(observation: Observation) -> list[Grasp]:
    import sys

    sys.exit(0)


def zero_quaternion(observation: Observation) -> np.ndarray:
    return np.array([[0.5, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.05, 1.0]])


def chatty(observation: Observation) -> None:
    print("thinking about the pile")
    return None


@pytest.mark.parametrize(
    "policy, said",
    [
        (f"{__name__}:raises", "the policy raised RuntimeError: my model file is missing"),
        (f"{__name__}:exits", "the policy called sys.exit(0): a policy returns grasps or None"),
        (f"{__name__}:zero_quaternion", "grasp 0: a zero quaternion is no rotation"),
        ("os:system", "the policy raised TypeError"),
    ],
)
def test_whatever_a_policy_raises_or_exits_with_ends_the_run_in_one_line_naming_it(
    convex_objects, policy, said
):
    """sys.exit(0) ended clutter-removal with exit 0 and no output; the others were tracebacks."""
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--per-scene", 1, "--workers", 1,
        "--policy", policy, check=2,
    )  # fmt: skip
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and f"--policy {policy}: {said}" in errors[0], result.output
    assert "Traceback" not in result.output


def test_what_a_policy_prints_does_not_mix_with_the_command_s_output(convex_objects):
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--per-scene", 1, "--workers", 1,
        "--policy", f"{__name__}:chatty",
    )  # fmt: skip
    assert "thinking about the pile" not in result.output and "grasp success rate" in result.output.lower()


def test_a_policy_module_with_a_syntax_error_is_one_line_before_any_work(
    convex_objects, tmp_path, monkeypatch
):
    (tmp_path / "broken_policy.py").write_text("def grasps(observation):\n    return [\n")
    monkeypatch.chdir(tmp_path)
    result = run_annotator(
        "clutter-removal",
        "--objects",
        convex_objects,
        "--rounds",
        1,
        "--policy",
        "broken_policy:grasps",
        check=2,
    )
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "broken_policy has a syntax error" in errors[0] and "line 2" in errors[0]
    assert "Traceback" not in result.output


def test_a_policys_nonsense_is_one_line(convex_objects):
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--per-scene", 1, "--workers", 1,
        "--policy", f"{__name__}:nonsense", check=2,
    )  # fmt: skip
    assert "outside the workspace" in result.output and "Traceback" not in result.output
    for policy, said in (
        (f"{__name__}:no_such_function", "has no no_such_function"),
        ("no_such_module_here:f", "cannot import"),
    ):
        result = run_annotator(
            "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", policy, check=2
        )
        assert said in result.output, result.output
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", f"{__name__}:nonsense",
        "--policy-arg", "model=x", check=2,
    )  # fmt: skip
    assert "cannot take" in result.output
    with pytest.raises(PolicyError, match="width"):
        Grasps.from_rows(np.array([[0.0, 0, 0.1, 1, 0, 0, 0, 5.0, 1.0]])).check(
            SEEN[0].workspace if SEEN else _workspace(), 0.11, 0.1
        )


def _workspace():
    from annotator.cli.clutter_removal import _workspace as ws

    return ws(AnnotatorConfig())


def test_grasps_come_in_every_documented_form():
    rows = np.array([[0.1, 0.2, 0.3, 0, 0, 0, 1, 0.05, 0.7]])
    a = Grasps.of(rows)
    b = Grasps.of([Grasp(Transform([0.1, 0.2, 0.3], [0, 0, 0, 1]), 0.05, 0.7)])
    np.testing.assert_array_equal(a.T_table_tcp, b.T_table_tcp)
    assert len(Grasps.of(None)) == 0 and len(Grasps.of([])) == 0
    with pytest.raises(PolicyError, match="must return"):
        Grasps.of(pd.DataFrame(rows))


@pytest.mark.slow  # a settled pile seen from three views and its grasps checked: several seconds
def test_vision_random_grasps_clear_the_observed_cloud_and_the_table(convex_objects):
    """On a known pile, seen from three views: every grasp vision-random returns holds the pads
    across an observed pair (the TCP between observed points), and its open gripper, at the grasp
    and every 5 mm back along the approach, holds no observed point above the table and stays above
    the table; the same call gives the same grasps."""
    from annotator.config import ProtocolConfig
    from annotator.grippers import load_gripper
    from annotator.objects import load_object
    from annotator.policies.gripper_boxes import box_corners, gripper_boxes, points_in_boxes
    from annotator.policies.observe import observe
    from annotator.policies.round_world import Round
    from annotator.policies.vision import TABLE_MARGIN, observed_surface, vision_random
    from annotator.scenes import SceneBuilder, SceneSpec

    config = AnnotatorConfig()
    models = {s.object_id: load_object(s, config.objects) for s in discover_objects(convex_objects)}
    record = SceneBuilder(models).build(SceneSpec(1, 0, "pile", 3, 3))
    round_ = Round(record, models, config, load_gripper(None))
    try:
        observation = observe(round_, 0, 3)
        grasps = vision_random(observation)
        again = vision_random(observe(round_, 0, 3))
        nearest = [round_._nearest(g) for g in (_proposal(grasps, k) for k in range(len(grasps)))]
    finally:
        round_.close()
    assert len(grasps) > 0
    np.testing.assert_array_equal(grasps.T_table_tcp, again.T_table_tcp)
    surface = observed_surface(observation)
    objects_seen = observation.cloud[observation.cloud[:, 2] > TABLE_MARGIN]
    boxes_of, protocol = gripper_boxes(), ProtocolConfig()
    for k in range(len(grasps)):
        T, w = grasps.T_table_tcp[k], float(grasps.width[k])
        assert 0 < w < observation.max_width
        pads = T[:3, 3] + np.outer([-w / 2, w / 2], T[:3, 0])  # where the pads' centres touch
        assert np.min(np.linalg.norm(surface.points[:, None] - pads, axis=2), axis=0).max() < 1e-9
        boxes = boxes_of.at(min(boxes_of.max_width, w + 2 * protocol.pregrasp_clearance), w)
        local = (objects_seen - T[:3, 3]) @ T[:3, :3]
        for back in np.arange(0.0, protocol.approach_distance + 1e-9, 0.005):
            assert not points_in_boxes(local + [0.0, 0.0, back], boxes).any(), (k, back)
            corners = (box_corners(boxes) - [0.0, 0.0, back]) @ T[:3, :3].T + T[:3, 3]
            assert corners[:, 2].min() >= 0.0
    assert all(n >= 0 for n in nearest)  # each on (or beside) an object of the pile


def _proposal(grasps, k):
    from annotator.policies import Proposal

    g = grasps.grasp(k)
    return Proposal(-1, g.T_table_tcp, g.width, g.score, None)


def _predictions(**change) -> pd.DataFrame:
    row = {"round": 0, "x": -0.15, "y": 0.0, "z": 0.05, "qx": 1.0, "qy": 0.0, "qz": 0.0, "qw": 0.0}
    row.update({"width": 0.05, "score": 1.0})
    row.update(change)
    return pd.DataFrame([row])


@pytest.mark.parametrize(
    "change, said",
    [
        ({"round": 7}, "no row for any of the rounds 0-0"),
        ({"width": 5.0}, "outside the gripper's stroke"),
        ({"width": -0.05}, "outside the gripper's stroke"),
        ({"x": 100.0}, "outside the workspace"),
    ],
)
def test_predictions_that_cannot_mean_the_piles_are_refused(convex_objects, tmp_path, change, said):
    path = tmp_path / "predictions.csv"
    _predictions(**change).to_csv(path, index=False)
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", path, check=2
    )
    assert said in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_a_repeated_predictions_column_is_refused(convex_objects, tmp_path):
    path = tmp_path / "predictions.csv"
    table = _predictions()
    path.write_text(",".join([*table.columns, "x"]) + "\n" + ",".join(map(str, [*table.iloc[0], 9.0])) + "\n")
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", path, check=2
    )
    assert "['x'] appear more than once" in result.output


def test_clutter_removal_never_replaces_a_rounds_csv_it_did_not_write(convex_objects, tmp_path):
    predictions = tmp_path / "predictions.csv"
    _predictions().to_csv(predictions, index=False)
    out = tmp_path / "out"
    out.mkdir()
    mine = out / "rounds.csv"
    mine.write_text("my own notes\n")
    args = [
        "clutter-removal",
        "--objects",
        convex_objects,
        "--rounds",
        1,
        "--per-scene",
        1,
        "--workers",
        1,
    ]
    args += ["--policy", predictions, "--out", out]
    result = run_annotator(*args, check=2)
    assert "rounds.csv exists and was not written by this tool; pass --overwrite" in result.output
    assert mine.read_text() == "my own notes\n"
    run_annotator(*args, "--overwrite")
    written = pd.read_csv(mine)
    assert list(written.columns) == ["round_id", "object_count", "successes", "attempts", "ended"]
    run_annotator(*args)  # its own file: replaced without asking
    assert pd.read_csv(mine).equals(written)
    mine.write_text(mine.read_text() + "0,1,0,0,edited\n")  # edited since: not its own any more
    assert "rounds.csv was written by this tool" in run_annotator(*args, check=2).output


def test_policy_names_resolve_to_their_callables():
    from annotator.learn.policy import learned
    from annotator.policies.resolve import is_vision_policy, load_callable
    from annotator.policies.vision import vision_random

    assert load_callable("vision-random") is vision_random and load_callable("learned") is learned
    assert load_callable(f"{__name__}:nonsense") is nonsense
    assert not is_vision_policy("labels") and not is_vision_policy("random")
    assert not is_vision_policy("predictions.csv") and is_vision_policy("a.b:c")
    with pytest.raises(PolicyError, match="no such policy"):
        load_callable("no-such-policy")


@pytest.mark.slow
def test_the_docs_example_policy_runs_from_the_current_folder_as_the_docs_say(convex_objects, tmp_path):
    """docs/learning.md's policy saved as my_policy.py in the current folder: the loop and its
    workers import it without PYTHONPATH (it failed with "No module named my_policy")."""
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from test_docs import python_blocks

    blocks = python_blocks()
    (code,) = [
        code
        for where, code in blocks
        if where.startswith("docs/learning.md:") and "def highest_point" in code
    ]
    (tmp_path / "my_policy.py").write_text(code)
    shutil.copytree(convex_objects, tmp_path / "objects")
    exe = shutil.which("annotator", path=str(Path(sys.executable).parent)) or shutil.which("annotator")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for workers in ("1", "2"):
        done = subprocess.run(
            [exe, "clutter-removal", "--objects", "objects/", "--rounds", "1", "--per-scene", "2",
             "--policy", "my_policy:highest_point", "--policy-arg", "depth=0.03", "--workers", workers],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr and "grasp success rate" in done.stdout.lower()
