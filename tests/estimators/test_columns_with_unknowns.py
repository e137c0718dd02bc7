"""``estimate_columns`` of every built-in batch estimator on batches with unknown nuisance
parameters (MATH §15): the columns equal ``estimate`` trial by trial, a built-in that refuses
the unknowns refuses with ``estimate``'s own one-line error, and the engine takes the columns
path (no silent fallback to one call per trial).

The two paths are compared by the rule of :mod:`tests.paths` (to rounding, at a tolerance from
the problem's conditioning); success, ambiguity, messages, the diagnostics' keys, their
strings and flags exactly.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import comparison.tasks as tasks
from comparison.estimator_calls import call_columns
from comparison.scoring import estimate_columns, frame_track
from comparison.specs import EstimatorSpec
from comparison.tasks import Task, run_task, tie_rng, trial_seed
from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.base import capabilities_of
from estimators.batch import BatchEstimates
from estimators.registry import BUILTIN, make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds
from tests import paths
from tests.estimators.batch_support import path_problems

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
    "cls-two-stage": ("cls", {"offset_method": "two-stage"}),
    "cls-last": ("cls", {"frames": "last"}),
    "cls-paper": ("cls-paper", {}),
    "cls-as-printed": ("cls-as-printed", {}),
    "sdp-cls": ("sdp-cls", {}),
    "ml": ("ml", {}),
    "ml-doppler": ("ml", {"use_toa": False}),
    "lls-toa": ("lls-toa", {}),
    "lls-rss": ("lls-rss", {}),
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


# --------------------------------------------------------------------------------------------
# every built-in × every batch with unknowns
# --------------------------------------------------------------------------------------------


@pytest.mark.paths
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
        if (found := path_problems(estimator, batch.trial(i), single, columns.estimate(i)))
    }
    assert not problems, problems
    batched = estimator.estimate_batch(batch, rngs=generators(batch.n_trials))
    for i, single in enumerate(singles):
        assert not path_problems(estimator, batch.trial(i), single, batched[i])


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


@pytest.mark.paths
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

    monkeypatch.setattr(tasks, "call_estimate", no_fallback)
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
        modalities = "+".join(sorted(capabilities_of(estimator).modalities))
        kappa = paths.fisher_condition(simulated.trial(row.trial), modalities)
        mine = dict(zip(ESTIMATE_COLUMNS, row.values, strict=True))
        theirs = dict(zip(ESTIMATE_COLUMNS, expected, strict=True))
        mine.pop("runtime_s"), theirs.pop("runtime_s")
        assert paths.row_problems(theirs, mine, kappa) == []
