"""Experiments at the signal level (``[signal]``, docs/math.md §18-§20): the C/N0 axis, what
is refused at load, and a small run whose rows, bounds and burst table are the front end's."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from comparison.engine import read_points, read_trials, run_experiment
from comparison.experiment import Experiment
from comparison.experiment_signal import received_scenario
from comparison.store import read_bursts
from scenarios.catalog import get_scenario
from scenarios.fisher import frame_statistics
from scenarios.signal import BurstPlan, noise_at_cn0
from scenarios.simulate import noise_free

SIGNAL = {
    "waveform": "bpsk",
    "burst_s": 0.01,
    "sample_rate_hz": 102400.0,
    "chip_rate_hz": 25600.0,
    "guard_s": 4.0 / 102400.0,
}


def experiment(**changes: object) -> Experiment:
    raw = {
        "name": "iq",
        "scenarios": ["turn"],
        "trials": 6,
        "seed": 5,
        "estimators": ["cls", "ml"],
        "signal": SIGNAL,
        "sweep": {"parameter": "cn0_dbhz", "values": [70.0, 75.0]},
    }
    raw.update(changes)
    return Experiment.from_dict({k: v for k, v in raw.items() if v is not None})


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"signal": None}, "sweep: cn0_dbhz is the axis of the signal level; add a [signal]"),
        (
            {"sweep": {"parameter": "snr_db", "values": [0.0]}},
            "sweep: a [signal] experiment's axis is cn0_dbhz",
        ),
        ({"sweep": {}}, "sweep: a [signal] experiment needs cn0_dbhz"),
        ({"signal": {**SIGNAL, "waveform": "cw"}}, "signal.waveform: a tone carries no delay"),
        ({"signal": {**SIGNAL, "guard_s": 1e-5}}, "signal.guard_s: must be a whole number"),
        ({"signal": {**SIGNAL, "burst_ms": 1.0}}, "signal.burst_ms"),
        ({"signal": {**SIGNAL, "sample_rate_hz": 8.0, "chip_rate_hz": 1.0}}, "signal."),
        ({"sweep": {"parameter": "cn0_dbhz", "values": [500.0]}}, "sweep.values[0]: cn0_dbhz"),
        ({"per_frame": True}, "per_frame: a [signal] experiment estimates once"),
        ({"signal": {**SIGNAL, "doppler_search_hz": -1.0}}, "signal.doppler_search_hz: "),
        (
            {"scenarios": ["beacon-pass"], "estimators": ["cls"]},
            "signal.doppler_search_hz: scenario 'beacon-pass''s carrier offset is unknown",
        ),
    ],
)
def test_bad_signal_experiments_are_one_line_naming_the_key(changes: dict, message: str) -> None:
    with pytest.raises(ValueError) as caught:
        experiment(**changes)
    assert str(caught.value).startswith(message), str(caught.value)
    assert "\n" not in str(caught.value)


def test_the_axis_is_c_n0_and_the_sigmas_are_the_bursts_bounds() -> None:
    chosen = experiment()
    assert chosen.swept_columns == ("cn0_dbhz",)
    assert Experiment.from_json(chosen.to_json()) == chosen
    scenario, snr_db = chosen.point_scenario(0, 1)
    plan = chosen.point_plan(1)
    assert snr_db == 0.0 and plan == BurstPlan(**SIGNAL, cn0_dbhz=75.0)
    bound = noise_at_cn0(plan)
    assert scenario.noise.doppler_hz == bound.doppler_hz and scenario.noise.toa_s == bound.toa_s
    # 5 dB more C/N0: every σ falls by 10^(5/20)
    lower, _ = chosen.point_scenario(0, 0)
    ratio = lower.noise.doppler_hz / scenario.noise.doppler_hz
    assert ratio == pytest.approx(10 ** (5 / 20), rel=1e-12)
    # a measurement-level experiment's JSON is unchanged
    assert (
        "signal"
        not in Experiment.from_dict(
            {"name": "m", "scenarios": ["turn"], "trials": 1, "seed": 0, "estimators": ["cls"]}
        ).to_dict()
    )


def test_a_signal_run_scores_the_front_ends_measurements(tmp_path: Path) -> None:
    chosen = experiment()
    run_experiment(chosen, tmp_path / "run", workers=1, progress=False)
    trials = read_trials(tmp_path / "run")
    assert len(trials) == 2 * 2 * 6 and trials["success"].all()
    assert sorted(set(trials["cn0_dbhz"])) == [70.0, 75.0]
    points = read_points(tmp_path / "run")
    # the bound is the measurement-level one at the bursts' σ's
    for p, cn0 in enumerate((70.0, 75.0)):
        plan = BurstPlan(**SIGNAL, cn0_dbhz=cn0)
        scenario = received_scenario(get_scenario("turn"), plan)
        data = noise_free(scenario)
        information = frame_statistics(data, data.truth_emitter_m, ("toa", "doppler"))
        crlb = np.linalg.inv(information.information(list(range(scenario.flight.n_frames))))
        rows = trials[(trials["point"] == p) & (trials["estimator"] == "ml")]
        assert rows["crlb_rmse_m"].iloc[0] == pytest.approx(math.sqrt(np.trace(crlb)), rel=1e-9)
        assert len(points[points["point"] == p]) == scenario.flight.n_frames
    bursts = read_bursts(tmp_path / "run")
    assert len(bursts) == 2 * 6
    assert (bursts["n_bursts"] == 20).all()
    # 70-75 dB-Hz: 50-55 dB a burst, far above threshold: no flag, no outlier
    assert (bursts[["flagged", "outliers", "unflagged_outliers"]] == 0).all().all()
    # the burst SNR estimated: C/N0 + 10 log10(T), 50 and 55 dB, within its spread
    expected_db = np.where(bursts["point"] == 0, 50.0, 55.0)
    np.testing.assert_allclose(bursts["mean_burst_snr_db"], expected_db, atol=0.1)


def test_below_threshold_refused_toas_fail_only_the_estimators_that_read_them(
    tmp_path: Path,
) -> None:
    """At 28 dB-Hz (8 dB a burst) the front end's ToA outliers are kilometres short of the
    UAV's height: the measurement sets refuse such a trial, so ml fails it with the reason,
    while ml from the Doppler alone reads every trial (and fails on its outliers, its own
    way: below threshold the Doppler is no better)."""
    chosen = experiment(
        estimators=["ml", {"name": "ml", "label": "ml-doppler", "options": {"use_toa": False}}],
        sweep={"fixed": {"cn0_dbhz": 28.0}},
    )
    run_experiment(chosen, tmp_path / "run", workers=1, progress=False)
    trials = read_trials(tmp_path / "run")
    ml = trials[trials["estimator"] == "ml"].set_index("trial")
    doppler = trials[trials["estimator"] == "ml-doppler"].set_index("trial")
    assert len(ml) == len(doppler) == 6
    refused = ml["message"].str.startswith("the front end's measurements are refused: toa_s")
    assert refused.sum() >= 3 and not ml.loc[refused, "success"].any()
    assert not doppler["message"].str.contains("refused").any()
    # every row's time holds the front end's share: the refused ones too, which ran nothing else
    assert (doppler["runtime_s"] > 0.0).all() and (ml["runtime_s"] > 0.0).all()


def test_dpd_reads_the_samples_every_estimator_of_measurements_reads_through_the_front_end(
    tmp_path: Path,
) -> None:
    """dpd in a [signal] run: one row per trial, held to the same bound as ml (the bursts'
    Doppler and ToA, the signal-level bound, MATH §21), within a few √CRLB at 50 dB-Hz; a
    measurement-level experiment refuses it at load, in one line."""
    chosen = experiment(estimators=["ml", "dpd"], sweep={"fixed": {"cn0_dbhz": 50.0}}, trials=4)
    run_experiment(chosen, tmp_path / "run", workers=1, progress=False)
    trials = read_trials(tmp_path / "run")
    dpd = trials[trials["estimator"] == "dpd"]
    ml = trials[trials["estimator"] == "ml"]
    assert len(dpd) == 4 and dpd["success"].all()
    assert (dpd["crlb_rmse_m"].to_numpy() == ml["crlb_rmse_m"].to_numpy()).all()
    assert (dpd["error_m"] < 5.0 * dpd["crlb_rmse_m"]).all()
    with pytest.raises(ValueError) as caught:
        Experiment.from_dict(
            {"name": "m", "scenarios": ["turn"], "trials": 1, "seed": 0, "estimators": ["dpd"]}
        )
    assert str(caught.value).startswith("estimators[0]: 'dpd' reads the received samples")
