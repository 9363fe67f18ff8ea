"""The two errors of the objects package: one object unusable, or no objects at all."""

from __future__ import annotations


class ObjectError(ValueError):
    """One object cannot be used; the message is one line naming the reason."""


class ObjectDiscoveryError(ValueError):
    """The objects folder is missing or holds no objects (a usage error: CLI exit 2)."""
