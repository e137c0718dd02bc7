"""Cost of isolating the estimators: a private copy of the data per call, compared after it,
and the process put back around it (:mod:`comparison.estimator_calls`).

Timed against the same code with the isolation taken out (``private_copy`` returning the data
itself, ``changed_field`` returning None, no process state kept; the prints still go to
stderr, two attribute assignments):

- ``paper-fig2 task``: :func:`comparison.tasks.run_task` of one open-loop task of ``paper-1m``
  at 10 dB with paper-fig2's seven estimators, chunks of 25 trials (the default
  ``chunk_size``), 100 and 500 (one columnar call per estimator, ``ml`` included);
- ``per-trial cls``: the same task with ``cls`` called one trial at a time (the test plug-in
  ``tests.comparison.plugins:PerTrialCls``, the cheapest estimator on the per-trial path,
  where the copy is made for every call);
- ``per-frame ekf``: ``ekf`` streamed over the 10 frames of ``paper-1m-turn`` (a copy per
  ``update``);
- the parts alone: the copy and the comparison of one chunk of 25 trials and of one trial,
  and keeping the process (a working-directory look-up, the recursion limit, two streams).

CPU times of this process (``time.process_time``) with BLAS held to one thread, best of three
runs of three, the two variants in turns;
each pair is checked to give the same rows first (but for wall times). Printed: microseconds per trial (per call
for the parts) and the ratio ``isolated / without``.

Run: ``python benchmarks/bench_isolation.py`` (from the repository root, so that the test
plug-ins import).
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.comparison.plugins

import numpy as np  # noqa: E402
from cpu_time import best_cpu_s, best_cpu_us  # noqa: E402

from comparison import estimator_calls  # noqa: E402
from comparison.estimator_calls import changed_field, private_copy  # noqa: E402
from comparison.experiment import builtin_experiment  # noqa: E402
from comparison.specs import EstimatorSpec  # noqa: E402
from comparison.tasks import Task, run_task, trial_seed  # noqa: E402
from comparison.trial_rows import ESTIMATE_COLUMNS  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate_trials  # noqa: E402

REPEATS = 3
RUNTIME = ESTIMATE_COLUMNS.index("runtime_s")
DIAGNOSTICS = ESTIMATE_COLUMNS.index("diagnostics_json")
assert RUNTIME < DIAGNOSTICS


class _NoProcessState:
    """``_ProcessState`` taken out: nothing kept, only the stream swapped back."""

    def __init__(self) -> None:
        self.stdout = sys.stdout

    def restore(self) -> None:
        sys.stdout = self.stdout


@contextmanager
def isolation_taken_out() -> Iterator[None]:
    saved = (
        estimator_calls.private_copy,
        estimator_calls.changed_field,
        estimator_calls._ProcessState,
    )
    estimator_calls.private_copy = lambda data: data
    estimator_calls.changed_field = lambda data, reference: None
    estimator_calls._ProcessState = _NoProcessState
    try:
        yield
    finally:
        (
            estimator_calls.private_copy,
            estimator_calls.changed_field,
            estimator_calls._ProcessState,
        ) = saved


def _best_pair_s(task: Task) -> tuple[float, float]:
    """Least CPU time of the task without the isolation and with it, taken in turns (the
    machine's load then weighs on both alike)."""
    without = isolated = np.inf
    for _ in range(REPEATS):
        with isolation_taken_out():
            without = min(without, best_cpu_s(lambda: run_task(task)))
        isolated = min(isolated, best_cpu_s(lambda: run_task(task)))
    return without, isolated


def _rows(task: Task) -> list[tuple[Any, ...]]:
    """The task's rows without the wall times (``runtime_s``, a solver's ``*time_s``)."""

    def timeless(values: tuple[Any, ...]) -> list[Any]:
        kept = list(values)
        del kept[RUNTIME]
        diagnostics = json.loads(kept[DIAGNOSTICS - 1])
        kept[DIAGNOSTICS - 1] = {k: v for k, v in diagnostics.items() if "time_s" not in k}
        return kept

    return [
        (row.estimator_index, row.frame, row.trial, *timeless(row.values))
        for row in run_task(task).rows
    ]


def _line(label: str, without_us: float, isolated_us: float, unit: str) -> None:
    print(
        f"  {label:<32} without {without_us:9.2f} µs   isolated {isolated_us:9.2f} µs   "
        f"ratio {isolated_us / without_us:5.3f}   ({unit})"
    )


def _task(scenario: str, names: list[str], trials: int, per_frame: bool = False) -> Task:
    return Task(
        seed=20_240_602,
        scenario_index=0,
        point=0,
        scenario=get_scenario(scenario),
        snr_db=10.0,
        trials=tuple(range(trials)),
        estimators=tuple(EstimatorSpec(name=name) for name in names),
        per_frame=per_frame,
    )


def compare_tasks() -> None:
    fig2 = [spec.name for spec in builtin_experiment("paper-fig2").estimators]
    cases = [
        *((f"paper-fig2 task, chunk {n}", _task("paper-1m", fig2, n)) for n in (25, 100, 500)),
        *((f"  {name} alone, chunk 25", _task("paper-1m", [name], 25)) for name in fig2),
        (
            "per-trial cls, chunk 25",
            _task("paper-1m", ["tests.comparison.plugins:PerTrialCls"], 25),
        ),
        ("per-frame ekf, chunk 25", _task("paper-1m-turn", ["ekf"], 25, per_frame=True)),
    ]
    print("tasks (CPU µs per trial):")
    for label, task in cases:
        isolated = _rows(task)
        with isolation_taken_out():
            without = _rows(task)
        assert repr(without) == repr(isolated), label  # the same rows, NaN included
        without_s, isolated_s = _best_pair_s(task)
        n = len(task.trials)
        _line(label, without_s / n * 1e6, isolated_s / n * 1e6, f"{n} trials")


def time_parts() -> None:
    seeds = [trial_seed(1, 0, 0, t) for t in range(25)]
    batch = simulate_trials(get_scenario("paper-1m"), snr_db=10.0, seeds=seeds)
    trial = batch.trial(0)
    count = 2000

    def per_call_us(run: Callable[[], Any]) -> float:
        return best_cpu_us(lambda: [run() for _ in range(count)], count)

    print("parts (CPU µs per call):")
    chunk_copy = private_copy(batch)
    trial_copy = private_copy(trial)
    for label, run in (
        ("copy, chunk of 25", lambda: private_copy(batch)),
        ("compare, chunk of 25", lambda: changed_field(chunk_copy, batch)),
        ("copy, one trial", lambda: private_copy(trial)),
        ("compare, one trial", lambda: changed_field(trial_copy, trial)),
        ("keep the process", lambda: estimator_calls._ProcessState().restore()),
    ):
        print(f"  {label:<32} {per_call_us(run):9.2f} µs")


def main() -> None:
    time_parts()
    compare_tasks()


if __name__ == "__main__":
    main()
