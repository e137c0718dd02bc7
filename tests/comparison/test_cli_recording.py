"""The command line on recordings: simulate-iq writes a SigMF pair, measure writes the
measurement file estimate reads, and estimate on the recording gives the same estimate."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sigmf import sigmffile

from comparison.crlb import fisher_information, rmse_bound_m
from scenarios.catalog import get_scenario
from scenarios.files import read_measurements
from scenarios.recording import open_recording
from scenarios.signal import BurstPlan, received_bursts
from tests.comparison.cli_support import clean_error, invoke

# turn: two legs at 300 MHz, Doppler within ±6 Hz; 40 dB-Hz: bursts of 10 ms at 20 dB, far above
# the front end's threshold (MATH §19)
TURN = ("simulate-iq", "turn", "--seed", 4, "--cn0-dbhz", 40)


def simulated_iq(folder: Path) -> Path:
    result = invoke(*TURN, "-o", folder / "rec")
    assert result.exit_code == 0, result.output
    assert result.stderr == ""  # |f| T = 0.06 cycles: no warning
    assert result.stdout == (
        f"wrote {folder / 'rec.sigmf-meta'} and {folder / 'rec.sigmf-data'}: turn, 20 bpsk "
        "bursts of 4000 samples (0.64 MB), C/N0 40 dB-Hz, burst SNR 20.0 dB, seed 4\n"
    )
    return folder / "rec.sigmf-meta"


def test_simulate_iq_writes_the_signal_models_samples_and_a_valid_pair(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    sigmffile.fromfile(str(meta_path)).validate()
    plan = BurstPlan(
        waveform="bpsk", burst_s=1e-2, sample_rate_hz=4e5, chip_rate_hz=1e5, cn0_dbhz=40.0
    )
    recording = open_recording(meta_path)
    assert recording.plan == plan
    expected = received_bursts(get_scenario("turn"), plan, [4]).samples[0]
    read = np.concatenate([samples for _, samples in recording.bursts()])
    np.testing.assert_array_equal(read, expected.astype(np.complex64))


def test_measure_then_estimate_the_file_and_the_recording_alike(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    measured_path = tmp_path / "m.json"
    result = invoke("measure", meta_path, "-o", measured_path)
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith(
        f"measured {meta_path}: 20 bpsk bursts, 0 of 20 flagged below threshold"
    )
    data = read_measurements(measured_path)
    assert data.n_samples == 20
    assert data.modalities == {"doppler", "toa"}
    truth = get_scenario("turn").truth_emitter_m
    np.testing.assert_array_equal(data.truth_emitter_m, truth)
    from_file = invoke("estimate", measured_path, "--estimator", "ml", "--json")
    from_recording = invoke("estimate", meta_path, "--estimator", "ml", "--json")
    assert from_file.exit_code == 0, from_file.output
    assert from_recording.exit_code == 0, from_recording.output
    assert from_recording.stderr.startswith(f"measured {meta_path}: 20 bpsk bursts, 0 of 20")
    estimate = json.loads(from_recording.stdout)
    assert estimate == json.loads(from_file.stdout)  # the file holds the same measurements
    # the measured σ's are the bounds at the bursts' SNR: the error is the CRLB's size
    bound_m = float(rmse_bound_m(fisher_information(data, truth, "toa+doppler")))
    assert estimate["success"] is True
    assert np.linalg.norm(np.array(estimate["position_m"]) - truth) <= 5.0 * bound_m


def test_estimate_says_on_stderr_how_many_bursts_were_flagged(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    result = invoke("estimate", meta_path, "--estimator", "ml")
    assert result.exit_code == 0, result.output
    assert result.stderr.startswith(f"measured {meta_path}: 20 bpsk bursts, 0 of 20 flagged below")
    assert result.stdout.startswith("estimator")


BEACON = ("simulate-iq", "beacon-pass", "--seed", 1, "--cn0-dbhz", 40)


def test_simulate_iq_warns_when_the_doppler_turns_too_far_over_a_bpsk_burst(
    tmp_path: Path,
) -> None:
    # beacon-pass: 1 kHz carrier offset, unknown, and its Doppler, up to 1020 Hz: 10.2 cycles
    # in 10 ms; the search suggested is 1.1 times that, rounded up to two digits
    args = (*BEACON, "-o", tmp_path / "rec")
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert result.stderr == (
        "warning: the Doppler turns 10.2 cycles over a burst and the carrier offset is unknown: "
        "measure the recording with --doppler-search-hz 1200 (its largest |Doppler|, 1020 Hz, "
        "and a margin; MATH §20), or shorten --burst-s to 9e-05 s, or use --waveform cw\n"
    )
    assert invoke(*args, "--waveform", "cw").stderr == ""


def test_beacon_pass_s_default_recording_measured_with_a_doppler_search(tmp_path: Path) -> None:
    """beacon-pass's default bursts (10 ms, f T = 10) at 50 dB-Hz (burst SNR 30 dB): searched
    over ±1.2 kHz (97 cells) no burst is flagged and ``ml`` is within 5 √CRLB of the truth
    (the CRLB at the σ's measured, the carrier offset and emission time unknown); without
    ``--doppler-search-hz`` the unknown offset is one line naming the option."""
    result = invoke(
        "simulate-iq", "beacon-pass", "--seed", 3, "--cn0-dbhz", 50, "-o", tmp_path / "rec"
    )
    assert result.exit_code == 0, result.output
    meta_path = tmp_path / "rec.sigmf-meta"
    line = clean_error(invoke("estimate", meta_path, "--estimator", "ml"), "--doppler-search-hz: ")
    assert "carrier offset is unknown" in line
    clean_error(invoke("measure", meta_path, "-o", tmp_path / "m.json"), "--doppler-search-hz: ")
    searched = ("--doppler-search-hz", 1200)
    estimate = invoke("estimate", meta_path, "--estimator", "ml", "--json", *searched)
    assert estimate.exit_code == 0, estimate.output
    assert estimate.stderr.startswith(f"measured {meta_path}: 40 bpsk bursts, 0 of 40 flagged")
    assert estimate.stderr.endswith("; Doppler searched within ±1200 Hz (97 cells)\n")
    measured_path = tmp_path / "m.json"
    assert invoke("measure", meta_path, "-o", measured_path, *searched).exit_code == 0
    data = read_measurements(measured_path)
    truth = get_scenario("beacon-pass").truth_emitter_m
    bound_m = float(rmse_bound_m(fisher_information(data, truth, "toa+doppler")))
    position_m = np.array(json.loads(estimate.stdout)["position_m"])
    assert np.linalg.norm(position_m - truth) <= 5.0 * bound_m, (position_m, bound_m)


def test_a_doppler_search_is_refused_for_a_measurement_file(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    measured_path = tmp_path / "m.json"
    assert invoke("measure", meta_path, "-o", measured_path).exit_code == 0
    for command in ("estimate", "crlb"):
        clean_error(
            invoke(command, measured_path, "--doppler-search-hz", 10), "--doppler-search-hz: only"
        )
    clean_error(
        invoke("measure", meta_path, "-o", measured_path, "--doppler-search-hz", -1),
        "--doppler-search-hz: -1 Hz is outside",
    )


@pytest.mark.parametrize(
    ("options", "field"),
    [
        (("--waveform", "qpsk"), "--waveform"),
        (("--burst-s", "0"), "--burst-s"),
        (("--chip-rate-hz", "3e5"), "--chip-rate-hz"),
        # beacon-pass: Doppler and carrier offset near 2 kHz, beyond ±fs/2 = ±1 kHz
        (("--sample-rate-hz", "2e3", "--waveform", "cw"), "--sample-rate-hz"),
        # 40 bursts of 10 s at 400 kHz: 160 million samples
        (("--burst-s", "10"), "--burst-s"),
    ],
)
def test_simulate_iq_refuses_a_bad_plan_and_writes_nothing(
    tmp_path: Path, options: tuple[str, ...], field: str
) -> None:
    args = ("simulate-iq", "beacon-pass", "--seed", 1, "--cn0-dbhz", 40, *options)
    clean_error(invoke(*args, "-o", tmp_path / "rec"), f"{field}: ")
    assert list(tmp_path.iterdir()) == []


def test_a_truncated_recording_is_one_line(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    data_path = tmp_path / "rec.sigmf-data"
    data_path.write_bytes(data_path.read_bytes()[:-8])
    line = clean_error(invoke("measure", meta_path, "-o", tmp_path / "m.json"), f"{data_path}: ")
    assert "the file is truncated" in line
    clean_error(invoke("estimate", meta_path), f"{data_path}: ")
    assert not (tmp_path / "m.json").exists()


def test_csv_constants_are_refused_for_a_recording(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    clean_error(invoke("estimate", meta_path, "--carrier-hz", 1e9), "--carrier-hz: only for CSV")


def test_measure_writes_json_only(tmp_path: Path) -> None:
    meta_path = simulated_iq(tmp_path)
    clean_error(invoke("measure", meta_path, "-o", tmp_path / "m.csv"), "--output: ")


def test_dpd_estimates_from_the_recordings_samples_and_refuses_a_measurement_file(
    tmp_path: Path,
) -> None:
    """`estimate REC --estimator dpd` reads the samples (MATH §22), the same answer as the
    estimator called on them, within a few √CRLB of the truth; on a measurement file it is one
    line naming --estimator."""
    from estimators.dpd import DirectPosition

    meta_path = simulated_iq(tmp_path)
    result = invoke("estimate", meta_path, "--estimator", "dpd", "--json")
    assert result.exit_code == 0, result.output
    answer = json.loads(result.stdout)
    recording = open_recording(meta_path)
    samples = np.concatenate([block for _, block in recording.bursts()])
    direct = DirectPosition().estimate_iq(
        recording.geometry.without_truth(),
        recording.plan,
        samples,
        recording.emission_time_s,
        rng=np.random.default_rng(0),
    )
    np.testing.assert_array_equal(answer["position_m"], direct.position_m)
    truth = get_scenario("turn").truth_emitter_m
    noise = recording.geometry.noise
    bound_m = rmse_bound_m(fisher_information(recording.geometry, truth, "toa+doppler"))
    assert np.linalg.norm(np.asarray(answer["position_m"]) - truth) < 5.0 * bound_m, noise
    measured_path = tmp_path / "m.json"
    assert invoke("measure", meta_path, "-o", measured_path).exit_code == 0
    refused = invoke("estimate", measured_path, "--estimator", "dpd")
    clean_error(refused, "--estimator")
    assert "locates from the received samples" in refused.stderr
