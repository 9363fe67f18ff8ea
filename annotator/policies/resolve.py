"""From ``--policy NAME`` to the policy a round calls.

NAME is, in this order:

- ``labels`` or ``random``: the policies that see the true scene (:mod:`annotator.policies.oracle`);
- a name in :data:`NAMED` (``vision-random``, ``learned``) or an entry point of the group
  ``rg2_annotator.policies`` (a package's ``[project.entry-points."rg2_annotator.policies"]``
  ``name = "module:function"``): a vision policy;
- ``module:function`` (``module.sub:object.method`` too): a vision policy, imported;
- otherwise a predictions file (:mod:`annotator.policies.predictions`).

A vision policy is called ``function(observation, **args)`` at every attempt
(:mod:`annotator.policies.loop`), ``args`` the ``--policy-arg KEY=VALUE`` pairs.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from importlib import metadata

from annotator.policies.loop import VisionPolicy, vision_round_policy
from annotator.policies.oracle import RoundPolicy, labels_policy, random_policy
from annotator.policies.records import PolicyError

ORACLES = ("labels", "random")
ENTRY_POINT_GROUP = "rg2_annotator.policies"
NAMED = {
    "vision-random": "annotator.policies.vision:vision_random",
    "learned": "annotator.learn.policy:learned",
}


def is_vision_policy(name: str) -> bool:
    """Whether ``name`` names a vision policy (rather than an oracle or a predictions file)."""
    if name in ORACLES:
        return False
    return name in NAMED or ":" in name or _entry_point(name) is not None


def _entry_point(name: str) -> metadata.EntryPoint | None:
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            return ep
    return None


def load_callable(name: str) -> VisionPolicy:
    """The callable ``name`` names (module docstring); PolicyError (one line) if it cannot be had."""
    target = NAMED.get(name)
    if target is None and ":" not in name:
        ep = _entry_point(name)
        if ep is None:
            raise PolicyError(f"--policy {name}: no such policy")
        target = ep.value
    target = target or name
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise PolicyError(f"--policy {name}: give a vision policy as module:function")
    try:
        obj: object = importlib.import_module(module_name)
    except ImportError as exc:
        raise PolicyError(f"--policy {name}: cannot import {module_name} ({exc})") from None
    for part in attribute.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise PolicyError(f"--policy {name}: {module_name} has no {attribute}") from None
    if not callable(obj):
        raise PolicyError(f"--policy {name}: {target} is not callable")
    return obj


def round_policy(
    name: str, *, seed: int, trials: int = 1, args: Mapping[str, str] | None = None, views: int = 1
) -> RoundPolicy:
    """The round policy for ``--policy name`` (not a predictions file): an oracle, or the vision
    policy ``name`` observed through ``views`` depth views and called with ``args``."""
    if name == "labels":
        return labels_policy(seed, trials)
    if name == "random":
        return random_policy(seed)
    return vision_round_policy(load_callable(name), dict(args or {}), views)
