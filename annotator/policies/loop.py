"""A vision policy in the clutter-removal loop: observe, ask the policy, execute the best reachable.

A vision policy is any callable ``policy(observation, **args) -> grasps`` (``args``: the
``--policy-arg KEY=VALUE`` pairs, strings). At every attempt it gets an
:class:`~annotator.policies.records.Observation` of the pile as it is now and returns scored grasps
(:meth:`~annotator.policies.records.Grasps.of` lists what it may return). Its grasps are checked
(finite, widths within the stroke, TCPs near the workspace: PolicyError otherwise), then tried in
order of decreasing score (ties: the order returned) until the arm reaches one: that one is
executed (its target instance is the object nearest its TCP). None reachable: the round ends
("no grasp proposed").
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from annotator.policies.observe import observe
from annotator.policies.oracle import RoundPolicy
from annotator.policies.predictions import WORKSPACE_MARGIN
from annotator.policies.records import Grasps, PolicyError, Proposal

if TYPE_CHECKING:
    from annotator.policies.round_world import Round

log = logging.getLogger(__name__)

VisionPolicy = Callable[..., object]


def vision_round_policy(policy: VisionPolicy, args: Mapping[str, str], views: int) -> RoundPolicy:
    """The round policy that observes with ``views`` depth views and executes ``policy``'s best
    reachable grasp (module docstring). PolicyError if ``policy`` does not take (observation,
    **args)."""
    check_signature(policy, args)

    def propose(round_: Round, attempt: int, tried: set[int]) -> Proposal | None:
        observation = observe(round_, attempt, views)
        grasps = Grasps.of(policy(observation, **args))
        grasps.check(observation.workspace, observation.max_width, WORKSPACE_MARGIN)
        return best_reachable(round_, grasps)

    return propose


def best_reachable(round_: Round, grasps: Grasps) -> Proposal | None:
    """The highest-scored of ``grasps`` that the arm reaches in the round's scene as it is."""
    order = np.lexsort((np.arange(len(grasps)), -grasps.score))
    for k in order:
        grasp = grasps.grasp(int(k))
        reach = round_.reach(grasp.T_table_tcp, grasp.width, -1)
        if reach.reachable:
            return Proposal(-1, grasp.T_table_tcp, grasp.width, grasp.score, reach)
    log.info("none of %d grasps is reachable", len(grasps))
    return None


def check_signature(policy: VisionPolicy, args: Mapping[str, str]) -> None:
    """PolicyError unless ``policy(observation, **args)`` binds to ``policy``'s parameters."""
    try:
        signature = inspect.signature(policy)
    except (TypeError, ValueError):
        return  # a builtin or C callable: it tells when called
    try:
        signature.bind(None, **args)
    except TypeError as exc:
        shown = ", ".join(f"{k}={v}" for k, v in args.items()) or "no --policy-arg"
        raise PolicyError(f"the policy cannot take an observation and {shown} ({exc})") from None
