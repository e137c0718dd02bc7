"""Wall time of every stage of ``write_report``, for paper-fig2 and for a dense geometry map.

The stages, in the order ``write_report`` meets them:

- ``read store``: experiment.json, the point rows of results.sqlite, run.json;
- ``summarize``: :func:`comparison.metrics.summarize_chunks` of the trial rows, their reading
  from results.sqlite (``  read trials`` below it: the summary's columns and the figures') and
  the bootstrap intervals (``comparison.metric_groups``; ``  bootstrap``) included;
- ``thresholds``, ``summary.csv``, ``thresholds.csv``, ``trials.csv`` (every column read
  again a batch at a time: ``  read trials`` below it);
- ``draw <figure>`` and ``save <figure>`` (PNG and SVG) for every figure of the report;
- ``notes`` (the first screen's sentences), ``html`` (the page) and ``write report.html``;
- ``other``: what ``write_report`` spends outside the stages above.

A stage called inside another (the verdict table computes the thresholds again) counts in
the outer one. The figures are drawn in this process, one after another, so that each is
timed (the report draws them in worker processes: ``benchmarks/bench_speed.py``). Each stage
is timed by wrapping the function ``write_report`` calls, so the report written is the
ordinary one. The runs are the built-ins ``paper-fig2`` (500 trials per
point, 7 estimators, 27 points) and ``geometry-map-dense`` (10,000 points, 2 estimators,
100 trials), run once into ``--fig2`` and ``--dense`` (2 workers) unless those folders
already hold a finished run; each report is then written ``--repeats`` times and the best
time of every stage kept.

Each stage's CPU time (this process's, every thread) is printed beside its wall time: the
work done, which other processes on a shared machine change less. The machine's load
average (1 min) is printed before and after each report: on a shared machine the wall
times are only comparable at similar loads.

Run: ``python benchmarks/bench_report.py [--fig2 DIR] [--dense DIR] [--only fig2|dense]``.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

import comparison.report as report
import comparison.report_figures as report_figures
from comparison import figures, metric_groups, verdict_table
from comparison.engine import run_experiment
from comparison.experiment import load_experiment

EXPERIMENTS = {"fig2": "paper-fig2", "dense": "geometry-map-dense"}


class StageClock:
    """Wall and CPU time per stage (``seconds``, ``cpu_seconds``; the CPU of every thread of
    this process, the bootstrap's included); a stage entered inside another counts in the
    outer one only."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.cpu_seconds: dict[str, float] = defaultdict(float)
        self.depth = 0
        self.outer = ""
        self.nested: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))

    @contextlib.contextmanager
    def stage(self, name: str, *, nested: bool = False) -> Iterator[None]:
        """Time the block as ``name``; with ``nested``, also inside another stage (kept under
        that stage's name)."""
        outer = self.depth == 0
        if outer:
            self.outer = name
        self.depth += 1
        start, start_cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            elapsed = time.perf_counter() - start
            self.depth -= 1
            if outer:
                self.seconds[name] += elapsed
                self.cpu_seconds[name] += time.process_time() - start_cpu
            elif nested:
                self.nested[self.outer][name] += elapsed

    def wrap(self, function: Callable[..., Any], name: Callable[..., str] | str, **kw) -> Any:
        @functools.wraps(function)
        def timed(*args: Any, **kwargs: Any) -> Any:
            label = name(*args, **kwargs) if callable(name) else name
            with self.stage(label, **kw):
                return function(*args, **kwargs)

        return timed

    def wrap_iterator(self, function: Callable[..., Iterator[Any]], name: str) -> Any:
        """``function`` returning an iterator whose every step is timed as ``name``."""

        @functools.wraps(function)
        def timed(*args: Any, **kwargs: Any) -> Iterator[Any]:
            iterator = iter(function(*args, **kwargs))
            while True:
                with self.stage(name, nested=True):
                    item = next(iterator, StopIteration)
                if item is StopIteration:
                    return
                yield item

        return timed


@contextlib.contextmanager
def patched(clock: StageClock) -> Iterator[None]:
    """Wrap the functions ``write_report`` calls in the clock's stages."""
    import comparison.intervals as intervals
    import comparison.store as store

    replacements: list[tuple[Any, str, Any]] = [
        (report_figures, "figure_processes", lambda n_figures: 1),
        (report, "_load", clock.wrap(report._load, "read store")),
        (report, "summarize", clock.wrap(report.summarize, "summarize")),
        (report, "summarize_chunks", clock.wrap(report.summarize_chunks, "summarize")),
        (store, "iter_trials", clock.wrap_iterator(store.iter_trials, "  read trials")),
        (
            metric_groups,
            "studentized_bootstrap_interval",
            clock.wrap(intervals.studentized_bootstrap_interval, "  bootstrap", nested=True),
        ),
        (verdict_table, "thresholds", clock.wrap(verdict_table.thresholds, "thresholds")),
        (
            report,
            "write_csv",
            clock.wrap(report.write_csv, lambda path, *_a, **_k: Path(path).name),
        ),
        (
            figures,
            "save_figure",
            clock.wrap(figures.save_figure, lambda _f, _d, stem, **_k: f"save {stem}"),
        ),
        (
            verdict_table,
            "first_screen_notes",
            clock.wrap(verdict_table.first_screen_notes, "notes"),
        ),
        (report, "render_html", clock.wrap(report.render_html, "html")),
        (report, "write_atomic", clock.wrap(report.write_atomic, "write report.html")),
    ]
    for attribute in figures.__all__:
        if attribute.endswith("_figure") and attribute != "save_figure":
            function = getattr(figures, attribute)
            label = f"draw {attribute.removesuffix('_figure')}"
            replacements.append((figures, attribute, clock.wrap(function, label)))
    saved = [(owner, attribute, getattr(owner, attribute)) for owner, attribute, _ in replacements]
    try:
        for owner, attribute, value in replacements:
            setattr(owner, attribute, value)
        yield
    finally:
        for owner, attribute, value in saved:
            setattr(owner, attribute, value)


def ensure_run(folder: Path, experiment: str) -> Path:
    """A finished run of ``experiment`` in ``folder``, run now (2 workers) when absent."""
    if (folder / "results.sqlite").is_file() and (folder / "run.json").is_file():
        return folder
    start = time.perf_counter()
    run_experiment(load_experiment(experiment), folder, workers=2, progress=False)
    print(f"ran {experiment} into {folder} in {time.perf_counter() - start:.1f} s")
    return folder


def time_report(
    folder: Path, repeats: int
) -> tuple[dict[str, float], dict[str, float], dict[str, dict[str, float]], float, float]:
    """The best wall and CPU time of every stage, the best wall time of the stages timed
    inside them (reading the trials, the bootstrap), and the best wall and CPU time of the
    whole report."""
    best: dict[str, float] = {}
    best_cpu: dict[str, float] = {}
    best_nested: dict[str, dict[str, float]] = defaultdict(dict)
    best_total = best_total_cpu = float("inf")
    for _ in range(repeats):
        clock = StageClock()
        with patched(clock):
            start, start_cpu = time.perf_counter(), time.process_time()
            report.write_report(folder)
            total, total_cpu = time.perf_counter() - start, time.process_time() - start_cpu
        clock.seconds["other"] = total - sum(clock.seconds.values())
        clock.cpu_seconds["other"] = total_cpu - sum(clock.cpu_seconds.values())
        for name, seconds in clock.seconds.items():
            best[name] = min(best.get(name, float("inf")), seconds)
            best_cpu[name] = min(best_cpu.get(name, float("inf")), clock.cpu_seconds[name])
        for outer, inner in clock.nested.items():
            for name, seconds in inner.items():
                best_nested[outer][name] = min(best_nested[outer].get(name, np.inf), seconds)
        best_total = min(best_total, total)
        best_total_cpu = min(best_total_cpu, total_cpu)
    return best, best_cpu, best_nested, best_total, best_total_cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fig2", type=Path, help="run folder of paper-fig2 (run if absent)")
    parser.add_argument("--dense", type=Path, help="run folder of geometry-map-dense")
    parser.add_argument("--only", choices=sorted(EXPERIMENTS), action="append")
    parser.add_argument("--repeats", type=int, default=2)
    options = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="bench_report_"))
    for key in options.only or list(EXPERIMENTS):
        folder = getattr(options, key) or scratch / key
        ensure_run(folder, EXPERIMENTS[key])
        load_before = os.getloadavg()[0]
        stages, stages_cpu, nested, total, total_cpu = time_report(folder, options.repeats)
        print(
            f"\n{EXPERIMENTS[key]} ({folder}): write_report {total:.2f} s, CPU {total_cpu:.2f} s "
            f"(best of {options.repeats}; load average {load_before:.2f} before, "
            f"{os.getloadavg()[0]:.2f} after)\n  {'stage':<28} {'wall':>10} {'CPU':>10}"
        )
        for name, seconds in stages.items():
            print(f"  {name:<28} {seconds:8.3f} s {stages_cpu[name]:8.3f} s")
            for inner, inner_seconds in nested.get(name, {}).items():
                print(f"  {inner:<28} {inner_seconds:8.3f} s")


if __name__ == "__main__":
    main()
