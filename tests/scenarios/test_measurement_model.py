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
from tests.scenarios.random_flights import random_data

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
# the derivatives to third order (doppler_range_derivatives) against central differences
# --------------------------------------------------------------------------------------------

ORDER_COLUMNS = {0: [0], 1: [1, 2], 2: [3, 4, 5], 3: [6, 7, 8, 9]}
"""Columns of each order in ``DERIVATIVE_COMPONENTS``."""


def differenced(function, emitter: np.ndarray, step: float, order: int) -> np.ndarray:
    """Order ``order``'s columns by central differences of order ``order − 1``'s."""
    lower = ORDER_COLUMNS[order - 1]
    dx, dy = central_difference(lambda s: function(s)[:, lower], emitter, step).transpose(2, 0, 1)
    if order == 1:
        return np.column_stack([dx[:, 0], dy[:, 0]])
    if order == 2:  # from (f_x, f_y): f_xx = ∂x f_x, f_xy = ∂x f_y, f_yy = ∂y f_y
        return np.column_stack([dx[:, 0], dx[:, 1], dy[:, 1]])
    # from (f_xx, f_xy, f_yy): f_xxx = ∂x f_xx, f_xxy = ∂x f_xy, f_xyy = ∂x f_yy, f_yyy = ∂y f_yy
    return np.column_stack([dx[:, 0], dx[:, 1], dx[:, 2], dy[:, 2]])


@settings(max_examples=150, deadline=None, database=None)
@given(geometries(), st.sampled_from([1, 2, 3]))
def test_doppler_range_derivatives_match_finite_differences(geometry, order) -> None:
    """Each order's derivatives are the central differences of the order below, to
    ``1e-6 ×`` their scale at the nearest sample (``γ|v|/ρ^k`` for Doppler, ``1/ρ^(k−1)`` for
    the range): truncation ``O((step/ρ)²) = 1e-8``, rounding ``O(ε ρ/step) = 2e-12``. The
    mixed derivatives are checked both ways (``∂y f_x = f_xy``, ``∂y f_xx = f_xxy``)."""
    position, velocity, emitter, height, gamma = geometry
    ranges = model.slant_range_m(position, emitter, height)
    step = 1e-4 * ranges.min()
    doppler, distance = model.doppler_range_derivatives(
        position, velocity, emitter, gamma, height, order=3
    )
    assert doppler.shape == distance.shape == (len(position), 10)
    speed = max(np.max(np.linalg.norm(velocity, axis=1)), 1e-3)
    for index, (analytic, scale) in enumerate(
        [(doppler, gamma * speed / ranges.min() ** order), (distance, ranges.min() ** (1 - order))]
    ):

        def at(s, index=index):
            return model.doppler_range_derivatives(
                position, velocity, s, gamma, height, order=order - 1
            )[index]

        numeric = differenced(at, emitter, step, order)
        np.testing.assert_allclose(
            analytic[:, ORDER_COLUMNS[order]], numeric, rtol=1e-6, atol=1e-6 * scale
        )
        if order >= 2:  # the other mixed difference: ∂y of the first lower column
            lower = ORDER_COLUMNS[order - 1][0]
            mixed = central_difference(lambda s, at=at, lower=lower: at(s)[:, lower], emitter, step)
            np.testing.assert_allclose(
                analytic[:, ORDER_COLUMNS[order][1]], mixed[:, 1], rtol=1e-6, atol=1e-6 * scale
            )


def central_difference_3d(function, emitter: np.ndarray, step: float) -> np.ndarray:
    """``∂h/∂(x_s, y_s, z_s)`` by central differences, shape (N, ..., 3)."""
    columns = []
    for axis in range(3):
        delta = np.zeros(3)
        delta[axis] = step
        columns.append((function(emitter + delta) - function(emitter - delta)) / (2.0 * step))
    return np.stack(columns, axis=-1)


@settings(max_examples=100, deadline=None, database=None)
@given(geometries(), st.sampled_from([1, 2, 3]))
def test_derivatives_in_three_coordinates_match_finite_differences(geometry, order) -> None:
    """``dimension=3`` (the height unknown): every component of order ``k`` (named by its
    axes, :func:`derivative_components`) is the central difference along its last axis of the
    component of order ``k − 1`` without that axis, to ``1e-6 ×`` its scale as in the 2-D
    test; every mixed component is thereby checked against the differences of another."""
    position, velocity, emitter_xy, height, gamma = geometry
    emitter = np.append(emitter_xy, height)  # the height a coordinate of the position
    names = model.derivative_components(3)
    assert len(names) == model.n_components(3, 3) == 20
    ranges = model.slant_range_m(position, emitter)
    step = 1e-4 * ranges.min()
    analytic = model.doppler_range_derivatives(
        position, velocity, emitter, gamma, order=3, dimension=3
    )
    speed = max(np.max(np.linalg.norm(velocity, axis=1)), 1e-3)
    scales = (gamma * speed / ranges.min() ** order, ranges.min() ** (1 - order))
    for index, scale in enumerate(scales):

        def at(s, index=index):
            return model.doppler_range_derivatives(
                position, velocity, s, gamma, order=order - 1, dimension=3
            )[index]

        numeric = central_difference_3d(at, emitter, step)  # (N, n_lower, 3)
        for column, name in enumerate(names):
            if len(name) != order:
                continue
            lower = names.index(name[:-1])
            np.testing.assert_allclose(
                analytic[index][:, column],
                numeric[:, lower, "xyz".index(name[-1])],
                rtol=1e-6,
                atol=1e-6 * scale,
                err_msg=f"component {name!r} of {('doppler', 'range')[index]}",
            )


def test_derivatives_in_three_coordinates_extend_the_plane_ones() -> None:
    """Of a 3-D emitter, ``dimension=3``'s ``(x, y)`` components are ``dimension=2``'s and its
    gradient the Jacobians of :func:`doppler_jacobian`, :func:`toa_jacobian` (two code paths:
    rtol 1e-12); the lower orders are the leading columns of the higher ones."""
    rng = np.random.default_rng(6)
    position = rng.uniform(-300.0, 300.0, (9, 3))
    velocity = rng.uniform(-20.0, 20.0, (9, 3))
    emitter, gamma, c = np.array([40.0, -70.0, 12.0]), 2.5, 3e8
    full = model.doppler_range_derivatives(position, velocity, emitter, gamma, order=3, dimension=3)
    plane = model.doppler_range_derivatives(position, velocity, emitter, gamma, order=3)
    names3, names2 = model.derivative_components(3), model.derivative_components(2)
    assert names2 == model.DERIVATIVE_COMPONENTS
    columns = [names3.index(name) for name in names2]
    for three, two in zip(full, plane, strict=True):
        np.testing.assert_allclose(three[:, columns], two, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(
        full[0][:, 1:4], model.doppler_jacobian(position, velocity, emitter, gamma), rtol=1e-12
    )
    np.testing.assert_allclose(
        full[1][:, 1:4], c * model.toa_jacobian(position, emitter, c), rtol=1e-12
    )
    for order in (0, 1, 2):
        lower = model.doppler_range_derivatives(
            position, velocity, emitter, gamma, order=order, dimension=3
        )
        width = model.n_components(order, 3)
        np.testing.assert_array_equal(lower[0], full[0][:, :width])
        np.testing.assert_array_equal(lower[1], full[1][:, :width])


def test_doppler_range_derivatives_agree_with_the_values_and_jacobians() -> None:
    """Order 0 and 1 are :func:`doppler_hz`, :func:`slant_range_m` and the Jacobians
    (``∇ρ = c∇τ``); the lower orders are the leading columns of the higher ones."""
    rng = np.random.default_rng(3)
    position = rng.uniform(-300.0, 300.0, (9, 3))
    velocity = rng.uniform(-20.0, 20.0, (9, 3))
    emitter, gamma, height, c = np.array([40.0, -70.0]), 2.5, 6.0, 3e8
    doppler, ranges = model.doppler_range_derivatives(
        position, velocity, emitter, gamma, height, order=3
    )
    np.testing.assert_allclose(
        doppler[:, 0], model.doppler_hz(position, velocity, emitter, gamma, height), rtol=1e-13
    )
    np.testing.assert_allclose(ranges[:, 0], model.slant_range_m(position, emitter, height))
    np.testing.assert_allclose(
        doppler[:, 1:3], model.doppler_jacobian(position, velocity, emitter, gamma, height)
    )
    np.testing.assert_allclose(
        ranges[:, 1:3], c * model.toa_jacobian(position, emitter, c, height), rtol=1e-15
    )
    for order in (0, 1, 2):
        lower = model.doppler_range_derivatives(
            position, velocity, emitter, gamma, height, order=order
        )
        width = model.N_COMPONENTS_TO_ORDER[order]
        assert lower[0].shape == lower[1].shape == (9, width)
        np.testing.assert_array_equal(lower[0], doppler[:, :width])
        np.testing.assert_array_equal(lower[1], ranges[:, :width])


def test_doppler_range_derivatives_take_per_sample_constants() -> None:
    """``γ`` and the height per sample, one emitter per sample ((K, 1, 3) samples against
    (K, 2) emitters): each row as if evaluated alone."""
    rng = np.random.default_rng(4)
    position = rng.uniform(-300.0, 300.0, (5, 3))
    velocity = rng.uniform(-20.0, 20.0, (5, 3))
    emitters = rng.uniform(-50.0, 50.0, (5, 2))
    gammas, heights = rng.uniform(1.0, 3.0, 5), rng.uniform(0.0, 10.0, 5)
    doppler, ranges = model.doppler_range_derivatives(
        position[:, None], velocity[:, None], emitters, gammas[:, None], heights[:, None], order=3
    )
    assert doppler.shape == (5, 1, 10)
    for k in range(5):
        one = model.doppler_range_derivatives(
            position[k : k + 1], velocity[k : k + 1], emitters[k], gammas[k], heights[k], order=3
        )
        np.testing.assert_allclose(doppler[k], one[0], rtol=1e-14)
        np.testing.assert_allclose(ranges[k], one[1], rtol=1e-14)


def test_derivatives_of_offsets_in_a_rows_first_layout() -> None:
    """Per-sample constants as columns (K, 1) against emitters along the last axis (E,): the
    components first, each (K, E), equal to :func:`doppler_range_derivatives` per emitter;
    ``values=False`` gives the same derivatives."""
    rng = np.random.default_rng(5)
    position = rng.uniform(-300.0, 300.0, (6, 3))
    velocity = rng.uniform(-20.0, 20.0, (6, 3))
    emitters = rng.uniform(-50.0, 50.0, (4, 2))
    gamma, height = 1.7, 3.0
    columns = [position[:, i, None] for i in range(3)]
    speeds = tuple(velocity[:, i, None] for i in range(3))
    for order in (0, 1, 2, 3):
        doppler, ranges = model.derivatives_of_offsets(
            columns[0] - emitters[:, 0],
            columns[1] - emitters[:, 1],
            columns[2] - height,
            speeds,
            gamma,
            order=order,
        )
        assert doppler.shape == ranges.shape == (model.N_COMPONENTS_TO_ORDER[order], 6, 4)
        for e in range(4):
            one = model.doppler_range_derivatives(
                position, velocity, emitters[e], gamma, height, order=order
            )
            np.testing.assert_allclose(doppler[:, :, e].T, one[0], rtol=1e-14, atol=1e-300)
            np.testing.assert_allclose(ranges[:, :, e].T, one[1], rtol=1e-14, atol=1e-300)
        if order:
            alone = model.derivatives_of_offsets(
                columns[0] - emitters[:, 0],
                columns[1] - emitters[:, 1],
                columns[2] - height,
                speeds,
                gamma,
                order=order,
                values=False,
            )
            np.testing.assert_array_equal(alone[0][1:], doppler[1:])
            np.testing.assert_array_equal(alone[1], ranges)


def test_doppler_range_derivatives_reject_an_order_above_three() -> None:
    with pytest.raises(ValueError, match="order: expected 0, 1, 2 or 3"):
        model.doppler_range_derivatives(
            [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]], [0.0, 0.0], 1.0, order=4
        )


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


def _whitened_data(data, emitter_m) -> np.ndarray:
    """Every noise-free Doppler, ToA and RSS value of ``data``'s samples for an emitter at
    ``emitter_m`` (three coordinates), in σ."""
    p, v = data.position_m, data.velocity_mps
    return np.concatenate(
        [
            model.doppler_hz(p, v, emitter_m, data.gamma_per_m) / data.noise.doppler_hz,
            model.toa_s(p, emitter_m, data.speed_of_light_mps) / data.noise.toa_s,
            model.rss_dbm(p, emitter_m, data.rss_model) / data.noise.rss_db,
        ]
    )


@pytest.mark.parametrize("seed", range(5))
def test_in_3d_a_straight_level_frame_leaves_a_circle_and_a_level_turn_a_reflection(seed) -> None:
    """MATH §7 with the height a coordinate: one straight level frame gives the same data for
    every rotation of the emitter about the track's line; a level turn for the reflection
    through the flight plane; a climbing turn not for that reflection (many σ off)."""
    rng = np.random.default_rng(seed)
    line = random_data(seed, n_frames=1)
    s = np.array([*line.truth_emitter_m, line.emitter_height_m])
    start, direction = (
        line.position_m[0],
        line.velocity_mps[0] / np.linalg.norm(line.velocity_mps[0]),
    )
    along = start + np.dot(s - start, direction) * direction  # s's foot on the track's line
    radial = s - along
    normal = np.cross(direction, radial / np.linalg.norm(radial))
    reference = _whitened_data(line, s)
    for angle in rng.uniform(0.1, 2.0 * np.pi, 6):
        rotated = along + np.cos(angle) * radial + np.sin(angle) * np.linalg.norm(radial) * normal
        np.testing.assert_allclose(_whitened_data(line, rotated), reference, rtol=1e-12, atol=1e-9)

    turn = random_data(seed, n_frames=3)
    s = np.array([*turn.truth_emitter_m, turn.emitter_height_m])
    plane = turn.position_m[0, 2]
    reflected = np.array([*s[:2], 2.0 * plane - s[2]])
    np.testing.assert_allclose(
        _whitened_data(turn, reflected), _whitened_data(turn, s), rtol=1e-12, atol=1e-9
    )

    climb = random_data(seed, n_frames=3, climb_mps=2.0)
    mirror = np.array([*s[:2], 2.0 * climb.position_m[:, 2].mean() - s[2]])
    assert np.abs(_whitened_data(climb, mirror) - _whitened_data(climb, s)).max() > 1.0
