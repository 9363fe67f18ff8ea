"""Generate ur3.urdf, kinect_v2.urdf and ur3_visual_grabbing_with_rg2.urdf from published numbers.

Run ``python assets/ur3/make_ur3.py`` (stdlib + numpy only). Every number is cited in README.md.

Frames. ``base_link`` follows ROS-Industrial (x, y flipped with respect to UR's DH base, so the
arm at q = 0 stretches along +x); the fixed child ``base`` is UR's DH base frame (Rz(pi) from
``base_link``). Each moving link's frame sits exactly where standard DH puts the frame of the joint
that moves it: link i's frame is DH frame {i-1} rotated by q_i about its z, so URDF forward
kinematics equal DH forward kinematics to rounding. ``tool0`` is DH frame {6}: the flange, +z out.

Geometry is written once, in the DH base frame with all joints at zero, and converted into each
link's frame with the DH transforms; so are the centres of mass, which UR gives in DH frame {i}.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import ModuleType

import numpy as np

HERE = Path(__file__).resolve().parent
RG2_GENERATOR = HERE.parent / "grippers" / "rg2" / "make_rg2.py"

PI = math.pi

# --- UR3 (CB3) standard DH, ur_description config/ur3/physical_parameters.yaml ------------------
D1, A2, A3, D4, D5, D6 = 0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819
DH_D = (D1, 0.0, 0.0, D4, D5, D6)
DH_A = (0.0, A2, A3, 0.0, 0.0, 0.0)
DH_ALPHA = (PI / 2, 0.0, 0.0, PI / 2, -PI / 2, 0.0)

JOINTS = (
    # name, lower, upper, velocity rad/s, effort N m  (config/ur3/joint_limits.yaml)
    ("shoulder_pan_joint", -2 * PI, 2 * PI, PI, 56.0),
    ("shoulder_lift_joint", -2 * PI, 2 * PI, PI, 56.0),
    ("elbow_joint", -PI, PI, PI, 28.0),
    ("wrist_1_joint", -2 * PI, 2 * PI, 2 * PI, 12.0),
    ("wrist_2_joint", -2 * PI, 2 * PI, 2 * PI, 12.0),
    ("wrist_3_joint", -2 * PI, 2 * PI, 2 * PI, 12.0),
)
LINKS = (
    "base_link",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
# kg, UR ROS2 description config/ur3/physical_parameters.yaml
MASSES = (2.0, 2.0, 3.42, 1.26, 0.8, 0.8, 0.35)
# Centres of mass of links 1..6 in DH frame {i} (same file / UR's DH article).
COM_DH = (
    (0.0, -0.02, 0.0),
    (0.13, 0.0, 0.1157),
    (0.05, 0.0, 0.0238),
    (0.0, 0.0, 0.01),
    (0.0, 0.0, 0.01),
    (0.0, 0.0, -0.02),
)
# Collision radii, "manually measured" (ur_description ur3 xacro properties).
R_SHOULDER, R_UPPER_ARM, R_ELBOW, R_FOREARM, R_WRIST = 0.060, 0.054, 0.060, 0.040, 0.045
SHOULDER_OFFSET = 0.1198  # upper-arm centre line along the shoulder-lift axis
ELBOW_OFFSET = 0.0275  # forearm centre line along the elbow axis

# Assumptions [U], not in the sources: base housing radius and height.
R_BASE = 0.060
BASE_HEIGHT = 0.075
# Wrist housings are 2 * R_WRIST long, shortened by 5 mm where that keeps non-adjacent links
# (checked with PyBullet's EXCLUDE_PARENT self-collision) apart at q = 0.
WRIST_LEN = 2 * R_WRIST
# Massless frames (base, tool0, camera frames) get an explicit tiny inertial: a link without one
# weighs 1 kg in PyBullet. 1e-4 kg matches the RG2's tcp frame.
# The flange's collision cylinder stops this short of the flange face (tool0), so that a tool
# mounted on tool0 (a grandchild of wrist_3_link, not excluded by EXCLUDE_PARENT) does not start
# in contact; bullet reports ~1 mm of penetration for shapes that merely touch.
FLANGE_COLLISION_CLEARANCE = 0.003
FRAME_MASS = 1e-4
FRAME_INERTIA = 1e-9
# The mount (ROS convention): a root link named exactly "world" with no <inertial>, fixed to
# base_link. PyBullet gives an inertial-less link mass 0 only when it is named "world" (any other
# name gets 1 kg and a warning), and a multibody whose root has mass 0 is static: the arm stays
# where it is loaded without useFixedBase, as the seed's script loads it.
MOUNT_LINK = "world"
MOUNT_JOINT = "world_joint"

UR_GREY = ("ur_grey", "0.70 0.71 0.73 1")
UR_BLUE = ("ur_blue", "0.29 0.56 0.82 1")
UR_DARK = ("ur_dark", "0.20 0.20 0.22 1")
KINECT_BLACK = ("kinect_black", "0.08 0.08 0.08 1")
KINECT_GLASS = ("kinect_glass", "0.15 0.15 0.25 1")

# --- Kinect v2 (see README) ----------------------------------------------------------------------
KINECT_SIZE = (0.066, 0.25, 0.067)  # x forward (depth), y width, z height, m [U]
KINECT_MASS = 0.9  # kg [U]


# --- small transform helpers ----------------------------------------------------------------------
def rot_x(a: float) -> np.ndarray:
    """(4, 4) rotation about x by ``a`` rad."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=float)


def rot_z(a: float) -> np.ndarray:
    """(4, 4) rotation about z by ``a`` rad."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def trans(x: float, y: float, z: float) -> np.ndarray:
    """(4, 4) translation."""
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def dh_tail(i: int) -> np.ndarray:
    """Constant part of DH link ``i`` (0-based): Tz(d) Tx(a) Rx(alpha), from joint frame to frame {i+1}."""
    return trans(DH_A[i], 0.0, DH_D[i]) @ rot_x(DH_ALPHA[i])


def rpy_from_matrix(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw of a (3, 3) rotation, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if abs(math.cos(pitch)) < 1e-9:  # gimbal lock: put everything in yaw
        return 0.0, pitch, math.atan2(-r[0, 1], r[1, 1])
    return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])


def frame_with_z(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose z column is the unit ``axis`` : (3,)."""
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _f(v: float) -> str:
    s = f"{v:.9f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def origin(t: np.ndarray) -> str:
    """URDF ``<origin>`` of a (4, 4) transform."""
    xyz = " ".join(_f(v) for v in t[:3, 3])
    rpy = " ".join(_f(v) for v in rpy_from_matrix(t[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


# --- the arm at q = 0 in the DH base frame ----------------------------------------------------------
def link_frames_q0() -> list[np.ndarray]:
    """(4, 4) poses, in the DH base frame at q = 0, of base_link, the six moving links, tool0.

    Moving link i's frame is DH frame {i-1} (rotated by q_i, zero here); tool0 is DH frame {6}.
    """
    frames = [rot_z(PI)]  # base_link: ROS-Industrial, Rz(pi) from the DH base
    t = np.eye(4)
    for i in range(6):
        frames.append(t.copy())
        t = t @ dh_tail(i)
    frames.append(t)  # tool0 = DH frame {6}
    return frames


def dh_frames_q0() -> list[np.ndarray]:
    """(4, 4) DH frames {1}..{6} in the DH base frame at q = 0."""
    out, t = [], np.eye(4)
    for i in range(6):
        t = t @ dh_tail(i)
        out.append(t.copy())
    return out


# Primitives in the DH base frame at q = 0 (arm along -x, joint offsets along -y).
# (kind, centre (3,), axis (3,) or None, radius, length, material); the first cylinder of a link
# is the one whose inertia stands for the link (cylinder approximation, as UR's description).
_U = np.array([0.0, -1.0, 0.0])  # direction of the shoulder-lift/elbow/wrist-1 axes at q = 0
_X = np.array([1.0, 0.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])
X_WRIST = A2 + A3  # x of the wrist axes at q = 0


def _at(x: float, s: float, z: float) -> np.ndarray:
    """Point at x, offset s along the lift axis (-y), height z."""
    return np.array([x, 0.0, z]) + s * _U


Prim = tuple[str, np.ndarray, np.ndarray, float, float, tuple[str, str]]


def arm_primitives() -> list[list[Prim]]:
    """Collision/visual primitives per link (base_link + six moving links), DH base frame, q = 0."""
    s_wrist_lo = ELBOW_OFFSET + R_FOREARM + 0.0025  # wrist housings start 2.5 mm past the forearm
    wrist2_len = D4 + R_WRIST - s_wrist_lo  # J6 housing, from there to the wrist-1 body's far side
    wrist2_mid = s_wrist_lo + wrist2_len / 2
    s_flange_lo = D4 + R_WRIST + 0.0025  # flange starts 2.5 mm past the wrist-1 body
    flange_len = D4 + D6 - s_flange_lo
    shoulder_col = D1 - BASE_HEIGHT
    return [
        [("cylinder", np.array([0, 0, BASE_HEIGHT / 2]), _Z, R_BASE, BASE_HEIGHT, UR_GREY)],
        [
            # J2 housing across the shoulder, then the J1 column under it
            ("cylinder", _at(0, 0, D1), _U, R_SHOULDER, 2 * R_SHOULDER, UR_BLUE),
            (
                "cylinder",
                np.array([0, 0, BASE_HEIGHT + shoulder_col / 2]),
                _Z,
                R_SHOULDER,
                shoulder_col,
                UR_GREY,
            ),
        ],
        [
            ("cylinder", _at(A2 / 2, SHOULDER_OFFSET, D1), _X, R_UPPER_ARM, -A2, UR_GREY),
            ("cylinder", _at(0, SHOULDER_OFFSET, D1), _U, R_UPPER_ARM, 2 * R_UPPER_ARM, UR_GREY),
            ("cylinder", _at(A2, SHOULDER_OFFSET, D1), _U, R_UPPER_ARM, 2 * R_UPPER_ARM, UR_GREY),
        ],
        [
            ("cylinder", _at(A2 + A3 / 2, ELBOW_OFFSET, D1), _X, R_FOREARM, -A3, UR_GREY),
            # elbow housing (J3), reaching from the forearm line towards the upper arm
            ("cylinder", _at(A2, ELBOW_OFFSET + 0.5 * R_FOREARM, D1), _U, R_ELBOW, 2 * R_FOREARM, UR_BLUE),
            ("sphere", _at(X_WRIST, ELBOW_OFFSET, D1), _U, R_FOREARM, 0.0, UR_GREY),
        ],
        [  # wrist 1 body: the J5 housing, vertical at q = 0
            ("cylinder", _at(X_WRIST, D4, D1), _Z, R_WRIST, WRIST_LEN, UR_BLUE),
        ],
        [  # wrist 2 body: the J6 housing along the flange axis
            ("cylinder", _at(X_WRIST, wrist2_mid, D1 - D5), _U, R_WRIST, wrist2_len, UR_BLUE),
        ],
        [  # wrist 3: the flange
            (
                "cylinder",
                _at(X_WRIST, s_flange_lo + flange_len / 2, D1 - D5),
                _U,
                R_WRIST,
                flange_len,
                UR_DARK,
            ),
        ],
    ]


def cylinder_inertia(m: float, r: float, length: float) -> tuple[float, float, float]:
    """Principal moments (ixx, iyy, izz) of a solid cylinder along z: m(3r²+l²)/12, m r²/2."""
    side = m * (3 * r * r + length * length) / 12.0
    return side, side, m * r * r / 2.0


def _material(mat: tuple[str, str]) -> str:
    return f'<material name="{mat[0]}"><color rgba="{mat[1]}"/></material>'


def _geometry(kind: str, r: float, length: float, box: tuple[float, float, float] | None = None) -> str:
    if kind == "cylinder":
        return f'<geometry><cylinder radius="{_f(r)}" length="{_f(length)}"/></geometry>'
    if kind == "sphere":
        return f'<geometry><sphere radius="{_f(r)}"/></geometry>'
    assert box is not None
    return f'<geometry><box size="{" ".join(_f(v) for v in box)}"/></geometry>'


def _shape_xml(
    t_link_shape: np.ndarray,
    geom: str,
    mat: tuple[str, str],
    t_collision: np.ndarray | None = None,
    collision_geom: str | None = None,
) -> str:
    """A visual and its collision twin (or a different collision shape when given)."""
    o = origin(t_link_shape)
    oc = o if t_collision is None else origin(t_collision)
    return (
        f"    <visual>{o}{geom}{_material(mat)}</visual>\n"
        f"    <collision>{oc}{collision_geom or geom}</collision>\n"
    )


def _inertial_xml(t_link_com: np.ndarray, m: float, moments: tuple[float, float, float]) -> str:
    ixx, iyy, izz = (_f(v) for v in moments)
    return (
        f'    <inertial>{origin(t_link_com)}<mass value="{_f(m)}"/>'
        f'<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>\n'
    )


def _frame_link(name: str) -> str:
    i = _f(FRAME_INERTIA)
    return (
        f'  <link name="{name}">\n    <inertial><mass value="{_f(FRAME_MASS)}"/>'
        f'<inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>\n  </link>\n'
    )


def _fixed_joint(name: str, parent: str, child: str, t: np.ndarray) -> str:
    return (
        f'  <joint name="{name}" type="fixed">{origin(t)}'
        f'<parent link="{parent}"/><child link="{child}"/></joint>\n'
    )


def link_com_and_inertia() -> list[tuple[np.ndarray, tuple[float, float, float]]]:
    """Per link (base_link + six), the (4, 4) inertial frame in the link frame and principal moments.

    The inertial frame's origin is the centre of mass (UR's figures in DH frame {i}, mapped through
    the DH transforms); its z axis is the axis of the link's main cylinder.
    """
    frames = link_frames_q0()
    dh = dh_frames_q0()
    prims = arm_primitives()
    out = []
    for k in range(7):
        _kind, centre, axis, r, length, _mat = prims[k][0]
        com_world = centre if k == 0 else (dh[k - 1] @ np.array([*COM_DH[k - 1], 1.0]))[:3]
        t_world_inertial = np.eye(4)
        t_world_inertial[:3, :3] = frame_with_z(axis)
        t_world_inertial[:3, 3] = com_world
        out.append((np.linalg.inv(frames[k]) @ t_world_inertial, cylinder_inertia(MASSES[k], r, length)))
    return out


def mount_xml(prefix: str = "") -> str:
    """The massless root ``world`` (no ``<inertial>``) and the fixed joint to ``{prefix}base_link``.

    The link keeps the name ``world`` whatever the prefix: PyBullet makes only that name static.
    """
    return f'  <link name="{MOUNT_LINK}"/>\n' + _fixed_joint(
        f"{prefix}{MOUNT_JOINT}", MOUNT_LINK, f"{prefix}base_link", np.eye(4)
    )


def ur3_xml(prefix: str = "") -> str:
    """The UR3's ``<link>``/``<joint>`` XML (no ``<robot>`` wrapper), from ``{prefix}base_link`` on.

    Also holds the fixed frames ``{prefix}base`` (UR's DH base) and ``{prefix}tool0`` (the flange).
    :func:`mount_xml` gives the root that mounts it.
    """
    p = prefix
    frames = link_frames_q0()
    prims = arm_primitives()
    inertials = link_com_and_inertia()
    out: list[str] = []
    for k, name in enumerate(LINKS):
        inv = np.linalg.inv(frames[k])
        body = _inertial_xml(*inertials[k][:1], MASSES[k], inertials[k][1])
        for n, (kind, centre, axis, r, length, mat) in enumerate(prims[k]):
            t = np.eye(4)
            t[:3, :3] = frame_with_z(axis)
            t[:3, 3] = centre
            if name == "wrist_3_link" and n == 0:  # the flange: collision clear of the face
                c = FLANGE_COLLISION_CLEARANCE
                tc = t.copy()
                tc[:3, 3] -= 0.5 * c * np.asarray(axis)
                body += _shape_xml(
                    inv @ t, _geometry(kind, r, length), mat, inv @ tc, _geometry(kind, r, length - c)
                )
            else:
                body += _shape_xml(inv @ t, _geometry(kind, r, length), mat)
        out.append(f'  <link name="{p}{name}">\n{body}  </link>\n')
    # joints: shoulder_pan from base_link (Rz(pi) to the DH base), then the DH "tails"
    for i, (jname, lo, hi, vel, eff) in enumerate(JOINTS):
        t = rot_z(PI) if i == 0 else dh_tail(i - 1)
        out.append(
            f'  <joint name="{p}{jname}" type="revolute">{origin(t)}'
            f'<parent link="{p}{LINKS[i]}"/><child link="{p}{LINKS[i + 1]}"/><axis xyz="0 0 1"/>'
            f'<limit lower="{_f(lo)}" upper="{_f(hi)}" effort="{_f(eff)}" velocity="{_f(vel)}"/></joint>\n'
        )
    out.append(_frame_link(f"{p}base"))
    out.append(_fixed_joint(f"{p}base_link-base_fixed_joint", f"{p}base_link", f"{p}base", rot_z(PI)))
    out.append(_frame_link(f"{p}tool0"))
    out.append(_fixed_joint(f"{p}wrist_3-tool0_fixed_joint", f"{p}wrist_3_link", f"{p}tool0", dh_tail(5)))
    return "".join(out)


def kinect_xml(prefix: str = "") -> str:
    """Kinect v2 links/joints; root ``{prefix}kinect_link`` at the body centre (x forward, z up).

    ``camera_link`` (x forward, y left, z up) sits on the front face; ``camera_optical_frame`` is
    its optical twin (z forward along the view, x right, y down in the image).
    """
    p = prefix
    sx, sy, sz = KINECT_SIZE
    m = KINECT_MASS
    moments = (m * (sy**2 + sz**2) / 12, m * (sx**2 + sz**2) / 12, m * (sx**2 + sy**2) / 12)
    body = _inertial_xml(np.eye(4), m, moments)
    body += _shape_xml(np.eye(4), _geometry("box", 0, 0, KINECT_SIZE), KINECT_BLACK)
    # a thin dark "glass" strip on the front face, visual only
    glass = trans(sx / 2 - 0.001, 0, 0.006)
    glass_geom = _geometry("box", 0, 0, (0.002, 0.22, 0.03))
    body += f"    <visual>{origin(glass)}{glass_geom}{_material(KINECT_GLASS)}</visual>\n"
    out = [f'  <link name="{p}kinect_link">\n{body}  </link>\n']
    out.append(_frame_link(f"{p}camera_link"))
    out.append(_fixed_joint(f"{p}camera_joint", f"{p}kinect_link", f"{p}camera_link", trans(sx / 2, 0, 0)))
    out.append(_frame_link(f"{p}camera_optical_frame"))
    # optical: z = camera x, x = -camera y, y = -camera z  (REP 103)
    optical = np.eye(4)
    optical[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float)
    out.append(
        _fixed_joint(f"{p}camera_optical_joint", f"{p}camera_link", f"{p}camera_optical_frame", optical)
    )
    return "".join(out)


def robot(name: str, body: str) -> str:
    """Wrap links/joints XML in a ``<robot>`` element."""
    header = "<!-- Generated by assets/ur3/make_ur3.py; do not edit. Sources in assets/ur3/README.md. -->"
    return f'<?xml version="1.0"?>\n{header}\n<robot name="{name}">\n{body}</robot>\n'


def load_rg2_generator() -> ModuleType | None:
    """The RG2 generator module (assets/grippers/rg2/make_rg2.py), or None while it does not exist."""
    if not RG2_GENERATOR.exists():
        return None
    spec = importlib.util.spec_from_file_location("make_rg2", RG2_GENERATOR)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def models() -> dict[str, str]:
    """File name -> URDF text of every model this script writes (the combined one needs make_rg2.py)."""
    out = {
        "ur3.urdf": robot("ur3", mount_xml() + ur3_xml()),
        "kinect_v2.urdf": robot("kinect_v2", kinect_xml()),
    }
    rg2 = load_rg2_generator()
    if rg2 is not None:
        body = mount_xml() + ur3_xml() + rg2.gripper_xml("tool0")
        out["ur3_visual_grabbing_with_rg2.urdf"] = robot("ur3_visual_grabbing_with_rg2", body)
    else:
        print(f"{RG2_GENERATOR} not found: skipped the combined UR3 + RG2 model")
    return out


def main() -> None:
    """Write the URDFs next to this script."""
    written = models()
    for name, text in written.items():
        (HERE / name).write_text(text)
    print("wrote", ", ".join(written))


if __name__ == "__main__":
    main()
