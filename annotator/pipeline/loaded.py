"""What a worker holds of an object: the object loaded in its world (:class:`LoadedObject`: model,
body, the object placed in the worker's mode, its sampled candidates) and what the manifest records
of a model (:func:`object_info`), for an object's spans and a scene's objects alike."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from annotator.objects import ObjectModel
from annotator.sampler import Candidates

if TYPE_CHECKING:
    from annotator.pipeline.modes import PlacedObject


@dataclass
class LoadedObject:
    """The object a worker has in its world: ``key`` (what identifies it, see
    :meth:`annotator.pipeline.worker.WorkerState.object_for`), ``model``, its body ``uid`` in the
    trial world, the object ``placed`` in the worker's mode (:mod:`annotator.pipeline.modes`: its
    trials), sampled candidates by (seed, n)."""

    key: tuple
    model: ObjectModel
    uid: int
    placed: PlacedObject
    candidates: dict[tuple[int, int], Candidates] = field(default_factory=dict)

    def release(self) -> None:
        """Free its trials and snapshots; the trial world's body is the caller's."""
        self.placed.release()


def object_info(model: ObjectModel) -> dict[str, Any]:
    """What the object was simulated as, for the manifest (JSON-ready; lengths in m, mass in kg)."""
    err = model.collision_error
    assert err is not None  # a loaded model has its collision shape
    return {
        "source": str(model.path),
        "scale": float(model.scale),
        "mass": float(model.mass),
        "volume": float(model.volume),
        "mesh_sha256": model.mesh_sha256,
        "watertight": bool(model.watertight),
        "convex": bool(model.convex),
        "parts": len(model.parts),
        "lateral_friction": float(model.friction),
        "collision_error_mean": float(err.mean),
        "collision_error_max": float(err.max),
        "geometry": model.geometry_record(),  # dataset.load_geometry reads these back
        "warnings": list(model.warnings),  # reported once per object per run
    }
