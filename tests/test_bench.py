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
