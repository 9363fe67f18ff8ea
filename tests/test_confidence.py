"""The score-to-probability mapping and the measures of a confidence against real outcomes
(annotator/confidence.py): isotonic fit, object-wise cross-validation, AUC, Brier, reliability."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from annotator import confidence as conf


def test_isotonic_fit_is_the_success_rate_per_score_pooled_where_it_would_fall():
    score = np.array([0.0, 0.0, 0.5, 0.5, 0.5, 0.5, 1.0, 1.0])
    real = np.array([0, 1, 0, 0, 0, 1, 1, 1], dtype=bool)
    m = conf.fit_isotonic(score, real, trials=2)
    # rates 0.5, 0.25, 1.0: the first two fall, so they pool to 2/6 at the mean score 1/3
    assert m.scores == pytest.approx((1 / 3, 1.0)) and m.p == pytest.approx((2 / 6, 1.0))
    assert m.trials == 2 and m.n == 8
    p = m.p_success(np.array([0.0, 2 / 3, 1.0]))
    assert p == pytest.approx([1 / 3, 2 / 3, 1.0])  # constant below, linear between knots
    assert np.all(np.diff(m.p) >= 0)


def test_cross_validation_by_object_never_fits_on_the_object_it_predicts():
    # each object's trials all succeed or all fail at the same score: a mapping that saw the
    # object would predict it; held out, it can only predict the other objects' rate
    score = np.repeat([0.4, 0.4, 0.4, 0.4], 5)
    real = np.repeat([True, True, False, False], 5)
    objects = np.repeat(["a", "b", "c", "d"], 5)
    p = conf.cross_validated(score, real, objects, trials=5, folds=4)
    assert p[real] == pytest.approx(1 / 3) and p[~real] == pytest.approx(2 / 3)
    with pytest.raises(ValueError):
        conf.cross_validated(score, real, np.repeat("a", 20), trials=5)


def test_auc_brier_and_top_fifth_on_known_cases():
    real = np.array([1, 1, 0, 0, 1, 0], dtype=bool)
    assert conf.auc(real, np.array([0.9, 0.8, 0.1, 0.2, 0.7, 0.3])) == 1.0
    assert conf.auc(real, np.full(6, 0.5)) == 0.5  # ties count half
    assert conf.auc(real, np.array([0.1, 0.2, 0.9, 0.8, 0.3, 0.7])) == 0.0
    assert np.isnan(conf.auc(np.ones(3, bool), np.arange(3.0)))
    assert conf.brier(real, real.astype(float)) == 0.0
    assert conf.brier(real, np.full(6, 0.5)) == 0.25
    ranked = np.arange(10.0)
    hits = ranked >= 8
    assert conf.top_fraction_precision(hits, ranked) == 1.0
    assert conf.top_fraction_precision(~hits, ranked) == 0.0


def test_bootstrap_interval_holds_the_value_and_narrows_with_trials():
    rng = np.random.default_rng(0)
    widths = []
    for n in (50, 800):
        score = rng.random(n)
        real = rng.random(n) < score
        m = conf.bootstrap(conf.auc, real, score, samples=300)
        assert m.low <= m.value <= m.high
        widths.append(m.high - m.low)
    assert widths[1] < widths[0] / 2


def test_threshold_cross_validated_by_object():
    score = np.tile([0.0, 0.2, 0.6, 1.0], 5)
    real = score >= 0.6
    objects = np.repeat(list("abcde"), 4)
    calls, thresholds = conf.cross_validated_decisions(score, real, objects, folds=5)
    assert (calls == real).all() and all(t == pytest.approx(0.6) for t in thresholds)


def test_reliability_table_and_diagram():
    p = np.array([0.05, 0.1, 0.5, 0.55, 0.95, 0.99])
    real = np.array([0, 0, 1, 0, 1, 1], dtype=bool)
    bins = conf.reliability(real, p, bins=5)
    assert [b.n for b in bins] == [2, 0, 2, 0, 2]
    assert bins[2].real_rate == 0.5 and bins[4].mean_p == pytest.approx(0.97)
    png = conf.reliability_png([("p", bins)], "test", size=300)
    image = Image.open(io.BytesIO(png))
    assert image.format == "PNG" and image.size == (300, 300)
    # something was drawn in the curve's colour
    pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    assert (np.abs(pixels - np.array([31, 119, 180])).sum(axis=1) == 0).sum() > 20


def test_labels_made_with_a_calibration_carry_p_success(tmp_path):
    """``[confidence]`` in the configuration: every row's p_success is the mapping of its score;
    without it no column; a run with another --trials than the mapping's is refused."""
    import dataclasses

    import trimesh

    from annotator.config import AnnotatorConfig, ConfigError
    from annotator.objects import ObjectSource
    from annotator.pipeline.worker import Span, SpanTask, label_span

    path = tmp_path / "brick.obj"
    trimesh.creation.box((0.05, 0.04, 0.10)).export(path)
    source = ObjectSource("brick", path)
    plain = AnnotatorConfig()
    fit = {"method": "isotonic", "trials": 2, "scores": [0.0, 1.0], "p_success": [0.2, 0.9]}
    calibrated = AnnotatorConfig.from_dict({"confidence": fit | {"perturbed_shake": False}})
    rows = label_span(
        SpanTask(span=Span("brick", source, None, 0, 6), config=calibrated, seed=0, n=6, trials=2)
    ).rows
    assert rows["p_success"].to_numpy() == pytest.approx(0.2 + 0.7 * rows["score"].to_numpy())
    assert (
        "p_success"
        not in label_span(
            SpanTask(span=Span("brick", source, None, 0, 6), config=plain, seed=0, n=6, trials=2)
        ).rows
    )
    with pytest.raises(ValueError, match="--trials 2"):
        label_span(SpanTask(span=Span("brick", source, None, 0, 6), config=calibrated, seed=0, n=6, trials=1))
    with pytest.raises(ConfigError):
        dataclasses.replace(calibrated.confidence, p_success=(0.9, 0.2))
    # fitted on scores whose perturbed trials shook (a file written before they ended at the lift)
    shaken = AnnotatorConfig.from_dict({"confidence": fit})
    with pytest.raises(ValueError, match="shake = true"):
        label_span(SpanTask(span=Span("brick", source, None, 0, 6), config=shaken, seed=0, n=6, trials=2))
    both = AnnotatorConfig.from_dict({"confidence": fit, "robust": {"shake": True}})
    assert (
        "p_success"
        in label_span(
            SpanTask(span=Span("brick", source, None, 0, 6), config=both, seed=0, n=6, trials=2)
        ).rows
    )


def test_the_report_shows_the_calibration_s_reliability_and_brier():
    import base64

    import pandas as pd

    from annotator.tools.report import _confidence_section

    section = {
        "method": "isotonic",
        "trials": 5,
        "scores": [0.0, 1.0],
        "p_success": [0.3, 0.9],
        "n": 200,
        "brier": 0.171,
        "reliability_p": [0.3, 0.9],
        "reliability_rate": [0.25, 0.95],
        "reliability_n": [80.0, 120.0],
    }
    manifest = {"run": {"config": {"confidence": section}}}
    df = pd.DataFrame({"p_success": [0.3, 0.6, 0.9]})
    html = _confidence_section(manifest, df)
    assert "Brier score 0.171" in html and "mean p_success is 0.600" in html and "--trials 5" in html
    png = base64.b64decode(html.split("base64,")[1].split("'")[0])
    assert Image.open(io.BytesIO(png)).format == "PNG"
    assert "No calibration" in _confidence_section({"run": {"config": {}}}, pd.DataFrame({"score": [1.0]}))


def test_annotate_refuses_a_calibration_fitted_at_another_number_of_trials(tmp_path):
    from click.testing import CliRunner

    from annotator.cli import annotate_command

    config = tmp_path / "calibrated.toml"
    config.write_text(
        '[confidence]\nmethod = "isotonic"\ntrials = 5\nscores = [0.0, 1.0]\np_success = [0.2, 0.9]\n'
    )
    args = ["--objects", str(tmp_path), "--n", "2", "--out", str(tmp_path / "out"), "--config", str(config)]
    result = CliRunner().invoke(annotate_command, args)
    assert result.exit_code == 2 and "run with --trials 5" in result.output, result.output
    assert "Traceback" not in result.output
    # at its K, but fitted on perturbed trials that shook while this run's end at the lift
    result = CliRunner().invoke(annotate_command, [*args, "--trials", "5"])
    assert result.exit_code == 2 and "set [robust] shake = true, or calibrate again" in result.output
    assert "Traceback" not in result.output


def test_ties_share_their_places_in_a_top_share_and_in_the_fifths():
    """241 of 425 rows scoring 1.0 must not be ranked by their row order: a tied group straddling
    a boundary counts in each share by the part of its places there, whatever the order."""
    rng = np.random.default_rng(2)
    real = rng.random(425) < 0.65
    score = np.where(np.arange(425) < 241, 1.0, rng.integers(0, 5, 425) / 5)
    top = conf.top_fraction_precision(real, score)
    assert top == pytest.approx(real[:241].mean())  # the top 85 places all lie in the tied group
    for order in (rng.permutation(425), np.arange(425)[::-1]):
        assert conf.top_fraction_precision(real[order], score[order]) == pytest.approx(top)
        bins = conf.fifths(real[order], score[order])
        assert [b.n for b in bins] == [85] * 5
        assert bins[0].mean_p == 1.0 and bins[0].real_rate == pytest.approx(real[:241].mean())
        assert bins[2].real_rate == pytest.approx(conf.fifths(real, score)[2].real_rate)
    shares = conf.rank_shares(np.array([3.0, 2.0, 2.0, 2.0, 1.0]), 5)
    assert np.allclose(shares.sum(axis=1), 1.0) and np.allclose(shares.sum(axis=0), 1.0)
    assert np.allclose(shares[1], [0, 1 / 3, 1 / 3, 1 / 3, 0])  # the tie spreads over fifths 2-4
