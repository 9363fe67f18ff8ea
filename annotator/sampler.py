"""Antipodal grasp candidates for a parallel gripper on a triangle mesh, drawn from a numpy Generator.

A candidate is a TCP pose ``T_obj_tcp`` in the object's mesh frame plus the expected opening. The
TCP frame (docs/frames.md): origin midway between the two contacts (where the pad centres go), +x the
closing direction from finger 1 to finger 2 along the contact line, +z the approach direction
(from the gripper into the object), +y = z x x.

Two kinds of candidate are mixed:

* antipodal: a surface point, a ray along the inward normal to the opposite wall, accepted if the
  chord fits the open gripper and both normals lie inside the friction cone of the contact line;
  the approach axis is one of ``n_rotations`` directions perpendicular to the closing axis.
* less selective (``random_fraction`` of the rows, and any shortfall of antipodal pairs): a
  surface point and a ray in a uniformly random inward direction; no width or cone test. These are
  the informative negatives (and some positives) a learner needs.

Rays are cast with a vectorised Moller-Trumbore test in numpy, so neither embree nor rtree is
needed; a bounding-sphere broad phase keeps 500 candidates on a 5k-face mesh well under a second.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import trimesh

from annotator.config import SamplerConfig
from annotator.rng import object_rng  # noqa: F401  (re-exported)

log = logging.getLogger(__name__)

# (ray, triangle) pairs screened per chunk of the broad phase: ~8 MB per float32 array.
_RAY_CHUNK_ELEMENTS = 2_000_000
# Barycentric slack so rays through a shared edge of two triangles hit one of them.
_BARY_EPS = 1e-9
# |det| below this means the ray is parallel to the triangle (units m^2; a 0.1 mm triangle
# seen at 1e-4 rad still has |det| ~ 1e-12).
_DET_EPS = 1e-18


@dataclass(frozen=True)
class Candidates:
    """Grasp candidates for one object, all arrays with the same first dimension ``n``.

    T_obj_tcp : (n, 4, 4) float64
        TCP pose in the object's mesh frame.
    width_expected : (n,) float64
        Chord between the two contacts, metres (0 when the ray found no opposite wall).
    antipodal : (n,) bool
        The row passes the antipodal test (width fits ``max_width - width_margin`` and both
        normals inside the friction cone); computed for every row, including the less selective.
    contacts : (n, 2, 3) float64
        Contact points of finger 1 and finger 2 in the mesh frame.
    placement : (n,) int64 or None
        ``annotate --cell``: the placement on the table each candidate was sampled for
        (:mod:`annotator.cell.candidates`); None for a floating object.
    """

    T_obj_tcp: np.ndarray
    width_expected: np.ndarray
    antipodal: np.ndarray
    contacts: np.ndarray
    placement: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.T_obj_tcp.shape[0])


def _first_hits(
    triangles: np.ndarray, origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of each ray with any triangle (Moller-Trumbore, both faces count).

    triangles : (F, 3, 3) float, origins : (R, 3) float, directions : (R, 3) unit float.
    Returns ``t`` : (R,) float distance (inf for a miss) and ``face`` : (R,) int (-1 for a miss).

    A broad phase keeps only (ray, triangle) pairs whose line passes within the triangle's
    bounding sphere (two matrix products per chunk); the exact test runs on those pairs only. The
    broad phase runs in float32 (half the memory traffic of its R x F arrays) on coordinates
    centred on the triangles, with the spheres grown by a bound on its rounding error, so it never
    drops a pair the float64 test would keep; the exact test is float64.
    """
    n_rays = origins.shape[0]
    t_best = np.full(n_rays, np.inf)
    face_best = np.full(n_rays, -1, dtype=np.int64)
    n_faces = triangles.shape[0]
    if n_rays == 0 or n_faces == 0:
        return t_best, face_best
    v0 = triangles[:, 0]
    e1 = triangles[:, 1] - v0
    e2 = triangles[:, 2] - v0
    centre = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centre[:, None, :], axis=2).max(axis=1)
    # the broad phase's frame: centred on the triangles, so its float32 terms are ~ size^2
    corners = triangles.reshape(-1, 3)
    shift = 0.5 * (corners.min(axis=0) + corners.max(axis=0))
    c64 = centre - shift
    c32 = c64.astype(np.float32)
    o64 = origins - shift
    size2 = max(float(np.max(np.sum(c64**2, axis=1))), float(np.max(np.sum(o64 * o64, axis=1))))
    # |c - o|^2 - ((c - o).d)^2 from float32 products of terms <= size2: its rounding error is
    # below ~16 eps32 size2; 64 eps32 size2 (+ the float64 margin) is the screen's slack
    slack = 64.0 * float(np.finfo(np.float32).eps) * size2
    threshold = ((radius * (1.0 + 1e-6) + 1e-12) ** 2 + slack).astype(np.float32)
    centre2 = np.sum(c32 * c32, axis=1)
    chunk = max(1, _RAY_CHUNK_ELEMENTS // n_faces)
    for start in range(0, n_rays, chunk):
        o = origins[start : start + chunk]
        d = directions[start : start + chunk]
        o32 = o64[start : start + chunk].astype(np.float32)
        d32 = d.astype(np.float32)
        # Squared distance from each triangle centre to each ray's line, |c - o|^2 - ((c - o).d)^2.
        co = centre2[None, :] - 2.0 * (o32 @ c32.T) + np.sum(o32 * o32, axis=1)[:, None]
        cd = d32 @ c32.T - np.sum(o32 * d32, axis=1)[:, None]
        ray_i, face_i = np.nonzero(co - cd * cd <= threshold[None, :])
        if ray_i.size == 0:
            continue
        ray_i, face_i, t = _pair_hits(v0, e1, e2, o, d, ray_i, face_i)
        # Nearest hit per ray: sort by (ray, t), keep the first of each ray.
        order = np.lexsort((t, ray_i))
        rays_sorted = ray_i[order]
        if rays_sorted.size:
            first = np.flatnonzero(np.r_[True, rays_sorted[1:] != rays_sorted[:-1]])
        else:
            first = np.zeros(0, dtype=np.intp)
        rows = start + rays_sorted[first]
        t_best[rows] = t[order][first]
        face_best[rows] = face_i[order][first]
    return t_best, face_best


def _pair_hits(
    v0: np.ndarray,
    e1: np.ndarray,
    e2: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    ray_i: np.ndarray,
    face_i: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exact Moller-Trumbore test of (ray ``ray_i``, triangle ``face_i``) pairs, float64.

    v0, e1, e2 : (F, 3) a vertex of each triangle and its two edges from it; origins, directions :
    (R, 3); ray_i, face_i : (P,) int. Returns the pairs that hit at t > 0 (both faces count):
    their ``ray_i``, ``face_i`` and ``t`` (the distance along the ray), in the order given.
    """
    dd = directions[ray_i]
    pvec = np.cross(dd, e2[face_i])
    det = np.sum(pvec * e1[face_i], axis=1)
    parallel = np.abs(det) < _DET_EPS
    inv = 1.0 / np.where(parallel, 1.0, det)
    tvec = origins[ray_i] - v0[face_i]
    u = np.sum(tvec * pvec, axis=1) * inv
    qvec = np.cross(tvec, e1[face_i])
    v = np.sum(dd * qvec, axis=1) * inv
    t = np.sum(e2[face_i] * qvec, axis=1) * inv
    hit = ~parallel & (u >= -_BARY_EPS) & (v >= -_BARY_EPS) & (u + v <= 1.0 + _BARY_EPS) & (t > 0.0)
    return ray_i[hit], face_i[hit], t[hit]


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (..., 3) scaled to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perpendicular(x: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each unit row of ``x`` : (n, 3); deterministic."""
    axis = np.argmin(np.abs(x), axis=1)
    a = np.zeros_like(x)
    a[np.arange(x.shape[0]), axis] = 1.0
    return unit(a - np.sum(a * x, axis=1, keepdims=True) * x)


def _frames(p1: np.ndarray, p2: np.ndarray, x: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """TCP poses (n, 4, 4): origin (p1 + p2) / 2, closing axis ``x`` (n, 3) unit, approach axis
    rotated by ``angles`` (n,) rad about ``x`` from a fixed perpendicular."""
    z0 = _perpendicular(x)
    z = np.cos(angles)[:, None] * z0 + np.sin(angles)[:, None] * np.cross(x, z0)
    z = unit(z - np.sum(z * x, axis=1, keepdims=True) * x)
    y = np.cross(z, x)
    T = np.zeros((x.shape[0], 4, 4))
    T[:, :3, 0] = x
    T[:, :3, 1] = y
    T[:, :3, 2] = z
    T[:, :3, 3] = 0.5 * (p1 + p2)
    T[:, 3, 3] = 1.0
    return T


@dataclass(frozen=True)
class ContactPairs:
    """Contact pairs from rays: p1, p2, x : (m, 3); width : (m,); antipodal : (m,) bool."""

    p1: np.ndarray
    p2: np.ndarray
    x: np.ndarray
    width: np.ndarray
    antipodal: np.ndarray

    def take(self, idx: np.ndarray) -> ContactPairs:
        return ContactPairs(self.p1[idx], self.p2[idx], self.x[idx], self.width[idx], self.antipodal[idx])


def cast_pairs(
    mesh: trimesh.Trimesh,
    count: int,
    rng: np.random.Generator,
    config: SamplerConfig,
    max_width: float,
    random_direction: bool,
) -> ContactPairs:
    """Draw ``count`` surface points and cast one ray each into the object.

    The ray goes along the inward face normal, or (``random_direction``) in a uniformly random
    direction on the inward hemisphere. A miss gives ``p2 = p1``, width 0 and ``x`` = the ray.
    """
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=rng)
    normals = mesh.face_normals[face_idx]
    if random_direction:
        d = unit(rng.normal(size=(count, 3)))
        flip = np.sum(d * normals, axis=1) > 0.0
        d[flip] *= -1.0
    else:
        d = -normals
    return chords(mesh, points, face_idx, d, config, max_width)


def chords(
    mesh: trimesh.Trimesh,
    points: np.ndarray,
    face_idx: np.ndarray,
    d: np.ndarray,
    config: SamplerConfig,
    max_width: float,
) -> ContactPairs:
    """The contact pairs of rays from surface ``points`` (m, 3) on faces ``face_idx`` (m,) into
    the object along unit directions ``d`` (m, 3), with the antipodal test of each (no draws)."""
    normals = mesh.face_normals[face_idx]
    t, hit_face = _first_hits(mesh.triangles, points + config.ray_offset * d, d)
    hit = hit_face >= 0
    width = np.where(hit, t + config.ray_offset, 0.0)
    p2 = points + width[:, None] * d
    # For rays that hit, x = d exactly (the contact line is the ray).
    n2 = np.where(hit[:, None], mesh.face_normals[np.maximum(hit_face, 0)], 0.0)
    cos_cone = 1.0 / np.sqrt(1.0 + config.friction_coefficient**2)  # cos(atan(mu))
    antipodal = (
        hit
        & (width >= config.min_width)
        & (width <= max_width - config.width_margin)
        & (-np.sum(normals * d, axis=1) >= cos_cone)
        & (np.sum(n2 * d, axis=1) >= cos_cone)
    )
    return ContactPairs(points, p2, d, width, antipodal)


def _antipodal_pool(
    mesh: trimesh.Trimesh, wanted: int, rng: np.random.Generator, config: SamplerConfig, max_width: float
) -> ContactPairs:
    """Accepted antipodal pairs, at least ``wanted`` if they can be found in ``max_rounds`` rounds."""
    found: list[ContactPairs] = []
    total = 0
    for round_ in range(config.max_rounds):
        count = max(16, config.oversample * wanted * 2**round_)
        pairs = cast_pairs(mesh, count, rng, config, max_width, random_direction=False)
        accepted = pairs.take(np.flatnonzero(pairs.antipodal))
        found.append(accepted)
        total += len(accepted.width)
        log.debug("sampler round %d: %d of %d pairs antipodal", round_, len(accepted.width), count)
        if total >= wanted:
            break
    return ContactPairs(
        *(np.concatenate([getattr(f, k) for f in found]) for k in ("p1", "p2", "x", "width", "antipodal"))
    )


def sample_candidates(
    mesh: trimesh.Trimesh,
    n: int,
    rng: np.random.Generator,
    config: SamplerConfig,
    max_width: float,
) -> Candidates:
    """Exactly ``n`` grasp candidates on ``mesh`` (metres, mesh frame), deterministic given ``rng``.

    ``round(n * config.random_fraction)`` rows are less selective; the rest are antipodal pairs,
    each with one of ``config.n_rotations`` approach directions about its closing axis. If fewer
    antipodal pairs exist (thin parts, objects wider than ``max_width``), pairs are reused with
    other rotations and the remainder is filled with less selective rows, so there are always
    ``n`` rows. Rows are shuffled so any prefix is a fair subsample.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if not 0.0 <= config.random_fraction <= 1.0:
        raise ValueError(f"random_fraction must be in [0, 1], got {config.random_fraction}")
    if config.n_rotations < 1:
        raise ValueError(f"n_rotations must be >= 1, got {config.n_rotations}")
    n_random_wanted = int(round(n * config.random_fraction))
    n_anti_wanted = n - n_random_wanted
    step = 2.0 * np.pi / config.n_rotations

    parts_T: list[np.ndarray] = []
    parts: list[ContactPairs] = []
    n_anti = 0
    if n_anti_wanted > 0:
        pool = _antipodal_pool(mesh, n_anti_wanted, rng, config, max_width)
        k = len(pool.width)
        if k >= n_anti_wanted:
            sel = pool.take(np.arange(n_anti_wanted))
            rot = rng.integers(config.n_rotations, size=n_anti_wanted)
        else:
            # Scarce pairs: distinct (pair, rotation) combinations, without replacement.
            combos = k * config.n_rotations
            pick = rng.choice(combos, size=min(combos, n_anti_wanted), replace=False)
            sel = pool.take(pick // config.n_rotations)
            rot = pick % config.n_rotations
            log.info(
                "only %d antipodal pairs (%d pose combinations) for %d wanted; filling with "
                "less selective candidates",
                k,
                combos,
                n_anti_wanted,
            )
        n_anti = len(sel.width)
        parts.append(sel)
        parts_T.append(_frames(sel.p1, sel.p2, sel.x, rot * step))
    n_random = n - n_anti
    if n_random > 0:
        rnd = cast_pairs(mesh, n_random, rng, config, max_width, random_direction=True)
        parts.append(rnd)
        parts_T.append(_frames(rnd.p1, rnd.p2, rnd.x, rng.uniform(0.0, 2.0 * np.pi, size=n_random)))

    if not parts:
        return Candidates(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0, dtype=bool), np.zeros((0, 2, 3)))
    order = rng.permutation(n)
    T = np.concatenate(parts_T)[order]
    width = np.concatenate([p.width for p in parts])[order]
    antipodal = np.concatenate([p.antipodal for p in parts])[order]
    contacts = np.stack(
        [np.concatenate([p.p1 for p in parts]), np.concatenate([p.p2 for p in parts])], axis=1
    )
    log.debug("sampled %d candidates: %d antipodal pairs, %d less selective", n, n_anti, n_random)
    return Candidates(
        T_obj_tcp=T.astype(np.float64),
        width_expected=width.astype(np.float64),
        antipodal=antipodal.astype(bool),
        contacts=contacts[order].astype(np.float64),
    )


def pad_opening(
    triangles: np.ndarray,
    T_obj_tcp: np.ndarray,
    width: float,
    pad_face: tuple[float, float],
    reach: float = 0.01,
    grid: tuple[int, int] = (11, 15),
) -> float:
    """The pad separation (m) at which two flat, parallel pads first touch ``triangles``.

    triangles : (F, 3, 3) float, the object's surface in its mesh frame; T_obj_tcp : (4, 4) float;
    pad_face : (across, along the approach) extents of a pad's face, m. The pads are centred on the
    TCP's closing axis (x) and close along it from ``width / 2 + reach`` on either side. This is the
    width the mesh implies for a grasp: on a concave surface (a mug's inner wall, a banana's inner
    curve) a flat pad rests on its edges, so it stops short of the chord through the TCP. Returns
    inf when a pad meets no surface.
    """
    x, y, z, origin = T_obj_tcp[:3, 0], T_obj_tcp[:3, 1], T_obj_tcp[:3, 2], T_obj_tcp[:3, 3]
    gy, gz = np.meshgrid(
        np.linspace(-pad_face[0] / 2, pad_face[0] / 2, grid[0]),
        np.linspace(-pad_face[1] / 2, pad_face[1] / 2, grid[1]),
    )
    face = origin + gy.reshape(-1, 1) * y + gz.reshape(-1, 1) * z  # (k, 3) on the pads' mid-plane
    start = width / 2 + reach
    directions = np.repeat([x, -x], len(face), axis=0)
    t, _ = _first_hits(triangles, np.concatenate([face - start * x, face + start * x]), directions)
    return float(2 * start - t[: len(face)].min() - t[len(face) :].min())
