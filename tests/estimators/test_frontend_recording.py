"""The front end over a recording (estimators/frontend/recording.py): streamed a block of bursts
at a time, it measures what it measures on the bursts held in memory, whatever the block."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from estimators.frontend import track_doppler_search_hz
from estimators.frontend.measure import measure_bursts
from estimators.frontend.recording import measure_recording
from scenarios.catalog import get_scenario
from scenarios.recording import open_recording, write_recording
from scenarios.signal import BurstPlan, received_bursts
from scenarios.simulate import noise_free

# turn: Doppler within ±6 Hz; 5 ms bursts at 40 dB-Hz, 17 dB: above threshold
PLAN = BurstPlan(
    waveform="bpsk", burst_s=5e-3, sample_rate_hz=1e5, chip_rate_hz=2.5e4, cn0_dbhz=40.0
)


@pytest.mark.bits(
    "measure_bursts on the same bursts' samples: a burst's result does not depend on the others "
    "measured beside it (MATH §19), and the σ's are the same function of the same arrays"
)
def test_a_recording_streamed_in_any_block_is_measured_as_in_memory(tmp_path: Path) -> None:
    scenario = get_scenario("turn")
    geometry = noise_free(scenario)
    received = received_bursts(scenario, PLAN, [11])
    meta_path, _ = write_recording(tmp_path / "rec", geometry, PLAN, received)
    recording = open_recording(meta_path)
    in_memory = measure_bursts(
        received.samples[0].astype(np.complex64).astype(np.complex128),
        PLAN,
        time_s=geometry.time_s,
        emission_time_s=received.emission_time_s,
    )
    for block in (1, 7, 64):
        data, measured = measure_recording(recording, block)
        np.testing.assert_array_equal(measured.doppler_hz, in_memory.doppler_hz)
        np.testing.assert_array_equal(measured.toa_s, in_memory.toa_s)
        np.testing.assert_array_equal(measured.below_threshold, in_memory.below_threshold)
        np.testing.assert_array_equal(data.doppler_hz, in_memory.doppler_hz)
        np.testing.assert_array_equal(data.toa_s, in_memory.toa_s)
        np.testing.assert_array_equal(data.position_m, geometry.position_m)
    # the measurements are the truth's within a few of their own σ's (far above threshold)
    assert not measured.below_threshold.any()
    doppler_z = (data.doppler_hz - geometry.doppler_hz) / np.sqrt(measured.doppler_variance_hz2)
    toa_z = (data.toa_s - geometry.toa_s) / np.sqrt(measured.toa_variance_s2)
    assert np.abs(doppler_z).max() < 5.0
    assert np.abs(toa_z).max() < 5.0


def test_a_recording_is_required() -> None:
    with pytest.raises(ValueError, match=r"^recording: expected a Recording, got str$"):
        measure_recording("rec.sigmf-meta")


@pytest.mark.bits("measure_bursts on the same bursts' samples, read from the file or held")
def test_a_tone_s_recording_is_sought_within_its_track_s_doppler(tmp_path: Path) -> None:
    """A CW recording of turn (the carrier offset known) at 33 dB-Hz, bursts of 5 ms at
    SNR_burst 10 dB: measured as in memory with the track's search ``γ max‖v‖`` (10 Hz) as the
    frequency's band, every Doppler within it plus a bin's margin; over the whole band (a
    search of 0) more bursts are flagged (16 of 20 against 4: the threshold counts 500 cells,
    not 2.1)."""
    scenario = get_scenario("turn")
    geometry = noise_free(scenario)
    plan = BurstPlan(waveform="cw", burst_s=5e-3, sample_rate_hz=1e5, cn0_dbhz=33.0)
    received = received_bursts(scenario, plan, [12])
    meta_path, _ = write_recording(tmp_path / "rec", geometry, plan, received)
    recording = open_recording(meta_path)
    search_hz = track_doppler_search_hz(recording.geometry)
    assert np.abs(geometry.doppler_hz).max() <= search_hz < 20.0

    def in_memory(doppler_search_hz):
        return measure_bursts(
            received.samples[0].astype(np.complex64).astype(np.complex128),
            plan,
            time_s=geometry.time_s,
            emission_time_s=received.emission_time_s,
            doppler_search_hz=doppler_search_hz,
        )

    _, measured = measure_recording(recording)
    banded = in_memory(search_hz)
    np.testing.assert_array_equal(measured.doppler_hz, banded.doppler_hz)
    np.testing.assert_array_equal(measured.below_threshold, banded.below_threshold)
    assert np.all(np.abs(measured.doppler_hz) <= (search_hz + 1 / plan.burst_s) * (1 + 1e-12))
    _, whole = measure_recording(recording, doppler_search_hz=0.0)
    assert whole.below_threshold.sum() > measured.below_threshold.sum()
