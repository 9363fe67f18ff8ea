"""Scenes: specs, records round-trip, determinism, settled objects at rest and apart, removals."""

from __future__ import annotations

import dataclasses
import io
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
from scene_helpers import CONCAVE, CONVEX, REPO, load_models

from annotator.config import PhysicsConfig, SceneConfig
from annotator.dataset import keyed_rng
from annotator.geometry import Transform
from annotator.objects import get_object_pose
from annotator.scenes import (
    Instance,
    SceneBuilder,
    SceneRecord,
    SceneSpec,
    Workspace,
    draw_objects,
    same_scene,
    scene_table,
    scenes_from_table,
)
from annotator.scenes.records import KEPT, LEFT_WORKSPACE, NOT_AT_REST, NOT_PLACED
from annotator.scenes.world import load_scene
from annotator.sim import pb
from annotator.sim.world import World

PENETRATION = 0.0015  # m: resting contacts overlap by less (Bullet keeps ~1 mm in resting contact)
REST_DRIFT = 0.002  # m: how far any corner of an object may move in 0.5 s after the scene is loaded


@pytest.fixture(scope="module")
def convex():
    return load_models(CONVEX)


@pytest.fixture(scope="module")
def concave():
    return load_models(CONCAVE)


def test_spec_rejects_bad_requests():
    with pytest.raises(ValueError, match="arrangement"):
        SceneSpec(0, arrangement="heap")
    with pytest.raises(ValueError, match="object count"):
        SceneSpec(0, min_objects=4, max_objects=3)
    with pytest.raises(ValueError, match="object count"):
        SceneSpec(0, min_objects=0, max_objects=3)
    with pytest.raises(ValueError, match="scene_id"):
        SceneSpec(-1)


def test_draw_depends_on_the_keys_only():
    spec = SceneSpec(7, seed=3, min_objects=3, max_objects=8)
    pool = ["mug", "bowl", "ring", "banana"]
    a = draw_objects(spec, pool, keyed_rng("scene", 3, 7))
    b = draw_objects(spec, list(reversed(pool)), keyed_rng("scene", 3, 7))
    assert a == b and 3 <= len(a) <= 8 and set(a) <= set(pool)
    counts = {len(draw_objects(spec, pool, keyed_rng("scene", 3, s))) for s in range(40)}
    assert counts == set(range(3, 9)), counts  # the whole range is drawn
    with pytest.raises(ValueError, match="no objects"):
        draw_objects(spec, [], keyed_rng("scene", 0, 0))


def _synthetic_record() -> SceneRecord:
    rng = np.random.default_rng(1)
    instances = []
    for k, status in enumerate([KEPT, LEFT_WORKSPACE, KEPT, NOT_PLACED]):
        T = Transform(rng.normal(size=3), rng.normal(size=4)) if status == KEPT else None
        instances.append(Instance(k, f"obj/{k % 2}", status, T, 1.0 + k, 0.1 * (k + 1)))
    ws = Workspace(0.3, np.array([-0.15, 0.01]))
    return SceneRecord(4, 9, "table", tuple(instances), ws, Transform((0.5, 0.0, -0.025), (0, 0, 0, 1)))


def test_records_round_trip_through_parquet_bit_for_bit():
    record = _synthetic_record()
    other = dataclasses.replace(record, scene_id=2, arrangement="pile")
    buffer = io.BytesIO()
    scene_table([record, other]).to_parquet(buffer, index=False)
    back = scenes_from_table(pd.read_parquet(io.BytesIO(buffer.getvalue())))
    assert [r.scene_id for r in back] == [2, 4]
    assert same_scene(back[1], record) and same_scene(back[0], other)
    assert back[1].instance(1).status == LEFT_WORKSPACE and back[1].instance(1).T_table_obj is None
    kept = back[1].instance(2)
    assert kept.T_table_obj.pos.tolist() == record.instance(2).T_table_obj.pos.tolist()
    assert [i.instance_id for i in back[1].kept] == [0, 2]
    # the comparison bites: one ulp in one coordinate is another scene
    nudged = list(record.instances)
    T = nudged[2].T_table_obj
    pos = T.pos.copy()
    pos[1] = np.nextafter(pos[1], np.inf)
    nudged[2] = dataclasses.replace(nudged[2], T_table_obj=Transform.exact(pos, T.quat))
    assert not same_scene(record, dataclasses.replace(record, instances=tuple(nudged)))
    with pytest.raises(ValueError, match="missing columns"):
        scenes_from_table(scene_table([record]).drop(columns=["qw"]))


def test_workspace_box_is_vgns():
    ws = Workspace(0.3, np.array([-0.15, 0.0]))
    np.testing.assert_allclose(ws.lower, [-0.3, -0.15, -0.05])
    np.testing.assert_allclose(ws.upper, [0.0, 0.15, 0.25])
    assert ws.contains(np.array([[-0.15, 0.0, 0.01], [0.01, 0.0, 0.01], [-0.15, 0.0, -0.06]])).tolist() == [
        True,
        False,
        False,
    ]
    np.testing.assert_allclose(ws.T_table_task.pos, ws.lower)


def _check_settled(record: SceneRecord, models) -> None:
    """Every kept instance inside the workspace, touching the table or another instance, apart
    from the others (no interpenetration beyond resting contact), and still at rest when the
    recorded scene is loaded and simulated for 0.5 s."""
    assert record.kept, "an empty scene says nothing"
    with World(PhysicsConfig()) as world:
        scene = load_scene(world, record, models)
        client, table = world.client, scene.cell.table.uid
        uids = scene.uids
        for k, uid in uids.items():
            com = np.asarray(pb.getBasePositionAndOrientation(uid, physicsClientId=client)[0])
            assert record.workspace.contains(record.T_world_table.inverse().apply(com))[0], k
            others = [table, *(u for j, u in uids.items() if j != k)]
            gaps = [p[8] for o in others for p in pb.getClosestPoints(uid, o, 0.001, physicsClientId=client)]
            assert gaps, f"instance {k} touches nothing: floating"
            assert min(gaps) > -PENETRATION, f"instance {k} is {-min(gaps) * 1e3:.2f} mm inside a neighbour"
        corners = {
            k: np.array(np.meshgrid(*models[record.instance(k).object_id].mesh.bounds.T, indexing="ij"))
            .reshape(3, -1)
            .T
            for k in uids
        }
        before = {k: get_object_pose(client, u).apply(corners[k]) for k, u in uids.items()}
        world.step(round(0.5 / world.dt))
        for k, u in uids.items():
            drift = np.linalg.norm(get_object_pose(client, u).apply(corners[k]) - before[k], axis=1).max()
            assert drift < REST_DRIFT, f"instance {k} moved {drift * 1e3:.1f} mm"


@pytest.mark.parametrize("arrangement", ["pile", "packed", "table"])
def test_convex_scene_settles_at_rest_apart_and_inside(convex, arrangement):
    record = SceneBuilder(convex).build(
        SceneSpec(0, seed=0, arrangement=arrangement, min_objects=4, max_objects=4)
    )
    assert len(record.instances) == 4
    assert all(i.status in (KEPT, LEFT_WORKSPACE, NOT_PLACED) for i in record.instances)
    _check_settled(record, convex)


def test_packed_objects_stand_upright(convex):
    record = SceneBuilder(convex).build(SceneSpec(3, arrangement="packed", min_objects=3, max_objects=3))
    for inst in record.kept:
        up = inst.T_table_obj.rotation[:, 2]  # the mesh's +z in the table frame
        assert up[2] > 0.99, (inst.object_id, up)  # box, can and plate all stand on their +z base


def test_objects_that_leave_a_small_workspace_are_removed(convex):
    """VGN's rule, on a scene set up to test it: a body at rest whose centre of mass lies outside
    the workspace is removed and recorded as having left it; one at rest inside stays."""
    from annotator.cell.world import build_cell
    from annotator.config import CellConfig
    from annotator.scenes.arrange import _Build, remove_outside_and_settle, workspace_on

    scenes = SceneConfig(workspace_size=0.12)
    box = convex["box"]
    lowest = float(box.mesh.vertices[:, 2].min())
    with World(PhysicsConfig()) as world:
        cell = build_cell(world, CellConfig(), robot=False, kinect=False)
        build = _Build(world, cell, workspace_on(cell, scenes), scenes, keyed_rng("test", 0))
        centre = build.workspace.center
        for k, dx in enumerate((0.0, 0.06 + 0.10)):  # in the middle; 10 cm beyond the workspace's edge
            p_table = np.array([centre[0] + dx, centre[1], 0.0005 - lowest])
            T = Transform(build.table_to_world(p_table), build.T_world_table.quat)
            build.add(k, "box", box, T)
        remove_outside_and_settle(build)
        assert [b.instance_id for b in build.bodies] == [0]
        assert build.status == {1: LEFT_WORKSPACE}


def test_a_pile_too_big_for_its_workspace_keeps_only_what_is_inside(convex):
    """Six objects cannot all stay in a 12 cm workspace (the plate alone is wider): some leave it,
    each instance says what became of it, and every one kept rests inside. How many stay is a
    chaotic outcome of the pile (it differs between CPUs whose maths libraries differ in the last
    bit: docs/reliability.md), so it is not asserted."""
    small = SceneConfig(workspace_size=0.12, pile_box_margin=0.0)
    record = SceneBuilder(convex, scenes=small).build(
        SceneSpec(1, arrangement="pile", min_objects=6, max_objects=6)
    )
    statuses = [i.status for i in record.instances]
    assert statuses.count(LEFT_WORKSPACE) >= 1, statuses
    assert set(statuses) <= {KEPT, LEFT_WORKSPACE, NOT_AT_REST}, statuses
    kept = {i.instance_id for i in record.instances if i.status == KEPT}
    assert {i.instance_id for i in record.kept} == kept
    if record.kept:
        _check_settled(record, convex)


@pytest.mark.slow
@pytest.mark.parametrize("arrangement", ["pile", "packed", "table"])
def test_concave_scene_settles_at_rest_apart_and_inside(concave, arrangement):
    record = SceneBuilder(concave).build(
        SceneSpec(2, seed=1, arrangement=arrangement, min_objects=5, max_objects=5)
    )
    _check_settled(record, concave)


BUILD_IN_A_FRESH_PROCESS = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    from scene_helpers import CONCAVE, load_models
    from annotator.scenes import SceneBuilder, SceneSpec, scene_table
    spec = SceneSpec(3, seed=5, arrangement="pile", min_objects=5, max_objects=5)
    record = SceneBuilder(load_models(CONCAVE)).build(spec)
    scene_table([record]).to_parquet(sys.argv[1], index=False)
    """
)


@pytest.mark.slow
def test_a_pile_of_concave_objects_is_bit_identical_on_any_worker(concave, tmp_path):
    """The same scene id gives the same pile bit for bit: built first, built after other scenes
    in the same process, and built in a fresh interpreter (another worker)."""
    spec = SceneSpec(3, seed=5, arrangement="pile", min_objects=5, max_objects=5)
    first = SceneBuilder(concave).build(spec)
    assert len(first.kept) >= 3 and {i.object_id for i in first.instances} <= {
        "mug",
        "bowl",
        "banana",
        "ring",
    }
    busy = SceneBuilder(concave)
    for other in (SceneSpec(9, seed=5, arrangement="pile", max_objects=6), SceneSpec(1, arrangement="table")):
        busy.build(other)
    again = busy.build(spec)
    assert same_scene(first, again)
    out = tmp_path / "scene.parquet"
    code = BUILD_IN_A_FRESH_PROCESS.format(tests=str(REPO / "tests"))
    subprocess.run([sys.executable, "-c", code, str(out)], check=True, cwd=REPO, timeout=600)
    (elsewhere,) = scenes_from_table(pd.read_parquet(out))
    assert same_scene(first, elsewhere)
    # another seed is another pile
    assert not same_scene(first, SceneBuilder(concave).build(dataclasses.replace(spec, seed=6)))
