"""The RG2 model: follower error under a 40 N squeeze (gear vs per-step position coupling), width
error over the stroke, squeeze force, and the UR3's FK error.

    python -m bench.experiments.rg2_coupling

Prints figures and writes a record (bench/harness.py); never a test. No timing: nothing here moves
with the machine's speed.
"""

from __future__ import annotations

import numpy as np

from annotator import paths
from annotator.config import GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import default_gripper
from annotator.sim import pb
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.hand import FloatingGripper
from annotator.sim.ur3 import JOINT_NAMES, dh_forward_kinematics
from annotator.sim.world import World
from bench.harness import Run

DOWN = np.array([1.0, 0.0, 0.0, 0.0])


def squeeze(
    coupling: str, passive: str = "simulated", size: float = 0.04, force: float = 40.0
) -> tuple[float, np.ndarray, float]:
    """Max follower error (deg) over 1 s of squeezing a 50 g box, pad forces (N), box drift (mm).

    ``passive``: the RG2's passive links simulated (the arm's, in a whole-linkage world) or
    kinematic (the annotation gripper, in an annotation world)."""
    physics = PhysicsConfig() if passive == "kinematic" else PhysicsConfig().whole_linkage()
    with World(physics) as world:
        hand = FloatingGripper(world, GripperConfig(coupling=coupling, passive_links=passive))
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[size / 2] * 3, physicsClientId=world.client)
        box = pb.createMultiBody(0.05, col, -1, [0, 0, 0.1], physicsClientId=world.client)
        pb.changeDynamics(box, -1, lateralFriction=1.0, physicsClientId=world.client)
        hand.teleport(hand.T_world_base_for_tcp(Transform([0, 0, 0.1], DOWN), size), size + 0.02)
        world.set_gravity(False)
        hand.close(force=force, max_steps=480)
        errors = []
        for _ in range(240):
            hand.gripper.command(-1.0, force)
            world.step()
            errors.append(hand.gripper.follower_errors().max())
        drift = np.linalg.norm(
            np.asarray(pb.getBasePositionAndOrientation(box, physicsClientId=world.client)[0]) - [0, 0, 0.1]
        )
        return float(np.degrees(max(errors))), hand.gripper.pad_normal_forces(box), drift * 1000


def width_errors() -> np.ndarray:
    """|measured - commanded| pad separation (mm) for 23 widths over the stroke, in free air."""
    with World(PhysicsConfig().whole_linkage()) as world:
        world.set_gravity(False)
        body = Body.load(world.client, default_gripper().urdf, fixed_base=True)
        rg2 = ParallelGripper(body, default_gripper(), GripperConfig(), urdf=default_gripper().urdf)
        out = []
        for width in np.linspace(0.0, 0.110, 23):
            for _ in range(240):
                rg2.hold_position(rg2.table.angle_of(width), 40.0)
                world.step()
            out.append(abs(rg2.measured_width() - width) * 1000)
        return np.array(out)


def ur3_fk_error(n: int = 200) -> float:
    """Max |tool0 (PyBullet) - DH FK| over n random configurations, mm (DH base frame)."""
    rng = np.random.default_rng(0)
    with World(PhysicsConfig()) as world:
        body = Body.load(world.client, paths.ur3_urdf(), fixed_base=True)
        worst = 0.0
        for _ in range(n):
            q = rng.uniform(-np.pi, np.pi, 6)
            body.reset_joints(dict(zip(JOINT_NAMES, q, strict=True)))
            T_world_base = body.link_pose("base")
            p = (T_world_base.inverse() * body.link_pose("tool0")).pos
            worst = max(worst, float(np.linalg.norm(p - dh_forward_kinematics(q)[:3, 3])))
        return worst * 1000


def main() -> None:
    physics = PhysicsConfig()
    with Run("rg2_coupling") as run:
        rows = []
        for coupling, passive in (("gear", "simulated"), ("position", "simulated"), ("gear", "kinematic")):
            err, forces, drift = squeeze(coupling, passive)
            its = physics.solver_iterations if passive == "kinematic" else physics.linkage_solver_iterations
            print(
                f"coupling={coupling:8s} passive links {passive:9s} ({its} iterations) 40 N squeeze on a "
                f"40 mm box: max follower error {err:6.3f} deg, "
                f"pad forces {forces[0]:5.1f} / {forces[1]:5.1f} N, "
                f"box drift {drift:5.1f} mm"
            )
            rows.append(
                {
                    "coupling": coupling,
                    "passive_links": passive,
                    "solver_iterations": its,
                    "max_follower_error_deg": err,
                    "pad_force_1_n": float(forces[0]),
                    "pad_force_2_n": float(forces[1]),
                    "box_drift_mm": drift,
                }
            )
        run.table("squeeze", rows, note="1 s of a 40 N squeeze on a 40 mm, 50 g box, gravity off")
        errs = width_errors()
        print(
            f"width command over 0..110 mm (23 widths): max error {errs.max():.3f} mm, "
            f"mean {errs.mean():.3f} mm"
        )
        run.figure(
            "width_error_max", float(errs.max()), "mm", note="|measured - commanded|, 23 widths in free air"
        )
        run.figure("width_error_mean", float(errs.mean()), "mm")
        with World(PhysicsConfig()) as world:
            body = Body.load(world.client, default_gripper().urdf, fixed_base=True)
            rg2 = ParallelGripper(body, default_gripper(), GripperConfig(), urdf=default_gripper().urdf)
            print(f"stroke from FK: {rg2.table.min_width * 1000:.2f} .. {rg2.max_width * 1000:.2f} mm")
            run.figure("stroke_min", rg2.table.min_width * 1000, "mm", note="pad separation from FK")
            run.figure("stroke_max", rg2.max_width * 1000, "mm")
        fk = ur3_fk_error()
        print(f"UR3 tool0 vs DH FK, 200 random q: max error {fk:.5f} mm")
        run.figure("ur3_fk_error_max", fk, "mm", note="tool0 in PyBullet vs the DH FK, 200 random q")


if __name__ == "__main__":
    main()
