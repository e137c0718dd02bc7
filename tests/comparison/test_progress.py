"""Progress without a terminal: a line every tenth of the work or minute, driven by a fake clock."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from comparison.progress import (
    PROGRESS_FRACTION,
    PROGRESS_INTERVAL_S,
    ProgressLog,
    duration_text,
)

REPO_ROOT = Path(__file__).resolve().parents[2]
CONSOLE = (sys.executable, "-c", "from comparison.cli import main; main()")


class FakeClock:
    """The times a test lists, one per reading; reading past the end is a test error."""

    def __init__(self, *times_s: float) -> None:
        self.times: Iterator[float] = iter(times_s)

    def __call__(self) -> float:
        return next(self.times)


def log_of(total: int, completed: int, *times_s: float) -> tuple[ProgressLog, list[str]]:
    lines: list[str] = []
    log = ProgressLog(total, completed, clock=FakeClock(*times_s), write=lines.append)
    return log, lines


def test_the_defaults_are_a_tenth_and_a_minute() -> None:
    assert (PROGRESS_FRACTION, PROGRESS_INTERVAL_S) == (0.1, 60.0)


def test_a_line_each_tenth_of_the_trials_with_rate_and_time_left() -> None:
    # 200 trials, 5 per task at 1 s each: a line at 20, 40, ... (every tenth), then the last
    times = [100.0 + t for t in range(41)]
    log, lines = log_of(200, 0, *times)
    assert lines == ["progress: running 200 trials (a line every 10% or 1 min)"]
    for _ in range(40):
        log.advance(5)
    log.finish()
    assert len(lines) == 1 + 9 + 1  # the first line, 10% ... 90%, the last line
    assert lines[1] == "progress: 20/200 trials (10%), 5 trials/s, about 36 s left"
    assert lines[5] == "progress: 100/200 trials (50%), 5 trials/s, about 20 s left"
    assert lines[9] == "progress: 180/200 trials (90%), 5 trials/s, about 4 s left"
    assert lines[10] == "progress: 200/200 trials done; 200 ran in 40 s, 5 trials/s"


def test_a_line_a_minute_when_a_tenth_takes_longer() -> None:
    # 1,000 trials, one per 25 s: a tenth would take 2,500 s; a line every minute instead
    log, lines = log_of(1000, 0, 0.0, 25.0, 50.0, 75.0, 100.0, 125.0, 150.0)
    for _ in range(6):
        log.advance(1)
    assert lines[1:] == [
        "progress: 3/1,000 trials (0%), 0.04 trials/s, about 6 h 55 min left",  # at 75 s
        "progress: 6/1,000 trials (1%), 0.04 trials/s, about 6 h 54 min left",  # at 150 s
    ]


def test_a_resumed_run_counts_only_what_runs_now() -> None:
    # 600 of 1,000 stored; 400 more at 10 per second: the rate is 10/s, not (600 + n)/t
    log, lines = log_of(1000, 600, 0.0, 10.0, 20.0, 30.0, 40.0)
    for _ in range(4):
        log.advance(100)
    log.finish()
    assert lines == [
        "progress: 600/1,000 trials done already; running the other 400 "
        "(a line every 10% or 1 min)",
        "progress: 700/1,000 trials (70%), 10 trials/s, about 30 s left",
        "progress: 800/1,000 trials (80%), 10 trials/s, about 20 s left",
        "progress: 900/1,000 trials (90%), 10 trials/s, about 10 s left",
        "progress: 1,000/1,000 trials done; 400 ran in 40 s, 10 trials/s",
    ]


def test_a_finished_run_says_there_is_nothing_to_run() -> None:
    log, lines = log_of(20, 20, 0.0)
    log.finish()
    assert lines == ["progress: all 20 trials are done already; nothing to run"]


def test_a_task_that_jumps_several_tenths_gives_one_line() -> None:
    log, lines = log_of(100, 0, 0.0, 2.0, 3.0)
    log.advance(35)  # past 10%, 20% and 30%: one line, next mark 40%
    log.advance(4)  # 39%: below the mark, within the minute
    assert lines[1:] == ["progress: 35/100 trials (35%), 17.5 trials/s, about 4 s left"]


def test_no_rate_before_the_clock_moves() -> None:
    log, lines = log_of(10, 0, 5.0, 5.0)
    log.advance(1)
    assert lines[1] == "progress: 1/10 trials (10%), rate unknown, time left unknown"


@pytest.mark.parametrize(
    ("seconds", "text"),
    [
        (0.2, "under 1 s"),
        (42.4, "42 s"),
        (60.0, "1 min"),
        (185.0, "3 min 05 s"),
        (3600.0, "1 h"),
        (7620.0, "2 h 07 min"),
    ],
)
def test_durations_read_as_a_person_says_them(seconds: float, text: str) -> None:
    assert duration_text(seconds) == text


def test_run_with_stdout_piped_writes_progress_lines_on_stderr(tmp_path: Path) -> None:
    out = tmp_path / "run"
    done = subprocess.run(
        [*CONSOLE, "run", "smoke", "-o", str(out), "--trials", "3", "--workers", "1"],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    # stdout: only what a script reads
    assert done.stdout.splitlines() == [
        f"report: {out / 'report.html'}",
        f"tables: {out / 'summary.csv'}, {out / 'trials.csv'}",
    ]
    lines = done.stderr.splitlines()
    total = 3 * 2  # 3 trials at each of the smoke run's 2 points
    assert lines[0] == f"progress: running {total} trials (a line every 10% or 1 min)"
    assert lines[-1].startswith(f"progress: {total}/{total} trials done; {total} ran in ")
    middle = lines[1:-1]
    assert middle and all(line.startswith("progress: ") for line in middle)
    assert all(" trials/s, about " in line or "unknown" in line for line in middle)
