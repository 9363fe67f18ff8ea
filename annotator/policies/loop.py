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

import contextlib
import inspect
import io
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
        grasps = Grasps.of(call_policy(policy, observation, args))
        grasps.check(observation.workspace, observation.max_width, WORKSPACE_MARGIN)
        return best_reachable(round_, grasps)

    return propose


# A policy's own error message is cut to this many characters in the one line that ends the run.
MESSAGE_CHARS = 300


def call_policy(policy: VisionPolicy, observation: object, args: Mapping[str, str]) -> object:
    """``policy(observation, **args)`` behind the one guard every user's policy is called through:
    whatever it raises (an error, ``sys.exit``) becomes :class:`PolicyError`, one line with its
    type and message (the command adds the policy's name and exits 2); what it prints to stdout is
    logged (logger ``annotator.policies.loop``, INFO) instead of mixing with the command's output.
    Ctrl-C (KeyboardInterrupt) stays an interrupt."""
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            return policy(observation, **args)
    except PolicyError:
        raise
    except SystemExit as exc:
        raise PolicyError(
            f"the policy called sys.exit({exc.code!r}): a policy returns grasps or None"
        ) from None
    except Exception as exc:
        text = " ".join(str(exc).split())[:MESSAGE_CHARS]
        raise PolicyError(f"the policy raised {type(exc).__name__}: {text}") from None
    finally:
        for line in printed.getvalue().splitlines()[:20]:
            log.info("the policy printed: %s", line)


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
