"""How far the collision geometry (convex parts or hull) is from the mesh surface.

Both ways, from surface samples (seeded, so the figure is reproducible):

- collision -> mesh: points on the boundary of the union of the parts (a part's surface points
  that lie inside another part are not on it) that are outside the mesh, and their distance to
  the mesh surface: collision shape that stands proud of the object (boundary points inside the
  solid, crevices between parts, count 0);
- mesh -> collision: points on the mesh surface and their distance to the union: exact for
  points outside every part (surface the collision shape misses), and for points inside a part
  the depth in the deepest part containing them (a lower bound where parts overlap; a fat part
  is measured exactly the other way).

``CollisionError.mean`` averages both sample sets, ``max`` is the largest of both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

# A part's surface point inside another part, or on its surface to within this, is not on the
# boundary of the union: neighbouring parts share their cut faces to rounding.
INSIDE_TOLERANCE = 1e-7  # m


MAX_CANDIDATES = 64  # triangles per point, see closest_distance
# Point-plane pairs per block of _depth: 2**21 float64 are 16 MB (about 50 MB with the temporaries).
DEPTH_BLOCK = 2**21


@dataclass(frozen=True)
class CollisionError:
    """Distances between collision geometry and mesh surface, m."""

    mean: float
    max: float
    mean_outward: float  # collision -> mesh alone
    max_outward: float
    mean_inward: float  # mesh -> collision alone
    max_inward: float

    def within(self, mean_limit: float, max_limit: float) -> bool:
        return self.mean <= mean_limit and self.max <= max_limit


def closest_distance(
    triangles: np.ndarray, points: np.ndarray, max_edge: float = 0.005
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each of ``points`` (n, 3) to the triangle soup ``triangles`` (m, 3, 3), (n,),
    and whether each point is on the outer side of its nearest triangle, (n,) bool.

    The triangles are first split to edges <= ``max_edge`` (the same surface); candidates are the
    triangles with the nearest centroids, and a point whose answer a farther triangle could still
    beat (its centroid within the best distance + the largest circumradius) is checked against all.
    """
    from scipy.spatial import cKDTree

    v, f = trimesh.remesh.subdivide_to_size(
        triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3), max_edge=max_edge
    )
    tri = np.asarray(v, dtype=np.float64)[np.asarray(f)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroids = tri.mean(axis=1)
    radius = float(np.linalg.norm(tri - centroids[:, None, :], axis=2).max())
    tree = cKDTree(centroids)
    best = np.full(len(points), np.inf)
    side = np.zeros(len(points))
    todo = np.arange(len(points))
    k = 8
    while len(todo):
        k = min(k, len(tri))
        dist, idx = tree.query(points[todo], k=k)
        dist, idx = np.asarray(dist).reshape(len(todo), k), np.asarray(idx).reshape(len(todo), k)
        for rows in np.array_split(np.arange(len(todo)), max(1, len(todo) * k // 200_000)):
            p = np.repeat(points[todo[rows]], k, axis=0)
            d, q = _point_triangle_distance(p, tri[idx[rows].reshape(-1)])
            d = d.reshape(len(rows), k)
            j = d.argmin(axis=1)
            better = d[np.arange(len(rows)), j] < best[todo[rows]]
            at = todo[rows][better]
            pick = idx[rows][better, j[better]]
            best[at] = d[better, j[better]]
            q = q.reshape(len(rows), k, 3)[better, j[better]]
            side[at] = np.einsum("ij,ij->i", points[at] - q, normals[pick])
        if k >= min(len(tri), MAX_CANDIDATES):
            break
        todo = todo[dist[:, -1] < best[todo] + radius]  # a triangle beyond the k-th could be nearer
        k *= 8
    return best, side >= 0


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from p[i] (n, 3) to triangle tri[i] (n, 3, 3), and the closest point (n, 3)
    (Ericson, Real-Time Collision Detection 5.1.5, vectorised)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edges
        e_ab = d1 / (d1 - d3)
        e_ac = d2 / (d2 - d6)
        e_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    q = np.where(on_bc[:, None], b + (c - b) * np.nan_to_num(e_bc)[:, None], q)
    q = np.where(on_ac[:, None], a + ac * np.nan_to_num(e_ac)[:, None], q)
    q = np.where(on_ab[:, None], a + ab * np.nan_to_num(e_ab)[:, None], q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
    q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    return np.linalg.norm(p - q, axis=1), q


def _planes(part: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals (k, 3) and offsets (k,) of a convex part: n . x <= d inside."""
    normals = np.asarray(part.face_normals, dtype=np.float64)
    offsets = np.einsum("ij,ij->i", normals, np.asarray(part.triangles[:, 0], dtype=np.float64))
    return normals, offsets


def _depth(points: np.ndarray, planes: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Signed depth inside a convex part, (n,): > 0 inside (distance to its nearest face plane).

    Bounded memory: the points go in blocks of about ``DEPTH_BLOCK`` point-plane pairs (a hull of
    19,800 faces against 10,000 points was one 1.6 GB matrix, twice). Every block has at least two
    rows, so each product comes from the same matrix kernel as the whole would (a one-row block
    is a matrix-vector product, whose sums can differ in the last bit): the figures are bit for
    bit those of the whole matrix.
    """
    normals, offsets = planes
    n, k = len(points), len(offsets)
    blocks = max(1, min(n // 2, (n * k) // DEPTH_BLOCK))
    if blocks == 1:
        return np.min(offsets[None, :] - points @ normals.T, axis=1)
    out = np.empty(n)
    for rows in np.array_split(np.arange(n), blocks):  # sizes differ by one at most, all >= 2
        block = slice(rows[0], rows[-1] + 1)
        out[block] = np.min(offsets[None, :] - points[block] @ normals.T, axis=1)
    return out


def collision_error(
    mesh: trimesh.Trimesh, parts: list[trimesh.Trimesh], samples: int, seed: int = 0
) -> CollisionError:
    """The error of collision ``parts`` (convex, metres) against ``mesh``; ``samples`` per direction."""
    rng = np.random.default_rng(seed)
    planes = [_planes(p) for p in parts]
    # collision -> mesh: boundary points of the union, spread over the parts by area
    areas = np.array([p.area for p in parts], dtype=np.float64)
    counts = rng.multinomial(samples, areas / areas.sum())
    boundary = []
    for i, (part, n) in enumerate(zip(parts, counts, strict=True)):
        if n == 0:
            continue
        pts, _ = trimesh.sample.sample_surface(part, int(n), seed=int(rng.integers(2**31)))
        keep = np.ones(len(pts), dtype=bool)
        for j, pl in enumerate(planes):
            if j != i:
                keep &= _depth(pts, pl) < -INSIDE_TOLERANCE
        boundary.append(pts[keep])
    pts_out = np.vstack(boundary) if boundary else np.zeros((0, 3))
    mesh_triangles = np.asarray(mesh.triangles, dtype=np.float64)
    d_out, outside_mesh = (
        closest_distance(mesh_triangles, pts_out) if len(pts_out) else (np.zeros(0), np.zeros(0, bool))
    )
    # a boundary point inside the solid is a crevice between parts (their cut faces need not
    # match exactly), not shape standing proud: the surface it leaves is measured the other way
    d_out = np.where(outside_mesh, d_out, 0.0)
    # mesh -> collision
    pts_in, _ = trimesh.sample.sample_surface(mesh, samples, seed=int(rng.integers(2**31)))
    depths = np.stack([_depth(pts_in, pl) for pl in planes], axis=1)  # (n, parts)
    inside = depths.max(axis=1) > 0
    d_in = np.empty(len(pts_in))
    d_in[inside] = depths[inside].max(axis=1)
    outside = np.flatnonzero(~inside)
    if len(outside):
        part_triangles = np.concatenate([np.asarray(p.triangles, dtype=np.float64) for p in parts])
        d_in[outside] = closest_distance(part_triangles, pts_in[outside])[0]
    d_out = np.asarray(d_out, dtype=np.float64)
    both = np.concatenate([d_out, d_in])
    return CollisionError(
        mean=float(both.mean()),
        max=float(both.max()),
        mean_outward=float(d_out.mean()) if len(d_out) else 0.0,
        max_outward=float(d_out.max()) if len(d_out) else 0.0,
        mean_inward=float(d_in.mean()),
        max_inward=float(d_in.max()),
    )


def surface_deviation(a: trimesh.Trimesh, b: trimesh.Trimesh, samples: int, seed: int = 0) -> float:
    """The largest distance (m) from a point of either surface to the other, from ``samples``
    seeded points on each: how far a simplified copy ``b`` strays from the mesh ``a`` (both
    metres, one frame; neither need be convex or closed)."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for src, dst in ((a, b), (b, a)):
        points, _ = trimesh.sample.sample_surface(src, samples, seed=int(rng.integers(2**31)))
        distance, _ = closest_distance(np.asarray(dst.triangles, dtype=np.float64), points)
        worst = max(worst, float(distance.max()))
    return worst
