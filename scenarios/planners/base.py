r"""The planner interface, its one result type, and what every planner shares.

A *planner* chooses the velocity of the next frame (MATH §0: a frame is K samples flown at one
constant velocity) from what is known after the frames flown so far:

- the flight so far, a :class:`~scenarios.types.FlightPlan` (positions, velocities, K, Δ);
- the current estimate: its candidates ``(n, d)``, the returned position first (with the
  mirror ambiguity of MATH §7 there are two), and optionally its covariance ``(d, d)``: ``d``
  the coordinates of a position, ``(x, y)`` at a known emitter height (what the built-in
  planners plan from, ``d = 2``) or ``(x, y, z)``;
- the measurements of the frames flown, a :class:`~scenarios.types.MeasurementSet`.

It is any object with a ``name`` and a ``plan`` method returning a :class:`Plan` (a
``typing.Protocol``, like :class:`estimators.base.Estimator`; no inheritance needed). Planners
belong to the scenario (the flight is scenario data), so they never import ``estimators`` or
``comparison``: the estimate arrives as plain arrays. Constructors only store their options
(frozen dataclasses); options are validated in ``plan``. A planner is deterministic: the same
inputs give the same velocity (``rng`` is accepted for planners that randomise; the built-ins
do not draw from it).

Limits shared by every built-in planner
---------------------------------------
``max_speed_mps`` (V_max, default 20 m/s, MATH §12) caps the speed, and the optional
``max_turn_rate_dps`` caps the heading change between consecutive frames at
``max_turn_rate_dps · K · Δ`` degrees: the average turn rate over one frame, since the model
changes velocity only at frame boundaries. Velocities are level (``v_z = 0``).

Kinematics (:class:`~scenarios.types.FlightPlan`): the UAV holds sample ``n``'s velocity until
sample ``n + 1``, so the first sample of the next frame is at ``p_K + Δ v_old`` whatever the
new velocity: :func:`next_frame_start_m`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.types import FlightPlan, MeasurementSet, positive_finite

FloatArray = NDArray[np.float64]

DEFAULT_MAX_SPEED_MPS = 20.0
"""V_max when none is given: the paper gives none (MATH §12)."""


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Plan:
    """What a planner returns: the next frame's velocity and why.

    Attributes
    ----------
    planner : str
        Registry name of the planner.
    velocity_mps : (3,)
        The velocity of the next frame, level (``v_z = 0``).
    message : str
        Which branch chose it, or why a fallback was taken.
    diagnostics : mapping
        Scalars such as the branch, the objective, the speed before limits.
    """

    planner: str
    velocity_mps: FloatArray
    message: str = ""
    diagnostics: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        velocity = np.array(self.velocity_mps, dtype=float).reshape(3)
        if not np.all(np.isfinite(velocity)):
            raise ValueError(f"velocity_mps: planner {self.planner!r} produced {velocity}")
        velocity.flags.writeable = False
        object.__setattr__(self, "velocity_mps", velocity)
        object.__setattr__(self, "diagnostics", dict(self.diagnostics))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""

        def clean(value: Any) -> Any:
            if isinstance(value, np.ndarray):
                return [clean(v) for v in value.tolist()]
            if isinstance(value, list | tuple):
                return [clean(v) for v in value]
            if isinstance(value, np.generic):
                value = value.item()
            if isinstance(value, float) and not math.isfinite(value):
                return None
            return value

        speed = float(np.hypot(*self.velocity_mps[:2]))
        return {
            "planner": self.planner,
            "velocity_mps": clean(self.velocity_mps),
            "speed_mps": speed,
            "heading_deg": float(np.degrees(np.arctan2(*self.velocity_mps[1::-1]))),
            "message": self.message,
            "diagnostics": {key: clean(value) for key, value in self.diagnostics.items()},
        }


@runtime_checkable
class Planner(Protocol):
    """Chooses the next frame's velocity from the flight, the estimate and the data so far.

    ``candidates_m`` holds the estimate's candidates, the returned position first; a planner
    that needs one position uses ``candidates_m[0]``. ``covariance_m2`` is optional.
    Malformed input raises ``ValueError`` naming the field.
    """

    name: ClassVar[str]

    def plan(
        self,
        flight: FlightPlan,
        candidates_m: ArrayLike,
        data: MeasurementSet,
        *,
        covariance_m2: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> Plan: ...


# --------------------------------------------------------------------------------------------
# validation and geometry shared by the planners
# --------------------------------------------------------------------------------------------


def check_candidates(candidates_m: ArrayLike, dimension: int = 2) -> FloatArray:
    """The candidates as a finite ``(n, d)`` array with ``n >= 1``, or ``ValueError``; ``d``
    is ``dimension``, the coordinates the planner plans from."""
    d = dimension
    try:
        points = np.array(candidates_m, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"candidates_m: expected numbers of shape (n, {d}), got {candidates_m!r}"
        ) from None
    if points.ndim == 1 and points.size == d:
        points = points.reshape(1, d)
    if points.ndim != 2 or points.shape[1] != d or len(points) == 0:
        raise ValueError(
            f"candidates_m: expected shape (n, {d}) with n >= 1, got {points.shape}; "
            "give the estimate's candidates, the returned position first"
        )
    if not np.all(np.isfinite(points)):
        raise ValueError(
            "candidates_m: not finite (the estimate failed?); plan only from a successful "
            "estimate, or hold the last velocity"
        )
    return points


def check_covariance(covariance_m2: ArrayLike | None, dimension: int = 2) -> FloatArray | None:
    """The covariance as a finite symmetric ``(d, d)`` array, None, or ``ValueError``; ``d``
    is ``dimension``, that of the candidates (:func:`check_candidates`)."""
    if covariance_m2 is None:
        return None
    d = dimension
    try:
        array = np.array(covariance_m2, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"covariance_m2: expected a ({d}, {d}) matrix of numbers or None, got "
            f"{type(covariance_m2).__name__}"
        ) from None
    if array.size != d * d:
        raise ValueError(
            f"covariance_m2: expected a ({d}, {d}) matrix or None, got shape {array.shape}; "
            "give the estimate's covariance of the candidates' coordinates"
        )
    matrix = array.reshape(d, d)
    if not np.all(np.isfinite(matrix)):
        return None  # an estimator without a usable covariance: as if none was given
    return 0.5 * (matrix + matrix.T)


def check_flight_matches(flight: FlightPlan, data: MeasurementSet) -> None:
    """``ValueError`` unless ``data`` holds the samples of ``flight`` (the frames flown)."""
    if not isinstance(flight, FlightPlan):
        raise ValueError(f"flight: expected a FlightPlan, got {type(flight).__name__}")
    if not isinstance(data, MeasurementSet):
        raise ValueError(f"data: expected a MeasurementSet, got {type(data).__name__}")
    if data.n_samples != flight.n_samples:
        raise ValueError(
            f"data: {data.n_samples} samples, but the flight has {flight.n_samples} "
            f"({flight.n_frames} frames of {flight.samples_per_frame}); give the measurements "
            "of exactly the frames flown"
        )


def last_velocity_mps(flight: FlightPlan) -> FloatArray:
    """``v_old``: the velocity of the last frame flown, (3,)."""
    return np.array(flight.frame_velocities_mps[-1], dtype=float)


def last_position_m(flight: FlightPlan) -> FloatArray:
    """``p_K``: the position of the last sample flown, (3,)."""
    return np.array(flight.sample_positions_m()[-1], dtype=float)


def next_frame_start_m(flight: FlightPlan) -> FloatArray:
    """The first sample of the next frame, ``p_K + Δ v_old`` (the flight's kinematics), (3,)."""
    return last_position_m(flight) + flight.sample_interval_s * last_velocity_mps(flight)


def frame_duration_s(flight: FlightPlan) -> float:
    """``K Δ``: the time between two velocity changes."""
    return flight.samples_per_frame * flight.sample_interval_s


def nominal_speed_mps(flight: FlightPlan, speed_mps: float | None) -> float:
    """The speed ``A`` a planner flies at: ``speed_mps``, else the first frame's speed.

    The paper fixes the speed at that of the initial velocity ``v0`` unless it must change
    (MATH §12, Algorithm 1: ``u_0 = v_0``).
    """
    if speed_mps is not None:
        return positive_finite(speed_mps, "speed_mps")
    first = float(np.hypot(*flight.frame_velocities_mps[0, :2]))
    if not first > 0.0:
        raise ValueError(
            "speed_mps: the first frame's horizontal speed is 0 m/s, so there is no nominal "
            "speed; give speed_mps > 0"
        )
    return first


def check_speed_limits(
    *,
    max_speed_mps: float,
    speed_mps: float | None = None,
    max_turn_rate_dps: float | None = None,
) -> None:
    """Validate the options every planner shares: nominal speed, V_max, turn-rate limit."""
    positive_finite(max_speed_mps, "max_speed_mps")
    if speed_mps is not None:
        positive_finite(speed_mps, "speed_mps")
    if max_turn_rate_dps is not None:
        positive_finite(max_turn_rate_dps, "max_turn_rate_dps")


def max_heading_change_rad(flight: FlightPlan, max_turn_rate_dps: float | None) -> float:
    """The largest heading change allowed between two frames, rad (``π`` when unlimited)."""
    if max_turn_rate_dps is None:
        return math.pi
    rate = positive_finite(max_turn_rate_dps, "max_turn_rate_dps")
    return min(math.pi, math.radians(rate) * frame_duration_s(flight))


def heading_rad(velocity_mps: ArrayLike) -> float:
    """Heading from east, counter-clockwise, rad; NaN for a zero horizontal velocity."""
    vx, vy = (float(v) for v in np.asarray(velocity_mps, dtype=float)[:2])
    return math.atan2(vy, vx) if (vx or vy) else math.nan


def level_velocity_mps(speed_mps: float, heading: float) -> FloatArray:
    """``speed (cos ψ, sin ψ, 0)``."""
    return np.array([speed_mps * math.cos(heading), speed_mps * math.sin(heading), 0.0])


def wrap_angle_rad(angle: ArrayLike) -> FloatArray:
    """Angles wrapped to ``[−π, π)``."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def apply_limits(
    velocity_xy_mps: ArrayLike,
    old_velocity_mps: ArrayLike,
    *,
    max_speed_mps: float,
    max_heading_change: float,
) -> tuple[FloatArray, list[str]]:
    """Clip a horizontal velocity to ``V_max`` and to the heading window around ``v_old``.

    The speed is scaled down to ``max_speed_mps``; the heading is clipped to within
    ``max_heading_change`` rad of the old heading (none when the old velocity is zero).
    Returns the level velocity (3,) and the names of the limits that acted.
    """
    velocity = np.asarray(velocity_xy_mps, dtype=float)[:2]
    speed = float(np.hypot(*velocity))
    acted = []
    if speed > max_speed_mps:
        velocity = velocity * (max_speed_mps / speed)
        speed = max_speed_mps
        acted.append("max_speed")
    old_heading = heading_rad(old_velocity_mps)
    if speed > 0.0 and math.isfinite(old_heading) and max_heading_change < math.pi:
        turn = float(wrap_angle_rad(math.atan2(velocity[1], velocity[0]) - old_heading))
        if abs(turn) > max_heading_change:
            velocity = level_velocity_mps(
                speed, old_heading + math.copysign(max_heading_change, turn)
            )[:2]
            acted.append("max_turn_rate")
    return np.array([velocity[0], velocity[1], 0.0]), acted


# --------------------------------------------------------------------------------------------
# the flight flown, from measurements (for a ground station)
# --------------------------------------------------------------------------------------------


def flight_from_measurements(data: MeasurementSet, *, rtol: float = 1e-6) -> FlightPlan:
    """Reconstruct the :class:`~scenarios.types.FlightPlan` flown from its samples.

    Frames are the ``frame`` labels; each must hold the same number of samples K, flown at one
    velocity (the first sample's), at one sample interval Δ (the mean time step). The samples
    must follow the flight's kinematics ``p_{n+1} = p_n + Δ v_n`` to within ``rtol`` of the
    track's size, since the planners use the reconstructed positions.

    Raises
    ------
    ValueError
        Naming the field (``frame``, ``time_s``, ``velocity_mps``, ``position_m``) and the fix.
    """
    frames, counts = np.unique(data.frame, return_counts=True)
    if np.any(counts != counts[0]):
        raise ValueError(
            f"frame: frames hold {sorted(set(counts.tolist()))} samples; every frame flown must "
            "hold the same number K of samples (drop an incomplete last frame)"
        )
    k = int(counts[0])
    if frames[0] != 0 or np.any(np.diff(frames) != 1):
        raise ValueError("frame: frame labels must be consecutive from 0 (0, 1, 2, ...)")
    if data.n_samples < 2:
        raise ValueError("time_s: one sample gives no sample interval; give at least two")
    steps = np.diff(data.time_s)
    interval = float(np.mean(steps))
    if not interval > 0.0 or np.any(np.abs(steps - interval) > rtol * max(interval, 1e-300)):
        raise ValueError(
            "time_s: samples must be equally spaced in time (one interval Δ) and increasing"
        )
    velocity = np.asarray(data.velocity_mps, dtype=float).reshape(len(frames), k, 3)
    frame_velocity = velocity[:, 0, :]
    speed_scale = max(float(np.max(np.abs(velocity))), 1e-300)
    if np.any(np.abs(velocity - frame_velocity[:, None, :]) > rtol * speed_scale):
        raise ValueError(
            "velocity_mps: every sample of a frame must share one velocity (a frame is a "
            "straight segment flown at constant velocity, MATH §0)"
        )
    flight = FlightPlan(
        start_position_m=data.position_m[0],
        frame_velocities_mps=frame_velocity,
        samples_per_frame=k,
        sample_interval_s=interval,
    )
    track = flight.sample_positions_m()
    scale = max(float(np.ptp(data.position_m[:, :2], axis=0).max()), 1.0)
    worst = float(np.max(np.abs(track - data.position_m)))
    if worst > rtol * scale:
        raise ValueError(
            f"position_m: the samples depart from p(n+1) = p(n) + Δ v(n) by up to {worst:.3g} m; "
            "give the positions and velocities of a flight of straight constant-velocity frames"
        )
    return flight
