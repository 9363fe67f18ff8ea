"""The seed scene (UR3 + RG2, table, Kinect, cube) as a feature: a slider GUI and headless recording.

``annotator scene`` opens the PyBullet GUI with the seed's sliders; ``annotator scene --headless
--gif out.gif`` plays a scripted sequence (sweep, reach towards the cube, open, close, lift) in
DIRECT mode and records it with the software renderer. Parts: ``model`` (the scene on the cell),
``demo`` (the scripted sequence), ``gui`` (the slider loop), ``capture`` (a grasp captured by
hand); the click command is :mod:`annotator.cli.scene`.
"""

from annotator.seed_scene.model import Scene, SeedSceneConfig, build_scene, open_world

__all__ = ["Scene", "SeedSceneConfig", "build_scene", "open_world"]
