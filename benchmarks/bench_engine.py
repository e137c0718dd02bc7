"""Per-trial cost of the engine around the estimators: the task runner and the scoring.

Columnar results (:class:`~estimators.batch.BatchEstimates`) go from ``estimate_columns`` to
the rows without an :class:`~estimators.base.Estimate` per trial, scored on columns
(:func:`comparison.scoring.score_outcomes`). Timed against the path of one object per trial
(``estimate_batch``, then :func:`comparison.scoring.estimate_columns` per estimate), which
gives the same rows:

- ``task runner, cls alone``: :func:`comparison.tasks.run_task` of one open-loop task of
  ``paper-1m`` at 10 dB with ``cls`` only (simulation, the tie-breaking generators, the
  estimator, the scoring), against the same task run one estimate at a time (written here),
  with chunks of 25 trials (the default ``chunk_size``), 100 and 500;
- ``scoring alone``: the rows of 500 ``cls`` estimates (from their columns; ``per estimate``
  counts building the objects, ``per estimate, objects given`` does not) and of 200 ``ml``
  estimates (one object per trial either way, with a covariance and its mirror image:
  :meth:`~comparison.scoring.Outcomes.of_estimates` then :func:`score_outcomes`);
- ``paper-fig2``: the wall time of :func:`comparison.engine.run_experiment` with ``--trials``
  trials per point (default 200) on ``--workers`` worker processes (default 2), report
  excluded, and the time the tasks took around the estimators (their ``runtime_s``) per row.

CPU times are of this process (``time.process_time``) with BLAS held to one thread, best of
three; every path is checked to give the same rows first. Printed: microseconds per trial and
the ratio ``per estimate / columnar``.

Run: ``python benchmarks/bench_engine.py`` (``--quick``: no paper-fig2 run).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import dataclasses  # noqa: E402

import numpy as np  # noqa: E402
from cpu_time import best_cpu_us  # noqa: E402

from comparison.engine import read_trials, run_experiment  # noqa: E402
from comparison.estimator_calls import call_batch, call_limits  # noqa: E402
from comparison.experiment import builtin_experiment  # noqa: E402
from comparison.scoring import (  # noqa: E402
    Outcomes,
    estimate_columns,
    frame_track,
    score_outcomes,
)
from comparison.specs import EstimatorSpec  # noqa: E402
from comparison.tasks import ScoredRow, Task, estimator_of, run_task, tie_rng, trial_seed  # noqa: E402
from comparison.trial_rows import ESTIMATE_COLUMNS  # noqa: E402
from estimators.registry import make_estimator  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate_trials, trial_seeds  # noqa: E402

RUNTIME = ESTIMATE_COLUMNS.index("runtime_s")


def _line(label: str, before_us: float, after_us: float) -> None:
    print(
        f"  {label:<34} per estimate {before_us:8.2f} µs   columnar {after_us:8.2f} µs   "
        f"ratio {before_us / after_us:5.2f}"
    )


# --------------------------------------------------------------------------------------------
# the task runner, cls alone
# --------------------------------------------------------------------------------------------


def run_task_per_estimate(task: Task) -> list[ScoredRow]:
    """An open-loop task of one batch estimator, one ``Estimate`` and one scoring per trial
    (the rows of :func:`run_task`, by the path without columns)."""
    seeds = [trial_seed(task.seed, task.scenario_index, task.point, t) for t in task.trials]
    simulated = simulate_trials(task.scenario, snr_db=task.snr_db, seeds=seeds)
    batch = dataclasses.replace(simulated, geometry=simulated.geometry.without_truth())
    truth = np.asarray(task.scenario.emitter_m, dtype=float)
    frame = int(batch.geometry.frames[-1])
    track = frame_track(batch.geometry, frame)
    rows = []
    for index, spec in enumerate(task.estimators):
        estimator = estimator_of(spec)
        rngs = [
            tie_rng(task.seed, task.scenario_index, task.point, t, spec.label) for t in task.trials
        ]
        results = call_batch(estimator, batch, rngs)
        assert results is not None
        for trial, (estimate, runtime_s) in zip(task.trials, results, strict=True):
            values = estimate_columns(estimate, truth, track, runtime_s)
            rows.append(ScoredRow(0, index, frame, trial, None, values))
    return rows


def _bits(value: Any) -> Any:
    """A float by its bytes (NaN equals NaN), anything else as it is, with its type."""
    return (float, np.float64(value).tobytes()) if type(value) is float else (type(value), value)


def _same(rows: list[Any], reference: list[Any]) -> bool:
    """Rows of values equal to the bit and in type, ``runtime_s`` aside."""

    def key(values: tuple[Any, ...]) -> list[Any]:
        return [_bits(v) for i, v in enumerate(values) if i != RUNTIME]

    return len(rows) == len(reference) and all(
        key(a) == key(b) for a, b in zip(rows, reference, strict=True)
    )


def bench_task_runner() -> None:
    print("task runner, cls alone (paper-1m, 10 dB, CPU µs per trial):")
    scenario = get_scenario("paper-1m")
    for size in (25, 100, 500):
        task = Task(
            seed=2024,
            scenario_index=0,
            point=0,
            scenario=scenario,
            snr_db=10.0,
            trials=tuple(range(size)),
            estimators=(EstimatorSpec.from_dict("cls"),),
            per_frame=False,
        )
        with call_limits(None):
            before = run_task_per_estimate(task)
        after = run_task(task).rows
        assert [r[:4] for r in before] == [r[:4] for r in after], "the keys differ"
        assert _same([r.values for r in after], [r.values for r in before]), "the rows differ"
        repeats = max(1, 2000 // size)

        def old(task: Task = task, repeats: int = repeats) -> None:
            with call_limits(None):
                for _ in range(repeats):
                    run_task_per_estimate(task)

        def new(task: Task = task, repeats: int = repeats) -> None:
            for _ in range(repeats):
                run_task(task)

        count = size * repeats
        _line(f"chunks of {size}", best_cpu_us(old, count), best_cpu_us(new, count))


# --------------------------------------------------------------------------------------------
# the scoring alone
# --------------------------------------------------------------------------------------------


def bench_scoring() -> None:
    print("scoring alone (CPU µs per trial):")
    scenario = get_scenario("paper-1m")
    truth = np.asarray(scenario.emitter_m, dtype=float)
    batch = simulate_trials(scenario, snr_db=10.0, seeds=trial_seeds(7, 500))
    track = frame_track(batch.geometry, int(batch.geometry.frames[-1]))
    rngs = [np.random.default_rng(i) for i in range(len(batch))]
    columns = make_estimator("cls").estimate_columns(batch, rngs=rngs)
    estimates = columns.to_estimates()
    outcomes = Outcomes.of_columns(columns, 1e-5)
    reference = [estimate_columns(e, truth, track, 1e-5) for e in estimates]
    assert _same(score_outcomes(outcomes, truth, track), reference), "cls: the rows differ"
    n = len(columns)
    after = best_cpu_us(lambda: score_outcomes(Outcomes.of_columns(columns, 1e-5), truth, track), n)
    _line(
        "cls, 500 trials",
        best_cpu_us(
            lambda: [estimate_columns(e, truth, track, 1e-5) for e in columns.to_estimates()], n
        ),
        after,
    )
    _line(
        "cls, 500 trials, objects given",
        best_cpu_us(lambda: [estimate_columns(e, truth, track, 1e-5) for e in estimates], n),
        after,
    )

    ml = make_estimator("ml")
    results = [
        (ml.estimate(data, rng=rngs[i]), 1e-3)
        for i, data in enumerate(map(batch.trial, range(200)))
    ]
    reference = [estimate_columns(e, truth, track, r) for e, r in results]
    assert _same(score_outcomes(Outcomes.of_estimates(results), truth, track), reference), "ml"
    mirrored = sum(e.ambiguous for e, _ in results)
    _line(
        f"ml, 200 objects ({mirrored} ambiguous)",
        best_cpu_us(lambda: [estimate_columns(e, truth, track, r) for e, r in results], 200),
        best_cpu_us(
            lambda: score_outcomes(Outcomes.of_estimates(results), truth, track), len(results)
        ),
    )


# --------------------------------------------------------------------------------------------
# paper-fig2
# --------------------------------------------------------------------------------------------


def bench_paper_fig2(trials: int, workers: int) -> None:
    experiment = builtin_experiment("paper-fig2")
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        run_experiment(experiment, folder, trials=trials, workers=workers, progress=False)
        wall_s = time.perf_counter() - start
        task_s = json.loads((Path(folder) / "run.json").read_text())["task_time_s"]
        estimator_s = float(read_trials(folder).runtime_s.sum())
    rows = trials * len(experiment.estimators) * len(experiment.scenarios)
    rows *= len(list(experiment.sweep.points()))
    print(
        f"paper-fig2, {trials} trials per point on {workers} workers ({rows} rows, no report; "
        f"load average {load:.1f} before): run_experiment {wall_s:.1f} s wall; in the tasks "
        f"{task_s:.1f} s, of which estimators {estimator_s:.1f} s, the rest "
        f"{(task_s - estimator_s) / rows * 1e6:.0f} µs per row"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip the paper-fig2 run")
    parser.add_argument("--trials", type=int, default=200, help="paper-fig2 trials per point")
    parser.add_argument("--workers", type=int, default=2, help="paper-fig2 worker processes")
    args = parser.parse_args()
    bench_task_runner()
    bench_scoring()
    if not args.quick:
        bench_paper_fig2(args.trials, args.workers)


if __name__ == "__main__":
    main()
