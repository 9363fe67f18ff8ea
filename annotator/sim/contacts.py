"""PyBullet's contact and closest-point tuples, read once into named records.

``getContactPoints`` and ``getClosestPoints`` return 14-field tuples; code that reads ``c[9]``
says nothing about what it reads. These records name the fields (PyBullet Quickstart Guide,
"getContactPoints"); ``Contact._make(t)`` costs a fraction of a microsecond, so they are used on
the hot paths too.
"""

from __future__ import annotations

from typing import NamedTuple

import pybullet as pb


class Contact(NamedTuple):
    """One contact (or closest) point between bodies A and B, as PyBullet reports it.

    Positions are in the world frame (m); ``normal_on_b`` is the contact normal on B pointing
    towards A; ``distance`` is the signed separation (m, negative when penetrating);
    ``normal_force`` (N) and the two lateral friction forces come from the last step (0 for
    closest points, which are not simulated).
    """

    flag: int
    body_a: int
    body_b: int
    link_a: int
    link_b: int
    position_on_a: tuple[float, float, float]
    position_on_b: tuple[float, float, float]
    normal_on_b: tuple[float, float, float]
    distance: float
    normal_force: float
    lateral_friction_1: float
    lateral_friction_dir_1: tuple[float, float, float]
    lateral_friction_2: float
    lateral_friction_dir_2: tuple[float, float, float]


def contact_points(client: int, a: int, b: int, *, link_a: int | None = None) -> list[Contact]:
    """The contacts of the last step between body ``a`` (its link ``link_a`` if given) and ``b``."""
    extra = {} if link_a is None else {"linkIndexA": link_a}
    return [Contact._make(c) for c in pb.getContactPoints(a, b, physicsClientId=client, **extra)]


def closest_points(client: int, a: int, b: int, distance: float) -> list[Contact]:
    """Pairs of points of ``a`` and ``b`` closer than ``distance`` (m), for the current poses
    (no step needed: the kinematic collision checks)."""
    return [Contact._make(c) for c in pb.getClosestPoints(a, b, distance, physicsClientId=client)]


def touching(points: list[Contact], margin: float, *, except_links_a: tuple[int, ...] = ()) -> bool:
    """Any of ``points`` closer than ``margin`` (m) on a link of A not in ``except_links_a``."""
    return any(p.distance < margin and p.link_a not in except_links_a for p in points)
