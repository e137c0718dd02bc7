"""Shared, seeded scenarios: geometry, flight, measurement model and simulation.

Data flows one way: ``scenarios`` → ``estimators`` → ``comparison``.
"""

from scenarios.catalog import CATALOG, get_scenario
from scenarios.signal import BurstPlan, ReceivedBursts, received_bursts
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import (
    MODALITIES,
    SPEED_OF_LIGHT_MPS,
    FlightPlan,
    MeasurementBatch,
    MeasurementSet,
    NoiseSigmas,
    RssModel,
    Scenario,
)

__all__ = [
    "CATALOG",
    "MODALITIES",
    "SPEED_OF_LIGHT_MPS",
    "BurstPlan",
    "FlightPlan",
    "MeasurementBatch",
    "MeasurementSet",
    "NoiseSigmas",
    "ReceivedBursts",
    "RssModel",
    "Scenario",
    "get_scenario",
    "noise_free",
    "received_bursts",
    "simulate",
    "simulate_trials",
    "trial_seeds",
]
