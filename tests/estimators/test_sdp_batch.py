"""The batch path of ``sdp-cls`` (``estimate_batch``, ``estimate_columns``) against the
one-at-a-time path, trial by trial, with each trial's own generator.

``estimate`` is the batch computation on a batch of one trial, and every per-trial number of
it depends on that trial alone (MATH §11 module notes in :mod:`estimators.sdp.sdp_cls`); a batch of
one and a batch of many are still other arrays, so they agree by the rule of
:mod:`tests.paths` (to rounding, at a tolerance from the problem's conditioning): the same
statuses, rungs, messages and tie-break draws, the candidates and positions as positions, and
every diagnostic but the solver's timings to rounding (its floats in the whitened units of
:func:`estimators.sdp.sdp_lift.whiten_batch`, where the problem's scale is one). The families cover
one straight frame (every trial the hard case: a rank-two lift, a mirror pair and a draw), a turn,
the paper's 300 km ToA noise and the turn scenario.

Against the rows of the previous one-at-a-time path (:func:`estimators.closed_form.cls.cls_rows`,
which differ from :mod:`estimators.closed_form.cls_batch`'s in the last bits) the solves differ at
the solver's tolerance; that bound is checked too.
"""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np
import pytest

import estimators.sdp.sdp_cls as sdp_cls
import estimators.sdp.sdp_lift as sdp_lift
import estimators.sdp.sdp_solvers as sdp_solvers
from estimators.base import Estimate, capabilities_of, protocol_problems
from estimators.closed_form.cls import cls_rows
from estimators.closed_form.cls_rows import LocalFrame
from estimators.sdp.sdp_cls import SdpCls, solve_sdp_relaxation
from scenarios.catalog import get_scenario
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import MeasurementBatch
from tests.estimators.batch_support import generators, path_problems

FAMILIES = {"paper-1m": 10.0, "paper-1m-turn": 10.0, "paper": 0.0, "turn": 10.0}
"""Scenario and SNR (dB) of each family; ``paper`` is the paper's 300 km ToA noise."""

TIMINGS = frozenset({"solve_time_s", "rungs_solve_time_s", "estimate_solve_time_s"})
ORIGINAL_RUN = sdp_solvers.run_clarabel


def family_batch(name: str, n: int, seed: int = 0) -> MeasurementBatch:
    return simulate_trials(get_scenario(name), snr_db=FAMILIES[name], seeds=trial_seeds(seed, n))


def differences(estimator, trial, single: Estimate, got: Estimate) -> list[str]:
    """Every way two paths' estimates differ beyond rounding, the solver's timings aside
    (empty: they agree); a float diagnostic at the scale ``max(1, |value|)``."""
    scales = {
        key: (max(1.0, abs(value)), 1.0)
        for key, value in single.diagnostics.items()
        if isinstance(value, float)
    }
    return path_problems(estimator, trial, single, got, scales=scales, ignore=TIMINGS)


def compare_with_single(estimator: SdpCls, batch: MeasurementBatch, seed: int = 100):
    """The batch's estimates and columns, checked trial by trial against ``estimate``."""
    n = batch.n_trials
    estimates = estimator.estimate_batch(batch, rngs=generators(n, seed))
    columns = estimator.estimate_columns(batch, rngs=generators(n, seed))
    rngs = generators(n, seed)
    problems = []
    for i in range(n):
        single = estimator.estimate(batch.trial(i), rng=rngs[i])
        from_columns = columns.estimate(i)
        if not single.success:  # columns keep a failure's message, not its diagnostics
            from_columns = replace(from_columns, diagnostics=single.diagnostics)
        for what, got in (("estimate_batch", estimates[i]), ("estimate_columns", from_columns)):
            found = differences(estimator, batch.trial(i), single, got)
            if found:
                problems.append(f"trial {i}, {what}: {'; '.join(found)}")
    assert not problems, "\n".join(problems[:10])
    return estimates, columns


# --------------------------------------------------------------------------------------------
# batch = one at a time
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_batch_equals_one_at_a_time(family):
    """500 trials: same statuses, rungs, candidates, positions, draws and diagnostics."""
    batch = family_batch(family, 500)
    estimates, columns = compare_with_single(SdpCls(), batch)
    assert columns.success.all()
    statuses = [e.diagnostics["stage_statuses"] for e in estimates]
    assert statuses == [["optimal", "optimal"]] * 500
    rank = columns.diagnostics["rank"]
    if family in ("paper-1m", "paper"):  # one straight frame: always the hard case
        assert (rank == 2).all() and columns.ambiguous.all()
        assert (columns.n_candidates == 2).all()
    else:
        assert (rank == 1).all() and not columns.ambiguous.any()
        assert (columns.n_candidates == 1).all()
    solved = columns.diagnostics["estimate_solve_time_s"]
    assert (solved > 0.0).all()


@pytest.mark.paths
@pytest.mark.parametrize(
    "estimator",
    [
        SdpCls(weighting="none"),
        SdpCls(frames="last"),
        SdpCls(relaxation="inequality"),
        SdpCls(side_prior_m=(35.0, 15.0)),
        SdpCls(accept_inaccurate=True, max_iter=12),
    ],
    ids=repr,
)
@pytest.mark.parametrize("family", ["paper-1m", "turn"])
def test_options_equal_one_at_a_time(estimator, family):
    compare_with_single(estimator, family_batch(family, 150, seed=3))


@pytest.mark.paths
def test_scs_batch_equals_one_at_a_time():
    estimates, _ = compare_with_single(SdpCls(solver="SCS"), family_batch("turn", 6, seed=4))
    assert all(e.success for e in estimates)


@pytest.mark.paths
def test_a_trial_does_not_depend_on_its_batch(monkeypatch):
    """Chunks of 256 trials (the last one of one trial), sub-batches and single trials all
    give the whole batch's columns (other arrays: to rounding)."""
    batch = family_batch("paper-1m-turn", 513, seed=5)
    whole = SdpCls().estimate_columns(batch, rngs=generators(513))
    monkeypatch.setattr(sdp_cls, "MAX_CHUNK", 256)
    chunked = SdpCls().estimate_columns(batch, rngs=generators(513))
    monkeypatch.undo()
    for index in (np.arange(513), np.arange(40, 297), np.array([512]), np.array([7, 3])):
        part = MeasurementBatch(
            geometry=batch.geometry,
            doppler_hz=batch.doppler_hz[index],
            toa_s=batch.toa_s[index],
            rss_dbm=None,
        )
        rngs = [np.random.default_rng(100 + i) for i in index]
        columns = SdpCls().estimate_columns(part, rngs=rngs)
        for reference in (whole, chunked):
            for i, trial in enumerate(index.tolist()):
                a, b = reference.estimate(trial), columns.estimate(i)
                assert differences(SdpCls(), batch.trial(trial), a, b) == [], trial


@pytest.mark.paths
def test_generators_shared_draw_in_trial_order():
    """One generator for every trial draws in trial order, as one at a time."""
    batch = family_batch("paper-1m", 60, seed=6)
    estimator = SdpCls()
    shared = np.random.default_rng(9)
    columns = estimator.estimate_columns(batch, rngs=[shared] * 60)
    again = np.random.default_rng(9)
    singles = [estimator.estimate(batch.trial(i), rng=again) for i in range(60)]
    for i, single in enumerate(singles):
        assert differences(estimator, batch.trial(i), single, columns.estimate(i)) == [], i
    assert shared.integers(1 << 30) == again.integers(1 << 30)  # the same number of draws
    sides = np.sign(columns.position_m[:, 1])
    assert 10 < np.count_nonzero(sides > 0) < 50  # a fair coin between the mirror points


def test_without_a_generator_the_first_kept_candidate_is_returned():
    plain = SdpCls().estimate_columns(family_batch("paper-1m", 60, seed=6))
    np.testing.assert_array_equal(plain.position_m, plain.candidates_m[:, 0])
    assert plain.ambiguous.all()


def test_batch_is_declared_and_checked():
    estimator = SdpCls()
    assert capabilities_of(estimator).batch and protocol_problems(estimator) == []
    batch = family_batch("turn", 3)
    with pytest.raises(TypeError, match=r"^batch: "):
        estimator.estimate_columns(batch.trial(0))
    with pytest.raises(ValueError, match=r"^rngs: "):
        estimator.estimate_batch(batch, rngs=generators(2))
    with pytest.raises(ValueError, match=r"^toa_s: "):
        estimator.estimate_batch(replace(batch, toa_s=None))


# --------------------------------------------------------------------------------------------
# statuses, retries and failures, trial by trial
# --------------------------------------------------------------------------------------------


def forced_by_data(program, q, constraint_row, settings):
    """Clarabel with statuses forced by the solver inputs (identical in both paths): from the
    CRC of ``q``, a sixth of the solves end ``AlmostSolved`` at the tight rung, a tenth raise
    or end ``NumericalError`` on every rung, one in fourteen ``MaxIterations``, one in twenty
    returns a NaN primal with ``Solved``."""
    key = zlib.crc32(q.tobytes())
    tight = settings.tol_gap_abs == sdp_solvers.CLARABEL_TOLERANCES[0][0]
    if key % 20 == 1:
        raise RuntimeError("numerical trouble")
    solution = ORIGINAL_RUN(program, q, constraint_row, settings)
    fields = {n: getattr(solution, n) for n in ("status", "x", "z", "iterations", "solve_time")}
    if key % 20 == 2:
        fields["status"] = "NumericalError"
    elif key % 14 == 3:
        fields["status"] = "MaxIterations"
    elif key % 20 == 4:
        fields["x"] = [np.nan] * len(solution.x)
    elif key % 6 == 5 and tight:
        fields["status"] = "AlmostSolved"
    return type("Forced", (), fields)()


@pytest.mark.paths
def test_statuses_and_retries_are_per_trial(monkeypatch):
    """Each trial climbs its own rungs and fails on its own, as one at a time."""
    monkeypatch.setattr(sdp_solvers, "run_clarabel", forced_by_data)
    batch = family_batch("turn", 400, seed=7)
    estimates, columns = compare_with_single(SdpCls(), batch)
    failed = [e for e in estimates if not e.success]
    stages = [e.diagnostics.get("stage") for e in failed]
    statuses = {e.diagnostics["status"] for e in failed}
    assert statuses == {"solver_error", "user_limit", "non_finite"}
    assert stages.count(1) > 20 and stages.count(2) > 10
    assert columns.success.sum() == 400 - len(failed) > 200
    # a retried trial records rung 2 and both solver times; its neighbours rung 1
    rungs = columns.diagnostics["tolerance_rung"][columns.success]
    assert 20 < np.count_nonzero(rungs == 2) < np.count_nonzero(rungs == 1)
    for estimate in failed:
        diagnostics = estimate.diagnostics
        assert np.isnan(estimate.position_m).all() and len(estimate.candidates_m) == 0
        assert diagnostics["stage_statuses"][-1] == diagnostics["status"]
        assert len(diagnostics["stage_statuses"]) == diagnostics["stage"]
        expected_rung = 1 if diagnostics["status"] == "user_limit" else 2
        if diagnostics["status"] != "non_finite":
            assert diagnostics["tolerance_rung"] == expected_rung
        assert estimate.message.startswith(f"stage {diagnostics['stage']}: solver CLARABEL")
    codes = columns.message_code[~columns.success]
    assert [columns.messages[c] for c in codes] == [e.message for e in failed]


@pytest.mark.paths
def test_accepted_inaccurate_solves_are_flagged_per_trial(monkeypatch):
    def inaccurate(program, q, constraint_row, settings):
        solution = ORIGINAL_RUN(program, q, constraint_row, settings)
        if zlib.crc32(q.tobytes()) % 3 == 0:
            return replace_status(solution, "AlmostSolved")
        return solution

    monkeypatch.setattr(sdp_solvers, "run_clarabel", inaccurate)
    estimates, columns = compare_with_single(
        SdpCls(accept_inaccurate=True), family_batch("paper-1m", 120, seed=8)
    )
    flagged = ["optimal_inaccurate" in e.message for e in estimates]
    last = [e.diagnostics["status"] == "optimal_inaccurate" for e in estimates]
    assert flagged == last and 10 < sum(flagged) < 110
    assert all("mirror pair recovered" in e.message for e in estimates)
    assert columns.success.all()


def replace_status(solution, status):
    fields = {n: getattr(solution, n) for n in ("x", "z", "iterations", "solve_time")}
    return type("Forced", (), fields | {"status": status})()


@pytest.mark.paths
def test_rows_that_are_not_finite_fail_their_trial_only(monkeypatch):
    """NaN rows at stage 1 for some trials and at stage 2 for others: each is a failed
    estimate naming its stage; the other trials are unchanged."""
    batch = family_batch("paper-1m-turn", 300, seed=9)
    clean = SdpCls().estimate_columns(batch, rngs=generators(300))
    original = sdp_lift.ChunkRows.systems
    first = batch.geometry.speed_of_light_mps * batch.toa_s[:, 0]  # as the rows compute it
    low, high = np.quantile(first, [0.2, 0.85])

    def broken(self, rows, weights_at):
        systems = original(self, rows, weights_at)
        key = self.rows_of.r[0, : self.m]
        bad = key < low if weights_at is None else key > high
        systems[bad, 0, 3] = np.nan
        return systems

    monkeypatch.setattr(sdp_lift.ChunkRows, "systems", broken)
    estimates, columns = compare_with_single(SdpCls(), batch)
    stage = np.where(first < low, 1, np.where(first > high, 2, 0))
    for i, estimate in enumerate(estimates):
        if stage[i]:
            assert not estimate.success and estimate.diagnostics == {"stage": int(stage[i])}
            assert estimate.message.startswith(f"rows: the stage-{stage[i]} CLS system")
            assert np.isnan(columns.position_m[i]).all() and columns.n_candidates[i] == 0
        else:
            assert estimate.success
    assert 50 < np.count_nonzero(stage == 1) and 30 < np.count_nonzero(stage == 2)
    kept = stage == 0
    for i in np.flatnonzero(kept).tolist():  # a batch with other trials failing: other arrays
        a, b = clean.estimate(i), columns.estimate(i)
        assert differences(SdpCls(), batch.trial(i), a, b) == [], i
    assert columns.success.tolist() == kept.tolist()


def test_every_trial_failing_gives_failures_not_an_exception(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("numerical trouble")

    monkeypatch.setattr(sdp_solvers, "run_clarabel", broken)
    batch = family_batch("turn", 5)
    estimates = SdpCls().estimate_batch(batch)
    columns = SdpCls().estimate_columns(batch)
    assert not columns.success.any() and columns.diagnostics == {}
    assert all(e.diagnostics["status"] == "solver_error" for e in estimates)
    assert all("numerical trouble" in columns.message(i) for i in range(5))


# --------------------------------------------------------------------------------------------
# against the rows of the previous path: equal at the solver's tolerance
# --------------------------------------------------------------------------------------------

POINT_RTOL = 1e-8
"""Candidates from the two row codes agree within this times the frame's length scale.

The rows differ in the last bits only; each solve stops at a relative gap of 1e−10 on a
whitened problem whose curvature is of order one (:func:`estimators.sdp.sdp_lift.whiten_batch`),
so a point can move by about √1e−10 = 1e−5 of a whitened unit before the gap notices, and by
much less in practice (Clarabel's iterates converge linearly near the solution). Measured
over 2000 trials per family: at most 7e−10 (``paper``, the flattest), 7e−12 (``turn``),
1e−14 (``paper-1m``, ``paper-1m-turn``)."""


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_equal_to_the_scalar_rows_at_the_solver_tolerance(family):
    batch = family_batch(family, 300, seed=11)
    columns = SdpCls().estimate_columns(batch)
    line = straight_track_line(batch.geometry.position_m, batch.geometry.velocity_mps)
    worst = 0.0
    for i in range(batch.n_trials):
        data = batch.trial(i)
        frame = LocalFrame.fit(data.position_m, data.range_m)
        points = None
        for _ in range(2):
            weights_at = None if points is None else points[0, :2]
            A, b = cls_rows(data, frame, "weighted", weights_at_local_xy=weights_at)
            solution = solve_sdp_relaxation(A, b)
            points = solution.points
        reference = frame.to_world(points[:, :2])
        if line is not None:
            reference = np.vstack([reference, mirror_across_line(reference, *line)])
        estimate = columns.estimate(i)
        assert estimate.diagnostics["status"] == solution.status == "optimal"
        assert estimate.diagnostics["rank"] == solution.rank
        distance = max(np.min(np.linalg.norm(reference - c, axis=1)) for c in estimate.candidates_m)
        worst = max(worst, distance / frame.scale_m)
    assert worst <= POINT_RTOL
