"""The one reader of a labels folder: what its run vouches for, read without changing anything.

A folder a run wrote holds its manifest (``_manifest.json``) and the journal of what finished since
the manifest was compacted (``_journal.jsonl``); together they say which label files are the run's
(finished units, and the chunks of units still running), which artifacts came with them and what
each unit was simulated as. :class:`LabelsFolder` reads them once, the journal applied
(:func:`annotator.store.manifest.load_state`), so every reader (the learner's
:mod:`annotator.dataset`, the tools, the learner's scene data) sees the run as far as it got. Files
of other runs, or a user's, in the folder are not its labels. A folder without a manifest (labels
copied elsewhere, one Parquet file) is read whole: every label file in it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from annotator.store.files import is_regular_file
from annotator.store.manifest import Manifest, load_state
from annotator.store.names import MANIFEST_NAME


class NoLabels(FileNotFoundError):
    """No label file where labels were looked for (a missing path, a folder without any)."""


class UnreadableLabels(ValueError):
    """A label file that cannot be read as one (one line naming it)."""


@dataclass(frozen=True)
class LabelsFolder:
    """A labels folder (or the folder of one label file, ``file``) as its run left it: ``manifest``
    with its journal applied, None when there is none beside the labels."""

    path: Path
    manifest: Manifest | None
    file: Path | None = None

    @classmethod
    def open(cls, labels: str | Path) -> LabelsFolder:
        """The folder ``labels`` (or the folder of the label file ``labels``); NoLabels when there is
        nothing there, ManifestUnreadableError for a manifest or journal that cannot be read."""
        path = Path(labels)
        if not path.exists():
            raise NoLabels(f"no labels at {path}")
        folder, file = (path, None) if path.is_dir() else (path.parent, path)
        manifest = load_state(folder).manifest if file is None or (folder / MANIFEST_NAME).exists() else None
        return cls(folder, manifest, file)

    @classmethod
    def without_manifest(cls, labels: str | Path) -> LabelsFolder:
        """``labels`` read as a folder no run vouches for (every label file in it); NoLabels when
        there is nothing there."""
        path = Path(labels)
        if not path.exists():
            raise NoLabels(f"no labels at {path}")
        return cls(path, None) if path.is_dir() else cls(path.parent, None, path)

    # --- what the run vouches for -----------------------------------------------------------------

    def records(self, unit: str | None = None) -> list[dict[str, Any]]:
        """The label file records the run vouches for (a finished unit's file, the chunks of one
        still running), of every unit or of ``unit``; [] without a manifest."""
        if self.manifest is None:
            return []
        done, chunks = self.manifest.objects_done, self.manifest.chunks_done
        units = sorted(set(done) | set(chunks)) if unit is None else [unit]
        out: list[dict[str, Any]] = []
        for u in units:
            if u in done:
                out.append(done[u])
            out += list((chunks.get(u) or {}).get("files", {}).values())
        return out

    def label_files(self) -> list[str]:
        """The label files to read: the one file asked for, else those the run vouches for, else
        (no manifest) every label file in the folder; sorted names relative to the folder."""
        if self.file is not None:
            return [self.file.name]
        if self.manifest is not None:
            return sorted(r["file"] for r in self.records())
        return sorted(p.name for p in self.path.iterdir() if p.suffix == ".parquet" and p.name[0] not in "._")

    def artifact(self, unit: str, name: str) -> Path | None:
        """The artifact ``name`` (``scene.parquet``, ``cameras.parquet``) that came with one of
        ``unit``'s label files, None if none did."""
        for record in self.records(unit):
            artifact = (record.get("artifacts") or {}).get(name)
            if artifact is not None:
                return self.path / artifact["file"]
        return None

    @property
    def run(self) -> dict[str, Any]:
        """The run's settings (seed, N, trials, configuration, inputs, gripper); {} without a manifest."""
        return dict(self.manifest.run) if self.manifest is not None else {}

    @property
    def objects_info(self) -> dict[str, Any]:
        """What each unit was simulated as (``objects_info``); {} without a manifest."""
        return dict(self.manifest.objects_info) if self.manifest is not None else {}

    # --- the labels -------------------------------------------------------------------------------

    def read(self, names: list[str] | None = None) -> pd.DataFrame:
        """The label files ``names`` (default :meth:`label_files`) as one table, unvalidated, in
        file order. NoLabels when there is none; FileNotFoundError when one vanished (a merge
        renamed it: open the folder again); UnreadableLabels for a file that is not a regular
        file, not Parquet, has a column twice, or whose layout does not join the others'."""
        names = self.label_files() if names is None else names
        if not names:
            raise NoLabels(f"no label files (*.parquet) in {self.path}")
        tables = [_read_table(self.path / name) for name in names]
        try:
            return pa.concat_tables(tables, promote_options="permissive").to_pandas()
        except pa.ArrowInvalid as exc:
            raise UnreadableLabels(f"{self.path}: label files of different layouts ({exc})") from None


def _read_table(path: Path) -> pa.Table:
    if not is_regular_file(path):
        if not path.exists():
            raise FileNotFoundError(path)
        raise UnreadableLabels(f"{path} is not a regular file")
    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise
    except Exception as exc:  # ArrowInvalid, OSError: a truncated or foreign file
        raise UnreadableLabels(f"{path}: not a readable label file ({type(exc).__name__}: {exc})") from None
    names = table.column_names
    for name in names:
        if names.count(name) > 1:
            count = names.count(name)
            raise UnreadableLabels(
                f"{path}: column {name!r} appears {count} times; column names must be unique"
            )
    return table
