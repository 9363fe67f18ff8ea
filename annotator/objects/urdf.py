"""The parts of an object URDF this package uses: base-link meshes, their scales and origins, and
the ``<inertial>``; every mesh path confined to the objects folder."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from annotator.objects.errors import ObjectError


@dataclass(frozen=True)
class UrdfMesh:
    """One ``<mesh>`` of a URDF link: ``kind`` is ``collision`` or ``visual`` (``-linkN`` for links
    after the first); ``scale`` (3,); ``T_link_geom`` (4, 4) the element's ``<origin>``."""

    kind: str
    path: Path
    filename: str
    scale: np.ndarray
    T_link_geom: np.ndarray


@dataclass(frozen=True)
class UrdfInertial:
    """A link's ``<inertial>``: mass (kg), centre of mass (3,) and inertia (3, 3) about it, both in
    the link frame."""

    mass: float
    center_mass: np.ndarray
    inertia: np.ndarray


def _floats(text: str | None, default: str, n: int, what: str, urdf: Path) -> np.ndarray:
    try:
        values = np.array([float(s) for s in (text or default).split()], dtype=np.float64)
    except ValueError:
        raise ObjectError(f"{urdf.name}: {what} is not numbers: {text!r}") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ObjectError(f"{urdf.name}: {what} must be {n} finite numbers, got {text!r}")
    return values


def _origin(elem: ET.Element | None, urdf: Path) -> np.ndarray:
    T = np.eye(4)
    if elem is not None:
        xyz = _floats(elem.get("xyz"), "0 0 0", 3, "origin xyz", urdf)
        rpy = _floats(elem.get("rpy"), "0 0 0", 3, "origin rpy", urdf)
        T = trimesh.transformations.euler_matrix(rpy[0], rpy[1], rpy[2], axes="sxyz")
        T[:3, 3] = xyz
    return T


def parse_root(urdf: Path) -> ET.Element:
    """The URDF's XML root, or ObjectError naming the file's problem."""
    if not urdf.is_file():
        raise ObjectError(f"file not found: {urdf}")
    if urdf.stat().st_size == 0:
        raise ObjectError(f"empty file: {urdf.name}")
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as exc:
        raise ObjectError(f"{urdf.name}: not a valid URDF (XML error: {exc})") from None
    if root.tag != "robot":
        raise ObjectError(f"{urdf.name}: not a URDF (root element <{root.tag}>, expected <robot>)")
    return root


def resolve_mesh_path(urdf: Path, filename: str, root: Path) -> Path:
    """The file a URDF mesh ``filename`` names, which must lie inside ``root`` (symlinks resolved).

    ``package://`` and ``file://`` prefixes are dropped and the rest is relative to the URDF's
    folder; an absolute path or one that leaves ``root`` is an ObjectError.
    """
    name = filename
    for prefix in ("package://", "file://"):
        name = name.removeprefix(prefix)
    if Path(name).is_absolute():
        raise ObjectError(
            f"{urdf.name}: mesh path {filename!r} is absolute; use a path inside the objects folder"
        )
    resolved = (urdf.parent / name).resolve()
    if not resolved.is_relative_to(root.resolve()):
        raise ObjectError(f"{urdf.name}: mesh path {filename!r} leads outside the objects folder")
    return resolved


def mesh_refs(urdf: Path, root: Path | None = None) -> list[UrdfMesh]:
    """Every ``<mesh>`` of the URDF's links, in document order; paths confined to ``root``
    (default: the URDF's folder)."""
    xml = parse_root(urdf)
    root = root if root is not None else urdf.parent
    refs = []
    for link_index, link in enumerate(xml.iter("link")):
        for kind in ("collision", "visual"):
            for elem in link.iter(kind):
                mesh = elem.find("geometry/mesh")
                if mesh is None or not mesh.get("filename"):
                    continue
                filename = mesh.get("filename", "")
                scale = _floats(mesh.get("scale"), "1 1 1", 3, "mesh scale", urdf)
                if not np.all(scale > 0):
                    raise ObjectError(f"{urdf.name}: mesh scale must be positive, got {mesh.get('scale')!r}")
                tag = kind if link_index == 0 else f"{kind}-link{link_index}"
                path = resolve_mesh_path(urdf, filename, root)
                refs.append(UrdfMesh(tag, path, filename, scale, _origin(elem.find("origin"), urdf)))
    return refs


def base_inertial(urdf: Path) -> UrdfInertial | None:
    """The first link's ``<inertial>`` in the link frame, or None when it has none (or no mass)."""
    xml = parse_root(urdf)
    link = next(iter(xml.iter("link")), None)
    elem = link.find("inertial") if link is not None else None
    mass_elem = elem.find("mass") if elem is not None else None
    if elem is None or mass_elem is None:
        return None
    mass = float(_floats(mass_elem.get("value"), "0", 1, "inertial mass", urdf)[0])
    if not mass > 0:
        return None
    T = _origin(elem.find("origin"), urdf)
    inertia = np.zeros((3, 3))
    node = elem.find("inertia")
    if node is not None:
        names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        v = {n: float(_floats(node.get(n), "0", 1, f"inertia {n}", urdf)[0]) for n in names}
        inertia = np.array(
            [[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]], [v["ixz"], v["iyz"], v["izz"]]]
        )
    R = T[:3, :3]
    return UrdfInertial(mass, T[:3, 3].copy(), R @ inertia @ R.T)
