"""``estimate_columns`` of every built-in batch estimator on batches with unknown nuisance
parameters (MATH §15): the columns equal ``estimate`` trial by trial, a built-in that refuses
the unknowns refuses with ``estimate``'s own one-line error, and the engine takes the columns
path (no silent fallback to one call per trial).

The two paths are compared at a tolerance: positions, candidates and covariances to
``RTOL`` of the problem's scale (the larger of the returned position's norm and the extent of
the samples used, with the UAV's height), numbers in the diagnostics to ``RTOL`` relative;
everything else (success, ambiguity, messages, the diagnostics' keys, their strings and
flags) exactly.
"""

from __future__ import annotations

import dataclasses
import json
import math
from numbers import Number

import numpy as np
import pytest

import comparison.tasks as tasks
from comparison.estimator_calls import call_columns
from comparison.scoring import estimate_columns, frame_track
from comparison.specs import EstimatorSpec
from comparison.tasks import Task, run_task, tie_rng, trial_seed
from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.base import Estimate, capabilities_of
from estimators.batch import BatchEstimates
from estimators.registry import BUILTIN, make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds

RTOL = 1e-9
N_TRIALS = 12
BOTH = ("carrier_offset_hz", "emission_time_s")

SCENARIOS = {
    "beacon-pass": ("beacon-pass", BOTH),
    "beacon-pass-doppler": ("beacon-pass-doppler", BOTH),
    "turn-noncooperative": ("turn-noncooperative", BOTH),
    "turn-offset": ("turn-noncooperative", ("carrier_offset_hz",)),
    "turn-emission": ("turn-noncooperative", ("emission_time_s",)),
    "beacon-pass-offset": ("beacon-pass", ("carrier_offset_hz",)),
}
"""Batches with unknowns: the catalog's non-cooperative scenarios, and one unknown at a time."""

ESTIMATORS = {
    "cls": ("cls", {}),
    "cls-profile": ("cls", {"offset_method": "profile"}),
    "cls-last": ("cls", {"frames": "last"}),
    "cls-paper": ("cls-paper", {}),
    "cls-as-printed": ("cls-as-printed", {}),
    "sdp-cls": ("sdp-cls", {}),
    "ml": ("ml", {}),
    "ml-doppler": ("ml", {"use_toa": False}),
}
"""Every built-in with ``estimate_columns``, with the options that change what it does with
unknowns."""


def batch_estimators() -> set[str]:
    """The built-ins that declare a batch path and have ``estimate_columns``."""
    return {
        name
        for name in BUILTIN
        if BUILTIN[name].is_available()
        and capabilities_of(make_estimator(name)).batch
        and callable(getattr(make_estimator(name), "estimate_columns", None))
    }


def test_every_builtin_with_columns_is_covered():
    assert batch_estimators() <= {name for name, _ in ESTIMATORS.values()}


def batch_of(key: str, snr_db: float = 10.0, n: int = N_TRIALS, seed: int = 3):
    name, unknowns = SCENARIOS[key]
    scenario = get_scenario(name).replace(unknowns=unknowns)
    return simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(seed, n))


def generators(n: int) -> list[np.random.Generator]:
    return [np.random.default_rng(500 + i) for i in range(n)]


# --------------------------------------------------------------------------------------------
# the comparison of two estimates of one trial
# --------------------------------------------------------------------------------------------


def problem_scale_m(data, position_m) -> float:
    """The larger of the returned position's norm and the extent of the samples with the
    UAV's height above the emitter: the length a relative tolerance applies to."""
    samples = np.asarray(data.position_m, dtype=float)
    extent = float(np.ptp(samples[:, :2], axis=0).max(initial=0.0))
    height = float(np.max(np.abs(samples[:, 2] - data.emitter_height_m)))
    finite = np.asarray(position_m)[np.isfinite(position_m)]
    return max(float(np.max(np.abs(finite), initial=0.0)), extent, height)


def value_differences(key: str, single, got) -> list[str]:
    """A diagnostics value: numbers to ``RTOL`` relative, lists item by item, else equal."""
    if isinstance(single, bool) or isinstance(got, bool) or single is None or got is None:
        return [] if single == got else [f"{key}: {single!r} vs {got!r}"]
    if isinstance(single, Number) and isinstance(got, Number):
        a, b = float(single), float(got)
        if (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=RTOL, abs_tol=0.0):
            return []
        return [f"{key}: {single!r} vs {got!r}"]
    if isinstance(single, list | tuple) and isinstance(got, list | tuple):
        if len(single) != len(got):
            return [f"{key}: {single!r} vs {got!r}"]
        return [d for a, b in zip(single, got, strict=True) for d in value_differences(key, a, b)]
    return [] if single == got else [f"{key}: {single!r} vs {got!r}"]


def estimate_differences(data, single: Estimate, got: Estimate) -> list[str]:
    """How ``got`` differs from ``single`` (empty: the same estimate, to the tolerance)."""
    problems = [
        f"{field}: {getattr(single, field)!r} vs {getattr(got, field)!r}"
        for field in ("estimator", "success", "ambiguous", "message")
        if getattr(single, field) != getattr(got, field)
    ]
    scale = problem_scale_m(data, single.position_m)
    for field in ("position_m", "candidates_m"):
        a, b = np.asarray(getattr(single, field)), np.asarray(getattr(got, field))
        if a.shape != b.shape or not np.allclose(a, b, rtol=0.0, atol=RTOL * scale, equal_nan=True):
            problems.append(f"{field}: {a.tolist()} vs {b.tolist()}")
    if (single.covariance_m2 is None) != (got.covariance_m2 is None):
        problems.append(f"covariance_m2: {single.covariance_m2} vs {got.covariance_m2}")
    elif single.covariance_m2 is not None:
        a, b = np.asarray(single.covariance_m2), np.asarray(got.covariance_m2)
        size = float(np.nanmax(np.abs(a), initial=0.0))
        if not np.allclose(a, b, rtol=0.0, atol=RTOL * size, equal_nan=True):
            problems.append(f"covariance_m2: {a.tolist()} vs {b.tolist()}")
    if single.success:  # a failed trial's columns hold no diagnostics (BatchEstimates)
        if set(single.diagnostics) != set(got.diagnostics):
            problems.append(
                f"diagnostics keys: {sorted(single.diagnostics)} vs {sorted(got.diagnostics)}"
            )
        else:
            for key, value in single.diagnostics.items():
                problems += value_differences(key, value, got.diagnostics[key])
    elif got.diagnostics:
        problems.append(f"a failed trial's diagnostics: {got.diagnostics!r}")
    return problems


# --------------------------------------------------------------------------------------------
# every built-in × every batch with unknowns
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
@pytest.mark.parametrize("label", sorted(ESTIMATORS))
def test_columns_equal_estimate_trial_by_trial_or_refuse_as_estimate(label, scenario):
    name, options = ESTIMATORS[label]
    estimator = make_estimator(name, **options)
    batch = batch_of(scenario)
    assert batch.geometry.unknowns
    try:
        singles = [
            estimator.estimate(batch.trial(i), rng=rng)
            for i, rng in enumerate(generators(batch.n_trials))
        ]
    except ValueError as refusal:  # the unknowns, or a modality, it cannot take
        with pytest.raises(ValueError) as raised:
            estimator.estimate_columns(batch, rngs=generators(batch.n_trials))
        assert str(raised.value) == str(refusal)
        assert "\n" not in str(refusal)
        return
    columns = estimator.estimate_columns(batch, rngs=generators(batch.n_trials))
    assert isinstance(columns, BatchEstimates) and len(columns) == batch.n_trials
    problems = {
        i: found
        for i, single in enumerate(singles)
        if (found := estimate_differences(batch.trial(i), single, columns.estimate(i)))
    }
    assert not problems, problems
    batched = estimator.estimate_batch(batch, rngs=generators(batch.n_trials))
    for i, single in enumerate(singles):
        assert estimate_differences(batch.trial(i), single, batched[i]) == []


def test_the_unknowns_cases_do_estimate():
    """The comparison above is not empty: cls and ml take every unknowns set with ToA, and
    ml from Doppler alone takes the Doppler-only pass; they succeed on most trials."""
    for label, scenarios in (
        ("cls", ["beacon-pass", "turn-noncooperative", "turn-offset", "turn-emission"]),
        ("ml", ["beacon-pass", "turn-noncooperative", "turn-offset", "turn-emission"]),
        ("ml-doppler", ["beacon-pass-doppler", "beacon-pass"]),
    ):
        name, options = ESTIMATORS[label]
        for scenario in scenarios:
            batch = batch_of(scenario, n=6)
            columns = make_estimator(name, **options).estimate_columns(batch, rngs=generators(6))
            assert columns.success.sum() >= 5, (label, scenario)
            if label.startswith("ml"):
                diagnostics = columns.estimate(int(np.argmax(columns.success))).diagnostics
                unknown = set(batch.geometry.unknowns)
                if label == "ml-doppler":
                    unknown.discard("emission_time_s")  # no ToA: b does not enter
                assert unknown <= set(diagnostics), (label, scenario)


# --------------------------------------------------------------------------------------------
# the engine takes the columns path
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("label", "scenario"),
    [("ml", "beacon-pass"), ("ml-doppler", "beacon-pass-doppler"), ("cls", "turn-noncooperative")],
)
def test_the_engine_calls_estimate_columns_on_a_batch_with_unknowns(label, scenario, monkeypatch):
    name, options = ESTIMATORS[label]
    estimator = make_estimator(name, **options)
    batch = batch_of(scenario, n=6)
    assert call_columns(estimator, batch, generators(6)) is not None

    def no_fallback(*args, **kwargs):
        raise AssertionError("the engine fell back to one call per trial")

    monkeypatch.setattr(tasks, "timed_call", no_fallback)
    scenario_name, unknowns = SCENARIOS[scenario]
    task = Task(
        seed=41,
        scenario_index=0,
        point=0,
        scenario=get_scenario(scenario_name).replace(unknowns=unknowns),
        snr_db=10.0,
        trials=tuple(range(6)),
        estimators=(EstimatorSpec.from_dict({"name": name, "label": label, "options": options}),),
        per_frame=False,
    )
    rows = run_task(task).rows
    assert len(rows) == 6
    # each row is that of scoring ``estimate`` of its trial (the runtime aside)
    seeds = [trial_seed(41, 0, 0, t) for t in task.trials]
    simulated = simulate_trials(task.scenario, snr_db=10.0, seeds=seeds)
    geometry = simulated.geometry.without_truth()
    data = dataclasses.replace(simulated, geometry=geometry)
    track = frame_track(geometry, int(geometry.frames[-1]))
    for row in rows:
        single = estimator.estimate(data.trial(row.trial), rng=tie_rng(41, 0, 0, row.trial, label))
        expected = estimate_columns(single, task.scenario.emitter_m, track, 0.0)
        assert row_differences(row.values, expected) == []


def row_differences(got, expected) -> list[str]:
    """The row's columns against the expected ones: numbers to ``RTOL`` relative of the
    column's scale, JSON columns parsed and compared so, the rest exactly; no runtime."""
    problems = []
    for column, a, b in zip(ESTIMATE_COLUMNS, got, expected, strict=True):
        if column == "runtime_s":
            continue
        if column.endswith("_json"):
            problems += value_differences(column, json.loads(b), json.loads(a))
        else:
            problems += value_differences(column, b, a)
    return problems


# --------------------------------------------------------------------------------------------
# the rule of BatchEstimates: every successful trial has the columns' keys
# --------------------------------------------------------------------------------------------


def one(estimator="e", **diagnostics) -> Estimate:
    point = np.array([1.0, 2.0])
    return Estimate(
        estimator=estimator,
        position_m=point,
        candidates_m=point[None],
        ambiguous=False,
        success=True,
        message="",
        diagnostics=diagnostics,
    )


def test_replacing_every_success_takes_the_replacements_keys():
    """A batch path's columns for trials it left to the one-trial path describe no trial:
    once every success is replaced, the replacements' keys (the same on each) are the
    columns'."""
    template = BatchEstimates.from_estimates("e", [one(a=1), one(a=2), Estimate.failed("e", "x")])
    replaced = template.with_trials([0, 1], [one(a=3, b=0.5), one(a=4, b=1.5)])
    assert [replaced.estimate(i).diagnostics for i in (0, 1)] == [
        {"a": 3, "b": 0.5},
        {"a": 4, "b": 1.5},
    ]
    assert replaced.estimate(2).diagnostics == {} and not replaced.success[2]


def test_a_replacement_whose_keys_differ_from_a_kept_trial_is_refused():
    template = BatchEstimates.from_estimates("e", [one(a=1), one(a=2)])
    with pytest.raises(ValueError, match=r"^diagnostics: trial 1 has keys \['a', 'b'\]"):
        template.with_trials([1], [one(a=3, b=0.5)])
    with pytest.raises(ValueError, match=r"^diagnostics: trial 1 has keys \['b'\]"):
        BatchEstimates.from_estimates("e", [one(a=1), one(b=2)])


def test_a_column_of_mixed_types_keeps_each_value():
    """A key whose values are ints on some trials and floats on others is held as objects,
    never cast (an int column would truncate 2.5)."""
    columns = BatchEstimates.from_estimates("e", [one(k=1, s=[1, 2]), one(k=2.5, s=[3])])
    assert [columns.estimate(i).diagnostics for i in (0, 1)] == [
        {"k": 1, "s": [1, 2]},
        {"k": 2.5, "s": [3]},
    ]
    assert columns.diagnostics["k"].dtype == object
    typed = BatchEstimates.from_estimates("e", [one(k=1.0), one(k=2.5)])
    assert typed.diagnostics["k"].dtype == np.float64
