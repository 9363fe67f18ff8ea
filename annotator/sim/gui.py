"""The PyBullet GUI's own controls, for the seed's interactive scene: sliders, text in the window,
the window's camera, its keys, its rendering switch and the frame's sub-steps. PyBullet raises
:data:`WindowClosed` from any call once the window is closed."""

from __future__ import annotations

from collections.abc import Sequence

from annotator.sim import pb

# What any call on a GUI client raises once its window is closed.
WindowClosed = pb.error
# The Enter key, as PyBullet's window reports it (and its ASCII code).
RETURN_KEYS = (pb.B3G_RETURN, 13)


def add_slider(client: int, name: str, low: float, high: float, start: float) -> int:
    """A slider in the window's side panel; its id for :func:`read_slider`."""
    slider: int = pb.addUserDebugParameter(name, low, high, start, physicsClientId=client)
    return slider


def read_slider(client: int, slider: int) -> float:
    return float(pb.readUserDebugParameter(slider, physicsClientId=client))


def window_camera(client: int) -> tuple[int, int, tuple[float, ...], tuple[float, ...]]:
    """The window's size (pixels) and its camera's view and projection matrices."""
    width, height, view, projection = pb.getDebugVisualizerCamera(physicsClientId=client)[:4]
    return width, height, tuple(view), tuple(projection)


def key_triggered(client: int, keys: Sequence[int]) -> bool:
    """Whether any of ``keys`` was pressed since the last call."""
    events = pb.getKeyboardEvents(physicsClientId=client)
    return any(events.get(k, 0) & pb.KEY_WAS_TRIGGERED for k in keys)


def add_text(
    client: int, text: str, position: Sequence[float], color: Sequence[float], size: float, seconds: float
) -> None:
    """``text`` at ``position`` (world, m) for ``seconds``."""
    pb.addUserDebugText(text, list(position), list(color), size, lifeTime=seconds, physicsClientId=client)


def set_rendering(client: int, on: bool) -> None:
    """Switch the window's rendering (off while loading: every call waits for the window thread)."""
    pb.configureDebugVisualizer(pb.COV_ENABLE_RENDERING, int(on), physicsClientId=client)


def set_camera(client: int, distance: float, yaw: float, pitch: float, target: Sequence[float]) -> None:
    """The window's orbit camera (m, degrees) about ``target``."""
    pb.resetDebugVisualizerCamera(distance, yaw, pitch, list(target), physicsClientId=client)


def set_frame(client: int, frame_dt: float, substeps: int) -> None:
    """One ``stepSimulation`` advances ``frame_dt`` s in ``substeps`` steps."""
    pb.setPhysicsEngineParameter(fixedTimeStep=frame_dt, numSubSteps=substeps, physicsClientId=client)


def step(client: int) -> None:
    """One frame (:func:`set_frame`); :data:`WindowClosed` once the window is closed."""
    pb.stepSimulation(physicsClientId=client)


def is_open(client: int) -> bool:
    return bool(pb.isConnected(physicsClientId=client))
