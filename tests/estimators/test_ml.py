"""Maximum likelihood (MATH §10): exact noise-free, brute-force optima, Jacobian, CRLB
efficiency."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest
from scipy.optimize import minimize

from comparison.crlb import crlb_m2, fisher_information
from estimators.ml.minpack_batch import LmderBatch
from estimators.ml.ml import MaximumLikelihood, whitened_residual_jacobian, whitened_residuals
from estimators.ml.ml_batch import SharedContext, distinct_minima
from estimators.ml.ml_batch_starts import doppler_frame_starts
from estimators.ml.ml_starts import ranges_uninformative
from estimators.registry import make_estimator
from scenarios.catalog import get_scenario
from scenarios.geometry import cross_track_m
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import MeasurementBatch

MIRROR_M = np.array([35.0, -15.0])


def _nearest(candidates_m: np.ndarray, point_m: np.ndarray) -> np.ndarray:
    return candidates_m[np.argmin(np.linalg.norm(candidates_m - point_m, axis=1))]


def _brute_force_minimum(data, centre_m, half_width_m, *, use_rss=False):
    """Global minimiser of ‖e‖²: a 1 m grid, then Nelder-Mead from each of its local minima.

    Independent of the estimator's Gauss-Newton machinery: the grid finds every basin wider
    than a metre, the derivative-free polish reaches the bottom of each.
    """
    axis = np.arange(-half_width_m, half_width_m + 0.5, 1.0)
    grid = np.stack(np.meshgrid(centre_m[0] + axis, centre_m[1] + axis), axis=-1)
    grid_cost = np.sum(whitened_residuals(data, grid, use_rss=use_rss) ** 2, axis=-1)
    padded = np.pad(grid_cost, 1, constant_values=np.inf)
    neighbours = [
        padded[1 + di : 1 + di + len(axis), 1 + dj : 1 + dj + len(axis)]
        for di in (-1, 0, 1)
        for dj in (-1, 0, 1)
        if di or dj
    ]
    is_local_minimum = np.all([grid_cost <= other for other in neighbours], axis=0)

    def cost(point):
        return float(np.sum(whitened_residuals(data, point, use_rss=use_rss) ** 2))

    best_point, best_cost = None, np.inf
    for node in grid[is_local_minimum]:
        result = minimize(cost, node, method="Nelder-Mead", options={"xatol": 1e-9, "fatol": 1e-13})
        if result.fun < best_cost:
            best_point, best_cost = result.x, float(result.fun)
    return best_point, best_cost


# --------------------------------------------------------------------------------------------
# noise-free answers
# --------------------------------------------------------------------------------------------


def test_ml_noise_free_straight_frame_returns_the_mirror_pair():
    data = noise_free(get_scenario("paper-1m"))
    estimate = MaximumLikelihood().estimate(data, rng=np.random.default_rng(0))
    assert estimate.success
    assert estimate.ambiguous
    assert len(estimate.candidates_m) == 2
    np.testing.assert_allclose(_nearest(estimate.candidates_m, [35.0, 15.0]), [35, 15], atol=1e-6)
    np.testing.assert_allclose(_nearest(estimate.candidates_m, MIRROR_M), MIRROR_M, atol=1e-6)
    assert estimate.diagnostics["cost"] < 1e-12


@pytest.mark.parametrize("name", ["turn", "orbit"])
@pytest.mark.parametrize("use_rss", [False, True])
def test_ml_noise_free_two_headings_is_exact_and_unique(name, use_rss):
    scenario = get_scenario(name)
    data = noise_free(scenario)
    estimate = MaximumLikelihood(use_rss=use_rss).estimate(data)
    assert estimate.success
    assert not estimate.ambiguous
    assert len(estimate.candidates_m) == 1
    np.testing.assert_allclose(estimate.position_m, scenario.emitter_m, atol=1e-6)


def test_ml_with_rss_noise_free_straight_frame_keeps_the_pair():
    data = noise_free(get_scenario("paper-1m"))
    estimate = MaximumLikelihood(use_rss=True, side_prior_m=(30.0, -10.0)).estimate(data)
    assert estimate.ambiguous
    np.testing.assert_allclose(estimate.position_m, MIRROR_M, atol=1e-6)


@pytest.mark.parametrize("use_rss", [False, True])
def test_ml_covariance_is_the_inverse_fisher_information(use_rss):
    scenario = get_scenario("turn")
    data = noise_free(scenario, snr_db=10.0)
    estimate = MaximumLikelihood(use_rss=use_rss).estimate(data)
    modalities = ("doppler", "toa", "rss") if use_rss else ("doppler", "toa")
    expected = crlb_m2(fisher_information(data, scenario.emitter_m, modalities))
    np.testing.assert_allclose(estimate.covariance_m2, expected, rtol=1e-8)


def test_doppler_frame_starts_are_exact_on_noise_free_data():
    data = noise_free(get_scenario("paper"))  # c σ_τ = 300 km: the starts ignore the ranges
    context = SharedContext.of(MaximumLikelihood(), MeasurementBatch.of_one(data))
    starts, present = doppler_frame_starts(context, np.arange(1))
    assert present[0]
    np.testing.assert_allclose(starts[0], [[35.0, 15.0], [35.0, -15.0]], atol=1e-9)
    estimate = MaximumLikelihood(doppler_start=True).estimate(data)
    np.testing.assert_allclose(_nearest(estimate.candidates_m, [35.0, 15.0]), [35, 15], atol=1e-6)


def test_ml_auto_doppler_start_only_when_the_ranges_are_useless():
    paper, paper_1m = noise_free(get_scenario("paper")), noise_free(get_scenario("paper-1m"))
    # geometry size √(mean spread² + 50²) ≈ 50 m against c σ_τ = 300 km and 1 m
    assert ranges_uninformative(paper)
    assert not ranges_uninformative(paper_1m)
    assert not ranges_uninformative(noise_free(get_scenario("paper-1m"), snr_db=-30.0))  # 32 m
    assert ranges_uninformative(noise_free(get_scenario("paper-1m"), snr_db=-40.0))  # 100 m
    # paper at 0 dB, trial 0 of seed 9: the CLS start lies ~300 km out; from it alone the search
    # ends in a distant local minimum, the Doppler start reaches the emitter's basin
    data = simulate(get_scenario("paper"), snr_db=0.0, seed=trial_seeds(9, 1)[0])
    only_cls = MaximumLikelihood(doppler_start=False).estimate(data)
    auto = MaximumLikelihood().estimate(data)
    assert auto.diagnostics["cost"] < only_cls.diagnostics["cost"]
    assert np.min(np.linalg.norm(auto.candidates_m - [35.0, 15.0], axis=1)) < 30.0


def test_ml_falls_back_to_lls_toa_when_the_cls_cannot_start():
    # a hovering first frame: the Doppler rows of the CLS need a moving UAV, the ML does not
    scenario = get_scenario("orbit")
    data = noise_free(scenario)
    first = data.frame == data.frame[0]
    velocity, position = np.array(data.velocity_mps), np.array(data.position_m)
    doppler, toa, rss = np.array(data.doppler_hz), np.array(data.toa_s), np.array(data.rss_dbm)
    velocity[first] = 0.0
    doppler[first] = 0.0
    position[first], toa[first], rss[first] = position[0], toa[0], rss[0]
    hovering = dataclasses.replace(
        data,
        velocity_mps=velocity,
        position_m=position,
        doppler_hz=doppler,
        toa_s=toa,
        rss_dbm=rss,
    )
    estimate = MaximumLikelihood().estimate(hovering)
    assert estimate.success
    assert estimate.diagnostics["start_method"] == "lls-toa"
    assert "started from LLS-ToA" in estimate.message
    np.testing.assert_allclose(estimate.position_m, scenario.emitter_m, atol=1e-6)
    failed = MaximumLikelihood(fallback_lls=False).estimate(hovering)
    assert not failed.success
    assert failed.message.startswith("no starting point: CLS failed (velocity_mps:")
    assert np.all(np.isnan(failed.position_m))


# --------------------------------------------------------------------------------------------
# the objective: Jacobian and brute-force optima
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("use_rss", [False, True])
def test_whitened_jacobian_matches_central_differences(use_rss):
    data = simulate(get_scenario("turn"), snr_db=0.0, seed=5)
    points = np.random.default_rng(8).uniform([-20.0, -40.0], [80.0, 60.0], size=(6, 2))
    step = 1e-5
    analytic = whitened_residual_jacobian(data, points, use_rss=use_rss)
    for axis in range(2):
        shift = np.zeros(2)
        shift[axis] = step
        plus = whitened_residuals(data, points + shift, use_rss=use_rss)
        minus = whitened_residuals(data, points - shift, use_rss=use_rss)
        numeric = (plus - minus) / (2.0 * step)
        scale = np.max(np.abs(analytic[..., axis]))
        np.testing.assert_allclose(analytic[..., axis], numeric, rtol=0, atol=1e-6 * scale)


@pytest.mark.parametrize(
    ("name", "snr_db", "trials"),
    [
        ("paper-10m", 0.0, range(6)),  # trials 1 and 4 have their minimum on the track
        ("turn", -10.0, range(6)),
    ],
)
def test_ml_reaches_the_brute_force_global_minimum(name, snr_db, trials):
    scenario = get_scenario(name)
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(1, max(trials) + 1))
    estimator = MaximumLikelihood()
    on_track = 0
    for index in trials:
        data = batch.trial(index)
        estimate = estimator.estimate(data)
        point, cost = _brute_force_minimum(data, data.position_m[:, :2].mean(axis=0), 100.0)
        assert estimate.success
        assert estimate.diagnostics["cost"] == pytest.approx(cost, rel=1e-7, abs=1e-9)
        assert estimate.diagnostics["cost"] <= cost * (1.0 + 1e-12)
        assert np.linalg.norm(_nearest(estimate.candidates_m, point) - point) < 1e-2
        on_track += int(len(estimate.candidates_m) == 1 and estimate.ambiguous)
    if name == "paper-10m":
        assert on_track >= 2  # the on-track branch of MATH §5 was exercised


def test_one_minimum_from_two_starts_keeps_the_earlier_start_at_a_tie():
    """``paper-10m`` trial 4: the on-plane CLS start ends on the plane, its off-plane copy
    0.2 µm off it at a cost lower by rounding only (3e-15 relative); within ``xtol`` the
    costs are one cost and the earlier start's point is kept: one on-track candidate."""
    data = simulate_trials(get_scenario("paper-10m"), snr_db=0.0, seeds=trial_seeds(1, 5)).trial(4)
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.diagnostics["n_starts"] == 2 and estimate.diagnostics["n_minima"] == 1
    assert len(estimate.candidates_m) == 1 and estimate.ambiguous
    assert estimate.position_m[1] == 0.0  # the track is the x axis
    points = np.array([[[0.0, 0.0], [1e-7, 0.0], [5.0, 0.0]]])
    context = types.SimpleNamespace(estimator=MaximumLikelihood(), line=None)  # no flat tie
    valid, scale, trials = np.ones((1, 3), dtype=bool), np.ones(1), np.zeros(1, dtype=np.int64)
    tied = np.array([[2.0 + 1e-12, 2.0, 1.0]])
    found = distinct_minima(context, trials, points.copy(), tied, valid, scale)
    assert found[2][0] == 2
    np.testing.assert_array_equal(found[0][0, :2], [[5.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(found[1][0, :2], [1.0, 2.0 + 1e-12])
    apart = np.array([[2.0 + 1e-9, 2.0, 1.0]])
    found = distinct_minima(context, trials, points.copy(), apart, valid, scale)
    assert found[2][0] == 2
    np.testing.assert_array_equal(found[0][0, :2], [[5.0, 0.0], [1e-7, 0.0]])


def test_a_minimum_and_the_mirror_image_of_another_are_one_minimum():
    """On a straight track a start that crossed it ends at the mirror image of another start's
    minimum, 4e-8 m from it in ``paper`` (the search's tolerance, not rounding): within
    ``COINCIDENT_RTOL`` of the scale that is one minimum, the cheaper kept, and the mirror rule
    then gives the pair once (two candidates, not four whose count depends on rounding)."""
    origin, direction = np.array([10.0, 2.0]), np.array([0.6, 0.8])
    context = types.SimpleNamespace(estimator=MaximumLikelihood(), line=(origin, direction))
    a = np.array([36.0, -21.5])
    image = origin + 2.0 * ((a - origin) @ direction) * direction - (a - origin)
    near_image = image + np.array([3e-8, -2.5e-8])  # 3.9e-8 m from it
    other = np.array([5.0, 40.0])
    points = np.array([[near_image, a, other]])
    costs = np.array([[12.5, 12.0, 13.0]])  # apart: no flat valley to test
    valid, trials = np.ones((1, 3), dtype=bool), np.zeros(1, dtype=np.int64)
    scale = np.array([36.0])  # threshold 3.6e-5 m
    found, found_costs, count = distinct_minima(context, trials, points, costs, valid, scale)
    assert count[0] == 2
    np.testing.assert_array_equal(found[0, :2], [a, other])
    np.testing.assert_array_equal(found_costs[0, :2], [12.0, 13.0])
    # at a cost tie the image on the left of the track (the starts' side) is kept, whichever
    # ends cheaper by rounding: the mirror rule's candidates come in one order
    tied = np.array([[12.0 * (1.0 + 1e-14), 12.0, 13.0]])  # a, on the right, cheaper
    found, found_costs, count = distinct_minima(context, trials, points.copy(), tied, valid, scale)
    assert count[0] == 2
    np.testing.assert_array_equal(found[0, :2], [near_image, other])
    np.testing.assert_array_equal(found_costs[0, :2], [tied[0, 0], 13.0])
    assert cross_track_m(near_image, origin, direction) > 0.0 > cross_track_m(a, origin, direction)
    # off the mirror image by more than the tolerance: two minima of their own
    points = np.array([[image + 1e-4, a, other]])
    assert distinct_minima(context, trials, points, costs, valid, scale)[2][0] == 3
    # no straight track: no mirror images
    context.line = None
    points = np.array([[near_image, a, other]])
    assert distinct_minima(context, trials, points, costs, valid, scale)[2][0] == 3


# --------------------------------------------------------------------------------------------
# input checking
# --------------------------------------------------------------------------------------------


def test_ml_requires_doppler_and_toa():
    data = noise_free(get_scenario("turn"))
    with pytest.raises(ValueError, match=r"^doppler_hz: estimator 'ml'"):
        MaximumLikelihood().estimate(data.without("doppler"))
    with pytest.raises(ValueError, match=r"^toa_s: estimator 'ml'"):
        MaximumLikelihood().estimate(data.without("toa"))
    with pytest.raises(ValueError, match=r"^rss_dbm: estimator 'ml' with use_rss=True"):
        MaximumLikelihood(use_rss=True).estimate(data.without("rss"))


def test_ml_options_are_validated():
    with pytest.raises(ValueError, match=r"^frames:"):
        MaximumLikelihood(frames="first")
    with pytest.raises(ValueError, match=r"^cost_rtol:"):
        MaximumLikelihood(cost_rtol=-1.0)
    with pytest.raises(ValueError, match=r"^doppler_start:"):
        MaximumLikelihood(doppler_start="always")
    with pytest.raises(ValueError, match=r"^method:"):
        MaximumLikelihood(method="bfgs")
    with pytest.raises(ValueError, match=r"^side_prior_m:"):
        MaximumLikelihood(side_prior_m=(1.0, np.nan))
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match=r"^max_nfev:"):
            MaximumLikelihood(max_nfev=bad)
    assert isinstance(make_estimator("ml", frames="last"), MaximumLikelihood)


def test_ml_frames_last_on_a_turn_is_ambiguous_again():
    scenario = get_scenario("turn")
    estimate = MaximumLikelihood(frames="last").estimate(noise_free(scenario))
    assert estimate.ambiguous
    assert estimate.diagnostics["n_samples"] == 10
    np.testing.assert_allclose(
        _nearest(estimate.candidates_m, scenario.emitter_m), scenario.emitter_m, atol=1e-6
    )


# --------------------------------------------------------------------------------------------
# convergence: success only from starts that converged
# --------------------------------------------------------------------------------------------


def _low_snr_turn():
    return simulate(get_scenario("paper-1m-turn"), snr_db=-20.0, seed=trial_seeds(757, 500)[0])


def test_ml_reports_every_start_converged_by_tolerance():
    estimate = MaximumLikelihood().estimate(_low_snr_turn())
    assert estimate.success
    statuses = estimate.diagnostics["lm_status"]
    assert len(statuses) == estimate.diagnostics["n_starts"] == estimate.diagnostics["n_converged"]
    assert all(
        s in ("converged (gtol)", "converged (ftol)", "converged (xtol)", "converged (ftol+xtol)")
        for s in statuses
    )
    assert estimate.diagnostics["max_nfev"] == 200


@pytest.mark.parametrize("max_nfev", [1, 3])
def test_ml_at_its_iteration_cap_is_a_failed_estimate(max_nfev):
    """Levenberg-Marquardt stopped by the evaluation cap has not converged: a failed estimate
    with the status, never the last iterate as a success."""
    estimate = MaximumLikelihood(max_nfev=max_nfev).estimate(_low_snr_turn())
    assert not estimate.success and np.all(np.isnan(estimate.position_m))
    assert "did not converge from any start" in estimate.message
    assert estimate.diagnostics["lm_status"] == [f"iteration cap (max_nfev={max_nfev})"]
    assert estimate.diagnostics["n_converged"] == 0
    assert MaximumLikelihood(max_nfev=8).estimate(_low_snr_turn()).success


def test_ml_stalled_away_from_a_minimum_is_not_converged(monkeypatch):
    """A tolerance met where the gradient is not zero (a collapsed trust region) is a stall:
    the decrement at the point exceeds ``DECREMENT_TOL`` and the start gives no minimum."""
    import estimators.ml.ml_batch as ml_batch

    def stalls_at_the_start(residuals, jacobian, x0, **kwargs):
        everyone = np.arange(len(x0))
        fvec = residuals(everyone, np.asarray(x0, dtype=float))
        info = np.full(len(x0), 2)  # xtol
        ones = np.ones(len(x0), dtype=np.int64)
        return LmderBatch(
            x=np.array(x0, dtype=float), fvec=fvec, info=info, nfev=ones, odd=info < 0
        )

    monkeypatch.setattr(ml_batch, "lmder_batch", stalls_at_the_start)
    estimate = MaximumLikelihood().estimate(_low_snr_turn())
    assert not estimate.success
    assert estimate.diagnostics["lm_status"][0].startswith("stalled (xtol, decrement")
    assert "not at a minimum" in estimate.message


def test_ml_fails_when_an_unconverged_start_ends_below_the_minima(monkeypatch):
    """If a start that hit its cap ended lower than every converged minimum, the reported
    optimum is not the best the data allow: a failure, not a success."""
    import estimators.ml.ml_batch as ml_batch

    real = ml_batch.lmder_batch

    def second_start_capped_lower(residuals, jacobian, x0, **kwargs):
        result = real(residuals, jacobian, x0, **kwargs)
        fvec, info = result.fvec.copy(), result.info.copy()
        fvec[:, 1], info[1] = 0.0, 5
        return dataclasses.replace(result, fvec=fvec, info=info)

    data = simulate(get_scenario("turn"), snr_db=0.0, seed=4)
    estimator = MaximumLikelihood(doppler_start=True)  # the CLS start plus the Doppler pair
    assert estimator.estimate(data).diagnostics["n_starts"] >= 2
    monkeypatch.setattr(ml_batch, "lmder_batch", second_start_capped_lower)
    estimate = estimator.estimate(data)
    assert not estimate.success
    assert "a start that did not converge ended below every converged minimum" in estimate.message


# --------------------------------------------------------------------------------------------
# efficiency at high SNR
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(("name", "snr_db"), [("paper-1m", 30.0), ("turn", 20.0)])
def test_ml_attains_the_crlb_at_high_snr(name, snr_db):
    n = 2000
    scenario = get_scenario(name)
    truth = scenario.emitter_m
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(20262, n))
    estimator = MaximumLikelihood()
    estimates = [estimator.estimate(data) for data in batch]
    assert all(e.success for e in estimates)
    errors = np.array([_nearest(e.candidates_m, truth) - truth for e in estimates])
    bound = crlb_m2(fisher_information(batch.geometry, truth, "toa+doppler"))
    sample = np.cov(errors, rowvar=False)
    # sample variance of n Gaussian draws: relative standard deviation √(2/(n − 1))
    relative = 4.0 * np.sqrt(2.0 / (n - 1))
    np.testing.assert_allclose(np.diag(sample), np.diag(bound), rtol=relative)
    trace_sd = np.sqrt(2.0 * np.trace(bound @ bound) / (n - 1))
    assert abs(np.trace(sample) - np.trace(bound)) < 4.0 * trace_sd
    # unbiased to Monte Carlo precision
    assert np.all(np.abs(errors.mean(axis=0)) < 4.0 * np.sqrt(np.diag(bound) / n))
    # the reported covariance (Fisher information at the estimate) is the CRLB to first order
    reported = np.mean([e.covariance_m2 for e in estimates], axis=0)
    np.testing.assert_allclose(np.diag(reported), np.diag(bound), rtol=0.02)
