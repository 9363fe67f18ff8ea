"""What a worker holds of an object: a model loaded as the run loads it (:func:`load_model`), the
object placed in a mode's world (:class:`PlacedObject`: for each grasp its trial, the pose to run
it at and its row's columns of the mode), the object loaded in its world (:class:`LoadedObject`:
model, body, the object placed, its sampled candidates) and what the manifest records of a model
(:func:`model_record`), for an object's spans and a scene's objects alike."""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from annotator.config import ObjectConfig
from annotator.geometry import Transform
from annotator.objects import ObjectModel, ObjectSource, load_object
from annotator.pipeline import status
from annotator.sampler import Candidates
from annotator.trial import GraspTrial


@dataclass(frozen=True)
class GraspSetup:
    """Where one grasp runs: its ``trial``, the ``pose`` (TCP, in the trial's object frame) to run it
    at, and ``columns``: its row's columns of the mode, asked for once the trial has run (None: the
    mode has none)."""

    trial: GraspTrial
    pose: Transform
    columns: Callable[[], dict[str, Any]] | None = None


class PlacedObject(Protocol):
    """An object placed in an object mode's world: it sets each grasp up."""

    def setup(
        self, T: Transform, width: float, grasp_id: int, placement: int | None, rest: np.ndarray | None
    ) -> GraspSetup:
        """The grasp ``T`` (TCP in the object's mesh frame, expected chord ``width`` m) set up:
        ``placement``, the cell placement it was sampled for (None: given); ``rest``, the
        orientation its object rests in (xyzw; resting only, None: upright)."""
        ...

    def release(self) -> None:
        """Free its trials and snapshots (the body in the trial world is the worker's)."""


@dataclass
class LoadedObject:
    """The object a worker has in a mode's world: ``key`` (what identifies it,
    :meth:`annotator.pipeline.object_cache.ObjectCache.key`), ``model``, its body ``uid`` in the
    trial world, the object ``placed`` in the mode, its sampled candidates by what they depend on
    (the worker's object cache's own record of them)."""

    key: tuple[Hashable, ...]
    model: ObjectModel
    uid: int
    placed: PlacedObject
    candidates: dict[Hashable, Candidates] = field(default_factory=dict)

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


def model_record(model: ObjectModel) -> dict[str, Any]:
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
