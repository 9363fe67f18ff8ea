"""Scenes: several objects settled on the seed's table, their Kinect views, TSDF and point clouds.

:mod:`~annotator.scenes.records` (what a scene is, as data), :mod:`~annotator.scenes.arrange`
(pile, packed and table arrangements, settled with physics), :mod:`~annotator.scenes.world` (a
recorded scene loaded into a world), :mod:`~annotator.scenes.views` (Kinect v2 views on VGN's
sphere, instance segmentation, the fused point cloud), :mod:`~annotator.scenes.tsdf` (a TSDF
volume of a given resolution).
"""

from annotator.scenes.arrange import SceneBuilder, draw_objects
from annotator.scenes.records import (
    ARRANGEMENTS,
    Instance,
    SceneRecord,
    SceneSpec,
    Workspace,
    same_scene,
    scene_table,
    scenes_from_table,
)

__all__ = [
    "ARRANGEMENTS",
    "Instance",
    "SceneBuilder",
    "SceneRecord",
    "SceneSpec",
    "Workspace",
    "draw_objects",
    "same_scene",
    "scene_table",
    "scenes_from_table",
]
