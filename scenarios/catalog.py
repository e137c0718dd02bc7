"""Named scenarios (MATH §14): the paper's numbers, the meaningful reproductions, a turn, an orbit.

The paper's scenario as printed has ``σ_τ² = 1e−6 s²``, i.e. ``c σ_τ = 300 km`` for an emitter
62 m away: ToA is useless there. ``paper-1m`` and ``paper-10m`` keep the geometry with
``c σ_τ = 1 m`` and ``10 m``. One straight frame can never tell the side of the track (MATH §7):
``turn`` (two headings) and ``orbit`` resolve it, and give the LLS baselines full rank (MATH §9).
``beacon-pass``, ``beacon-pass-doppler`` and ``turn-noncooperative`` have a non-cooperative
emitter, whose carrier offset and emission time are unknown (MATH §15). ``hill``,
``hill-climb`` and ``roof-beacon`` put the emitter above the take-off ground at a height the
receiver does not know (MATH §7, §8): the position then has three coordinates;
``hill-terrain`` gives the receiver the hill's shape as a prior on that height (MATH §8).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenarios.terrain import Terrain
from scenarios.types import FlightPlan, NoiseSigmas, RssModel, Scenario

PAPER_SPEED_OF_LIGHT_MPS = 3.0e8
"""The paper rounds c to 3e8 m/s (MATH §14)."""


def paper_scenario(
    *, range_sigma_m: float | None = None, n_frames: int = 1, name: str = "paper"
) -> Scenario:
    """The paper's Section 5 scenario (MATH §14).

    UAV from (0, 0, 50) m at (10, 0, 0) m/s, emitter at (35, 15, 0) m, ``f0 = c = 3e8``
    (γ = 1 /m), Δ = 0.05 s, K = 10, ``σ_f² = 0.01 Hz²`` and, unless ``range_sigma_m`` gives
    ``c σ_τ``, the printed ``σ_τ² = 1e−6 s²``. The paper gives no RSS model: log-distance with
    P0 = 0 dBm at 1 m, η = 2 and σ_P = 4 dB at 0 dB.
    """
    toa_sigma_s = 1e-3 if range_sigma_m is None else range_sigma_m / PAPER_SPEED_OF_LIGHT_MPS
    return Scenario(
        name=name,
        emitter_m=[35.0, 15.0],
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=np.tile([10.0, 0.0, 0.0], (n_frames, 1)),
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
        carrier_hz=3.0e8,
        speed_of_light_mps=PAPER_SPEED_OF_LIGHT_MPS,
        emitter_height_m=0.0,
        noise=NoiseSigmas(doppler_hz=0.1, toa_s=toa_sigma_s, rss_db=4.0),
        rss_model=RssModel(
            reference_power_dbm=0.0, reference_distance_m=1.0, path_loss_exponent=2.0
        ),
        description=(
            "paper geometry, c*sigma_tau = 300 km as printed"
            if range_sigma_m is None
            else f"paper geometry, c*sigma_tau = {range_sigma_m:g} m"
        ),
    )


def heading_velocities_mps(speed_mps: float, headings_deg: list[float]) -> np.ndarray:
    """Level-flight velocities (n, 3) for headings measured from east, counter-clockwise."""
    angle = np.deg2rad(np.asarray(headings_deg, dtype=float))
    return np.column_stack([speed_mps * np.cos(angle), speed_mps * np.sin(angle), 0 * angle])


def turn_scenario() -> Scenario:
    """The paper geometry at ``c σ_τ = 1 m``, flying east for one frame and then north."""
    base = paper_scenario(range_sigma_m=1.0)
    return base.replace(
        name="turn",
        flight=FlightPlan(
            start_position_m=base.flight.start_position_m,
            frame_velocities_mps=heading_velocities_mps(10.0, [0.0, 90.0]),
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
        description="paper geometry at c*sigma_tau = 1 m, two headings (east, then north)",
    )


def paper_turn_scenario() -> Scenario:
    """10 frames of the paper geometry at ``c σ_τ = 1 m``: 4 frames east, then 6 north.

    One straight frame cannot tell the side of the track (MATH §7); the turn after frame 3
    resolves it, which is what estimators that accumulate frames should exploit.
    """
    base = paper_scenario(range_sigma_m=1.0)
    return base.replace(
        name="paper-1m-turn",
        flight=FlightPlan(
            start_position_m=base.flight.start_position_m,
            frame_velocities_mps=heading_velocities_mps(10.0, [0.0] * 4 + [90.0] * 6),
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
        description="paper-1m geometry, 10 frames, turning north after frame 3",
    )


def orbit_scenario() -> Scenario:
    """A closed 12-gon of radius ≈ 38 m around the emitter: 12 frames, 30° turn per frame."""
    base = paper_scenario(range_sigma_m=1.0)
    return base.replace(
        name="orbit",
        flight=FlightPlan(
            start_position_m=base.flight.start_position_m,
            frame_velocities_mps=heading_velocities_mps(10.0, list(np.arange(12) * 30.0)),
            samples_per_frame=10,
            sample_interval_s=0.2,
        ),
        description="12 frames of 20 m, a 30 degree turn per frame, c*sigma_tau = 1 m",
    )


BEACON_CARRIER_HZ = 406.025e6
"""A 406 MHz distress-beacon channel (MATH §15)."""


def beacon_pass_scenario(*, toa: bool = True, name: str = "beacon-pass") -> Scenario:
    """A lost distress beacon found by one UAV: a non-cooperative emitter (MATH §15).

    The beacon, on the ground at (150, 120) m, transmits near 406.025 MHz with its oscillator
    1 kHz off and on its own clock (an emission time of 12.3 ms against the receiver's). The
    UAV flies at 100 m and 20 m/s, 200 m east and then 200 m north, 4 frames of K = 10 samples
    0.5 s apart; Doppler σ_f = 0.5 Hz and, with ``toa``, c σ_τ = 10 m at 0 dB. Both the
    carrier offset and the emission time are unknown to the receiver; without ``toa`` only the
    offset matters (Doppler alone). Samples are taken as from a continuous carrier: a real
    406 MHz beacon sends a 0.5 s burst every 50 s, which a pass of 20 s would see once.
    """
    return Scenario(
        name=name,
        emitter_m=[150.0, 120.0],
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 100.0],
            frame_velocities_mps=heading_velocities_mps(20.0, [0.0, 0.0, 90.0, 90.0]),
            samples_per_frame=10,
            sample_interval_s=0.5,
        ),
        carrier_hz=BEACON_CARRIER_HZ,
        noise=NoiseSigmas(doppler_hz=0.5, toa_s=10.0 / 299_792_458.0 if toa else None),
        modalities=("doppler", "toa") if toa else ("doppler",),
        carrier_offset_hz=1000.0,
        emission_time_s=12.3e-3,
        unknowns=("carrier_offset_hz", "emission_time_s"),
        description=(
            "a 406 MHz beacon 1 kHz off its carrier, on its own clock; UAV at 100 m, 20 m/s, "
            + ("Doppler + ToA (c*sigma_tau = 10 m)" if toa else "Doppler only")
        ),
    )


def noncooperative_turn_scenario() -> Scenario:
    """``turn`` with a non-cooperative emitter: the carrier 800 Hz off and an emission time of
    0.3 ms, both unknown (MATH §15)."""
    return turn_scenario().replace(
        name="turn-noncooperative",
        carrier_offset_hz=800.0,
        emission_time_s=3e-4,
        unknowns=("carrier_offset_hz", "emission_time_s"),
        description="turn with the carrier 800 Hz off and the emission time unknown",
    )


TELEMETRY_CARRIER_HZ = 433.92e6
"""A 433 MHz ISM telemetry tag's carrier (the ``hill`` scenarios)."""


def hill_scenario(*, climb: bool = False) -> Scenario:
    """An emitter on a hill, 120 m above the UAV's take-off ground, its height unknown (MATH §8).

    A 433.92 MHz telemetry tag at (150, 120, 120) m; the UAV at 300 m and 20 m/s, 200 m east
    and then 200 m north, 4 frames of K = 10 samples 0.5 s apart; Doppler σ_f = 0.5 Hz and
    c σ_τ = 10 m at 0 dB. A level turn leaves the reflection of the emitter through the flight
    plane (at 480 m) at the same cost, which "the emitter is below the UAV" removes (MATH §7).
    With ``climb`` (``hill-climb``) the UAV climbs at 5 m/s while it flies north (to 350 m):
    the two legs then span a tilted plane, and the reflection through it, at about
    (150, 21, 515) m, fits as exactly and is dropped the same way (MATH §7).
    """
    velocities = heading_velocities_mps(20.0, [0.0, 0.0, 90.0, 90.0])
    if climb:
        velocities[2:, 2] = 5.0
    return Scenario(
        name="hill-climb" if climb else "hill",
        emitter_m=[150.0, 120.0],
        emitter_height_m=120.0,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 300.0],
            frame_velocities_mps=velocities,
            samples_per_frame=10,
            sample_interval_s=0.5,
        ),
        carrier_hz=TELEMETRY_CARRIER_HZ,
        noise=NoiseSigmas(doppler_hz=0.5, toa_s=10.0 / 299_792_458.0),
        modalities=("doppler", "toa"),
        unknowns=("emitter_height_m",),
        description=(
            "a 433.92 MHz tag 120 m up a hill, its height unknown; UAV at 300 m, east then "
            + ("north climbing 5 m/s" if climb else "north")
            + ", Doppler + ToA (c*sigma_tau = 10 m)"
        ),
    )


HILL_TERRAIN_OFFSET_M = 2.0
"""How far above the ``hill-terrain`` ground the tag sits (a short pole)."""


def hill_terrain() -> Terrain:
    """The ``hill`` scenario's hill as a known surface (MATH §8, :mod:`scenarios.terrain`): a
    Gaussian hill of width 100 m centred at (200, 150) m on level take-off ground (0 m), its
    height set so that the surface under the tag at (150, 120) m is
    :data:`HILL_TERRAIN_OFFSET_M` below it (118 m; the hill ≈ 139.9 m high); the tag sits on
    its western slope, so the prior ties the height to ``(x, y)``. σ_m = 5 m: the tag may be
    on a mast or in a tree, so the prior informs the height without fixing it."""
    centre, width = np.array([200.0, 150.0]), 100.0
    under = 120.0 - HILL_TERRAIN_OFFSET_M
    squared = float(np.sum((np.array([150.0, 120.0]) - centre) ** 2))
    return Terrain(
        sigma_m=5.0,
        hill_height_m=under / np.exp(-squared / (2.0 * width**2)),
        hill_centre_m=centre,
        hill_width_m=width,
    )


def roof_beacon_scenario() -> Scenario:
    """``beacon-pass`` with the beacon on a roof 25 m up: its carrier offset, emission time
    and height all unknown (MATH §8, §15)."""
    return beacon_pass_scenario(name="roof-beacon").replace(
        emitter_height_m=25.0,
        unknowns=("carrier_offset_hz", "emission_time_s", "emitter_height_m"),
        description=(
            "the 406 MHz beacon on a roof 25 m up: carrier offset, emission time and height "
            "unknown; UAV at 100 m, 20 m/s, Doppler + ToA (c*sigma_tau = 10 m)"
        ),
    )


@dataclass(frozen=True)
class CatalogEntry:
    name: str
    build: Callable[[], Scenario]
    summary: str


CATALOG: dict[str, CatalogEntry] = {
    entry.name: entry
    for entry in (
        CatalogEntry(
            "paper", paper_scenario, "the paper's numbers as printed (c*sigma_tau = 300 km)"
        ),
        CatalogEntry(
            "paper-1m",
            lambda: paper_scenario(range_sigma_m=1.0, name="paper-1m"),
            "paper geometry, c*sigma_tau = 1 m",
        ),
        CatalogEntry(
            "paper-10m",
            lambda: paper_scenario(range_sigma_m=10.0, name="paper-10m"),
            "paper geometry, c*sigma_tau = 10 m",
        ),
        CatalogEntry("turn", turn_scenario, "paper geometry, east then north (two headings)"),
        CatalogEntry(
            "paper-1m-turn", paper_turn_scenario, "paper-1m, 10 frames, turning north after frame 3"
        ),
        CatalogEntry("orbit", orbit_scenario, "a 12-frame polygonal orbit around the emitter"),
        CatalogEntry(
            "beacon-pass",
            beacon_pass_scenario,
            "a 406 MHz beacon, carrier offset and emission time unknown, Doppler + ToA",
        ),
        CatalogEntry(
            "beacon-pass-doppler",
            lambda: beacon_pass_scenario(toa=False, name="beacon-pass-doppler"),
            "the beacon pass from Doppler alone, carrier offset unknown (ml with use_toa=false)",
        ),
        CatalogEntry(
            "turn-noncooperative",
            noncooperative_turn_scenario,
            "turn with the carrier offset and emission time unknown",
        ),
        CatalogEntry("hill", hill_scenario, "an emitter 120 m up a hill, its height unknown"),
        CatalogEntry(
            "hill-climb",
            lambda: hill_scenario(climb=True),
            "the hill with the UAV climbing while it turns, the height unknown",
        ),
        CatalogEntry(
            "hill-terrain",
            lambda: hill_scenario().replace(
                name="hill-terrain",
                terrain=hill_terrain(),
                description=(
                    "hill with the hill's shape known: the tag 2 m above a mapped Gaussian hill, "
                    "a prior of sigma 5 m on its height above the ground"
                ),
            ),
            "the hill with the ground's shape known: a prior on the height (sigma 5 m)",
        ),
        CatalogEntry(
            "roof-beacon",
            roof_beacon_scenario,
            "the beacon on a roof 25 m up: carrier offset, emission time and height unknown",
        ),
    )
}


def get_scenario(name: str, *, frames: int | None = None) -> Scenario:
    """The named scenario, optionally with ``frames`` frames (extended at the last velocity)."""
    try:
        entry = CATALOG[name]
    except KeyError:
        known = ", ".join(CATALOG)
        raise ValueError(f"scenario: unknown name {name!r}; known scenarios: {known}") from None
    scenario = entry.build()
    if frames is not None:
        scenario = scenario.replace(flight=scenario.flight.with_n_frames(frames))
    return scenario
