"""Generate the Robotiq 2F-85 URDF from published numbers (see README.md beside this file).

Run ``python assets/grippers/robotiq_2f85/make_robotiq_2f85.py`` to rewrite ``robotiq_2f85.urdf``.
Every collision shape is a box written here; no mesh or URDF of another project is used.

Base frame (``robotiq_2f85_base``): Robotiq's ``robotiq_arg2f_base_link`` (origin on the gripper's
mounting face; +z towards the fingertips) turned +90 deg about z, so that the fingers close along
x: x_here = y_robotiq, y_here = -x_robotiq. Finger 1 (Robotiq's left finger, driven by
``finger_joint``) sits at -x, finger 2 at +x.

The linkage is Robotiq's four-bar in its parallel mode, as their ROS description models it: on each
side an outer knuckle (driven, or mimicking the drive with +1), an inner knuckle (+1) pivoting on
the base, and an inner finger (-1) on the outer knuckle's end that stays parallel to the base and
carries the pad. ``finger_joint`` = 0 is fully open; a larger angle closes, as on the real gripper.
Tags: [V] read in a published source, [D] derived from [V] numbers, [C] our modelling choice.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import urdf_parts as parts  # noqa: E402  (assets/grippers/urdf_parts.py: the shared URDF writer)

BASE = "robotiq_2f85_base"
DRIVE = "finger_joint"
# --- linkage: ros-industrial/robotiq robotiq_2f_85_gripper_visualization (BSD), in Robotiq's frame --
OUTER_PIVOT_X = 0.0306011  # [V] finger_joint / right_outer_knuckle_joint at y = -+0.0306011 ...
OUTER_PIVOT_Z = 0.054904  # [V] ... z = 0.054904
# [V] outer knuckle -> outer finger (fixed): (y 0.0315, z -0.0041); outer finger -> inner finger
# joint: (y 0.0061, z 0.0471). Together [D] the distal pivot sits 37.6 mm out and 43.0 mm down the
# tool axis from the proximal one at finger_joint = 0.
DISTAL_OUT = 0.0315 + 0.0061
DISTAL_DOWN = -0.0041 + 0.0471
LINK_LENGTH = math.hypot(DISTAL_OUT, DISTAL_DOWN)  # [D] 57.12 mm, pivot to pivot
LINK_TILT = math.atan2(DISTAL_OUT, DISTAL_DOWN)  # [D] 41.17 deg outward from the tool axis when open
INNER_PIVOT_X = 0.0127  # [V] inner knuckle joints at y = -+0.0127 ...
INNER_PIVOT_Z = 0.06142  # [V] ... z = 0.06142 (the parallelogram's second base pivot)
PAD_INWARD = 0.0220203446692936  # [V] pad centre from the inner finger joint: inward ...
PAD_DOWN = 0.03242  # [V] ... and down the tool axis
PAD_SIZE = (0.00635, 0.022, 0.0375)  # [V] pad box: thickness (closing), width (across), length
# [D] the drive angle at which the pads touch: width(q) = 2 (OUTER_PIVOT_X + L sin(tilt - q) -
# PAD_INWARD - t / 2) = 0. Robotiq's description stops at 0.8 rad (1.5 mm apart).
PAD_FACE_OFFSET = OUTER_PIVOT_X - PAD_INWARD - PAD_SIZE[0] / 2
CLOSED = LINK_TILT + math.asin(PAD_FACE_OFFSET / LINK_LENGTH)
DRIVE_VELOCITY = 2.0  # [V] rad/s, the description's velocity limit
MAX_FORCE = 235.0  # [V] N, Robotiq 2F-85 grip force 20-235 N
DRIVE_EFFORT = 30.0  # [D] N m: 235 N x max |dw/dq| (2 L = 0.114 m/rad) = 26.8 N m, rounded up
# --- masses: the 2F-85 weighs 0.925 kg [V Robotiq]; the links' CAD masses from the description's
# inertials [V] (outer knuckle 8.53 g + outer finger 22.61 g, inner knuckle 27.12 g, inner finger
# 10.40 g), the pad [C] 2 g, the base the remainder [D] at the description's base COM z [V].
TOTAL_MASS = 0.925
OUTER_MASS = 0.00853 + 0.02261
INNER_KNUCKLE_MASS = 0.02712
INNER_FINGER_MASS = 0.0104
PAD_MASS = 0.002
BASE_COM_Z = 0.03145
# [C] as the RG2's: the geared drive's reflected inertia on each linkage link, so the gear
# constraints hold the four-bar under the squeeze (docs/decisions/0202-mimic-coupling.md).
ARMATURE = 1e-3
# --- shapes [C]: boxes around the published pivots ---------------------------------------------
LINK_THICKNESS = 0.008
LINK_WIDTH = 0.022  # as the pad
INNER_COLLISION_SHORT = 0.012  # the inner knuckle's box stops short of the finger, as the RG2's
FINGER_PLATE = 0.006  # the inner finger's plate behind the pad
# the housing: encloses the base pivots (+-30.6 mm, up to 61.4 mm) with a few mm around them
HOUSING = (2 * (OUTER_PIVOT_X + 0.012), 0.035, INNER_PIVOT_Z + 0.004)
GREY = "0.2 0.2 0.22 1"
LIGHT = "0.75 0.75 0.78 1"
BLACK = "0.1 0.1 0.1 1"


def base_mass() -> float:
    return TOTAL_MASS - 2 * (OUTER_MASS + INNER_KNUCKLE_MASS + INNER_FINGER_MASS + PAD_MASS)


def finger_xml(i: int, side: float) -> str:
    """Finger ``i`` (1 at -x, 2 at +x). Link frames sit at their pivots; a knuckle's z points along
    it to its far pivot (the joint origin turned by the open tilt); a positive drive closes."""
    name = "left" if i == 1 else "right"
    tilt = (0.0, side * LINK_TILT, 0.0)  # the knuckles lean outwards when open
    untilt = (0.0, -side * LINK_TILT, 0.0)
    axis = (0.0, -side, 0.0)  # rotation about this axis turns the knuckle inwards
    limit_knuckle = (0.0, CLOSED, DRIVE_EFFORT, DRIVE_VELOCITY)
    out = []
    size = (LINK_THICKNESS, LINK_WIDTH, LINK_LENGTH)
    body = parts.inertial(OUTER_MASS, (0.0, 0.0, LINK_LENGTH / 2), size, ARMATURE)
    body += parts.box("visual", (0.0, 0.0, LINK_LENGTH / 2), size, LIGHT)
    body += parts.box("collision", (0.0, 0.0, LINK_LENGTH / 2), size)
    out.append(parts.link(f"{name}_outer_knuckle", body))
    joint = DRIVE if i == 1 else "right_outer_knuckle_joint"
    out.append(
        parts.joint(
            joint,
            "revolute",
            BASE,
            f"{name}_outer_knuckle",
            (side * OUTER_PIVOT_X, 0.0, OUTER_PIVOT_Z),
            rpy=tilt,
            axis=axis,
            limit=limit_knuckle,
            mimic=None if i == 1 else (DRIVE, 1.0),
        )
    )
    inner_length = LINK_LENGTH - INNER_COLLISION_SHORT
    size = (LINK_THICKNESS, LINK_WIDTH, LINK_LENGTH)
    body = parts.inertial(INNER_KNUCKLE_MASS, (0.0, 0.0, LINK_LENGTH / 2), size, ARMATURE)
    body += parts.box("visual", (0.0, 0.0, LINK_LENGTH / 2), size, GREY)
    body += parts.box("collision", (0.0, 0.0, inner_length / 2), (LINK_THICKNESS, LINK_WIDTH, inner_length))
    out.append(parts.link(f"{name}_inner_knuckle", body))
    out.append(
        parts.joint(
            f"{name}_inner_knuckle_joint",
            "revolute",
            BASE,
            f"{name}_inner_knuckle",
            (side * INNER_PIVOT_X, 0.0, INNER_PIVOT_Z),
            rpy=tilt,
            axis=axis,
            limit=limit_knuckle,
            mimic=(DRIVE, 1.0),
        )
    )
    # the inner finger: parallel to the base; a plate from the pivot down behind the pad
    inward = -side
    plate_x = inward * (PAD_INWARD - PAD_SIZE[0] / 2 - FINGER_PLATE / 2)
    plate_top, plate_bottom = -0.006, PAD_DOWN + PAD_SIZE[2] / 2
    plate = (FINGER_PLATE, LINK_WIDTH, plate_bottom - plate_top)
    plate_xyz = (plate_x, 0.0, (plate_top + plate_bottom) / 2)
    head = (PAD_INWARD - PAD_SIZE[0] / 2, LINK_WIDTH, 0.014)  # from the pivot in to the plate
    head_xyz = (inward * head[0] / 2, 0.0, plate_top + head[2] / 2)
    body = parts.inertial(INNER_FINGER_MASS, plate_xyz, plate, ARMATURE)
    for xyz, box in ((plate_xyz, plate), (head_xyz, head)):
        body += parts.box("visual", xyz, box, GREY)
        body += parts.box("collision", xyz, box)
    out.append(parts.link(f"{name}_inner_finger", body))
    limit_finger = (-CLOSED, 0.0, DRIVE_EFFORT, DRIVE_VELOCITY)
    out.append(
        parts.joint(
            f"{name}_inner_finger_joint",
            "revolute",
            f"{name}_outer_knuckle",
            f"{name}_inner_finger",
            (0.0, 0.0, LINK_LENGTH),
            rpy=untilt,
            axis=axis,
            limit=limit_finger,
            mimic=(DRIVE, -1.0),
        )
    )
    body = parts.inertial(PAD_MASS, (0.0, 0.0, 0.0), PAD_SIZE)
    body += parts.box("visual", (0.0, 0.0, 0.0), PAD_SIZE, BLACK)
    body += parts.box("collision", (0.0, 0.0, 0.0), PAD_SIZE)
    out.append(parts.link(f"{name}_inner_finger_pad", body))
    out.append(
        parts.joint(
            f"{name}_inner_finger_pad_joint",
            "fixed",
            f"{name}_inner_finger",
            f"{name}_inner_finger_pad",
            (inward * PAD_INWARD, 0.0, PAD_DOWN),
        )
    )
    return "".join(out)


def tcp_z() -> float:
    """[D] the pad-centre midpoint along z with the pads touching (drive at CLOSED)."""
    return OUTER_PIVOT_Z + LINK_LENGTH * math.cos(LINK_TILT - CLOSED) + PAD_DOWN


def gripper_xml() -> str:
    body = parts.inertial(base_mass(), (0.0, 0.0, BASE_COM_Z), HOUSING)
    body += parts.box("visual", (0.0, 0.0, HOUSING[2] / 2), HOUSING, GREY)
    body += parts.box("collision", (0.0, 0.0, HOUSING[2] / 2), HOUSING)
    out = parts.link(BASE, body)
    out += finger_xml(1, -1.0) + finger_xml(2, 1.0)
    out += parts.frame_link("robotiq_2f85_tcp")
    out += parts.joint("robotiq_2f85_tcp_joint", "fixed", BASE, "robotiq_2f85_tcp", (0.0, 0.0, tcp_z()))
    return out


def urdf() -> str:
    return parts.robot("robotiq_2f85", "assets/grippers/robotiq_2f85/make_robotiq_2f85.py", gripper_xml())


def main() -> None:
    out = Path(__file__).with_name("robotiq_2f85.urdf")
    out.write_text(urdf())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
