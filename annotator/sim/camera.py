"""PyBullet's software cameras: the view and projection matrices it computes and the images it
renders of a client's bodies (RGBA, depth buffer, segmentation), for the renderers above the
physics layer (:mod:`annotator.render`, the Kinect's views)."""

from __future__ import annotations

from collections.abc import Sequence

from annotator.sim import pb

# The renderers: the software one (any machine), the OpenGL one (a GUI client only).
TINY_RENDERER = pb.ER_TINY_RENDERER
OPENGL_RENDERER = pb.ER_BULLET_HARDWARE_OPENGL


def view_from_yaw_pitch(
    target: Sequence[float], distance: float, yaw: float, pitch: float
) -> tuple[float, ...]:
    """The view matrix (16, column-major) of an orbit camera about ``target`` (degrees, z up)."""
    view = pb.computeViewMatrixFromYawPitchRoll(
        cameraTargetPosition=list(target), distance=distance, yaw=yaw, pitch=pitch, roll=0.0, upAxisIndex=2
    )
    return tuple(view)


def view_from_eye(eye: Sequence[float], target: Sequence[float], up: Sequence[float]) -> tuple[float, ...]:
    """The view matrix (16, column-major) of a camera at ``eye`` looking at ``target``, ``up`` up."""
    view = pb.computeViewMatrix(cameraEyePosition=eye, cameraTargetPosition=target, cameraUpVector=up)
    return tuple(view)


def projection_fov(fov: float, aspect: float, near: float, far: float) -> tuple[float, ...]:
    """The projection matrix (16) of a vertical field of view ``fov`` (degrees)."""
    return tuple(pb.computeProjectionMatrixFOV(fov=fov, aspect=aspect, nearVal=near, farVal=far))


def camera_image(
    client: int,
    width: int,
    height: int,
    view: Sequence[float],
    projection: Sequence[float],
    renderer: int = TINY_RENDERER,
) -> tuple:
    """``(rgba, zbuffer, segmentation)``: PyBullet's raw buffers of the image ``width`` x ``height``."""
    _, _, rgba, zbuffer, seg = pb.getCameraImage(
        width,
        height,
        viewMatrix=list(view),
        projectionMatrix=list(projection),
        renderer=renderer,
        physicsClientId=client,
    )
    return rgba, zbuffer, seg
