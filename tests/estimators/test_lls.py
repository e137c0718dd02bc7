"""LLS-ToA and LLS-RSS baselines (MATH §9): exact on noise-free data, rank diagnostics, CRLB."""

from __future__ import annotations

import numpy as np
import pytest

from comparison.crlb import fisher_information, rmse_bound_m
from estimators.baselines.lls import (
    LlsRss,
    LlsToa,
    rss_bias_factor,
    rss_squared_distance_m2,
    solve_lls_rss,
    solve_lls_toa,
)
from estimators.registry import make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import RssModel


def _exact_rss_with_bias(scenario_name: str, snr_db: float):
    """Noise-free data whose raw squared distances carry exactly the bias factor F.

    The de-biasing divides ``d̂²`` by ``F``; lowering every power by ``5η log10 F`` multiplies the
    raw ``d̂²`` by ``F``, so the de-biased distances are exact.
    """
    scenario = get_scenario(scenario_name)
    data = noise_free(scenario, snr_db=snr_db)
    eta = data.rss_model.path_loss_exponent
    factor = rss_bias_factor(data.noise.rss_db, eta)
    shifted = data.rss_dbm - 5.0 * eta * np.log10(factor)
    return scenario, data, shifted, factor


# --------------------------------------------------------------------------------------------
# LLS-ToA
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["turn", "orbit"])
def test_lls_toa_noise_free_is_exact_with_two_headings(name):
    scenario = get_scenario(name)
    estimate = LlsToa().estimate(noise_free(scenario))
    assert estimate.success
    assert not estimate.ambiguous
    assert estimate.diagnostics["rank"] == 3
    assert estimate.message == ""
    np.testing.assert_allclose(estimate.position_m, scenario.emitter_m, atol=1e-8)
    assert estimate.diagnostics["cost_m4"] < 1e-12


def test_lls_toa_straight_track_is_rank_two_minimum_norm_on_the_track():
    # noise-free: the along-track coordinate is exact (35 m); min-norm puts y on the track (0)
    estimate = LlsToa().estimate(noise_free(get_scenario("paper-1m")))
    assert estimate.success
    assert estimate.diagnostics["rank"] == 2
    assert estimate.diagnostics["rank_deficient"]
    assert "rank-deficient" in estimate.message
    assert estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [[35.0, 0.0]], atol=1e-9)


def test_lls_toa_straight_track_noisy_does_not_raise():
    data = simulate(get_scenario("paper-10m"), snr_db=-10.0, seed=7)
    estimate = LlsToa().estimate(data)
    assert estimate.success
    assert estimate.diagnostics["rank"] == 2
    assert np.all(np.isfinite(estimate.position_m))


def test_lls_toa_frames_last_uses_the_straight_last_frame():
    data = noise_free(get_scenario("turn"))
    estimate = LlsToa(frames="last").estimate(data)
    assert estimate.diagnostics["rank"] == 2
    assert estimate.diagnostics["n_samples"] == 10
    # the second frame flies north along x = 5 m: along-track y exact, x on the track
    track_x = data.position_m[-1, 0]
    assert track_x == pytest.approx(5.0)
    np.testing.assert_allclose(estimate.candidates_m, [[track_x, 15.0]], atol=1e-9)


def test_solve_lls_toa_is_unit_invariant():
    data = noise_free(get_scenario("orbit"))
    rng = np.random.default_rng(3)
    ranges = data.range_m + rng.normal(0.0, 1.0, data.n_samples)
    metres = solve_lls_toa(data.position_m, ranges, 0.0)
    km = solve_lls_toa(data.position_m / 1e3, ranges / 1e3, 0.0)
    np.testing.assert_allclose(km.position_m * 1e3, metres.position_m, rtol=1e-10)


def test_lls_toa_requires_toa():
    data = noise_free(get_scenario("orbit")).without("toa")
    with pytest.raises(ValueError, match=r"^toa_s: estimator 'lls-toa'"):
        LlsToa().estimate(data)


def test_lls_options_are_validated():
    with pytest.raises(ValueError, match=r"^frames:"):
        LlsToa(frames="first")
    with pytest.raises(ValueError, match=r"^reference:"):
        LlsRss(reference="weakest")


def test_registry_builds_the_baselines():
    assert isinstance(make_estimator("lls-toa"), LlsToa)
    assert make_estimator("lls-rss", reference="mean").reference == "mean"


@pytest.mark.slow
def test_lls_toa_on_orbit_is_near_the_toa_crlb():
    scenario = get_scenario("orbit")
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(20260, 300))
    estimator = LlsToa()
    errors = np.array([estimator.estimate(d).position_m for d in batch]) - scenario.emitter_m
    rmse = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
    bound = rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m, "toa"))
    # lower limit: four Monte Carlo standard errors of an RMSE (1/√(2n) relative) below the bound
    assert (1.0 - 4.0 / np.sqrt(2 * len(batch))) * bound <= rmse <= 1.5 * bound


# --------------------------------------------------------------------------------------------
# LLS-RSS
# --------------------------------------------------------------------------------------------


def test_rss_squared_distance_is_unbiased():
    model = RssModel(reference_power_dbm=-30.0, reference_distance_m=2.0, path_loss_exponent=3.0)
    distance_m, sigma_db, n = 40.0, 6.0, 400_000
    power = model.reference_power_dbm - 30.0 * np.log10(distance_m / 2.0)
    noise = np.random.default_rng(11).normal(0.0, sigma_db, n)
    squared = rss_squared_distance_m2(power + noise, model, sigma_db)
    # log-normal: relative standard deviation of one draw is sqrt(F² − 1), F = bias factor
    factor = rss_bias_factor(sigma_db, 3.0)
    standard_error = distance_m**2 * np.sqrt(factor**2 - 1.0) / np.sqrt(n)
    assert abs(squared.mean() - distance_m**2) < 4.0 * standard_error
    assert factor == pytest.approx(np.exp(0.5 * (sigma_db * np.log(10.0) / 15.0) ** 2))


@pytest.mark.parametrize("reference", ["strongest", "mean"])
@pytest.mark.parametrize("name", ["turn", "orbit"])
def test_lls_rss_noise_free_is_exact_with_the_bias_factor(name, reference):
    scenario, data, shifted, factor = _exact_rss_with_bias(name, snr_db=0.0)
    assert factor > 1.5  # σ_P = 4 dB, η = 2: a real correction
    solution, _ = solve_lls_rss(
        data.position_m, shifted, data.rss_model, data.noise.rss_db, reference=reference
    )
    assert solution.rank == 2
    np.testing.assert_allclose(solution.position_m, scenario.emitter_m, atol=1e-8)


@pytest.mark.parametrize("name", ["turn", "orbit"])
def test_lls_rss_estimator_noise_free_at_tiny_sigma_is_exact(name):
    scenario = get_scenario(name)
    estimate = LlsRss().estimate(noise_free(scenario, snr_db=300.0))  # σ_P = 4e-15 dB
    assert estimate.success
    assert not estimate.ambiguous
    assert estimate.diagnostics["rank"] == 2
    np.testing.assert_allclose(estimate.position_m, scenario.emitter_m, atol=1e-8)


def test_lls_rss_uses_the_strongest_sample_as_reference():
    data = noise_free(get_scenario("paper-1m"), snr_db=300.0)
    estimate = LlsRss().estimate(data)
    distances = np.linalg.norm(data.position_m - [35.0, 15.0, 0.0], axis=1)
    assert estimate.diagnostics["reference_sample"] == int(np.argmin(distances))


def test_lls_rss_straight_track_is_rank_one():
    estimate = LlsRss().estimate(noise_free(get_scenario("paper-1m"), snr_db=300.0))
    assert estimate.success
    assert estimate.diagnostics["rank"] == 1
    assert "rank-deficient" in estimate.message
    assert estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [[35.0, 0.0]], atol=1e-8)
    noisy = LlsRss().estimate(simulate(get_scenario("paper-1m"), snr_db=-10.0, seed=2))
    assert noisy.diagnostics["rank"] == 1
    assert np.all(np.isfinite(noisy.position_m))


def test_lls_rss_needs_two_samples_and_rss():
    data = noise_free(get_scenario("paper-1m"))
    with pytest.raises(ValueError, match=r"^position_m: every sample is at one horizontal point"):
        LlsRss().estimate(data.take(np.arange(data.n_samples) == 0))
    with pytest.raises(ValueError, match=r"^rss_dbm: estimator 'lls-rss'"):
        LlsRss().estimate(data.without("rss"))


@pytest.mark.slow
def test_lls_rss_mean_reference_on_orbit_is_near_the_rss_crlb():
    scenario = get_scenario("orbit")
    batch = simulate_trials(scenario, snr_db=20.0, seeds=trial_seeds(20261, 300))
    estimator = LlsRss(reference="mean")
    errors = np.array([estimator.estimate(d).position_m for d in batch]) - scenario.emitter_m
    rmse = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
    bound = rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m, "rss"))
    # lower limit: four Monte Carlo standard errors of an RMSE (1/√(2n) relative) below the bound
    assert (1.0 - 4.0 / np.sqrt(2 * len(batch))) * bound <= rmse <= 1.5 * bound


# --------------------------------------------------------------------------------------------
# every trial at once: one trial is the batch of one
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario_name", ["turn", "paper-1m", "orbit"])
def test_lls_solutions_equal_numpy_lstsq_trial_by_trial(scenario_name):
    """The stacked SVD's minimum-norm solutions are ``numpy.linalg.lstsq``'s (LAPACK gelsd,
    another path) on each trial's rows in its local frame, to rounding, ranks equal."""
    from estimators.baselines.lls import RANK_RTOL, lls_toa_columns

    batch = simulate_trials(get_scenario(scenario_name), snr_db=10.0, seeds=trial_seeds(5, 40))
    geometry = batch.geometry
    ranges = geometry.speed_of_light_mps * batch.toa_s
    solved = lls_toa_columns(geometry.position_m, ranges, geometry.emitter_height_m)
    for i in range(40):
        scale, origin = solved.scale_m[i], solved.origin_m
        x, y = ((geometry.position_m[:, :2] - origin) / scale).T
        dz = (geometry.position_m[:, 2] - geometry.emitter_height_m) / scale
        A = np.column_stack([-2 * x, -2 * y, np.ones_like(x)])
        b = (ranges[i] / scale) ** 2 - x**2 - y**2 - dz**2
        reference, _, rank, singular = np.linalg.lstsq(A, b, rcond=RANK_RTOL)
        assert solved.rank[i] == rank
        tolerance = 1e-9 * singular[0] / singular[rank - 1] * (1.0 + np.abs(reference).max())
        np.testing.assert_allclose(
            (solved.position_m[i] - origin) / scale, reference[:2], rtol=0.0, atol=tolerance
        )


@pytest.mark.bits("one trial and a batch's row run the same code on the same arrays")
@pytest.mark.parametrize("estimator", [LlsToa(), LlsRss(), LlsRss(reference="mean")], ids=repr)
@pytest.mark.parametrize("scenario_name", ["turn", "paper-1m"])
def test_estimate_is_the_batchs_row(estimator, scenario_name):
    batch = simulate_trials(get_scenario(scenario_name), snr_db=0.0, seeds=trial_seeds(6, 30))
    rngs = [np.random.default_rng(i) for i in range(30)]
    columns = estimator.estimate_columns(batch, rngs=rngs)
    again = [np.random.default_rng(i) for i in range(30)]
    for i in range(30):
        single, row = estimator.estimate(batch.trial(i), rng=again[i]), columns.estimate(i)
        np.testing.assert_array_equal(single.position_m, row.position_m)
        np.testing.assert_array_equal(single.candidates_m, row.candidates_m)
        assert (single.message, single.ambiguous) == (row.message, row.ambiguous)
        np.testing.assert_equal(single.diagnostics, row.diagnostics)
    assert [r.bit_generator.state for r in rngs] == [r.bit_generator.state for r in again]
