"""Fisher information and the CRLB of MATH §8."""

from __future__ import annotations

import numpy as np
import pytest

from comparison.crlb import (
    crlb_m2,
    fisher_information,
    fisher_information_per_frame,
    rmse_bound_m,
    whitened_jacobian,
)
from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free
from scenarios.types import MeasurementSet, NoiseSigmas
from tests.scenarios.random_flights import random_data

MODALITY_SETS = ["toa", "doppler", "rss", "toa+doppler", ("toa", "doppler", "rss")]


def random_geometry(seed: int) -> tuple[MeasurementSet, np.ndarray]:
    """A random two-heading flight, its noise-free data and the emitter."""
    data = random_data(seed, n_frames=2)
    return data, data.truth_emitter_m


def finite_difference_fisher(data: MeasurementSet, emitter: np.ndarray, modalities) -> np.ndarray:
    """``Σ ∇h ∇hᵀ/σ²`` with every ∇h by central differences of the measurement functions."""
    functions = {
        "toa": lambda s: model.toa_s(
            data.position_m, s, data.speed_of_light_mps, data.emitter_height_m
        ),
        "doppler": lambda s: model.doppler_hz(
            data.position_m, data.velocity_mps, s, data.gamma_per_m, data.emitter_height_m
        ),
        "rss": lambda s: model.rss_dbm(data.position_m, s, data.rss_model, data.emitter_height_m),
    }
    step = 1e-4 * model.slant_range_m(data.position_m, emitter, data.emitter_height_m).min()
    J = np.zeros((2, 2))
    for modality in modalities:
        gradient = np.stack(
            [
                (
                    functions[modality](emitter + step * unit)
                    - functions[modality](emitter - step * unit)
                )
                / (2.0 * step)
                for unit in np.eye(2)
            ],
            axis=-1,
        )
        J += gradient.T @ gradient / data.noise.for_modality(modality) ** 2
    return J


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("modalities", [("toa",), ("doppler",), ("rss",), ("toa", "doppler")])
def test_crlb_is_the_inverse_of_the_finite_difference_fisher_information(seed, modalities) -> None:
    data, emitter = random_geometry(seed)
    independent = np.linalg.inv(finite_difference_fisher(data, emitter, modalities))
    bound = crlb_m2(fisher_information(data, emitter, modalities))
    np.testing.assert_allclose(bound, independent, rtol=1e-5, atol=1e-5 * np.abs(bound).max())
    assert rmse_bound_m(fisher_information(data, emitter, modalities)) == pytest.approx(
        np.sqrt(np.trace(independent)), rel=1e-5
    )


@pytest.mark.parametrize("modalities", MODALITY_SETS)
def test_vectorised_over_a_grid_equals_a_loop(modalities) -> None:
    data = noise_free(get_scenario("turn"))
    xs, ys = np.linspace(-80.0, 120.0, 5), np.linspace(-60.0, 90.0, 4)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)  # (5, 4, 2)
    J = fisher_information(data, grid, modalities)
    bound = rmse_bound_m(J)
    assert J.shape == (5, 4, 2, 2)
    assert bound.shape == (5, 4)
    for i in range(5):
        for j in range(4):
            one = fisher_information(data, grid[i, j], modalities)
            np.testing.assert_allclose(J[i, j], one, rtol=1e-13)
            np.testing.assert_allclose(bound[i, j], rmse_bound_m(one), rtol=1e-13)


def test_accumulated_per_frame_information_equals_the_total() -> None:
    data = noise_free(get_scenario("orbit"))
    emitter = data.truth_emitter_m
    per_frame, accumulated = fisher_information_per_frame(data, emitter, "toa+doppler")
    assert per_frame.shape == accumulated.shape == (12, 2, 2)
    for index in range(12):
        np.testing.assert_allclose(
            per_frame[index],
            fisher_information(data.select_frames([index]), emitter, "toa+doppler"),
            rtol=1e-13,
        )
        np.testing.assert_allclose(
            accumulated[index],
            fisher_information(data.up_to_frame(index), emitter, "toa+doppler"),
            rtol=1e-12,
        )
    np.testing.assert_allclose(
        accumulated[-1], fisher_information(data, emitter, "toa+doppler"), rtol=1e-12
    )
    # information only grows: every accumulated bound is at most the one before
    bounds = rmse_bound_m(accumulated)
    assert np.all(np.diff(bounds) <= 0.0)


def test_doppler_alone_localises_from_one_frame() -> None:
    """MATH §8: one straight frame of Doppler gives a nonsingular J (the paper says otherwise).

    Paper geometry, σ_f = 0.1 Hz: the Doppler-only RMSE bound is finite and equals the inverse
    of the independently differenced information."""
    data = noise_free(get_scenario("paper-1m"))
    emitter = data.truth_emitter_m
    J = fisher_information(data, emitter, "doppler")
    eigenvalues = np.linalg.eigvalsh(J)
    assert eigenvalues[0] > 1e-6 * eigenvalues[1]
    bound = rmse_bound_m(J)
    assert np.isfinite(bound)
    expected = np.sqrt(
        np.trace(np.linalg.inv(finite_difference_fisher(data, emitter, ["doppler"])))
    )
    assert bound == pytest.approx(expected, rel=1e-5)


def test_singular_geometry_gives_nan() -> None:
    """ToA only with the emitter in the track's vertical plane: every ∇τ is along the track,
    J has rank one and the bound is NaN; one ToA sample is rank one too."""
    data = noise_free(get_scenario("paper-1m"))
    on_track = np.array([35.0, 0.0])
    assert np.all(np.isnan(crlb_m2(fisher_information(data, on_track, "toa"))))
    assert np.isnan(rmse_bound_m(fisher_information(data, on_track, "toa")))
    single = data.take(np.arange(data.n_samples) == 0)
    assert np.isnan(rmse_bound_m(fisher_information(single, [35.0, 15.0], "toa")))
    # and in a grid, only the singular points are NaN
    grid = np.array([[35.0, 0.0], [35.0, 15.0]])
    bounds = rmse_bound_m(fisher_information(data, grid, "toa"))
    assert np.isnan(bounds[0]) and np.isfinite(bounds[1])


def test_crlb_of_a_2x2_matrix() -> None:
    J = np.array([[4.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(crlb_m2(J), np.linalg.inv(J), rtol=1e-15)
    assert rmse_bound_m(J) == pytest.approx(np.sqrt(7.0 / 11.0), rel=1e-15)
    assert np.all(np.isnan(crlb_m2(np.zeros((2, 2)))))
    assert np.all(np.isnan(crlb_m2(1e12 * np.ones((2, 2)))))


def test_whitened_rows_stack_the_modalities() -> None:
    data = noise_free(get_scenario("paper-1m"))
    rows = whitened_jacobian(data, data.truth_emitter_m, ("toa", "doppler", "rss"))
    assert rows.shape == (3 * data.n_samples, 2)
    np.testing.assert_allclose(
        rows[: data.n_samples],
        model.toa_jacobian(data.position_m, data.truth_emitter_m, data.speed_of_light_mps)
        / data.noise.toa_s,
    )


def test_unknown_modality_or_missing_sigma_raises() -> None:
    data = noise_free(get_scenario("paper-1m"))
    with pytest.raises(ValueError, match=r"^modalities:"):
        fisher_information(data, data.truth_emitter_m, "toa+aoa")
    no_rss_sigma = MeasurementSet(
        frame=data.frame,
        time_s=data.time_s,
        position_m=data.position_m,
        velocity_mps=data.velocity_mps,
        toa_s=data.toa_s,
        carrier_hz=data.carrier_hz,
        noise=NoiseSigmas(toa_s=data.noise.toa_s),
    )
    with pytest.raises(ValueError, match=r"^noise.rss_db:"):
        fisher_information(no_rss_sigma, data.truth_emitter_m, "rss")
