"""The run folder: writes whole or not at all, never through a link; one session at a time;
nothing left behind by an experiment that cannot run.

``Gated`` is a test plug-in (``tests.comparison.test_run_folder:Gated``) that holds a run
open for as long as a gate file exists, so that a second session meets the first one.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import importlib
import json
import os
import stat
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from matplotlib.figure import Figure

from comparison.code_files import code_files
from comparison.engine import run_experiment
from comparison.experiment import Experiment, load_experiment
from comparison.figures import save_figure
from comparison.run_folder import (
    LOCK_FILE,
    atomic_file,
    folder_lock,
    folder_session,
    report_lock,
    running_session,
    write_atomic,
    write_experiment,
)
from comparison.store import read_trials
from estimators.closed_form.cls import Cls
from tests.comparison.cli_support import clean_error, invoke

REPO_ROOT = Path(__file__).resolve().parents[2]
HERE = "tests.comparison.test_run_folder"
GATED_RUN = "EMITTERBENCH_TEST_GATED_RUN"


@dataclasses.dataclass(frozen=True, kw_only=True)
class Gated:
    """``cls`` that waits while the file ``gate`` exists (a run held open by the test),
    having made ``<gate>.waiting``; only in a process started with ``GATED_RUN`` set, so
    that a session the test runs itself never waits."""

    name: ClassVar[str] = "gated-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    gate: str = ""

    def estimate(self, data, *, rng=None):
        held = bool(os.environ.get(GATED_RUN)) and os.path.exists(self.gate)
        if held:
            Path(self.gate + ".waiting").touch()
        while held and os.path.exists(self.gate):
            time.sleep(0.01)
        return Cls().estimate(data, rng=rng)


def smoke(**changes: Any) -> Experiment:
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    raw.update(changes)
    return Experiment.from_dict(raw)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (links as their own text), by relative path."""
    return {
        str(p.relative_to(folder)): (os.readlink(p).encode() if p.is_symlink() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_symlink() or p.is_file()
    }


# --------------------------------------------------------------------------------------------
# atomic writes, and links refused
# --------------------------------------------------------------------------------------------


def test_a_write_replaces_the_file_whole_or_not_at_all(tmp_path):
    path = tmp_path / "summary.csv"
    write_atomic(path, "old\n")
    path.chmod(0o640)
    with pytest.raises(RuntimeError, match="midway"), atomic_file(path) as handle:
        handle.write("half of the new")
        raise RuntimeError("midway")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.csv"]  # no temporary left
    write_atomic(path, lambda handle: handle.write("new\n"))
    write_atomic(tmp_path / "figure.png", b"\x89PNG")
    assert path.read_text() == "new\n"
    assert stat.S_IMODE(path.stat().st_mode) == 0o640  # the file keeps its permissions
    assert (tmp_path / "figure.png").read_bytes() == b"\x89PNG"


def test_a_write_through_a_link_is_refused_and_its_target_untouched(tmp_path):
    target = tmp_path / "elsewhere.csv"
    target.write_text("precious")
    link = tmp_path / "summary.csv"
    link.symlink_to(target)
    with pytest.raises(ValueError, match=r"^summary.csv: .* is a symbolic link; .*remove the link"):
        write_atomic(link, "overwritten")
    assert target.read_text() == "precious"
    assert link.is_symlink()
    figure = Figure()
    figure.subplots().plot([0, 1], [1, 0])
    (tmp_path / "rmse.svg").symlink_to(target)
    with pytest.raises(ValueError, match=r"^rmse.svg: "):
        save_figure(figure, tmp_path, "rmse")
    assert target.read_text() == "precious"


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A small finished run, its report written (copy it before changing it)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    result = invoke("run", "smoke", "-o", out, "--trials", "4", "--workers", "1")
    assert result.exit_code == 0, result.output
    return out


def copy_of(run: Path, folder: Path) -> Path:
    copy = folder / "run"
    copy.mkdir()
    for name, content in snapshot(run).items():
        (copy / name).parent.mkdir(parents=True, exist_ok=True)
        (copy / name).write_bytes(content)
    return copy


@pytest.mark.parametrize("name", ["summary.csv", "report.html"])
def test_report_refuses_a_linked_output_and_writes_nothing(finished_run, tmp_path, name):
    run = copy_of(finished_run, tmp_path)
    target = tmp_path / "target.txt"
    target.write_text("not a report")
    (run / name).unlink()
    (run / name).symlink_to(target)
    (run / "trials.csv").unlink()
    before = snapshot(run)
    clean_error(invoke("report", run), f"{name}: {run / name} is a symbolic link")
    assert target.read_text() == "not a report"
    assert snapshot(run) == before  # refused before any file was written


def test_a_run_into_a_linked_folder_writes_real_files(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    run_experiment(smoke(trials=2), tmp_path / "link", workers=1)
    assert len(read_trials(real)) == 2 * 2 * 2
    assert not any(p.is_symlink() for p in real.iterdir())


# --------------------------------------------------------------------------------------------
# nothing written for an experiment that cannot run
# --------------------------------------------------------------------------------------------


UNUSABLE_HEIGHT_M = 13.0


@pytest.fixture
def unusable(monkeypatch) -> Experiment:
    """An experiment that validates, whose second point fails when it is simulated (as a
    point whose measurements overflow would; the simulation is patched to fail there)."""
    from comparison import bounds, engine
    from scenarios.simulate import noise_free

    def failing(scenario, *, snr_db=0.0):
        if scenario.emitter_height_m == UNUSABLE_HEIGHT_M:
            raise ValueError("toa_s: entry (0,) is inf; every value must be finite")
        return noise_free(scenario, snr_db=snr_db)

    monkeypatch.setattr(bounds, "noise_free", failing)
    monkeypatch.setattr(engine, "noise_free", failing)
    sweep = {"parameter": "emitter_height_m", "values": [0.0, UNUSABLE_HEIGHT_M]}
    return smoke(trials=2, sweep=sweep)


def test_a_point_that_cannot_be_simulated_leaves_no_trace(tmp_path, unusable):
    pattern = (
        r"^sweep: point 1 \(.*emitter_height_m=13\) of scenarios\[0\] \(paper-1m\) gives "
        r"measurements that cannot be used \(toa_s: entry \(0,\) is inf; .*\); change or drop"
    )
    with pytest.raises(ValueError, match=pattern):
        run_experiment(unusable, tmp_path / "new" / "run", workers=1)
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"^sweep: point 1 "):
        run_experiment(unusable, tmp_path / "empty", workers=1)
    assert list((tmp_path / "empty").iterdir()) == []
    run_experiment(smoke(trials=2), tmp_path / "empty", workers=1)  # the corrected one runs
    assert len(read_trials(tmp_path / "empty")) == 2 * 2 * 2


def test_the_command_line_says_so_in_one_line(tmp_path, unusable):
    definition = tmp_path / "unusable.json"
    definition.write_text(unusable.to_json())
    out = tmp_path / "run"
    clean_error(invoke("run", definition, "-o", out, "--workers", "1"), "sweep: point 1 ")
    assert not out.exists()


def test_a_failed_start_removes_only_what_it_wrote(tmp_path):
    experiment = smoke(trials=2)
    out = tmp_path / "a" / "run"
    with pytest.raises(RuntimeError), folder_session(out, experiment, resume=False) as session:
        write_experiment(out, experiment)
        raise RuntimeError("before any row")
    assert list(tmp_path.iterdir()) == []  # the folders it made are gone too
    with pytest.raises(RuntimeError), folder_session(out, experiment, resume=False) as session:
        write_experiment(out, experiment)
        session.keep = True  # a row may be stored: the folder is kept for --resume
        raise RuntimeError("after a row")
    assert sorted(p.name for p in out.iterdir()) == ["experiment.json"]


# --------------------------------------------------------------------------------------------
# one session at a time
# --------------------------------------------------------------------------------------------


def test_the_lock_admits_one_session_and_outlives_no_process(tmp_path):
    (tmp_path / LOCK_FILE).write_text('{"pid": 1, "host": "gone", "started_utc": "then"}')
    with folder_lock(tmp_path):  # a lock file left by a killed run does not lock
        held = json.loads((tmp_path / LOCK_FILE).read_text())
        assert held["pid"] == os.getpid()
        assert running_session(tmp_path).startswith(f"pid {os.getpid()} on ")
        with pytest.raises(
            ValueError, match=rf"^out_dir: .* in use by another .*pid {os.getpid()}"
        ):
            with folder_lock(tmp_path):
                pass
    assert running_session(tmp_path) is None
    assert list(tmp_path.iterdir()) == []


def test_what_a_killed_session_leaves_does_not_make_a_folder_hold_a_run(tmp_path):
    (tmp_path / LOCK_FILE).write_text('{"pid": 1}')
    (tmp_path / ".experiment.json.0a1b2c3d.tmp").write_text('{"name": "half')
    run_experiment(smoke(trials=2), tmp_path, workers=1)
    assert len(read_trials(tmp_path)) == 2 * 2 * 2
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / ".notes.tmp").write_text("a file of the user's, not of a session")
    with pytest.raises(ValueError, match=r"^out_dir: .* already holds files"):
        run_experiment(smoke(trials=2), mine, workers=1)


def test_a_second_session_is_refused_while_a_run_writes(tmp_path):
    gate = tmp_path / "gate"
    gate.write_text("hold the run open")
    estimators = [{"name": "cls"}, {"name": f"{HERE}:Gated", "options": {"gate": str(gate)}}]
    definition = tmp_path / "gated.json"
    definition.write_text(smoke(trials=4, estimators=estimators).to_json())
    out = tmp_path / "run"
    command = [sys.executable, "-c", "from comparison.cli import main; main()"]
    process = subprocess.Popen(
        [*command, "run", str(definition), "-o", str(out), "--workers", "1"],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT), GATED_RUN: "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        for _ in range(6000):  # polls 0.02 s apart (2 minutes): a bound, not a clock
            if (tmp_path / "gate.waiting").exists():  # the run holds the folder, idle
                break
            assert process.poll() is None, process.stderr.read().decode()
            time.sleep(0.02)
        else:
            pytest.fail("the run did not start in 6000 polls 0.02 s apart")
        assert (running_session(out) or "").startswith(f"pid {process.pid} on ")
        before = snapshot(out)
        resumed = invoke("run", definition, "-o", out, "--workers", "1", "--resume")
        line = clean_error(resumed, f"--output: {out} is in use by another emitterbench run")
        assert f"(pid {process.pid} on " in line and line.endswith("rerun with --resume")
        clean_error(invoke("report", out), f"run_dir: {out} is in use by another emitterbench run")
        assert snapshot(out) == before
    finally:
        gate.unlink()
        _, errors = process.communicate(timeout=300)
    assert process.returncode == 0, errors.decode()
    assert running_session(out) is None and not (out / LOCK_FILE).exists()
    assert len(read_trials(out)) == 2 * 4 * 2


def hold_in_another_thread(lock: Any) -> tuple[threading.Event, threading.Thread]:
    """The context manager ``lock`` (a folder's lock) held by another thread of this process
    until the event returned is set."""
    held, release = threading.Event(), threading.Event()

    def hold() -> None:
        with lock:
            held.set()
            release.wait()

    thread = threading.Thread(target=hold)
    thread.start()
    held.wait()
    return release, thread


def test_a_report_while_the_folder_is_locked_is_refused_in_one_line(finished_run, tmp_path):
    run = copy_of(finished_run, tmp_path)
    (run / "summary.csv").unlink()
    before = snapshot(run)
    release, thread = hold_in_another_thread(folder_lock(run))
    try:
        result = invoke("report", run)
        line = clean_error(result, f"run_dir: {run} is in use by another emitterbench run (pid ")
        assert line.endswith("; wait for it to finish, then write the report")
        assert result.exit_code == 2
        assert {**snapshot(run), LOCK_FILE: b""} == {**before, LOCK_FILE: b""}
    finally:
        release.set()
        thread.join()
    assert invoke("report", run).exit_code == 0  # the lock let go: the report is written
    assert (run / "summary.csv").is_file() and not (run / LOCK_FILE).exists()


def test_a_run_while_a_report_writes_is_refused_naming_the_report(finished_run, tmp_path):
    run = copy_of(finished_run, tmp_path)
    release, thread = hold_in_another_thread(report_lock(run))
    try:
        with pytest.raises(ValueError) as raised:
            run_experiment(smoke(trials=4), run, workers=1, resume=True)
    finally:
        release.set()
        thread.join()
    message = str(raised.value)
    assert message.startswith(
        f"out_dir: {run} is in use by another emitterbench report (pid {os.getpid()} on "
    )
    assert message.endswith("; wait for it to finish, then run again")


def test_run_writes_its_report_while_it_holds_the_lock(tmp_path, monkeypatch):
    from comparison import report

    holders = []
    write_report = report.write_report

    def observed(run_dir, **options):
        holders.append(running_session(Path(run_dir)))
        return write_report(run_dir, **options)

    monkeypatch.setattr(report, "write_report", observed)
    out = tmp_path / "run"
    result = invoke("run", "smoke", "-o", out, "--trials", "2", "--workers", "1")
    assert result.exit_code == 0, result.output
    (holder,) = holders
    assert holder is not None and holder.startswith(f"pid {os.getpid()} on ")
    assert (out / "report.html").is_file() and running_session(out) is None
    assert not (out / LOCK_FILE).exists()
    with (out / "summary.csv").open(newline="") as file:
        assert {row["n_trials"] for row in csv.DictReader(file)} == {"2"}


# --------------------------------------------------------------------------------------------
# the code of a run: emitterbench's and its plug-ins', the same on resume or refused
# --------------------------------------------------------------------------------------------

PLUGIN_PACKAGE = "eb_shift_plugin"
PLUGIN_INIT = '"""A plug-in package for the tests: a fixed answer, moved by helpers.OFFSET_M."""\n'
PLUGIN_MODULE = """
import numpy as np

from estimators.base import Estimate

from eb_shift_plugin import helpers


class Shifted:
    name = "shifted"
    requires = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        position_m = np.array([100.0 + helpers.OFFSET_M, 200.0])
        return Estimate(
            estimator=self.name, position_m=position_m, candidates_m=[position_m], ambiguous=False
        )
"""
"""``Shifted`` answers (100 + OFFSET_M, 200) m whatever the data: which code wrote a row shows
in its ``x_m``, exactly."""


@pytest.fixture
def plugin_site(tmp_path, monkeypatch) -> Path:
    """A plug-in package on ``sys.path`` (``eb_shift_plugin.shifted:Shifted``), imported
    afresh by each session (as by a new process), its modules written without bytecode."""
    site = tmp_path / "site"
    package = site / PLUGIN_PACKAGE
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(PLUGIN_INIT)
    (package / "helpers.py").write_text("OFFSET_M = 0.0\n")
    (package / "shifted.py").write_text(PLUGIN_MODULE)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    yield package
    for name in [m for m in sys.modules if m.split(".")[0] == PLUGIN_PACKAGE]:
        del sys.modules[name]


def fresh_imports() -> None:
    """Forget the plug-in's modules and the estimators built of them, as a new process (a
    resume) would not have them."""
    from comparison.tasks import estimator_of

    estimator_of.cache_clear()
    for name in [m for m in sys.modules if m.split(".")[0] == PLUGIN_PACKAGE]:
        del sys.modules[name]
    importlib.invalidate_caches()


SHIFTED = [{"name": "cls"}, {"name": f"{PLUGIN_PACKAGE}.shifted:Shifted", "label": "shifted"}]


def x_m(out: Path, estimator: str) -> np.ndarray:
    trials = read_trials(out)
    mine = trials[trials["estimator"] == estimator]
    return mine.sort_values(["scenario", "point", "trial"])["x_m"].to_numpy()


def test_the_digest_covers_a_plugins_package_without_importing_it(plugin_site, tmp_path):
    experiment = smoke(estimators=SHIFTED)  # checked: its plug-in imported
    (plugin_site / "__init__.py").write_text("raise RuntimeError('imported')\n")
    fresh_imports()
    files = code_files(experiment)
    assert PLUGIN_PACKAGE not in sys.modules  # found, not imported
    mine = {k: v for k, v in files.items() if k.startswith(f"{PLUGIN_PACKAGE}/")}
    assert mine == {
        f"{PLUGIN_PACKAGE}/{name}": hashlib.sha256((plugin_site / name).read_bytes()).hexdigest()
        for name in ("__init__.py", "helpers.py", "shifted.py")
    }
    assert "comparison/run_folder.py" in files and "estimators/closed_form/cls.py" in files
    assert files == code_files(experiment)
    assert not set(files) - set(mine) - set(code_files(smoke()))  # the rest: emitterbench's


def test_resume_refuses_a_changed_plugin_naming_its_files(plugin_site, tmp_path):
    experiment = smoke(estimators=SHIFTED)
    out = run_experiment(experiment.with_trials(2), tmp_path / "run", workers=1)
    first = json.loads((out / "run.json").read_text())
    assert f"{PLUGIN_PACKAGE}/shifted.py" in first["code_files"]

    fresh_imports()  # unchanged: resumed silently
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run_experiment(experiment.with_trials(3), out, workers=1, resume=True)
    assert "code_change_accepted" not in json.loads((out / "run.json").read_text())
    assert x_m(out, "shifted").tolist() == [100.0] * 2 * 3

    # another file of the plug-in's package changed: refused, the folder untouched
    (plugin_site / "helpers.py").write_text("OFFSET_M = 1000.0\n")
    fresh_imports()
    before = snapshot(out)
    pattern = (
        rf"^resume: the code differs from the one that wrote the rows already in {out} "
        rf"\(changed: {PLUGIN_PACKAGE}/helpers.py; code_files in run.json\); .* pass "
        r"accept_code_change=True to resume anyway$"
    )
    with pytest.raises(ValueError, match=pattern):
        run_experiment(experiment.with_trials(4), out, workers=1, resume=True)
    assert snapshot(out) == before

    # the module itself too, on the command line: one line naming both files
    (plugin_site / "shifted.py").write_text(PLUGIN_MODULE + "\n# edited\n")
    fresh_imports()
    definition = tmp_path / "shifted.json"
    definition.write_text(experiment.with_trials(4).to_json())
    args = ("run", definition, "-o", out, "--resume", "--trials", "4", "--workers", "1")
    line = clean_error(invoke(*args), "--resume: the code ")
    changed = f"{PLUGIN_PACKAGE}/helpers.py, {PLUGIN_PACKAGE}/shifted.py"
    assert f"(changed: {changed}; " in line and line.endswith(
        "pass --accept-code-change to resume anyway"
    )
    assert snapshot(out) == before

    # told to go on: the new rows come from the edited code, run.json records both versions
    fresh_imports()
    result = invoke(*args, "--accept-code-change")
    assert result.exit_code == 0, result.output
    info = json.loads((out / "run.json").read_text())
    old, new = info["sessions"][-2], info["sessions"][-1]
    assert new["code_change_accepted"] == changed.split(", ")
    for name in ("helpers.py", "shifted.py"):
        key = f"{PLUGIN_PACKAGE}/{name}"
        assert old["code_files"][key] != new["code_files"][key]
        assert (
            new["code_files"][key] == hashlib.sha256((plugin_site / name).read_bytes()).hexdigest()
        )
    assert old["code_digest"] != new["code_digest"] == info["code_digest"]
    assert x_m(out, "shifted").tolist() == [100.0, 100.0, 100.0, 1100.0] * 2  # trial 3: new

    fresh_imports()  # the same code as the last session: silent again
    run_experiment(experiment.with_trials(5), out, workers=1, resume=True)
    assert "code_change_accepted" not in json.loads((out / "run.json").read_text())
