"""Tests of the columnar path of the engine: an estimator with ``estimate_columns`` is called
through it, its results stay columns to the rows, and the rows are those of scoring each
``Estimate`` of the same results one at a time (two paths: to rounding, by the rule of
:mod:`tests.paths`); the fallbacks keep their rules.

The estimator classes at the top are test plug-ins, referred to by experiments and tasks as
``tests.comparison.test_columnar:Name``.
"""

import dataclasses
import math
import sqlite3
import time
from typing import ClassVar

import numpy as np
import pytest

from comparison.engine import run_experiment
from comparison.experiment import Experiment, load_experiment
from comparison.run_folder import RESULTS_FILE
from comparison.scoring import estimate_columns, frame_track
from comparison.specs import EstimatorSpec
from comparison.tasks import Task, run_task, tie_rng, trial_seed
from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.base import Capabilities
from estimators.closed_form.cls import Cls
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate_trials
from scenarios.types import MeasurementBatch
from tests import paths
from tests.comparison.plugins import PER_TRIAL_CLS
from tests.comparison.test_engine import rows, smoke

HERE = "tests.comparison.test_columnar"
HANG_S = 120.0
"""How long a hanging columns call sleeps: 20 times the 6 s that 12 trials at 0.5 s allow."""
RUNTIME = ESTIMATE_COLUMNS.index("runtime_s")
DIAGNOSTICS = ESTIMATE_COLUMNS.index("diagnostics_json")
MESSAGE = ESTIMATE_COLUMNS.index("message")
SUCCESS = ESTIMATE_COLUMNS.index("success")


# --------------------------------------------------------------------------------------------
# test plug-in estimators
# --------------------------------------------------------------------------------------------


dataclass_frozen = dataclasses.dataclass(frozen=True, kw_only=True)


@dataclass_frozen
class ColumnsCls:
    """``cls`` through ``estimate_columns`` only, marking its rows; ``mode`` breaks that path:
    ``"raise"``, ``"short"`` (one trial too few), ``"list"`` (a list, not columns),
    ``"hang"`` (sleeps ``HANG_S``, far beyond any limit a test sets). ``estimate`` is
    ``cls``'s; ``estimate_batch`` must not be called."""

    name: ClassVar[str] = "columns-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    mode: str = "ok"
    declared: bool = True

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, batch=self.declared)

    def estimate(self, data, *, rng=None):
        return Cls().estimate(data, rng=rng)

    def estimate_batch(self, batch, *, rngs=None):
        raise AssertionError("estimate_batch called although estimate_columns is there")

    def estimate_columns(self, batch, *, rngs=None):
        if not self.declared:
            raise AssertionError("estimate_columns called although batch is not declared")
        if self.mode == "raise":
            raise RuntimeError("columns broken on purpose")
        if self.mode == "hang":
            time.sleep(HANG_S)
        columns = Cls().estimate_columns(batch, rngs=rngs)
        if self.mode == "list":
            return columns.to_estimates()
        if self.mode == "short":
            return columns.to_estimates()[:-1]
        marked = {**columns.diagnostics, "via_columns": np.ones(len(columns), dtype=bool)}
        return dataclasses.replace(columns, diagnostics=marked)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def bits(value):
    """A value as stored: its type, and a float by its bytes (NaN equal to NaN)."""
    if type(value) is float:
        return float, np.float64(value).tobytes()
    return type(value), value


def without_runtime(values):
    return [bits(v) for i, v in enumerate(values) if i != RUNTIME]


def task_of(estimators, *, scenario="paper-1m", snr_db=10.0, trials=range(3, 15), **changes):
    changes = {"per_frame": False, **changes}
    return Task(
        seed=77,
        scenario_index=0,
        point=1,
        scenario=get_scenario(scenario),
        snr_db=snr_db,
        trials=tuple(trials),
        estimators=tuple(EstimatorSpec.from_dict(e) for e in estimators),
        **changes,
    )


def up_to_frame(batch: MeasurementBatch, frame: int) -> MeasurementBatch:
    mask = batch.geometry.frame <= frame
    pick = {
        name: None if getattr(batch, name) is None else getattr(batch, name)[:, mask]
        for name in ("doppler_hz", "toa_s", "rss_dbm")
    }
    return MeasurementBatch(geometry=batch.geometry.take(mask), **pick)


def reference_rows(task: Task, index: int) -> dict[tuple[int, int], tuple]:
    """``{(frame, trial): values}`` of estimator ``index``: its ``estimate_columns`` on the
    task's trials, each of ``to_estimates()`` scored by ``estimate_columns`` (runtime 0)."""
    seeds = [trial_seed(task.seed, task.scenario_index, task.point, t) for t in task.trials]
    simulated = simulate_trials(task.scenario, snr_db=task.snr_db, seeds=seeds)
    batch = dataclasses.replace(simulated, geometry=simulated.geometry.without_truth())
    spec = task.estimators[index]
    estimator = spec.build()
    frames = [int(f) for f in batch.geometry.frames]
    out = {}
    for frame in frames if task.per_frame else frames[-1:]:
        rngs = [
            tie_rng(task.seed, task.scenario_index, task.point, t, spec.label) for t in task.trials
        ]
        columns = estimator.estimate_columns(up_to_frame(batch, frame), rngs=rngs)
        track = frame_track(batch.geometry, frame)
        for trial, estimate in zip(task.trials, columns.to_estimates(), strict=True):
            out[(frame, trial)] = estimate_columns(estimate, task.scenario.emitter_m, track, 0.0)
    return out


def kappa_of(scenario) -> float:
    """``κ`` of a row without a covariance: the Fisher information's at the truth."""
    return paths.fisher_condition(noise_free(scenario))


def agree(values, expected, kappa: float) -> list[str]:
    """Two paths' values of one row (:data:`ESTIMATE_COLUMNS` but the runtime) by the rule of
    :mod:`tests.paths` (empty: they agree)."""
    mine = {c: v for c, v in zip(ESTIMATE_COLUMNS, expected, strict=True) if c != "runtime_s"}
    theirs = {c: v for c, v in zip(ESTIMATE_COLUMNS, values, strict=True) if c != "runtime_s"}
    return paths.row_problems(mine, theirs, kappa)


def rows_by_estimator(result, index):
    return {(r.frame, r.trial): r.values for r in result.rows if r.estimator_index == index}


# --------------------------------------------------------------------------------------------
# the columnar path gives the rows of scoring each estimate
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("scenario", "snr_db", "per_frame"),
    [("paper-1m", 10.0, False), ("paper", -10.0, False), ("turn", 0.0, True)],
)
@pytest.mark.paths
def test_columnar_rows_equal_scoring_each_estimate_of_the_same_results(scenario, snr_db, per_frame):
    estimators = [
        "cls",
        "cls-paper",
        {"name": "cls", "label": "cls-last", "options": {"frames": "last"}},
    ]
    task = task_of(estimators, scenario=scenario, snr_db=snr_db, per_frame=per_frame)
    result = run_task(task)
    n_frames = len(get_scenario(scenario).flight.frame_velocities_mps) if per_frame else 1
    assert len(result.rows) == len(estimators) * len(task.trials) * n_frames
    for index in range(len(estimators)):
        got, expected = rows_by_estimator(result, index), reference_rows(task, index)
        assert got.keys() == expected.keys()
        for key, values in got.items():
            assert agree(values, expected[key], kappa_of(task.scenario)) == [], (index, key)
            assert values[RUNTIME] > 0.0


@pytest.mark.paths
def test_the_engine_stores_the_columnar_rows(tmp_path):
    """Through run_experiment and results.sqlite: the stored values of cls are those of the
    per-estimate scoring (bool as 0/1, NaN as NULL), whatever the chunking."""
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    experiment = Experiment.from_dict({**raw, "trials": 7, "chunk_size": 3})
    out = run_experiment(experiment, tmp_path / "run", workers=1)
    names = ", ".join(ESTIMATE_COLUMNS)
    with sqlite3.connect(out / RESULTS_FILE) as connection:
        stored = connection.execute(
            f"SELECT estimator_index, point, frame, trial, {names} FROM trials"
        ).fetchall()
    assert len(stored) == len(experiment.estimators) * 2 * 7

    def as_stored(value):
        if isinstance(value, bool):
            return int(value)
        return None if isinstance(value, float) and math.isnan(value) else value

    expected = {}
    for point in range(2):
        scenario, snr_db = experiment.point_scenario(0, point)
        task = dataclasses.replace(
            task_of(raw["estimators"], scenario="paper", trials=range(7)),
            seed=experiment.seed,
            point=point,
            scenario=scenario,
            snr_db=snr_db,
        )
        for index in range(len(experiment.estimators)):
            for (frame, trial), values in reference_rows(task, index).items():
                expected[(index, point, frame, trial)] = [as_stored(v) for v in values]
    kappa = kappa_of(experiment.point_scenario(0, 0)[0])
    for index, point, frame, trial, *values in stored:
        want = expected[(index, point, frame, trial)]
        assert agree(values, want, kappa) == [], (index, point, frame, trial)


# --------------------------------------------------------------------------------------------
# which path, and the fallbacks
# --------------------------------------------------------------------------------------------


@pytest.mark.bits("both call Cls().estimate_columns on the task's batch")
def test_estimate_columns_is_called_when_declared_and_rows_say_nothing_else():
    wrapped = run_task(task_of([{"name": f"{HERE}:ColumnsCls", "label": "cls"}]))
    marked, plain = rows_by_estimator(wrapped, 0), rows_by_estimator(run_task(task_of(["cls"])), 0)
    assert marked.keys() == plain.keys()
    for key, values in marked.items():
        assert '"via_columns": true' in values[DIAGNOSTICS]
        # apart from the mark, the rows of cls itself
        unmarked = values[DIAGNOSTICS].replace(', "via_columns": true', "")
        same = [*values[:DIAGNOSTICS], unmarked, *values[DIAGNOSTICS + 1 :]]
        assert without_runtime(same) == without_runtime(plain[key])


def test_an_undeclared_estimate_columns_is_not_called():
    task = task_of([{"name": f"{HERE}:ColumnsCls", "options": {"declared": False}}])
    rows = run_task(task).rows
    assert all(r.values[SUCCESS] for r in rows)
    assert not any("via_columns" in r.values[DIAGNOSTICS] for r in rows)


@pytest.mark.paths
@pytest.mark.parametrize("mode", ["raise", "short", "list"])
def test_a_failed_columns_call_falls_back_to_one_call_per_trial(mode):
    """Each trial then gets its own outcome: the rows of cls's ``estimate`` one trial at a
    time (estimate_batch is not tried: it raises here)."""
    spec = {"name": f"{HERE}:ColumnsCls", "label": "cls", "options": {"mode": mode}}
    task = task_of([spec])
    rows = run_task(task).rows
    assert len(rows) == len(task.trials)
    seeds = [trial_seed(77, 0, 1, t) for t in task.trials]
    batch = simulate_trials(task.scenario, snr_db=task.snr_db, seeds=seeds)
    track = frame_track(batch.geometry, 0)
    for row, data in zip(rows, batch, strict=True):
        estimate = Cls().estimate(data.without_truth(), rng=tie_rng(77, 0, 1, row.trial, "cls"))
        expected = estimate_columns(estimate, task.scenario.emitter_m, track, 0.0)
        assert agree(row.values, expected, kappa_of(task.scenario)) == []
        assert row.values[SUCCESS] and "via_columns" not in row.values[DIAGNOSTICS]


def test_the_columns_call_has_the_limit_times_the_trials():
    """0.5 s per trial, 6 s for the columns call of 12 trials: a call that does not pause (a
    12-trial cls batch takes milliseconds) stays columnar; a call that hangs (``HANG_S``) is
    stopped and the trials run one at a time, each within its own limit (a cls trial takes
    about a millisecond). Neither outcome depends on the machine's speed or load."""
    within = [{"name": f"{HERE}:ColumnsCls"}]
    rows = run_task(task_of(within, time_limit_s=0.5)).rows
    assert all('"via_columns": true' in r.values[DIAGNOSTICS] for r in rows)
    over = [{"name": f"{HERE}:ColumnsCls", "options": {"mode": "hang"}}]
    rows = run_task(task_of(over, time_limit_s=0.5)).rows
    assert len(rows) == 12 and all(r.values[SUCCESS] for r in rows)
    assert not any("via_columns" in r.values[DIAGNOSTICS] for r in rows)


@pytest.mark.paths
def test_batch_rows_equal_one_at_a_time_rows_and_do_not_depend_on_the_chunking(tmp_path):
    """cls runs in batch (estimate_columns): its rows do not depend on the chunk size, and
    equal the rows of ``estimate`` called one trial at a time (``estimate`` is the batch of
    one); other chunks are other arrays, so they agree to rounding (:mod:`tests.paths`)."""
    chunked = {
        size: rows(run_experiment(smoke(chunk_size=size), tmp_path / f"c{size}", workers=1))
        for size in (1, 7, 20)
    }
    kappa = kappa_of(smoke().point_scenario(0, 0)[0])
    assert paths.frame_problems(chunked[1], chunked[7], kappa) == []
    assert paths.frame_problems(chunked[1], chunked[20], kappa) == []
    single = rows(run_experiment(smoke(estimators=PER_TRIAL_CLS), tmp_path / "one", workers=1))
    assert paths.frame_problems(chunked[7], single, kappa) == []
