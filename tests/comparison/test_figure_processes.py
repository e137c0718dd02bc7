"""The report's figures drawn in worker processes: the files of one process, errors raised."""

from __future__ import annotations

import dataclasses
import threading

import pytest

import comparison.report_figures as report_figures
from comparison.engine import run_experiment
from comparison.execution import release_workers
from comparison.experiment import load_experiment
from comparison.metrics import summarize
from comparison.report_figures import figure_plans, figure_processes, write_figures
from tests.comparison.test_report import synthetic_run


@pytest.fixture(scope="module")
def plans():
    trials, points, _ = synthetic_run([{"snr_db": s} for s in (0.0, 10.0, 20.0)], n_trials=30)
    return figure_plans(summarize(trials, n_bootstrap=50), trials, points, None)


def files(folder) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


@pytest.mark.bits("the same figure calls on the same rows, in a forked process and here")
def test_figures_drawn_in_workers_are_the_bytes_of_one_process(plans, tmp_path, monkeypatch):
    """Two workers draw the SNR sweep's figures while this process runs ``meanwhile``; the
    files equal those drawn here one after another, and the PNG paths come back in the
    plans' order with their captions."""
    assert len(plans) >= 4  # efficiency, rmse, wrong side, error CDF, run time
    monkeypatch.setattr(report_figures, "figure_processes", lambda n: 2)
    called = []
    made = write_figures(plans, tmp_path / "two", meanwhile=lambda: called.append(True))
    assert called == [True]
    assert [(stem, caption) for stem, caption, _ in made] == [(s, c) for s, c, _ in plans]
    assert [path.name for _, _, path in made] == [f"{stem}.png" for stem, _, _ in plans]
    monkeypatch.setattr(report_figures, "figure_processes", lambda n: 1)
    write_figures(plans, tmp_path / "one", meanwhile=lambda: called.append(True))
    assert called == [True, True]
    assert files(tmp_path / "two") == files(tmp_path / "one")
    assert len(files(tmp_path / "one")) == 2 * len(plans)


def test_an_error_in_a_worker_s_figure_is_raised_here(plans, tmp_path, monkeypatch):
    def broken():
        raise ValueError("no such column: error_m")

    monkeypatch.setattr(report_figures, "figure_processes", lambda n: 2)
    with pytest.raises(ValueError, match="no such column: error_m"):
        write_figures([*plans[:1], ("broken", "a caption", broken)], tmp_path)
    assert not [p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]


def test_one_figure_or_another_thread_keeps_the_figures_here():
    assert figure_processes(1) == 1
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:
        assert figure_processes(6) == 1  # a fork would copy the other thread's state
    finally:
        release.set()
        other.join()


def test_a_run_on_worker_processes_hands_its_report_a_process_of_one_thread(tmp_path):
    """The pool a run keeps for the next one is shut down before its report, which forks
    (threads of other tests, if any, aside)."""
    release_workers()  # an earlier test's pool
    before = threading.active_count()
    seen = []
    experiment = dataclasses.replace(load_experiment("smoke"), trials=4)
    run_experiment(
        experiment,
        tmp_path / "run",
        workers=2,
        progress=False,
        write_report=lambda out: seen.append(threading.active_count()),
    )
    assert seen == [before]
