"""What the batch estimators' tests share: families of seeded trials, one generator per
trial, a scenario turned off the axes, and the comparison of two estimates of one trial."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from estimators.base import Estimate
from estimators.cls_rows import LocalFrame
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import MeasurementBatch, MeasurementSet, Scenario

Families = Mapping[str, tuple[Callable[[], Scenario], float]]
"""Family name -> (the scenario, the SNR in dB)."""


def family_batch(families: Families, name: str, n: int, seed: int = 0) -> MeasurementBatch:
    """``n`` seeded trials of family ``name``."""
    build, snr_db = families[name]
    return simulate_trials(build(), snr_db=snr_db, seeds=trial_seeds(seed, n))


def generators(n: int, seed: int = 100) -> list[np.random.Generator]:
    """One generator per trial."""
    return [np.random.default_rng(seed + i) for i in range(n)]


def field_differences(single: Estimate, got: Estimate) -> list[str]:
    """How the estimator name, ``success``, ``ambiguous`` and message differ (empty: equal)."""
    return [
        f"{field} {getattr(single, field)!r} vs {getattr(got, field)!r}"
        for field in ("estimator", "success", "ambiguous", "message")
        if getattr(single, field) != getattr(got, field)
    ]


def answer_differences(
    estimator, trial: MeasurementSet, single: Estimate, got: Estimate, rtol: float
) -> list[str]:
    """:func:`field_differences`, then the candidates (same order) and the returned position
    within ``rtol`` of the problem's length scale, ``max(‖p‖, L)`` with ``L`` the local
    frame's scale of the frames the estimator uses (MATH §5)."""
    problems = field_differences(single, got)
    used = trial.select_frames(estimator.frames)
    length = LocalFrame.fit(used.position_m, used.range_m).scale_m
    scale = max(float(np.max(np.abs(single.position_m), initial=0.0)), length)
    if single.candidates_m.shape != got.candidates_m.shape or np.any(
        np.abs(single.candidates_m - got.candidates_m) > rtol * scale
    ):
        problems.append(f"candidates {single.candidates_m.tolist()} vs {got.candidates_m.tolist()}")
    if not np.allclose(
        single.position_m, got.position_m, rtol=0.0, atol=rtol * scale, equal_nan=True
    ):
        problems.append(f"position {single.position_m.tolist()} vs {got.position_m.tolist()}")
    return problems


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
