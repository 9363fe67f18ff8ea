"""Labels among neighbours: the collision check names what it hit, trials run where the target
rests among its neighbours and say how far they moved, candidates depend on their keys only."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scene_helpers import CONVEX, load_models

from annotator.cell.world import build_cell
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.outcome import Outcome
from annotator.scenes import SceneBuilder, SceneSpec
from annotator.scenes.arrange import workspace_on
from annotator.scenes.labels import (
    HIT_NEIGHBOUR,
    HIT_NONE,
    HIT_TABLE,
    SCENE_LABEL_COLUMNS,
    SceneCandidates,
    SceneTrials,
    label_scene,
)
from annotator.scenes.records import KEPT, Instance, SceneRecord
from annotator.sim.world import World

CAN_RADIUS = 0.033  # m, objects/can.stl
BOX_HALF_X = 0.03  # m, objects/box.obj is 60 x 40 x 120 mm, its base at z = 0
# A top-down grasp across the box's 60 mm side, pads 15 mm below its top, closing along the mesh's x
# (towards where the can stands).
TOP_DOWN = Transform.from_rotation(np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]), [0.0, 0.0, 0.105])
DRIFT = 2e-4  # m: how far a resting neighbour may drift while a trial beside it runs


@pytest.fixture(scope="module")
def models():
    return load_models(CONVEX)


@pytest.fixture(scope="module")
def table():
    config = AnnotatorConfig()
    with World() as world:
        cell = build_cell(world, config.cell, robot=False, kinect=False)
        return cell.top.T_world_top, workspace_on(cell, config.scenes)


def box_and_can(models, table, gap: float | None) -> SceneRecord:
    """The box upright at the workspace's centre and, unless ``gap`` is None, the can upright
    beside it along x with ``gap`` m between them (table frame)."""
    T_world_table, ws = table
    c = ws.center
    instances = [
        Instance(0, "box", KEPT, Transform([c[0], c[1], 0.0], [0, 0, 0, 1]), 1.0, models["box"].mass)
    ]
    if gap is not None:
        x = c[0] + BOX_HALF_X + gap + CAN_RADIUS
        pose = Transform([x, c[1], 0.0], [0, 0, 0, 1])
        instances.append(Instance(1, "can", KEPT, pose, 1.0, models["can"].mass))
    return SceneRecord(0, 0, "table", tuple(instances), ws, T_world_table)


def test_a_grasp_whose_finger_meets_a_neighbour_is_a_collision_naming_it(models, table):
    """The open finger (80 mm apart for the 60 mm box) reaches 51 mm from the box's centre: with the
    can 12 mm from the box it hits the can on the way down; 50 mm away the same grasp holds, and
    alone the box holds too."""
    config = AnnotatorConfig()
    with SceneTrials(box_and_can(models, table, 0.012), models, config) as trials:
        got = trials.run(0, TOP_DOWN, 0.06)
        assert got.result.outcome == Outcome.COLLISION
        assert got.check.stage == "approach"
        assert trials.hit_of(got.check, 0) == (HIT_NEIGHBOUR, 1)
        assert got.disturbance < 1e-9  # nothing was simulated
    with SceneTrials(box_and_can(models, table, 0.05), models, config) as trials:
        got = trials.run(0, TOP_DOWN, 0.06)
        assert got.result.outcome == Outcome.SUCCESS, got.result
        assert trials.hit_of(got.check, 0) == (HIT_NONE, -1)
        assert got.disturbed_instance == 1 and got.disturbance < DRIFT  # the can stayed where it was
    with SceneTrials(box_and_can(models, table, None), models, config) as trials:
        got = trials.run(0, TOP_DOWN, 0.06)
        assert got.result.outcome == Outcome.SUCCESS
        assert got.disturbed_instance == -1 and got.disturbance == 0.0


def test_a_grasp_into_the_table_names_the_table(models, table):
    """Pads 25 mm beside the box, their centres 5 mm above the table: their lower half in it."""
    low = Transform([BOX_HALF_X + 0.055, 0.0, 0.005], TOP_DOWN.quat)
    with SceneTrials(box_and_can(models, table, None), models, AnnotatorConfig()) as trials:
        got = trials.run(0, low, 0.02)  # open 40 mm: the fingers 20 mm from the box at least
        assert got.result.outcome == Outcome.COLLISION
        assert trials.hit_of(got.check, 0) == (HIT_TABLE, -1)


def test_scene_rows_carry_the_scene_columns_and_poses_in_both_frames(models, table):
    record = box_and_can(models, table, 0.012)
    T = np.stack([TOP_DOWN.as_matrix(), Transform([0.0, 0.0, 0.09], TOP_DOWN.quat).as_matrix()])
    T[1, :3, 3] = [0.0, 0.0, 0.095]  # the second on the can (its top is 115 mm up)
    candidates = SceneCandidates(T, np.array([0.06, 0.066]), np.array([0, 1]), np.array([True, True]))
    with SceneTrials(record, models, AnnotatorConfig()) as trials:
        rows = label_scene(trials, candidates, 0, 2, seed=0)
    assert set(SCENE_LABEL_COLUMNS) <= set(rows.columns)
    assert rows["object_id"].tolist() == ["box", "can"] and rows["instance_id"].tolist() == [0, 1]
    assert rows.loc[0, "collided_with"] == HIT_NEIGHBOUR and rows.loc[0, "collided_instance"] == 1
    assert rows["gripper"].tolist() == ["rg2", "rg2"]
    for k in range(2):  # the table-frame pose is the mesh-frame pose moved by the instance's pose
        inst = record.instance(int(rows.loc[k, "instance_id"]))
        T_obj = Transform(rows.loc[k, ["x", "y", "z"]].to_numpy(float), rows.loc[k, ["qx", "qy", "qz", "qw"]])
        T_table = inst.T_table_obj * T_obj
        cols = [f"table_tcp_{c}" for c in ("x", "y", "z")]
        np.testing.assert_allclose(rows.loc[k, cols].to_numpy(float), T_table.pos, atol=1e-12)


def test_lift_only_trials_never_shake(models, table):
    """``[scenes] shake = false``: close and lift, judged after the lift (VGN's trial): fewer steps,
    and a grasp that holds is still a success."""
    record = box_and_can(models, table, 0.05)
    shake = AnnotatorConfig()
    lift = dataclasses.replace(shake, scenes=dataclasses.replace(shake.scenes, shake=False))
    with SceneTrials(record, models, shake) as trials:
        full = trials.run(0, TOP_DOWN, 0.06).result
    with SceneTrials(record, models, lift) as trials:
        short = trials.run(0, TOP_DOWN, 0.06).result
    assert full.outcome == short.outcome == Outcome.SUCCESS
    shake_steps = round(shake.protocol.shake_duration / shake.physics.time_step)
    assert full.steps - short.steps >= shake_steps - 1


@pytest.mark.slow
def test_candidates_depend_on_the_scene_and_seed_only(models):
    """Each kept instance gets an equal share, sampled in its own frame from above; the same keys
    give the same candidates in any world, another seed other ones."""
    record = SceneBuilder(models).build(
        SceneSpec(2, seed=0, arrangement="packed", min_objects=3, max_objects=3)
    )
    config = AnnotatorConfig()
    with SceneTrials(record, models, config) as trials:
        a = trials.candidates(30, seed=0)
        other = trials.candidates(30, seed=1)
    with SceneTrials(record, models, config) as trials:
        b = trials.candidates(30, seed=0)
    for name in ("T_obj_tcp", "width_expected", "instance_id", "antipodal"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.T_obj_tcp, other.T_obj_tcp)
    counts = np.bincount(a.instance_id)[[i.instance_id for i in record.kept]]
    assert counts.max() - counts.min() <= 1 and counts.sum() == 30
    for k in range(len(a)):  # every approach comes from above, within the cell's cone
        inst = record.instance(int(a.instance_id[k]))
        approach = (inst.T_table_obj * Transform.from_matrix(a.T_obj_tcp[k])).rotation[:, 2]
        assert approach[2] <= -np.cos(np.radians(config.cell.approach_cone)) + 1e-9


def test_with_the_arm_rows_say_whether_the_ur3_reaches_the_grasp(models, table):
    """``--cell``: the top-down grasp on the box at the workspace's centre (mid-reach) is reachable,
    with the arm's joints; a grasp from below the table is not."""
    from annotator.scenes.labels import SceneArm

    record = box_and_can(models, table, 0.05)
    arm = SceneArm(record, models, AnnotatorConfig())
    try:
        top = arm.columns(0, TOP_DOWN, 0.06, "test")
        assert top["reachable"] and top["unreachable_reason"] == ""
        q = np.array([top[f"q_grasp_{i}"] for i in range(6)])
        assert np.isfinite(q).all()
        T_world_tcp = arm.scene.cell.tcp_pose(q, 0.06)
        np.testing.assert_allclose(T_world_tcp.pos, record.T_world_obj(0).apply(TOP_DOWN.pos), atol=1e-6)
        upwards = Transform([0.0, 0.0, 0.06], [0.0, 0.0, 0.0, 1.0])  # TCP z (the approach) along +z
        up = arm.columns(0, upwards, 0.06, "test")  # from under the table
        assert not up["reachable"] and up["unreachable_reason"]
    finally:
        arm.close()
