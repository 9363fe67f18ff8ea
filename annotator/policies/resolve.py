"""From ``--policy NAME`` to the policy a round calls.

NAME is, in this order:

- ``labels`` or ``random``: the policies that see the true scene (:mod:`annotator.policies.oracle`);
- a name in :data:`NAMED` (``vision-random``, ``learned``) or an entry point of the group
  ``rg2_annotator.policies`` (a package's ``[project.entry-points."rg2_annotator.policies"]``
  ``name = "module:function"``): a vision policy;
- ``module:function`` (``module.sub:object.method`` too): a vision policy, imported with the
  current folder first on the path (as Python does for a script), for the loop and its workers;
- otherwise a predictions file (:mod:`annotator.policies.predictions`).

A vision policy is called ``function(observation, **args)`` at every attempt
(:mod:`annotator.policies.loop`), ``args`` the ``--policy-arg KEY=VALUE`` pairs.
"""

from __future__ import annotations

import importlib
import os
import sys
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
    obj: object = _import(name, module_name, here=name not in NAMED and ":" in name)
    for part in attribute.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise PolicyError(f"--policy {name}: {module_name} has no {attribute}") from None
    if not callable(obj):
        raise PolicyError(f"--policy {name}: {target} is not callable")
    return obj


def _import(name: str, module_name: str, *, here: bool) -> object:
    """Import a policy's module: whatever its import raises (a missing module, a syntax error, an
    error of its own, ``sys.exit``) is one line, PolicyError. ``here``: a user's ``module:function``,
    for which the current folder is importable (:func:`importable_here`), as ``python -c`` makes it."""
    if here:
        importable_here()
    try:
        return importlib.import_module(module_name)
    except SyntaxError as exc:
        where = f"{exc.filename}, line {exc.lineno}" if exc.filename else module_name
        raise PolicyError(f"--policy {name}: {module_name} has a syntax error ({where}: {exc.msg})") from None
    except (Exception, SystemExit) as exc:
        text = " ".join(str(exc).split())[:300]
        raise PolicyError(
            f"--policy {name}: cannot import {module_name} ({type(exc).__name__}: {text})"
        ) from None


def importable_here() -> None:
    """Put the current folder on ``sys.path`` (first) and in ``PYTHONPATH`` (for the worker
    processes, which start with the environment), as ``python`` does for a script or ``-c``: a
    policy saved beside the command (``my_policy.py``, docs/learning.md) imports as
    ``my_policy:grasps`` in the loop and in every worker."""
    here = os.getcwd()
    if here not in sys.path:
        sys.path.insert(0, here)
    paths = os.environ.get("PYTHONPATH", "").split(os.pathsep) if os.environ.get("PYTHONPATH") else []
    if here not in paths:
        os.environ["PYTHONPATH"] = os.pathsep.join([here, *paths])


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
