"""The frame-by-frame (iterated) EKF and UKF with mirror hypotheses (MATH §1, §7, §8, §10)."""

from __future__ import annotations

import itertools
import pickle

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.stats import chi2

from comparison.crlb import fisher_information, rmse_bound_m
from estimators import convergence
from estimators.base import SequentialEstimator
from estimators.convergence import DECREMENT_TOL, iterated_update, map_cost
from estimators.frame_model import FrameModel
from estimators.registry import make_estimator
from estimators.sequential.ekf import Ekf, ekf_update
from estimators.sequential.mirror_hypotheses import (
    DIFFUSE_PRIOR_SCALE,
    diffuse_prior_information,
    first_frame_candidates,
    hypotheses_estimate,
)
from scenarios.catalog import get_scenario, heading_velocities_mps, paper_scenario
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import FlightPlan, MeasurementSet, Scenario

EAST_THEN_NORTH = [0.0] * 4 + [90.0] * 6
"""Headings of the turning test flight: 4 frames east, then 6 frames north (MATH §7)."""


def flight_scenario(headings_deg: list[float], emitter_m=(35.0, 15.0)) -> Scenario:
    """The paper geometry at ``c σ_τ = 1 m`` (``paper-1m``), 10 m/s, K = 10, Δ = 0.05 s."""
    base = paper_scenario(range_sigma_m=1.0, name="paper-1m")
    return base.replace(
        emitter_m=emitter_m,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=heading_velocities_mps(10.0, headings_deg),
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
    )


def frame_ml_m(frames: list[FrameModel], start_m) -> np.ndarray:
    """Maximum likelihood over ``frames`` by scipy (MATH §10), to tight tolerances."""
    result = least_squares(
        lambda s: np.concatenate([f.whitened_error(s) for f in frames]),
        np.asarray(start_m, dtype=float),
        jac=lambda s: np.vstack([f.whitened_jacobian(s) for f in frames]),
        method="lm",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    return result.x


def streamed_states(estimator: Ekf, data: MeasurementSet) -> list:
    state = estimator.init()
    states = []
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
        states.append(state)
    return states


# --------------------------------------------------------------------------------------------
# one update
# --------------------------------------------------------------------------------------------


def frame_after_turn() -> tuple[FrameModel, np.ndarray, np.ndarray]:
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=11)
    frame = FrameModel.from_measurements(list(data.iter_frames())[5])
    prior_mean = np.array([36.0, 14.2])
    prior_covariance = np.array([[0.4, 0.1], [0.1, 0.9]])
    return frame, prior_mean, prior_covariance


def test_single_pass_is_the_kalman_update() -> None:
    """``max_iterations=1``: ``s̄ + K(z − h(s̄))``, ``K = P̄Hᵀ(HP̄Hᵀ + R)⁻¹``, ``P = (I −
    KH)P̄``."""
    frame, prior_mean, prior_covariance = frame_after_turn()
    mean, covariance, report = ekf_update(frame, prior_mean, prior_covariance, max_iterations=1)
    H = frame.jacobian(prior_mean)
    S = H @ prior_covariance @ H.T + np.diag(frame.sigma**2)
    K = prior_covariance @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(
        mean, prior_mean + K @ (frame.measured - frame.predicted(prior_mean)), rtol=1e-12
    )
    np.testing.assert_allclose(covariance, (np.eye(2) - K @ H) @ prior_covariance, rtol=1e-9)
    assert mean.shape == (2,) and report.iterations == 1 and report.converged


def test_iterated_filterpy_update_is_the_posterior_mode() -> None:
    """The IEKF's filterpy passes converge to the Gauss-Newton mode of the frame's posterior."""
    frame, prior_mean, prior_covariance = frame_after_turn()
    mean, covariance, report = ekf_update(frame, prior_mean, prior_covariance, max_iterations=50)
    mode, information, _, mode_report = iterated_update(
        frame, prior_mean, np.linalg.inv(prior_covariance)
    )
    assert 1 < report.iterations < 50 and report.converged and mode_report.converged
    assert report.decrement < 1e-12 and mode_report.decrement < 1e-12
    np.testing.assert_allclose(mean, mode, atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(covariance), information, rtol=1e-7)
    # the single pass stops short of the mode by far more than the IEKF's tolerance
    single, _, _ = ekf_update(frame, prior_mean, prior_covariance, max_iterations=1)
    assert np.linalg.norm(single - mode) > 1e-4


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("estimator", "atol_m"),
    [
        (Ekf(), 1e-6),
        (Ekf(max_iterations=1), 1e-6),
        (Ekf(process_noise_mps=0.1), 1e-6),
        # the unscented mean of h is not h(mean): a bias of ~1 % of the CRLB's σ remains
        (Ekf(filter="ukf"), 2e-3),
    ],
)
def test_noise_free_turn_returns_the_truth(estimator: Ekf, atol_m: float) -> None:
    """Noise-free, east then north: the truth, one hypothesis, not ambiguous (MATH §7)."""
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    estimate = estimator.estimate(data)
    assert estimate.success, estimate.message
    np.testing.assert_allclose(estimate.position_m, [35.0, 15.0], atol=atol_m)
    assert not estimate.ambiguous
    assert estimate.diagnostics["weights"] == (1.0,)
    np.testing.assert_allclose(estimate.candidates_m, [[35.0, 15.0]], atol=atol_m)


def test_noise_free_covariance_is_the_accumulated_crlb() -> None:
    """Static and linearised at the truth, ``P`` is the accumulated ``J⁻¹`` (MATH §8)."""
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    estimate = Ekf().estimate(data)
    bound = np.linalg.inv(fisher_information(data, [35.0, 15.0], "toa+doppler"))
    np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6)


def test_random_walk_covariance_follows_the_information_recursion() -> None:
    """``P_t = ((P_{t−1} + (qΔt)² I)⁻¹ + J_t)⁻¹`` with the frames' Fisher information at the
    truth."""
    q = 0.2
    data = noise_free(flight_scenario(EAST_THEN_NORTH))
    frames = [FrameModel.from_measurements(f) for f in data.iter_frames()]
    truth = np.array([35.0, 15.0])
    length = frames[0].mean_range_m(truth)
    covariance = np.linalg.inv(frames[0].information(truth) + diffuse_prior_information(length))
    for previous, frame in itertools.pairwise(frames):
        step = q * (frame.time_s - previous.time_s)
        predicted = covariance + step**2 * np.eye(2)
        covariance = np.linalg.inv(np.linalg.inv(predicted) + frame.information(truth))
    estimate = Ekf(process_noise_mps=q).estimate(data)
    np.testing.assert_allclose(estimate.covariance_m2, covariance, rtol=1e-6)
    static = Ekf().estimate(data).covariance_m2
    assert np.all(np.linalg.eigvalsh(estimate.covariance_m2 - static) > 0)


def test_straight_track_keeps_both_mirrors_with_exactly_equal_weights() -> None:
    """No turn: two mirror candidates, weights exactly ½/½, ambiguous (MATH §7)."""
    data = simulate(flight_scenario([0.0] * 4), seed=3)
    for estimator in (Ekf(), Ekf(filter="ukf")):
        estimate = estimator.estimate(data)
        assert estimate.success and estimate.ambiguous
        assert estimate.diagnostics["weights"] == (0.5, 0.5)
        first, second = estimate.candidates_m
        np.testing.assert_allclose(second, [first[0], -first[1]], atol=1e-9)
        assert abs(first[1]) > 10.0


def test_single_frame_is_its_maximum_likelihood_with_inverse_fisher_covariance() -> None:
    """One frame: the frame's ML (MATH §10) with the inverse Fisher information (MATH §8)."""
    data = simulate(flight_scenario([0.0]), seed=5)
    estimate = Ekf().estimate(data)
    frame = FrameModel.from_measurements(data)
    assert estimate.ambiguous and len(estimate.candidates_m) == 2
    np.testing.assert_allclose(
        estimate.position_m, frame_ml_m([frame], estimate.position_m + 0.5), atol=1e-6
    )
    np.testing.assert_allclose(
        estimate.covariance_m2, np.linalg.inv(frame.information(estimate.position_m)), rtol=1e-6
    )


@pytest.mark.parametrize("estimator", [Ekf(), Ekf(filter="ukf")])
def test_emitter_on_the_track_is_flagged_not_crashed(estimator: Ekf) -> None:
    """Emitter on the track: the candidates coincide and the cross-track is unobservable."""
    for headings in ([0.0], [0.0] * 4):
        data = noise_free(flight_scenario(headings, emitter_m=(35.0, 0.0)))
        estimate = estimator.estimate(data)
        assert estimate.success and estimate.ambiguous
        np.testing.assert_allclose(estimate.candidates_m, [[35.0, 0.0]], atol=1e-6)
        assert estimate.covariance_m2 is None
        assert estimate.diagnostics["fisher_rank"] == 1
        assert "rank 1" in estimate.message
    turned = noise_free(flight_scenario([0.0] * 4 + [90.0] * 3, emitter_m=(35.0, 0.0)))
    estimate = estimator.estimate(turned)
    assert estimate.success and not estimate.ambiguous
    atol_m = 1e-6 if estimator.filter == "ekf" else 2e-3  # the UKF's bias, as above
    np.testing.assert_allclose(estimate.position_m, [35.0, 0.0], atol=atol_m)
    assert estimate.diagnostics["fisher_rank"] == 2 and estimate.covariance_m2 is not None


@pytest.mark.bits("the position is the first hypothesis of the same state")
def test_rng_breaks_the_mirror_tie_with_a_fair_coin() -> None:
    """On a straight track ``rng`` picks either side; without one, the first hypothesis."""
    estimator = Ekf()
    state = streamed_states(estimator, simulate(flight_scenario([0.0] * 2), seed=8))[-1]
    sides = [
        np.sign(estimator.estimate_state(state, rng=np.random.default_rng(seed)).position_m[1])
        for seed in range(200)
    ]
    assert 70 < sides.count(1.0) < 130
    first = estimator.estimate_state(state)
    np.testing.assert_array_equal(first.position_m, first.candidates_m[0])


@pytest.mark.bits("estimate runs init/update/estimate_state on the same frames")
def test_streaming_equals_batch_and_states_are_values() -> None:
    """``estimate`` equals init/update/estimate_state; an old state is unchanged by updates."""
    estimator = Ekf()
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=2)
    states = streamed_states(estimator, data)
    batch = estimator.estimate(data)
    streamed = estimator.estimate_state(states[-1])
    np.testing.assert_array_equal(batch.position_m, streamed.position_m)
    np.testing.assert_array_equal(batch.covariance_m2, streamed.covariance_m2)
    before = estimator.estimate_state(states[3]).position_m.copy()
    frames = list(data.iter_frames())
    again = estimator.update(states[3], frames[4])
    np.testing.assert_array_equal(estimator.estimate_state(states[3]).position_m, before)
    np.testing.assert_array_equal(
        estimator.estimate_state(again).position_m, estimator.estimate_state(states[4]).position_m
    )
    with pytest.raises(ValueError, match="read-only"):
        states[-1].hypotheses[0].mean_m[0] = 0.0


@pytest.mark.bits("a pickled state continues with the same arrays")
def test_estimator_and_state_pickle() -> None:
    """A pickled mid-stream state continues to the same estimate (worker processes)."""
    estimator = pickle.loads(pickle.dumps(Ekf(filter="ukf", process_noise_mps=0.05)))
    assert isinstance(estimator, SequentialEstimator)
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=4)
    frames = list(data.iter_frames())
    state = estimator.init()
    for frame in frames[:5]:
        state = estimator.update(state, frame)
    copy = pickle.loads(pickle.dumps(state))
    for frame in frames[5:]:
        state = estimator.update(state, frame)
        copy = estimator.update(copy, frame)
    np.testing.assert_array_equal(
        estimator.estimate_state(copy).position_m, estimator.estimate_state(state).position_m
    )


def test_options_and_inputs_are_validated() -> None:
    with pytest.raises(ValueError, match=r"^filter:"):
        Ekf(filter="kalman")
    with pytest.raises(ValueError, match=r"^process_noise_mps:"):
        Ekf(process_noise_mps=-1.0)
    with pytest.raises(ValueError, match=r"^max_iterations:"):
        Ekf(max_iterations=0)
    data = noise_free(flight_scenario([0.0]))
    with pytest.raises(ValueError, match=r"^toa_s:"):
        Ekf().estimate(data.without("toa"))


def test_closed_form_failure_becomes_a_failed_estimate(monkeypatch) -> None:
    def broken(self, data, *, rng=None):
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr("estimators.closed_form.cls.Cls.estimate", broken)
    estimate = Ekf().estimate(noise_free(flight_scenario([0.0] * 2)))
    assert not estimate.success
    assert "closed form failed" in estimate.message
    assert np.all(np.isnan(estimate.position_m))


def test_no_frame_yet_is_a_failed_estimate() -> None:
    estimate = Ekf().estimate_state(Ekf().init())
    assert not estimate.success and "no frame" in estimate.message


def test_diffuse_prior_is_negligible_against_one_frame() -> None:
    """The diffuse prior's information is < 1e−9 of one frame's (its effect on the estimate)."""
    data = noise_free(flight_scenario([0.0]))
    frame = FrameModel.from_measurements(data)
    length = frame.mean_range_m([35.0, 15.0])
    prior = diffuse_prior_information(length)
    assert prior[0, 0] == pytest.approx(1.0 / (DIFFUSE_PRIOR_SCALE * length) ** 2)
    assert prior[0, 0] < 1e-9 * np.linalg.eigvalsh(frame.information([35.0, 15.0]))[0]


# --------------------------------------------------------------------------------------------
# convergence: the iterated updates are checked, with documented fallbacks
# --------------------------------------------------------------------------------------------


def near_track_first_frame() -> tuple[MeasurementSet, FrameModel, np.ndarray, np.ndarray]:
    """Trial 31 of seed 757 at −20 dB: the first frame's minimum lies on the track."""
    data = simulate(get_scenario("paper-1m-turn"), snr_db=-20.0, seed=trial_seeds(757, 500)[31])
    first = data.take(data.frame == 0)
    frame = FrameModel.from_measurements(first)
    start = first_frame_candidates(first)[0]
    return first, frame, start, diffuse_prior_information(frame.mean_range_m(start))


def test_gauss_newton_stuck_near_the_track_is_finished_by_newton() -> None:
    """Gauss-Newton creeps along the on-track valley: after its 50 iterations it was 0.17 m
    short of the first frame's ML (and returned that silently). The report says so, Newton's
    method finishes the update, and the result is the ML to 1e-3 m."""
    first, frame, start, prior = near_track_first_frame()
    mean, _, _, report = iterated_update(frame, start, prior, max_iterations=50)
    assert report.converged and report.decrement <= DECREMENT_TOL
    assert report.fallback == "newton"
    assert "iteration cap (50)" in report.fallback_reason
    assert report.iterations > 50 and report.max_iterations > 50
    ml = make_estimator("ml").estimate(first)
    assert np.min(np.linalg.norm(ml.candidates_m - mean, axis=1)) < 1e-3
    estimate = Ekf().estimate_state(Ekf().update(Ekf().init(), first))
    assert estimate.success
    assert estimate.diagnostics["fallback"] == "newton"
    assert estimate.diagnostics["fallbacks"] == 1
    assert "Newton's method finished it" in estimate.message


def test_gauss_newton_alone_stops_short_near_the_track(monkeypatch) -> None:
    """The same update with the Newton fallback disabled is reported not converged."""
    _, frame, start, prior = near_track_first_frame()

    def no_refinement(frame, prior_mean_m, prior_information, start_m, **_):
        point = np.asarray(start_m, dtype=float)
        return point, map_cost(frame, point, prior_mean_m, prior_information), 0, True

    converged, _, _, _ = iterated_update(frame, start, prior, max_iterations=50)
    monkeypatch.setattr(convergence, "newton_refine", no_refinement)
    stuck, _, _, report = iterated_update(frame, start, prior, max_iterations=50)
    assert not report.converged and report.decrement > DECREMENT_TOL
    assert "iteration cap (50)" in report.reason and "stalled" in report.reason
    assert np.linalg.norm(stuck - converged) > 0.1  # metres short of the minimum


def test_iekf_that_does_not_converge_is_a_failed_estimate(monkeypatch) -> None:
    """Two IEKF passes do not reach the mode at −20 dB; with the fallback disabled the estimate
    fails from that frame on, naming the frame and the cap: never a silent success."""

    def no_refinement(frame, prior_mean_m, prior_information, start_m, **_):
        point = np.asarray(start_m, dtype=float)
        return point, map_cost(frame, point, prior_mean_m, prior_information), 0, True

    monkeypatch.setattr(convergence, "newton_refine", no_refinement)
    data = simulate(get_scenario("paper-1m-turn"), snr_db=-20.0, seed=0)
    states = streamed_states(Ekf(max_iterations=2), data)
    assert Ekf().estimate_state(states[0]).success
    estimate = Ekf(max_iterations=2).estimate_state(states[-1])
    assert not estimate.success and np.all(np.isnan(estimate.position_m))
    assert estimate.message.startswith(
        "frame 1: the iterated EKF update reached its iteration cap (2)"
    )
    monkeypatch.undo()
    rescued = Ekf(max_iterations=2).estimate(data)
    assert rescued.success and rescued.diagnostics["converged"]


def test_converged_update_reports_its_iterations_and_decrement() -> None:
    data = simulate(flight_scenario(EAST_THEN_NORTH), seed=5)
    estimate = Ekf().estimate(data)
    diagnostics = estimate.diagnostics
    assert diagnostics["converged"] and diagnostics["fallback"] == "none"
    assert diagnostics["fallbacks"] == 0 and diagnostics["fallback_reason"] == ""
    assert 1 <= diagnostics["update_iterations"] < diagnostics["max_iterations"] == 20
    assert diagnostics["decrement"] <= DECREMENT_TOL
    assert Ekf(max_iterations=1).estimate(data).diagnostics["decrement"] is None


def test_non_finite_hypothesis_is_a_failed_estimate() -> None:
    """``success=True`` only with finite candidates."""
    estimate = hypotheses_estimate(
        "ekf",
        [[np.nan, 1.0], [35.0, 15.0]],
        [np.eye(2), np.eye(2)],
        [0.0, -1.0],
        [np.eye(2), np.eye(2)],
        straight_track=False,
        length_scale_m=60.0,
    )
    assert not estimate.success and "not finite" in estimate.message


# --------------------------------------------------------------------------------------------
# statistics: the accumulated CRLB after a turn
# --------------------------------------------------------------------------------------------

N_TRIALS = 500


@pytest.mark.slow
@pytest.mark.parametrize("estimator", [Ekf(), Ekf(filter="ukf")], ids=["ekf", "ukf"])
def test_turn_reaches_the_accumulated_crlb_with_honest_covariance(estimator: Ekf) -> None:
    """10 frames of ``paper-1m`` at 0 dB, turn after frame 4, 500 trials.

    RMSE/√CRLB(accumulated, toa+doppler) <= 1.1; no wrong side in any frame after the turn;
    the mean NEES inside the two-sided 95% chi-square band (2 dof, n trials).
    """
    scenario = flight_scenario(EAST_THEN_NORTH)
    truth = scenario.emitter_m
    mirror = np.array([truth[0], -truth[1]])
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(2024, N_TRIALS))
    errors = np.empty((N_TRIALS, 2))
    nees = np.empty(N_TRIALS)
    wrong_side = np.zeros((N_TRIALS, 6), dtype=bool)
    for trial, data in enumerate(batch):
        for frame, state in enumerate(streamed_states(estimator, data)[4:]):
            estimate = estimator.estimate_state(state)
            assert estimate.success and not estimate.ambiguous
            position = estimate.position_m
            wrong_side[trial, frame] = np.linalg.norm(position - mirror) < np.linalg.norm(
                position - truth
            )
        errors[trial] = position - truth
        nees[trial] = errors[trial] @ np.linalg.solve(estimate.covariance_m2, errors[trial])
    bound = rmse_bound_m(fisher_information(batch.geometry, truth, "toa+doppler"))
    ratio = np.sqrt(np.mean(np.sum(errors**2, axis=1))) / bound
    low, high = chi2.ppf([0.025, 0.975], 2 * N_TRIALS) / N_TRIALS
    print(f"{estimator.filter}: RMSE/sqrt(CRLB) = {ratio:.3f}, mean NEES = {nees.mean():.3f}")
    assert ratio <= 1.1
    assert not wrong_side.any()
    assert low <= nees.mean() <= high


def test_step_halving_takes_the_first_lower_halving() -> None:
    """:func:`~estimators.convergence.lower_cost_step` (the halvings after the first trial
    evaluated together) returns what a brute-force loop over ``point + 2⁻ⁱ step`` with
    :func:`map_cost` finds first; a step uphill at every length is a stall (None)."""
    data = simulate(flight_scenario(EAST_THEN_NORTH), snr_db=10.0, seed=3)
    frame = FrameModel.from_measurements(list(data.iter_frames())[5])
    prior_mean = np.array([30.0, 20.0])
    prior_information = np.eye(2) * 1e-4
    point = np.array([34.0, 16.0])
    cost = map_cost(frame, point, prior_mean, prior_information)
    e, E = frame.whitened_error_and_jacobian(point)
    gauss_newton = -np.linalg.solve(
        prior_information + E.T @ E, E.T @ e + prior_information @ (point - prior_mean)
    )
    for scale in (1.0, 300.0, 1e5):  # the first trial, a few halvings, many
        step = scale * gauss_newton
        costs = [
            map_cost(frame, point + step * 0.5**i, prior_mean, prior_information)
            for i in range(convergence.HALVINGS)
        ]
        first = next(i for i, c in enumerate(costs) if c <= cost)
        trial, trial_cost, taken = convergence.lower_cost_step(
            frame, prior_mean, prior_information, point, step, cost
        )
        np.testing.assert_allclose(taken, step * 0.5**first, rtol=1e-15)
        np.testing.assert_allclose(trial, point + step * 0.5**first, rtol=1e-15)
        assert trial_cost == pytest.approx(costs[first], rel=1e-12)
        assert scale == 1.0 or first > 0
    at_minimum = frame_ml_m([frame], point)
    uphill = convergence.lower_cost_step(
        frame,
        at_minimum,
        np.zeros((2, 2)),
        at_minimum,
        gauss_newton,
        map_cost(frame, at_minimum, at_minimum, np.zeros((2, 2))) * (1.0 - 1e-9),
    )
    assert uphill is None


def test_update_finish_reuses_the_derivatives_it_is_given() -> None:
    """:func:`~estimators.convergence.finish_update` with the cost derivatives already formed
    at the point returns exactly what it returns forming them itself (the same arrays)."""
    data = simulate(flight_scenario(EAST_THEN_NORTH), snr_db=0.0, seed=5)
    frame = FrameModel.from_measurements(list(data.iter_frames())[4])
    prior_mean, prior_information = np.array([33.0, 17.0]), np.eye(2) * 0.05
    point, information, _, report = iterated_update(frame, prior_mean, prior_information)
    cost = map_cost(frame, point, prior_mean, prior_information)
    derivatives = convergence.cost_derivatives(frame, prior_mean, prior_information, point)
    given = convergence.finish_update(
        frame, prior_mean, prior_information, point, cost, report, derivatives=derivatives
    )
    formed = convergence.finish_update(frame, prior_mean, prior_information, point, cost, report)
    assert report.converged
    np.testing.assert_array_equal(given[0], formed[0])
    assert given[1] == formed[1] and given[3] == formed[3]
    np.testing.assert_array_equal(given[2], formed[2])
    np.testing.assert_array_equal(given[2], information)  # what iterated_update returned
