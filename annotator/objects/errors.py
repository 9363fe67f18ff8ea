"""The errors of the objects package: one object unusable, no objects at all, or a decomposition
that is not in the cache where the caller does not make it."""

from __future__ import annotations


class ObjectError(ValueError):
    """One object cannot be used; the message is one line naming the reason."""


class ObjectDiscoveryError(ValueError):
    """The objects folder is missing or holds no objects (a usage error: CLI exit 2)."""


class NotDecomposed(LookupError):
    """The object's decomposition is not in the cache and the caller asked not to make it
    (``load_object(..., decompose=False)``: a process that leaves decompositions to workers)."""
