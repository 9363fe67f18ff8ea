"""How fast this machine cuts meshes, against the machine the decomposition budget was set on.

A CPU-second is not a fixed amount of work. On one 2-core virtual machine the same CoACD cuts took
about 2.3 times the CPU time on one day as on another, so a budget in plain CPU seconds gave the
same mesh another collision shape on the slower day: pybullet_data's lego brick fell from CoACD on
the remeshed mesh (1.81 mm) to its convex hull (11.5 mm), the sample bowl from CoACD at 0.03
(1.90 mm) to the remeshed rung (4.97 mm). With ``[objects.decomposition] budget_basis = "reference"`` (the
default) the ladder's budget and V-HACD's reserve are reference CPU-seconds: the CPU-seconds of the
machine the ladder's limits were measured on. The ladder multiplies them by :func:`speed_factor`,
the CPU time of a fixed reference cut (:func:`reference_mesh`, CoACD at :data:`REFERENCE_THRESHOLD`)
here over its CPU time there (:data:`REFERENCE_CUT_SECONDS`), so a slower machine spends more CPU
seconds on the same work and keeps the same shapes (docs/decisions/0101-collision-ladder.md,
"Revision: a budget in reference CPU-seconds").

The factor is measured once per process, only when a decomposition is about to run (a warm cache
or a convex object never pays for it), unless ``RG2_SPEED_FACTOR`` gives it: in a child process
with one OpenMP thread, as the decompositions run, the fastest of :data:`REFERENCE_REPEATS` cuts
(a cut slowed by another process only ever takes longer).
"""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys

import numpy as np
import trimesh

log = logging.getLogger(__name__)

# CPU seconds of one reference cut (reference_mesh, REFERENCE_THRESHOLD, REFERENCE_ITERATIONS, seed
# 0) on the machine the ladder's limits were measured on: 1.31 to 1.34 CPU-s (record
# machine_speed/2026-11-27-a73f4de) on a day when the code of those measurements (commit 18ba63c)
# loaded the sample objects 2.31 times slower than its record object_sets/2026-11-24-18ba63c (the
# four cut by CoACD alike: 17.9 -> 41.4 CPU-s; record object_sets/2026-11-27-18ba63c), over 2.31.
REFERENCE_CUT_SECONDS = 0.57
REFERENCE_THRESHOLD = 0.05  # CoACD's concavity threshold of the reference cut
REFERENCE_ITERATIONS = 20  # CoACD tree-search iterations per cut
REFERENCE_REPEATS = 2  # cuts in the measuring child; the fastest is the machine's time
# A factor outside this range is a broken measurement (a stalled child, a throttled timer), not a
# machine: it is clamped and said.
FACTOR_RANGE = (0.25, 8.0)
# A factor given here (a positive number) is used instead of a measurement: a parent process that
# measured it passes it to its children, and a user can pin it on identical machines (no noise).
FACTOR_ENV = "RG2_SPEED_FACTOR"
MEASURE_TIMEOUT = 300.0  # wall seconds the measuring child may take before the factor falls back to 1


def reference_mesh() -> trimesh.Trimesh:
    """The reference cut's mesh: a closed ring, 80 mm across, 40 mm bore, 30 mm high, 16 sides
    (concave, so CoACD cuts it into several parts; generated, so every machine cuts the same bytes)."""
    return trimesh.creation.annulus(r_min=0.02, r_max=0.04, height=0.03, sections=16)


def reference_cut_seconds(repeats: int = REFERENCE_REPEATS) -> list[float]:
    """CPU seconds of ``repeats`` reference cuts in this process (the measuring child's work)."""
    import time

    import coacd

    coacd.set_log_level("error")
    ring = reference_mesh()
    vertices, faces = np.asarray(ring.vertices), np.asarray(ring.faces)
    seconds = []
    for _ in range(repeats):
        started = time.process_time()
        coacd.run_coacd(
            coacd.Mesh(vertices, faces),
            threshold=REFERENCE_THRESHOLD,
            mcts_iterations=REFERENCE_ITERATIONS,
            preprocess_mode="off",
            seed=0,
        )
        seconds.append(time.process_time() - started)
    return seconds


def measure_command() -> list[str]:
    """The command of the measuring child: prints the cuts' CPU seconds as JSON (a test seam)."""
    code = (
        "import json; from annotator.objects.machine_speed import reference_cut_seconds; "
        "print(json.dumps(reference_cut_seconds()))"
    )
    return [sys.executable, "-c", code]


_measured: float | None = None  # this process's factor, once measured (a failed measurement is not kept)


def forget() -> None:
    """Drop this process's measured factor: the next :func:`speed_factor` measures again (tests)."""
    global _measured
    _measured = None


def _clamped(factor: float, what: str) -> float:
    """``factor`` within :data:`FACTOR_RANGE`, said when it was not (``what``: where it came from)."""
    low, high = FACTOR_RANGE
    if low <= factor <= high:
        return factor
    log.warning("%s gives the factor %.3g: clamped to %g-%g", what, factor, low, high)
    return min(max(factor, low), high)


def speed_factor() -> float:
    """CPU seconds here per reference CPU-second (> 1: a slower machine), measured once per process.

    ``RG2_SPEED_FACTOR`` (:data:`FACTOR_ENV`), when set to a positive number, is the factor
    (clamped to :data:`FACTOR_RANGE` like a measurement). A child that fails or prints nothing
    usable gives 1.0 (plain CPU seconds) for this decomposition, said as a warning with the child's
    last line of error; it is not kept, so the next decomposition measures again."""
    global _measured
    given = os.environ.get(FACTOR_ENV, "").strip()
    if given:
        try:
            pinned = float(given)
        except ValueError:
            pinned = float("nan")
        if math.isfinite(pinned) and pinned > 0.0:
            return _clamped(pinned, FACTOR_ENV)
        log.warning("%s=%r is not a positive number; measuring this machine instead", FACTOR_ENV, given)
    if _measured is not None:
        return _measured
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    try:
        out = subprocess.run(
            measure_command(),
            capture_output=True,
            text=True,
            timeout=MEASURE_TIMEOUT,
            env=env,
            stdin=subprocess.DEVNULL,
            check=True,
        )
        seconds = [float(s) for s in json.loads(out.stdout.strip().splitlines()[-1])]
        measured = min(seconds)
        if not (math.isfinite(measured) and measured > 0.0):
            raise ValueError(f"the reference cut took {measured} CPU-s")
    except (OSError, subprocess.SubprocessError, ValueError, IndexError, TypeError) as exc:
        stderr = getattr(exc, "stderr", None) or ""
        last = stderr.strip().splitlines()[-1] if stderr.strip() else ""
        log.warning(
            "could not measure this machine's speed (%s%s); this decomposition's budget is in CPU seconds",
            exc,
            f": {last}" if last else "",
        )
        return 1.0
    factor = _clamped(measured / REFERENCE_CUT_SECONDS, f"a reference cut of {measured:.2f} CPU-s")
    log.info(
        "reference cut %.2f CPU-s here, %.2f on the budget's machine: the decomposition budget x %.2f",
        measured,
        REFERENCE_CUT_SECONDS,
        factor,
    )
    _measured = factor
    return factor
