"""A small reader for binary glTF (.glb): the scene's bodies (mesh nodes), read one by one.

Discovery needs each body's name without reading geometry (cheap on folders of thousands of
files: only the JSON chunk is parsed); loading needs one body's triangles in the file's frame.
Supported: triangle primitives (mode 4) with float POSITION and optional unsigned indices, in the
binary chunk; other features (Draco, sparse accessors, external buffers) are a one-line error.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
import trimesh

from annotator.objects.errors import ObjectError
from annotator.objects.parts import touching_groups

GLB_MAGIC = b"glTF"
_COMPONENTS = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC3": 3}


@dataclass(frozen=True)
class GlbNode:
    """A body of the scene: its first mesh node's ``index`` in ``nodes``, its part ``name``, and
    the mesh nodes it is made of (``members``: nodes whose bounding boxes meet are one body)."""

    index: int
    name: str
    members: tuple[int, ...] = ()


def _chunks(path: Path, with_binary: bool) -> tuple[dict, bytes]:
    data = path.read_bytes() if with_binary else path.open("rb").read(1 << 20)
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise ObjectError(f"not a GLB file (no glTF header): {path.name}")
    length, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON":
        raise ObjectError(f"not a GLB file (first chunk is not JSON): {path.name}")
    if not with_binary and 20 + length > len(data):
        data = path.read_bytes()
    try:
        doc = json.loads(data[20 : 20 + length].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ObjectError(f"GLB file with a broken JSON chunk: {path.name} ({exc})") from None
    binary = b""
    start = 20 + length + (-length % 4)
    if with_binary and start + 8 <= len(data):
        blen, bkind = struct.unpack_from("<I4s", data, start)
        if bkind == b"BIN\x00":
            binary = data[start + 8 : start + 8 + blen]
    if not isinstance(doc, dict):
        raise ObjectError(f"GLB file with a broken JSON chunk: {path.name}")
    return doc, binary


def _scene_nodes(doc: dict) -> list[tuple[int, np.ndarray]]:
    """(node index, T_file_node (4, 4)) of every node reachable from the default scene, depth first."""
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes") or [{"nodes": list(range(len(nodes)))}]
    roots = scenes[int(doc.get("scene", 0))].get("nodes", [])
    out: list[tuple[int, np.ndarray]] = []
    stack = [(int(i), np.eye(4)) for i in reversed(roots)]
    seen: set[int] = set()
    while stack:
        i, T_parent = stack.pop()
        if i in seen or not 0 <= i < len(nodes):
            continue
        seen.add(i)
        node = nodes[i]
        T = T_parent @ _local_matrix(node)
        out.append((i, T))
        stack.extend((int(c), T) for c in reversed(node.get("children", [])))
    return out


def _local_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    T = np.eye(4)
    if "rotation" in node:
        x, y, z, w = node["rotation"]
        T = trimesh.transformations.quaternion_matrix([w, x, y, z])
    if "scale" in node:
        T = T @ np.diag([*node["scale"], 1.0])
    if "translation" in node:
        T[:3, 3] = node["translation"]
    return T


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")


def mesh_nodes(path: Path) -> list[GlbNode]:
    """The scene's bodies, in scene order, named for use in object ids: its mesh nodes, those
    whose bounding boxes meet (the accessors' min/max, in the file's frame) joined into one body
    (:mod:`annotator.objects.parts`).

    A node's name (made file-name safe) when every body's first node has a distinct non-empty one,
    otherwise ``node<index>`` for all of them.
    """
    doc, _ = _chunks(path, with_binary=False)
    nodes = doc.get("nodes", [])
    found = [(i, T) for i, T in _scene_nodes(doc) if "mesh" in nodes[i]]
    boxes = [_node_bounds(doc, nodes[i], T) for i, T in found]
    known = [b for b in boxes if b is not None]
    if len(found) > 1 and len(known) == len(boxes):
        groups = touching_groups(known)
    else:
        groups = [[k] for k in range(len(found))]
    firsts = [found[g[0]][0] for g in groups]
    names = [_safe(str(nodes[i].get("name", ""))) for i in firsts]
    if any(not n for n in names) or len(set(names)) != len(names):
        names = [f"node{i}" for i in firsts]
    return [
        GlbNode(first, name, tuple(found[k][0] for k in g))
        for first, name, g in zip(firsts, names, groups, strict=True)
    ]


def _node_bounds(doc: dict, node: dict, T: np.ndarray) -> np.ndarray | None:
    """Bounding box (2, 3) in the file's frame of a mesh node, from its POSITION accessors' min and
    max (required by glTF); None when they are missing or malformed."""
    corners = []
    try:
        for prim in doc["meshes"][node["mesh"]].get("primitives", []):
            acc = doc["accessors"][prim["attributes"]["POSITION"]]
            lo, hi = np.asarray(acc["min"], dtype=np.float64), np.asarray(acc["max"], dtype=np.float64)
            box = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
            corners.append(box @ T[:3, :3].T + T[:3, 3])
    except (KeyError, IndexError, TypeError, ValueError):
        return None
    if not corners:
        return None
    pts = np.vstack(corners)
    return np.array([pts.min(axis=0), pts.max(axis=0)])


def body_members(path: Path, index: int) -> list[int]:
    """The mesh nodes of the body whose first node is ``index`` (as :func:`mesh_nodes` lists it)."""
    for body in mesh_nodes(path):
        if body.index == index:
            return list(body.members)
    raise ObjectError(f"{path.name}: the file no longer holds body {index} (it was listed with more)")


def _accessor(doc: dict, binary: bytes, index: int, path: Path) -> np.ndarray:
    acc = doc["accessors"][index]
    if "sparse" in acc or "bufferView" not in acc:
        raise ObjectError(f"{path.name}: unsupported glTF accessor (sparse or without data)")
    view = doc["bufferViews"][acc["bufferView"]]
    if int(view.get("buffer", 0)) != 0:
        raise ObjectError(f"{path.name}: unsupported glTF feature (external buffer)")
    dtype = np.dtype(_COMPONENTS[acc["componentType"]]).newbyteorder("<")
    width = _WIDTH[acc["type"]]
    count = int(acc["count"])
    offset = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    stride = int(view.get("byteStride", 0)) or dtype.itemsize * width
    end = offset + stride * (count - 1) + dtype.itemsize * width
    if count < 1 or end > len(binary):
        raise ObjectError(f"{path.name}: truncated GLB (an accessor runs past the binary chunk)")
    rows = np.lib.stride_tricks.as_strided(
        np.frombuffer(binary, dtype=np.uint8, count=end - offset, offset=offset),
        shape=(count, dtype.itemsize * width),
        strides=(stride, 1),
    )
    return (
        np.ascontiguousarray(rows)
        .view(dtype)
        .reshape(count, width)
        .astype(np.float64 if width == 3 else np.int64)
    )


def read_nodes(path: Path, node_indices: list[int] | None = None) -> trimesh.Trimesh:
    """The triangles of the given mesh nodes (all mesh nodes if None) in the file's frame.

    Raises ObjectError for a file that is not a GLB this reader supports.
    """
    doc, binary = _chunks(path, with_binary=True)
    nodes = doc.get("nodes", [])
    pieces = []
    try:
        for i, T in _scene_nodes(doc):
            if "mesh" not in nodes[i] or (node_indices is not None and i not in node_indices):
                continue
            for prim in doc["meshes"][nodes[i]["mesh"]].get("primitives", []):
                if int(prim.get("mode", 4)) != 4:
                    raise ObjectError(f"{path.name}: unsupported glTF primitive mode {prim.get('mode')}")
                if "extensions" in prim:
                    raise ObjectError(f"{path.name}: unsupported glTF extension {sorted(prim['extensions'])}")
                v = _accessor(doc, binary, prim["attributes"]["POSITION"], path)
                f = (
                    _accessor(doc, binary, prim["indices"], path).reshape(-1, 3)
                    if "indices" in prim
                    else np.arange(len(v)).reshape(-1, 3)
                )
                if f.size and (f.min() < 0 or f.max() >= len(v)):
                    raise ObjectError(f"{path.name}: glTF indices out of range")
                v = v @ T[:3, :3].T + T[:3, 3]
                pieces.append(trimesh.Trimesh(v, f, process=False))
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        if isinstance(exc, ObjectError):
            raise
        raise ObjectError(f"{path.name}: malformed glTF ({type(exc).__name__}: {exc})") from None
    if not pieces:
        raise ObjectError(f"not a mesh (no triangles found): {path.name}")
    return cast(trimesh.Trimesh, trimesh.util.concatenate(pieces)) if len(pieces) > 1 else pieces[0]
