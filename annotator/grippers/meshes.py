"""A gripper's mesh files checked from their bytes before PyBullet sees them: a format PyBullet's
URDF loader reads (Wavefront ``.obj``, ``.stl`` binary or ASCII), at least one face, and within
the budgets below. What it finds (faces, vertex extents) lets the description compare a pad's
mesh with its stated ``[pads] size``.

The budgets bound a worker's memory: PyBullet holds about 1.7 kB per collision face (a
2-million-face mesh measured 3.5 GB per worker), and a gripper's collision meshes need a few
thousand faces; a finer mesh is for pictures, not for contacts.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MESH_SUFFIXES = (".obj", ".stl")
# every mesh file of a gripper together (bytes), checked by size before any is read
MAX_MESH_BYTES = 64 * 1024 * 1024
# every mesh's faces together (PyBullet: ~1.7 kB each per worker, so ~170 MB at the budget)
MAX_MESH_FACES = 100_000


class MeshError(ValueError):
    """A mesh file PyBullet would not load as a shape, or one over the budget (one line)."""


@dataclass(frozen=True)
class MeshFacts:
    """What a mesh file holds: ``faces`` (count), ``extents`` (3,) of its vertices (file units)."""

    faces: int
    extents: tuple[float, float, float]


def mesh_facts(name: str, data: bytes) -> MeshFacts:
    """Faces and extents of mesh file ``name`` read as ``data``; :class:`MeshError` when it is
    empty, not of its suffix's format, or has no face."""
    suffix = Path(name).suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"{name}: a gripper's mesh must be {' or '.join(MESH_SUFFIXES)} (PyBullet's loaders)")
    if not data:
        raise MeshError(f"{name} is empty")
    facts = _stl(name, data) if suffix == ".stl" else _obj(name, data)
    if facts.faces == 0:
        raise MeshError(f"{name} holds no face: not a {suffix} mesh PyBullet would load")
    return facts


def _extents(points: np.ndarray, name: str) -> tuple[float, float, float]:
    if len(points) == 0 or not np.isfinite(points).all():
        raise MeshError(f"{name}: vertices missing or not finite")
    ext = points.max(axis=0) - points.min(axis=0)
    return (float(ext[0]), float(ext[1]), float(ext[2]))


def _stl(name: str, data: bytes) -> MeshFacts:
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        if 84 + 50 * count == len(data):  # binary: 80-byte header, count, 50 bytes per triangle
            if count == 0:
                return MeshFacts(0, (0.0, 0.0, 0.0))
            records = np.frombuffer(data, dtype=np.uint8, offset=84).reshape(count, 50)
            points = records[:, 12:48].copy().view("<f4").reshape(-1, 3).astype(np.float64)
            return MeshFacts(count, _extents(points, name))
    head = data[:512].lstrip()
    if not head.startswith(b"solid"):
        raise MeshError(f"{name} is neither a binary STL (its size does not match its count) nor ASCII")
    vertices: list[list[float]] = []
    faces = 0
    for line in data.splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == b"vertex" and len(words) == 4:
            try:
                vertices.append([float(w) for w in words[1:]])
            except ValueError:
                raise MeshError(f"{name}: a vertex line is not three numbers") from None
        elif words[0] == b"endfacet":
            faces += 1
    extents = _extents(np.asarray(vertices, dtype=float).reshape(-1, 3), name) if faces else (0.0, 0.0, 0.0)
    return MeshFacts(faces, extents)


def _obj(name: str, data: bytes) -> MeshFacts:
    points = []
    faces = 0
    for line in data.splitlines():
        if line.startswith(b"v "):
            words = line.split()
            try:
                points.append([float(w) for w in words[1:4]])
            except ValueError:
                raise MeshError(f"{name}: a 'v' line is not three numbers") from None
            if len(words) < 4:
                raise MeshError(f"{name}: a 'v' line is not three numbers")
        elif line.startswith(b"f "):
            faces += 1
    if faces and len(points) < 3:
        raise MeshError(f"{name}: faces but fewer than three vertices")
    extents = _extents(np.asarray(points, dtype=float).reshape(-1, 3), name) if faces else (0.0, 0.0, 0.0)
    return MeshFacts(faces, extents)
