"""The libraries that shape labels, listed once, and their installed versions.

A label depends on the versions of the libraries that compute it: PyBullet simulates the trial,
NumPy does the arithmetic, trimesh reads, cleans and samples the mesh, pymeshfix fills its holes,
manifold3d joins overlapping shells, fast-simplification decimates what CoACD cuts, CoACD (and
PyBullet's V-HACD) cut the convex parts, SciPy (Qhull) makes their hulls. Two places must agree on
this list, and both read it from here:

- the run's binding (:func:`annotator.store.manifest.bound_versions`): a resume with another
  version of any of them is refused in one line (exit 2), so one folder never mixes labels made
  with two;
- the decomposition cache's key (:func:`annotator.objects.cache.entry_key`): an entry made with
  another version is a miss, and the object is decomposed again, never simulated with a shape
  another version made.

The versions are looked up through :func:`library_versions` (read once per process); both users
call it through this module, so a test that replaces it replaces what both see.
"""

from __future__ import annotations

import functools
from importlib import metadata

__all__ = ["LABEL_LIBRARIES", "NOT_INSTALLED", "library_versions"]

# Distribution names (as pip knows them), sorted; the order is part of no key (keys sort them).
LABEL_LIBRARIES: tuple[str, ...] = (
    "coacd",
    "fast-simplification",
    "manifold3d",
    "numpy",
    "pybullet",
    "pymeshfix",
    "scipy",
    "trimesh",
)
NOT_INSTALLED = "not installed"


def library_versions() -> dict[str, str]:
    """``{distribution: version}`` of :data:`LABEL_LIBRARIES` (``"not installed"`` for a missing one)."""
    return dict(_installed())


@functools.cache
def _installed() -> dict[str, str]:
    out = {}
    for dist in LABEL_LIBRARIES:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = NOT_INSTALLED
    return out
