"""Rigid transforms with one convention: quaternions are xyzw (as PyBullet), frames compose left to right.

A transform named ``T_a_b`` maps coordinates in frame ``b`` to frame ``a``, so
``T_world_tcp = T_world_base * T_base_tcp`` and ``p_world = T_world_tcp.apply(p_tcp)``.
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-12


def connected_groups(adjacent: np.ndarray) -> list[list[int]]:
    """Indices grouped by connectivity: ``adjacent`` (n, n) bool, symmetric, True where two items
    are linked; items linked through a chain share a group. Each group sorted, groups in order of
    their first item."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    _, labels = connected_components(csr_matrix(np.asarray(adjacent, dtype=bool)), directed=False)
    groups: dict[int, list[int]] = {}
    for i, label in enumerate(labels.tolist()):
        groups.setdefault(label, []).append(i)
    return sorted(groups.values(), key=lambda g: g[0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s). ``q`` : (4,) or (n, 4) float, xyzw."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < _EPS):
        raise ValueError("zero-length quaternion")
    return q / n


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices from quaternions. ``q`` : (4,) or (n, 4) xyzw -> (3, 3) or (n, 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 1:  # the per-step case: scalar arithmetic is ~20x faster than the array path
        x, y, z, w = q.tolist()
        n = math.sqrt(x * x + y * y + z * z + w * w)
        if n < _EPS:
            raise ValueError("zero-length quaternion")
        x, y, z, w = x / n, y / n, z / n, w / n
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
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


def canonical_quat(q: np.ndarray) -> np.ndarray:
    """xyzw quaternion(s) ``q`` ((4,) or (n, 4)) with ``w >= 0``: the same rotations (q and -q are
    one), a new array; the labels write their orientations so."""
    q = np.asarray(q, dtype=np.float64)
    return np.where((q[..., 3] < 0)[..., None], -q, q)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternion (xyzw, w >= 0) from rotation matrix/matrices. ``R`` : (3, 3) or (n, 3, 3)."""
    R = np.asarray(R, dtype=np.float64)
    single = R.ndim == 2
    R = R.reshape(-1, 3, 3)
    m00, m01, m02 = R[:, 0, 0], R[:, 0, 1], R[:, 0, 2]
    m10, m11, m12 = R[:, 1, 0], R[:, 1, 1], R[:, 1, 2]
    m20, m21, m22 = R[:, 2, 0], R[:, 2, 1], R[:, 2, 2]
    # four candidate formulas; each row uses the numerically best one (largest pivot)
    t = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], 1)
    s = 2.0 * np.sqrt(np.maximum(t, 1e-300))
    cands = np.stack(
        [
            np.stack([(m21 - m12) / s[:, 0], (m02 - m20) / s[:, 0], (m10 - m01) / s[:, 0], s[:, 0] / 4], 1),
            np.stack([s[:, 1] / 4, (m01 + m10) / s[:, 1], (m02 + m20) / s[:, 1], (m21 - m12) / s[:, 1]], 1),
            np.stack([(m01 + m10) / s[:, 2], s[:, 2] / 4, (m12 + m21) / s[:, 2], (m02 - m20) / s[:, 2]], 1),
            np.stack([(m02 + m20) / s[:, 3], (m12 + m21) / s[:, 3], s[:, 3] / 4, (m10 - m01) / s[:, 3]], 1),
        ],
        1,
    )
    q = cands[np.arange(len(R)), np.argmax(t, axis=1)]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q = canonical_quat(q)
    return q[0] if single else q


def axis_angle_to_matrix(axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rotation by ``angle`` radians about the unit vector ``axis`` : (3,).

    A scalar ``angle`` gives (3, 3); an array of shape (n,) gives (n, 3, 3) (Rodrigues' formula).
    """
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.asarray(angle, dtype=np.float64)[..., None, None]
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * (K @ K)


class Transform:
    """A rigid transform ``T_a_b``: rotation ``quat`` (4,) xyzw and translation ``pos`` (3,) metres.

    Immutable by convention; the rotation matrix is computed once, on first use.
    """

    __slots__ = ("pos", "quat", "_R")

    def __init__(self, pos, quat) -> None:
        p = np.asarray(pos, dtype=np.float64).reshape(3)
        q = np.asarray(quat, dtype=np.float64).reshape(4)
        n = math.sqrt(float(q @ q))
        if n < _EPS:
            raise ValueError("zero-length quaternion")
        self.pos = p
        self.quat = q / n
        self._R: np.ndarray | None = None

    @classmethod
    def _trusted(cls, pos: np.ndarray, quat: np.ndarray, R: np.ndarray | None) -> Transform:
        """Build from already valid float64 arrays (no checks; ``R`` None: computed when first
        asked for): the hot path of ``*``."""
        t = cls.__new__(cls)
        t.pos, t.quat, t._R = pos, quat, R
        return t

    @classmethod
    def exact(cls, pos, quat) -> Transform:
        """From a recorded ``pos`` (3,) and unit ``quat`` (4,) bit for bit (no renormalisation), so
        a pose written out and read back is the very transform that was used."""
        return cls._trusted(
            np.array(pos, dtype=np.float64).reshape(3), np.array(quat, dtype=np.float64).reshape(4), None
        )

    @classmethod
    def identity(cls) -> Transform:
        """The identity transform (no translation, quaternion (0, 0, 0, 1))."""
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
        return cls(pose[0], pose[1])

    def to_pybullet(self) -> tuple[list[float], list[float]]:
        """``(position (3,) list, quaternion xyzw (4,) list)``, as PyBullet takes a pose."""
        return self.pos.tolist(), self.quat.tolist()

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation matrix."""
        if self._R is None:
            self._R = quat_to_matrix(self.quat)
        return self._R

    def as_matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.pos
        return T

    def inverse(self) -> Transform:
        """``T_b_a`` for this ``T_a_b``."""
        x, y, z, w = self.quat
        q_inv = np.array([-x, -y, -z, w])
        R_t = self.rotation.T
        return Transform._trusted(-(R_t @ self.pos), q_inv, R_t)

    def __mul__(self, other: Transform) -> Transform:
        """``T_a_b * T_b_c -> T_a_c``."""
        x1, y1, z1, w1 = self.quat
        x2, y2, z2, w2 = other.quat
        q = np.array(
            [
                w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            ]
        )
        R = self.rotation
        return Transform._trusted(self.pos + R @ other.pos, q, R @ other.rotation)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map points (3,) or (n, 3) from frame b to frame a."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.rotation.T + self.pos

    def __repr__(self) -> str:
        return f"Transform(pos={np.round(self.pos, 5).tolist()}, quat={np.round(self.quat, 5).tolist()})"
