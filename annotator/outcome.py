"""How a grasp trial ends and how far it held: the :class:`Outcome` enum (the strings stored in the
``outcome`` column) and the :class:`Stage` enum (the stages of the protocol a trial held through).

The lowest floor of the label schema, with no dependencies, so that the physics (:mod:`annotator.trial`)
and the readers of labels (:mod:`annotator.dataset`) both import it without importing each other.
The strings are the label contract (docs/labels.md, "Outcomes").
"""

from __future__ import annotations

import enum

__all__ = ["GATES", "OUTCOMES", "OUTCOME_RGB", "STAGES", "Outcome", "Stage"]


class Outcome(enum.IntEnum):
    """How a grasp trial ended: the stages of the protocol in order, then ``ERROR``, then the stage
    added last (``SLIPPED_MOTION``, between the lift and the shake; numbered after ``ERROR`` so
    that the numbers of the others never change)."""

    SUCCESS = 0
    COLLISION = 1
    NO_CONTACT = 2
    SLIPPED_LIFT = 3
    SLIPPED_SHAKE = 4
    ERROR = 5
    SLIPPED_MOTION = 6

    @property
    def label(self) -> str:
        """The string stored in the ``outcome`` column, e.g. ``"slipped_lift"``."""
        return self.name.lower()

    @classmethod
    def from_label(cls, label: str) -> Outcome:
        """The :class:`Outcome` stored as ``label`` in the ``outcome`` column; ValueError if unknown."""
        try:
            return cls[label.upper()]
        except KeyError:
            raise ValueError(f"unknown outcome {label!r}; expected one of {OUTCOMES}") from None


OUTCOMES: tuple[str, ...] = tuple(o.label for o in Outcome)
# Each outcome's colour in pictures and pages (Okabe-Ito, readable with colour-blindness), RGB 0..255.
OUTCOME_RGB: dict[str, tuple[int, int, int]] = {
    "success": (0, 158, 115),
    "collision": (153, 153, 153),
    "no_contact": (230, 159, 0),
    "slipped_lift": (213, 94, 0),
    "slipped_motion": (0, 114, 178),
    "slipped_shake": (204, 121, 167),
    "error": (0, 0, 0),
}


class Stage(enum.IntEnum):
    """How far a trial held, in the protocol's order (docs/protocol.md, "Stages"): each stage a
    trial held through counts every stage before it as held. A stage a trial's protocol does not
    run (no benchmark motion configured) is passed by holding through the stage before it.

    ``NONE``: never held (a collision, no contact on both pads, an error); ``CLOSED``: both pads
    on the object after the close; ``LIFTED``: still held after the lift; ``MOVED``: after the
    benchmark's slow motion; ``SHAKEN``: after the shake.
    """

    NONE = 0
    CLOSED = 1
    LIFTED = 2
    MOVED = 3
    SHAKEN = 4

    @property
    def label(self) -> str:
        """The stage's name in the ``stage`` column, e.g. ``"lifted"``."""
        return self.name.lower()

    @classmethod
    def from_label(cls, label: str) -> Stage:
        """The :class:`Stage` named ``label`` (``"lifted"``) or its gate (``"lift"``); ValueError if
        unknown."""
        key = GATES.get(label, label)
        try:
            return cls[str(key).upper()]
        except KeyError:
            raise ValueError(f"unknown stage {label!r}; expected one of {STAGES} or {tuple(GATES)}") from None


STAGES: tuple[str, ...] = tuple(s.label for s in Stage)
# The gates a label's ``success`` may require ([protocol] gate): each names the stage it is held through.
GATES: dict[str, str] = {"close": "closed", "lift": "lifted", "motion": "moved", "shake": "shaken"}
