"""The progress of a run on stderr: a bar on a terminal, else a line every tenth of the work
or minute (:class:`ProgressLog`), and :func:`duration_text`, a duration as a person reads it.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from contextlib import ExitStack

PROGRESS_FRACTION = 0.1
"""Without a terminal, a progress line each time another tenth of the work is done ..."""
PROGRESS_INTERVAL_S = 60.0
"""... or a minute after the last line, whichever comes first."""


class ProgressLog:
    """Progress as lines on stderr, for a run whose stderr is not a terminal (a batch job, CI,
    ``2> log``), where a progress bar would show nothing until the end.

    A first line when it starts; then, as work is reported done (:meth:`advance`), a line each
    time another ``fraction`` of the ``total`` is done or ``interval_s`` has passed since the
    last line, whichever comes first: ``progress: 480/1,200 trials (40%), 3.2 trials/s, about
    3 min 45 s left``; and a last line (:meth:`finish`). The rate and the time left count only
    the work done since the start (a resumed run's stored trials are not), on ``clock``, a
    function returning seconds (``time.monotonic``; a test passes its own).
    """

    def __init__(
        self,
        total: int,
        completed: int = 0,
        *,
        unit: str = "trials",
        clock: Callable[[], float] = time.monotonic,
        write: Callable[[str], None] | None = None,
        fraction: float = PROGRESS_FRACTION,
        interval_s: float = PROGRESS_INTERVAL_S,
    ) -> None:
        self.total, self.done, self.unit = total, completed, unit
        self.clock, self.interval_s = clock, interval_s
        self.write = write or _stderr_line
        self.step = max(1, math.ceil(fraction * total))
        self.next_mark = (completed // self.step + 1) * self.step
        self.started_done = completed
        self.started_s = self.last_line_s = self.last_done_s = clock()
        every = f"a line every {fraction:.0%} or {duration_text(interval_s)}"
        if completed >= total:
            self.write(f"progress: all {total:,} {unit} are done already; nothing to run")
        elif completed:
            self.write(
                f"progress: {completed:,}/{total:,} {unit} done already; running the other "
                f"{total - completed:,} ({every})"
            )
        else:
            self.write(f"progress: running {total:,} {unit} ({every})")

    def advance(self, n: int) -> None:
        """``n`` more done: a line when a mark or the interval is reached."""
        self.done += n
        now = self.last_done_s = self.clock()
        if self.done >= self.total:
            return  # the last line is finish's
        if self.done >= self.next_mark or now - self.last_line_s >= self.interval_s:
            self.next_mark = (self.done // self.step + 1) * self.step
            self.last_line_s = now
            rate = self._rate(now)
            left = (
                "time left unknown"
                if rate is None
                else f"about {duration_text((self.total - self.done) / rate)} left"
            )
            self.write(
                f"progress: {self.done:,}/{self.total:,} {self.unit} "
                f"({self.done / self.total:.0%}), {self._rate_text(rate)}, {left}"
            )

    def describe(self, text: str) -> None:
        """Nothing: the lines count the work, whatever it is."""

    def finish(self) -> None:
        """The last line: how much ran, in how long (until the last :meth:`advance`)."""
        if self.done == self.started_done:
            return
        ran, now = self.done - self.started_done, self.last_done_s
        self.write(
            f"progress: {self.done:,}/{self.total:,} {self.unit} done; {ran:,} ran in "
            f"{duration_text(now - self.started_s)}, {self._rate_text(self._rate(now))}"
        )

    def _rate(self, now: float) -> float | None:
        """Work per second since the start; None before any time has passed."""
        elapsed_s = now - self.started_s
        return (self.done - self.started_done) / elapsed_s if elapsed_s > 0 else None

    def _rate_text(self, rate: float | None) -> str:
        if rate is None:
            return "rate unknown"
        return f"{rate:,.0f} {self.unit}/s" if rate >= 100 else f"{rate:.3g} {self.unit}/s"


def _stderr_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def duration_text(seconds: float) -> str:
    """``under 1 s``, ``42 s``, ``3 min 05 s``, ``1 min``, ``2 h 07 min``: a duration as a
    person reads it."""
    whole = round(seconds)
    if whole < 1:
        return "under 1 s"
    if whole < 60:
        return f"{whole} s"
    if whole < 3600:
        minutes, rest = divmod(whole, 60)
        return f"{minutes} min" if rest == 0 else f"{minutes} min {rest:02d} s"
    hours, minutes = divmod(round(seconds / 60), 60)
    return f"{hours} h" if minutes == 0 else f"{hours} h {minutes:02d} min"


class ProgressBar:
    """A progress bar on stderr (a terminal), closed with the ``stack`` it is given."""

    def __init__(
        self, stack: ExitStack, *, total: int, completed: int, unit: str = "trials"
    ) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(unit),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(stderr=True),
        )
        stack.enter_context(self.progress)
        self.task_id = self.progress.add_task("running", total=total, completed=completed)

    def advance(self, n: int) -> None:
        self.progress.advance(self.task_id, n)

    def describe(self, text: str) -> None:
        """Show ``text`` before the bar (what is being worked on)."""
        self.progress.update(self.task_id, description=text)

    def finish(self) -> None:
        """Nothing to add: the bar shows the end itself."""


def progress_display(
    stack: ExitStack, *, total: int, completed: int = 0, unit: str = "trials"
) -> ProgressBar | ProgressLog:
    """The progress of the work on stderr: a bar on a terminal, else :class:`ProgressLog`
    lines. Its ``advance(n)`` counts ``unit`` done, ``describe(text)`` names what is being
    worked on (on the bar), ``finish()`` ends it."""
    if sys.stderr.isatty():
        return ProgressBar(stack, total=total, completed=completed, unit=unit)
    return ProgressLog(total, completed, unit=unit)


def progress_reporter(
    show: bool, stack: ExitStack, *, total: int, completed: int
) -> ProgressBar | ProgressLog | None:
    """The progress of a run's trials (:func:`progress_display`); None when not ``show``."""
    return progress_display(stack, total=total, completed=completed) if show else None
