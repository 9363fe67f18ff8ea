"""The labels of objects in the formats existing grasp learners read (:mod:`annotator.tools.formats`:
ACRONYM-style HDF5, GraspGen JSON), and what every export shares: its folder, the base poses.

Both formats give a grasp as the pose of the gripper's *base* frame in the object's mesh frame,
not of the TCP: its description's base link (``[base] link``, the frame convention in ``[base]
frame``). For the RG2 that frame is ``rg2_base_link``: origin on the tool flange, +z out along the
tool axis (the approach), +x the closing direction (finger 1 towards finger 2) -- the same axes as
our TCP, which sits on the tool axis between the pads. The RG2's fingertips move on arcs, so the
TCP's depth below the flange depends on the opening (161 mm fully open ... 200 mm closed); the
Panda's fingers slide, its TCP stays put. Every grasp is exported as

    T_obj_base = T_obj_tcp * T_base_tcp(width)^-1,    T_base_tcp(width) = translation (0, 0, d(width))

with ``d`` from the gripper model's own forward kinematics
(:meth:`annotator.sim.gripper.ParallelGripper.T_base_tcp`); ``gripper/type`` is the description's
``export_type`` (``onrobot_rg2``, ``franka_panda``, ``robotiq_2f85``).
The label's ``width`` is exported beside each transform, so ``T_obj_tcp`` is recovered exactly.
Labels that record their commanded grasp (``cmd_*``) also give ``commanded_transforms``: the
flange pose where the gripper was placed before closing (the same transform of the ``cmd`` pose
at ``cmd_width``), which is what a robot executes.

Each object's mesh is written once, as the labels see it (metres, mesh frame, scale applied), to
``meshes/<object id>.obj`` in the output folder; ``object/file`` names it and ``object/scale`` is 1.

Every file goes through the one output writer (:class:`ExportFolder`, on
:class:`annotator.store.outputs.Outputs`): the folder is locked for the export (a second export
into it is refused), each file is written to a temporary file and renamed, and recorded with its
SHA-256 in the folder's ``_export.json`` (no mark beside each file: the learners' readers list
the folders); a file the export did not write is never replaced.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from annotator.dataset import poses_as_matrices
from annotator.files import atomic_write_path
from annotator.grippers import GripperDescription

log = logging.getLogger(__name__)


def frame_note(description: GripperDescription) -> str:
    """What ``grasps/transforms`` are, written into every exported file."""
    return (
        f"grasps/transforms: {description.base_link} in the object mesh frame ({description.base_frame}). "
        "TCP (pad-centre midpoint, the rg2-annotator label pose) = transform * translation(0, 0, tcp_depth); "
        f"tcp_depth from the {description.name} model's FK at the opening: see grasps/width"
    )


@dataclass(frozen=True)
class LeftOut:
    """Grasps of the labels an export did not write: how many, and why (one line)."""

    grasps: int
    reason: str

    def to_json(self) -> dict:
        return {"grasps": int(self.grasps), "reason": self.reason}


@dataclass(frozen=True)
class ExportResult:
    """What ``export`` wrote: the folder, one file per object, the number of grasps written, and
    the grasps it left out (also recorded in the folder's ``_export.json``)."""

    out_dir: Path
    files: list[Path]
    n_grasps: int
    left_out: list[LeftOut] = field(default_factory=list)

    def summary(self) -> str:
        """One line: what was left out and why ("" when nothing was)."""
        return "; ".join(f"left out {x.grasps} grasps: {x.reason}" for x in self.left_out if x.grasps)


class TcpDepth:
    """``T_base_tcp(width)`` of a gripper model (default the RG2): the TCP in its base frame, from
    the model's own FK; ``config`` (a GripperConfig) resolves the run's grip force.

    The model is loaded once in a private DIRECT client; :meth:`ParallelGripper.T_base_tcp` only
    reads the FK table it tabulated, so it keeps working after the client is closed.
    """

    def __init__(self, gripper: GripperDescription | str | None = None, config=None) -> None:
        from annotator.config import GripperConfig
        from annotator.grippers import load_gripper
        from annotator.sim.body import Body
        from annotator.sim.gripper import ParallelGripper
        from annotator.sim.world import World

        self.description = load_gripper(gripper)
        with World() as world:
            body = Body.load(world.client, self.description.urdf, fixed_base=True)
            self._gripper = ParallelGripper(body, self.description, config or GripperConfig())

    @property
    def max_width(self) -> float:
        """The gripper's widest opening (m)."""
        return self._gripper.max_width

    @property
    def grip_force(self) -> float:
        """The run's squeeze, N per pad."""
        return self._gripper.grip_force

    def T_base_tcp(self, width: np.ndarray) -> np.ndarray:
        """(n, 4, 4) gripper-base-to-TCP transforms for openings ``width`` : (n,) m."""
        width = np.asarray(width, dtype=np.float64).reshape(-1)
        return np.array([self._gripper.T_base_tcp(float(w)).as_matrix() for w in width]).reshape(-1, 4, 4)


def base_poses(T_obj_tcp: np.ndarray, width: np.ndarray, depth: TcpDepth) -> np.ndarray:
    """``T_obj_base`` : (n, 4, 4) from label poses ``T_obj_tcp`` : (n, 4, 4) at ``width`` : (n,)."""
    return np.asarray(T_obj_tcp) @ np.linalg.inv(depth.T_base_tcp(width))


# ``write(path, fill)``: ``fill(tmp)`` fills a temporary file that becomes ``path`` (the exporters'
# writers take one: :meth:`ExportFolder.write_path` in an export, :func:`write_atomically` alone).
Writer = Callable[[Path, Callable[[Path], object]], object]


def write_atomically(path: Path, fill: Callable[[Path], object]) -> None:
    """``fill(tmp_path)`` then rename over ``path``: a file appears whole or not at all."""
    atomic_write_path(path, fill, make_parents=True)


def fill_text(text: str) -> Callable[[Path], object]:
    """A fill (:data:`Writer`'s second argument) writing ``text``."""

    def fill(tmp: Path) -> None:
        tmp.write_text(text)

    return fill


def fill_bytes(data: bytes) -> Callable[[Path], object]:
    """A fill (:data:`Writer`'s second argument) writing ``data``."""

    def fill(tmp: Path) -> None:
        tmp.write_bytes(data)

    return fill


def _fill_mesh(mesh: Any) -> Callable[[Path], object]:
    """A fill writing ``mesh`` as OBJ (trimesh's export, as before)."""

    def fill(tmp: Path) -> None:
        mesh.export(tmp, file_type="obj")

    return fill


EXPORT_RECORD = "_export.json"  # what an export wrote into its folder: the only files --overwrite removes
EXPORT_LOCK = ".export.rg2-annotator.lock"  # an export's lock of its whole folder (removed at the end)
EXPORT_COMMAND = "annotator export"


@dataclass
class ExportFolder:
    """An export's output folder: what earlier exports wrote there (its ``_export.json``) and what
    this one writes, every file through the one output writer (:class:`annotator.store.outputs.
    Outputs`: a temporary file renamed; its SHA-256 recorded in ``_export.json`` rather than in a
    mark beside it). The folder is locked for the export's life with the store's lock (a second
    export into it is refused naming the first); release it with :meth:`close` or :meth:`release`
    (or use the folder as a context manager). Files an export did not write are never replaced;
    ``overwrite`` removes the files the earlier export recorded, nothing else."""

    path: Path
    written: dict[str, str]  # name -> SHA-256 of what this export wrote
    lock: Any = None  # the folder's RunLock while held

    @classmethod
    def open(cls, out_dir: Path, *, overwrite: bool) -> ExportFolder:
        """Check, lock (and with ``overwrite`` clear) the folder before any work; ToolError if it
        holds another export and ``overwrite`` is not given, or another export is writing it;
        OutputToolError if it cannot be written."""
        from annotator.store.lock import RunLock
        from annotator.tools.common import acquire_output_lock, check_output_dir

        out_dir = check_output_dir(out_dir, "--out")
        lock = RunLock(out_dir, name=EXPORT_LOCK, whole_folder=False, subject=f"--out {out_dir}")
        acquire_output_lock(lock)
        folder = cls(out_dir, {}, lock)
        try:
            folder._clear(overwrite)
        except BaseException:
            folder.release()
            raise
        return folder

    def _clear(self, overwrite: bool) -> None:
        """An earlier export in the folder: refused, or with ``overwrite`` its files removed."""
        from annotator.tools.common import ToolError

        out_dir = self.path
        record = out_dir / EXPORT_RECORD
        if record.exists():
            if not overwrite:
                raise ToolError(
                    f"{out_dir} holds an earlier export; pass --overwrite to replace it (only the files an "
                    "export wrote are removed) or choose another --out"
                )
            for name in [*_earlier_files(record), EXPORT_RECORD]:
                path = out_dir / name
                if path.is_file() and not path.is_symlink():
                    path.unlink()
            from annotator.tools.formats import folders

            for sub in folders():  # the folders exports make, deepest first
                with contextlib.suppress(OSError):
                    (out_dir / sub).rmdir()  # once empty

    def target(self, name: str) -> Path:
        """Where the export writes ``name`` (relative, ``/``-separated); ToolError if a file the
        export did not write lies there."""
        from annotator.tools.common import ToolError

        path = self.path / name
        if name not in self.written and (path.exists() or path.is_symlink()):
            raise ToolError(
                f"{path} exists and was not written by an export; move it away or choose another --out"
            )
        return path

    def write(self, name: str, fill: Callable[[Path], object]) -> Path:
        """Write ``name`` (relative, ``/``-separated) through the one output writer: ``fill(tmp)``
        fills a temporary file, renamed over it; its digest kept for the record. Refused
        (ToolError) as :meth:`target` says. Returns where it went (beside it, ``NAME.new.EXT``,
        if someone wrote there meanwhile)."""
        from annotator.tools.common import claim_outputs

        path = self.target(name)
        with claim_outputs(
            EXPORT_COMMAND, {name: path}, overwrite=name in self.written, mark=False
        ) as claimed:
            written = claimed.write(name, fill)
        self.written[written.relative_to(self.path).as_posix()] = claimed.digest(written)
        return written

    def write_path(self, path: Path, fill: Callable[[Path], object]) -> Path:
        """:meth:`write` of ``path``, a file inside the folder (the exporters' :data:`Writer`)."""
        return self.write(Path(path).relative_to(self.path).as_posix(), fill)

    def close(self, fmt: str, labels: Path, left_out: Sequence[LeftOut] = ()) -> None:
        """Record what this export wrote (so a later --overwrite removes exactly that) and the
        grasps it left out (``left_out``: one entry per reason); then release the folder."""
        record: dict[str, Any] = {
            "format": fmt,
            "labels": str(labels),
            "files": sorted(self.written),
            "sha256": dict(sorted(self.written.items())),
        }
        if left_out:
            record["left_out"] = [x.to_json() for x in left_out]
        text = json.dumps(record, indent=1)
        try:
            self.write(EXPORT_RECORD, lambda tmp: tmp.write_text(text + "\n"))
        finally:
            self.release()

    def release(self) -> None:
        """Unlock the folder (its lock file goes)."""
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> ExportFolder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _earlier_files(record: Path) -> list[str]:
    """The files an earlier export recorded, each a plain relative path inside its folder."""
    try:
        names = json.loads(record.read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [
        n for n in names if isinstance(n, str) and not Path(n).is_absolute() and ".." not in Path(n).parts
    ]


def object_stem(object_id: str) -> str:
    """What an export names an object's files (its label file's name without ``.parquet``)."""
    from annotator.store.names import object_filename

    return object_filename(object_id)[: -len(".parquet")]


def _object_mass(rows: pd.DataFrame, manifest: dict | None) -> float:
    """The object's mass (kg) as simulated: the run's record of it, else the labels' column."""
    from annotator.tools.report import MASS_COLUMNS, _recorded

    mass = _recorded(manifest, str(rows["object_id"].iloc[0]), MASS_COLUMNS)
    if np.isnan(mass) and "object_mass" in rows.columns:
        return float(rows["object_mass"].median())
    return mass


def export(
    labels_dir: Path,
    fmt: str,
    out_dir: Path,
    objects_dir: Path | None = None,
    object_ids: tuple[str, ...] = (),
    gripper: GripperDescription | str | None = None,
    *,
    overwrite: bool = False,
    partial: bool = False,
) -> ExportResult:
    """Write one file per object in format ``fmt`` (an object format of
    :mod:`annotator.tools.formats`: ``acronym`` .h5, ``graspgen`` .json) and its mesh to ``out_dir``,
    then what the format adds once (GraspGen: the objects' split and the gripper's description).
    ``gripper``: the gripper the labels were made with (default the RG2).

    A folder holding an earlier export is refused unless ``overwrite`` (which removes what that
    export wrote, nothing else); labels of an unfinished run are refused unless ``partial``."""
    from annotator.tools.common import ToolError, labelling_config, open_labels
    from annotator.tools.formats import of_unit

    formats = of_unit("object")
    if fmt not in formats:
        raise ToolError(f"unknown format {fmt!r}; choose from {', '.join(formats)}")
    exporter = formats[fmt]
    if exporter.needs is not None:
        module, how = exporter.needs
        try:
            importlib.import_module(module)
        except ImportError:
            raise ToolError(how) from None
    run = open_labels(labels_dir)
    if not partial:
        run.require_finished("export")
    labels, manifest = run.labels, run.manifest
    if "scene_id" in labels.columns:  # a scene's grasps are numbered per scene, not per object
        scene_formats = " or ".join(of_unit("scene"))
        raise ToolError(f"{labels_dir} holds scenes: export them with --format {scene_formats}")
    ids = list(object_ids) or sorted(labels["object_id"].unique())
    config = labelling_config(labels_dir).config
    with ExportFolder.open(Path(out_dir), overwrite=overwrite) as folder:
        return _export(folder, labels_dir, labels, manifest, ids, fmt, config, objects_dir, gripper)


def _export(
    folder: ExportFolder, labels_dir, labels, manifest, ids, fmt, config, objects_dir, gripper
) -> ExportResult:
    """:func:`export`'s writing, into the locked ``folder``."""
    from annotator.tools.common import object_mesh, object_rows
    from annotator.tools.formats import of_unit
    from annotator.tools.given import records_commands, replay_grasps

    exporter = of_unit("object")[fmt]

    out_dir = folder.path
    depth = TcpDepth(gripper, config.gripper)
    description = depth.description
    friction, grip_force = config.objects.lateral_friction, depth.grip_force
    files: list[Path] = []
    n = 0
    assert exporter.write_object is not None  # an object format writes objects
    for oid in ids:
        rows = object_rows(labels, oid).sort_values("grasp_id", ignore_index=True)
        mesh = object_mesh(labels_dir, oid, objects_dir, rows)
        mesh_file = f"meshes/{object_stem(oid)}.obj"
        folder.write(mesh_file, _fill_mesh(mesh))
        T_obj_base = base_poses(poses_as_matrices(rows), rows["width"].to_numpy(), depth)
        commanded = None
        if records_commands(rows):  # where the gripper was placed before closing, flange frame
            T_cmd, cmd_width, _ = replay_grasps(rows, config, depth.max_width)
            commanded = base_poses(T_cmd, cmd_width, depth)
        extra = {
            "object_id": oid,
            "mass": _object_mass(rows, manifest),
            "friction": float(friction),
            "grip_force": float(grip_force),
            "mesh_sha256": str(rows["mesh_sha256"].iloc[0]),
            "label_scale": float(rows["object_scale"].iloc[0]),
            "commanded": commanded,
            "gripper_type": description.export_type,
            "base_frame": description.base_link,
            "frame_note": frame_note(description),
        }
        files.append(exporter.write_object(folder, object_stem(oid), rows, T_obj_base, mesh_file, extra))
        n += len(rows)
    if exporter.finish is not None:
        exporter.finish(folder, depth, config, labels, ids)
    folder.close(fmt, Path(labels_dir))
    log.info("exported %d grasps of %d objects to %s (%s)", n, len(ids), out_dir, fmt)
    return ExportResult(out_dir, files, n)
