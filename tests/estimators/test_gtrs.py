"""The GTRS solver of MATH §5 against a brute-force minimisation of the same quartic objective.

``constrained_cost(A, b, xy) = ‖A (x, y, x² + y²) − b‖²`` is a quartic in ``(x, y)``; its global
minimum is found here independently of :func:`estimators.closed_form.gtrs.solve_gtrs`: a grid over a
disc that provably contains every global minimiser, then ``scipy.optimize.minimize`` (trust-exact,
exact gradient and Hessian) from every local minimum of the grid.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

from estimators.closed_form.cls import cls_rows
from estimators.closed_form.cls_rows import LocalFrame
from estimators.closed_form.gtrs import constrained_cost, solve_gtrs
from scenarios.catalog import get_scenario, heading_velocities_mps
from scenarios.geometry import mirror_across_line, straight_track_line, straight_track_lines
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan, NoiseSigmas, Scenario

COST_RTOL = 1e-9
GRID_POINTS = 161
MAX_STARTS = 4


# --------------------------------------------------------------------------------------------
# brute force
# --------------------------------------------------------------------------------------------


def _lift(xy: np.ndarray) -> np.ndarray:
    return np.array([xy[0], xy[1], xy[0] ** 2 + xy[1] ** 2])


def _gradient(A: np.ndarray, b: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``2 Jᵀ Aᵀ (A r − b)`` with ``J = ∂r/∂(x, y) = [[1, 0], [0, 1], [2x, 2y]]``."""
    residual = A @ _lift(xy) - b
    jac = np.array([[1.0, 0.0], [0.0, 1.0], [2.0 * xy[0], 2.0 * xy[1]]])
    return 2.0 * jac.T @ (A.T @ residual)


def _hessian(A: np.ndarray, b: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``2 Jᵀ AᵀA J + 4 (Aᵀ(A r − b))₃ I``: the second derivative of r_z is ``2 I``."""
    residual = A @ _lift(xy) - b
    jac = np.array([[1.0, 0.0], [0.0, 1.0], [2.0 * xy[0], 2.0 * xy[1]]])
    return 2.0 * jac.T @ (A.T @ A) @ jac + 4.0 * (A[:, 2] @ residual) * np.eye(2)


def minimiser_radius_bound(A: np.ndarray, b: np.ndarray) -> float:
    """A radius ``R`` with every global minimiser in ``‖(x, y)‖ <= R``.

    With ``ρ = ‖(x, y)‖``: ``‖A r‖ >= ρ² ‖a₃‖ − ρ ‖A[:, :2]‖₂`` and a minimiser has cost at most
    the cost ``‖b‖²`` at the origin, so ``‖A r‖ <= 2 ‖b‖``; solve the quadratic for ρ.
    """
    a3 = np.linalg.norm(A[:, 2])
    sigma = np.linalg.norm(A[:, :2], 2)
    b_norm = np.linalg.norm(b)
    return float((sigma + np.sqrt(sigma**2 + 8.0 * a3 * b_norm)) / (2.0 * a3))


def brute_force_minimum(A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """Global minimum of ``constrained_cost(A, b, ·)`` and its minimiser, by multi-start search.

    The grid (over a square holding the disc of :func:`minimiser_radius_bound`) is evaluated on
    the QR-compressed system, which only ranks the starts; every start is then minimised on the
    objective itself.
    """
    radius = 1.05 * minimiser_radius_bound(A, b)
    axis = np.linspace(-radius, radius, GRID_POINTS)
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1)
    Q, R = np.linalg.qr(A)
    cost = constrained_cost(R, Q.T @ b, grid)
    inner = cost[1:-1, 1:-1]
    is_local_min = np.ones_like(inner, dtype=bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di or dj:
                shifted = cost[1 + di : GRID_POINTS - 1 + di, 1 + dj : GRID_POINTS - 1 + dj]
                is_local_min &= inner <= shifted
    starts = grid[1:-1, 1:-1][is_local_min]
    starts = starts[np.argsort(inner[is_local_min])][:MAX_STARTS]
    best_cost, best_xy = np.inf, None
    for start in starts:
        result = minimize(
            lambda xy: float(constrained_cost(A, b, xy)),
            start,
            jac=lambda xy: _gradient(A, b, xy),
            hess=lambda xy: _hessian(A, b, xy),
            method="trust-exact",
            options={"gtol": 1e-13 * max(1.0, np.linalg.norm(A.T @ b)), "maxiter": 500},
        )
        polished = float(constrained_cost(A, b, result.x))
        if polished < best_cost:
            best_cost, best_xy = polished, result.x
    return best_cost, best_xy


def assert_global_minimum(A: np.ndarray, b: np.ndarray) -> None:
    """``solve_gtrs`` attains the brute-force minimum to ``COST_RTOL``, on the constraint."""
    solution = solve_gtrs(A, b)
    points = solution.points
    np.testing.assert_allclose(points[:, 2], np.sum(points[:, :2] ** 2, axis=1), rtol=1e-12)
    costs = constrained_cost(A, b, points[:, :2])
    np.testing.assert_allclose(solution.costs, costs, rtol=1e-9, atol=1e-12 * (b @ b))
    brute, _ = brute_force_minimum(A, b)
    floor = 1e-18 * (1.0 + b @ b)
    assert np.all(costs <= brute * (1 + COST_RTOL) + floor), (costs, brute)
    assert np.all(costs >= brute * (1 - COST_RTOL) - floor), (costs, brute)


# --------------------------------------------------------------------------------------------
# random instances
# --------------------------------------------------------------------------------------------


def random_scenario(rng: np.random.Generator, headings: int) -> Scenario:
    """A random level-flight geometry with ``headings`` frames of distinct headings."""
    heading = rng.uniform(0.0, 360.0)
    turns = rng.uniform(20.0, 160.0, size=headings - 1) * rng.choice([-1, 1], size=headings - 1)
    speed = rng.uniform(3.0, 40.0)
    start = np.array([*rng.uniform(-500.0, 500.0, size=2), rng.uniform(20.0, 300.0)])
    samples = int(rng.integers(5, 25))
    interval = rng.uniform(0.02, 0.5)
    track = speed * samples * interval
    emitter = start[:2] + rng.uniform(-3.0, 3.0, size=2) * max(track, start[2])
    range_sigma_m = rng.uniform(0.1, 20.0)
    c = rng.choice([3.0e8, 299_792_458.0])
    return Scenario(
        name="random",
        emitter_m=emitter,
        flight=FlightPlan(
            start_position_m=start,
            frame_velocities_mps=heading_velocities_mps(
                speed, list(heading + np.concatenate([[0.0], np.cumsum(turns)]))
            ),
            samples_per_frame=samples,
            sample_interval_s=interval,
        ),
        carrier_hz=rng.uniform(1e8, 6e9),
        speed_of_light_mps=c,
        emitter_height_m=rng.uniform(-10.0, 10.0),
        noise=NoiseSigmas(doppler_hz=rng.uniform(0.01, 5.0), toa_s=range_sigma_m / c, rss_db=4.0),
    )


def cls_instance(seed: int, headings: int, rows: str) -> tuple[np.ndarray, np.ndarray]:
    """``(A, b)`` of ``cls_rows`` on one noisy simulation of a random geometry and SNR."""
    rng = np.random.default_rng(seed)
    scenario = random_scenario(rng, headings)
    data = simulate(scenario, snr_db=rng.uniform(-10.0, 40.0), seed=seed)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    return cls_rows(data, frame, rows)


ROWS = ("weighted", "per-sample", "per-frame")


@pytest.mark.parametrize("rows", ROWS)
@pytest.mark.parametrize("headings", [1, 2])
def test_gtrs_matches_brute_force_on_cls_rows(rows: str, headings: int) -> None:
    """6 × 40 = 240 simulated instances: straight and two-heading, weighted and unweighted."""
    for seed in range(40):
        A, b = cls_instance(1000 * headings + seed, headings, rows)
        assert_global_minimum(A, b)


@pytest.mark.parametrize("rank", [2, 3])
def test_gtrs_matches_brute_force_on_random_systems(rank: int) -> None:
    """40 raw random systems per rank; rank 2 is the hard case of MATH §5 whatever A is."""
    rng = np.random.default_rng(rank)
    for _ in range(40):
        m = int(rng.integers(3, 12))
        A = rng.standard_normal((m, rank)) @ rng.standard_normal((rank, 3))
        b = rng.standard_normal(m) * rng.uniform(0.1, 10.0)
        assert_global_minimum(A, b)


def test_straight_frames_give_the_mirror_pair_in_the_hard_case() -> None:
    """One straight frame: rank 2; when the LS line crosses the paraboloid the two minimisers
    are mirror images across the track, of equal cost (MATH §5, §7)."""
    hard = 0
    for seed in range(60):
        rng = np.random.default_rng(seed)
        scenario = random_scenario(rng, 1)
        data = simulate(scenario, snr_db=rng.uniform(10.0, 40.0), seed=seed)
        frame = LocalFrame.fit(data.position_m, data.range_m)
        local_position = frame.positions(data.position_m)
        origin, direction = straight_track_line(local_position, data.velocity_mps)
        for rows in ROWS:
            solution = solve_gtrs(*cls_rows(data, frame, rows))
            assert solution.rank == 2
            xy = solution.points[:, :2]
            if solution.hard_case:
                hard += 1
                assert len(xy) == 2
                np.testing.assert_allclose(
                    mirror_across_line(xy[0], origin, direction), xy[1], atol=1e-9
                )
                np.testing.assert_allclose(solution.costs[0], solution.costs[1], rtol=1e-9)
            else:
                # the LS line misses the paraboloid: one point, on the track's vertical plane
                assert len(xy) == 1
                offset = xy[0] - origin
                assert abs(direction[0] * offset[1] - direction[1] * offset[0]) < 1e-9
    assert hard >= 0.9 * 60 * len(ROWS)


def test_least_squares_line_missing_the_paraboloid_gives_one_point_on_the_track_plane() -> None:
    """Ranges 20 % short on the paper geometry: ``y² = 0.64 r² − x-terms − 50² < 0``, so the
    least-squares line misses the paraboloid and the minimiser is unique, on y = 0 (MATH §5)."""
    scenario = Scenario(
        name="short",
        emitter_m=[35.0, 15.0],
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=[[10.0, 0.0, 0.0]],
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
        carrier_hz=3e8,
        speed_of_light_mps=3e8,
        noise=NoiseSigmas(doppler_hz=0.1, toa_s=1.0 / 3e8, rss_db=4.0),
    )
    exact = noise_free(scenario)
    data = replace(exact, toa_s=0.8 * exact.toa_s)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    for rows in ROWS:
        A, b = cls_rows(data, frame, rows)
        solution = solve_gtrs(A, b)
        assert not solution.hard_case
        assert solution.points.shape == (1, 3)
        world = frame.to_world(solution.points[0, :2])
        assert abs(world[1]) < 1e-9 * frame.scale_m
        assert_global_minimum(A, b)


@pytest.mark.parametrize(("snr_db", "rows"), [(60.0, "weighted"), (None, "per-sample")])
def test_headings_a_millidegree_apart_are_not_a_hard_case(snr_db, rows) -> None:
    """Paper geometry, second frame turned by 0.001°: ``e₁`` is tiny but real, so the minimiser
    is unique; the mirror point costs 1.5 % more at 60 dB (and 1e-12 against 1e-31 noise-free)."""
    scenario = get_scenario("paper-1m")
    scenario = scenario.replace(
        flight=replace(
            scenario.flight, frame_velocities_mps=heading_velocities_mps(10.0, [0.0, 0.001])
        )
    )
    data = noise_free(scenario) if snr_db is None else simulate(scenario, snr_db=snr_db, seed=1)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    solution = solve_gtrs(A, b)
    assert not solution.hard_case
    assert solution.points.shape == (1, 3)
    assert_global_minimum(A, b)
    if snr_db is None:
        np.testing.assert_allclose(frame.to_world(solution.points[0, :2]), [35, 15], atol=1e-6)


def test_noise_free_paper_frame_returns_emitter_and_mirror() -> None:
    """Noise-free paper scenario: the two hard-case points are (35, ±15) m exactly."""
    scenario = Scenario(
        name="paper",
        emitter_m=[35.0, 15.0],
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=[[10.0, 0.0, 0.0]],
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
        carrier_hz=3e8,
        speed_of_light_mps=3e8,
        noise=NoiseSigmas(doppler_hz=0.1, toa_s=1.0 / 3e8, rss_db=4.0),
    )
    data = noise_free(scenario)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    for rows in ROWS:
        solution = solve_gtrs(*cls_rows(data, frame, rows))
        assert solution.hard_case
        world = frame.to_world(solution.points[:, :2])
        np.testing.assert_allclose(world[np.argsort(world[:, 1])], [[35, -15], [35, 15]], atol=1e-9)
        assert solution.multiplier == pytest.approx(0.0, abs=1e-12)


def test_zero_rz_column_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"^A: the r_z column is zero"):
        solve_gtrs(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([1.0, 2.0]))


# --------------------------------------------------------------------------------------------
# many systems in one call (estimators.closed_form.gtrs_batch): solve_gtrs is the batch of one
# --------------------------------------------------------------------------------------------


def _blocks(A: np.ndarray, b: np.ndarray) -> list:
    """Systems stacked along the last axis: A (m, 3, n), b (m, n) as one row block."""
    from estimators.closed_form.gtrs_batch import RowBlock

    return [RowBlock(ax=A[:, 0], ay=A[:, 1], az=A[:, 2], b=b)]


def _random_systems(rank: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random systems of 8 rows of rank ``rank``: A (8, 3, n), b (8, n)."""
    rng = np.random.default_rng(10 + rank)
    A = np.einsum(
        "mrn,rcn->mcn", rng.standard_normal((8, rank, n)), rng.standard_normal((rank, 3, n))
    )
    return A, rng.standard_normal((8, n)) * rng.uniform(0.1, 10.0, size=n)


@pytest.mark.parametrize("rank", [2, 3])
def test_a_system_gets_the_same_bits_alone_and_in_a_batch(rank: int) -> None:
    """500 random systems in one call, and each alone (``solve_gtrs``): the same code on the
    same rows (the row sums of :func:`~estimators.closed_form.gtrs_rank.row_dot` do not depend
    on the batch), so the same bits. Rank 2 is the hard case (MATH §5)."""
    from estimators.closed_form.gtrs_batch import solve_gtrs_batch

    n = 500
    A, b = _random_systems(rank, n)
    batch = solve_gtrs_batch(_blocks(A, b), n, rank=True)
    assert not batch.failed.any()
    for i in range(n):
        single = solve_gtrs(A[:, :, i], b[:, i])
        count = int(batch.count[i])
        assert len(single.points) == count
        assert single.hard_case == bool(batch.hard_case[i])
        assert single.rank == int(batch.rank[i])
        assert single.multiplier == batch.multiplier[i]
        np.testing.assert_array_equal(single.points[:, 0], batch.x[i, :count])
        np.testing.assert_array_equal(single.points[:, 1], batch.y[i, :count])
        np.testing.assert_array_equal(single.costs, batch.costs[i, :count])
    if rank == 2:
        assert batch.hard_case.mean() > 0.3
        pair = batch.hard_case  # the pair lies on the null line, at costs equal to rounding
        np.testing.assert_allclose(batch.costs[pair, 0], batch.costs[pair, 1], rtol=1e-9)
    else:
        assert not batch.hard_case.any()
        assert (batch.rank == 3).all()


@pytest.mark.parametrize("rank", [2, 3])
def test_random_systems_attain_the_brute_force_minimum(rank: int) -> None:
    """Twenty of the random systems above against the brute-force search: in the hard case and
    off it, the batch's answer is the global minimum."""
    A, b = _random_systems(rank, 20)
    for i in range(20):
        assert_global_minimum(A[:, :, i], b[:, i])


def test_batch_solver_flags_what_it_cannot_solve() -> None:
    """A zero r_z column (no ToA rows), for which solve_gtrs raises, and non-finite rows are
    flagged as failed, without an exception or a warning."""
    from estimators.closed_form.gtrs_batch import solve_gtrs_batch

    A = np.zeros((4, 3, 3))
    A[:, :2, :] = np.random.default_rng(0).standard_normal((4, 2, 3))
    A[:, 2, 1:] = 1.0
    A[0, 0, 2] = np.inf
    b = np.ones((4, 3))
    batch = solve_gtrs_batch(_blocks(A, b), 3)
    assert batch.failed.tolist() == [True, False, True]
    with pytest.raises(ValueError, match=r"^A: the r_z column is zero"):
        solve_gtrs(A[:, :, 0], b[:, 0])
    with pytest.raises(ValueError, match=r"^A, b: the rows hold NaN"):
        solve_gtrs(A[:, :, 2], b[:, 2])


@pytest.mark.parametrize(
    ("bend", "expected"),
    [(0.0, (True, True)), (1e-11, (True, False)), (1e-6, (False, False))],
)
def test_straight_track_lines_decide_each_tolerance_as_straight_track_line(bend, expected):
    """One decomposition, several tolerances (the CLS's straight and collinear tests, MATH §5,
    §7): a track bent sideways by ``bend`` of its length is straight to 1e-9 but not to 1e-13
    at 1e-11, and at 1e-6 to neither; each answer is straight_track_line's at that tolerance."""
    along = np.linspace(-400.0, 400.0, 9)
    position = np.column_stack(
        [along, 20.0 + bend * 800.0 * (along / 400.0) ** 2, np.full(9, 50.0)]
    )
    velocity = np.tile([30.0, 0.0, 0.0], (9, 1))
    lines = straight_track_lines(position, velocity, (1e-9, 1e-13))
    assert tuple(line is not None for line in lines) == expected
    for line, rtol in zip(lines, (1e-9, 1e-13), strict=True):
        single = straight_track_line(position, velocity, rtol=rtol)
        assert (line is None) == (single is None)
        if line is not None:
            np.testing.assert_array_equal(line[0], single[0])
            np.testing.assert_array_equal(line[1], single[1])
            np.testing.assert_allclose(
                line[0], [0.0, 20.0 + bend * 800.0 * 5.0 / 12.0], rtol=0.0, atol=1e-12
            )
            assert abs(line[1][0]) == pytest.approx(1.0, abs=1e-12)
