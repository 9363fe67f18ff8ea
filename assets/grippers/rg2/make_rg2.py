"""Generate the OnRobot RG2 URDF from published numbers (see README.md beside this file).

Run ``python assets/grippers/rg2/make_rg2.py`` to rewrite ``rg2.urdf``. The UR3 generator imports
:func:`gripper_xml` to mount the same gripper on the arm's flange.

Gripper frame (``rg2_base_link``): origin at the tool flange, +z out along the tool axis,
+x the closing direction of finger 1 (finger 1 sits at -x, finger 2 at +x), +y = z x x.
All lengths below are metres; each carries its source tag (README.md beside this file cites the
sources): [V] read in a published source, [D] derived from [V] numbers, [C] our modelling choice.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import urdf_parts as parts  # noqa: E402  (assets/grippers/urdf_parts.py: the shared URDF writer)

# --- linkage (OnRobot URCap script and ROS descriptions, three agree) -----------------------
LINK_LENGTH = 0.055  # [V] outer link, pivot to finger pivot; w = 5 + 110 sin(phi) mm
OUTER_PIVOT_X = 0.017  # [V] driven pivots at +-17 mm lateral
INNER_PIVOT_X = 0.0075  # [V] passive pivots at +-7.5 mm lateral ...
INNER_PIVOT_DZ = 0.0165  # [V] ... 16.5 mm further out along the tool axis
# [D] depth of the driven pivots: fingertips span 176..215 mm from the base over the stroke
# [D] and 215 = PIVOT_Z + 55 + FINGER_BELOW_PIVOT. The passive link meets the finger 16.5 mm below
# the finger pivot, so the pad (29.8 mm) must start below that: [C] fingertip end 50 mm below the
# finger pivot (pad top 3.7 mm below the passive pivot), which puts the driven pivots at 110 mm,
# inside the housing's lower end (the links emerge from it, as on the real gripper).
FINGER_BELOW_PIVOT = 0.050
PIVOT_Z = 0.215 - LINK_LENGTH - FINGER_BELOW_PIVOT
# --- fingertip pad (OnRobot ROS2 onrobot_rg2_macro.xacro) -----------------------------------
PAD_LENGTH = 0.0298  # [V] along the tool axis
PAD_WIDTH = 0.0202  # [V] along y
PAD_THICKNESS = 0.01145  # [V] along the closing axis
# [D] the URCap's w = 5 + 110 sin(phi) mm puts each pad face 2.5 mm off centre at phi = 0,
# i.e. 14.5 mm inward of the finger pivot (17 - 2.5); the pad fills the inner 11.45 mm of that
# and a 3.05 mm finger plate the rest.
PAD_FACE_INWARD = OUTER_PIVOT_X - 0.0025
FINGER_PLATE_THICKNESS = PAD_FACE_INWARD - PAD_THICKNESS
PAD_CENTRE_DZ = FINGER_BELOW_PIVOT - PAD_LENGTH / 2  # pad centre below the finger pivot
# --- driven range -------------------------------------------------------------------------
# [D] closed: pads touch (w = 0): sin(phi) = -5/110. Open: w = 110 mm stroke [V]: sin = 105/110.
PHI_CLOSED = math.asin(-0.005 / 0.110)
PHI_OPEN = math.asin(0.105 / 0.110)
# --- housing (OnRobot URCap / ROS2 xacro dimensions) -----------------------------------------
BASE_SIZE = (0.071, 0.075, 0.0274)  # [V] 75 x 71 footprint; [C] 27.4 mm high, up to the body
BODY_SIZE = (0.064, 0.037, 0.1182)  # [V] 118.2 x 37 x 64 mm
BODY_CENTRE_Z = 0.0865  # [V] ~86.5 mm out
# --- masses (URCap: 0.7415 kg total, centre of gravity 69.35 mm along the tool axis) --------
TOTAL_MASS = 0.7415  # [V]
TOTAL_COG_Z = 0.06935  # [V]
OUTER_LINK_MASS = 0.015  # [C] aluminium link ~ 55 x 16 x 6 mm
INNER_LINK_MASS = 0.010  # [C]
FINGER_MASS = 0.025  # [C] finger plate and its fixings
PAD_MASS = 0.005  # [C] rubber-faced pad
# [C] Reflected inertia of the RG2's geared drive, added to each linkage link as an armature:
# a small DC rotor (~1e-7..1e-6 kg m^2) behind a ~1:30..1:100 reduction reflects 1e-4..1e-2
# kg m^2 at the link; 1e-3 sits in that range. Without it the 5..25 g links (~4e-6 kg m^2)
# let the gear coupling buckle by 15-40 deg under a 40 N squeeze; with it the followers stay
# within 0.5 deg (bench/experiments/rg2_coupling.py).
ARMATURE = 1e-3  # kg m^2
LINK_THICKNESS = 0.006  # [C] link plate thickness (along x at phi = 0)
LINK_WIDTH = 0.016  # [C] link plate width (along y)
INNER_COLLISION_LENGTH = 0.035  # [C] see the passive link below

# Mimic table: the seed scene's joint names and multipliers (its control loop finds the joints by them).
DRIVEN_JOINT = "gripper_finger1_joint"
MIMIC = {
    "gripper_finger2_joint": -1.0,
    "gripper_finger1_inner_knuckle_joint": 1.0,
    "gripper_finger2_inner_knuckle_joint": -1.0,
    "gripper_finger1_finger_tip_joint": -1.0,
    "gripper_finger2_finger_tip_joint": 1.0,
}
DRIVEN_EFFORT = 10.0  # [C] N m; 40 N squeeze needs 40 N x dw/dphi <= 4.4 N m


# [D] A follower q_f = m q_d in the closed parallelogram transmits the drive's power: by virtual
# work its torque is DRIVEN_EFFORT / |m| (10 N m for every |m| = 1). An effort of 0 would leave
# a follower limp under the seed's per-joint position loop (it passes each joint's own maxForce);
# the annotator switches the followers' motors off and couples them with gear constraints.
def follower_effort(multiplier: float) -> float:
    return DRIVEN_EFFORT / abs(multiplier)


DRIVEN_VELOCITY = 1.2  # [D] rad/s: 127 mm/s max width speed [V datasheet] / 110 mm/rad at phi=0

GREY = "0.35 0.35 0.38 1"
LIGHT = "0.8 0.8 0.82 1"
BLACK = "0.1 0.1 0.1 1"


def _joint(
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz: tuple[float, float, float],
    lower: float = 0.0,
    upper: float = 0.0,
    mimic: float | None = None,
) -> str:
    if kind != "revolute":
        return parts.joint(name, kind, parent, child, xyz)
    effort = DRIVEN_EFFORT if mimic is None else follower_effort(mimic)
    return parts.joint(
        name,
        kind,
        parent,
        child,
        xyz,
        axis=(0.0, -1.0, 0.0),
        limit=(lower, upper, effort, DRIVEN_VELOCITY),
        mimic=None if mimic is None else (DRIVEN_JOINT, mimic),
    )


def _limits(multiplier: float) -> tuple[float, float]:
    a, b = multiplier * PHI_CLOSED, multiplier * PHI_OPEN
    return min(a, b), max(a, b)


def finger_part_masses() -> list[tuple[float, float]]:
    """(mass, z of centre of mass) of every finger-side link at the closed pose, both fingers."""
    c = math.cos(PHI_CLOSED)
    parts = [
        (OUTER_LINK_MASS, PIVOT_Z + c * LINK_LENGTH / 2),
        (INNER_LINK_MASS, PIVOT_Z + INNER_PIVOT_DZ + c * LINK_LENGTH / 2),
        (FINGER_MASS, PIVOT_Z + c * LINK_LENGTH),
        (PAD_MASS, PIVOT_Z + c * LINK_LENGTH + PAD_CENTRE_DZ),
    ]
    return parts * 2


def base_mass_and_com_z() -> tuple[float, float]:
    """[D] base mass and COM height so that the whole gripper matches the URCap mass and COG."""
    parts = finger_part_masses()
    m_fingers = sum(m for m, _ in parts)
    m_base = TOTAL_MASS - m_fingers
    z_base = (TOTAL_MASS * TOTAL_COG_Z - sum(m * z for m, z in parts)) / m_base
    return m_base, z_base


def tcp_z() -> float:
    """[D] the pad-centre midpoint along the tool axis with the gripper closed (w = 0)."""
    return PIVOT_Z + LINK_LENGTH * math.cos(PHI_CLOSED) + PAD_CENTRE_DZ


def gripper_xml(parent_link: str | None, prefix: str = "") -> str:
    """URDF ``<link>``/``<joint>`` elements of the RG2.

    With ``parent_link`` a fixed joint ``{prefix}rg2_mount_joint`` mounts ``rg2_base_link`` on it,
    gripper +z along the parent's +z. ``prefix`` is prepended to link names (joint names of the
    linkage keep the seed's names so the seed's control loop finds them).
    """
    p = prefix
    m_base, z_base = base_mass_and_com_z()
    out = []
    base = parts.inertial(m_base, (0, 0, z_base), (BODY_SIZE[0], BODY_SIZE[1], 0.145))
    base += parts.box("visual", (0, 0, BASE_SIZE[2] / 2), BASE_SIZE, GREY)
    base += parts.box("collision", (0, 0, BASE_SIZE[2] / 2), BASE_SIZE)
    base += parts.box("visual", (0, 0, BODY_CENTRE_Z), BODY_SIZE, LIGHT)
    base += parts.box("collision", (0, 0, BODY_CENTRE_Z), BODY_SIZE)
    out.append(parts.link(f"{p}rg2_base_link", base))
    if parent_link is not None:
        out.append(_joint(f"{p}rg2_mount_joint", "fixed", parent_link, f"{p}rg2_base_link", (0, 0, 0)))

    for i, side in ((1, -1.0), (2, 1.0)):
        inward = -side  # +x for finger 1 (at -x), -x for finger 2
        outer, inner = f"gripper_finger{i}_joint", f"gripper_finger{i}_inner_knuckle_joint"
        tip = f"gripper_finger{i}_finger_tip_joint"
        mult_outer = 1.0 if i == 1 else MIMIC[outer]
        link_size = (LINK_THICKNESS, LINK_WIDTH, LINK_LENGTH)
        # outer (driven side) link
        body = parts.inertial(OUTER_LINK_MASS, (0, 0, LINK_LENGTH / 2), link_size, ARMATURE)
        body += parts.box("visual", (0, 0, LINK_LENGTH / 2), link_size, GREY)
        body += parts.box("collision", (0, 0, LINK_LENGTH / 2), link_size)
        out.append(parts.link(f"{p}gripper_finger{i}_knuckle_link", body))
        lo, hi = _limits(mult_outer)
        out.append(
            _joint(
                outer,
                "revolute",
                f"{p}rg2_base_link",
                f"{p}gripper_finger{i}_knuckle_link",
                (side * OUTER_PIVOT_X, 0, PIVOT_Z),
                lo,
                hi,
                None if i == 1 else MIMIC[outer],
            )
        )
        # inner (passive) link: thinner, offset in y so it does not overlap the outer link's plate
        inner_size = (LINK_THICKNESS, LINK_WIDTH * 0.6, LINK_LENGTH)
        body = parts.inertial(INNER_LINK_MASS, (0, 0, LINK_LENGTH / 2), inner_size, ARMATURE)
        body += parts.box("visual", (0, 0, LINK_LENGTH / 2), inner_size, GREY)
        # [C] its collision stops short of the finger end: that end sits inside the finger on the
        # real gripper, and a full-length box would reach 2 mm behind the pad face and touch
        # objects that the pads hold.
        inner_col = (LINK_THICKNESS, LINK_WIDTH * 0.6, INNER_COLLISION_LENGTH)
        body += parts.box("collision", (0, 0, INNER_COLLISION_LENGTH / 2), inner_col)
        out.append(parts.link(f"{p}gripper_finger{i}_inner_knuckle_link", body))
        lo, hi = _limits(MIMIC[inner])
        out.append(
            _joint(
                inner,
                "revolute",
                f"{p}rg2_base_link",
                f"{p}gripper_finger{i}_inner_knuckle_link",
                (side * INNER_PIVOT_X, 0, PIVOT_Z + INNER_PIVOT_DZ),
                lo,
                hi,
                MIMIC[inner],
            )
        )
        # finger: frame at the finger pivot, stays parallel to the base (counter-rotating joint)
        plate_top = -0.005  # [C] the plate reaches 5 mm above the finger pivot
        plate_size = (FINGER_PLATE_THICKNESS, PAD_WIDTH, FINGER_BELOW_PIVOT - plate_top)
        plate_xyz = (inward * FINGER_PLATE_THICKNESS / 2, 0, (FINGER_BELOW_PIVOT + plate_top) / 2)
        body = parts.inertial(FINGER_MASS, plate_xyz, plate_size, ARMATURE)
        body += parts.box("visual", plate_xyz, plate_size, GREY)
        body += parts.box("collision", plate_xyz, plate_size)
        out.append(parts.link(f"{p}gripper_finger{i}_finger_tip_link", body))
        lo, hi = _limits(MIMIC[tip])
        out.append(
            _joint(
                tip,
                "revolute",
                f"{p}gripper_finger{i}_knuckle_link",
                f"{p}gripper_finger{i}_finger_tip_link",
                (0, 0, LINK_LENGTH),
                lo,
                hi,
                MIMIC[tip],
            )
        )
        # pad: its own link, frame at the pad centre, so contacts and FK name it directly
        pad_size = (PAD_THICKNESS, PAD_WIDTH, PAD_LENGTH)
        body = parts.inertial(PAD_MASS, (0, 0, 0), pad_size)
        body += parts.box("visual", (0, 0, 0), pad_size, BLACK)
        body += parts.box("collision", (0, 0, 0), pad_size)
        out.append(parts.link(f"{p}gripper_finger{i}_pad_link", body))
        pad_x = inward * (FINGER_PLATE_THICKNESS + PAD_THICKNESS / 2)
        out.append(
            _joint(
                f"gripper_finger{i}_pad_joint",
                "fixed",
                f"{p}gripper_finger{i}_finger_tip_link",
                f"{p}gripper_finger{i}_pad_link",
                (pad_x, 0, PAD_CENTRE_DZ),
            )
        )
    # TCP: midway between the pad centres of the closed gripper (the labels' TCP frame)
    out.append(parts.frame_link(f"{p}tcp"))
    out.append(_joint(f"{p}tcp_joint", "fixed", f"{p}rg2_base_link", f"{p}tcp", (0, 0, tcp_z())))
    return "".join(out)


def floating_urdf() -> str:
    """The floating RG2 used for annotation: root link ``rg2_base_link``."""
    return parts.robot("onrobot_rg2", "assets/grippers/rg2/make_rg2.py", gripper_xml(None))


def main() -> None:
    out = Path(__file__).with_name("rg2.urdf")
    out.write_text(floating_urdf())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
