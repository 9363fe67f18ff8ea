"""Read a mesh file and clean it before anything judges it.

Order matters: texture seams duplicate vertices (an OBJ splits them along UV seams), so vertices
are merged by position first, then degenerate and duplicate faces dropped, and only then is the
surface judged watertight; a hole that is still there is really open and is filled with MeshFix
(pymeshfix, :mod:`annotator.objects.repair`). Meshes above the face budget are simplified
(fast-simplification, quadric decimation) with the change reported.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
import trimesh
import trimesh.parent

from annotator.objects import gltf, wavefront
from annotator.objects.errors import ObjectError

log = logging.getLogger(__name__)

_TEXT_SUFFIXES = (".obj", ".off")


# m^3: a closed piece enclosing less is flat (a double-sided sheet; 121.obj's is exactly 0)
FLAT_VOLUME = 1e-15

# m: open-edge vertices closer than this are one. trimesh merges by rounding positions to 1e-8 m,
# so two copies of a seam vertex that straddle a rounding step stay apart (robosuite's can.stl:
# 31 seam vertices 7-11 nm apart left its lid unjoined); a tenth of a micrometre joins no feature.
WELD_TOLERANCE = 1e-7


@dataclass
class Cleaning:
    """What cleaning changed: counts, for the log and the geometry record."""

    faces_read: int = 0
    vertices_merged: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    internal_faces: int = 0  # coincident opposite faces of abutting solids, both dropped
    shells_joined: int = 0  # closed shells that touched or overlapped, joined into their union
    shared_edges: int = 0  # edges where closed shells meet (used by 4+ faces), the shells separated
    flat_pieces: int = 0  # closed pieces that enclose no volume (double-sided sheets), dropped
    fragments_dropped: int = 0  # loose pieces of a scan dropped (annotator.objects.repair)
    fragment_area_share: float = 0.0  # their share of the surface area
    holes_filled: int = 0
    mended: bool = False  # MeshFix repaired what was still open or not a manifold
    simplified_to: int = 0  # faces after simplification; 0: not simplified

    def summary(self) -> str:
        parts = [
            f"{self.vertices_merged} seam vertices merged" if self.vertices_merged else "",
            f"{self.degenerate_faces} degenerate faces dropped" if self.degenerate_faces else "",
            f"{self.duplicate_faces} duplicate faces dropped" if self.duplicate_faces else "",
            f"{self.internal_faces} faces between abutting parts dropped" if self.internal_faces else "",
            f"{self.shared_edges} edges shared by two shells separated" if self.shared_edges else "",
            f"{self.flat_pieces} flat closed pieces dropped" if self.flat_pieces else "",
            f"{self.shells_joined} overlapping shells joined" if self.shells_joined else "",
            (
                f"{self.fragments_dropped} loose fragments dropped ({100 * self.fragment_area_share:.2g} % "
                "of the area)"
                if self.fragments_dropped
                else ""
            ),
            f"{self.holes_filled} holes filled" if self.holes_filled else "",
            "repaired by MeshFix" if self.mended else "",
            f"simplified {self.faces_read} -> {self.simplified_to} faces" if self.simplified_to else "",
        ]
        return ", ".join(p for p in parts if p) or "clean"


def _looks_binary(head: bytes) -> bool:
    """Random or binary bytes: a NUL, or more than 10 % control characters outside whitespace."""
    if b"\x00" in head:
        return True
    control = sum(1 for b in head if b < 32 and b not in (9, 10, 12, 13))
    return control > 0.1 * max(1, len(head))


MB = 1024 * 1024


def check_size(path: Path, budget_mb: float) -> None:
    """Before a byte of ``path`` is read: reading a mesh holds at least its bytes, so a file
    larger than the memory budget (MB per worker, ``ObjectConfig.memory_budget``) cannot load and
    is refused here, naming the file and the figure, never scanned or hashed first."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ObjectError(f"cannot read {path.name}: {exc.strerror or exc}") from None
    if size > budget_mb * MB:
        raise ObjectError(
            f"{path.name} is {size / MB:,.0f} MB, above the memory budget of {budget_mb:,.0f} MB per worker "
            "(ObjectConfig.memory_budget): reading it alone would exceed it"
        )


def sniff(path: Path) -> None:
    """Check the file looks like its suffix says, naming the file's problem if not."""
    if not path.is_file():
        raise ObjectError(f"file not found: {path}")
    size = path.stat().st_size
    if size == 0:
        raise ObjectError(f"empty file: {path.name}")
    suffix = path.suffix.lower()
    with path.open("rb") as fh:
        head = fh.read(4096)
    if suffix == ".stl":
        if size >= 84:
            n = int(np.frombuffer(head[80:84], dtype="<u4")[0])
            if size == 84 + 50 * n:
                return  # binary STL whose size matches its triangle count
        if head.lstrip()[:5].lower() == b"solid" and not _looks_binary(head):
            return
        raise ObjectError(
            f"not an STL mesh (neither binary STL of matching size nor ASCII 'solid'): {path.name}"
        )
    if suffix == ".ply":
        if not head.startswith(b"ply"):
            raise ObjectError(f"not a PLY mesh (no 'ply' header): {path.name}")
        return
    if suffix == ".glb":
        if not head.startswith(gltf.GLB_MAGIC):
            raise ObjectError(f"not a GLB file (no glTF header): {path.name}")
        return
    if suffix in _TEXT_SUFFIXES and _looks_binary(head):
        raise ObjectError(f"not an {suffix[1:].upper()} mesh (binary data in a text format): {path.name}")
    if suffix == ".off" and not head.lstrip()[:4].upper().lstrip(b"CNST4").startswith(b"OFF"):
        raise ObjectError(f"not an OFF mesh (no OFF header): {path.name}")


def read_triangles(path: Path, node: int | None = None) -> trimesh.Trimesh:
    """The file's triangles (vertices as written, no visuals, nothing merged), or ObjectError.

    ``node``: one body of a multi-body file, a .glb node or an .obj part (None: the whole file,
    in its frame).
    """
    sniff(path)
    if path.suffix.lower() == ".glb":
        mesh = gltf.read_nodes(path, None if node is None else gltf.body_members(path, node))
    else:
        loaded: trimesh.parent.Geometry  # trimesh.load may give a point cloud or a path
        try:
            if path.suffix.lower() == ".obj":
                loaded = wavefront.read(path, node)
            else:
                loaded = trimesh.load(path, force="mesh", process=False)
        except ObjectError:
            raise
        except ImportError as exc:  # a format reader's dependency is missing: the install's fault
            raise ObjectError(
                f"cannot read {path.name}: the install lacks the package {exc.name!r}"
            ) from None
        except Exception as exc:  # trimesh raises many types for unreadable input
            raise ObjectError(f"not a readable mesh: {path.name} ({type(exc).__name__}: {exc})") from None
        if not isinstance(loaded, trimesh.Trimesh):
            raise ObjectError(f"not a mesh (no triangles found): {path.name}")
        mesh = trimesh.Trimesh(np.asarray(loaded.vertices), np.asarray(loaded.faces), process=False)
    if len(mesh.faces) == 0:
        raise ObjectError(f"not a mesh (no triangles found): {path.name}")
    return mesh


def clean(mesh: trimesh.Trimesh, name: str, report: Cleaning) -> trimesh.Trimesh:
    """Merge vertices by position, drop degenerate and duplicate faces, drop unused vertices.

    ``mesh``: scaled, in metres. Vertices closer than trimesh's merge tolerance (1e-8 m) are one,
    and so are those of open edges within :data:`WELD_TOLERANCE` (:func:`weld_open_edges`).
    """
    if not np.all(np.isfinite(mesh.vertices)):
        raise ObjectError(f"{name}: vertices contain NaN or inf")
    faces = np.asarray(mesh.faces)
    if faces.min() < 0 or faces.max() >= len(mesh.vertices):
        raise ObjectError(f"{name}: faces index missing vertices")
    report.faces_read = len(faces)
    n_vertices = len(np.unique(faces))
    out = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=np.float64), faces, process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    out = weld_open_edges(out, WELD_TOLERANCE)
    report.vertices_merged = n_vertices - len(np.unique(out.faces))
    keep = out.nondegenerate_faces(height=1e-12)
    report.degenerate_faces = int((~keep).sum())
    out.update_faces(keep)
    out.update_faces(_drop_coincident(out, report))
    out.remove_unreferenced_vertices()
    return out


def weld_open_edges(mesh: trimesh.Trimesh, tolerance: float) -> trimesh.Trimesh:
    """``mesh`` with the vertices of its open edges (edges of one face) that lie within
    ``tolerance`` (m) of each other made one (the lowest index of each cluster); the input itself
    when there are none. Faces are kept, vertices left unreferenced; a face the weld collapses is
    dropped afterwards with the degenerate ones."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    edges = mesh.edges_sorted
    open_edges = trimesh.grouping.group_rows(edges, require_count=1)
    if len(open_edges) == 0:
        return mesh
    ends = np.unique(edges[open_edges])
    pairs = cKDTree(mesh.vertices[ends]).query_pairs(tolerance, output_type="ndarray")
    if len(pairs) == 0:
        return mesh
    n = len(ends)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, cluster = connected_components(graph, directed=False)
    first = np.full(cluster.max() + 1, len(mesh.vertices), dtype=np.int64)
    np.minimum.at(first, cluster, ends)
    remap = np.arange(len(mesh.vertices), dtype=np.int64)
    remap[ends] = first[cluster]
    return trimesh.Trimesh(mesh.vertices, remap[np.asarray(mesh.faces)], process=False)


def _drop_coincident(mesh: trimesh.Trimesh, report: Cleaning) -> np.ndarray:
    """Indices of the faces to keep when faces coincide (the same three vertices).

    Wound the same way they are duplicates: one is kept. Wound opposite ways with every edge
    shared by four faces, they are the common face of two closed solids that abut (convex parts
    written as one file, e.g. a V-HACD collision mesh): their union has no face there, so both go
    (keeping one left a membrane and an open surface). A flipped copy on a single surface (edges
    shared by three faces) is a duplicate too.
    """
    faces = np.asarray(mesh.faces)
    _, first, inverse, counts = np.unique(
        np.sort(faces, axis=1), axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1)
    keep = np.zeros(len(faces), dtype=bool)
    keep[first] = True
    pairs = np.flatnonzero(counts == 2)
    if len(pairs):
        order = np.argsort(inverse, kind="stable")
        starts = np.cumsum(counts) - counts
        a, b = order[starts[pairs]], order[starts[pairs] + 1]
        opposite = _odd(faces[a], faces[b])
        edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)  # (3 n, 2)
        _, edge_id, edge_uses = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
        uses = edge_uses[edge_id.reshape(-1)].reshape(-1, 3)  # faces on each edge of each face
        internal = opposite & np.all(uses[a] >= 4, axis=1)
        keep[a[internal]] = False
        keep[b[internal]] = False
        report.internal_faces = int(2 * internal.sum())
    report.duplicate_faces = int(len(faces) - keep.sum() - report.internal_faces)
    return np.flatnonzero(keep)


def _odd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether face ``b`` (n, 3) lists the vertices of face ``a`` (n, 3) in the opposite cyclic order."""
    same = np.zeros(len(a), dtype=bool)
    for shift in range(3):
        same |= np.all(np.roll(a, shift, axis=1) == b, axis=1)
    return ~same


def closed_shells(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The closed components of a watertight ``mesh`` (face adjacency), each outward wound with
    positive volume; empty when there is only one or when any encloses no volume (a cavity's
    inverted shell: the components are not separate solids then)."""
    groups = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)))
    if len(groups) < 2:
        return []
    shells = []
    for faces in groups:
        shell = trimesh.Trimesh(mesh.vertices, mesh.faces[np.sort(faces)], process=False)
        shell.remove_unreferenced_vertices()
        if not (shell.is_watertight and shell.volume > 0):
            return []
        shells.append(shell)
    return sorted(shells, key=lambda s: tuple(np.round(s.bounds[0], 12)))


def separate_at_shared_edges(mesh: trimesh.Trimesh, report: Cleaning) -> trimesh.Trimesh | None:
    """A closed surface that is not a manifold only because closed shells share an edge (convex
    parts written as one file, touching along an edge once their vertices are merged: pybullet_data
    random_urdfs 037 and 121) as those shells, each with its own vertices; None when ``mesh`` has
    an open edge or its pieces are not closed.

    Faces are connected across edges used by exactly two faces only, so the shells come apart at
    the edges they share (used by four or more).
    """
    edges = np.asarray(mesh.edges_sorted)
    _, edge_id, uses = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    if np.any(uses % 2) or not np.any(uses > 2):
        return None
    edge_id = edge_id.reshape(-1)
    face_of_edge = np.repeat(np.arange(len(mesh.faces)), 3)
    twice = np.flatnonzero(uses[edge_id] == 2)
    order = twice[np.argsort(edge_id[twice], kind="stable")]
    pairs = face_of_edge[order].reshape(-1, 2)
    groups = trimesh.graph.connected_components(pairs, nodes=np.arange(len(mesh.faces)))
    pieces = []
    for faces in groups:
        piece = trimesh.Trimesh(mesh.vertices, mesh.faces[np.sort(faces)], process=False)
        piece.remove_unreferenced_vertices()
        if not (piece.is_watertight and piece.is_winding_consistent):
            return None
        with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by a flat one's 0
            volume = piece.volume
        if abs(volume) <= FLAT_VOLUME:  # a closed but flat piece (a double-sided sheet): no solid
            report.flat_pieces += 1
            continue
        pieces.append(piece)
    if not pieces:
        return None
    report.shared_edges = int(np.sum(uses > 2))
    # trimesh annotates concatenate as any Geometry; of Trimeshes it makes a Trimesh
    return cast(trimesh.Trimesh, trimesh.util.concatenate(pieces))


def overlapping(shells: list[trimesh.Trimesh], tolerance: float = 1e-9) -> bool:
    """Whether any two shells' bounding boxes meet (touch or overlap, within ``tolerance`` m)."""
    lo = np.array([s.bounds[0] for s in shells]) - tolerance
    hi = np.array([s.bounds[1] for s in shells]) + tolerance
    meet = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]), axis=2)
    return bool(np.triu(meet, k=1).any())


def join(shells: list[trimesh.Trimesh], name: str) -> trimesh.Trimesh:
    """The union of closed shells that touch or overlap (manifold3d, a maintained boolean library):
    the surface of the solid they make, without the faces inside it."""
    import manifold3d

    solids = []
    for shell in shells:
        mesh = manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(shell.vertices, dtype=np.float64),
            tri_verts=np.ascontiguousarray(shell.faces, dtype=np.uint64),
        )
        mesh.merge()
        solids.append(manifold3d.Manifold(mesh))
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    out = union.to_mesh64()
    # copies that own their memory: a view into manifold3d's buffers keeps its Mesh64 alive as long
    # as the mesh lives (a worker's kept objects at exit: "nanobind: leaked N instances!")
    vertices = np.array(out.vert_properties, dtype=np.float64, copy=True)[:, :3].copy()
    faces = np.array(out.tri_verts, dtype=np.int64, copy=True)
    del out, union, solids, mesh
    joined = trimesh.Trimesh(vertices, faces, process=False)
    if not (len(joined.faces) and joined.is_watertight and joined.volume > 0):
        raise ObjectError(f"{name}: its overlapping closed shells could not be joined into one solid")
    return joined


def simplify(mesh: trimesh.Trimesh, max_faces: int, report: Cleaning) -> trimesh.Trimesh:
    """Quadric decimation to ``max_faces`` (fast-simplification) when ``mesh`` has more faces
    (``report.simplified_to`` says to how many)."""
    if len(mesh.faces) <= max_faces:
        return mesh
    import fast_simplification

    v, f = fast_simplification.simplify(
        np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(mesh.faces, dtype=np.int32),
        target_count=max_faces,
    )
    out = trimesh.Trimesh(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64), process=False)
    report.simplified_to = len(out.faces)
    return out
