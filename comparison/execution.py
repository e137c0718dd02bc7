"""Where tasks run: in this process, in local processes (joblib/loky), or on a dask cluster.

Local processes through joblib/loky by default (``workers`` defaults to ``os.cpu_count()``),
``workers=1`` in-process, or a dask cluster with ``scheduler="tcp://HOST:PORT"``
(``pip install 'emitterbench[cluster]'``; the workers need emitterbench installed too: a
task is a :class:`comparison.tasks.Task` and the function run is
:func:`comparison.tasks.run_task`). Results come back in completion order; rows never depend
on it. Also the progress bar on stderr.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack

from comparison.tasks import Task, TaskResult, run_task


def connect_scheduler(scheduler: str, stack: ExitStack) -> None:
    """Connect a dask client to ``scheduler`` and route joblib through it, or raise clearly."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError(
            f"scheduler: running on {scheduler} needs dask.distributed; install it with "
            "pip install 'emitterbench[cluster]' (and emitterbench on every worker)"
        ) from None
    from joblib import parallel_config

    try:
        stack.enter_context(Client(scheduler, timeout=30))
    except (OSError, TimeoutError) as error:
        raise ValueError(
            f"scheduler: cannot reach {scheduler} ({error}); start it with "
            "'dask scheduler --port 8786' and workers with 'dask worker tcp://HOST:8786'"
        ) from None
    stack.enter_context(parallel_config(backend="dask"))


def execute(tasks: list[Task], workers: int, scheduler: str | None) -> Iterator[TaskResult]:
    """Results in completion order: in-process, loky processes, or the connected dask cluster."""
    if not tasks:
        return iter(())
    if scheduler is None and workers == 1:
        return (run_task(task) for task in tasks)
    from joblib import Parallel, delayed

    # with a scheduler, parallel_config(backend="dask") is active and -1 means every worker
    n_jobs = -1 if scheduler is not None else min(workers, len(tasks))
    parallel = Parallel(n_jobs=n_jobs, return_as="generator_unordered")
    return parallel(delayed(run_task)(task) for task in tasks)


def progress_bar(
    enabled: bool, stack: ExitStack, *, total: int, completed: int
) -> Callable[[int], None] | None:
    """A progress bar of trials on stderr, closed with ``stack``: its ``advance(n)``, or None."""
    if not enabled:
        return None
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
    )
    stack.enter_context(progress)
    task_id = progress.add_task("running", total=total, completed=completed)
    return lambda n: progress.advance(task_id, n)
