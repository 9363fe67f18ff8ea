"""What a gripper's URDF says, read as XML (no physics): links, joints, ``<mimic>`` tags, boxes.

PyBullet ignores ``<mimic>`` (bullet3 #1140), so the coupling of a gripper's joints is read here
from the file and enforced by :class:`annotator.sim.gripper.ParallelGripper`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Mimic:
    """``follower = multiplier * driven + offset`` as written in the URDF."""

    follower: str
    driven: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>``: its kind, links, origin in the parent link (xyz m, rpy rad) and mimic tag."""

    name: str
    kind: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    mimic: Mimic | None

    @property
    def movable(self) -> bool:
        return self.kind in ("revolute", "prismatic", "continuous")

    def T_parent_child(self) -> np.ndarray:
        """(4, 4) the child link frame in the parent link frame at joint position 0."""
        T = np.eye(4)
        T[:3, :3] = rpy_matrix(self.rpy)
        T[:3, 3] = self.xyz
        return T


@dataclass(frozen=True)
class UrdfModel:
    """A URDF's tree: ``links`` (names, document order), ``joints`` by name (document order), the
    mesh files it references (as written), the links that have ``<collision>`` elements and those
    whose first collision geometry is a box."""

    path: Path
    robot: str
    links: tuple[str, ...]
    joints: dict[str, UrdfJoint]
    meshes: tuple[str, ...]
    colliding: frozenset[str]
    boxes: frozenset[str]

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints.values()}
        roots = [name for name in self.links if name not in children]
        return roots[0]

    def parent_joint(self, link: str) -> UrdfJoint | None:
        """The joint whose child is ``link`` (None for the root)."""
        for joint in self.joints.values():
            if joint.child == link:
                return joint
        return None

    def chain(self, link: str) -> list[str]:
        """Links from ``link`` up to the root, ``link`` first, the root last."""
        out = [link]
        joint = self.parent_joint(link)
        while joint is not None:
            out.append(joint.parent)
            joint = self.parent_joint(joint.parent)
        return out

    def joints_to(self, link: str) -> list[str]:
        """Names of the joints between the root and ``link`` (root side last)."""
        out = []
        joint = self.parent_joint(link)
        while joint is not None:
            out.append(joint.name)
            joint = self.parent_joint(joint.parent)
        return out

    def mimic_table(self) -> dict[str, Mimic]:
        """Follower joint name -> :class:`Mimic`, in document order."""
        return {name: j.mimic for name, j in self.joints.items() if j.mimic is not None}

    def T_root_link(self, link: str) -> np.ndarray:
        """(4, 4) ``link``'s frame in the root link's frame with every joint at 0."""
        T = np.eye(4)
        for name in reversed(self.joints_to(link)):
            T = T @ self.joints[name].T_parent_child()
        return T


def rpy_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """(3, 3) rotation of URDF roll-pitch-yaw (fixed axes x, then y, then z), rad."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _floats(text: str | None, n: int, default: float = 0.0) -> tuple[float, ...]:
    if text is None:
        return (default,) * n
    values = tuple(float(v) for v in text.split())
    if len(values) != n:
        raise ValueError(f"expected {n} numbers, got {text!r}")
    return values


def read_urdf(path: Path | str) -> UrdfModel:
    """Parse ``path``; ValueError (one line) when it is not a URDF this reader understands."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ValueError(f"cannot read {path.name}: {exc}") from exc
    if root.tag != "robot":
        raise ValueError(f"{path.name} is not a URDF (its root element is <{root.tag}>, not <robot>)")
    links = tuple(link.attrib.get("name", "") for link in root.findall("link"))
    colliding = frozenset(
        link.attrib.get("name", "") for link in root.findall("link") if link.find("collision") is not None
    )
    boxes = frozenset(
        link.attrib.get("name", "")
        for link in root.findall("link")
        if link.find("collision/geometry/box") is not None
        and link.find("collision/geometry/*") is link.find("collision/geometry/box")
    )
    joints: dict[str, UrdfJoint] = {}
    for el in root.findall("joint"):
        name = el.attrib.get("name", "")
        try:
            origin = el.find("origin")
            mimic_el = el.find("mimic")
            mimic = None
            if mimic_el is not None:
                mimic = Mimic(
                    follower=name,
                    driven=mimic_el.attrib["joint"],
                    multiplier=float(mimic_el.attrib.get("multiplier", 1.0)),
                    offset=float(mimic_el.attrib.get("offset", 0.0)),
                )
            joints[name] = UrdfJoint(
                name=name,
                kind=el.attrib["type"],
                parent=el.find("parent").attrib["link"],  # type: ignore[union-attr]
                child=el.find("child").attrib["link"],  # type: ignore[union-attr]
                xyz=_floats(None if origin is None else origin.attrib.get("xyz"), 3),  # type: ignore[arg-type]
                rpy=_floats(None if origin is None else origin.attrib.get("rpy"), 3),  # type: ignore[arg-type]
                mimic=mimic,
            )
        except (KeyError, AttributeError, ValueError) as exc:
            raise ValueError(f"{path.name}: joint {name!r} is malformed ({exc})") from exc
    meshes = tuple(m.attrib.get("filename", "") for m in root.iter("mesh"))
    return UrdfModel(path, root.attrib.get("name", ""), links, joints, meshes, colliding, boxes)


def read_mimic_table(urdf: Path | str) -> dict[str, Mimic]:
    """Parse the ``<mimic>`` tags of a URDF: follower joint name -> :class:`Mimic` (document order)."""
    return read_urdf(urdf).mimic_table()
