"""The memory an object will take to load, estimated from its face count before it is read.

A worker checks the estimate against ``ObjectConfig.memory_budget`` before it parses a vertex: an
object above it fails with its estimate in its one-line reason, instead of the worker being killed
by the system (which the run can only report as "a worker process died twice").

Face counts come from the file's header where the format has one (binary STL, PLY, OFF, glTF's
accessors) and from a streaming count of face lines otherwise (OBJ, ASCII STL), a URDF's as the
sum of its meshes'. The estimate is piecewise linear in the faces, measured by ``bench/memory.py``
(peak RSS of a child process loading spheres of 20 k, 200 k and 2 M faces;
docs/decisions/0102-memory.md).
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

from annotator.config import ObjectConfig
from annotator.objects.discovery import ObjectSource
from annotator.objects.errors import ObjectError

# A load's peak RSS (MB), from bench/memory.py (binary STL UV spheres, the format that costs most
# per face; OBJ cost less: 1,709 MB at 2 M faces): 20,160 faces 243 MB, 202,496 faces 532 MB,
# 1,999,392 faces 2,358 MB. Up to ObjectConfig.max_faces a face costs the whole load (cleaning,
# mass, collision error, decomposition input); above it only reading, cleaning and simplifying.
MB_FIXED = 210.0  # the interpreter with trimesh, SciPy and PyBullet, and small arrays
MB_PER_FACE = 0.0017
MB_PER_FACE_ABOVE = 0.00102
_CHUNK = 1 << 24  # bytes read at a time when counting lines
_PLY_FACES = re.compile(rb"^element\s+face\s+(\d+)", re.MULTILINE)


def _count(path: Path, needle: bytes) -> int:
    """Occurrences of ``needle`` in the file, read in chunks (bounded memory)."""
    count, tail = 0, b""
    with path.open("rb") as fh:
        while chunk := fh.read(_CHUNK):
            data = tail + chunk
            count += data.count(needle)
            tail = data[-(len(needle) - 1) :] if len(needle) > 1 else b""
    return count


def _stl_faces(path: Path) -> int:
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(84)
    if len(head) == 84:
        n = struct.unpack_from("<I", head, 80)[0]
        if size == 84 + 50 * n:
            return n
    return _count(path, b"endfacet")


def _obj_faces(path: Path) -> int:
    with path.open("rb") as fh:
        first = fh.read(2)
    return _count(path, b"\nf ") + _count(path, b"\nf\t") + int(first in (b"f ", b"f\t"))


def _ply_faces(path: Path) -> int:
    with path.open("rb") as fh:
        head = fh.read(65536)
    m = _PLY_FACES.search(head.split(b"end_header", 1)[0])
    return int(m.group(1)) if m else 0


def _off_faces(path: Path) -> int:
    with path.open("rb") as fh:
        words = []
        for line in fh:
            line = line.split(b"#", 1)[0].strip()
            if not line:
                continue
            words += line.split()
            if words and words[0].upper().lstrip(b"CNST4").startswith(b"OFF"):
                words = words[1:]
            if len(words) >= 2:
                return int(words[1])
    return 0


def _glb_faces(path: Path) -> int:
    with path.open("rb") as fh:
        head = fh.read(20)
        if len(head) < 20:
            return 0
        length = struct.unpack_from("<I", head, 12)[0]
        doc = json.loads(fh.read(length).decode("utf-8"))
    accessors = doc.get("accessors", [])
    total = 0
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            index = prim.get("indices", prim.get("attributes", {}).get("POSITION"))
            if isinstance(index, int) and 0 <= index < len(accessors):
                total += int(accessors[index].get("count", 0)) // 3
    return total


_COUNTERS = {
    ".stl": _stl_faces,
    ".obj": _obj_faces,
    ".ply": _ply_faces,
    ".off": _off_faces,
    ".glb": _glb_faces,
}


def count_faces(path: Path) -> int:
    """Triangles in a mesh file, from its header or a count of its face lines (a polygon line
    counts once; 0 when the file cannot tell: reading it names the problem)."""
    counter = _COUNTERS.get(Path(path).suffix.lower())
    if counter is None:
        return 0
    try:
        return counter(Path(path))
    except (OSError, ValueError, UnicodeDecodeError, struct.error):
        return 0


def estimate_mb(faces: int, max_faces: int = ObjectConfig.max_faces) -> float:
    """Peak MB a process needs to load an object of ``faces`` file faces that is simplified to
    ``max_faces`` (see :data:`MB_PER_FACE`)."""
    return MB_FIXED + MB_PER_FACE * min(faces, max_faces) + MB_PER_FACE_ABOVE * max(0, faces - max_faces)


def check(source: ObjectSource, config: ObjectConfig) -> None:
    """Raise :class:`ObjectError` when ``source`` would need more than
    ``config.memory_budget`` MB to load."""
    if source.is_urdf:
        from annotator.objects import urdf

        try:
            paths = sorted({ref.path for ref in urdf.mesh_refs(source.path, source.folder)})
        except ObjectError:
            return  # reading it names the problem
    else:
        paths = [source.path]
    faces = sum(count_faces(p) for p in paths)
    need = estimate_mb(faces, config.max_faces)
    if need > config.memory_budget:
        raise ObjectError(
            f"{source.object_id}: needs about {need:,.0f} MB to load ({faces:,} faces), above the memory "
            f"budget of {config.memory_budget:,.0f} MB per worker (ObjectConfig.memory_budget)"
        )
