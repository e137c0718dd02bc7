"""SigMF recordings of bursts (scenarios/recording.py): the files validate with the sigmf
package, the samples, plan, track, schedule and truth read back bit for bit, the samples stream
a block at a time, and a damaged recording is one line naming the field."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sigmf import sigmffile

from scenarios.catalog import get_scenario
from scenarios.recording import open_recording, recording_paths, write_recording
from scenarios.signal import BurstPlan, ReceivedBursts, received_bursts
from scenarios.simulate import noise_free

# 1 ms bursts of 100 samples: small files; the Doppler of every scenario below (at most about
# 2 kHz with roof-beacon's carrier offset) lies well inside ±fs/2
BPSK = BurstPlan(
    waveform="bpsk", burst_s=1e-3, sample_rate_hz=1e5, chip_rate_hz=2.5e4, cn0_dbhz=45.0
)
CW = BurstPlan(waveform="cw", burst_s=1e-3, sample_rate_hz=1e5, cn0_dbhz=45.0, guard_s=1e-4)


def recorded(
    folder: Path, scenario: str = "turn", plan: BurstPlan = BPSK, trials: int = 1, trial: int = 0
) -> tuple[Path, Any, ReceivedBursts]:
    chosen = get_scenario(scenario)
    geometry = noise_free(chosen)
    received = received_bursts(chosen, plan, list(range(7, 7 + trials)))
    meta_path, _ = write_recording(folder / "rec", geometry, plan, received, trial)
    return meta_path, geometry, received


def edited(meta_path: Path, edit: Any) -> None:
    metadata = json.loads(meta_path.read_text())
    edit(metadata)
    meta_path.write_text(json.dumps(metadata))


def error_line(meta_path: Path) -> str:
    with pytest.raises(ValueError) as raised:
        open_recording(meta_path)
    message = str(raised.value)
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------------------------
# the files
# --------------------------------------------------------------------------------------------


def test_the_pair_validates_with_the_sigmf_package_and_reads_there_too(tmp_path: Path) -> None:
    meta_path, geometry, received = recorded(tmp_path)
    assert meta_path == tmp_path / "rec.sigmf-meta"
    handle = sigmffile.fromfile(str(meta_path))  # checks the SHA-512 of the data too
    handle.validate()
    n_bursts, n = geometry.n_samples, BPSK.n_samples
    assert handle.get_global_field("core:datatype") == "cf32_le"
    assert handle.get_global_field("core:sample_rate") == BPSK.sample_rate_hz
    assert handle.get_global_field("core:recorder") == "emitterbench"
    assert handle.get_global_field("core:extensions") == [
        {"name": "emitterbench", "version": "1.0.0", "optional": True}
    ]
    assert handle.sample_count == n_bursts * n
    captures = handle.get_captures()
    assert [c["core:sample_start"] for c in captures] == [k * n for k in range(n_bursts)]
    assert {c["core:frequency"] for c in captures} == {geometry.carrier_hz}
    # each capture's time is its first sample's: the window is centred on the burst's t_k
    first_s = [c["emitterbench:time_s"] for c in captures]
    np.testing.assert_allclose(first_s, received.time_s[:, 0], rtol=0, atol=1e-12)
    annotations = handle.get_annotations()
    assert [a["core:sample_count"] for a in annotations] == [BPSK.n_burst_samples] * n_bursts
    np.testing.assert_array_equal(
        handle.read_samples(0, -1), received.samples[0].astype(np.complex64).ravel()
    )


def test_every_plan_field_is_in_the_extension(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path, plan=CW)
    plan = sigmffile.fromfile(str(meta_path)).get_global_field("emitterbench:plan")
    assert plan == {
        "waveform": "cw",
        "burst_s": 1e-3,
        "sample_rate_hz": 1e5,
        "cn0_dbhz": 45.0,
        "chip_rate_hz": None,
        "chip_seed": 0,
        "received_power_w": 1.0,
        "guard_s": 1e-4,
    }


@pytest.mark.parametrize("scenario", ["turn", "hill-terrain", "roof-beacon"])
@pytest.mark.parametrize("plan", [BPSK, CW], ids=["bpsk", "cw"])
def test_plan_track_constants_schedule_truth_and_samples_round_trip(
    tmp_path: Path, scenario: str, plan: BurstPlan
) -> None:
    meta_path, geometry, received = recorded(tmp_path, scenario, plan, trials=2, trial=1)
    recording = open_recording(meta_path)
    assert recording.plan == plan
    assert recording.trial == 1
    got = recording.geometry
    for name in ("frame", "time_s", "position_m", "velocity_mps"):
        np.testing.assert_array_equal(getattr(got, name), getattr(geometry, name))
    for name in (
        "carrier_hz",
        "speed_of_light_mps",
        "emitter_height_m",
        "unknowns",
        "truth_carrier_offset_hz",
        "truth_emission_time_s",
    ):
        assert getattr(got, name) == getattr(geometry, name), name
    if geometry.terrain is None:
        assert got.terrain is None
    else:
        assert got.terrain.as_dict() == geometry.terrain.as_dict()
    np.testing.assert_array_equal(got.truth_emitter_m, geometry.truth_emitter_m)
    np.testing.assert_array_equal(recording.emission_time_s, received.emission_time_s)
    samples = np.concatenate([block for _, block in recording.bursts(block=3)])
    assert samples.dtype == np.complex128
    np.testing.assert_array_equal(samples, received.samples[1].astype(np.complex64))


def test_the_geometry_carries_the_nominal_measurements_at_the_plans_bounds(
    tmp_path: Path,
) -> None:
    meta_path, geometry, _ = recorded(tmp_path, "beacon-pass")
    got = open_recording(meta_path).geometry
    np.testing.assert_array_equal(got.doppler_hz, np.zeros(geometry.n_samples))
    # the window is centred on the burst's arrival: t_k − e_k is its ToA (MATH §18)
    np.testing.assert_allclose(got.toa_s, geometry.toa_s, rtol=1e-12, atol=0)
    # Rife-Boorstyn, 6 / ((2π)² SNR_burst T²) · N²/(N² − 1), SNR_burst = C/N0 · T (MATH §18)
    snr_burst, t_s = 10**4.5 * 1e-3, 1e-3
    bound_hz2 = 6 / ((2 * np.pi) ** 2 * snr_burst * t_s**2) * 100**2 / (100**2 - 1)
    assert got.noise.doppler_hz**2 == pytest.approx(bound_hz2, rel=1e-12)
    assert got.rss_dbm is None
    assert open_recording(recorded(tmp_path, plan=CW)[0]).geometry.toa_s is None


def test_a_recording_without_truth_reads_without_truth(tmp_path: Path) -> None:
    chosen = get_scenario("turn")
    geometry = noise_free(chosen)
    received = received_bursts(chosen, BPSK, [3])
    blind = dataclasses.replace(geometry, truth_emitter_m=None)
    meta_path, _ = write_recording(tmp_path / "rec.sigmf-meta", blind, BPSK, received)
    assert "emitterbench:truth" not in json.loads(meta_path.read_text())["global"]
    assert open_recording(meta_path).geometry.truth_emitter_m is None


def test_the_names_with_or_without_a_suffix_are_one_pair(tmp_path: Path) -> None:
    pair = (tmp_path / "a.sigmf-meta", tmp_path / "a.sigmf-data")
    for name in ("a", "a.sigmf-meta", "a.sigmf-data"):
        assert recording_paths(tmp_path / name) == pair


# --------------------------------------------------------------------------------------------
# streaming
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("block", [1, 6, 64])
def test_bursts_are_read_a_block_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, block: int
) -> None:
    meta_path, geometry, received = recorded(tmp_path)  # 20 bursts
    recording = open_recording(meta_path)  # hashes the file, reads no sample with numpy
    reads: list[int] = []
    fromfile = np.fromfile

    def counted(*args: Any, **kwargs: Any) -> np.ndarray:
        samples = fromfile(*args, **kwargs)
        reads.append(samples.size)
        return samples

    monkeypatch.setattr(np, "fromfile", counted)
    firsts = []
    for first, samples in recording.bursts(block):
        firsts.append(first)
        expected = received.samples[0, first : first + block].astype(np.complex64)
        np.testing.assert_array_equal(samples, expected)
    n_bursts, n = geometry.n_samples, BPSK.n_samples
    assert firsts == list(range(0, n_bursts, block))
    assert max(reads) == min(block, n_bursts) * n
    assert sum(reads) == n_bursts * n  # each sample read once


# --------------------------------------------------------------------------------------------
# one line naming the field
# --------------------------------------------------------------------------------------------


def test_a_truncated_data_file_names_the_file_and_the_counts(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    data_path = tmp_path / "rec.sigmf-data"
    data_path.write_bytes(data_path.read_bytes()[:-12])
    message = error_line(meta_path)
    assert message.startswith(f"{data_path}: holds 15988 bytes (1998 samples), ")
    assert "20 bursts × 100 samples = 2000 (16000 bytes); the file is truncated" in message


def test_changed_samples_fail_the_hash(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    data_path = tmp_path / "rec.sigmf-data"
    content = bytearray(data_path.read_bytes())
    content[100] ^= 1
    data_path.write_bytes(bytes(content))
    assert error_line(meta_path).startswith("core:sha512: differs from the hash of ")


def test_a_missing_data_file(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    (tmp_path / "rec.sigmf-data").unlink()
    assert error_line(meta_path).startswith(f"{tmp_path / 'rec.sigmf-data'}: missing; ")


def test_a_missing_meta_file(tmp_path: Path) -> None:
    assert error_line(tmp_path / "none.sigmf-meta") == (
        f"{tmp_path / 'none.sigmf-meta'}: no such file; check the path"
    )


def test_a_wrong_datatype(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    edited(meta_path, lambda m: m["global"].update({"core:datatype": "ci16_le"}))
    assert error_line(meta_path) == (
        "core:datatype: expected 'cf32_le' (complex float32, little-endian), got 'ci16_le'; "
        "convert the samples to cf32_le"
    )


def test_a_missing_track(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    edited(meta_path, lambda m: m["global"].pop("emitterbench:track"))
    assert error_line(meta_path).startswith("emitterbench:track: missing; ")


@pytest.mark.parametrize(
    ("edit", "start"),
    [
        (
            lambda m: m["global"]["emitterbench:track"].pop("velocity_mps"),
            "emitterbench:track.velocity_mps: missing; ",
        ),
        (
            lambda m: m["global"]["emitterbench:track"]["position_m"][3].pop(),
            "emitterbench:track.position_m: expected ",
        ),
        (
            lambda m: m["global"]["emitterbench:track"]["time_s"].__setitem__(4, "soon"),
            "emitterbench:track.time_s: expected numbers",
        ),
        (
            # a velocity that changes inside a frame: the track's own physical check
            lambda m: m["global"]["emitterbench:track"]["velocity_mps"][1].__setitem__(0, 99.0),
            "emitterbench:track.velocity_mps",
        ),
        (
            lambda m: m["global"]["emitterbench:plan"].pop("burst_s"),
            "emitterbench:plan.burst_s: missing; ",
        ),
        (
            lambda m: m["global"]["emitterbench:plan"].__setitem__("waveform", "qpsk"),
            "emitterbench:plan.waveform: expected one of cw, bpsk",
        ),
        (
            lambda m: m["global"]["emitterbench:constants"].__setitem__("gamma_per_m", 2.0),
            "emitterbench:constants.gamma_per_m: 2.0 × c = ",
        ),
        (
            lambda m: m["global"]["emitterbench:emission_time_s"].pop(),
            "emitterbench:emission_time_s: expected shape (20), got (19,)",
        ),
        (
            lambda m: m["global"]["emitterbench:truth"].__setitem__("emitter_m", [1.0]),
            "emitterbench:truth.emitter_m: expected shape (2), got (1,)",
        ),
        (
            lambda m: m["captures"].pop(),
            "captures: 19 capture(s) for 20 bursts",
        ),
        (
            lambda m: m["captures"][2].__setitem__("core:sample_start", 250),
            "captures[2].core:sample_start: expected 200 (burst 2 at 2 × 100 samples), got 250",
        ),
        (
            lambda m: m["global"].__setitem__("core:sample_rate", 2e5),
            "core:sample_rate: 200000.0 differs from emitterbench:plan.sample_rate_hz",
        ),
    ],
)
def test_a_malformed_field_is_one_line_naming_it(tmp_path: Path, edit: Any, start: str) -> None:
    meta_path, _, _ = recorded(tmp_path)
    edited(meta_path, edit)
    assert error_line(meta_path).startswith(start)


def test_metadata_that_fails_the_sigmf_schema(tmp_path: Path) -> None:
    meta_path, _, _ = recorded(tmp_path)
    edited(meta_path, lambda m: m["global"].update({"core:sample_rate": "fast"}))
    message = error_line(meta_path)
    assert message.startswith(f"{meta_path}: fails the SigMF schema (")
    assert message.endswith("; fix the metadata")


def test_not_json(tmp_path: Path) -> None:
    meta_path = tmp_path / "rec.sigmf-meta"
    meta_path.write_text("{")
    assert error_line(meta_path).startswith(f"{meta_path}: invalid JSON at line 1")


def test_write_refuses_samples_of_another_plan(tmp_path: Path) -> None:
    chosen = get_scenario("turn")
    received = received_bursts(chosen, BPSK, [1])
    with pytest.raises(ValueError, match=r"^received: samples of shape \(1, 20, 100\) do not fit"):
        write_recording(tmp_path / "rec", noise_free(chosen), CW, received)
    with pytest.raises(ValueError, match=r"^trial: 1 is beyond the 1 trial\(s\) drawn"):
        write_recording(tmp_path / "rec", noise_free(chosen), BPSK, received, trial=1)
    assert list(tmp_path.iterdir()) == []
