"""The pseudo-range closed form (MATH §15) for many trials at once against one at a time.

Checks, with numbers: the indefinite GTRS of a stack of systems, hard cases at both ends mixed
with ordinary systems, against each system solved alone (to a tolerance from each system's
measured conditioning, :mod:`tests.paths`); ``cls`` columns of noise-free trials with unknown
emission times and carrier offsets, each exact; and the columns of a straight frame (the hard
case and the physical-sheet fallback mixed with ordinary trials; a mirror pair and the
tie-break drawn per trial) against ``estimate``.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.closed_form.cls import Cls
from estimators.closed_form.gtrs_indefinite import (
    solve_gtrs_indefinite,
    solve_gtrs_indefinite_batch,
)
from estimators.closed_form.pseudorange_cls import solve_pseudorange_batch, solve_pseudorange_cls
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate_trials, trial_seeds
from scenarios.types import MeasurementBatch
from tests import paths
from tests.estimators.batch_support import generators, path_problems

BOTH = ("carrier_offset_hz", "emission_time_s")
HYPERBOLOID = np.array([1.0, 1.0, -1.0])


def mixed_systems(n: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` systems on a hyperboloid (one or two sheets, ``c`` of either sign): every third with a zero x column (the hard case at the
    lower end when it occurs), every third with a zero ρ column (the upper end), the rest
    ordinary."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 6, 3))
    A[0::3, :, 0] = 0.0
    A[1::3, :, 2] = 0.0
    return A, 3.0 * rng.normal(size=(n, 6)), rng.normal(size=n)


def measured_condition(A: np.ndarray, b: np.ndarray, c: float, points: np.ndarray) -> float:
    """How far the minimisers move, in units of their size, per relative change of the data
    (the rule of :mod:`tests.paths`, for a GTRS): at least one."""
    step = paths.SENSITIVITY_STEP
    signs = np.random.default_rng(20).choice([-1.0, 1.0], size=A.size + b.size)
    moved = solve_gtrs_indefinite(
        A * (1.0 + step * signs[: A.size].reshape(A.shape)),
        b * (1.0 + step * signs[A.size :]),
        HYPERBOLOID,
        None,
        c,
    ).points
    if len(moved) == 0:
        return np.inf
    distance = np.linalg.norm(points[:, None] - moved[None], axis=2).min(axis=1).max()
    return max(1.0, float(distance) / max(float(np.max(np.abs(points))), paths.EPS) / step)


@pytest.mark.paths
def test_gtrs_batch_with_hard_cases_matches_each_system_alone() -> None:
    A, b, c = mixed_systems(30)
    batch = solve_gtrs_indefinite_batch(A, b, HYPERBOLOID, None, c)
    ends = set()
    for i in range(len(A)):
        alone = solve_gtrs_indefinite(A[i], b[i], HYPERBOLOID, None, c[i])
        got = batch.solution(i)
        assert (got.status, got.hard_end, got.rank, len(got.points)) == (
            alone.status,
            alone.hard_end,
            alone.rank,
            len(alone.points),
        )
        ends.add(got.hard_end)
        if not len(alone.points):
            continue
        kappa = measured_condition(A[i], b[i], c[i], alone.points)
        scale = float(np.max(np.abs(alone.points)))
        tolerance = paths.SAFETY * kappa * paths.EPS * scale
        np.testing.assert_allclose(got.points, alone.points, rtol=0, atol=tolerance)
        cost_scale = float(np.sum(b[i] ** 2))
        np.testing.assert_allclose(
            got.costs, alone.costs, rtol=0, atol=paths.SAFETY * kappa * paths.EPS * cost_scale
        )
    assert {None, "lower", "upper"} <= ends  # ordinary systems and both hard ends, mixed


def noise_free_batch(scenario_name: str, emission_s: np.ndarray, offset_hz: np.ndarray):
    """Noise-free trials of one geometry, trial ``i`` with emission time ``emission_s[i]`` and
    carrier offset ``offset_hz[i]`` (both unknown to the estimator)."""
    scenario = get_scenario(scenario_name).replace(
        unknowns=BOTH, emission_time_s=0.0, carrier_offset_hz=0.0
    )
    data = noise_free(scenario)
    return scenario, MeasurementBatch(
        geometry=data,
        doppler_hz=data.doppler_hz[None] + offset_hz[:, None],
        toa_s=data.toa_s[None] + emission_s[:, None],
        rss_dbm=None,
    )


@pytest.mark.parametrize("scenario_name", ["turn", "beacon-pass"])
def test_noise_free_columns_with_unknowns_are_exact(scenario_name) -> None:
    emission = np.array([0.0, 3e-4, -2e-6, 1.5e-3])
    offset = np.array([0.0, 800.0, -350.0, 1e3])
    scenario, batch = noise_free_batch(scenario_name, emission, offset)
    columns = Cls().estimate_columns(batch)
    assert columns.success.all()
    np.testing.assert_allclose(
        columns.position_m, np.tile(scenario.emitter_m, (len(emission), 1)), rtol=0, atol=1e-6
    )
    np.testing.assert_allclose(columns.diagnostics["emission_time_s"], emission, atol=1e-12)
    np.testing.assert_allclose(columns.diagnostics["carrier_offset_hz"], offset, atol=1e-6)
    assert set(columns.diagnostics["status"]) == {"interior-root"}


@pytest.mark.bits("solve_pseudorange_cls runs solve_pseudorange_batch on the same one-row arrays")
def test_batch_of_one_is_solve_pseudorange_cls() -> None:
    """``solve_pseudorange_cls`` is the batch of one: the same arrays give the same bits."""
    batch = simulate_trials(
        get_scenario("turn-noncooperative"), snr_db=10.0, seeds=trial_seeds(4, 1)
    )
    data = batch.trial(0)
    alone = solve_pseudorange_cls(data, carrier_offset_unknown=True)
    one = solve_pseudorange_batch(
        data, data.range_m[None], data.doppler_hz[None], carrier_offset_unknown=True
    )
    assert np.array_equal(alone.candidates_m, one.candidates_m[0, : one.count[0]])
    assert np.array_equal(alone.carrier_offset_hz, one.carrier_offset_hz[0, : one.count[0]])


@pytest.mark.paths
@pytest.mark.parametrize("snr_db", [-10.0, 30.0])
def test_straight_frame_columns_match_estimate(snr_db) -> None:
    """A straight frame with both unknown: a batch mixing the hard case (30 dB) or the
    physical-sheet fallback (−10 dB) with ordinary trials; every trial ambiguous (the mirror
    pair), one tie-break drawn per trial."""
    scenario = get_scenario("paper-1m").replace(
        unknowns=BOTH, emission_time_s=3e-4, carrier_offset_hz=800.0
    )
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(11, 10))
    estimator = Cls()
    columns = estimator.estimate_columns(batch, rngs=generators(10))
    singles = [estimator.estimate(batch.trial(i), rng=rng) for i, rng in enumerate(generators(10))]
    assert columns.ambiguous.all() and columns.diagnostics["straight_track"].all()
    statuses = set(columns.diagnostics["status"])
    if snr_db > 0.0:  # the hard case (a pair of equal cost) beside ordinary roots
        assert statuses == {"hard-case", "interior-root"}
    else:  # and trials whose global minimiser is on the wrong sheet
        assert "wrong-sheet-fallback" in statuses
    for i, single in enumerate(singles):
        assert not path_problems(estimator, batch.trial(i), single, columns.estimate(i))
