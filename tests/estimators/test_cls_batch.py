"""The closed-form CLS is one implementation, vectorised over trials: ``estimate`` is the batch
of one, ``estimate_batch`` and ``estimate_columns`` the batch of many.

Where the same code runs on the same arrays the answers are asserted to the bit: a trial's row
does not depend on the batch it is solved in (worker counts, chunking, resume), ``estimate`` is
its row, and each trial's generator is drawn exactly once on a tie without a prior. Against
independent references: the global minimum of the system each trial solves (brute force, at
``COST_RTOL``). The families cover one straight frame (every trial the hard case, a mirror pair
and a tie-break draw), turns, the paper's 300 km ToA noise, an emitter a centimetre from the
track's plane (hard case and unique root side by side) and two headings a millidegree apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

import estimators.closed_form.gtrs_batch as gtrs_batch
from estimators.base import Estimate, capabilities_of, protocol_problems
from estimators.batch import BatchEstimates
from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper
from estimators.closed_form.cls_batch import FAILED_MESSAGE
from estimators.closed_form.gtrs import constrained_cost
from estimators.closed_form.gtrs_rank import row_dot
from scenarios.catalog import get_scenario, heading_velocities_mps
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import FlightPlan, MeasurementBatch, Scenario
from tests.estimators import batch_support
from tests.estimators.batch_support import generators, rotated, sub_batch
from tests.estimators.test_gtrs import COST_RTOL, brute_force_minimum


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


def assert_same_estimate(a: Estimate, b: Estimate) -> None:
    """The same answer to the bit: position, candidates, flags, message and diagnostics."""
    np.testing.assert_array_equal(a.position_m, b.position_m)
    np.testing.assert_array_equal(a.candidates_m, b.candidates_m)
    assert (a.estimator, a.success, a.ambiguous, a.message) == (
        b.estimator,
        b.success,
        b.ambiguous,
        b.message,
    )
    np.testing.assert_equal(a.diagnostics, b.diagnostics)


# --------------------------------------------------------------------------------------------
# the batch's answers against the exact optimum of the system it solves
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("family", sorted(FAMILIES))
@pytest.mark.parametrize(
    "estimator", [Cls(), ClsPaper(), ClsPaper(frames="all"), ClsAsPrinted()], ids=repr
)
def test_candidates_attain_the_brute_force_minimum_of_their_system(family, estimator) -> None:
    """Five trials of each family: every candidate's cost on the last stage's system
    (``constrained_ls``) is its brute-force global minimum to ``COST_RTOL``, and the families
    hold the cases the batch must handle itself."""
    batch = family_batch(family, 200)
    columns = estimator.estimate_columns(batch, rngs=generators(200))
    assert columns.success.all()
    for i in range(5):
        system = estimator.constrained_ls(batch.trial(i))
        count = int(columns.n_candidates[i])
        local = (columns.candidates_m[i, :count] - system.origin_m) / system.scale_m
        costs = constrained_cost(system.A, system.b, local)
        best, _ = brute_force_minimum(system.A, system.b)
        floor = 1e-18 * (1.0 + system.b @ system.b)
        assert np.all(costs <= best + COST_RTOL * abs(best) + floor), (i, costs, best)
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


# --------------------------------------------------------------------------------------------
# one implementation: the same bits however the trials are batched or called
# --------------------------------------------------------------------------------------------


@pytest.mark.bits("chunks of one batch run the same code on the same arrays")
@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(), Cls(weighting="none")], ids=repr)
@pytest.mark.parametrize("family", ["paper-1m", "turn-rotated", "near-plane"])
def test_a_trials_result_does_not_depend_on_its_batch(family, estimator) -> None:
    """Batches of 1, 2, 3 and 7 trials give every trial what the batch of 40 gives it, to the
    bit, draws included: a run's rows do not depend on how it is chunked."""
    batch = family_batch(family, 40, seed=13)
    whole = estimator.estimate_columns(batch, rngs=generators(40))
    for size in (1, 2, 3, 7):
        for start in range(0, 40, size):
            part = slice(start, min(start + size, 40))
            columns = estimator.estimate_columns(sub_batch(batch, part), rngs=generators(40)[part])
            for i, trial in enumerate(range(40)[part]):
                assert_same_estimate(whole.estimate(trial), columns.estimate(i))


@pytest.mark.bits("estimate is the batch of one: the same code on the same arrays")
@pytest.mark.parametrize(
    "estimator",
    [
        Cls(),
        ClsPaper(),
        ClsAsPrinted(),
        Cls(weighting="none"),
        Cls(frames="last"),
        Cls(side_prior_m=(30.0, -10.0)),
        ClsPaper(frames="all", side_prior_m=(-20.0, 15.0)),
    ],
    ids=repr,
)
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_estimate_is_the_batchs_row(family, estimator) -> None:
    """``estimate`` of a trial is its row of a batch of 60, to the bit, and leaves its
    generator in the state the batch leaves it in."""
    batch = family_batch(family, 60, seed=14)
    drawn = generators(60)
    columns = estimator.estimate_columns(batch, rngs=drawn)
    rngs = generators(60)
    for i in range(60):
        assert_same_estimate(estimator.estimate(batch.trial(i), rng=rngs[i]), columns.estimate(i))
    assert [r.bit_generator.state for r in rngs] == [r.bit_generator.state for r in drawn]


def test_single_columns_are_summed_in_the_order_of_many() -> None:
    """:func:`~estimators.closed_form.gtrs_rank.row_dot` sums one system by ``cumsum`` and many
    by an outer-axis reduction: both add row after row, so a system's sums do not depend on how
    many share its batch."""
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


@pytest.mark.bits("estimate_batch is estimate_columns(...).to_estimates(): the same arrays")
def test_estimate_batch_is_the_columns_as_estimates() -> None:
    batch = family_batch("paper-1m-turn", 50)
    estimator = Cls()
    listed = estimator.estimate_batch(batch, rngs=generators(50))
    columns = estimator.estimate_columns(batch, rngs=generators(50))
    assert len(listed) == 50
    for i, estimate in enumerate(listed):
        assert isinstance(estimate, Estimate)
        assert_same_estimate(estimate, columns.estimate(i))


# --------------------------------------------------------------------------------------------
# tie-breaking: one draw from the trial's own generator, only on a tie without a prior
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(), Cls(side_prior_m=(35.0, 20.0))], ids=repr)
def test_each_generator_is_drawn_once_on_a_tie_and_only_then(estimator) -> None:
    """A generator is drawn once on an ambiguous trial without a prior, untouched otherwise."""
    batch = family_batch("near-plane", 300, seed=3)
    batch_rngs = generators(300)
    columns = estimator.estimate_columns(batch, rngs=batch_rngs)
    untouched = generators(300)
    once = generators(300)
    for rng in once:
        rng.integers(2)
    drawn = np.array(
        [
            a.bit_generator.state != b.bit_generator.state
            for a, b in zip(batch_rngs, untouched, strict=True)
        ]
    )
    for a, b, was_drawn in zip(batch_rngs, once, drawn, strict=True):
        if was_drawn:
            assert a.bit_generator.state == b.bit_generator.state
    if estimator.side_prior_m is None:
        assert 50 < drawn.sum() < 300  # hard-case pairs draw, unique roots on the plane do not
        np.testing.assert_array_equal(drawn, columns.n_candidates > 1)
    else:
        assert drawn.sum() == 0


@pytest.mark.bits("one shared generator: the batch and the loop draw in trial order")
def test_one_generator_shared_by_every_trial_is_drawn_in_trial_order() -> None:
    batch = family_batch("paper-1m", 200, seed=4)
    shared_batch, shared_single = np.random.default_rng(7), np.random.default_rng(7)
    columns = Cls().estimate_columns(batch, rngs=[shared_batch] * 200)
    for i in range(200):
        assert_same_estimate(Cls().estimate(batch.trial(i), rng=shared_single), columns.estimate(i))
    sides = np.sign(columns.position_m[:, 1])
    assert 0.3 < np.mean(sides > 0) < 0.7  # a fair coin over the mirror pair


def test_without_generators_the_first_candidate_is_returned() -> None:
    columns = ClsPaper().estimate_columns(family_batch("paper-1m", 100, seed=5))
    np.testing.assert_array_equal(columns.position_m, columns.candidates_m[:, 0])
    # left of the eastbound heading first: the candidate north of the track
    assert (columns.candidates_m[:, 0, 1] > 0).all()
    assert (columns.candidates_m[:, 1, 1] < 0).all()


# --------------------------------------------------------------------------------------------
# decisions at the edge of rounding, and failures
# --------------------------------------------------------------------------------------------


def test_the_emitter_in_the_tracks_plane_is_decided_by_the_batch() -> None:
    """The emitter exactly in the track's plane at 200 dB: φ(−μ₁) is rounding, so whether the
    pair exists is rounding's choice; either way the answer is the emitter to rounding, and
    every trial succeeds."""
    scenario = get_scenario("paper-1m").replace(emitter_m=[35.0, 0.0])
    batch = simulate_trials(scenario, snr_db=200.0, seeds=trial_seeds(6, 100))
    for estimator in (Cls(), ClsPaper()):
        columns = estimator.estimate_columns(batch, rngs=generators(100))
        assert columns.success.all()
        np.testing.assert_allclose(columns.position_m, [[35.0, 0.0]] * 100, atol=1e-4)


@pytest.mark.bits("a failed trial beside solved ones: the same code on the same arrays")
def test_a_trial_without_a_finite_minimiser_is_a_failed_row(monkeypatch) -> None:
    """A secular equation whose iteration fails (no Newton step allowed) fails its row only:
    success false, NaN position, no candidates, the reason in the message; the hard-case rows
    beside it (no secular equation) are what they are without it."""
    batch = family_batch("near-plane", 40, seed=8)
    whole = ClsPaper().estimate_columns(batch)
    monkeypatch.setattr(gtrs_batch, "NEWTON_ITERATIONS", 0)
    columns = ClsPaper().estimate_columns(batch)
    hard = whole.diagnostics["hard_case"]
    assert 0 < hard.sum() < 40
    np.testing.assert_array_equal(columns.success, hard)
    for i in range(40):
        if hard[i]:
            assert_same_estimate(whole.estimate(i), columns.estimate(i))
            continue
        failed = columns.estimate(i)
        assert not failed.success and not failed.ambiguous
        assert failed.message == FAILED_MESSAGE
        assert np.isnan(failed.position_m).all() and failed.candidates_m.shape == (0, 2)
        alone = ClsPaper().estimate(batch.trial(i))
        assert not alone.success and alone.message == FAILED_MESSAGE


def test_a_geometry_without_horizontal_motion_is_refused_alike() -> None:
    """The geometry is shared: a sample without horizontal motion fails every trial alike, with
    one ValueError naming the field (a batch holds finite data only, MeasurementBatch checks)."""
    scenario = get_scenario("turn").replace(
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=[[0.0, 0.0, 2.0], [10.0, 0.0, 0.0]],
            samples_per_frame=10,
            sample_interval_s=0.05,
        )
    )
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(9, 3))
    with pytest.raises(ValueError, match=r"^velocity_mps: sample 0 has zero horizontal speed"):
        Cls().estimate(batch.trial(0))
    with pytest.raises(ValueError, match=r"^velocity_mps: sample 0 has zero horizontal speed"):
        Cls().estimate_batch(batch)
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
    assert columns.success.tolist() == [True] * 3 + [False] + [True] * 4
    assert columns.diagnostics["rank"].dtype == np.int64
    for i, estimate in enumerate(estimates):
        again = columns.estimate(i)
        assert again.message == estimate.message and again.diagnostics == estimate.diagnostics
        np.testing.assert_array_equal(again.candidates_m, estimate.candidates_m)
        np.testing.assert_array_equal(again.position_m, estimate.position_m)
    assert not columns.position_m.flags.writeable
