"""Non-cooperative emitters in the comparison (MATH §15): refusal, ignore_unknowns, the price."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from comparison.cli import app
from comparison.engine import run_experiment
from comparison.experiment import Experiment
from comparison.metrics import summarize
from comparison.specs import EstimatorSpec
from comparison.store import read_points, read_trials
from scenarios import get_scenario
from scenarios.files import write_measurements
from scenarios.fisher import fisher_information, rmse_bound_m
from scenarios.simulate import noise_free, simulate

runner = CliRunner()


def experiment(estimators, scenarios=("beacon-pass",), trials=20) -> Experiment:
    return Experiment.from_dict(
        {
            "name": "nc",
            "scenarios": list(scenarios),
            "sweep": {"parameter": "snr_db", "values": [20]},
            "estimators": estimators,
            "trials": trials,
            "seed": 3,
        }
    )


def test_an_estimator_that_takes_the_offsets_as_known_is_refused_at_load() -> None:
    with pytest.raises(ValueError) as error:
        experiment(["ml", "cls-paper"])
    message = str(error.value)
    assert message.startswith("estimators[1]: scenario 'beacon-pass': unknowns: ")
    assert "'cls-paper' takes them as known" in message
    assert "ignore_unknowns = true on the estimator" in message
    assert "'ml'" in message and "'cls'" in message


def test_ignore_unknowns_must_be_a_boolean_or_a_list_and_round_trips() -> None:
    with pytest.raises(ValueError, match="ignore_unknowns: expected true, false or a list"):
        experiment([{"name": "ml", "ignore_unknowns": "yes"}])
    loaded = experiment(["ml", {"name": "cls-paper", "ignore_unknowns": True}])
    assert loaded.estimators[1].ignore_unknowns
    assert loaded.estimators[1].to_dict()["ignore_unknowns"] is True
    assert "ignore_unknowns" not in EstimatorSpec(name="ml").to_dict()


def test_a_run_scores_against_the_nuisance_bound_and_stores_the_known_one(tmp_path) -> None:
    run = run_experiment(
        experiment(
            ["ml", {"name": "ml", "label": "ml-ignoring", "ignore_unknowns": True}],
            scenarios=("beacon-pass", "turn"),
        ),
        tmp_path / "run",
        workers=1,
        progress=False,
    )
    points = read_points(run)
    last = points.groupby("scenario").tail(1).set_index("scenario")
    for name in ("beacon-pass", "turn"):
        scenario = get_scenario(name)
        data = noise_free(scenario, snr_db=20.0)
        nuisance = float(rmse_bound_m(fisher_information(data, scenario.emitter_m)))
        known = float(rmse_bound_m(fisher_information(data, scenario.emitter_m, unknowns=())))
        assert last.loc[name, "crlb_rmse_toa_doppler_m"] == pytest.approx(nuisance, rel=1e-12)
        assert last.loc[name, "crlb_rmse_known_toa_doppler_m"] == pytest.approx(known, rel=1e-12)
    price = last["crlb_rmse_toa_doppler_m"] / last["crlb_rmse_known_toa_doppler_m"]
    assert price["beacon-pass"] == pytest.approx(1.97, abs=0.01)
    assert price["turn"] == 1.0  # a cooperative emitter: no price
    summary = summarize(read_trials(run)).set_index(["scenario", "estimator"])
    # ml estimates the offsets; ignoring a 12.3 ms emission time is 3,700 km of range
    assert summary.loc[("beacon-pass", "ml"), "efficiency_judged"] < 1.5
    ignoring = summary.loc[("beacon-pass", "ml-ignoring")]
    assert ignoring["success_rate"] < 1.0 or ignoring["efficiency_judged"] > 1e3
    # on a cooperative emitter ignore_unknowns changes nothing
    assert summary.loc[("turn", "ml-ignoring"), "rmse_m"] == summary.loc[("turn", "ml"), "rmse_m"]


def test_the_cli_prints_the_price_and_estimates_with_or_without_the_unknowns(tmp_path) -> None:
    path = write_measurements(simulate(get_scenario("beacon-pass"), seed=2), tmp_path / "b.json")
    result = runner.invoke(app, ["crlb", str(path), "--json"])
    assert result.exit_code == 0, result.output
    table = json.loads(result.stdout)
    assert table["unknowns"] == ["carrier_offset_hz", "emission_time_s"]
    assert table["price"]["toa+doppler"] == pytest.approx(1.97, abs=0.01)
    assert table["price"]["doppler"] == pytest.approx(2.28, abs=0.01)
    refused = runner.invoke(app, ["estimate", str(path), "-e", "cls-paper"])
    assert refused.exit_code == 2
    assert refused.stderr.strip().startswith("error: unknowns: ")
    assert "(--ignore-unknowns)" in refused.stderr
    result = runner.invoke(app, ["estimate", str(path), "-e", "ml", "--json"])
    assert result.exit_code == 0, result.output
    estimate = json.loads(result.stdout)
    assert np.linalg.norm(np.subtract(estimate["position_m"], [150.0, 120.0])) < 10.0
    assert estimate["diagnostics"]["carrier_offset_hz"] == pytest.approx(1000.0, abs=5.0)
    ignored = runner.invoke(
        app, ["estimate", str(path), "-e", "cls", "--ignore-unknowns", "--json"]
    )
    assert ignored.exit_code == 0, ignored.output
    position = json.loads(ignored.stdout)["position_m"]
    assert position is None or np.linalg.norm(np.subtract(position, [150.0, 120.0])) > 1e3


def test_the_builtin_noncooperative_experiment_loads() -> None:
    from comparison.experiment import builtin_experiment

    loaded = builtin_experiment("noncooperative")
    labels = loaded.labels
    assert {"cls", "cls-profile", "ml", "ekf", "gtsam-smoother"} <= set(labels)
    assert all(get_scenario(name).unknowns for name in loaded.scenarios)


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)


def test_a_closed_loop_feeds_ignore_unknowns_estimators_the_data_taken_as_known(tmp_path):
    closed = Experiment.from_dict(
        {
            "name": "nc-loop",
            "scenarios": ["turn-noncooperative"],
            "estimators": ["ml", {"name": "cls", "label": "cls-ignoring", "ignore_unknowns": True}],
            "planners": ["constant"],
            "per_frame": True,
            "frames": 2,
            "trials": 4,
            "seed": 5,
        }
    )
    trials = read_trials(run_experiment(closed, tmp_path / "loop", workers=1, progress=False))
    ignoring = trials[trials["estimator"] == "cls-ignoring"]
    assert not ignoring["message"].fillna("").str.contains("unknowns:").any()
    # the 800 Hz offset and 0.3 ms taken as zero: answers far off (90 km of range error)
    assert (ignoring["error_m"].fillna(np.inf) > 1e3).all()
    known = trials[(trials["estimator"] == "ml") & (trials["frame"] == 1)]
    assert (known["error_m"] < 50.0).all()
