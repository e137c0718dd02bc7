"""``ml`` over a batch (MATH §10): the one implementation, one trial the batch of one.

The batch of a trial equals that trial alone to rounding; the search ends where scipy's
MINPACK (``least_squares(method="lm")``, the same method in another order of operations) ends,
at the same minima to ``1e-9`` of the cost.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from estimators.base import Estimate, capabilities_of, protocol_problems
from estimators.closed_form.cls_batch import candidates_of_trial
from estimators.closed_form.cls_rows import LocalFrame
from estimators.ml.minpack_batch import lmder_batch
from estimators.ml.ml import MaximumLikelihood, whitened_residual_jacobian, whitened_residuals
from estimators.ml.ml_batch import SINGULAR_NOTE, SharedContext
from estimators.ml.ml_batch_starts import find_starts, on_start_grid
from scenarios.catalog import get_scenario
from scenarios.types import MeasurementBatch, Scenario
from tests.estimators import batch_support
from tests.estimators.batch_support import generators, path_problems, rotated, sub_batch


def near_plane() -> Scenario:
    """The emitter 5 cm from the vertical plane of a track at 37°."""
    return rotated(get_scenario("paper-1m").replace(emitter_m=[35.0, 0.05]), 37.0)


FAMILIES: dict[str, tuple[Callable[[], Scenario], float]] = {
    "paper-1m": (lambda: get_scenario("paper-1m"), 0.0),
    "paper-1m-turn": (lambda: get_scenario("paper-1m-turn"), 0.0),
    "paper": (lambda: get_scenario("paper"), 0.0),
    "near-plane": (near_plane, 10.0),
    "turn": (lambda: get_scenario("turn"), -5.0),
}


def family_batch(name: str, n: int, seed: int = 0) -> MeasurementBatch:
    return batch_support.family_batch(FAMILIES, name, n, seed)


def differences(estimator, batch: MeasurementBatch, columns) -> list[str]:
    """Every way ``columns`` differs from ``estimate`` trial by trial (empty: equal)."""
    found = []
    rngs = generators(batch.n_trials)
    for i in range(batch.n_trials):
        single = estimator.estimate(batch.trial(i), rng=rngs[i])
        problems = estimate_differences(estimator, batch.trial(i), single, columns.estimate(i))
        if problems:
            found.append(f"trial {i}: {'; '.join(problems)}")
    return found


def estimate_differences(estimator, trial, single: Estimate, got: Estimate) -> list[str]:
    """:func:`~tests.estimators.batch_support.path_problems` (the cost, a sum of squares,
    to rounding of itself); a failed trial's columns hold no diagnostics."""
    if not single.success:  # the columns keep no diagnostics of a failed trial (BatchEstimates)
        extra = [f"diagnostics {got.diagnostics!r}"] if got.diagnostics else []
        single = replace(single, diagnostics={})
        return [*path_problems(estimator, trial, single, replace(got, diagnostics={})), *extra]
    return path_problems(estimator, trial, single, got)


# --------------------------------------------------------------------------------------------
# one trial = the batch of one
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
@pytest.mark.parametrize("family", ["paper-1m", "paper-1m-turn", "paper", "near-plane"])
def test_one_trial_is_the_batch_of_one(family: str) -> None:
    n = 150
    batch = family_batch(family, n)
    estimator = MaximumLikelihood()
    columns = estimator.estimate_columns(batch, rngs=generators(n))
    assert len(columns) == n and columns.success.all()
    assert differences(estimator, batch, columns) == []
    starts = columns.diagnostics["n_starts"]
    if family == "paper-1m":  # the CLS pair folds to one start; every answer a mirror pair
        assert (starts == 1).all()
        assert (columns.n_candidates == 2).all() and columns.ambiguous.all()
    if family == "paper-1m-turn":  # the turn resolves the side
        assert not columns.ambiguous.any() and (columns.n_candidates == 1).all()
    if family == "paper":  # CLS and Doppler starts, and on-plane minima without covariance
        assert (starts >= 2).all()
        singular = np.isnan(columns.covariance_m2[:, 0, 0])
        assert 0.2 < singular.mean() < 0.8, singular.mean()
        assert all(columns.message(i) == SINGULAR_NOTE for i in np.flatnonzero(singular))
    if family == "near-plane":  # a CLS start on the plane gets a copy off it
        assert 0.05 < np.mean(starts == 2) < 0.95


@pytest.mark.paths
@pytest.mark.parametrize(
    ("family", "estimator"),
    [
        ("turn", MaximumLikelihood(use_rss=True)),
        ("paper-1m-turn", MaximumLikelihood(use_rss=True, frames="last")),
        ("paper-1m-turn", MaximumLikelihood(frames="last")),
        ("paper-1m", MaximumLikelihood(side_prior_m=(30.0, -10.0))),
        ("near-plane", MaximumLikelihood(side_prior_m=(10.0, 25.0), use_rss=True)),
        ("paper-1m", MaximumLikelihood(doppler_start=True)),
        ("turn", MaximumLikelihood(doppler_start=True, cost_rtol=1e-3)),
    ],
    ids=repr,
)
def test_options_one_trial_is_the_batch_of_one(family: str, estimator) -> None:
    n = 200
    batch = family_batch(family, n, seed=1)
    columns = estimator.estimate_columns(batch, rngs=generators(n))
    assert differences(estimator, batch, columns) == []


@pytest.mark.paths
@pytest.mark.parametrize("family", ["paper-1m", "paper", "near-plane"])
def test_a_trials_result_does_not_depend_on_its_batch(family) -> None:
    """Batches of 1, 2, 3 and 7 trials give every trial what the batch of 30 gives it (other
    arrays, so to rounding: BLAS may pick other kernels by size), draws and decisions equal."""
    batch = family_batch(family, 30, seed=13)
    estimator = MaximumLikelihood()
    whole = estimator.estimate_columns(batch, rngs=generators(30))
    for size in (1, 2, 3, 7):
        for start in range(0, 30, size):
            part = slice(start, min(start + size, 30))
            columns = estimator.estimate_columns(sub_batch(batch, part), rngs=generators(30)[part])
            for i, trial in enumerate(range(30)[part]):
                a, b = whole.estimate(trial), columns.estimate(i)
                assert estimate_differences(estimator, batch.trial(trial), a, b) == [], size


@pytest.mark.paths
def test_each_generator_is_drawn_exactly_as_one_at_a_time() -> None:
    """After the batch every generator is in the state ``estimate`` leaves it in: drawn once
    on an ambiguous trial without a prior, untouched otherwise."""
    batch = family_batch("near-plane", 300, seed=3)
    batch_rngs, single_rngs = generators(300), generators(300)
    MaximumLikelihood().estimate_columns(batch, rngs=batch_rngs)
    for i in range(300):
        MaximumLikelihood().estimate(batch.trial(i), rng=single_rngs[i])
    fresh = generators(300)
    drawn = 0
    for a, b, untouched in zip(batch_rngs, single_rngs, fresh, strict=True):
        assert a.bit_generator.state == b.bit_generator.state
        drawn += a.bit_generator.state != untouched.bit_generator.state
    assert 50 < drawn < 300  # pairs off the plane draw, single minima on it do not


@pytest.mark.paths
@pytest.mark.parametrize("max_nfev", [1, 2])
def test_an_iteration_cap_fails_every_trial(max_nfev) -> None:
    """Starts stopped by the cap did not converge: every trial fails with the cap in its
    message, alone as in the batch. (From the CLS start the search converges at its third
    evaluation: ``max_nfev=3`` succeeds everywhere.)"""
    batch = family_batch("paper-1m-turn", 30, seed=5)
    estimator = MaximumLikelihood(max_nfev=max_nfev)
    columns = estimator.estimate_columns(batch, rngs=generators(30))
    assert not columns.success.any()
    assert differences(estimator, batch, columns) == []
    message = columns.estimate(0).message
    assert "did not converge from any start" in message and f"max_nfev={max_nfev}" in message
    assert MaximumLikelihood(max_nfev=3).estimate_columns(batch).success.all()


def test_bad_input_is_refused_as_one_at_a_time() -> None:
    batch = family_batch("turn", 3, seed=7)
    with pytest.raises(ValueError, match=r"^rss_dbm: estimator 'ml' with use_rss=True"):
        MaximumLikelihood(use_rss=True).estimate_batch(replace(batch, rss_dbm=None))
    with pytest.raises(ValueError, match=r"^toa_s: "):
        MaximumLikelihood().estimate_batch(replace(batch, toa_s=None))
    with pytest.raises(TypeError, match=r"^batch: expected a scenarios.types.MeasurementBatch"):
        MaximumLikelihood().estimate_batch(batch.trial(0))
    with pytest.raises(ValueError, match=r"^rngs: expected one generator per trial \(3\), got 2"):
        MaximumLikelihood().estimate_batch(batch, rngs=generators(2))


@pytest.mark.bits("estimate_batch is estimate_columns(...).to_estimates(): the same arrays")
def test_the_batch_capability_is_declared_and_lists_are_the_columns() -> None:
    estimator = MaximumLikelihood()
    assert capabilities_of(estimator).batch
    assert protocol_problems(estimator) == []
    batch = family_batch("paper-1m", 30, seed=8)
    listed = estimator.estimate_batch(batch, rngs=generators(30))
    columns = estimator.estimate_columns(batch, rngs=generators(30))
    assert [e.position_m.tolist() for e in listed] == columns.position_m.tolist()
    assert list(columns.diagnostics) == list(listed[0].diagnostics)
    assert columns.diagnostics["lm_status"][0] == listed[0].diagnostics["lm_status"]
    assert isinstance(listed[0].diagnostics["lm_status"], list)


# --------------------------------------------------------------------------------------------
# scipy's MINPACK as the cross-check, at a tolerance
# --------------------------------------------------------------------------------------------

SAME_COST_RTOL = 1e-9
"""Two searches that end at one minimum end at costs this close (relative): the tolerances
``ftol = xtol = 1e-10`` of both."""
SAME_POINT_CHI2 = 1e-6
"""...and at points this close in χ² units, ``‖J Δs‖²`` (a thousandth of a standard deviation:
where each stops inside the tolerances is the solver's choice, not the data's)."""


def point_gap_chi2(J: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """``‖J (a − b)‖²``: how far apart two points are in the data's own units (χ²)."""
    return float(np.sum((J @ (np.asarray(a) - np.asarray(b))) ** 2))


def scipy_minimum(data, frame: LocalFrame, start: np.ndarray, use_rss: bool = False):
    """``least_squares(method="lm")`` from ``start`` (local units) on ``data``."""
    return least_squares(
        lambda u: whitened_residuals(data, frame.to_world(u), use_rss=use_rss),
        start,
        jac=lambda u: (
            whitened_residual_jacobian(data, frame.to_world(u), use_rss=use_rss) * frame.scale_m
        ),
        method="lm",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=200,
    )


@pytest.mark.paths
@pytest.mark.parametrize(
    ("family", "estimator"),
    [
        ("paper", MaximumLikelihood()),
        ("near-plane", MaximumLikelihood()),
        ("turn", MaximumLikelihood(use_rss=True)),
        ("paper-1m-turn", MaximumLikelihood(doppler_start=True)),
    ],
    ids=repr,
)
def test_the_minima_are_scipys(family: str, estimator: MaximumLikelihood) -> None:
    """From each trial's starts, scipy's ``least_squares`` ends at minima whose best cost is
    the estimate's, to ``SAME_COST_RTOL``, and its best point is one of the estimate's
    candidates (or their mirror images), to rounding of the problem."""
    n = 40
    batch = family_batch(family, n, seed=14)
    columns = estimator.estimate_columns(batch)
    context = SharedContext.of(estimator, batch)
    trials = np.arange(n)
    scale = context.frame_scales(trials)
    starts, count, _, _ = find_starts(context, trials, scale)
    for i in range(n):
        data = batch.trial(i)
        frame = LocalFrame.fit(data.position_m, data.range_m)
        assert frame.scale_m == pytest.approx(scale[i], rel=1e-14)
        ends = [
            scipy_minimum(data, frame, start, estimator.use_rss)
            for start in on_start_grid(frame.to_local(starts[i, : count[i]]))
        ]
        best = min(ends, key=lambda end: end.cost)
        assert best.status > 0
        cost = columns.estimate(i).diagnostics["cost"]
        assert abs(2.0 * best.cost - cost) <= SAME_COST_RTOL * max(cost, 1.0), (i, cost)
        point = frame.to_world(best.x)
        candidates = columns.estimate(i).candidates_m
        nearest = candidates[np.argmin(np.linalg.norm(candidates - point, axis=1))]
        J = whitened_residual_jacobian(data, point, use_rss=estimator.use_rss)
        assert point_gap_chi2(J, point, nearest) <= SAME_POINT_CHI2, i


def problem_batch(n: int, seed: int):
    """``n`` single-start problems of the ``paper`` family: residuals and Jacobian functions
    in local units for the engine and for ``least_squares``, and the starts."""
    batch = family_batch("paper", n, seed=seed)
    trials = [batch.trial(i) for i in range(n)]
    frames = [LocalFrame.fit(t.position_m, t.range_m) for t in trials]
    starts = np.array(
        [f.to_local(candidates_of_trial(t)[0]) for t, f in zip(trials, frames, strict=True)]
    )
    scale = np.array([f.scale_m for f in frames])
    origin = frames[0].origin_m

    def residuals(index, local):
        world = local * scale[index, None] + origin
        return np.stack(
            [whitened_residuals(trials[i], w) for i, w in zip(index, world, strict=True)], axis=1
        )

    def jacobian(index, local):
        world = local * scale[index, None] + origin
        J = whitened_residual_jacobian(batch.geometry, world) * scale[index, None, None]
        return J[..., 0].T.copy(), J[..., 1].T.copy()

    return trials, frames, on_start_grid(starts), residuals, jacobian


def minpack_problems(result, i: int, expected) -> list[str]:
    """How the engine's search ``i`` differs from scipy's MINPACK ``expected`` (two paths):
    the end point to ``SAME_POINT_CHI2``, the cost to ``SAME_COST_RTOL``, and both ended by a
    tolerance."""
    problems = []
    gap = point_gap_chi2(expected.jac, expected.x, result.x[i])
    if not gap <= SAME_POINT_CHI2:
        problems.append(f"x {result.x[i]} vs {expected.x}: {gap:.3g} apart in χ²")
    cost, expected_cost = float(np.sum(result.fvec[:, i] ** 2)), 2.0 * float(expected.cost)
    if abs(cost - expected_cost) > SAME_COST_RTOL * max(expected_cost, 1.0):
        problems.append(f"cost {cost!r} vs {expected_cost!r}")
    if not (1 <= result.info[i] <= 4 and expected.status >= 1):
        problems.append(f"status {result.info[i]} vs {expected.status}")
    return problems


@pytest.mark.paths
def test_the_engine_ends_where_least_squares_ends() -> None:
    """Far starts (the paper's 300 km ranges): tens of evaluations, rejected steps, the
    Levenberg-Marquardt parameter iterated; the engine ends where scipy's MINPACK ends."""
    trials, frames, starts, residuals, jacobian = problem_batch(60, seed=10)
    result = lmder_batch(
        residuals, jacobian, starts, ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200
    )
    assert not result.odd.any()
    assert result.nfev.max() > 20
    for i, (data, frame) in enumerate(zip(trials, frames, strict=True)):
        expected = scipy_minimum(data, frame, starts[i])
        assert minpack_problems(result, i, expected) == []


@pytest.mark.paths
def test_the_engine_handles_a_zero_jacobian_column_as_minpack_does() -> None:
    """A start exactly on a straight track's plane (y = 0 on the x axis): the cross-track
    column of the Jacobian is zero, MINPACK's rank-deficient branch; the search stays on the
    plane exactly, as scipy's does."""
    data = family_batch("paper-1m", 1, seed=11).trial(0)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    start = np.array([[frame.to_local([30.0, 0.0])[0], 0.0]])

    def residuals(index, local):
        return whitened_residuals(data, frame.to_world(local[0]))[:, None]

    def jacobian(index, local):
        J = whitened_residual_jacobian(data, frame.to_world(local[0])) * frame.scale_m
        return J[:, :1], J[:, 1:]

    assert not np.any(jacobian(None, start)[1])
    result = lmder_batch(
        residuals, jacobian, start, ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200
    )
    expected = scipy_minimum(data, frame, start[0])
    assert not result.odd[0] and result.x[0, 1] == 0.0 == expected.x[1]
    assert minpack_problems(result, 0, expected) == []
