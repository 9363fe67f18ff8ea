"""A gripper's masses and inertias checked before it simulates anything.

PyBullet takes a link's ``<inertial>`` as written: a mass of -1 or ``nan``, an inertia of
``inf``, an inertial origin of ``inf`` all load without a word, and the gripper then labels
nothing as it should (every grasp fails, or every object fails with an error about the width
table). Each link that has an ``<inertial>`` must have (the link named, the value shown,
otherwise):

* a mass that is a finite number > 0 kg: zero makes PyBullet treat a link as fixed in space, a
  negative or infinite one is no body;
* an inertia tensor of finite numbers whose principal moments are all > 0 (a real body's, as a
  positive-definite matrix; a zero moment lets the link spin freely about that axis), and that
  satisfy the triangle inequality (each at most the sum of the other two, as every rigid body's
  do; within :data:`TRIANGLE_TOLERANCE`): a tensor that breaks it belongs to no mass distribution;
* an inertial frame whose origin and angles are finite numbers.

:func:`inertial_problems` runs where a description is loaded (:func:`annotator.grippers.
load_gripper`), so every command that simulates a gripper, and ``annotator gripper check``, refuses
such a model in one line before any work.
"""

from __future__ import annotations

import math

import numpy as np

from annotator.grippers.urdf import Inertial, UrdfModel

# Relative slack on the principal moments' triangle inequality: box and cylinder formulas printed
# to 5 significant digits (the shipped models' 1.0041e-03 ...) must pass.
TRIANGLE_TOLERANCE = 1e-3


def inertial_problem(name: str, inertial: Inertial) -> str | None:
    """What is wrong with link ``name``'s ``<inertial>`` (module docstring), or None."""
    mass = inertial.mass
    if not (math.isfinite(mass) and mass > 0.0):
        return f"link {name!r}: mass {mass:g} kg: must be a finite number > 0"
    for label, values in (("origin xyz", inertial.xyz), ("origin rpy", inertial.rpy)):
        if not all(math.isfinite(v) for v in values):
            written = " ".join(f"{v:g}" for v in values)
            return f"link {name!r}: inertial {label} {written}: must be finite numbers"
    ixx, ixy, ixz, iyy, iyz, izz = inertial.inertia
    shown = f"ixx {ixx:g} ixy {ixy:g} ixz {ixz:g} iyy {iyy:g} iyz {iyz:g} izz {izz:g} kg m^2"
    if not all(math.isfinite(v) for v in inertial.inertia):
        return f"link {name!r}: inertia {shown}: must be finite numbers"
    moments = np.linalg.eigvalsh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    if moments[0] <= 0.0:
        return (
            f"link {name!r}: inertia {shown}: its principal moments must all be > 0 (smallest {moments[0]:g})"
        )
    if moments[2] > (moments[0] + moments[1]) * (1.0 + TRIANGLE_TOLERANCE):
        return (
            f"link {name!r}: inertia {shown}: its largest principal moment {moments[2]:g} exceeds the sum of "
            f"the other two ({moments[0] + moments[1]:g}): no rigid body has it"
        )
    return None


def inertial_problems(model: UrdfModel) -> list[str]:
    """Every link's :func:`inertial_problem`, in document order."""
    found = (inertial_problem(name, inertial) for name, inertial in model.inertials.items())
    return [problem for problem in found if problem is not None]
