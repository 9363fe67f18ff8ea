"""What a worker holds of an object: a model loaded as the run loads it (:func:`load_model`), the
object loaded in its world (:class:`LoadedObject`: model, body, the object placed in the worker's
mode, its sampled candidates) and what the manifest records of a model (:func:`object_info`), for
an object's spans and a scene's objects alike."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from annotator.config import ObjectConfig
from annotator.objects import ObjectModel, ObjectSource, load_object
from annotator.pipeline import status
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


def load_model(
    source: ObjectSource,
    config: ObjectConfig,
    scale: float | None,
    cache_dir: str | None,
    status_dir: str | None,
) -> ObjectModel:
    """``source`` read, cleaned and given its collision shape (from the decomposition cache
    ``cache_dir``, None: the default, or made and cached), saying so in ``status_dir``; ObjectError
    for an unusable object."""
    status.write(status_dir, f"loading {source.object_id}")
    return load_object(
        source,
        config,
        scale=scale,
        cache_dir=Path(cache_dir) if cache_dir is not None else None,
        progress=lambda oid, message: status.write(status_dir, f"{oid}: {message}"),
    )


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
