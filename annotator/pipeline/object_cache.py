"""The objects a worker keeps in memory, for every mode: each model loaded as the run loads it (its
collision shape from the decomposition cache, or made and cached) with what was derived of it (its
candidates), under one memory budget, most recently used kept; and the objects that cannot be
loaded, with their one-line error, so that their other spans fail at once.

A worker moves between objects (an object's decomposition task runs ahead of its spans, which reach
it after spans of other objects; a scene draws objects from the pool), so it keeps what it loaded:
without the cache it loaded and sampled such an object again (sampling was 4.4 % of a span's time on
the sample objects, bench/profile_worker.py).
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from annotator.config import ObjectConfig
from annotator.objects import ObjectError, ObjectModel, ObjectSource
from annotator.pipeline.loaded import load_model
from annotator.pipeline.tasks import SpanTask
from annotator.sampler import Candidates

# Objects a worker keeps in memory (model and derived candidates, not a body), up to about this
# many bytes in all. 128 MB holds 14 objects under ~8 MB each (about 40,000 faces) and keeps a
# worker within its memory target; a larger object is loaded again when it is met again.
RECENT_OBJECT_BYTES = 128 * 2**20
# Memory of a mesh or collision-part face with its vertices and trimesh's cached normals, about.
BYTES_PER_FACE = 200

ObjectKey = tuple[Hashable, ...]


def footprint(model: ObjectModel, candidates: dict[Hashable, Candidates]) -> int:
    """About how many bytes a kept object holds: its mesh and collision parts, its candidates."""
    faces = len(model.mesh.faces) + sum(len(part.faces) for part in model.parts)
    arrays = (v for c in candidates.values() for v in vars(c).values() if isinstance(v, np.ndarray))
    return BYTES_PER_FACE * faces + sum(a.nbytes for a in arrays)


def source_version(source: ObjectSource, digest: str | None) -> str:
    """What identifies ``source`` as it is now: its digest (a mesh behind an unchanged URDF
    included), else the file's stat. Worker processes outlive a run (they are reused), so an object
    is known by its content, not its name. ObjectError when the file cannot be read."""
    if digest is not None:
        return digest
    try:
        stat = os.stat(source.path)
    except OSError as exc:
        raise ObjectError(f"cannot read {source.path}: {exc.strerror or exc}") from exc
    return f"{stat.st_mtime_ns}-{stat.st_size}"


@dataclass
class _Kept:
    """A kept object: its model, its candidates by (what they depend on, seed, n), its footprint."""

    model: ObjectModel
    candidates: dict[Hashable, Candidates] = field(default_factory=dict)
    bytes: int = 0


@dataclass(frozen=True)
class Got:
    """A model taken from the cache: ``key`` (what identifies it), ``model``, ``loaded``: this call
    loaded it (False: it was kept); ``candidates``: what was sampled of it, by what they depend on
    (the cache's own dict while it keeps the object: add to it, then :meth:`ObjectCache.measure`)."""

    key: ObjectKey
    model: ObjectModel
    loaded: bool
    candidates: dict[Hashable, Candidates]


class ObjectCache:
    """A worker's objects, most recently used last, within ``budget`` bytes."""

    def __init__(self, budget: int | None = None) -> None:
        self.budget = RECENT_OBJECT_BYTES if budget is None else budget
        self._kept: OrderedDict[ObjectKey, _Kept] = OrderedDict()
        self._total = 0
        self._failed: dict[ObjectKey, str] = {}

    def key(
        self, source: ObjectSource, digest: str | None, scale: float | None, config: ObjectConfig
    ) -> ObjectKey:
        """What identifies an object in this worker: its id, path, version (:func:`source_version`),
        scale and properties, and the object configuration it is loaded with."""
        version = source_version(source, digest)
        return (source.object_id, str(source.path), version, scale, source.properties, config)

    def get(
        self,
        source: ObjectSource,
        *,
        digest: str | None,
        scale: float | None,
        config: ObjectConfig,
        cache_dir: str | None,
        status_dir: str | None,
    ) -> Got:
        """The model of ``source``: kept, or loaded now (:func:`annotator.pipeline.loaded.
        load_model`) and kept. ObjectError for an object that cannot be loaded (and at once for one
        that could not be before)."""
        key = self.key(source, digest, scale, config)
        if key in self._failed:
            raise ObjectError(self._failed[key])
        kept = self._kept.get(key)
        if (
            kept is not None
            and kept.model.collision_file is not None
            and not kept.model.collision_file.exists()
        ):
            self._drop(key)  # its collision file left the cache: load it again
            kept = None
        if kept is not None:
            self._kept.move_to_end(key)
            return Got(key, kept.model, False, kept.candidates)
        try:
            model = load_model(source, config, scale, cache_dir, status_dir)
        except ObjectError as exc:
            self._failed[key] = str(exc)
            raise
        kept = _Kept(model)
        self._keep(key, kept)
        return Got(key, model, True, kept.candidates)

    def of(self, task: SpanTask) -> Got:
        """The model of ``task``'s object (:meth:`get`, as the task's run loads it)."""
        unit = task.span
        return self.get(
            unit.source,
            digest=task.source_sha256,
            scale=unit.scale,
            config=task.config.objects,
            cache_dir=task.cache_dir,
            status_dir=task.status_dir,
        )

    def measure(self, key: ObjectKey) -> None:
        """Measure a kept object again (candidates were added to it), within the budget."""
        kept = self._kept.get(key)
        if kept is not None:
            self._keep(key, kept)

    def _keep(self, key: ObjectKey, kept: _Kept) -> None:
        self._drop(key)
        kept.bytes = footprint(kept.model, kept.candidates)
        self._kept[key] = kept
        self._total += kept.bytes
        while self._kept and self._total > self.budget:
            _, oldest = self._kept.popitem(last=False)
            self._total -= oldest.bytes

    def _drop(self, key: ObjectKey) -> None:
        kept = self._kept.pop(key, None)
        if kept is not None:
            self._total -= kept.bytes

    def __contains__(self, key: ObjectKey) -> bool:
        return key in self._kept

    def __len__(self) -> int:
        return len(self._kept)
