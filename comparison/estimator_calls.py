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
    - :func:`timed_call`, one call of an estimator method (:func:`call_estimate`: of
      ``estimate``, on a copy of the data);
    - :func:`call_columns`, ``estimate_columns`` on a whole chunk (the results as
      :class:`~estimators.batch.BatchEstimates`, no object per trial), or None when it fails
      or overruns;
    - :func:`call_batch`, ``estimate_batch`` on a whole chunk, or None when it fails or
      overruns (after either, the caller falls back to one call per trial, so that a row
      never depends on its neighbours);
    - :class:`Stream`, a sequential estimator (``init``/``update``/``estimate_state``) fed frame
      by frame, in the per-frame open loop (:mod:`comparison.tasks`) and in the closed loop
      (:mod:`comparison.closed_loop`) alike.

The data an estimator is given
    No estimator can change the data another one sees. Every call gets its own copy of its
    data (:func:`private_copy`: the arrays, the geometry, the noise and RSS model; the numbers
    and names, which cannot change, shared), made from the task's data, which no estimator is
    ever given. After the call the copy is compared with them, bit for bit
    (:func:`changed_field`); if the estimator changed anything (``object.__setattr__``, an
    array made writeable through its ``.base`` then written, another type or shape), every
    estimate of the call fails with ``"the estimator changed the data it was given
    (doppler_hz)"`` (the first field that differs, ``geometry.noise.toa_s`` for a part), which
    takes precedence over what the call raised; a failed batch call is then not retried one
    trial at a time; a stream's ``update`` fails that frame and every later one. The next call,
    of this estimator or another, gets a fresh copy. Cost (``benchmarks/bench_isolation.py``,
    ``paper-1m``): about 30 µs for the copy and the comparison of a chunk of 25 trials, 20 µs
    for one trial, a few per cent of the cheapest estimators' time.

The process around a call
    An estimator runs in the process of the run (``--workers 1``, a worker, an isolation
    process), so what it does to the process could break the run: in the main thread, while
    a call runs, ``sys.stdout`` is ``sys.stderr`` (stdout carries only emitterbench's own
    output: an estimator's ``print`` cannot corrupt ``estimate --json``), and after it the
    working directory, the recursion limit and ``sys.stdout``/``sys.stderr`` are put back; a
    standard stream the estimator closed is opened again on its file descriptor
    (:func:`kept_process`, which ``emitterbench estimate`` and ``fly`` use too). In another
    thread (a dask worker's) the process is shared with the other threads' calls and left
    alone.

Isolation
    In an isolation process (:func:`comparison.execution.run_isolated`) a :class:`CallJournal`
    numbers the calls, reports each to the supervisor before and after it runs, and replaces
    the calls the supervisor names (those that ended an earlier process) by failures. Outside
    isolation there is none and it costs nothing.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any, TextIO, TypeVar

import numpy as np
from numpy.typing import NDArray

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


class _ProcessState:
    """What an estimator's code may change in the process and the run needs back: the working
    directory, the recursion limit, ``sys.stdout`` and ``sys.stderr`` (module docstring)."""

    __slots__ = ("directory", "recursion_limit", "stderr", "stdout")

    def __init__(self) -> None:
        self.recursion_limit = sys.getrecursionlimit()
        self.directory = _working_directory()
        self.stdout: TextIO = sys.stdout
        self.stderr: TextIO = sys.stderr

    def restore(self) -> None:
        """Put back what changed; a standard stream that was closed is opened again."""
        if sys.getrecursionlimit() != self.recursion_limit:
            sys.setrecursionlimit(self.recursion_limit)
        if self.directory is not None and _working_directory() != self.directory:
            try:
                os.chdir(self.directory)
            except OSError:
                pass  # the folder itself is gone: nothing to go back to
        sys.stdout = _open_again(self.stdout, 1)
        sys.stderr = _open_again(self.stderr, 2)


def _working_directory() -> str | None:
    """The working directory, or None when it no longer exists."""
    try:
        return os.getcwd()
    except OSError:
        return None


def _open_again(stream: TextIO, descriptor: int) -> TextIO:
    """``stream``, or, when it was closed, a new text stream on ``descriptor`` with its
    encoding (the standard streams never close their descriptor), or on the null device
    when that fails."""
    if stream is None or not getattr(stream, "closed", False):
        return stream
    encoding = getattr(stream, "encoding", None) or "utf-8"
    errors = getattr(stream, "errors", None) or "backslashreplace"
    try:
        return open(descriptor, "w", buffering=1, encoding=encoding, errors=errors, closefd=False)
    except OSError:
        return open(os.devnull, "w", encoding=encoding)


@contextmanager
def kept_process() -> Iterator[None]:
    """Run an estimator's or a planner's code outside a run (``emitterbench estimate``,
    ``fly``): its prints go to stderr, and what it changes in the process is put back
    (module docstring)."""
    kept = _ProcessState()
    sys.stdout = sys.stderr
    try:
        yield
    finally:
        kept.restore()


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
    kept = _ProcessState() if threading.current_thread() is threading.main_thread() else None
    fault: BaseException | None = None
    value: Any = None
    start = time.perf_counter()
    try:
        try:
            if kept is not None:
                sys.stdout = sys.stderr  # an estimator's prints never reach stdout
            if alarm:
                _armed = True
                signal.setitimer(signal.ITIMER_REAL, min(budget_s, _LONGEST_ALARM_S))
            value = method(*args, **kwargs)
        finally:
            if alarm:
                _armed = False
                signal.setitimer(signal.ITIMER_REAL, 0.0)
            if kept is not None:
                kept.restore()
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


# --------------------------------------------------------------------------------------------
# the data an estimator is given (module docstring)
# --------------------------------------------------------------------------------------------

Data = TypeVar("Data", MeasurementSet, MeasurementBatch)
_FIELD_NAMES: dict[type, tuple[str, ...]] = {}
_SMALL_BYTES = 4096  # below it bytes compare fastest as bytes, above it as unsigned integers


def _field_names(kind: type) -> tuple[str, ...]:
    names = _FIELD_NAMES.get(kind)
    if names is None:
        names = _FIELD_NAMES[kind] = tuple(f.name for f in dataclasses.fields(kind))
    return names


def _is_part(value: Any) -> bool:
    """A frozen dataclass instance inside the data (``geometry``, ``noise``, ``rss_model``)."""
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def private_copy(data: Data) -> Data:
    """A copy of ``data`` sharing nothing that can be changed with it: every array copied and
    read-only, every part (``geometry``, ``noise``, ``rss_model``) copied; numbers, names and
    tuples shared. Not checked again (``data`` was, when it was built). Anything but a
    dataclass instance is returned as it is."""
    if not _is_part(data):
        return data
    copied = object.__new__(type(data))
    for name in _field_names(type(data)):
        value = getattr(data, name)
        if type(value) is np.ndarray:
            value = value.copy()
            value.flags.writeable = False
        elif _is_part(value):
            value = private_copy(value)
        object.__setattr__(copied, name, value)
    return copied


def changed_field(data: Any, reference: Any) -> str | None:
    """The first field of ``data`` that differs from ``reference``, by its dotted name
    (``doppler_hz``, ``geometry.noise.toa_s``), or None when they agree: every array in its
    type, dtype, shape and bits, every part field by field, every other value by type and
    equality."""
    if type(data) is not type(reference):
        return "the object itself"
    if not _is_part(reference):  # what private_copy returns as it is
        return None if data is reference else "the object itself"
    for name in _field_names(type(reference)):
        value, expected = getattr(data, name, None), getattr(reference, name)
        if value is expected:
            continue
        if type(expected) is np.ndarray:
            if not _same_array(value, expected):
                return name
        elif _is_part(expected):
            inner = changed_field(value, expected)
            if inner is not None:
                return f"{name}.{inner}" if inner != "the object itself" else name
        elif type(value) is not type(expected) or value != expected:
            return name
    return None


def _same_array(value: Any, expected: np.ndarray) -> bool:
    if (
        type(value) is not np.ndarray
        or value.dtype != expected.dtype
        or value.shape != expected.shape
    ):
        return False
    if expected.nbytes <= _SMALL_BYTES or expected.itemsize not in (1, 2, 4, 8):
        return value.tobytes() == expected.tobytes()
    bits = np.dtype(f"u{expected.itemsize}")  # NaN and -0.0 compared by their bits
    return bool(np.array_equal(value.view(bits), expected.view(bits)))


def changed_message(field: str) -> str:
    """The ``message`` of every estimate of a call that changed its data."""
    return f"the estimator changed the data it was given ({field})"


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


def call_estimate(
    estimator: Estimator, data: MeasurementSet, *, rng: np.random.Generator | None
) -> tuple[Estimate, float]:
    """``estimate`` on a private copy of ``data`` as :func:`timed_call`; failed when the
    estimator changed the copy (module docstring)."""
    given = private_copy(data)
    estimate, runtime_s = timed_call(estimator.estimate, given, rng=rng)
    change = changed_field(given, data)
    if change is not None:
        return Estimate.failed("", changed_message(change)), runtime_s
    return estimate, runtime_s


def call_batch(
    estimator: Estimator, batch: MeasurementBatch, rngs: Sequence[np.random.Generator]
) -> list[tuple[Estimate, float]] | None:
    """``estimate_batch`` on a private copy of ``batch``, timed and split evenly; None when it
    failed or overran; every estimate failed when it changed the copy."""
    given = private_copy(batch)

    def estimate_batch() -> list[Any]:
        return list(estimator.estimate_batch(given, rngs=rngs))

    estimates, fault, runtime_s = _guarded(estimate_batch, (), {}, batch.n_trials, estimator)
    change = changed_field(given, batch)
    if change is not None:
        failed = Estimate.failed("", changed_message(change))
        return [(failed, runtime_s / batch.n_trials)] * batch.n_trials
    if fault is not None:
        return None  # retried one trial at a time, so each row gets its own outcome
    if len(estimates) != batch.n_trials or not all(isinstance(e, Estimate) for e in estimates):
        return None
    return [(estimate, runtime_s / batch.n_trials) for estimate in estimates]


def call_columns(
    estimator: Estimator, batch: MeasurementBatch, rngs: Sequence[np.random.Generator]
) -> tuple[BatchEstimates, float] | None:
    """``estimate_columns`` on a private copy of ``batch``, timed, with each trial's share of
    the time; None when it failed, overran, or returned something else than one row of
    :class:`BatchEstimates` per trial; every row failed when it changed the copy."""
    given = private_copy(batch)

    def estimate_columns() -> Any:
        return estimator.estimate_columns(given, rngs=rngs)  # type: ignore[attr-defined]

    columns, fault, runtime_s = _guarded(estimate_columns, (), {}, batch.n_trials, estimator)
    change = changed_field(given, batch)
    if change is not None:
        failed = BatchEstimates.failed(batch.n_trials, changed_message(change))
        return failed, runtime_s / batch.n_trials
    if fault is not None or not isinstance(columns, BatchEstimates):
        return None  # retried one trial at a time, so each row gets its own outcome
    if len(columns) != batch.n_trials:
        return None
    return columns, runtime_s / batch.n_trials


def call_samples(
    estimator: Any,
    geometry: MeasurementSet,
    plan: Any,
    samples: NDArray[np.complexfloating],
    schedule_s: NDArray[np.float64],
    rngs: Sequence[np.random.Generator],
) -> tuple[BatchEstimates, float]:
    """An estimator of the received samples (``estimate_iq_batch``, docs/math.md §22) on a
    private, read-only copy of ``samples`` ``(n_trials, n_bursts, n_samples)``, with one
    generator of ties per trial (``rngs``), timed, with
    each trial's share of the time; every row failed, with the fault's message, when it raised,
    overran or returned something else than one row of :class:`BatchEstimates` per trial."""
    n = len(samples)
    given = samples.copy()
    given.flags.writeable = False
    schedule = np.array(schedule_s, dtype=float)
    schedule.flags.writeable = False

    def estimate() -> Any:
        return estimator.estimate_iq_batch(private_copy(geometry), plan, given, schedule, rngs=rngs)

    columns, fault, runtime_s = _guarded(estimate, (), {}, n, estimator)
    if fault is not None:
        return BatchEstimates.failed(n, fault_message(fault)), runtime_s / n
    if not isinstance(columns, BatchEstimates) or len(columns) != n:
        message = f"estimate_iq_batch returned {type(columns).__name__}, not {n} rows of columns"
        return BatchEstimates.failed(n, message), runtime_s / n
    return columns, runtime_s / n


class Stream:
    """A sequential estimator fed frame by frame: ``init`` now, then :meth:`step` per frame.

    A failed ``init`` fails every frame; a failed ``update`` fails that frame and every later
    one (the state is lost), and so does an ``update`` that changed its frame's data (it gets
    a private copy, module docstring); a failed ``estimate_state`` fails only its frame.
    ``init``'s time is counted in the first frame. Each of the three calls has the time limit.
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
        estimator, previous, given = self._estimator, self._state, private_copy(frame_data)
        state, fault, update_s = _guarded(
            lambda: estimator.update(previous, given), (), {}, 1, estimator
        )
        change = changed_field(given, frame_data)
        if change is not None:
            self._failure = Estimate.failed("", f"{changed_message(change)} in update")
            return self._failure, carried_s + update_s
        if fault is not None:
            self._failure = Estimate.failed("", fault_message(fault, "update"))
            return self._failure, carried_s + update_s
        self._state = state
        estimate, estimate_s = timed_call(self._estimator.estimate_state, self._state, rng=rng)
        return estimate, carried_s + update_s + estimate_s
