"""Finding and loading a gripper description: a shipped gripper's name or a user's folder, read,
checked (the model's forward kinematics, from the URDF's bytes: no physics client) and cached
while its files do not change."""

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
from annotator.grippers.urdf import UrdfModel, read_urdf_bytes

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
    check_inertials(description)
    check_kinematics(description)
    _check_name(description)
    return description


def check_inertials(description: GripperDescription) -> None:
    """Every link's mass, inertia and inertial origin physical (:mod:`annotator.grippers.
    inertials`); :class:`DescriptionError` naming the first link that is not, and its value."""
    from annotator.grippers.inertials import inertial_problems

    problems = inertial_problems(description_model(description))
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise DescriptionError(f"{description.urdf}: {problems[0]}{more}")


def _check_name(description: GripperDescription) -> None:
    """A shipped gripper's name belongs to its model: a description elsewhere may carry it only
    with the same files (a copy), else every row it labels would name the wrong gripper."""
    name = description.name
    if name not in shipped_grippers() or is_shipped(description):
        return
    shipped = gripper_dir(name) / TOML_NAME
    if description.digest != _load(str(shipped.resolve()), _stamp(shipped.parent)).digest:
        raise DescriptionError(
            f"{description.folder / TOML_NAME}: name {name!r} is a shipped gripper's and this model is "
            "another: give it its own name"
        )


def default_gripper() -> GripperDescription:
    """The OnRobot RG2, the gripper every command uses unless told otherwise."""
    return load_gripper(DEFAULT_GRIPPER)


def check_kinematics(description: GripperDescription) -> None:
    """The checks that need the model's forward kinematics, computed from the URDF's bytes the
    description holds (no physics client): the width is strictly monotonic in the drive over its
    limits, finger 1 sits at -x and finger 2 at +x of the base, and the drive's limits reach the
    stated stroke. :class:`DescriptionError` otherwise."""
    import numpy as np

    from annotator.config import GripperConfig

    d = description
    where = d.folder / TOML_NAME
    model = description_model(d)
    drive = model.joints[d.drive_joint]
    thickness = d.pad_size[0] if d.pad_size is not None else model.box_sizes[d.pad_links[0]][0]
    angles = np.linspace(drive.lower, drive.upper, GripperConfig().width_table_samples)
    widths = np.empty_like(angles)
    for k, q in enumerate(angles):
        q_joints = {d.drive_joint: float(q), **{m.follower: m.multiplier * q + m.offset for m in d.mimic}}
        x1, x2 = (model.T_root_link(pad, q_joints)[0, 3] for pad in d.pad_links)
        widths[k] = (x2 - x1) - thickness
    steps = np.diff(widths)
    if not (np.all(steps > 0) or np.all(steps < 0)):
        raise DescriptionError(
            f"{where}: the width is not monotonic in the drive {d.drive_joint!r} over its limits: "
            f"check {d.urdf}"
        )
    max_width, min_width = float(widths.max()), float(widths.min())
    if max_width <= 0.0:
        raise DescriptionError(
            f"{where}: [pads] links: finger 1's pad must sit at -x of the base, finger 2's at +x"
        )
    if max_width < d.stroke_max - STROKE_TOLERANCE:
        raise DescriptionError(
            f"{where}: [stroke] max {d.stroke_max:g} m is beyond the model: it opens to "
            f"{max_width:.4f} m at the limit of {d.drive_joint!r}"
        )
    if min_width > d.stroke_min + STROKE_TOLERANCE:
        raise DescriptionError(
            f"{where}: [stroke] min {d.stroke_min:g} m is below the model: it closes to "
            f"{min_width:.4f} m at the limit of {d.drive_joint!r}"
        )


def description_model(description: GripperDescription) -> UrdfModel:
    """The :class:`annotator.grippers.urdf.UrdfModel` of the URDF bytes ``description`` holds."""
    relative = description.urdf.resolve().relative_to(description.folder.resolve()).as_posix()
    return read_urdf_bytes(dict(description.files)[relative], description.urdf)


def is_shipped(description: GripperDescription) -> bool:
    """Is ``description`` read from the package's own ``assets/grippers/<name>`` folder?"""
    try:
        return description.folder.resolve() == gripper_dir(description.name).resolve()
    except OSError:
        return False
