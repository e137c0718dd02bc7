"""The front end over a SigMF recording (:mod:`scenarios.recording`): every burst measured, the
samples read from disk a block of bursts at a time (docs/math.md §18, §19, §20)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from estimators.frontend.measure import (
    BurstMeasurements,
    measure_bursts,
    measurement_set,
    track_doppler_search_hz,
)
from scenarios.recording import Recording
from scenarios.types import MeasurementSet


def measure_recording(
    recording: Recording, block: int = 64, *, doppler_search_hz: float | None = None
) -> tuple[MeasurementSet, BurstMeasurements]:
    """The recording's measurement set (its geometry with the measured Doppler and ToA and
    their σ's) and the per-burst measurements, ``block`` bursts read and measured at a time:
    the memory held is a block's samples and a few numbers per burst.

    ``doppler_search_hz``: the span ``±D`` of the Doppler searched
    (:func:`~estimators.frontend.measure_bursts`, docs/math.md §19, §20: the BPSK first pass's
    cells and the frequency's band; for a tone the band alone), 0 for none; None takes
    :func:`~estimators.frontend.measure.track_doppler_search_hz` of its geometry. A BPSK
    recording of an unknown carrier offset, whose Doppler only the caller can bound, is then
    refused; a tone's is searched over the whole band.
    """
    if not isinstance(recording, Recording):
        raise ValueError(f"recording: expected a Recording, got {type(recording).__name__}")
    if doppler_search_hz is None:
        doppler_search_hz = track_doppler_search_hz(recording.geometry)
        if doppler_search_hz is None and recording.plan.waveform == "bpsk":
            raise ValueError(
                "doppler_search_hz: the recording's carrier offset is unknown, and with it the "
                "Doppler of its bursts; give the largest |Doppler| expected, the offset's bound "
                "plus γ·max|v| (0: no search)"
            )
    geometry = recording.geometry
    parts = []
    for first, samples in recording.bursts(block):
        burst = slice(first, first + len(samples))
        parts.append(
            measure_bursts(
                samples,
                recording.plan,
                time_s=geometry.time_s[burst],
                emission_time_s=recording.emission_time_s[burst],
                doppler_search_hz=doppler_search_hz,
            )
        )
    joined = {
        name: None
        if getattr(parts[0], name) is None
        else np.concatenate([getattr(part, name) for part in parts])
        for name in (field.name for field in fields(BurstMeasurements))
    }
    measured = BurstMeasurements(**joined)
    return measurement_set(geometry, measured), measured
