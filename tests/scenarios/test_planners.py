"""Tests of scenarios.planners: MATH §12 (the paper's rule corrected), §13 (Fisher-optimal
heading), the orbit and constant planners, their limits, errors and the registry."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scenarios import measurement_model as model
from scenarios.catalog import get_scenario, heading_velocities_mps
from scenarios.fisher import information_at_samples as fisher_information_m2
from scenarios.planners import (
    PLANNERS,
    ConstantPlanner,
    FisherPlanner,
    OrbitPlanner,
    PaperPlanner,
    Plan,
    flight_from_measurements,
    get_planner,
)
from scenarios.planners.fisher import best_heading_rad, heading_objective
from scenarios.planners.paper import (
    choose_root,
    circle_roots_mps,
    paper_rhs_m2ps,
    paper_velocity_mps,
    predict_next_rhs_m2ps,
    speed_change_squared_mps2,
)
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan

TRUTH = np.array([35.0, 15.0])


def flown(headings_deg, *, seed=None, scenario="paper-1m", speed=10.0):
    """A paper-geometry scenario flown at the given headings, and its data (noise-free: None)."""
    base = get_scenario(scenario)
    flight = dataclasses.replace(
        base.flight, frame_velocities_mps=heading_velocities_mps(speed, list(headings_deg))
    )
    chosen = base.replace(flight=flight)
    data = noise_free(chosen) if seed is None else simulate(chosen, seed=seed)
    return chosen, flight, data


# --------------------------------------------------------------------------------------------
# MATH §12: the roots, the tie, the no-solution branch, V_max
# --------------------------------------------------------------------------------------------

finite = dict(allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(
    bx=st.floats(-200, 200, **finite),
    by=st.floats(-200, 200, **finite),
    speed=st.floats(0.1, 40, **finite),
    fraction=st.floats(-1, 1, **finite),
)
def test_paper_roots_solve_both_equations(bx, by, speed, fraction):
    b = np.array([bx, by])
    norm = float(np.hypot(bx, by))
    if norm < 1e-3:
        return
    d = fraction * speed * norm
    roots = circle_roots_mps(b, d, speed)
    assert roots is not None
    for u in roots:
        assert abs(float(u @ b) - d) <= 1e-9 * speed * norm  # uᵀb = d (eq ueq)
        assert abs(float(np.hypot(*u)) - speed) <= 1e-9 * speed  # |u| = A
    # the + root is counter-clockwise of b (b × u ≥ 0), the − root clockwise
    assert b[0] * roots[0][1] - b[1] * roots[0][0] >= -1e-9 * speed * norm
    assert b[0] * roots[1][1] - b[1] * roots[1][0] <= 1e-9 * speed * norm
    assert circle_roots_mps(b, 1.01 * speed * norm, speed) is None  # |d| > A|b|: none


@settings(max_examples=300, deadline=None)
@given(
    bx=st.floats(-100, 100, **finite),
    by=st.floats(-100, 100, **finite),
    rhs=st.floats(-2000, 2000, **finite),
    interval=st.floats(0.01, 0.5, **finite),
)
def test_speed_change_makes_the_discriminant_vanish(bx, by, rhs, interval):
    b_norm_sq = bx * bx + by * by
    if b_norm_sq < 1e-2:
        return
    x = speed_change_squared_mps2(rhs, b_norm_sq, interval)
    roots = np.roots([interval**2, -(2 * interval * rhs + b_norm_sq), rhs**2])
    real = [r.real for r in roots if abs(r.imag) <= 1e-9 * abs(r)]
    positive = sorted(r for r in real if r > 1e-12 * max(real, default=0.0))
    if not positive:
        assert math.isnan(x)
        return
    assert x == pytest.approx(positive[0], rel=1e-6)
    # the discriminant A²|b|² − d² of the circle problem vanishes at A² = X, d = F − ΔX
    d_new = rhs - interval * x
    scale = max(x * b_norm_sq, d_new**2, 1e-12)
    assert abs(x * b_norm_sq - d_new**2) <= 1e-9 * scale


def test_no_solution_branch_returns_the_corrected_quadratic_speed():
    b = np.array([-30.0, -15.0])
    # |d| > A|b| at A = 10: F = 600, d = 600 − 0.05·100 = 595 > 10·33.5
    velocity, branch, diagnostics = paper_velocity_mps(b, 600.0, 0.05, 10.0, [10.0, 0.0])
    assert branch == "speed-change"
    x = float(velocity @ velocity)
    expected = speed_change_squared_mps2(600.0, float(b @ b), 0.05)
    assert x == pytest.approx(expected, rel=1e-12)
    assert diagnostics["speed_mps"] == pytest.approx(math.sqrt(expected), rel=1e-12)
    # zero residual with the new speed: uᵀb = F − Δ|u|² (eq ufin on the circle's tangency)
    assert float(velocity @ b) == pytest.approx(600.0 - 0.05 * x, rel=1e-9)
    # parallel to b (the double root u = d_new b/|b|²)
    assert abs(velocity[0] * b[1] - velocity[1] * b[0]) <= 1e-9 * float(np.hypot(*velocity)) * 34


@settings(max_examples=300, deadline=None)
@given(
    bx=st.floats(-100, 100, **finite),
    by=st.floats(-100, 100, **finite),
    rhs=st.floats(-5000, 5000, **finite),
    speed=st.floats(0.5, 60, **finite),
    max_speed=st.floats(1, 30, **finite),
    tie=st.sampled_from(["turn", "literal"]),
)
def test_paper_rule_never_exceeds_vmax(bx, by, rhs, speed, max_speed, tie):
    b = np.array([bx, by])
    if float(np.hypot(bx, by)) < 1e-2:
        return
    velocity, branch, _ = paper_velocity_mps(
        b, rhs, 0.05, speed, [1.0, 0.0], max_speed_mps=max_speed, tie=tie
    )
    assert float(np.hypot(*velocity)) <= max_speed * (1 + 1e-12)
    assert branch in {"circle", "speed-change", "vmax-circle", "vmax-along-b"}
    if branch == "vmax-along-b":  # the least residual at V_max: along ±b
        assert float(np.hypot(*velocity)) == pytest.approx(max_speed, rel=1e-12)


def test_noise_free_the_old_velocity_is_a_root_and_turn_reflects_it():
    _, flight, data = flown([0.0, 0.0])
    rhs = predict_next_rhs_m2ps(flight, data)
    b = flight.sample_positions_m()[-1, :2] - TRUTH
    d = rhs - flight.sample_interval_s * 100.0
    old = flight.frame_velocities_mps[-1, :2]
    assert d == pytest.approx(float(old @ b), rel=1e-9)  # MATH §12: v_old solves uᵀb = d
    roots = circle_roots_mps(b, d, 10.0)
    assert np.min(np.linalg.norm(roots - old, axis=1)) < 1e-6
    plan = PaperPlanner().plan(flight, [TRUTH, TRUTH * [1, -1]], data)
    reflected = 2 * (old @ b) / (b @ b) * b - old  # v_old reflected about b
    assert plan.velocity_mps[:2] == pytest.approx(reflected, abs=1e-6)
    assert plan.message == "circle"


def test_the_literal_rule_is_an_exact_tie_broken_counter_clockwise():
    b = np.array([-30.5, -15.0])
    roots = circle_roots_mps(b, -250.0, 10.0)
    index, compared = choose_root(roots, [10.0, 0.0], b, 0.05, tie="literal")
    assert compared["tied"] and index == 0
    assert compared["tie_distance_plus"] == pytest.approx(compared["tie_distance_minus"], rel=1e-12)
    _, flight, data = flown([0.0, 0.0])
    plan = PaperPlanner(tie="literal").plan(flight, TRUTH, data)
    b = flight.sample_positions_m()[-1, :2] - TRUTH
    assert b[0] * plan.velocity_mps[1] - b[1] * plan.velocity_mps[0] > 0  # + root: b × u > 0
    assert plan.diagnostics["tied"]


def test_rhs_prediction_is_exact_noise_free_and_the_frame_mean_has_k_times_less_variance():
    scenario, flight, data = flown([0.0, 30.0])
    p_next = (
        flight.sample_positions_m()[-1] + flight.sample_interval_s * flight.frame_velocities_mps[-1]
    )
    exact = float(flight.frame_velocities_mps[-1] @ (p_next - np.append(TRUTH, 0.0)))
    for method in ("frame", "last-sample"):
        assert predict_next_rhs_m2ps(flight, data, method=method) == pytest.approx(exact, rel=1e-12)
    # F_k = −r_k f_k/γ = v_kᵀ(p_k − s) noise-free (MATH §12)
    rhs = paper_rhs_m2ps(data.range_m, data.doppler_hz, data.gamma_per_m)
    offsets = data.position_m - np.append(TRUTH, 0.0)
    assert rhs == pytest.approx(np.einsum("ij,ij->i", data.velocity_mps, offsets), rel=1e-12)
    draws = {"frame": [], "last-sample": []}
    for seed in range(400):
        noisy = simulate(scenario, seed=seed)
        for method, values in draws.items():
            values.append(predict_next_rhs_m2ps(flight, noisy, method=method))
    ratio = np.var(draws["frame"]) / np.var(draws["last-sample"])
    assert 0.06 < ratio < 0.16  # 1/K = 0.1
    assert np.mean(draws["frame"]) == pytest.approx(exact, abs=4 * np.std(draws["frame"]) / 20)


def test_paper_planner_needs_doppler_and_toa():
    _, flight, data = flown([0.0])
    with pytest.raises(ValueError, match=r"^toa_s: the paper planner needs"):
        PaperPlanner().plan(flight, TRUTH, data.without("toa"))


# --------------------------------------------------------------------------------------------
# MATH §13: the Fisher-optimal heading
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("headings", "candidates", "options"),
    [
        ([0.0], [[35.0, 15.0], [35.0, -15.0]], {}),
        ([0.0, 60.0], [[34.0, 16.0]], {}),
        ([0.0, 90.0, 180.0], [[30.0, 10.0]], {"criterion": "D"}),
        ([0.0], [[35.0, 15.0], [35.0, -15.0]], {"aggregate": "mean"}),
        ([0.0, 45.0], [[36.0, 14.0]], {"max_turn_rate_dps": 60.0}),
    ],
)
def test_fisher_choice_beats_a_brute_force_grid(headings, candidates, options):
    _, flight, data = flown(headings)
    planner = FisherPlanner(**options)
    plan = planner.plan(flight, candidates, data)
    candidates = np.asarray(candidates, dtype=float)
    past = fisher_information_m2(
        data.position_m, data.velocity_mps, candidates[:, None, :], data, ("toa", "doppler")
    )
    start = flight.sample_positions_m()[-1] + 0.05 * flight.frame_velocities_mps[-1]

    def objective(psi):
        return heading_objective(
            psi,
            past_information=past,
            candidates_m=candidates,
            start_m=start,
            speed_mps=10.0,
            samples_per_frame=10,
            sample_interval_s=0.05,
            data=data,
            criterion=planner.criterion,
            aggregate=planner.aggregate,
        )

    old = math.radians(headings[-1])
    if "max_turn_rate_dps" in options:  # 60°/s over a 0.5 s frame: ±30°
        grid = old + np.radians(np.linspace(-30.0, 30.0, 6001))
    else:
        grid = np.radians(np.arange(0.0, 360.0, 0.01))
    brute = objective(grid)
    chosen = float(objective([math.atan2(plan.velocity_mps[1], plan.velocity_mps[0])])[0])
    assert plan.diagnostics["objective"] == pytest.approx(chosen, rel=1e-12)
    # no grid heading is better by more than the variation over one grid step
    step_variation = float(np.max(np.abs(np.diff(brute))))
    assert chosen <= brute.min() + step_variation
    assert float(np.hypot(*plan.velocity_mps[:2])) == pytest.approx(10.0, rel=1e-12)
    if "max_turn_rate_dps" in options:
        assert abs(plan.diagnostics["turn_deg"]) <= 30.0 + 1e-9


def test_fisher_information_matches_the_per_sample_sum():
    *_, data = flown([0.0, 90.0])
    total = fisher_information_m2(data.position_m, data.velocity_mps, TRUTH, data)
    rows = np.concatenate(
        [
            model.toa_jacobian(data.position_m, TRUTH, data.speed_of_light_mps) / data.noise.toa_s,
            model.doppler_jacobian(data.position_m, data.velocity_mps, TRUTH, data.gamma_per_m)
            / data.noise.doppler_hz,
        ]
    )
    assert total == pytest.approx(rows.T @ rows, rel=1e-12)


# --------------------------------------------------------------------------------------------
# orbit, constant, limits, determinism, errors
# --------------------------------------------------------------------------------------------


def test_orbit_on_the_circle_flies_a_chord():
    radius = 30.0
    centre = np.array([35.0, 15.0])
    # a frame ending so that the next one starts on the circle, heading along it
    start = centre + radius * np.array([np.cos(-2.0), np.sin(-2.0)])
    tangent = np.array([-np.sin(-2.0), np.cos(-2.0)]) * 10.0  # counter-clockwise
    flight = FlightPlan(
        start_position_m=[*(start - 0.5 * tangent), 50.0],
        frame_velocities_mps=[[*tangent, 0.0]],
        samples_per_frame=10,
        sample_interval_s=0.05,
    )
    scenario = get_scenario("paper-1m").replace(flight=flight)
    data = noise_free(scenario)
    plan = OrbitPlanner(radius_m=radius).plan(flight, centre, data)
    nxt = flight.with_frame(plan.velocity_mps).sample_positions_m()
    # the frame starts on the circle and the next one starts on it again: a chord
    ends = np.array([nxt[10, :2], nxt[10, :2] + 0.5 * plan.velocity_mps[:2]])
    assert np.hypot(*(ends - centre).T) == pytest.approx([radius, radius], abs=0.01)
    far_centre = centre + np.array([200.0, 0.0])
    far = OrbitPlanner(radius_m=5.0).plan(flight, far_centre, data)
    towards = far_centre - nxt[10, :2]
    cosine = far.velocity_mps[:2] @ towards / (10.0 * np.hypot(*towards))
    assert cosine > 0.99  # far away it flies towards the centre


def test_constant_holds_the_velocity_and_caps_the_speed():
    _, flight, data = flown([30.0], speed=25.0)
    plan = ConstantPlanner().plan(flight, TRUTH, data)
    assert np.hypot(*plan.velocity_mps[:2]) == pytest.approx(20.0)
    assert math.degrees(math.atan2(plan.velocity_mps[1], plan.velocity_mps[0])) == pytest.approx(
        30.0
    )
    assert ConstantPlanner(max_speed_mps=30).plan(flight, TRUTH, data).velocity_mps == (
        pytest.approx(flight.frame_velocities_mps[-1])
    )


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_limits_and_determinism_of_every_planner(name):
    _, flight, data = flown([0.0, 0.0], seed=4, speed=25.0)
    candidates = [[35.2, 14.9], [35.2, -14.9]]
    planner = get_planner(name, max_turn_rate_dps=40.0)  # ±20° over a 0.5 s frame
    first = planner.plan(flight, candidates, data)
    again = get_planner(name, max_turn_rate_dps=40.0).plan(flight, candidates, data)
    assert isinstance(first, Plan) and first.planner == name
    assert np.array_equal(first.velocity_mps, again.velocity_mps)  # deterministic
    assert np.hypot(*first.velocity_mps[:2]) <= 20.0 + 1e-9  # V_max (25 m/s asked)
    assert first.velocity_mps[2] == 0.0
    turn = math.degrees(math.atan2(first.velocity_mps[1], first.velocity_mps[0]))
    assert abs(turn) <= 20.0 + 1e-9


@pytest.mark.parametrize("name", ["paper", "fisher", "orbit"])
def test_zero_speed_is_a_clear_error(name):
    _, flight, data = flown([0.0], speed=0.0)
    with pytest.raises(ValueError, match=r"^speed_mps: the first frame's horizontal speed is 0"):
        get_planner(name).plan(flight, TRUTH, data)
    plan = get_planner(name, speed_mps=5.0).plan(flight, TRUTH, data)
    assert np.hypot(*plan.velocity_mps[:2]) <= 5.0 + 1e-9


def test_an_estimate_below_the_uav():
    _, flight, data = flown([0.0, 90.0], seed=1)
    below = flight.sample_positions_m()[-1, :2]
    with pytest.raises(ValueError, match=r"^candidates_m: the estimate lies directly below"):
        PaperPlanner().plan(flight, below, data)
    # the orbit keeps the old heading above its centre (documented fallback)
    next_start = below + 0.05 * flight.frame_velocities_mps[-1, :2]
    plan = OrbitPlanner().plan(flight, next_start, data)
    assert plan.velocity_mps[:2] == pytest.approx([0.0, 10.0], abs=1e-9)
    assert "kept the old heading" in plan.message
    # the Fisher planner is defined there (the emitter is 50 m below)
    assert np.isfinite(FisherPlanner().plan(flight, below, data).velocity_mps).all()


@pytest.mark.parametrize(
    ("candidates", "message"),
    [
        ([np.nan, 1.0], r"^candidates_m: not finite"),
        ([[1.0, 2.0, 3.0]], r"^candidates_m: expected shape \(n, 2\)"),
        ("abc", r"^candidates_m: expected numbers"),
    ],
)
def test_malformed_candidates_name_the_field(candidates, message):
    _, flight, data = flown([0.0])
    for name in ("paper", "fisher", "orbit"):
        with pytest.raises(ValueError, match=message):
            get_planner(name).plan(flight, candidates, data)


def test_registry_and_options():
    assert set(PLANNERS) == {"constant", "paper", "fisher", "orbit"}
    assert isinstance(get_planner("scenarios.planners.fisher:FisherPlanner"), FisherPlanner)
    with pytest.raises(ValueError, match=r"^planner: unknown name 'nope'"):
        get_planner("nope")
    with pytest.raises(ValueError, match=r"^radius: not an option of planner 'orbit'"):
        get_planner("orbit", radius=3)
    with pytest.raises(ValueError, match=r"^tie: expected 'turn' or 'literal'"):
        get_planner("paper", tie="nearest")
    with pytest.raises(ValueError, match=r"^max_speed_mps: must be finite and > 0"):
        get_planner("fisher", max_speed_mps=0)
    with pytest.raises(ValueError, match=r"^n_headings: expected a whole number >= 3"):
        get_planner("fisher", n_headings=2)
    _, flight, data = flown([0.0, 0.0])
    with pytest.raises(ValueError, match=r"^data: 10 samples, but the flight has 20"):
        PaperPlanner().plan(flight, TRUTH, data.up_to_frame(0))


class PlanWithoutRng:
    """A planner whose plan cannot take the closed loop's keywords."""

    name = "no-rng"
    built = False

    def __init__(self):
        PlanWithoutRng.built = True

    def plan(self, flight, candidates_m, data):
        raise AssertionError("never called")


def test_the_registry_refuses_anything_but_a_planner_class_before_calling_it(tmp_path):
    marker = tmp_path / "marker"
    with pytest.raises(ValueError, match=r"^planner: 'os:system' is a function, not a planner cl"):
        get_planner("os:system", command=f"touch {marker}")
    assert not marker.exists()
    with pytest.raises(ValueError, match=r"^planner: 'scenarios.planners:PLANNERS' is a dict obj"):
        get_planner("scenarios.planners:PLANNERS")
    with pytest.raises(ValueError, match=r"^planner: cannot import 'no_such_planner_module' \("):
        get_planner("no_such_planner_module:Planner")
    name = f"{__name__}:PlanWithoutRng"
    with pytest.raises(
        ValueError,
        match=r"lacks the planner interface: plan must take the keyword covariance_m2; "
        r"plan must take the keyword rng; give a class",
    ):
        get_planner(name)
    assert not PlanWithoutRng.built


def test_planner_options_are_checked_against_their_annotations():
    with pytest.raises(ValueError, match=r"^radius_m: expected a number in metres, got 'big'$"):
        get_planner("orbit", radius_m="big")
    with pytest.raises(ValueError, match=r"^max_turn_rate_dps: expected a number in degrees per"):
        get_planner("paper", max_turn_rate_dps=[40])
    with pytest.raises(ValueError, match=r"^n_headings: expected a whole number, got 360.0$"):
        get_planner("fisher", n_headings=360.0)
    with pytest.raises(ValueError, match=r"^criterion: expected 'A' or 'D', got True$"):
        get_planner("fisher", criterion=True)
    assert get_planner("orbit", radius_m=25).radius_m == 25  # an int is a number
    assert get_planner("paper", speed_mps=None).speed_mps is None


def test_flight_is_reconstructed_from_the_samples():
    _, flight, data = flown([0.0, 75.0, 150.0], seed=2)
    rebuilt = flight_from_measurements(data)
    assert rebuilt.samples_per_frame == 10
    assert rebuilt.sample_interval_s == pytest.approx(0.05, rel=1e-12)
    assert rebuilt.frame_velocities_mps == pytest.approx(flight.frame_velocities_mps)
    assert rebuilt.sample_positions_m() == pytest.approx(data.position_m, abs=1e-9)
    with pytest.raises(ValueError, match=r"^frame: frames hold \[5, 10\] samples"):
        flight_from_measurements(data.take(data.time_s < 0.05 * 25))
    shift = np.zeros((30, 3))
    shift[10:, 0] = 1.0  # a jump between frames: each frame straight, the flight not one path
    moved = dataclasses.replace(data, position_m=data.position_m + shift)
    with pytest.raises(ValueError, match=r"^position_m: the samples depart"):
        flight_from_measurements(moved)


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_mirror_symmetric_best_headings_are_decided_by_the_turn_not_the_rounding(sign) -> None:
    """A criterion symmetric about the current heading (a straight track's mirror pair, MATH
    §7, §13) has its best headings in mirror pairs; whichever of the two the rounding makes a
    unit in the last place smaller, the planner turns the least, and left on a tie of turns."""
    current = 0.3
    best_turn = 1.1  # radians, either side

    def objective(headings: np.ndarray) -> np.ndarray:
        turn = np.angle(np.exp(1j * (headings - current)))
        value = 1.0 + (np.abs(turn) - best_turn) ** 2
        return value * (1.0 + sign * 2.2e-16 * np.sign(turn))  # one side an ulp cheaper

    heading, value = best_heading_rad(
        objective, centre_rad=current, half_width_rad=math.pi, n_headings=360, refine_rounds=3
    )
    assert heading - current == pytest.approx(best_turn, abs=1e-4)
    assert value == pytest.approx(1.0, abs=1e-8)
