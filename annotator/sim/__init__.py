"""PyBullet simulation: a world per process, bodies with joints by name, any parallel gripper.

Modules: ``world`` (a physics client and its settings, one per process), ``body`` (a loaded URDF
with its joints and links by name), ``rigid`` (rigid bodies by id), ``contacts`` (contact and
distance queries), ``camera``, ``gui``, ``decompose``, ``width_table``
(a gripper's opening against its driven joint, from forward kinematics), ``gripper`` (the
:class:`~annotator.sim.gripper.ParallelGripper` any gripper description is simulated as), ``hand``
(the floating gripper the object trials move by a constraint), ``ur3`` (the arm: names, DH
kinematics, closed-form IK). The grippers themselves are data (:mod:`annotator.grippers`,
``assets/grippers/``). The package imports nothing above it but ``config``, ``geometry`` and the
gripper descriptions (docs/architecture.md, "Floors").

Nothing outside this package calls PyBullet (``tests/test_floors.py`` checks it): ``rigid`` (a
body's pose, velocity, dynamics, shapes; loading and creating bodies; PyBullet's frame arithmetic),
``camera`` (view and projection matrices, images), ``gui`` (the GUI's sliders, text, camera and
keys) and ``decompose`` (V-HACD) wrap what the layers above need. Inside it, import pybullet
through this package (``from annotator.sim import pb``): it is imported here with its C-level
"pybullet build time" banner silenced.
"""

import os
import sys


def _import_pybullet_quietly() -> None:
    """Import pybullet with its C-level "pybullet build time" banner (on stderr) sent to /dev/null.

    Every process that imports the package (the command and each worker) would print the banner
    in the middle of the progress bar and the summary. Warnings after the import are untouched.
    """
    if "pybullet" in sys.modules:
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (AttributeError, OSError, ValueError):  # no real stderr (embedded interpreters)
        import pybullet  # noqa: F401

        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet  # noqa: F401
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


_import_pybullet_quietly()

import pybullet as pb  # noqa: E402  (imported above with the banner silenced)

__all__ = ["pb"]
