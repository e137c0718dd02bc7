"""The forward model of MATH §1 and its Jacobians (MATH §8)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free
from scenarios.types import RssModel

RSS = RssModel(reference_power_dbm=-30.0, reference_distance_m=2.0, path_loss_exponent=2.7)


# --------------------------------------------------------------------------------------------
# values
# --------------------------------------------------------------------------------------------


def test_first_paper_sample_doppler_is_plus_5_57_hz() -> None:
    """p = (0, 0, 50), v = (10, 0, 0), s = (35, 15, 0), γ = 1: closing, so
    ``f = −γ vᵀu = 10 · 35/√(35² + 15² + 50²) = 5.5689 Hz`` (MATH §1, physical sign)."""
    f = model.doppler_hz([[0.0, 0.0, 50.0]], [[10.0, 0.0, 0.0]], [35.0, 15.0], 1.0)
    assert f.shape == (1,)
    assert f[0] == pytest.approx(350.0 / np.sqrt(3950.0), rel=1e-14)
    assert round(float(f[0]), 2) == 5.57
    data = noise_free(get_scenario("paper"))
    assert data.doppler_hz[0] == pytest.approx(350.0 / np.sqrt(3950.0), rel=1e-14)


def test_doppler_is_positive_closing_and_negative_opening() -> None:
    position = [[0.0, 0.0, 50.0], [70.0, 0.0, 50.0], [35.0, 0.0, 50.0]]
    velocity = [[10.0, 0.0, 0.0]] * 3
    f = model.doppler_hz(position, velocity, [35.0, 15.0], 2.0)
    assert f[0] > 0.0  # approaching
    assert f[1] == pytest.approx(-f[0], rel=1e-14)  # receding, symmetric
    assert f[2] == pytest.approx(0.0, abs=1e-12)  # abeam


def test_toa_and_rss_values() -> None:
    """``τ = ρ/c`` and ``P = P0 − 10 η log10(ρ/d0)`` on a 3-4-12 triangle (ρ = 13 m)."""
    position = [[3.0, 4.0, 12.0]]
    assert model.slant_range_m(position, [0.0, 0.0])[0] == pytest.approx(13.0, rel=1e-15)
    assert model.slant_range_m(position, [0.0, 0.0], 12.0)[0] == pytest.approx(5.0, rel=1e-15)
    assert model.toa_s(position, [0.0, 0.0], 2.0)[0] == pytest.approx(6.5, rel=1e-15)
    expected = -30.0 - 27.0 * np.log10(13.0 / 2.0)
    assert model.rss_dbm(position, [0.0, 0.0], RSS)[0] == pytest.approx(expected, rel=1e-14)


# --------------------------------------------------------------------------------------------
# Jacobians against central differences
# --------------------------------------------------------------------------------------------


# rounded to µm and µm/s: no subnormal speeds whose Doppler underflows
coordinates = st.floats(-2000.0, 2000.0).map(lambda x: round(x, 6))
speeds = st.floats(-60.0, 60.0).map(lambda x: round(x, 6))


@st.composite
def geometries(draw):
    """Random samples, velocities, emitter, heights and γ, at least 1 m from the emitter."""
    n = draw(st.integers(1, 6))
    position = draw(arrays(np.float64, (n, 3), elements=coordinates))
    velocity = draw(arrays(np.float64, (n, 3), elements=speeds))
    emitter = draw(arrays(np.float64, (2,), elements=coordinates))
    height = draw(st.floats(-100.0, 100.0))
    gamma = draw(st.floats(0.01, 50.0))
    offset = position - np.append(emitter, height)
    # keep every range >= 1 m: lift samples that come closer than that
    too_close = np.linalg.norm(offset, axis=1) < 1.0
    position[too_close, 2] = height + 1.0 + draw(st.floats(0.0, 100.0))
    return position, velocity, emitter, height, gamma


def central_difference(function, emitter: np.ndarray, step: float) -> np.ndarray:
    """``∂h/∂(x_s, y_s)`` by central differences, shape (N, 2)."""
    columns = []
    for axis in range(2):
        delta = np.zeros(2)
        delta[axis] = step
        columns.append((function(emitter + delta) - function(emitter - delta)) / (2.0 * step))
    return np.stack(columns, axis=-1)


@settings(max_examples=150, deadline=None, database=None)
@given(geometries(), st.floats(1.0, 3e8))
def test_toa_jacobian_matches_finite_differences(geometry, c) -> None:
    position, _, emitter, height, _ = geometry
    analytic = model.toa_jacobian(position, emitter, c, height)
    assert analytic.shape == (len(position), 2)
    # truncation O((step/ρ)²) = 1e-8, rounding O(ε ρ/step) = 2e-12, relative to |∇τ| = 1/c
    step = 1e-4 * model.slant_range_m(position, emitter, height).min()
    numeric = central_difference(lambda s: model.toa_s(position, s, c, height), emitter, step)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-6 / c)


@settings(max_examples=150, deadline=None, database=None)
@given(geometries())
def test_doppler_jacobian_matches_finite_differences(geometry) -> None:
    position, velocity, emitter, height, gamma = geometry
    analytic = model.doppler_jacobian(position, velocity, emitter, gamma, height)
    assert analytic.shape == (len(position), 2)
    # the Doppler terms are of size γ|v|/ρ; compare relative to that, not to f itself
    ranges = model.slant_range_m(position, emitter, height)
    step = 1e-4 * ranges.min()
    numeric = central_difference(
        lambda s: model.doppler_hz(position, velocity, s, gamma, height), emitter, step
    )
    term = gamma * np.max(np.linalg.norm(velocity, axis=1)) / ranges.min()
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-6 * term)


@settings(max_examples=150, deadline=None, database=None)
@given(geometries(), st.floats(1.0, 6.0), st.floats(0.1, 10.0))
def test_rss_jacobian_matches_finite_differences(geometry, eta, d0) -> None:
    position, _, emitter, height, _ = geometry
    rss = RssModel(reference_power_dbm=-20.0, reference_distance_m=d0, path_loss_exponent=eta)
    analytic = model.rss_jacobian(position, emitter, rss, height)
    ranges = model.slant_range_m(position, emitter, height)
    step = 1e-4 * ranges.min()
    numeric = central_difference(lambda s: model.rss_dbm(position, s, rss, height), emitter, step)
    term = 10.0 * eta / np.log(10.0) / ranges.min()
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-6 * term)


# --------------------------------------------------------------------------------------------
# broadcasting over leading axes
# --------------------------------------------------------------------------------------------


def test_leading_axes_broadcast_like_a_loop() -> None:
    """Positions (T, 1, N, 3) of T trials against candidates (E, 2): results (T, E, N[, 2])."""
    rng = np.random.default_rng(0)
    T, E, N = 4, 3, 7
    position = rng.uniform(-200.0, 200.0, (T, 1, N, 3))
    position[..., 2] += 300.0
    velocity = rng.uniform(-20.0, 20.0, (T, 1, N, 3))
    emitter = rng.uniform(-100.0, 100.0, (E, 2))
    gamma, c, height = 3.3, 3e8, 4.0
    functions = {
        "range": lambda p, v, s: model.slant_range_m(p, s, height),
        "doppler": lambda p, v, s: model.doppler_hz(p, v, s, gamma, height),
        "toa": lambda p, v, s: model.toa_s(p, s, c, height),
        "rss": lambda p, v, s: model.rss_dbm(p, s, RSS, height),
        "doppler_jacobian": lambda p, v, s: model.doppler_jacobian(p, v, s, gamma, height),
        "toa_jacobian": lambda p, v, s: model.toa_jacobian(p, s, c, height),
        "rss_jacobian": lambda p, v, s: model.rss_jacobian(p, s, RSS, height),
    }
    for name, function in functions.items():
        batched = function(position, velocity, emitter)
        assert batched.shape[:3] == (T, E, N), name
        for t in range(T):
            for e in range(E):
                one = function(position[t, 0], velocity[t, 0], emitter[e])
                np.testing.assert_allclose(batched[t, e], one, rtol=1e-14, atol=0, err_msg=name)
    # shared positions against many candidates: (N, 3) with (E, 2) gives (E, N)
    shared = model.doppler_hz(position[0, 0], velocity[0, 0], emitter, gamma, height)
    assert shared.shape == (E, N)
    np.testing.assert_allclose(
        shared[1], model.doppler_hz(position[0, 0], velocity[0, 0], emitter[1], gamma, height)
    )
