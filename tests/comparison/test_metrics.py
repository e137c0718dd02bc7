"""Metrics on synthetic trial rows whose answers are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from comparison.metrics import (
    CONTRACT_METRIC_NAMES,
    METRIC_NAMES,
    attainment_status,
    bootstrap_rmse_interval,
    crlb_attainment,
    format_number,
    nees_band,
    summarize,
)

TRUTH_M = np.array([35.0, 15.0])


def trial_rows(
    errors_m: np.ndarray,
    *,
    estimator: str = "est",
    scenario: str = "paper-1m",
    point: int = 0,
    snr_db: float = 0.0,
    crlb_rmse_m: float = 1.0,
    success: np.ndarray | None = None,
    ambiguous: bool = False,
    covariance_m2: np.ndarray | None = None,
) -> pd.DataFrame:
    """Contract rows for the errors ``(n, 2)`` of the returned position (truth at (35, 15)).

    Ambiguous rows carry the mirror image across the track y = 0 as a second candidate.
    """
    n = len(errors_m)
    ok = np.ones(n, dtype=bool) if success is None else success
    position = TRUTH_M + errors_m
    mirror = position * [1.0, -1.0]
    error = np.linalg.norm(errors_m, axis=1)
    side = np.minimum(error, np.linalg.norm(mirror - TRUTH_M, axis=1)) if ambiguous else error
    if covariance_m2 is None:
        nees = np.full(n, np.nan)
        cov = np.full((n, 3), np.nan)
    else:
        nees = np.einsum("ni,ij,nj->n", errors_m, np.linalg.inv(covariance_m2), errors_m)
        cov = np.tile(covariance_m2.ravel()[[0, 1, 3]], (n, 1))

    def masked(values: np.ndarray) -> np.ndarray:
        return np.where(ok, values, np.nan)

    return pd.DataFrame(
        {
            "experiment": "synthetic",
            "scenario": scenario,
            "point": point,
            "snr_db": snr_db,
            "estimator": estimator,
            "frame": 0,
            "trial": np.arange(n),
            "truth_x_m": TRUTH_M[0],
            "truth_y_m": TRUTH_M[1],
            "x_m": masked(position[:, 0]),
            "y_m": masked(position[:, 1]),
            "error_m": masked(error),
            "error_side_resolved_m": masked(side),
            "wrong_side": masked((position[:, 1] < 0).astype(float)),
            "ambiguous": ok & ambiguous,
            "success": ok,
            "n_candidates": np.where(ok, 2 if ambiguous else 1, 0),
            "candidates_json": "[]",
            "cov_xx_m2": masked(cov[:, 0]),
            "cov_xy_m2": masked(cov[:, 1]),
            "cov_yy_m2": masked(cov[:, 2]),
            "nees": masked(nees),
            "crlb_rmse_m": crlb_rmse_m,
            "runtime_s": np.linspace(1e-3, 3e-3, n),
            "message": "",
            "diagnostics_json": "{}",
        }
    )


def test_columns_follow_the_contract_order():
    rows = trial_rows(np.zeros((4, 2)))
    rows.insert(4, "range_sigma_m", 1.0)
    summary = summarize(rows, n_bootstrap=10)
    assert list(summary.columns) == [
        "scenario",
        "snr_db",
        "range_sigma_m",
        "frame",
        "estimator",
        *METRIC_NAMES,
    ]
    assert list(METRIC_NAMES[: len(CONTRACT_METRIC_NAMES)]) == list(CONTRACT_METRIC_NAMES)


def test_gaussian_errors_give_their_rmse_cep_and_bias():
    rng = np.random.default_rng(11)
    sigma_m, n = 2.0, 10_000
    bias_m = np.array([0.5, -0.3])
    unbiased = rng.normal(0.0, sigma_m, (n, 2))
    biased = bias_m + rng.normal(0.0, sigma_m, (n, 2))
    rows = pd.concat(
        [
            trial_rows(unbiased, estimator="unbiased", crlb_rmse_m=sigma_m * math.sqrt(2)),
            trial_rows(biased, estimator="biased", crlb_rmse_m=sigma_m * math.sqrt(2)),
        ]
    )
    summary = summarize(rows, n_bootstrap=50).set_index("estimator")

    # Exact sample statistics of the rows.
    radial = np.linalg.norm(unbiased, axis=1)
    assert summary.loc["unbiased", "rmse_m"] == pytest.approx(np.sqrt(np.mean(radial**2)))
    assert summary.loc["unbiased", "mean_error_m"] == pytest.approx(radial.mean())
    assert summary.loc["unbiased", "cep50_m"] == pytest.approx(np.median(radial))
    assert summary.loc["unbiased", "p95_error_m"] == pytest.approx(np.quantile(radial, 0.95))
    assert summary.loc["biased", "bias_x_m"] == pytest.approx(biased[:, 0].mean())
    assert summary.loc["biased", "bias_y_m"] == pytest.approx(biased[:, 1].mean())

    # The population values, within Monte Carlo error (relative sd about 0.5% at n = 10 000).
    assert summary.loc["unbiased", "rmse_m"] == pytest.approx(sigma_m * math.sqrt(2), rel=0.02)
    assert summary.loc["unbiased", "cep50_m"] == pytest.approx(
        sigma_m * math.sqrt(2 * math.log(2)), rel=0.02
    )  # Rayleigh median
    assert summary.loc["unbiased", "mean_error_m"] == pytest.approx(
        sigma_m * math.sqrt(math.pi / 2), rel=0.02
    )  # Rayleigh mean: the paper's "accuracy"
    assert summary.loc["unbiased", "efficiency"] == pytest.approx(1.0, rel=0.02)
    assert summary.loc["biased", "rmse_m"] == pytest.approx(
        math.sqrt(2 * sigma_m**2 + bias_m @ bias_m), rel=0.02
    )
    assert summary.loc["biased", "bias_x_m"] == pytest.approx(0.5, abs=0.05)
    assert summary.loc["biased", "bias_y_m"] == pytest.approx(-0.3, abs=0.05)
    assert summary.loc["unbiased", "runtime_median_s"] == pytest.approx(2e-3)


def test_rates_are_exact_on_constructed_rows():
    # Ten trials: two failures, three of the eight successes on the wrong side (y < 0).
    errors = np.zeros((10, 2))
    errors[[0, 1, 2], 1] = -30.0  # returned at y = -15: the mirror image, wrong side
    errors[3:, 0] = 1.0
    success = np.array([True] * 8 + [False] * 2)
    rows = trial_rows(errors, success=success, ambiguous=True, crlb_rmse_m=0.5)
    row = summarize(rows, n_bootstrap=50).iloc[0]
    assert row["n_trials"] == 10
    assert row["n_successes"] == 8
    assert row["success_rate"] == 0.8
    assert row["wrong_side_rate"] == 3 / 8
    assert row["ambiguous_rate"] == 1.0
    # Returned errors: 30 m three times and 1 m five times; side-resolved: 0 and 1 m.
    assert row["rmse_m"] == pytest.approx(math.sqrt((3 * 900 + 5) / 8))
    assert row["mean_error_m"] == pytest.approx((90 + 5) / 8)
    assert row["rmse_side_resolved_m"] == pytest.approx(math.sqrt(5 / 8))
    assert row["efficiency"] == pytest.approx(math.sqrt((3 * 900 + 5) / 8) / 0.5)
    assert row["efficiency_side_resolved"] == pytest.approx(math.sqrt(5 / 8) / 0.5)
    assert row["nees_mean"] != row["nees_mean"]  # NaN: no covariance given
    assert row["n_nees"] == 0


def test_bootstrap_interval_covers_the_true_rmse_about_95_percent_of_the_time():
    rng = np.random.default_rng(5)
    sigma_m, n, replications = 1.0, 100, 300
    rows = pd.concat(
        [
            trial_rows(rng.normal(0, sigma_m, (n, 2)), point=i, snr_db=float(i))
            for i in range(replications)
        ]
    )
    summary = summarize(rows, n_bootstrap=1000, seed=1)
    true_rmse = sigma_m * math.sqrt(2)
    covered = (summary["rmse_ci_low_m"] <= true_rmse) & (true_rmse <= summary["rmse_ci_high_m"])
    assert 0.90 <= covered.mean() <= 0.99
    assert (summary["rmse_ci_low_m"] <= summary["rmse_m"]).all()
    assert (summary["rmse_m"] <= summary["rmse_ci_high_m"]).all()
    # Width about 2·1.96·RMSE/(2√n) for 2-D Gaussian errors: 0.277 m here.
    width = (summary["rmse_ci_high_m"] - summary["rmse_ci_low_m"]).mean()
    assert width == pytest.approx(1.96 * true_rmse / math.sqrt(n), rel=0.1)


def test_bootstrap_blocks_skip_failed_groups_and_keep_constant_ones_exact():
    # Groups: 0 all failed (NaN), 1 constant errors of 2 m, 2 empty, 3 spread errors.
    squared = np.array([np.nan, np.nan, 4.0, 4.0, 4.0, 1.0, 9.0, 25.0, 1.0])
    groups = np.array([0, 0, 1, 1, 1, 3, 3, 3, 3])
    for max_draws in (8, 2**22):  # several blocks, or one
        low, high = bootstrap_rmse_interval(
            squared, groups, 4, n_bootstrap=400, rng=np.random.default_rng(0), max_draws=max_draws
        )
        assert np.isnan(low[[0, 2]]).all() and np.isnan(high[[0, 2]]).all()
        assert (low[1], high[1]) == (2.0, 2.0)
        # Resampled RMSEs of {1, 3, 5, 1} m lie in [1, 5] m and the interval brackets √9.
        assert 1.0 <= low[3] < 3.0 < high[3] <= 5.0


def test_bootstrap_is_seeded():
    rows = trial_rows(np.random.default_rng(2).normal(0, 1, (50, 2)))
    first = summarize(rows, n_bootstrap=300, seed=4)
    again = summarize(rows, n_bootstrap=300, seed=4)
    other = summarize(rows, n_bootstrap=300, seed=5)
    assert first["rmse_ci_low_m"].iloc[0] == again["rmse_ci_low_m"].iloc[0]
    assert first["rmse_ci_low_m"].iloc[0] != other["rmse_ci_low_m"].iloc[0]


def test_nees_band_is_the_chi_square_interval_of_the_mean():
    low, high = nees_band(1)
    # χ²(2) has the closed-form quantile −2 ln(1 − p).
    assert low == pytest.approx(-2 * math.log(0.975))
    assert high == pytest.approx(-2 * math.log(0.025))
    low, high = nees_band([50, 400])
    assert low == pytest.approx(stats.chi2.ppf(0.025, [100, 800]) / [50, 400])
    assert high[1] == pytest.approx(2 + 1.96 * 2 / math.sqrt(400), abs=0.01)  # sd of mean 2/√n
    assert np.isnan(nees_band(0)[0])


def test_nees_mean_of_a_consistent_covariance_lies_in_the_band():
    rng = np.random.default_rng(8)
    covariance = np.array([[4.0, 1.0], [1.0, 2.0]])
    errors = rng.multivariate_normal([0.0, 0.0], covariance, size=400)
    consistent = trial_rows(errors, estimator="consistent", covariance_m2=covariance)
    optimistic = trial_rows(errors, estimator="optimistic", covariance_m2=covariance / 2)
    summary = summarize(pd.concat([consistent, optimistic]), n_bootstrap=10)
    summary = summary.set_index("estimator")
    good, bad = summary.loc["consistent"], summary.loc["optimistic"]
    assert good["n_nees"] == 400
    assert good["nees_band_low"] <= good["nees_mean"] <= good["nees_band_high"]
    assert good["nees_mean"] == pytest.approx(2.0, abs=0.25)
    assert bad["nees_mean"] == pytest.approx(2 * good["nees_mean"])
    assert bad["nees_mean"] > bad["nees_band_high"]


def test_bad_input_names_the_field():
    rows = trial_rows(np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"^trials: missing columns \['error_m'\]"):
        summarize(rows.drop(columns="error_m"))
    with pytest.raises(ValueError, match=r"^n_bootstrap:"):
        summarize(rows, n_bootstrap=0)
    with pytest.raises(ValueError, match=r"^trials: the frame has no rows"):
        summarize(rows.iloc[:0])


# --------------------------------------------------------------------------------------------
# attainment
# --------------------------------------------------------------------------------------------


def summary_rows(estimator: str, efficiencies, *, half_width=0.02, side_resolved=None, **extra):
    """Summary rows at SNR -10, 0, 10, 20, 30 dB with √CRLB 1 m and the given RMSE/√CRLB."""
    efficiency = np.asarray(efficiencies, dtype=float)
    side = efficiency if side_resolved is None else np.asarray(side_resolved, dtype=float)
    frame = pd.DataFrame(
        {
            "scenario": "paper-1m",
            "snr_db": [-10.0, 0.0, 10.0, 20.0, 30.0],
            "frame": 0,
            "estimator": estimator,
        }
    )
    for name in METRIC_NAMES:
        frame[name] = np.nan
    frame["crlb_rmse_m"] = 1.0
    frame["success_rate"] = 1.0
    frame["ambiguous_rate"] = 0.0 if side_resolved is None else 1.0
    frame["rmse_m"] = efficiency
    frame["rmse_ci_low_m"] = efficiency * (1 - half_width)
    frame["rmse_ci_high_m"] = efficiency * (1 + half_width)
    frame["efficiency"] = efficiency
    frame["rmse_side_resolved_m"] = side
    frame["rmse_side_resolved_ci_low_m"] = side * (1 - half_width)
    frame["rmse_side_resolved_ci_high_m"] = side * (1 + half_width)
    frame["efficiency_side_resolved"] = side
    for name, value in extra.items():
        frame[name] = value
    return frame


def test_attainment_sentences_are_computed_from_the_rows():
    summary = pd.concat(
        [
            summary_rows("cls", [3.0, 2.9, 2.8, 2.9, 3.0], side_resolved=[1.02, 1.0, 0.99, 1, 1]),
            summary_rows("cls-paper", [3.2, 4.0, 5.0, 6.0, 7.0]),
            summary_rows("lls-toa", [1.01, 1.05, 1.3, 1.5, 1.02]),
            summary_rows("ml", [1.0] * 5, success_rate=[0.9, 1, 1, 1, 1]),
            summary_rows("lls-rss", [0.5, 0.6, 1.3, 1.5, 2.0]),
        ],
        ignore_index=True,
    )
    assert crlb_attainment(summary) == [
        "cls attains the CRLB (side-resolved RMSE) on paper-1m at every point "
        "(SNR from -10 to 30 dB; efficiency 0.99 to 1.02).",
        "cls-paper does not attain the CRLB on paper-1m at any point "
        "(efficiency closest to 1: 3.2 at SNR -10 dB).",
        "lls-toa attains the CRLB on paper-1m at SNR -10 to 0, 30 dB; "
        "not at SNR from 10 to 20 dB (efficiency up to 1.5 at SNR 20 dB).",
        "ml attains the CRLB on paper-1m at SNR from 0 to 30 dB; "
        "too many estimates fail at SNR -10 dB (success rate down to 0.9).",
        "lls-rss does not attain the CRLB on paper-1m at any point "
        "(efficiency closest to 1: 1.3 at SNR 10 dB); above the band at SNR from 10 to 30 dB "
        "(efficiency up to 2 at SNR 30 dB); its RMSE is more than 10% below √CRLB at SNR "
        "from -10 to 0 dB (a biased estimate, which the bound does not cover).",
    ]


def test_monte_carlo_noise_does_not_decide_attainment():
    # Point estimate 1.12 (outside ±10%) but interval [1.05, 1.19] overlaps the band: attains.
    noisy = summary_rows("noisy", [1.12] * 5, half_width=0.0625)
    # Interval [1.12, 1.28] wholly above 1.1: does not. Interval below 0.9: "below".
    above = summary_rows("above", [1.2] * 5, half_width=0.0625)
    below = summary_rows("below", [0.8] * 5, half_width=0.05)
    status = attainment_status(pd.concat([noisy, above, below], ignore_index=True))
    assert status.tolist() == ["attains"] * 5 + ["above"] * 5 + ["below"] * 5


def test_format_number_prints_four_significant_digits():
    assert format_number(0.000104912) == "0.0001049"
    assert format_number(12345.6) == "1.235e+04"
    assert format_number(np.int64(500)) == "500"
    assert format_number(float("nan")) == "NaN"


def test_planners_are_grouped_and_their_bounds_averaged_as_rms():
    rng = np.random.default_rng(5)
    first = trial_rows(rng.normal(0, math.sqrt(0.5), (200, 2)), crlb_rmse_m=1.0)
    first["planner"] = "constant"
    second = trial_rows(rng.normal(0, 2.0, (200, 2)))
    second["planner"] = "fisher"
    second["crlb_rmse_m"] = np.where(np.arange(200) % 2 == 0, 1.0, 3.0)  # per-trial bounds
    summary = summarize(pd.concat([first, second], ignore_index=True), n_bootstrap=10)
    assert list(summary.columns[:5]) == ["scenario", "snr_db", "frame", "planner", "estimator"]
    assert summary["planner"].tolist() == ["constant", "fisher"]
    assert summary["crlb_rmse_m"].tolist() == [1.0, pytest.approx(math.sqrt(5.0))]
    assert summary["rmse_m"].iloc[1] == pytest.approx(
        math.sqrt(np.mean(second["error_m"] ** 2)), rel=1e-12
    )
    sentences = crlb_attainment(summary)
    assert sentences[0].startswith("est (planner constant) attains the CRLB on paper-1m")
    # empty planner labels (an open-loop run) leave the summary as it was
    first["planner"] = ""
    plain = summarize(first, n_bootstrap=10)
    assert "planner" not in plain.columns
    assert plain["crlb_rmse_m"].tolist() == [1.0]
