"""The SDP relaxation of the CLS (MATH §11) against the closed form (MATH §5) and exact truths."""

from __future__ import annotations

import pickle
from dataclasses import replace

import cvxpy as cp
import numpy as np
import pytest

import estimators.sdp_cls as sdp_cls
from estimators.cls import Cls, cls_rows
from estimators.cls_rows import LocalFrame
from estimators.gtrs import constrained_cost, solve_gtrs
from estimators.sdp_cls import (
    SdpCls,
    compress_rows,
    relaxation_problem,
    solve_sdp_relaxation,
)
from scenarios.catalog import get_scenario
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.simulate import noise_free, simulate

SCENARIOS = ("paper-1m", "paper-10m", "turn", "orbit")


def local_rows(data, rows="weighted"):
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    return frame, A, b


# --------------------------------------------------------------------------------------------
# the pure solve against the closed form
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SCENARIOS)
@pytest.mark.parametrize("rows", ["weighted", "per-sample"])
def test_sdp_optimum_equals_closed_form(name, rows):
    """Equal optimal values (rel. 1e-6), equal argmins or mirror pairs (1e-3 of the scale)."""
    scenario = get_scenario(name)
    for seed in range(3):
        data = simulate(scenario, snr_db=10.0, seed=seed)
        _, A, b = local_rows(data, rows)
        closed = solve_gtrs(A, b)
        sdp = solve_sdp_relaxation(A, b)
        assert sdp.status == "optimal"
        best = closed.costs.min()
        assert abs(sdp.value - best) <= 1e-6 * best
        # every recovered point is a minimiser: its CLS cost equals the optimum
        np.testing.assert_allclose(constrained_cost(A, b, sdp.points[:, :2]), sdp.costs, rtol=1e-12)
        assert abs(sdp.costs.min() - best) <= 1e-6 * best
        assert len(sdp.points) == len(closed.points)
        distance = np.linalg.norm(sdp.points[:, None, :2] - closed.points[None, :, :2], axis=-1)
        assert distance.min(axis=0).max() <= 1e-3
        assert distance.min(axis=1).max() <= 1e-3
        assert sdp.rank == (2 if closed.hard_case else 1)


@pytest.mark.parametrize("name", ["turn", "orbit"])
def test_dual_multiplier_is_the_closed_form_lambda(name):
    """The dual of the lifted constraint is λ* of MATH §5 (same sign convention)."""
    for seed in range(3):
        _, A, b = local_rows(simulate(get_scenario(name), snr_db=10.0, seed=seed))
        closed = solve_gtrs(A, b)
        sdp = solve_sdp_relaxation(A, b)
        assert not closed.hard_case
        assert sdp.multiplier == pytest.approx(closed.multiplier, rel=1e-3)


def test_hard_case_lift_is_rank_two_mixture_of_the_mirror_pair():
    """One straight frame: Z has two nonzero eigenvalues and y lies between the pair."""
    _, A, b = local_rows(simulate(get_scenario("paper-1m"), snr_db=10.0, seed=4))
    closed = solve_gtrs(A, b)
    sdp = solve_sdp_relaxation(A, b)
    assert closed.hard_case and sdp.rank == 2
    z = sdp.z_eigenvalues
    assert z[1] > 1e-3 * z[0] and abs(z[2]) < 1e-6 * z[0]
    first, second = closed.points[:, :2]
    y = sdp.relaxed_point[:2]
    # y = α p₁ + (1 − α) p₂ with α in [0, 1]: on the segment, not on the paraboloid
    along = (y - second) @ (first - second) / ((first - second) @ (first - second))
    assert 0.0 <= along <= 1.0
    np.testing.assert_allclose(second + along * (first - second), y, atol=1e-6)
    assert sdp.tightness_gap == pytest.approx(0.0, abs=1e-8)


def test_qr_compression_keeps_the_cost():
    """‖A r − b‖² = ‖R r − c‖² + ρ² for any r; R is 3×3 whatever the number of rows."""
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=0.0, seed=1))
    R, c, residual_sq = compress_rows(A, b)
    assert R.shape == (3, 3) and c.shape == (3,)
    for r in np.random.default_rng(0).normal(size=(5, 3)):
        full = np.sum((A @ r - b) ** 2)
        assert np.sum((R @ r - c) ** 2) + residual_sq == pytest.approx(full, rel=1e-10)


def test_malformed_rows_raise_value_error_naming_the_field():
    A = np.ones((4, 3))
    with pytest.raises(ValueError, match=r"^A: "):
        solve_sdp_relaxation(np.ones((4, 2)), np.ones(4))
    with pytest.raises(ValueError, match=r"^b: "):
        solve_sdp_relaxation(A, np.ones(3))
    A[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"^A/b: "):
        solve_sdp_relaxation(A, np.ones(4))
    with pytest.raises(ValueError, match=r"^relaxation: "):
        relaxation_problem("convex")


# --------------------------------------------------------------------------------------------
# the inequality relaxation: tight iff λ* >= 0
# --------------------------------------------------------------------------------------------


def biased_range_rows(bias_m):
    """Noise-free turn data whose ranges are all off by ``bias_m`` (unweighted rows)."""
    exact = noise_free(get_scenario("turn"))
    biased = replace(exact, toa_s=exact.toa_s + bias_m / exact.speed_of_light_mps)
    _, A, b = local_rows(biased, "per-sample")
    return A, b


def test_inequality_relaxation_is_not_tight_when_lambda_is_negative():
    """Ranges too long put the LS point inside the paraboloid: λ* < 0, r_z ≥ ‖y‖² is loose."""
    A, b = biased_range_rows(+5.0)
    closed = solve_gtrs(A, b)
    assert closed.multiplier < 0.0
    best = closed.costs.min()
    inequality = solve_sdp_relaxation(A, b, relaxation="inequality")
    equality = solve_sdp_relaxation(A, b, relaxation="equality")
    assert inequality.status == equality.status == "optimal"
    assert abs(equality.value - best) <= 1e-6 * best
    assert inequality.value < best * (1.0 - 1e-2)
    # it returns the unconstrained LS point, strictly inside the paraboloid
    r_ls = np.linalg.lstsq(A, b, rcond=None)[0]
    np.testing.assert_allclose(inequality.relaxed_point, r_ls, atol=1e-6)
    assert r_ls[2] - r_ls[:2] @ r_ls[:2] > 1e-3
    assert inequality.tightness_gap > 1e-2
    assert inequality.multiplier == pytest.approx(0.0, abs=1e-6 * abs(closed.multiplier))


def test_inequality_relaxation_is_tight_when_lambda_is_positive():
    """Ranges too short: λ* > 0, the inequality is active and both relaxations are exact."""
    A, b = biased_range_rows(-5.0)
    closed = solve_gtrs(A, b)
    assert closed.multiplier > 0.0
    best = closed.costs.min()
    for relaxation in ("inequality", "equality"):
        sdp = solve_sdp_relaxation(A, b, relaxation=relaxation)
        assert sdp.status == "optimal"
        assert abs(sdp.value - best) <= 1e-6 * best
        assert sdp.rank == 1
        np.testing.assert_allclose(sdp.points[0, :2], closed.points[0, :2], atol=1e-6)
        assert sdp.multiplier == pytest.approx(closed.multiplier, rel=1e-3)


def test_estimator_flags_a_loose_inequality_relaxation():
    exact = noise_free(get_scenario("turn"))
    biased = replace(exact, toa_s=exact.toa_s + 5.0 / exact.speed_of_light_mps)
    estimate = SdpCls(relaxation="inequality", weighting="none").estimate(biased)
    assert estimate.success
    assert "not tight" in estimate.message
    assert estimate.diagnostics["tightness_gap"] > 1e-2
    assert estimate.diagnostics["constraint_residual"] < 0.0


# --------------------------------------------------------------------------------------------
# the estimator: noise-free truths, agreement with cls, failure paths
# --------------------------------------------------------------------------------------------


def test_noise_free_turn_returns_the_truth_alone():
    data = noise_free(get_scenario("turn"), snr_db=20.0)
    estimate = SdpCls().estimate(data)
    assert estimate.success and not estimate.ambiguous
    assert estimate.candidates_m.shape == (1, 2)
    np.testing.assert_allclose(estimate.position_m, data.truth_emitter_m, atol=1e-5)
    assert estimate.diagnostics["rank"] == 1


@pytest.mark.parametrize("weighting", ["optimal", "none"])
def test_noise_free_straight_frame_returns_both_mirror_candidates(weighting):
    data = noise_free(get_scenario("paper-1m"), snr_db=20.0)
    estimate = SdpCls(weighting=weighting).estimate(data)
    assert estimate.success and estimate.ambiguous
    line = straight_track_line(data.position_m, data.velocity_mps)
    truths = np.array([data.truth_emitter_m, mirror_across_line(data.truth_emitter_m, *line)])
    np.testing.assert_allclose(truths, [[35.0, 15.0], [35.0, -15.0]], atol=1e-9)
    assert estimate.candidates_m.shape == (2, 2)
    distance = np.linalg.norm(estimate.candidates_m[:, None] - truths[None], axis=-1)
    assert distance.min(axis=0).max() < 1e-5
    assert estimate.diagnostics["rank"] == 2
    # recovered from the rank-two lift itself, not only by the mirror rule of MATH §7
    assert "mirror pair recovered" in estimate.message


@pytest.mark.parametrize("name", ["paper-1m", "turn", "orbit"])
def test_estimator_agrees_with_cls_two_stage_weighting(name):
    data = simulate(get_scenario(name), snr_db=5.0, seed=11)
    sdp = SdpCls().estimate(data)
    closed = Cls().estimate(data)
    assert sdp.success and sdp.diagnostics["stages"] == 2
    scale = LocalFrame.fit(data.position_m, data.range_m).scale_m
    distance = np.linalg.norm(sdp.candidates_m[:, None] - closed.candidates_m[None], axis=-1)
    assert sdp.candidates_m.shape == closed.candidates_m.shape
    assert distance.min(axis=0).max() <= 1e-4 * scale


def test_side_prior_picks_the_nearer_mirror_candidate():
    data = simulate(get_scenario("paper-1m"), snr_db=10.0, seed=2)
    estimate = SdpCls(side_prior_m=(30.0, -10.0)).estimate(data)
    assert estimate.position_m[1] < 0.0


def test_max_iter_one_gives_a_failed_estimate_with_the_status():
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    estimate = SdpCls(max_iter=1).estimate(data)
    assert not estimate.success
    assert np.all(np.isnan(estimate.position_m)) and len(estimate.candidates_m) == 0
    assert "user_limit" in estimate.message and "max_iter" in estimate.message
    assert estimate.diagnostics["status"] == "user_limit"
    # the limit does not leak into the next solve of the shared problem
    assert SdpCls().estimate(data).success


def test_solver_error_gives_a_failed_estimate(monkeypatch):
    def broken_solve(self, *args, **kwargs):
        raise cp.error.SolverError("numerical trouble")

    monkeypatch.setattr(cp.Problem, "solve", broken_solve)
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert not estimate.success
    assert "solver_error" in estimate.diagnostics["status"]
    assert "numerical trouble" in estimate.message


def test_malformed_problem_gives_a_failed_estimate(monkeypatch):
    def nan_rows(data, frame, rows, **kwargs):
        A, b = cls_rows(data, frame, rows, **kwargs)
        return A, np.full_like(b, np.nan)

    monkeypatch.setattr(sdp_cls, "cls_rows", nan_rows)
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert not estimate.success
    assert estimate.message.startswith("rows: ")


def _status_forced(status):
    original = cp.Problem.solve

    def solve(self, *args, **kwargs):
        value = original(self, *args, **kwargs)
        self._status = status
        return value

    return solve


def test_optimal_inaccurate_is_not_a_success_by_default(monkeypatch):
    monkeypatch.setattr(cp.Problem, "solve", _status_forced(cp.OPTIMAL_INACCURATE))
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    rejected = SdpCls().estimate(data)
    assert not rejected.success and "optimal_inaccurate" in rejected.message
    accepted = SdpCls(accept_inaccurate=True).estimate(data)
    assert accepted.success and "optimal_inaccurate" in accepted.message
    assert accepted.diagnostics["status"] == "optimal_inaccurate"


def test_problem_is_dpp_and_built_once_per_relaxation():
    for relaxation in ("equality", "inequality"):
        built = relaxation_problem(relaxation)
        assert built.problem.is_dpp()
        assert relaxation_problem(relaxation) is built


def test_resolve_reuses_the_built_problem():
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=5)
    estimator = SdpCls()
    estimator.estimate(data)
    built = relaxation_problem("equality")
    misses = relaxation_problem.cache_info().misses
    first = estimator.estimate(data)
    second = estimator.estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=6))
    assert relaxation_problem.cache_info().misses == misses
    assert relaxation_problem("equality") is built
    assert first.success and second.success
    # same data, same answer, whatever was solved in between
    np.testing.assert_array_equal(first.position_m, estimator.estimate(data).position_m)


def test_estimator_pickles_and_validates_its_options():
    estimator = SdpCls(relaxation="inequality", solver="SCS", max_iter=500)
    clone = pickle.loads(pickle.dumps(estimator))
    assert clone == estimator
    for options, field in (
        ({"relaxation": "exact"}, "relaxation"),
        ({"solver": "MOSEK"}, "solver"),
        ({"max_iter": 0}, "max_iter"),
        ({"max_iter": 2.5}, "max_iter"),
        ({"weighting": "inverse"}, "weighting"),
        ({"frames": "first"}, "frames"),
    ):
        with pytest.raises(ValueError, match=rf"^{field}: "):
            SdpCls(**options)


def test_missing_toa_raises_value_error_naming_the_field():
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0).without("toa")
    with pytest.raises(ValueError, match=r"^toa_s: "):
        SdpCls().estimate(data)


def test_scs_cross_check_agrees_with_clarabel():
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=3)
    clarabel = SdpCls().estimate(data)
    scs = SdpCls(solver="SCS").estimate(data)
    assert scs.success and clarabel.success
    np.testing.assert_allclose(scs.position_m, clarabel.position_m, atol=1e-3)


def test_an_inaccurate_tight_solve_is_retried_at_the_default_tolerances(monkeypatch):
    """Rung 1 ending ``optimal_inaccurate`` is re-solved at rung 2, and the rung is recorded."""
    original = cp.Problem.solve
    tight_gap = sdp_cls.CLARABEL_TOLERANCES[0][0]
    calls = []

    def solve(self, *args, **kwargs):
        calls.append(kwargs["tol_gap_abs"])
        value = original(self, *args, **kwargs)
        if kwargs["tol_gap_abs"] == tight_gap:
            self._status = cp.OPTIMAL_INACCURATE
        return value

    monkeypatch.setattr(cp.Problem, "solve", solve)
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    sdp = solve_sdp_relaxation(A, b)
    assert calls == [tight_gap, sdp_cls.CLARABEL_TOLERANCES[1][0]]
    assert sdp.status == "optimal" and sdp.rung == 2
    assert abs(sdp.value - solve_gtrs(A, b).costs.min()) <= 1e-6 * sdp.value


def test_success_records_the_status_of_every_stage():
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert estimate.success and estimate.diagnostics["status"] == "optimal"
    assert estimate.diagnostics["stage_statuses"] == ["optimal", "optimal"]
    assert np.all(np.isfinite(estimate.candidates_m))


@pytest.mark.parametrize("status", [cp.OPTIMAL, cp.OPTIMAL_INACCURATE])
def test_non_finite_lift_with_a_success_status_is_a_failed_estimate(monkeypatch, status):
    """A solver that claims success but returns NaN in the lift gives a failure with status
    ``non_finite``, never a success with a NaN position (even when inaccurate is accepted)."""
    original = sdp_cls._solve_built

    def nan_lift(*args, **kwargs):
        outcome = original(*args, **kwargs)
        lift = np.full((4, 4), np.nan)
        return replace(outcome, status=status, lift=lift)

    monkeypatch.setattr(sdp_cls, "_solve_built", nan_lift)
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    for estimator in (SdpCls(), SdpCls(accept_inaccurate=True)):
        estimate = estimator.estimate(data)
        assert not estimate.success and np.all(np.isnan(estimate.position_m))
        assert estimate.diagnostics["status"] == sdp_cls.NON_FINITE
        assert "not finite" in estimate.message
        assert estimate.diagnostics["stage_statuses"] == [sdp_cls.NON_FINITE]


def test_user_limit_and_infeasible_statuses_are_failures(monkeypatch):
    """Every status other than ``optimal`` (or the accepted ``optimal_inaccurate``) fails."""
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    for status in (cp.USER_LIMIT, cp.INFEASIBLE, cp.UNBOUNDED, cp.INFEASIBLE_INACCURATE):
        monkeypatch.setattr(cp.Problem, "solve", _status_forced(status))
        estimate = SdpCls(accept_inaccurate=True).estimate(data)
        assert not estimate.success, status
        assert estimate.diagnostics["status"] == status
        assert status in estimate.message
