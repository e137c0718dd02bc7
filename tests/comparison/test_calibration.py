"""The suite's own credential: how often the verdicts say ``attains`` for an estimator of
known efficiency and bias (comparison.calibration, the built-in experiment ``calibration``).

The estimator returns the truth plus ``N(0, s² CRLB)`` plus a bias of ``b √trace(CRLB)``
along the CRLB's major axis, so its efficiency is exactly ``√(s² + b²)``. With 500 trials
per row on one straight frame (paper-1m) and on a turn, 9 SNR points each:

- ``s = 1, b = 0`` (efficient, unbiased) attains on at least 85% of the rows;
- ``s = 0.8, b = 0.6`` (RMSE exactly √CRLB, through a bias) never attains: ``biased``;
- ``s = 1.2`` is never ``attains`` nor ``below``; ``s = 0.8`` (below the bound: only a biased
  estimator can be, and along an axis it shows) is never ``attains`` nor ``above``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from comparison.calibration import KnownEfficiency
from comparison.engine import run_experiment
from comparison.experiment import load_experiment
from comparison.metrics import summarize
from comparison.store import read_trials
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    experiment = load_experiment("calibration")
    folder = run_experiment(experiment, tmp_path_factory.mktemp("calibration") / "run", workers=1)
    return summarize(read_trials(folder), seed=experiment.seed)


@pytest.mark.slow
def test_an_efficient_unbiased_estimator_attains_on_85_percent_of_500_trial_rows(calibration):
    """Pooled over the 18 rows of paper-1m and turn. One straight frame has a thin bound, so
    its errors are nearly one-dimensional and the 95% interval is ±6% wide against ±4.5% on the
    turn: over 10 seeds (180 rows) the efficient estimator attained on 78% of the paper-1m
    rows and 99% of the turn rows, 88% pooled (docs/math.md §16)."""
    efficient = calibration[calibration["estimator"] == "efficient"]
    assert (efficient["n_trials"] == 500).all() and len(efficient) == 18
    assert (efficient["verdict"] == "attains").mean() >= 0.85, efficient["verdict"].tolist()
    by_scenario = efficient.groupby("scenario")["verdict"].apply(lambda v: (v == "attains").sum())
    assert by_scenario["turn"] >= 8 and by_scenario["paper-1m"] >= 6
    # what is not attains is an interval across an edge of the band, never a claim, and
    # never the bias: its interval ends well inside the limit
    others = efficient[efficient["verdict"] != "attains"]
    assert (others["verdict"] == "inconclusive").all()
    assert others["verdict_reason"].str.contains("straddles an edge").all()
    assert (efficient["bias_ratio_ci_high"] < 0.25).all()


@pytest.mark.slow
def test_a_biased_estimator_at_the_bound_s_rmse_never_attains(calibration):
    biased = calibration[calibration["estimator"] == "biased (s=0.8, b=0.6)"]
    assert len(biased) == 18
    # its efficiency is 1 by construction ...
    assert np.all(np.abs(biased["efficiency_judged"] - 1.0) < 0.1)
    # ... and every row says it is biased, with the bias in the reason
    assert (biased["verdict"] == "biased").all(), biased["verdict_reason"].tolist()
    assert biased["verdict_reason"].str.startswith("bias ").all()
    assert np.all(np.abs(biased["bias_ratio"] - 0.6) < 0.15)


@pytest.mark.slow
def test_inefficient_and_super_efficient_estimators_are_never_said_to_attain(calibration):
    above = calibration.loc[calibration["estimator"] == "above (s=1.2)", "verdict"]
    below = calibration.loc[calibration["estimator"] == "below (s=0.8)", "verdict"]
    assert set(above) <= {"above", "inconclusive"} and (above == "above").mean() >= 0.85
    assert set(below) <= {"biased", "below", "inconclusive"}
    assert (below != "inconclusive").mean() >= 0.85


def test_the_known_efficiency_estimator_draws_n_of_s2_crlb_plus_its_bias():
    """Its errors over 20,000 draws: mean b √trace(CRLB) along the major axis, covariance
    s² CRLB, to Monte Carlo accuracy (3 standard errors)."""
    scenario = get_scenario("paper-1m")
    data = noise_free(scenario, snr_db=10.0).without_truth()
    estimator = KnownEfficiency(emitter_m=(35.0, 15.0), scale=0.8, bias_ratio=0.6)
    rng = np.random.default_rng(4)
    errors = np.array([estimator.estimate(data, rng=rng).position_m for _ in range(20_000)]) - [
        35.0,
        15.0,
    ]
    crlb = estimator.estimate(data, rng=rng).covariance_m2 / 0.8**2
    variances, axes = np.linalg.eigh(crlb)
    expected_mean = 0.6 * np.sqrt(np.trace(crlb)) * axes[:, -1] * np.sign(axes[0, -1])
    mean = errors.mean(axis=0) * np.sign(axes[0, -1])
    standard_error = np.sqrt(np.diag(0.64 * crlb) / len(errors))
    assert np.all(np.abs(mean - expected_mean) < 3 * standard_error)
    np.testing.assert_allclose(np.cov(errors.T), 0.64 * crlb, rtol=0.05, atol=0.05 * variances[0])


def test_the_known_efficiency_estimator_names_a_bad_option():
    with pytest.raises(ValueError, match=r"^scale: expected a finite number >= 0"):
        KnownEfficiency(scale=-1.0)
    with pytest.raises(ValueError, match=r"^bias_axis: expected one of"):
        KnownEfficiency(bias_axis="diagonal")
    with pytest.raises(ValueError, match=r"^emitter_m: expected a finite \(x, y\) in metres"):
        KnownEfficiency(emitter_m=(1.0, 2.0, 3.0))
    data = noise_free(get_scenario("paper-1m"), snr_db=0.0)
    with pytest.raises(ValueError, match=r"^rng: "):
        KnownEfficiency().estimate(data)


@pytest.mark.slow
def test_the_readme_quotes_the_calibration_run(calibration):
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    quoted = re.search(
        r"on (\d+) rows of 500 trials each: the efficient unbiased one attains on (\d+) of\s+the "
        r"\d+ rows and is inconclusive on the other; the one with `s = 0.8, b = 0.6` \(RMSE "
        r"exactly\s+√CRLB\) is `biased` on all (\d+)",
        readme,
    )
    assert quoted, "the README's calibration sentence changed: update this test with it"
    rows, attains, biased = (int(g) for g in quoted.groups())
    efficient = calibration[calibration["estimator"] == "efficient"]
    assert rows == len(efficient) == biased
    assert attains == int((efficient["verdict"] == "attains").sum())
    assert (efficient["verdict"] != "attains").sum() == 1
    wrong = calibration[calibration["estimator"] == "biased (s=0.8, b=0.6)"]
    assert int((wrong["verdict"] == "biased").sum()) == biased
