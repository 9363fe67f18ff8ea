"""The smaller edges of a run's start: an unwritable cache is one line before any work, and an
interrupt in the first second ends the command with 130 (not lost, not click's `Aborted!` 1)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import run_annotate

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def objects(tmp_path) -> Path:
    folder = tmp_path / "objects"
    folder.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", folder)
    return folder


def test_an_unwritable_cache_is_one_line_before_any_work(tmp_path, objects, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("RG2_CACHE_DIR", str(blocker / "cache"))  # cannot be made, even by root
    out = tmp_path / "labels"
    result = run_annotate("--objects", objects, "--n", 2, "--out", out, check=2)
    assert f"the decomposition cache {blocker / 'cache'} cannot be written" in result.output
    assert "Traceback" not in result.output and not out.exists()
