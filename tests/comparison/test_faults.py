"""Tests of estimator faults: what Python can catch, processes that die, and the time limit.

The estimator classes at the top are test plug-ins, referred to by experiments as
``tests.comparison.test_faults:Name`` (worker and isolation processes import them by that
path). Each one is ``cls``, except that it faults where its tie-breaking generator first draws
below ``rate``; the tests work out where from the same generator (:func:`tie_rng`).
"""

import ctypes
import dataclasses
import os
import signal
import sys
import time
from typing import ClassVar

import pandas as pd
import pytest

from comparison.engine import read_flights, read_trials, run_experiment
from comparison.execution import GIVE_UP_AFTER, run_isolated
from comparison.experiment import Experiment, load_experiment
from comparison.specs import EstimatorSpec
from comparison.tasks import Task, tie_rng
from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.closed_form.cls import Cls
from scenarios.catalog import get_scenario

HERE = "tests.comparison.test_faults"
LIMIT_S = 1.0
HANG_S = 60.0
"""How long a hanging estimate sleeps: a recorded runtime below it was stopped at the limit."""


def _hang() -> None:
    time.sleep(HANG_S)


def _hang_in_c() -> None:
    """Like C code that never returns to Python: the alarm cannot reach it."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
    time.sleep(HANG_S)


def _interrupt() -> None:
    raise KeyboardInterrupt


def _raise() -> None:
    raise RuntimeError("broken on purpose")


FAULTS = {
    "raise": _raise,
    "system-exit": lambda: sys.exit(3),
    "os-exit": lambda: os._exit(3),
    "segfault": lambda: ctypes.string_at(0),
    "hang": _hang,
    "hang-in-c": _hang_in_c,
    "interrupt": _interrupt,
}

MESSAGES = {
    "raise": "RuntimeError: broken on purpose",
    "system-exit": "the estimator raised SystemExit(3)",
    "os-exit": "the estimator ended its process (exit status 3)",
    "segfault": "the estimator killed its process (signal 11, SIGSEGV)",
    "hang": "the estimate took longer than the limit of 1 s (time_limit_s)",
    "hang-in-c": (
        "the estimate took longer than the limit of 1 s (time_limit_s) and did not return to "
        "Python; its process was stopped"
    ),
}


@dataclasses.dataclass(frozen=True, kw_only=True)
class Faulty:
    """``cls``, except that it faults (``FAULTS[fault]``) where its generator draws < ``rate``."""

    name: ClassVar[str] = "faulty"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    fault: str = "raise"
    rate: float = 0.5

    def estimate(self, data, *, rng=None):
        if rng.random() < self.rate:
            FAULTS[self.fault]()
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True, kw_only=True)
class DiesWhenBuilt:
    """An estimator whose construction ends its process (never built in the test process)."""

    name: ClassVar[str] = "dies-when-built"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def __post_init__(self):
        os._exit(4)

    def estimate(self, data, *, rng=None):
        raise AssertionError("never called")


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def experiment(faults: dict[str, tuple[str, float]], **changes) -> Experiment:
    """``smoke`` at 20 dB with ``cls`` and one :class:`Faulty` per ``label: (fault, rate)``."""
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    raw.update(
        sweep={"parameter": "snr_db", "values": [20]},
        trials=6,
        chunk_size=3,
        time_limit_s=LIMIT_S,
        estimators=[
            {"name": "cls"},
            *(
                {"name": f"{HERE}:Faulty", "label": label, "options": {"fault": f, "rate": r}}
                for label, (f, r) in faults.items()
            ),
        ],
    )
    raw.update(changes)
    return Experiment.from_dict(raw)


def faulted(experiment: Experiment, label: str, rate: float) -> list[bool]:
    """Where the :class:`Faulty` labelled ``label`` faults, trial by trial."""
    return [
        tie_rng(experiment.seed, 0, 0, trial, label).random() < rate
        for trial in range(experiment.trials)
    ]


def without_runtime(frame: pd.DataFrame) -> pd.DataFrame:
    """Every column but the wall time (the only non-deterministic one), indexed afresh."""
    return frame.drop(columns="runtime_s").reset_index(drop=True)


@pytest.fixture(scope="module")
def cls_rows(tmp_path_factory) -> pd.DataFrame:
    """The rows of ``cls`` alone, in-process: what every faulty run must give it."""
    out = tmp_path_factory.mktemp("reference") / "run"
    return without_runtime(read_trials(run_experiment(experiment({}), out, workers=1)))


def check_rows(trials, experiment, faults, cls_rows):
    """``cls`` has its reference rows; each faulty estimator fails exactly where it faults,
    with the message of its fault, and succeeds everywhere else."""
    cls = without_runtime(trials[trials.estimator == "cls"])
    pd.testing.assert_frame_equal(cls, cls_rows)
    for label, (fault, rate) in faults.items():
        rows = trials[trials.estimator == label].sort_values("trial")
        expected = faulted(experiment, label, rate)
        assert 0 < sum(expected) or rate == 0.0
        assert (~rows.success).to_list() == expected, label
        assert rows[rows.success].error_m.notna().all()
        failed = rows[~rows.success]
        assert failed[["x_m", "y_m", "error_m"]].isna().all().all()
        assert (failed.message == MESSAGES[fault]).all(), failed.message.to_list()


# --------------------------------------------------------------------------------------------
# what Python can catch: the same in-process and in loky workers
# --------------------------------------------------------------------------------------------

CATCHABLE = {
    "raises": ("raise", 0.5),
    "exits": ("system-exit", 0.5),
    "hangs": ("hang", 0.3),
}


@pytest.mark.parametrize("workers", [1, 2])
def test_catchable_faults_give_failed_rows_and_the_run_completes(tmp_path, cls_rows, workers):
    """An exception, SystemExit and a hang past ``time_limit_s`` each fail the row of the
    estimate (with the reason), in this process and in worker processes alike; every other
    row is the one a run without them gives."""
    chosen = experiment(CATCHABLE)
    trials = read_trials(run_experiment(chosen, tmp_path / "run", workers=workers))
    assert len(trials) == 4 * chosen.trials
    check_rows(trials, chosen, CATCHABLE, cls_rows)
    hung = trials[(trials.estimator == "hangs") & ~trials.success]
    assert len(hung) > 0 and (hung.message == MESSAGES["hang"]).all()
    # each hang was stopped at its limit, not after HANG_S: the runtimes the run recorded
    assert ((hung.runtime_s >= LIMIT_S) & (hung.runtime_s < HANG_S)).all()


def test_keyboard_interrupt_stops_the_run(tmp_path):
    chosen = experiment({"interrupts": ("interrupt", 1.0)}, trials=2, chunk_size=2)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(chosen, tmp_path / "run", workers=1)


# --------------------------------------------------------------------------------------------
# processes that die: loky workers, dask workers, isolation
# --------------------------------------------------------------------------------------------

CHUNK = GIVE_UP_AFTER + 2
GIVEN_UP = (
    f"not run: the estimator ended its process {GIVE_UP_AFTER} times in this task "
    "(last: signal 11, SIGSEGV)"
)


def crash_messages(experiment, label, fault, rate):
    """The message of each trial of a crashing estimator: its fault's where it faults, until
    it has ended GIVE_UP_AFTER processes in a task (a chunk); then every later trial of the
    task is given up; None where it succeeds."""
    messages = []
    for first in range(0, experiment.trials, experiment.chunk_size):
        crashes = 0
        chunk = faulted(experiment, label, rate)[first : first + experiment.chunk_size]
        for faults in chunk:
            if crashes >= GIVE_UP_AFTER:
                messages.append(GIVEN_UP)
            elif faults:
                messages.append(MESSAGES[fault])
                crashes += 1
            else:
                messages.append(None)
    return messages


def mixed_label(experiment, rate):
    """A label whose first task succeeds, then crashes GIVE_UP_AFTER times, then has a trial
    left: the give-up spares the success before it (found by search; the seeds are fixed)."""
    for k in range(1000):
        label = f"mixed-{k}"
        chunk = faulted(experiment, label, rate)[: experiment.chunk_size]
        if not chunk[0] and all(chunk[1 : 1 + GIVE_UP_AFTER]):
            return label
    raise AssertionError("no such label")


def check_crashes(trials, experiment, faults, cls_rows):
    cls = without_runtime(trials[trials.estimator == "cls"])
    pd.testing.assert_frame_equal(cls, cls_rows)
    for label, (fault, rate) in faults.items():
        rows = trials[trials.estimator == label].sort_values("trial")
        expected = crash_messages(experiment, label, fault, rate)
        assert rows.success.to_list() == [m is None for m in expected], label
        assert rows[~rows.success].message.to_list() == [m for m in expected if m], label
        assert rows[rows.success].error_m.notna().all()


@pytest.fixture(scope="module")
def crashing():
    chosen = experiment({}, chunk_size=CHUNK, trials=2 * CHUNK)
    faults = {
        "segfaults": ("segfault", 0.5),
        "exits": ("os-exit", 0.4),
        "always": ("segfault", 1.0),
        mixed_label(chosen, 0.7): ("segfault", 0.7),
    }
    estimators = [{"name": "cls"}] + [
        {"name": f"{HERE}:Faulty", "label": label, "options": {"fault": f, "rate": r}}
        for label, (f, r) in faults.items()
    ]
    chosen = experiment({}, chunk_size=CHUNK, trials=2 * CHUNK, estimators=estimators)
    given_up = [m for label, f in faults.items() for m in crash_messages(chosen, label, *f)]
    assert given_up.count(GIVEN_UP) >= 3  # "always" and the mixed one are given up
    return chosen, faults


@pytest.fixture(scope="module")
def cls_rows_long(tmp_path_factory) -> pd.DataFrame:
    out = tmp_path_factory.mktemp("reference-long") / "run"
    chosen = experiment({}, chunk_size=CHUNK, trials=2 * CHUNK)
    return without_runtime(read_trials(run_experiment(chosen, out, workers=1)))


def test_estimators_that_end_their_process_fail_their_rows_and_the_run_completes(
    tmp_path, crashing, cls_rows_long
):
    """With workers, a segfault or os._exit fails the estimate that caused it, with how the
    process ended; the other estimates of the task, other estimators' and the same
    estimator's, keep their rows. An estimator that crashes every time is given up after
    GIVE_UP_AFTER crashes in a task, so the run ends."""
    chosen, faults = crashing
    trials = read_trials(run_experiment(chosen, tmp_path / "run", workers=2))
    assert len(trials) == len(chosen.estimators) * chosen.trials
    check_crashes(trials, chosen, faults, cls_rows_long)


@pytest.mark.slow  # a dask cluster of processes, whose workers die and restart
def test_a_dask_cluster_survives_estimators_that_end_their_process(
    tmp_path, crashing, cls_rows_long
):
    distributed = pytest.importorskip(
        "distributed", reason="dask.distributed is not installed (emitterbench[cluster])"
    )
    chosen, faults = crashing
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",  # not 8787, which another test's cluster may hold
        silence_logs=50,  # logging.CRITICAL: dask logs each worker death
    ) as cluster:
        out = run_experiment(chosen, tmp_path / "run", scheduler=cluster.scheduler_address)
    check_crashes(read_trials(out), chosen, faults, cls_rows_long)


@pytest.mark.bits(
    "ml's closed-loop estimates are one trial's each: a crashing neighbour leaves its arrays alone"
)
def test_a_crash_in_a_closed_loop_fails_its_frame_and_keeps_every_other_row(tmp_path):
    """Isolation replays a closed-loop task too: the steering estimator's rows and the flown
    frames are those of a run without the crashing estimator."""

    def closed_loop(*extra):
        raw = load_experiment("paper-fig3").to_dict()
        raw.pop("swept_columns")
        raw.update(
            scenarios=["paper-1m"],
            trials=2,
            chunk_size=2,
            frames=2,
            planners=["fisher"],
            estimators=[{"name": "ml", "options": {"frames": "all"}}, *extra],
        )
        return Experiment.from_dict(raw)

    options = {"fault": "segfault", "rate": 0.5}
    crashing = closed_loop({"name": f"{HERE}:Faulty", "label": "seg", "options": options})
    out = run_experiment(crashing, tmp_path / "crash", workers=2)
    reference = run_experiment(closed_loop(), tmp_path / "reference", workers=1)
    trials = read_trials(out)
    ml = without_runtime(trials[trials.estimator == "ml"])
    pd.testing.assert_frame_equal(ml, without_runtime(read_trials(reference)))
    pd.testing.assert_frame_equal(read_flights(out), read_flights(reference))
    seg = trials[trials.estimator == "seg"]
    assert set(seg[~seg.success].message) == {MESSAGES["segfault"]}
    assert seg.success.any() and not seg.success.all()


# --------------------------------------------------------------------------------------------
# isolation, directly
# --------------------------------------------------------------------------------------------


def task(*estimators: EstimatorSpec, trials=(0, 1)) -> Task:
    return Task(
        seed=7,
        scenario_index=0,
        point=0,
        scenario=get_scenario("paper-1m"),
        snr_db=20.0,
        trials=trials,
        estimators=estimators,
        per_frame=False,
        time_limit_s=LIMIT_S,
    )


def test_isolation_stops_a_call_that_never_returns_to_python():
    """The alarm cannot stop C code (here: SIGALRM blocked); in an isolated process the
    supervisor kills it after the limit and a grace, and only that estimate fails."""
    spec = EstimatorSpec(
        name=f"{HERE}:Faulty", label="stuck", options={"fault": "hang-in-c", "rate": 1.0}
    )
    result, ended = run_isolated(task(EstimatorSpec(name="cls"), spec, trials=(0,)))
    assert ended
    success, message = ESTIMATE_COLUMNS.index("success"), ESTIMATE_COLUMNS.index("message")
    by_estimator = {row.estimator_index: row.values for row in result.rows}
    assert by_estimator[0][success]
    assert not by_estimator[1][success]
    # what the run recorded: stopped for the limit (a call the supervisor kills has no runtime)
    assert by_estimator[1][message] == MESSAGES["hang-in-c"]


def test_a_process_that_dies_outside_any_estimate_ends_the_run_with_one_line():
    with pytest.raises(
        RuntimeError, match=r"ended outside any estimator call \(exit status 4\)"
    ) as error:
        run_isolated(task(EstimatorSpec(name="cls"), EstimatorSpec(name=f"{HERE}:DiesWhenBuilt")))
    assert "\n" not in str(error.value)
