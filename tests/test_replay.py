"""Replay a label on the UR3 + RG2 in the cell: a box success lifts the box, a collision touches it."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from PIL import Image, ImageSequence

from annotator.cell import build_cell
from annotator.cell.execute import execute_plan
from annotator.cli.replay import replay_command
from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels
from annotator.objects import create_body, load_object
from annotator.pipeline.run import ObjectOptions, RunOptions, run
from annotator.sim.world import World
from annotator.tools.replay import PLACEMENT_COLUMNS, plan_replay

CONFIG = AnnotatorConfig()
SAMPLES = Path(__file__).resolve().parent.parent / "objects"


@pytest.fixture(scope="module")
def box_labels(tmp_path_factory):
    """Real floating labels of the sample box (20 candidates, one worker)."""
    root = tmp_path_factory.mktemp("replay")
    objects = root / "objects"
    objects.mkdir()
    shutil.copy(SAMPLES / "box.obj", objects / "box.obj")
    out = root / "labels"
    run(RunOptions(objects_dir=objects, n=20, out_dir=out, workers=1, quiet=True), CONFIG)
    return objects, out, load_labels(out)


def _world_with_box(objects):
    world = World(CONFIG.physics)
    cell = build_cell(world, CONFIG.cell, gripper=CONFIG.gripper, kinect=False)
    model = load_object(objects / "box.obj", CONFIG.objects)
    return world, cell, model, create_body(world.client, model)


def test_a_reachable_box_success_lifts_the_box(box_labels):
    objects, _, labels = box_labels
    successes = labels[labels.outcome == "success"]
    assert len(successes) >= 3
    world, cell, model, obj = _world_with_box(objects)
    with world:
        for _, row in successes.iterrows():
            plan = plan_replay(cell, model, obj, row, CONFIG)
            if plan.reach.reachable:
                break
        else:
            pytest.fail("no box success is reachable in any placement")
        # the placement puts the box on the table, the arm path ends at the label's TCP pose
        assert plan.T_world_obj.pos[2] > cell.top.z
        np.testing.assert_allclose(
            cell.tcp_pose(plan.reach.q_grasp, plan.width).pos, plan.T_world_tcp.pos, atol=1e-9
        )
        result = execute_plan(cell, obj, plan, CONFIG)
        assert result.approach_contacts == []
        assert result.pads_touching == 2
        assert result.closed_width == pytest.approx(float(row["width"]), abs=0.003)
        assert result.lifted(CONFIG.protocol.lift_height), result.rise
        assert result.held(CONFIG.protocol.lift_height, CONFIG.protocol.max_slip)
        assert result.slip < 0.005


def test_a_collision_row_reports_the_contact(box_labels):
    objects, _, labels = box_labels
    collisions = labels[labels.outcome == "collision"]
    assert len(collisions) >= 1
    world, cell, model, obj = _world_with_box(objects)
    with world:
        for _, row in collisions.iterrows():
            plan = plan_replay(cell, model, obj, row, CONFIG)
            if plan.reach.reachable:
                break
        else:  # the sample gives reachable collision rows; a sampler change must not turn this off
            pytest.fail(f"none of the {len(collisions)} collision rows is reachable in any placement")
        result = execute_plan(cell, obj, plan, CONFIG)
        assert any("the object" in c for c in result.approach_contacts), result.approach_contacts


def test_a_labels_own_placement_is_used(box_labels):
    """A label that carries the object's pose on the table (annotate --cell) is replayed there."""
    objects, _, labels = box_labels
    row = labels[labels.outcome == "success"].iloc[0].copy()
    world, cell, model, obj = _world_with_box(objects)
    with world:
        chosen = plan_replay(cell, model, obj, row, CONFIG)
        moved = chosen.T_world_obj.pos + np.array([0.03, -0.02, 0.0])
        for name, value in zip(PLACEMENT_COLUMNS, [*moved, *chosen.T_world_obj.quat], strict=True):
            row[name] = value
        plan = plan_replay(cell, model, obj, row, CONFIG)
        assert plan.note == "placement: the label's own"
        np.testing.assert_allclose(plan.T_world_obj.pos, moved, atol=1e-12)


@pytest.mark.slow
def test_replay_command_prints_the_verdict_and_writes_a_gif(box_labels, tmp_path):
    objects, out, labels = box_labels
    grasp = int(labels[labels.outcome == "success"].iloc[0]["grasp_id"])
    gif = tmp_path / "replay.gif"
    args = [str(out), "--object", "box", "--grasp", str(grasp), "--objects", str(objects), "--gif", str(gif)]
    result = CliRunner().invoke(replay_command, args)
    assert result.exit_code == 0, result.output
    assert "placement:" in result.output and "lift: the object" in result.output
    assert "verdict:" in result.output
    with Image.open(gif) as im:
        assert im.n_frames > 20
    bad = CliRunner().invoke(
        replay_command, [str(out), "--object", "box", "--grasp", "999", "--objects", str(objects)]
    )
    assert bad.exit_code == 2 and "has no grasp 999" in bad.output
    missing = CliRunner().invoke(
        replay_command, [str(out), "--object", "nope", "--grasp", "0", "--objects", str(objects)]
    )
    assert missing.exit_code == 2 and "no labels for object 'nope'" in missing.output


@pytest.mark.slow
def test_a_light_blocks_cell_labels_replay_as_labelled(tmp_path):
    """A 10 g block (under ``[physics] light_object_mass``) is labelled at a third of the time step;
    ``annotator replay`` simulates it at the same step, so every reachable success is held on the
    arm too (at 1/240 s, 3 of these 6 fell out of the hand or were dropped on the lift). The GIF
    keeps 20 frames per simulated second."""
    objects = tmp_path / "objects"
    objects.mkdir()
    trimesh.creation.box((0.03, 0.03, 0.022)).export(objects / "block.obj")
    model = load_object(objects / "block.obj", CONFIG.objects)
    assert model.mass < 0.011 and model.substeps(CONFIG.physics) == 3
    out = tmp_path / "labels"
    options = RunOptions(objects_dir=objects, n=10, out_dir=out, workers=1, quiet=True)
    run(options, CONFIG, ObjectOptions(cell=True))
    labels = load_labels(out)
    successes = labels[labels.success & labels.reachable]
    assert len(successes) >= 5
    for k, grasp in enumerate(successes["grasp_id"]):
        args = [str(out), "--object", "block", "--grasp", str(grasp), "--objects", str(objects)]
        gif = tmp_path / "block.gif"
        result = CliRunner().invoke(replay_command, args + (["--gif", str(gif)] if k == 0 else []))
        assert result.exit_code == 0, result.output
        assert "verdict: held (the label says success)" in result.output, (grasp, result.output)
        if k == 0:  # one frame per 50 ms simulated (identical frames merged): ~4.5 s of replay
            with Image.open(gif) as im:
                durations = [frame.info["duration"] for frame in ImageSequence.Iterator(im)]
            assert all(d % 50 == 0 for d in durations) and 3000 < sum(durations) < 7000, durations
