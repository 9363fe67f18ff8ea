"""Whether a mesh is its own convex hull: a box, a cylinder, a capsule, any closed convex
polyhedron. Such a mesh collides as its hull with no error at all, so it needs no decomposition,
no child process, no cache entry and no sampled error figure (the sampled figure of an exactly
convex mesh against its hull is rounding, about 1e-17 m, and costs about a CPU-second).

The test, on a closed (watertight) mesh: every face's plane supports the hull (no hull vertex lies
beyond it by more than :data:`OWN_HULL_TOLERANCE` of the mesh's extent, so every face lies on the
hull's surface), and the mesh encloses the hull's volume (to :data:`OWN_HULL_VOLUME_TOLERANCE`, so
it covers that surface once). A concave mesh fails the first (a face of a dent or a cavity has hull
vertices in front of it), a mesh with a missing or doubled piece of surface the second.
"""

from __future__ import annotations

import time

import numpy as np
import trimesh

from annotator.objects.collision_entry import CollisionGeometry
from annotator.objects.fidelity import CollisionError

# How far (a share of the mesh's largest extent) a hull vertex may lie beyond a face's plane with
# the face still taken as on the hull: rounding of the face normals of a float64 mesh is ~1e-13 of
# the extent for faces a thousandth of the extent across; 1e-9 is 0.1 nm on a 100 mm object.
OWN_HULL_TOLERANCE = 1e-9
# Largest relative difference of the mesh's volume from its hull's: float64 sums of a few
# thousand signed tetrahedra differ by ~1e-15; a surface covered twice or left open differs by
# whole multiples or by the missing piece.
OWN_HULL_VOLUME_TOLERANCE = 1e-9
# The collision error of a mesh that is its own hull: none, either way (m).
NO_ERROR = CollisionError(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
# Face-vertex pairs per block of the plane test (float64: 16 MB per block with its temporaries).
PAIRS_PER_BLOCK = 2**20


def is_own_hull(mesh: trimesh.Trimesh, hull: trimesh.Trimesh) -> bool:
    """True when the closed ``mesh`` (metres, any frame) is its convex ``hull`` (the same frame):
    every face on the hull's surface and the surface covered once (see the module's text).
    False for an open mesh, a concave one, or one whose faces' normals are too rough to tell."""
    if len(mesh.faces) == 0 or not mesh.is_watertight:
        return False
    hull_volume = float(hull.volume)
    if not hull_volume > 0 or abs(float(mesh.volume) - hull_volume) > OWN_HULL_VOLUME_TOLERANCE * hull_volume:
        return False
    tolerance = OWN_HULL_TOLERANCE * float(np.max(mesh.extents))
    triangles = np.asarray(mesh.triangles, dtype=np.float64)  # (m, 3, 3)
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    if not np.all(lengths > 0):
        return False
    normals /= lengths[:, None]
    offsets = np.einsum("ij,ij->i", normals, triangles[:, 0])  # n . x <= offset behind the face
    corners = np.asarray(hull.vertices, dtype=np.float64)  # (k, 3)
    rows = max(1, PAIRS_PER_BLOCK // max(1, len(corners)))
    for start in range(0, len(normals), rows):
        block = slice(start, start + rows)
        beyond = corners @ normals[block].T - offsets[block][None, :]  # (k, rows)
        if float(beyond.max()) > tolerance:
            return False
    return True


def own_hull_geometry(mesh: trimesh.Trimesh) -> CollisionGeometry | None:
    """The collision geometry of a ``mesh`` that :func:`is_own_hull`: its hull as the one part
    (float64 vertices, int64 faces, as a cache entry would hold them), error :data:`NO_ERROR`,
    method ``hull``, no cache file; None for any other mesh."""
    start = time.process_time()
    hull = mesh.convex_hull
    if not is_own_hull(mesh, hull):
        return None
    part = trimesh.Trimesh(
        np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64), process=False
    )
    return CollisionGeometry([part], NO_ERROR, "hull", 0.0, None, False, time.process_time() - start)
