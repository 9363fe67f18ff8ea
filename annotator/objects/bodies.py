"""PyBullet bodies of loaded objects, and their poses in the mesh frame.

PyBullet reports and resets a body's pose at its centre of mass; :func:`get_object_pose` and
:func:`reset_object_pose` convert to and from the mesh frame. PyBullet's C-level output while a
shape is created (warnings printed by createCollisionShape) is captured at the file-descriptor
level and logged at DEBUG, so it never reaches the user's terminal.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from annotator.config import ObjectConfig
from annotator.geometry import Transform
from annotator.objects.errors import ObjectError
from annotator.sim import pb

if TYPE_CHECKING:
    from annotator.objects.model import ObjectModel

log = logging.getLogger(__name__)

# PyBullet's createVisualShape(vertices=..., indices=...) rejects very large arrays; bigger meshes
# get their convex hull as the visual (visuals only matter for pictures).
MAX_VISUAL_INDICES = 24_000
OBJECT_RGBA = (0.8, 0.55, 0.3, 1.0)


@contextlib.contextmanager
def quiet_c_output(what: str) -> Iterator[None]:
    """Capture what C code writes to fd 1 and 2 inside the block; log it at DEBUG."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = (os.dup(1), os.dup(2))
    except (AttributeError, OSError, ValueError):  # no real descriptors (embedded interpreters)
        yield
        return
    with tempfile.TemporaryFile() as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            sink.seek(0)
            text = sink.read().decode(errors="replace").strip()
            if text:
                log.debug("%s: PyBullet said: %s", what, text.replace("\n", " | ")[:2000])


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and a proper rotation (3, 3) whose columns are the principal axes."""
    moments, R = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1.0
    return np.maximum(moments, 0.0), R


def create_body(
    client: int,
    model: ObjectModel,
    T_world_obj: Transform | None = None,
    config: ObjectConfig | None = None,
) -> int:
    """A dynamic PyBullet body for ``model`` (an ObjectModel) in ``client``; returns its body id.

    Collision: the convex hull, or a compound of the convex parts (the cached multi-part .obj).
    Visual: the mesh. Mass and inertia from the model with the inertial frame at the centre of
    mass along the principal axes, so the body's link frame is the mesh frame; ``T_world_obj``
    places that frame. Friction: the model's (sidecar or ``config``); the contact settings of
    ``config`` (by default the one the model was loaded with).
    """
    config = config or model.config
    T_world_obj = T_world_obj or Transform.identity()
    if config.sat_features:
        return _create_body_with_sat(client, model, T_world_obj, config)
    with quiet_c_output(model.object_id):
        if len(model.parts) <= 1:
            hull = model.parts[0] if model.parts else model.mesh.convex_hull
            col = pb.createCollisionShape(
                pb.GEOM_MESH, vertices=np.asarray(hull.vertices).tolist(), physicsClientId=client
            )
        else:
            path = model.collision_file
            if path is None or not path.is_file():
                raise ObjectError(f"{model.object_id}: collision parts file missing: {path}")
            col = pb.createCollisionShape(pb.GEOM_MESH, fileName=str(path), physicsClientId=client)
        if col < 0:
            raise ObjectError(f"{model.object_id}: PyBullet rejected the collision shape")
        visual = model.mesh if 3 * len(model.mesh.faces) <= MAX_VISUAL_INDICES else model.mesh.convex_hull
        vis = pb.createVisualShape(
            pb.GEOM_MESH,
            vertices=np.asarray(visual.vertices).tolist(),
            indices=np.asarray(visual.faces).reshape(-1).tolist(),
            rgbaColor=list(OBJECT_RGBA),
            physicsClientId=client,
        )
    moments, R = principal_axes(model.inertia)
    T_obj_com = Transform.from_rotation(R, model.center_mass)
    pos, quat = T_world_obj.to_pybullet()
    body = pb.createMultiBody(
        baseMass=model.mass,
        baseCollisionShapeIndex=col,
        baseVisualShapeIndex=vis,
        basePosition=pos,
        baseOrientation=quat,
        baseInertialFramePosition=T_obj_com.pos.tolist(),
        baseInertialFrameOrientation=T_obj_com.quat.tolist(),
        physicsClientId=client,
    )
    pb.changeDynamics(
        body,
        -1,
        localInertiaDiagonal=moments.tolist(),
        lateralFriction=model.friction,
        spinningFriction=config.spinning_friction,
        rollingFriction=config.rolling_friction,
        collisionMargin=config.collision_margin,
        physicsClientId=client,
    )
    return body


def _create_body_with_sat(
    client: int, model: ObjectModel, T_world_obj: Transform, config: ObjectConfig
) -> int:
    """:func:`create_body` with the convex shapes' polyhedral features (``[objects]
    sat_features``): a face against a flat pad then gives its whole contact patch at once (Bullet
    clips the two hulls) instead of a point per step. PyBullet builds them only for shapes a URDF
    brings (``URDF_INITIALIZE_SAT_FEATURES``), so the body is loaded from a URDF written for it:
    the same collision shape (the hull, or the parts file), mass, centre of mass and principal
    inertia, the mesh (or its hull) as the visual."""
    import trimesh

    moments, R = principal_axes(model.inertia)
    T_obj_com = Transform.from_rotation(R, model.center_mass)
    rpy = _rpy(T_obj_com.rotation)
    with tempfile.TemporaryDirectory(prefix="rg2-body-") as folder:
        if len(model.parts) <= 1:
            hull = model.parts[0] if model.parts else model.mesh.convex_hull
            collision = os.path.join(folder, "collision.obj")
            trimesh.Trimesh(hull.vertices, hull.faces, process=False).export(collision)
        else:
            if model.collision_file is None or not model.collision_file.is_file():
                raise ObjectError(f"{model.object_id}: collision parts file missing: {model.collision_file}")
            collision = str(model.collision_file)
        small = 3 * len(model.mesh.faces) <= MAX_VISUAL_INDICES
        visual_mesh = model.mesh if small else model.mesh.convex_hull
        visual = os.path.join(folder, "visual.obj")
        visual_mesh.export(visual)
        ixx, iyy, izz = (float(v) for v in moments)
        xyz = " ".join(repr(float(v)) for v in T_obj_com.pos)
        urdf = os.path.join(folder, "object.urdf")
        with open(urdf, "w", encoding="utf-8") as fh:
            fh.write(
                f'<robot name="object"><link name="base"><inertial><origin xyz="{xyz}" '
                f'rpy="{" ".join(repr(v) for v in rpy)}"/><mass value="{model.mass!r}"/>'
                f'<inertia ixx="{ixx!r}" iyy="{iyy!r}" izz="{izz!r}" ixy="0" ixz="0" iyz="0"/></inertial>'
                f'<visual><geometry><mesh filename="{visual}"/></geometry>'
                f'<material name="m"><color rgba="{" ".join(map(str, OBJECT_RGBA))}"/></material></visual>'
                f'<collision><geometry><mesh filename="{collision}"/></geometry></collision></link></robot>'
            )
        pos, quat = T_world_obj.to_pybullet()
        with quiet_c_output(model.object_id):
            body = pb.loadURDF(
                urdf,
                pos,
                quat,
                flags=pb.URDF_INITIALIZE_SAT_FEATURES | pb.URDF_USE_INERTIA_FROM_FILE,
                physicsClientId=client,
            )
    if body < 0:
        raise ObjectError(f"{model.object_id}: PyBullet rejected the collision shape")
    # loadURDF places the link frame: the mesh frame at T_world_obj, as createMultiBody's base pose
    pb.changeDynamics(
        body,
        -1,
        lateralFriction=model.friction,
        spinningFriction=config.spinning_friction,
        rollingFriction=config.rolling_friction,
        collisionMargin=config.collision_margin,
        physicsClientId=client,
    )
    return body


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF's fixed-axis roll, pitch, yaw (rad) of the rotation ``R`` (3, 3)."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        roll = float(np.arctan2(R[2, 1], R[2, 2]))
        yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    else:  # gimbal lock: yaw carries the rotation about z
        roll, yaw = 0.0, float(np.arctan2(-R[0, 1], R[1, 1]))
    return roll, pitch, yaw


def _T_com_obj(client: int, body: int) -> Transform:
    info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
    return Transform(np.asarray(info[3]), np.asarray(info[4])).inverse()


def get_object_pose(client: int, body: int) -> Transform:
    """``T_world_obj`` of the body's mesh frame (PyBullet's base pose is its centre of mass)."""
    T_world_com = Transform.from_pybullet(pb.getBasePositionAndOrientation(body, physicsClientId=client))
    return T_world_com * _T_com_obj(client, body)


def reset_object_pose(client: int, body: int, T_world_obj: Transform) -> None:
    """Teleport the body so its mesh frame is at ``T_world_obj`` (velocities are left unchanged)."""
    T_world_com = T_world_obj * _T_com_obj(client, body).inverse()
    pos, quat = T_world_com.to_pybullet()
    pb.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=client)
