"""scenarios.fisher: the Fisher information of MATH §8 and its 2×2 inverse.

Checked against an independent construction (every gradient by central differences of the
measurement functions), across its layers (per sample, per frame, accumulated), vectorised
against a loop, and the 2×2 inverse against ``numpy.linalg.inv``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from comparison.crlb import crlb_table
from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.fisher import (
    MODALITY_SETS,
    fisher_information,
    fisher_information_per_frame,
    gram_information,
    information_at_samples,
    inverse_2x2,
    inverse_symmetric,
    parse_modalities,
    per_sample_information,
    regular_2x2,
    rmse_bound_m,
    whitened_gradients,
    whitened_jacobian,
)
from scenarios.simulate import noise_free
from scenarios.types import MeasurementSet, NoiseSigmas
from tests.scenarios.random_flights import random_data

MODALITY_CHOICES = ["toa", "doppler", "rss", "toa+doppler", ("doppler", "toa", "rss")]


def differenced_gradients(
    position: np.ndarray, velocity: np.ndarray, emitter: np.ndarray, data: MeasurementSet
) -> dict[str, np.ndarray]:
    """``∇h_k`` of every modality, shape (N, d), by central differences of the model in the
    emitter's ``d`` coordinates (``d = 3``: the height one of them)."""
    height = data.emitter_height_m
    functions = {
        "toa": lambda s: model.toa_s(position, s, data.speed_of_light_mps, height),
        "doppler": lambda s: model.doppler_hz(position, velocity, s, data.gamma_per_m, height),
        "rss": lambda s: model.rss_dbm(position, s, data.rss_model, height),
    }
    step = 1e-4 * model.slant_range_m(position, emitter, height).min()
    return {
        name: np.stack(
            [
                (h(emitter + step * unit) - h(emitter - step * unit)) / (2.0 * step)
                for unit in np.eye(len(emitter))
            ],
            axis=-1,
        )
        for name, h in functions.items()
    }


def differenced_per_sample(
    position: np.ndarray,
    velocity: np.ndarray,
    emitter: np.ndarray,
    data: MeasurementSet,
    modalities: tuple[str, ...],
) -> np.ndarray:
    """``J_k = Σ_m ∇h_k∇h_kᵀ/σ_m²`` from differenced gradients, shape (N, d, d)."""
    gradients = differenced_gradients(position, velocity, emitter, data)
    return sum(
        np.einsum("ki,kj->kij", gradients[m], gradients[m]) / data.noise.for_modality(m) ** 2
        for m in modalities
    )


def assert_matrices_close(actual: np.ndarray, expected: np.ndarray, rtol: float) -> None:
    """Entry-wise, relative to each matrix's largest entry (off-diagonals may be ~0)."""
    scale = np.abs(expected).max(axis=(-2, -1), keepdims=True)
    error = np.abs(np.asarray(actual) - expected)
    np.testing.assert_array_less(error, np.broadcast_to(rtol * scale + 1e-300, error.shape))


# --------------------------------------------------------------------------------------------
# against finite differences
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("modalities", MODALITY_CHOICES)
@pytest.mark.parametrize("dimension", [2, 3])
def test_information_equals_the_finite_difference_fisher_matrix(seed, modalities, dimension):
    """The information of ``(x, y)`` on level flights, and of ``(x, y, z)`` (the height a
    coordinate, a 3-D ``emitter_m``) on climbing ones, against central differences, rtol 1e-6."""
    data = random_data(seed, climb_mps=0.0 if dimension == 2 else 3.0)
    emitter = np.array([*data.truth_emitter_m, data.emitter_height_m][:dimension])
    used = parse_modalities(modalities)
    expected_per_sample = differenced_per_sample(
        data.position_m, data.velocity_mps, emitter, data, used
    )
    per_sample = per_sample_information(
        data.position_m, data.velocity_mps, emitter, data, modalities
    )
    assert per_sample.shape == (data.n_samples, dimension, dimension)
    assert_matrices_close(per_sample, expected_per_sample, rtol=1e-6)
    expected = expected_per_sample.sum(axis=0)
    assert_matrices_close(fisher_information(data, emitter, modalities), expected, rtol=1e-6)
    assert_matrices_close(
        information_at_samples(data.position_m, data.velocity_mps, emitter, data, modalities),
        expected,
        rtol=1e-6,
    )
    assert rmse_bound_m(fisher_information(data, emitter, modalities)) == pytest.approx(
        np.sqrt(np.trace(np.linalg.inv(expected))), rel=1e-5
    )


@pytest.mark.parametrize("seed", range(4))
def test_information_of_planned_samples_equals_the_finite_difference_fisher(seed) -> None:
    """Samples that are not the data's (a planned frame): only the constants come from data."""
    data = random_data(seed)
    rng = np.random.default_rng(100 + seed)
    position = data.position_m + rng.normal(0.0, 40.0, data.position_m.shape)
    velocity = rng.normal(0.0, 10.0, data.velocity_mps.shape)
    emitter = data.truth_emitter_m + rng.normal(0.0, 20.0, 2)
    for modalities in MODALITY_CHOICES:
        used = parse_modalities(modalities)
        expected = differenced_per_sample(position, velocity, emitter, data, used).sum(axis=0)
        got = information_at_samples(position, velocity, emitter, data, modalities)
        assert_matrices_close(got, expected, rtol=1e-6)


# --------------------------------------------------------------------------------------------
# the layers agree
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("modalities", MODALITY_CHOICES)
def test_per_frame_information_sums_to_the_accumulated_one(seed, modalities) -> None:
    data = random_data(seed, n_frames=4)
    emitter = data.truth_emitter_m
    per_frame, accumulated = fisher_information_per_frame(data, emitter, modalities)
    assert per_frame.shape == accumulated.shape == (4, 2, 2)
    per_sample = per_sample_information(
        data.position_m, data.velocity_mps, emitter, data, modalities
    )
    for index, frame in enumerate(data.frames):
        one = fisher_information(data.select_frames([frame]), emitter, modalities)
        np.testing.assert_allclose(per_frame[index], one, rtol=1e-13)
        assert_matrices_close(per_frame[index], per_sample[data.frame == frame].sum(0), 1e-12)
        assert_matrices_close(
            accumulated[index],
            fisher_information(data.up_to_frame(frame), emitter, modalities),
            1e-12,
        )
        assert_matrices_close(accumulated[index], per_frame[: index + 1].sum(axis=0), 1e-12)
    assert_matrices_close(accumulated[-1], fisher_information(data, emitter, modalities), 1e-12)
    assert_matrices_close(per_sample.sum(axis=0), accumulated[-1], 1e-12)


def test_whitened_rows_are_modality_blocks_and_their_gram_is_the_information() -> None:
    data = random_data(7)
    emitter = data.truth_emitter_m
    n = data.n_samples
    rows = whitened_jacobian(data, emitter, ("rss", "doppler", "toa"))
    assert rows.shape == (3 * n, 2)
    height = data.emitter_height_m
    np.testing.assert_array_equal(
        rows[:n],
        model.rss_jacobian(data.position_m, emitter, data.rss_model, height) / data.noise.rss_db,
    )
    np.testing.assert_array_equal(
        rows[n : 2 * n],
        model.doppler_jacobian(
            data.position_m, data.velocity_mps, emitter, data.gamma_per_m, height
        )
        / data.noise.doppler_hz,
    )
    np.testing.assert_array_equal(
        rows[2 * n :],
        model.toa_jacobian(data.position_m, emitter, data.speed_of_light_mps, height)
        / data.noise.toa_s,
    )
    np.testing.assert_array_equal(
        rows,
        whitened_gradients(data.position_m, data.velocity_mps, emitter, data, "rss+doppler+toa"),
    )
    np.testing.assert_allclose(gram_information(rows), rows.T @ rows, rtol=1e-13)
    np.testing.assert_array_equal(
        gram_information(rows), fisher_information(data, emitter, ("rss", "doppler", "toa"))
    )


def test_gram_information_adds_the_rows_in_order_whatever_the_stack_or_layout() -> None:
    """Each entry is ``s = 0; s += g_i g_j`` over the rows: the same bits for one stack alone,
    among many, rows first (``row_axis=0``) or with ``p`` columns; ``JᵀJ`` to rounding."""
    rng = np.random.default_rng(16)
    rows = rng.standard_normal((6, 41, 3)) * np.exp(4.0 * rng.standard_normal((6, 41, 3)))
    together = gram_information(rows)
    alone = np.stack([gram_information(stack) for stack in rows])
    rows_first = gram_information(np.ascontiguousarray(np.moveaxis(rows, 1, 0)), row_axis=0)
    np.testing.assert_array_equal(together, alone)
    np.testing.assert_array_equal(together, rows_first)
    expected = np.zeros((6, 3, 3))
    for row in np.moveaxis(rows, 1, 0):
        expected = expected + row[:, :, None] * row[:, None, :]
    np.testing.assert_array_equal(together, expected)
    np.testing.assert_allclose(together, np.einsum("ski,skj->sij", rows, rows), rtol=1e-12)
    with pytest.raises(ValueError, match=r"^whitened_rows: expected rows along axis -1"):
        gram_information(rows, row_axis=-1)


# --------------------------------------------------------------------------------------------
# vectorised equals a loop
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("modalities", MODALITY_CHOICES)
def test_vectorised_over_emitter_positions_equals_a_loop(modalities) -> None:
    data = random_data(3)
    centre = data.truth_emitter_m
    xs, ys = centre[0] + np.linspace(-80.0, 120.0, 5), centre[1] + np.linspace(-60.0, 90.0, 4)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)  # (5, 4, 2)
    J = fisher_information(data, grid, modalities)
    per_frame, accumulated = fisher_information_per_frame(data, grid, modalities)
    per_sample = per_sample_information(data.position_m, data.velocity_mps, grid, data, modalities)
    bound = rmse_bound_m(J)
    inverse = inverse_2x2(J)
    assert J.shape == inverse.shape == (5, 4, 2, 2)
    assert per_frame.shape == accumulated.shape == (3, 5, 4, 2, 2)
    assert per_sample.shape == (5, 4, data.n_samples, 2, 2)
    assert bound.shape == regular_2x2(J).shape == (5, 4)
    for i in range(5):
        for j in range(4):
            one = fisher_information(data, grid[i, j], modalities)
            np.testing.assert_allclose(J[i, j], one, rtol=1e-13)
            frames_one, accumulated_one = fisher_information_per_frame(data, grid[i, j], modalities)
            np.testing.assert_allclose(per_frame[:, i, j], frames_one, rtol=1e-13)
            np.testing.assert_allclose(accumulated[:, i, j], accumulated_one, rtol=1e-13)
            np.testing.assert_allclose(
                per_sample[i, j],
                per_sample_information(
                    data.position_m, data.velocity_mps, grid[i, j], data, modalities
                ),
                rtol=1e-13,
            )
            np.testing.assert_allclose(inverse[i, j], inverse_2x2(one), rtol=1e-13)
            np.testing.assert_allclose(bound[i, j], rmse_bound_m(one), rtol=1e-13)


def test_vectorised_over_planned_frames_and_candidates_equals_a_loop() -> None:
    """A planner's call: (n_ψ, K, 3) samples against (n_c, 1, 2) candidates."""
    data = noise_free(get_scenario("paper-1m"))
    headings = np.radians([0.0, 37.0, 90.0, 200.0])
    velocity = 10.0 * np.stack([np.cos(headings), np.sin(headings), 0.0 * headings], axis=-1)
    steps = 0.05 * np.arange(10)
    position = data.position_m[-1] + steps[None, :, None] * velocity[:, None, :]
    velocity = np.broadcast_to(velocity[:, None, :], position.shape)
    candidates = np.array([[35.0, 15.0], [35.0, -15.0], [20.0, 40.0]])
    J = information_at_samples(position, velocity, candidates[:, None, :], data, ("toa", "doppler"))
    assert J.shape == (3, 4, 2, 2)
    for c in range(3):
        for h in range(4):
            one = information_at_samples(position[h], velocity[h], candidates[c], data)
            np.testing.assert_allclose(J[c, h], one, rtol=1e-13)


# --------------------------------------------------------------------------------------------
# the 2×2 algebra
# --------------------------------------------------------------------------------------------


def test_inverse_2x2_equals_numpy_inverse() -> None:
    rng = np.random.default_rng(11)
    factor = rng.normal(size=(6, 5, 2, 2))
    matrices = factor @ np.swapaxes(factor, -1, -2) + 0.1 * np.eye(2)  # symmetric positive definite
    matrices *= 10.0 ** rng.uniform(-8.0, 8.0, (6, 5, 1, 1))
    inverse = inverse_2x2(matrices)
    assert inverse.shape == (6, 5, 2, 2)
    assert np.all(regular_2x2(matrices))
    assert_matrices_close(inverse, np.linalg.inv(matrices), rtol=1e-12)
    np.testing.assert_allclose(
        rmse_bound_m(matrices),
        np.sqrt(np.trace(np.linalg.inv(matrices), axis1=-2, axis2=-1)),
        rtol=1e-12,
    )
    for index in np.ndindex(6, 5):
        np.testing.assert_allclose(inverse[index], inverse_2x2(matrices[index]), rtol=1e-15)
    J = np.array([[4.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(inverse_2x2(J), np.linalg.inv(J), rtol=1e-15)
    assert rmse_bound_m(J) == pytest.approx(np.sqrt(7.0 / 11.0), rel=1e-15)


def test_inverse_2x2_is_nan_where_singular() -> None:
    u = np.array([0.6, 0.8])
    singular = np.array(
        [
            np.zeros((2, 2)),
            1e12 * np.ones((2, 2)),
            np.outer(u, u),  # rank one
            np.outer(u, u) + 1e-14 * np.eye(2),  # rank one to a relative 1e-12
            [[1.0, 2.0], [2.0, 1.0]],  # indefinite: not an information
            [[np.nan, 0.0], [0.0, 1.0]],
        ]
    )
    regular = np.array([[[2.0, 0.5], [0.5, 1.0]], np.outer(u, u) + 1e-6 * np.eye(2)])
    stacked = np.concatenate([singular, regular])
    flags = regular_2x2(stacked)
    assert flags.tolist() == [False] * len(singular) + [True] * len(regular)
    inverse = inverse_2x2(stacked)
    assert np.all(np.isnan(inverse[: len(singular)]))
    assert np.all(np.isnan(rmse_bound_m(stacked)[: len(singular)]))
    assert_matrices_close(inverse[len(singular) :], np.linalg.inv(regular), rtol=1e-9)


def test_singular_geometry_gives_a_nan_bound() -> None:
    """ToA only with the emitter in the track's vertical plane: J has rank one."""
    data = noise_free(get_scenario("paper-1m"))
    J = fisher_information(data, np.array([[35.0, 0.0], [35.0, 15.0]]), "toa")
    assert regular_2x2(J).tolist() == [False, True]
    bound = rmse_bound_m(J)
    assert np.isnan(bound[0]) and np.isfinite(bound[1])


# --------------------------------------------------------------------------------------------
# modalities and errors
# --------------------------------------------------------------------------------------------


def test_modalities_are_parsed_in_the_order_given() -> None:
    assert {name: parse_modalities(name) for name in MODALITY_SETS} == MODALITY_SETS
    assert parse_modalities("doppler+toa+rss") == ("doppler", "toa", "rss")
    assert parse_modalities(["rss", "toa"]) == ("rss", "toa")
    for bad in ("toa+aoa", "", (), ["toa", "aoa"]):
        with pytest.raises(ValueError, match=r"^modalities: expected a subset of"):
            parse_modalities(bad)


def test_a_missing_sigma_or_rss_model_raises() -> None:
    data = noise_free(get_scenario("paper-1m"))
    emitter = data.truth_emitter_m
    toa_only = data.without("doppler", "rss")
    no_sigma = dataclasses.replace(toa_only, noise=NoiseSigmas(toa_s=data.noise.toa_s))
    with pytest.raises(ValueError, match=r"^noise.rss_db: needed for the rss information"):
        fisher_information(no_sigma, emitter, "rss")
    with pytest.raises(ValueError, match=r"^noise.doppler_hz: needed for the doppler"):
        information_at_samples(data.position_m, data.velocity_mps, emitter, no_sigma)
    no_model = dataclasses.replace(
        toa_only, rss_model=None, noise=NoiseSigmas(toa_s=data.noise.toa_s, rss_db=1.0)
    )
    with pytest.raises(ValueError, match=r"^rss_model: needed for the RSS information"):
        fisher_information(no_model, emitter, "rss")
    # a modality absent from the measurements is usable when its σ is given
    without_toa = data.without("toa")
    np.testing.assert_array_equal(
        fisher_information(without_toa, emitter, "toa"), fisher_information(data, emitter, "toa")
    )


def test_a_3d_emitter_at_the_known_height_is_the_2d_model_and_its_plane_gradient() -> None:
    """The same samples seen from ``(x, y)`` at the known height and from ``(x, y, z)`` with
    ``z`` that height: the same values, and the 3-D gradients' first two columns are the 2-D
    ones."""
    data = random_data(3, climb_mps=-2.0)
    plane, height = data.truth_emitter_m, data.emitter_height_m
    solid = np.array([*plane, height])
    p, v, c, gamma = data.position_m, data.velocity_mps, data.speed_of_light_mps, data.gamma_per_m
    pairs = [
        (model.toa_s(p, plane, c, height), model.toa_s(p, solid, c, 1e3)),
        (model.doppler_hz(p, v, plane, gamma, height), model.doppler_hz(p, v, solid, gamma, 1e3)),
        (model.rss_dbm(p, plane, data.rss_model, height), model.rss_dbm(p, solid, data.rss_model)),
        (model.toa_jacobian(p, plane, c, height), model.toa_jacobian(p, solid, c)[..., :2]),
        (
            model.doppler_jacobian(p, v, plane, gamma, height),
            model.doppler_jacobian(p, v, solid, gamma)[..., :2],
        ),
        (
            model.rss_jacobian(p, plane, data.rss_model, height),
            model.rss_jacobian(p, solid, data.rss_model)[..., :2],
        ),
    ]
    for two_d, three_d in pairs:
        np.testing.assert_allclose(three_d, two_d, rtol=1e-12, atol=0.0)


def test_the_3d_bound_with_unknown_offset_and_emission_time_and_the_price_of_the_height() -> None:
    """beacon-pass (carrier offset and emission time unknown): the position block of the
    inverse of a finite-difference Fisher matrix over (x, y, z, δ, b) is the 3-D CRLB, rtol
    1e-6; the horizontal block of that bound is at least the bound with the height known (a
    Schur complement only loses information), strictly so here."""
    data = noise_free(get_scenario("beacon-pass"), snr_db=20.0)
    plane = data.truth_emitter_m
    truth = np.array([*plane, data.emitter_height_m])
    p, v = data.position_m, data.velocity_mps
    sigma_f, sigma_t = data.noise.doppler_hz, data.noise.toa_s

    def whitened(theta: np.ndarray) -> np.ndarray:
        s, offset_hz, emission_s = theta[:3], theta[3], theta[4]
        doppler = model.doppler_hz(p, v, s, data.gamma_per_m, carrier_offset_hz=offset_hz)
        toa = model.toa_s(p, s, data.speed_of_light_mps, emission_time_s=emission_s)
        return np.concatenate([doppler / sigma_f, toa / sigma_t])

    theta = np.array([*truth, 0.0, 0.0])
    steps = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-12])
    jacobian = np.column_stack(
        [
            (whitened(theta + h * e) - whitened(theta - h * e)) / (2.0 * h)
            for h, e in zip(steps, np.eye(5), strict=True)
        ]
    )
    expected = np.linalg.inv(jacobian.T @ jacobian)[:3, :3]
    bound_3d = inverse_symmetric(fisher_information(data, truth))
    assert_matrices_close(bound_3d, expected, rtol=1e-6)
    price = bound_3d[:2, :2] - inverse_symmetric(fisher_information(data, plane))
    assert np.linalg.eigvalsh(price).min() >= -1e-9 * np.trace(bound_3d)
    assert np.trace(price) > 0.01 * np.trace(bound_3d[:2, :2])


@pytest.mark.parametrize("name", ["hill", "hill-climb", "roof-beacon"])
def test_the_3d_bound_of_each_elevated_scenario_is_the_finite_difference_one(name) -> None:
    """The emitter above the ground, its height unknown (and, on roof-beacon, the carrier
    offset and emission time): the position block of the inverse of a finite-difference Fisher
    matrix over (x, y, z, the nuisances) is ``crlb_table``'s 3×3 ``crlb_m2``, rtol 1e-6, and
    its horizontal and vertical parts are that matrix's."""
    data = noise_free(get_scenario(name), snr_db=10.0)
    truth = data.truth_emitter_m
    assert truth.shape == (3,) and truth[2] > 0.0
    p, v = data.position_m, data.velocity_mps
    offset_unknown = "carrier_offset_hz" in data.unknowns
    emission_unknown = "emission_time_s" in data.unknowns

    def whitened(theta: np.ndarray) -> np.ndarray:
        s, offset_hz, emission_s = theta[:3], theta[3], theta[4]
        doppler = model.doppler_hz(p, v, s, data.gamma_per_m, carrier_offset_hz=offset_hz)
        toa = model.toa_s(p, s, data.speed_of_light_mps, emission_time_s=emission_s)
        return np.concatenate([doppler / data.noise.doppler_hz, toa / data.noise.toa_s])

    used = [0, 1, 2] + [3] * offset_unknown + [4] * emission_unknown
    steps = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-12])
    theta = np.array([*truth, 0.0, 0.0])
    jacobian = np.column_stack(
        [
            (whitened(theta + steps[j] * e) - whitened(theta - steps[j] * e)) / (2 * steps[j])
            for j, e in ((j, np.eye(5)[j]) for j in used)
        ]
    )
    expected = np.linalg.inv(jacobian.T @ jacobian)[:3, :3]
    table = crlb_table(data, truth)
    bound = np.asarray(table["crlb_m2"]["toa+doppler"])
    assert_matrices_close(bound, expected, rtol=1e-6)
    horizontal = np.sqrt(np.trace(expected[:2, :2]))
    np.testing.assert_allclose(
        table["horizontal_rmse_bound_m"]["toa+doppler"], horizontal, rtol=1e-6
    )
    np.testing.assert_allclose(
        table["vertical_rmse_bound_m"]["toa+doppler"], np.sqrt(expected[2, 2]), rtol=1e-6
    )
