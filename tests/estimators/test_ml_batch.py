"""The batch path of ``ml`` (``estimate_batch``, ``estimate_columns``) against ``estimate``,
trial by trial, with each trial's own generator, and the pieces it is built from.

Two paths agree by the rule of :mod:`tests.paths` (equal to rounding, at a tolerance from the
problem's conditioning): the same ``success``, ``ambiguous`` and message; the candidates in the
same order and the position as positions; the covariance as a covariance, or absent in both
(the columns hold NaN where a trial has none); the same diagnostics keys in the same order, the
same integers, strings, flags and per-start statuses, the cost to rounding; a failed trial's
columns hold no diagnostics (:class:`~estimators.batch.BatchEstimates`). The
families: one straight frame (``paper-1m``: every trial the hard case of the CLS, a mirror
pair and a tie-break draw), ten frames with a turn (``paper-1m-turn``), the paper's 300 km
ToA noise (``paper``: Doppler-only starts, far CLS starts, on-plane starts), and an emitter
5 cm from the plane of a track at 37° (``near-plane``: minima on and near the plane).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

import estimators.ml.ml_batch_starts as ml_batch_starts
from estimators.base import Estimate, capabilities_of, protocol_problems
from estimators.closed_form.cls import solve_doppler_toa_cls
from estimators.closed_form.cls_rows import LocalFrame
from estimators.ml.minpack_batch import (
    INFO_CODES,
    RDWARF,
    RGIANT,
    enorm_rows,
    lmder_batch,
    ordered_sum,
)
from estimators.ml.ml import (
    MINPACK_STATUS,
    MaximumLikelihood,
    straight_track_starts,
    whitened_residual_jacobian,
    whitened_residuals,
)
from estimators.ml.ml_batch import SharedContext
from estimators.ml.ml_batch_starts import START_GRID, batch_starts, on_start_grid
from estimators.ml.ml_starts import doppler_frame_starts, ranges_uninformative
from scenarios.catalog import get_scenario
from scenarios.geometry import straight_track_line
from scenarios.types import MeasurementBatch, Scenario
from tests import paths
from tests.estimators import batch_support
from tests.estimators.batch_support import generators, path_problems, rotated


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
# batch = one at a time
# --------------------------------------------------------------------------------------------

DEFERRED_AT_MOST = {"paper-1m": 10, "paper-1m-turn": 10, "paper": 10, "near-plane": 10}
"""Trials of 2,000 the batch may leave to ``estimate`` (0.5%: it leaves 0-3 of each)."""


@pytest.mark.paths
@pytest.mark.parametrize("family", sorted(DEFERRED_AT_MOST))
def test_batch_equals_one_at_a_time(family: str) -> None:
    n = 2000
    batch = family_batch(family, n)
    estimator = MaximumLikelihood()
    columns = estimator.estimate_columns(batch, rngs=generators(n))
    assert len(columns) == n
    assert differences(estimator, batch, columns) == []
    deferred = int(columns.recomputed.sum())
    assert deferred <= DEFERRED_AT_MOST[family], deferred
    solved = ~columns.recomputed
    starts = columns.diagnostics["n_starts"]
    if family == "paper-1m":  # the CLS pair folds to one start; every answer a mirror pair
        assert (starts[solved] == 1).all()
        assert (columns.n_candidates == 2).all() and columns.ambiguous.all()
    if family == "paper-1m-turn":  # the turn resolves the side
        assert not columns.ambiguous.any() and (columns.n_candidates == 1).all()
    if family == "paper":  # CLS and Doppler starts, and on-plane minima without covariance
        assert (starts[solved] >= 2).all()
        singular = columns.message_code[solved] == 1
        assert 0.2 < singular.mean() < 0.8, singular.mean()
        assert np.isnan(columns.covariance_m2[solved][singular]).all()
    if family == "near-plane":  # a CLS start on the plane gets a copy off it
        assert 0.05 < np.mean(starts[solved] == 2) < 0.95


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
def test_options_batch_equals_one_at_a_time(family: str, estimator) -> None:
    n = 2000
    batch = family_batch(family, n, seed=1)
    columns = estimator.estimate_columns(batch, rngs=generators(n))
    assert differences(estimator, batch, columns) == []
    assert int(columns.recomputed.sum()) <= n // 200


def sub_batch(batch: MeasurementBatch, trials: slice) -> MeasurementBatch:
    return MeasurementBatch(
        geometry=batch.geometry,
        doppler_hz=batch.doppler_hz[trials],
        toa_s=batch.toa_s[trials],
        rss_dbm=None if batch.rss_dbm is None else batch.rss_dbm[trials],
    )


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


# --------------------------------------------------------------------------------------------
# what the batch leaves to the one-at-a-time path
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
@pytest.mark.parametrize("family", ["paper-1m", "paper", "near-plane"])
def test_starts_in_doubt_are_found_one_trial_at_a_time(monkeypatch, family) -> None:
    """With every start's error bound inflated past the grid, every trial's starts are in
    doubt: ``estimate``'s own code finds them, the search stays in the batch (nothing is
    recomputed), and every trial, draws included, still equals ``estimate``."""
    monkeypatch.setattr(ml_batch_starts, "START_ERROR_FACTOR", 1e6)
    batch = family_batch(family, 40, seed=4)
    columns = MaximumLikelihood().estimate_columns(batch, rngs=generators(40))
    assert not columns.recomputed.any() and columns.success.all()
    assert differences(MaximumLikelihood(), batch, columns) == []


@pytest.mark.paths
@pytest.mark.parametrize("max_nfev", [1, 2])
def test_an_iteration_cap_is_left_to_the_one_trial_path(max_nfev) -> None:
    """Starts stopped by the cap did not converge: ``estimate`` writes the failure with
    scipy's message; the batch hands those trials over and agrees. (From the CLS start the
    search converges at its third evaluation: ``max_nfev=3`` would succeed everywhere.)"""
    batch = family_batch("paper-1m-turn", 30, seed=5)
    estimator = MaximumLikelihood(max_nfev=max_nfev)
    columns = estimator.estimate_columns(batch, rngs=generators(30))
    assert columns.recomputed.all() and not columns.success.any()
    assert differences(estimator, batch, columns) == []
    assert "did not converge from any start" in columns.estimate(0).message


@pytest.mark.paths
def test_the_trf_method_is_solved_one_at_a_time() -> None:
    batch = family_batch("turn", 20, seed=6)
    estimator = MaximumLikelihood(method="trf")
    columns = estimator.estimate_columns(batch, rngs=generators(20))
    assert columns.recomputed.all() and columns.success.all()
    assert differences(estimator, batch, columns) == []


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
# the pieces: the starts, MINPACK's iteration, the ordered sums
# --------------------------------------------------------------------------------------------


def one_trial_starts(estimator: MaximumLikelihood, data) -> np.ndarray:
    """The local, gridded starts ``estimate`` searches from (its own code path)."""
    used = data.select_frames(estimator.frames)
    starts = solve_doppler_toa_cls(used).candidates_m
    if ranges_uninformative(used):
        last = used.take(used.frame == used.frame[-1])
        starts = np.vstack([starts, doppler_frame_starts(last)])
    frame = LocalFrame.fit(used.position_m, used.range_m)
    line = straight_track_line(used.position_m, used.velocity_mps)
    if line is not None:
        starts = straight_track_starts(used, starts, line, frame.scale_m)
    return on_start_grid(frame.to_local(starts))


def grid_points(local_xy: np.ndarray) -> np.ndarray:
    """Which ``START_GRID`` point each start is rounded to (integers: a decision, not a
    rounded number)."""
    return np.rint(np.asarray(local_xy) / START_GRID).astype(np.int64)


@pytest.mark.paths
@pytest.mark.parametrize("family", ["paper", "near-plane", "paper-1m-turn"])
def test_batch_starts_are_within_their_bound_and_on_the_same_grid_points(family) -> None:
    n = 300
    batch = family_batch(family, n, seed=9)
    estimator = MaximumLikelihood()
    context = SharedContext.of(estimator, batch)
    trials = np.arange(n)
    ranges, scale = context.frame_scales(trials)
    starts, count, error, doubt = batch_starts(context, trials, ranges, scale)
    assert doubt.sum() < n // 10
    largest = 0.0
    for i in np.flatnonzero(~doubt):
        data = batch.trial(i)
        frame = LocalFrame.fit(data.position_m, data.range_m)
        assert paths.number_problems("scale", frame.scale_m, scale[i], frame.scale_m) == []
        expected = one_trial_starts(estimator, data)
        assert len(expected) == count[i]
        got = frame.to_local(starts[i, : count[i]])
        gap = np.max(np.abs(got - frame.to_local(frame.to_world(expected))), axis=1)
        bound = error[i, : count[i]] / scale[i] + 0.5 * 2.0**-16
        assert (gap <= bound).all()
        largest = max(largest, float(np.max(error[i, : count[i]] / scale[i])))
        assert (grid_points(got) == grid_points(expected)).all()
    assert largest < 1e-6  # the bounds are far below the grid: few doubts


def problem_batch(n: int, seed: int):
    """``n`` single-start problems of the ``paper`` family: residuals and Jacobian functions
    in local units for the engine and for ``least_squares``, and the starts."""
    batch = family_batch("paper", n, seed=seed)
    trials = [batch.trial(i) for i in range(n)]
    frames = [LocalFrame.fit(t.position_m, t.range_m) for t in trials]
    starts = np.array(
        [
            f.to_local(solve_doppler_toa_cls(t).candidates_m[0])
            for t, f in zip(trials, frames, strict=True)
        ]
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
    the end point by the position rule of :mod:`tests.paths` in local units (length
    ``max(‖x‖, 1)``, ``κ = cond(JᵀJ)`` there: a least-squares solution's sensitivity, its
    residual term included), each residual to rounding of ``‖J‖ · L`` (the size of its terms)
    at the same ``κ``, the same number of evaluations and the same status."""
    J = expected.jac
    length = max(float(np.max(np.abs(expected.x))), 1.0)
    kappa = paths.condition(J.T @ J)
    problems = paths.position_problems("x", expected.x, result.x[i], length, kappa)
    scale = float(np.linalg.norm(J, ord=2)) * length
    for k, (a, b) in enumerate(zip(expected.fun, result.fvec[:, i], strict=True)):
        problems += paths.number_problems(f"residual {k}", a, b, scale, kappa)
    if result.nfev[i] != expected.nfev:
        problems.append(f"nfev {result.nfev[i]} vs {expected.nfev}")
    if INFO_CODES[int(result.info[i])] != MINPACK_STATUS[int(expected.status)]:
        problems.append(f"status {result.info[i]} vs {expected.status}")
    return problems


@pytest.mark.paths
def test_the_engine_repeats_least_squares() -> None:
    """Far starts (the paper's 300 km ranges): tens of evaluations, rejected steps, the
    Levenberg-Marquardt parameter iterated; the engine ends where scipy's MINPACK ends, after
    as many evaluations (it repeats MINPACK's arithmetic; to rounding across paths)."""
    trials, frames, starts, residuals, jacobian = problem_batch(60, seed=10)
    result = lmder_batch(
        residuals, jacobian, starts, ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200
    )
    assert not result.odd.any()
    assert result.nfev.max() > 20
    for i, (data, frame) in enumerate(zip(trials, frames, strict=True)):
        scipy_result = least_squares(
            lambda u, d=data, f=frame: whitened_residuals(d, f.to_world(u)),
            starts[i],
            jac=lambda u, d=data, f=frame: whitened_residual_jacobian(d, f.to_world(u)) * f.scale_m,
            method="lm",
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
            max_nfev=200,
        )
        assert minpack_problems(result, i, scipy_result) == []


@pytest.mark.paths
def test_the_engine_handles_a_zero_jacobian_column_as_minpack_does() -> None:
    """A start exactly on a straight track's plane (y = 0 on the x axis): the cross-track
    column of the Jacobian is zero, MINPACK's rank-deficient branch; the search stays on the
    plane exactly as scipy's."""
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
    expected = least_squares(
        lambda u: residuals(None, u[None])[:, 0],
        start[0],
        jac=lambda u: np.hstack(jacobian(None, u[None])),
        method="lm",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=200,
    )
    assert not result.odd[0] and result.x[0, 1] == 0.0 == expected.x[1]
    assert minpack_problems(result, 0, expected) == []


def test_ordered_sums_add_in_order() -> None:
    """``s = 0; s += v[i]`` column by column, for any layout (a pairwise sum would differ)."""
    rng = np.random.default_rng(12)
    for shape in [(1, 1), (7, 1), (40, 2), (300, 5), (33, 1000), (200, 1024), (4099, 3)]:
        values = rng.standard_normal(shape) * 10.0 ** rng.uniform(-8, 8, shape)
        for layout in (values, np.asfortranarray(values)):
            expected = np.zeros(shape[1])
            for row in values:
                expected = expected + row
            np.testing.assert_array_equal(ordered_sum(layout), expected)
    big = rng.standard_normal(1000) * 10.0 ** rng.uniform(-8, 8, 1000)
    assert ordered_sum(big) != np.sum(big)  # numpy's own sum is pairwise
    total = 0.0
    for value in big:
        total += value
    assert ordered_sum(big) == total


def test_enorm_flags_exactly_the_columns_minpack_would_scale() -> None:
    """The screen on the squares misses no column with a component in ``(0, RDWARF]`` or not
    below ``RGIANT / m``, and flags none that has none; the norm is the ordered one."""
    rng = np.random.default_rng(5)
    m, k = 50, 12
    values = rng.standard_normal((m, k))
    values[3, 0] = RDWARF  # the edge itself: scaled
    values[4, 1] = RDWARF * (1.0 + 1e-15)  # just above: not scaled
    values[5, 2] = 1e-200  # its square underflows to zero
    values[6, 3] = 0.0  # zero is not small
    values[7, 4] = RGIANT / m  # the upper edge: scaled
    values[8, 5] = np.nextafter(RGIANT / m, 0.0)  # just below: not scaled
    values[9, 6] = np.nan
    values[10, 7] = -np.inf
    norm, odd = enorm_rows(values)
    size = np.abs(values)
    expected = np.any(((size <= RDWARF) & (size != 0.0)) | ~(size < RGIANT / m), axis=0)
    np.testing.assert_array_equal(odd, expected)
    assert odd.tolist()[:8] == [True, False, True, False, True, False, True, True]
    np.testing.assert_array_equal(norm[~odd], np.sqrt(ordered_sum(values**2))[~odd])
