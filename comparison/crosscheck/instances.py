"""The seeded instance families: one stacked system ``A r = b`` per seed (MATH §5).

Each instance is drawn from its own ``SeedSequence`` (:func:`instance_seeds`), so instance
``i`` of a family does not depend on how many are drawn, and :func:`make_instance` rebuilds it
from its seed alone.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.closed_form.cls import Rows, cls_rows
from estimators.closed_form.cls_rows import LocalFrame
from scenarios.catalog import heading_velocities_mps, paper_scenario
from scenarios.simulate import simulate
from scenarios.types import FlightPlan, MeasurementSet, NoiseSigmas, Scenario

FloatArray = NDArray[np.float64]

FAMILIES: tuple[str, ...] = ("straight", "turn", "turn-weighted", "paper")
"""The instance families, in report order."""


@dataclass(frozen=True, slots=True, eq=False)
class ValidationInstance:
    """One stacked system ``A r = b`` (local frame) and how it was drawn."""

    family: str
    seed: int
    data: MeasurementSet
    frame: LocalFrame
    rows: str
    A: FloatArray
    b: FloatArray
    parameters: dict[str, Any]

    @property
    def length_scale_m(self) -> float:
        return self.frame.scale_m


def instance_seeds(seed: int, family: str, instances: int) -> list[int]:
    """``instances`` integer seeds for ``family``: instance ``i`` does not depend on the count."""
    check_family(family)
    words = np.random.SeedSequence([int(seed), zlib.crc32(family.encode())]).generate_state(
        instances, dtype=np.uint64
    )
    return [int(word) for word in words]


def check_family(family: str) -> None:
    """Raise ``ValueError`` naming the families unless ``family`` is one of :data:`FAMILIES`."""
    if family not in FAMILIES:
        raise ValueError(f"families: unknown family {family!r}; choose from {', '.join(FAMILIES)}")


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _random_flight_scenario(rng: np.random.Generator, n_frames: int) -> tuple[Scenario, dict]:
    """A random level flight of ``n_frames`` straight frames and a random ground emitter."""
    speed = rng.uniform(2.0, 40.0)
    heading = rng.uniform(0.0, 360.0)
    headings = [heading]
    for _ in range(n_frames - 1):
        turn = rng.uniform(20.0, 160.0) * rng.choice([-1.0, 1.0])
        headings.append(headings[-1] + turn)
    samples = int(rng.integers(3, 41))
    interval = _log_uniform(rng, 0.01, 0.5)
    height = rng.uniform(5.0, 200.0)
    track_m = speed * interval * samples * n_frames
    distance = _log_uniform(rng, 10.0, 2000.0) + 0.1 * track_m
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    emitter = distance * np.array([np.cos(bearing), np.sin(bearing)])
    carrier = _log_uniform(rng, 1e8, 6e9)
    doppler_sigma = _log_uniform(rng, 1e-3, 10.0)
    range_sigma = _log_uniform(rng, 1e-2, 30.0)
    scenario = Scenario(
        name="validate",
        emitter_m=emitter,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, height],
            frame_velocities_mps=heading_velocities_mps(speed, headings),
            samples_per_frame=samples,
            sample_interval_s=interval,
        ),
        carrier_hz=carrier,
        noise=NoiseSigmas(doppler_hz=doppler_sigma, toa_s=range_sigma / 299_792_458.0),
        modalities=("doppler", "toa"),
    )
    parameters = {
        "speed_mps": speed,
        "headings_deg": headings,
        "samples_per_frame": samples,
        "sample_interval_s": interval,
        "uav_height_m": height,
        "emitter_m": emitter.tolist(),
        "carrier_hz": carrier,
        "doppler_sigma_hz": doppler_sigma,
        "range_sigma_m": range_sigma,
    }
    return scenario, parameters


def make_instance(family: str, seed: int) -> ValidationInstance:
    """The instance ``seed`` of ``family``: every draw from ``SeedSequence(seed)``."""
    check_family(family)
    geometry_seed, noise_seed = np.random.SeedSequence(int(seed)).spawn(2)
    rng = np.random.default_rng(geometry_seed)
    rows: Rows
    if family == "paper":
        range_sigma = float(rng.choice([1.0, 10.0]))
        snr_db = float(rng.uniform(-10.0, 40.0))
        scenario = paper_scenario(range_sigma_m=range_sigma, name=f"paper-{range_sigma:g}m")
        scenario = scenario.replace(modalities=("doppler", "toa"))
        parameters: dict[str, Any] = {"scenario": scenario.name, "snr_db": snr_db}
        rows = "weighted"
    else:
        n_frames = 1 if family == "straight" else 2
        scenario, parameters = _random_flight_scenario(rng, n_frames)
        snr_db = 0.0
        rows = "per-sample" if family == "turn" else "weighted"
    data = simulate(scenario, snr_db=snr_db, seed=noise_seed)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    return ValidationInstance(
        family=family,
        seed=int(seed),
        data=data,
        frame=frame,
        rows=rows,
        A=A,
        b=b,
        parameters=dict(parameters, rows=rows, n_rows=len(b)),
    )
