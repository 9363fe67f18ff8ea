"""One seed, one label, on any machine: small runs of each mode, their labels digested and compared
with the digests shipped in ``tests/label_digests.json``.

The same versions of the label libraries must give the same labels bit for bit on every machine.
Where a machine's maths differ in the last bit (docs/reliability.md, "One seed, one label"), the
runs below show it: a failure names the mode, the digest recorded, this machine's, and both kinds
of machine. ``python -m tests.test_label_digests`` writes the file anew from this machine (after a
change that moves labels on purpose; say so in the commit).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]
DIGESTS = Path(__file__).with_name("label_digests.json")
OBJECTS = ("box.obj", "can.stl")  # convex: no decomposition, no budget, a few seconds
# Each mode: the arguments of a tiny annotate run (one worker: a run's labels do not depend on it).
RUNS: dict[str, tuple[str, ...]] = {
    "objects": ("--n", "6", "--trials", "2"),
    "cell": ("--n", "4", "--cell"),
    "scenes": ("--scenes", "1", "--per-scene", "3", "--n", "6"),
}


def label_digest(df: pd.DataFrame) -> str:
    """SHA-256 of a label table, column by column in name order, rows by (scene, object, grasp):
    numbers by their little-endian float64 / int64 bytes (every bit), the rest as text."""
    keys = [c for c in ("scene_id", "object_id", "grasp_id") if c in df.columns]
    df = df.sort_values(keys, kind="stable", ignore_index=True)
    digest = hashlib.sha256()
    for column in sorted(df.columns):
        values = df[column]
        digest.update(column.encode() + b"\0")
        if values.dtype.kind in "fiub":
            kind = "<f8" if values.dtype.kind == "f" else "<i8"
            digest.update(np.ascontiguousarray(values.to_numpy(dtype=kind)).tobytes())
        else:
            digest.update("\0".join(values.astype(str)).encode())
    return digest.hexdigest()


def labels_of(mode: str, root: Path) -> pd.DataFrame:
    """The labels of :data:`RUNS`'s ``mode``, made in ``root`` by the real ``annotate`` command."""
    from click.testing import CliRunner

    from annotator.cli import annotate_command
    from annotator.dataset import load_labels

    objects = root / "objects"
    objects.mkdir(parents=True, exist_ok=True)
    for name in OBJECTS:
        shutil.copy(REPO / "objects" / name, objects / name)
    out = root / "labels" / mode
    args = ["--objects", str(objects), "--out", str(out), "--workers", "1", "--quiet", "--seed", "7"]
    result = CliRunner().invoke(annotate_command, [*args, *RUNS[mode]])
    assert result.exit_code == 0, result.output
    return load_labels(out)


@pytest.mark.slow
@pytest.mark.parametrize("mode", list(RUNS))
def test_labels_are_the_shipped_digests(mode: str, tmp_path: Path) -> None:
    from annotator.versions import library_versions, machine_kind

    shipped = json.loads(DIGESTS.read_text())
    if shipped["versions"] != library_versions():
        pytest.skip(f"the digests are of other library versions ({shipped['versions']})")
    found = label_digest(labels_of(mode, tmp_path))
    assert found == shipped["digests"][mode], (
        f"{mode}: labels differ from the shipped digest ({shipped['digests'][mode][:16]} made on "
        f"{shipped['machine']}; {found[:16]} here, on {machine_kind()})"
    )


def write_digests(root: Path) -> dict:
    """Label every mode of :data:`RUNS` under ``root`` and write :data:`DIGESTS` from them."""
    from annotator.versions import library_versions, machine_kind

    record = {
        "machine": machine_kind(),
        "versions": library_versions(),
        "digests": {mode: label_digest(labels_of(mode, root)) for mode in RUNS},
    }
    DIGESTS.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    return record


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        json.dump(write_digests(Path(folder)), sys.stdout, indent=1)
        print()
