"""Objects resting on the cell's table: stable poses (trimesh), merged, ranked, placed in reach.

``stable_poses(mesh)`` runs trimesh's ``compute_stable_poses`` (the quasi-static topple analysis
of the convex hull about the centre of mass; deterministic with its defaults) and merges poses that
are one placement in practice (a cylinder's hull yields one pose per side facet): poses whose
world-up directions, seen in the object frame, are linked by a chain of neighbours each within
``placement_merge_angle`` form one placement with their probabilities added. ``placements(...)``
keeps the most probable few and puts each on the table top with the centre of mass over the
cell's placement point.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import trimesh

from annotator.cell.world import TableTop
from annotator.config import CellConfig
from annotator.geometry import Transform, axis_angle_to_matrix, connected_groups

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StablePose:
    """A resting pose: ``T_rest_obj`` (4, 4) puts the mesh on the plane z = 0 (rest frame z up),
    with the (merged) ``probability`` of landing in it. ``members`` are the ``T_rest_obj`` of every
    trimesh pose merged into it, most probable first (``T_rest_obj`` is the first): a can lying on
    any of its side facets."""

    T_rest_obj: np.ndarray
    probability: float
    members: tuple[np.ndarray, ...] = ()

    def each_member(self) -> list[StablePose]:
        """One pose per merged member (this pose alone when it has none), each with the whole
        placement's probability."""
        return [StablePose(T, self.probability) for T in self.members] or [self]

    @property
    def up_in_object(self) -> np.ndarray:
        """The rest frame's +z seen in the object's mesh frame, (3,) unit."""
        return self.T_rest_obj[2, :3]


def stable_poses(mesh: trimesh.Trimesh, merge_angle: float, min_probability: float = 0.0) -> list[StablePose]:
    """Merged stable poses of ``mesh`` (mesh frame, metres), most probable first.

    ``merge_angle`` degrees; poses below ``min_probability`` after merging are dropped.
    """
    transforms, probabilities = trimesh.poses.compute_stable_poses(mesh)
    T_all = [np.asarray(T) for T in transforms]
    p_all = np.asarray(probabilities, dtype=float)
    if not T_all:
        return []
    up = np.array([T[2, :3] for T in T_all])  # (k, 3): world up in the object frame, per pose
    # Single linkage: poses whose up directions lie within merge_angle are joined, and so are
    # their neighbours' neighbours. A cylinder's side facets (7.5 deg apart on the can) are one
    # chain all round, however many there are; a greedy cluster of one radius cut that ring into
    # pieces of ~5 facets, each less probable than standing upright, so the can and the bottle
    # were never placed standing. Faces of a box (90 deg apart) stay apart.
    cos_merge = math.cos(math.radians(merge_angle))
    groups = connected_groups(up @ up.T >= cos_merge)
    # Each placement is represented by its most probable member (ties: trimesh's order).
    kept = []
    for members in groups:
        members = sorted(members, key=lambda i: (-p_all[i], i))
        kept.append((float(p_all[members].sum()), members[0], tuple(T_all[i] for i in members)))
    kept.sort(key=lambda e: (-e[0], e[1]))
    return [StablePose(Ts[0], p, Ts) for p, _, Ts in kept if p >= min_probability]


@dataclass(frozen=True)
class Placement:
    """An object at rest on the table: ``T_world_obj`` of its mesh frame, from stable pose
    ``pose_index`` (in :func:`stable_poses` order) with its merged ``probability``, turned by ``yaw``
    (rad) about the vertical."""

    placement_id: int
    T_world_obj: Transform
    pose_index: int
    probability: float
    yaw: float


def place(
    pose: StablePose, top: TableTop, xy: np.ndarray, yaw: float = 0.0, point_obj: np.ndarray | None = None
) -> Transform:
    """``T_world_obj`` resting in ``pose`` on ``top``, turned by ``yaw`` (rad), with the object point
    ``point_obj`` (3,) (default: the rest frame's origin) over the world point ``xy`` (2,)."""
    R_yaw = np.eye(4)
    R_yaw[:3, :3] = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), yaw)
    T_top_obj = R_yaw @ pose.T_rest_obj
    T_world_obj = top.T_world_top.as_matrix() @ T_top_obj
    anchor = T_world_obj[:3, 3] if point_obj is None else (T_world_obj @ np.append(point_obj, 1.0))[:3]
    T_world_obj[:2, 3] += np.asarray(xy, dtype=float) - anchor[:2]
    return Transform.from_matrix(T_world_obj)


def placements(mesh: trimesh.Trimesh, top: TableTop, config: CellConfig) -> list[Placement]:
    """The ``placements_per_object`` most probable stable poses, each with its centre of mass over
    (placement_x, placement_y), unturned. ``placement_id`` counts from 0 in that order."""
    poses = stable_poses(mesh, config.placement_merge_angle, config.placement_min_probability)
    xy = np.array([config.placement_x, config.placement_y])
    out = []
    for k, pose in enumerate(poses[: config.placements_per_object]):
        T = place(pose, top, xy, 0.0, np.asarray(mesh.center_mass))
        out.append(Placement(k, T, k, pose.probability, 0.0))
    return out
