"""The tools on a scene run: exports read back as VGN and Contact-GraspNet read them, the scene's
picture, clutter removal on the UR3 with each policy."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from helpers import SCENE_RUN_N, run_annotate, run_annotator
from scene_helpers import REPO

from annotator.config import AnnotatorConfig
from annotator.dataset import load_scenes
from annotator.geometry import Transform
from annotator.objects import discover_objects, load_object
from annotator.policies.clutter import ClutterSetup, clutter_removal, read_predictions, wilson
from annotator.scenes import SceneBuilder, SceneSpec, same_scene, scenes_from_table
from annotator.tools import export_cgn, export_vgn
from annotator.tools.export import TcpDepth
from annotator.tools.scene_labels import open_scene_labels

N = SCENE_RUN_N


def test_vgn_export_reads_back_as_vgn_reads_it(convex_scene_run, tmp_path):
    out = tmp_path / "vgn"
    run_annotator("export", convex_scene_run, "--format", "vgn", "--out", out)
    scenes = open_scene_labels(convex_scene_run, "test")
    setup = export_vgn.read_setup(out)
    views = scenes.views(0)
    assert setup["size"] == pytest.approx(0.3) and setup["finger_depth"] == pytest.approx(0.05)
    assert setup["intrinsic"] == views[0].depth_K
    assert setup["max_opening_width"] == pytest.approx(TcpDepth("rg2").max_width)
    df = export_vgn.read_grasps(out)
    reach = export_vgn.fingertip_reach(scenes.gripper)
    assert list(df.columns) == list(export_vgn.RAW_COLUMNS) and N < len(df) <= 2 * N
    for scene_id in (0, 1):
        record, rows = scenes.records[scene_id], scenes.rows(scene_id)
        offset = reach(rows["width"].to_numpy()) - setup["finger_depth"]  # VGN's palm on our TCP's z
        inside = export_vgn.inside_grid(record, scenes.grasps(scene_id), setup["size"], offset=offset)
        rows, offset = rows[inside].reset_index(drop=True), offset[inside]
        part = df[df["scene_id"] == export_vgn.scene_name(scene_id)].reset_index(drop=True)
        assert part["label"].tolist() == rows["success"].astype(int).tolist()
        np.testing.assert_array_equal(part["width"].to_numpy(), rows["width"].to_numpy())
        for k in range(len(part)):
            T_task_vgn, _, _ = export_vgn.grasp_in_task(part.loc[k])
            T_table_tcp = export_vgn.tcp_in_table(T_task_vgn.as_matrix(), record, offset[k])
            want = rows.loc[k, [f"table_tcp_{c}" for c in "xyz"]].to_numpy(float)
            np.testing.assert_allclose(T_table_tcp[:3, 3], want, atol=1e-12)
        depth, extrinsics = export_vgn.read_sensor_data(out, export_vgn.scene_name(scene_id))
        assert depth.shape == (1, 424, 512) and depth.dtype == np.float32 and extrinsics.shape == (1, 7)
        grid = export_vgn.read_grid(out / "dataset", export_vgn.scene_name(scene_id))
        assert grid.shape == (1, 40, 40, 40) and (grid != 0).any()
    dataset = export_vgn.read_grasps(out / "dataset")
    np.testing.assert_allclose(dataset["i"].to_numpy(), df["x"].to_numpy() / (0.3 / 40), rtol=1e-12)


def test_contact_graspnet_export_reads_back(convex_scene_run, tmp_path):
    out = tmp_path / "cgn"
    run_annotator("export", convex_scene_run, "--format", "contact_graspnet", "--out", out)
    scenes = open_scene_labels(convex_scene_run, "test")
    infos = export_cgn.load_scene_contacts(out)
    assert len(infos) == 2
    for scene_id, info in enumerate(infos):
        record, rows = scenes.records[scene_id], scenes.rows(scene_id)
        held = rows[rows["success"]]
        assert len(info["grasp_transforms"]) == len(held) > 0
        labels = export_cgn.contact_labels(info)
        distance = np.sort(labels["finger_distance"][::2])
        # the contacts lie on the mesh where the closing line meets it, the width is the pads'
        # separation: the same but for the squeeze and a line off a round object's axis
        gap = np.abs(distance - np.sort(held["width"].to_numpy()))
        assert np.median(gap) < 1e-3 and gap.max() < 2 * export_cgn.CONTACT_RAY_MARGIN
        # the meshes as Contact-GraspNet's renderer poses them are where the scene has them
        meshes = export_cgn.scene_meshes(out, info)
        T_cgn_table = export_cgn.T_cgn_table(record)
        for mesh, inst in zip(meshes, record.kept, strict=True):
            original = scenes_mesh(scenes, inst.object_id)
            want = (T_cgn_table @ inst.T_table_obj.as_matrix())[:3, :3] @ original.vertices.T
            want = want.T + (T_cgn_table @ inst.T_table_obj.as_matrix())[:3, 3]
            np.testing.assert_allclose(mesh.vertices, want, atol=1e-8)
    assert sorted(p.name for p in (out / "views").iterdir()) == ["000000_00.npz", "000001_00.npz"]


def scenes_mesh(scenes, object_id):
    from annotator.tools.common import object_mesh

    return object_mesh(scenes.path, object_id)


def test_exports_refuse_the_other_kind_of_labels(convex_scene_run, tmp_path):
    result = run_annotator(
        "export", convex_scene_run, "--format", "acronym", "--out", tmp_path / "a", check=2
    )
    assert "holds scenes" in result.output and "Traceback" not in result.output
    objects_run = tmp_path / "objects_run"
    run_annotate(
        "--objects", REPO / "objects" / "urdf", "--n", 10, "--out", objects_run, "--quiet", "--workers", 1
    )
    result = run_annotator("export", objects_run, "--format", "vgn", "--out", tmp_path / "v", check=2)
    assert "holds no scenes" in result.output


def test_show_scene_draws_the_scene_and_its_grasps(convex_scene_run, tmp_path):
    from annotator.tools.scene_labels import open_scene_labels
    from annotator.tools.show_scene import choose_scene_grasps, render_scene

    png = tmp_path / "scene.png"
    result = run_annotator("show", convex_scene_run, "--scene", 1, "--png", png)
    assert png.stat().st_size > 10_000 and "scene 1" in result.output
    scenes = open_scene_labels(convex_scene_run, "test")
    record, rows = scenes.records[1], scenes.rows(1)
    chosen = choose_scene_grasps(rows, 40, 0, ("success",))
    meshes = {oid: scenes_mesh(scenes, oid) for oid in {i.object_id for i in record.kept}}
    picture = render_scene(record, meshes, chosen, {"success": len(chosen)}, "test")
    top = picture.instance_masks[1]
    assert set(top) == {i.instance_id for i in record.kept} and all(m.any() for m in top.values())
    # every success's TCP is seen on (or beside) its object from above
    order = {g: k for k, g in enumerate(picture.overview.grasp_ids)}
    uv = picture.overview.tcp_pixels[1]
    for row in chosen.itertuples():
        u, v = np.round(uv[order[row.grasp_id]]).astype(int)
        mask = top[row.instance_id]
        window = mask[max(0, v - 12) : v + 13, max(0, u - 12) : u + 13]
        assert window.any(), (row.grasp_id, u, v)
    bad = run_annotator("show", convex_scene_run, "--scene", 7, "--png", png, check=2)
    assert "no scene 7" in bad.output
    both = run_annotator("show", convex_scene_run, "--scene", 1, "--object", "box", "--png", png, check=2)
    assert "one of them" in both.output


def test_show_scene_draws_a_clutter_round_s_attempts_on_it(convex_objects, convex_scene_run, tmp_path):
    """Round 0 of clutter-removal (same objects, seed and objects per pile) is the run's scene 0:
    its attempts are drawn there, numbered, each TCP on or beside the object it went for."""
    from annotator.tools.show_scene import attempt_rows, render_scene

    config = AnnotatorConfig()
    job = ClutterSetup(tuple(discover_objects(convex_objects)), 3, 0, "labels", config)
    _, grasps = clutter_removal(job, 1).tables()
    csv = tmp_path / "grasps.csv"
    grasps.to_csv(csv, index=False)
    png = tmp_path / "round0.png"
    result = run_annotator("show", convex_scene_run, "--scene", 0, "--attempts", csv, "--png", png)
    assert png.stat().st_size > 10_000 and f"{len(grasps)} attempts" in result.output
    rows = attempt_rows(csv, 0)
    assert rows["grasp_id"].tolist() == list(range(len(grasps)))
    assert rows["text"].iloc[0].startswith(f"0: {grasps['target_object'].iloc[0]} ")
    scenes = open_scene_labels(convex_scene_run, "test")
    record = scenes.records[0]
    meshes = {oid: scenes_mesh(scenes, oid) for oid in {i.object_id for i in record.kept}}
    picture = render_scene(record, meshes, rows, {"success": len(rows)}, "test", numbered=True)
    top, uv = picture.instance_masks[1], picture.overview.tcp_pixels[1]
    order = {g: k for k, g in enumerate(picture.overview.grasp_ids)}
    first = int(grasps["target_instance"].iloc[0])  # the scene as first settled: attempt 0's target
    u, v = np.round(uv[order[0]]).astype(int)
    assert top[first][max(0, v - 12) : v + 13, max(0, u - 12) : u + 13].any()
    other = run_annotator("show", convex_scene_run, "--scene", 1, "--attempts", csv, "--png", png, check=2)
    assert "no attempt of round 1" in other.output
    not_attempts = tmp_path / "not_attempts.csv"
    pd.DataFrame({"x": [0.0]}).to_csv(not_attempts, index=False)
    wrong = run_annotator(
        "show", convex_scene_run, "--scene", 0, "--attempts", not_attempts, "--png", png, check=2
    )
    assert "not a clutter-removal grasps.csv" in wrong.output
    alone = run_annotator(
        "show", convex_scene_run, "--object", "box", "--attempts", csv, "--png", png, check=2
    )
    assert "give --scene ROUND" in alone.output


def test_wilson_interval():
    lo, hi = wilson(9, 10)
    assert lo == pytest.approx(0.596, abs=1e-3) and hi == pytest.approx(0.982, abs=1e-3)  # Wilson 1927
    assert wilson(0, 0) != wilson(0, 0)  # nan: no trials, no interval


@pytest.mark.slow
def test_clutter_removal_rounds_are_annotates_scenes_and_clear_with_labels(
    convex_objects, convex_scene_run, tmp_path
):
    """Round 0 is scene 0 of annotate --scenes (same seed and count); the labels policy clears
    a pile of boxes and cans; a learner's file of the scene's successes is executed best first."""
    config = AnnotatorConfig()
    sources = tuple(discover_objects(convex_objects))
    models = {s.object_id: load_object(s, config.objects) for s in sources}
    built = SceneBuilder(models).build(SceneSpec(0, 0, "pile", 3, 3))
    recorded = {r.scene_id: r for r in scenes_from_table(load_scenes(convex_scene_run))}[0]
    assert same_scene(built, recorded)

    summary = clutter_removal(ClutterSetup(sources, 3, 0, "labels", config), 1)
    (round_,) = summary.rounds
    assert round_.object_count == len(built.kept) and summary.attempts >= 1
    assert summary.successes >= round_.object_count - 1, [
        (a.proposal.instance_id, a.success) for a in round_.attempts
    ]
    again = clutter_removal(ClutterSetup(sources, 3, 0, "labels", config), 1)
    pd.testing.assert_frame_equal(again.tables()[1], summary.tables()[1], check_exact=True)

    scenes = open_scene_labels(convex_scene_run, "test")
    held = scenes.rows(0)
    held = held[held["success"]]
    cols = [f"table_tcp_{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
    predictions = held[cols].set_axis(["x", "y", "z", "qx", "qy", "qz", "qw"], axis=1)
    predictions.insert(0, "round", 0)
    predictions["width"] = held["cmd_width"].to_numpy()
    predictions["score"] = np.linspace(1.0, 0.5, len(held))
    path = tmp_path / "predictions.csv"
    predictions.to_csv(path, index=False)
    result = run_annotator(
        "clutter-removal",
        "--objects",
        convex_objects,
        "--rounds",
        1,
        "--per-scene",
        3,
        "--policy",
        path,
        "--workers",
        1,
        "--out",
        tmp_path / "cr",
    )
    assert "grasp success rate" in result.output and "percent cleared" in result.output
    grasps = pd.read_csv(tmp_path / "cr" / "grasps.csv")
    assert len(grasps) >= 1 and grasps["label"].sum() >= 1
    assert grasps["score"].iloc[0] == pytest.approx(1.0)  # the best first
    first = Transform(grasps.loc[0, ["x", "y", "z"]].to_numpy(float), grasps.loc[0, ["qx", "qy", "qz", "qw"]])
    np.testing.assert_allclose(
        first.pos, predictions.loc[predictions.index[0], ["x", "y", "z"]].to_numpy(float), atol=1e-12
    )
    read_predictions(path)  # the file's contract
    broken = tmp_path / "broken.csv"
    predictions.drop(columns=["score"]).to_csv(broken, index=False)
    result = run_annotator(
        "clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", broken, check=2
    )
    assert "score" in result.output and "Traceback" not in result.output


@pytest.mark.parametrize(
    "column, value, said",
    [
        ("x", "abc", "has x 'abc': not a valid number"),
        ("width", "nan", "has width 'nan': not a valid number"),
        ("qw", "0", "a zero quaternion is no rotation"),
    ],
)
def test_show_attempts_that_are_not_numbers_are_one_line(convex_scene_run, tmp_path, column, value, said):
    """x = 'abc', NaN or a zero quaternion in a grasps.csv were tracebacks."""
    attempt = {"round_id": 0, "attempt": 0, "x": 0.0, "y": 0.0, "z": 0.05, "qx": 1.0, "qy": 0.0, "qz": 0.0}
    attempt |= {"qw": 0.0, "width": 0.05, "label": 0, "failure": "no_contact"}
    if column == "qw":
        attempt["qx"] = 0.0
    attempt[column] = value
    csv = tmp_path / "grasps.csv"
    pd.DataFrame([attempt]).to_csv(csv, index=False)
    png = tmp_path / "round.png"
    result = run_annotator("show", convex_scene_run, "--scene", 0, "--attempts", csv, "--png", png, check=2)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and said in errors[0] and "Traceback" not in result.output
    assert not png.exists()
