"""rg2-annotator: batch grasp annotation for a UR3 + OnRobot RG2 in PyBullet."""

import os as _os
import sys as _sys

__version__ = "0.1.0"


def _import_pybullet_quietly() -> None:
    """Import pybullet with its C-level "pybullet build time" banner (on stderr) sent to /dev/null.

    Every process that imports the package (the command and each worker) would print the banner
    in the middle of the progress bar and the summary. Warnings after the import are untouched.
    """
    if "pybullet" in _sys.modules:
        return
    try:
        _sys.stderr.flush()
        saved = _os.dup(2)
    except (AttributeError, OSError, ValueError):  # no real stderr (embedded interpreters)
        import pybullet  # noqa: F401

        return
    devnull = _os.open(_os.devnull, _os.O_WRONLY)
    try:
        _os.dup2(devnull, 2)
        import pybullet  # noqa: F401
    finally:
        _os.dup2(saved, 2)
        _os.close(saved)
        _os.close(devnull)


_import_pybullet_quietly()
