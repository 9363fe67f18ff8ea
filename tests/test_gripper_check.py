"""annotator gripper check: the shipped grippers' physics checks on a gripper of one's own, with a
verdict line per check (real PyBullet throughout)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from annotator.cli import main
from annotator.grippers import gripper_dir, shipped_grippers
from annotator.tools.gripper_check import check_gripper

NAMES = (
    "pads follow the FK",
    "followers' drift",
    "squeeze equals the grip force",
    "box held through lift and shake",
    "no success wider than the stroke",
)


def _user_folder(tmp_path: Path, shipped: str, name: str) -> Path:
    """A shipped gripper copied as a user's folder under another name."""
    folder = tmp_path / name
    shutil.copytree(gripper_dir(shipped), folder, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    toml = folder / "gripper.toml"
    toml.write_text(re.sub(r'(?m)^name = ".*"$', f'name = "{name}"', toml.read_text()))
    return folder


def _check(*args: str):
    return CliRunner().invoke(main, ["gripper", "check", *args])


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(shipped_grippers()))
def test_every_shipped_gripper_passes_every_check(name: str) -> None:
    verdicts = check_gripper(name)
    assert [v.name for v in verdicts] == list(NAMES)
    assert all(v.passed for v in verdicts), [v.line() for v in verdicts if not v.passed]
    assert all(v.advice == "" for v in verdicts)


def test_rg2_and_a_users_copy_pass(tmp_path: Path) -> None:
    result = _check("rg2")
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert [line.split(":")[0] for line in lines[1:-1]] == [f"PASS {n}" for n in NAMES]
    assert lines[-1] == "5 of 5 checks passed"
    mine = _user_folder(tmp_path, "rg2", "my_rg2")
    result = _check(str(mine), "--fast")
    assert result.exit_code == 0, result.output
    assert "gripper my_rg2" in result.output and "4 of 4 checks passed" in result.output


def test_a_housing_too_light_fails_on_the_followers_drift(tmp_path: Path) -> None:
    """The Panda's 0.73 kg housing made 0.05 kg: the fingers' coupling gives under the squeeze."""
    folder = _user_folder(tmp_path, "panda", "light_panda")
    urdf = folder / "panda.urdf"
    text = urdf.read_text()
    assert text.count('<mass value="0.730000"/>') == 1  # the housing (panda_hand_base)
    urdf.write_text(text.replace('<mass value="0.730000"/>', '<mass value="0.050000"/>'))
    result = _check(str(folder), "--fast")
    assert result.exit_code == 1, result.output
    line = next(x for x in result.output.splitlines() if x.startswith("FAIL followers' drift"))
    drift = float(re.search(r"followers drift ([0-9.]+) mm", line).group(1))
    assert drift > 1.5 and "(limit 1.5 mm)" in line
    assert "raise the housing's mass (0.05 kg, the base link 'panda_hand_base'" in line
    assert "PASS pads follow the FK" in result.output  # in free air the coupling holds


def test_a_grip_force_far_too_low_drops_the_box(tmp_path: Path) -> None:
    folder = _user_folder(tmp_path, "rg2", "weak_rg2")
    toml = folder / "gripper.toml"
    text = toml.read_text().replace("default = 40.0", "default = 0.5").replace("min = 3.0", "min = 0.5")
    toml.write_text(text)
    result = _check(str(folder), "--fast")
    assert result.exit_code == 1, result.output
    failed = [x for x in result.output.splitlines() if x.startswith("FAIL")]
    assert len(failed) == 1 and failed[0].startswith("FAIL box held through lift and shake: a 200 g")
    assert "raise [force] default (0.5 N)" in failed[0]


@pytest.mark.parametrize("broken", ["missing", "bad_toml"])
def test_an_unusable_gripper_is_one_line_exit_2(tmp_path: Path, broken: str) -> None:
    folder = tmp_path / "nothing"
    if broken == "bad_toml":
        folder = _user_folder(tmp_path, "rg2", "bad")
        toml = folder / "gripper.toml"
        toml.write_text(toml.read_text().replace('link = "tcp"', 'link = "no_such_link"'))
    result = _check(str(folder))
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and result.output.startswith("Error: ")
