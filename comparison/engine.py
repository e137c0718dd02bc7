"""The Monte Carlo engine: run an :class:`~comparison.experiment.Experiment` into a run folder.

:func:`run_experiment` works out every point's CRLB (:mod:`comparison.bounds`) and builds the
estimators and planners, then checks and locks the folder (:mod:`comparison.run_folder`) and
its store, so that nothing is written for an experiment that cannot run; it cuts the missing
trials into tasks (:mod:`comparison.tasks`), runs them here, in local processes or on a dask
cluster (:mod:`comparison.execution`), and stores each task's rows as it finishes
(:mod:`comparison.store`). The rows follow the contract of :mod:`comparison.trial_rows`;
``runtime_s`` is the only column that is not a function of the experiment, and no row depends
on the number of workers, their order, or the number of trials asked (the seed tree is in
:mod:`comparison.tasks`); a batch estimator's rows depend on the chunking only to rounding (a
batch of other trials is other arrays). ``chunk_size = "auto"`` is sized for the workers when
a run starts (:func:`comparison.tasks.auto_chunk_size`) and recorded in ``experiment.json``;
a resume keeps it, so its rows are those of an uninterrupted run, whatever its workers.

The pieces:

- :mod:`comparison.trial_rows`: the columns of the trial, point and flight rows, once;
- :mod:`comparison.tasks`: seeds, tasks and the code a worker runs (open and closed loop);
- :mod:`comparison.estimator_calls`: an estimator called, batched or streamed, never raising;
- :mod:`comparison.scoring`: one estimate's columns (errors, side, the two NEES);
- :mod:`comparison.bounds`: the CRLB of every point and of every flown trial;
- :mod:`comparison.store`: ``results.sqlite``, written and read back;
- :mod:`comparison.run_folder`: the folder's rules and lock, safe writes, ``experiment.json``
  and ``run.json``;
- :mod:`comparison.execution`: joblib/loky, dask, isolation; :mod:`comparison.progress`: the
  progress on stderr.

:func:`read_trials`, :func:`read_points`, :func:`read_flights` and :func:`read_experiment` are
re-exported here from :mod:`comparison.store` and :mod:`comparison.run_folder`.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from collections.abc import Callable
from contextlib import ExitStack, closing
from pathlib import Path
from typing import Any

import numpy as np

from comparison.bounds import CrlbKey, PointInfo, crlb_key, point_infos, point_rows, run_dimension
from comparison.execution import WORKER_WAIT_S, connect_scheduler, execute, release_workers
from comparison.experiment import AUTO_CHUNK_SIZE, Experiment
from comparison.progress import progress_reporter
from comparison.run_folder import (
    EXPERIMENT_FILE,
    RESULTS_FILE,
    check_code_change,
    check_folder,
    folder_session,
    now_utc,
    read_experiment,
    session_info,
    write_experiment,
    write_run_info,
)
from comparison.store import (
    check_store,
    complete_trials,
    connect,
    create_tables,
    read_flights,
    read_points,
    read_trials,
    store_errors,
    write_points,
    write_task,
)
from comparison.tasks import auto_chunk_size, estimator_of, plan_tasks, planner_of
from scenarios.simulate import noise_free

__all__ = ["read_experiment", "read_flights", "read_points", "read_trials", "run_experiment"]


def run_experiment(
    experiment: Experiment,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    trials: int | None = None,
    progress: bool = True,
    worker_wait_s: float = WORKER_WAIT_S,
    accept_code_change: bool = False,
    write_report: Callable[[Path], Any] | None = None,
) -> Path:
    """Run ``experiment`` into the run folder ``out_dir``; return the folder.

    Everything that can fail from the experiment alone (every point's scenario and CRLB, the
    estimators and planners) is worked out before the folder is touched, and a session that
    fails before it stores a row leaves the folder as it found it. One session at a time
    writes a folder (a lock held for the session, :func:`comparison.run_folder.folder_session`).

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
        (except ``trials``, which may grow, and a ``chunk_size`` of ``"auto"``, which takes
        the run's); only missing trials run, and the run ends with exactly the rows of an
        uninterrupted run.
    trials : int, optional
        Trials per point instead of ``experiment.trials``.
    progress : bool
        Show the progress on stderr: a bar when stderr is a terminal, else a line every tenth
        of the trials or minute, whichever comes first, and a last line
        (:class:`comparison.progress.ProgressLog`).
    worker_wait_s : float
        With ``scheduler``: how long to wait for a first worker, s, before the folder is
        locked.
    accept_code_change : bool
        Resume even though the code differs from the last session's: emitterbench's own or
        a plug-in's (:func:`comparison.run_folder.check_code_change`; the changed files are
        recorded in ``run.json``). Without it such a resume is refused.
    write_report : callable, optional
        Called with the folder once every row is stored, while the session still holds the
        folder's lock, so that no other session adds rows while it reads them (the CLI passes
        :func:`comparison.report.write_report`).

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ValueError
        A point that cannot be simulated, a non-empty folder without ``resume``, a
        mismatching experiment or changed code on resume (without ``accept_code_change``), a
        folder another session is writing, a damaged ``results.sqlite``, a file of the run
        that is a symbolic link, bad ``workers``, an unreachable or missing dask scheduler, or
        a ``worker_wait_s`` that is not a positive number.
    comparison.execution.ClusterError
        No dask worker joined within ``worker_wait_s``, or the scheduler was lost during the
        run (the rows stored so far are kept; ``resume`` finishes the run).
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
    if isinstance(worker_wait_s, bool) or not (
        isinstance(worker_wait_s, int | float) and 0 < worker_wait_s < float("inf")
    ):
        raise ValueError(
            f"worker_wait_s: expected a positive number of seconds, got {worker_wait_s!r}"
        )
    out = Path(out_dir)
    # everything that can fail from the experiment alone, before the folder is touched
    crlb_keys, infos, points = _worked_out(experiment)
    dimension = run_dimension(infos)  # 3 with an emitter of unknown height (MATH §8)
    if resume:
        experiment = _stored_chunk_size(experiment, out)
    check_folder(out, experiment, resume)
    database = out / RESULTS_FILE
    with ExitStack() as stack:
        if scheduler is not None:
            connect_scheduler(scheduler, stack, worker_wait_s)
        if experiment.chunk_size == AUTO_CHUNK_SIZE:  # a new run: sized for these workers
            slots = workers if scheduler is None else _cluster_slots()
            chunk_size = auto_chunk_size(experiment, infos, slots)
            experiment = dataclasses.replace(experiment, chunk_size=chunk_size)
        folder = stack.enter_context(folder_session(out, experiment, resume))
        check_store(database)  # a damaged store stops a resume before anything is written
        session = session_info(experiment, workers, scheduler, resume)
        if resume:
            check_code_change(out, session, accept_code_change)
        write_experiment(out, experiment)
        write_run_info(out, session)
        start = time.perf_counter()
        connection = stack.enter_context(closing(connect(database)))
        stack.enter_context(store_errors(database))
        create_tables(connection, experiment, dimension)
        write_points(connection, experiment, points, dimension)

        # the missing trials, in tasks, stored as each finishes
        complete = complete_trials(connection, experiment, infos)
        tasks = plan_tasks(experiment, infos, complete, dimension)
        reporter = progress_reporter(
            progress,
            stack,
            total=experiment.trials * len(infos),
            completed=sum(len(v) for v in complete.values()),
        )
        task_time_s = 0.0
        # closed on the way out, whatever ends the loop: no process of the run outlives it
        results = stack.enter_context(closing(execute(tasks, workers, scheduler)))
        for result in results:
            folder.keep = True  # rows from here on: a failure keeps the folder for --resume
            info = infos[(result.scenario_index, result.point)]
            write_task(connection, experiment, result, info, crlb_keys, dimension)
            task_time_s += result.elapsed_s
            if reporter is not None:
                reporter.advance(len(result.trials))
        if reporter is not None:
            reporter.finish()
        folder.keep = True
        session.update(
            finished_utc=now_utc(),
            wall_time_s=time.perf_counter() - start,
            tasks_run=len(tasks),
            task_time_s=task_time_s,
        )
        write_run_info(out, session)
        if write_report is not None:
            release_workers()  # the report forks its own processes: no pool's threads then
            write_report(out)
    return out


def _stored_chunk_size(experiment: Experiment, out: Path) -> Experiment:
    """``experiment`` with the chunk size of the run it resumes when its own is ``"auto"``:
    the remaining trials fall in the chunks of an uninterrupted run, whatever the workers."""
    stored = out / EXPERIMENT_FILE  # not a link, which check_folder refuses
    if experiment.chunk_size != AUTO_CHUNK_SIZE or stored.is_symlink() or not stored.is_file():
        return experiment
    return dataclasses.replace(experiment, chunk_size=read_experiment(out).chunk_size)


def _cluster_slots() -> int:
    """The threads of the connected dask cluster's workers when the run starts (at least 1)."""
    from distributed import get_client

    workers = get_client().scheduler_info().get("workers", {})
    return max(1, sum(int(worker.get("nthreads", 1)) for worker in workers.values()))


def _worked_out(
    experiment: Experiment,
) -> tuple[list[CrlbKey], dict[tuple[int, int], PointInfo], list[dict[str, Any]]]:
    """The bound keys of the estimators, every point's scenario and CRLB and the rows of the
    points table, with the estimators and planners built: what can fail before a run."""
    crlb_keys = []
    for index, spec in enumerate(experiment.estimators):
        try:
            crlb_keys.append(crlb_key(estimator_of(spec)))
        except ValueError as error:
            raise ValueError(f"estimators[{index}]: {error}") from None
    for index, spec in enumerate(experiment.planners):
        try:
            planner_of(spec)
        except ValueError as error:
            raise ValueError(f"planners[{index}]: {error}") from None
    with warnings.catch_warnings(record=True) as caught:  # numpy's, on a point that fails
        try:
            infos = point_infos(experiment, crlb_keys)
            rows = point_rows(experiment, infos)
        except (ValueError, ArithmeticError) as error:
            with np.errstate(all="ignore"):
                raise _point_error(experiment, error) from None
    for warning in caught:  # the experiment can run: the caller sees them
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return crlb_keys, infos, rows


def _point_error(experiment: Experiment, error: Exception) -> ValueError:
    """The error of the first point that cannot be simulated (else ``error`` as it is)."""
    for i, name in enumerate(experiment.scenarios):
        for p, settings in enumerate(experiment.sweep.points()):
            try:
                scenario, snr_db = experiment.point_scenario(i, p)
                noise_free(scenario, snr_db=snr_db)
            except (ValueError, ArithmeticError) as failure:
                values = ", ".join(f"{key}={value:g}" for key, value in settings.items())
                return ValueError(
                    f"sweep: point {p} ({values}) of scenarios[{i}] ({name}) gives measurements "
                    f"that cannot be used ({failure}); change or drop that value"
                )
    return ValueError(f"sweep: the bounds of the points cannot be computed ({error})")
