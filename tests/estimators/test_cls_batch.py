"""The batch path of the closed-form CLS (``estimate_batch``, ``estimate_columns``) against the
one-trial solver (``estimate_one_trial``), trial by trial, with each trial's own generator;
and ``estimate``, the batch of one, against a batch of many.

Two paths agree by the rule of :mod:`tests.paths` (equal to rounding, at a tolerance from the
problem's conditioning): the same estimator name, ``success``, ``ambiguous``, message and
diagnostics keys; the same integer and boolean diagnostics; the candidates in the same order and
the returned position as positions; the multiplier within ``SAFETY · cond(M) · EPS`` of the
scale ``‖A‖²`` of ``M = AᵀA``, the system it solves. The families cover
one straight frame (every trial the hard case, every trial a mirror pair and a tie-break
draw), turns, the paper's 300 km ToA noise, an emitter a centimetre from the track's plane
(hard case and unique root side by side) and two headings a millidegree apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

import estimators.closed_form.gtrs_batch as gtrs_batch
from estimators.base import Estimate, capabilities_of, protocol_problems
from estimators.batch import BatchEstimates
from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper, _estimate
from estimators.closed_form.cls_batch import estimate_columns
from estimators.closed_form.gtrs_rounding import row_dot
from scenarios.catalog import get_scenario, heading_velocities_mps
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import FlightPlan, MeasurementBatch, Scenario
from tests.estimators import batch_support
from tests.estimators.batch_support import generators, path_problems, rotated


def near_plane() -> Scenario:
    """The emitter 1 cm from the vertical plane of the track, on a track at 37°."""
    return rotated(get_scenario("paper-1m").replace(emitter_m=[35.0, 0.01]), 37.0)


def millidegree() -> Scenario:
    """Two frames whose headings differ by 0.001°."""
    scenario = get_scenario("paper-1m")
    velocities = heading_velocities_mps(10.0, [0.0, 0.001])
    return scenario.replace(flight=replace(scenario.flight, frame_velocities_mps=velocities))


FAMILIES: dict[str, tuple[Callable[[], Scenario], float]] = {
    "paper-1m": (lambda: get_scenario("paper-1m"), 0.0),
    "paper-1m-turn": (lambda: get_scenario("paper-1m-turn"), 0.0),
    "turn-rotated": (lambda: rotated(get_scenario("turn"), 123.0), 10.0),
    "paper": (lambda: get_scenario("paper"), 0.0),
    "near-plane": (near_plane, 20.0),
    "millidegree": (millidegree, 60.0),
}


def family_batch(name: str, n: int, seed: int = 0) -> MeasurementBatch:
    return batch_support.family_batch(FAMILIES, name, n, seed)


def differences(estimator, batch: MeasurementBatch, columns: BatchEstimates) -> list[str]:
    """Every way ``columns`` differs from the one-trial solver trial by trial (empty: equal)."""
    found = []
    rngs = generators(batch.n_trials)
    for i in range(batch.n_trials):
        trial = batch.trial(i)
        single = estimator.estimate_one_trial(trial, rng=rngs[i])
        got = columns.estimate(i)
        problems = _estimate_differences(estimator, trial, single, got)
        if problems:
            found.append(f"trial {i}: {'; '.join(problems)}")
    return found


def _estimate_differences(estimator, trial, single: Estimate, got: Estimate) -> list[str]:
    """:func:`~tests.estimators.batch_support.path_problems`, the points also within the
    bound the batch certifies (``POSITION_RTOL`` of the local unit times ``1 + ‖p‖``); the
    multiplier at the scale and conditioning of ``M = AᵀA`` (computed only when the first
    comparison finds a difference)."""
    problems = path_problems(estimator, trial, single, got)
    if problems:
        system = estimator.constrained_ls(trial)
        points = np.vstack([single.candidates_m.reshape(-1, 2), single.position_m[None]])
        points = points[np.isfinite(points).all(axis=1)]
        reach = 1.0 + float(
            np.max(np.linalg.norm((points - system.origin_m) / system.scale_m, axis=1), initial=0)
        )
        certified_m = gtrs_batch.POSITION_RTOL * reach * system.scale_m
        A = system.A
        scales = {"multiplier": (float(np.sum(A**2)), float(np.linalg.cond(A.T @ A)))}
        problems = path_problems(
            estimator, trial, single, got, certified_m=certified_m, scales=scales
        )
    return problems


# --------------------------------------------------------------------------------------------
# batch = one at a time
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
@pytest.mark.parametrize("family", sorted(FAMILIES))
@pytest.mark.parametrize(
    ("estimator", "n"),
    [(Cls(), 2000), (ClsPaper(), 2000), (ClsPaper(frames="all"), 2000), (ClsAsPrinted(), 500)],
    ids=repr,
)
def test_batch_equals_one_at_a_time(family: str, estimator, n: int) -> None:
    batch = family_batch(family, n)
    columns = estimator.estimate_columns(batch, rngs=generators(n))
    assert len(columns) == n
    assert differences(estimator, batch, columns) == []
    # the families hold the cases the batch must handle itself
    if family == "paper-1m":
        assert columns.diagnostics["hard_case"].all()
        assert (columns.n_candidates == 2).all() and columns.ambiguous.all()
    if family == "millidegree" and estimator.frames == "all":
        # the second heading resolves the side, if barely: one point, near the pole
        assert not columns.diagnostics["hard_case"].any() and not columns.ambiguous.any()
        assert (columns.diagnostics["rank"] == 3).all()
    if family == "near-plane" and estimator.name != "cls-as-printed":
        # (without the height term the pair sits 50 m off the track: always the hard case)
        hard = columns.diagnostics["hard_case"]
        assert 0.2 < hard.mean() < 0.8, hard.mean()


@pytest.mark.paths
@pytest.mark.parametrize(
    "estimator",
    [
        Cls(frames="last"),
        Cls(weighting="none"),
        ClsPaper(frames="all"),
        Cls(side_prior_m=(30.0, -10.0)),
        ClsPaper(side_prior_m=(40.0, 5.0)),
        ClsPaper(frames="all", side_prior_m=(-20.0, 15.0)),
    ],
    ids=repr,
)
@pytest.mark.parametrize("family", ["paper-1m", "paper-1m-turn", "near-plane"])
def test_options_batch_equals_one_at_a_time(family: str, estimator) -> None:
    batch = family_batch(family, 400, seed=1)
    columns = estimator.estimate_columns(batch, rngs=generators(400))
    assert differences(estimator, batch, columns) == []


def sub_batch(batch: MeasurementBatch, trials: slice) -> MeasurementBatch:
    return MeasurementBatch(
        geometry=batch.geometry,
        doppler_hz=batch.doppler_hz[trials],
        toa_s=batch.toa_s[trials],
        rss_dbm=None if batch.rss_dbm is None else batch.rss_dbm[trials],
    )


@pytest.mark.paths
@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(), Cls(weighting="none")], ids=repr)
@pytest.mark.parametrize("family", ["paper-1m", "turn-rotated", "near-plane"])
def test_a_trials_result_does_not_depend_on_its_batch(family, estimator) -> None:
    """Batches of 1, 2, 3 and 7 trials give every trial what the batch of 40 gives it
    (candidates, position, multiplier: other arrays, so to rounding; decisions and draws
    equal), recomputed trials included: a run's rows do not depend on how it is chunked."""
    batch = family_batch(family, 40, seed=13)
    whole = estimator.estimate_columns(batch, rngs=generators(40))
    for size in (1, 2, 3, 7):
        for start in range(0, 40, size):
            part = slice(start, min(start + size, 40))
            rngs = generators(40)[part]
            columns = estimator.estimate_columns(sub_batch(batch, part), rngs=rngs)
            for i, trial in enumerate(range(40)[part]):
                a, b = whole.estimate(trial), columns.estimate(i)
                assert _estimate_differences(estimator, batch.trial(trial), a, b) == [], size


@pytest.mark.paths
@pytest.mark.parametrize(
    "estimator", [Cls(), ClsPaper(), ClsAsPrinted(), Cls(weighting="none")], ids=repr
)
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_estimate_is_the_batchs_row(family, estimator) -> None:
    """``estimate`` of a trial (a batch of one) is its row of a batch of 60 (a run's row,
    whatever the chunking or a fallback to one call per trial), to rounding: position,
    candidates, message, diagnostics and the generator's state, trials the batch leaves to
    the one-trial solver included."""
    batch = family_batch(family, 60, seed=14)
    columns = estimator.estimate_columns(batch, rngs=generators(60))
    rngs = generators(60)
    for i in range(60):
        single, row = estimator.estimate(batch.trial(i), rng=rngs[i]), columns.estimate(i)
        assert _estimate_differences(estimator, batch.trial(i), single, row) == [], i
    drawn = generators(60)
    estimator.estimate_columns(batch, rngs=drawn)
    assert [r.bit_generator.state for r in rngs] == [r.bit_generator.state for r in drawn]


@pytest.mark.bits("estimate of a trial in doubt calls estimate_one_trial on the same arrays")
def test_estimate_of_a_trial_in_doubt_is_the_one_trial_solvers() -> None:
    """Where the batch defers (the emitter in the track's plane at 200 dB), ``estimate`` is the
    one-trial solver's answer itself."""
    scenario = get_scenario("paper-1m").replace(emitter_m=[35.0, 0.0])
    batch = simulate_trials(scenario, snr_db=200.0, seeds=trial_seeds(6, 40))
    columns = Cls().estimate_columns(batch)
    deferred = np.flatnonzero(columns.recomputed)
    assert deferred.size > 0
    for i in deferred.tolist():
        single, alone = Cls().estimate(batch.trial(i)), Cls().estimate_one_trial(batch.trial(i))
        assert np.array_equal(single.candidates_m, alone.candidates_m)
        assert single.diagnostics == alone.diagnostics


def test_single_columns_are_summed_in_the_order_of_many() -> None:
    """:func:`~estimators.closed_form.gtrs_rounding.row_dot` sums one system by ``cumsum`` and many
    by an outer-axis reduction: both add row after row, so a system's sums do not depend on how many
    share its batch."""
    rng = np.random.default_rng(15)
    for rows in (1, 2, 7, 8, 9, 17, 100, 1000):
        for _ in range(50):
            values = rng.standard_normal(rows) * np.exp(8.0 * rng.standard_normal(rows))
            ones = np.ones((rows, 1))
            alone = row_dot(values[:, None], ones, 1)[0]
            many = row_dot(np.column_stack([values, values[::-1], values]), ones, 3)
            assert alone == many[0] == many[2]
            total = 0.0
            for value in values:
                total += value
            assert alone == total


@pytest.mark.parametrize("estimator", [Cls(), ClsPaper()], ids=repr)
def test_standard_families_are_solved_by_the_batch_itself(estimator) -> None:
    """On the benchmark's families no trial is left to the one-at-a-time path."""
    for family in ("paper-1m", "paper-1m-turn", "turn-rotated", "paper"):
        columns = estimator.estimate_columns(family_batch(family, 2000, seed=2))
        assert int(columns.recomputed.sum()) == 0, family


@pytest.mark.bits("estimate_batch is estimate_columns(...).to_estimates(): the same arrays")
def test_estimate_batch_is_the_columns_as_estimates() -> None:
    batch = family_batch("paper-1m-turn", 50)
    estimator = Cls()
    listed = estimator.estimate_batch(batch, rngs=generators(50))
    columns = estimator.estimate_columns(batch, rngs=generators(50))
    assert len(listed) == 50
    for i, estimate in enumerate(listed):
        assert isinstance(estimate, Estimate)
        row = columns.estimate(i)
        assert (estimate.message, estimate.diagnostics) == (row.message, row.diagnostics)
        np.testing.assert_array_equal(estimate.candidates_m, row.candidates_m)
    assert [e.position_m.tolist() for e in columns.to_estimates()] == [
        e.position_m.tolist() for e in listed
    ]


# --------------------------------------------------------------------------------------------
# tie-breaking: the same draw from the same generator, only where the one-trial path draws
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(), Cls(side_prior_m=(35.0, 20.0))], ids=repr)
def test_each_generator_is_drawn_exactly_as_one_at_a_time(estimator) -> None:
    """After the batch, every generator is in the state the one-trial path leaves it in: drawn
    once on an ambiguous trial without a prior, untouched otherwise."""
    batch = family_batch("near-plane", 300, seed=3)
    batch_rngs, single_rngs = generators(300), generators(300)
    estimator.estimate_columns(batch, rngs=batch_rngs)
    for i in range(300):
        estimator.estimate_one_trial(batch.trial(i), rng=single_rngs[i])
    untouched = generators(300)
    drawn = 0
    for a, b, fresh in zip(batch_rngs, single_rngs, untouched, strict=True):
        assert a.bit_generator.state == b.bit_generator.state
        drawn += a.bit_generator.state != fresh.bit_generator.state
    if estimator.side_prior_m is None:
        assert 50 < drawn < 300  # hard-case pairs draw, unique roots on the plane do not
    else:
        assert drawn == 0


@pytest.mark.paths
def test_one_generator_shared_by_every_trial_is_drawn_in_trial_order() -> None:
    batch = family_batch("paper-1m", 200, seed=4)
    shared_batch, shared_single = np.random.default_rng(7), np.random.default_rng(7)
    columns = Cls().estimate_columns(batch, rngs=[shared_batch] * 200)
    singles = [Cls().estimate_one_trial(batch.trial(i), rng=shared_single) for i in range(200)]
    for i, single in enumerate(singles):
        assert _estimate_differences(Cls(), batch.trial(i), single, columns.estimate(i)) == []
    sides = np.sign(columns.position_m[:, 1])
    assert 0.3 < np.mean(sides > 0) < 0.7  # a fair coin over the mirror pair


def test_without_generators_the_first_candidate_is_returned() -> None:
    columns = ClsPaper().estimate_columns(family_batch("paper-1m", 100, seed=5))
    np.testing.assert_array_equal(columns.position_m, columns.candidates_m[:, 0])
    # left of the eastbound heading first: the candidate north of the track
    assert (columns.candidates_m[:, 0, 1] > 0).all()
    assert (columns.candidates_m[:, 1, 1] < 0).all()


@pytest.mark.paths
def test_without_generators_nothing_is_drawn_as_one_at_a_time() -> None:
    batch = family_batch("paper-1m", 100, seed=5)
    columns = ClsPaper().estimate_columns(batch)
    assert differences_without_rng(ClsPaper(), batch, columns) == []


def differences_without_rng(estimator, batch, columns) -> list[str]:
    return [
        f"trial {i}"
        for i in range(batch.n_trials)
        if _estimate_differences(
            estimator,
            batch.trial(i),
            estimator.estimate_one_trial(batch.trial(i)),
            columns.estimate(i),
        )
    ]


# --------------------------------------------------------------------------------------------
# what the batch leaves to the one-at-a-time path, and failures
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
def test_decisions_within_rounding_are_left_to_the_one_trial_path() -> None:
    """The emitter exactly in the track's plane at 200 dB: φ(−μ₁) is rounding, so whether the
    pair exists is rounding's choice; those trials are solved one at a time, and all agree."""
    scenario = get_scenario("paper-1m").replace(emitter_m=[35.0, 0.0])
    batch = simulate_trials(scenario, snr_db=200.0, seeds=trial_seeds(6, 100))
    for estimator in (Cls(), ClsPaper()):
        columns = estimator.estimate_columns(batch, rngs=generators(100))
        assert 10 < int(columns.recomputed.sum()) <= 100
        assert differences(estimator, batch, columns) == []


@pytest.mark.paths
def test_every_trial_recomputed_still_equals_one_at_a_time(monkeypatch) -> None:
    """With no rounding tolerated every trial takes the one-trial path, draws included."""
    monkeypatch.setattr(gtrs_batch, "POSITION_RTOL", 0.0)
    batch = family_batch("paper-1m-turn", 60, seed=7)
    columns = Cls(frames="last").estimate_columns(batch, rngs=generators(60))
    assert columns.recomputed.all()
    assert differences(Cls(frames="last"), batch, columns) == []


def test_a_trial_whose_one_trial_solve_raises_is_a_failed_row(monkeypatch) -> None:
    """A trial left to the one-trial path that raises becomes data: success false, NaN
    position, no candidates, no diagnostics, the exception in the message."""
    monkeypatch.setattr(gtrs_batch, "POSITION_RTOL", 0.0)
    batch = family_batch("paper-1m", 6, seed=8)

    def solve_one(data, rng):
        if data.doppler_hz[0] == batch.doppler_hz[2, 0]:
            raise ArithmeticError("overflow in trial 2")
        return _estimate("cls", "weighted", "all", data, rng, None)

    columns = estimate_columns("cls", "weighted", "all", batch, None, None, solve_one)
    failed = columns.estimate(2)
    assert not failed.success and not failed.ambiguous
    assert failed.message == "ArithmeticError: overflow in trial 2"
    assert np.isnan(failed.position_m).all() and failed.candidates_m.shape == (0, 2)
    assert failed.diagnostics == {}
    assert columns.success.tolist() == [True, True, False, True, True, True]
    assert columns.estimate(3).message == "hard case: mirror pair (MATH §5)"


def test_a_geometry_the_one_trial_path_refuses_is_refused_for_the_batch() -> None:
    """The geometry is shared: a sample without horizontal motion fails every trial alike, with
    the one-trial path's ValueError (a batch holds finite data only, MeasurementBatch checks)."""
    scenario = get_scenario("turn").replace(
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=[[0.0, 0.0, 2.0], [10.0, 0.0, 0.0]],
            samples_per_frame=10,
            sample_interval_s=0.05,
        )
    )
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(9, 3))
    with pytest.raises(ValueError) as single:
        Cls().estimate_one_trial(batch.trial(0))
    with pytest.raises(ValueError) as batched:
        Cls().estimate_batch(batch)
    assert str(batched.value) == str(single.value)
    with pytest.raises(ValueError, match=r"^toa_s: "):
        Cls().estimate_batch(replace(batch, toa_s=None))
    with pytest.raises(TypeError, match=r"^batch: expected a scenarios.types.MeasurementBatch"):
        Cls().estimate_batch(batch.trial(0))
    with pytest.raises(ValueError, match=r"^rngs: expected one generator per trial \(3\), got 2"):
        Cls().estimate_batch(batch, rngs=generators(2))
    with pytest.raises(TypeError, match=r"^rng: expected a numpy.random.Generator"):
        Cls().estimate_batch(batch, rngs=[np.random.default_rng(0), 1, None])


# --------------------------------------------------------------------------------------------
# the protocol and the columnar type
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(), ClsAsPrinted()], ids=repr)
def test_the_batch_capability_is_declared(estimator) -> None:
    assert capabilities_of(estimator).batch
    assert protocol_problems(estimator) == []


def test_columns_hold_arrays_and_build_estimates_on_demand() -> None:
    batch = family_batch("paper-1m-turn", 40, seed=10)
    columns = ClsPaper(frames="all").estimate_columns(batch, rngs=generators(40))
    assert columns.position_m.shape == (40, 2)
    assert columns.candidates_m.shape[0] == 40 and columns.candidates_m.shape[2] == 2
    assert list(columns.diagnostics) == [
        "multiplier",
        "hard_case",
        "rank",
        "stages",
        "n_samples",
        "straight_track",
        "fit_chi2",
        "fit_dof",
    ]
    assert (columns.diagnostics["rank"] == 3).all()
    assert (columns.diagnostics["n_samples"] == 100).all()
    assert (columns.n_candidates == 1).all() and not columns.ambiguous.any()
    assert np.isnan(columns.candidates_m[:, 1:]).all()
    assert columns.messages[columns.message_code[0]] == ""
    estimate = columns.estimate(0)
    assert estimate.candidates_m.shape == (1, 2)
    assert isinstance(estimate.diagnostics["rank"], int)
    assert isinstance(estimate.diagnostics["multiplier"], float)
    assert isinstance(estimate.diagnostics["hard_case"], bool)


def test_with_trials_replaces_rows_and_checks_keys() -> None:
    batch = family_batch("paper-1m", 5, seed=11)
    columns = Cls().estimate_columns(batch)
    failed = Estimate.failed("cls", "refused")
    replaced = columns.with_trials([1], [failed])
    assert replaced.recomputed.tolist() == [False, True, False, False, False]
    assert replaced.estimate(1).message == "refused"
    assert replaced.messages[-1] == "refused" and not replaced.success[1]
    assert replaced.estimate(0).message == columns.estimate(0).message
    other = replace(columns.estimate(2), diagnostics={"iterations": 3})
    with pytest.raises(ValueError, match=r"^diagnostics: trial 2 has keys \['iterations'\]"):
        columns.with_trials([2], [other])
    with pytest.raises(ValueError, match=r"^ambiguous: expected shape \(5,\), got \(4,\)"):
        replace(columns, ambiguous=np.zeros(4, dtype=bool))


@pytest.mark.bits("a round trip through columns: the same numbers stored and read back")
def test_columns_from_per_trial_estimates_round_trip() -> None:
    batch = family_batch("paper-1m", 8, seed=12)
    estimates = Cls().estimate_batch(batch, rngs=generators(8))
    estimates[3] = Estimate.failed("cls", "refused")
    columns = BatchEstimates.from_estimates("cls", estimates)
    assert not columns.recomputed.any()
    assert columns.success.tolist() == [True] * 3 + [False] + [True] * 4
    assert columns.diagnostics["rank"].dtype == np.int64
    for i, estimate in enumerate(estimates):
        again = columns.estimate(i)
        assert again.message == estimate.message and again.diagnostics == estimate.diagnostics
        np.testing.assert_array_equal(again.candidates_m, estimate.candidates_m)
        np.testing.assert_array_equal(again.position_m, estimate.position_m)
    assert not columns.position_m.flags.writeable
