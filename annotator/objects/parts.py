"""Which explicit parts of a multi-body file (.obj objects, .glb nodes) are one body.

Bodies of a scene lie apart; the convex parts of one object (a V-HACD file) or a handle written as
its own object touch or overlap. So parts whose bounding boxes meet are one body: this merges
explicit parts only, it never splits a part (a bowl's nested shells stay one body).
"""

from __future__ import annotations

import numpy as np

from annotator.geometry import connected_groups


def touching_groups(boxes: list[np.ndarray]) -> list[list[int]]:
    """Indices of the bodies grouped so that bodies whose bounding boxes meet share a group
    (chains of meeting boxes too), each group sorted, groups in order of their first body."""
    lo = np.array([b[0] for b in boxes])
    hi = np.array([b[1] for b in boxes])
    # boxes within 1e-4 of the file's extent meet: pybullet_data's lego_vhacd.obj writes its 83
    # V-HACD parts with gaps up to ~1e-5 of 0.32 (6 decimals); at 1e-6 it read as 27 bodies
    tol = 1e-4 * float(np.max(hi.max(axis=0) - lo.min(axis=0)))
    meet = np.all((lo[:, None] <= hi[None] + tol) & (lo[None] <= hi[:, None] + tol), axis=2)
    return connected_groups(meet)
