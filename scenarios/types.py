"""Frozen data types: noise levels, the RSS model, flight plans, scenarios and measurements.

Every type validates itself on construction and names the offending field in its error, so
that a malformed file or a typo in an experiment fails at once and says what to fix. Arrays
are copied and made read-only: ``frozen=True`` alone does not stop in-place writes.

Conventions (MATH §0): local flat-earth frame, x east, y north, z up; SI units in every name;
Doppler is received minus carrier frequency, positive while closing (MATH §1).

Physical consistency. A :class:`MeasurementSet` (and each trial of a :class:`MeasurementBatch`)
must describe a flight that can happen, whether it comes from a file, a simulation or Python:

- time never decreases; frames are whole numbers ``0 <= frame < 2^31``, never decreasing;
- a frame is one straight segment flown at one velocity (MATH §0): every sample of a frame has
  the velocity of the frame's first sample, and consecutive samples of a frame follow
  ``p[k+1] = p[k] + v[k] (t[k+1] − t[k])``, both to within :data:`KINEMATIC_RTOL` (1e-6, the
  tolerance of ``emitterbench fly``) of the speed or of the step, plus float rounding;
- a ToA range ``c τ_k`` is never shorter than the height ``|z_k − z_s|`` of the UAV above the
  emitter (MATH §1) by more than :data:`RANGE_DEFICIT_SIGMAS` = 8 standard deviations
  ``c σ_τ``. The true range never is; noise makes it so with probability Φ(−8) = 6.2e-16 per
  sample, once in 1.6e15 samples (at 5 σ it would be once in 3.5 million samples, which one
  long Monte Carlo run reaches). So the paper's scenario, ``c σ_τ = 300 km`` and ranges often
  negative, still loads, while a negated or zero ToA with ``c σ_τ = 1 m`` is refused.

Limits. Every number is bounded so that what the estimators and the Fisher information form
from it (squares, fourth powers, products with a σ², inverses of σ²) stays far inside the
float range (1.8e308); beyond them no measurement is physical. Values in SI units:

=============================================  ====================  ==========================
quantity                                       accepted              why
=============================================  ====================  ==========================
positions, emitter, emitter height             ``|x| <= 1e9`` m      a million km; squares 4e18
velocities (each component)                    ``|v| <= 1e6`` m/s    100 × a satellite's speed
times                                          ``|t| <= 1e12`` s     Unix time fits; ``v Δt`` 1e18
carrier ``f0``                                 1e-3 to 1e15 Hz       infrasound to ultraviolet
propagation speed ``c``                        1e-3 to 1e12 m/s      sound in km/s to light in mm/s
σ of Doppler (Hz), ToA (s), RSS (dB)           1e-30 to 1e30         ``(c σ_τ)⁴ <= 1e168``,
                                                                     ``1/σ² <= 1e60``
measured ``|c τ|`` (m), ``|f|`` (Hz), ``|P|``  ``<= 1e40``           40 σ beyond the world at
(dBm)                                                                the largest σ; the LLS cost
                                                                     in m⁴ stays below 1e160
=============================================  ====================  ==========================

Every refusal is a ``ValueError`` whose message starts with the field and the sample
(``toa_s[12]: ...``, ``toa_s[3][12]`` for trial 3 of a batch) and says what to fix.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.fields import (
    FRAME_LIMIT,
    MAX_COORDINATE_M,
    bounded,
    check_magnitude,
    entry_path,
    finite,
    frame_index,
    frozen_array,
    positive_finite,
    text,
)
from scenarios.geometry import KINEMATIC_RTOL as KINEMATIC_RTOL  # cited by the module text
from scenarios.geometry import check_order, check_straight_frames
from scenarios.nuisance import (
    HEIGHT_UNKNOWN,
    parse_unknowns,
    position_dimension,
    set_nuisance_fields,
)
from scenarios.terrain import Terrain

SPEED_OF_LIGHT_MPS = 299_792_458.0
"""Speed of light in vacuum, m/s: the default propagation speed (MATH §0)."""

MODALITIES = ("doppler", "toa", "rss")
"""Measurement kinds, in the order noise is drawn for them (MATH §1)."""
MEASURED = ("doppler_hz", "toa_s", "rss_dbm")
"""The measurement fields, one per modality in that order."""
MEASURED_FIELD = dict(zip(MODALITIES, MEASURED, strict=True))
"""The :class:`MeasurementSet` field of each modality's measurements."""
NOISE_FIELD = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_db"}
"""The :class:`NoiseModel` field of each modality's standard deviation."""

FloatArray = NDArray[np.float64]

MAX_SPEED_MPS = 1e6
"""Largest velocity component, m/s."""
MAX_TIME_S = 1e12
"""Largest ``|time_s|``, seconds."""
CARRIER_RANGE_HZ = (1e-3, 1e15)
"""Accepted carrier frequencies ``f0``, Hz."""
PROPAGATION_SPEED_RANGE_MPS = (1e-3, 1e12)
"""Accepted propagation speeds ``c``, m/s."""
SIGMA_RANGE = (1e-30, 1e30)
"""Accepted noise standard deviations, each in its unit (Hz, s, dB)."""
MAX_MEASURED = 1e40
"""Largest measured ``|c τ|`` (m), ``|f|`` (Hz) and ``|P|`` (dBm)."""
RANGE_DEFICIT_SIGMAS = 8.0
"""How many ``c σ_τ`` a ToA range may fall short of the height ``|z_k − z_s|`` (noise)."""

_ROUNDING = 16 * np.finfo(float).eps
_SIGMA_UNIT = {"doppler_hz": "Hz", "toa_s": "s", "rss_db": "dB"}


# --------------------------------------------------------------------------------------------
# models
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class NoiseSigmas:
    """Standard deviations of the measurement noise (MATH §1).

    A ``None`` entry means the modality carries no noise level (it is absent or unused).
    In a :class:`Scenario` these are the reference levels at 0 dB (MATH §2); in a
    :class:`MeasurementSet` they are the levels the data were drawn with.
    """

    doppler_hz: float | None = None
    toa_s: float | None = None
    rss_db: float | None = None

    def __post_init__(self) -> None:
        for name in ("doppler_hz", "toa_s", "rss_db"):
            value = getattr(self, name)
            if value is not None:
                checked = positive_finite(value, f"noise.{name}")
                bounded(
                    checked,
                    f"noise.{name}",
                    *SIGMA_RANGE,
                    _SIGMA_UNIT[name],
                    "give the standard deviation in SI units (Hz, s, dB)",
                )
                object.__setattr__(self, name, checked)

    def at_snr(self, snr_db: float) -> NoiseSigmas:
        """Every σ multiplied by ``10^(−snr_db/20)`` (MATH §2: the SNR axis).

        Raises ``ValueError`` naming ``snr_db`` when a σ would leave :data:`SIGMA_RANGE`.
        """
        snr = finite(snr_db, "snr_db")
        low, high = np.log10(SIGMA_RANGE)
        for name, value in self.as_dict().items():
            if value is not None and not low <= np.log10(value) - snr / 20.0 <= high:
                raise ValueError(
                    f"snr_db: {snr:g} dB takes noise.{name} = {value:g} {_SIGMA_UNIT[name]} "
                    f"outside [{SIGMA_RANGE[0]:g}, {SIGMA_RANGE[1]:g}]; choose an SNR nearer 0 dB"
                )
        factor = 10.0 ** (-snr / 20.0)
        return NoiseSigmas(
            **{
                name: None if value is None else value * factor
                for name, value in self.as_dict().items()
            }
        )

    def for_modality(self, modality: str) -> float | None:
        """The σ of ``modality`` (one of :data:`MODALITIES`)."""
        return getattr(self, NOISE_FIELD[modality])

    def as_dict(self) -> dict[str, float | None]:
        return {"doppler_hz": self.doppler_hz, "toa_s": self.toa_s, "rss_db": self.rss_db}


@dataclass(frozen=True, slots=True, kw_only=True)
class RssModel:
    """Log-distance path loss ``P = P0 − 10 η log10(ρ/d0)`` dB (MATH §1, RSS)."""

    reference_power_dbm: float = 0.0
    reference_distance_m: float = 1.0
    path_loss_exponent: float = 2.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "reference_power_dbm",
            finite(self.reference_power_dbm, "rss_model.reference_power_dbm"),
        )
        object.__setattr__(
            self,
            "reference_distance_m",
            positive_finite(self.reference_distance_m, "rss_model.reference_distance_m"),
        )
        object.__setattr__(
            self,
            "path_loss_exponent",
            positive_finite(self.path_loss_exponent, "rss_model.path_loss_exponent"),
        )

    def as_dict(self) -> dict[str, float]:
        return {
            "reference_power_dbm": self.reference_power_dbm,
            "reference_distance_m": self.reference_distance_m,
            "path_loss_exponent": self.path_loss_exponent,
        }


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class FlightPlan:
    """Frames of ``samples_per_frame`` samples, each frame flown at one constant velocity.

    Sample ``n`` (frame ``n // K``) is taken at ``t_n = n Δ``; the UAV holds sample ``n``'s
    velocity until sample ``n + 1``, so ``p_{n+1} = p_n + Δ v_n`` and a straight frame has
    ``p_k = p_1 + (k − 1) Δ v`` (paper, Section 3).

    Parameters
    ----------
    start_position_m : (3,)
        Position of the first sample.
    frame_velocities_mps : (n_frames, 3)
        Velocity flown during each frame.
    samples_per_frame : int
        K, the samples in each frame.
    sample_interval_s : float
        Δ, the time between samples.
    """

    start_position_m: FloatArray
    frame_velocities_mps: FloatArray
    samples_per_frame: int
    sample_interval_s: float

    def __post_init__(self) -> None:
        start = frozen_array(self.start_position_m, "flight.start_position_m", (3,))
        check_magnitude(start, "flight.start_position_m", MAX_COORDINATE_M, "m", _FIX_POSITION)
        object.__setattr__(self, "start_position_m", start)
        try:
            velocities = np.atleast_2d(np.asarray(self.frame_velocities_mps, dtype=float))
        except (TypeError, ValueError, OverflowError) as error:
            raise ValueError(
                f"flight.frame_velocities_mps: expected numbers of shape (N, 3) ({error})"
            ) from None
        velocities = frozen_array(velocities, "flight.frame_velocities_mps", (None, 3))
        check_magnitude(
            velocities, "flight.frame_velocities_mps", MAX_SPEED_MPS, "m/s", _FIX_VELOCITY
        )
        object.__setattr__(self, "frame_velocities_mps", velocities)
        if len(self.frame_velocities_mps) == 0:
            raise ValueError("flight.frame_velocities_mps: needs at least one frame")
        if int(self.samples_per_frame) != self.samples_per_frame or self.samples_per_frame < 1:
            raise ValueError(
                f"flight.samples_per_frame: must be a whole number >= 1, "
                f"got {self.samples_per_frame!r}"
            )
        object.__setattr__(self, "samples_per_frame", int(self.samples_per_frame))
        interval = positive_finite(self.sample_interval_s, "flight.sample_interval_s")
        bounded(interval, "flight.sample_interval_s", 0.0, MAX_TIME_S, "s", _FIX_TIME)
        object.__setattr__(self, "sample_interval_s", interval)

    @property
    def n_frames(self) -> int:
        return len(self.frame_velocities_mps)

    @property
    def n_samples(self) -> int:
        return self.n_frames * self.samples_per_frame

    def sample_frames(self) -> NDArray[np.int64]:
        """Frame index of every sample, shape (n_samples,)."""
        return np.repeat(np.arange(self.n_frames), self.samples_per_frame)

    def sample_times_s(self) -> FloatArray:
        """``t_n = n Δ``, shape (n_samples,)."""
        return np.arange(self.n_samples) * self.sample_interval_s

    def sample_velocities_mps(self) -> FloatArray:
        """Velocity of every sample, shape (n_samples, 3)."""
        return np.repeat(self.frame_velocities_mps, self.samples_per_frame, axis=0)

    def sample_positions_m(self) -> FloatArray:
        """``p_n = p_0 + Δ Σ_{m<n} v_m``, shape (n_samples, 3)."""
        steps = self.sample_velocities_mps()[:-1] * self.sample_interval_s
        offsets = np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
        return self.start_position_m + offsets

    def with_frame(self, velocity_mps: ArrayLike) -> FlightPlan:
        """This plan with one more frame flown at ``velocity_mps``."""
        velocity = frozen_array(velocity_mps, "velocity_mps", (3,))
        check_magnitude(velocity, "velocity_mps", MAX_SPEED_MPS, "m/s", _FIX_VELOCITY)
        return replace(self, frame_velocities_mps=np.vstack([self.frame_velocities_mps, velocity]))

    def with_n_frames(self, n_frames: int) -> FlightPlan:
        """The first ``n_frames`` frames, or this plan extended at its last velocity."""
        if int(n_frames) != n_frames or n_frames < 1:
            raise ValueError(f"frames: must be a whole number >= 1, got {n_frames!r}")
        velocities = self.frame_velocities_mps
        if n_frames <= len(velocities):
            return replace(self, frame_velocities_mps=velocities[:n_frames])
        extra = np.repeat(velocities[-1:], n_frames - len(velocities), axis=0)
        return replace(self, frame_velocities_mps=np.vstack([velocities, extra]))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Scenario:
    """A ground emitter, a flight plan and the measurement constants (MATH §0-§2).

    ``noise`` holds the reference standard deviations at 0 dB; simulation at ``snr_db``
    scales each by ``10^(−snr_db/20)`` (MATH §2). ``modalities`` lists what is simulated.
    ``carrier_offset_hz`` (δ) and ``emission_time_s`` (b) are the emitter's true nuisance
    parameters and ``unknowns`` names those the receiver does not know (MATH §15); a known one is
    corrected for, so only the unknown ones reach the measurements. ``terrain`` (None: none) is
    the known ground, a prior on the emitter's height when that is unknown (MATH §8,
    :mod:`scenarios.terrain`); the simulated data carry it.
    """

    name: str
    emitter_m: FloatArray
    flight: FlightPlan
    carrier_hz: float
    noise: NoiseSigmas
    speed_of_light_mps: float = SPEED_OF_LIGHT_MPS
    emitter_height_m: float = 0.0
    rss_model: RssModel = field(default_factory=RssModel)
    modalities: tuple[str, ...] = MODALITIES
    description: str = ""
    carrier_offset_hz: float = 0.0
    emission_time_s: float = 0.0
    unknowns: tuple[str, ...] = ()
    terrain: Terrain | None = None

    def __post_init__(self) -> None:
        text(self.name, "scenario.name")
        set_nuisance_fields(self, "", "")
        check_terrain(self.terrain)
        emitter = frozen_array(self.emitter_m, "emitter_m", (2,))
        check_magnitude(emitter, "emitter_m", MAX_COORDINATE_M, "m", _FIX_POSITION)
        object.__setattr__(self, "emitter_m", emitter)
        if not isinstance(self.flight, FlightPlan):
            raise ValueError("flight: expected a FlightPlan")
        if not isinstance(self.noise, NoiseSigmas):
            raise ValueError(f"noise: expected NoiseSigmas, got {type(self.noise).__name__}")
        _set_constants(self)
        modalities = tuple(self.modalities)
        unknown = sorted(set(modalities) - set(MODALITIES))
        if unknown or not modalities:
            raise ValueError(
                f"modalities: expected a non-empty subset of {MODALITIES}, got {modalities!r}"
            )
        object.__setattr__(self, "modalities", tuple(m for m in MODALITIES if m in modalities))
        for modality in self.modalities:
            if self.noise.for_modality(modality) is None:
                raise ValueError(
                    f"noise.{NOISE_FIELD[modality]}: scenario simulates {modality} "
                    "but gives no reference noise level"
                )

    @property
    def gamma_per_m(self) -> float:
        """``γ = f0 / c`` (MATH §0)."""
        return self.carrier_hz / self.speed_of_light_mps

    @property
    def truth_emitter_m(self) -> FloatArray:
        """The emitter's coordinates a receiver estimates: ``(x, y)`` at a known height,
        ``(x, y, z)`` with the height unknown (MATH §8); the simulated data's truth."""
        if HEIGHT_UNKNOWN in self.unknowns:
            return np.array([*self.emitter_m, self.emitter_height_m])
        return np.array(self.emitter_m)

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


_FIX_POSITION = (
    "positions are metres in a local frame (MATH §0); check the unit, or move the origin near "
    "the flight"
)
_FIX_VELOCITY = "velocities are metres per second; check the unit"
_FIX_TIME = "times are seconds; check the unit, or count time from the start of the flight"


def check_terrain(terrain: Any) -> None:
    """Raise ``ValueError`` naming ``terrain`` unless it is a :class:`Terrain` or None."""
    if terrain is not None and not isinstance(terrain, Terrain):
        raise ValueError(
            f"terrain: expected a Terrain (scenarios.terrain) or None, got {type(terrain).__name__}"
        )


def _set_constants(obj: Any) -> None:
    """Check and store ``carrier_hz``, ``speed_of_light_mps`` and ``emitter_height_m``."""
    set_ = object.__setattr__
    carrier = positive_finite(obj.carrier_hz, "carrier_hz")
    bounded(carrier, "carrier_hz", *CARRIER_RANGE_HZ, "Hz", "give the carrier in hertz")
    set_(obj, "carrier_hz", carrier)
    speed = positive_finite(obj.speed_of_light_mps, "speed_of_light_mps")
    bounded(
        speed,
        "speed_of_light_mps",
        *PROPAGATION_SPEED_RANGE_MPS,
        "m/s",
        "give the propagation speed in metres per second",
    )
    set_(obj, "speed_of_light_mps", speed)
    height = finite(obj.emitter_height_m, "emitter_height_m")
    bounded(height, "emitter_height_m", -MAX_COORDINATE_M, MAX_COORDINATE_M, "m", _FIX_POSITION)
    set_(obj, "emitter_height_m", height)


# --------------------------------------------------------------------------------------------
# physical consistency of measurements (the module text)
# --------------------------------------------------------------------------------------------


def _frame_indices(frame: FloatArray) -> NDArray[np.int64]:
    """The frame labels as int64, each a whole number in ``[0, 2^31)``."""
    bad = (frame != np.round(frame)) | (frame < 0) | (frame >= FRAME_LIMIT)
    if bad.any():
        index = int(np.argmax(bad))
        frame_index(float(frame[index]), f"frame[{index}]")  # raises, with the right message
    indices = frame.astype(np.int64)
    indices.flags.writeable = False
    return indices


def check_measured(
    geometry: MeasurementSet,
    doppler_hz: FloatArray | None,
    toa_s: FloatArray | None,
    rss_dbm: FloatArray | None,
) -> None:
    """Measured values of shape ``(..., N)`` against the limits and the geometry.

    ``|f|`` and ``|P|`` at most :data:`MAX_MEASURED`; ToA ranges ``c τ`` at most
    :data:`MAX_MEASURED` in size and, unless the emission time is unknown (MATH §15), never
    shorter than the height ``|z_k − z_s|`` by more than :data:`RANGE_DEFICIT_SIGMAS` ``c σ_τ``
    (module text). The message names the entry,
    ``toa_s[12]`` or, for trial 3 of a batch, ``toa_s[3][12]``.
    """
    fix = "check the unit and the sign"
    if doppler_hz is not None:
        check_magnitude(doppler_hz, "doppler_hz", MAX_MEASURED, "Hz", fix)
    if rss_dbm is not None:
        check_magnitude(rss_dbm, "rss_dbm", MAX_MEASURED, "dBm", fix)
    if toa_s is None:
        return
    c = geometry.speed_of_light_mps
    if "emission_time_s" in geometry.unknowns:
        # pseudo-ranges c(τ − b) (MATH §15): an unknown emission time may make them any size
        check_magnitude(toa_s, "toa_s", MAX_MEASURED / c, "s", fix)
        return
    check_magnitude(
        toa_s, "toa_s", MAX_MEASURED / c, "s", f"a range c·τ beyond {MAX_MEASURED:g} m; {fix}"
    )
    assert geometry.noise.toa_s is not None  # checked before
    sigma_m = c * geometry.noise.toa_s
    height = np.abs(geometry.position_m[:, 2] - geometry.emitter_height_m)
    if HEIGHT_UNKNOWN in geometry.unknowns or geometry.height_assumed:
        # any height may fit (or the assumed one is wrong): a range only is not negative
        height = np.zeros_like(height)
    range_m = c * toa_s
    slack = RANGE_DEFICIT_SIGMAS * sigma_m + _ROUNDING * (height + np.abs(range_m))
    short = range_m < height - slack
    if not short.any():
        return
    index = tuple(int(i) for i in np.argwhere(short)[0])
    deficit = height[index[-1]] - range_m[index]
    raise ValueError(
        f"{entry_path('toa_s', index)}: the range c·τ = {range_m[index]:.6g} m is shorter than the "
        f"height of the UAV above the emitter, |z − z_s| = {height[index[-1]]:.6g} m, by "
        f"{deficit:.4g} m = {deficit / sigma_m:.4g} σ (c·σ_τ = {sigma_m:.3g} m; at most "
        f"{RANGE_DEFICIT_SIGMAS:g} σ is noise, MATH §1); check the sign and unit of toa_s, "
        "emitter_height_m, the z of position_m and noise.toa_s"
    )


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class MeasurementSet:
    """What the UAV recorded: one row per sample, plus the constants an estimator needs.

    Parameters
    ----------
    frame : (N,) int
        Frame of each sample, non-decreasing.
    time_s : (N,)
    position_m, velocity_mps : (N, 3)
        UAV position and velocity, known exactly (MATH §0).
    doppler_hz, toa_s, rss_dbm : (N,) or None
        Received minus carrier frequency (physical sign, MATH §1), one-way time of arrival,
        received power. ``None`` marks an absent modality.
    carrier_hz, speed_of_light_mps, emitter_height_m : float
    noise : NoiseSigmas
        The σ's the data were drawn with; required for every modality present.
    rss_model : RssModel or None
        Required when ``rss_dbm`` is present.
    truth_emitter_m : (2,), (3,) or None
        The true emitter, when known (simulations), ``(x, y)`` or, with the height unknown,
        ``(x, y, z)``. Estimators must not read it.
    unknowns : tuple of str
        What the receiver does not know (MATH §15, §8): the nuisance parameters the data carry,
        ``"carrier_offset_hz"`` (every Doppler sample is off by δ) and ``"emission_time_s"``
        (every ToA is late by b), and ``"emitter_height_m"``: the height is then a third
        coordinate of the position and ``emitter_height_m`` only the height an estimator that
        ignores it assumes. Empty: a cooperative emitter at a known height.
    truth_carrier_offset_hz, truth_emission_time_s : float or None
        Their true values, when known (simulations). Estimators must not read them.
    height_assumed : bool
        The height was unknown and :meth:`assuming_known` took ``emitter_height_m`` for it: a
        range shorter than the UAV's height above that is the assumption's error, not the
        data's, and is not refused.
    terrain : Terrain or None
        The known ground and the emitter's spread about it (:mod:`scenarios.terrain`): with the
        height unknown a prior on it (MATH §8), which the Fisher information and ``ml`` use;
        unused with the height known. None: no terrain.
    """

    frame: NDArray[np.int64]
    time_s: FloatArray
    position_m: FloatArray
    velocity_mps: FloatArray
    carrier_hz: float
    noise: NoiseSigmas
    doppler_hz: FloatArray | None = None
    toa_s: FloatArray | None = None
    rss_dbm: FloatArray | None = None
    speed_of_light_mps: float = SPEED_OF_LIGHT_MPS
    emitter_height_m: float = 0.0
    rss_model: RssModel | None = None
    truth_emitter_m: FloatArray | None = None
    unknowns: tuple[str, ...] = ()
    truth_carrier_offset_hz: float | None = None
    truth_emission_time_s: float | None = None
    height_assumed: bool = False
    terrain: Terrain | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_nuisance_fields(self, "truth_", "truth.")
        check_terrain(self.terrain)
        position = frozen_array(self.position_m, "position_m", (None, 3))
        n = len(position)
        if n == 0:
            raise ValueError("samples: need at least one sample")
        velocity = frozen_array(self.velocity_mps, "velocity_mps", (n, 3))
        time = frozen_array(self.time_s, "time_s", (n,))
        check_magnitude(position, "position_m", MAX_COORDINATE_M, "m", _FIX_POSITION, axes="xyz")
        check_magnitude(velocity, "velocity_mps", MAX_SPEED_MPS, "m/s", _FIX_VELOCITY, axes="xyz")
        check_magnitude(time, "time_s", MAX_TIME_S, "s", _FIX_TIME)
        frame = _frame_indices(frozen_array(self.frame, "frame", (n,)))
        check_order(frame, time)
        check_straight_frames(frame, time, position, velocity)
        for name, value in (
            ("position_m", position),
            ("velocity_mps", velocity),
            ("time_s", time),
            ("frame", frame),
        ):
            set_(self, name, value)
        for name in MEASURED:
            value = getattr(self, name)
            if value is not None:
                set_(self, name, frozen_array(value, name, (n,)))
        if self.doppler_hz is None and self.toa_s is None and self.rss_dbm is None:
            raise ValueError(
                "doppler_hz/toa_s/rss_dbm: no measurements; give at least one modality"
            )
        _set_constants(self)
        if not isinstance(self.noise, NoiseSigmas):
            raise ValueError(f"noise: expected NoiseSigmas, got {type(self.noise).__name__}")
        for modality in self.modalities:
            if self.noise.for_modality(modality) is None:
                raise ValueError(
                    f"noise.{NOISE_FIELD[modality]}: {modality} measurements are present, so "
                    "their noise standard deviation is required"
                )
        if self.rss_model is not None and not isinstance(self.rss_model, RssModel):
            raise ValueError(
                f"rss_model: expected RssModel or None, got {type(self.rss_model).__name__}"
            )
        if self.rss_dbm is not None and self.rss_model is None:
            raise ValueError(
                "rss_model: RSS measurements are present, so the path-loss model is required"
            )
        check_measured(self, self.doppler_hz, self.toa_s, self.rss_dbm)
        if self.truth_emitter_m is not None:
            dimension = position_dimension(self.unknowns)
            truth = frozen_array(self.truth_emitter_m, "truth.emitter_m", (dimension,))
            check_magnitude(truth, "truth.emitter_m", MAX_COORDINATE_M, "m", _FIX_POSITION)
            set_(self, "truth_emitter_m", truth)

    # -- views -----------------------------------------------------------------------------

    @property
    def n_samples(self) -> int:
        return len(self.position_m)

    @property
    def modalities(self) -> frozenset[str]:
        """The modalities present, a subset of :data:`MODALITIES`."""
        present = {
            "doppler": self.doppler_hz is not None,
            "toa": self.toa_s is not None,
            "rss": self.rss_dbm is not None,
        }
        return frozenset(name for name, here in present.items() if here)

    @property
    def frames(self) -> NDArray[np.int64]:
        """The distinct frame indices, ascending."""
        return np.unique(self.frame)

    @property
    def gamma_per_m(self) -> float:
        """``γ = f0 / c`` (MATH §0)."""
        return self.carrier_hz / self.speed_of_light_mps

    @property
    def range_m(self) -> FloatArray | None:
        """ToA ranges ``r_k = c τ_k`` (MATH §1), or None without ToA."""
        return None if self.toa_s is None else self.speed_of_light_mps * self.toa_s

    def take(self, mask: NDArray[np.bool_]) -> MeasurementSet:
        """The samples where ``mask`` (N,) is true.

        Not checked again: every check of ``__post_init__`` holds sample by sample or along a
        straight frame, so it holds for any subset of samples that passed it (the filters take
        a frame of the data at every update)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (self.n_samples,):
            raise ValueError(f"mask: expected shape ({self.n_samples},), got {mask.shape}")
        if not mask.any():
            raise ValueError("samples: the selection is empty")
        subset = copy.copy(self)
        for name in ("frame", "time_s", "position_m", "velocity_mps", *MEASURED):
            value = getattr(self, name)
            if value is not None:
                value = value[mask]
                value.flags.writeable = False
                object.__setattr__(subset, name, value)
        return subset

    def select_frames(self, frames: str | Sequence[int]) -> MeasurementSet:
        """``"all"``, ``"last"``, or the listed frame indices."""
        if isinstance(frames, str):
            if frames == "all":
                return self
            if frames == "last":
                return self.take(self.frame == self.frame[-1])
            raise ValueError(f"frames: expected 'all', 'last' or a list of frames, got {frames!r}")
        return self.take(np.isin(self.frame, np.asarray(frames)))

    def up_to_frame(self, frame: int) -> MeasurementSet:
        """Every sample of frames ``<= frame`` (what a cumulative estimator has seen)."""
        return self.take(self.frame <= frame)

    def iter_frames(self) -> Iterator[MeasurementSet]:
        """One :class:`MeasurementSet` per frame, in order (for sequential estimators)."""
        for index in self.frames:
            yield self.take(self.frame == index)

    def without(self, *modalities: str) -> MeasurementSet:
        """A copy with the named modalities removed."""
        unknown = set(modalities) - set(MODALITIES)
        if unknown:
            raise ValueError(f"modalities: unknown {sorted(unknown)}; choose from {MODALITIES}")
        return replace(self, **{MEASURED_FIELD[m]: None for m in modalities})

    def without_truth(self) -> MeasurementSet:
        return replace(
            self, truth_emitter_m=None, truth_carrier_offset_hz=None, truth_emission_time_s=None
        )

    def assuming_known(self, unknowns: Iterable[str] | None = None) -> MeasurementSet:
        """The same measurements with the ``unknowns`` named (default: every one the data
        declare) taken as known: a nuisance parameter as zero, the height as
        ``emitter_height_m``. What an estimator that ignores them sees (MATH §15, §8), biased by
        their true values; the truth loses its height when the height is assumed. A range
        shorter than the UAV's height above the assumed height is then the assumption's
        error (``height_assumed``), not refused."""
        assumed = set(self.unknowns if unknowns is None else parse_unknowns(unknowns))
        truth = self.truth_emitter_m
        height = HEIGHT_UNKNOWN in assumed and HEIGHT_UNKNOWN in self.unknowns
        return replace(
            self,
            unknowns=tuple(u for u in self.unknowns if u not in assumed),
            truth_emitter_m=truth[:2] if truth is not None and height else truth,
            height_assumed=self.height_assumed or height,
        )


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class MeasurementBatch:
    """Monte Carlo trials over one geometry: a shared flight, per-trial measurements.

    The geometry fields are those of :class:`MeasurementSet`; ``doppler_hz``, ``toa_s`` and
    ``rss_dbm`` have shape (n_trials, N). Batch-capable estimators take the whole object;
    :meth:`trial` gives the one-trial view every estimator accepts.
    """

    geometry: MeasurementSet
    doppler_hz: FloatArray | None
    toa_s: FloatArray | None
    rss_dbm: FloatArray | None

    def __post_init__(self) -> None:
        if not isinstance(self.geometry, MeasurementSet):
            raise ValueError(
                f"geometry: expected a MeasurementSet, got {type(self.geometry).__name__}"
            )
        n = self.geometry.n_samples
        trials = {len(getattr(self, name)) for name in MEASURED if getattr(self, name) is not None}
        if len(trials) != 1:
            raise ValueError("batch: every modality needs the same number of trials")
        (n_trials,) = trials
        for name, modality in zip(MEASURED, MODALITIES, strict=True):
            value = getattr(self, name)
            if value is None:
                continue
            object.__setattr__(self, name, frozen_array(value, name, (n_trials, n)))
            if self.geometry.noise.for_modality(modality) is None:
                raise ValueError(
                    f"noise.{NOISE_FIELD[modality]}: {modality} measurements are present, so "
                    "their noise standard deviation is required (in geometry.noise)"
                )
        if self.rss_dbm is not None and self.geometry.rss_model is None:
            raise ValueError(
                "rss_model: RSS measurements are present, so the path-loss model is required "
                "(in geometry.rss_model)"
            )
        check_measured(self.geometry, self.doppler_hz, self.toa_s, self.rss_dbm)

    @classmethod
    def of_one(cls, data: MeasurementSet) -> MeasurementBatch:
        """``data`` as a batch of one trial: its measurements the batch's only row."""
        rows = {name: getattr(data, name) for name in MEASURED}
        return cls(geometry=data, **{k: None if v is None else v[None] for k, v in rows.items()})

    @property
    def n_trials(self) -> int:
        return len(next(getattr(self, n) for n in MEASURED if getattr(self, n) is not None))

    def trial(self, index: int) -> MeasurementSet:
        """Trial ``index`` as a :class:`MeasurementSet`.

        The batch checked its geometry and every trial's measurements when it was built, so the
        trial is assembled without checking them again (a copy of the geometry with the trial's
        read-only measurement rows).
        """
        index = range(self.n_trials)[index]  # IndexError for a trial the batch does not hold
        trial = copy.copy(self.geometry)
        for name in MEASURED:
            values = getattr(self, name)
            object.__setattr__(trial, name, None if values is None else values[index])
        return trial

    def __iter__(self) -> Iterator[MeasurementSet]:
        for index in range(self.n_trials):
            yield self.trial(index)

    def __len__(self) -> int:
        return self.n_trials
