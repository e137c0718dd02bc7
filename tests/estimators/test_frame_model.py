"""The per-frame model the frame-by-frame estimators share (:mod:`estimators.frame_model`): the
forward model of MATH §1, its Jacobian and Hessian against central differences, and its
information against the CRLB's (MATH §8)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from comparison.crlb import fisher_information
from estimators.frame_model import FrameModel
from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate
from tests.estimators.test_ekf import EAST_THEN_NORTH, flight_scenario

# --------------------------------------------------------------------------------------------
# the shared frame model
# --------------------------------------------------------------------------------------------


def test_frame_model_is_the_forward_model() -> None:
    """``h(s)`` stacks MATH §1's Doppler and ``c τ``; the noise-free error is zero at the truth."""
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    frame = next(data.iter_frames())
    stacked = FrameModel.from_measurements(frame)
    point = np.array([12.0, -7.0])
    expected = np.concatenate(
        [
            model.doppler_hz(frame.position_m, frame.velocity_mps, point, frame.gamma_per_m),
            frame.speed_of_light_mps * model.toa_s(frame.position_m, point, 3e8),
        ]
    )
    np.testing.assert_allclose(stacked.predicted(point), expected, rtol=1e-13)
    np.testing.assert_allclose(stacked.whitened_error([35.0, 15.0]), 0.0, atol=1e-6)
    assert stacked.n_rows == 20
    np.testing.assert_array_equal(stacked.sigma, [0.1] * 10 + [1.0] * 10)


@pytest.mark.parametrize("frame_index", [0, 5])
def test_frame_jacobian_matches_central_differences(frame_index: int) -> None:
    """``E(s)``, the filter's H and the factor's Jacobian, against central differences."""
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    frame = FrameModel.from_measurements(list(data.iter_frames())[frame_index])
    rng = np.random.default_rng(7)
    points = np.vstack([[35.0, 15.0], [35.0, -15.0], rng.uniform(-80.0, 80.0, (6, 2))])
    step = 1e-5
    for point in points:
        numeric = np.column_stack(
            [
                (
                    frame.whitened_error(point + step * axis)
                    - frame.whitened_error(point - step * axis)
                )
                / (2 * step)
                for axis in np.eye(2)
            ]
        )
        analytic = frame.whitened_jacobian(point)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-8)
        error, jacobian = frame.whitened_error_and_jacobian(point)
        np.testing.assert_array_equal(error, frame.whitened_error(point))
        np.testing.assert_array_equal(jacobian, analytic)


@pytest.mark.parametrize("frame_index", [3, 4])
def test_frame_hessian_matches_central_differences(frame_index: int) -> None:
    """``∂²h/∂s²`` of every row (the curvature Gauss-Newton drops) against differences of the
    analytic Jacobian, also on the track and per sample."""
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=1)
    frame = FrameModel.from_measurements(list(data.iter_frames())[frame_index])
    step = 1e-5
    for point in np.array([[35.0, 15.0], [20.0, 1e-3], [-40.0, 70.0]]):
        numeric = np.stack(
            [
                (frame.jacobian(point + step * axis) - frame.jacobian(point - step * axis))
                / (2 * step)
                for axis in np.eye(2)
            ],
            axis=-1,
        )
        hessian = frame.hessian(point)
        np.testing.assert_allclose(hessian, numeric, rtol=1e-6, atol=1e-9 * np.abs(hessian).max())
        per_sample = frame.hessian(np.tile(point, (len(frame.position_m), 1)), per_sample=True)
        np.testing.assert_allclose(per_sample, hessian, rtol=1e-12)
        e = frame.whitened_error(point)
        np.testing.assert_allclose(
            frame.curvature_terms(point, e), (e / frame.sigma)[:, None, None] * hessian
        )


def test_frame_information_sums_to_the_crlb_fisher_information() -> None:
    """``Σ_frames EᵀE`` is MATH §8's toa+doppler Fisher information."""
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    frames = [FrameModel.from_measurements(f) for f in data.iter_frames()]
    truth = np.array([35.0, 15.0])
    total = sum(frame.information(truth) for frame in frames)
    np.testing.assert_allclose(total, fisher_information(data, truth, "toa+doppler"), rtol=1e-12)


# --------------------------------------------------------------------------------------------
# the height unknown: a 3-D emitter (MATH §8)
# --------------------------------------------------------------------------------------------


def height_frames(seed: int = 1) -> list[FrameModel]:
    """The frames of ``hill-climb`` (the height unknown: 3-D models), noisy."""
    data = simulate(get_scenario("hill-climb"), seed=seed)
    return [FrameModel.from_measurements(frame) for frame in data.iter_frames()]


@pytest.mark.parametrize("frame_index", [0, 3])
def test_3d_frame_jacobian_and_hessian_match_central_differences(frame_index: int) -> None:
    """With the height unknown (``dimension`` 3) ``E(s)`` is ``(2K, 3)`` and ``∂²h/∂s²`` is
    ``(2K, 3, 3)``: against central differences of the error and of the Jacobian in
    ``(x, y, z)``, one emitter and per sample (what the smoother's stacked frames use)."""
    frame = height_frames()[frame_index]
    assert frame.dimension == 3
    step = 1e-4
    for point in np.array([[150.0, 120.0, 120.0], [100.0, -40.0, 10.0], [170.0, 0.0, 250.0]]):
        analytic = frame.whitened_jacobian(point)
        assert analytic.shape == (frame.n_rows, 3)
        numeric = np.column_stack(
            [
                (
                    frame.whitened_error(point + step * axis)
                    - frame.whitened_error(point - step * axis)
                )
                / (2 * step)
                for axis in np.eye(3)
            ]
        )
        np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-9 * np.abs(analytic).max())
        hessian = frame.hessian(point)
        numeric = np.stack(
            [
                (frame.jacobian(point + step * axis) - frame.jacobian(point - step * axis))
                / (2 * step)
                for axis in np.eye(3)
            ],
            axis=-1,
        )
        np.testing.assert_allclose(hessian, numeric, rtol=1e-6, atol=1e-9 * np.abs(hessian).max())
        tiled = np.tile(point, (len(frame.position_m), 1))
        np.testing.assert_allclose(frame.hessian(tiled, per_sample=True), hessian, rtol=1e-12)
        e, E = frame.whitened_error_and_jacobian_per_sample(tiled)
        np.testing.assert_allclose(e, frame.whitened_error(point), rtol=1e-13, atol=1e-12)
        np.testing.assert_allclose(E, analytic, rtol=1e-12)


def test_3d_frame_at_the_known_height_is_the_2d_frame() -> None:
    """A 3-D model evaluated at ``(x, y, z_s)`` is the 2-D model of the same frame with the
    height ``z_s`` known: the same values, the ``(x, y)`` columns of its Jacobian and the
    ``(x, y)`` block of its Hessian (two code paths: rtol 1e-12); its information sums to the
    3-D Fisher information of MATH §8."""
    data = noise_free(get_scenario("hill"))
    truth = data.truth_emitter_m
    frames = [FrameModel.from_measurements(frame) for frame in data.iter_frames()]
    for frame in frames:
        plane = replace(frame, dimension=2, emitter_height_m=truth[2])
        np.testing.assert_allclose(frame.predicted(truth), plane.predicted(truth[:2]), rtol=1e-12)
        np.testing.assert_allclose(
            frame.jacobian(truth)[:, :2], plane.jacobian(truth[:2]), rtol=1e-12, atol=1e-15
        )
        np.testing.assert_allclose(
            frame.hessian(truth)[:, :2, :2], plane.hessian(truth[:2]), rtol=1e-12, atol=1e-18
        )
    total = sum(frame.information(truth) for frame in frames)
    np.testing.assert_allclose(total, fisher_information(data, truth, "toa+doppler"), rtol=1e-12)
