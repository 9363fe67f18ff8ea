"""PyBullet's own convex decomposition, V-HACD (``pybullet.vhacd``), for the collision ladder
(:mod:`annotator.objects.decomposers`)."""

from __future__ import annotations

from pathlib import Path

from annotator.sim import pb


def vhacd(source: Path, out: Path, log: Path, resolution: int) -> None:
    """Decompose the mesh file ``source`` into convex parts written to ``out`` (one OBJ of parts),
    in voxel mode at ``resolution`` voxels, its other settings PyBullet's defaults; its log to
    ``log``."""
    pb.vhacd(str(source), str(out), str(log), resolution=int(resolution))
