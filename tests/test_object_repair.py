"""Meshes as scans come: loose fragments, holes, non-manifold edges; the memory budget and the
bounded-memory collision error; on real files, loaded by load_object."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from annotator.config import ObjectConfig
from annotator.objects import ObjectError, ObjectSource, fidelity, load_object, memory, reading, repair

CONFIG = ObjectConfig()


def _obj_text(vertices, faces) -> str:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces).tolist()]
    return "\n".join(lines) + "\n"


def _l_block() -> trimesh.Trimesh:
    """A concave L-shaped block, 60 x 20 x 50 mm."""
    outline = np.array([(-0.03, 0), (0.03, 0), (0.03, 0.02), (-0.01, 0.02), (-0.01, 0.05), (-0.03, 0.05)])
    fan = np.array([(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)])
    return trimesh.creation.extrude_triangulation(outline, fan, 0.02)


def _with(mesh: trimesh.Trimesh, *pieces: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.util.concatenate([mesh, *pieces])


def _stray_triangle(at) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(at) + [[0, 0, 0], [0.002, 0, 0], [0, 0.002, 0]], [[0, 1, 2]])


# ---------------------------------------------------------------------------------------------- fragments


def test_loose_scan_fragments_are_dropped_and_reported_then_the_object_is_judged(tmp_path):
    """A box scanned with two stray triangles, a small open patch and a floating crumb: before,
    "not watertight", collided as its hull and weighed as a sheet; now the fragments go (reported)
    and the box is a closed solid."""
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    patch = trimesh.creation.box(extents=(0.004, 0.004, 0.004))
    patch = trimesh.Trimesh(patch.vertices + [0.0, 0.0, 0.04], patch.faces[:6])  # half a cube: open
    crumb = trimesh.creation.icosphere(subdivisions=1, radius=0.001)
    crumb.apply_translation((0.0, 0.06, 0.0))  # closed, tiny, apart from the box
    mesh = _with(box, _stray_triangle((0.05, 0, 0)), _stray_triangle((0, 0, -0.05)), patch, crumb)
    path = tmp_path / "scan.obj"
    path.write_text(_obj_text(mesh.vertices, mesh.faces))
    model = load_object(path, CONFIG, cache_dir=tmp_path / "c")
    assert model.cleaning.fragments_dropped == 4
    assert 0 < model.cleaning.fragment_area_share < 0.01
    assert "4 loose fragments dropped" in model.geometry_record()["cleaning"]
    assert model.watertight and model.convex and model.mass_model == "solid"
    assert model.mass == pytest.approx(0.05**3 * CONFIG.density, rel=1e-9)
    assert len(model.mesh.faces) == 12 and model.collision_error.max < 1e-9


def test_closed_parts_that_touch_are_not_fragments_however_small():
    """A small closed knob touching a body (or a V-HACD file's small convex part) is part of it."""
    body = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    knob = trimesh.creation.box(extents=(0.004, 0.004, 0.004))
    knob.apply_translation((0.0, 0.0, 0.026))  # overlaps the top face
    mesh = _with(body, knob)
    out, dropped = repair.drop_fragments(mesh, CONFIG.fragment_max_share)
    assert dropped == repair.Dropped() and out is mesh


def test_a_mesh_of_many_small_open_pieces_is_not_taken_for_fragments():
    """A triangle soup (every face its own piece) holds more than the share in small pieces: kept."""
    soup = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    soup = trimesh.Trimesh(soup.triangles.reshape(-1, 3), np.arange(3 * len(soup.faces)).reshape(-1, 3))
    out, dropped = repair.drop_fragments(soup, CONFIG.fragment_max_share)
    assert dropped.pieces == 0 and len(out.faces) == len(soup.faces)


def test_pieces_are_measured_right():
    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    far = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    far.apply_translation((0.1, 0.0, 0.0))
    p = repair.pieces(_with(box, far, _stray_triangle((0.0, 0.1, 0.0))))
    assert len(p.area) == 3
    order = np.argsort(-p.area)
    np.testing.assert_allclose(p.area[order], [6 * 0.02**2, 6 * 0.01**2, 0.002**2 / 2])
    np.testing.assert_allclose(p.volume[order][:2], [0.02**3, 0.01**3])
    assert p.closed[order].tolist() == [True, True, False]
    np.testing.assert_allclose(p.lo[order][1], [0.095, -0.005, -0.005])


# ---------------------------------------------------------------------------------------------- repair


def test_an_open_non_manifold_scan_of_a_concave_object_is_repaired_and_decomposed_not_hulled(tmp_path):
    """A concave block scanned with a hole, a stray fin on one edge (three faces on it: hole filling
    cannot close it) and a loose fragment: MeshFix repairs it, it is decomposed, not hulled."""
    block = _l_block()
    fin = np.vstack([block.vertices, [[0.0, 0.01, 0.05]]])
    faces = np.vstack([block.faces[1:], [block.faces[5][:2].tolist() + [len(block.vertices)]]])  # hole + fin
    mesh = _with(trimesh.Trimesh(fin, faces, process=False), _stray_triangle((0.1, 0.1, 0.1)))
    path = tmp_path / "scan.obj"
    path.write_text(_obj_text(mesh.vertices, mesh.faces))
    model = load_object(path, CONFIG, cache_dir=tmp_path / "c")
    assert model.cleaning.fragments_dropped == 1 and model.cleaning.mended
    assert model.watertight and not model.convex
    assert model.volume == pytest.approx(block.volume, rel=0.02)
    assert model.collision_method == "coacd" and len(model.parts) >= 2
    assert not model.approximate
    assert any("repaired by MeshFix" in w for w in model.warnings)


def test_a_repair_that_would_lose_half_the_object_is_refused():
    """MeshFix's clean on a box with a fin makes a wedge (half the box): the area check refuses it
    and the repair without the fin is taken."""
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    verts = np.vstack([box.vertices, [[0.0, 0.0, 0.0]]])
    faces = np.vstack([box.faces, [box.faces[0][:2].tolist() + [8]]])
    mended = repair.mend(
        trimesh.Trimesh(verts, faces, process=False), CONFIG.min_volume, CONFIG.mend_area_tolerance
    )
    assert mended is not None and mended.volume == pytest.approx(0.05**3, rel=1e-6)


# ---------------------------------------------------------------------------------------------- memory


def test_the_collision_error_in_blocks_gives_the_figures_of_the_whole_matrix_bit_for_bit(monkeypatch):
    """A hull of 19,800 faces against 10,000 points was one 1.6 GB matrix: now blocks of ~16 MB,
    with the same figures (every block has two rows or more, so the same matrix kernel)."""
    sphere = trimesh.creation.uv_sphere(radius=0.04, count=[40, 40])
    mesh = _l_block()
    parts = [mesh.convex_hull, sphere.convex_hull]
    monkeypatch.setattr(fidelity, "DEPTH_BLOCK", 2**62)
    whole = fidelity.collision_error(mesh, parts, 2001)
    for block in (7, 4097):
        monkeypatch.setattr(fidelity, "DEPTH_BLOCK", block)
        assert fidelity.collision_error(mesh, parts, 2001) == whole, block
    planes = fidelity._planes(sphere.convex_hull)
    points = np.random.default_rng(0).normal(scale=0.03, size=(1001, 3))
    monkeypatch.setattr(fidelity, "DEPTH_BLOCK", 2**62)
    whole_depth = fidelity._depth(points, planes)
    monkeypatch.setattr(fidelity, "DEPTH_BLOCK", 3)
    assert np.array_equal(fidelity._depth(points, planes), whole_depth)


def _write_glb(path: Path, mesh: trimesh.Trimesh) -> None:
    path.write_bytes(trimesh.Scene(mesh).export(file_type="glb"))


def test_face_counts_come_from_headers_or_a_count_of_face_lines(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)  # 1,280 faces
    n = len(sphere.faces)
    sphere.export(tmp_path / "a.stl")
    (tmp_path / "b.stl").write_text(trimesh.exchange.stl.export_stl_ascii(sphere))
    (tmp_path / "c.obj").write_text(_obj_text(sphere.vertices, sphere.faces))
    sphere.export(tmp_path / "d.ply")
    sphere.export(tmp_path / "e.off")
    _write_glb(tmp_path / "f.glb", sphere)
    for name in ("a.stl", "b.stl", "c.obj", "d.ply", "e.off", "f.glb"):
        assert memory.count_faces(tmp_path / name) == n, name
    (tmp_path / "broken.stl").write_bytes(b"solid nothing here")
    assert memory.count_faces(tmp_path / "broken.stl") == 0


def test_an_object_beyond_the_memory_budget_fails_before_it_is_read_with_its_estimate(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.04)  # 5,120 faces
    path = tmp_path / "ball.stl"
    sphere.export(path)
    need = memory.estimate_mb(len(sphere.faces))
    tight = dataclasses.replace(CONFIG, memory_budget=need - 1.0)
    with pytest.raises(
        ObjectError, match=r"^ball: needs about \d+ MB to load \(5,120 faces\), above the memory "
    ):
        load_object(path, tight, cache_dir=tmp_path / "c")
    assert load_object(path, dataclasses.replace(CONFIG, memory_budget=need + 1.0), cache_dir=tmp_path / "c")
    # a URDF counts the faces of every mesh it references
    (tmp_path / "ball.urdf").write_text(
        '<robot name="b"><link name="base"><collision><geometry><mesh filename="ball.stl"/></geometry>'
        '</collision><visual><geometry><mesh filename="ball.stl"/></geometry></visual></link></robot>'
    )
    with pytest.raises(ObjectError, match="ObjectConfig.memory_budget"):
        load_object(ObjectSource("ball_urdf", tmp_path / "ball.urdf"), tight, cache_dir=tmp_path / "c")


# ---------------------------------------------------------------------------------------------- terminal


def _owner(array) -> object:
    base = array
    while getattr(base, "base", None) is not None:
        base = base.base
    return base


def test_a_union_of_shells_owns_its_arrays_so_no_manifold3d_object_outlives_it():
    """A view into manifold3d's output kept its Mesh64 alive for as long as the object (a worker's
    kept models at exit: "nanobind: leaked N instances!")."""
    a = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    b = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    b.apply_translation((0.02, 0.0, 0.0))
    joined = reading.join([a, b], "two")
    assert joined.is_watertight and joined.volume == pytest.approx(0.06 * 0.04 * 0.04)
    for array in (joined.vertices, joined.faces):
        owner = _owner(np.asarray(array))
        assert isinstance(owner, np.ndarray) and owner.flags.owndata, type(owner)


def test_memory_and_face_count_helpers_read_only_headers_of_large_binary_files(tmp_path):
    """A binary STL that says 2,000,000 triangles and is that long is counted from its header."""
    path = tmp_path / "big.stl"
    n = 2_000_000
    with path.open("wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", n))
        fh.truncate(84 + 50 * n)  # sparse: no data written
    assert memory.count_faces(path) == n
    assert memory.estimate_mb(n) > memory.estimate_mb(200_000) > memory.estimate_mb(20_000)


def test_seam_copies_a_rounding_step_apart_are_welded_and_a_real_gap_is_not() -> None:
    """A box whose top face was written with its own copies of the four top corners, 0.2 nm from
    the others but on the other side of trimesh's 1e-8 m rounding step (as robosuite's can.stl
    writes its lid): cleaning joins them, and the box is closed. Copies 0.1 mm apart are a gap,
    not a seam, and stay apart."""
    h = 0.0200000049  # x 1e8 rounds down; h + 2e-10 rounds up
    box = trimesh.creation.box(extents=[2 * h, 2 * h, 2 * h])
    box.vertices = np.sign(box.vertices) * h
    for shift, welded in ((2e-10, True), (1e-4, False)):
        top = np.flatnonzero(np.all(box.vertices[box.faces][:, :, 2] > 0, axis=1))
        upper = np.flatnonzero(box.vertices[:, 2] > 0)
        vertices = np.vstack([box.vertices, box.vertices[upper] + shift])
        copy_of = {int(v): len(box.vertices) + k for k, v in enumerate(upper)}
        faces = box.faces.copy()
        faces[top] = np.vectorize(copy_of.get)(faces[top])
        split = trimesh.Trimesh(vertices, faces, process=False)
        assert not split.is_watertight
        report = reading.Cleaning()
        cleaned = reading.clean(split, "box", report)
        assert cleaned.is_watertight == welded
        assert report.vertices_merged == (4 if welded else 0)
        if welded:
            assert np.isclose(cleaned.volume, (2 * h) ** 3)
