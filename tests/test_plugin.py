"""Third-party estimators end to end: the example plug-in (examples/plugin) installed and found
through the entry-point group ``emitterbench.estimators``, and ``module:Class`` paths, on the
command line and in experiment files.

The plug-in is installed into a temporary folder without network access: ``pip install
--no-deps --no-build-isolation --no-index --target`` when the environment's setuptools can
build a wheel (setuptools >= 70.1, or the ``wheel`` package); otherwise setuptools'
``egg_info`` writes the same metadata (``entry_points.txt``) beside a copy of the package, which
is what an install puts on the path. The commands then run in subprocesses with that folder
on ``PYTHONPATH``.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from estimators.registry import all_entries, make_estimator

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "plugin"
PLUGIN_NAME = "doppler-grid"
CLASS_PATH = "emitterbench_gridsearch:DopplerGridSearch"

pytestmark = pytest.mark.slow


def can_build_wheel() -> bool:
    """setuptools builds wheels itself from 70.1; before that it needs the ``wheel`` package."""
    version = metadata.version("setuptools").split(".")
    major_minor = tuple(int("".join(c for c in part if c.isdigit()) or 0) for part in version[:2])
    return major_minor >= (70, 1) or importlib.util.find_spec("wheel") is not None


def run(command: list[str], *, env: dict[str, str], cwd: Path | None = None) -> str:
    """Run a command; on failure show its output in the assertion."""
    done = subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{command} failed:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def emitterbench_command() -> list[str]:
    """The ``emitterbench`` console script of this environment."""
    script = Path(sys.executable).with_name("emitterbench")
    return [str(script)] if script.exists() else [sys.executable, "-m", "comparison.cli"]


def environment(*paths: Path) -> dict[str, str]:
    """This process's environment with ``paths`` first on PYTHONPATH."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [*(str(p) for p in paths), *filter(None, [env.get("PYTHONPATH")])]
    )
    env.setdefault("MPLBACKEND", "Agg")
    return env


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding the installed example plug-in (package and metadata)."""
    if importlib.util.find_spec("setuptools") is None:
        pytest.skip("setuptools is not installed, so the example plug-in cannot be built offline")
    base = tmp_path_factory.mktemp("plugin")
    source = base / "source"  # a copy, so that building leaves examples/plugin untouched
    shutil.copytree(
        EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__")
    )
    site = base / "site"
    env = environment()
    if can_build_wheel():
        pip = [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation"]
        run([*pip, "--no-index", "--target", str(site), str(source)], env=env)
    else:
        site.mkdir()
        setup = [sys.executable, "-c", "from setuptools import setup; setup()"]
        run([*setup, "-q", "egg_info", "--egg-base", str(site)], env=env, cwd=source)
        shutil.copytree(
            source / "src" / "emitterbench_gridsearch", site / "emitterbench_gridsearch"
        )
    return site


def test_the_installed_plugin_is_listed(plugin_site: Path) -> None:
    output = run([*emitterbench_command(), "list"], env=environment(plugin_site))
    (line,) = [line for line in output.splitlines() if line.split()[:1] == [PLUGIN_NAME]]
    assert CLASS_PATH in line
    assert "unavailable" not in line


def test_the_entry_point_is_found_in_process(
    plugin_site: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.syspath_prepend(str(plugin_site))
    entries = all_entries()
    assert entries[PLUGIN_NAME].target == CLASS_PATH
    assert list(entries)[-1] == PLUGIN_NAME  # built-ins first, then plug-ins
    estimator = make_estimator(PLUGIN_NAME, grid_points=41)
    assert estimator.name == PLUGIN_NAME and estimator.grid_points == 41
    with pytest.raises(ValueError, match=r"^grid_pointz: not an option of estimator"):
        make_estimator(PLUGIN_NAME, grid_pointz=41)


def test_an_experiment_runs_the_plugin_by_name_and_by_path(
    plugin_site: Path, tmp_path: Path
) -> None:
    """Both names in one experiment file; the report and summary.csv show both, with results."""
    experiment = tmp_path / "plugin.toml"
    experiment.write_text(
        f"""
name = "plugin-smoke"
scenarios = ["turn"]
trials = 50
seed = 3
estimators = [
  "cls",
  {{name = "{PLUGIN_NAME}"}},
  {{name = "{CLASS_PATH}", label = "doppler-grid-path", options = {{grid_points = 41}}}},
]

[sweep]
parameter = "snr_db"
values = [10]
""",
        encoding="utf-8",
    )
    out = tmp_path / "run"
    command = [*emitterbench_command(), "run", str(experiment), "-o", str(out)]
    run([*command, "--trials", "10", "--workers", "1"], env=environment(plugin_site))
    with (out / "summary.csv").open(newline="") as file:
        rows = {row["estimator"]: row for row in csv.DictReader(file)}
    assert set(rows) == {"cls", PLUGIN_NAME, "doppler-grid-path"}
    for label in (PLUGIN_NAME, "doppler-grid-path"):
        assert rows[label]["n_trials"] == "10"
        assert float(rows[label]["success_rate"]) == 1.0
        # Doppler alone at 10 dB on two headings: centimetres, near its own CRLB
        assert 0.0 < float(rows[label]["rmse_m"]) < 0.5
    # the grid only picks the start: both grid sizes reach the same minima
    np.testing.assert_allclose(
        float(rows[PLUGIN_NAME]["rmse_m"]), float(rows["doppler-grid-path"]["rmse_m"]), rtol=1e-6
    )
    html = (out / "report.html").read_text(encoding="utf-8")
    assert PLUGIN_NAME in html and "doppler-grid-path" in html


def test_estimate_takes_a_module_class_path_without_installing(tmp_path: Path) -> None:
    """``--estimator package.module:Class`` needs only the package on the path."""
    env = environment(EXAMPLE / "src")
    measurements = tmp_path / "m.json"
    cli = emitterbench_command()
    run(
        [*cli, "simulate", "turn", "--seed", "1", "--snr-db", "20", "-o", str(measurements)],
        env=env,
    )
    output = run(
        [
            *cli,
            "estimate",
            str(measurements),
            "--estimator",
            CLASS_PATH,
            "--option",
            "grid_points=41",
            "--json",
        ],
        env=env,
    )
    result = json.loads(output)
    assert result["estimator"] == PLUGIN_NAME
    assert result["success"] and not result["ambiguous"]
    assert result["diagnostics"]["grid_step_m"] == pytest.approx(10.0)
    assert result["error_m"] < 0.2


def test_the_plugin_passes_its_own_tests(plugin_site: Path) -> None:
    """The example's own suite (the conformance checks among them) passes against the install."""
    tests = EXAMPLE / "tests"
    output = run(
        [
            sys.executable,
            "-m",
            "pytest",
            str(tests),
            "-q",
            "-p",
            "no:cacheprovider",
            "-p",
            "no:xdist",
        ],
        env=environment(plugin_site),
        cwd=ROOT,
    )
    assert " passed" in output and "failed" not in output
