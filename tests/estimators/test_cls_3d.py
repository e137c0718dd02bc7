"""The closed form with the emitter's height a coordinate (MATH §5 in three dimensions).

Unknown ``r = (x, y, z, x² + y² + z²)``: noise-free exactness on climbing turns (one minimiser)
and level turns (the emitter and its reflection through the flight plane, MATH §7), the global
minimum against a multi-start search of the same weighted cost, one trial as the batch of one,
and the one-line refusals (one straight track; the height with the emission time unknown).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from estimators import make_estimator
from estimators.closed_form.cls_batch import candidates_of_trial, system_of_trial
from estimators.closed_form.gtrs import constrained_cost, solve_gtrs
from estimators.closed_form.gtrs_batch import RowBlock, solve_gtrs_batch
from estimators.closed_form.gtrs_rank import RANK_RTOL
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from scenarios import get_scenario, simulate_trials, trial_seeds
from scenarios.catalog import heading_velocities_mps
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan, NoiseSigmas, Scenario

HEIGHT_M = 30.0
STARTS_PER_AXIS = 4


def elevated(name: str = "turn", height_m: float = HEIGHT_M) -> Scenario:
    """A named scenario with its emitter ``height_m`` above the ground, the height unknown."""
    return get_scenario(name).replace(unknowns=(HEIGHT_UNKNOWN,), emitter_height_m=height_m)


def random_flight(seed: int, *, climb: bool) -> Scenario:
    """Three headings at random; each frame climbs or sinks at its own rate (``climb``) or the
    flight is level. The emitter at a random height below the UAV, the height unknown."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 360.0)
    headings = heading + np.cumsum(np.r_[0.0, rng.uniform(40.0, 140.0, 2)])
    velocities = np.array(heading_velocities_mps(rng.uniform(5.0, 30.0), list(headings)))
    if climb:
        velocities[:, 2] = rng.uniform(-3.0, 3.0, 3)
    start_height = rng.uniform(80.0, 300.0)
    return Scenario(
        name="random-3d",
        emitter_m=rng.uniform(-300.0, 300.0, 2),
        flight=FlightPlan(
            start_position_m=[*rng.uniform(-300.0, 300.0, 2), start_height],
            frame_velocities_mps=velocities,
            samples_per_frame=int(rng.integers(6, 15)),
            sample_interval_s=rng.uniform(0.2, 1.0),
        ),
        carrier_hz=rng.uniform(1e8, 5e9),
        emitter_height_m=rng.uniform(0.0, 0.5 * start_height),
        noise=NoiseSigmas(
            doppler_hz=rng.uniform(0.05, 1.0),
            toa_s=rng.uniform(0.3, 10.0) / 299_792_458.0,
            rss_db=4.0,
        ),
        modalities=("doppler", "toa"),
        unknowns=(HEIGHT_UNKNOWN,),
    )


def reflection(point: np.ndarray, plane_height_m: float) -> np.ndarray:
    """``point`` reflected through the horizontal plane ``z = plane_height_m``."""
    return np.array([point[0], point[1], 2.0 * plane_height_m - point[2]])


# --------------------------------------------------------------------------------------------
# noise-free exactness
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_a_noise_free_climbing_flight_gives_the_emitter_alone(seed: int) -> None:
    """Three headings flown at different climb rates: no plane holds the samples, so the CLS
    has one minimiser, the emitter, to rounding of the frame's scale."""
    data = noise_free(random_flight(seed, climb=True))
    truth = data.truth_emitter_m
    scale = np.max(np.abs(data.position_m)) + np.max(np.abs(truth))
    candidates = candidates_of_trial(data, dimension=3)
    assert candidates.shape == (1, 3)
    np.testing.assert_allclose(candidates[0], truth, rtol=0.0, atol=1e-9 * scale)
    estimate = make_estimator("cls").estimate(data)
    assert estimate.success and not estimate.ambiguous, estimate.message
    assert estimate.diagnostics["hard_case"] is False and estimate.diagnostics["rank"] == 4
    np.testing.assert_allclose(estimate.position_m, truth, rtol=0.0, atol=1e-9 * scale)


@pytest.mark.parametrize("seed", range(6))
def test_a_noise_free_level_flight_gives_the_emitter_and_its_reflection(seed: int) -> None:
    """A level flight (three headings at one height h): the rows annihilate ``(0, 0, 1, 2h)``
    in the local frame, the hard case of MATH §5, and both minimisers are exact: the emitter
    and its reflection through the flight plane (MATH §7). The estimate keeps the one below
    the UAV."""
    data = noise_free(random_flight(seed, climb=False))
    truth = data.truth_emitter_m
    height = data.position_m[0, 2]
    scale = np.max(np.abs(data.position_m)) + np.max(np.abs(truth))
    candidates = candidates_of_trial(data, dimension=3)
    assert candidates.shape == (2, 3)
    np.testing.assert_allclose(candidates[0], truth, rtol=0.0, atol=1e-9 * scale)
    np.testing.assert_allclose(candidates[1], reflection(truth, height), atol=1e-9 * scale)
    estimate = make_estimator("cls").estimate(data)
    assert estimate.success and estimate.diagnostics["hard_case"] is True
    assert estimate.diagnostics["rank"] == 3
    np.testing.assert_allclose(estimate.candidates_m, truth[None], rtol=0.0, atol=1e-9 * scale)


def test_the_catalogs_level_turn_gives_both_reflections() -> None:
    """``turn`` (level at 50 m) with the emitter 30 m up: (35, 15, 30) and (35, 15, 70)."""
    candidates = candidates_of_trial(noise_free(elevated()), dimension=3)
    np.testing.assert_allclose(candidates, [[35.0, 15.0, 30.0], [35.0, 15.0, 70.0]], atol=1e-9)
    estimate = make_estimator("cls").estimate(noise_free(elevated()))
    np.testing.assert_allclose(estimate.position_m, [35.0, 15.0, 30.0], atol=1e-9)


# --------------------------------------------------------------------------------------------
# the global minimum against a multi-start search
# --------------------------------------------------------------------------------------------


def _lift(s: np.ndarray) -> np.ndarray:
    return np.append(s, s @ s)


def _gradient(A: np.ndarray, b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``2 Jᵀ Aᵀ(A r − b)`` with ``J = ∂r/∂s = [I; 2sᵀ]``."""
    jac = np.vstack([np.eye(3), 2.0 * s])
    return 2.0 * jac.T @ (A.T @ (A @ _lift(s) - b))


def _hessian(A: np.ndarray, b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``2 JᵀAᵀA J + 4 (Aᵀ(A r − b))_w I``: the second derivative of ``‖s‖²`` is ``2I``."""
    jac = np.vstack([np.eye(3), 2.0 * s])
    return 2.0 * jac.T @ (A.T @ A) @ jac + 4.0 * (A[:, 3] @ (A @ _lift(s) - b)) * np.eye(3)


def brute_force_minimum(A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """The least of ``‖A r − b‖²`` subject to ``r_w = ‖s‖²`` over every start of a grid in a
    cube holding every global minimiser: SLSQP over ``r = (s, r_w)`` with the constraint, each
    end point polished by trust-exact on the cost with the constraint substituted (exact
    gradient and Hessian). An independent search: no eigen-decomposition, no secular equation.

    The cube: with ``ρ = ‖s‖``, ``‖A r‖ ≥ ρ²‖a_w‖ − ρ‖A_s‖₂`` and a minimiser costs at most the
    origin's ``‖b‖²``, so ``‖A r‖ ≤ 2‖b‖``: ``ρ`` below the positive root of the quadratic.
    """
    a_w = np.linalg.norm(A[:, 3])
    sigma = np.linalg.norm(A[:, :3], 2)
    radius = (sigma + np.sqrt(sigma**2 + 8.0 * a_w * np.linalg.norm(b))) / (2.0 * a_w)
    axis = np.linspace(-radius, radius, STARTS_PER_AXIS)
    starts = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    constraint = {
        "type": "eq",
        "fun": lambda r: r[3] - r[:3] @ r[:3],
        "jac": lambda r: np.append(-2.0 * r[:3], 1.0),
    }
    best_cost, best_s = np.inf, np.zeros(3)
    for start in starts:
        constrained = minimize(
            lambda r: float(np.sum((A @ r - b) ** 2)),
            _lift(start),
            jac=lambda r: 2.0 * A.T @ (A @ r - b),
            constraints=[constraint],
            method="SLSQP",
            options={"ftol": 1e-15, "maxiter": 500},
        )
        result = minimize(
            lambda s: float(constrained_cost(A, b, s)),
            constrained.x[:3],
            jac=lambda s: _gradient(A, b, s),
            hess=lambda s: _hessian(A, b, s),
            method="trust-exact",
            options={"gtol": 1e-13 * max(1.0, np.linalg.norm(A.T @ b)), "maxiter": 500},
        )
        cost = float(constrained_cost(A, b, result.x))
        if cost < best_cost:
            best_cost, best_s = cost, result.x
    return best_cost, best_s


def assert_global_minimum(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``solve_gtrs`` on the 3-D rows attains the brute-force minimum to 1e-9 relative (plus a
    floor of rounding), on the constraint; returns its points."""
    solution = solve_gtrs(A, b)
    points = solution.points
    assert points.shape[1] == 4
    np.testing.assert_allclose(points[:, 3], np.sum(points[:, :3] ** 2, axis=1), rtol=1e-12)
    costs = constrained_cost(A, b, points[:, :3])
    floor = 1e-18 * (1.0 + b @ b)
    np.testing.assert_allclose(solution.costs, costs, rtol=1e-9, atol=floor)
    brute, _ = brute_force_minimum(A, b)
    assert np.all(costs <= brute * (1 + 1e-9) + floor), (costs, brute)
    assert np.all(costs >= brute * (1 - 1e-9) - floor), (costs, brute)
    return points


@pytest.mark.parametrize("climb", [True, False], ids=["climbing", "level"])
@pytest.mark.parametrize("seed", range(4))
def test_noisy_trials_attain_the_brute_force_minimum_of_the_weighted_cost(seed, climb) -> None:
    """At 0 dB the weighted rows of the last stage (MATH §6) of random climbing and level
    flights: the closed form's minimisers are the global minimum of the same cost; the
    estimate returns one of them (in world metres); a level flight's pair costs the same."""
    data = simulate(random_flight(seed, climb=climb), snr_db=0.0, seed=seed)
    A, b, offset, scale = system_of_trial(data, "weighted", last_stage=True, dimension=3)
    assert offset is None and A.shape[1] == 4
    points = assert_global_minimum(A, b)
    if not climb:
        assert len(points) == 2
        np.testing.assert_allclose(points[0, :2], points[1, :2], rtol=1e-9, atol=1e-12)
    origin = data.position_m[:, :2].mean(axis=0)
    world = np.column_stack([points[:, :2] * scale + origin, points[:, 2] * scale])
    estimate = make_estimator("cls").estimate(data)
    gap = np.min(np.linalg.norm(world - estimate.position_m, axis=1))
    assert gap <= 1e-9 * (np.linalg.norm(estimate.position_m) + scale)


@pytest.mark.parametrize("rank", [3, 4])
def test_random_rows_attain_the_brute_force_minimum(rank: int) -> None:
    """Random systems of 10 rows over ``(x, y, z, ‖s‖²)`` of rank 4 and of rank 3 (a null
    vector: the hard case when it meets the paraboloid twice)."""
    rng = np.random.default_rng(40 + rank)
    hard = 0
    for _ in range(12):
        A = rng.standard_normal((10, rank)) @ rng.standard_normal((rank, 4))
        b = rng.standard_normal(10) * rng.uniform(0.1, 10.0)
        hard += len(assert_global_minimum(A, b)) == 2
    assert (hard > 0) == (rank == 3)


def test_a_system_gets_the_same_bits_alone_and_in_a_batch() -> None:
    """300 random 3-D systems in one call and each alone: the same code on the same rows."""
    rng = np.random.default_rng(3)
    n = 300
    A = np.einsum("mrn,rcn->mcn", rng.standard_normal((9, 3, n)), rng.standard_normal((3, 4, n)))
    A[:, :, ::2] += rng.standard_normal((9, 4, (n + 1) // 2))  # every other: full rank
    b = rng.standard_normal((9, n))
    rows = [RowBlock(ax=A[:, 0], ay=A[:, 1], az=A[:, 3], b=b, ah=A[:, 2])]
    batch = solve_gtrs_batch(rows, n, rank=True)
    assert not batch.failed.any() and 0 < batch.hard_case.sum() < n
    for i in range(n):
        single = solve_gtrs(A[:, :, i], b[:, i])
        count = int(batch.count[i])
        assert (len(single.points), single.rank) == (count, int(batch.rank[i]))
        for j, coordinate in enumerate(batch.points):
            np.testing.assert_array_equal(single.points[:, j], coordinate[i, :count])
        np.testing.assert_array_equal(single.costs, batch.costs[i, :count])


# --------------------------------------------------------------------------------------------
# one trial is the batch of one; refusals
# --------------------------------------------------------------------------------------------


@pytest.mark.bits("estimate is the batch of one: the same code on the same arrays")
@pytest.mark.parametrize("name", ["turn", "hill", "hill-climb"])
def test_estimate_is_the_batchs_row(name: str) -> None:
    """Each trial's ``estimate`` is its row of ``estimate_columns``, to the bit, in 3-D."""
    scenario = get_scenario(name)
    if HEIGHT_UNKNOWN not in scenario.unknowns:
        scenario = elevated(name)
    batch = simulate_trials(scenario, snr_db=10.0, seeds=trial_seeds(5, 40))
    estimator = make_estimator("cls")
    columns = estimator.estimate_columns(batch)
    assert columns.position_m.shape == (40, 3) and columns.success.all()
    for i in (0, 7, 39):
        one = estimator.estimate(batch.trial(i))
        np.testing.assert_array_equal(one.position_m, columns.position_m[i])
        count = int(columns.n_candidates[i])
        np.testing.assert_array_equal(one.candidates_m, columns.candidates_m[i, :count])


def test_one_straight_track_is_refused_in_one_line() -> None:
    """One straight frame leaves a circle about the track (MATH §7): a failed estimate, the
    mirror rule's one line, for one trial and for a batch."""
    estimator = make_estimator("cls")
    one = estimator.estimate(noise_free(elevated("paper-1m")))
    assert not one.success and one.message == STRAIGHT_TRACK_HEIGHT
    assert one.position_m.shape == (3,) and np.isnan(one.position_m).all()
    batch = simulate_trials(elevated("paper-1m"), snr_db=10.0, seeds=trial_seeds(1, 5))
    columns = estimator.estimate_columns(batch)
    assert not columns.success.any()
    assert {estimator.estimate_batch(batch)[i].message for i in range(5)} == {STRAIGHT_TRACK_HEIGHT}


@pytest.mark.parametrize("name", ["hill", "hill-climb"])
def test_constrained_ls_describes_the_3d_system_the_estimate_minimises(name: str) -> None:
    """``cls.constrained_ls(data)`` in 3-D: rows over ``(x, y, z, ‖s‖²)`` whose exact optimum
    (MATH §5) the estimate's candidates attain, world and local points round-tripping."""
    data = simulate(get_scenario(name), snr_db=0.0, seed=3)
    estimator = make_estimator("cls")
    estimate = estimator.estimate(data)
    system = estimator.constrained_ls(data)
    assert system.A.shape[1] == 4 and system.dimension == 3
    optimum = solve_gtrs(system.A, system.b).costs.min()
    np.testing.assert_allclose(system.cost(estimate.candidates_m), optimum, rtol=1e-9)
    local = system.to_local(estimate.candidates_m)
    np.testing.assert_allclose(system.to_world(local), estimate.candidates_m, rtol=1e-14)


@pytest.mark.parametrize("rank", [3, 4])
def test_the_certified_rank_is_the_svd_rank(rank: int) -> None:
    """The rank of 3-D rows certified from the normal equations
    (:func:`~estimators.closed_form.gtrs_rank.numerical_rank_3d`) is the count of singular
    values above the threshold, on 1000 random systems with columns scaled over four decades."""
    rng = np.random.default_rng(7 + rank)
    n = 1000
    A = np.einsum(
        "mrn,rcn->mcn", rng.standard_normal((9, rank, n)), rng.standard_normal((rank, 4, n))
    )
    A *= rng.uniform(0.01, 100.0, size=(1, 4, n))
    rows = [RowBlock(ax=A[:, 0], ay=A[:, 1], az=A[:, 3], b=rng.standard_normal((9, n)), ah=A[:, 2])]
    values = np.linalg.svd(A.transpose(2, 0, 1), compute_uv=False)
    singular = np.sum(values > RANK_RTOL * values[:, :1], axis=1)
    assert (singular == rank).all()
    for deficient in (False, rank == 3):
        certified = solve_gtrs_batch(rows, n, rank=True, rank_deficient=deficient).rank
        np.testing.assert_array_equal(certified, singular)


def test_the_2d_solve_at_an_assumed_height_stays_available() -> None:
    """With the height unknown, ``candidates_of_trial`` without ``dimension`` is the 2-D CLS at
    the height the data give (what ``ml``'s starts at assumed heights use): at the true height
    its answer is the emitter's (x, y), noise-free."""
    import dataclasses

    data = noise_free(elevated())
    at_truth = dataclasses.replace(data, emitter_height_m=HEIGHT_M)
    np.testing.assert_allclose(candidates_of_trial(at_truth), [[35.0, 15.0]], atol=1e-9)
    assert candidates_of_trial(at_truth, dimension=3).shape == (2, 3)
