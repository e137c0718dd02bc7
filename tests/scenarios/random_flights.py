"""Random flights shared by the tests of the bound: noise-free data, all three modalities."""

from __future__ import annotations

import numpy as np

from scenarios.catalog import heading_velocities_mps
from scenarios.simulate import noise_free
from scenarios.types import FlightPlan, MeasurementSet, NoiseSigmas, RssModel, Scenario


def random_data(seed: int, n_frames: int = 3, *, climb_mps: float = 0.0) -> MeasurementSet:
    """Noise-free data of a random flight of ``n_frames`` headings, all three modalities;
    ``climb_mps`` adds a vertical speed to every frame (level by default)."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 360.0)
    headings = heading + np.cumsum(np.r_[0.0, rng.uniform(30.0, 150.0, n_frames - 1)])
    velocities = np.array(heading_velocities_mps(rng.uniform(5.0, 30.0), list(headings)))
    velocities[:, 2] += climb_mps
    scenario = Scenario(
        name="random",
        emitter_m=rng.uniform(-300.0, 300.0, 2),
        flight=FlightPlan(
            start_position_m=[*rng.uniform(-300.0, 300.0, 2), rng.uniform(20.0, 200.0)],
            frame_velocities_mps=velocities,
            samples_per_frame=int(rng.integers(3, 12)),
            sample_interval_s=rng.uniform(0.05, 1.0),
        ),
        carrier_hz=rng.uniform(1e8, 5e9),
        emitter_height_m=rng.uniform(-5.0, 5.0),
        noise=NoiseSigmas(
            doppler_hz=rng.uniform(0.01, 2.0),
            toa_s=rng.uniform(0.3, 30.0) / 299_792_458.0,
            rss_db=rng.uniform(1.0, 8.0),
        ),
        rss_model=RssModel(
            reference_power_dbm=-20.0, reference_distance_m=1.0, path_loss_exponent=2.5
        ),
    )
    return noise_free(scenario)
