"""An experiment end to end (``paper-fig2`` unless ``--experiment``): the wall time of its
rows and of its report, apart.

- ``rows``: :func:`comparison.engine.run_experiment` of the built-in ``paper-fig2`` (3
  scenarios × 9 SNR points × 500 trials, 7 estimators: 94,500 estimates) on ``--workers``
  worker processes (default 2) into a fresh folder, without the report; printed with the
  trials per task the run used (``chunk_size``, ``"auto"`` unless ``--chunk-size N``: the
  fixed 25 of earlier versions for comparison);
- ``report``: :func:`comparison.report.write_report` of that folder (summary.csv,
  thresholds.csv, trials.csv, twelve figure files, report.html), after the run's idle worker
  pool is shut down as ``emitterbench run`` does before its report
  (:func:`comparison.execution.release_workers`: a process that forks runs no other thread),
  with trials.csv and the figures written in forked processes as the report does
  (``--serial-figures``: drawn one after another here),
  and the time spent in the figures alone (:func:`comparison.report_figures.write_figures`,
  the trials.csv it overlaps included).

Each is run ``--repeats`` times (default 3), each time into a new folder, and the best wall
time is printed with the machine's load average (1 min) before and after: on a shared
machine the times are only comparable at similar loads. Beside the rows' wall time, the time
the tasks took in the workers (``task_time_s`` of ``run.json``); beside the report's, its CPU
time, of this process and of the figure processes it ended (``RUSAGE_CHILDREN``): the work
done, which other processes on the machine change less. The rows of the repeats are checked
to be equal (``runtime_s`` and the diagnostics' timings aside).

With ``--command``, each repeat also runs ``emitterbench run EXPERIMENT -o DIR --workers N``
as a command (a new process, as a user runs it) and splits its wall time into the start-up
(from the command's start to the start of the first task in a worker: the imports, the
bounds and the workers' own start), the rows (the first task's start to the last row
stored, ``run.json``) and the report (the last row stored to the command's end), with the
CPU time of the command and every process it waited for.

Run: ``python benchmarks/bench_speed.py [--experiment paper-fig2] [--workers 2] [--repeats 3]
[--chunk-size N] [--serial-figures] [--command]`` (``--experiment noncooperative``: the
non-cooperative emitters, where the filters with unknowns dominate).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import pandas as pd

import comparison.report_figures as report_figures
from comparison.engine import read_trials, run_experiment
from comparison.execution import release_workers
from comparison.experiment import builtin_experiment
from comparison.report import write_report
from comparison.run_folder import read_experiment

TIMED_KEYS = ("runtime_s", "diagnostics_json")
"""Columns that hold timings (the diagnostics carry solver times), left out of the check."""


def cpu_s() -> float:
    """CPU time of this process and of its ended children (user and system), s."""
    mine = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return mine.ru_utime + mine.ru_stime + children.ru_utime + children.ru_stime


def timed_rows(experiment, folder: Path, workers: int) -> tuple[float, float]:
    """The rows' wall time and the tasks' time in the workers (run.json's task_time_s)."""
    start = time.perf_counter()
    run_experiment(experiment, folder, workers=workers, progress=False)
    wall_s = time.perf_counter() - start
    return wall_s, json.loads((folder / "run.json").read_text())["sessions"][-1]["task_time_s"]


def timed_report(folder: Path) -> tuple[float, float, float]:
    """The report's wall time, its CPU time, and the wall time of its figures (trials.csv
    meanwhile included)."""
    spent = []
    write_figures = report_figures.write_figures

    def watched(*args, **kwargs):
        start = time.perf_counter()
        try:
            return write_figures(*args, **kwargs)
        finally:
            spent.append(time.perf_counter() - start)

    report_figures.write_figures = watched
    try:
        start = time.perf_counter()
        release_workers()  # as run_experiment before its report (the workers' CPU not counted)
        cpu = cpu_s()
        write_report(folder)
        return time.perf_counter() - start, cpu_s() - cpu, sum(spent)
    finally:
        report_figures.write_figures = write_figures


def timed_command(experiment: str, folder: Path, workers: int) -> dict[str, float]:
    """``emitterbench run`` as a command: its start-up, rows, report and total wall time, s,
    and its CPU time (with the processes it waited for)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start_utc = time.time()
    start = time.perf_counter()
    command = [sys.executable, "-m", "comparison.cli", "run", experiment, "-o", str(folder)]
    subprocess.run([*command, "--workers", str(workers)], check=True, capture_output=True)
    total_s = time.perf_counter() - start
    end_utc = start_utc + total_s
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    session = json.loads((folder / "run.json").read_text())["sessions"][-1]
    finished_utc = datetime.fromisoformat(session["finished_utc"]).timestamp()
    with sqlite3.connect(folder / "results.sqlite") as connection:  # each task as stored
        tasks = connection.execute("SELECT finished_utc, elapsed_s FROM tasks").fetchall()
    first_utc = min(datetime.fromisoformat(done).timestamp() - took for done, took in tasks)
    return {
        "start-up": first_utc - start_utc,
        "rows": finished_utc - first_utc,
        "report": end_utc - finished_utc,
        "total": total_s,
        "CPU": sum(getattr(after, f) - getattr(before, f) for f in ("ru_utime", "ru_stime")),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="paper-fig2", help="a built-in experiment")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--chunk-size", type=int, help="trials per task instead of auto")
    parser.add_argument("--serial-figures", action="store_true")
    parser.add_argument("--command", action="store_true", help="also time emitterbench run")
    options = parser.parse_args()
    experiment = builtin_experiment(options.experiment)
    if options.chunk_size is not None:
        experiment = dataclasses.replace(experiment, chunk_size=options.chunk_size)
    if options.serial_figures:
        report_figures.figure_processes = lambda n_figures: 1
    scratch = Path(tempfile.mkdtemp(prefix="bench_speed_"))
    best = dict.fromkeys(("rows", "tasks", "report", "report cpu", "figures"), float("inf"))
    best_command = dict.fromkeys(("start-up", "rows", "report", "total", "CPU"), float("inf"))
    reference = None
    load_before = os.getloadavg()[0]
    try:
        for repeat in range(options.repeats):
            folder = scratch / f"run{repeat}"
            rows_s, tasks_s = timed_rows(experiment, folder, options.workers)
            report_s, report_cpu_s, figures_s = timed_report(folder)
            rows = read_trials(folder).drop(columns=list(TIMED_KEYS))
            if reference is None:
                reference = rows
                chunk_size = read_experiment(folder).chunk_size
            else:
                pd.testing.assert_frame_equal(rows, reference)
            print(
                f"repeat {repeat + 1}: rows {rows_s:6.2f} s (tasks {tasks_s:6.2f} s), report "
                f"{report_s:5.2f} s (CPU {report_cpu_s:5.2f} s, figures {figures_s:5.2f} s), "
                f"load {os.getloadavg()[0]:.2f}",
                flush=True,
            )
            for key, seconds in zip(
                best, (rows_s, tasks_s, report_s, report_cpu_s, figures_s), strict=True
            ):
                best[key] = min(best[key], seconds)
            shutil.rmtree(folder)
            if options.command:
                phases = timed_command(options.experiment, folder, options.workers)
                print(
                    "  command: "
                    + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in phases.items())
                    + f", load {os.getloadavg()[0]:.2f}",
                    flush=True,
                )
                for name, seconds in phases.items():
                    best_command[name] = min(best_command[name], seconds)
                shutil.rmtree(folder)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    print(
        f"\n{options.experiment} on {options.workers} workers, chunk_size {chunk_size} "
        f"({'set' if options.chunk_size else 'auto'}), figures "
        f"{'here' if options.serial_figures else 'in worker processes'}; best of "
        f"{options.repeats} (load average {load_before:.2f} before, "
        f"{os.getloadavg()[0]:.2f} after):\n"
        f"  rows       {best['rows']:6.2f} s   (tasks {best['tasks']:6.2f} s)\n"
        f"  report     {best['report']:6.2f} s   (CPU {best['report cpu']:6.2f} s; figures and "
        f"trials.csv {best['figures']:.2f} s)\n"
        f"  end to end {best['rows'] + best['report']:6.2f} s"
    )
    if options.command:
        print(
            f"emitterbench run {options.experiment} --workers {options.workers} (best of "
            f"{options.repeats}, each phase apart):\n"
            + "".join(f"  {name:<10} {seconds:6.2f} s\n" for name, seconds in best_command.items())
        )


if __name__ == "__main__":
    main()
