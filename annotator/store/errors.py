"""Why a run cannot start on an output folder: usage errors (exit code 2), one line each.

A folder that cannot be written at all is :class:`annotator.store.files.OutputError` (exit code 3).
"""

from __future__ import annotations


class StoreError(Exception):
    """The run cannot start on this output folder (a usage error: exit code 2); one line."""


class LockedError(StoreError):
    """Another run holds the folder."""


class RunMismatchError(StoreError):
    """The folder holds a run with other settings."""


class ManifestUnreadableError(StoreError):
    """The manifest is missing (with label files present) or cannot be read."""


class JournalUnreadableError(ManifestUnreadableError):
    """A journal line other than the last does not verify (its message says what to pass)."""
