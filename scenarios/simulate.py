"""Seeded simulation of Doppler, ToA and RSS measurements (MATH §1, with the SNR axis of §2).

Every random draw comes from a ``numpy.random.Generator`` built from one
``numpy.random.SeedSequence`` per trial, and every trial draws its noise in the same fixed
order (a standard-normal block of shape (3, N): Doppler, ToA, RSS) whatever the modalities
simulated. So trial ``i`` of a run is the same wherever and in whichever order it runs, and every
estimator and modality subset sees common random numbers.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenarios import measurement_model as model
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.types import MODALITIES, MeasurementBatch, MeasurementSet, Scenario

SeedLike = int | np.random.SeedSequence


def noise_free(scenario: Scenario, *, snr_db: float = 0.0) -> MeasurementSet:
    """The scenario's exact measurements, labelled with the σ's of ``snr_db`` (MATH §2)."""
    flight = scenario.flight
    position = flight.sample_positions_m()
    velocity = flight.sample_velocities_mps()
    emitter, height = scenario.emitter_m, scenario.emitter_height_m
    # a known offset is corrected by the receiver: only the unknown ones reach the data (§15)
    offset_hz = scenario.carrier_offset_hz if "carrier_offset_hz" in scenario.unknowns else None
    emission_s = scenario.emission_time_s if "emission_time_s" in scenario.unknowns else None
    # an unknown height is the truth's third coordinate; the data then say only what an
    # estimator that ignores it assumes: the take-off ground (MATH §8)
    height_unknown = HEIGHT_UNKNOWN in scenario.unknowns
    truth = scenario.truth_emitter_m
    values = {
        "doppler": lambda: model.doppler_hz(
            position, velocity, emitter, scenario.gamma_per_m, height, offset_hz or 0.0
        ),
        "toa": lambda: model.toa_s(
            position, emitter, scenario.speed_of_light_mps, height, emission_s or 0.0
        ),
        "rss": lambda: model.rss_dbm(position, emitter, scenario.rss_model, height),
    }
    present = {m: values[m]() if m in scenario.modalities else None for m in MODALITIES}
    return MeasurementSet(
        frame=flight.sample_frames(),
        time_s=flight.sample_times_s(),
        position_m=position,
        velocity_mps=velocity,
        doppler_hz=present["doppler"],
        toa_s=present["toa"],
        rss_dbm=present["rss"],
        carrier_hz=scenario.carrier_hz,
        speed_of_light_mps=scenario.speed_of_light_mps,
        emitter_height_m=0.0 if height_unknown else height,
        noise=scenario.noise.at_snr(snr_db),
        rss_model=scenario.rss_model if "rss" in scenario.modalities else None,
        truth_emitter_m=truth,
        unknowns=scenario.unknowns,
        truth_carrier_offset_hz=offset_hz,
        truth_emission_time_s=emission_s,
        terrain=scenario.terrain,
    )


def standard_noise(seed: SeedLike, n_samples: int) -> np.ndarray:
    """One trial's standard-normal draws, shape (3, n_samples): Doppler, ToA, RSS rows."""
    return np.random.default_rng(seed).standard_normal((len(MODALITIES), n_samples))


def simulate_trials(
    scenario: Scenario, *, snr_db: float, seeds: Sequence[SeedLike]
) -> MeasurementBatch:
    """Noisy measurements of ``len(seeds)`` trials, one seed (SeedSequence child) per trial."""
    exact = noise_free(scenario, snr_db=snr_db)
    if len(seeds) == 0:
        raise ValueError("seeds: need at least one trial")
    draws = np.stack([standard_noise(seed, exact.n_samples) for seed in seeds], axis=1)
    noisy = {}
    for row, (modality, name) in enumerate(
        (("doppler", "doppler_hz"), ("toa", "toa_s"), ("rss", "rss_dbm"))
    ):
        value = getattr(exact, name)
        if value is None:
            noisy[name] = None
        else:
            noisy[name] = value + exact.noise.for_modality(modality) * draws[row]
    return MeasurementBatch(geometry=exact, **noisy)


def simulate(scenario: Scenario, *, snr_db: float = 0.0, seed: SeedLike = 0) -> MeasurementSet:
    """One noisy trial (MATH §1-§2), reproducible from ``seed``."""
    return simulate_trials(scenario, snr_db=snr_db, seeds=[seed]).trial(0)


def trial_seeds(seed: int, n_trials: int) -> list[np.random.SeedSequence]:
    """``SeedSequence(seed).spawn(n_trials)``: child ``i`` drives trial ``i``."""
    return np.random.SeedSequence(seed).spawn(n_trials)
