"""The output folder of a run: names, atomic label files, the lock, the manifest, resuming.

Modules by job: :mod:`names` (what files are called), :mod:`files` (atomic writes, the tool's
mark, reading back), :mod:`lock` (one run per folder), :mod:`manifest` (what the run is, its
schema), :mod:`artifacts` (records and the files bound to them), :mod:`reconcile` (opening,
verifying and resuming a folder), :mod:`store` (the :class:`Store` a run writes through).
"""

from annotator.store.errors import LockedError, ManifestUnreadableError, RunMismatchError, StoreError
from annotator.store.files import OutputError
from annotator.store.manifest import Manifest, RunSpec
from annotator.store.names import ARTIFACTS_DIR, LOCK_NAME, MANIFEST_NAME, STALE_DIR
from annotator.store.reconcile import Resume
from annotator.store.store import Store, object_stats

__all__ = [
    "ARTIFACTS_DIR",
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
