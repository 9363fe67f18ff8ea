"""Where a run's candidates come from: sampled by the workers (``annotate``) or given (``evaluate``).

The pipeline (planning, workers, store, resume) is the same for both; a source says how many
candidates each object has, which objects take part, and, for given grasps, the poses of a span.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from annotator.objects import ObjectSource
from annotator.pipeline.tasks import GivenGrasps


@dataclass(frozen=True)
class SampledCandidates:
    """N candidates per object, sampled in the workers (Generator keyed on seed and object id)."""

    n: int

    def count(self, object_id: str) -> int:
        return self.n

    def given(self, object_id: str, start: int, stop: int) -> GivenGrasps | None:
        return None

    def select(self, sources: Sequence[ObjectSource]) -> tuple[list[ObjectSource], dict[str, str]]:
        """Every object found takes part; none is missing."""
        return list(sources), {}

    def inputs(self) -> dict[str, Any]:
        return {}


@dataclass(frozen=True)
class GivenCandidates:
    """Given grasps per object id, numbered 0..k-1 in the order given.

    ``grasps`` : object id -> GivenGrasps (T_obj_tcp (k, 4, 4), width (k,) expected chords);
    ``digest``: a hash of everything given, bound by the manifest (a changed input is a new run).
    """

    grasps: Mapping[str, GivenGrasps]
    digest: str
    counts: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "counts", {oid: len(g.width) for oid, g in sorted(self.grasps.items())})

    def count(self, object_id: str) -> int:
        return self.counts.get(object_id, 0)

    def given(self, object_id: str, start: int, stop: int) -> GivenGrasps:
        g = self.grasps[object_id]
        quat = None if g.quat is None else np.asarray(g.quat[start:stop])
        rest = None if g.rest_quat is None else np.asarray(g.rest_quat[start:stop])
        return GivenGrasps(np.asarray(g.T_obj_tcp[start:stop]), np.asarray(g.width[start:stop]), quat, rest)

    def select(self, sources: Sequence[ObjectSource]) -> tuple[list[ObjectSource], dict[str, str]]:
        """The objects that have given grasps; ids with grasps but no object are failures."""
        found = {s.object_id for s in sources}
        missing = {
            oid: "no such object in --objects (searched recursively)"
            for oid in self.counts
            if oid not in found
        }
        return [s for s in sources if s.object_id in self.counts], missing

    def inputs(self) -> dict[str, Any]:
        return {"given_sha256": self.digest, "counts": dict(self.counts)}
