"""Render the RG2 with its TCP frame (x red, y green, z blue) to ``tcp_frame.png`` beside this file.

python docs/images/draw_tcp.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb

from annotator import paths
from annotator.geometry import Transform
from annotator.grippers import default_gripper
from annotator.render import orbit_camera, render_rgb, write_png
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.world import World

WIDTH = 0.06  # m, the opening drawn
AXIS_LENGTH, AXIS_THICKNESS = 0.06, 0.003


def main() -> None:
    with World() as world:
        c = world.client
        # approach (+z of the gripper) pointing down, as in a top grasp
        body = Body.load(c, paths.rg2_urdf(), Transform([0, 0, 0.3], [1.0, 0, 0, 0]), fixed_base=True)
        rg2 = ParallelGripper(body, default_gripper())
        rg2.reset_width(WIDTH)
        T_world_tcp = body.link_pose("rg2_base_link") * rg2.T_base_tcp(WIDTH)
        for axis, rgba in enumerate(([0.9, 0.1, 0.1, 1], [0.1, 0.8, 0.1, 1], [0.1, 0.2, 0.95, 1])):
            half = np.full(3, AXIS_THICKNESS / 2)
            half[axis] = AXIS_LENGTH / 2
            centre = T_world_tcp.apply(np.eye(3)[axis] * AXIS_LENGTH / 2)
            vis = pb.createVisualShape(
                pb.GEOM_BOX, halfExtents=half.tolist(), rgbaColor=rgba, physicsClientId=c
            )
            pb.createMultiBody(0, -1, vis, centre.tolist(), T_world_tcp.quat.tolist(), physicsClientId=c)
        camera = orbit_camera(tuple(T_world_tcp.pos + [0, 0, 0.06]), 0.42, 35, -20, 640, 480, fov=45)
        out = Path(__file__).with_name("tcp_frame.png")
        write_png(render_rgb(c, camera), out)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
