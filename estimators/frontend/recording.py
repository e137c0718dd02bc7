"""The front end over a SigMF recording (:mod:`scenarios.recording`): every burst measured, the
samples read from disk a block of bursts at a time (docs/math.md §18, §19)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from estimators.frontend.measure import BurstMeasurements, measure_bursts, measurement_set
from scenarios.recording import Recording
from scenarios.types import MeasurementSet


def measure_recording(
    recording: Recording, block: int = 64
) -> tuple[MeasurementSet, BurstMeasurements]:
    """The recording's measurement set (its geometry with the measured Doppler and ToA and
    their σ's) and the per-burst measurements, ``block`` bursts read and measured at a time:
    the memory held is a block's samples and a few numbers per burst."""
    if not isinstance(recording, Recording):
        raise ValueError(f"recording: expected a Recording, got {type(recording).__name__}")
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
