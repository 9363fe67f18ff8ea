"""The gripper description GraspGen (NVlabs/GraspGen) needs for the labels' gripper.

GraspGen names a gripper by ``gripper_name`` and reads ``config/grippers/<gripper_name>.yaml``
(``grasp_gen/robot.py: get_gripper_info``; the keys in its ``docs/GRIPPER_DESCRIPTION.md``):

- ``width``: the distance between the fingers fully open (m): the model's widest opening;
- ``depth``: from the gripper's base frame to its TCP along +z (m); without a
  ``get_transform_from_base_link_to_tool_tcp`` in the gripper's Python config the tool tip is
  ``translation(0, 0, depth)`` of every grasp, which its training's visibility filter
  (``dataset_utils.filter_grasps_by_point_cloud_visibility``: the tool tip within 3 cm of the
  observed cloud) and its canonical control points (``(+/-width/2, 0, depth/2)``,
  ``(+/-width/2, 0, depth)``) use;
- ``transform_offset_from_asset_to_graspgen_convention``: ``[[x, y, z], [qx, qy, qz, qw]]`` from
  the gripper's asset frame to GraspGen's (+z approach, +x closing): the identity here, as every
  gripper description's base frame already has those axes (``[base] frame``);
- ``symmetric_antipodal``: a two-finger gripper turned 180 degrees about its approach is the same grasp;
- ``collision_mesh_fname``: the gripper's collision mesh (as GraspGen's suction cup names its own).

The export writes ``gripper/<export_type>.yaml`` and ``gripper/<export_type>_collision.obj``
(the name is the description's ``export_type``, the ``gripper/name`` of the grasp files). Every
number comes from the description and its model's forward kinematics: ``width`` the model's
widest opening (the description's ``[stroke] max``, reached by the FK), the collision mesh the
model's collision shapes at that opening in the base frame (metres). A linkage's TCP moves
along the tool axis as it opens (the RG2's from 161 mm below the flange fully open to 200 mm
closed), and GraspGen's TCP is fixed: ``depth`` is the middle of that travel, so the tool tip
GraspGen places is within half the travel (19.5 mm for the RG2, inside its 3 cm visibility
radius) of every grasp's true TCP; ``depth_open`` and ``depth_closed`` (ours, GraspGen does not
read them) give the ends, and each grasp's exact TCP is ``transform * translation(0, 0,
tcp_depth(width))`` with its ``width`` (the grasp files' frame note). GraspGen also wants a Python
config per gripper (``<gripper_name>.py``: a ``GripperModel`` that loads the collision mesh, and
its control points); the YAML holds what that needs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from annotator.geometry import Transform
from annotator.grippers import GripperDescription


@dataclass(frozen=True)
class GraspGenGripper:
    """The numbers of GraspGen's gripper YAML (module docstring), metres."""

    name: str
    width: float
    depth: float
    depth_open: float
    depth_closed: float
    collision_mesh_fname: str

    def yaml_text(self, description: GripperDescription) -> str:
        """The YAML file (flow style lists; every value a plain number or string)."""
        lines = [
            f"# GraspGen gripper description of {description.title} ({description.name}), written by "
            "annotator export from its gripper.toml and the model's forward kinematics.",
            "# Frame: the gripper's base link, " + description.base_frame.replace("\n", " "),
            f"gripper_name: {json.dumps(self.name)}",
            f"width: {self.width!r}  # m, pad faces fully open",
            f"depth: {self.depth!r}  # m, base to TCP: the middle of the TCP's travel over the stroke",
            "transform_offset_from_asset_to_graspgen_convention: [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]",
            "symmetric_antipodal: true",
            f"collision_mesh_fname: {json.dumps(self.collision_mesh_fname)}  # beside this file",
            f"depth_open: {self.depth_open!r}  # m, base to TCP fully open (not read by GraspGen)",
            f"depth_closed: {self.depth_closed!r}  # m, base to TCP closed (not read by GraspGen)",
        ]
        return "\n".join(lines) + "\n"


def graspgen_gripper(depth) -> GraspGenGripper:
    """The description of the gripper of ``depth`` (:class:`annotator.tools.export.TcpDepth`)."""
    name = depth.description.export_type
    ends = depth.T_base_tcp(np.array([depth.max_width, 0.0]))[:, 2, 3]
    return GraspGenGripper(
        name=name,
        width=float(depth.max_width),
        depth=float(np.mean(ends)),
        depth_open=float(ends[0]),
        depth_closed=float(ends[1]),
        collision_mesh_fname=f"{name}_collision.obj",
    )


def collision_mesh(description: GripperDescription, width: float, config=None) -> trimesh.Trimesh:
    """The model's collision shapes (boxes, spheres, cylinders, meshes) at opening ``width`` (m),
    in its base frame, as one mesh (metres). ``config``: a GripperConfig (default the defaults)."""
    from annotator.config import GripperConfig
    from annotator.sim import rigid
    from annotator.sim.body import Body
    from annotator.sim.gripper import ParallelGripper
    from annotator.sim.world import World

    parts = []
    with World() as world:
        body = Body.load(world.client, description.urdf, fixed_base=True)
        gripper = ParallelGripper(body, description, config or GripperConfig())
        gripper.reset_width(width)
        T_base_world = gripper.base_pose().inverse()
        client, uid = world.client, body.uid
        for index in [-1, *sorted(set(body.links.values()) - {-1})]:
            pos, orn = rigid.link_pose(client, uid, index)
            T_base_com = T_base_world * Transform(pos, orn)
            for shape in rigid.collision_shapes(client, uid, index):
                T_com_shape = Transform(shape.local_position, shape.local_orientation)
                parts.append(_shape_mesh(shape).apply_transform((T_base_com * T_com_shape).as_matrix()))
    if not parts:
        raise ValueError(f"{description.name}: its model has no collision shape")
    return trimesh.util.concatenate(parts)


def _shape_mesh(shape) -> trimesh.Trimesh:
    """One collision shape (:class:`annotator.sim.rigid.Shape`) as a mesh in its own frame."""
    kind, dims = shape.kind, shape.dimensions
    if kind == "box":
        return trimesh.creation.box(extents=np.asarray(dims, dtype=np.float64))
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=float(dims[0]))
    if kind in ("cylinder", "capsule"):
        make = trimesh.creation.cylinder if kind == "cylinder" else trimesh.creation.capsule
        return make(radius=float(dims[1]), height=float(dims[0]))
    if kind == "mesh":
        mesh = trimesh.load(shape.file, force="mesh")
        return mesh.apply_scale(np.asarray(dims, dtype=np.float64))
    raise ValueError(f"collision shape of kind {kind} is not supported")


def write_graspgen_gripper(folder, depth, config=None) -> list[Path]:
    """Write ``gripper/<name>.yaml`` and its collision mesh through ``folder`` (an
    :class:`annotator.tools.export.ExportFolder`); returns the two paths."""

    gg = graspgen_gripper(depth)
    mesh = collision_mesh(depth.description, gg.width, config)
    mesh_name, yaml_name = f"gripper/{gg.collision_mesh_fname}", f"gripper/{gg.name}.yaml"
    folder.target(mesh_name), folder.target(yaml_name)  # both refused before either is written
    text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False, digits=10)
    mesh_path = folder.write(mesh_name, lambda target: target.write_text(text))
    yaml_text = gg.yaml_text(depth.description)
    yaml_path = folder.write(yaml_name, lambda target: target.write_text(yaml_text))
    return [yaml_path, mesh_path]
