"""How a grasp trial ends: the :class:`Outcome` enum and the strings stored in the ``outcome`` column.

The lowest floor of the label schema, with no dependencies, so that the physics (:mod:`annotator.trial`)
and the readers of labels (:mod:`annotator.dataset`) both import it without importing each other.
The strings are the label contract (docs/labels.md, "Outcomes").
"""

from __future__ import annotations

import enum

__all__ = ["OUTCOMES", "Outcome"]


class Outcome(enum.IntEnum):
    """How a grasp trial ended; the stages of the protocol in order, then ``ERROR``."""

    SUCCESS = 0
    COLLISION = 1
    NO_CONTACT = 2
    SLIPPED_LIFT = 3
    SLIPPED_SHAKE = 4
    ERROR = 5

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
