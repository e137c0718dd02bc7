"""Where tasks run, and what happens when an estimator ends the process running it.

Backends
    Local processes through joblib/loky by default (``workers`` defaults to
    ``os.cpu_count()``), ``workers=1`` in-process, or a dask cluster with
    ``scheduler="tcp://HOST:PORT"`` (``pip install 'emitterbench[cluster]'``; the workers need
    emitterbench installed too: a task is a :class:`comparison.tasks.Task` and the function run
    is :func:`comparison.tasks.run_task`), one dask future per task (joblib's dask backend never
    returns once a worker has died). Results come back in completion order; rows never depend
    on it. The progress on stderr is :mod:`comparison.progress`'s.

Processes that die
    Whatever Python can catch becomes a failed row where it happens
    (:mod:`comparison.estimator_calls`: exceptions, ``SystemExit``, the time limit). A fault
    that ends the process (a segfault, ``os._exit``, the kernel's OOM killer) is handled here,
    and the common path does not change: a worker runs its task in its own process.

    - In-process (``workers=1``) such a fault ends the run, as it would any Python program.
      The rows of the finished tasks are stored and ``--resume`` continues, running the same
      task again: run an estimator that may crash with ``workers >= 2``.
    - loky: a worker first creates an empty marker file named after its task (about 25 µs).
      When a worker dies, loky breaks the pool and joblib raises ``TerminatedWorkerError``; the
      tasks that started and did not return are the suspects (the one that crashed, and those
      that died with the pool). The suspects run next, isolated (below), then the other tasks
      in a fresh pool; once an isolated task has shown that an estimator ends its process,
      every task not started yet runs isolated. Each break isolates at least one more task,
      so no task is retried forever; a break with no new suspect (a worker killed from outside
      while it ran isolated tasks) ends the run with a one-line error. Loky's crash reports on
      stderr are turned off in its workers (the rows say what happened); set
      ``PYTHONFAULTHANDLER=1`` to see Python's traceback of a crash, in isolation too.
    - dask: dask retries a task whose worker died (``distributed.scheduler.allowed-failures``)
      and then gives up on it (``KilledWorker``); that task runs again isolated, and so does
      every task not finished yet. Dask runs tasks in worker threads, where no alarm reaches
      them: there the time limit is checked when a call returns, and a call that never
      returns holds its thread.

Isolation (:func:`run_isolated`)
    An isolated task runs in a child process forked from a sandbox server: one helper process
    per worker process (per thread on dask), started on first use (it imports the engine,
    about 2 s), which imports the modules of the task's estimators and planners and forks one
    child per run (about 0.1 s) from a state in which no estimator ever ran (no thread pool,
    no half-initialised library). The child runs the ordinary :func:`~comparison.tasks.run_task`
    with a :class:`~comparison.estimator_calls.CallJournal`, which reports each estimator call
    before and after it runs. When the child dies, the call in flight is the culprit: the task
    runs again in a fresh child with that call replaced by a failed estimate whose message
    says how the process ended (``"the estimator killed its process (signal 11, SIGSEGV)"``,
    ``"the estimator ended its process (exit status 3)"``). Every other estimate is computed
    again by the same code, so its row is the one an in-process run gives (in a closed loop a
    failed steering estimate holds the velocity, as any failure does). The supervisor also stops
    a call that overruns its time limit without returning to Python (C code), after a grace of
    a quarter of the limit, at least 2 s: ``"the estimate took longer than the limit of 60 s
    (time_limit_s) and did not return to Python; its process was stopped"``. After an estimator
    has ended :data:`GIVE_UP_AFTER` processes in one task, its later calls in that task fail
    unrun (``"not run: the estimator ended its process 3 times in this task (last: signal 11,
    SIGSEGV)"``): an estimator that always crashes costs a few runs per task, not one per
    trial, and this is the one case where a failed row's message depends on the chunking. A
    child that dies outside any estimator call, or whose own code raises, ends the run with a
    one-line error. Isolation needs ``os.fork`` (Linux, macOS).

Stopping (Ctrl-C, SIGTERM)
    The command line turns SIGTERM into a ``KeyboardInterrupt``
    (:func:`comparison.cli_support.sigterm_as_interrupt`); either one, raised in the main
    process, closes :func:`execute`'s generator: the loky pool is shut down with its workers
    killed, each with its descendants (a worker's sandbox server and its forked child), after
    which loky's resource tracker sees the end of its pipe and exits; a sandbox of this
    process is killed with its child; the dask futures are cancelled. No process of the run
    outlives it. A worker that catches the interrupt itself (Ctrl-C reaches the whole process
    group) ends the same way.

Dask clusters that fail
    :func:`connect_scheduler` waits up to ``worker_wait_s`` (:data:`WORKER_WAIT_S`) for a
    first worker, before the run folder is locked; none, or the scheduler lost while tasks
    run, raises :class:`ClusterError`: the run ends with the rows stored so far, the folder
    unlocked, and ``--resume`` finishes it.
"""

from __future__ import annotations

import atexit
import faulthandler
import json
import logging
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import CancelledError
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any

from comparison.estimator_calls import CallJournal, journal_calls, limit_message
from comparison.tasks import Task, TaskResult, estimator_of, run_task

GIVE_UP_AFTER = 3
"""Processes an estimator may end in one isolated task before its other calls there fail."""


WORKER_WAIT_S = 60.0
"""How long a run on a dask cluster waits for a first worker before it gives up, s."""


class ClusterError(RuntimeError):
    """The dask cluster failed under the run: its scheduler was lost, or no worker joined in
    time. ``what`` says what happened and what to do about the cluster; the message adds that
    the stored rows are kept and that ``resume=True`` finishes the run."""

    def __init__(self, what: str) -> None:
        super().__init__(f"{what}; the rows stored so far are kept: rerun with resume=True")
        self.what = what


def connect_scheduler(
    scheduler: str, stack: ExitStack, worker_wait_s: float = WORKER_WAIT_S
) -> None:
    """Connect a dask client to ``scheduler`` and route joblib through it, or raise clearly.

    Waits up to ``worker_wait_s`` seconds for a first worker: :class:`ClusterError` when none
    joins; ``ValueError`` when the scheduler cannot be reached.
    """
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError(
            f"scheduler: running on {scheduler} needs dask.distributed; install it with "
            "pip install 'emitterbench[cluster]' (and emitterbench on every worker)"
        ) from None
    from joblib import parallel_config

    client_log = logging.getLogger("distributed.client")
    stack.callback(client_log.setLevel, client_log.level)  # see _run_on_dask
    try:
        client = stack.enter_context(Client(scheduler, timeout=30))
    except (OSError, TimeoutError, ValueError) as error:  # ValueError: a malformed address
        raise ValueError(
            f"scheduler: cannot reach {scheduler} ({error}); start it with "
            "'dask scheduler --port 8786' and workers with 'dask worker tcp://HOST:8786'"
        ) from None
    try:
        client.wait_for_workers(1, timeout=worker_wait_s)
    except TimeoutError:  # distributed's WorkerStartTimeoutError
        raise ClusterError(
            f"no dask worker joined the scheduler at {scheduler} within "
            f"{worker_wait_s:g} s (worker_wait_s); start workers with "
            f"'dask worker {scheduler}' (emitterbench installed on them)"
        ) from None
    except OSError as error:  # the scheduler went away meanwhile
        raise ClusterError(_lost(scheduler, type(error).__name__)) from None
    stack.enter_context(parallel_config(backend="dask"))


def _lost(scheduler: str, reason: str) -> str:
    """What to say when the connection to the scheduler is gone."""
    return (
        f"lost the connection to the dask scheduler at {scheduler} ({reason}); start it "
        "again, with its workers"
    )


def execute(tasks: list[Task], workers: int, scheduler: str | None) -> Iterator[TaskResult]:
    """Results in completion order: in-process, loky processes, or the connected dask cluster.

    Closing the generator early (an exception in the caller's loop, Ctrl-C, SIGTERM) stops
    every process it started (module docstring).
    """
    if not tasks:
        return
    if scheduler is not None:
        yield from _run_on_dask(tasks, scheduler)
    elif workers == 1:
        yield from (run_task(task) for task in tasks)
    else:
        yield from _run_on_loky(tasks, workers)


# --------------------------------------------------------------------------------------------
# the pool: suspects after a break, isolated
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Outcome:
    task_id: int
    result: TaskResult
    ended_process: bool  # isolated, and an estimator ended a process


def _run_job(task_id: int, task: Task, isolated: bool, marker_dir: str | None) -> _Outcome:
    """What a worker runs: the task isolated, or here after creating its marker."""
    if faulthandler.is_enabled() and not os.environ.get("PYTHONFAULTHANDLER"):
        faulthandler.disable()  # loky's: a crash is reported in its rows, not on stderr
    if isolated:
        result, ended = run_isolated(task)
        return _Outcome(task_id, result, ended)
    if marker_dir is not None:
        open(os.path.join(marker_dir, str(task_id)), "wb").close()
    return _Outcome(task_id, run_task(task), False)


def _run_on_loky(tasks: list[Task], workers: int) -> Iterator[TaskResult]:
    """Rounds of a loky pool (module docstring): every task, or the suspects of a break."""
    from joblib import Parallel, delayed

    pending = dict(enumerate(tasks))
    isolate: set[int] = set()
    isolate_all = False
    with tempfile.TemporaryDirectory(prefix="emitterbench-tasks-") as marker_dir:
        while pending:
            suspects = [] if isolate_all else [i for i in pending if i in isolate]
            batch = suspects or list(pending)
            # never n_jobs=1: joblib would run the tasks in this process
            parallel = Parallel(
                n_jobs=min(workers, max(2, len(batch))), return_as="generator_unordered"
            )
            jobs = (  # decided at dispatch: isolate_all may turn on meanwhile
                delayed(_run_job)(i, pending[i], isolate_all or i in isolate, marker_dir)
                for i in batch
            )
            outcomes = parallel(jobs)
            try:
                for outcome in outcomes:
                    del pending[outcome.task_id]
                    isolate_all = isolate_all or outcome.ended_process
                    yield outcome.result
            except BrokenProcessPool as error:  # loky's TerminatedWorkerError
                started = {i for i in pending if os.path.exists(f"{marker_dir}/{i}")}
                if not started - isolate:
                    raise RuntimeError(
                        "a worker process died while it ran no estimator "
                        f"({type(error).__name__}); the rows so far are stored: rerun with "
                        "--resume"
                    ) from None
                isolate |= started
            finally:  # stopped early: joblib kills the workers, each with its descendants
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # "... tasks ... cancelled"
                    outcomes.close()


FEEDER_JOIN_S = 1.0
"""How long :func:`release_workers` waits for a closed queue's feeder thread to end."""


def release_workers() -> None:
    """Shut down the worker processes loky keeps for the next run, and the threads that tend
    them, if this process has them: a process that forks (the report's figures and
    trials.csv, :func:`comparison.report_figures.figure_processes`) must run no other thread.
    The workers are idle: they are killed, each with its descendants, as on Ctrl-C (about
    0.03 s; letting them end by themselves takes about 0.5 s). A later run in this process
    starts its workers again."""
    if "joblib.externals.loky.reusable_executor" not in sys.modules:
        return  # no pool was ever started here
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor(reuse=True).shutdown(wait=True, kill_workers=True)
    # the pool's call queue hands its feeder thread the shutdown and lets it end on its own
    for thread in threading.enumerate():
        if thread.name == "QueueFeederThread":
            thread.join(timeout=FEEDER_JOIN_S)


def _run_on_dask(tasks: list[Task], scheduler: str) -> Iterator[TaskResult]:
    """A dask future per task (joblib's dask backend never returns when a worker dies); a
    task dask gave up on (KilledWorker) runs again isolated, and so does every task not
    finished once an estimator is known to end its process. The scheduler lost (the client
    cancels every future) raises :class:`ClusterError`."""
    from distributed import as_completed, get_client
    from distributed.scheduler import KilledWorker

    client = get_client()
    running: dict[Any, tuple[int, bool]] = {}  # future → task id, isolated

    def submit(task_id: int, isolated: bool) -> Any:
        future = client.submit(_run_job, task_id, tasks[task_id], isolated, None, pure=False)
        running[future] = (task_id, isolated)
        return future

    isolate_all = False
    queue = as_completed([submit(i, False) for i in range(len(tasks))])
    try:
        for future in queue:
            entry = running.pop(future, None)
            if entry is None:  # cancelled below
                continue
            task_id, isolated = entry
            try:
                outcome: _Outcome | None = future.result()
            except CancelledError as error:  # not by this function, which drops those
                reason = getattr(error, "reason", type(error).__name__)
                if reason != "scheduler-connection-lost":
                    raise ClusterError(
                        f"a task was cancelled on the dask cluster at {scheduler} ({reason})"
                    ) from None
                # closing the client will log that it could not reconnect: this error says it
                logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
                raise ClusterError(_lost(scheduler, reason)) from None
            except KilledWorker:
                if isolated:
                    raise RuntimeError(
                        "a dask worker died while it ran no estimator (KilledWorker); the rows "
                        "so far are stored: rerun with --resume"
                    ) from None
                outcome = None
            if not isolate_all and (outcome is None or outcome.ended_process):
                isolate_all = True
                for other, (other_id, other_isolated) in list(running.items()):
                    if not other_isolated:
                        del running[other]
                        other.cancel()
                        queue.add(submit(other_id, True))
            if outcome is None:
                queue.add(submit(task_id, True))
                continue
            yield outcome.result
    finally:
        if client.status == "running":  # else the futures are gone with the scheduler
            client.cancel(list(running))


# --------------------------------------------------------------------------------------------
# isolation: a sandbox server per worker, a forked child per run
# --------------------------------------------------------------------------------------------

_HEADER = struct.Struct(">Q")
_TIMEOUT = object()
_BOOT = (
    "import json, sys; sys.path[:] = json.loads(sys.argv[1]); "
    "from comparison.execution import serve_sandbox; serve_sandbox()"
)


def _frame(message: Any) -> bytes:
    payload = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(payload)) + payload


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class _FrameReader:
    """Length-prefixed pickles from a file descriptor, read with a timeout."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.buffer = bytearray()

    def read_raw(self, timeout: float | None = None) -> bytes | object | None:
        """The next frame's payload, ``_TIMEOUT``, or None at the end of the stream."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if len(self.buffer) >= _HEADER.size:
                (size,) = _HEADER.unpack_from(self.buffer)
                end = _HEADER.size + size
                if len(self.buffer) >= end:
                    payload = bytes(self.buffer[_HEADER.size : end])
                    del self.buffer[:end]
                    return payload
            wait = None if deadline is None else min(max(0.0, deadline - time.monotonic()), 3600)
            if not select.select([self.fd], [], [], wait)[0]:
                if deadline is not None and time.monotonic() >= deadline:
                    return _TIMEOUT
                continue  # a long wait, in steps
            if self.at_end():
                return None

    def read(self, timeout: float | None = None) -> Any:
        """The next message, ``_TIMEOUT``, or None at the end of the stream."""
        payload = self.read_raw(timeout)
        return payload if payload is None or payload is _TIMEOUT else pickle.loads(payload)

    def at_end(self) -> bool:
        """Read what is there (the descriptor is readable): True at the end of the stream."""
        chunk = os.read(self.fd, 1 << 16)
        self.buffer += chunk
        return not chunk


def serve_sandbox() -> None:
    """The sandbox server: for each request on stdin, fork a child that runs it, relay the
    child's messages to stdout, then report its exit code. Ends with its parent's stdin."""
    channel = os.dup(1)
    os.dup2(2, 1)  # whatever an estimator prints goes to stderr, not into the messages
    requests = _FrameReader(0)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: it ends with its parent
    while (payload := requests.read_raw()) is not None:
        request = pickle.loads(payload)  # type: ignore[arg-type]
        _preload(request[0])
        read_end, write_end = os.pipe()
        with warnings.catch_warnings():  # Python >= 3.12 warns of BLAS threads; none runs
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child
            code = 70
            try:
                signal.signal(signal.SIGINT, signal.default_int_handler)
                os.close(read_end)
                os.close(channel)
                os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
                code = _isolated_child(request, write_end)
            finally:
                os._exit(code)
        os.close(write_end)
        try:
            _write_all(channel, _frame(("pid", pid)))
            parent_gone = _relay(read_end, channel, requests)
        except BaseException:
            os.kill(pid, signal.SIGKILL)
            raise
        finally:
            os.close(read_end)
        if parent_gone:
            os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        if parent_gone:
            return
        _write_all(channel, _frame(("exit", os.waitstatus_to_exitcode(status))))


def _relay(read_end: int, channel: int, requests: _FrameReader) -> bool:
    """Copy the child's messages until it closes its end; True when the parent went away."""
    while True:
        ready = select.select([read_end, requests.fd], [], [])[0]
        if requests.fd in ready and requests.at_end():
            return True
        if read_end in ready:
            chunk = os.read(read_end, 1 << 16)
            if not chunk:
                return False
            _write_all(channel, chunk)


def _preload(task: Task) -> None:
    """Import the modules of the task's estimators and planners in the server, once, so that
    no child imports them again (importing runs no estimator; a failure is the child's to
    report)."""
    from estimators.registry import estimator_class
    from scenarios.planners import planner_class

    for spec, find in [(s, estimator_class) for s in task.estimators] + [
        (s, planner_class) for s in task.planners
    ]:
        try:
            find(spec.name)
        except Exception:
            pass


def _isolated_child(request: tuple[Task, dict[int, str], dict[str, Any]], fd: int) -> int:
    """Run the requested task with a journal reporting to ``fd``; the exit code."""

    def report(message: tuple[Any, ...]) -> None:
        _write_all(fd, _frame(message))

    try:
        task, replaced, given_up = request
        labels = {id(estimator_of(spec)): spec.label for spec in task.estimators}
        with journal_calls(CallJournal(labels, replaced, given_up, report)):
            result = run_task(task)
        report(("result", result))
        return 0
    except KeyboardInterrupt:
        report(("interrupted",))
        return 130
    except BaseException as error:  # not an estimator's: its faults are rows
        report(("error", f"{type(error).__name__}: {error}"))
        return 1


class _Sandbox:
    """A sandbox server and the reader of its messages."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-c", _BOOT, json.dumps(sys.path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        assert self.process.stdin is not None and self.process.stdout is not None
        self.stdin = self.process.stdin
        self.messages = _FrameReader(self.process.stdout.fileno())
        atexit.register(self.close)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()


_sandboxes = threading.local()


def _sandbox() -> _Sandbox:
    """This thread's sandbox server, started (again) when needed."""
    box: _Sandbox | None = getattr(_sandboxes, "box", None)
    if box is None or box.process.poll() is not None:
        if box is not None:
            box.close()
        box = _sandboxes.box = _Sandbox()
    return box


def run_isolated(task: Task) -> tuple[TaskResult, bool]:
    """Run ``task`` in a forked child, again without each call that ends a child (module
    docstring); the result, and whether any call ended a child."""
    replaced: dict[int, str] = {}
    given_up: dict[str, tuple[int, str]] = {}
    ended: Counter[str] = Counter()
    while True:
        outcome = _run_child(task, replaced, given_up)
        if isinstance(outcome, TaskResult):
            return outcome, bool(ended)
        number, label, reason, cause = outcome
        replaced[number] = reason
        ended[label] += 1
        if label and ended[label] >= GIVE_UP_AFTER:
            given_up[label] = (
                number,
                f"not run: the estimator ended its process {ended[label]} times in this task "
                f"(last: {cause})",
            )


def _grace_s(budget_s: float) -> float:
    """How long past its budget a call may run before the supervisor stops it."""
    return max(2.0, 0.25 * budget_s)


def _run_child(
    task: Task, replaced: dict[int, str], given_up: dict[str, tuple[int, str]]
) -> TaskResult | tuple[int, str, str, str]:
    """One run in a fresh child: its result, or ``(call, label, reason, cause)`` of the
    estimator call that ended it."""
    box = _sandbox()
    pid = code = None
    call: tuple[int, str] | None = None
    deadline: float | None = None
    stopped = False
    result: TaskResult | None = None
    error: str | None = None
    try:
        box.stdin.write(_frame((task, replaced, given_up)))
        box.stdin.flush()
        while code is None:
            timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
            message = box.messages.read(timeout)
            if message is _TIMEOUT:  # the call overran and never came back to Python
                os.kill(pid, signal.SIGKILL)  # type: ignore[arg-type]
                stopped, deadline = True, None
                continue
            if message is None:
                raise RuntimeError(
                    "isolation: the sandbox process ended unexpectedly (exit status "
                    f"{box.process.wait()}); see its message above"
                )
            kind = message[0]
            if kind == "pid":
                pid = message[1]
            elif kind == "start":
                _, number, label, budget_s = message
                call = (number, label)
                if budget_s is not None:
                    deadline = time.monotonic() + budget_s + _grace_s(budget_s)
            elif kind == "done":
                call, deadline = None, None
            elif kind == "result":
                result = message[1]
            elif kind == "error":
                error = message[1]
            elif kind == "interrupted":
                raise KeyboardInterrupt
            elif kind == "exit":
                code = message[1]
    except BaseException:
        if pid is not None and code is None:  # the server's child would outlive it
            _kill(pid)
        box.close()  # its state is unknown: the next run starts a fresh one
        _sandboxes.box = None
        raise
    if result is not None:
        return result
    first, last = task.trials[0], task.trials[-1]
    where = f"scenario {task.scenario_index}, point {task.point}, trials {first}-{last}"
    if error is not None:
        raise RuntimeError(f"the isolated task ({where}) raised {error}")
    if call is None:
        raise RuntimeError(
            f"the process of a task ({where}) ended outside any estimator call "
            f"({_exit_cause(code)}); the rows so far are stored: rerun with --resume"
        )
    number, label = call
    if stopped:
        limit_s = task.time_limit_s or 0.0
        reason = f"{limit_message(limit_s)} and did not return to Python; its process was stopped"
        return number, label, reason, "time limit"
    cause = _exit_cause(code)
    verb = "killed" if code is not None and code < 0 else "ended"
    return number, label, f"the estimator {verb} its process ({cause})", cause


def _kill(pid: int) -> None:
    """SIGKILL ``pid``, which may have ended already."""
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def _exit_cause(code: int | None) -> str:
    """``"signal 11, SIGSEGV"`` or ``"exit status 3"``."""
    if code is None or code >= 0:
        return f"exit status {code}"
    try:
        return f"signal {-code}, {signal.Signals(-code).name}"
    except ValueError:
        return f"signal {-code}"
