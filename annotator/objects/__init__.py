"""Objects: find them, read and clean their meshes, weigh them, give them collision geometry
(hull or convex parts, with its measured error), and PyBullet bodies.

Steps, one module each: :mod:`~annotator.objects.discovery` (what objects a folder holds),
:mod:`~annotator.objects.memory` (the memory budget), :mod:`~annotator.objects.reading` (read +
clean), :mod:`~annotator.objects.repair` (fragments, holes), :mod:`~annotator.objects.mass` (mass
models), :mod:`~annotator.objects.decomposition` (collision geometry, cached), its
:mod:`~annotator.objects.collision_ladder` (which decomposer within a CPU budget),
:mod:`~annotator.objects.decomposers` (CoACD, V-HACD and their settings),
:mod:`~annotator.objects.decomposition_child` and :mod:`~annotator.objects.limited_process` (each
decomposition in a child process under a CPU limit), :mod:`~annotator.objects.collision_entry` (the
geometry's record and cache entry), :mod:`~annotator.objects.cache` (the content-addressed cache),
:mod:`~annotator.objects.fidelity` (collision error), :mod:`~annotator.objects.bodies` (PyBullet),
:mod:`~annotator.objects.properties` (the ``objects.toml`` sidecar), tied together by
:mod:`~annotator.objects.model` (:func:`load_object`).
"""

from annotator.objects.bodies import create_body, get_object_pose, quiet_c_output, reset_object_pose
from annotator.objects.cache import default_cache_dir
from annotator.objects.decomposition import Progress
from annotator.objects.discovery import MESH_SUFFIXES, URDF_SUFFIX, ObjectSource, discover_objects
from annotator.objects.errors import NotDecomposed, ObjectDiscoveryError, ObjectError
from annotator.objects.fidelity import CollisionError
from annotator.objects.model import (
    ObjectMesh,
    ObjectModel,
    contact_substeps,
    load_object,
    physics_for,
    read_object,
    read_object_mesh,
    source_digest,
)
from annotator.objects.properties import ObjectProperties

__all__ = [
    "MESH_SUFFIXES",
    "URDF_SUFFIX",
    "CollisionError",
    "NotDecomposed",
    "ObjectDiscoveryError",
    "ObjectError",
    "ObjectMesh",
    "ObjectModel",
    "ObjectProperties",
    "ObjectSource",
    "Progress",
    "contact_substeps",
    "create_body",
    "default_cache_dir",
    "discover_objects",
    "get_object_pose",
    "load_object",
    "physics_for",
    "quiet_c_output",
    "read_object",
    "read_object_mesh",
    "reset_object_pose",
    "source_digest",
]
