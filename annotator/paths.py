"""Locations of the shipped robot models, resolved through the installed package."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def assets_dir() -> Path:
    """Return the folder holding the robot models (``assets/`` in the source tree)."""
    return Path(str(resources.files("annotator.assets")))


def grippers_dir() -> Path:
    """The folder of the shipped gripper descriptions (``assets/grippers/<name>/``)."""
    return assets_dir() / "grippers"


def ur3_rg2_urdf() -> Path:
    """The UR3 arm with the RG2 on its flange (the seed scene's file name)."""
    return assets_dir() / "ur3" / "ur3_visual_grabbing_with_rg2.urdf"


def ur3_urdf() -> Path:
    """The bare UR3 arm."""
    return assets_dir() / "ur3" / "ur3.urdf"


def kinect_urdf() -> Path:
    """A Kinect v2 body with a named camera frame."""
    return assets_dir() / "ur3" / "kinect_v2.urdf"
