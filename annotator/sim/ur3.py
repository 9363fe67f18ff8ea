"""UR3 kinematics (standard DH) and name lookups of a loaded body's joints and links.

DH parameters: ros-industrial/universal_robot ``ur_description/config/ur3/physical_parameters.yaml``
and UR's article "DH parameters for calculations of kinematics and dynamics" (UR3, CB3).
Frames: ``dh_forward_kinematics`` returns ``T_base_tool0`` in UR's DH base frame (the URDF link
``base``); the URDF root ``base_link`` is the ROS-Industrial frame, ``T_BASELINK_BASE`` = Rz(pi).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pybullet as p

log = logging.getLogger(__name__)

JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
BASE_LINK = "base_link"  # ROS-Industrial root frame of the URDF
DH_BASE_LINK = "base"  # UR's DH base frame, a fixed child of base_link
TOOL0_LINK = "tool0"  # the flange, +z out of the flange (DH frame {6})

# Standard DH, metres and radians (sources in the module docstring).
DH_D1 = 0.1519
DH_A2 = -0.24365
DH_A3 = -0.21325
DH_D4 = 0.11235
DH_D5 = 0.08535
DH_D6 = 0.0819
DH_D: tuple[float, ...] = (DH_D1, 0.0, 0.0, DH_D4, DH_D5, DH_D6)
DH_A: tuple[float, ...] = (0.0, DH_A2, DH_A3, 0.0, 0.0, 0.0)
DH_ALPHA: tuple[float, ...] = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)

# T_baselink_base: the ROS-Industrial base_link is UR's DH base turned by pi about z.
T_BASELINK_BASE: np.ndarray = np.array(
    [[-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def dh_transform(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """(4, 4) standard DH link transform Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def dh_forward_kinematics(q: np.ndarray) -> np.ndarray:
    """``T_base_tool0`` : (4, 4) float, the flange pose in UR's DH base frame.

    ``q`` : (6,) float, joint angles in radians in ``JOINT_NAMES`` order.
    """
    q = np.asarray(q, dtype=np.float64).reshape(6)
    t = np.eye(4)
    for i in range(6):
        t = t @ dh_transform(float(q[i]), DH_D[i], DH_A[i], DH_ALPHA[i])
    return t


def joint_indices_by_name(client: int, body: int) -> dict[str, int]:
    """Joint name -> joint index of ``body`` in the PyBullet world ``client`` (all joints)."""
    n = p.getNumJoints(body, physicsClientId=client)
    return {p.getJointInfo(body, j, physicsClientId=client)[1].decode(): j for j in range(n)}


def link_indices_by_name(client: int, body: int) -> dict[str, int]:
    """Link name -> link index of ``body``; the root link maps to -1 (PyBullet's base index)."""
    n = p.getNumJoints(body, physicsClientId=client)
    root = p.getBodyInfo(body, physicsClientId=client)[0].decode()
    out = {root: -1}
    for j in range(n):
        out[p.getJointInfo(body, j, physicsClientId=client)[12].decode()] = j
    return out


def arm_joint_indices(client: int, body: int, prefix: str = "") -> tuple[int, ...]:
    """Indices of the six arm joints of ``body`` in ``JOINT_NAMES`` order.

    Raises ``KeyError`` naming the missing joint when the body is not a UR3.
    """
    by_name = joint_indices_by_name(client, body)
    missing = [f"{prefix}{n}" for n in JOINT_NAMES if f"{prefix}{n}" not in by_name]
    if missing:
        raise KeyError(f"body {body} has no joint(s) {missing}")
    return tuple(by_name[f"{prefix}{n}"] for n in JOINT_NAMES)


def set_arm_configuration(client: int, body: int, q: np.ndarray, prefix: str = "") -> None:
    """Reset the six arm joints of ``body`` to ``q`` : (6,) rad (teleport, zero velocity)."""
    q = np.asarray(q, dtype=np.float64).reshape(6)
    for j, angle in zip(arm_joint_indices(client, body, prefix), q, strict=True):
        p.resetJointState(body, j, float(angle), 0.0, physicsClientId=client)
    log.debug("body %d arm set to %s", body, q)


def link_pose_matrix(client: int, body: int, link: int) -> np.ndarray:
    """(4, 4) world pose of the URDF frame of ``link`` (-1: the root) with fresh forward kinematics."""
    if link == -1:
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=client)
        # the root's URDF frame differs from its inertial frame by the inertial origin
        local_pos, local_quat = p.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
        inv_pos, inv_quat = p.invertTransform(local_pos, local_quat)
        pos, quat = p.multiplyTransforms(pos, quat, inv_pos, inv_quat)
    else:
        state = p.getLinkState(body, link, computeForwardKinematics=1, physicsClientId=client)
        pos, quat = state[4], state[5]
    t = np.eye(4)
    t[:3, :3] = np.asarray(p.getMatrixFromQuaternion(quat), dtype=np.float64).reshape(3, 3)
    t[:3, 3] = pos
    return t
