"""A small real dataset, labelled once for these tests by the real ``annotate`` command, for the tools."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from annotator.cli import annotate_command
from annotator.dataset import load_labels

REPO = Path(__file__).resolve().parents[2]
OBJECTS = ("box.obj", "can.stl")  # convex: no decomposition, a few seconds of physics
N = 20


@dataclass(frozen=True)
class Labelled:
    labels_dir: Path
    objects_dir: Path
    df: pd.DataFrame


@pytest.fixture(scope="package")  # once for every module of tests/tools/
def labelled(tmp_path_factory: pytest.TempPathFactory) -> Labelled:
    root = tmp_path_factory.mktemp("tools")
    objects = root / "objects"
    objects.mkdir()
    for name in OBJECTS:
        shutil.copy(REPO / "objects" / name, objects / name)
    out = root / "labels"
    result = CliRunner().invoke(
        annotate_command,
        ["--objects", str(objects), "--n", str(N), "--out", str(out), "--workers", "1", "--quiet"],
    )
    assert result.exit_code == 0, result.output
    df = load_labels(out)
    assert df["success"].any() and (~df["success"]).any()
    return Labelled(out, objects, df)
