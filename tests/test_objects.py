"""Object discovery, validation, mass, decomposition cache and PyBullet bodies, on real files and physics."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pybullet
import pytest
import trimesh

from annotator.config import ObjectConfig
from annotator.geometry import Transform
from annotator.objects import (
    ObjectDiscoveryError,
    ObjectError,
    create_body,
    discover_objects,
    get_object_pose,
    load_object,
    reset_object_pose,
)

REPO_OBJECTS = Path(__file__).resolve().parents[1] / "objects"
CONFIG = ObjectConfig()


@pytest.fixture
def client():
    cid = pybullet.connect(pybullet.DIRECT)
    pybullet.setGravity(0, 0, -9.81, physicsClientId=cid)
    yield cid
    pybullet.disconnect(cid)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("decomposition-cache")


@pytest.fixture(scope="module")
def mug_models(cache_dir):
    """The sample mug loaded twice with one cache: (first, second)."""
    first = load_object(REPO_OBJECTS / "mug.obj", CONFIG, cache_dir=cache_dir)
    second = load_object(REPO_OBJECTS / "mug.obj", CONFIG, cache_dir=cache_dir)
    return first, second


def _write_cube(path: Path, size: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(size, size, size)).export(path)
    return path


# ---------------------------------------------------------------------------------------------- discovery


def test_discovery_recursive_ids_and_urdf_meshes_excluded(tmp_path):
    _write_cube(tmp_path / "a" / "b" / "cube.obj", 0.04)
    _write_cube(tmp_path / "top.stl", 0.04)
    _write_cube(tmp_path / "thing" / "thing_visual.obj", 0.04)
    _write_cube(tmp_path / "thing" / "thing_collision.obj", 0.04)
    (tmp_path / "thing" / "thing.urdf").write_text(
        '<robot name="thing"><link name="base">'
        '<visual><geometry><mesh filename="thing_visual.obj" scale="1 1 1"/></geometry></visual>'
        '<collision><geometry><mesh filename="thing_collision.obj" scale="1 1 1"/></geometry></collision>'
        "</link></robot>"
    )
    (tmp_path / "notes.txt").write_text("not an object")

    sources = discover_objects(tmp_path)

    assert [s.object_id for s in sources] == ["a/b/cube", "thing/thing", "top"]
    assert sources[1].is_urdf
    assert discover_objects(tmp_path) == sources  # deterministic


def test_discovery_missing_and_empty_folders_raise(tmp_path):
    with pytest.raises(ObjectDiscoveryError, match="not found"):
        discover_objects(tmp_path / "nope")
    (tmp_path / "readme.md").write_text("# nothing here")
    with pytest.raises(ObjectDiscoveryError, match="no objects"):
        discover_objects(tmp_path)


def test_sample_objects_folder():
    ids = [s.object_id for s in discover_objects(REPO_OBJECTS)]
    assert ids == [
        "banana",
        "big_ball",
        "bottle",
        "bowl",
        "box",
        "can",
        "mug",
        "plate",
        "ring",
        "urdf/shampoo/shampoo",
    ]
    suffixes = {s.path.suffix for s in discover_objects(REPO_OBJECTS)}
    assert {".obj", ".stl", ".ply", ".urdf"} <= suffixes


# ---------------------------------------------------------------------------------------------- bad input


def _obj_text(vertices, faces) -> str:
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def _bad_inputs(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    cube = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    cases = {}
    p = tmp_path / "empty.obj"
    p.write_bytes(b"")
    cases["empty"] = (p, "empty file")
    p = tmp_path / "text.obj"
    p.write_text("This is a shopping list, not a mesh.\nmilk\neggs\n")
    cases["text"] = (p, "not a")
    v = cube.vertices.copy()
    v[3, 1] = np.nan
    p = tmp_path / "nan.obj"
    p.write_text(_obj_text(v, cube.faces))
    cases["nan"] = (p, "NaN")
    p = tmp_path / "mm.obj"
    p.write_text(_obj_text(trimesh.creation.box(extents=(60.0, 40.0, 120.0)).vertices, cube.faces))
    cases["millimetres"] = (p, r"looks like millimetres \(extent 120 m\); pass --scale 0.001")
    grid = np.array([[x, y, 0.0] for x in (0, 0.03, 0.06) for y in (0, 0.03, 0.06)])
    flat_faces = [(i, i + 3, i + 1) for i in (0, 1, 3, 4)] + [(i + 1, i + 3, i + 4) for i in (0, 1, 3, 4)]
    p = tmp_path / "flat.obj"
    p.write_text(_obj_text(grid, flat_faces))
    cases["zero-volume"] = (p, "zero volume")
    p = tmp_path / "tiny.obj"
    p.write_text(_obj_text(cube.vertices * 0.05, cube.faces))
    cases["too-small"] = (p, "too small")
    return cases


@pytest.mark.parametrize("case", ["empty", "text", "nan", "millimetres", "zero-volume", "too-small"])
def test_bad_input_gives_object_error(tmp_path, case):
    path, message = _bad_inputs(tmp_path)[case]
    with pytest.raises(ObjectError, match=message) as info:
        load_object(path, CONFIG, cache_dir=tmp_path / "cache")
    assert "\n" not in str(info.value)


def test_millimetre_mesh_loads_with_explicit_scale(tmp_path):
    path = tmp_path / "box_mm.stl"
    trimesh.creation.box(extents=(60.0, 40.0, 120.0)).export(path)
    model = load_object(path, CONFIG, scale=0.001, cache_dir=tmp_path)
    np.testing.assert_allclose(model.mesh.extents, [0.06, 0.04, 0.12], atol=1e-9)
    assert model.scale == 0.001
    assert model.mass == pytest.approx(0.06 * 0.04 * 0.12 * CONFIG.density)


# ---------------------------------------------------------------------------------------------- mass


def test_mass_and_inertia_of_a_40mm_cube(tmp_path):
    path = _write_cube(tmp_path / "cube.obj", 0.04)
    model = load_object(path, CONFIG, cache_dir=tmp_path)
    mass = 0.04**3 * CONFIG.density
    assert model.mass == pytest.approx(mass, rel=1e-9)
    assert model.watertight and model.convex and len(model.parts) == 1
    assert model.collision_file is None  # convex: no decomposition
    np.testing.assert_allclose(model.inertia, np.eye(3) * mass * 2 * 0.04**2 / 12, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(model.center_mass, 0.0, atol=1e-12)
    assert len(model.mesh_sha256) == 64


def test_open_mesh_hole_is_closed(tmp_path, caplog):
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    top = box.face_normals[:, 2] > 0.5
    path = tmp_path / "open_box.obj"
    trimesh.Trimesh(box.vertices, box.faces[~top]).export(path)
    with caplog.at_level(logging.WARNING, logger="annotator.objects"):
        model = load_object(path, CONFIG, cache_dir=tmp_path)
    assert model.watertight and model.convex
    assert model.mass == pytest.approx(0.05**3 * CONFIG.density, rel=1e-9)
    assert "closed 1 hole" in caplog.text


def test_unrepairable_open_mesh_uses_hull_with_warning(tmp_path, caplog):
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    # a fin from one edge to the centre: that edge has three faces, no hole filling can fix it
    verts = np.vstack([box.vertices, [[0.0, 0.0, 0.0]]])
    faces = np.vstack([box.faces, [box.faces[0][:2].tolist() + [8]]])
    path = tmp_path / "finned_box.obj"
    path.write_text(_obj_text(verts, faces))
    with caplog.at_level(logging.WARNING, logger="annotator.objects"):
        model = load_object(path, CONFIG, cache_dir=tmp_path)
    assert not model.watertight
    assert model.mass == pytest.approx(0.05**3 * CONFIG.density, rel=1e-9)  # the hull is the cube
    assert len(model.parts) == 1 and model.collision_file is None
    assert "not watertight" in caplog.text


def test_urdf_mesh_scale_is_applied():
    source = next(s for s in discover_objects(REPO_OBJECTS) if s.is_urdf)
    model = load_object(source, CONFIG)
    np.testing.assert_allclose(model.mesh.extents, [0.06, 0.036, 0.18], atol=1e-3)  # cm x 0.01
    assert model.object_id == "urdf/shampoo/shampoo"


def test_big_ball_is_wider_than_the_rg2_stroke():
    model = load_object(REPO_OBJECTS / "big_ball.obj", CONFIG)
    # min over directions of the width of the object (the distance between two supporting planes)
    directions = trimesh.sample.sample_surface_sphere(500, seed=0)
    proj = model.mesh.vertices @ directions.T
    assert (proj.max(axis=0) - proj.min(axis=0)).min() > 0.110


# ---------------------------------------------------------------------------------------------- decomposition


def test_mug_is_decomposed_and_cached(mug_models, cache_dir):
    first, second = mug_models
    assert not first.convex
    assert len(first.parts) > 1
    assert first.collision_file is not None and first.collision_file.is_file()
    assert first.collision_file.parent == cache_dir
    assert first.mesh_sha256 in first.collision_file.name
    assert not first.from_cache and first.decomposition_seconds > 0
    assert second.from_cache and second.decomposition_seconds == 0.0
    assert second.collision_file == first.collision_file
    assert len(second.parts) == len(first.parts)
    assert sum(p.volume for p in first.parts) < 0.5 * first.mesh.convex_hull.volume  # cavity kept open
    assert list(cache_dir.glob("*.tmp")) == []


def test_cache_dir_defaults_to_env_var(tmp_path, monkeypatch):
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "envcache"))
    model = load_object(REPO_OBJECTS / "banana.obj", CONFIG)
    assert model.collision_file is not None
    assert model.collision_file.parent == tmp_path / "envcache"


# ---------------------------------------------------------------------------------------------- bodies


def test_body_link_frame_is_the_mesh_frame(client, tmp_path):
    mesh = trimesh.creation.box(extents=(0.06, 0.04, 0.12))
    mesh.apply_translation((0.01, 0.0, 0.06))  # centre of mass away from the mesh origin
    path = tmp_path / "offset_box.obj"
    mesh.export(path)
    model = load_object(path, CONFIG, cache_dir=tmp_path)
    T_world_obj = Transform(np.array([0.2, -0.1, 0.3]), np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)]))
    body = create_body(client, model, T_world_obj)

    info = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)
    assert info[0] == pytest.approx(model.mass)
    np.testing.assert_allclose(info[3], model.center_mass, atol=1e-9)
    assert info[1] == pytest.approx(CONFIG.lateral_friction)
    # PyBullet's base pose is the centre of mass; the helpers give the mesh frame.
    com_world = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)[0]
    np.testing.assert_allclose(com_world, T_world_obj.apply(model.center_mass), atol=1e-9)
    T = get_object_pose(client, body)
    np.testing.assert_allclose(T.pos, T_world_obj.pos, atol=1e-9)
    assert abs(np.dot(T.quat, T_world_obj.quat)) == pytest.approx(1.0, abs=1e-9)
    reset_object_pose(client, body, Transform.identity())
    np.testing.assert_allclose(get_object_pose(client, body).pos, 0.0, atol=1e-9)


def test_bodies_dropped_on_a_plane_come_to_rest(client, mug_models, tmp_path):
    plane = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client)
    pybullet.createMultiBody(0, plane, physicsClientId=client)
    mug = mug_models[1]
    box = load_object(REPO_OBJECTS / "box.obj", CONFIG, cache_dir=tmp_path)
    bodies = {
        "mug": create_body(client, mug, Transform(np.array([0.0, 0.0, 0.02]), np.array([0, 0, 0, 1.0]))),
        "box": create_body(client, box, Transform(np.array([0.3, 0.0, 0.02]), np.array([0, 0, 0, 1.0]))),
    }
    # a 20 mm ball dropped into the mug must land inside it: the decomposition keeps the cavity
    ball_shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.01, physicsClientId=client)
    ball = pybullet.createMultiBody(0.01, ball_shape, basePosition=[0, 0, 0.15], physicsClientId=client)
    for _ in range(720):  # 3 s at 1/240 s
        pybullet.stepSimulation(physicsClientId=client)

    for name, body in bodies.items():
        T = get_object_pose(client, body)
        lin, ang = pybullet.getBaseVelocity(body, physicsClientId=client)
        assert np.all(np.isfinite(T.pos)), name
        assert np.linalg.norm(lin) < 1e-2 and np.linalg.norm(ang) < 1e-1, name
        assert T.pos[2] == pytest.approx(0.0, abs=3e-3), name  # resting on its base
        assert T.rotation[2, 2] > 0.999, name  # upright
    ball_z = pybullet.getBasePositionAndOrientation(ball, physicsClientId=client)[0][2]
    assert 0.006 < ball_z < 0.03  # on the mug's 6 mm base, well below its 95 mm rim
