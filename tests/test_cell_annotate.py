"""``annotate --cell [--views K]``: objects resting on the seed's table, reachability, Kinect views.

Real physics throughout: a trial on a box resting on the table, then one end-to-end run of the
command on two sample objects whose files (labels, PNGs, camera tables) the tests read back.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh
from click.testing import CliRunner

from annotator.cell import build_cell
from annotator.cell.batch import JOINT_COLUMNS, PARKED
from annotator.cell.reach import REASONS
from annotator.cell.views import OBJECT_POSE_COLUMNS, SEG_OBJECT, load_cameras, open_view
from annotator.cli import annotate_command
from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels
from annotator.geometry import Transform
from annotator.objects import create_body, load_object, reset_object_pose
from annotator.outcome import Outcome
from annotator.sim import ur3
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.store import ARTIFACTS_DIR, MANIFEST_NAME
from annotator.trial import GraspTrial

SAMPLES = Path(__file__).resolve().parents[1] / "objects"
N = 20  # two spans per object
DOWN = np.diag([1.0, -1.0, -1.0])  # TCP z pointing down: a grasp from above
# quick colour images (a quarter of 1920 x 1080): the views' geometry does not depend on it
CONFIG_TOML = "[kinect]\nviews_color_scale = 0.25\n"


@pytest.fixture(scope="module", autouse=True)
def _cache_dir(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RG2_CACHE_DIR", str(tmp_path_factory.mktemp("rg2-cache")))
        yield


def test_a_gripper_that_would_hit_the_table_is_a_collision(tmp_path):
    """A 30 mm box resting on the table, grasped from above across its 50 mm: with the TCP 10 mm
    above the table top the fingertips would go through the table (collision; without the table
    in the checks the physics runs and the fingers stall on it); 20 mm up the box is held and
    lifted off the table."""
    config = AnnotatorConfig()
    trimesh.creation.box((0.05, 0.05, 0.03)).export(tmp_path / "box.obj")
    model = load_object(tmp_path / "box.obj", config.objects)
    with World(config.physics) as world:
        hand = FloatingGripper(world, config.gripper)
        table = build_cell(world, config.cell, robot=False, kinect=False)
        hand.teleport(PARKED, hand.gripper.max_width)
        uid = create_body(world.client, model)
        reset_object_pose(world.client, uid, Transform([0.35, 0.0, table.top.z + 0.015], [0, 0, 0, 1]))
        in_cell = GraspTrial(world, hand, uid, config, obstacles=(table.table.uid,), resting=True)
        unchecked = GraspTrial(world, hand, uid, config, resting=True)
        low = Transform.from_rotation(DOWN, [0.0, 0.0, -0.005])  # 10 mm above the table top
        high = Transform.from_rotation(DOWN, [0.0, 0.0, 0.005])  # 20 mm above it
        assert in_cell.run(low, 0.05).outcome == Outcome.COLLISION
        assert unchecked.run(low, 0.05).outcome != Outcome.COLLISION
        assert in_cell.run(high, 0.05).outcome == Outcome.SUCCESS


def _annotate(objs: Path, out: Path, *extra, check: int = 0):
    config = out.parent / "views.toml"
    config.write_text(CONFIG_TOML)
    args = ["--objects", objs, "--n", N, "--out", out, "--quiet", "--config", config, *extra]
    result = CliRunner().invoke(annotate_command, [str(a) for a in args], catch_exceptions=False)
    assert result.exit_code == check, result.output
    return result


@pytest.fixture(scope="module")
def cell_run(tmp_path_factory) -> tuple[Path, Path]:
    """``annotate --cell --views 1`` on the sample box and can, 2 workers."""
    root = tmp_path_factory.mktemp("cell")
    objs = root / "objects"
    objs.mkdir()
    for name in ("box.obj", "can.stl"):
        shutil.copy(SAMPLES / name, objs)
    out = root / "labels"
    _annotate(objs, out, "--cell", "--views", 1, "--workers", 2)
    return objs, out


def _T_world_obj(row: pd.Series) -> Transform:
    values = row[list(OBJECT_POSE_COLUMNS)].to_numpy(dtype=float)
    return Transform(values[:3], values[3:])


def _T_world_cmd(row: pd.Series) -> Transform:
    cmd = row[["cmd_x", "cmd_y", "cmd_z", "cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw"]].to_numpy(dtype=float)
    return _T_world_obj(row) * Transform.exact(cmd[:3], cmd[3:])


@pytest.mark.slow
def test_cell_labels_have_the_columns_and_a_placement_each(cell_run):
    _, out = cell_run
    df = load_labels(out)  # pandas.read_parquet underneath: the _views/ folder is not read as labels
    assert df.groupby("object_id").size().to_dict() == {"box": N, "can": N}
    for column in ("placement_id", "placement_probability", *OBJECT_POSE_COLUMNS, "reachable"):
        assert column in df.columns
    assert df["reachable"].dtype == bool and df["placement_id"].dtype == np.int64
    q = df[list(JOINT_COLUMNS)].to_numpy()
    reachable = df["reachable"].to_numpy()
    assert np.isfinite(q[reachable]).all() and np.isnan(q[~reachable]).all()
    assert (df.loc[reachable, "unreachable_reason"] == "").all()
    assert set(df.loc[~reachable, "unreachable_reason"]) <= set(REASONS)
    assert reachable.any() and (~reachable).any() and df["success"].any()
    info = json.loads((out / MANIFEST_NAME).read_text())["objects_info"]["box"]["placements"]
    assert [p["placement_id"] for p in info] == sorted(set(df.loc[df.object_id == "box", "placement_id"]))
    # every placement rests on the table top, a few mm of settling at most
    config = AnnotatorConfig()
    model = load_object(SAMPLES / "box.obj", config.objects)
    with World() as world:
        top = build_cell(world, config.cell, robot=False, kinect=False).top
    for _, row in df[df.object_id == "box"].drop_duplicates("placement_id").iterrows():
        lowest = _T_world_obj(row).apply(model.mesh.vertices)[:, 2].min()
        assert lowest == pytest.approx(top.z, abs=0.002)


@pytest.mark.slow
def test_candidates_come_from_above_shared_by_placement_probability_and_mostly_hold(cell_run):
    """Each object's N rows are shared among its placements by their stable-pose probabilities (as
    the manifest lists them), every commanded grasp approaches within the cone of straight down,
    and on the box and the can at least a third hold (with the floating sampler's candidates, a
    fifth of the box's and a tenth of the can's held in the cell)."""
    from annotator.cell.candidates import allocate

    _, out = cell_run
    df = load_labels(out)
    config = AnnotatorConfig()
    info = json.loads((out / MANIFEST_NAME).read_text())["objects_info"]
    cos_cone = np.cos(np.radians(config.cell.approach_cone))
    for oid, rows in df.groupby("object_id"):
        probabilities = [p["probability"] for p in info[oid]["placements"]]
        counts = rows["placement_id"].value_counts().reindex(range(len(probabilities)), fill_value=0)
        assert counts.tolist() == allocate(N, probabilities, "probability").tolist()
        for _, row in rows.iterrows():
            assert -_T_world_cmd(row).rotation[2, 2] >= cos_cone - 1e-9
        assert rows["success"].sum() >= N / 3, oid


def test_a_puck_lower_than_the_pads_is_held_from_above(tmp_path):
    """A 16 mm puck lying flat (its one placement here): its contacts are lower than the pads'
    centres are above the fingertips (14.9 mm), so a grasp centred on them puts the fingers into
    the table (the floating sampler's candidates: 0 of 40 held; the sample ring, an 18 mm tube, 0 of
    100). Standing off along the approach, grasps from above hold it (32 of 40), the pad centres
    more than 15 mm above the table top."""
    from annotator.objects import discover_objects
    from annotator.pipeline.modes import CellMode
    from annotator.pipeline.tasks import Span, SpanTask
    from annotator.pipeline.worker import label_span

    trimesh.creation.cylinder(radius=0.03, height=0.016, sections=32).export(tmp_path / "puck.obj")
    (source,) = discover_objects(tmp_path)
    n = 8
    config = AnnotatorConfig.from_dict({"cell": {"placements_per_object": 1}})  # flat, not on its rim
    task = SpanTask(span=Span("puck", source, None, 0, n), config=config, seed=0, n=n, mode=CellMode())
    result = label_span(task)
    assert result.error is None, result.error
    rows = result.rows
    assert rows["success"].sum() >= 3
    with World() as world:
        top_z = build_cell(world, config.cell, robot=False, kinect=False).top.z
    for _, row in rows[rows["success"]].iterrows():
        assert _T_world_cmd(row).pos[2] - top_z > 0.015


def test_nothing_held_approaches_from_below_the_table_top(cell_run):
    """The whole open gripper along the approach stays above the table: the TCP of a success, and
    every point 10 cm back along its approach, is above the table top."""
    _, out = cell_run
    df = load_labels(out)
    config = AnnotatorConfig()
    with World() as world:
        top_z = build_cell(world, config.cell, robot=False, kinect=False).top.z
    successes = df[df["success"]]
    assert len(successes) >= 2
    for _, row in successes.iterrows():
        T = _T_world_cmd(row)
        for back in np.linspace(0.0, config.protocol.approach_distance, 11):
            assert (T.pos - back * T.rotation[:, 2])[2] > top_z


def test_q_grasp_round_trips_through_the_arms_kinematics_to_the_commanded_tcp(cell_run):
    """FK of q_grasp, through the mount and the RG2's TCP at the commanded width, is the label's
    commanded TCP (cmd_* in the object frame, placed by obj_*) in the world."""
    _, out = cell_run
    df = load_labels(out)
    rows = df[df["reachable"]]
    assert len(rows) >= 3
    config = AnnotatorConfig()
    frames = ur3.arm_frames(None, config.gripper)
    with World() as world:
        cell = build_cell(world, config.cell, robot=True, kinect=False, gripper=config.gripper)
        T_world_baselink = cell.T_world_baselink
    for _, row in rows.iterrows():
        q = row[list(JOINT_COLUMNS)].to_numpy(dtype=float)
        T_fk = T_world_baselink * frames.tcp_pose(q, float(row["cmd_width"]))
        T_cmd = _T_world_cmd(row)
        np.testing.assert_allclose(T_fk.pos, T_cmd.pos, atol=1e-6)
        np.testing.assert_allclose(T_fk.rotation, T_cmd.rotation, atol=1e-6)


def test_views_are_written_with_their_cameras_and_read_without_the_package(cell_run):
    from PIL import Image

    _, out = cell_run
    cameras = load_cameras(out)
    labels = load_labels(out)
    placements = labels.drop_duplicates(["object_id", "placement_id"])
    assert len(cameras) == len(placements)  # --views 1: the seed's Kinect, once per placement
    row = cameras.iloc[0]
    with Image.open(out / row["depth"]) as depth:
        assert depth.mode in ("I;16", "I") and depth.size == (512, 424)
    with Image.open(out / row["segmentation"]) as seg:
        assert seg.mode == "L"
    assert (out / ARTIFACTS_DIR).is_dir() and not list(out.glob("*.png"))


def test_rendered_depth_of_the_box_is_right_at_its_centre_and_grasps_land_on_its_mask(cell_run):
    """From the files alone: the depth PNG at the box's top-face centre is within 5 mm of its
    known geometry, and the TCPs of its successes, moved into the camera frame, project onto the
    box's segmentation mask."""
    _, out = cell_run
    config = AnnotatorConfig()
    model = load_object(SAMPLES / "box.obj", config.objects)
    cameras = load_cameras(out)
    labels = load_labels(out)
    checked = 0
    for _, camera in cameras[cameras.object_id == "box"].iterrows():
        view = open_view(out, camera)
        corners = view.T_world_obj.apply(model.mesh.vertices)
        centre = np.append(view.T_world_obj.apply(model.center_mass)[:2], corners[:, 2].max())
        centre_camera = view.T_world_camera.inverse().apply(centre)
        ((u, v),) = np.round(view.project(centre_camera)).astype(int)
        assert view.segmentation[v, u] == SEG_OBJECT
        assert view.depth[v, u] == pytest.approx(centre_camera[2], abs=0.005)
        rows, T_camera_tcp = view.labels_in_camera(labels)
        held = rows["success"].to_numpy()
        for u, v in np.round(view.project(T_camera_tcp[held, :3, 3])).astype(int):
            assert view.segmentation[v, u] == SEG_OBJECT
            checked += 1
        assert len(view.point_cloud()) == int((view.depth > 0).sum())
    assert checked >= 1


def test_a_cell_run_resumes_and_refuses_other_cell_settings(cell_run, tmp_path):
    objs, out = cell_run
    copy = tmp_path / "labels"
    shutil.copytree(out, copy)
    before = load_labels(copy)
    result = _annotate(objs, copy, "--cell", "--views", 1)
    assert "0 candidates simulated" in result.output
    pd.testing.assert_frame_equal(load_labels(copy), before)
    for extra, named in [
        (("--cell", "--views", 2), "cell {'views': 1} in the folder, {'views': 2} now"),
        ((), "cell {'views': 1} in the folder, None now"),  # a floating run on a cell folder
    ]:
        assert named in _annotate(objs, copy, *extra, check=2).output
    changed = tmp_path / "changed.toml"
    changed.write_text(CONFIG_TOML + "[cell]\nplacement_x = 0.3\n")
    args = [
        "--objects",
        objs,
        "--n",
        N,
        "--out",
        copy,
        "--quiet",
        "--config",
        changed,
        "--cell",
        "--views",
        1,
    ]
    result = CliRunner().invoke(annotate_command, [str(a) for a in args])
    assert result.exit_code == 2 and "[cell] placement_x 0.35 in the folder, 0.3 now" in result.output
    assert (
        CliRunner()
        .invoke(annotate_command, [str(a) for a in ["--objects", objs, "--n", 5, "--views", 2]])
        .exit_code
        == 2
    )


def test_a_cell_success_replays_on_the_arm_at_its_placement_with_its_q_grasp(cell_run):
    """The arm reaches a cell label's commanded grasp with the label's own joints, and lifts."""
    from annotator.cell.execute import execute_plan
    from annotator.tools.replay import plan_replay

    _, out = cell_run
    labels = load_labels(out)
    row = labels[(labels.object_id == "box") & labels.success & labels.reachable].iloc[0]
    config = AnnotatorConfig()
    model = load_object(SAMPLES / "box.obj", config.objects)
    with World(config.physics) as world:
        cell = build_cell(world, config.cell, gripper=config.gripper, kinect=False)
        obj = create_body(world.client, model)
        plan = plan_replay(cell, model, obj, row, config)
        assert plan.note == "placement: the label's own"
        np.testing.assert_allclose(plan.reach.q_grasp, row[list(JOINT_COLUMNS)].to_numpy(float), atol=1e-9)
        result = execute_plan(cell, obj, plan, config, camera=None)
    assert result.held(config.protocol.lift_height, config.protocol.max_slip)
