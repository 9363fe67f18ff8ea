"""Mass, centre of mass and inertia of an object: a solid, a thin shell, a sheet, or given.

Models (``ObjectModel.mass_model``):

- ``solid``: the enclosed volume x ``density`` (objects that are full or nearly so).
- ``shell``: a closed mesh whose walls are modelled (a mug, a pot: thin and mostly cavity) has
  its wall volume weighed at the wall material's ``shell_density``; an open sheet (a surface with
  no thickness) has area x ``shell_thickness`` x ``shell_density``, as a lamina.
- ``urdf``: a URDF's own ``<inertial>``; ``given``: a sidecar mass (the geometry's inertia scaled).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import trimesh

from annotator.config import ObjectConfig


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and a proper rotation (3, 3) whose columns are the principal axes."""
    moments, R = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1.0
    return np.maximum(moments, 0.0), R


@dataclass(frozen=True)
class MassProperties:
    """``mass`` kg, ``volume`` m^3 of material, ``center_mass`` (3,) m and ``inertia`` (3, 3) kg m^2
    about it (axes of the mesh frame), and the ``model`` that gave them."""

    mass: float
    volume: float
    center_mass: np.ndarray
    inertia: np.ndarray
    model: str

    def with_mass(self, mass: float, model: str) -> MassProperties:
        """Same distribution, total ``mass`` (inertia scales with it)."""
        return replace(self, mass=float(mass), inertia=self.inertia * (mass / self.mass), model=model)


def solid(mesh: trimesh.Trimesh, density: float, model: str = "solid") -> MassProperties:
    """A closed, outward-wound mesh filled with ``density``."""
    p = trimesh.triangles.mass_properties(mesh.triangles, density=density)
    return MassProperties(
        float(p.mass), float(p.volume), np.asarray(p.center_mass, float), np.asarray(p.inertia, float), model
    )


def lamina(mesh: trimesh.Trimesh, thickness: float, density: float) -> MassProperties:
    """A sheet of ``thickness`` along the surface (open meshes): mass from the area.

    Second moment of a triangle (a, b, c) of area A: A/12 (a a^T + b b^T + c c^T + s s^T), s = a+b+c.
    """
    tri = np.asarray(mesh.triangles, dtype=np.float64)  # (n, 3, 3)
    area = np.asarray(mesh.area_faces, dtype=np.float64)  # (n,)
    sigma = thickness * density  # kg / m^2
    total = float(area.sum())
    mass = sigma * total
    com = (area[:, None] * tri.mean(axis=1)).sum(axis=0) / total
    s = tri.sum(axis=1)
    second = (area[:, None, None] / 12.0) * (
        np.einsum("nki,nkj->nij", tri, tri) + np.einsum("ni,nj->nij", s, s)
    )
    C = sigma * second.sum(axis=0) - mass * np.outer(com, com)  # about the centre of mass
    inertia = np.trace(C) * np.eye(3) - C
    return MassProperties(mass, total * thickness, com, inertia, "shell")


def is_thin_walled(mesh: trimesh.Trimesh, hull_volume: float, config: ObjectConfig) -> bool:
    """A closed mesh whose mean wall (2 V / A) is thin and whose material fills little of its hull."""
    volume, area = float(mesh.volume), float(mesh.area)
    wall = 2.0 * volume / area if area > 0 else 0.0
    return wall <= config.shell_max_wall and volume <= config.shell_max_fill * hull_volume


def weigh(
    mesh: trimesh.Trimesh,
    hull: trimesh.Trimesh,
    watertight: bool,
    config: ObjectConfig,
    mass_model: str = "auto",
    density: float | None = None,
    shell_thickness: float | None = None,
) -> MassProperties:
    """The mass properties of a cleaned object by ``mass_model`` (``auto``, ``solid``, ``shell``).

    ``density``: the sidecar's, for whichever model applies (default: ``config.density`` for a
    solid, ``config.shell_density`` for a shell). ``auto``: ``shell`` for thin-walled closed
    meshes and for open sheets, else ``solid``. An open
    mesh weighed ``solid`` uses its convex hull (an upper bound).
    """
    thickness = config.shell_thickness if shell_thickness is None else shell_thickness
    hull_volume = float(hull.volume)
    if mass_model == "auto":
        thin = is_thin_walled(mesh, hull_volume, config) if watertight else True
        mass_model = "shell" if thin else "solid"
    if mass_model == "shell":
        material = config.shell_density if density is None else density
        if watertight:
            return solid(mesh, material, model="shell")
        return lamina(mesh, thickness, material)
    return solid(mesh if watertight else hull, config.density if density is None else density)
