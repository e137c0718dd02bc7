"""Seeded simulation (MATH §1-§2): reproducible, batch-size independent, the right noise."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds

FIELDS = ("doppler_hz", "toa_s", "rss_dbm")


def test_noise_free_values_are_the_forward_model() -> None:
    scenario = get_scenario("turn")
    data = noise_free(scenario, snr_db=10.0)
    flight = scenario.flight
    np.testing.assert_array_equal(data.position_m, flight.sample_positions_m())
    np.testing.assert_array_equal(data.frame, flight.sample_frames())
    np.testing.assert_array_equal(
        data.toa_s, model.toa_s(data.position_m, scenario.emitter_m, scenario.speed_of_light_mps)
    )
    np.testing.assert_array_equal(
        data.doppler_hz,
        model.doppler_hz(data.position_m, data.velocity_mps, scenario.emitter_m, 1.0),
    )
    np.testing.assert_array_equal(data.truth_emitter_m, [35.0, 15.0])
    assert data.noise.toa_s == pytest.approx(scenario.noise.toa_s / np.sqrt(10.0), rel=1e-15)


def test_same_seed_gives_identical_arrays_and_another_seed_does_not() -> None:
    scenario = get_scenario("paper-1m")
    first = simulate(scenario, snr_db=5.0, seed=42)
    again = simulate(scenario, snr_db=5.0, seed=42)
    other = simulate(scenario, snr_db=5.0, seed=43)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
        assert not np.any(getattr(first, name) == getattr(other, name)), name


def test_trial_i_is_independent_of_the_batch_size() -> None:
    """Trial i is driven by child i of ``SeedSequence(seed)`` whatever the batch."""
    scenario = get_scenario("orbit")
    small = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(9, 3))
    large = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(9, 8))
    children = np.random.SeedSequence(9).spawn(8)
    for index in range(3):
        alone = simulate(scenario, snr_db=0.0, seed=children[index])
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(small, name)[index], getattr(large, name)[index])
            np.testing.assert_array_equal(getattr(small, name)[index], getattr(alone, name))


def test_modality_subsets_share_the_same_noise() -> None:
    """Common random numbers: dropping RSS changes neither the Doppler nor the ToA draws."""
    scenario = get_scenario("paper-1m")
    full = simulate(scenario, snr_db=0.0, seed=7)
    toa_doppler = simulate(scenario.replace(modalities=("toa", "doppler")), snr_db=0.0, seed=7)
    assert toa_doppler.rss_dbm is None
    np.testing.assert_array_equal(full.toa_s, toa_doppler.toa_s)
    np.testing.assert_array_equal(full.doppler_hz, toa_doppler.doppler_hz)


@pytest.mark.parametrize("snr_db", [-10.0, 0.0, 17.0])
def test_noise_standard_deviation_follows_the_snr_axis(snr_db: float) -> None:
    """Sample std of 1000 trials × 120 samples is ``σ · 10^(−snr/20)`` within 1.5 % (the
    standard error of a std from n = 120 000 draws is 0.2 %); means are zero, modalities
    uncorrelated."""
    scenario = get_scenario("orbit")
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(1, 1000))
    exact = noise_free(scenario, snr_db=snr_db)
    factor = 10.0 ** (-snr_db / 20.0)
    residuals = {}
    for name, modality in zip(FIELDS, ("doppler", "toa", "rss"), strict=True):
        sigma = scenario.noise.for_modality(modality) * factor
        residual = (getattr(batch, name) - getattr(exact, name)) / sigma
        residuals[name] = residual.ravel()
        n = residual.size
        assert abs(residual.mean()) < 5.0 / np.sqrt(n), name
        assert residual.std() == pytest.approx(1.0, abs=0.015), name
        assert batch.geometry.noise.for_modality(modality) == pytest.approx(sigma, rel=1e-15)
    correlation = np.corrcoef(np.stack(list(residuals.values())))
    np.testing.assert_allclose(correlation, np.eye(3), atol=5.0 / np.sqrt(n))


def test_empty_seed_list_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"^seeds:"):
        simulate_trials(get_scenario("paper"), snr_db=0.0, seeds=[])
