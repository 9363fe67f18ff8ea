"""Grippers as data: a folder with a URDF and a ``gripper.toml`` describes a parallel gripper.

``load_gripper("panda")`` (a shipped gripper, under ``assets/grippers/``) or
``load_gripper("path/to/folder")`` (your own) returns a checked :class:`GripperDescription`;
:class:`annotator.sim.gripper.ParallelGripper` simulates it. ``docs/grippers.md`` documents the
format and the shipped grippers' numbers with their sources.
"""

from __future__ import annotations

from annotator.grippers.description import DescriptionError, GripperDescription
from annotator.grippers.loading import (
    DEFAULT_GRIPPER,
    STROKE_TOLERANCE,
    check_kinematics,
    default_gripper,
    description_model,
    gripper_dir,
    is_shipped,
    load_gripper,
    shipped_grippers,
)
from annotator.grippers.package import GripperFiles, gripper_record, resolve_gripper
from annotator.grippers.urdf import Mimic, read_mimic_table, read_urdf

__all__ = [
    "DEFAULT_GRIPPER",
    "STROKE_TOLERANCE",
    "DescriptionError",
    "GripperDescription",
    "GripperFiles",
    "Mimic",
    "check_kinematics",
    "default_gripper",
    "description_model",
    "gripper_dir",
    "gripper_record",
    "is_shipped",
    "load_gripper",
    "read_mimic_table",
    "read_urdf",
    "resolve_gripper",
    "shipped_grippers",
]
