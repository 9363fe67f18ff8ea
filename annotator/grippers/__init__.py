"""Grippers as data: a folder with a URDF and a ``gripper.toml`` describes a parallel gripper.

``load_gripper("panda")`` (a shipped gripper, under ``assets/grippers/``) or
``load_gripper("path/to/folder")`` (your own) returns a checked :class:`GripperDescription`;
:class:`annotator.sim.gripper.ParallelGripper` simulates it. ``docs/grippers.md`` documents the
format and the shipped grippers' numbers with their sources.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from annotator.grippers.description import (
    TOML_NAME,
    DescriptionError,
    GripperDescription,
    read_description,
)
from annotator.grippers.package import GripperFiles, gripper_record, is_shipped, resolve_gripper
from annotator.grippers.urdf import Mimic, read_mimic_table, read_urdf

__all__ = [
    "DEFAULT_GRIPPER",
    "DescriptionError",
    "GripperDescription",
    "GripperFiles",
    "Mimic",
    "default_gripper",
    "gripper_dir",
    "gripper_record",
    "is_shipped",
    "load_gripper",
    "read_mimic_table",
    "read_urdf",
    "resolve_gripper",
    "shipped_grippers",
]

DEFAULT_GRIPPER = "rg2"
# The model's FK must reach the stated stroke within this (m): a stroke is a datasheet figure, the
# model's joint limits are derived from it (the RG2's give 0 .. 110.0 mm).
STROKE_TOLERANCE = 0.001


def gripper_dir(name: str) -> Path:
    """The folder of shipped gripper ``name`` (``assets/grippers/<name>``)."""
    from annotator import paths

    return paths.grippers_dir() / name


def shipped_grippers() -> tuple[str, ...]:
    """Names of the grippers shipped with the package, sorted."""
    from annotator import paths

    folder = paths.grippers_dir()
    return tuple(sorted(p.parent.name for p in folder.glob(f"*/{TOML_NAME}")))


def load_gripper(spec: str | os.PathLike | GripperDescription | None = None) -> GripperDescription:
    """The checked description of ``spec``: a shipped gripper's name, a folder holding a
    ``gripper.toml`` (or that file), a description already loaded, or None for the default (the
    RG2). :class:`DescriptionError` (one line) when it cannot be used."""
    if isinstance(spec, GripperDescription):
        return spec
    spec = DEFAULT_GRIPPER if spec is None else spec
    text = os.fspath(spec)
    if isinstance(spec, str) and text in shipped_grippers():
        path = gripper_dir(text)
    else:
        path = Path(text)
        if not path.exists():
            known = ", ".join(shipped_grippers())
            raise DescriptionError(
                f"no gripper {text!r}: name a shipped one ({known}) or a folder with {TOML_NAME}"
            )
    toml = path if path.suffix == ".toml" else path / TOML_NAME
    return _load(str(toml.resolve()) if toml.exists() else str(toml), _stamp(toml.parent))


def _stamp(folder: Path) -> tuple:
    """What changes when any file of a description folder changes (its cache key)."""
    if not folder.is_dir():
        return ()
    files = sorted(p for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    return tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in files)


@functools.lru_cache(maxsize=16)
def _load(toml: str, stamp: tuple) -> GripperDescription:
    description = read_description(toml)
    check_kinematics(description)
    return description


def default_gripper() -> GripperDescription:
    """The OnRobot RG2, the gripper every command uses unless told otherwise."""
    return load_gripper(DEFAULT_GRIPPER)


def check_kinematics(description: GripperDescription) -> None:
    """The checks that need the model's forward kinematics (PyBullet, a private DIRECT client):
    the width is monotonic in the drive, finger 1 sits at -x and finger 2 at +x of the base, and
    the drive's limits reach the stated stroke. :class:`DescriptionError` otherwise."""
    from annotator.config import GripperConfig
    from annotator.sim import pb
    from annotator.sim.body import Body
    from annotator.sim.width_table import fk_table

    d = description
    where = d.folder / TOML_NAME
    client = pb.connect(pb.DIRECT)
    try:
        drive = Body.load(client, d.urdf, fixed_base=True).joints[d.drive_joint]
    finally:
        pb.disconnect(physicsClientId=client)
    thickness = None if d.pad_size is None else d.pad_size[0]
    samples = GripperConfig().width_table_samples
    try:
        table = fk_table(
            str(d.urdf), d.drive_joint, d.pad_links, d.base_link, thickness, drive.lower, drive.upper, samples
        )
    except ValueError as exc:
        raise DescriptionError(f"{where}: {exc}") from exc
    if table.max_width <= 0.0:
        raise DescriptionError(
            f"{where}: [pads] links: finger 1's pad must sit at -x of the base, finger 2's at +x"
        )
    if table.max_width < d.stroke_max - STROKE_TOLERANCE:
        raise DescriptionError(
            f"{where}: [stroke] max {d.stroke_max:g} m is beyond the model: it opens to "
            f"{table.max_width:.4f} m at the limit of {d.drive_joint!r}"
        )
    if table.min_width > d.stroke_min + STROKE_TOLERANCE:
        raise DescriptionError(
            f"{where}: [stroke] min {d.stroke_min:g} m is below the model: it closes to "
            f"{table.min_width:.4f} m at the limit of {d.drive_joint!r}"
        )
