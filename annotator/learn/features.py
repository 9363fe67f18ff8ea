"""What a grasp looks like to the learner: the observed cloud around it, in the gripper's frame.

Only the cloud (:func:`annotator.policies.vision.observed_surface`: the object points of the depth
views, one per 3 mm cube; the table is the plane z = 0 of the table frame), as the policy will see
it. For a grasp ``T_table_tcp`` of chord ``width`` (TCP frame: +x closing, +z approach), the
object points within RADIUS of the TCP are moved into the TCP frame and counted:

- ``between``: between the pads' faces (|x| < width / 2 + PAD_GAP), over the pads' width (|y| <
  PAD_HALF_WIDTH) and length (PAD_Z); ``between_wide`` the same over twice the pads' width;
- ``pads``: inside the pads' and fingers' collision boxes opened to the chord + 2 x the pregrasp
  clearance; ``swept``: met by those boxes backing off 10 cm along the approach; ``palm``: ahead of
  the palm (above the pads, |x| < width / 2);
- ``left`` / ``right``: between the pads, on each side of the TCP (balance of the contacts);
- the centroid (x, y, z) and spread of the points between the pads (0 when there are none);
- a GRID occupancy grid (log1p counts) of the box ``GRID_LOWER``..``GRID_UPPER`` in the TCP frame;
- the grasp's own geometry: width, TCP height above the table, the approach's and the closing
  axis's vertical components, the gripper's lowest point above the table.

Counts enter as log1p(count). :data:`FEATURE_NAMES` names every column.
"""

from __future__ import annotations

import numpy as np

from annotator.config import ProtocolConfig
from annotator.policies.gripper_boxes import (
    box_corners,
    gripper_boxes,
    points_in_boxes,
    points_in_swept_boxes,
)
from annotator.policies.vision import ObservedSurface

RADIUS = 0.2  # m: points farther from the TCP cannot touch the open RG2 (its boxes reach 0.19 m)
PAD_GAP = 0.002  # m: a contact point may lie this far outside the chord (noise, curvature)
PAD_HALF_WIDTH = 0.01  # m: half the RG2 pad's 20.2 mm width (its collision box)
PAD_Z = (-0.0275, 0.0025)  # m: the pads' extent along the approach about the TCP (collision boxes)
PALM_Z = (-0.09, -0.0275)  # m: from the pads' top to the palm's face
GRID = (5, 3, 5)  # cells along x, y, z
GRID_LOWER = np.array([-0.06, -0.03, -0.07])  # m, TCP frame
GRID_UPPER = np.array([0.06, 0.03, 0.03])

_SCALARS = (
    "between", "between_wide", "pads", "swept", "palm", "left", "right",
    "mean_x", "mean_y", "mean_z", "spread_x", "spread_y", "spread_z",
    "width", "tcp_height", "approach_z", "closing_z", "lowest_above_table",
)  # fmt: skip
_CELLS = tuple(f"grid_{i}_{j}_{k}" for i in range(GRID[0]) for j in range(GRID[1]) for k in range(GRID[2]))
FEATURE_NAMES = (*_SCALARS, *_CELLS)


def grasp_features(
    surface: ObservedSurface,
    T_table_tcp: np.ndarray,
    width: np.ndarray,
    protocol: ProtocolConfig | None = None,
) -> np.ndarray:
    """(n, len(FEATURE_NAMES)) float64 features of grasps ``T_table_tcp`` (n, 4, 4) table frame with
    chords ``width`` (n,) m, seen through ``surface`` (module docstring)."""
    protocol = protocol or ProtocolConfig()
    boxes_of = gripper_boxes()
    T_table_tcp = np.asarray(T_table_tcp, dtype=np.float64).reshape(-1, 4, 4)
    width = np.asarray(width, dtype=np.float64).reshape(-1)
    out = np.zeros((len(width), len(FEATURE_NAMES)))
    near_lists = (
        surface.tree.query_ball_point(T_table_tcp[:, :3, 3], r=RADIUS)
        if len(surface.points)
        else [[] for _ in width]
    )
    for k, near in enumerate(near_lists):
        R, t, w = T_table_tcp[k, :3, :3], T_table_tcp[k, :3, 3], float(width[k])
        q = (surface.points[np.asarray(near, dtype=np.int64)] - t) @ R  # (m, 3) TCP frame
        open_width = min(boxes_of.max_width, w + 2 * protocol.pregrasp_clearance)
        boxes = boxes_of.at(open_width, w)
        x, y, z = q[:, 0], q[:, 1], q[:, 2]
        along = (z > PAD_Z[0]) & (z < PAD_Z[1])
        inside = np.abs(x) < w / 2 + PAD_GAP
        between = inside & along & (np.abs(y) < PAD_HALF_WIDTH)
        wide = inside & along & (np.abs(y) < 2 * PAD_HALF_WIDTH)
        palm = (np.abs(x) < w / 2) & (np.abs(y) < 2 * PAD_HALF_WIDTH) & (z > PALM_Z[0]) & (z <= PALM_Z[1])
        b = q[between]
        centroid = b.mean(axis=0) if len(b) else np.zeros(3)
        spread = b.std(axis=0) if len(b) > 1 else np.zeros(3)
        corners = box_corners(boxes) @ R.T + t
        counts = [
            between.sum(),
            wide.sum(),
            points_in_boxes(q, boxes).sum(),
            points_in_swept_boxes(q, boxes, protocol.approach_distance).sum(),
            palm.sum(),
            (between & (x < 0)).sum(),
            (between & (x >= 0)).sum(),
        ]
        scalars = [
            *np.log1p(counts),
            *centroid,
            *spread,
            w,
            t[2],
            R[2, 2],
            abs(R[2, 0]),
            corners[:, 2].min(),
        ]
        cell = np.floor((q - GRID_LOWER) / (GRID_UPPER - GRID_LOWER) * GRID).astype(np.int64)
        ok = np.all((cell >= 0) & (cell < GRID), axis=1)
        grid = np.zeros(GRID)
        np.add.at(grid, tuple(cell[ok].T), 1.0)
        out[k] = np.concatenate([scalars, np.log1p(grid).ravel()])
    return out
