"""``ml`` with a terrain prior (MATH §8, §10): its answer is the MAP, its covariance the
prior-augmented bound.

The residual gains one row, ``(0 − (z_s − h(x_s, y_s)))/σ_m``: checked against the terrain's
functions and by central differences of its Jacobian; with the surface through the emitter the
noise-free answer is the emitter exactly and its covariance the bound of
:func:`scenarios.fisher.fisher_information` at it; on noisy data the answer is the best of a
multi-start search of the same posterior.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from scipy.optimize import least_squares

from estimators.ml.ml import MaximumLikelihood, whitened_residual_jacobian, whitened_residuals
from scenarios import get_scenario
from scenarios.fisher import fisher_information, inverse_symmetric, terrain_row
from scenarios.simulate import noise_free, simulate_trials, trial_seeds
from scenarios.terrain import Terrain, offset_above_surface_m
from scenarios.types import MeasurementSet
from tests.estimators.batch_support import generators
from tests.estimators.test_ml_height import height_unknown
from tests.scenarios.random_flights import random_data


def surface_through_emitter(snr_db: float = 20.0) -> MeasurementSet:
    """``hill-terrain``'s noise-free data with the hill raised 2 m: its surface through the
    emitter, on a slope."""
    data = noise_free(get_scenario("hill-terrain"), snr_db=snr_db)
    terrain = dataclasses.replace(data.terrain, height_m=2.0)
    return dataclasses.replace(data, terrain=terrain)


def cost(data: MeasurementSet, point) -> float:
    return float(np.sum(whitened_residuals(data, point) ** 2))


def best_of_starts(data: MeasurementSet, starts) -> Any:
    """The least ``‖e‖²`` of MINPACK's Levenberg-Marquardt (scipy) from each start."""
    results = [
        least_squares(
            lambda s: whitened_residuals(data, s),
            start,
            jac=lambda s: whitened_residual_jacobian(data, s),
            method="lm",
            xtol=1e-12,
            ftol=1e-12,
        )
        for start in starts
    ]
    return min(results, key=lambda result: result.cost)


def test_the_residual_ends_with_the_prior_and_its_jacobian_is_central_differences() -> None:
    data = noise_free(get_scenario("hill-terrain"), snr_db=0.0)
    bare = dataclasses.replace(data, terrain=None)
    point = data.truth_emitter_m + np.array([6.0, -4.0, 9.0])
    residual = whitened_residuals(data, point)
    np.testing.assert_array_equal(residual[:-1], whitened_residuals(bare, point))
    expected = -offset_above_surface_m(data.terrain, point) / data.terrain.sigma_m
    assert residual[-1] == pytest.approx(expected, rel=1e-14)
    jacobian = whitened_residual_jacobian(data, point)
    step = 1e-4
    numeric = np.stack(
        [
            (
                whitened_residuals(data, point + step * axis)
                - whitened_residuals(data, point - step * axis)
            )
            / (2 * step)
            for axis in np.eye(3)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-6, atol=1e-9 * np.abs(numeric).max())
    np.testing.assert_allclose(jacobian.T @ jacobian, fisher_information(data, point), rtol=1e-12)
    # many emitters at once, as the batch search evaluates them
    points = point + np.array([[0.0, 0.0, 0.0], [20.0, 5.0, -30.0]])
    np.testing.assert_allclose(whitened_residuals(data, points)[0], residual, rtol=1e-14)
    np.testing.assert_allclose(whitened_residual_jacobian(data, points)[0], jacobian, rtol=1e-14)


def test_with_the_height_known_ml_ignores_the_terrain() -> None:
    data = noise_free(get_scenario("hill-terrain"), snr_db=0.0).assuming_known()
    bare = dataclasses.replace(data, terrain=None)
    point = data.truth_emitter_m + np.array([6.0, -4.0])
    np.testing.assert_array_equal(whitened_residuals(data, point), whitened_residuals(bare, point))


@pytest.mark.parametrize("snr_db", [0.0, 20.0])
def test_noise_free_with_the_surface_through_the_emitter_is_exact(snr_db: float) -> None:
    data = surface_through_emitter(snr_db)
    truth = data.truth_emitter_m
    assert offset_above_surface_m(data.terrain, truth) == pytest.approx(0.0, abs=1e-12)
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    scale = float(np.max(np.linalg.norm(data.position_m - truth, axis=1)))
    np.testing.assert_allclose(estimate.position_m, truth, rtol=0, atol=1e-7 * scale)
    assert estimate.candidates_m.shape == (1, 3) and not estimate.ambiguous
    bound = inverse_symmetric(fisher_information(data, truth))
    np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6)
    unaided = inverse_symmetric(fisher_information(dataclasses.replace(data, terrain=None), truth))
    assert np.trace(bound) < np.trace(unaided)


def test_noise_free_hill_terrain_is_the_map_between_the_emitter_and_the_ground() -> None:
    """The tag 2 m above the mapped ground: the noise-free MAP is pulled toward the ground, by
    the prior's share of the vertical information, and is a stationary point of the posterior
    (gradient ``Jᵀe`` zero)."""
    data = noise_free(get_scenario("hill-terrain"), snr_db=0.0)
    truth = data.truth_emitter_m
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    answer = estimate.position_m
    gradient = whitened_residual_jacobian(data, answer).T @ whitened_residuals(data, answer)
    assert np.linalg.norm(gradient) < 1e-6
    assert 0.0 < offset_above_surface_m(data.terrain, answer) < 2.0
    # to first order the MAP moves by −P g (offset/σ_m), P the prior-augmented bound
    bound = inverse_symmetric(fisher_information(data, truth))
    row = fisher_information(data, truth) - fisher_information(
        dataclasses.replace(data, terrain=None), truth
    )
    step = -bound @ row @ np.array([0.0, 0.0, 1.0]) * 2.0
    np.testing.assert_allclose(answer - truth, step, rtol=0.05, atol=1e-3)


def test_noisy_hill_terrain_is_the_best_of_a_multistart_search() -> None:
    scenario = get_scenario("hill-terrain")
    batch = simulate_trials(scenario, snr_db=-10.0, seeds=trial_seeds(23, 6))
    estimator = MaximumLikelihood()
    columns = estimator.estimate_columns(batch, rngs=generators(6))
    rng = np.random.default_rng(8)
    for index, data in enumerate(batch):
        assert columns.success[index], columns.messages[columns.message_code[index]]
        answer = columns.position_m[index]
        starts = data.truth_emitter_m + rng.normal(0.0, [60.0, 60.0, 40.0], (12, 3))
        best = best_of_starts(data, starts)
        assert cost(data, answer) <= 2.0 * best.cost * (1 + 1e-9) + 1e-9
        np.testing.assert_allclose(answer, best.x, rtol=0, atol=1e-4)
        one = estimator.estimate(data, rng=generators(1)[0])
        np.testing.assert_allclose(one.position_m, answer, rtol=0, atol=1e-9)


def test_the_map_is_pulled_toward_the_ground_by_the_predicted_bias() -> None:
    """On ``hill-terrain`` (the tag 2 m above the ground, σ_m = 5 m) the MAP's mean error over
    4000 trials at 0 dB is the prior's pull ``−P g δ/σ_m`` (``P`` the prior-augmented bound,
    ``g`` the prior's row, ``δ`` the offset), within 4 standard errors of each coordinate; the
    height's pull, −0.18 m, is 8 standard errors from 0."""
    scenario = get_scenario("hill-terrain")
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(31, 4000))
    columns = MaximumLikelihood().estimate_columns(batch)
    assert columns.success.all()
    data = batch.geometry
    truth = data.truth_emitter_m
    bound = inverse_symmetric(fisher_information(data, truth))
    row = terrain_row(data, truth, data.unknowns)[0]
    offset = offset_above_surface_m(data.terrain, truth)
    pull = -bound @ row * offset / data.terrain.sigma_m
    errors = columns.position_m - truth
    standard_error = errors.std(axis=0, ddof=1) / np.sqrt(len(errors))
    assert np.all(np.abs(errors.mean(axis=0) - pull) <= 4.0 * standard_error)
    assert pull[2] < -8.0 * standard_error[2]


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("climb_mps", [0.0, 3.0])
def test_noise_free_random_flights_over_a_sloped_surface_are_exact(seed, climb_mps) -> None:
    """Random level and climbing turns with a sloped hill through the emitter: the one
    candidate is the emitter (on a level turn too, where the prior leaves no reflection to
    add), its covariance the prior-augmented bound."""
    data = height_unknown(random_data(seed, climb_mps=climb_mps))
    truth = data.truth_emitter_m
    rng = np.random.default_rng(seed)
    ground = Terrain(
        sigma_m=rng.uniform(0.5, 20.0),
        slope=rng.uniform(-0.3, 0.3, 2),
        hill_height_m=rng.uniform(-50.0, 50.0),
        hill_centre_m=truth[:2] + rng.uniform(-80.0, 80.0, 2),
        hill_width_m=rng.uniform(30.0, 150.0),
    )
    ground = dataclasses.replace(ground, height_m=float(offset_above_surface_m(ground, truth)))
    data = dataclasses.replace(data, terrain=ground)
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    scale = float(np.max(np.linalg.norm(data.position_m - truth, axis=1)))
    np.testing.assert_allclose(estimate.position_m, truth, rtol=0, atol=1e-7 * scale)
    assert estimate.candidates_m.shape == (1, 3)
    bound = inverse_symmetric(fisher_information(data, truth, "toa+doppler"))
    np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6)
