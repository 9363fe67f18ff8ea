"""Shared by the tools: one validated reader of a labels folder (its labels and its manifest), the
configuration the labels were made with, output paths checked before any work, an object's mesh.

Every problem is one line and an exit code (:class:`ToolError`: 2, :class:`OutputToolError`: 3),
never a traceback and never a silent fallback.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
import numpy as np
import pandas as pd

from annotator.dataset import SchemaError, validate_labels
from annotator.store.outputs import Outputs

log = logging.getLogger(__name__)

# A label file can vanish between listing a folder and reading it (a run merging its chunks):
# the folder is read again, up to this many times.
READ_ATTEMPTS = 5


class ToolError(click.ClickException):
    """A bad input to one of the tools: printed as one line ``Error: ...``, exit code 2 (usage)."""

    exit_code = 2


class OutputToolError(ToolError):
    """An output of a tool cannot be written (missing or read-only folder, no space): exit code 3."""

    exit_code = 3


# --- outputs -------------------------------------------------------------------------------------


def acquire_output_lock(lock: Any) -> None:
    """Take ``lock`` (an :class:`annotator.store.lock.RunLock` on an output folder): held by
    another command, :class:`ToolError` naming it (exit 2); the folder not writable,
    :class:`OutputToolError` (exit 3)."""
    from annotator.store import LockedError, OutputError

    try:
        lock.acquire()
    except LockedError as exc:
        raise ToolError(str(exc)) from None
    except OutputError as exc:
        raise OutputToolError(str(exc)) from None


def check_output_dir(path: str | Path, what: str) -> Path:
    """Before any work: the folder ``path`` exists or can be made, and a file can be written in it."""
    from annotator.files import probe_writable

    path = Path(path)
    try:
        probe_writable(path)
    except OSError as exc:
        raise OutputToolError(f"{what} {path} cannot be written: {exc.strerror or exc}") from None
    return path


class ToolOutputs(Outputs):
    """The output files of one tool's command (:class:`annotator.store.outputs.Outputs`: atomic,
    marked, locked; never replacing a file the tool did not write, or one changed since, unless
    told), whose failure to write is one line, :class:`OutputToolError` (exit 3)."""

    def asked(self, option: str) -> bool:
        """Was a file given for ``option``?"""
        return option in self.claimed

    def write(self, option: str, fill: Any) -> Path:
        """:meth:`annotator.store.outputs.Outputs.write`: ``fill(tmp)`` fills the file; where it went."""
        from annotator.store import OutputError

        try:
            return super().write(option, fill)
        except OutputError as exc:
            raise OutputToolError(str(exc)) from None


def claim_outputs(
    command: str,
    paths: Mapping[str, Path | str | None],
    overwrite: bool = False,
    overwrite_option: str = "--overwrite",
    mark: bool = True,
) -> ToolOutputs:
    """Before any work: claim every file a tool's ``command`` writes (``paths``: option -> file,
    None: not asked for); see :class:`ToolOutputs`. Refusals are one line: :class:`ToolError`
    (exit 2) for a file that must not be replaced (a user's, one changed since the tool wrote it,
    unless ``overwrite``), one given to two options, or one another command is writing;
    :class:`OutputToolError` (exit 3) for one whose folder cannot take it. Inside a click command
    the claims end with the command; elsewhere use the result as a context manager. ``mark``:
    :class:`annotator.store.outputs.Outputs`' (False: no mark beside each file)."""
    from annotator.store import OutputError, StoreError

    try:
        claimed = ToolOutputs.claim(
            command, paths, overwrite=overwrite, overwrite_option=overwrite_option, mark=mark
        )
    except StoreError as exc:
        raise ToolError(str(exc)) from None
    except OutputError as exc:
        raise OutputToolError(str(exc)) from None
    context = click.get_current_context(silent=True)
    if context is not None:
        context.call_on_close(claimed.release)
    return claimed


# A picture the tools write carries this in a PNG tEXt chunk (key "Software"): says which program
# made it (whether a file may be replaced is its mark's business: annotator.store.outputs).
PICTURE_SOFTWARE = "rg2-annotator"


def png_bytes(image: Any) -> bytes:
    """``image`` ((h, w, 3) or (h, w) uint8) as PNG bytes, tagged with :data:`PICTURE_SOFTWARE`."""
    import io

    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_text("Software", PICTURE_SOFTWARE)
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", pnginfo=info)
    return buffer.getvalue()


# --- reading tables ------------------------------------------------------------------------------


def unique_columns(names: list[str], path: str | Path) -> None:
    """:class:`ToolError` when a column name repeats: which of the two would be meant?"""
    seen: set[str] = set()
    for name in names:
        if name in seen:
            count = list(names).count(name)
            raise ToolError(f"{path}: column {name!r} appears {count} times; column names must be unique")
        seen.add(name)


def csv_header(path: str | Path) -> list[str]:
    """The column names of a CSV file as written (pandas renames a repeated ``x`` to ``x.1``)."""
    import csv

    with open(path, newline="", encoding="utf-8-sig", errors="replace") as f:
        return [name.strip() for name in next(csv.reader(f), [])]


def read_table(path: str | Path, what: str) -> pd.DataFrame:
    """A CSV (by its suffix) or Parquet table the tools read, its column names unique;
    :class:`ToolError` (one line) when it is missing, unreadable or names a column twice."""
    path = Path(path)
    if not path.exists():
        raise ToolError(f"no {what} at {path}")
    is_csv = path.suffix.lower() == ".csv"
    try:
        if is_csv:
            unique_columns(csv_header(path), path)
            return pd.read_csv(path)
        if path.is_dir():  # a folder of Parquet files (a labels folder)
            df = pd.read_parquet(path)
            unique_columns(list(df.columns), path)
            return df
        import pyarrow.parquet as pq

        unique_columns(pq.read_schema(path).names, path)
        return pd.read_parquet(path)
    except ToolError:
        raise
    except Exception as exc:  # OSError, ValueError, ArrowInvalid, ParserError: not a table we can read
        kind = "a CSV file" if is_csv else "a Parquet or .csv file"
        raise ToolError(f"{path}: cannot read {what} ({type(exc).__name__}: {exc}); give {kind}") from None


_TRUTH = {"1": True, "0": False, "true": True, "false": False, "yes": True, "no": False}


def truth_column(values: pd.Series, where: str | Path, column: str) -> np.ndarray:
    """A column of real outcomes as bool (n,): 1/0, true/false, yes/no (any case; 1.0 and 0.0 as
    a spreadsheet writes them); :class:`ToolError` naming the first row that is none of those."""
    if values.dtype == bool:
        return values.to_numpy(dtype=bool)
    text = values.astype(str).str.strip().str.lower().str.replace(r"\.0$", "", regex=True)
    bad = ~text.isin(list(_TRUTH))
    if bad.any():
        row = int(np.argmax(bad.to_numpy()))
        raise ToolError(f"{where}: row {row}: {column} must be 1/0 or true/false, got {values.iloc[row]!r}")
    return text.map(_TRUTH).to_numpy(dtype=bool)


def one_row_per_grasp(
    labels: pd.DataFrame, path: str | Path, scene: int | None, option: str = "--scene"
) -> pd.DataFrame:
    """The labels keyed by (object_id, grasp_id): scene labels (where that pair repeats across
    scenes) only with a scene named (its rows), else :class:`ToolError` naming the option."""
    if scene is not None:
        if "scene_id" not in labels.columns:
            raise ToolError(f"{path}: not scene labels (no scene_id column); drop {option}")
        rows = labels[labels["scene_id"] == scene]
        if rows.empty:
            known = sorted(int(s) for s in labels["scene_id"].unique())
            shown = ", ".join(map(str, known[:10])) + (" ..." if len(known) > 10 else "")
            raise ToolError(f"{path} has no scene {scene}; its scenes: {shown}")
        labels = rows
    repeated = labels.duplicated(["object_id", "grasp_id"])
    if repeated.any():
        first = labels[repeated].iloc[0]
        where = (
            f"in {labels['scene_id'].nunique()} scenes; name one with {option} N"
            if "scene_id" in labels.columns
            else "more than once"
        )
        raise ToolError(
            f"{path}: object {first['object_id']!r} grasp {int(first['grasp_id'])} is labelled {where}"
        )
    return labels


# --- reading a labels folder ---------------------------------------------------------------------


@dataclass
class LabelsRun:
    """A labels folder (or one label file) as read: validated labels, the run's manifest (None
    when there is none beside the labels), and whether the run is unfinished.

    ``unfinished``: objects the run planned that are neither done nor failed; ``running``: a run
    holds the folder right now.
    """

    path: Path
    labels: pd.DataFrame
    manifest: dict[str, Any] | None = None
    unfinished: list[str] = field(default_factory=list)
    running: bool = False

    @property
    def finished(self) -> bool:
        """Every planned object done or failed, and no run writing now."""
        return not self.unfinished and not self.running

    def state(self) -> str:
        """One line: ``finished``, or why not."""
        if self.finished:
            return "finished" if self.manifest is not None else "unknown (no manifest beside the labels)"
        parts = ["a run is writing it now"] if self.running else []
        if self.unfinished:
            shown = ", ".join(self.unfinished[:3]) + (" ..." if len(self.unfinished) > 3 else "")
            parts.append(f"{len(self.unfinished)} of its objects not labelled yet ({shown})")
        return "unfinished: " + "; ".join(parts)

    def require_finished(self, command: str) -> None:
        """``--partial`` not given: an unfinished run is refused with one line."""
        if not self.finished:
            raise ToolError(
                f"{self.path} is {self.state()}; finish it (re-run the same annotate command) or pass "
                f"--partial to {command} what is there"
            )


def _manifest_path(labels: Path) -> Path:
    from annotator.store import MANIFEST_NAME

    return (labels if labels.is_dir() else labels.parent) / MANIFEST_NAME


def _folder(labels: str | Path):
    """The labels folder (:class:`annotator.store.reader.LabelsFolder`); :class:`ToolError` in one
    line for a manifest or journal that cannot be read."""
    from annotator.store import ManifestUnreadableError
    from annotator.store.reader import LabelsFolder

    try:
        return LabelsFolder.open(labels)
    except ManifestUnreadableError as exc:
        raise ToolError(f"{exc}") from None
    except FileNotFoundError:
        raise ToolError(f"no labels at {labels}") from None


def read_manifest(labels: str | Path) -> dict[str, Any] | None:
    """The run's manifest beside the labels, its journal applied, checked against its schema (as a
    dict), or None if there is none; :class:`ToolError` in one line for one of any other shape."""
    path = _manifest_path(Path(labels))
    if not path.parent.exists():
        return None
    manifest = _folder(path.parent).manifest
    return None if manifest is None else manifest.to_json()


def open_labels(labels: str | Path) -> LabelsRun:
    """Read a labels folder or file once, validated: the labels the run's manifest vouches for
    (files of other runs or a user's in the folder are not its labels), or every Parquet file
    when there is no manifest (:class:`annotator.store.reader.LabelsFolder`); one line and exit 2
    for anything unreadable."""
    from annotator.store.lock import is_locked
    from annotator.store.reader import UnreadableLabels

    path = Path(labels)
    if not path.exists():
        raise ToolError(f"no labels at {path}")
    for attempt in range(READ_ATTEMPTS):
        folder = _folder(path)
        try:
            if folder.manifest is not None and folder.file is None and not folder.label_files():
                raise ToolError(f"{path}: its run has written no labels yet")
            df = validate_labels(folder.read()).sort_values(
                ["object_id", "grasp_id"], kind="stable", ignore_index=True
            )
            break
        except FileNotFoundError as exc:
            if folder.manifest is None:
                raise ToolError(f"{path}: {exc}") from None
            if attempt == READ_ATTEMPTS - 1:
                raise ToolError(f"{path}: label files keep changing while being read ({exc})") from None
            time.sleep(0.05)  # a merge renamed or removed a chunk: read the folder again
        except UnreadableLabels as exc:
            raise ToolError(str(exc)) from None
        except SchemaError as exc:
            raise ToolError(f"{path}: not a label table ({exc})") from None
        except ToolError:
            raise
        except Exception as exc:  # unreadable, not Parquet
            raise ToolError(f"{path}: cannot read labels ({type(exc).__name__}: {exc})") from None
    manifest = None if folder.manifest is None else folder.manifest.to_json()
    unfinished: list[str] = []
    if manifest is not None:
        planned = manifest.get("objects_planned") or []
        unfinished = sorted(set(planned) - set(manifest["objects_done"]) - set(manifest["objects_failed"]))
        unfinished += sorted(set(manifest["chunks_done"]) - set(planned))
    return LabelsRun(path, df, manifest, unfinished, running=is_locked(folder.path))


def read_labels(labels: str | Path) -> pd.DataFrame:
    """Every label under ``labels`` (a folder or a Parquet file), validated, or :class:`ToolError`."""
    return open_labels(labels).labels


def run_settings(manifest: dict | None) -> dict:
    """The run's settings (seed, n, trials, scale, config, ...) of a manifest, {} without one."""
    return dict((manifest or {}).get("run") or {})


@dataclass(frozen=True)
class LabellingConfig:
    """The configuration to simulate labels with, and where it came from (said to the user)."""

    config: Any  # annotator.config.AnnotatorConfig
    source: str

    def line(self) -> str:
        """One line saying which configuration is used."""
        return f"configuration: {self.source}"


def labelling_config(labels: str | Path | None, config_file: Path | None = None) -> LabellingConfig:
    """The configuration the labels were made with (their manifest's), unless ``config_file``
    (--config) is given; the defaults when there is neither. A manifest whose configuration this
    version cannot read is one line, never a silent fallback to the defaults."""
    from annotator.config import AnnotatorConfig

    if config_file is not None:
        try:
            return LabellingConfig(AnnotatorConfig.from_toml(config_file), f"--config {config_file}")
        except (ValueError, OSError) as exc:
            raise ToolError(f"--config {config_file}: {exc}") from None
    manifest = read_manifest(labels) if labels is not None and Path(labels).exists() else None
    settings = run_settings(manifest)
    config = settings.get("config")
    if not config or labels is None:  # no labels, no manifest: nothing but the defaults
        return LabellingConfig(AnnotatorConfig(), "the defaults (no manifest beside the labels)")
    try:
        return LabellingConfig(
            AnnotatorConfig.from_run(config, settings.get("trials", 1)),
            f"the labels' own ({_manifest_path(Path(labels))})",
        )
    except (ValueError, TypeError) as exc:
        raise ToolError(f"{labels}: the manifest's configuration is not this version's ({exc})") from None


@dataclass(frozen=True)
class LabellingGripper:
    """The gripper to simulate or draw labels with, and where that choice came from (said to the user)."""

    description: Any  # annotator.grippers.GripperDescription
    source: str

    def line(self) -> str:
        return f"gripper: {self.description.name} ({self.source})"


def labelling_gripper(
    labels: str | Path | None, gripper: str | os.PathLike | None = None, rows: pd.DataFrame | None = None
) -> LabellingGripper:
    """The gripper the labels were made with, unless ``gripper`` (--gripper) is given.

    Recorded with the labels: the run's manifest binds the gripper's name and digest (and where a
    gripper of the user's own was read from); a label file without a manifest has a ``gripper``
    column (``rows``, read from ``labels`` when not given). A shipped gripper is found by its name;
    one of the user's own at the folder the manifest names, if it is still that gripper (the same
    digest), else a :class:`ToolError` asking for ``--gripper``. Nothing recorded: the RG2, said so.
    """
    from annotator.grippers import DescriptionError, load_gripper

    recorded = _recorded_gripper(labels, rows)
    if gripper is not None:
        try:
            description = load_gripper(gripper)
        except DescriptionError as exc:
            raise ToolError(f"--gripper: {exc}") from None
        note = ""
        if recorded is not None and recorded[0].get("name") != description.name:
            note = f"; the labels were made with {recorded[0].get('name')}"
        return LabellingGripper(description, f"--gripper {gripper}{note}")
    if recorded is None:
        return LabellingGripper(load_gripper(None), "the default: no gripper recorded with the labels")
    return _resolve_recorded(*recorded)


def _recorded_gripper(
    labels: str | Path | None, rows: pd.DataFrame | None
) -> tuple[dict[str, str | None], str] | None:
    """``({"name", "digest", "folder"}, where)`` recorded with the labels, or None."""
    if labels is None or not Path(labels).exists():
        return None
    manifest = read_manifest(labels)
    record = run_settings(manifest).get("gripper")
    if record:
        return {**record, "folder": (manifest or {}).get("gripper_folder")}, str(_manifest_path(Path(labels)))
    if rows is None and manifest is None and Path(labels).is_file() and Path(labels).suffix == ".parquet":
        try:
            rows = pd.read_parquet(labels, columns=["gripper"])
        except Exception:  # no such column, or not Parquet: nothing recorded
            return None
    if rows is None or "gripper" not in rows.columns or rows.empty:
        return None
    names = sorted(set(rows["gripper"].astype(str)))
    if len(names) > 1:
        raise ToolError(f"{labels}: labels of several grippers ({', '.join(names)}); pass --gripper")
    return {"name": names[0], "digest": None, "folder": None}, f"the labels' gripper column ({labels})"


def _resolve_recorded(record: dict[str, str | None], where: str) -> LabellingGripper:
    """The description of a recorded gripper (see :func:`labelling_gripper`)."""
    from annotator.grippers import DescriptionError, load_gripper, shipped_grippers

    name, digest, folder = record.get("name"), record.get("digest"), record.get("folder")
    if folder:
        try:
            description = load_gripper(folder)
        except DescriptionError:
            description = None
        if description is not None and description.digest == digest:
            return LabellingGripper(description, f"the labels' own, from {folder}")
        raise ToolError(
            f"the labels were made with gripper {name!r} (digest {str(digest)[:12]}) from {folder}, which "
            "is no longer there or has changed; pass --gripper DIR (its folder)"
        )
    if name not in shipped_grippers():
        raise ToolError(
            f"the labels were made with gripper {name!r}, which is not shipped; pass --gripper DIR"
        )
    description = load_gripper(name)
    source = f"the labels' own, recorded in {where}"
    if digest is not None and description.digest != digest:
        source += (
            f"; its description has changed since (digest {str(digest)[:12]} then, "
            f"{description.digest[:12]} now): simulating today's"
        )
        log.warning("gripper %s: the shipped description changed since these labels were made", name)
    return LabellingGripper(description, source)


def labels_resting(labels: str | Path | None) -> str | None:
    """How these labels' objects rested on the table (``evaluate --resting``): ``"object"`` (the
    grasps moved with them), ``"table"`` (the grasps stayed in the table frame) or None (floating)."""
    if labels is None or not Path(labels).exists():
        return None
    from annotator.pipeline.modes import resting_grasps

    return resting_grasps((run_settings(read_manifest(labels)).get("inputs") or {}).get("resting"))


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

    With ``objects_dir`` the object is looked up there by id and read and cleaned as ``annotate``
    reads it (:func:`annotator.objects.read_object`, at the labels' ``object_scale``; never
    decomposed: only its mesh is drawn or measured); a mesh whose hash differs from the labels'
    ``mesh_sha256`` is used with a warning. Without it, the geometry
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
    from annotator.objects import ObjectDiscoveryError, ObjectError, discover_objects, read_object

    try:
        sources = {s.object_id: s for s in discover_objects(Path(objects_dir))}
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    if object_id not in sources:
        raise ToolError(f"object {object_id!r} is not in {objects_dir}")
    scale = float(rows["object_scale"].iloc[0]) if rows is not None and len(rows) else None
    config = labelling_config(labels_dir).config
    try:
        model = read_object(sources[object_id], config.objects, scale=scale)
    except ObjectError as exc:
        raise ToolError(f"{object_id}: {exc}") from None
    if rows is not None and len(rows) and model.mesh_sha256 != rows["mesh_sha256"].iloc[0]:
        log.warning("%s: the mesh in %s differs from the one labelled (sha256)", object_id, objects_dir)
    return model.mesh
