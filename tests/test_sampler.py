"""Antipodal sampler: determinism, shapes, frames, and geometry on boxes with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from annotator.config import SamplerConfig
from annotator.geometry import Transform
from annotator.rng import object_rng
from annotator.sampler import Candidates, _first_hits, _pair_hits, sample_candidates

RG2_MAX_WIDTH = 0.110  # m, RG2 stroke
CONFIG = SamplerConfig()


def _box(size: float) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(size, size, size))


def _sample(
    mesh: trimesh.Trimesh, n: int, object_id: str = "box", max_width: float = RG2_MAX_WIDTH
) -> Candidates:
    return sample_candidates(mesh, n, object_rng(0, object_id), CONFIG, max_width)


def test_object_rng_is_stable_and_keyed() -> None:
    a = object_rng(0, "ycb/mug").random(5)
    b = object_rng(0, "ycb/mug").random(5)
    c = object_rng(0, "ycb/bowl").random(5)
    d = object_rng(1, "ycb/mug").random(5)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert not np.allclose(a, d)
    # Pinned raw PCG64 output: a change in the key hashing would silently change every dataset.
    raw = object_rng(0, "cube").bit_generator.random_raw(2)
    assert raw.tolist() == [10513003499897655280, 8458310525757665165]


def test_same_rng_same_candidates_and_object_id_changes_them() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    a = _sample(mesh, 100, object_id="sphere")
    b = _sample(mesh, 100, object_id="sphere")
    c = _sample(mesh, 100, object_id="sphere2")
    for field in ("T_obj_tcp", "width_expected", "antipodal", "contacts"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.allclose(a.T_obj_tcp, c.T_obj_tcp)


@pytest.mark.parametrize("n", [0, 1, 7, 100])
def test_exactly_n_rows_with_dtypes(n: int) -> None:
    cand = _sample(trimesh.creation.cylinder(radius=0.03, height=0.1), n)
    assert len(cand) == n
    assert cand.T_obj_tcp.shape == (n, 4, 4) and cand.T_obj_tcp.dtype == np.float64
    assert cand.width_expected.shape == (n,) and cand.width_expected.dtype == np.float64
    assert cand.antipodal.shape == (n,) and cand.antipodal.dtype == np.bool_
    assert cand.contacts.shape == (n, 2, 3)


def test_frames_are_right_handed_and_x_along_contact_line() -> None:
    mesh = trimesh.creation.torus(major_radius=0.04, minor_radius=0.012)
    cand = _sample(mesh, 300)
    R = cand.T_obj_tcp[:, :3, :3]
    np.testing.assert_allclose(R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    np.testing.assert_array_equal(cand.T_obj_tcp[:, 3], np.broadcast_to([0, 0, 0, 1.0], (300, 4)))
    x, y, z = R[:, :, 0], R[:, :, 1], R[:, :, 2]
    np.testing.assert_allclose(np.cross(z, x), y, atol=1e-9)  # +y = z x x
    p1, p2 = cand.contacts[:, 0], cand.contacts[:, 1]
    chord = p2 - p1
    np.testing.assert_allclose(np.linalg.norm(chord, axis=1), cand.width_expected, atol=1e-9)
    hit = cand.width_expected > 0
    assert hit.mean() > 0.9
    np.testing.assert_allclose(chord[hit] / cand.width_expected[hit, None], x[hit], atol=1e-9)
    np.testing.assert_allclose(cand.T_obj_tcp[:, :3, 3], 0.5 * (p1 + p2), atol=1e-12)
    # Through the xyzw Transform and back: unit quaternions, same matrices.
    for T in cand.T_obj_tcp[:20]:
        tf = Transform.from_matrix(T)
        assert abs(np.linalg.norm(tf.quat) - 1.0) < 1e-12
        np.testing.assert_allclose(tf.as_matrix(), T, atol=1e-9)


def test_40mm_box_antipodal_widths_and_tcp_inside() -> None:
    mesh = _box(0.04)
    cand = _sample(mesh, 200)
    anti = cand.antipodal
    # 80 % are antipodal pairs by construction; some less selective rows also pass the test.
    assert anti.sum() >= 160
    w = cand.width_expected[anti]
    cone_max = 0.04 * np.sqrt(1 + CONFIG.friction_coefficient**2)  # 0.04 / cos(atan(mu))
    assert np.all(w >= 0.04 - 1e-6) and np.all(w <= cone_max + 1e-6)
    assert np.median(w) == pytest.approx(0.04, abs=1e-6)
    assert np.all(w <= RG2_MAX_WIDTH - CONFIG.width_margin)
    # Contact line along a face normal for the pure antipodal rows: x is +-e_i.
    x = cand.T_obj_tcp[anti, :3, 0]
    axis_aligned = np.isclose(np.abs(x).max(axis=1), 1.0, atol=1e-9)
    assert axis_aligned.sum() >= 160
    # The approach axis is perpendicular to the closing axis, and TCPs of chords lie inside the box.
    z = cand.T_obj_tcp[:, :3, 2]
    np.testing.assert_allclose(np.sum(x * z[anti], axis=1), 0.0, atol=1e-9)
    tcp = cand.T_obj_tcp[cand.width_expected > 0, :3, 3]
    assert np.all(np.abs(tcp) <= 0.02 + 1e-9)
    # Contacts are on the surface.
    assert np.all(np.isclose(np.abs(cand.contacts).max(axis=2), 0.02, atol=1e-6))


def test_approach_rotations_take_n_rotations_values() -> None:
    cand = _sample(_box(0.04), 400)
    anti = cand.antipodal & np.isclose(cand.width_expected, 0.04)
    x = cand.T_obj_tcp[anti, :3, 0]
    z = cand.T_obj_tcp[anti, :3, 2]
    # On a box the closing axis is one of six directions; per direction, the approach axes take
    # at most n_rotations distinct values, and more than one.
    key = np.round(x).astype(int)
    for k in np.unique(key, axis=0):
        zs = np.round(z[(key == k).all(axis=1)], 6)
        distinct = np.unique(zs, axis=0)
        assert 1 < len(distinct) <= CONFIG.n_rotations


def test_too_wide_cube_still_gives_n_rows_and_no_antipodal() -> None:
    cand = _sample(_box(0.150), 120, max_width=0.11)
    assert len(cand) == 120
    assert not cand.antipodal.any()
    assert np.all(np.isfinite(cand.T_obj_tcp))
    np.testing.assert_allclose(np.linalg.det(cand.T_obj_tcp[:, :3, :3]), 1.0, atol=1e-9)


def test_random_fraction_mixes_in_less_selective_rows() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    all_random = SamplerConfig(random_fraction=1.0)
    none_random = SamplerConfig(random_fraction=0.0)
    a = sample_candidates(mesh, 200, object_rng(0, "s"), all_random, RG2_MAX_WIDTH)
    b = sample_candidates(mesh, 200, object_rng(0, "s"), none_random, RG2_MAX_WIDTH)
    assert b.antipodal.all()
    # Random chords through a sphere: most fall outside the friction cone.
    assert a.antipodal.mean() < 0.6
    assert a.width_expected.std() > b.width_expected.std()


def test_first_hits_matches_analytic_sphere() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, face = _first_hits(mesh.triangles, np.zeros((200, 3)), d)
    assert np.all(face >= 0)
    np.testing.assert_allclose(t, 0.03, rtol=0.01)  # polyhedron within 1 % of the sphere
    t_out, face_out = _first_hits(mesh.triangles, 0.1 * d, d)  # outside, pointing away
    assert np.all(face_out == -1) and np.all(np.isinf(t_out))


def _all_pairs_first_hits(triangles: np.ndarray, origins: np.ndarray, directions: np.ndarray):
    """The sampler's exact test on every (ray, triangle) pair, unscreened; the nearest hit per ray."""
    ray_i, face_i = (
        a.ravel() for a in np.meshgrid(np.arange(len(origins)), np.arange(len(triangles)), indexing="ij")
    )
    v0 = triangles[:, 0]
    ray_i, face_i, t = _pair_hits(
        v0, triangles[:, 1] - v0, triangles[:, 2] - v0, origins, directions, ray_i, face_i
    )
    t_best = np.full(len(origins), np.inf)
    face_best = np.full(len(origins), -1)
    order = np.lexsort((t, ray_i))
    for r, f, tt in zip(ray_i[order][::-1], face_i[order][::-1], t[order][::-1], strict=True):
        t_best[r], face_best[r] = tt, f  # the last written is each ray's first in order
    return t_best, face_best


@pytest.mark.parametrize("offset", [0.0, 5.0])
@pytest.mark.parametrize("scale", [0.02, 1.0])
def test_first_hits_screen_never_drops_a_hit(offset: float, scale: float) -> None:
    """The float32 broad phase keeps every pair the exact float64 test hits: the nearest hit of each
    ray equals, bit for bit, that of the exact test on all pairs (objects of 2 cm and 1 m, at the
    origin and 5 m from it; rays from the surface inwards, as the sampler casts them, and at random)."""
    mesh = trimesh.creation.torus(major_radius=0.04, minor_radius=0.015, major_sections=24, minor_sections=12)
    mesh.apply_scale(scale / 0.11)
    mesh.apply_translation([offset, -offset, 0.5 * offset])
    rng = np.random.default_rng(7)
    points, faces = trimesh.sample.sample_surface(mesh, 300, seed=7)
    inward = -mesh.face_normals[faces]
    random = rng.normal(size=(300, 3))
    random /= np.linalg.norm(random, axis=1, keepdims=True)
    origins = np.concatenate([points + 1e-6 * inward, mesh.bounds.mean(axis=0) + 0.3 * scale * random])
    directions = np.concatenate([inward, -random])
    t, face = _first_hits(mesh.triangles, origins, directions)
    t_ref, face_ref = _all_pairs_first_hits(mesh.triangles, origins, directions)
    assert np.sum(face_ref >= 0) > 400  # most rays hit: the comparison is not of misses
    np.testing.assert_array_equal(face, face_ref)
    np.testing.assert_array_equal(t, t_ref)
