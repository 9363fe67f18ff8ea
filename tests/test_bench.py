"""The bench scripts' bookkeeping that their printed figures rest on (no timing is asserted)."""

from __future__ import annotations

import collections
import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import pytest

from annotator.config import AnnotatorConfig
from annotator.sim.world import World
from bench import _variants, fidelity, profile_worker


def test_profiler_finds_the_line_that_steps_the_world():
    """profile_worker counts a sample as physics when its innermost frame is World.step's call of
    stepSimulation: if World.step changed, every sample would silently count as outside."""
    suffix, line = profile_worker.step_line()
    source = Path(sys.modules[World.__module__].__file__).read_text().splitlines()
    assert suffix == "annotator/sim/world.py"
    assert "pb.stepSimulation(" in source[line - 1]


def test_profiler_attributes_samples_to_the_innermost_process(tmp_path, monkeypatch):
    """py-spy nests a worker's stack under its parent's "process" frame; the worker's samples
    must be the worker's, and a worker sample in stepSimulation counts as physics."""
    suffix, line = profile_worker.step_line()
    parent = 'process 10:"python annotate --objects objects"'
    worker = 'process 11:"python -m joblib.externals.loky.backend.popen_loky_posix --pipe 3"'
    span = "WorkerState.label (annotator/pipeline/worker.py:330)"
    raw = "\n".join(
        [
            f"{parent};<module> (annotate:8);run (annotator/pipeline/run.py:400) 5",
            f"{parent};{worker};{span};step (/x/{suffix}:{line}) 7",
            f"{parent};{worker};{span};_first_hits (annotator/sampler.py:90) 2",
        ]
    )

    def fake_run(cmd, capture_output, text):
        Path(cmd[cmd.index("--output") + 1]).write_text(raw)
        return dataclasses.make_dataclass("P", ["returncode", "stderr"])(0, "")

    monkeypatch.setattr(profile_worker.subprocess, "run", fake_run)
    # py-spy is the bench extra's, not the tests': only its output's parsing is tested here
    monkeypatch.setattr(profile_worker.shutil, "which", lambda name, path=None: f"/not/run/{name}")
    stacks = profile_worker.profile(1, 1, 100, tmp_path)
    assert set(stacks) == {parent, worker}
    assert sum(stacks[parent].values()) == 5
    counter: collections.Counter = stacks[worker]
    assert sum(counter.values()) == 9
    (in_step,) = [s for s in counter if s[-1].startswith("step (")]
    assert counter[in_step] == 7
    assert profile_worker.is_worker(worker, counter) and not profile_worker.is_worker(parent, stacks[parent])
    # a process py-spy read no command line for is a worker when it ran a span
    assert profile_worker.is_worker('process 12:""', counter)
    # what a span was doing, and within a trial which step of it
    sampling = (span, "candidates (annotator/pipeline/worker.py:1)", "_first_hits (annotator/sampler.py:90)")
    assert profile_worker.phase(sampling) == "candidates"
    shaking = (
        span,
        "simulate (w.py:1)",
        "GraspTrial.run (t.py:2)",
        "FloatingGripper.shake (h.py:3)",
        "x (y.py:4)",
    )
    assert profile_worker.phase(shaking) == "trial: FloatingGripper.shake"
    assert profile_worker.owner(("a (lib.py:1)", "_first_hits (annotator/sampler.py:90)", "b (np.py:2)")) == (
        "_first_hits (annotator/sampler.py)"
    )
    # the shares the record keeps: 7 of the worker's 9 samples in stepSimulation, all 9 in a span
    shares = profile_worker.Shares()
    shares.add_worker(counter, lambda s: s[-1].startswith("step ("))
    assert (shares.total, shares.inside, shares.in_span) == (9, 7, 9)
    assert shares.outside_share == shares.span_outside_share == 2 / 9
    assert shares.phases == {"_first_hits": 2}


def test_fidelity_cache_key_keeps_cell_settings_out_but_not_physics():
    """Cached floating labels survive a change to [cell] or [kinect] (which they never read), and
    never survive a change to the gripper, the objects, the physics or the protocol."""
    cache = fidelity.LabelCache(Path("/nonexistent"))
    base = AnnotatorConfig()
    key = {"seed": 0}
    path = cache._path("default", base, key)
    cell = dataclasses.replace(base, cell=dataclasses.replace(base.cell, approach_cone=55.0))
    assert cache._path("default", cell, key) == path
    for changed in (
        dataclasses.replace(base, gripper=dataclasses.replace(base.gripper, pad_rolling_friction=1e-4)),
        dataclasses.replace(base, objects=dataclasses.replace(base.objects, rolling_friction=1e-4)),
        dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, settle_time=0.05)),
        dataclasses.replace(base, physics=dataclasses.replace(base.physics, solver_iterations=200)),
    ):
        assert cache._path("default", changed, key) != path


def test_variant_documented_in_the_module_parses_to_what_it_says():
    """The variant _variants' docstring shows names fields that exist, and sets them."""
    (example,) = re.findall(r'``"([^"]+)"``', _variants.__doc__.splitlines()[0])
    label, config = _variants.parse_variant(example)
    assert label == "it100"
    assert config.physics.solver_iterations == 100
    assert config.protocol.shake_paired is False
    assert config.to_dict() != AnnotatorConfig().to_dict()


@pytest.mark.parametrize(
    "args, said",
    [
        (
            ["--train-objects", "no/such/folder", "--test-objects", "objects"],
            "--train-objects: no/such/folder: no such folder",
        ),
        (
            ["--train-objects", "objects", "--test-objects", "README.md"],
            "--test-objects: README.md: not a folder",
        ),
        (
            ["--train-objects", "objects", "--test-objects", "objects", "--rounds", "-1"],
            "--rounds: -1 is not in 0 .. 100,000",
        ),
        (
            ["--train-objects", "objects", "--test-objects", "objects", "--scenes", "0"],
            "--scenes: 0 is not in 1 .. 1,000,000",
        ),
        (
            ["--train-objects", "objects", "--test-objects", "objects", "--model", "no.npz"],
            "--model: no.npz: no such file",
        ),
        (
            ["--train-objects", "objects", "--test-objects", "objects", "--model", "README.md"],
            "is not a model of annotator learn train",
        ),
    ],
)
def test_bench_learning_checks_its_arguments_in_one_line(args, said):
    """Bad paths were tracebacks; --rounds -1 and --scenes 0 were accepted."""
    repo = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-m", "bench.learning", *args], capture_output=True, text=True, cwd=repo
    )
    assert done.returncode == 2 and done.stdout == ""
    assert said in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


# --- every benchmark's arguments --------------------------------------------------------------------

REPO = Path(__file__).resolve().parents[1]
BENCHES = sorted(
    ".".join(path.relative_to(REPO / "bench").with_suffix("").parts)
    for path in [*(REPO / "bench").glob("*.py"), *(REPO / "bench" / "experiments").glob("*.py")]
    if "add_argument" in path.read_text() and path.stem != "arguments"
)


def _parser(name: str):
    import importlib

    return importlib.import_module(f"bench.{name}").parser()


def _actions(parser):
    """Every option of ``parser`` and of its subcommands."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _actions(sub)
        else:
            yield action


@pytest.mark.parametrize("name", BENCHES)
def test_every_bench_builds_its_options_with_checked_types(name):
    """Each benchmark's options come from its ``parser()`` (a bench.arguments.Parser: errors are one
    line): a count, size, fraction or path is one of bench.arguments' types, never a bare
    ``int``/``float``/``Path`` that takes 0, -1, nan or a missing folder to a traceback later."""
    from bench.arguments import Parser

    parser = _parser(name)
    assert isinstance(parser, Parser)
    bare = [a.option_strings or [a.dest] for a in _actions(parser) if a.type in (int, float, Path)]
    assert not bare, f"bench.{name}: unchecked {bare}"


HERE = str(REPO)
PY = sys.executable


BAD_ARGUMENTS = [  # (bench, arguments, what its one line says)
    ("cold_start", ["--repeat", "0"], "--repeat: 0 is not in 1 .. 1,000"),
    ("cold_start", ["--objects", "no/such"], "--objects: no/such: no such folder"),
    ("collision_error", ["--scale", "0"], "--scale: 0 is not in (0, 1000]"),
    ("collision_error", ["--first-cut-share", "1.5"], "--first-cut-share: 1.5 is not in (0, 1]"),
    ("docs", ["--results", "no/such"], "--results: no/such: no such folder"),
    ("evaluate_pads", ["--workers", "0"], "--workers: 0 is not in 1 .. 1,024"),
    ("evaluate_pads", ["--n", "-1"], "--n: -1 is not in 1 .. 1,000,000"),
    ("evaluate_pads", ["--miss", "nan"], "--miss: nan is not in [0, 0.1]"),
    ("fidelity", ["--per-object", "0"], "--per-object: 0 is not in 1 .. 1,000,000"),
    ("fidelity", ["--seed", "-1"], "--seed: -1 is not in 0 .. 9,223,372,036,854,775,807"),
    ("gripper_speed", ["--n", "-1"], "--n: -1 is not in 1 .. 1,000,000"),
    ("label_equality", ["--versus-install", "no/such"], "--versus-install: no/such: no such folder"),
    ("label_equality", ["--versus-install", HERE, "--evaluate-n", "0"], "--evaluate-n: 0 is not in"),
    (
        "learning",
        ["--train-objects", "objects", "--test-objects", "objects", "--workers", "0"],
        "--workers",
    ),
    ("machine_speed", ["--cuts", "0"], "--cuts: 0 is not in 1 .. 1,000"),
    ("memory", ["--faces", "0"], "--faces: 0 is not in 100 .. 50,000,000"),
    ("object_cost", ["--few", "0"], "--few: 0 is not in 1 .. 1,000,000"),  # was a ZeroDivisionError
    ("object_sets", ["--samples", "--workers", "0"], "--workers: 0 is not in 1 .. 1,024"),
    ("object_sets", ["--samples", "--timeout", "-1"], "--timeout: -1 is not in (0, 86400]"),
    ("object_sets", ["--ycb", "no/such"], "--ycb: no/such: no such folder"),
    ("object_sets", ["--samples", "--json", "objects"], "--json: objects: is a folder"),
    ("peer_network", ["--vgn", "no/such", "--vgn-python", PY], "--vgn: no/such: no such folder"),
    (
        "peer_network",
        ["--vgn", HERE, "--vgn-python", PY, "--val-split", "1"],
        "--val-split: 1 is not in (0, 1)",
    ),
    ("peer_network", ["--vgn", HERE, "--vgn-python", HERE], f"--vgn-python: {HERE}: not a file"),
    (
        "peer_network",
        ["--vgn", HERE, "--vgn-python", PY, "--until", "judge"],
        "--until: invalid choice: 'judge'",
    ),
    ("peers", ["--per-object", "0"], "--per-object: 0 is not in 1 .. 1,000,000"),
    ("profile_worker", ["--rate", "0"], "--rate: 0 is not in 1 .. 10,000"),
    ("real_trials", ["--data", "no/such"], "--data: no/such: no such folder"),
    ("real_trials", ["--data", "objects"], "--data: objects: no trials.csv in it"),
    ("real_trials", ["--workers", "0"], "--workers: 0 is not in 1 .. 1,024"),
    ("real_trials", ["--folds", "-1"], "--folds: -1 is not in 0 .. 1,000"),
    ("real_trials", ["--profile", "no.toml"], "--profile: no.toml: no such file"),
    ("scale", ["folder", "--objects", "0"], "--objects: 0 is not in 1 .. 10,000,000"),
    ("scale", ["store", "--sizes", "10,-1"], "--sizes: -1 is not in 1 .. 10,000,000"),
    ("scenes", ["--scenes", "0"], "--scenes: 0 is not in 1 .. 1,000,000"),
    ("scenes", ["--workers", "0"], "--workers: 0 is not in 1 .. 1,024"),
    ("structure", ["--repo", "no/such"], "--repo: no/such: no such folder"),
    ("throughput", ["--repeat", "0"], "--repeat: 0 is not in 1 .. 1,000"),
    ("throughput", ["--config", "no.toml"], "--config: no.toml: no such file"),
    ("trials_cost", ["--trials", "1"], "--trials: 1 is not in 2 .. 100"),
    ("trials_cost", ["--n", "-1"], "--n: -1 is not in 1 .. 1,000,000"),
    ("experiments.arm_agreement", ["--labels", "no/such"], "--labels: no/such: no such folder"),
    ("experiments.evaluate_replay", ["--workers", "0"], "--workers: 0 is not in 1 .. 1,024"),
    ("experiments.gripper_coupling", ["--mass", "0"], "--mass: 0 is not in (0, 100]"),
    ("experiments.light_objects", ["--grams", "4", "-1"], "--grams: -1 is not in (0, 100000]"),
    ("experiments.light_threshold", ["--jobs", "0"], "--jobs: 0 is not in 1 .. 1,024"),
    ("experiments.scene_substeps", ["--per-scene", "0"], "--per-scene: 0 is not in 1 .. 253"),
    ("experiments.ur3_ik", ["--n", "0"], "--n: 0 is not in 1 .. 10,000,000"),
    ("experiments.widths", ["--seed", "x"], "--seed: 'x' is not a whole number"),
]


@pytest.mark.parametrize("name, args, said", BAD_ARGUMENTS)
def test_a_bad_bench_argument_is_one_line_and_exit_2(name, args, said, capsys, monkeypatch):
    """Each benchmark's counts, sizes, fractions and paths are checked as argparse reads them:
    --workers 0, --n -1, a missing --data folder end in one line, exit 2, before any work (they
    were accepted, or a traceback later)."""
    monkeypatch.chdir(REPO)
    with pytest.raises(SystemExit) as exit_:
        _parser(name).parse_args(args)
    err = capsys.readouterr().err
    assert exit_.value.code == 2
    assert said in err and len(err.strip().splitlines()) == 1, err


def test_every_bench_with_arguments_has_a_bad_value_above():
    assert "experiments.widths" in BENCHES and "learning" in BENCHES
    covered = {name for name, _, _ in BAD_ARGUMENTS}
    assert covered == set(BENCHES), sorted(set(BENCHES) ^ covered)


@pytest.mark.parametrize(
    "args, said",
    [
        (["bench.real_trials", "--data", "no/such"], "real_trials.py: error: argument --data: no/such"),
        (["bench.object_cost", "--few", "0"], "object_cost.py: error: argument --few: 0 is not in"),
    ],
)
def test_a_bad_bench_argument_from_the_command_line_is_one_line(args, said):
    """As run (``python -m bench.NAME``): one line on stderr, nothing on stdout, exit 2."""
    done = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=REPO)
    assert done.returncode == 2 and done.stdout == "", done.stderr
    assert said in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


@pytest.mark.parametrize("name", BENCHES)
def test_every_bench_s_default_folders_exist(name):
    """A default objects folder is the repository's (three experiments looked in bench/objects)."""
    missing = [
        f"{a.dest}={a.default}"
        for a in _actions(_parser(name))
        if a.type is not None
        and getattr(a.type, "__name__", "") == "existing_folder"
        and isinstance(a.default, Path)
        and not a.default.is_dir()
    ]
    assert not missing
