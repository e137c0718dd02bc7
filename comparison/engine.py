"""The Monte Carlo engine: run an :class:`~comparison.experiment.Experiment` into a run folder.

:func:`run_experiment` checks the folder (:mod:`comparison.run_folder`), works out every
point's CRLB (:mod:`comparison.bounds`), cuts the missing trials into tasks
(:mod:`comparison.tasks`), runs them here, in local processes or on a dask cluster
(:mod:`comparison.execution`), and stores each task's rows as it finishes
(:mod:`comparison.store`). The rows follow the contract of :mod:`comparison.trial_rows`;
``runtime_s`` is the only column that is not a function of the experiment, and no row depends
on the number of workers, their order, the chunking, or the number of trials asked (the seed
tree is in :mod:`comparison.tasks`).

The pieces:

- :mod:`comparison.trial_rows`: the columns of the trial, point and flight rows, once;
- :mod:`comparison.tasks`: seeds, tasks and the code a worker runs (open and closed loop);
- :mod:`comparison.estimator_calls`: an estimator called, batched or streamed, never raising;
- :mod:`comparison.scoring`: one estimate's columns (errors, side, the two NEES);
- :mod:`comparison.bounds`: the CRLB of every point and of every flown trial;
- :mod:`comparison.store`: ``results.sqlite``, written and read back;
- :mod:`comparison.run_folder`: the folder's rules, ``experiment.json`` and ``run.json``;
- :mod:`comparison.execution`: joblib/loky, dask, the progress bar.

:func:`read_trials`, :func:`read_points`, :func:`read_flights` and :func:`read_experiment` are
re-exported here from :mod:`comparison.store` and :mod:`comparison.run_folder`.
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import ExitStack, closing
from pathlib import Path

from comparison.bounds import crlb_key, point_infos, point_rows
from comparison.execution import connect_scheduler, execute, progress_bar
from comparison.experiment import Experiment
from comparison.run_folder import (
    RESULTS_FILE,
    now_utc,
    prepare_folder,
    read_experiment,
    session_info,
    warn_on_code_change,
    write_run_info,
)
from comparison.store import (
    complete_trials,
    connect,
    create_tables,
    read_flights,
    read_points,
    read_trials,
    write_points,
    write_task,
)
from comparison.tasks import estimator_of, plan_tasks

__all__ = ["read_experiment", "read_flights", "read_points", "read_trials", "run_experiment"]


def run_experiment(
    experiment: Experiment,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    trials: int | None = None,
    progress: bool | None = None,
) -> Path:
    """Run ``experiment`` into the run folder ``out_dir``; return the folder.

    Parameters
    ----------
    experiment : Experiment
    out_dir : path
        The run folder. Must be absent or empty unless ``resume``.
    workers : int, optional
        Local worker processes (default ``os.cpu_count()``); 1 runs in this process.
        Ignored with ``scheduler``.
    scheduler : str, optional
        ``"tcp://HOST:PORT"`` of a dask scheduler: run the tasks on its cluster.
    resume : bool
        Continue the run in ``out_dir``: its ``experiment.json`` must match ``experiment``
        (except ``trials``, which may grow); only missing trials run, and the run ends with
        exactly the rows of an uninterrupted run.
    trials : int, optional
        Trials per point instead of ``experiment.trials``.
    progress : bool or None
        Show a progress bar on stderr; None shows it when stderr is a terminal.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ValueError
        A non-empty folder without ``resume``, a mismatching experiment on resume, bad
        ``workers``, or an unreachable or missing dask scheduler.
    """
    if not isinstance(experiment, Experiment):
        raise ValueError(f"experiment: expected an Experiment, got {type(experiment).__name__}")
    if trials is not None:
        experiment = experiment.with_trials(trials)
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers: expected a whole number >= 1, got {workers!r}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise ValueError(
            f"scheduler: expected an address such as tcp://host:8786, got {scheduler!r}"
        )
    out = Path(out_dir)
    with ExitStack() as stack:
        if scheduler is not None:  # fail before touching the folder
            connect_scheduler(scheduler, stack)
        prepare_folder(out, experiment, resume)
        session = session_info(experiment, workers, scheduler, resume)
        if resume:
            warn_on_code_change(out, session)
        write_run_info(out, session)
        start = time.perf_counter()

        # the bounds of every point, and the points table
        crlb_keys = [crlb_key(estimator_of(spec)) for spec in experiment.estimators]
        infos = point_infos(experiment, crlb_keys)
        connection = stack.enter_context(closing(connect(out / RESULTS_FILE)))
        create_tables(connection, experiment)
        write_points(connection, experiment, point_rows(experiment, infos))

        # the missing trials, in tasks, stored as each finishes
        complete = complete_trials(connection, experiment, infos)
        tasks = plan_tasks(experiment, infos, complete)
        advance = progress_bar(
            sys.stderr.isatty() if progress is None else bool(progress),
            stack,
            total=experiment.trials * len(infos),
            completed=sum(len(v) for v in complete.values()),
        )
        task_time_s = 0.0
        for result in execute(tasks, workers, scheduler):
            info = infos[(result.scenario_index, result.point)]
            write_task(connection, experiment, result, info, crlb_keys)
            task_time_s += result.elapsed_s
            if advance is not None:
                advance(len(result.trials))
    session.update(
        finished_utc=now_utc(),
        wall_time_s=time.perf_counter() - start,
        tasks_run=len(tasks),
        task_time_s=task_time_s,
    )
    write_run_info(out, session)
    return out
