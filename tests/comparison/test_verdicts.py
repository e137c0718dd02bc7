"""Verdicts (comparison.verdicts): honest intervals under heavy tails, counts, thresholds."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from comparison.verdicts import (
    MIN_TRIALS,
    efficiency_verdicts,
    nees_verdicts,
    studentized_bootstrap_interval,
    tail_share,
    threshold_snr,
)


def verdict_of(squared_errors: np.ndarray, bound_m: float = 1.0, *, seed: int = 0) -> str:
    """The efficiency verdict of one sample of squared errors against √CRLB ``bound_m``."""
    n = len(squared_errors)
    groups = np.zeros(n, dtype=int)
    low, high = studentized_bootstrap_interval(
        squared_errors, groups, 1, rng=np.random.default_rng(seed)
    )
    verdicts, _ = efficiency_verdicts(
        n_judged=[n],
        n_trials=[n],
        efficiency=[math.sqrt(np.mean(squared_errors)) / bound_m],
        low=np.sqrt(low) / bound_m,
        high=np.sqrt(high) / bound_m,
        tail=tail_share(squared_errors, groups, 1),
    )
    return str(verdicts[0])


def efficient_squared_errors(n: int, rng: np.random.Generator) -> np.ndarray:
    """Squared errors of an efficient 2-D estimator with √trace(CRLB) = 1 m: ‖e‖², e ~ N(0, I/2)."""
    return np.sum(rng.normal(0.0, math.sqrt(0.5), (n, 2)) ** 2, axis=1)


@pytest.mark.parametrize("n", [50, 100, 200, 500, 1000, 5000])
@pytest.mark.parametrize("seed", range(5))
def test_two_percent_outliers_at_1e4_times_the_bound_never_attain(n: int, seed: int) -> None:
    """2% of the trials 1e4 √CRLB away: the RMSE is about 1400 √CRLB, never 'attains'.
    With few outliers the interval is unbounded above (inconclusive); with many, wholly above."""
    rng = np.random.default_rng(seed)
    squared = efficient_squared_errors(n, rng)
    outliers = rng.choice(n, size=round(0.02 * n), replace=False)
    squared[outliers] = 1e8
    verdict = verdict_of(squared, seed=seed)
    assert verdict != "attains"
    if n >= 500:
        assert verdict == "above"


def test_the_percentile_bootstrap_would_have_called_an_outlier_sample_plausible() -> None:
    """Why not the percentile bootstrap: with 3 trials of 500 at 150 km and the rest at the
    bound (ml on `paper` at 0 dB), resamples that omit all three happen 5% of the time, so the
    percentile interval's lower end sits near the bound; the studentized one stays far above."""
    rng = np.random.default_rng(1)
    squared = efficient_squared_errors(500, rng) * 35.0**2
    squared[:3] = 150e3**2
    draws = rng.integers(0, 500, size=(2000, 500))
    percentile_low = np.sqrt(np.quantile(squared[draws].mean(axis=1), 0.025))
    low, _ = studentized_bootstrap_interval(squared, np.zeros(500, int), 1, rng=rng)
    assert percentile_low < 100.0  # within 3× the 35 m bound
    assert np.sqrt(low[0]) > 1000.0


@pytest.mark.parametrize("seed", range(5))
def test_ten_trials_are_inconclusive(seed: int) -> None:
    squared = efficient_squared_errors(10, np.random.default_rng(seed))
    assert verdict_of(squared, seed=seed) == "inconclusive"
    _, reasons = efficiency_verdicts(
        n_judged=[10], n_trials=[10], efficiency=[1.0], low=[0.9], high=[1.1], tail=[0.1]
    )
    assert reasons[0].startswith(f"too few trials: 10 < {MIN_TRIALS}")


@pytest.mark.parametrize("seed", range(5))
def test_an_efficient_sample_of_1000_attains(seed: int) -> None:
    squared = efficient_squared_errors(1000, np.random.default_rng(seed))
    assert verdict_of(squared, seed=seed) == "attains"


def test_biased_and_inefficient_samples_are_below_and_above() -> None:
    rng = np.random.default_rng(3)
    assert verdict_of(0.5 * efficient_squared_errors(1000, rng)) == "below"
    assert verdict_of(1.5 * efficient_squared_errors(1000, rng)) == "above"
    # efficiency 1.08: its interval straddles 1.1 at n = 500
    assert verdict_of(1.08**2 * efficient_squared_errors(500, rng), seed=2) == "inconclusive"


def test_studentized_interval_covers_the_mean_about_95_percent_of_the_time() -> None:
    """Coverage of the true MSE by the interval, 400 samples of 200 exponential values."""
    rng = np.random.default_rng(7)
    n_groups, n = 400, 200
    values = efficient_squared_errors(n_groups * n, rng)
    groups = np.repeat(np.arange(n_groups), n)
    low, high = studentized_bootstrap_interval(values, groups, n_groups, rng=rng)
    covered = (low <= 1.0) & (1.0 <= high)
    assert 0.92 <= covered.mean() <= 0.98
    # width about 2·1.96·σ/√n of the mean, σ = 1 for exponential squared errors
    assert np.median(high - low) == pytest.approx(2 * 1.96 / math.sqrt(n), rel=0.15)


def test_failures_and_heavy_tails_block_attains_and_say_why() -> None:
    verdicts, reasons = efficiency_verdicts(
        n_judged=[490, 500, 500],
        n_trials=[500, 500, 500],
        efficiency=[1.0, 1.0, 1.0],
        low=[0.95, 0.95, 0.95],
        high=[1.05, 1.05, 1.05],
        tail=[0.06, 0.40, 0.06],
    )
    assert verdicts.tolist() == ["inconclusive", "inconclusive", "attains"]
    assert reasons[0].startswith("only 98.0% of the estimates succeeded (490 of 500")
    assert reasons[1].startswith("heavy tail: the largest 1% of the trials carry 40%")
    assert "inside [0.9, 1.1]" in reasons[2]


def test_tail_share_is_the_share_of_the_largest_one_percent() -> None:
    values = np.concatenate([np.ones(199), [801.0], np.ones(100)])
    groups = np.repeat([0, 1], [200, 100])
    share = tail_share(values, groups, 3)
    # group 0: top 2 values (801 + 1) of 1000; group 1: top 1 of 100; group 2: empty
    assert share[0] == pytest.approx(802 / 1000)
    assert share[1] == pytest.approx(1 / 100)
    assert np.isnan(share[2])


def test_nees_verdicts_against_the_band() -> None:
    verdicts = nees_verdicts(
        nees_mean=[2.0, 3.0, 1.0, 2.0, np.nan],
        n_nees=[500, 500, 500, 10, 0],
        band_low=[1.83] * 5,
        band_high=[2.18] * 5,
    )
    assert verdicts.tolist() == [
        "consistent",
        "optimistic",
        "pessimistic",
        "inconclusive",
        "no covariance",
    ]


def test_threshold_snr_is_the_lowest_snr_from_which_every_higher_point_attains() -> None:
    snr = [-10.0, 0.0, 10.0, 20.0, 30.0]
    rows = pd.DataFrame(
        {
            "scenario": "s",
            "estimator": np.repeat(["a", "b", "c", "d"], 5),
            "snr_db": snr * 4,
            "verdict": ["above", "attains", "inconclusive", "attains", "attains"]
            + ["attains"] * 5
            + ["attains"] * 4
            + ["above"]
            + ["below", "attains", "attains", "attains", "attains"],
        }
    )
    table = threshold_snr(rows, ["scenario", "estimator"])
    assert table["threshold_snr_db"].tolist()[:2] == [20.0, -10.0]
    assert math.isnan(table["threshold_snr_db"].iloc[2])  # the highest point does not attain
    assert table["threshold_snr_db"].iloc[3] == 0.0
    assert table["n_attains"].tolist() == [3, 5, 4, 4]
