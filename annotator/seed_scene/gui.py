"""The seed's slider loop in the PyBullet GUI, at real time (the one place that sleeps)."""

from __future__ import annotations

import functools
import time
from pathlib import Path

import click
import numpy as np

from annotator.objects import ObjectModel
from annotator.render import Camera, render_rgb, write_png
from annotator.seed_scene.capture import Capturer, capture_now
from annotator.seed_scene.demo import demo_script
from annotator.seed_scene.model import Scene, SeedSceneConfig, build_scene, open_world
from annotator.sim import gui
from annotator.sim.camera import OPENGL_RENDERER
from annotator.sim.ur3 import JOINT_NAMES
from annotator.store.outputs import Outputs

GRIPPER_SLIDER = "gripper_opening_angle"  # the seed's slider name
# Enter captures the current grasp (PyBullet's window binds many letter keys to its own toggles).
CAPTURE_KEYS = gui.RETURN_KEYS


def add_sliders(scene: Scene) -> dict[str, int]:
    """The seed's sliders: six joints over +-pi at the initial pose, and the gripper angle."""
    c = scene.config
    sliders = {
        name: gui.add_slider(scene.client, name, -c.slider_range, c.slider_range, q)
        for name, q in zip(JOINT_NAMES, c.initial_arm, strict=True)
    }
    lower, upper = scene.gripper_range()
    sliders[GRIPPER_SLIDER] = gui.add_slider(scene.client, GRIPPER_SLIDER, lower, upper, 0.0)
    return sliders


def read_sliders(scene: Scene, sliders: dict[str, int]) -> tuple[np.ndarray, float]:
    read = lambda name: gui.read_slider(scene.client, sliders[name])  # noqa: E731
    return np.array([read(n) for n in JOINT_NAMES]), read(GRIPPER_SLIDER)


def screenshot(scene: Scene) -> np.ndarray:
    """The GUI window's current view, (h, w, 3) uint8, rendered with the window's own camera."""
    width, height, view, projection = gui.window_camera(scene.client)
    camera = Camera(view, projection, width, height)
    return render_rgb(scene.client, camera, renderer=OPENGL_RENDERER)


def _capture_key_pressed(client: int) -> bool:
    return gui.key_triggered(client, CAPTURE_KEYS)


def _capture(scene: Scene, capturer: Capturer) -> None:
    candidate, row = capture_now(scene, capturer)
    r = row.iloc[0]
    chord = "the object's chord" if candidate.chord_found else "the current opening"
    text = f"capture {r['object_id']} #{r['grasp_id']}: {r['outcome']}, width {r['width'] * 1000:.1f} mm"
    click.echo(f"{text} (expected width {candidate.width * 1000:.1f} mm, {chord}) -> {capturer.written}")
    above = (scene.cube.base_pose().pos + [0.0, 0.0, 0.15]).tolist()
    gui.add_text(scene.client, text, above, [0.1, 0.1, 0.6], 1.2, seconds=4.0)


def run_gui(
    config: SeedSceneConfig,
    seconds: float | None,
    screenshot_path: Path | None,
    screenshot_at: float,
    demo: bool,
    capturer: Capturer | None = None,
    obj: ObjectModel | None = None,
    outputs: Outputs | None = None,
) -> None:
    """The seed's slider loop at real time until the window closes or ``seconds`` of sim time pass.

    With a ``capturer``, the capture key (Enter) runs the current grasp through the protocol and
    appends its label row (:func:`annotator.seed_scene.capture.capture_now`). ``obj`` replaces the cube.
    The screenshot is written through ``outputs`` (the command's, ``screenshot_path`` claimed as
    ``--screenshot``), or claimed here for the loop's life.
    """
    if screenshot_path is not None and outputs is None:
        with Outputs.claim("annotator scene", {"--screenshot": screenshot_path}) as claimed:
            return run_gui(config, seconds, screenshot_path, screenshot_at, demo, capturer, obj, claimed)
    world = open_world(config, gui=True)
    client = world.client
    # Every PyBullet call in GUI mode waits for the window thread; loading and the gripper's FK table with
    # rendering on took ~40 s under software OpenGL, ~1-10 s with it off.
    gui.set_rendering(client, False)
    scene = build_scene(world, config, obj)
    script = demo_script(scene) if demo else None
    gui.set_rendering(client, True)
    gui.set_camera(
        client, config.camera_distance, config.camera_yaw, config.camera_pitch, config.camera_target
    )
    sliders = add_sliders(scene)
    # One stepSimulation call per GUI frame, split into substeps of the usual time step.
    substeps = max(1, round(1.0 / (config.gui_rate * world.dt)))
    frame_dt = substeps * world.dt
    gui.set_frame(client, frame_dt, substeps)
    frame, start = 0, time.monotonic()
    try:
        while seconds is None or frame * frame_dt < seconds:
            try:
                if script is not None:
                    arm, angle = script.at((frame * frame_dt) % (script.duration + 1.0))
                else:
                    arm, angle = read_sliders(scene, sliders)
                scene.command_arm(arm)
                scene.command_gripper(angle)
                gui.step(client)
            except gui.WindowClosed:  # the window was closed
                break
            frame += 1
            t = frame * frame_dt
            if capturer is not None and _capture_key_pressed(client):
                _capture(scene, capturer)
            if screenshot_path is not None and t >= screenshot_at:
                assert outputs is not None
                written = outputs.write("--screenshot", functools.partial(write_png, screenshot(scene)))
                width, height = gui.window_camera(client)[:2]
                q = np.round(scene.arm_positions(), 4).tolist()
                click.echo(f"screenshot {width}x{height} at t={t:.2f} s, arm q = {q} -> {written}")
                screenshot_path = None
            lag = start + t - time.monotonic()
            if lag > 0:
                time.sleep(lag)  # real time in the interactive loop only
        if gui.is_open(client):
            wall = time.monotonic() - start
            q = np.round(scene.arm_positions(), 4).tolist()
            click.echo(f"ran {frame * frame_dt:.2f} s simulated in {wall:.2f} s; arm q = {q}")
    finally:
        world.close()
