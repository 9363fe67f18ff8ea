"""Helpers for the tests of gripper descriptions: a user's copy of the shipped RG2 folder, an edit of
one of its files, and the one-line error a broken folder gives."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from annotator.grippers import DescriptionError, gripper_dir, load_gripper


def users_rg2(parent: Path) -> Path:
    """A user's RG2 in ``parent``/my_rg2: the shipped files under the user's own name (edited, it
    is another model)."""
    folder = parent / "my_rg2"
    shutil.copytree(gripper_dir("rg2"), folder, ignore=shutil.ignore_patterns("*.py", "*.md", "__pycache__"))
    edit(folder / "gripper.toml", 'name = "rg2"', 'name = "my_rg2"')
    return folder


def edit(path: Path, old: str, new: str, count: int = 1) -> None:
    """Replace ``old`` (which must be there) by ``new`` in the text file ``path``, ``count`` times."""
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, count))


def description_error(folder: Path) -> str:
    """The message of the DescriptionError loading ``folder`` raises, checked to be one line
    without a traceback."""
    with pytest.raises(DescriptionError) as info:
        load_gripper(folder)
    message = str(info.value)
    assert "\n" not in message and "Traceback" not in message
    return message
