"""annotator report: one self-contained HTML file, checked in a real headless browser (chromium)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from annotator.cli import main

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-logging=stderr",
    "--v=0",
]


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    pytest.skip("no chromium on PATH (Debian: apt-get install chromium; .ci/run installs it)")


def _browse(page: Path, shot: Path, profile: Path) -> list[str]:
    """Load ``page`` in headless chromium, screenshot it; returns the console messages."""
    proc = subprocess.run(
        [
            _chromium(),
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            "--window-size=1200,3000",
            f"--screenshot={shot}",
            page.resolve().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert shot.exists(), proc.stderr[-2000:]
    return [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]


@pytest.mark.browser
def test_console_check_catches_a_broken_page(tmp_path: Path) -> None:
    """The browser check itself can fail: a script error and an undecodable picture are seen."""
    from annotator.tools.report import IMAGE_CHECK

    page = tmp_path / "bad.html"
    page.write_text(
        f"<!DOCTYPE html><html><head><script>{IMAGE_CHECK}</script></head><body>"
        "<img src='data:image/png;base64,AAAA'><script>noSuchFunction();</script></body></html>"
    )
    console = _browse(page, tmp_path / "bad.png", tmp_path / "profile")
    text = "\n".join(console)
    assert "noSuchFunction" in text and "did not decode" in text


@pytest.mark.slow
@pytest.mark.browser
def test_report_loads_cleanly_in_chromium(labelled, tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    args = ["report", str(labelled.labels_dir), "--objects", str(labelled.objects_dir), "--html", str(out)]
    result = CliRunner().invoke(main, [*args, "--pictures", "1"])
    assert result.exit_code == 0, result.output
    page = out.read_text()
    # self-contained: no fetch from anywhere (the only URL is SVG's namespace, which is not fetched)
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", page)
    assert "url(" not in page and "@import" not in page
    assert page.count("data:image/png;base64,") == 2  # overview and sheet of one object
    for oid in ("box", "can"):
        assert f">{oid}</td>" in page
    # the collision error comes from each object's geometry record: convex meshes collide as their
    # hulls, 0.00 mm from the surface
    for oid in ("box", "can"):
        row = re.search(rf">{oid}</td>.*?</tr>", page, re.S)
        assert row is not None and row.group(0).endswith("<td>0.00</td></tr>"), oid
    assert '"seed": 0' not in page and "<th class='l'>seed</th><td class='l'>0</td>" in page

    console = _browse(out, tmp_path / "shot.png", tmp_path / "profile")
    assert console == []
    shot = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB")).astype(float)
    assert shot.std() > 20.0
    assert (np.abs(shot - 255).sum(axis=-1) > 30).mean() > 0.03  # more than a white page


def test_report_errors_are_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["report", str(tmp_path / "none"), "--html", str(tmp_path / "r.html")])
    assert result.exit_code == 2 and result.output.strip() == f"Error: no labels at {tmp_path / 'none'}"


def test_per_object_table_takes_mass_and_collision_error_where_recorded() -> None:
    import pandas as pd

    from annotator.tools.report import per_object_table

    df = pd.DataFrame(
        {
            "object_id": ["a", "a", "b"],
            "outcome": ["success", "collision", "success"],
            "object_mass": [0.1] * 3,
        }
    )
    manifest = {"objects_info": {"a": {"geometry": {"mass": 0.11, "collision_error_mean": 0.0004}}}}
    table = per_object_table(df, manifest)
    assert table.loc["a", ["n", "successes", "collision"]].tolist() == [2, 1, 1]
    assert table.loc["a", "mass"] == 0.11 and table.loc["a", "collision_error"] == 0.0004
    assert table.loc["b", "mass"] == 0.1 and np.isnan(table.loc["b", "collision_error"])  # shown n/a
