"""trials.csv: every trial row of a run as text, written from results.sqlite.

:func:`trials_csv_forked` writes the file in a forked process started at once, so that its
reading and formatting overlap the report's summary (:func:`comparison.report.write_report`),
and makes sure no process outlives the report; where no second process pays or can be forked,
the report writes it itself from :func:`trial_batches`. A run of more rows than
:data:`MAX_TRIALS_CSV_ROWS` keeps them in results.sqlite only, and the report says so
(:func:`trials_csv_note`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import pandas as pd

from comparison.run_folder import write_csv

MAX_TRIALS_CSV_ROWS = 1_000_000
"""Most trial rows written to trials.csv (``EMITTERBENCH_MAX_TRIALS_CSV_ROWS``): about 500 MB of
text and 10 s of formatting. A larger run (a dense geometry map) keeps its rows in
results.sqlite only, which :func:`comparison.engine.read_trials` reads."""

TRIALS_CSV_LIMIT = (MAX_TRIALS_CSV_ROWS, "EMITTERBENCH_MAX_TRIALS_CSV_ROWS")
"""The limit and the environment variable that raises it (``scenarios.limits``)."""


def trial_batches(run_dir: Path) -> Iterator[pd.DataFrame]:
    """Every trial row of results.sqlite, every column, a batch at a time."""
    from comparison import store

    return store.iter_trials(run_dir, chunk_rows=store.TRIAL_BATCH_ROWS, whole_points=False)


def _write_in_process(folder: Path, sender: Any) -> None:
    """Write trials.csv from results.sqlite, in a process of :func:`trials_csv_forked`;
    send None when done, else the error."""
    try:
        write_csv(folder / "trials.csv", trial_batches(folder))
    except BaseException as error:  # a Ctrl-C too: the report sees it
        try:
            sender.send(error)
        except Exception:  # an error that does not pickle: its text
            sender.send(RuntimeError(f"trials.csv: {error}"))
    else:
        sender.send(None)
    finally:
        sender.close()


@contextmanager
def trials_csv_forked(folder: Path, start: bool) -> Iterator[Callable[[], None] | None]:
    """With ``start``, write trials.csv from results.sqlite in a forked process started now,
    so that it overlaps the summary: the block gets the function that waits for it (and
    raises its error here), and the block's end waits for it in any case, so that no process
    is left behind. None when not started, or when a second process does not pay or cannot
    be forked (:func:`comparison.report_figures.figure_processes`)."""
    from comparison.report_figures import figure_processes

    if not start or figure_processes(2) < 2:
        yield None
        return
    context = get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(target=_write_in_process, args=(folder, sender), daemon=True)
    process.start()
    sender.close()
    outcome: list[BaseException | None] = []

    def wait() -> None:
        if not outcome:
            try:
                error = receiver.recv()
            except EOFError:  # ended without a word
                error = None
            finally:
                process.join()
                receiver.close()
            if error is None and process.exitcode != 0:  # killed
                error = RuntimeError(
                    f"trials.csv: the process writing it ended with code {process.exitcode}; "
                    "run emitterbench report again"
                )
            outcome.append(error)
        if outcome[0] is not None:
            raise outcome[0]

    try:
        yield wait
    except BaseException:
        with suppress(BaseException):  # the block's error is the one to see
            wait()
        raise
    wait()


def trials_csv_note(n_rows: int, limit: int) -> str:
    """The sentence of a report whose trial rows are too many for trials.csv."""
    return (
        f"trials.csv is not written: this run has {n_rows:,} trial rows, more than the "
        f"{limit:,} written as text ({TRIALS_CSV_LIMIT[1]}). Every row is in results.sqlite, "
        "which comparison.engine.read_trials reads; to have the file, raise the limit and "
        "run emitterbench report again."
    )
