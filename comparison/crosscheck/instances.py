"""The seeded instance families: one stacked system ``A r = b`` per seed (MATH §5).

The 2-D families solve for ``r = (x, y, x² + y²)`` at the emitter's known height; the 3-D ones
(:data:`FAMILY_DIMENSION`) leave the height unknown and solve for ``r = (x, y, z, x² + y² + z²)``
(MATH §5 in three coordinates, §7 for the reflection through a level flight's plane).

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
from estimators.closed_form.constrained_ls import ConstrainedLS
from scenarios.catalog import heading_velocities_mps, paper_scenario
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan, MeasurementSet, NoiseSigmas, Scenario

FloatArray = NDArray[np.float64]

FAMILY_DIMENSION: dict[str, int] = {
    "straight": 2,
    "turn": 2,
    "turn-weighted": 2,
    "paper": 2,
    "climb-height": 3,
    "level-height": 3,
}
"""Each family's emitter coordinates: 2 (the height known), 3 (the height unknown)."""

FAMILIES: tuple[str, ...] = tuple(FAMILY_DIMENSION)
"""The instance families, in report order."""

MIN_CLIMB_VOLUME = 0.05
"""``climb-height``: least ``|det|`` of the three legs' unit velocities. Legs whose velocities
lie in one plane fly in that plane and leave its reflection at the same cost (MATH §7); a
volume this far from zero keeps the family off that tie (a unique minimiser)."""


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

    @property
    def dimension(self) -> int:
        """The emitter's coordinates in the rows: 2, or 3 with the height a coordinate."""
        return self.A.shape[1] - 1

    @property
    def problem(self) -> ConstrainedLS:
        """The rows with their frame (world and local points, the cost at world points)."""
        return ConstrainedLS.in_frame(self.A, self.b, self.frame)


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


def _random_noise(rng: np.random.Generator) -> tuple[float, float, float]:
    """A carrier, a Doppler σ and a range σ (the draws of every random family)."""
    carrier = _log_uniform(rng, 1e8, 6e9)
    doppler_sigma = _log_uniform(rng, 1e-3, 10.0)
    range_sigma = _log_uniform(rng, 1e-2, 30.0)
    return carrier, doppler_sigma, range_sigma


def _random_emitter(rng: np.random.Generator, track_m: float) -> FloatArray:
    """A horizontal emitter position: a log-uniform distance from 10 m to 2 km beyond a tenth
    of the track's length, at a uniform bearing."""
    distance = _log_uniform(rng, 10.0, 2000.0) + 0.1 * track_m
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    return distance * np.array([np.cos(bearing), np.sin(bearing)])


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
    emitter = _random_emitter(rng, speed * interval * samples * n_frames)
    carrier, doppler_sigma, range_sigma = _random_noise(rng)
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


def _random_height_scenario(rng: np.random.Generator, *, climb: bool) -> tuple[Scenario, dict]:
    """Three straight legs at random headings and an emitter at an unknown height below the
    UAV's lowest sample (MATH §5 in three coordinates, §7).

    ``climb``: each leg climbs or sinks at its own rate (a climb angle within ±25°, drawn again
    until the unit velocities span a volume of at least :data:`MIN_CLIMB_VOLUME`): no plane
    holds the flight, one minimiser. Otherwise the flight is level at one height ``h``: the
    emitter and its reflection through ``z = h`` are both minimisers (the hard case of MATH §5).
    """
    speed = rng.uniform(2.0, 40.0)
    headings = [rng.uniform(0.0, 360.0)]
    for _ in range(2):
        headings.append(headings[-1] + rng.uniform(20.0, 160.0) * rng.choice([-1.0, 1.0]))
    velocities = heading_velocities_mps(speed, headings)
    climb_deg = [0.0, 0.0, 0.0]
    if climb:
        while True:
            climb_deg = rng.uniform(-25.0, 25.0, 3).tolist()
            velocities[:, 2] = speed * np.tan(np.deg2rad(climb_deg))
            units = velocities / np.linalg.norm(velocities, axis=1, keepdims=True)
            if abs(np.linalg.det(units)) >= MIN_CLIMB_VOLUME:
                break
    samples = int(rng.integers(3, 41))
    interval = _log_uniform(rng, 0.01, 0.5)
    lowest = rng.uniform(20.0, 300.0)  # the UAV's lowest sample height
    # sample n + 1 is sample n moved by Δ v_n (FlightPlan): the heights before the start's
    rise = np.cumsum(np.repeat(velocities[:, 2], samples)[:-1] * interval)
    start_height = lowest - min(0.0, float(rise.min()))
    emitter_height = rng.uniform(0.0, 0.9) * lowest
    emitter = _random_emitter(rng, speed * interval * samples * 3)
    carrier, doppler_sigma, range_sigma = _random_noise(rng)
    scenario = Scenario(
        name="validate",
        emitter_m=emitter,
        emitter_height_m=emitter_height,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, start_height],
            frame_velocities_mps=velocities,
            samples_per_frame=samples,
            sample_interval_s=interval,
        ),
        carrier_hz=carrier,
        noise=NoiseSigmas(doppler_hz=doppler_sigma, toa_s=range_sigma / 299_792_458.0),
        modalities=("doppler", "toa"),
        unknowns=(HEIGHT_UNKNOWN,),
    )
    parameters = {
        "speed_mps": speed,
        "headings_deg": headings,
        "climb_deg": climb_deg,
        "samples_per_frame": samples,
        "sample_interval_s": interval,
        "uav_lowest_height_m": lowest,
        "emitter_m": [*emitter.tolist(), emitter_height],
        "carrier_hz": carrier,
        "doppler_sigma_hz": doppler_sigma,
        "range_sigma_m": range_sigma,
    }
    return scenario, parameters


def make_instance(family: str, seed: int, *, exact: bool = False) -> ValidationInstance:
    """The instance ``seed`` of ``family``: every draw from ``SeedSequence(seed)``.

    ``exact``: the same geometry's noise-free measurements (:func:`scenarios.simulate.noise_free`),
    whose minimisers are the emitter (and its reflection in the hard case of a level flight).
    """
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
    elif FAMILY_DIMENSION[family] == 3:
        scenario, parameters = _random_height_scenario(rng, climb=family == "climb-height")
        snr_db = 0.0
        rows = "weighted"
    else:
        n_frames = 1 if family == "straight" else 2
        scenario, parameters = _random_flight_scenario(rng, n_frames)
        snr_db = 0.0
        rows = "per-sample" if family == "turn" else "weighted"
    if exact:
        data = noise_free(scenario, snr_db=snr_db)
        parameters["noise_free"] = True
    else:
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
