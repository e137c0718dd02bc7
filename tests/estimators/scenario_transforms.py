"""Scenario transformations shared by the batch estimators' tests."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from scenarios.types import Scenario


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
