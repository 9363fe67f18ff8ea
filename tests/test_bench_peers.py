"""What bench/peers.py's figures rest on, with real pybullet: every tool steps the same candidates,
in turns, and a trial's step count is the steps it really took."""

from __future__ import annotations

import collections
import dataclasses
import math

import numpy as np
import pytest

from annotator.config import AnnotatorConfig
from annotator.objects import load_object
from annotator.pipeline.in_memory import ExecutionOptions
from annotator.pipeline.simulate import object_candidates
from annotator.sim import pb
from bench import peers
from bench.reference import free_step

CANDIDATES = 4  # per object; seed 0 gives each object a candidate all three tools simulate


@pytest.fixture(scope="module")
def turns(tmp_path_factory):
    """One round of ours, VGN and AdaGrasp over the 40 mm cube (light: ours substeps it) and the
    cylinder (heavy), with every stepSimulation counted per client and every run's arguments kept."""
    folder = tmp_path_factory.mktemp("peers")
    config = AnnotatorConfig()
    tools = [peers.Ours(config), peers.VGN(folder), peers.AdaGrasp(folder)]
    # the collision shapes' error check on fewer samples: it only reports, the bodies are the same
    objects = config.objects.with_decomposition(collision_error_samples=500)
    work = []
    for source in peers.bench_objects(folder, ("cube40", "cylinder66x120")):
        model = load_object(source, objects, cache_dir=folder / "cache")
        work.append((model, object_candidates(model, CANDIDATES, 0, config, tools[0].hand.gripper.max_width)))
    steps: collections.Counter = collections.Counter()  # client -> stepSimulation calls
    seen: dict[str, list] = collections.defaultdict(list)  # tool -> [(T_obj_tcp, width, steps taken)]
    step = pb.stepSimulation
    with pytest.MonkeyPatch.context() as mp:

        def counted(*args, physicsClientId=0, **kwargs):
            steps[physicsClientId] += 1
            return step(*args, physicsClientId=physicsClientId, **kwargs)

        mp.setattr(pb, "stepSimulation", counted)
        for tool in tools:

            def run(T, width, tool=tool, inner=tool.run):
                before = steps[tool.client]
                result = inner(T, width)
                seen[tool.name].append((T.as_matrix(), width, steps[tool.client] - before))
                return result

            mp.setattr(tool, "run", run)
        tallies, by_object = peers.take_turns(tools, work)
    yield tools, work, tallies, by_object, seen
    for tool in tools:
        tool.close()


def test_every_tool_runs_the_same_candidates(turns):
    tools, work, tallies, _, seen = turns
    n = sum(len(c) for _, c in work)
    expected = np.concatenate([c.T_obj_tcp for _, c in work])
    for tool in tools:
        assert len(seen[tool.name]) == len(tallies[tool.name].results) == n
        np.testing.assert_allclose(np.array([T for T, _, _ in seen[tool.name]]), expected, rtol=0, atol=1e-12)
        assert [w for _, w, _ in seen[tool.name]] == [w for _, c in work for w in c.width_expected.tolist()]
    # and each object has a candidate all of them simulate, so the per-trial figures compare trials
    for k0, (_, cands) in zip((0, CANDIDATES), work, strict=True):
        both = [all(tallies[t.name].results[k].simulated for t in tools) for k in range(k0, k0 + len(cands))]
        assert any(both)


def test_a_trials_steps_are_the_steps_it_took(turns):
    """Result.steps (what steps per trial and ms per step are computed from) equals the
    stepSimulation calls made in that tool's client during that run, substeps included."""
    tools, _, tallies, _, seen = turns
    for tool in tools:
        results = tallies[tool.name].results
        assert [r.steps for r in results] == [taken for _, _, taken in seen[tool.name]]
        for r in results:
            assert (r.step_seconds > 0) == (r.steps > 0)
        simulated = [r.steps for r in results if r.simulated]
        assert all(s > 0 for s in simulated)
        assert tallies[tool.name].figures()["steps_trial"] == pytest.approx(np.mean(simulated))
    # ours on the light cube takes more steps per trial than on the heavy cylinder (it substeps)
    ours = {o: t.figures()["steps_trial"] for (o, name), t in turns[3].items() if name == "ours"}
    assert ours["cube40"] > ours["cylinder66x120"]


def test_figures_and_ratios_of_a_round(turns):
    _, _, tallies, by_object, _ = turns
    ours, vgn = tallies["ours"].figures(), tallies["vgn"].figures()
    assert ours["candidates"] == vgn["candidates"] == 2 * CANDIDATES
    assert 0 < ours["ms_trial"] and 0 < ours["ms_step"] < ours["ms_trial"]
    assert peers.agreement(tallies["ours"], tallies["ours"]) == (1.0, 1.0)
    groups = peers.light_groups(by_object, {"cube40"}, 0.04)
    assert groups == [("at or above 40 g", ["cylinder66x120"]), ("below 40 g (substepped)", ["cube40"])]
    assert math.isnan(peers.over(1.0, 0.0))
    assert peers.slug("ours[it100: x]") == "ours_it100_x"


def test_the_reference_free_step_is_a_step_in_contact():
    step = free_step(steps=24, blocks=2)
    assert 0 < step.cpu < 0.05 and 0 < step.wall < 0.05 and step.steps == 24


@pytest.mark.slow
def test_an_objects_turns_through_the_runner_are_the_turns_taken_in_process(turns, tmp_path):
    """bench.peers runs each object's turns in a worker (``object_turns``, a Call through the
    runner), its tools built there: on the same candidates every tool's outcomes, steps and widths
    are those of the tools taking turns in this process, and the object is described as loaded."""
    tools, _, _, by_object, _ = turns
    config = AnnotatorConfig()
    config = dataclasses.replace(
        config, objects=config.objects.with_decomposition(collision_error_samples=500)
    )
    unit = peers.ObjectTurns("cube40", CANDIDATES, 0, config, cache_dir=tmp_path / "cache")
    (got,) = peers.run_round([unit], ExecutionOptions(workers=1))
    assert (got.object_id, got.parts, got.substepped, got.candidates) == ("cube40", 1, True, CANDIDATES)
    assert list(got.tallies) == [tool.name for tool in tools]
    for tool in tools:
        mine, theirs = by_object[("cube40", tool.name)].results, got.tallies[tool.name].results
        assert [(r.simulated, r.success, r.steps) for r in theirs] == [
            (r.simulated, r.success, r.steps) for r in mine
        ]
        np.testing.assert_array_equal([r.width for r in theirs], [r.width for r in mine])
        assert all(seconds > 0 for seconds in got.tallies[tool.name].seconds)  # the worker's CPU
