"""Rigid transforms with one convention: quaternions are xyzw (as PyBullet), frames compose left to right.

A transform named ``T_a_b`` maps coordinates in frame ``b`` to frame ``a``, so
``T_world_tcp = T_world_base * T_base_tcp`` and ``p_world = T_world_tcp.apply(p_tcp)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_EPS = 1e-12


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s). ``q`` : (4,) or (n, 4) float, xyzw."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < _EPS):
        raise ValueError("zero-length quaternion")
    return q / n


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices from quaternions. ``q`` : (4,) or (n, 4) xyzw -> (3, 3) or (n, 3, 3)."""
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.stack(
        [
            1 - 2 * (yy + zz),
            2 * (xy - wz),
            2 * (xz + wy),
            2 * (xy + wz),
            1 - 2 * (xx + zz),
            2 * (yz - wx),
            2 * (xz - wy),
            2 * (yz + wx),
            1 - 2 * (xx + yy),
        ],
        axis=-1,
    )
    return m.reshape(m.shape[:-1] + (3, 3))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternion (xyzw, w >= 0) from rotation matrix/matrices. ``R`` : (3, 3) or (n, 3, 3)."""
    R = np.asarray(R, dtype=np.float64)
    single = R.ndim == 2
    R = R.reshape(-1, 3, 3)
    q = np.empty((R.shape[0], 4))
    tr = np.trace(R, axis1=1, axis2=2)
    for i, (m, t) in enumerate(zip(R, tr, strict=True)):
        if t > 0:
            s = 2.0 * np.sqrt(t + 1.0)
            q[i] = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q[i] = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
        elif m[1, 1] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q[i] = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q[i] = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    q = quat_normalize(q)
    q[q[:, 3] < 0] *= -1.0
    return q[0] if single else q


def axis_angle_to_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the unit vector ``axis`` : (3,)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


@dataclass(frozen=True)
class Transform:
    """A rigid transform ``T_a_b``: rotation ``quat`` (4,) xyzw and translation ``pos`` (3,) metres."""

    pos: np.ndarray
    quat: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "pos", np.asarray(self.pos, dtype=np.float64).reshape(3))
        object.__setattr__(self, "quat", quat_normalize(np.asarray(self.quat).reshape(4)))

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    @classmethod
    def from_matrix(cls, T: np.ndarray) -> Transform:
        """From a (4, 4) homogeneous matrix."""
        T = np.asarray(T, dtype=np.float64)
        return cls(T[:3, 3], matrix_to_quat(T[:3, :3]))

    @classmethod
    def from_rotation(cls, R: np.ndarray, pos: np.ndarray | None = None) -> Transform:
        """From a (3, 3) rotation matrix and an optional (3,) translation."""
        return cls(np.zeros(3) if pos is None else pos, matrix_to_quat(R))

    @classmethod
    def from_pybullet(cls, pose: tuple) -> Transform:
        """From PyBullet's ``(position, orientation)`` pair."""
        return cls(np.asarray(pose[0]), np.asarray(pose[1]))

    def to_pybullet(self) -> tuple[list[float], list[float]]:
        return self.pos.tolist(), self.quat.tolist()

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation matrix."""
        return quat_to_matrix(self.quat)

    def as_matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.pos
        return T

    def inverse(self) -> Transform:
        R_t = self.rotation.T
        return Transform.from_rotation(R_t, -R_t @ self.pos)

    def __mul__(self, other: Transform) -> Transform:
        """``T_a_b * T_b_c -> T_a_c``."""
        R = self.rotation
        return Transform.from_rotation(R @ other.rotation, self.pos + R @ other.pos)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map points (3,) or (n, 3) from frame b to frame a."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.rotation.T + self.pos

    def __repr__(self) -> str:
        return f"Transform(pos={np.round(self.pos, 5).tolist()}, quat={np.round(self.quat, 5).tolist()})"
