"""Generate the Franka Hand (Panda gripper) URDF from published numbers (see README.md beside this file).

Run ``python assets/grippers/panda/make_panda.py`` to rewrite ``panda.urdf``. Every collision shape
is a box written here; no mesh or URDF of another project is used.

Base frame (``panda_hand_base``): Franka's hand frame ``panda_hand`` (origin on the hand's mounting
face, the arm's flange; +z towards the fingertips) turned -90 deg about z, so that the fingers close
along x as in ACRONYM's and GraspGen's Panda grasps: x_here = -y_franka, y_here = x_franka. Finger 1
(Franka's left finger, ``panda_finger_joint1``, the drive) sits at -x, finger 2 at +x.
Tags: [V] read in a published source, [D] derived from [V] numbers, [C] our modelling choice.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import urdf_parts as parts  # noqa: E402  (assets/grippers/urdf_parts.py: the shared URDF writer)

BASE = "panda_hand_base"
DRIVE = "panda_finger_joint1"
FOLLOWER = "panda_finger_joint2"
# --- stroke and fingers: franka_description (franka_ros, robots/common/franka_hand.xacro) -------
FINGER_Z = 0.0584  # [V] both finger joints' origin along the hand's z (the carriage's slide)
FINGER_TRAVEL = 0.04  # [V] joint limits 0 .. 0.04 m per finger: the 80 mm stroke of the datasheet
FINGER_VELOCITY = 0.2  # [V] m/s, the finger joints' velocity limit
MAX_FORCE = 140.0  # [V] N, the datasheet's peak grasping force (70 N continuous)
DRIVE_EFFORT = 2 * MAX_FORCE  # [D] N: the drive reacts both pads' squeeze (virtual work, w = 2 q)
# The finger's collision boxes in Franka's finger frame, (y, z) centre and (x, y, z) size, m [V];
# here (x, z) = (-y, z) for finger 1 and the size's x and y swap (x across is y here).
RUBBER_TIP = ((0.00758, 0.04525), (0.0175, 0.0152, 0.0185))  # "rubber tip with which to grasp"
SCREW_MOUNT = ((0.0185, 0.011), (0.022, 0.015, 0.020))
CARRIAGE_SLEDGE = ((0.0068, 0.0022), (0.022, 0.0088, 0.0038))
DIAGONAL_FINGER = ((0.0159, 0.02835), (0.0175, 0.007, 0.0235))
DIAGONAL_TILT = math.pi / 6  # [V] the diagonal box turned 30 deg about the across axis
# --- masses: franka_description robots/common/inertial.yaml (identified, Gaz et al. 2019) --------
HAND_MASS = 0.73  # [V] kg
HAND_COM = (0.0, -0.01, 0.03)  # [D] Franka's (-0.01, 0, 0.03) in this frame
HAND_MOMENTS = (0.0025, 0.001, 0.0017)  # [D] Franka's (xx 0.001, yy 0.0025, zz 0.0017) turned
FINGER_MASS = 0.015  # [V] kg per finger, of which [C] 5 g in the pad link (the rubber tip)
PAD_MASS = 0.005
# [C] The drive's reflected inertia on each finger, as mass (the prismatic analogue of the RG2's
# armature, 3 x 1e-3 kg m^2 on ~55 mm links ~ 1 kg at its pad; URDF has no joint armature). With
# the fingers' own 15 g the solver let a 70 N squeeze reach 12 N on a 200 g box; 0.5 kg reached
# 70 N there but 55 N on a 50 g box; 1 kg 69 N on it and 140 N on the 200 g box
# (docs/decisions/0202-mimic-coupling.md). The model weighs 2 kg more for it (only the carrier feels it).
REFLECTED_MASS = 1.0
# --- the hand's housing: franka_description's self-collision capsule of the hand (radius 0.04 m,
# 0.1 m long along the closing axis, at z 0.04) as a box [D] 0.18 x 0.08, from the mounting face
# [C] down to the fingers' slide at FINGER_Z (below it the fingers' own boxes take over).
HOUSING = (0.18, 0.08, FINGER_Z)
GREY = "0.85 0.85 0.87 1"
DARK = "0.25 0.25 0.27 1"
BLACK = "0.1 0.1 0.1 1"


def _xz(yz: tuple[float, float], side: float) -> tuple[float, float, float]:
    """A point of Franka's finger frame (its y, z) in finger ``side``'s frame here (-1: finger 1)."""
    return (side * yz[0], 0.0, yz[1])


def _size(size: tuple[float, float, float]) -> tuple[float, float, float]:
    """Franka's (x, y, z) box size in this frame (x and y swap)."""
    return (size[1], size[0], size[2])


def finger_xml(i: int, side: float) -> str:
    """Finger ``i`` (1 at -x, 2 at +x): its prismatic joint, its body and its pad link."""
    name = "leftfinger" if i == 1 else "rightfinger"
    mass = FINGER_MASS - PAD_MASS + REFLECTED_MASS
    body = parts.inertial(mass, _xz(SCREW_MOUNT[0], side), _size(SCREW_MOUNT[1]))
    for centre, size in (SCREW_MOUNT, CARRIAGE_SLEDGE):
        body += parts.box("visual", _xz(centre, side), _size(size), DARK)
        body += parts.box("collision", _xz(centre, side), _size(size))
    # the diagonal part turns its long (z) axis towards the other finger: about +y for finger 1
    tilt = (0.0, -side * DIAGONAL_TILT, 0.0)
    body += parts.box("visual", _xz(DIAGONAL_FINGER[0], side), _size(DIAGONAL_FINGER[1]), DARK, tilt)
    body += parts.box("collision", _xz(DIAGONAL_FINGER[0], side), _size(DIAGONAL_FINGER[1]), rpy=tilt)
    out = parts.link(f"panda_{name}", body)
    limit = (0.0, FINGER_TRAVEL, DRIVE_EFFORT, FINGER_VELOCITY)
    mimic = None if i == 1 else (DRIVE, 1.0)
    joint = DRIVE if i == 1 else FOLLOWER
    axis = (side, 0.0, 0.0)  # a larger joint position moves the finger outwards: opens
    out += parts.joint(
        joint, "prismatic", BASE, f"panda_{name}", (0.0, 0.0, FINGER_Z), axis=axis, limit=limit, mimic=mimic
    )
    pad_size = _size(RUBBER_TIP[1])
    pad = parts.inertial(PAD_MASS, (0.0, 0.0, 0.0), pad_size)
    pad += parts.box("visual", (0.0, 0.0, 0.0), pad_size, BLACK)
    pad += parts.box("collision", (0.0, 0.0, 0.0), pad_size)
    out += parts.link(f"panda_{name}_pad", pad)
    out += parts.joint(
        f"panda_{name}_pad_joint", "fixed", f"panda_{name}", f"panda_{name}_pad", _xz(RUBBER_TIP[0], side)
    )
    return out


def tcp_z() -> float:
    """[D] the pad-centre midpoint along z (the same at every opening: the fingers slide)."""
    return FINGER_Z + RUBBER_TIP[0][1]


def gripper_xml() -> str:
    base = parts.inertial_moments(HAND_MASS, HAND_COM, HAND_MOMENTS)
    base += parts.box("visual", (0.0, 0.0, HOUSING[2] / 2), HOUSING, GREY)
    base += parts.box("collision", (0.0, 0.0, HOUSING[2] / 2), HOUSING)
    out = parts.link(BASE, base)
    out += finger_xml(1, -1.0) + finger_xml(2, 1.0)
    out += parts.frame_link("panda_tcp")
    out += parts.joint("panda_tcp_joint", "fixed", BASE, "panda_tcp", (0.0, 0.0, tcp_z()))
    return out


def urdf() -> str:
    return parts.robot("franka_hand", "assets/grippers/panda/make_panda.py", gripper_xml())


def main() -> None:
    out = Path(__file__).with_name("panda.urdf")
    out.write_text(urdf())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
