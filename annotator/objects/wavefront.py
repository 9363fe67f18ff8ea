"""The separate bodies of a Wavefront .obj: its named ``o`` objects, or ``g`` groups that are bodies.

An .obj exported from a scene holds one ``o`` statement per object (Blender) or one ``g`` group per
object (exporters without ``o``). Explicit statements decide, never connectivity (a bowl's nested
shells are one body):

- two or more ``o`` objects with faces: one body each (a name that recurs continues its object);
- otherwise two or more ``g`` groups with faces that share no vertex: one body each. Groups that
  share vertices split one surface (by material or smoothing) and stay one body.

Discovery needs only the names: the statements are found with a compiled regex over the mapped
file (C speed, no parsing of numbers), and face indices are parsed only for a file with several
``g`` groups and no ``o``. Loading a part hands trimesh the file without the other parts' faces.
"""

from __future__ import annotations

import io
import mmap
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from annotator.objects.errors import ObjectError

_STATEMENT = re.compile(rb"^[ \t]*([og])(?:[ \t]+([^\r\n]*))?[ \t]*\r?$", re.MULTILINE)
_FACE = re.compile(rb"^[ \t]*f[ \t]", re.MULTILINE)
_FACE_LINE = re.compile(rb"^[ \t]*f[ \t][^\n]*\n?", re.MULTILINE)
_VERTEX = re.compile(rb"^[ \t]*v[ \t]", re.MULTILINE)
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


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")


def _segments(data: bytes | mmap.mmap) -> list[tuple[str, str | None, str | None, int, int]]:
    """(kind, current o name, current g name, start, end) of each stretch between statements that
    holds faces. Faces before any statement belong to no object and no group (names None)."""
    out = []
    obj = grp = None
    kind = ""
    start = 0
    for m in _STATEMENT.finditer(data):
        if _FACE.search(data, start, m.start()):
            out.append((kind, obj, grp, start, m.start()))
        name = (m.group(2) or b"").decode("utf-8", "replace").strip()
        kind = m.group(1).decode()
        if kind == "o":
            obj, grp = name, None
        else:
            grp = name
        start = m.end()
    if _FACE.search(data, start, len(data)):
        out.append((kind, obj, grp, start, len(data)))
    return out


def _group_by(segments, key: int, kind: str) -> list[tuple[str, list[tuple[int, int]]]]:
    """Segments gathered by their o (key 1) or g (key 2) name, in order of first appearance."""
    order: dict[str | None, list[tuple[int, int]]] = {}
    for seg in segments:
        order.setdefault(seg[key], []).append((seg[3], seg[4]))
    return [("" if name is None else name, spans) for name, spans in order.items()]


def _vertex_sets(data: bytes | mmap.mmap, groups) -> list[np.ndarray] | None:
    """The vertex indices (0-based) each group's faces use; None when a face uses a relative
    (negative) index, which would need every vertex line's position."""
    out = []
    for _, spans in groups:
        idx = []
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


def parts(path: Path) -> list[ObjPart]:
    """The file's bodies when it holds several (empty: one body). Reads no vertex coordinates."""
    with path.open("rb") as fh:
        if path.stat().st_size == 0:
            return []
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
            segments = _segments(data)
            by_object = _group_by([s for s in segments if s[1] is not None], 1, "o")
            if len(by_object) > 1:
                chosen, kind = _group_by(segments, 1, "o"), "o"
            else:
                by_group = _group_by(segments, 2, "g")
                if len(by_object) == 1 or len(by_group) < 2:  # one object, or no groups to split
                    return []
                sets = _vertex_sets(data, by_group)
                if sets is None or not _disjoint(sets):
                    return []
                chosen, kind = by_group, "g"
    names = [_safe(name) for name, _ in chosen]
    if any(not n for n in names) or len(set(names)) != len(names):
        names = [f"{kind}{i}" for i in range(len(chosen))]
    return [
        ObjPart(i, n, kind, tuple(spans)) for i, (n, (_, spans)) in enumerate(zip(names, chosen, strict=True))
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
