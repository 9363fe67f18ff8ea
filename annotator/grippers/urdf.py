"""What a gripper's URDF says, read as XML (no physics): links, joints, ``<mimic>`` tags, boxes.

PyBullet ignores ``<mimic>`` (bullet3 #1140), so the coupling of a gripper's joints is read here
from the file and enforced by :class:`annotator.sim.gripper.ParallelGripper`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# A gripper's URDF is a few kilobytes of links and joints (the shipped ones: 3-9 kB): these bound
# what the reader accepts, so a hostile or broken file is one line, never a traceback or a
# process holding gigabytes.
MAX_URDF_BYTES = 4 * 1024 * 1024
MAX_URDF_DEPTH = 32  # <robot><link><collision><geometry><mesh/>: a URDF nests 5 deep


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
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    lower: float = 0.0  # <limit lower> (rad or m); 0 when not given
    upper: float = 0.0

    @property
    def movable(self) -> bool:
        return self.kind in ("revolute", "prismatic", "continuous")

    def T_parent_child(self) -> np.ndarray:
        """(4, 4) the child link frame in the parent link frame at joint position 0."""
        T = np.eye(4)
        T[:3, :3] = rpy_matrix(self.rpy)
        T[:3, 3] = self.xyz
        return T

    def T_motion(self, q: float) -> np.ndarray:
        """(4, 4) the child frame moved by joint position ``q`` (rad or m) along :attr:`axis`."""
        T = np.eye(4)
        if q == 0.0 or not self.movable:
            return T
        axis = np.asarray(self.axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        if self.kind == "prismatic":
            T[:3, 3] = axis * q
            return T
        x, y, z = axis
        K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        T[:3, :3] = np.eye(3) + math.sin(q) * K + (1.0 - math.cos(q)) * (K @ K)
        return T


@dataclass(frozen=True)
class Inertial:
    """A link's ``<inertial>`` as written: ``mass`` (kg), the inertia tensor's ``ixx ixy ixz iyy
    iyz izz`` (kg m², about the centre of mass, in the inertial frame) and that frame's origin in
    the link frame (``xyz`` m, ``rpy`` rad). Read as numbers, not judged: ``nan`` and ``inf`` are
    kept for :func:`annotator.grippers.inertials.inertial_problem` to name."""

    mass: float
    inertia: tuple[float, float, float, float, float, float]
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


@dataclass(frozen=True)
class UrdfModel:
    """A URDF's tree: ``links`` (names, document order), ``joints`` by name (document order), the
    mesh files it references (as written), the links that have ``<collision>`` elements and those
    whose first collision geometry is a box; ``collision_meshes``: each link's collision meshes as
    ``(filename as written, (sx, sy, sz) scale)``."""

    path: Path
    robot: str
    links: tuple[str, ...]
    joints: dict[str, UrdfJoint]
    meshes: tuple[str, ...]
    colliding: frozenset[str]
    boxes: frozenset[str]
    collision_meshes: dict[str, tuple[tuple[str, tuple[float, float, float]], ...]] = field(
        default_factory=dict
    )
    box_sizes: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    inertials: dict[str, Inertial] = field(default_factory=dict)  # links that have one

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

    def T_root_link(self, link: str, q: dict[str, float] | None = None) -> np.ndarray:
        """(4, 4) ``link``'s frame in the root link's frame with the joints at ``q`` (by name,
        rad or m; a joint not named, or ``q`` None: at 0). Forward kinematics from the file, no
        physics."""
        T = np.eye(4)
        q = q or {}
        for name in reversed(self.joints_to(link)):
            joint = self.joints[name]
            T = T @ joint.T_parent_child() @ joint.T_motion(q.get(name, 0.0))
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
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise ValueError(f"expected {n} finite numbers, got {text!r}")
    return values


def _vec3(text: str | None, default: float = 0.0) -> tuple[float, float, float]:
    """Three finite numbers from ``text`` ((default,) * 3 when None); ValueError otherwise."""
    x, y, z = _floats(text, 3, default)
    return (x, y, z)


def _scalar(text: str | None) -> float:
    """One finite number from ``text`` (0.0 when None); ValueError otherwise."""
    return _floats(text, 1)[0]


def _link_of(joint: ET.Element, tag: str) -> str:
    """The ``link`` attribute of the joint's ``<parent>`` or ``<child>``; KeyError when either is
    missing."""
    element = joint.find(tag)
    if element is None:
        raise KeyError(f"no <{tag}>")
    return element.attrib["link"]


def read_urdf(path: Path | str) -> UrdfModel:
    """Parse ``path``; ValueError (one line) when it is not a URDF this reader understands or is
    larger than :data:`MAX_URDF_BYTES` (checked before it is read)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_URDF_BYTES:
            raise ValueError(
                f"{path.name} is {size:,} bytes, over the {MAX_URDF_BYTES:,} a gripper's URDF may have"
            )
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read {path.name}: {exc.strerror or exc}") from exc
    return read_urdf_bytes(data, path)


def parse_xml(data: bytes, name: str) -> ET.Element:
    """The root element of ``data``, parsed incrementally with limits: no DOCTYPE or ENTITY
    declaration, elements at most :data:`MAX_URDF_DEPTH` deep. ValueError (one line) otherwise."""
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ValueError(f"{name}: a DOCTYPE or ENTITY declaration is not accepted in a gripper's URDF")
    parser: ET.XMLPullParser[ET.Element] = ET.XMLPullParser(events=("start", "end"))
    root: ET.Element | None = None
    depth = 0
    step = 1 << 16
    try:
        for start in range(0, max(len(data), 1), step):
            parser.feed(data[start : start + step])
            for event in parser.read_events():
                element = event[-1]
                if not isinstance(element, ET.Element):
                    continue  # a namespace event: only starts and ends were asked for
                if event[0] == "start":
                    depth += 1
                    root = element if root is None else root
                    if depth > MAX_URDF_DEPTH:
                        raise ValueError(
                            f"{name}: elements nested more than {MAX_URDF_DEPTH} deep: not a URDF"
                        )
                else:
                    depth -= 1
        parser.close()
    except ET.ParseError as exc:
        raise ValueError(f"cannot read {name}: {exc}") from None
    if root is None:
        raise ValueError(f"cannot read {name}: no element")
    return root


def read_urdf_bytes(data: bytes, path: Path | str) -> UrdfModel:
    """Parse a URDF's bytes (``path``: where it was read, for messages and relative meshes)."""
    path = Path(path)
    root = parse_xml(data, path.name)
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
        joint = _read_joint(el, path.name)
        joints[joint.name] = joint
    meshes = tuple(m.attrib.get("filename", "") for m in root.iter("mesh"))
    return UrdfModel(
        path,
        root.attrib.get("name", ""),
        links,
        joints,
        meshes,
        colliding,
        boxes,
        _collision_meshes(root, path.name),
        _box_sizes(root, path.name),
        _inertials(root, path),
    )


def _read_joint(el: ET.Element, where: str) -> UrdfJoint:
    """One ``<joint>`` element; ValueError naming it when it is malformed."""
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
        axis_el, limit = el.find("axis"), el.find("limit")
        axis = (1.0, 0.0, 0.0) if axis_el is None else _vec3(axis_el.attrib.get("xyz"), 1.0)
        if not any(axis):
            raise ValueError("its axis is zero")
        return UrdfJoint(
            name=name,
            kind=el.attrib["type"],
            parent=_link_of(el, "parent"),
            child=_link_of(el, "child"),
            xyz=_vec3(None if origin is None else origin.attrib.get("xyz")),
            rpy=_vec3(None if origin is None else origin.attrib.get("rpy")),
            mimic=mimic,
            axis=axis,
            lower=_scalar(None if limit is None else limit.attrib.get("lower")),
            upper=_scalar(None if limit is None else limit.attrib.get("upper")),
        )
    except (KeyError, AttributeError, ValueError) as exc:
        raise ValueError(f"{where}: joint {name!r} is malformed ({exc})") from exc


def _collision_meshes(
    root: ET.Element, where: str
) -> dict[str, tuple[tuple[str, tuple[float, float, float]], ...]]:
    """Each link's collision meshes: (file name, scale) in document order, links without none left out."""
    collision_meshes: dict[str, tuple[tuple[str, tuple[float, float, float]], ...]] = {}
    for link in root.findall("link"):
        found: list[tuple[str, tuple[float, float, float]]] = []
        for mesh in link.findall("collision/geometry/mesh"):
            try:
                scale = _vec3(mesh.attrib.get("scale"), default=1.0)
            except ValueError as exc:
                name = link.attrib.get("name", "")
                raise ValueError(f"{where}: link {name!r}: mesh scale {exc}") from None
            found.append((mesh.attrib.get("filename", ""), scale))
        if found:
            collision_meshes[link.attrib.get("name", "")] = tuple(found)
    return collision_meshes


def _box_sizes(root: ET.Element, where: str) -> dict[str, tuple[float, float, float]]:
    """Each link's collision box size (m), links without one left out."""
    box_sizes: dict[str, tuple[float, float, float]] = {}
    for link in root.findall("link"):
        box = link.find("collision/geometry/box")
        if box is not None:
            try:
                box_sizes[link.attrib.get("name", "")] = _vec3(box.attrib.get("size"))
            except ValueError as exc:
                name = link.attrib.get("name", "")
                raise ValueError(f"{where}: link {name!r}: box size {exc}") from None
    return box_sizes


def _numbers(text: str | None, n: int, default: float) -> tuple[float, ...]:
    """``n`` numbers from ``text`` as written (``nan`` and ``inf`` kept); ValueError for text
    that is not ``n`` numbers."""
    if text is None:
        return (default,) * n
    values = tuple(float(v) for v in text.split())
    if len(values) != n:
        raise ValueError(f"expected {n} numbers, got {text!r}")
    return values


def _inertials(root: ET.Element, path: Path) -> dict[str, Inertial]:
    """Each link's ``<inertial>`` (:class:`Inertial`); ValueError (one line) for one that is not
    numbers. A link without ``<inertial>`` is left out (PyBullet gives it its own default)."""
    out: dict[str, Inertial] = {}
    for link in root.findall("link"):
        name = link.attrib.get("name", "")
        element = link.find("inertial")
        if element is None:
            continue
        try:
            mass_el, inertia_el, origin = (
                element.find("mass"),
                element.find("inertia"),
                element.find("origin"),
            )
            mass = _numbers(None if mass_el is None else mass_el.attrib.get("value"), 1, 0.0)[0]
            keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
            v = [_numbers(None if inertia_el is None else inertia_el.attrib.get(k), 1, 0.0)[0] for k in keys]
            xyz = _numbers(None if origin is None else origin.attrib.get("xyz"), 3, 0.0)
            rpy = _numbers(None if origin is None else origin.attrib.get("rpy"), 3, 0.0)
        except ValueError as exc:
            raise ValueError(f"{path.name}: link {name!r}: <inertial> is malformed ({exc})") from None
        inertia = (v[0], v[1], v[2], v[3], v[4], v[5])
        out[name] = Inertial(mass, inertia, (xyz[0], xyz[1], xyz[2]), (rpy[0], rpy[1], rpy[2]))
    return out


def read_mimic_table(urdf: Path | str) -> dict[str, Mimic]:
    """Parse the ``<mimic>`` tags of a URDF: follower joint name -> :class:`Mimic` (document order)."""
    return read_urdf(urdf).mimic_table()
