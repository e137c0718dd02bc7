"""Tests of comparison.scoring: a trial's row does not depend on how many trials are scored
with it (a task at once, or one estimate, ``estimate_columns``, as a closed loop scores its
frames), in type, and to rounding by the rule of :mod:`tests.paths` (``np.matmul`` on stacks
of different sizes may take other BLAS kernels), the JSON texts exactly, on random estimates
and columns with every case the rows must get right; and hand-computed values."""

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from comparison.scoring import (
    Outcomes,
    estimate_columns,
    frame_track,
    jsonable,
    score_outcomes,
)
from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.base import Estimate
from estimators.batch import BatchEstimates
from estimators.registry import make_estimator
from estimators.validity import INVALID
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds
from tests import paths

COLUMN = {name: i for i, name in enumerate(ESTIMATE_COLUMNS)}
TRUTH = np.array([120.0, 850.0])


def bits(value):
    """A value as it is stored: its type, and a float by its bytes (NaN equal to NaN, -0.0
    not equal to 0.0)."""
    if type(value) is float:
        return float, np.float64(value).tobytes()
    return type(value), value


def assert_same_rows(rows, reference):
    assert len(rows) == len(reference)
    for i, (row, expected) in enumerate(zip(rows, reference, strict=True)):
        assert len(row) == len(ESTIMATE_COLUMNS)
        for name, got, want in zip(ESTIMATE_COLUMNS, row, expected, strict=True):
            assert bits(got) == bits(want), f"row {i}, {name}: {got!r} != {want!r}"


def assert_rows_agree(rows, reference):
    """The rows of two scoring paths (columns, one estimate at a time) agree by the rule of
    :mod:`tests.paths`: every float to rounding (the NEES at ``cond`` of its covariance), the
    rest, types included, equal."""
    assert len(rows) == len(reference)
    problems = []
    for i, (row, expected) in enumerate(zip(rows, reference, strict=True)):
        assert len(row) == len(ESTIMATE_COLUMNS)
        mine = dict(zip(ESTIMATE_COLUMNS, expected, strict=True))
        theirs = dict(zip(ESTIMATE_COLUMNS, row, strict=True))
        problems += [f"row {i}: {p}" for p in paths.row_problems(mine, theirs, 1.0)]
    assert not problems, "\n".join(problems[:10])


def reference_rows(estimates, runtimes, truth, track):
    with np.errstate(over="ignore"):  # hypot of the largest floats
        return [
            estimate_columns(estimate, truth, track, runtime)
            for estimate, runtime in zip(estimates, runtimes, strict=True)
        ]


# --------------------------------------------------------------------------------------------
# random estimates with every case: failures, NaN, mirror pairs, on the plane, covariances
# --------------------------------------------------------------------------------------------


def mirror(points, track):
    """Points reflected across the track's vertical plane."""
    (origin, direction) = (np.asarray(v, dtype=float) for v in track)
    offset = np.asarray(points, dtype=float) - origin
    along = offset @ direction
    return origin + 2.0 * along[..., None] * direction - offset


def random_covariance(rng):
    kind = rng.integers(6)
    if kind == 0:
        return None
    if kind == 1:  # singular
        v = rng.normal(size=2)
        return np.outer(v, v)
    if kind == 2:  # not finite
        return np.array([[np.nan, 0.0], [0.0, 4.0]])
    if kind == 3:  # negative determinant
        return np.array([[1.0, 3.0], [3.0, 1.0]])
    a = rng.normal(size=(2, 2)) * rng.lognormal(0.0, 3.0)
    return a @ a.T + np.eye(2) * 1e-3


def random_diagnostics(rng):
    pool = {
        "multiplier": float(rng.normal() * 10.0 ** rng.integers(-12, 12)),
        "nan": math.nan,
        "inf": -math.inf,
        "zero": -0.0,
        "rank": int(rng.integers(0, 4)),
        "numpy_int": np.int64(rng.integers(-5, 5)),
        "numpy_float": np.float32(rng.normal()),
        "hard_case": bool(rng.integers(2)),
        "numpy_bool": np.bool_(rng.integers(2)),
        "note": "é → ☃",
        "nested": {"b": [1.5, math.nan, np.float64(2.0)], "a": (1, 2)},
        "array": rng.normal(size=3),
        "none": None,
        "object": object,
    }
    keys = rng.permutation(list(pool))[: rng.integers(0, len(pool) + 1)]
    return {str(key): pool[key] for key in keys}


def random_estimate(rng, track, truth):
    """An estimate of one of the cases a row must score right."""
    case = rng.integers(9)
    diagnostics = random_diagnostics(rng)
    covariance = random_covariance(rng)
    if case == 0:
        return Estimate.failed("x", "RuntimeError: broken", **diagnostics)
    if case == 1:  # a failure that still reports candidates and a covariance
        return Estimate(
            estimator="x",
            position_m=[1.0, 2.0],
            candidates_m=rng.normal(size=(2, 2)),
            ambiguous=True,
            covariance_m2=covariance,
            success=False,
            message="gave up",
            diagnostics=diagnostics,
        )
    if case == 2:  # a success with a NaN: Estimate makes it a failure
        return Estimate(
            estimator="x",
            position_m=[math.nan, 3.0],
            candidates_m=[[math.nan, 3.0]],
            ambiguous=True,
            covariance_m2=covariance,
            diagnostics=diagnostics,
        )
    point = truth + rng.normal(size=2) * rng.lognormal(0.0, 4.0)
    if case == 3 and track is not None:  # in the track's vertical plane: on neither side
        origin, direction = (np.asarray(v, dtype=float) for v in track)
        point = origin + direction * rng.normal() * 500.0
    if case == 4:  # exactly on the truth
        point = truth.copy()
    if case in (5, 6) and track is not None:  # a mirror pair, the returned one either side
        pair = np.array([point, mirror(point, track)])
        candidates = pair if case == 5 else pair[::-1]
        return Estimate(
            estimator="x",
            position_m=candidates[0],
            candidates_m=candidates,
            ambiguous=True,
            covariance_m2=covariance,
            message="hard case: mirror pair (MATH §5)",
            diagnostics=diagnostics,
        )
    if case == 7:  # several candidates, none of them the position's copy
        candidates = point + rng.normal(size=(int(rng.integers(1, 5)), 2)) * 50.0
        return Estimate(
            estimator="x",
            position_m=candidates[0],
            candidates_m=candidates,
            ambiguous=len(candidates) > 1,
            covariance_m2=covariance,
            diagnostics=diagnostics,
        )
    if case == 8:  # no candidates at all: the position is the pool
        return Estimate(
            estimator="x",
            position_m=point,
            candidates_m=np.empty((0, 2)),
            ambiguous=False,
            covariance_m2=covariance,
            diagnostics=diagnostics,
        )
    return Estimate(
        estimator="x",
        position_m=point,
        candidates_m=[point],
        ambiguous=False,
        covariance_m2=covariance,
        diagnostics=diagnostics,
    )


TRACKS = {
    "east along y = 0": (np.array([0.0, 0.0]), np.array([1.0, 0.0])),
    "oblique, as tuples": ((-300.0, 40.0), (0.6, 0.8)),
    "through the truth": (TRUTH, np.array([np.sqrt(0.5), np.sqrt(0.5)])),
    "none (hovering)": None,
}


@pytest.mark.paths
@pytest.mark.parametrize("track_name", list(TRACKS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scoring_estimates_on_columns_equals_scoring_each(track_name, seed):
    track = TRACKS[track_name]
    rng = np.random.default_rng(seed)
    estimates = [random_estimate(rng, track, TRUTH) for _ in range(300)]
    runtimes = list(rng.uniform(0.0, 1e-2, size=len(estimates)))
    results = list(zip(estimates, runtimes, strict=True))
    rows = score_outcomes(Outcomes.of_estimates(results), TRUTH, track)
    assert_rows_agree(rows, reference_rows(estimates, runtimes, TRUTH, track))
    # every case is there
    column = {name: [row[COLUMN[name]] for row in rows] for name in ESTIMATE_COLUMNS}
    assert not all(column["success"]) and any(column["success"])
    assert any(np.isfinite(column["nees_side_resolved"]))
    if track is not None:  # (a truth in the plane is on neither side: never the wrong one)
        sides = {0.0} if track_name == "through the truth" else {0.0, 1.0}
        assert sides <= set(column["wrong_side"])
        assert any(
            s and math.isnan(w)
            for s, w in zip(column["success"], column["wrong_side"], strict=True)
        )


def test_of_estimates_keeps_what_the_diagnostics_hold():
    """Those of a failure, keys that differ between trials, nested values: as written by the
    one-estimate scoring (BatchEstimates.from_estimates would drop or refuse them)."""
    estimates = [
        Estimate.failed("x", "digest only", digest="ab12", truth=np.array([1.0, 2.0])),
        Estimate(estimator="x", position_m=[1.0, 2.0], candidates_m=[[1.0, 2.0]], ambiguous=False),
        Estimate(
            estimator="x",
            position_m=[1.0, 2.0],
            candidates_m=[[1.0, 2.0]],
            ambiguous=False,
            diagnostics={"z": {"b": 1, "a": [math.inf]}, "a": np.float64(0.1)},
        ),
    ]
    outcomes = Outcomes.of_estimates([(estimate, 0.0) for estimate in estimates])
    texts = [row[COLUMN["diagnostics_json"]] for row in score_outcomes(outcomes, TRUTH, None)]
    assert texts == [
        '{"digest": "ab12", "truth": [1.0, 2.0]}',
        "{}",
        '{"a": 0.1, "z": {"a": [null], "b": 1}}',
    ]


# --------------------------------------------------------------------------------------------
# columns as an estimator returns them
# --------------------------------------------------------------------------------------------


MIXED = ([1, 2.0], [True, 1], [1, True], [1.0, 2.0], "1", 1, True, 1.0, 0.0, -0.0, [0.0], [-0.0])
"""Values that compare equal but are written differently (``true`` and ``1``, ``1`` and
``1.0``, ``0.0`` and ``-0.0``): a diagnostics column of them must keep each one's own text."""


def object_column(values) -> np.ndarray:
    """An object array holding each of ``values`` as it is (lists kept whole)."""
    column = np.empty(len(values), dtype=object)
    column[:] = values
    return column


def random_columns(rng, n, track):
    """BatchEstimates with NaN padding, failures, successes with a non-finite value or an
    invalid covariance (which the columns, as Estimate, turn into failures), covariances, and
    diagnostics of every dtype."""
    k = 3
    count = rng.integers(0, k + 1, size=n)
    candidates = TRUTH + rng.normal(size=(n, k, 2)) * rng.lognormal(0.0, 3.0, size=(n, 1, 1))
    candidates[:, 1] = mirror(candidates[:, 0], track) if track is not None else candidates[:, 1]
    candidates[np.arange(k)[None, :] >= count[:, None]] = np.nan
    success = rng.random(n) < 0.8
    position = np.where(count[:, None] > 0, candidates[:, 0], TRUTH + rng.normal(size=(n, 2)))
    position[~success] = np.nan
    odd = success & (rng.random(n) < 0.05)
    position[odd, 0] = np.inf
    slot = count > 0
    candidates[slot & (rng.random(n) < 0.05), 0, 1] = np.nan  # a NaN candidate
    covariance = np.full((n, 2, 2), np.nan)  # NaN: the estimate has none
    for i in range(n):
        given = random_covariance(rng)
        if given is not None:
            covariance[i] = given
    vectors = rng.normal(size=(n, 4)) * 10.0 ** rng.integers(-300, 300, size=(n, 1))
    vectors.flat[rng.choice(4 * n, 12, replace=False)] = [np.nan, np.inf, -np.inf, -0.0] * 3
    floats = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)
    floats[rng.random(n) < 0.1] = np.nan
    floats[rng.random(n) < 0.1] = -np.inf
    floats[rng.random(n) < 0.1] = -0.0
    diagnostics = {
        "multiplier": floats,
        "single": rng.normal(size=n).astype(np.float32),
        "rank": rng.integers(-3, 3, size=n),
        "unsigned": rng.integers(0, 2**63, size=n, dtype=np.uint64) * np.uint64(2),
        "hard_case": rng.random(n) < 0.5,
        "note": np.array(["a", "é ☃", 'quo"te'] * n)[:n],
        "anything": np.array([None, 1.5, [1, np.nan], {"b": 1, "a": 2}] * n, dtype=object)[:n],
        "eigenvalues": object_column([list(row) for row in vectors]),  # written together
        "arrays": object_column(list(vectors[:, :2])),
        "statuses": object_column([["optimal", "user_limit"][: 1 + i % 2] for i in range(n)]),
        "mixed": object_column([MIXED[i % len(MIXED)] for i in range(n)]),
    }
    messages = ("", "hard case: mirror pair (MATH §5)", "RuntimeError: no")
    return BatchEstimates(
        estimator="cols",
        position_m=position,
        candidates_m=candidates,
        n_candidates=count,
        ambiguous=count > 1,
        success=success,
        message_code=rng.integers(0, len(messages), size=n),
        messages=messages,
        diagnostics=diagnostics,
        covariance_m2=covariance,
    )


@pytest.mark.paths
@pytest.mark.parametrize("track_name", list(TRACKS))
def test_scoring_columns_equals_scoring_their_estimates(track_name):
    track = TRACKS[track_name]
    rng = np.random.default_rng(11)
    columns = random_columns(rng, 400, track)
    rows = score_outcomes(Outcomes.of_columns(columns, 2.5e-6), TRUTH, track)
    estimates = columns.to_estimates()
    assert_rows_agree(rows, reference_rows(estimates, [2.5e-6] * len(columns), TRUTH, track))
    # the columns refused some successes as invalid (a non-finite value, a bad covariance)
    assert any(columns.message(i).startswith(INVALID) for i in range(len(columns)))


@pytest.mark.paths
def test_scoring_columns_without_covariance_or_diagnostics():
    columns = dataclass_replace_columns(random_columns(np.random.default_rng(3), 50, None))
    rows = score_outcomes(Outcomes.of_columns(columns, 0.0), TRUTH, TRACKS["east along y = 0"])
    reference = reference_rows(
        columns.to_estimates(), [0.0] * 50, TRUTH, TRACKS["east along y = 0"]
    )
    assert_rows_agree(rows, reference)
    assert {row[COLUMN["diagnostics_json"]] for row in rows} == {"{}"}
    assert all(math.isnan(row[COLUMN["nees"]]) for row in rows)


def dataclass_replace_columns(columns):
    return dataclasses.replace(columns, diagnostics={}, covariance_m2=None)


def test_no_trials_no_rows():
    empty = Outcomes.of_estimates([])
    assert score_outcomes(empty, TRUTH, None) == []


@pytest.mark.paths
@pytest.mark.parametrize("estimator", ["cls", "cls-paper"])
@pytest.mark.parametrize(("scenario", "snr_db"), [("paper-1m", 10.0), ("turn", -10.0)])
def test_scoring_a_real_batch_equals_scoring_its_estimates(estimator, scenario, snr_db):
    world = get_scenario(scenario)
    batch = simulate_trials(world, snr_db=snr_db, seeds=trial_seeds(5, 200))
    rngs = [np.random.default_rng(i) for i in range(200)]
    columns = make_estimator(estimator).estimate_columns(batch, rngs=rngs)
    track = frame_track(batch.geometry, 0)
    rows = score_outcomes(Outcomes.of_columns(columns, 1e-6), world.emitter_m, track)
    reference = reference_rows(columns.to_estimates(), [1e-6] * 200, world.emitter_m, track)
    assert_rows_agree(rows, reference)


# --------------------------------------------------------------------------------------------
# the JSON text
# --------------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    values=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=12),
    flags=st.lists(st.booleans(), min_size=1, max_size=12),
)
@pytest.mark.bits("the texts format the same floats (copied, not computed): no arithmetic differs")
def test_the_json_text_is_that_of_json_dumps(values, flags):
    """Any float, in the diagnostics of a success and the candidates of a failure (a success
    with a non-finite candidate is refused: a failure without candidates or diagnostics)."""
    n = min(len(values), len(flags))
    floats, flags = np.array(values[:n]), np.array(flags[:n])
    candidates = np.stack([floats, floats[::-1]], axis=-1)[:, None, :]
    refused = ~np.isfinite(candidates).all(axis=(1, 2))
    success = flags | refused
    columns = BatchEstimates(
        estimator="json",
        position_m=candidates[:, 0],
        candidates_m=candidates,
        n_candidates=np.ones(n, dtype=np.int64),
        ambiguous=np.zeros(n, dtype=bool),
        success=success,
        message_code=np.zeros(n, dtype=np.int64),
        messages=("",),
        diagnostics={
            "f": floats,
            "b": flags,
            "i": np.arange(n) - 2**40,
            "v": object_column([[x, -x] for x in floats.tolist()]),  # vectors of one length
            "m": object_column([MIXED[i % len(MIXED)] for i in range(n)]),
        },
    )
    rows = score_outcomes(Outcomes.of_columns(columns, 0.0), TRUTH, None)
    assert_same_rows(rows, reference_rows(columns.to_estimates(), [0.0] * n, TRUTH, None))
    for i, row in enumerate(rows):
        x = floats[i].item()
        m = MIXED[i % len(MIXED)]
        expected = {"f": x, "b": bool(flags[i]), "i": i - 2**40, "v": [x, -x], "m": m}
        if success[i] and not refused[i]:
            assert row[COLUMN["diagnostics_json"]] == json.dumps(jsonable(expected), sort_keys=True)
        else:
            assert row[COLUMN["diagnostics_json"]] == "{}"
            shown = [] if refused[i] else candidates[i].tolist()
            assert row[COLUMN["candidates_json"]] == json.dumps(jsonable(shown))
            assert row[COLUMN["message"]].startswith(INVALID) == bool(refused[i])


# --------------------------------------------------------------------------------------------
# hand-computed values of the one-estimate scoring
# --------------------------------------------------------------------------------------------


def test_hand_computed_mirror_pair_with_a_covariance():
    """Truth (0, 100) north of a track along y = 0; the returned (3, -96) is its wrong-side
    mirror, the candidate (3, 96) the right one: error hypot(3, 196), side-resolved 5, wrong
    side; NEES against P, side-resolved NEES against the reflected P."""
    truth = np.array([0.0, 100.0])
    track = (np.array([0.0, 0.0]), np.array([1.0, 0.0]))
    covariance = np.array([[4.0, 1.0], [1.0, 9.0]])
    estimate = Estimate(
        estimator="hand",
        position_m=[3.0, -96.0],
        candidates_m=[[3.0, -96.0], [3.0, 96.0]],
        ambiguous=True,
        covariance_m2=covariance,
        message="pair",
        diagnostics={"rank": 2},
    )
    expected = {
        "x_m": 3.0,
        "y_m": -96.0,
        "error_m": math.hypot(3.0, 196.0),
        "error_side_resolved_m": 5.0,
        "wrong_side": 1.0,
        "ambiguous": True,
        "success": True,
        "n_candidates": 2,
        "candidates_json": "[[3.0, -96.0], [3.0, 96.0]]",
        "cov_xx_m2": 4.0,
        "cov_xy_m2": 1.0,
        "cov_yy_m2": 9.0,
        # e = (3, -196), P⁻¹ = [[9, -1], [-1, 4]] / 35
        "nees": (9 * 9 + 2 * 3 * 196 + 4 * 196**2) / 35,
        # e = (3, -4), reflected P = [[4, -1], [-1, 9]], its inverse [[9, 1], [1, 4]] / 35
        "nees_side_resolved": (9 * 9 - 2 * 3 * 4 + 4 * 16) / 35,
        "runtime_s": 0.5,
        "message": "pair",
        "diagnostics_json": '{"rank": 2}',
    }
    for scored in (
        estimate_columns(estimate, truth, track, 0.5),
        score_outcomes(Outcomes.of_estimates([(estimate, 0.5)]), truth, track)[0],
    ):
        for name, value in expected.items():
            if isinstance(value, float):
                assert scored[COLUMN[name]] == pytest.approx(value, rel=1e-12), name
            else:
                assert scored[COLUMN[name]] == value, name


def test_hand_computed_plane_and_failure():
    truth = np.array([0.0, 100.0])
    track = (np.array([0.0, 0.0]), np.array([1.0, 0.0]))
    on_plane = Estimate(
        estimator="h", position_m=[5.0, 0.0], candidates_m=[[5.0, 0.0]], ambiguous=False
    )
    failed = Estimate.failed("h", "no")
    for estimates in ([on_plane, failed],):
        results = [(e, 0.0) for e in estimates]
        for rows in (
            [estimate_columns(e, truth, track, 0.0) for e in estimates],
            score_outcomes(Outcomes.of_estimates(results), truth, track),
        ):
            plane, fail = rows
            assert math.isnan(plane[COLUMN["wrong_side"]])  # on neither side, not a lucky 0
            assert plane[COLUMN["error_m"]] == math.hypot(5.0, 100.0)
            assert fail[COLUMN["success"]] is False
            assert all(
                math.isnan(fail[COLUMN[c]])
                for c in ("x_m", "error_m", "error_side_resolved_m", "wrong_side", "nees")
            )
            assert fail[COLUMN["n_candidates"]] == 0 and fail[COLUMN["candidates_json"]] == "[]"
            assert fail[COLUMN["message"]] == "no"
