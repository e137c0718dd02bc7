"""Isolation: whatever an estimator does to the data it is given changes no other estimator's
rows and fails its own, and what it does to its process (the working folder, the standard
streams, the recursion limit, prints) breaks neither a run nor ``estimate --json``.

The misbehaving estimators are the test plug-ins of :mod:`tests.comparison.plugins`; each run
with one is compared with the same run without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from comparison.engine import read_flights, read_trials, run_experiment
from comparison.estimator_calls import changed_field, changed_message, private_copy
from comparison.experiment import Experiment, load_experiment
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials
from tests.comparison.cli_support import invoke

PLUGINS = "tests.comparison.plugins"
REPO_ROOT = Path(__file__).resolve().parents[2]
CONSOLE = (sys.executable, "-c", "from comparison.cli import main; main()")
VICTIMS = [{"name": "cls"}, {"name": "lls-toa"}, {"name": "ekf"}]
"""Columnar, columnar, one call per trial: each runs after the misbehaving estimator."""


def experiment(estimators: list[dict], **changes) -> Experiment:
    """``smoke`` at 20 dB, 4 trials in chunks of 2, with ``estimators``."""
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    raw.update(
        sweep={"parameter": "snr_db", "values": [20]},
        trials=4,
        chunk_size=2,
        estimators=estimators,
    )
    raw.update(changes)
    return Experiment.from_dict(raw)


def without_runtime(frame: pd.DataFrame) -> pd.DataFrame:
    """Every column but the wall time (the only non-deterministic one), indexed afresh."""
    return frame.drop(columns="runtime_s").reset_index(drop=True)


def victim_rows(trials: pd.DataFrame) -> pd.DataFrame:
    rows = trials[trials.estimator.isin([v["name"] for v in VICTIMS])]
    return without_runtime(rows.sort_values(["estimator", "frame", "trial"]))


def plugin(name: str, label: str = "mutator") -> dict:
    return {"name": f"{PLUGINS}:{name}", "label": label}


# --------------------------------------------------------------------------------------------
# the copy and the comparison
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def batch():
    seeds = [np.random.SeedSequence(3, spawn_key=(0, 0, t)) for t in range(3)]
    return simulate_trials(get_scenario("paper-1m"), snr_db=10.0, seeds=seeds)


def test_a_private_copy_shares_no_array_or_part_and_equals_its_data(batch):
    copied = private_copy(batch)
    assert changed_field(copied, batch) is None
    assert copied.toa_s is not batch.toa_s and not copied.toa_s.flags.writeable
    assert copied.geometry is not batch.geometry
    assert copied.geometry.noise is not batch.geometry.noise
    assert copied.geometry.position_m is not batch.geometry.position_m
    assert copied.geometry.unknowns is batch.geometry.unknowns  # a tuple cannot change


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda b: object.__setattr__(b, "toa_s", b.toa_s + 0.0), None),  # the same bits
        (lambda b: object.__setattr__(b, "toa_s", b.toa_s.astype(np.float32)), "toa_s"),
        (lambda b: object.__setattr__(b, "toa_s", b.toa_s.tolist()), "toa_s"),
        (lambda b: object.__setattr__(b, "doppler_hz", None), "doppler_hz"),
        (lambda b: object.__setattr__(b.geometry, "carrier_hz", 1.0), "geometry.carrier_hz"),
        (lambda b: object.__setattr__(b.geometry.noise, "toa_s", 1.0), "geometry.noise.toa_s"),
        (
            lambda b: object.__setattr__(b.geometry, "unknowns", ["emission_time_s"]),
            "geometry.unknowns",
        ),
    ],
)
def test_changed_field_names_the_first_field_that_differs(batch, change, field):
    copied = private_copy(batch)
    change(copied)
    assert changed_field(copied, batch) == field


def test_changed_field_compares_bits_not_values(batch):
    """-0.0 == 0.0 and NaN != NaN as numbers; the bits tell a change either way."""
    values = np.array([0.0, np.nan, 1.0])
    data = private_copy(batch)
    object.__setattr__(data, "rss_dbm", None)
    reference = private_copy(data)
    object.__setattr__(reference.geometry, "truth_emitter_m", values[:2])
    object.__setattr__(data.geometry, "truth_emitter_m", values[:2].copy())
    assert changed_field(data, reference) is None  # NaN where NaN was
    object.__setattr__(data.geometry, "truth_emitter_m", np.array([-0.0, np.nan]))
    assert changed_field(data, reference) == "geometry.truth_emitter_m"


# --------------------------------------------------------------------------------------------
# estimators that change their data: open loop, per-frame streams, closed loop
# --------------------------------------------------------------------------------------------

MUTATORS = {
    "SetsAttribute": "doppler_hz",
    "WritesThroughBase": "toa_s",
    "ChangesNoise": "noise.doppler_hz",
    "ChangesColumns": "doppler_hz",
    "ChangesBatch": "geometry.position_m",
}
"""Plug-in → the field its rows name: per trial (setattr, through the array's base, a shared
part), on columns, through ``estimate_batch``."""


@pytest.fixture(scope="module")
def reference_rows(tmp_path_factory) -> pd.DataFrame:
    out = tmp_path_factory.mktemp("reference") / "run"
    return victim_rows(read_trials(run_experiment(experiment(VICTIMS), out, workers=1)))


@pytest.mark.bits(
    "the victims run the same code on the same simulated arrays with and without the mutator"
)
@pytest.mark.parametrize("mutator", sorted(MUTATORS))
def test_an_estimator_that_changes_its_data_fails_and_no_other_row_changes(
    tmp_path, reference_rows, mutator
):
    chosen = experiment([plugin(mutator), *VICTIMS])
    trials = read_trials(run_experiment(chosen, tmp_path / "run", workers=1))
    pd.testing.assert_frame_equal(victim_rows(trials), reference_rows)
    own = trials[trials.estimator == "mutator"]
    assert len(own) == chosen.trials
    assert not own.success.any()
    assert set(own.message) == {changed_message(MUTATORS[mutator])}


@pytest.mark.bits("ekf and cls stream the same simulated frames with and without the mutator")
def test_a_stream_that_changes_its_frame_fails_every_later_frame_and_no_other_row(tmp_path):
    def per_frame(*extra):
        return experiment(
            [*extra, {"name": "ekf"}, {"name": "cls"}],
            scenarios=["paper-1m-turn"],
            per_frame=True,
            trials=2,
        )

    reference = read_trials(run_experiment(per_frame(), tmp_path / "reference", workers=1))
    trials = read_trials(
        run_experiment(per_frame(plugin("ChangesInUpdate")), tmp_path / "run", workers=1)
    )
    pd.testing.assert_frame_equal(victim_rows(trials), victim_rows(reference))
    own = trials[trials.estimator == "mutator"]
    assert own.frame.nunique() == 10 and not own.success.any()
    assert set(own.message) == {changed_message("noise.toa_s") + " in update"}


@pytest.mark.bits(
    "cls steers and ekf follows on the same noise blocks with and without the mutator"
)
def test_in_a_closed_loop_an_estimator_that_changes_its_data_changes_no_flight_or_row(tmp_path):
    def closed_loop(*extra):
        return experiment(
            [{"name": "cls"}, *extra, {"name": "ekf"}],
            frames=3,
            planners=["fisher"],
            per_frame=True,
            trials=2,
        )

    reference = run_experiment(closed_loop(), tmp_path / "reference", workers=1)
    out = run_experiment(
        closed_loop(plugin("SetsAttribute"), plugin("ChangesInUpdate", "stream")),
        tmp_path / "run",
        workers=1,
    )
    trials = read_trials(out)
    pd.testing.assert_frame_equal(victim_rows(trials), victim_rows(read_trials(reference)))
    pd.testing.assert_frame_equal(read_flights(out), read_flights(reference))
    assert set(trials[trials.estimator == "mutator"].message) == {changed_message("doppler_hz")}
    stream = trials[trials.estimator == "stream"]
    assert set(stream.message) == {changed_message("noise.toa_s") + " in update"}


# --------------------------------------------------------------------------------------------
# estimators that change their process
# --------------------------------------------------------------------------------------------


def console(*args: str, cwd: Path, **options) -> subprocess.CompletedProcess:
    """``emitterbench`` in a process of its own, the test plug-ins importable."""
    return subprocess.run(
        [*CONSOLE, *args],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
        text=True,
        timeout=600,
        **options,
    )


@pytest.mark.parametrize("name", ["ChangesDirectory", "ClosesStdout", "LowersRecursionLimit"])
def test_an_estimator_that_changes_its_process_leaves_the_run_whole(tmp_path, name):
    """In process (``--workers 1``), with the run folder given relative to the working one:
    the run ends well, says where its report is, and the estimator's rows are ``cls``'s."""
    definition = tmp_path / "experiment.json"
    definition.write_text(experiment([{"name": "cls"}, plugin(name)]).to_json())
    done = console(
        "run", "experiment.json", "-o", "run", "--workers", "1", cwd=tmp_path, capture_output=True
    )
    assert done.returncode == 0, done.stderr
    assert "error" not in done.stderr
    assert "report: run/report.html" in done.stdout
    trials = read_trials(tmp_path / "run")
    own, cls = (trials[trials.estimator == label] for label in ("mutator", "cls"))
    assert own.success.all() and len(own) == 4
    np.testing.assert_allclose(own.x_m.to_numpy(), cls.x_m.to_numpy(), rtol=1e-9)


def test_an_estimators_prints_stay_off_the_json_of_estimate(tmp_path):
    path = tmp_path / "data.json"
    assert invoke("simulate", "paper-1m", "--seed", 1, "-o", path).exit_code == 0
    result = invoke("estimate", path, "-e", f"{PLUGINS}:Talks", "--json")
    assert result.exit_code == 0, result.output
    estimate = json.loads(result.stdout)
    assert estimate["success"] is True and len(estimate["position_m"]) == 2
    assert "a line the estimator prints" in result.stderr
    plain = json.loads(invoke("estimate", path, "-e", "cls", "--json").stdout)
    np.testing.assert_allclose(estimate["position_m"], plain["position_m"], rtol=1e-9)


def test_estimate_into_a_closed_pipe_ends_quietly(tmp_path):
    path = tmp_path / "data.json"
    assert invoke("simulate", "paper-1m", "--seed", 1, "-o", path).exit_code == 0
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone: `emitterbench estimate ... --json | head -0`
    try:
        done = console(
            "estimate", str(path), "-e", f"{PLUGINS}:Talks", "--json",
            cwd=tmp_path, stdout=write_end, stderr=subprocess.PIPE,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert done.stderr == "a line the estimator prints\n"
    assert done.returncode == 141  # the reader went away (comparison.cli_support)
