"""Maximum likelihood with the carrier offset and emission time profiled out (MATH §10, §15)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimators.ml.ml import whitened_residual_jacobian, whitened_residuals
from estimators.registry import make_estimator
from scenarios import get_scenario
from scenarios.fisher import fisher_information, inverse_2x2
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds

OFFSET, EMISSION = "carrier_offset_hz", "emission_time_s"


@pytest.mark.parametrize("name", ["turn-noncooperative", "beacon-pass"])
@pytest.mark.parametrize("unknowns", [(OFFSET,), (EMISSION,), (OFFSET, EMISSION)], ids=str)
def test_noise_free_two_headings_give_the_emitter_and_its_offsets(name, unknowns) -> None:
    scenario = get_scenario(name).replace(unknowns=unknowns)
    estimate = make_estimator("ml").estimate(noise_free(scenario))
    assert estimate.success and not estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [scenario.emitter_m], atol=1e-6)
    if OFFSET in unknowns:
        assert estimate.diagnostics[OFFSET] == pytest.approx(scenario.carrier_offset_hz, abs=1e-6)
    if EMISSION in unknowns:
        assert estimate.diagnostics[EMISSION] == pytest.approx(scenario.emission_time_s, abs=1e-13)


def test_the_profiled_residual_is_the_minimum_over_the_offsets() -> None:
    """At any emitter, the centred residual's cost equals the full residual's cost minimised
    over (δ, b) by brute force, and its Jacobian matches central differences."""
    data = simulate(get_scenario("beacon-pass"), snr_db=0.0, seed=8)
    point = np.array([140.0, 131.0])
    profiled = float(np.sum(whitened_residuals(data, point) ** 2))
    known = data.assuming_known()
    offsets = np.linspace(990.0, 1010.0, 201)
    delays = data.truth_emission_time_s + np.linspace(-2e-7, 2e-7, 201)

    def cost(offset, delay):
        shifted = dataclasses.replace(
            known, doppler_hz=known.doppler_hz - offset, toa_s=known.toa_s - delay
        )
        return float(np.sum(whitened_residuals(shifted, point) ** 2))

    best_offset = min(offsets, key=lambda o: cost(o, delays[100]))
    best = min(cost(best_offset, d) for d in delays)
    assert profiled <= best * (1 + 1e-12)
    assert profiled == pytest.approx(best, rel=1e-3)  # the grid's resolution
    jacobian = whitened_residual_jacobian(data, point)
    for axis in range(2):
        # a step of 1 cm: the ToA residuals hold c·b/σ ~ 4e5 before centring, so a smaller
        # step loses digits to cancellation
        step = np.eye(2)[axis] * 1e-2
        numeric = (
            whitened_residuals(data, point + step) - whitened_residuals(data, point - step)
        ) / 2e-2
        np.testing.assert_allclose(jacobian[:, axis], numeric, rtol=1e-5, atol=1e-8)
    information = jacobian.T @ jacobian
    np.testing.assert_allclose(information, fisher_information(data, point), rtol=1e-10)


@pytest.mark.slow
def test_ml_sample_covariance_matches_the_nuisance_crlb_at_high_snr() -> None:
    """2,000 trials of the beacon pass at 30 dB with both offsets unknown: the sample
    covariance of the ML error against the nuisance CRLB (MATH §15)."""
    scenario = get_scenario("beacon-pass")
    n = 2000
    batch = simulate_trials(scenario, snr_db=30.0, seeds=trial_seeds(15, n))
    ml = make_estimator("ml")
    errors = np.array(
        [ml.estimate(batch.trial(i)).position_m - scenario.emitter_m for i in range(n)]
    )
    bound = inverse_2x2(fisher_information(batch.geometry, scenario.emitter_m))
    known = inverse_2x2(fisher_information(batch.geometry, scenario.emitter_m, unknowns=()))
    assert np.trace(bound) > 3.0 * np.trace(known)  # the unknowns have a price here
    sample = np.cov(errors.T)
    # trace of a sample covariance of n Gaussian draws: relative sd about sqrt(2/n) = 3.2%
    assert np.trace(sample) / np.trace(bound) == pytest.approx(1.0, abs=0.1)
    # NEES against the bound: mean of chi2(2) over n trials, sd 2/sqrt(n) = 0.045
    nees = np.einsum("ni,ij,nj->n", errors, np.linalg.inv(bound), errors)
    assert nees.mean() == pytest.approx(2.0, abs=0.2)
    # the bound's orientation: the sample's principal axis within 5 degrees of the bound's
    sample_axis = np.linalg.eigh(sample)[1][:, -1]
    bound_axis = np.linalg.eigh(bound)[1][:, -1]
    assert abs(sample_axis @ bound_axis) > np.cos(np.radians(5.0))


@pytest.mark.parametrize("name", ["beacon-pass-doppler", "beacon-pass", "turn-noncooperative"])
def test_from_doppler_alone_ml_finds_the_emitter_and_the_carrier_offset(name) -> None:
    """use_toa=False: the grid of profiled-cost minima starts the search (MATH §15)."""
    scenario = get_scenario(name)
    estimate = make_estimator("ml", use_toa=False).estimate(noise_free(scenario))
    assert estimate.success and not estimate.ambiguous
    assert estimate.diagnostics["start_method"] == "doppler-grid"
    np.testing.assert_allclose(estimate.candidates_m, [scenario.emitter_m], atol=1e-6)
    assert estimate.diagnostics[OFFSET] == pytest.approx(scenario.carrier_offset_hz, abs=1e-6)
    assert EMISSION not in estimate.diagnostics  # ToA unused: its offset does not enter


def test_from_doppler_alone_ml_attains_the_doppler_bound() -> None:
    scenario = get_scenario("beacon-pass-doppler")
    batch = simulate_trials(scenario, snr_db=20.0, seeds=trial_seeds(4, 600))
    ml = make_estimator("ml", use_toa=False)
    errors = np.array(
        [ml.estimate(batch.trial(i)).position_m - scenario.emitter_m for i in range(600)]
    )
    bound = inverse_2x2(fisher_information(batch.geometry, scenario.emitter_m, "doppler"))
    rmse = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
    assert rmse / np.sqrt(np.trace(bound)) == pytest.approx(1.0, abs=0.12)  # 600 trials


def test_ml_with_toa_refuses_doppler_only_data_and_says_how() -> None:
    data = noise_free(get_scenario("beacon-pass-doppler"))
    with pytest.raises(ValueError, match=r"toa_s: .*use_toa=False"):
        make_estimator("ml").estimate(data)
