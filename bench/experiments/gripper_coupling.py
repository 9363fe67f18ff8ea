"""What each gripper's coupling holds under its squeeze, lifted and shaken (gear vs position control).

    python -m bench.experiments.gripper_coupling [rg2 panda robotiq_2f85] [--force N] [--mass KG]
        [--non-contact-iterations K] [--solver-iterations K]

For each gripper, coupling ("gear", "position") and passive-link mode ("kinematic": the annotation
worlds' 120 solver iterations; "simulated": the whole linkage at 150): a 40 mm box (``--mass``,
default 200 g) is closed on from above with the grip force (``--force``, default the gripper's),
squeezed for 120 steps, then lifted 10 cm and shaken as the protocol does. Prints the steps the
close took (480: it never stalled), the width and the pads' normal forces after the squeeze, the
largest follower error over squeeze, lift and shake (deg for a linkage, mm for sliding fingers),
and how far the box moved in the hand. ``--non-contact-iterations`` / ``--solver-iterations``
change the annotation worlds' ``[physics]`` settings of the same names.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pybullet as pb

from annotator.config import AnnotatorConfig, GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.sim.hand import FloatingGripper, ShakeMotion
from annotator.sim.world import World
from bench.arguments import Parser, count, number
from bench.harness import Run

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # TCP +z pointing down: a top grasp
SIZE = 0.04  # m, the box's edge


def box(world: World, mass: float) -> int:
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[SIZE / 2] * 3, physicsClientId=world.client)
    uid = pb.createMultiBody(mass, shape, -1, [0.0, 0.0, 0.1], physicsClientId=world.client)
    pb.changeDynamics(uid, -1, lateralFriction=1.0, spinningFriction=0.002, physicsClientId=world.client)
    return uid


def run(
    name: str, coupling: str, passive: str, force: float | None, mass: float, base: PhysicsConfig
) -> dict[str, float | str]:
    """One gripper, coupling and passive-link mode squeezing, lifting and shaking the box: a row."""
    physics = base if passive == "kinematic" else base.whole_linkage()
    protocol = AnnotatorConfig().protocol
    with World(physics) as world:
        config = GripperConfig(coupling=coupling, passive_links=passive, grip_force=force)
        hand = FloatingGripper(world, config, name)
        g, force = hand.gripper, hand.grip_force
        uid = box(world, mass)
        T_world_tcp = Transform([0.0, 0.0, 0.1], DOWN)
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, SIZE), min(SIZE + 0.02, g.max_width))
        world.set_gravity(False)
        steps = hand.close(force=force, max_steps=480)
        errors = []

        def watch(_: int = 0) -> bool:
            errors.append(g.follower_errors().max())
            return False

        for _ in range(120):
            g.squeeze(force)
            world.step()
            watch()
        forces, width = g.pad_normal_forces(uid), g.measured_width()
        world.set_gravity(True)
        hand.move(
            Transform(hand.target.pos + [0, 0, 0.1], hand.target.quat),
            duration=protocol.lift_duration,
            force=force,
            on_step=watch,
        )
        p = protocol
        shake = ShakeMotion(p.shake_amplitude, p.shake_angle, p.shake_duration, paired=True)
        hand.shake(shake, force=force, on_step=watch)
        pos = pb.getBasePositionAndOrientation(uid, physicsClientId=world.client)[0]
        in_hand = (hand.base_pose().inverse() * Transform(pos, [0, 0, 0, 1])).pos
        slip = np.linalg.norm(in_hand - g.T_base_tcp(SIZE).pos)
        revolute = hand.description.drive_kind == "revolute"
        return {
            "gripper": name,
            "coupling": coupling,
            "passive_links": passive,
            "force_n": float(force),
            "close_steps": int(steps),
            "width_mm": float(width * 1000),
            "pad1_n": float(forces[0]),
            "pad2_n": float(forces[1]),
            "follower_error": float(np.degrees(max(errors)) if revolute else 1000 * max(errors)),
            "follower_unit": "deg" if revolute else "mm",
            "box_moved_mm": float(slip * 1000),
        }


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("grippers", nargs="*", default=["rg2", "panda", "robotiq_2f85"])
    ap.add_argument(
        "--force", type=number(0.0, 10_000.0, low_open=True), default=None, help="N (default: each gripper's)"
    )
    ap.add_argument("--mass", type=number(0.0, 100.0, low_open=True), default=0.2, help="kg, the box")
    ap.add_argument("--non-contact-iterations", type=count(1, 100_000), default=None)
    ap.add_argument("--solver-iterations", type=count(1, 100_000), default=None)
    return ap


def main() -> None:
    args = parser().parse_args()
    physics = PhysicsConfig()
    if args.non_contact_iterations is not None:
        physics = dataclasses.replace(physics, non_contact_iterations=args.non_contact_iterations)
    if args.solver_iterations is not None:
        physics = dataclasses.replace(physics, solver_iterations=args.solver_iterations)
    with Run("gripper_coupling", config=vars(args)) as record:
        rows = []
        for name in args.grippers:
            for coupling in ("gear", "position"):
                for passive in ("kinematic", "simulated"):
                    row = run(name, coupling, passive, args.force, args.mass, physics)
                    rows.append(row)
                    print(
                        f"{name:13s} {coupling:8s} {passive:9s} {row['force_n']:6.1f} N  close "
                        f"{row['close_steps']:3d} steps  width {row['width_mm']:6.2f} mm  pads "
                        f"{row['pad1_n']:6.1f} {row['pad2_n']:6.1f} N  follower {row['follower_error']:.3f} "
                        f"{row['follower_unit']}  box moved {row['box_moved_mm']:.1f} mm",
                        flush=True,
                    )
        record.table("couplings", rows, note="a 40 mm box squeezed 120 steps, lifted and shaken")


if __name__ == "__main__":
    main()
