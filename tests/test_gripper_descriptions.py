"""A gripper description that cannot be used is one line naming the file and the key, never a
traceback from deep inside the simulation: each broken variant of the shipped RG2 folder below."""

from __future__ import annotations

import dataclasses
import re

import pytest
from gripper_helpers import description_error, edit

from annotator.config import AnnotatorConfig, ConfigError, GripperConfig, RobustConfig
from annotator.grippers import DescriptionError, load_gripper
from annotator.sim.gripper import GripperSettings

TOML_BREAKS = [
    (
        'joint = "gripper_finger1_joint"',
        'joint = "gripper_finger1_joint"\nspeed = 1.0',
        "unknown key [drive] speed",
    ),
    ("[collision]", "[fingers]\nlinks = []\n\n[collision]", "unknown table [fingers]"),
    ("close_speed = 1.0", "", "missing [drive] close_speed"),
    ("close_speed = 1.0", 'close_speed = "fast"', "[drive] close_speed: expected a finite number"),
    ('link = "tcp"', 'link = "nope"', "[tcp] link 'nope' is not a link of rg2.urdf"),
    ('link = "tcp"', 'link = "gripper_finger1_pad_link"', None),  # any link may be the TCP frame
    ('link = "rg2_base_link"', 'link = "tcp"', "[base] link 'tcp' must be the root link of rg2.urdf"),
    (
        'joint = "gripper_finger1_joint"',
        'joint = "nope"',
        "[drive] joint 'nope' is not a revolute or prismatic",
    ),
    (
        'joint = "gripper_finger1_joint"',
        'joint = "gripper_finger2_joint"',
        "itself mimics 'gripper_finger1_joint'",
    ),
    ('coupling = "gear"', 'coupling = "glue"', "[drive] coupling must be one of ['gear', 'position']"),
    ("max = 0.110", "max = 0.150", "[stroke] max 0.15 m is beyond the model: it opens to 0.1100 m"),
    ("min = 0.0\nmax = 0.110", "min = 0.02\nmax = 0.110", None),  # a stroke the model spans is fine
    ("min = 0.0\nmax = 0.110", "min = 0.2\nmax = 0.110", "[stroke] needs 0 <= min < max"),
    ("default = 40.0", "default = 50.0", "[force] needs 0 < min <= default <= max"),
    ('name = "my_rg2"', 'name = "RG 2"', "name 'RG 2': use lower-case letters, digits and '_'"),
    ("format = 1", "format = 2", "format 2 is not supported"),
    (
        '["gripper_finger1_pad_link", "gripper_finger2_pad_link"]',
        '["rg2_base_link", "gripper_finger2_pad_link"]',
        "[pads] link 'rg2_base_link' is not moved by the drive",
    ),
    (
        '["gripper_finger1_pad_link", "gripper_finger2_pad_link"]',
        '["gripper_finger2_pad_link", "gripper_finger1_pad_link"]',
        "finger 1's pad must sit at -x of the base",
    ),
    (
        '["gripper_finger1_inner_knuckle_link", "gripper_finger2_inner_knuckle_link"]',
        '["gripper_finger1_finger_tip_link"]',
        "kinematic link 'gripper_finger1_finger_tip_link' carries a pad",
    ),
    (
        '["gripper_finger1_inner_knuckle_link", "gripper_finger2_inner_knuckle_link"]',
        '["gripper_finger1_knuckle_link"]',
        "kinematic link 'gripper_finger1_knuckle_link' is not the child of a <mimic> follower",
    ),
    ("lateral_friction = 1.0", "lateral_friction = -1.0", "[pads] lateral_friction must be >= 0"),
    ("[pads]", "[pads]\nsize = [0.01, 0.02]", "[pads] size: expected three finite numbers"),
]


@pytest.mark.parametrize("old, new, fragment", TOML_BREAKS)
def test_a_broken_toml_is_one_line_naming_the_key(my_rg2, old, new, fragment):
    edit(my_rg2 / "gripper.toml", old, new)
    if fragment is None:
        assert load_gripper(my_rg2).name == "my_rg2"
        return
    message = description_error(my_rg2)
    assert fragment in message, message
    assert str(my_rg2 / "gripper.toml") in message


def test_no_coupling_is_an_error(my_rg2):
    urdf = my_rg2 / "rg2.urdf"
    urdf.write_text(re.sub(r"\s*<mimic [^>]*/>", "", urdf.read_text()))
    assert "no <mimic> tag in rg2.urdf: nothing couples the fingers" in description_error(my_rg2)


def test_a_movable_joint_nothing_moves_is_an_error(my_rg2):
    urdf = my_rg2 / "rg2.urdf"
    text = urdf.read_text()
    urdf.write_text(
        re.sub(r'\s*<mimic joint="gripper_finger1_joint" multiplier="-1" offset="0"/>', "", text, count=1)
    )
    assert (
        "movable joint 'gripper_finger1_finger_tip_joint' neither is the drive nor mimics it"
        in description_error(my_rg2)
    )


def test_a_follower_of_another_joint_is_an_error(my_rg2):
    edit(
        my_rg2 / "rg2.urdf",
        '<mimic joint="gripper_finger1_joint" multiplier="1"',
        '<mimic joint="gripper_finger2_joint" multiplier="1"',
    )
    assert "mimics 'gripper_finger2_joint', not the drive 'gripper_finger1_joint'" in description_error(
        my_rg2
    )


def test_a_missing_mesh_or_urdf_or_toml_is_an_error(my_rg2, tmp_path):
    edit(
        my_rg2 / "rg2.urdf",
        '<geometry><box size="0.011450 0.020200 0.029800"/></geometry>',
        '<geometry><mesh filename="pad.stl"/></geometry>',
    )
    assert "rg2.urdf references pad.stl, which does not exist" in description_error(my_rg2)
    (my_rg2 / "rg2.urdf").unlink()
    assert "urdf: rg2.urdf does not exist beside gripper.toml" in description_error(my_rg2)
    (my_rg2 / "gripper.toml").write_text("[stroke\nmax = ")
    assert "not TOML" in description_error(my_rg2)
    (my_rg2 / "gripper.toml").unlink()
    assert "no gripper.toml" in description_error(my_rg2)
    with pytest.raises(DescriptionError, match="no gripper 'robotiq_3f'"):
        load_gripper("robotiq_3f")


def test_a_pad_without_a_box_needs_its_size_stated(my_rg2):
    pad = '<geometry><box size="0.011450 0.020200 0.029800"/></geometry>'
    edit(
        my_rg2 / "rg2.urdf", f'<collision><origin xyz="0.000000 0.000000 0.000000"/>{pad}</collision>', "", 2
    )
    assert (
        "[pads] link 'gripper_finger1_pad_link' has no collision box: state [pads] size"
        in description_error(my_rg2)
    )


def test_grip_force_override_is_checked_against_the_gripper():
    rg2, panda = load_gripper("rg2"), load_gripper("panda")
    assert GripperSettings.resolve(panda, GripperConfig()).grip_force == 70.0
    assert GripperSettings.resolve(panda, GripperConfig(grip_force=120.0)).grip_force == 120.0
    with pytest.raises(ConfigError, match=r"\[gripper\] grip_force: 120 N is outside the rg2's 3..40 N"):
        GripperSettings.resolve(rg2, GripperConfig(grip_force=120.0))
    resolved = GripperSettings.resolve(rg2, GripperConfig(pad_lateral_friction=0.5, coupling="position"))
    assert (resolved.pad_lateral_friction, resolved.coupling, resolved.close_speed) == (0.5, "position", 1.0)


def _with_robust(folder, table: str) -> None:
    toml = folder / "gripper.toml"
    toml.write_text(toml.read_text() + "\n[robust]\n" + table + "\n")


def test_a_gripper_s_robust_table_sits_between_the_defaults_and_the_run_s_config(my_rg2, tmp_path):
    _with_robust(my_rg2, 'object_position_sigma = 0.005\ngrip_force_delta = 0.1\nsource = "measured"')
    description = load_gripper(my_rg2)
    assert dict(description.robust) == {"object_position_sigma": 0.005, "grip_force_delta": 0.1}
    assert description.sources["robust"] == "measured"
    # over the project's defaults
    robust = AnnotatorConfig().robust.over(dict(description.robust))
    assert (robust.object_position_sigma, robust.grip_force_delta) == (0.005, 0.1)
    assert robust.mass_delta == RobustConfig().mass_delta
    # a cell's --config wins where it sets a field, even to the project's default value
    cell = tmp_path / "cell.toml"
    cell.write_text(f"[robust]\nobject_position_sigma = {RobustConfig().object_position_sigma}\n")
    robust = AnnotatorConfig.from_toml(cell).robust.over(dict(description.robust))
    default = RobustConfig().object_position_sigma
    assert (robust.object_position_sigma, robust.grip_force_delta) == (default, 0.1)
    # a section made in code: its fields off the default count as set
    mine = dataclasses.replace(RobustConfig(), grip_force_delta=0.2)
    assert mine.over(dict(description.robust)).grip_force_delta == 0.2
    # the shipped grippers have none: the run's section as it is
    assert load_gripper("rg2").robust == ()


@pytest.mark.parametrize(
    "table, fragment",
    [
        ("mass_delta = 1.5", "[robust] mass_delta: must be >= 0 and < 1, got 1.5"),
        ("object_yaw_sigma = -0.1", "[robust] object_yaw_sigma: must be >= 0 and <= 0.52, got -0.1"),
        ("wobble = 0.1", "unknown key [robust] wobble"),
        ('friction_delta = "a lot"', "[robust] friction_delta: expected a finite number"),
        # the perturbed trials' protocol is the run's, not a gripper's range
        ("shake = true", "unknown key [robust] shake"),
        ("approach_from_contact = false", "unknown key [robust] approach_from_contact"),
        ("stall_by_travel = false", "unknown key [robust] stall_by_travel"),
        ("fingers_from_contact = false", "unknown key [robust] fingers_from_contact"),
    ],
)
def test_a_broken_robust_table_is_one_line_naming_the_field(my_rg2, table, fragment):
    _with_robust(my_rg2, table)
    assert fragment in description_error(my_rg2)
