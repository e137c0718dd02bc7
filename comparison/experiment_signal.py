"""The signal level of an experiment (``[signal]``, docs/math.md §18-§20): the table's keys and
checks, the burst plan at a point, the front end's Doppler search, and a scenario as the bursts
measure it. :class:`comparison.experiment.Experiment` holds the table and asks here; the TOML
format is in :mod:`comparison.experiment`'s text."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

from comparison.specs import check_keys
from estimators.frontend import search_cells_hz, track_doppler_search_hz
from scenarios.catalog import get_scenario
from scenarios.fields import FrozenDict
from scenarios.signal import BurstPlan, burst_truth, noise_at_cn0
from scenarios.simulate import noise_free
from scenarios.types import NoiseSigmas, Scenario

SIGNAL_PARAMETER = "cn0_dbhz"
"""The axis of an experiment at the signal level (``[signal]``): C/N0 in dB-Hz (MATH §18)."""

CN0_RANGE_DBHZ = (-20.0, 120.0)
"""The C/N0 values an experiment accepts, dB-Hz (inclusive)."""

SIGNAL_KEYS = (
    "doppler_search_hz",
    "waveform",
    "burst_s",
    "sample_rate_hz",
    "chip_rate_hz",
    "chip_seed",
    "received_power_w",
    "guard_s",
)
"""The keys of ``[signal]``: the fields of :class:`scenarios.signal.BurstPlan` but its C/N0
(the point's), and the front end's Doppler search."""


def checked_signal(
    signal: Any, swept: set[str | None], points: Iterable[Mapping[str, float]], closed_loop: bool
) -> FrozenDict:
    """The ``[signal]`` table checked, with what it asks of the rest of the experiment: the
    ``cn0_dbhz`` axis (``swept`` names the swept and fixed parameters; ``snr_db`` refused),
    open loop, one estimate a trial, a burst with a delay, and a burst plan at every point."""
    if not isinstance(signal, Mapping):
        raise ValueError(f"signal: expected a table, got {type(signal).__name__}")
    check_keys(signal, SIGNAL_KEYS, "signal")
    signal = FrozenDict(signal)
    if "snr_db" in swept:
        raise ValueError(
            "sweep: a [signal] experiment's axis is cn0_dbhz (dB-Hz), not snr_db; "
            "sweep or fix cn0_dbhz instead"
        )
    if SIGNAL_PARAMETER not in swept:
        raise ValueError(
            "sweep: a [signal] experiment needs cn0_dbhz; sweep it "
            "(parameter = 'cn0_dbhz') or fix it ([sweep.fixed] cn0_dbhz = 40)"
        )
    if closed_loop:
        raise ValueError("planners: a [signal] experiment is open loop; remove the planners")
    if signal.get("waveform", "bpsk") != "bpsk":
        raise ValueError(
            "signal.waveform: a tone carries no delay, so no ToA; use 'bpsk' in experiments"
        )
    for settings in points:
        plan = burst_plan(signal, settings)
    try:
        search_cells_hz(signal.get("doppler_search_hz"), plan)
    except ValueError as error:
        raise ValueError(f"signal.{error}") from None
    return signal


def check_doppler_search(signal: Mapping[str, Any], scenarios: Iterable[str]) -> None:
    """A search span for every scenario whose carrier offset is unknown (MATH §20): no flight
    bounds its Doppler."""
    if signal.get("doppler_search_hz") is not None:
        return
    for name in scenarios:
        if "carrier_offset_hz" in get_scenario(name).unknowns:
            raise ValueError(
                f"signal.doppler_search_hz: scenario {name!r}'s carrier offset is unknown, "
                "so no flight bounds the Doppler the front end must search; give the span "
                "(±Hz), e.g. the largest offset expected plus γ·max|v|"
            )


def burst_plan(signal: Mapping[str, Any], settings: Mapping[str, float]) -> BurstPlan:
    """The bursts and the receiver at a point's ``settings`` (its ``cn0_dbhz``), errors named
    by their key in ``[signal]``."""
    fields = {k: v for k, v in signal.items() if k != "doppler_search_hz"}
    try:
        return BurstPlan(**{"waveform": "bpsk", **fields}, cn0_dbhz=settings[SIGNAL_PARAMETER])
    except ValueError as error:
        raise ValueError(f"signal.{error}") from None


def doppler_search_of(signal: Mapping[str, Any], scenario: Scenario) -> float | None:
    """The front end's Doppler search (MATH §20): ``[signal]``'s ``doppler_search_hz``, else
    what the scenario's flight calls for (γ·max‖v‖,
    :func:`estimators.frontend.track_doppler_search_hz`)."""
    if signal.get("doppler_search_hz") is not None:
        return float(signal["doppler_search_hz"])
    return track_doppler_search_hz(noise_free(scenario))


def received_scenario(scenario: Scenario, plan: BurstPlan) -> Scenario:
    """``scenario`` measured through bursts of ``plan``: its Doppler and ToA σ's those the
    bursts allow at the plan's C/N0 (:func:`scenarios.signal.noise_at_cn0`, MATH §18), its RSS
    not measured. Raises naming ``sample_rate_hz`` when the Doppler leaves the band."""
    burst_truth(scenario, plan)
    noise = noise_at_cn0(plan)
    return dataclasses.replace(
        scenario,
        noise=NoiseSigmas(doppler_hz=noise.doppler_hz, toa_s=noise.toa_s),
        modalities=tuple(m for m in scenario.modalities if m != "rss"),
    )
