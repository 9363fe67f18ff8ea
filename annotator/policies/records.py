"""What a clutter-removal policy sees and what it answers, as records.

A *vision* policy (a learner's) is called at every attempt with an :class:`Observation`: what the
cell's Kinect v2 sees of the pile as it is now, and nothing else (no mesh, no object pose, no
segmentation). It answers with :class:`Grasps`: TCP poses in the table frame, the width each
closes from, a score each (higher first). Frames and conventions:

- the *table frame* (annotator/scenes/records.py): origin at the centre of the table top, +z up;
- the TCP frame (docs/frames.md): origin midway between the pads, +x the closing direction, +z
  the approach (from the gripper into the object);
- the TSDF is VGN's grid (annotator/scenes/tsdf.py): ``tsdf[i, j, k]`` is the voxel whose centre
  is ``T_table_volume * ((i, j, k) + 0.5) * voxel_size``, values (tsdf + 1) / 2 near the observed
  surface, 0 elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from annotator.cell.kinect import Intrinsics
from annotator.cell.reach import Reach
from annotator.geometry import Transform, matrix_to_quat, quat_to_matrix
from annotator.scenes.records import Workspace


class PolicyError(ValueError):
    """A policy that cannot be found, loaded, or that answered something the arm cannot take."""


def _frozen(array: np.ndarray, dtype) -> np.ndarray:
    out = np.array(array, dtype=dtype)  # a copy: the policy cannot change the round's data
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class CameraImage:
    """One depth image: ``depth`` (h, w) float32 m along the optical axis (0 = no measurement), the
    pinhole ``K`` (:class:`annotator.cell.kinect.Intrinsics`) and the camera's optical frame in
    the table frame ``T_table_camera`` (+z along the view, +x right, +y down in the image)."""

    depth: np.ndarray
    K: Intrinsics
    T_table_camera: Transform


@dataclass(frozen=True)
class Observation:
    """What the Kinect v2 sees of a pile before an attempt (module docstring for the frames).

    ``round_id``, ``attempt`` (0-based within the round) and ``seed`` identify the call (a policy
    that draws random numbers keys them on these); ``images`` the depth views; ``cloud`` (n, 3)
    float64 m, every valid depth pixel of the views back-projected into the table frame and cropped
    to the workspace's box (the table top included: its points have z ~ 0); ``tsdf``
    (r, r, r) float32 VGN's grid fused from the views over the workspace, ``T_table_volume`` its
    lower corner, ``voxel_size`` m; ``workspace`` the box objects are in; ``max_width`` the
    gripper's widest opening (m), ``gripper`` the name of the gripper the arm carries. All arrays
    are read-only."""

    round_id: int
    attempt: int
    seed: int
    images: tuple[CameraImage, ...]
    cloud: np.ndarray
    tsdf: np.ndarray
    T_table_volume: Transform
    voxel_size: float
    workspace: Workspace
    max_width: float
    gripper: str


@dataclass(frozen=True)
class Grasp:
    """One scored grasp: the TCP pose ``T_table_tcp`` (table frame), the ``width`` (m) between the
    pads the gripper closes from (the chord across the object; the arm opens a pregrasp clearance
    wider on the approach), the ``score`` (higher is executed first)."""

    T_table_tcp: Transform
    width: float
    score: float = 0.0


@dataclass(frozen=True)
class Grasps:
    """Scored grasps as arrays: ``T_table_tcp`` (n, 4, 4) float64, ``width`` (n,) m, ``score`` (n,).

    :meth:`from_rows` builds them from an (n, 9) array ``x y z qx qy qz qw width score`` (TCP in the
    table frame, quaternion xyzw), :meth:`of` from whatever a policy returned."""

    T_table_tcp: np.ndarray
    width: np.ndarray
    score: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.width)
        if np.shape(self.T_table_tcp) != (n, 4, 4) or np.shape(self.score) != (n,):
            raise PolicyError(
                "grasps need T_table_tcp (n, 4, 4), width (n,), score (n,); got "
                f"{np.shape(self.T_table_tcp)}, {np.shape(self.width)}, {np.shape(self.score)}"
            )

    def __len__(self) -> int:
        return len(self.width)

    @classmethod
    def empty(cls) -> Grasps:
        return cls(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0))

    @classmethod
    def from_rows(cls, rows: np.ndarray) -> Grasps:
        """From (n, 9) ``x y z qx qy qz qw width score`` (quaternions normalised)."""
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, 9)
        bad = ~np.isfinite(rows).all(axis=1)
        if bad.any():
            raise PolicyError(f"grasp {int(np.argmax(bad))} is not finite")
        norm = np.linalg.norm(rows[:, 3:7], axis=1)
        if (norm < 1e-9).any():
            raise PolicyError(f"grasp {int(np.argmax(norm < 1e-9))}: a zero quaternion is no rotation")
        T = np.tile(np.eye(4), (len(rows), 1, 1))
        if len(rows):
            T[:, :3, :3] = quat_to_matrix(rows[:, 3:7])
            T[:, :3, 3] = rows[:, :3]
        return cls(T, rows[:, 7].copy(), rows[:, 8].copy())

    @classmethod
    def of(cls, value: object) -> Grasps:
        """What a policy returned -> Grasps: Grasps, a sequence of :class:`Grasp`, an (n, 9) array
        (:meth:`from_rows`), or None (no grasp). PolicyError for anything else."""
        if value is None:
            return cls.empty()
        if isinstance(value, Grasps):
            return cls(
                np.asarray(value.T_table_tcp, dtype=np.float64),
                np.asarray(value.width, dtype=np.float64).reshape(-1),
                np.asarray(value.score, dtype=np.float64).reshape(-1),
            )
        if isinstance(value, Sequence) and all(isinstance(g, Grasp) for g in value):
            if not value:
                return cls.empty()
            return cls(
                np.array([g.T_table_tcp.as_matrix() for g in value]),
                np.array([float(g.width) for g in value]),
                np.array([float(g.score) for g in value]),
            )
        if isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1] == 9:
            return cls.from_rows(value)
        raise PolicyError(
            f"a policy returned {type(value).__name__}: it must return Grasps, a list of Grasp, "
            "an (n, 9) array (x y z qx qy qz qw width score) or None"
        )

    def grasp(self, k: int) -> Grasp:
        """Row ``k`` as a :class:`Grasp` (its rotation re-orthonormalised through a quaternion)."""
        M = self.T_table_tcp[k]
        T = Transform(M[:3, 3], matrix_to_quat(M[:3, :3]))
        return Grasp(T, float(self.width[k]), float(self.score[k]))

    def check(self, workspace: Workspace, max_width: float, margin: float) -> None:
        """PolicyError naming the first grasp that is not finite, has a width outside 0..max_width,
        a rotation that is not one, or a TCP farther than ``margin`` m outside the workspace's box."""
        values = np.column_stack([self.T_table_tcp.reshape(len(self), 16), self.width, self.score])
        bad = ~np.isfinite(values).all(axis=1)
        if bad.any():
            raise PolicyError(f"grasp {int(np.argmax(bad))} is not finite")
        wide = (self.width < 0) | (self.width > max_width)
        if wide.any():
            k = int(np.argmax(wide))
            w = self.width[k]
            raise PolicyError(f"grasp {k}: width {w:.4g} m outside the stroke 0-{max_width:.4g} m")
        R = self.T_table_tcp[:, :3, :3]
        off = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2)) > 1e-6
        if off.any():
            raise PolicyError(f"grasp {int(np.argmax(off))}: its rotation is not orthonormal")
        p = self.T_table_tcp[:, :3, 3]
        out = ((p < workspace.lower - margin) | (p > workspace.upper + margin)).any(axis=1)
        if out.any():
            k = int(np.argmax(out))
            raise PolicyError(
                f"grasp {k}: TCP at {np.round(p[k], 3).tolist()} m, more than {margin} m outside "
                "the workspace"
            )


@dataclass(frozen=True)
class Proposal:
    """A grasp to execute: the target ``instance_id`` (-1: not known, a learner's), the TCP pose
    ``T_table_tcp`` (table frame) with the pads ``width`` apart, the policy's ``score``, and the
    arm's path (:class:`annotator.cell.reach.Reach`)."""

    instance_id: int
    T_table_tcp: Transform
    width: float
    score: float
    reach: Reach
