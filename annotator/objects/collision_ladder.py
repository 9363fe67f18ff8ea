"""The collision ladder of a concave object: which decomposer gives its convex parts, inside
``DecompositionConfig.budget`` CPU seconds for the object's whole load (what its reading
and repair used comes off the ladder's share):

1. CoACD at each of :func:`~annotator.objects.decomposers.thresholds` (coarse to fine) until the
   collision error is within ``collision_mean_limit`` / ``collision_max_limit``, the best so far
   kept (CoACD 1.0's tree search bounded to ``coacd_search_iterations``, seed 0, on the mesh or the
   smallest simplified copy that follows it within ``copy_tolerance``, in a child
   process limited to the budget; a threshold that misses the limits by at most
   ``coacd_retry_margin`` is cut again with CoACD's own search before a finer one; stopped at
   ``coacd_first_cut_share`` of the budget if it has finished no threshold by then); a refinement
   stopped by the budget keeps the best threshold it finished;
2. when that finished no threshold: CoACD again, the same thresholds, on the mesh remeshed by
   CoACD's own manifold preprocessing (``coacd_remesh_resolution``, tree search bounded to
   ``coacd_remesh_search_iterations``), in a child process limited to what is left, stopped at that
   less ``vhacd_reserve`` if it has finished no threshold by then;
3. V-HACD (pybullet.vhacd, bullet3's V-HACD 2.2) when neither CoACD finished a threshold, in a
   child process limited to what is left;
4. the convex hull, in this process, when none gave parts.

Every step reports what it did (:class:`~annotator.objects.collision_entry.Rung`: kept, over
budget, crashed, no parts) with its CPU seconds and error. Running over the budget or crashing is a
normal result, the next rung's turn: the object still gets its shape, cached like any other, and is
never decomposed again; only an unusable mesh (found before, by reading and cleaning it) fails an
object. The budget is CPU time (RLIMIT_CPU of the child), so a loaded machine does not push an
object down the ladder; with ``budget_basis = "reference"`` (the default) it is counted in reference
CPU-seconds (:mod:`annotator.objects.machine_speed`), so a slower machine does not either. Near an
edge the measurement's noise still can, and the cache keeps whichever shape was made first.

The decomposers are :mod:`annotator.objects.decomposers`, their isolated child process
:mod:`annotator.objects.decomposition_child`. CoACD is the first rung because it was faster and
about twice as tight as V-HACD on the concave sample objects; measurements and reasons in
docs/decisions/0101-collision-ladder.md.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import trimesh

from annotator.config import DecompositionConfig
from annotator.objects.collision_entry import Rung
from annotator.objects.decomposers import METHOD, REMESHED, VHACD
from annotator.objects.decomposition_child import RungParts, child_rung
from annotator.objects.fidelity import collision_error
from annotator.objects.machine_speed import speed_factor

log = logging.getLogger(__name__)

LADDER = (METHOD, REMESHED, VHACD, "hull")
# Called as progress(object_id, message) when a decomposition starts, moves down the ladder and ends.
Progress = Callable[[str, str], None]
# Budget seconds the ladder leaves for what follows it in a load: writing the cache entry, reading
# it back and writing the parts' .obj (a 100-part entry of the YCB meshes: about 0.1 CPU-s).
AFTER_LADDER_SECONDS = 0.5


def budget_factor(config: DecompositionConfig) -> float:
    """This machine's CPU seconds per budget second: :func:`~annotator.objects.machine_speed.speed_factor`
    with ``budget_basis = "reference"``, 1 with ``"cpu"``."""
    return speed_factor() if config.budget_basis == "reference" else 1.0


def first_parts_by(method: str, limit: float, config: DecompositionConfig, factor: float) -> float | None:
    """CPU-s of its own by which a rung given ``limit`` CPU-s must have parts or be stopped (None:
    no such point). CoACD as the mesh is: ``coacd_first_cut_share`` of the budget, and at the
    latest ``vhacd_reserve`` before its limit; CoACD remeshed: ``vhacd_reserve`` before its limit.
    ``factor``: CPU seconds per budget second (:func:`budget_factor`)."""
    if method not in (METHOD, REMESHED):
        return None
    stop = limit - config.vhacd_reserve * factor
    if method == METHOD:
        stop = min(stop, config.coacd_first_cut_share * config.budget * factor)
    return stop if stop < limit else None


def run_ladder(
    mesh: trimesh.Trimesh,
    config: DecompositionConfig,
    label: str,
    progress: Progress | None,
    spent: float = 0.0,
) -> tuple[RungParts, tuple[Rung, ...]]:
    """The ladder within what is left of the budget (``spent``: CPU seconds the load used before
    it; the ladder's own work in this process counts too): CoACD, CoACD remeshed, V-HACD, the hull;
    the first rung with parts. CoACD remeshed starts only with more than a CPU-s beyond V-HACD's
    reserve left. The budget and the reserve are in this machine's CPU seconds (:func:`budget_factor`:
    measured only here, when a decomposition is about to run)."""
    factor = budget_factor(config)
    reserve = config.vhacd_reserve * factor
    budget = (config.budget - AFTER_LADDER_SECONDS) * factor - spent
    start = time.process_time()
    rungs: list[Rung] = []
    children = 0.0
    for method in LADDER:
        used = children + (time.process_time() - start)
        if method == "hull":
            hull_started = time.process_time()
            parts = [mesh.convex_hull]
            error = collision_error(mesh, parts, config.collision_error_samples)
            hull = Rung("hull", "kept", time.process_time() - hull_started, 0.0, error)
            found = RungParts(hull, parts, error)
        elif budget - used < 1.0:  # the load spent the budget before this rung: no child at all
            left = f"{max(0.0, budget - used):.1f} CPU-s left"
            found = RungParts(Rung(method, "over budget", 0.0, detail=left))
        elif method == REMESHED and budget - used - reserve < 1.0:
            left = f"{max(0.0, budget - used):.1f} CPU-s left, V-HACD's reserve {reserve:.1f}"
            found = RungParts(Rung(method, "over budget", 0.0, detail=left))
        else:
            # CoACD may use the whole budget once it has parts; until then it leaves the next rungs theirs
            limit = math.floor(budget - used)  # whole seconds, within the budget
            found = child_rung(mesh, config, method, limit, first_parts_by(method, limit, config, factor))
        rungs.append(found.rung)
        if method != "hull":
            children += found.rung.cpu_seconds
        if found.parts:
            return found, tuple(rungs)
        say(progress, label, f"{found.rung.summary()}; next: {LADDER[LADDER.index(method) + 1]}")
    raise AssertionError("the hull always has parts")  # pragma: no cover


def say(progress: Progress | None, label: str, message: str) -> None:
    log.info("%s: %s", label, message)
    if progress is not None:
        progress(label, message)
