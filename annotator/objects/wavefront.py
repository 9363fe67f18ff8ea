"""The separate bodies of a Wavefront .obj: its named ``o`` objects, or ``g`` groups that are bodies.

An .obj exported from a scene holds one ``o`` statement per object (Blender) or one ``g`` group per
object (exporters without ``o``). Explicit statements decide, never connectivity (a bowl's nested
shells are one body):

- two or more ``o`` objects with faces: one body each (a name that recurs continues its object);
- otherwise two or more ``g`` groups with faces that share no vertex: one body each. Groups that
  share vertices split one surface (by material or smoothing) and stay one body;
- objects whose bounding boxes meet are one body: bodies of a scene lie apart, while the convex
  parts of one object (a V-HACD file, pybullet_data's teddy) or a handle written as its own
  object touch or overlap.

Discovery stays cheap: the statements are found with a compiled regex over the mapped file (C
speed); vertex coordinates are parsed only for a file with several objects, and face indices only
for one with several ``g`` groups and no ``o``. Loading a part hands trimesh the file without the
other parts' faces.
"""

from __future__ import annotations

import io
import mmap
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from annotator.objects.errors import ObjectError
from annotator.objects.parts import touching_groups

_STATEMENT = re.compile(rb"^[ \t]*([og])(?:[ \t]+([^\r\n]*))?[ \t]*\r?$", re.MULTILINE)
_FACE = re.compile(rb"^[ \t]*f[ \t]", re.MULTILINE)
_FACE_LINE = re.compile(rb"^[ \t]*f[ \t][^\n]*\n?", re.MULTILINE)
_VERTEX_COORDS = re.compile(rb"^[ \t]*v[ \t]+([^\r\n]*)", re.MULTILINE)
_INDEX = re.compile(rb"(?:^|[ \t])(-?\d+)")  # the position index of a face corner (before any '/')
_RELATIVE = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?:^|[ \t/])-\d", re.MULTILINE)
_LINE_KIND = re.compile(rb"^[ \t]*(v|vt|vn|f)[ \t]")


@dataclass(frozen=True)
class ObjPart:
    """One body of a multi-body .obj: ``index`` in the file's parts, ``name`` for the object id,
    the statement ``kind`` (``o`` or ``g``) and the byte ranges (start, end) holding its faces."""

    index: int
    name: str
    kind: str
    spans: tuple[tuple[int, int], ...]


# (kind, current o name, current g name, start, end, holds faces) of a stretch between statements
Segment = tuple[str, str | None, str | None, int, int, bool]
# (name, stretches holding its faces, all its stretches) of an o object or a g group
NamedPart = tuple[str, list[tuple[int, int]], list[tuple[int, int]]]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")


def _segments(data: bytes | mmap.mmap) -> list[Segment]:
    """(kind, current o name, current g name, start, end, holds faces) of each stretch between
    statements. Lines before any statement belong to no object and no group (names None)."""
    out: list[Segment] = []
    obj: str | None = None
    grp: str | None = None
    kind = ""
    start = 0
    for m in _STATEMENT.finditer(data):
        out.append((kind, obj, grp, start, m.start(), bool(_FACE.search(data, start, m.start()))))
        name = (m.group(2) or b"").decode("utf-8", "replace").strip()
        kind = m.group(1).decode()
        if kind == "o":
            obj, grp = name, None
        else:
            grp = name
        start = m.end()
    out.append((kind, obj, grp, start, len(data), bool(_FACE.search(data, start, len(data)))))
    return out


def _group_by(segments: list[Segment], key: Literal[1, 2]) -> list[NamedPart]:
    """(name, stretches holding its faces, all its stretches) per o (key 1) or g (key 2) name
    that has faces, in order of first appearance."""
    faces: dict[str | None, list[tuple[int, int]]] = {}
    every: dict[str | None, list[tuple[int, int]]] = {}
    for seg in segments:
        every.setdefault(seg[key], []).append((seg[3], seg[4]))
        if seg[5]:
            faces.setdefault(seg[key], []).append((seg[3], seg[4]))
    return [("" if name is None else name, spans, every[name]) for name, spans in faces.items()]


def _bounds(data: bytes | mmap.mmap, stretches: list[tuple[int, int]]) -> np.ndarray | None:
    """The bounding box (2, 3) of the vertex lines written in ``stretches``; None if there are none
    (vertices written elsewhere)."""
    rows = [line.split()[:3] for start, end in stretches for line in _VERTEX_COORDS.findall(data, start, end)]
    if not rows:
        return None
    try:
        xyz = np.asarray(rows, dtype=np.float64)
    except ValueError:
        return None
    return np.array([xyz.min(axis=0), xyz.max(axis=0)])


def _vertex_sets(data: bytes | mmap.mmap, groups: list[NamedPart]) -> list[np.ndarray] | None:
    """The vertex indices (0-based) each group's faces use; None when a face uses a relative
    (negative) index, which would need every vertex line's position."""
    out = []
    for _, spans, _ in groups:
        idx: list[int] = []
        for start, end in spans:
            for line in _FACE_LINE.findall(data, start, end):
                idx.extend(int(i) for i in _INDEX.findall(line.split(b"f", 1)[1]))
        arr = np.unique(np.asarray(idx, dtype=np.int64))
        if arr.size and arr.min() < 0:
            return None
        out.append(arr)
    return out


def _disjoint(sets: list[np.ndarray]) -> bool:
    total = sum(len(s) for s in sets)
    return len(np.unique(np.concatenate(sets))) == total if sets else True


def _bodies(data: bytes | mmap.mmap) -> tuple[list[NamedPart], str]:
    """The explicit objects of the file (name, face stretches, all stretches) and their statement
    kind: ``o`` objects if there are two or more with faces, else vertex-disjoint ``g`` groups;
    ([], "") when neither gives two."""
    segments = _segments(data)
    by_object = _group_by([s for s in segments if s[1] is not None], 1)
    if len(by_object) > 1:
        return _group_by(segments, 1), "o"
    by_group = _group_by(segments, 2)
    if len(by_object) == 1 or len(by_group) < 2:  # one object, or no groups to split
        return [], ""
    sets = _vertex_sets(data, by_group)
    if sets is None or not _disjoint(sets):
        return [], ""
    return by_group, "g"


def _names(chosen: list[NamedPart], groups: list[list[int]], kind: str) -> list[str]:
    """A file-safe name per body (its first object's), or ``<kind><index>`` when any is empty or
    two are the same."""
    names = [_safe(chosen[g[0]][0]) for g in groups]
    if any(not n for n in names) or len(set(names)) != len(names):
        return [f"{kind}{g[0]}" for g in groups]
    return names


def parts(path: Path) -> list[ObjPart]:
    """The file's bodies when it holds several (empty: one body).

    Explicit objects (``o``, or vertex-disjoint ``g`` groups) whose bounding boxes meet are one
    body: separate bodies in a file do not interpenetrate, the convex parts of one body (a V-HACD
    file, a mug's handle written as its own object) do. Reads the coordinates of the vertex lines
    only for a file with several objects.
    """
    if path.stat().st_size == 0:
        return []
    with path.open("rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        chosen, kind = _bodies(data)
        boxes = [_bounds(data, every) for _, _, every in chosen]
    if not chosen:
        return []
    known = [b for b in boxes if b is not None]
    groups = [[i] for i in range(len(chosen))] if len(known) < len(boxes) else touching_groups(known)
    if len(groups) < 2:
        return []
    names = _names(chosen, groups, kind)
    return [
        ObjPart(i, name, kind, tuple(sorted(span for k in group for span in chosen[k][1])))
        for i, (name, group) in enumerate(zip(names, groups, strict=True))
    ]


def absolute_indices(data: bytes) -> bytes:
    """``data`` with relative (negative) face indices made absolute.

    A negative index counts back from the last vertex (texture coordinate, normal) defined
    *before the face line*; trimesh's reader counts it from the end of the file, which gives the
    wrong vertices whenever more follow (a multi-object file written object by object). Files
    without negative indices are returned as they are.
    """
    if not _RELATIVE.search(data):
        return data
    counts = {b"v": 0, b"vt": 0, b"vn": 0}
    out = []
    for line in data.splitlines(keepends=True):
        m = _LINE_KIND.match(line)
        if m is None:
            out.append(line)
            continue
        kind = m.group(1)
        if kind != b"f":
            counts[kind] += 1
            out.append(line)
            continue
        corners = []
        for corner in line.split()[1:]:
            refs = corner.split(b"/")
            for k, key in enumerate((b"v", b"vt", b"vn")[: len(refs)]):
                if refs[k].startswith(b"-"):
                    refs[k] = str(counts[key] + 1 + int(refs[k])).encode()
            corners.append(b"/".join(refs))
        out.append(b"f " + b" ".join(corners) + b"\n")
    return b"".join(out)


def read(path: Path, index: int | None = None) -> trimesh.Trimesh:
    """The triangles of the file (``index`` None) or of its part ``index`` of :func:`parts`
    (vertices as written, nothing merged); relative indices resolved as the format defines them.
    Raises ObjectError or whatever trimesh raises for unreadable text."""
    data = path.read_bytes()
    name = path.name
    if index is not None:
        found = parts(path)
        if not 0 <= index < len(found):
            raise ObjectError(f"{name}: the file no longer holds body {index} (it was listed with more)")
        pieces, last = [], 0
        others = sorted(s for p in found if p.index != index for s in p.spans)
        for start, end in others:  # drop the other parts' face lines, keep every other line in place
            pieces.append(data[last:start])
            pieces.append(_FACE_LINE.sub(b"", data[start:end]))
            last = end
        pieces.append(data[last:])
        data = b"".join(pieces)
        name = f"{name} body {found[index].name}"
    loaded = trimesh.load(io.BytesIO(absolute_indices(data)), file_type="obj", force="mesh", process=False)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ObjectError(f"not a mesh (no triangles found): {name}")
    return trimesh.Trimesh(np.asarray(loaded.vertices), np.asarray(loaded.faces), process=False)
