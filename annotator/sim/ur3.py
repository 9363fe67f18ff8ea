"""UR3 kinematics: standard-DH forward kinematics, the closed-form inverse (all eight branches), and
the model's fixed frames (DH base, flange, the gripper's tool point) read from its URDF.

DH parameters: ros-industrial/universal_robot ``ur_description/config/ur3/physical_parameters.yaml``
and UR's article "DH parameters for calculations of kinematics and dynamics" (UR3, CB3).
Frames: :func:`dh_forward_kinematics` returns ``T_base_tool0`` in UR's DH base frame (the URDF link
``base``); the URDF's ``base_link`` is the ROS-Industrial frame, ``T_baselink_base`` = Rz(pi)
(:func:`arm_frames` reads it from the model).

Inverse kinematics: the standard UR analytical solution (Hawkins, "Analytic inverse kinematics for
the Universal Robots UR-5/UR-10 arms", 2013), re-derived for standard DH:

1. *Shoulder* (q1). The wrist centre ``p05 = p06 - d6 z6`` lies d4 off the shoulder's plane:
   ``sin(q1 - psi) = d4 / r`` with ``(r, psi)`` the polar form of p05's x, y. Two branches
   ``q1 = psi + pi/2 +- acos(d4 / r)``; none when ``r < d4`` (the wrist centre inside the cylinder
   of radius d4 around the base axis).
2. *Wrist* (q5). The z row of ``R_16 = Rz(q2 + q3 + q4) Ry(-q5) Rz(q6)`` is
   ``(s5 c6, -s5 s6, c5)``: two branches ``q5 = atan2(+-|s5|, c5)`` (Hawkins' ``+-acos`` of the
   equivalent ``(s1 px - c1 py - d4) / d6`` loses ~1e-8 rad near ``q5 = 0``). They always exist.
3. q6 from the same row. When ``sin q5 = 0`` (the *wrist singularity*: joints 4 and 6 turn
   about one line) only ``q4 + q6`` is defined: q6 is set to ``q6_singular`` (0 by default; the
   seed's q6 in :func:`nearest_ik`) and q4 takes the rest.
4. *Elbow* (q3), then q2 and q4, from the planar chain in ``T_14 = A1^-1 T_06 A6^-1 A5^-1``: two
   branches ``q3 = +- acos(...)``; none when upper arm and forearm cannot span the distance.

Each solution gets two Gauss-Newton steps on the DH model (``acos`` near +-1 loses ~1e-8 rad) and
is kept only if it reproduces the pose within ``IK_TOLERANCE``. Solutions that coincide (on a
branch boundary) are returned once.

Joint ranges. Angles come back in ``(-pi, pi]`` (the elbow, from ``acos``, in ``[-pi, pi]``). When a
joint's limits allow ``q +- 2 pi`` as well (the UR3's are +-2 pi, elbow +-pi), :func:`ik_solutions`
returns the representative within the limits that is nearest to zero (ties: the one in
``(-pi, pi]``), and :func:`nearest_ik` the one nearest to the seed configuration: the only place
where that choice changes a motion.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from annotator import paths
from annotator.config import GripperConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.sim.body import Body
from annotator.sim.width_table import WidthTable, fk_table

log = logging.getLogger(__name__)

JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
MOUNT_LINK = "world"  # the massless root the models are mounted by (assets/ur3/README.md)
BASE_LINK = "base_link"  # ROS-Industrial base frame
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
# Position limits (rad), ur_description config/ur3/joint_limits.yaml: +-2 pi, elbow +-pi; (6, 2).
JOINT_LIMITS: np.ndarray = np.array([[-2 * math.pi, 2 * math.pi]] * 6)
JOINT_LIMITS[2] = (-math.pi, math.pi)
JOINT_LIMITS.setflags(write=False)

# T_baselink_base: the ROS-Industrial base_link is UR's DH base turned by pi about z.
T_BASELINK_BASE: np.ndarray = np.array(
    [[-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

# A solution is kept if its tool0 pose is within this of the target (metres, and rotation-matrix
# entries): far below what the arm (repeatability +-0.1 mm) or a label can tell apart, far above
# the ~1e-15 that polished solutions reach.
IK_TOLERANCE = 1e-9
# |sin q5| below this is the wrist singularity (joints 4 and 6 coaxial; only q4 + q6 is defined):
# there the q6 formula divides two rounding errors.
WRIST_SINGULAR = 1e-10
# acos arguments this far past +-1 are taken as +-1: rounding, not unreachability. Measured: the
# fully stretched elbow's argument came out 3e-12 past 1 for a pose made by forward kinematics.
# Whether the clipped branch really reaches the pose is then decided by IK_TOLERANCE.
ACOS_SLACK = 1e-9
GAUSS_NEWTON_STEPS = 2
# Solutions closer than this in every joint (rad) are one solution (two branches meeting on their
# boundary); 1e-7 rad moves the flange by < 0.1 um.
SAME_SOLUTION = 1e-7

# Branch order of the eight candidates: index = 4 * shoulder + 2 * wrist + elbow, each 0 for the
# "+" sign of its acos and 1 for the "-" sign.
BRANCHES: tuple[tuple[int, int, int], ...] = tuple((s, w, e) for s in (0, 1) for w in (0, 1) for e in (0, 1))

NO_SHOULDER = "no IK solution: the wrist centre is within d4 = 112 mm of the base axis"
NO_ELBOW = "no IK solution: out of the arm's reach (upper arm and forearm cannot span it)"
NO_LIMITS = "joint limits: every IK solution has a joint outside its limits"


# --- forward kinematics ---------------------------------------------------------------------------


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


def _dh_links(theta: np.ndarray, i: int) -> np.ndarray:
    """DH link ``i`` (0-based) for many angles: ``theta`` (n,) -> (n, 4, 4)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(DH_ALPHA[i]), math.sin(DH_ALPHA[i])
    A = np.zeros((len(theta), 4, 4))
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, DH_A[i] * ct
    A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, DH_A[i] * st
    A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, DH_D[i]
    A[:, 3, 3] = 1.0
    return A


def _dh_frames(q: np.ndarray) -> np.ndarray:
    """DH frames {0}..{6} in the DH base frame: ``q`` (n, 6) -> (n, 7, 4, 4)."""
    out = np.empty((len(q), 7, 4, 4))
    out[:, 0] = np.eye(4)
    for i in range(6):
        out[:, i + 1] = out[:, i] @ _dh_links(q[:, i], i)
    return out


def dh_forward_kinematics_batch(q: np.ndarray) -> np.ndarray:
    """``T_base_tool0`` for many configurations: ``q`` (n, 6) rad -> (n, 4, 4)."""
    return _dh_frames(np.asarray(q, dtype=np.float64).reshape(-1, 6))[:, 6]


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """Largest difference of position (m) or rotation-matrix entry: (..., 4, 4) twice -> (...,)."""
    d = np.abs(np.asarray(T_a)[..., :3, :] - np.asarray(T_b)[..., :3, :])
    return d.reshape(*d.shape[:-2], 12).max(axis=-1)


def _gauss_newton_step(q: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """One least-squares step of ``q`` (n, 6) towards ``T_target`` (n, 4, 4) on the DH model.

    Geometric Jacobian from the DH frames; the orientation error is the (small) rotation vector
    of ``R_target R^T``; ``pinv`` keeps the step bounded at singular configurations.
    """
    F = _dh_frames(q)
    z, o, p = F[:, :6, :3, 2], F[:, :6, :3, 3], F[:, 6, :3, 3]  # axes, origins (n, 6, 3); tool (n, 3)
    J = np.concatenate([np.cross(z, p[:, None, :] - o), z], axis=2).transpose(0, 2, 1)  # (n, 6, 6)
    dR = T_target[:, :3, :3] @ F[:, 6, :3, :3].transpose(0, 2, 1)
    w = 0.5 * np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]], 1)
    err = np.concatenate([T_target[:, :3, 3] - p, w], axis=1)
    return q + np.einsum("nij,nj->ni", np.linalg.pinv(J, rcond=1e-10), err)


# --- inverse kinematics ---------------------------------------------------------------------------


def _wrap(q: np.ndarray) -> np.ndarray:
    """Angles into (-pi, pi]."""
    return np.pi - np.mod(np.pi - q, 2 * np.pi)


def _acos(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``acos`` of values up to ACOS_SLACK past +-1 (clipped), and the mask where it exists."""
    with np.errstate(invalid="ignore"):
        ok = np.abs(c) <= 1.0 + ACOS_SLACK
    return np.arccos(np.clip(np.nan_to_num(c, nan=2.0), -1.0, 1.0)), ok


@dataclass(frozen=True)
class Branches:
    """The eight analytic branches for n poses (see :func:`ik_branches`).

    ``q`` : (n, 8, 6) rad, NaN where the branch does not exist; ``stage`` : (n, 8) int, 0 the
    branch exists (and reproduces the pose), 1 no shoulder, 2 no elbow solution, 3 not reproduced
    within IK_TOLERANCE (the arm's edge of reach, where acos rounding decides); ``wrist_singular``
    : (n, 8) bool.
    """

    q: np.ndarray
    stage: np.ndarray
    wrist_singular: np.ndarray

    REASONS = {1: NO_SHOULDER, 2: NO_ELBOW, 3: NO_ELBOW}


def ik_branches(T_base_tool0: np.ndarray, q6_singular: np.ndarray | float = 0.0) -> Branches:
    """All eight closed-form branches for many flange poses, polished, wrapped, unfiltered by limits.

    ``T_base_tool0`` : (n, 4, 4) or (4, 4), flange poses in UR's DH base frame; ``q6_singular`` :
    scalar or (n,), the q6 chosen at the wrist singularity.
    """
    T = np.asarray(T_base_tool0, dtype=np.float64).reshape(-1, 4, 4)
    n = len(T)
    R, p = T[:, :3, :3], T[:, :3, 3]
    q6_hint = np.broadcast_to(np.asarray(q6_singular, dtype=np.float64), (n,))
    q = np.empty((n, 8, 6))
    stage = np.zeros((n, 8), dtype=np.int64)
    singular = np.zeros((n, 8), dtype=bool)
    # 1. shoulder
    p05 = p - DH_D6 * R[:, :, 2]
    r = np.hypot(p05[:, 0], p05[:, 1])
    psi = np.arctan2(p05[:, 1], p05[:, 0])
    with np.errstate(divide="ignore"):
        phi, ok1 = _acos(DH_D4 / r)
    for b, (s, w, e) in enumerate(BRANCHES):
        q1 = psi + np.pi / 2 + (phi if s == 0 else -phi)
        c1, s1 = np.cos(q1), np.sin(q1)
        # 2. wrist: the z row of R_16 is (s5 c6, -s5 s6, c5); |sin q5| from its first two entries
        # keeps full precision near the singularity (acos of c5 loses ~1e-8 rad there). Always
        # exists: that row is a unit vector. (c5 also equals (s1 px - c1 py - d4) / d6 by step 1.)
        u = s1 * R[:, 0, 0] - c1 * R[:, 1, 0]  # s5 c6
        v = s1 * R[:, 0, 1] - c1 * R[:, 1, 1]  # -s5 s6
        sign5 = 1.0 if w == 0 else -1.0
        q5 = np.arctan2(sign5 * np.hypot(u, v), s1 * R[:, 0, 2] - c1 * R[:, 1, 2])
        # 3. q6, unless joints 4 and 6 are coaxial
        sing = np.hypot(u, v) < WRIST_SINGULAR
        q6 = np.where(sing, q6_hint, np.arctan2(-sign5 * v, sign5 * u))
        # 4. elbow, then q2 and q4 from T_14 (its origin minus d4 along z is the wrist-1 axis point)
        T14 = (
            np.linalg.inv(_dh_links(q1, 0))
            @ T
            @ np.linalg.inv(_dh_links(q6, 5))
            @ np.linalg.inv(_dh_links(q5, 4))
        )
        x, y = T14[:, 0, 3], T14[:, 1, 3]
        q3, ok3 = _acos((x * x + y * y - DH_A2 * DH_A2 - DH_A3 * DH_A3) / (2 * DH_A2 * DH_A3))
        q3 = q3 if e == 0 else -q3
        q2 = np.arctan2(y, x) - np.arctan2(DH_A3 * np.sin(q3), DH_A2 + DH_A3 * np.cos(q3))
        q4 = np.arctan2(T14[:, 1, 0], T14[:, 0, 0]) - q2 - q3
        q[:, b] = np.stack([q1, q2, q3, q4, q5, q6], axis=1)
        stage[:, b] = np.where(~ok1, 1, np.where(~ok3, 2, 0))
        singular[:, b] = sing
    # polish the existing branches (keeping the better of before and after: near a singularity a
    # least-squares step can overshoot), then keep those that reproduce the pose
    live = stage == 0
    if live.any():
        q_live, T_live = q[live], np.repeat(T[:, None], 8, axis=1)[live]
        err = pose_error(dh_forward_kinematics_batch(q_live), T_live)
        for _ in range(GAUSS_NEWTON_STEPS):
            q_new = _gauss_newton_step(q_live, T_live)
            err_new = pose_error(dh_forward_kinematics_batch(q_new), T_live)
            better = err_new < err
            q_live[better], err[better] = q_new[better], err_new[better]
        elbow = np.clip(q_live[:, 2], -np.pi, np.pi)  # acos put it in [-pi, pi]: keep its sign
        q_live = _wrap(q_live)
        q_live[:, 2] = elbow
        q[live] = q_live
        stage[live] = np.where(err > IK_TOLERANCE, 3, 0)
    q[stage > 0] = np.nan
    return Branches(q, stage, singular & (stage == 0))


def _within_limits(q: np.ndarray, limits: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each joint the representative ``q + 2 pi k`` within ``limits`` nearest to ``reference``.

    ``q`` (k, 6), ``limits`` (6, 2), ``reference`` (6,) -> (k, 6) representatives and (k,) bool:
    every joint has one. Ties go to the smaller shift |k| (the wrapped value itself).
    """
    two_pi = 2 * np.pi
    best = np.full_like(q, np.nan)
    for shift in (0, -1, 1, -2, 2):  # |shift| order: ties keep the smaller shift
        cand = q + two_pi * shift
        inside = (cand >= limits[:, 0] - 1e-12) & (cand <= limits[:, 1] + 1e-12)
        better = inside & (np.isnan(best) | (np.abs(cand - reference) < np.abs(best - reference) - 1e-12))
        best = np.where(better, cand, best)
    return best, ~np.isnan(best).any(axis=1)


@dataclass(frozen=True)
class IKResult:
    """The closed-form solutions of one flange pose.

    ``solutions`` : (k, 6) rad, k <= 8, in ``BRANCHES`` order, each within the joint limits;
    ``reason``: empty when k > 0, otherwise why there is none (``NO_SHOULDER``, ``NO_ELBOW`` or
    ``NO_LIMITS``); ``wrist_singular`` : (k,) bool.
    """

    solutions: np.ndarray
    reason: str
    wrist_singular: np.ndarray

    def __bool__(self) -> bool:
        return len(self.solutions) > 0


def solve_ik(
    T_base_tool0: np.ndarray,
    *,
    limits: np.ndarray = JOINT_LIMITS,
    reference: np.ndarray | None = None,
) -> IKResult:
    """Every joint configuration placing the flange at ``T_base_tool0`` (4, 4), DH base frame.

    Joints are represented within ``limits`` (6, 2) rad nearest to ``reference`` (6,) (default
    zeros, see the module docstring); the reference's q6 is also the q6 used at the wrist
    singularity.
    """
    reference = np.zeros(6) if reference is None else np.asarray(reference, dtype=np.float64)
    br = ik_branches(T_base_tool0, q6_singular=reference[5])
    return solutions_of(br, 0, limits=limits, reference=reference)


def solutions_of(
    br: Branches, i: int, *, limits: np.ndarray = JOINT_LIMITS, reference: np.ndarray | None = None
) -> IKResult:
    """:func:`solve_ik`'s answer for pose ``i`` of branches computed for many poses at once.

    Equal to ``solve_ik`` of that pose with ``reference`` when ``br`` was computed with
    ``q6_singular = reference[5]`` or when no branch of the pose is wrist-singular
    (``br.wrist_singular[i].any()`` is False): the hint is only used there.
    """
    reference = np.zeros(6) if reference is None else np.asarray(reference, dtype=np.float64)
    limits = np.asarray(limits, dtype=np.float64)
    ok = br.stage[i] == 0
    if not ok.any():
        worst = int(br.stage[i].max())  # the stage where the furthest-getting branch failed
        return IKResult(np.empty((0, 6)), Branches.REASONS[worst], np.empty(0, dtype=bool))
    q, singular = br.q[i][ok], br.wrist_singular[i][ok]
    keep: list[int] = []
    for k in range(len(q)):  # drop branches that coincide with an earlier one (boundaries)
        if all(np.abs(_wrap(q[k] - q[j])).max() > SAME_SOLUTION for j in keep):
            keep.append(k)
    q, singular = q[keep], singular[keep]
    q, inside = _within_limits(q, limits, reference)
    if not inside.any():
        return IKResult(np.empty((0, 6)), NO_LIMITS, np.empty(0, dtype=bool))
    return IKResult(q[inside], "", singular[inside])


def ik_solutions(T_base_tool0: np.ndarray, limits: np.ndarray = JOINT_LIMITS) -> np.ndarray:
    """The closed-form solutions (k, 6) rad of a flange pose (4, 4) in the DH base frame; k = 0 if none."""
    return solve_ik(T_base_tool0, limits=limits).solutions


def nearest_ik(
    T_base_tool0: np.ndarray, q_seed: np.ndarray, limits: np.ndarray = JOINT_LIMITS
) -> np.ndarray | None:
    """The solution (6,) nearest to ``q_seed`` (6,) (Euclidean in joint space, each joint unwrapped
    towards the seed within its limits), or None. Ties go to the earlier branch."""
    return _nearest(solve_ik(T_base_tool0, limits=limits, reference=q_seed), q_seed)


def _nearest(result: IKResult, q_seed: np.ndarray) -> np.ndarray | None:
    """The solution of ``result`` nearest to ``q_seed`` (ties: the earlier branch), or None."""
    if not result:
        return None
    d = np.linalg.norm(result.solutions - np.asarray(q_seed, dtype=np.float64), axis=1)
    return result.solutions[int(np.argmin(d))]


def nearest_ik_along(
    br: Branches, i: int, T_base_tool0: np.ndarray, q_seed: np.ndarray, limits: np.ndarray = JOINT_LIMITS
) -> np.ndarray | None:
    """:func:`nearest_ik` for pose ``i`` (flange ``T_base_tool0`` (4, 4)) of branches ``br``
    computed for a whole path at once: the same answer, solved again alone only where a branch of
    that pose is wrist-singular (where q6 is chosen from ``q_seed``)."""
    if br.wrist_singular[i].any():
        return nearest_ik(T_base_tool0, q_seed, limits)
    return _nearest(solutions_of(br, i, limits=limits, reference=q_seed), q_seed)


# --- the model's fixed frames ----------------------------------------------------------------------


@dataclass(frozen=True)
class ArmFrames:
    """Fixed transforms of a UR3 (+ gripper) model, read from its URDF by forward kinematics.

    ``T_baselink_base``: UR's DH base in ``base_link``; ``T_tool0_gripper``: the gripper's base link
    on the flange (None for the bare arm); ``gripper``: the gripper's FK table (pad-centre midpoint
    over the opening), None for the bare arm.
    """

    T_baselink_base: Transform
    T_tool0_gripper: Transform | None
    gripper: WidthTable | None

    def T_tool0_tcp(self, width: float) -> Transform:
        """The gripper's tool point (pad-centre midpoint, TCP axes) at opening ``width`` (m), in tool0."""
        if self.T_tool0_gripper is None or self.gripper is None:
            raise ValueError("this arm model has no gripper")
        return self.T_tool0_gripper * self.gripper.T_base_tcp(width)

    def T_base_tool0(self, T_baselink_tcp: Transform, width: float) -> np.ndarray:
        """Flange pose (4, 4) in the DH base for a TCP pose in ``base_link`` at opening ``width``."""
        T = self.T_baselink_base.inverse() * T_baselink_tcp * self.T_tool0_tcp(width).inverse()
        return T.as_matrix()

    def tcp_pose(self, q: np.ndarray, width: float) -> Transform:
        """``T_baselink_tcp`` for arm joints ``q`` (6,) at opening ``width`` (DH forward kinematics)."""
        T_base_tool0 = Transform.from_matrix(dh_forward_kinematics(q))
        return self.T_baselink_base * T_base_tool0 * self.T_tool0_tcp(width)

    def ik_tcp(
        self,
        T_baselink_tcp: Transform,
        width: float,
        *,
        limits: np.ndarray = JOINT_LIMITS,
        reference: np.ndarray | None = None,
    ) -> IKResult:
        """:func:`solve_ik` for a TCP pose in ``base_link`` at opening ``width`` (m)."""
        return solve_ik(self.T_base_tool0(T_baselink_tcp, width), limits=limits, reference=reference)


@functools.lru_cache(maxsize=4)
def arm_frames(
    urdf: str | None = None,
    gripper_config: GripperConfig | None = None,
    gripper: GripperDescription | None = None,
) -> ArmFrames:
    """Read :class:`ArmFrames` from a UR3 model (default: the UR3 + RG2) in a private DIRECT client.

    ``gripper``: the description of the gripper on its flange (default the RG2; its base link
    absent from the model: the bare arm); ``gripper_config`` sets how finely the gripper's FK table
    is sampled (as :class:`annotator.sim.gripper.ParallelGripper` does).
    """
    path = Path(urdf) if urdf is not None else paths.ur3_rg2_urdf()
    gripper = load_gripper(gripper)
    client = pb.connect(pb.DIRECT)
    try:
        body = Body.load(client, path)
        T_world_baselink = body.link_pose(BASE_LINK)
        T_baselink_base = T_world_baselink.inverse() * body.link_pose(DH_BASE_LINK)
        T_tool0_gripper = None
        if gripper.base_link in body.links:
            T_tool0_gripper = body.link_pose(TOOL0_LINK).inverse() * body.link_pose(gripper.base_link)
        limits = {j.name: (j.lower, j.upper) for j in body.movable_joints}
    finally:
        pb.disconnect(physicsClientId=client)
    table = None
    if T_tool0_gripper is not None:
        samples = (gripper_config or GripperConfig()).width_table_samples
        thickness = None if gripper.pad_size is None else gripper.pad_size[0]
        drive = gripper.drive_joint
        lower, upper = limits[drive]
        table = fk_table(
            str(path),
            drive=drive,
            pads=gripper.pad_links,
            base_link=gripper.base_link,
            pad_thickness=thickness,
            lower=lower,
            upper=upper,
            samples=samples,
        )
    return ArmFrames(T_baselink_base, T_tool0_gripper, table)


def arm_limits(body: Body) -> np.ndarray:
    """The six arm joints' position limits (6, 2) rad as the loaded model declares them."""
    return np.array([(body.joints[n].lower, body.joints[n].upper) for n in JOINT_NAMES])
