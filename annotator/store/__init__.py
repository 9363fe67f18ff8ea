"""The output folder of a run: names, atomic label files, the lock, the manifest, resuming.

Modules by job: :mod:`names` (what files are called), :mod:`files` (atomic writes, the tool's
mark, reading back), :mod:`lock` (one run per folder), :mod:`manifest` (what the run is, its
schema, its journal operations), :mod:`journal` (the append-only record of changes since the
manifest was compacted), :mod:`artifacts` (records and the files bound to them), :mod:`survey`
(what a folder holds, read without changing it), :mod:`reconcile` (what to do about it: pure,
a plan out), :mod:`store` (the :class:`Store` a run writes through, which applies the plans).
"""

from annotator.store.errors import LockedError, ManifestUnreadableError, RunMismatchError, StoreError
from annotator.store.files import OutputError
from annotator.store.manifest import Manifest, RunSpec
from annotator.store.names import ARTIFACTS_DIR, JOURNAL_NAME, LOCK_NAME, MANIFEST_NAME, STALE_DIR
from annotator.store.reconcile import Resume
from annotator.store.store import Store, object_stats

__all__ = [
    "ARTIFACTS_DIR",
    "JOURNAL_NAME",
    "LOCK_NAME",
    "MANIFEST_NAME",
    "STALE_DIR",
    "LockedError",
    "Manifest",
    "ManifestUnreadableError",
    "OutputError",
    "Resume",
    "RunMismatchError",
    "RunSpec",
    "Store",
    "StoreError",
    "object_stats",
]
