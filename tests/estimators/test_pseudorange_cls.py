"""The closed form with an unknown emission time (MATH §15): pseudo-ranges on a hyperboloid.

Checks, with numbers: noise-free exactness on a two-heading pass (b unknown, and b and δ
unknown); the straight-frame mirror pair; invariance to b, δ and the unit system; the indefinite
GTRS against brute force (a dense grid on a parametrisation of the constraint surface, refined
by Nelder-Mead from the best grid points); and a Monte Carlo against the nuisance CRLB.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from estimators.closed_form.gtrs_indefinite import (
    constraint_value,
    indefinite_cost,
    solve_gtrs_indefinite,
    stationary_points,
)
from estimators.closed_form.pseudorange_cls import relaxed_fisher_information, solve_pseudorange_cls
from scenarios.catalog import get_scenario
from scenarios.fisher import fisher_information, rmse_bound_m
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import FlightPlan

B_ONLY = ("emission_time_s",)
BOTH = ("carrier_offset_hz", "emission_time_s")
EMISSION_S = 3e-4
OFFSET_HZ = 800.0


def pass_with(name: str, unknowns: tuple[str, ...], **changes):
    values = {"emission_time_s": EMISSION_S}
    if "carrier_offset_hz" in unknowns:
        values["carrier_offset_hz"] = OFFSET_HZ
    values.update(changes)
    return get_scenario(name).replace(unknowns=unknowns, **values)


# --------------------------------------------------------------------------------------------
# noise-free exactness
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("stages", [1, 2])
@pytest.mark.parametrize("reference", ["centre", "first", 13])
def test_noise_free_turn_with_unknown_emission_time_is_exact(stages, reference) -> None:
    scenario = pass_with("turn", B_ONLY)
    solution = solve_pseudorange_cls(
        noise_free(scenario), carrier_offset_unknown=False, stages=stages, reference=reference
    )
    np.testing.assert_allclose(solution.candidates_m, [scenario.emitter_m], rtol=0, atol=1e-6)
    np.testing.assert_allclose(solution.emission_time_s, [EMISSION_S], rtol=0, atol=1e-12)
    assert solution.carrier_offset_hz is None
    info = solution.diagnostics
    assert info["success"] and info["status"] == "interior-root" and info["rank"] == 3
    assert info["on_physical_sheet"] and info["sheet"] == ["+"]
    j = info["reference_sample"]
    assert j == {"centre": 7, "first": 0, 13: 13}[reference]
    true_range = np.linalg.norm(noise_free(scenario).position_m[j] - [35.0, 15.0, 0.0])
    assert solution.reference_range_m[0] == pytest.approx(true_range, abs=1e-6)


@pytest.mark.parametrize("method", ["relaxed", "profile"])
def test_noise_free_turn_with_both_unknown_is_exact(method) -> None:
    scenario = pass_with("turn", BOTH)
    solution = solve_pseudorange_cls(
        noise_free(scenario), carrier_offset_unknown=True, offset_method=method
    )
    np.testing.assert_allclose(solution.candidates_m, [scenario.emitter_m], rtol=0, atol=1e-6)
    np.testing.assert_allclose(solution.emission_time_s, [EMISSION_S], rtol=0, atol=1e-12)
    np.testing.assert_allclose(solution.carrier_offset_hz, [OFFSET_HZ], rtol=0, atol=1e-6)
    assert solution.diagnostics["on_physical_sheet"]
    if method == "relaxed":  # the free (δ, w) satisfy w = ρ_j δ at noise-free
        assert solution.diagnostics["relaxed_carrier_offset_hz"] == pytest.approx(OFFSET_HZ)
        assert abs(solution.diagnostics["relaxation_gap_hz"]) < 1e-6


def test_noise_free_two_heading_flight_plan_with_climb_and_raised_emitter() -> None:
    """A plan of our own: two headings, a climbing second leg, the emitter 7 m up."""
    base = get_scenario("turn")
    scenario = base.replace(
        emitter_height_m=7.0,
        emitter_m=[-20.0, 40.0],
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 60.0],
            frame_velocities_mps=[[12.0, 3.0, 0.0], [-2.0, 11.0, 1.5]],
            samples_per_frame=15,
            sample_interval_s=0.1,
        ),
        unknowns=BOTH,
        emission_time_s=2e-6,
        carrier_offset_hz=-350.0,
    )
    solution = solve_pseudorange_cls(noise_free(scenario), carrier_offset_unknown=True)
    np.testing.assert_allclose(solution.candidates_m, [[-20.0, 40.0]], rtol=0, atol=1e-6)
    np.testing.assert_allclose(solution.emission_time_s, [2e-6], rtol=0, atol=1e-12)
    np.testing.assert_allclose(solution.carrier_offset_hz, [-350.0], rtol=0, atol=1e-6)


# --------------------------------------------------------------------------------------------
# the straight frame: the hard case and the mirror pair
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("unknowns", [B_ONLY, BOTH])
def test_straight_frame_gives_the_mirror_pair_at_equal_cost(unknowns) -> None:
    scenario = pass_with("paper-1m", unknowns)
    solution = solve_pseudorange_cls(
        noise_free(scenario), carrier_offset_unknown="carrier_offset_hz" in unknowns
    )
    info = solution.diagnostics
    assert info["hard_case"] and info["hard_end"] == "lower" and info["rank"] == 2
    assert info["multiplier"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(
        sorted(solution.candidates_m.tolist()), [[35.0, -15.0], [35.0, 15.0]], rtol=0, atol=1e-6
    )
    np.testing.assert_allclose(solution.emission_time_s, [EMISSION_S] * 2, rtol=0, atol=1e-12)
    assert solution.costs[0] == solution.costs[1]


def test_noisy_straight_frame_pair_is_symmetric_across_the_track() -> None:
    scenario = pass_with("paper-1m", B_ONLY)
    solution = solve_pseudorange_cls(
        simulate(scenario, snr_db=20.0, seed=3), carrier_offset_unknown=False
    )
    assert solution.diagnostics["status"] == "hard-case"
    (x1, y1), (x2, y2) = solution.candidates_m
    assert x1 == pytest.approx(x2, abs=1e-9) and y1 == pytest.approx(-y2, abs=1e-9)
    assert abs(y1) == pytest.approx(15.0, abs=2.0)
    assert solution.costs[0] == pytest.approx(solution.costs[1], rel=1e-9)
    assert solution.emission_time_s[0] == pytest.approx(solution.emission_time_s[1], abs=1e-15)


# --------------------------------------------------------------------------------------------
# invariances
# --------------------------------------------------------------------------------------------


def test_estimate_does_not_depend_on_the_emission_time_or_the_carrier_offset() -> None:
    first = simulate(pass_with("turn", BOTH), snr_db=10.0, seed=7)
    second = simulate(
        pass_with("turn", BOTH, emission_time_s=4e-5, carrier_offset_hz=-1500.0),
        snr_db=10.0,
        seed=7,
    )
    a = solve_pseudorange_cls(first, carrier_offset_unknown=True)
    b = solve_pseudorange_cls(second, carrier_offset_unknown=True)
    np.testing.assert_allclose(a.candidates_m, b.candidates_m, rtol=0, atol=1e-7)
    np.testing.assert_allclose(
        a.emission_time_s - b.emission_time_s, [EMISSION_S - 4e-5], rtol=0, atol=1e-14
    )
    np.testing.assert_allclose(
        a.carrier_offset_hz - b.carrier_offset_hz, [OFFSET_HZ + 1500.0], rtol=0, atol=1e-6
    )


def test_weighted_estimate_is_invariant_to_the_unit_system() -> None:
    metres = pass_with("paper-1m-turn", B_ONLY)
    kilometres = metres.replace(
        emitter_m=metres.emitter_m / 1e3,
        speed_of_light_mps=metres.speed_of_light_mps / 1e3,
        flight=FlightPlan(
            start_position_m=metres.flight.start_position_m / 1e3,
            frame_velocities_mps=metres.flight.frame_velocities_mps / 1e3,
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
    )
    in_m = solve_pseudorange_cls(simulate(metres, seed=3), carrier_offset_unknown=False)
    in_km = solve_pseudorange_cls(simulate(kilometres, seed=3), carrier_offset_unknown=False)
    np.testing.assert_allclose(in_km.candidates_m * 1e3, in_m.candidates_m, rtol=0, atol=1e-6)
    np.testing.assert_allclose(in_km.emission_time_s, in_m.emission_time_s, rtol=1e-9)


def test_weighted_estimate_does_not_depend_on_the_reference_to_first_order() -> None:
    """Centre and first sample: stage-2 estimates differ by O(σ²), 1.5e-3 √CRLB at 30 dB."""
    scenario = pass_with("turn", B_ONLY)
    bound = float(rmse_bound_m(fisher_information(noise_free(scenario, snr_db=30.0), [35, 15])))
    gaps = []
    for seed in range(10):
        data = simulate(scenario, snr_db=30.0, seed=seed)
        centre = solve_pseudorange_cls(data, carrier_offset_unknown=False, reference="centre")
        first = solve_pseudorange_cls(data, carrier_offset_unknown=False, reference="first")
        gaps.append(np.linalg.norm(centre.candidates_m - first.candidates_m))
    assert max(gaps) < 0.01 * bound


# --------------------------------------------------------------------------------------------
# the indefinite GTRS against brute force
# --------------------------------------------------------------------------------------------


def _surface(d: np.ndarray, g: np.ndarray, c: float):
    """A parametrisation ``(p0, p1, sheet) -> θ`` of ``θᵀDθ + 2gᵀθ = c`` for D of signature
    (+, +, −): with ``u_i = √|d_i| (θ_i + g_i/d_i)``, ``u₊₁² + u₊₂² − u₋² = c'``."""
    order = np.argsort(-d)
    shift = c + np.sum(g**2 / d)

    def theta(p0, p1, sheet):
        p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
        if shift < 0.0:  # two sheets: p0 the radius, u₋ = ±√(p0² − c')
            radius, minus = np.abs(p0), sheet * np.sqrt(p0**2 - shift)
        else:  # one sheet: p0 = u₋
            radius, minus = np.sqrt(shift + p0**2), p0
        u = np.empty((*radius.shape, 3))
        u[..., order[0]] = radius * np.cos(p1)
        u[..., order[1]] = radius * np.sin(p1)
        u[..., order[2]] = minus
        return u / np.sqrt(np.abs(d)) - g / d

    return theta, (1, -1) if shift < 0.0 else (1,)


def brute_force_minimum(A, b, d, g, c, *, sheet_only: int | None = None) -> float:
    theta, sheets = _surface(d, g, c)
    best = np.inf
    p0, p1 = np.meshgrid(np.linspace(-60.0, 60.0, 241), np.linspace(0.0, 2 * np.pi, 121))
    for sheet in sheets if sheet_only is None else (sheet_only,):
        costs = indefinite_cost(A, b, theta(p0, p1, sheet))
        for index in np.argsort(costs, axis=None)[:5]:
            start = [p0.flat[index], p1.flat[index]]
            result = minimize(
                lambda p, s=sheet: indefinite_cost(A, b, theta(p[0], p[1], s)),
                start,
                method="Nelder-Mead",
                options={"xatol": 1e-11, "fatol": 1e-13, "maxiter": 4000},
            )
            best = min(best, float(result.fun))
    return best


def random_problem(rng, *, null_column: int | None = None):
    A = rng.normal(size=(6, 3))
    if null_column is not None:
        A[:, null_column] = 0.0
        return A, 3.0 * rng.normal(size=6), np.array([1.0, 1.0, -1.0]), np.zeros(3), rng.normal()
    d = np.array([1.0, 1.0, -1.0]) * rng.uniform(0.3, 3.0, 3)
    return A, 3.0 * rng.normal(size=6), rng.permutation(d), rng.normal(size=3), 2 * rng.normal()


@pytest.mark.parametrize("seed", range(8))
def test_indefinite_gtrs_matches_brute_force(seed) -> None:
    rng = np.random.default_rng(100 + seed)
    A, b, d, g, c = random_problem(rng)
    solution = solve_gtrs_indefinite(A, b, d, g, c)
    assert solution.status == "interior-root" and len(solution.points) == 1
    assert abs(constraint_value(solution.points, d, g, c)).max() < 1e-10
    lo, hi = solution.interval
    assert lo < solution.multiplier < hi
    assert np.all(np.linalg.eigvalsh(A.T @ A + solution.multiplier * np.diag(d)) > 0.0)
    brute = brute_force_minimum(A, b, d, g, c)
    assert solution.costs[0] <= brute + 1e-9 * (1.0 + brute)
    assert solution.costs[0] == pytest.approx(brute, rel=1e-7, abs=1e-9)


@pytest.mark.parametrize("seed", range(8))
def test_indefinite_gtrs_hard_case_returns_both_minimisers(seed) -> None:
    """A zero column: the null direction has positive (x, lower end) or negative (ρ, upper
    end) curvature; the hard case, when it occurs, returns two points of equal cost."""
    rng = np.random.default_rng(200 + seed)
    column = 0 if seed % 2 == 0 else 2
    A, b, d, g, c = random_problem(rng, null_column=column)
    solution = solve_gtrs_indefinite(A, b, d, g, c)
    assert solution.rank == 2
    assert abs(constraint_value(solution.points, d, g, c)).max() < 1e-10
    brute = brute_force_minimum(A, b, d, g, c)
    assert solution.costs.min() == pytest.approx(brute, rel=1e-7, abs=1e-9)
    if solution.hard_case:
        assert solution.hard_end == ("lower" if column == 0 else "upper")
        assert len(solution.points) == 2
        assert solution.costs[0] == pytest.approx(solution.costs[1], rel=1e-12)
        # the pair differs only along the null direction
        np.testing.assert_allclose(
            np.delete(solution.points, column, axis=1)[0],
            np.delete(solution.points, column, axis=1)[1],
            atol=1e-9,
        )


def test_hard_cases_at_both_ends_occur_in_the_random_set() -> None:
    ends = set()
    for seed in range(8):
        A, b, d, g, c = random_problem(np.random.default_rng(200 + seed), null_column=seed % 2 * 2)
        ends.add(solve_gtrs_indefinite(A, b, d, g, c).hard_end)
    assert {"lower", "upper"} <= ends


@pytest.mark.parametrize("seed", range(4))
def test_stationary_points_give_the_minimum_of_each_sheet(seed) -> None:
    rng = np.random.default_rng(300 + seed)
    A, b = rng.normal(size=(6, 3)), 3.0 * rng.normal(size=6)
    d, g, c = np.array([1.0, 1.0, -1.0]), np.zeros(3), -abs(rng.normal()) - 0.5
    points, costs, _ = stationary_points(A, b, d, g, c)
    assert abs(constraint_value(points, d, g, c)).max() < 1e-8
    assert costs[0] == pytest.approx(solve_gtrs_indefinite(A, b, d, g, c).costs[0], rel=1e-9)
    for sheet in (1, -1):
        on_sheet = costs[np.sign(points[:, 2]) == sheet]
        brute = brute_force_minimum(A, b, d, g, c, sheet_only=sheet)
        assert on_sheet.min() == pytest.approx(brute, rel=1e-7, abs=1e-9)


def test_no_definite_interval_is_reported() -> None:
    """``A`` annihilates ``u = (1, 0, 1)``, with ``uᵀDu = 0``: ``M + λD`` is never definite."""
    A = np.random.default_rng(4).normal(size=(6, 3))
    A[:, 2] = -A[:, 0]
    solution = solve_gtrs_indefinite(A, np.ones(6), [1.0, 1.0, -1.0], None, -1.0)
    assert solution.status == "no-definite-interval" and len(solution.points) == 0


def test_a_definite_or_singular_constraint_is_refused() -> None:
    with pytest.raises(ValueError, match="both signs"):
        solve_gtrs_indefinite(np.eye(3), np.ones(3), [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="both signs"):
        solve_gtrs_indefinite(np.eye(3), np.ones(3), [1.0, 0.0, -1.0])


# --------------------------------------------------------------------------------------------
# the sheet, the inputs
# --------------------------------------------------------------------------------------------


def test_a_wrong_sheet_minimiser_is_reported_and_replaced() -> None:
    """At −20 dB the global minimiser sometimes has ρ_j < 0; the physical-sheet stationary
    point is returned instead, at a cost not below the global one."""
    scenario = pass_with("turn", B_ONLY)
    for seed in range(60):
        solution = solve_pseudorange_cls(
            simulate(scenario, snr_db=-20.0, seed=seed), carrier_offset_unknown=False
        )
        if solution.diagnostics["status"] == "wrong-sheet-fallback":
            break
    else:
        pytest.fail("no wrong-sheet minimiser in 60 trials at -20 dB")
    info = solution.diagnostics
    assert not info["on_physical_sheet"] and info["sheet"] == ["−"] and info["success"]
    assert solution.reference_range_m[0] > 0.0
    assert solution.costs[0] >= info["global_cost"]


def test_inputs_are_checked() -> None:
    data = noise_free(pass_with("turn", BOTH))
    with pytest.raises(ValueError, match="carrier_offset_unknown"):
        solve_pseudorange_cls(data, carrier_offset_unknown=False)
    with pytest.raises(ValueError, match="ToA"):
        solve_pseudorange_cls(data.without("toa"), carrier_offset_unknown=True)
    with pytest.raises(ValueError, match="offset_method"):
        solve_pseudorange_cls(data, carrier_offset_unknown=True, offset_method="exact")


def test_relaxed_information_is_the_nuisance_information_without_the_offset() -> None:
    data = noise_free(pass_with("turn", B_ONLY))
    np.testing.assert_allclose(
        relaxed_fisher_information(data, [35.0, 15.0], unknowns=B_ONLY),
        fisher_information(data, [35.0, 15.0]),
        rtol=1e-12,
    )
    both = noise_free(pass_with("turn", BOTH))
    relaxed = float(rmse_bound_m(relaxed_fisher_information(both, [35.0, 15.0])))
    full = float(rmse_bound_m(fisher_information(both, [35.0, 15.0])))
    assert relaxed / full == pytest.approx(1.567, abs=0.001)  # the price of w ≠ ρ_j δ on `turn`


# --------------------------------------------------------------------------------------------
# Monte Carlo against the nuisance CRLB
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("unknowns", "method", "bound_kind", "band"),
    [
        (B_ONLY, "relaxed", "crlb", (0.9, 1.1)),  # measured 0.992
        (BOTH, "relaxed", "relaxed", (0.9, 1.15)),  # measured 1.026 of the relaxed bound
        (BOTH, "relaxed", "crlb", (1.45, 1.8)),  # 1.608 = 1.567 x 1.026: the relaxation's price
        (BOTH, "profile", "crlb", (0.9, 1.15)),  # measured 0.978
    ],
)
def test_monte_carlo_rmse_is_within_a_factor_of_the_bound(
    unknowns, method, bound_kind, band
) -> None:
    scenario = pass_with("turn", unknowns)
    trials = simulate_trials(scenario, snr_db=30.0, seeds=trial_seeds(2026, 400))
    geometry = trials.geometry
    if bound_kind == "crlb":
        bound = float(rmse_bound_m(fisher_information(geometry, scenario.emitter_m)))
    else:
        information = relaxed_fisher_information(geometry, scenario.emitter_m, unknowns=unknowns)
        bound = float(rmse_bound_m(information))
    errors, emission = [], []
    for i in range(400):
        solution = solve_pseudorange_cls(
            trials.trial(i),
            carrier_offset_unknown="carrier_offset_hz" in unknowns,
            offset_method=method,
        )
        assert solution.diagnostics["success"] and solution.diagnostics["on_physical_sheet"]
        errors.append(np.linalg.norm(solution.candidates_m[0] - scenario.emitter_m))
        emission.append(solution.emission_time_s[0] - EMISSION_S)
    rmse = float(np.sqrt(np.mean(np.square(errors))))
    assert np.isfinite(rmse)
    assert band[0] <= rmse / bound <= band[1]
    assert abs(np.mean(emission)) < 3 * np.std(emission) / np.sqrt(400) + 1e-12
