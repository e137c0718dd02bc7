"""Frozen data types: noise levels, the RSS model, flight plans, scenarios and measurements.

Every type validates itself on construction and names the offending field in its error, so
that a malformed file or a typo in an experiment fails at once and says what to fix. Arrays
are copied and made read-only: ``frozen=True`` alone does not stop in-place writes.

Conventions (MATH §0): local flat-earth frame, x east, y north, z up; SI units in every name;
Doppler is received minus carrier frequency, positive while closing (MATH §1).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.fields import finite, positive_finite, text

SPEED_OF_LIGHT_MPS = 299_792_458.0
"""Speed of light in vacuum, m/s: the default propagation speed (MATH §0)."""

MODALITIES = ("doppler", "toa", "rss")
"""Measurement kinds, in the order noise is drawn for them (MATH §1)."""

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# validation helpers: arrays here, numbers and text in scenarios.fields (finite and
# positive_finite are still imported from this module, e.g. by scenarios.planners)
# --------------------------------------------------------------------------------------------


def frozen_array(
    value: ArrayLike, name: str, shape: tuple[int | None, ...], *, dtype: type = np.float64
) -> NDArray[Any]:
    """Return ``value`` as a read-only array of the given shape, or raise ``ValueError``.

    ``None`` in ``shape`` accepts any length. The message names ``name``, the shape expected
    and the one received, and the first non-finite entry.
    """
    try:
        array = np.array(value, dtype=dtype, copy=True)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"{name}: expected numbers of shape {_shape_text(shape)} ({error})"
        ) from None
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        raise ValueError(
            f"{name}: expected shape {_shape_text(shape)}, got {array.shape}; "
            "give one value per sample in the same order as the other per-sample fields"
        )
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        index = np.unravel_index(np.argmin(np.isfinite(array)), array.shape)
        raise ValueError(
            f"{name}: entry {tuple(int(i) for i in index)} is {array[index]}; "
            "every value must be finite (drop the sample or mark the modality absent)"
        )
    array.flags.writeable = False
    return array


def _shape_text(shape: tuple[int | None, ...]) -> str:
    names = iter("NMLK")
    return "(" + ", ".join(str(s) if s is not None else next(names) for s in shape) + ")"


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
                object.__setattr__(self, name, positive_finite(value, f"noise.{name}"))

    def at_snr(self, snr_db: float) -> NoiseSigmas:
        """Every σ multiplied by ``10^(−snr_db/20)`` (MATH §2: the SNR axis)."""
        factor = 10.0 ** (-finite(snr_db, "snr_db") / 20.0)
        return NoiseSigmas(
            **{
                name: None if value is None else value * factor
                for name, value in self.as_dict().items()
            }
        )

    def for_modality(self, modality: str) -> float | None:
        """The σ of ``modality`` (one of :data:`MODALITIES`)."""
        return {"doppler": self.doppler_hz, "toa": self.toa_s, "rss": self.rss_db}[modality]

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
        object.__setattr__(
            self,
            "start_position_m",
            frozen_array(self.start_position_m, "flight.start_position_m", (3,)),
        )
        velocities = np.atleast_2d(np.asarray(self.frame_velocities_mps, dtype=float))
        object.__setattr__(
            self,
            "frame_velocities_mps",
            frozen_array(velocities, "flight.frame_velocities_mps", (None, 3)),
        )
        if len(self.frame_velocities_mps) == 0:
            raise ValueError("flight.frame_velocities_mps: needs at least one frame")
        if int(self.samples_per_frame) != self.samples_per_frame or self.samples_per_frame < 1:
            raise ValueError(
                f"flight.samples_per_frame: must be a whole number >= 1, "
                f"got {self.samples_per_frame!r}"
            )
        object.__setattr__(self, "samples_per_frame", int(self.samples_per_frame))
        object.__setattr__(
            self,
            "sample_interval_s",
            positive_finite(self.sample_interval_s, "flight.sample_interval_s"),
        )

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

    def __post_init__(self) -> None:
        text(self.name, "scenario.name")
        object.__setattr__(self, "emitter_m", frozen_array(self.emitter_m, "emitter_m", (2,)))
        if not isinstance(self.flight, FlightPlan):
            raise ValueError("flight: expected a FlightPlan")
        object.__setattr__(self, "carrier_hz", positive_finite(self.carrier_hz, "carrier_hz"))
        object.__setattr__(
            self,
            "speed_of_light_mps",
            positive_finite(self.speed_of_light_mps, "speed_of_light_mps"),
        )
        object.__setattr__(
            self, "emitter_height_m", finite(self.emitter_height_m, "emitter_height_m")
        )
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
                    f"noise.{_NOISE_FIELD[modality]}: scenario simulates {modality} "
                    "but gives no reference noise level"
                )

    @property
    def gamma_per_m(self) -> float:
        """``γ = f0 / c`` (MATH §0)."""
        return self.carrier_hz / self.speed_of_light_mps

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


_NOISE_FIELD = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_db"}


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
    truth_emitter_m : (2,) or None
        The true emitter, when known (simulations). Estimators must not read it.
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

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        position = frozen_array(self.position_m, "position_m", (None, 3))
        n = len(position)
        if n == 0:
            raise ValueError("samples: need at least one sample")
        set_(self, "position_m", position)
        set_(self, "velocity_mps", frozen_array(self.velocity_mps, "velocity_mps", (n, 3)))
        set_(self, "time_s", frozen_array(self.time_s, "time_s", (n,)))
        frame_float = frozen_array(self.frame, "frame", (n,))
        if np.any(frame_float != np.round(frame_float)) or np.any(frame_float < 0):
            raise ValueError("frame: every frame index must be a whole number >= 0")
        frame = frame_float.astype(np.int64)
        if np.any(np.diff(frame) < 0):
            raise ValueError("frame: samples must be ordered by frame (non-decreasing)")
        frame.flags.writeable = False
        set_(self, "frame", frame)
        for name in ("doppler_hz", "toa_s", "rss_dbm"):
            value = getattr(self, name)
            if value is not None:
                set_(self, name, frozen_array(value, name, (n,)))
        if self.doppler_hz is None and self.toa_s is None and self.rss_dbm is None:
            raise ValueError(
                "doppler_hz/toa_s/rss_dbm: no measurements; give at least one modality"
            )
        set_(self, "carrier_hz", positive_finite(self.carrier_hz, "carrier_hz"))
        set_(
            self,
            "speed_of_light_mps",
            positive_finite(self.speed_of_light_mps, "speed_of_light_mps"),
        )
        set_(self, "emitter_height_m", finite(self.emitter_height_m, "emitter_height_m"))
        if not isinstance(self.noise, NoiseSigmas):
            raise ValueError("noise: expected NoiseSigmas")
        for modality in self.modalities:
            if self.noise.for_modality(modality) is None:
                raise ValueError(
                    f"noise.{_NOISE_FIELD[modality]}: {modality} measurements are present, so "
                    "their noise standard deviation is required"
                )
        if self.rss_dbm is not None and self.rss_model is None:
            raise ValueError(
                "rss_model: RSS measurements are present, so the path-loss model is required"
            )
        if self.truth_emitter_m is not None:
            set_(
                self, "truth_emitter_m", frozen_array(self.truth_emitter_m, "truth.emitter_m", (2,))
            )

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
        """The samples where ``mask`` is true."""
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            raise ValueError("samples: the selection is empty")
        changes: dict[str, Any] = {
            name: getattr(self, name)[mask]
            for name in ("frame", "time_s", "position_m", "velocity_mps")
        }
        for name in ("doppler_hz", "toa_s", "rss_dbm"):
            value = getattr(self, name)
            changes[name] = None if value is None else value[mask]
        return replace(self, **changes)

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
        field_of = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_dbm"}
        return replace(self, **{field_of[m]: None for m in modalities})

    def without_truth(self) -> MeasurementSet:
        return replace(self, truth_emitter_m=None)


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
        n = self.geometry.n_samples
        trials = {len(v) for v in (self.doppler_hz, self.toa_s, self.rss_dbm) if v is not None}
        if len(trials) != 1:
            raise ValueError("batch: every modality needs the same number of trials")
        (n_trials,) = trials
        for name in ("doppler_hz", "toa_s", "rss_dbm"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, frozen_array(value, name, (n_trials, n)))

    @property
    def n_trials(self) -> int:
        return len(next(v for v in (self.doppler_hz, self.toa_s, self.rss_dbm) if v is not None))

    def trial(self, index: int) -> MeasurementSet:
        """Trial ``index`` as a :class:`MeasurementSet`."""
        return replace(
            self.geometry,
            doppler_hz=None if self.doppler_hz is None else self.doppler_hz[index],
            toa_s=None if self.toa_s is None else self.toa_s[index],
            rss_dbm=None if self.rss_dbm is None else self.rss_dbm[index],
        )

    def __iter__(self) -> Iterator[MeasurementSet]:
        for index in range(self.n_trials):
            yield self.trial(index)

    def __len__(self) -> int:
        return self.n_trials
