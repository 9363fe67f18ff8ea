"""A closed convex mesh is its own hull (annotator/objects/own_hull.py): it collides as that hull
with no error, with no error sampling, no child process and no cache entry; any other mesh goes the
measured way. Real meshes, real hulls; the slow path is the one a cache entry holds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import write_l

from annotator.config import ObjectConfig
from annotator.objects import discover_objects, load_object, read_object_mesh
from annotator.objects.collision_entry import entry_arrays, entry_geometry
from annotator.objects.fidelity import collision_error
from annotator.objects.own_hull import NO_ERROR, is_own_hull, own_hull_geometry
from bench.object_cost import primitive, write_convex_primitives

CONFIG = ObjectConfig()


def primitives() -> list[trimesh.Trimesh]:
    rng = np.random.default_rng(7)
    return [primitive(kind, sides, rng) for kind, sides in ((0, 12), (1, 24), (2, 12))]


def test_a_closed_convex_primitive_is_its_own_hull_and_its_geometry_is_the_measured_ones_but_the_error():
    """Boxes, cylinders and capsules: the own-hull geometry's part is bit for bit the part the
    measured way stores in its cache entry, and the error that way measures is rounding."""
    for mesh in primitives():
        assert is_own_hull(mesh, mesh.convex_hull)
        fast = own_hull_geometry(mesh)
        assert fast is not None and fast.method == "hull" and fast.error == NO_ERROR and fast.file is None
        hull = mesh.convex_hull
        measured = collision_error(mesh, [hull], CONFIG.decomposition.collision_error_samples)
        assert measured.max < 1e-12  # the sampled figure of an exact hull: rounding only
        entry = entry_geometry(entry_arrays([hull], measured, "hull", 0.0, 0.0), Path("."))
        assert len(fast.parts) == len(entry.parts) == 1
        assert fast.parts[0].vertices.tobytes() == entry.parts[0].vertices.tobytes()
        assert fast.parts[0].faces.tobytes() == entry.parts[0].faces.tobytes()


def concave_or_open() -> dict[str, trimesh.Trimesh]:
    box = trimesh.creation.box(extents=(0.04, 0.03, 0.02))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)  # one triangle missing
    dented = box.copy()
    dented.vertices[0] *= 0.5  # one corner pushed in: no longer convex
    capsule = trimesh.creation.capsule(height=0.05, radius=0.015, count=[16, 16])
    rounded = trimesh.Trimesh(np.round(capsule.vertices, 6), capsule.faces, process=False)  # off by ~1e-7 m
    twice = trimesh.util.concatenate([box, box.copy()])  # the surface covered twice
    return {
        "ring": trimesh.creation.torus(0.03, 0.01, 24, 12),
        "open box": open_box,
        "dented box": dented,
        "capsule rounded to a micrometre": rounded,
        "a box twice": twice,
    }


@pytest.mark.parametrize("name", list(concave_or_open()))
def test_a_concave_open_or_rounded_mesh_is_never_its_own_hull(name):
    mesh = concave_or_open()[name]
    assert not is_own_hull(mesh, mesh.convex_hull), name
    assert own_hull_geometry(mesh) is None, name


def test_a_concave_object_never_takes_the_own_hull_way(tmp_path):
    """The L block is decomposed (or hulled by the ladder), never given the no-error hull."""
    mesh = read_object_mesh(write_l(tmp_path / "l.obj"))
    assert not is_own_hull(mesh, mesh.convex_hull)


def test_cold_and_warm_loads_of_convex_primitives_give_identical_models_and_leave_the_cache_empty(tmp_path):
    """Written as files and loaded as a run's worker loads them: the decision is the same every
    time, the shape and error identical with an empty and a used cache, and nothing is cached."""
    write_convex_primitives(tmp_path / "objs", 6)
    cache = tmp_path / "cache"
    sources = discover_objects(tmp_path / "objs", CONFIG)
    loads = [[load_object(s, CONFIG, cache_dir=cache) for s in sources] for _ in range(2)]
    for cold, warm in zip(*loads, strict=True):
        assert cold.collision_method == warm.collision_method == "hull" and cold.convex
        assert cold.collision_error == warm.collision_error == NO_ERROR and not cold.approximate
        assert [p.vertices.tobytes() for p in cold.parts] == [p.vertices.tobytes() for p in warm.parts]
        assert cold.mass == warm.mass and cold.collision_file is None
    assert not list(cache.glob("**/*.npz")), "a mesh that is its own hull needs no cache entry"
