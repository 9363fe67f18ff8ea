"""One object for a tool that simulates it in its own process (``annotator replay``), its
decomposition made the way a run makes it: by a decomposition task in a worker process, written to
the cache, then read from there. So a tool's process never decomposes, and it simulates the very
geometry a run with the same cache did."""

from __future__ import annotations

from pathlib import Path

from annotator.config import AnnotatorConfig
from annotator.objects import (
    NotDecomposed,
    ObjectError,
    ObjectModel,
    ObjectSource,
    default_cache_dir,
    load_object,
)
from annotator.pipeline.tasks import Prepare, SpanTask
from annotator.pipeline.worker import label_span


def load_prepared(
    source: ObjectSource, config: AnnotatorConfig, scale: float | None = None, cache_dir: Path | None = None
) -> ObjectModel:
    """The object's model in this process; if the cache (``cache_dir``, default
    :func:`default_cache_dir`) does not hold its decomposition, a worker process makes it first
    (the run's own decomposition task). Raises :class:`ObjectError` for an unusable object."""
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    try:
        return load_object(source, config.objects, scale=scale, cache_dir=cache, decompose=False)
    except NotDecomposed:
        pass
    from joblib.executor import get_memmapping_executor

    from annotator.pipeline.worker_spawn import detach_local_workers

    detach_local_workers()
    task = SpanTask(
        span=Prepare(source.object_id, source, scale), config=config, seed=0, n=1, cache_dir=str(cache)
    )
    result = get_memmapping_executor(1).submit(label_span, task).result()
    if result.error is not None:
        raise ObjectError(result.error)
    return load_object(source, config.objects, scale=scale, cache_dir=cache, decompose=False)
