"""A truncated signed distance function (TSDF) over a cube, fused from depth images, in numpy.

The projective TSDF of Curless and Levoy (SIGGRAPH 1996) as KinectFusion (Newcombe et al., ISMAR
2011) integrates it, with the conventions of Open3D's ``UniformTSDFVolume`` (the library VGN calls),
so that :meth:`TSDFVolume.vgn_grid` is the grid VGN trains on:

- the cube of side ``size`` is split into ``resolution``^3 voxels; voxel (i, j, k) (i along x)
  has its centre at ``(i + 0.5, j + 0.5, k + 0.5) * voxel_size`` in the volume's frame;
- each view projects every voxel centre into its depth image (``T_camera_volume``, pinhole K, the
  nearest pixel); where the pixel has a depth d > 0 and the voxel is in front of the camera,
  ``sdf = (d - z) * sqrt(1 + ((u - cx) / fx)^2 + ((v - cy) / fy)^2)`` at the pixel (u, v) (the
  distance along its ray, positive in front of the surface),
  and a voxel with sdf > -trunc takes ``min(1, sdf / trunc)`` into its running mean (weight + 1);
- the truncation is 4 voxels by default (VGN's ``sdf_trunc = 4 * voxel_size``).

Open3D was measured against this module on the same views (see the scenes documentation): the
values agree to float32 rounding except where a voxel centre projects onto a pixel boundary.
Open3D itself (~300 MB with its dependencies) is not needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotator.cell.kinect import Intrinsics
from annotator.geometry import Transform

# VGN's grid keeps the voxels Open3D's extract_voxel_point_cloud reports: seen (weight > 0) and
# with -0.98 <= tsdf < 0.98; the rest (unseen, or empty space beyond the truncation) are 0.
NEAR_SURFACE = 0.98
TRUNCATION_VOXELS = 4.0  # VGN: sdf_trunc = 4 * voxel_size


@dataclass
class TSDFVolume:
    """A cube of side ``size`` (m) and ``resolution`` voxels per side, its lower corner at the
    origin of its frame ("volume" frame). ``tsdf`` and ``weight`` are (r, r, r) float32 arrays
    indexed [i, j, k] along x, y, z; ``trunc`` m (default 4 voxels)."""

    size: float
    resolution: int
    trunc: float = 0.0

    def __post_init__(self) -> None:
        if self.resolution < 2 or not self.size > 0:
            raise ValueError(f"a TSDF needs size > 0 and resolution >= 2, got {self.size}, {self.resolution}")
        if self.trunc <= 0:
            self.trunc = TRUNCATION_VOXELS * self.voxel_size
        r = self.resolution
        self.tsdf = np.zeros((r, r, r), dtype=np.float32)
        self.weight = np.zeros((r, r, r), dtype=np.float32)

    @property
    def voxel_size(self) -> float:
        return self.size / self.resolution

    def centres(self, i: int) -> np.ndarray:
        """Centres (r * r, 3) of the voxels of slab i (x index), volume frame, in [j, k] order."""
        r, s = self.resolution, self.voxel_size
        j, k = np.meshgrid(np.arange(r), np.arange(r), indexing="ij")
        return np.stack([np.full(r * r, i + 0.5), j.ravel() + 0.5, k.ravel() + 0.5], axis=1) * s

    def integrate(self, depth: np.ndarray, K: Intrinsics, T_camera_volume: Transform) -> None:
        """Fuse one depth image (h, w) m (0 = no measurement) seen by a camera with intrinsics
        ``K`` whose optical frame is ``T_camera_volume``^-1 in the volume frame."""
        d_img = np.asarray(depth, dtype=np.float32)
        h, w = d_img.shape
        R, t = T_camera_volume.rotation, T_camera_volume.pos
        for i in range(self.resolution):  # one slab at a time: bounded memory at any resolution
            p = self.centres(i) @ R.T + t
            x, y, z = p[:, 0], p[:, 1], p[:, 2]
            front = z > 0
            z_safe = np.where(front, z, 1.0)
            u_f = x * K.fx / z_safe + K.cx + 0.5
            v_f = y * K.fy / z_safe + K.cy + 0.5
            ok = front & (u_f >= 1e-4) & (u_f < w - 1e-4) & (v_f >= 1e-4) & (v_f < h - 1e-4)
            u = np.where(ok, u_f, 0).astype(np.int64)
            v = np.where(ok, v_f, 0).astype(np.int64)
            d = d_img[v, u].astype(np.float64)
            ok &= d > 0
            ray = np.sqrt(1.0 + ((u - K.cx) / K.fx) ** 2 + ((v - K.cy) / K.fy) ** 2)
            sdf = (d - z) * ray
            ok &= sdf > -self.trunc
            jk = np.flatnonzero(ok)
            if not len(jk):
                continue
            value = np.minimum(1.0, sdf[jk] / self.trunc)
            jj, kk = np.divmod(jk, self.resolution)
            old_w = self.weight[i, jj, kk].astype(np.float64)
            old_t = self.tsdf[i, jj, kk].astype(np.float64)
            self.tsdf[i, jj, kk] = ((old_t * old_w + value) / (old_w + 1.0)).astype(np.float32)
            self.weight[i, jj, kk] = (old_w + 1.0).astype(np.float32)

    def observed_near_surface(self) -> np.ndarray:
        """(r, r, r) bool: seen, and within the truncation band (|tsdf| < 0.98, as Open3D reports)."""
        return (self.weight > 0) & (self.tsdf >= -NEAR_SURFACE) & (self.tsdf < NEAR_SURFACE)

    def vgn_grid(self) -> np.ndarray:
        """VGN's input grid (r, r, r) float32: (tsdf + 1) / 2 where :meth:`observed_near_surface`,
        0 elsewhere (VGN's ``TSDFVolume.get_grid``)."""
        keep = self.observed_near_surface()
        return np.where(keep, (self.tsdf + np.float32(1.0)) * np.float32(0.5), np.float32(0.0)).astype(
            np.float32
        )

    def surface_points(self) -> np.ndarray:
        """The surface as points (n, 3), volume frame: the linear zero crossing between every pair
        of neighbouring voxels (along x, y, z) that are both near the surface with opposite signs."""
        near = self.observed_near_surface()
        f = self.tsdf.astype(np.float64)
        s = self.voxel_size
        points = []
        for axis in range(3):
            a = [slice(None)] * 3
            b = [slice(None)] * 3
            a[axis], b[axis] = slice(0, -1), slice(1, None)
            f0, f1 = f[tuple(a)], f[tuple(b)]
            cross = near[tuple(a)] & near[tuple(b)] & (f0 * f1 < 0)
            idx = np.argwhere(cross).astype(np.float64)
            r0, r1 = np.abs(f0[cross]), np.abs(f1[cross])
            p = (idx + 0.5) * s
            p[:, axis] += s * r0 / (r0 + r1)
            points.append(p)
        return np.concatenate(points) if points else np.zeros((0, 3))


def fuse(views, size: float, resolution: int, T_table_volume: Transform) -> TSDFVolume:
    """A TSDF of ``resolution``^3 over the cube of side ``size`` whose lower corner frame is
    ``T_table_volume`` (table frame), fused from ``views`` (:class:`annotator.scenes.views.SceneView`)."""
    volume = TSDFVolume(size, resolution)
    for view in views:
        volume.integrate(view.depth, view.depth_K, view.T_table_camera.inverse() * T_table_volume)
    return volume
