"""Rigid bodies in a physics client, by client and body id: the calls every world above the physics
layer makes on a body (its pose and velocity, read and reset; its dynamics, read and changed; a
torque; the bounding box; creating and removing one), and the frame arithmetic PyBullet does on
poses, so that nothing outside :mod:`annotator.sim` calls PyBullet.

Poses are PyBullet's own tuples, ``((x, y, z), (qx, qy, qz, qw))`` of the body's base (its inertial
frame: the centre of mass on the principal axes), in metres and the world frame, as the caller
has always read them: a label computed from them is the same bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from annotator.sim import pb

Vec3 = tuple[float, ...]  # (x, y, z)
Quat = tuple[float, ...]  # (qx, qy, qz, qw)
Pose = tuple[Vec3, Quat]
PoseLike = tuple[Sequence[float], Sequence[float]]

# Collision and visual shape kinds (PyBullet's GEOM_*), by name.
SHAPES = {
    "box": pb.GEOM_BOX,
    "sphere": pb.GEOM_SPHERE,
    "cylinder": pb.GEOM_CYLINDER,
    "capsule": pb.GEOM_CAPSULE,
    "mesh": pb.GEOM_MESH,
}


def pose(client: int, uid: int) -> Pose:
    """The base's pose (world frame)."""
    pos, orn = pb.getBasePositionAndOrientation(uid, physicsClientId=client)
    return pos, orn


def reset_pose(client: int, uid: int, position: Sequence[float], orientation: Sequence[float]) -> None:
    """Put the base at ``position`` (m) and ``orientation`` (xyzw), world frame."""
    pb.resetBasePositionAndOrientation(uid, position, orientation, physicsClientId=client)


def velocity(client: int, uid: int) -> tuple[Vec3, Vec3]:
    """The base's linear (m/s) and angular (rad/s) velocity, world frame."""
    linear, angular = pb.getBaseVelocity(uid, physicsClientId=client)
    return linear, angular


def reset_velocity(client: int, uid: int, linear: Sequence[float], angular: Sequence[float]) -> None:
    pb.resetBaseVelocity(uid, linear, angular, physicsClientId=client)


@dataclass(frozen=True)
class Dynamics:
    """A link's dynamics as PyBullet holds them: ``mass`` (kg), ``lateral_friction``,
    ``inertia`` (3,) the principal moments (kg m^2), the inertial frame in the link frame
    (``inertial_position`` m, ``inertial_orientation`` xyzw), ``restitution``, ``rolling_friction``,
    ``spinning_friction``, ``contact_damping``, ``contact_stiffness``."""

    mass: float
    lateral_friction: float
    inertia: Vec3
    inertial_position: Vec3
    inertial_orientation: Quat
    restitution: float
    rolling_friction: float
    spinning_friction: float
    contact_damping: float
    contact_stiffness: float


def dynamics(client: int, uid: int, link: int = -1) -> Dynamics:
    """The dynamics of ``link`` of ``uid`` (-1: the base)."""
    info = pb.getDynamicsInfo(uid, link, physicsClientId=client)
    return Dynamics(*info[:10])


def change_dynamics(client: int, uid: int, link: int = -1, **params: Any) -> None:
    """Change the dynamics of ``link`` (PyBullet's ``changeDynamics`` keywords: ``mass``,
    ``localInertiaDiagonal``, ``lateralFriction``, ...)."""
    pb.changeDynamics(uid, link, physicsClientId=client, **params)


def apply_torque(client: int, uid: int, torque: Sequence[float], link: int = -1) -> None:
    """A torque (N m, world frame) on ``link`` for the next step."""
    pb.applyExternalTorque(uid, link, list(torque), pb.WORLD_FRAME, physicsClientId=client)


def aabb(client: int, uid: int, link: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned bounding box of ``link`` (world frame, m): its low and high corners."""
    low, high = pb.getAABB(uid, link, physicsClientId=client)
    return np.asarray(low), np.asarray(high)


def remove(client: int, uid: int) -> None:
    pb.removeBody(uid, physicsClientId=client)


def link_pose(client: int, uid: int, link: int) -> Pose:
    """The inertial frame of ``link`` (its forward kinematics computed; -1: the base), world frame."""
    if link == -1:
        return pose(client, uid)
    pos, orn = pb.getLinkState(uid, link, computeForwardKinematics=1, physicsClientId=client)[:2]
    return pos, orn


@dataclass(frozen=True)
class Shape:
    """A link's collision shape: its ``kind`` (:data:`SHAPES`' name), ``dimensions`` (a box's full
    sizes, m; a sphere's radius; a cylinder's length and radius; a mesh's scale), its frame in the
    link's inertial frame, and a mesh's ``file``."""

    kind: str
    dimensions: tuple[float, ...]
    local_position: Vec3
    local_orientation: Quat
    file: str = ""


_SHAPE_NAMES = {code: name for name, code in SHAPES.items()}


def collision_shapes(client: int, uid: int, link: int = -1) -> list[Shape]:
    """The collision shapes of ``link`` of ``uid``."""
    return [
        Shape(
            _SHAPE_NAMES.get(s[2], "other"),
            tuple(s[3]),
            s[5],
            s[6],
            s[4].decode() if isinstance(s[4], bytes) else str(s[4]),
        )
        for s in pb.getCollisionShapeData(uid, link, physicsClientId=client)
    ]


def detect_collisions(client: int) -> None:
    """Update the contact points of every pair for the bodies as posed, without a step."""
    pb.performCollisionDetection(physicsClientId=client)


def multiply(a: PoseLike, b: PoseLike) -> Pose:
    """The pose ``a · b`` as PyBullet composes poses (its floats)."""
    pos, orn = pb.multiplyTransforms(a[0], a[1], b[0], b[1])
    return pos, orn


def invert(a: PoseLike) -> Pose:
    """The inverse of ``a`` as PyBullet inverts it."""
    pos, orn = pb.invertTransform(a[0], a[1])
    return pos, orn


# URDF loading flags, by name.
URDF_FLAGS = {
    "sat_features": pb.URDF_INITIALIZE_SAT_FEATURES,
    "inertia_from_file": pb.URDF_USE_INERTIA_FROM_FILE,
    "self_collision": pb.URDF_USE_SELF_COLLISION,
    "self_collision_exclude_parent": pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT,
}


def collision_shape(client: int, kind: str, **params: Any) -> int:
    """A collision shape of ``kind`` (:data:`SHAPES`; PyBullet's ``createCollisionShape`` keywords:
    ``vertices``, ``fileName``, ``halfExtents``, ``radius``, ...); its id, negative when refused."""
    shape: int = pb.createCollisionShape(SHAPES[kind], physicsClientId=client, **params)
    return shape


def visual_shape(client: int, kind: str, **params: Any) -> int:
    """A visual shape of ``kind`` (:data:`SHAPES`; ``createVisualShape`` keywords)."""
    shape: int = pb.createVisualShape(SHAPES[kind], physicsClientId=client, **params)
    return shape


def multibody(client: int, **params: Any) -> int:
    """A body of shapes (PyBullet's ``createMultiBody`` keywords: ``baseMass``,
    ``baseCollisionShapeIndex``, ``basePosition``, ...); its id."""
    uid: int = pb.createMultiBody(physicsClientId=client, **params)
    return uid


def load_urdf(
    client: int,
    path: str,
    position: Sequence[float] = (0.0, 0.0, 0.0),
    orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
    *,
    flags: Sequence[str] = (),
    **params: Any,
) -> int:
    """The URDF at ``path`` loaded with its base at ``position`` and ``orientation`` and the named
    :data:`URDF_FLAGS`; its body id, negative when refused."""
    bits = 0
    for name in flags:
        bits |= URDF_FLAGS[name]
    uid: int = pb.loadURDF(path, position, orientation, flags=bits, physicsClientId=client, **params)
    return uid
