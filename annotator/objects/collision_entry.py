"""A collision geometry and its cache entry: the convex parts (float64), their error against the
mesh and how they were made (:class:`CollisionGeometry`, the ladder's :class:`Rung` s), as the
arrays of one content-addressed entry (:mod:`annotator.objects.cache`) and the multi-part .obj
PyBullet loads.

Precision: parts are stored as float64; fresh and cached parts are both read back from the entry,
so a first run and later runs simulate identical geometry.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from annotator.config import DecompositionConfig
from annotator.objects import cache
from annotator.objects.fidelity import CollisionError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Rung:
    """One step of the ladder as it went.

    ``method``: coacd, coacd-remeshed, vhacd or hull; ``outcome``: ``kept`` (its parts are the
    shape), ``over budget`` (stopped by the CPU budget before it had parts), ``crashed`` (its
    process died; the reason in ``detail``) or ``no parts``; ``cpu_seconds`` it took;
    ``threshold`` (CoACD: of its parts; 0 otherwise) and ``error`` of its parts (None without
    parts).
    """

    method: str
    outcome: str
    cpu_seconds: float
    threshold: float = 0.0
    error: CollisionError | None = None
    detail: str = ""

    def summary(self, seconds: bool = True) -> str:
        """One phrase, e.g. ``coacd kept (threshold 0.03, error 0.15 / 1.82 mm, 12.1 CPU-s)``."""
        bits = [f"threshold {self.threshold:g}"] if self.threshold else []
        if self.error is not None:
            bits.append(f"error {self.error.mean * 1e3:.2f} / {self.error.max * 1e3:.2f} mm")
        if self.detail:
            bits.append(self.detail)
        if seconds:
            bits.append(f"{self.cpu_seconds:.1f} CPU-s")
        return f"{self.method} {self.outcome} ({', '.join(bits)})"

    def to_json(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["error"] = None if self.error is None else dataclasses.astuple(self.error)
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Rung:
        error = data.get("error")
        return cls(
            str(data["method"]),
            str(data["outcome"]),
            float(data["cpu_seconds"]),
            float(data.get("threshold", 0.0)),
            None if error is None else CollisionError(*map(float, error)),
            str(data.get("detail", "")),
        )


@dataclass
class CollisionGeometry:
    """Convex ``parts`` (metres, mesh frame), their ``error`` against the mesh, how they were made.

    ``method``: hull, shells, coacd, coacd-remeshed or vhacd (the rung that gave the parts);
    ``threshold``: CoACD's concavity threshold of the parts (0 otherwise); ``seconds``: CPU seconds
    it took to make them (all rungs); ``ladder``: the rungs tried, in order (empty for hull and
    shells); ``file``: the cache entry (None: a mesh that is its own hull, never cached);
    ``obj_file``: the multi-part .obj PyBullet loads (None for one part).
    """

    parts: list[trimesh.Trimesh]
    error: CollisionError
    method: str
    threshold: float
    file: Path | None
    from_cache: bool
    seconds: float
    ladder: tuple[Rung, ...] = ()
    obj_file: Path | None = None

    def within(self, config: DecompositionConfig) -> bool:
        return self.error.within(config.collision_mean_limit, config.collision_max_limit)

    def ladder_summary(self, seconds: bool = True) -> str:
        """The rungs tried, ``; ``-separated (empty for a hull or shells); ``seconds``: with their
        CPU seconds (which vary from run to run)."""
        return "; ".join(r.summary(seconds) for r in self.ladder)


def entry_arrays(
    parts: list[trimesh.Trimesh],
    error: CollisionError,
    method: str,
    threshold: float,
    seconds: float,
    ladder: tuple[Rung, ...] = (),
) -> dict[str, np.ndarray]:
    return {
        "vertex_counts": np.array([len(p.vertices) for p in parts], dtype=np.int64),
        "face_counts": np.array([len(p.faces) for p in parts], dtype=np.int64),
        "vertices": np.concatenate([np.asarray(p.vertices, dtype=np.float64) for p in parts]),
        "faces": np.concatenate([np.asarray(p.faces, dtype=np.int64) for p in parts]),
        "error": np.array(dataclasses.astuple(error), dtype=np.float64),
        "method": np.array(method),
        "threshold": np.array(threshold, dtype=np.float64),
        "seconds": np.array(seconds, dtype=np.float64),
        "ladder": np.array(json.dumps([r.to_json() for r in ladder])),
    }


def entry_geometry(arrays: dict[str, np.ndarray], path: Path) -> CollisionGeometry:
    """The geometry of an entry's arrays; ValueError/KeyError when they do not make one."""
    v_split = np.cumsum(arrays["vertex_counts"])[:-1]
    f_split = np.cumsum(arrays["face_counts"])[:-1]
    parts = [
        trimesh.Trimesh(v, f, process=False)
        for v, f in zip(
            np.split(arrays["vertices"], v_split), np.split(arrays["faces"], f_split), strict=True
        )
    ]
    if not parts or any(len(p.faces) == 0 for p in parts):
        raise ValueError("no parts")
    ladder = tuple(Rung.from_json(r) for r in json.loads(str(arrays["ladder"])))
    return CollisionGeometry(
        parts,
        CollisionError(*arrays["error"].tolist()),
        str(arrays["method"]),
        float(arrays["threshold"]),
        path,
        True,
        float(arrays["seconds"]),
        ladder,
    )


def obj_text(parts: list[trimesh.Trimesh]) -> str:
    """Multi-part .obj, one ``o`` group per convex part (PyBullet loads it as a compound), with
    repr-exact coordinates of the float64 parts."""
    lines, offset = [], 1
    for i, part in enumerate(parts):
        lines.append(f"o part_{i}")
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(part.vertices, dtype=float).tolist()]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in np.asarray(part.faces).tolist()]
        offset += len(part.vertices)
    return "\n".join(lines) + "\n"


_REPORTED: set[tuple[str, str]] = set()  # (entry, problem) already logged by this process


def read_entry(path: Path, label: str, inputs: cache.EntryInputs | None = None) -> CollisionGeometry | None:
    """The verified entry at ``path`` (made from ``inputs`` when given) with its .obj in place;
    None when missing, broken or made from other inputs (logged once per entry and problem)."""
    try:
        geometry = entry_geometry(cache.load_arrays(path, inputs), path)
    except FileNotFoundError:
        return None
    except (cache.CorruptEntry, ValueError, KeyError, TypeError) as exc:
        what = "foreign" if isinstance(exc, cache.ForeignEntry) else "broken"
        if (str(path), str(exc)) not in _REPORTED:
            _REPORTED.add((str(path), str(exc)))
            log.warning("%s: %s collision cache entry %s (%s); making it again", label, what, path.name, exc)
        return None
    if len(geometry.parts) > 1:
        geometry.obj_file = cache.write_obj(path.parent, path.stem, obj_text(geometry.parts))
    return geometry
