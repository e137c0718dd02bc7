"""The scenario parameters an experiment can vary, and the scenario at given parameter values.

:func:`with_parameter` returns a copy of a :class:`~scenarios.types.Scenario` with one named
parameter changed; :data:`SWEEPABLE` lists the names. The SNR is not a scenario parameter (a
scenario holds the reference σ's at 0 dB and the SNR scales them at simulation time, MATH §2),
so ``snr_db`` is handled by whoever simulates, not here.

Every value is checked before it is applied (:func:`check_parameter_value`), so an experiment
file with a negative σ or a fractional frame count fails at load, naming the parameter.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from scenarios import fields
from scenarios.types import Scenario

SWEEPABLE: dict[str, str] = {
    "range_sigma_m": "ToA range noise c·σ_τ at 0 dB SNR, metres (MATH §1-§2)",
    "doppler_sigma_hz": "Doppler noise σ_f at 0 dB SNR, hertz (MATH §1-§2)",
    "rss_sigma_db": "RSS noise σ_P at 0 dB SNR, decibels (MATH §1-§2)",
    "samples_per_frame": "K, the samples in each frame (whole number >= 1)",
    "sample_interval_s": "Δ, the time between samples, seconds",
    "frames": "number of frames flown (extended at the last frame's velocity)",
    "speed_mps": "speed of every frame, metres per second (headings kept)",
    "emitter_x_m": "emitter east coordinate, metres",
    "emitter_y_m": "emitter north coordinate, metres",
    "emitter_height_m": "emitter height z_s (known), metres",
}
"""Scenario parameters :func:`with_parameter` can set: name → one-line description."""

_POSITIVE = frozenset(
    {"range_sigma_m", "doppler_sigma_hz", "rss_sigma_db", "sample_interval_s", "speed_mps"}
)
_WHOLE = frozenset({"samples_per_frame", "frames"})


def check_parameter_value(name: str, value: float) -> float:
    """``value`` as a float if it is valid for the sweepable parameter ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`SWEEPABLE`.
    value : float
        The value to check: a finite number; > 0 for σ's, Δ and the speed; a whole number
        >= 1 for ``samples_per_frame`` and ``frames``.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Naming ``name`` and saying what is allowed.
    """
    if name not in SWEEPABLE:
        known = ", ".join(SWEEPABLE)
        raise ValueError(
            f"{name}: not a sweepable scenario parameter; choose one of {known} "
            "(snr_db is applied at simulation time, not to the scenario)"
        )
    number = fields.number(value, name)
    if name in _POSITIVE and number <= 0.0:
        raise ValueError(f"{name}: must be > 0, got {value!r}")
    if name in _WHOLE and (number != round(number) or number < 1):
        raise ValueError(f"{name}: must be a whole number >= 1, got {value!r}")
    return number


def with_parameter(scenario: Scenario, name: str, value: float) -> Scenario:
    """A copy of ``scenario`` with the sweepable parameter ``name`` set to ``value``.

    Parameters
    ----------
    scenario : Scenario
    name : str
        One of :data:`SWEEPABLE`:

        - ``range_sigma_m``: ``c σ_τ`` at 0 dB, so ``σ_τ = value / c`` with the scenario's ``c``;
        - ``doppler_sigma_hz``, ``rss_sigma_db``: the other reference σ's at 0 dB (MATH §2);
        - ``samples_per_frame``, ``sample_interval_s``: K and Δ of the flight plan;
        - ``frames``: the first ``value`` frames, or the plan extended at its last velocity;
        - ``speed_mps``: every frame velocity rescaled to this speed (3-D norm), headings and
          climb angles kept; a frame with zero velocity cannot be rescaled;
        - ``emitter_x_m``, ``emitter_y_m``, ``emitter_height_m``: the emitter position.
    value : float
        See :func:`check_parameter_value` for the allowed range.

    Returns
    -------
    Scenario
        Validated again; same name.

    Raises
    ------
    ValueError
        Unknown ``name`` (the message lists the known ones) or a value out of range.
    """
    number = check_parameter_value(name, value)
    noise = scenario.noise
    flight = scenario.flight
    if name == "range_sigma_m":
        return scenario.replace(noise=replace(noise, toa_s=number / scenario.speed_of_light_mps))
    if name == "doppler_sigma_hz":
        return scenario.replace(noise=replace(noise, doppler_hz=number))
    if name == "rss_sigma_db":
        return scenario.replace(noise=replace(noise, rss_db=number))
    if name == "samples_per_frame":
        return scenario.replace(flight=replace(flight, samples_per_frame=int(number)))
    if name == "sample_interval_s":
        return scenario.replace(flight=replace(flight, sample_interval_s=number))
    if name == "frames":
        return scenario.replace(flight=flight.with_n_frames(int(number)))
    if name == "speed_mps":
        velocities = np.asarray(flight.frame_velocities_mps)
        speeds = np.linalg.norm(velocities, axis=1)
        if np.any(speeds == 0.0):
            frame = int(np.argmin(speeds))
            raise ValueError(
                f"speed_mps: frame {frame} of scenario {scenario.name!r} has zero velocity, "
                "so it has no heading to keep; sweep a scenario whose frames all move"
            )
        return scenario.replace(
            flight=replace(flight, frame_velocities_mps=velocities * (number / speeds)[:, None])
        )
    if name == "emitter_x_m":
        return scenario.replace(emitter_m=[number, scenario.emitter_m[1]])
    if name == "emitter_y_m":
        return scenario.replace(emitter_m=[scenario.emitter_m[0], number])
    # name == "emitter_height_m" (check_parameter_value rejected everything else)
    return scenario.replace(emitter_height_m=number)


def with_parameters(scenario: Scenario, values: Mapping[str, float]) -> Scenario:
    """``scenario`` with every ``name: value`` of ``values`` applied by :func:`with_parameter`.

    The parameters are independent of one another, so the order does not matter.
    """
    for name, value in values.items():
        scenario = with_parameter(scenario, name, value)
    return scenario


__all__ = ["SWEEPABLE", "check_parameter_value", "with_parameter", "with_parameters"]
