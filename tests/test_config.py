"""Configuration: every field typed and range-checked up front (a usage error naming the field)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from annotator.cli import annotate_command
from annotator.config import AnnotatorConfig, ConfigError, ObjectConfig


@pytest.mark.parametrize(
    "data, message",
    [
        ({"protocol": {"lift_height": "high"}}, "[protocol] lift_height: expected a number, got 'high'"),
        ({"physics": {"time_step": -0.01}}, "[physics] time_step: must be > 0"),
        ({"physics": {"time_step": 0}}, "[physics] time_step: must be > 0"),
        ({"objects": {"density": 0}}, "[objects] density: must be > 0"),
        ({"objects": {"lateral_friction": -0.5}}, "[objects] lateral_friction: must be >= 0"),
        ({"gripper": {"pad_lateral_friction": -1}}, "[gripper] pad_lateral_friction: must be >= 0"),
        ({"physics": {"time_step": float("nan")}}, "[physics] time_step: expected a finite number"),
        ({"physics": {"solver_iterations": 1.5}}, "[physics] solver_iterations: expected an integer"),
        ({"protocol": {"shake_paired": 1}}, "[protocol] shake_paired: expected true or false"),
        ({"gripper": {"coupling": "glue"}}, "[gripper] coupling: must be one of ['gear', 'position']"),
        ({"gripper": {"grip_force": -5}}, "[gripper] grip_force: must be > 0"),
        ({"gripper": {"grip_force": "strong"}}, "[gripper] grip_force: expected a number"),
        ({"robust": {"mass_delta": 1.0}}, "[robust] mass_delta: must be >= 0 and < 1"),
        ({"protocol": 3}, "[protocol] must be a section of settings, got 3"),
        ({"shaking": {}}, "unknown config section [shaking]"),
        ({"protocol": {"lift_heigth": 0.1}}, "unknown field(s) ['lift_heigth'] in [protocol]"),
        ([1, 2], "expected sections of settings"),
    ],
)
def test_bad_values_name_the_field(data, message):
    with pytest.raises(ConfigError) as info:
        AnnotatorConfig.from_dict(data)
    assert message in str(info.value)


def test_every_field_has_a_type_the_checks_know():
    """A field typed otherwise would escape the checks (and the manifest would not bind it); the one
    section within a section is the ladder's, ``[objects.decomposition]``."""
    for name, section in _sections(AnnotatorConfig()).items():
        for f in dataclasses.fields(section):
            if (name, f.name) == ("objects", "decomposition"):
                continue
            # "float | None": the gripper's own numbers, None leaving them to its description;
            # "tuple[float, ...]": a list of numbers ([confidence]'s knots)
            known = ("float", "int", "bool", "str", "float | None", "str | None", "tuple[float, ...]")
            assert f.type in known, (name, f.name, f.type)


def test_a_list_of_numbers_is_checked_like_a_number():
    section = {"method": "isotonic", "trials": 5, "scores": [0, 1], "p_success": [0, 1]}
    ok = AnnotatorConfig.from_dict({"confidence": section})
    assert ok.confidence.scores == (0.0, 1.0)
    for bad in ("0.5", [0.0, float("nan")], [0.0, True]):
        with pytest.raises(ConfigError, match=r"\[confidence\] scores"):
            AnnotatorConfig.from_dict({"confidence": {"scores": bad}})


def test_integers_for_floats_are_stored_as_floats():
    config = AnnotatorConfig.from_dict({"protocol": {"lift_height": 1}})
    assert isinstance(config.protocol.lift_height, float)
    assert config.to_dict() == AnnotatorConfig.from_dict({"protocol": {"lift_height": 1.0}}).to_dict()


def test_defaults_and_the_thorough_reference_round_trip_through_a_manifest():
    """Both configurations pass their own range checks and come back equal from the manifest's
    dictionary form; the reference is the finer, longer protocol it says it is."""
    default, thorough = AnnotatorConfig(), AnnotatorConfig.thorough()
    for config in (default, thorough):
        assert AnnotatorConfig.from_dict(config.to_dict()) == config
    assert thorough.physics.time_step < default.physics.time_step
    assert thorough.physics.solver_iterations > default.physics.solver_iterations
    assert thorough.protocol.shake_duration >= 10 * default.protocol.shake_duration
    assert thorough.gripper.passive_links == "simulated" != default.gripper.passive_links


def _spec(config: AnnotatorConfig, trials: int):
    """The run a run of ``config`` at ``--trials trials`` binds (its manifest's RunSpec)."""
    from annotator.store.manifest import RunSpec

    return RunSpec(0, 5, trials, None, 5, config.to_dict(trials=trials))


def _made_before(config: AnnotatorConfig, trials: int, field: str) -> dict:
    """The manifest record a folder of ``config`` made before ``[robust] field`` existed holds."""
    from annotator.store.manifest import RunSpec

    data = config.to_dict(trials=trials)
    data["robust"].pop(field, None)
    return RunSpec(0, 5, trials, None, 5, data).to_json()


def test_a_run_binds_robust_shake_where_folders_made_before_it_did_not_describe_its_scores():
    """``[robust] shake`` is in a run's manifest only at ``--trials`` > 1 with perturbed trials
    that end at the lift: a folder made before the field existed (its perturbed trials shook) then
    never resumes as such a run, and resumes as the runs it does describe."""
    from annotator.store.manifest import RunSpec

    lift = AnnotatorConfig()
    shaken = dataclasses.replace(lift, robust=dataclasses.replace(lift.robust, shake=True))
    old = lift.to_dict()
    # what a folder of an earlier version bound
    for name in ("shake", "approach_from_contact", "stall_by_travel", "fingers_from_contact"):
        old["robust"].pop(name)

    def recorded(trials: int) -> dict:
        return RunSpec(0, 5, trials, None, 5, old).to_json()

    assert _spec(lift, 1).differences(recorded(1)) == []
    assert _spec(shaken, 5).differences(recorded(5)) == []
    assert _spec(lift, 5).differences(recorded(5)) == [
        "[robust] shake None in the folder, False now",
        "[robust] stall_by_travel None in the folder, True now",
    ]
    # read back from a manifest: what the run simulated
    for config in (lift, shaken):
        assert AnnotatorConfig.from_run(config.to_dict(trials=5), 5) == config
    assert AnnotatorConfig.from_run(lift.to_dict(trials=1), 1) == lift
    assert AnnotatorConfig.from_run(old, 5) == shaken


IMPLICIT = (  # (section, field, the name a run binds it under, another value)
    ("objects", "mend_area_tolerance", "mend_area_tolerance", 0.2),
    ("objects.decomposition", "coacd_refine_iterations", "coacd_refine_iterations", 300),
    ("objects.decomposition", "copy_samples", "decomposition_copy_samples", 8_000),
    ("protocol", "approach_hold", "approach_hold", 0.2),
    ("robust", "approach_lead", "approach_lead", 0.02),
    ("robust", "rest_speed", "rest_speed", 2e-3),
    ("robust", "rest_spin", "rest_spin", 2e-2),
    ("cell", "touch_search", "touch_search", 0.1),
)


def _sections(config: AnnotatorConfig) -> dict[str, Any]:
    """Every section of ``config`` by its name in a config file (``objects.decomposition`` too)."""
    out = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    return out | {"objects.decomposition": config.objects.decomposition}


def _changed(config: AnnotatorConfig, section: str, name: str, value: Any) -> AnnotatorConfig:
    """``config`` with one field of one section (by its config-file name) set to ``value``."""
    if section == "objects.decomposition":
        return dataclasses.replace(config, objects=config.objects.with_decomposition(**{name: value}))
    return dataclasses.replace(
        config, **{section: dataclasses.replace(getattr(config, section), **{name: value})}
    )


def test_the_implicit_fields_are_the_ones_named_here():
    """Every field declared implicit (a number every run had before it became a field) is listed
    above, so the tests below cover each."""
    declared = {
        (section, f.name)
        for section, values in _sections(AnnotatorConfig()).items()
        for f in dataclasses.fields(values)
        if f.metadata.get("implicit")
    }
    assert declared == {(section, name) for section, name, _, _ in IMPLICIT}


@pytest.mark.parametrize(("section", "name", "bound_as", "other"), IMPLICIT)
def test_an_implicit_field_is_bound_only_where_it_differs_from_the_value_every_run_had(
    section, name, bound_as, other
):
    """At its default an implicit field is not in a run's manifest, so a folder made before it was a
    field resumes (no difference) and reads back as the default; set to another value it is bound,
    the older folder refuses the run naming the field, and it reads back as set."""
    from annotator.store.manifest import RunSpec

    default = AnnotatorConfig()
    changed = _changed(default, section, name, other)
    bound_section = section.split(".")[0]  # the ladder is bound in [objects]
    for trials in (1, 5):
        bound = default.to_dict(trials=trials)
        assert bound_as not in bound[bound_section]
        before = RunSpec(0, 5, trials, None, 5, bound).to_json()  # a folder of an earlier version
        assert _spec(default, trials).differences(before) == []
        assert AnnotatorConfig.from_run(bound, trials) == default
        assert changed.to_dict(trials=trials)[bound_section][bound_as] == other
        assert any(f"[{bound_section}] {bound_as}" in d for d in _spec(changed, trials).differences(before))
        assert AnnotatorConfig.from_run(changed.to_dict(trials=trials), trials) == changed


# [objects] as a run bound it before the ladder was its own section: every folder made since binds
# the same names, so its run keeps its key and resumes.
OBJECTS_BOUND_BEFORE_THE_SECTION = {
    "budget_basis", "coacd_first_cut_share", "coacd_remesh_resolution", "coacd_remesh_search_iterations",
    "coacd_retry_margin", "coacd_search_iterations", "collision_error_samples", "collision_margin",
    "collision_max_limit", "collision_mean_limit", "convex_volume_tolerance", "decomposition_budget",
    "decomposition_copy_max_faces", "decomposition_copy_tolerance", "decomposition_max_faces",
    "decomposition_min_threshold", "decomposition_threshold", "decomposition_timeout", "density",
    "fragment_max_share", "lateral_friction", "max_extent", "max_faces", "memory_budget", "merge_parts",
    "min_extent", "min_faces", "min_volume", "rolling_friction", "sat_features", "shell_density",
    "shell_max_fill", "shell_max_wall", "shell_thickness", "spinning_friction", "vhacd_reserve",
    "vhacd_resolution",
}  # fmt: skip


def test_the_ladder_is_its_own_section_and_a_run_binds_it_as_before():
    """``[objects.decomposition]`` in a config file sets the ladder; a run binds it under
    ``[objects]`` with the names it had before (so the run's key, and a folder's resume, are
    unchanged), and a manifest's bound names read back as the section. A file may still give the
    older names in ``[objects]``; the same setting both ways, an unknown field and a value out of
    range are each a one-line ConfigError naming the table."""
    default = AnnotatorConfig()
    assert set(default.to_dict(trials=5)["objects"]) == OBJECTS_BOUND_BEFORE_THE_SECTION
    assert {f.name for f in dataclasses.fields(ObjectConfig)} & OBJECTS_BOUND_BEFORE_THE_SECTION == {
        "collision_margin", "density", "fragment_max_share", "lateral_friction", "max_extent", "max_faces",
        "memory_budget", "merge_parts", "min_extent", "min_faces", "min_volume", "rolling_friction",
        "sat_features", "shell_density", "shell_max_fill", "shell_max_wall", "shell_thickness",
        "spinning_friction",
    }  # fmt: skip
    table = AnnotatorConfig.from_dict(
        {"objects": {"density": 600, "decomposition": {"budget": 30, "threshold": 0.03}}}
    )
    assert table.objects.density == 600.0
    assert table.objects.decomposition.budget == 30.0
    assert table.objects.decomposition.threshold == 0.03
    bound = table.to_dict(trials=5)["objects"]
    assert (bound["decomposition_budget"], bound["decomposition_threshold"]) == (30.0, 0.03)
    assert "decomposition" not in bound and "budget" not in bound
    assert AnnotatorConfig.from_run(table.to_dict(trials=5), 5) == table
    assert AnnotatorConfig.from_dict(
        {"objects": {"decomposition_budget": 30, "decomposition_threshold": 0.03}}
    ) == (dataclasses.replace(table, objects=dataclasses.replace(table.objects, density=500.0)))
    with pytest.raises(
        ConfigError,
        match=r"\[objects.decomposition\] budget is given twice: as \[objects\] decomposition_budget",
    ):
        AnnotatorConfig.from_dict({"objects": {"decomposition_budget": 30, "decomposition": {"budget": 20}}})
    with pytest.raises(ConfigError, match=r"unknown field\(s\) \['bugdet'\] in \[objects.decomposition\]"):
        AnnotatorConfig.from_dict({"objects": {"decomposition": {"bugdet": 30}}})
    with pytest.raises(ConfigError, match=r"\[objects.decomposition\] budget: must be >= 1"):
        AnnotatorConfig.from_dict({"objects": {"decomposition": {"budget": 0}}})
    with pytest.raises(ConfigError, match=r"unknown field"):
        AnnotatorConfig().objects.with_decomposition(bugdet=30)


def test_a_config_file_sets_the_ladder_in_its_own_table(tmp_path):
    """A TOML file's ``[objects.decomposition]`` table is the ladder's section."""
    path = tmp_path / "ladder.toml"
    path.write_text(
        '[objects]\ndensity = 700\n\n[objects.decomposition]\nbudget = 45\nbudget_basis = "cpu"\n'
    )
    config = AnnotatorConfig.from_toml(path)
    assert config.objects.density == 700.0
    assert (config.objects.decomposition.budget, config.objects.decomposition.budget_basis) == (45.0, "cpu")


def test_the_collision_shape_key_is_the_one_the_constants_made():
    """The decomposition settings that key a cached shape (annotator.objects.decomposition.settings)
    are, at the defaults, the tuple the constants made before they were implicit fields: shapes
    cached before keep their keys. A changed implicit field keys another shape."""
    import trimesh

    from annotator.objects.decomposers import METHOD, copy_sizes, thresholds
    from annotator.objects.decomposition import settings

    ladder = AnnotatorConfig().objects.decomposition
    dense = trimesh.creation.icosphere(subdivisions=5)  # 20,480 faces: above the ladder's max_faces
    assert len(dense.faces) > ladder.max_faces
    made_before = (
        ladder.collision_error_samples,
        thresholds(ladder),
        ladder.coacd_search_iterations,
        ladder.coacd_retry_margin,
        ladder.coacd_first_cut_share,
        ladder.coacd_remesh_resolution,
        ladder.coacd_remesh_search_iterations,
        ladder.collision_mean_limit,
        ladder.collision_max_limit,
        ladder.budget,
        ladder.budget_basis,
        ladder.vhacd_reserve,
        ladder.vhacd_resolution,
        copy_sizes(ladder),
        ladder.copy_tolerance,
        4_000,  # COPY_SAMPLES; CoACD's own 150 iterations were not part of the key
    )
    assert settings(METHOD, dense, ladder) == made_before
    more_samples = dataclasses.replace(ladder, copy_samples=8_000)
    assert settings(METHOD, dense, more_samples)[-1] == 8_000
    own = dataclasses.replace(ladder, coacd_refine_iterations=300)
    assert settings(METHOD, dense, own) == (*made_before, ("coacd_refine_iterations", 300))


def test_a_folder_made_before_light_objects_were_held_at_the_time_step_reads_back_as_it_simulated():
    """A folder made before ``[physics] light_hold_mass`` simulated its light objects at their finer
    step throughout: it reads back so (a tool that simulates its labels again does what the run
    did), and a run that lifts and shakes them at the time step never resumes in it, naming the
    fields."""
    from annotator.store.manifest import RunSpec

    config = AnnotatorConfig()
    old = config.to_dict(trials=1)
    for name in ("light_hold_mass", "light_hold_contact_erp"):
        old["physics"].pop(name)
    assert _spec(config, 1).differences(RunSpec(0, 5, 1, None, 5, old).to_json()) == [
        "[physics] light_hold_contact_erp None in the folder, 0.5 now",
        "[physics] light_hold_mass None in the folder, 0.028 now",
    ]
    never = dataclasses.replace(config.physics, light_hold_mass=config.physics.light_object_mass)
    throughout = dataclasses.replace(config, physics=never)
    assert AnnotatorConfig.from_run(old, 1) == throughout
    for made in (config, throughout):
        assert AnnotatorConfig.from_run(made.to_dict(trials=1), 1) == made


@pytest.mark.parametrize("field", ["approach_from_contact", "fingers_from_contact"])
def test_a_run_binds_the_simulated_approach_s_shortcuts_only_where_they_change_the_scores(field):
    """``[robust] approach_from_contact`` and ``fingers_from_contact`` are in a run's manifest only
    where they change a perturbed trial: past one trial, lift-only perturbed trials, a simulated
    approach. A folder made before the field (its perturbed approaches ran in full, its fingers
    closed from where the approach left them) never resumes as a run that takes the shortcut, and
    reads back as what it simulated; every other folder resumes as before."""
    teleported = AnnotatorConfig()
    simulated = AnnotatorConfig.from_dict({"protocol": {"approach": "simulated"}})
    without = dataclasses.replace(simulated, robust=dataclasses.replace(simulated.robust, **{field: False}))
    shaken = dataclasses.replace(simulated, robust=dataclasses.replace(simulated.robust, shake=True))
    for config, trials in ((teleported, 5), (simulated, 1), (shaken, 5)):
        assert field not in config.to_dict(trials=trials)["robust"]
        assert _spec(config, trials).differences(_made_before(config, trials, field)) == []
    assert _spec(simulated, 5).differences(_made_before(simulated, 5, field)) == [
        f"[robust] {field} None in the folder, True now"
    ]
    # read back from a manifest: what the run simulated
    for config in (teleported, simulated, without, shaken):
        assert AnnotatorConfig.from_run(config.to_dict(trials=5), 5) == config
    assert AnnotatorConfig.from_run(_made_before(simulated, 5, field)["config"], 5) == without


@pytest.mark.parametrize(
    "toml, fragment",
    [
        ('[protocol]\nlift_height = "high"\n', "[protocol] lift_height: expected a number"),
        ("[physics]\ntime_step = -1\n", "[physics] time_step: must be > 0"),
        ("protocol = 3\n", "[protocol] must be a section of settings"),
        ("not toml at all [[\n", "not a TOML file"),
    ],
)
def test_a_bad_config_file_is_a_usage_error(tmp_path, toml, fragment):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    objs = tmp_path / "objs"
    objs.mkdir()
    result = CliRunner().invoke(
        annotate_command,
        ["--objects", str(objs), "--n", "2", "--config", str(cfg), "--out", str(tmp_path / "o")],
    )
    assert result.exit_code == 2, result.output
    assert fragment in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "o").exists()  # nothing written before the inputs are checked


@pytest.mark.parametrize("scale", ["0", "-1", "nan", "inf"])
def test_scale_must_be_finite_and_positive(tmp_path, scale):
    result = CliRunner().invoke(
        annotate_command,
        ["--objects", str(tmp_path), "--n", "2", f"--scale={scale}", "--out", str(tmp_path / "o")],
    )
    assert result.exit_code == 2, result.output
    assert "--scale" in result.output and "finite number > 0" in result.output


def test_a_run_binds_stall_by_travel_only_where_it_changes_the_scores():
    """``[robust] stall_by_travel`` is in a run's manifest only past one trial with lift-only
    perturbed trials, whatever the approach. A folder made before the field (its perturbed closes
    stalled by speed alone) never resumes as a run whose closes stall by travel, and reads back as
    what it simulated; a folder of ``--trials 1`` or of shaken perturbed trials resumes as before."""

    lift = AnnotatorConfig()
    simulated = AnnotatorConfig.from_dict({"protocol": {"approach": "simulated"}})
    by_speed = dataclasses.replace(lift, robust=dataclasses.replace(lift.robust, stall_by_travel=False))
    shaken = dataclasses.replace(lift, robust=dataclasses.replace(lift.robust, shake=True))

    def before(config: AnnotatorConfig, trials: int) -> dict:
        return _made_before(config, trials, "stall_by_travel")

    for config, trials in ((lift, 1), (shaken, 5)):
        assert "stall_by_travel" not in config.to_dict(trials=trials)["robust"]
        assert _spec(config, trials).differences(before(config, trials)) == []
    for config in (lift, simulated):
        assert _spec(config, 5).differences(before(config, 5)) == [
            "[robust] stall_by_travel None in the folder, True now"
        ]
    # read back from a manifest: what the run simulated
    for config in (lift, simulated, by_speed, shaken):
        assert AnnotatorConfig.from_run(config.to_dict(trials=5), 5) == config
    assert AnnotatorConfig.from_run(before(lift, 5)["config"], 5) == by_speed


# --- physical bounds of [robust] and [confidence] -------------------------------------------------------


@pytest.mark.parametrize(
    "field, value, bound",
    [
        ("position_sigma", 1000.0, "<= 0.1"),  # a 1 km sigma scored 0.27 where the labels scored 0.8
        ("approach_sigma", 0.5, "<= 0.1"),
        ("rotation_sigma", 3.0, "<= 0.35"),
        ("object_position_sigma", 0.5, "<= 0.05"),
        ("object_yaw_sigma", 6.3, "<= 0.52"),
        ("object_tilt_sigma", 1.0, "<= 0.35"),
        ("friction_delta", 5.0, "<= 1"),
    ],
)
def test_robust_ranges_are_execution_errors_not_another_task(field, value, bound):
    with pytest.raises(ConfigError, match=rf"\[robust\] {field}: must be >= 0 and {bound}") as info:
        AnnotatorConfig.from_dict({"robust": {field: value}})
    assert bound in str(info.value)


MAPPING = {"method": "isotonic", "trials": 5, "scores": [0.0, 1.0], "p_success": [0.2, 0.9], "n": 20}
BINS = {"reliability_p": [0.2, 0.9], "reliability_rate": [0.25, 0.8], "reliability_n": [10, 10]}


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"reliability_rate": [2.0, 0.8]},
            "[confidence] reliability_rate: a share of trials, in [0, 1], got 2",
        ),
        ({"reliability_rate": [-1.0, 0.8]}, "reliability_rate: a share of trials, in [0, 1], got -1"),
        ({"reliability_p": [0.2, 1.5]}, "reliability_p: a share of trials, in [0, 1], got 1.5"),
        ({"n": -5}, "[confidence] n: must be >= 0"),
        (
            {"reliability_rate": [0.25]},
            "one value per bin (reliability_p 2, reliability_rate 1, reliability_n 2)",
        ),
        ({"reliability_n": [10, 2.5]}, "reliability_n: whole numbers of trials >= 0, got 2.5"),
        ({"reliability_n": [15, 15]}, "30 trials in the bins, more than n = 20"),
        ({"n": 0}, "n = 0: a reliability table and a Brier score are measured on real trials"),
        ({"trials": 1000}, "[confidence] trials: must be >= 0 and <= 100"),
    ],
)
def test_a_confidence_table_no_calibration_makes_is_refused(change, message):
    with pytest.raises(ConfigError) as info:
        AnnotatorConfig.from_dict({"confidence": {**MAPPING, **BINS, **change}})
    assert message in str(info.value)
    AnnotatorConfig.from_dict({"confidence": {**MAPPING, **BINS}})  # the table itself is fine


def test_a_sigma_of_a_kilometre_is_one_line_from_the_config_and_from_the_gripper(tmp_path, my_rg2):
    import shutil

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "objects" / "box.obj", objects)
    config = tmp_path / "far.toml"
    config.write_text("[robust]\nposition_sigma = 1000.0\n")
    runner = CliRunner()
    base = ["--objects", str(objects), "--n", "4", "--trials", "3", "--workers", "1"]
    result = runner.invoke(annotate_command, [*base, "--config", str(config), "--out", str(tmp_path / "a")])
    assert (
        result.exit_code == 2
        and "[robust] position_sigma: must be >= 0 and <= 0.1, got 1000.0" in result.output
    )
    with (my_rg2 / "gripper.toml").open("a") as f:
        f.write("\n[robust]\nposition_sigma = 1e9\n")
    result = runner.invoke(annotate_command, [*base, "--gripper", str(my_rg2), "--out", str(tmp_path / "b")])
    assert result.exit_code == 2 and "position_sigma" in result.output and "<= 0.1" in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_the_report_of_a_hand_written_mapping_claims_no_measurement(tmp_path):
    """It showed "Brier 0.000 ... over 0 real trials" for a mapping that measured nothing."""
    import shutil

    from annotator.cli import main

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "objects" / "box.obj", objects)
    config = tmp_path / "mine.toml"
    mapping = 'method = "isotonic"\ntrials = 1\nscores = [0.0, 1.0]\np_success = [0.1, 0.7]\n'
    mapping += "perturbed_shake = false\n"
    config.write_text("[confidence]\n" + mapping)
    out = tmp_path / "labels"
    runner = CliRunner()
    made = runner.invoke(
        annotate_command,
        ["--objects", str(objects), "--n", "4", "--config", str(config), "--out", str(out), "-q"],
    )
    assert made.exit_code == 0, made.output
    page = tmp_path / "r.html"
    result = runner.invoke(main, ["report", str(out), "--pictures", "0", "--html", str(page)])
    assert result.exit_code == 0, result.output
    html = page.read_text()
    assert "by a mapping written by hand" in html and "no Brier score and no reliability diagram" in html
    assert "Brier score 0.000" not in html and "over 0 real trials" not in html
