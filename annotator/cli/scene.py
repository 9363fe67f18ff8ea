"""``annotator scene``: the seed scene in the GUI (sliders) or headless (GIF/PNG of the demo)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from annotator.cli.common import (
    CONTEXT,
    GRIPPER_OPTION,
    file_option,
    overwrite_option,
)


@click.command("scene", context_settings=CONTEXT)
@click.option("--headless", is_flag=True, help="No window: play the scripted sequence in DIRECT mode.")
@file_option(
    "--gif",
    "gif_path",
    help="Headless: write an animated GIF.",
)
@file_option(
    "--png",
    "png_path",
    help="Headless: write the last frame as PNG.",
)
@file_option(
    "--kinect-png",
    "kinect_path",
    help="Headless: write the Kinect v2's colour image at the end (1920x1080, 84.1 x 53.8 deg) as PNG.",
)
@file_option(
    "--kinect-depth",
    "kinect_depth_path",
    help="Headless: write the Kinect v2's depth at the end (512x424, 70.6 x 60 deg) as a 16-bit PNG in mm.",
)
@click.option(
    "--frames",
    default=40,
    show_default=True,
    type=click.IntRange(min=2, max=2000),
    help="Headless: GIF frames (2..2000).",
)
@click.option(
    "--size",
    default=(320, 240),
    show_default=True,
    type=(click.IntRange(16, 4096), click.IntRange(16, 4096)),
    help="Headless: frame width height (pixels, 16..4096 each).",
)
@click.option(
    "--fov",
    type=click.FloatRange(1, 170),
    help="Headless: vertical field of view, degrees [default: 60; the GUI window's is 90].",
)
@click.option(
    "--seconds", type=click.FloatRange(min=0), help="GUI: quit after this much simulated (= real) time."
)
@file_option(
    "--screenshot",
    "screenshot_path",
    help="GUI: save the window's view as PNG once --screenshot-at seconds have run.",
)
@click.option(
    "--screenshot-at", default=0.5, show_default=True, type=click.FloatRange(min=0), help="GUI: when (s)."
)
@click.option(
    "--demo", is_flag=True, help="GUI: play the scripted sequence (looping) instead of reading the sliders."
)
@file_option(
    "--object",
    "object_path",
    help="An object (mesh or object URDF, metres) instead of the seed's cube, resting on the table "
    "0.35 m in front of the arm.",
    exists=True,
)
@file_option(
    "--capture-out",
    default=Path("captures.parquet"),
    show_default=True,
    help="GUI: Enter captures the current grasp on the object, runs the label protocol on it and "
    "appends the row here (a file this tool wrote; another is refused unless --overwrite).",
)
@GRIPPER_OPTION
@overwrite_option(
    "Replace a --gif, --png, --kinect-png, --kinect-depth or --screenshot this tool did not write (or "
    "one edited since); a --capture-out it did not write is started anew (one it wrote is appended to)."
)
def scene_command(
    headless: bool,
    gif_path: Path | None,
    png_path: Path | None,
    kinect_path: Path | None,
    kinect_depth_path: Path | None,
    frames: int,
    size: tuple[int, int],
    fov: float | None,
    seconds: float | None,
    screenshot_path: Path | None,
    screenshot_at: float,
    demo: bool,
    object_path: Path | None,
    capture_out: Path,
    gripper: str | None,
    overwrite: bool,
) -> None:
    """The seed scene: UR3 + RG2 (or --gripper) at the origin, table, cube and a Kinect looking
    down at the table.

    \b
    GUI (default): sliders for the six arm joints (+-pi, starting at 0, -pi/2, 0, 0, pi/2, 0) and
    `gripper_opening_angle`, the RG2's driven joint over the model's own URDF limits
    (-0.045 .. 1.268 rad, 0 .. 110 mm, the full RG2 stroke; the seed's slider stopped at 0.8 rad,
    which is only ~84 mm on this model). Each step the arm joints are position-controlled to the
    sliders with the URDF effort limits, the gripper holds the slider angle with the 40 N grip force
    (followers coupled by gear constraints), and the loop runs at real time. Close the window or
    pass --seconds to stop.

    \b
    Capture (GUI): put the gripper around the object with the sliders and press Enter: the grasp
    (its pose relative to the object, the expected width from the object's chord along the
    closing axis) runs through the same trial as `annotate` (close, lift, shake) and one row with
    the label schema is appended to --capture-out.

    \b
    Headless (--headless): no window; the scripted sequence (sweep the joints, open, reach
    towards the cube from the side, close, lift) runs in simulated time and is rendered with the
    software renderer from the seed's camera (distance 2, yaw 0, pitch -40, target 0.5 -0.9 0.5).

    \b
    Examples:
      annotator scene
      annotator scene --headless --gif scene.gif --png last.png --kinect-png kinect.png
      annotator scene --headless --kinect-depth depth.png
      xvfb-run -a annotator scene --demo --seconds 3 --screenshot-at 2 --screenshot window.png
      annotator scene --object objects/mug.obj --capture-out mug_captures.parquet
    """
    from annotator.cell.kinect import write_depth_png
    from annotator.config import AnnotatorConfig
    from annotator.grippers import DescriptionError, load_gripper
    from annotator.objects import ObjectError
    from annotator.render import write_gif, write_png
    from annotator.seed_scene.capture import Capturer, load_capture_object
    from annotator.seed_scene.demo import demo_script, run_script
    from annotator.seed_scene.gui import run_gui
    from annotator.seed_scene.model import SeedSceneConfig, build_scene, open_world

    try:
        description = load_gripper(gripper)
    except DescriptionError as exc:
        raise click.UsageError(f"--gripper: {exc}") from exc
    config = SeedSceneConfig(description=description)
    labels_config = AnnotatorConfig()
    try:
        obj = load_capture_object(object_path, labels_config, config.cube_urdf)
    except ObjectError as exc:
        raise click.UsageError(f"--object {object_path}: {exc}") from exc
    scene_obj = obj if object_path is not None else None  # the seed's own cube body otherwise
    from annotator.tools.common import claim_outputs

    if not headless:
        if gif_path or png_path or kinect_path or kinect_depth_path:
            raise click.UsageError("--gif, --png, --kinect-png and --kinect-depth need --headless")
        gui_outputs = {"--capture-out": capture_out, "--screenshot": screenshot_path}
        claimed_gui = claim_outputs("annotator scene", gui_outputs, overwrite)  # before the window opens
        capturer = Capturer(obj, labels_config, capture_out, description, outputs=claimed_gui)
        try:
            run_gui(config, seconds, screenshot_path, screenshot_at, demo, capturer, scene_obj, claimed_gui)
        finally:
            capturer.close()
        return
    if screenshot_path:
        raise click.UsageError("--screenshot is for the GUI; use --png with --headless")
    outputs = {
        "--gif": gif_path,
        "--png": png_path,
        "--kinect-png": kinect_path,
        "--kinect-depth": kinect_depth_path,
    }
    claimed = claim_outputs("annotator scene", outputs, overwrite)
    with open_world(config, gui=False) as world:
        scene = build_scene(world, config, scene_obj)
        camera = scene.seed_camera(*size, fov=fov) if (gif_path or png_path) else None
        try:
            script = demo_script(scene)
        except ValueError as exc:  # the seed's cube lies beyond the arm's reach with a shorter gripper
            raise click.UsageError(
                f"the scripted demo cannot reach the seed's cube with the {description.name} ({exc}); "
                "it is laid out for the RG2's reach: use the GUI (without --headless)"
            ) from exc
        rec = run_script(scene, script, camera, frames if gif_path else 2)
        if gif_path:
            fps = len(rec.frames) / script.duration
            written = claimed.write("--gif", lambda tmp: write_gif(rec.frames, tmp, fps=fps))
            click.echo(f"gif: {len(rec.frames)} frames {size[0]}x{size[1]} -> {written}")
        if png_path:
            click.echo(f"png -> {claimed.write('--png', lambda tmp: write_png(rec.frames[-1], tmp))}")
        if kinect_path or kinect_depth_path:
            view = scene.cell.render_kinect(color=kinect_path is not None)
            if kinect_path:
                written = claimed.write("--kinect-png", lambda tmp: write_png(view.color, tmp))
                click.echo(f"kinect colour png -> {written}")
            if kinect_depth_path:
                written = claimed.write("--kinect-depth", lambda tmp: write_depth_png(view.depth, tmp))
                seen = view.depth[view.depth > 0]
                click.echo(
                    f"kinect depth png (mm) -> {written}: "
                    f"{seen.min():.3f} .. {seen.max():.3f} m over {seen.size} pixels"
                )
        click.echo(
            f"arm q = {np.round(rec.arm, 4).tolist()}; gripper width {rec.gripper_width * 1000:.1f} mm; "
            f"cube at {np.round(rec.cube_pos, 3).tolist()}"
        )
