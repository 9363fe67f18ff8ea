"""What the cell's Kinect v2 sees of a round's pile now: an :class:`~annotator.policies.records.Observation`.

The views are the scene's own (:func:`annotator.scenes.views.view_pose`: view v of round r is view
v of scene r of ``annotate --scenes`` with the same seed, so a learner sees the piles from where
its training views were taken), rendered from the round's world as it is (the arm at READY,
objects taken away gone), with the depth noise of ``[kinect] views_depth_noise`` as ``annotate``
renders it. The arm's own pixels are taken out of each depth image (0, no measurement), as a real
cell filters its robot out with the robot's model and joint angles; nothing else of the
segmentation is used. Only the depth images leave this module: no segmentation, no mesh, no pose.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from annotator.policies.records import CameraImage, Observation, _frozen
from annotator.scenes.records import SceneRecord
from annotator.scenes.tsdf import fuse
from annotator.scenes.views import SEG_ROBOT, SceneView, render_views

if TYPE_CHECKING:
    from annotator.policies.round_world import Round

# VGN's grid: 40 voxels over the 0.3 m workspace (its ``resolution``).
TSDF_RESOLUTION = 40


def observe(round_: Round, attempt: int, views: int) -> Observation:
    """The Kinect's ``views`` depth images of ``round_``'s pile before attempt ``attempt``, fused."""
    config, record = round_.config, round_.record
    rendered = render_views(
        round_.scene,
        views,
        scenes=config.scenes,
        kinect_config=config.kinect,
        noise=config.kinect.views_depth_noise,
        color=False,
    )
    rendered = [_without_the_arm(v) for v in rendered]
    return fused_observation(
        record,
        rendered,
        attempt=attempt,
        max_width=round_.cell.gripper.max_width,
        gripper=round_.gripper.name,
    )


def fused_observation(
    record: SceneRecord, views: Sequence[SceneView], *, attempt: int, max_width: float, gripper: str
) -> Observation:
    """What a policy gets of ``record``'s pile from ``views``: their depth images, the cloud in the
    table frame cropped to the workspace, and VGN's TSDF grid (:data:`TSDF_RESOLUTION` voxels over
    the workspace). ``max_width``: the gripper's opening (m)."""
    workspace = record.workspace
    images = tuple(CameraImage(_frozen(v.depth, np.float32), v.depth_K, v.T_table_camera) for v in views)
    points = np.concatenate([v.points_in_table() for v in views]) if views else np.zeros((0, 3))
    cloud = points[workspace.contains(points)] if len(points) else points
    tsdf = fuse(list(views), workspace.size, TSDF_RESOLUTION, workspace.T_table_task)
    return Observation(
        round_id=int(record.scene_id),
        attempt=int(attempt),
        seed=int(record.seed),
        images=images,
        cloud=_frozen(cloud, np.float64),
        tsdf=_frozen(tsdf.vgn_grid(), np.float32),
        T_table_volume=workspace.T_table_task,
        voxel_size=tsdf.voxel_size,
        workspace=workspace,
        max_width=float(max_width),
        gripper=gripper,
    )


def _without_the_arm(view: SceneView) -> SceneView:
    """The view with the robot's pixels' depth set to 0 (self-filtering)."""
    depth = np.where(view.segmentation == SEG_ROBOT, np.float32(0.0), view.depth).astype(np.float32)
    return dataclasses.replace(view, depth=depth)
