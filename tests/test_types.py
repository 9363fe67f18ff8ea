"""Types checked: mypy over annotator/ (the configuration in pyproject.toml), each package held to
its recorded count of errors (tests/mypy_baseline.json), which may only go down. ``sim`` and
``objects`` but the mesh reader are at zero."""

from __future__ import annotations

import collections
import json
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BASELINE = REPO / "tests" / "mypy_baseline.json"


def mypy_errors() -> tuple[collections.Counter[str], list[str]]:
    """({package or top-level module: errors}, the error lines) of mypy run on the package."""
    api = pytest.importorskip("mypy.api")
    stdout, stderr, _ = api.run(["--config-file", str(REPO / "pyproject.toml"), "--no-error-summary"])
    lines = [line for line in stdout.splitlines() if ": error:" in line]
    counts: collections.Counter[str] = collections.Counter()
    for line in lines:
        m = re.match(r"annotator/([A-Za-z0-9_]+)(?:/|\.py:)", line)
        assert m, f"an error outside the package's files: {line}\n{stderr}"
        counts[m.group(1)] += 1
    return counts, lines


@pytest.mark.slow
def test_mypy_errors_per_package_do_not_rise(monkeypatch):
    """``mypy`` from the repository's root; a package with more errors than its baseline fails
    (fix them, or the change that made them); one with fewer may lower its number."""
    monkeypatch.chdir(REPO)
    baseline: dict[str, int] = json.loads(BASELINE.read_text())["errors"]
    counts, lines = mypy_errors()
    risen = {p: (n, baseline.get(p, 0)) for p, n in sorted(counts.items()) if n > baseline.get(p, 0)}
    shown = [line for line in lines if re.match(rf"annotator/({'|'.join(risen)})\b", line)] if risen else []
    assert risen == {}, "more mypy errors than recorded (now, baseline):\n" + "\n".join(
        [str(risen), *shown]
    )
    assert baseline.get("sim", 0) == 0 and counts["sim"] == 0
