"""The SDP relaxation of the CLS (MATH §11) against the closed form (MATH §5) and exact truths."""

from __future__ import annotations

import math
import pickle
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from types import SimpleNamespace

import cvxpy as cp
import numpy as np
import pytest

import estimators.sdp.sdp_lift as sdp_lift
import estimators.sdp.sdp_solvers as sdp_solvers
from estimators.closed_form.cls import Cls, cls_rows
from estimators.closed_form.cls_rows import LocalFrame
from estimators.closed_form.gtrs import constrained_cost, solve_gtrs
from estimators.sdp.sdp_cls import SdpCls, solve_sdp_relaxation
from estimators.sdp.sdp_lift import compress_rows, whiten_relaxation
from estimators.sdp.sdp_solvers import relaxation_problem, solver_attempts
from scenarios.catalog import get_scenario
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.simulate import noise_free, simulate

SCENARIOS = ("paper-1m", "paper-10m", "turn", "orbit")


def local_rows(data, rows="weighted"):
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    return frame, A, b


ORIGINAL_RUN = sdp_solvers.run_clarabel


def forged(solution, **changes):
    """A stand-in for Clarabel's DefaultSolution with some fields replaced."""
    fields = {
        name: getattr(solution, name) for name in ("status", "x", "z", "iterations", "solve_time")
    }
    return SimpleNamespace(**(fields | changes))


def status_forced(name):
    def run(program, q, constraint_row, settings):
        return forged(ORIGINAL_RUN(program, q, constraint_row, settings), status=name)

    return run


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
    for build in (relaxation_problem, sdp_solvers.clarabel_program):
        with pytest.raises(ValueError, match=r"^relaxation: "):
            build("convex")
    with pytest.raises(ValueError, match=r"^relaxation: "):
        solve_sdp_relaxation(np.ones((4, 3)), np.ones(4), relaxation="convex")


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


# --------------------------------------------------------------------------------------------
# the direct Clarabel program: the same program as cvxpy's, solved the same way
# --------------------------------------------------------------------------------------------


def whitened_instances():
    """Whitened data of a few real row systems: unique minimisers, the hard case, λ* < 0."""
    systems = [
        local_rows(simulate(get_scenario(name), snr_db=10.0, seed=seed))[1:]
        for name, seed in (("turn", 0), ("orbit", 1), ("paper-1m", 4), ("paper-10m", 2))
    ]
    systems.append(biased_range_rows(+5.0))
    return [whiten_relaxation(*compress_rows(A, b)) for A, b in systems]


@pytest.mark.parametrize("relaxation", ["equality", "inequality"])
def test_direct_program_is_the_one_cvxpy_compiles(relaxation):
    """q, A (values and pattern), b and the cones equal cvxpy's Clarabel data entry for entry."""
    program = sdp_solvers.clarabel_program(relaxation)
    built = relaxation_problem(relaxation)
    for whitened in whitened_instances():
        built.set_data(whitened)
        data, _, _ = built.problem.get_problem_data(cp.CLARABEL)
        q = sdp_solvers.inner_product_coefficients(whitened.objective)
        row = sdp_solvers.inner_product_coefficients(whitened.constraint)
        A = program.A.copy()
        A.data[program.constraint_slots] = row
        np.testing.assert_array_equal(q, data["c"])
        np.testing.assert_array_equal(A.indptr, data["A"].indptr)
        np.testing.assert_array_equal(A.indices, data["A"].indices)
        np.testing.assert_array_equal(A.data, data["A"].data)
        np.testing.assert_array_equal(program.b, data["b"])
        dims = data["dims"]
        assert (dims.zero, dims.nonneg, dims.psd) == (
            (2, 0, [4]) if relaxation == "equality" else (1, 1, [4])
        )


@pytest.mark.parametrize("relaxation", ["equality", "inequality"])
def test_direct_solve_equals_the_cvxpy_solve(relaxation):
    """Same program, same settings: same status, iterations, lift and dual as Problem.solve."""
    settings = solver_attempts("CLARABEL", None)[0]
    for whitened in whitened_instances():
        direct = sdp_solvers.solve_with_clarabel(whitened, relaxation, settings)
        through = sdp_solvers.solve_with_cvxpy(whitened, relaxation, "CLARABEL", settings)
        assert direct.status == through.status == "optimal"
        assert direct.iterations == through.iterations
        np.testing.assert_allclose(direct.lift, through.lift, rtol=0.0, atol=1e-12)
        assert direct.dual == pytest.approx(through.dual, rel=1e-10, abs=1e-12)
        assert direct.solve_time_s > 0.0 and through.solve_time_s > 0.0


def test_solution_reports_the_solver_time_of_every_rung_and_stage(monkeypatch):
    """``rungs_solve_time_s`` sums the rungs; the estimate sums the stages."""
    calls = []

    def fake_clock(program, q, constraint_row, settings):
        solution = ORIGINAL_RUN(program, q, constraint_row, settings)
        calls.append(settings.tol_gap_abs)
        status = "AlmostSolved" if len(calls) == 1 else str(solution.status)
        return forged(solution, status=status, solve_time=1e-3 * len(calls))

    monkeypatch.setattr(sdp_solvers, "run_clarabel", fake_clock)
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    estimate = SdpCls().estimate(data)
    # stage 1: rung 1 (1 ms, AlmostSolved) then rung 2 (2 ms); stage 2: rung 1 (3 ms)
    assert calls == [1e-10, 1e-8, 1e-10]
    assert estimate.success and estimate.diagnostics["tolerance_rung"] == 1
    assert estimate.diagnostics["estimate_solve_time_s"] == pytest.approx(6e-3, rel=1e-12)
    assert estimate.diagnostics["rungs_solve_time_s"] == pytest.approx(3e-3, rel=1e-12)
    calls.clear()
    _, A, b = local_rows(data)
    sdp = solve_sdp_relaxation(A, b)
    assert sdp.rung == 2 and sdp.solve_time_s == pytest.approx(2e-3)
    assert sdp.rungs_solve_time_s == pytest.approx(3e-3, rel=1e-12)


@pytest.mark.bits("the same solve twice, the second in a fresh program")
def test_every_setting_is_passed_on_every_solve(monkeypatch):
    """A fresh DefaultSettings per solve, with every setting of its rung: none leaks."""
    seen = []

    def spy(program, q, constraint_row, settings):
        seen.append(
            (
                settings.tol_gap_abs,
                settings.tol_gap_rel,
                settings.tol_feas,
                settings.max_iter,
                settings.verbose,
            )
        )
        return ORIGINAL_RUN(program, q, constraint_row, settings)

    monkeypatch.setattr(sdp_solvers, "run_clarabel", spy)
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    limited = solve_sdp_relaxation(A, b, max_iter=1)
    default = solve_sdp_relaxation(A, b)
    assert limited.status == "user_limit" and limited.iterations == 1
    assert default.status == "optimal" and default.iterations > 1
    assert seen == [(1e-10, 1e-10, 1e-9, 1, False), (1e-10, 1e-10, 1e-9, 200, False)]
    # the first solve leaves nothing behind: same lift as a solve in a fresh program
    sdp_solvers.clarabel_program.cache_clear()
    fresh = solve_sdp_relaxation(A, b)
    np.testing.assert_array_equal(fresh.lift, default.lift)


def test_settings_reject_an_unknown_name():
    with pytest.raises(TypeError, match="tol_gap"):
        sdp_solvers.clarabel_settings({"tol_gap": 1e-8})


@pytest.mark.bits("the same solves on the same arrays, threaded or not")
def test_concurrent_solves_equal_sequential_ones():
    """The shared pattern is filled under a lock: threads get the sequential answers."""
    systems = [
        local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=s))[1:] for s in range(12)
    ]
    sequential = [solve_sdp_relaxation(A, b).lift for A, b in systems]
    with ThreadPoolExecutor(max_workers=4) as pool:
        threaded = list(pool.map(lambda system: solve_sdp_relaxation(*system).lift, systems * 3))
    for index, lift in enumerate(threaded):
        np.testing.assert_array_equal(lift, sequential[index % len(systems)])


def test_compression_of_short_systems_and_the_residual():
    """m < 3 pads with zero rows; m = 3 leaves no residual; ρ² is the least-squares misfit."""
    rng = np.random.default_rng(7)
    for m in (1, 2, 3, 4, 25):
        A, b = rng.normal(size=(m, 3)), rng.normal(size=m)
        R, c, residual_sq = compress_rows(A, b)
        assert np.all(np.tril(R, -1) == 0.0) and np.all(R[m:] == 0.0) and np.all(c[m:] == 0.0)
        least_squares = np.linalg.lstsq(A, b, rcond=None)[0]
        expected = float(np.sum((A @ least_squares - b) ** 2))
        assert residual_sq == pytest.approx(expected, rel=1e-10, abs=1e-24)
        assert (residual_sq == 0.0) == (m <= 3)
        for r in rng.normal(size=(3, 3)):
            full = np.sum((A @ r - b) ** 2)
            assert np.sum((R @ r - c) ** 2) + residual_sq == pytest.approx(full, rel=1e-10)


def test_whitened_data_reproduce_the_cost_and_the_constraint():
    """tr(H_w W) · s = ‖A r − b‖² and tr(C_w W) · κ = ‖y‖² − r_z on rank-one lifts of (w, 1)."""
    _, A, b = local_rows(simulate(get_scenario("orbit"), snr_db=10.0, seed=3))
    whitened = whiten_relaxation(*compress_rows(A, b))
    for w in np.random.default_rng(1).normal(size=(5, 3)):
        lift = np.outer(np.append(w, 1.0), np.append(w, 1.0))
        r = whitened.points(w)
        cost = np.sum((A @ r - b) ** 2)
        assert whitened.objective_scale * np.sum(whitened.objective * lift) == pytest.approx(
            cost, rel=1e-9
        )
        assert whitened.constraint_scale * np.sum(whitened.constraint * lift) == pytest.approx(
            r[0] ** 2 + r[1] ** 2 - r[2], rel=1e-9, abs=1e-12
        )
        np.testing.assert_allclose(
            whitened.to_local(lift), np.outer(*[np.append(r, 1.0)] * 2), rtol=1e-12, atol=1e-12
        )


# --------------------------------------------------------------------------------------------
# failures: every status but optimal is one, nothing raises for a solver failure
# --------------------------------------------------------------------------------------------


def test_solver_exception_gives_a_failed_estimate(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("numerical trouble")

    monkeypatch.setattr(sdp_solvers, "run_clarabel", broken)
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert not estimate.success
    assert estimate.diagnostics["status"] == "solver_error"
    assert estimate.diagnostics["tolerance_rung"] == 2  # both rungs were tried
    assert "numerical trouble" in estimate.message and "SCS" in estimate.message


@pytest.mark.parametrize("name", ["NumericalError", "InsufficientProgress", "SomethingNew"])
def test_clarabel_error_statuses_are_solver_errors(monkeypatch, name):
    monkeypatch.setattr(sdp_solvers, "run_clarabel", status_forced(name))
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    sdp = solve_sdp_relaxation(A, b)
    assert sdp.status == "solver_error" and sdp.rung == 2 and not sdp.has_solution
    assert name in sdp.message
    assert np.isnan(sdp.value) and sdp.points.shape == (0, 3)


def test_malformed_problem_gives_a_failed_estimate(monkeypatch):
    original = sdp_lift.ChunkRows.systems

    def nan_rows(self, rows, weights_at):
        systems = original(self, rows, weights_at)
        systems[:, :, 3] = np.nan
        return systems

    monkeypatch.setattr(sdp_lift.ChunkRows, "systems", nan_rows)
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert not estimate.success
    assert estimate.message.startswith("rows: the stage-1 CLS system")
    assert estimate.diagnostics == {"stage": 1}


def test_optimal_inaccurate_is_not_a_success_by_default(monkeypatch):
    """AlmostSolved on every rung: optimal_inaccurate, rejected unless accepted (flagged)."""
    monkeypatch.setattr(sdp_solvers, "run_clarabel", status_forced("AlmostSolved"))
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    rejected = SdpCls().estimate(data)
    assert not rejected.success and "optimal_inaccurate" in rejected.message
    assert rejected.diagnostics["tolerance_rung"] == 2
    accepted = SdpCls(accept_inaccurate=True).estimate(data)
    assert accepted.success and "optimal_inaccurate" in accepted.message
    assert accepted.diagnostics["status"] == "optimal_inaccurate"
    assert accepted.diagnostics["stage_statuses"] == ["optimal_inaccurate"] * 2
    monkeypatch.undo()
    # the accepted answer is that of rung 2 (Clarabel's default tolerances)
    np.testing.assert_allclose(
        accepted.position_m, SdpCls().estimate(data).position_m, rtol=0.0, atol=1e-5
    )


def test_programs_are_built_once_per_relaxation():
    for relaxation in ("equality", "inequality"):
        assert sdp_solvers.clarabel_program(relaxation) is sdp_solvers.clarabel_program(relaxation)
        built = relaxation_problem(relaxation)
        assert built.problem.is_dpp()
        assert relaxation_problem(relaxation) is built


@pytest.mark.bits("the same data estimated twice")
def test_resolve_reuses_the_built_program():
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=5)
    estimator = SdpCls()
    estimator.estimate(data)
    program = sdp_solvers.clarabel_program("equality")
    misses = sdp_solvers.clarabel_program.cache_info().misses
    first = estimator.estimate(data)
    second = estimator.estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=6))
    assert sdp_solvers.clarabel_program.cache_info().misses == misses
    assert sdp_solvers.clarabel_program("equality") is program
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


def test_scs_solver_error_gives_a_failed_solution(monkeypatch):
    """SCS still goes through cvxpy: its SolverError is a failure, not an exception."""

    def broken_solve(self, *args, **kwargs):
        raise cp.error.SolverError("numerical trouble")

    monkeypatch.setattr(cp.Problem, "solve", broken_solve)
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    sdp = solve_sdp_relaxation(A, b, solver="SCS")
    assert sdp.status == "solver_error" and "numerical trouble" in sdp.message
    assert solve_sdp_relaxation(A, b).status == "optimal"  # Clarabel does not use cvxpy


def test_an_inaccurate_tight_solve_is_retried_at_the_default_tolerances(monkeypatch):
    """Rung 1 ending ``AlmostSolved`` is re-solved at rung 2, and the rung is recorded."""
    tight_gap = sdp_solvers.CLARABEL_TOLERANCES[0][0]
    calls = []

    def run(program, q, constraint_row, settings):
        calls.append((settings.tol_gap_abs, settings.tol_feas))
        solution = ORIGINAL_RUN(program, q, constraint_row, settings)
        if settings.tol_gap_abs == tight_gap:
            return forged(solution, status="AlmostSolved")
        return solution

    monkeypatch.setattr(sdp_solvers, "run_clarabel", run)
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    sdp = solve_sdp_relaxation(A, b)
    assert calls == list(sdp_solvers.CLARABEL_TOLERANCES)
    assert sdp.status == "optimal" and sdp.rung == 2
    assert abs(sdp.value - solve_gtrs(A, b).costs.min()) <= 1e-6 * sdp.value


def test_success_records_the_status_of_every_stage():
    estimate = SdpCls().estimate(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    assert estimate.success and estimate.diagnostics["status"] == "optimal"
    assert estimate.diagnostics["stage_statuses"] == ["optimal", "optimal"]
    assert np.all(np.isfinite(estimate.candidates_m))
    assert estimate.diagnostics["estimate_solve_time_s"] > 0.0
    eigenvalues = estimate.diagnostics["lift_eigenvalues"]
    assert len(eigenvalues) == 4 and eigenvalues[1] < 1e-6 * eigenvalues[0]  # rank one


@pytest.mark.parametrize("status", ["optimal", "optimal_inaccurate"])
def test_non_finite_lift_with_a_success_status_is_a_failed_estimate(monkeypatch, status):
    """A solver that claims success but returns NaN in the lift gives a failure with status
    ``non_finite``, never a success with a NaN position (even when inaccurate is accepted)."""
    original = sdp_solvers.clarabel_outcome

    def nan_lift(*args, **kwargs):
        outcome = original(*args, **kwargs)
        return replace(outcome, status=status, lift=np.full((4, 4), np.nan))

    monkeypatch.setattr(sdp_solvers, "clarabel_outcome", nan_lift)
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    for estimator in (SdpCls(), SdpCls(accept_inaccurate=True)):
        estimate = estimator.estimate(data)
        assert not estimate.success and np.all(np.isnan(estimate.position_m))
        assert estimate.diagnostics["status"] == sdp_solvers.NON_FINITE
        assert "not finite" in estimate.message
        assert estimate.diagnostics["stage_statuses"] == [sdp_solvers.NON_FINITE]


def test_non_finite_clarabel_primal_is_a_failed_solution(monkeypatch):
    """NaN in Clarabel's x with status Solved: non_finite, not a solution."""

    def nan_x(program, q, constraint_row, settings):
        solution = ORIGINAL_RUN(program, q, constraint_row, settings)
        return forged(solution, x=[math.nan] * len(solution.x))

    monkeypatch.setattr(sdp_solvers, "run_clarabel", nan_x)
    _, A, b = local_rows(simulate(get_scenario("turn"), snr_db=10.0, seed=0))
    sdp = solve_sdp_relaxation(A, b)
    assert sdp.status == sdp_solvers.NON_FINITE and not sdp.has_solution
    assert np.all(np.isnan(sdp.lift))


@pytest.mark.parametrize(
    ("name", "status"),
    [
        ("MaxIterations", "user_limit"),
        ("MaxTime", "user_limit"),
        ("PrimalInfeasible", "infeasible"),
        ("DualInfeasible", "unbounded"),
        ("AlmostPrimalInfeasible", "infeasible_inaccurate"),
        ("AlmostDualInfeasible", "unbounded_inaccurate"),
    ],
)
def test_other_statuses_are_failures(monkeypatch, name, status):
    """Every status other than ``optimal`` (or the accepted ``optimal_inaccurate``) fails,
    with cvxpy's name for it, after one rung (only inaccuracy and errors are retried)."""
    monkeypatch.setattr(sdp_solvers, "run_clarabel", status_forced(name))
    data = simulate(get_scenario("turn"), snr_db=10.0, seed=0)
    estimate = SdpCls(accept_inaccurate=True).estimate(data)
    assert not estimate.success
    assert estimate.diagnostics["status"] == status
    assert estimate.diagnostics["tolerance_rung"] == 1
    assert status in estimate.message
