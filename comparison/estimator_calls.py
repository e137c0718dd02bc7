"""How a run calls an estimator: timed, limited in time, and never raising for it.

Faults as data
    Whatever an estimator raises becomes a failed estimate (``success`` false, the reason in
    ``message``), so a fault costs its rows and never the run:

    - an exception: ``"RuntimeError: flaky on purpose"`` (a stream: ``"RuntimeError in init:
      ..."``);
    - any other ``BaseException`` (``SystemExit``, ``GeneratorExit``, one of its own):
      ``"the estimator raised SystemExit(3)"``;
    - a call longer than the time limit (below): ``"the estimate took longer than the limit of
      60 s (time_limit_s)"``.

    ``KeyboardInterrupt`` is never caught: Ctrl-C stops the run (the rows stored so far are
    kept for ``--resume``). A fault that ends the process itself (a segfault, ``os._exit``)
    cannot be caught in it; :mod:`comparison.execution` handles those.

Time limit
    Inside :func:`call_limits` (every task, ``Experiment.time_limit_s``) each call may take
    the limit (``estimate_columns``, ``estimate_batch``: the limit times the number of
    trials). In the main thread of a process (in-process runs, loky workers, the isolation
    processes of :mod:`comparison.execution`) ``signal.setitimer`` arms SIGALRM for the call,
    and the handler raises inside the estimator: that stops Python code and the blocking calls that
    return to Python on a signal (``time.sleep``, I/O, lock waits). C code that computes
    without returning to Python (a GTSAM solve, a long BLAS call) sees the alarm only when it
    returns; every call that returns later than the limit fails with the same message, so the
    row does not depend on how the overrun was noticed. A call that never returns to Python
    hangs its process, unless it runs isolated, where the supervisor stops it; an estimator
    that catches ``BaseException`` and carries on is likewise stopped only by returning. In
    another thread (a dask worker), or when SIGALRM or the real-time timer is in use by
    someone else, the limit is checked when the call returns. Cost: two ``setitimer`` calls,
    about 1.3 µs, per call.

Four ways to call
    - :func:`timed_call`, one call of ``estimate`` (or any estimator method);
    - :func:`call_columns`, ``estimate_columns`` on a whole chunk (the results as
      :class:`~estimators.batch.BatchEstimates`, no object per trial), or None when it fails
      or overruns;
    - :func:`call_batch`, ``estimate_batch`` on a whole chunk, or None when it fails or
      overruns (after either, the caller falls back to one call per trial, so that a row
      never depends on its neighbours);
    - :class:`Stream`, a sequential estimator (``init``/``update``/``estimate_state``) fed frame
      by frame, in the per-frame open loop (:mod:`comparison.tasks`) and in the closed loop
      (:mod:`comparison.closed_loop`) alike.

Isolation
    In an isolation process (:func:`comparison.execution.run_isolated`) a :class:`CallJournal`
    numbers the calls, reports each to the supervisor before and after it runs, and replaces
    the calls the supervisor names (those that ended an earlier process) by failures. Outside
    isolation there is none and it costs nothing.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import numpy as np

from estimators.base import Estimate, Estimator
from estimators.batch import BatchEstimates
from scenarios.types import MeasurementBatch, MeasurementSet


def limit_message(limit_s: float) -> str:
    """The message of a call that took longer than ``limit_s``."""
    return f"the estimate took longer than the limit of {limit_s:g} s (time_limit_s)"


class _TimeLimit(BaseException):
    """Raised inside an estimator by the SIGALRM handler, or noted when a call returns late."""


class _Replaced(BaseException):
    """A call the supervisor replaced by a failure (it ended an earlier process)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class CallJournal:
    """Isolation only: numbers every estimator call and reports it to the supervisor.

    Parameters
    ----------
    labels : mapping
        ``id(estimator object) → label``, to name the estimator of each call.
    replaced : mapping
        Call number → the message of the failure that replaces it.
    given_up : mapping
        Label → ``(number, message)``: the message replaces every call of that estimator
        numbered above ``number``.
    report : callable
        Sends ``("start", n, label, budget_s)`` before a call runs and ``("done",)`` after.
    """

    def __init__(
        self,
        labels: Mapping[int, str],
        replaced: Mapping[int, str],
        given_up: Mapping[str, tuple[int, str]],
        report: Callable[[tuple[Any, ...]], None],
    ) -> None:
        self._labels = labels
        self._replaced = replaced
        self._given_up = given_up
        self._report = report
        self._count = 0

    def begin(self, estimator: Any, budget_s: float | None) -> str | None:
        """Number a call of ``estimator``; the message that replaces it, or None after
        reporting it."""
        number = self._count
        self._count += 1
        label = self._labels.get(id(estimator), "")
        message = self._replaced.get(number)
        after, given_up = self._given_up.get(label, (number, None))
        if message is None and number > after:
            message = given_up
        if message is None:
            self._report(("start", number, label, budget_s))
        return message

    def end(self) -> None:
        self._report(("done",))


class _Settings(threading.local):
    """This thread's time limit, whether SIGALRM enforces it, and the journal (isolation)."""

    limit_s: float | None = None
    alarm: bool = False
    journal: CallJournal | None = None


_settings = _Settings()
_armed = False  # the main thread is inside an estimator call with the alarm set
_LONGEST_ALARM_S = 1e8  # setitimer overflows near 1e12 s; a longer budget is no limit at all


def _on_alarm(signum: int, frame: Any) -> None:
    global _armed
    if _armed:
        _armed = False  # once per call: the disarming code can never be interrupted
        raise _TimeLimit


@contextmanager
def call_limits(limit_s: float | None) -> Iterator[None]:
    """Limit every estimator call of this thread to ``limit_s`` seconds (None: no limit)."""
    previous = (_settings.limit_s, _settings.alarm)
    installed = None
    alarm = False
    if limit_s is not None and threading.current_thread() is threading.main_thread():
        handler = signal.getsignal(signal.SIGALRM)
        idle = signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
        if handler is _on_alarm:
            alarm = True
        elif handler in (signal.SIG_DFL, signal.SIG_IGN, None) and idle:
            installed = handler
            signal.signal(signal.SIGALRM, _on_alarm)
            alarm = True
    _settings.limit_s, _settings.alarm = limit_s, alarm
    try:
        yield
    finally:
        _settings.limit_s, _settings.alarm = previous
        if installed is not None:
            signal.signal(signal.SIGALRM, installed)


@contextmanager
def journal_calls(journal: CallJournal) -> Iterator[None]:
    """Route this thread's estimator calls through ``journal`` (isolation processes)."""
    previous, _settings.journal = _settings.journal, journal
    try:
        yield
    finally:
        _settings.journal = previous


def _guarded(
    method: Callable[..., Any],
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
    n_calls: int = 1,
    owner: Any = None,
) -> tuple[Any, BaseException | None, float]:
    """``(value, fault, runtime_s)`` of one call (worth ``n_calls`` estimates, of the estimator
    ``owner``, by default the method's); ``fault`` is whatever it raised, a
    :class:`_TimeLimit`, a :class:`_Replaced`, or None. Never catches KeyboardInterrupt."""
    global _armed
    limit_s = _settings.limit_s
    budget_s = None if limit_s is None else limit_s * n_calls
    journal = _settings.journal
    if journal is not None:
        message = journal.begin(
            getattr(method, "__self__", None) if owner is None else owner, budget_s
        )
        if message is not None:
            return None, _Replaced(message), 0.0
    alarm = _settings.alarm and budget_s is not None
    fault: BaseException | None = None
    value: Any = None
    start = time.perf_counter()
    try:
        try:
            if alarm:
                _armed = True
                signal.setitimer(signal.ITIMER_REAL, min(budget_s, _LONGEST_ALARM_S))
            value = method(*args, **kwargs)
        finally:
            if alarm:
                _armed = False
                signal.setitimer(signal.ITIMER_REAL, 0.0)
    except KeyboardInterrupt:
        raise
    except BaseException as error:  # the estimator's fault, whatever it is
        fault = error
    runtime_s = time.perf_counter() - start
    if fault is None and budget_s is not None and runtime_s > budget_s:
        value, fault = None, _TimeLimit()
    if journal is not None:
        journal.end()
    return value, fault, runtime_s


def fault_message(fault: BaseException, where: str | None = None) -> str:
    """The ``message`` of a failed estimate: an exception as ``"Type: text"`` (``"Type in
    init: text"``), anything else as a sentence (with ``" in init"``)."""
    if isinstance(fault, Exception):
        kind = type(fault).__name__ if where is None else f"{type(fault).__name__} in {where}"
        return f"{kind}: {fault}"
    if isinstance(fault, _Replaced):
        sentence = fault.message
    elif isinstance(fault, _TimeLimit):
        sentence = limit_message(_settings.limit_s or 0.0)
    else:
        sentence = f"the estimator raised {fault!r}"
    return sentence if where is None else f"{sentence} in {where}"


def timed_call(method: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Estimate, float]:
    """Call an estimator method; a fault or a non-Estimate becomes a failed estimate."""
    estimate, fault, runtime_s = _guarded(method, args, kwargs)
    if fault is not None:
        return Estimate.failed("", fault_message(fault)), runtime_s
    if not isinstance(estimate, Estimate):
        estimate = Estimate.failed(
            "", f"TypeError: returned {type(estimate).__name__}, not an Estimate"
        )
    return estimate, runtime_s


def call_batch(
    estimator: Estimator, batch: MeasurementBatch, rngs: list[np.random.Generator]
) -> list[tuple[Estimate, float]] | None:
    """``estimate_batch`` timed and split evenly, or None (it failed or overran)."""

    def estimate_batch() -> list[Any]:
        return list(estimator.estimate_batch(batch, rngs=rngs))

    estimates, fault, runtime_s = _guarded(estimate_batch, (), {}, batch.n_trials, estimator)
    if fault is not None:
        return None  # retried one trial at a time, so each row gets its own outcome
    if len(estimates) != batch.n_trials or not all(isinstance(e, Estimate) for e in estimates):
        return None
    return [(estimate, runtime_s / batch.n_trials) for estimate in estimates]


def call_columns(
    estimator: Estimator, batch: MeasurementBatch, rngs: list[np.random.Generator]
) -> tuple[BatchEstimates, float] | None:
    """``estimate_columns`` timed, with each trial's share of the time, or None (it failed,
    overran, or returned something else than one row of :class:`BatchEstimates` per trial)."""

    def estimate_columns() -> Any:
        return estimator.estimate_columns(batch, rngs=rngs)  # type: ignore[attr-defined]

    columns, fault, runtime_s = _guarded(estimate_columns, (), {}, batch.n_trials, estimator)
    if fault is not None or not isinstance(columns, BatchEstimates):
        return None  # retried one trial at a time, so each row gets its own outcome
    if len(columns) != batch.n_trials:
        return None
    return columns, runtime_s / batch.n_trials


class Stream:
    """A sequential estimator fed frame by frame: ``init`` now, then :meth:`step` per frame.

    A failed ``init`` fails every frame; a failed ``update`` fails that frame and every later
    one (the state is lost); a failed ``estimate_state`` fails only its frame. ``init``'s time
    is counted in the first frame. Each of the three calls has the time limit.
    """

    def __init__(self, estimator: Any) -> None:
        self._estimator = estimator
        self._failure: Estimate | None = None
        self._state, fault, self._carried_s = _guarded(
            lambda: estimator.init(), (), {}, 1, estimator
        )
        if fault is not None:
            self._failure = Estimate.failed("", fault_message(fault, "init"))

    def step(
        self, frame_data: MeasurementSet, rng: np.random.Generator | None
    ) -> tuple[Estimate, float]:
        """``update`` with the samples of the next frame, then ``estimate_state(rng=rng)``.

        Returns the frame's ``(estimate, runtime_s)``.
        """
        carried_s, self._carried_s = self._carried_s, 0.0
        if self._failure is not None:
            return self._failure, carried_s
        estimator, previous = self._estimator, self._state
        state, fault, update_s = _guarded(
            lambda: estimator.update(previous, frame_data), (), {}, 1, estimator
        )
        if fault is not None:
            self._failure = Estimate.failed("", fault_message(fault, "update"))
            return self._failure, carried_s + update_s
        self._state = state
        estimate, estimate_s = timed_call(self._estimator.estimate_state, self._state, rng=rng)
        return estimate, carried_s + update_s + estimate_s
