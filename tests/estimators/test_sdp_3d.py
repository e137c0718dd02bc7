"""The SDP relaxation of MATH §11 with the emitter's height a coordinate: the lift over
``(x, y, z, ‖s‖², 1)`` (5×5) against the exact GTRS of MATH §5 in three dimensions, the
"closed form against its convex relaxation" promise in 3-D."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import make_estimator
from estimators.closed_form.cls_batch import system_of_trial
from estimators.closed_form.gtrs import constrained_cost, solve_gtrs
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sdp.sdp_cls import solve_sdp_relaxation
from estimators.sdp.sdp_lift import compress_rows
from scenarios import get_scenario, simulate_trials, trial_seeds
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free, simulate
from tests.estimators.test_cls_3d import elevated, random_flight

VALUE_RTOL = 1e-6
"""The relaxation's value against the GTRS optimum, relative: the interior-point solver stops
at a relative gap of 1e−9 of the whitened problem, whose scale is the least-squares residual
(a lower bound of the optimum), so 1e−6 leaves three orders for the conditioning."""

VALUE_ATOL = 1e-12
"""Times ``‖b‖²``: where the optimum is zero to rounding (noise-free data) the value is held
to the rounding of the cost, ``ε·‖b‖²`` summed over the rows, with margin."""

POINT_ATOL = 1e-3
"""The recovered minimisers against the closed form's, in the local frame's unit (as in 2-D)."""


def rows_of(data):
    """The weighted rows of the last stage (MATH §6), as ``cls`` solves them: (m, 4)."""
    A, b, offset, _ = system_of_trial(data, "weighted", last_stage=True, dimension=3)
    assert offset is None and A.shape[1] == 4
    return A, b


@pytest.mark.parametrize("snr_db", [None, 0.0, 20.0], ids=["noise-free", "0dB", "20dB"])
@pytest.mark.parametrize("climb", [True, False], ids=["climbing", "level"])
@pytest.mark.parametrize("seed", range(3))
def test_the_relaxations_optimum_is_the_gtrs_optimum(seed, climb, snr_db) -> None:
    """On random climbing flights (one minimiser, a rank-one lift) and level ones (the emitter
    and its reflection through the flight plane, a rank-two lift): the relaxation's value is
    the exact GTRS's, and the minimisers recovered from the lift are the closed form's."""
    scenario = random_flight(seed, climb=climb)
    data = noise_free(scenario) if snr_db is None else simulate(scenario, snr_db=snr_db, seed=seed)
    A, b = rows_of(data)
    closed = solve_gtrs(A, b)
    sdp = solve_sdp_relaxation(A, b)
    assert sdp.status == "optimal" and sdp.lift.shape == (5, 5)
    best = closed.costs.min()
    tolerance = VALUE_RTOL * best + VALUE_ATOL * (b @ b)
    assert abs(sdp.value - best) <= tolerance, (sdp.value, best)
    np.testing.assert_allclose(
        constrained_cost(A, b, sdp.points[:, :3]), sdp.costs, rtol=1e-12, atol=VALUE_ATOL * (b @ b)
    )
    assert np.all(np.abs(sdp.costs - best) <= tolerance)
    assert len(closed.points) == (1 if climb else 2)
    distance = np.linalg.norm(sdp.points[:, None, :3] - closed.points[None, :, :3], axis=-1)
    assert distance.min(axis=1).max() <= POINT_ATOL  # every recovered point is a minimiser
    if snr_db is None and not climb:
        # a zero optimum: either rank-one lift of the pair is optimal, and the solver may
        # stop at one (sdp-cls then adds its reflection, test_a_level_flight_...)
        assert 1 <= len(sdp.points) <= 2
        return
    assert len(sdp.points) == len(closed.points) and sdp.rank == len(closed.points)
    assert distance.min(axis=0).max() <= POINT_ATOL


@pytest.mark.parametrize("seed", range(3))
def test_the_dual_multiplier_is_the_gtrs_lambda(seed: int) -> None:
    """Off the hard case (a climbing flight at 10 dB) the dual of the lifted constraint is λ*
    of MATH §5."""
    A, b = rows_of(simulate(random_flight(seed, climb=True), snr_db=10.0, seed=seed))
    closed = solve_gtrs(A, b)
    assert not closed.hard_case
    assert solve_sdp_relaxation(A, b).multiplier == pytest.approx(closed.multiplier, rel=1e-3)


def test_the_compression_keeps_the_3d_cost() -> None:
    """``‖A r − b‖² = ‖R r − c‖² + ρ²`` with ``R`` 4×4 for rows over ``(x, y, z, ‖s‖²)``."""
    A, b = rows_of(simulate(random_flight(0, climb=True), snr_db=0.0, seed=1))
    R, c, residual_sq = compress_rows(A, b)
    assert R.shape == (4, 4) and c.shape == (4,)
    for r in np.random.default_rng(0).normal(size=(5, 4)):
        full = np.sum((A @ r - b) ** 2)
        assert np.sum((R @ r - c) ** 2) + residual_sq == pytest.approx(full, rel=1e-10)


@pytest.mark.bits("estimate is the batch of one: the same code on the same arrays")
@pytest.mark.parametrize("name", ["turn", "hill"])
def test_sdp_cls_agrees_with_cls_and_a_trial_is_the_batch_of_one(name: str) -> None:
    """``sdp-cls`` in 3-D returns ``cls``'s answer to the solver's accuracy (about 1e-6 of the
    local frame's unit, some hundreds of metres here: 1 mm), and each trial's ``estimate`` is
    its row of ``estimate_columns`` to the bit."""
    scenario = get_scenario(name)
    if HEIGHT_UNKNOWN not in scenario.unknowns:
        scenario = elevated(name)
    batch = simulate_trials(scenario, snr_db=10.0, seeds=trial_seeds(2, 12))
    sdp, cls = make_estimator("sdp-cls"), make_estimator("cls")
    columns = sdp.estimate_columns(batch)
    reference = cls.estimate_columns(batch)
    assert columns.success.all() and columns.position_m.shape == (12, 3)
    np.testing.assert_allclose(columns.position_m, reference.position_m, atol=1e-3)
    for i in (0, 5, 11):
        one = sdp.estimate(batch.trial(i))
        np.testing.assert_array_equal(one.position_m, columns.position_m[i])


def test_one_straight_track_is_refused_in_one_line() -> None:
    """As ``cls``: a circle of minimisers (MATH §7), the mirror rule's line."""
    estimator = make_estimator("sdp-cls")
    one = estimator.estimate(noise_free(elevated("paper-1m")))
    assert not one.success and one.message == STRAIGHT_TRACK_HEIGHT
    assert one.position_m.shape == (3,)
    batch = simulate_trials(elevated("paper-1m"), snr_db=10.0, seeds=trial_seeds(1, 3))
    columns = estimator.estimate_columns(batch)
    assert not columns.success.any() and columns.position_m.shape == (3, 3)


@pytest.mark.parametrize("seed", range(8))
def test_a_level_flight_noise_free_gives_the_emitter(seed: int) -> None:
    """Noise-free, on a level flight: ``sdp-cls`` returns the emitter (the reflection of a
    point recovered alone is added, and the one above the UAV dropped), to the solver's
    accuracy. (Seed 5's lift holds the point above the UAV alone.)"""
    data = noise_free(random_flight(seed, climb=False))
    estimate = make_estimator("sdp-cls").estimate(data)
    assert estimate.success, estimate.message
    scale = np.max(np.abs(data.position_m)) + np.max(np.abs(data.truth_emitter_m))
    np.testing.assert_allclose(estimate.position_m, data.truth_emitter_m, atol=1e-5 * scale)
