"""Repair a cleaned mesh before it is judged: drop loose fragments, close holes, mend the rest.

Scans come with loose fragments (a few stray triangles or patches of the turntable: 6 of the 16
YCB meshes of the GRASPA benchmark) and holes. Judged as they are, they are "not watertight" and
were collided as their convex hull (a power drill without its handle). In order:

1. :func:`drop_fragments`: open pieces (with a boundary) that each hold less than
   ``ObjectConfig.fragment_max_share`` of the surface area, and together less than that share,
   are fragments; so are closed pieces under that share of the volume that lie apart from every
   other piece (floaters). Closed pieces that touch others are parts of the object (a handle, the
   convex parts of a V-HACD file) and stay.
2. :func:`fill_holes`: MeshFix fills the boundary loops (no refinement).
3. :func:`mend`: what is still open or not a manifold is handed to MeshFix's repair (it removes
   self-intersections and degenerate faces and fills what is left); a result that is closed and
   encloses volume replaces the mesh.

MeshFix (pymeshfix) is a maintained repair library (Attene, "A lightweight approach to repairing
digitized polygon meshes", The Visual Computer 2010).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import trimesh

if TYPE_CHECKING:
    from pymeshfix import PyTMesh  # loaded on first use: a repair is rare


@dataclass(frozen=True)
class Pieces:
    """The connected pieces of a mesh (faces joined across edges), one entry per piece.

    ``label`` (faces,) piece of each face; ``area`` (k,) m^2; ``volume`` (k,) m^3, signed (closed
    pieces only mean anything); ``closed`` (k,) bool, no boundary edge; ``lo``/``hi`` (k, 3) bounds.
    """

    label: np.ndarray
    area: np.ndarray
    volume: np.ndarray
    closed: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def pieces(mesh: trimesh.Trimesh) -> Pieces:
    """The connected pieces of ``mesh`` and their area, volume, closedness and bounds (vectorised)."""
    faces = np.asarray(mesh.faces)
    n = len(faces)
    groups = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(n))
    label = np.empty(n, dtype=np.int64)
    for i, g in enumerate(groups):
        label[g] = i
    k = len(groups)
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    area = np.bincount(label, weights=np.asarray(mesh.area_faces, dtype=np.float64), minlength=k)
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    volume = np.bincount(label, weights=signed, minlength=k)
    edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)
    _, edge_id, uses = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    boundary_faces = np.repeat(np.arange(n), 3)[uses[edge_id.reshape(-1)] == 1]
    closed = np.ones(k, dtype=bool)
    closed[label[boundary_faces]] = False
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    corners = tri.reshape(-1, 3)
    owner = np.repeat(label, 3)
    for axis in range(3):
        np.minimum.at(lo[:, axis], owner, corners[:, axis])
        np.maximum.at(hi[:, axis], owner, corners[:, axis])
    return Pieces(label, area, volume, closed, lo, hi)


def _apart(p: Pieces, candidates: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """Which ``candidates`` (piece indices) have bounding boxes that meet no other piece's."""
    out = np.zeros(len(candidates), dtype=bool)
    for j, i in enumerate(candidates):
        meet = np.all((p.lo - tolerance <= p.hi[i]) & (p.lo[i] - tolerance <= p.hi), axis=1)
        meet[i] = False
        out[j] = not meet.any()
    return out


@dataclass(frozen=True)
class Dropped:
    """What :func:`drop_fragments` removed: how many pieces, their faces and share of the area."""

    pieces: int = 0
    faces: int = 0
    area_share: float = 0.0


def drop_fragments(mesh: trimesh.Trimesh, max_share: float) -> tuple[trimesh.Trimesh, Dropped]:
    """``mesh`` without its loose fragments (see the module), and what went.

    Nothing is dropped from a mesh of one piece, nor when the open candidates together hold
    ``max_share`` of the area or more (a triangle soup or a mesh in several open pieces: not one
    body with fragments)."""
    if max_share <= 0 or len(mesh.faces) == 0:
        return mesh, Dropped()
    p = pieces(mesh)
    if len(p.area) < 2:
        return mesh, Dropped()
    total_area = float(p.area.sum())
    open_small = np.flatnonzero(~p.closed & (p.area < max_share * total_area))
    if p.area[open_small].sum() >= max_share * total_area:
        open_small = open_small[:0]
    closed_volume = float(np.abs(p.volume[p.closed]).sum())
    tiny = np.flatnonzero(p.closed & (np.abs(p.volume) < max_share * closed_volume))
    floaters = tiny[_apart(p, tiny)] if len(tiny) and len(tiny) < len(p.area) else tiny[:0]
    drop = np.union1d(open_small, floaters)
    if len(drop) == 0 or len(drop) == len(p.area):
        return mesh, Dropped()
    keep = ~np.isin(p.label, drop)
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)[keep], process=False)
    out.remove_unreferenced_vertices()
    return out, Dropped(len(drop), int((~keep).sum()), float(p.area[drop].sum() / total_area))


def _meshfix(mesh: trimesh.Trimesh) -> PyTMesh:
    import pymeshfix

    tin = pymeshfix.PyTMesh()
    tin.set_quiet(True)
    tin.load_array(
        np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(mesh.faces, dtype=np.int32),
    )
    return tin


def _closed(mesh: trimesh.Trimesh) -> bool:
    return bool(len(mesh.faces) and mesh.is_watertight and mesh.is_winding_consistent)


def _arrays_mesh(tin: PyTMesh) -> trimesh.Trimesh:
    v, f = tin.return_arrays()
    return trimesh.Trimesh(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64), process=False)


def fill_holes(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """``mesh`` with its boundary loops filled by MeshFix (no refinement), and how many were filled.

    Returns the input unchanged (0) when MeshFix cannot make it a consistently wound closed
    surface, e.g. edges shared by three faces.
    """
    tin = _meshfix(mesh)
    filled = int(tin.fill_small_boundaries(nbe=0, refine=False))
    out = _arrays_mesh(tin)
    if filled == 0 or not _closed(out):
        return mesh, 0
    return out, filled


def mend(mesh: trimesh.Trimesh, min_volume: float, area_tolerance: float) -> trimesh.Trimesh | None:
    """MeshFix's repair of a mesh that is still open or not a manifold: holes filled, degenerate
    faces and self-intersections removed (``clean``); first with every piece MeshFix sees, then
    with its largest alone (MeshFix splits a surface at non-manifold edges, so a stray fin is a
    piece of its own). The first result that is a closed surface enclosing more than
    ``min_volume`` (m^3) with its area within ``area_tolerance`` (a share, ``[objects]
    mend_area_tolerance``) of the input's (a repair, not a different object), else None: filling
    holes and removing a fin or a self-intersection changes it a little (a 50 mm box with a 35 mm
    fin: 6 %), while a repair that lost half of the object (MeshFix's clean on the box with its
    fin: a wedge, -31 %) is rejected."""
    area = float(mesh.area)
    for largest_only in (False, True):
        tin = _meshfix(mesh)
        tin.fill_small_boundaries(nbe=0, refine=True)
        if largest_only:
            tin.remove_smallest_components()
        tin.clean(max_iters=10, inner_loops=3)
        out = _arrays_mesh(tin)
        if not _closed(out) or abs(float(out.area) - area) > area_tolerance * area:
            continue
        if out.volume < 0:
            out.invert()
        if out.volume > min_volume:
            return out
    return None
