"""Tests of a run stopped from outside: SIGTERM, and a dask cluster that fails under it.

A stopped run keeps the rows it stored, says in one line how to finish with ``--resume``,
exits with its documented status (143 for SIGTERM, 3 for a failed cluster), leaves no process
behind and releases its folder; the resumed run gives the rows of an uninterrupted one.

The run to stop is an ``emitterbench run`` subprocess whose estimator :class:`HeldAt` holds
the tasks of the second point while a gate file exists, so that the first point's rows are
stored and every worker is busy when the signal comes. Waiting is a bounded number of polls
(no test reads a clock).
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, ClassVar

import pytest

from comparison.cli_support import CLUSTER_FAILED_STATUS, TERMINATED_STATUS
from comparison.engine import read_trials, run_experiment
from comparison.experiment import load_experiment
from scenarios.catalog import get_scenario
from scenarios.files import write_measurements
from scenarios.simulate import noise_free, simulate
from tests.comparison.cli_support import invoke

REPO_ROOT = Path(__file__).resolve().parents[2]
HERE = "tests.comparison.test_signals"
HELD_RUN = "EMITTERBENCH_TEST_HELD_RUN"
"""Set in the environment of the run a test stops: elsewhere :class:`HeldAt` never holds."""
CONSOLE = (sys.executable, "-c", "from comparison.cli import main; main()")
POLLS = 6000
POLL_S = 0.02
"""Polls 0.02 s apart, at most 6000 (2 minutes on a loaded machine): a bound, not a clock."""
TRIALS = 10
CHUNK = 5


@dataclasses.dataclass(frozen=True, kw_only=True)
class HeldAt:
    """``cls``; in a process started with ``HELD_RUN`` set, at a point whose Doppler σ is below
    ``below_doppler_sigma_hz`` it waits while the file ``gate`` exists, having made
    ``<gate>.<pid>``; at a point above it, with ``crash``, it ends its process."""

    name: ClassVar[str] = "held-at"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    gate: str = ""
    below_doppler_sigma_hz: float = 0.0
    crash: bool = False

    def estimate(self, data, *, rng=None):
        from estimators.closed_form.cls import Cls

        if os.environ.get(HELD_RUN):
            if data.noise.doppler_hz >= self.below_doppler_sigma_hz:
                if self.crash:
                    os._exit(3)
            elif os.path.exists(self.gate):
                Path(f"{self.gate}.{os.getpid()}").touch()
                while os.path.exists(self.gate):
                    time.sleep(0.01)
        return Cls().estimate(data, rng=rng)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def held_experiment(folder: Path, *, crash: bool = False) -> Path:
    """``smoke`` (0 and 20 dB) with ``cls`` and :class:`HeldAt` holding the 20 dB point (and
    with ``crash``, ending its process at 0 dB), as a file in ``folder``."""
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    sigmas = []
    smoke = load_experiment("smoke")
    for point in range(2):
        scenario, snr_db = smoke.point_scenario(0, point)
        sigmas.append(noise_free(scenario, snr_db=snr_db).noise.doppler_hz)
    assert sigmas[1] < sigmas[0]  # 20 dB after 0 dB: the first point's tasks go first
    options = {
        "gate": str(folder / "gate"),
        "below_doppler_sigma_hz": float((sigmas[0] * sigmas[1]) ** 0.5),
        "crash": crash,
    }
    raw.update(
        trials=TRIALS,
        chunk_size=CHUNK,
        estimators=[
            {"name": "cls"},
            {"name": f"{HERE}:HeldAt", "label": "held", "options": options},
        ],
    )
    path = folder / "held.json"
    path.write_text(json.dumps(raw))
    return path


def start_run(definition: Path, out: Path, *args: str) -> subprocess.Popen[str]:
    """``emitterbench run definition -o out --workers 2 args`` with ``HeldAt`` holding."""
    return subprocess.Popen(
        [*CONSOLE, "run", str(definition), "-o", str(out), "--workers", "2", *args],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT), HELD_RUN: "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def stored_rows(out: Path) -> int:
    """Rows in the run's store so far (0 before it has its table)."""
    try:
        with sqlite3.connect(f"file:{out / 'results.sqlite'}?mode=ro", uri=True) as connection:
            return connection.execute("SELECT COUNT(*) FROM trials").fetchone()[0]
    except sqlite3.Error:
        return 0


def wait_until(done: Any, process: subprocess.Popen[str], what: str) -> None:
    """Poll ``done()`` while ``process`` runs, at most :data:`POLLS` times."""
    for _ in range(POLLS):
        if done():
            return
        if process.poll() is not None:
            pytest.fail(f"the run ended before {what}: {process.stderr.read()}")
        time.sleep(POLL_S)
    process.kill()
    pytest.fail(f"not {what} after {POLLS} polls {POLL_S} s apart")


def parents() -> dict[int, int]:
    """Every live process (not a zombie) → its parent, from /proc."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rpartition(")")[2].split()
        except OSError:  # ended meanwhile
            continue
        if fields[0] != "Z":
            found[int(entry.name)] = int(fields[1])
    return found


def descendants(pid: int) -> set[int]:
    """The live descendants of ``pid``."""
    links = parents()
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {child for child, parent in links.items() if parent in frontier} - found
        found |= frontier
    return found


def wait_gone(pids: set[int]) -> set[int]:
    """Those of ``pids`` still alive after at most :data:`POLLS` polls."""
    alive = set(pids)
    for _ in range(POLLS):
        alive &= set(parents())
        if not alive:
            break
        time.sleep(POLL_S)
    return alive


def rows_of(out: Path):
    """The trial rows without the wall time (the one column that differs between runs)."""
    return read_trials(out).drop(columns="runtime_s").reset_index(drop=True)


def resume_line(definition: Path, out: Path) -> str:
    command = f"emitterbench run {definition} -o {out} --resume"
    return f"the rows stored so far are kept; finish the run with `{command}`"


def error_lines(stderr: str) -> list[str]:
    """stderr without the progress lines (stderr is not a terminal)."""
    return [line for line in stderr.splitlines() if not line.startswith("progress: ")]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Any:
    """The rows of the held experiment run in one go, in-process (nothing holds there)."""
    folder = tmp_path_factory.mktemp("uninterrupted")
    out = run_experiment(load_experiment(str(held_experiment(folder))), folder / "run", workers=1)
    return rows_of(out)


# --------------------------------------------------------------------------------------------
# SIGTERM
# --------------------------------------------------------------------------------------------


def stop_with_sigterm(process: subprocess.Popen[str], workers: int) -> tuple[str, set[int]]:
    """SIGTERM to the run (alone, not its process group); its stderr, and those of its
    descendants at the signal that are still alive after a bounded wait."""
    before = descendants(process.pid)
    assert len(before) >= workers  # the workers, loky's resource tracker, sandboxes
    process.send_signal(signal.SIGTERM)
    _, errors = process.communicate(timeout=120)
    return errors, wait_gone(before)


@pytest.mark.slow  # a loky pool, then the resumed run
@pytest.mark.bits("same code, same arrays: resume")
def test_sigterm_stops_the_run_like_ctrl_c_and_resume_finishes_it(tmp_path, uninterrupted):
    definition = held_experiment(tmp_path)
    out = tmp_path / "run"
    gate = tmp_path / "gate"
    gate.write_text("hold the run")
    process = start_run(definition, out)
    try:
        first_point = TRIALS * 2  # the 0 dB point's rows, cls and held
        wait_until(lambda: stored_rows(out) == first_point, process, "the first point stored")
        wait_until(lambda: len(list(tmp_path.glob("gate.*"))) == 2, process, "both workers held")
        errors, survivors = stop_with_sigterm(process, workers=2)
    finally:
        gate.unlink(missing_ok=True)
        if process.poll() is None:
            process.kill()
    assert process.returncode == TERMINATED_STATUS == 143
    assert error_lines(errors) == [
        f"error: terminated (SIGTERM): {resume_line(definition, out)}"
    ], errors
    assert not survivors, f"processes of the run still alive: {survivors}"
    assert stored_rows(out) == first_point
    finished = invoke("run", definition, "-o", out, "--resume", "--workers", "1")
    assert finished.exit_code == 0, finished.output
    assert rows_of(out).equals(uninterrupted)


@pytest.mark.slow  # a pool break, then sandboxes started in both workers (about 2 s each)
def test_sigterm_leaves_no_sandbox_process_behind(tmp_path):
    """Once an estimator has ended its process, every task runs in a sandbox's forked child:
    SIGTERM while two of them hold stops the workers, their sandboxes and the children."""
    definition = held_experiment(tmp_path, crash=True)
    out = tmp_path / "run"
    gate = tmp_path / "gate"
    gate.write_text("hold the run")
    process = start_run(definition, out)
    try:
        wait_until(lambda: len(list(tmp_path.glob("gate.*"))) == 2, process, "both tasks held")
        held = {int(path.suffix[1:]) for path in tmp_path.glob("gate.*")}
        assert held <= descendants(process.pid)  # the forked children, grandchildren of workers
        errors, survivors = stop_with_sigterm(process, workers=2 * 3)  # worker, server, child
    finally:
        gate.unlink(missing_ok=True)
        if process.poll() is None:
            process.kill()
    assert process.returncode == TERMINATED_STATUS
    assert error_lines(errors) == [f"error: terminated (SIGTERM): {resume_line(definition, out)}"]
    assert not survivors, f"processes of the run still alive: {survivors}"
    assert stored_rows(out) == TRIALS * 2  # the 0 dB point: cls, and held's failed rows


@dataclasses.dataclass(frozen=True, kw_only=True)
class SelfTerminating:
    """Sends SIGTERM to its own process, then waits in a ``try`` whose ``finally`` writes
    ``<record>`` (as a command's cleanup would)."""

    name: ClassVar[str] = "self-terminating"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    record: str = ""

    def estimate(self, data, *, rng=None):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(POLLS):  # the handler runs at once; a bound all the same
                time.sleep(POLL_S)
        finally:
            Path(self.record).write_text("cleaned up")
        raise AssertionError("SIGTERM did not interrupt the estimate")


def test_sigterm_in_any_command_runs_its_cleanup_and_exits_143_in_one_line(tmp_path):
    """SIGTERM raises where the command is, like Ctrl-C: ``finally`` blocks run (a report's
    temporary files are removed), one line, exit 143; the handler is gone afterwards."""
    data = write_measurements(simulate(get_scenario("paper-1m"), seed=1), tmp_path / "m.json")
    record = tmp_path / "cleanup"
    estimator = f"{HERE}:SelfTerminating"
    result = invoke("estimate", data, "-e", estimator, "--option", f'record="{record}"')
    assert result.exit_code == TERMINATED_STATUS
    assert result.stdout == ""
    assert result.stderr == "error: terminated (SIGTERM): stopped before the end\n"
    assert record.read_text() == "cleaned up"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


# --------------------------------------------------------------------------------------------
# dask: the scheduler lost, no workers
# --------------------------------------------------------------------------------------------

CLUSTER = (
    "import sys, time\n"
    "from distributed import LocalCluster\n"
    "cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol='tcp',"
    " host='127.0.0.1', dashboard_address=':0', silence_logs=50)\n"
    "print(cluster.scheduler_address, flush=True)\n"
    "while True:\n"
    "    time.sleep(1)\n"
)
"""A dask cluster in a process of its own (a scheduler and a worker thread) that a test kills."""


@pytest.mark.slow  # a dask cluster, a run on it, then the resumed run
@pytest.mark.bits("same code, same arrays: resume")
def test_a_scheduler_lost_mid_run_ends_in_one_line_and_resume_finishes(tmp_path, uninterrupted):
    pytest.importorskip("distributed", reason="dask.distributed is not installed")
    definition = held_experiment(tmp_path)
    out = tmp_path / "run"
    gate = tmp_path / "gate"
    gate.write_text("hold the run")
    environment = {**os.environ, "PYTHONPATH": str(REPO_ROOT), HELD_RUN: "1"}
    cluster = subprocess.Popen(
        [sys.executable, "-c", CLUSTER],
        cwd=REPO_ROOT,
        env=environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    process = None
    try:
        address = cluster.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        process = subprocess.Popen(
            [*CONSOLE, "run", str(definition), "-o", str(out), "--scheduler", address],
            cwd=REPO_ROOT,
            env=environment,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        wait_until(lambda: stored_rows(out) == TRIALS * 2, process, "the first point stored")
        wait_until(lambda: len(list(tmp_path.glob("gate.*"))) == 1, process, "the worker held")
        cluster.kill()  # the scheduler and its worker, as a crash would
        cluster.wait()
        _, errors = process.communicate(timeout=120)
    finally:
        gate.unlink(missing_ok=True)
        for started in (cluster, process):
            if started is not None and started.poll() is None:
                started.kill()
    assert process.returncode == CLUSTER_FAILED_STATUS == 3
    assert error_lines(errors) == [
        f"error: --scheduler: lost the connection to the dask scheduler at {address} "
        "(scheduler-connection-lost); start it again, with its workers; "
        + resume_line(definition, out)
    ], errors
    assert stored_rows(out) == TRIALS * 2
    finished = invoke("run", definition, "-o", out, "--resume", "--workers", "1")
    assert finished.exit_code == 0, finished.output
    assert rows_of(out).equals(uninterrupted)


@pytest.mark.slow  # a dask scheduler, then the run
def test_a_scheduler_without_workers_ends_in_one_line_and_leaves_the_folder_free(
    tmp_path, uninterrupted
):
    distributed = pytest.importorskip("distributed", reason="dask.distributed is not installed")
    definition = held_experiment(tmp_path)
    out = tmp_path / "run"
    with distributed.LocalCluster(
        n_workers=0, processes=False, protocol="tcp", dashboard_address=":0", silence_logs=50
    ) as cluster:
        address = cluster.scheduler_address
        result = invoke(
            "run", definition, "-o", out, "--scheduler", address, "--worker-wait-s", "2"
        )
    assert result.exit_code == CLUSTER_FAILED_STATUS
    assert result.stdout == ""
    assert error_lines(result.stderr) == [
        f"error: --scheduler: no dask worker joined the scheduler at {address} within 2 s "
        f"(--worker-wait-s); start workers with 'dask worker {address}' (emitterbench "
        f"installed on them); {resume_line(definition, out)}"
    ]
    finished = invoke("run", definition, "-o", out, "--resume", "--workers", "1")  # not locked
    assert finished.exit_code == 0, finished.output
    assert rows_of(out).equals(uninterrupted)
