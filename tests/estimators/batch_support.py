"""What the batch estimators' tests share: families of seeded trials, one generator per
trial, a scenario turned off the axes, and the comparison of two paths' estimates of one trial
(by the rule of :mod:`tests.paths`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from estimators.base import Estimate, capabilities_of
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import MeasurementBatch, MeasurementSet, Scenario
from tests import paths

Families = Mapping[str, tuple[Callable[[], Scenario], float]]
"""Family name -> (the scenario, the SNR in dB)."""


def family_batch(families: Families, name: str, n: int, seed: int = 0) -> MeasurementBatch:
    """``n`` seeded trials of family ``name``."""
    build, snr_db = families[name]
    return simulate_trials(build(), snr_db=snr_db, seeds=trial_seeds(seed, n))


def sub_batch(batch: MeasurementBatch, trials: slice) -> MeasurementBatch:
    """The trials ``trials`` of ``batch``, on its geometry."""
    return MeasurementBatch(
        geometry=batch.geometry,
        doppler_hz=batch.doppler_hz[trials],
        toa_s=batch.toa_s[trials],
        rss_dbm=None if batch.rss_dbm is None else batch.rss_dbm[trials],
    )


def generators(n: int, seed: int = 100) -> list[np.random.Generator]:
    """One generator per trial."""
    return [np.random.default_rng(seed + i) for i in range(n)]


def path_problems(
    estimator,
    trial: MeasurementSet,
    single: Estimate,
    got: Estimate,
    *,
    certified_m: float = 0.0,
    scales: Mapping[str, tuple[float, float]] | None = None,
    ignore: Sequence[str] = (),
) -> list[str]:
    """How two paths' estimates of ``trial`` differ beyond rounding (empty: they agree):
    :func:`tests.paths.estimate_problems` at the length scale of the frames ``estimator``
    uses, with ``estimator.estimate``'s measured sensitivity on this trial."""
    frames = capabilities_of(estimator).frames
    length_m = paths.length_scale_m(trial, frames, single.position_m)

    def sensitivity() -> float:
        return paths.sensitivity(
            lambda data: estimator.estimate(data, rng=np.random.default_rng(0)), trial, single
        )

    return paths.estimate_problems(
        single,
        got,
        length_m,
        sensitivity=sensitivity,
        certified_m=certified_m,
        scales=scales,
        ignore=ignore,
    )


def rotated(scenario: Scenario, angle_deg: float) -> Scenario:
    """The scenario turned about the vertical through the origin (no axis-aligned track)."""
    a = np.deg2rad(angle_deg)
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    flight = scenario.flight
    return scenario.replace(
        emitter_m=turn[:2, :2] @ scenario.emitter_m,
        flight=replace(
            flight,
            start_position_m=turn @ flight.start_position_m,
            frame_velocities_mps=flight.frame_velocities_mps @ turn.T,
        ),
    )
