"""Shared by the tools: reading a labels folder with one-line errors, finding an object's mesh."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click
import pandas as pd

from annotator.dataset import SchemaError, load_labels

log = logging.getLogger(__name__)

MANIFEST_NAME = "_manifest.json"


class ToolError(click.ClickException):
    """A bad input to one of the tools: printed as one line ``Error: ...``, exit code 2 (usage)."""

    exit_code = 2


def read_labels(labels: str | Path) -> pd.DataFrame:
    """Every label under ``labels`` (a folder or a Parquet file), or :class:`ToolError`."""
    try:
        return load_labels(labels)
    except FileNotFoundError as exc:
        raise ToolError(str(exc)) from None
    except SchemaError as exc:
        raise ToolError(f"{labels}: not a label table ({exc})") from None
    except OSError as exc:  # unreadable or not Parquet
        raise ToolError(f"{labels}: cannot read labels ({exc})") from None


def read_manifest(labels: str | Path) -> dict | None:
    """The run's ``_manifest.json`` beside the labels as a dict, or None if there is none."""
    path = Path(labels)
    path = (path if path.is_dir() else path.parent) / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        log.warning("%s is unreadable (%s); ignoring it", path, exc)
        return None


def run_settings(manifest: dict | None) -> dict:
    """The run's settings (seed, n, trials, scale, config, ...) from a manifest of either layout:
    flat (manifest version 2) or under ``run`` (the pipeline's store)."""
    if not manifest:
        return {}
    run = manifest.get("run")
    if isinstance(run, dict):
        return run
    return {k: manifest[k] for k in ("seed", "n", "trials", "scale", "config") if k in manifest}


def labelling_config(labels_dir: str | Path):
    """The :class:`AnnotatorConfig` the labels were made with (defaults without a manifest)."""
    from annotator.config import AnnotatorConfig

    config = run_settings(read_manifest(labels_dir)).get("config")
    if not config:
        return AnnotatorConfig()
    try:
        return AnnotatorConfig.from_dict(config)
    except (ValueError, TypeError) as exc:
        raise ToolError(f"{labels_dir}: the manifest's configuration is not this version's ({exc})") from None


def object_info(manifest: dict | None, object_id: str) -> dict:
    """What the run recorded about an object as simulated (mass, friction, ...), or {}."""
    return ((manifest or {}).get("objects_info") or {}).get(object_id) or {}


def object_rows(labels: pd.DataFrame, object_id: str) -> pd.DataFrame:
    """The labels of one object, or a :class:`ToolError` listing a few known ids."""
    rows = labels[labels["object_id"] == object_id]
    if rows.empty:
        known = sorted(labels["object_id"].unique())
        more = f", ... ({len(known)} in all)" if len(known) > 8 else ""
        raise ToolError(f"unknown object id {object_id!r}; the labels have {', '.join(known[:8])}{more}")
    return rows.reset_index(drop=True)


def object_mesh(
    labels_dir: str | Path,
    object_id: str,
    objects_dir: str | Path | None = None,
    rows: pd.DataFrame | None = None,
):
    """The object's mesh in its mesh frame, as the label poses see it (metres, label's scale).

    With ``objects_dir`` the object is looked up there by id and loaded as ``annotate`` loads it
    (:func:`annotator.objects.load_object`, at the labels' ``object_scale``); a mesh whose hash
    differs from the labels' ``mesh_sha256`` is used with a warning. Without it, the geometry
    record the labels folder carries is used when this version writes one.
    """
    if objects_dir is None:
        try:
            from annotator.dataset import load_object_mesh  # written beside the labels (objects work)
        except ImportError:
            raise ToolError(
                f"pass --objects DIR (the folder the labels were made from): {labels_dir} carries no "
                f"geometry of {object_id!r}"
            ) from None
        try:
            return load_object_mesh(labels_dir, object_id)
        except (FileNotFoundError, KeyError, ValueError) as exc:
            raise ToolError(f"{object_id}: no mesh in {labels_dir} ({exc}); pass --objects DIR") from None
    from annotator.objects import ObjectDiscoveryError, ObjectError, discover_objects, load_object

    try:
        sources = {s.object_id: s for s in discover_objects(Path(objects_dir))}
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    if object_id not in sources:
        raise ToolError(f"object {object_id!r} is not in {objects_dir}")
    scale = float(rows["object_scale"].iloc[0]) if rows is not None and len(rows) else None
    config = labelling_config(labels_dir)
    try:
        model = load_object(sources[object_id], config.objects, scale=scale)
    except ObjectError as exc:
        raise ToolError(f"{object_id}: {exc}") from None
    if rows is not None and len(rows) and model.mesh_sha256 != rows["mesh_sha256"].iloc[0]:
        log.warning("%s: the mesh in %s differs from the one labelled (sha256)", object_id, objects_dir)
    return model.mesh
