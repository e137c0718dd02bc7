"""Verdicts and their intervals (comparison.verdicts, comparison.intervals): honest intervals
under heavy tails, the bias and the principal axes, counts, thresholds."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import comparison.intervals as intervals_module
from comparison.intervals import (
    AxisEfficiencies,
    BiasIntervals,
    axis_squared_errors,
    bias_intervals,
    studentized_bootstrap_interval,
    tail_share,
)
from comparison.verdicts import MIN_TRIALS, efficiency_verdicts, nees_verdicts, threshold_snr

CRLB_M2 = np.diag([0.8, 0.2])
"""The bound of the samples below: √trace = 1 m, an elongated error ellipse (axes 0.89 m and
0.45 m along x and y)."""


def verdicts_of(
    errors_m: np.ndarray, *, seed: int = 0, crlb_m2: np.ndarray = CRLB_M2
) -> tuple[str, str]:
    """The efficiency verdict of one sample of error vectors ``(n, 2)`` against a diagonal
    CRLB of trace 1 (default CRLB_M2), and its reason, computed as
    comparison.metrics.summarize computes them."""
    n = len(errors_m)
    groups = np.zeros(n, dtype=int)
    squared = np.sum(errors_m**2, axis=1)
    rng = np.random.default_rng(seed)
    low, high = studentized_bootstrap_interval(squared, groups, 1, rng=rng)
    along = axis_squared_errors(errors_m, np.broadcast_to(crlb_m2, (n, 2, 2)))
    intervals = [studentized_bootstrap_interval(q, groups, 1, rng=rng) for q in along.T]
    verdicts, reasons = efficiency_verdicts(
        n_judged=[n],
        n_trials=[n],
        efficiency=[math.sqrt(np.mean(squared))],
        low=np.sqrt(low),
        high=np.sqrt(high),
        tail=tail_share(squared, groups, 1),
        bias=bias_intervals(errors_m, groups, 1, [1.0]),
        axes=AxisEfficiencies(
            efficiency=np.sqrt(along.mean(axis=0))[None, :],
            low=np.sqrt([[lo[0] for lo, _ in intervals]]),
            high=np.sqrt([[hi[0] for _, hi in intervals]]),
        ),
    )
    return str(verdicts[0]), reasons[0]


def verdict_of(errors_m: np.ndarray, *, seed: int = 0) -> str:
    return verdicts_of(errors_m, seed=seed)[0]


def efficient_errors(n: int, rng: np.random.Generator) -> np.ndarray:
    """Errors of an efficient unbiased estimator: N(0, CRLB_M2), shape (n, 2)."""
    return rng.normal(size=(n, 2)) * np.sqrt(np.diag(CRLB_M2))


def efficient_squared_errors(n: int, rng: np.random.Generator) -> np.ndarray:
    """Squared errors of an efficient 2-D estimator with √trace(CRLB) = 1 m: ‖e‖², e ~ N(0, I/2)."""
    return np.sum(rng.normal(0.0, math.sqrt(0.5), (n, 2)) ** 2, axis=1)


def no_bias(n: int) -> BiasIntervals:
    """Rows whose bias is measured as zero (for tests of the other rules)."""
    zero = np.zeros(n)
    return BiasIntervals(mean_m=np.zeros((n, 2)), low_m=zero, high_m=zero, bound_m=np.ones(n))


def axes_at_one(n: int) -> AxisEfficiencies:
    """Rows efficient along both axes of the bound."""
    return AxisEfficiencies(
        efficiency=np.ones((n, 2)), low=np.full((n, 2), 0.95), high=np.full((n, 2), 1.05)
    )


@pytest.mark.parametrize("n", [50, 100, 200, 500, 1000, 5000])
@pytest.mark.parametrize("seed", range(5))
def test_two_percent_outliers_at_1e4_times_the_bound_never_attain(n: int, seed: int) -> None:
    """2% of the trials 1e4 √CRLB away: the RMSE is about 1400 √CRLB, never 'attains'.
    With few outliers the interval is unbounded above (inconclusive); with many, wholly above."""
    rng = np.random.default_rng(seed)
    errors = efficient_errors(n, rng)
    outliers = rng.choice(n, size=round(0.02 * n), replace=False)
    errors[outliers] = 1e4 * rng.choice([-1.0, 1.0], size=(len(outliers), 1)) * [0.6, 0.8]
    verdict = verdict_of(errors, seed=seed)
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
    errors = efficient_errors(10, np.random.default_rng(seed))
    assert verdict_of(errors, seed=seed) == "inconclusive"
    _, reasons = efficiency_verdicts(
        n_judged=[10],
        n_trials=[10],
        efficiency=[1.0],
        low=[0.9],
        high=[1.1],
        tail=[0.1],
        bias=no_bias(1),
        axes=axes_at_one(1),
    )
    assert reasons[0].startswith(f"too few trials: 10 < {MIN_TRIALS}")


@pytest.mark.parametrize("seed", range(5))
def test_an_efficient_sample_of_1000_attains(seed: int) -> None:
    errors = efficient_errors(1000, np.random.default_rng(seed))
    assert verdict_of(errors, seed=seed) == "attains"


def test_biased_and_inefficient_samples_are_below_and_above() -> None:
    rng = np.random.default_rng(3)
    assert verdict_of(1.5 * efficient_errors(1000, rng)) == "above"
    # efficiency 1.08: its interval straddles 1.1 at n = 500
    assert verdict_of(1.08 * efficient_errors(500, rng), seed=2) == "inconclusive"
    # below the bound along both axes: only a biased estimator can be, and it says so
    verdict, reason = verdicts_of(0.7 * efficient_errors(1000, rng))
    assert verdict == "biased"
    assert "along the CRLB's major axis its RMSE is 0.7" in reason


def test_a_biased_estimator_at_the_bound_s_rmse_is_biased_not_attains() -> None:
    """The issue's plug-in: truth + N(0, 0.64 CRLB) + a constant bias of 0.6 √trace(CRLB),
    RMSE exactly √CRLB; the bias along either axis of the bound. Never attains."""
    rng = np.random.default_rng(5)
    for axis in ([1.0, 0.0], [0.0, 1.0]):
        for n in (100, 500, 2000):
            errors = 0.8 * efficient_errors(n, rng) + 0.6 * np.asarray(axis)
            verdict, reason = verdicts_of(errors)
            assert verdict == "biased", reason
            assert reason.startswith("bias 0.")
            assert "beyond 0.3 √CRLB" in reason


def test_a_row_wholly_below_the_bound_along_one_axis_is_biased() -> None:
    """A linear LS that returns a point on the track: no cross-track error at all, 1.1 times
    the bound along the track; its trace efficiency (0.98, in the band) says nothing, the axis
    test does. With 1.4 times along the track the row is above the bound, bias noted."""
    rng = np.random.default_rng(6)
    errors = efficient_errors(500, rng)
    errors[:, 1] = 0.0  # across: a constant, below what any unbiased estimator reaches
    verdict, reason = verdicts_of(errors * [1.1, 1.0])
    assert verdict == "biased"
    assert "minor axis its RMSE is 0 of the bound's" in reason
    verdict, reason = verdicts_of(errors * [1.4, 1.0])
    assert verdict == "above"
    assert "; also along the CRLB's minor axis its RMSE is 0" in reason


def test_above_along_one_axis_is_above_even_with_the_trace_in_the_band() -> None:
    """A curved likelihood valley (ml on `paper`): the bound is thin across the valley, where
    the error is 3 times the bound's, and a little under it along; the trace efficiency is 1,
    but the estimator does not attain the bound."""
    rng = np.random.default_rng(8)
    crlb = np.diag([0.98, 0.02])
    errors = rng.normal(size=(1000, 2)) * np.sqrt(np.diag(crlb))
    errors[:, 1] *= 3.0
    errors[:, 0] *= math.sqrt((1.0 - 0.02 * 9.0) / 0.98)
    verdict, reason = verdicts_of(errors, crlb_m2=crlb)
    assert verdict == "above"
    assert "along the CRLB's minor axis its RMSE is 3" in reason
    assert "though its efficiency 1" in reason


def test_a_bias_within_its_interval_of_the_limit_is_inconclusive_not_attains() -> None:
    """A bias of 0.25 √CRLB along the major axis: with 100 trials its interval reaches past
    0.3; with 20,000 it does not, and the row attains."""
    rng = np.random.default_rng(9)
    bias = 0.25 * np.array([1.0, 0.0])
    few, reason = verdicts_of(0.97 * efficient_errors(100, rng) + bias)
    assert few == "inconclusive"
    assert "may reach past 0.3 √CRLB" in reason
    many, reason = verdicts_of(0.97 * efficient_errors(20_000, rng) + bias)
    assert many == "attains", reason


def test_bias_interval_covers_the_true_bias_at_least_95_percent_of_the_time() -> None:
    """Hotelling's region, widened to a circle: coverage of ‖b‖ over 2,000 samples of 50."""
    rng = np.random.default_rng(10)
    truth = np.array([0.3, -0.2])
    n_groups, n = 2000, 50
    errors = efficient_errors(n_groups * n, rng) + truth
    groups = np.repeat(np.arange(n_groups), n)
    bias = bias_intervals(errors, groups, n_groups, np.ones(n_groups))
    norm = float(np.hypot(*truth))
    covered = (bias.low_m <= norm) & (norm <= bias.high_m)
    assert 0.95 <= covered.mean() <= 1.0
    # the mean error itself, to rounding
    expected = errors.reshape(n_groups, n, 2).mean(axis=1)
    np.testing.assert_allclose(bias.mean_m, expected, rtol=1e-12, atol=1e-15)


def test_axis_squared_errors_are_the_projections_on_the_principal_axes() -> None:
    """Brute force: for a rotated bound, each error's projection on the eigenvectors."""
    angle = 0.3
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    crlb = rotation @ np.diag([4.0, 0.25]) @ rotation.T
    errors = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, -1.0]])
    got = axis_squared_errors(errors, np.broadcast_to(crlb, (3, 2, 2)))
    expected = np.stack(
        [(errors @ rotation[:, 0]) ** 2 / 4.0, (errors @ rotation[:, 1]) ** 2 / 0.25], axis=1
    )
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert np.isnan(axis_squared_errors(errors[:1], np.full((1, 2, 2), np.nan))).all()


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


def one_group_at_a_time(values, groups, n_groups, *, rng, pairs, n_bootstrap, confidence=0.95):
    """The bootstrap-t interval as its docstring defines the draws, one group after another:
    key seeds from ``rng`` in ascending key order, ``U`` of shape ``(n_bootstrap, size)`` per
    key, a group of ``n`` values resampling ``⌊n U[:, :n]⌋``."""
    values = np.asarray(values, dtype=float)
    keep = np.isfinite(values)
    values, groups = values[keep], np.asarray(groups)[keep]
    order = np.argsort(groups, kind="stable")
    values, groups = values[order], groups[order]
    counts = np.bincount(groups, minlength=n_groups)
    starts = np.cumsum(counts) - counts
    keys = np.arange(n_groups) if pairs is None else np.asarray(pairs)
    alpha = 1 - confidence
    k_low = math.floor(alpha / 2 * n_bootstrap)
    k_high = min(math.ceil((1 - alpha / 2) * n_bootstrap) - 1, n_bootstrap - 1)
    low, high = np.full(n_groups, np.nan), np.full(n_groups, np.nan)
    unique = np.unique(keys)
    for key, seed in zip(unique, rng.integers(0, 2**63, size=unique.size), strict=True):
        members = np.flatnonzero((keys == key) & (counts >= 2))
        if members.size == 0:
            continue
        uniform = np.random.default_rng(int(seed)).random((n_bootstrap, counts[members].max()))
        for group in members:
            n = int(counts[group])
            sample = values[starts[group] : starts[group] + n]
            mean = float(sample.mean())
            deviation = sample - mean
            se = math.sqrt(float(deviation @ deviation) / (n - 1) / n)
            resampled = deviation[(uniform[:, :n] * n).astype(np.int64)]
            s1 = resampled.sum(axis=1)
            shift = s1 / n
            s2 = np.einsum("ij,ij->i", resampled, resampled)
            se_star = np.sqrt(np.maximum(s2 - s1 * shift, 0.0) / (n - 1) / n)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(se_star > 0, shift / se_star, np.sign(shift) * np.inf)
            t = np.sort(np.where(np.isnan(t), 0.0, t))
            with np.errstate(invalid="ignore"):
                low[group] = max(mean - t[k_high] * se, 0.0)
                upper = mean - t[k_low] * se
            high[group] = np.inf if np.isnan(upper) else upper
    return low, high


@pytest.mark.parametrize(
    ("threads", "max_draws", "block_draws"),
    [(1, 2**24, 2**19), (2, 2**24, 2**19), (2, 2**24, 5000), (1, 700, 2**19)],
)
def test_blocks_threads_and_chunks_give_the_numbers_of_one_group_at_a_time(
    monkeypatch, threads, max_draws, block_draws
) -> None:
    """Bit for bit: the blocks of keys, the threads and the rows of draws worked at a time
    change nothing (groups of 0 to 150 values, NaNs, constant groups, shared keys)."""
    monkeypatch.setattr(intervals_module, "BLOCK_DRAWS", block_draws)
    rng = np.random.default_rng(12)
    n_groups = 60
    counts = rng.integers(0, 150, size=n_groups)
    counts[:6] = [0, 1, 2, 3, 150, 150]
    groups = rng.permutation(np.repeat(np.arange(n_groups), counts))
    values = rng.exponential(size=groups.size) ** 3
    values[rng.random(groups.size) < 0.03] = np.nan
    values[groups == 5] = 2.0  # a constant group: se = 0
    pairs = np.arange(n_groups) // 3  # three estimators on the same trials
    for keys in (pairs, None):
        got = studentized_bootstrap_interval(
            values,
            groups,
            n_groups,
            rng=np.random.default_rng(3),
            pairs=keys,
            n_bootstrap=300,
            max_draws=max_draws,
            threads=threads,
        )
        expected = one_group_at_a_time(
            values, groups, n_groups, rng=np.random.default_rng(3), pairs=keys, n_bootstrap=300
        )
        for mine, theirs in zip(got, expected, strict=True):
            assert np.array_equal(mine, theirs, equal_nan=True)


def test_failures_and_heavy_tails_block_attains_and_say_why() -> None:
    verdicts, reasons = efficiency_verdicts(
        n_judged=[490, 500, 500],
        n_trials=[500, 500, 500],
        efficiency=[1.0, 1.0, 1.0],
        low=[0.95, 0.95, 0.95],
        high=[1.05, 1.05, 1.05],
        tail=[0.06, 0.40, 0.06],
        bias=no_bias(3),
        axes=axes_at_one(3),
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
