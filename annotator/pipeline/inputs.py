"""What every job finds before it binds a run: the objects under ``--objects`` (discovered, never
loaded) with their source digests, and the gripper its tasks carry (the description, or its files
for a cluster's workers, which may not see the gripper's folder)."""

from __future__ import annotations

from collections.abc import Sequence

from annotator.config import AnnotatorConfig
from annotator.grippers import DescriptionError, GripperDescription, GripperFiles
from annotator.objects import ObjectDiscoveryError, ObjectError, ObjectSource, discover_objects, source_digest
from annotator.pipeline.execution import UsageError
from annotator.pipeline.lifecycle import TaskContext
from annotator.pipeline.options import RunOptions


def discover(options: RunOptions, config: AnnotatorConfig) -> list[ObjectSource]:
    """The objects under ``options.objects_dir`` (sorted by id); a folder that cannot be searched
    is a usage error."""
    try:
        return discover_objects(options.objects_dir, config.objects)
    except ObjectDiscoveryError as exc:
        raise UsageError(str(exc)) from exc


def digest_sources(
    sources: Sequence[ObjectSource], config: AnnotatorConfig
) -> tuple[dict[str, str], dict[str, str]]:
    """Each object's source digest (a mesh behind a URDF included), and the objects whose files
    cannot be read, with why: ``(object id -> digest, object id -> one line)``."""
    digests: dict[str, str] = {}
    unreadable: dict[str, str] = {}
    for source in sources:
        try:
            digests[source.object_id] = source_digest(source, config.objects.memory_budget)
        except ObjectError as exc:
            unreadable[source.object_id] = str(exc)
    return digests, unreadable


def sent_gripper(gripper: GripperDescription, context: TaskContext) -> GripperDescription | GripperFiles:
    """What a task carries of the run's ``gripper``: the description for local workers, its files
    for a cluster's (they may not see its folder); a gripper whose files cannot be packed is a
    usage error."""
    if context.local:
        return gripper
    try:
        return GripperFiles.of(gripper)
    except DescriptionError as exc:
        raise UsageError(f"--gripper: {exc}") from exc
