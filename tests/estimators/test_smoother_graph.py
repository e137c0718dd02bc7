"""The smoother's factor graph (:mod:`estimators.sequential.smoother_graph`): the frame factor's
Jacobian, the numpy evidence, decrements and block elimination against GTSAM's own (MATH §8), and
the third-order expansion the streaming smoother reads."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from gtsam.symbol_shorthand import X  # noqa: E402

from estimators.frame_model import FrameModel  # noqa: E402
from estimators.sequential.smoother_graph import (  # noqa: E402
    N_TERMS,
    Expansion,
    _block_elimination,
    _whitened_derivatives,
    chain_fit,
    chain_log_evidence,
    data_sums,
    expansion_terms,
    frame_factor,
    graph_part,
    step_sigmas_m,
    values_of,
)
from scenarios.simulate import simulate  # noqa: E402
from tests.estimators.test_ekf import EAST_THEN_NORTH, flight_scenario  # noqa: E402


def frame_models(data) -> tuple[FrameModel, ...]:
    return tuple(FrameModel.from_measurements(frame) for frame in data.iter_frames())


# --------------------------------------------------------------------------------------------
# the factor and the evidence
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("frame_index", [0, 7])
def test_custom_factor_jacobian_matches_central_differences(frame_index: int) -> None:
    """``linearize(values).jacobian()`` against central differences of the factor's error."""
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=1)
    frame = frame_models(data)[frame_index]
    factor = frame_factor(frame, X(0))
    step = 1e-5
    rng = np.random.default_rng(3)
    for point in np.vstack([[35.0, 15.0], [35.0, -15.0], rng.uniform(-60.0, 60.0, (4, 2))]):
        A, b = factor.linearize(values_of(point)).jacobian()
        error = factor.unwhitenedError(values_of(point))
        numeric = np.column_stack(
            [
                (
                    factor.unwhitenedError(values_of(point + step * axis))
                    - factor.unwhitenedError(values_of(point - step * axis))
                )
                / (2 * step)
                for axis in np.eye(2)
            ]
        )
        assert A.shape == (frame.n_rows, 2)
        np.testing.assert_allclose(A, numeric, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(b, -error, rtol=1e-12)
        np.testing.assert_allclose(error, frame.whitened_error(point), rtol=1e-12)
        assert factor.error(values_of(point)) == pytest.approx(0.5 * error @ error, rel=1e-12)


def test_chain_log_evidence_matches_gtsam_elimination() -> None:
    """``−½χ² − ½ log det Λ`` equals GTSAM's ``−error − logDeterminant`` of the linearised graph."""
    data = simulate(flight_scenario([0.0, 0.0, 90.0, 90.0]), seed=6)
    frames = frame_models(data)
    steps = step_sigmas_m(frames, 0.3)
    estimates = np.array([[35.2, 15.1], [35.0, 14.8], [34.9, 15.3], [35.1, 15.0]])
    prior_mean = np.array([34.0, 16.0])
    graph = graph_part(
        frames,
        0,
        4,
        random_walk=True,
        step_sigmas=steps,
        prior_mean_m=prior_mean,
        prior_sigma_m=50.0,
    )
    values = values_of(estimates)
    log_evidence, information = chain_log_evidence(
        frames,
        estimates,
        random_walk=True,
        step_sigmas=steps,
        prior_mean_m=prior_mean,
        prior_sigma_m=50.0,
    )
    bayes_net = graph.linearize(values).eliminateSequential()
    assert log_evidence == pytest.approx(
        -graph.error(values) - bayes_net.logDeterminant(), rel=1e-10
    )
    expected = sum(f.information(s) for f, s in zip(frames, estimates, strict=True))
    np.testing.assert_allclose(information, expected, rtol=1e-12)


def test_block_elimination_matches_dense_algebra() -> None:
    """``log det A`` and ``gᵀA⁻¹g`` of a block tridiagonal ``A`` (off-diagonal ``−w_t I``)."""
    rng = np.random.default_rng(0)
    n = 6
    links = rng.uniform(0.5, 3.0, n - 1)
    blocks = np.array([m @ m.T + np.eye(2) for m in rng.normal(size=(n, 2, 2))])
    for t, w in enumerate(links):
        blocks[t] += w * np.eye(2)
        blocks[t + 1] += w * np.eye(2)
    dense = np.zeros((2 * n, 2 * n))
    for t in range(n):
        dense[2 * t : 2 * t + 2, 2 * t : 2 * t + 2] = blocks[t]
    for t, w in enumerate(links):
        dense[2 * t : 2 * t + 2, 2 * t + 2 : 2 * t + 4] = -w * np.eye(2)
        dense[2 * t + 2 : 2 * t + 4, 2 * t : 2 * t + 2] = -w * np.eye(2)
    gradient = rng.normal(size=(n, 2))
    log_det, decrement, last, solution = _block_elimination(blocks, links, gradient)
    assert log_det == pytest.approx(np.linalg.slogdet(dense)[1], rel=1e-12)
    g = gradient.reshape(-1)
    assert decrement == pytest.approx(g @ np.linalg.solve(dense, g), rel=1e-10)
    np.testing.assert_allclose(solution.reshape(-1), np.linalg.solve(dense, g), rtol=1e-10)
    # the last Schur complement is the last variable's marginal information
    np.testing.assert_allclose(np.linalg.inv(last), np.linalg.inv(dense)[-2:, -2:], rtol=1e-10)
    # not positive definite: no decrement
    log_det, decrement, last, _ = _block_elimination(-blocks, links, gradient)
    assert np.isnan(log_det) and decrement == np.inf and np.all(np.isnan(last))


def test_chain_fit_decrements_match_gtsam_and_the_exact_hessian() -> None:
    """The Gauss-Newton decrement is GTSAM's linearised cost reduction ``2(E(0) − E(δ*))``
    (random walk: gradient and information assembled over every variable); the Newton one
    uses the exact Hessian ``Λ + Σ e_k ∇²e_k`` (static emitter, dense check)."""
    data = simulate(flight_scenario([0.0, 0.0, 90.0, 90.0]), seed=6)
    frames = frame_models(data)
    steps = step_sigmas_m(frames, 0.3)
    estimates = np.array([[35.9, 15.6], [35.0, 14.1], [34.2, 15.3], [35.6, 15.0]])
    prior_mean = np.array([34.0, 16.0])
    fit = chain_fit(
        frames,
        estimates,
        random_walk=True,
        step_sigmas=steps,
        prior_mean_m=prior_mean,
        prior_sigma_m=50.0,
    )
    graph = graph_part(
        frames,
        0,
        4,
        random_walk=True,
        step_sigmas=steps,
        prior_mean_m=prior_mean,
        prior_sigma_m=50.0,
    )
    linear = graph.linearize(values_of(estimates))
    step = linear.optimize()
    reduction = 2.0 * (linear.error(gtsam.VectorValues.Zero(step)) - linear.error(step))
    assert fit.gauss_newton_decrement == pytest.approx(reduction, rel=1e-8)
    assert fit.decrement == min(fit.gauss_newton_decrement, fit.newton_decrement)
    assert fit.chi2 == pytest.approx(2.0 * graph.error(values_of(estimates)), rel=1e-12)

    point = np.array([35.9, 15.6])
    static = chain_fit(
        frames,
        point,
        random_walk=False,
        step_sigmas=np.empty(0),
        prior_mean_m=prior_mean,
        prior_sigma_m=50.0,
    )
    stacked = FrameModel.stacked(frames)
    e, E = stacked.whitened_error_and_jacobian(point)
    information = E.T @ E + np.eye(2) / 50.0**2
    g = E.T @ e + (point - prior_mean) / 50.0**2
    hessian = information + np.sum(stacked.curvature_terms(point, e), axis=0)
    assert np.all(np.linalg.eigvalsh(hessian) > 0)
    assert static.newton_decrement == pytest.approx(g @ np.linalg.solve(hessian, g), rel=1e-9)
    assert static.gauss_newton_decrement == pytest.approx(
        g @ np.linalg.solve(information, g), rel=1e-9
    )
    np.testing.assert_allclose(static.uniform_hessian, hessian, rtol=1e-12)


# --------------------------------------------------------------------------------------------
# the third-order expansion of the streaming smoother
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_frames", [1, 3], ids=["one frame", "stacked frames"])
def test_row_derivatives_match_the_frame_model_and_central_differences(n_frames: int) -> None:
    """``e`` and ``∇e`` bit for bit as :class:`FrameModel` (a cached linearisation equals a fresh
    one), ``∇²e`` as its Hessian, ``∇³e`` against central differences of that Hessian."""
    frames = frame_models(simulate(flight_scenario(EAST_THEN_NORTH), seed=2))[3 : 3 + n_frames]
    points = np.array([[30.0, 12.0], [41.0, -7.0], [35.5, 15.5]])[:n_frames]
    rows, e, jacobian = _whitened_derivatives(frames, points)
    k = len(frames[0].position_m)

    def frame_rows(values, index):  # frame `index`'s Doppler rows, then its range rows
        n = n_frames * k
        return np.concatenate([values[index * k : (index + 1) * k], values[n + index * k :][:k]])

    for index, frame in enumerate(frames):
        e_ref, jacobian_ref = frame.whitened_error_and_jacobian(points[index])
        assert np.array_equal(frame_rows(e, index), e_ref)
        assert np.array_equal(frame_rows(jacobian, index), jacobian_ref)
        np.testing.assert_array_equal(frame_rows(rows[:, :3], index)[:, 0], e_ref)
        hessian = frame.hessian(points[index]) / frame.sigma[:, None, None]
        second = frame_rows(rows[:, 3:6], index)
        np.testing.assert_allclose(second, hessian.reshape(-1, 4)[:, [0, 1, 3]], rtol=1e-12)
        step = 1e-4
        third = frame_rows(rows[:, 6:10], index)
        for axis in (0, 1):
            shift = step * np.eye(2)[axis]
            numeric = (
                frame.hessian(points[index] + shift) - frame.hessian(points[index] - shift)
            ) / (2 * step * frame.sigma[:, None, None])
            # ∇³e_{ab,axis}: xxx, xxy | xxy, xyy | ... the unique columns hold a+b+c ones
            expected = third[:, [axis, 1 + axis, 1 + axis, 2 + axis]].reshape(-1, 2, 2)
            np.testing.assert_allclose(
                expected, numeric, rtol=1e-6, atol=1e-9 * np.abs(numeric).max()
            )


def test_expansion_is_the_exact_sums_at_its_point_and_third_order_nearby() -> None:
    """At ``θ`` the expansion equals the frames' exact sums; nearby its cost is off by
    ``O(|δ|⁴)`` and its gradient and information by ``O(|δ|³)`` (halving ``δ`` divides the
    errors by ~16 and ~8); the per-frame layout of the random walk matches too."""
    frames = frame_models(simulate(flight_scenario(EAST_THEN_NORTH), seed=12))
    theta = np.array([34.9, 15.1])
    terms, _ = expansion_terms(frames, np.tile(theta, (len(frames), 1)))
    assert terms.shape == (len(frames), N_TERMS)
    static = Expansion(theta[None, :], np.sum(terms, axis=0, keepdims=True))
    exact = data_sums(frames, theta, random_walk=False)
    at_theta = static.at(theta)
    for name in ("chi2", "gradient", "information", "curvature"):
        np.testing.assert_allclose(
            getattr(at_theta, name), getattr(exact, name), rtol=1e-12, atol=1e-12
        )
    errors = []
    for length in (0.02, 0.01):
        point = theta + length * np.array([0.6, -0.8])
        model, truth = static.at(point), data_sums(frames, point, random_walk=False)
        errors.append(
            [
                abs(model.chi2[0] - truth.chi2[0]),
                np.abs(model.gradient - truth.gradient).max(),
                np.abs(model.information - truth.information).max(),
            ]
        )
    (chi2_2, gradient_2, information_2), (chi2_1, gradient_1, information_1) = errors
    assert chi2_1 < 1e-9 and gradient_1 < 1e-6
    assert information_1 < 1e-10 * np.abs(exact.information).max()
    assert 12.0 < chi2_2 / chi2_1 < 20.0
    assert 6.0 < gradient_2 / gradient_1 < 10.0
    assert 6.0 < information_2 / information_1 < 10.0
    # the random walk: one variable per frame, each about its own point
    points = theta + np.linspace(-0.5, 0.5, len(frames))[:, None] * [1.0, -0.5]
    walk = Expansion(points.copy(), expansion_terms(frames, points)[0])
    model, truth = walk.at(points + 0.001), data_sums(frames, points + 0.001, random_walk=True)
    np.testing.assert_allclose(model.gradient, truth.gradient, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(model.information, truth.information, rtol=1e-10)


def test_frame_factor_reads_a_linearisation_only_at_its_point() -> None:
    """A factor given ``(point, e, E)`` returns them when GTSAM asks for exactly that point (a
    doctored copy shows it is read) and evaluates the frame anywhere else."""
    frame = frame_models(simulate(flight_scenario(EAST_THEN_NORTH), seed=1))[5]
    point = np.array([35.0, 15.0])
    e, E = frame.whitened_error_and_jacobian(point)
    linearised = [None, (point.copy(), 2.0 * e, 3.0 * E)]
    factor = frame_factor(frame, X(0), linearised, 1)
    A, b = factor.linearize(values_of(point)).jacobian()
    np.testing.assert_allclose(A, 3.0 * E, rtol=1e-14)
    np.testing.assert_allclose(b, -2.0 * e, rtol=1e-14)
    elsewhere = point + np.array([1e-9, 0.0])
    A, b = factor.linearize(values_of(elsewhere)).jacobian()
    e_there, E_there = frame.whitened_error_and_jacobian(elsewhere)
    np.testing.assert_allclose(A, E_there, rtol=1e-14)
    np.testing.assert_allclose(b, -e_there, rtol=1e-14)
