r"""The ``orbit`` planner: circle the current estimate at a given radius.

``orbit`` circles the current estimate ``ŝ = candidates_m[0]`` at radius ``R`` with the
Lyapunov guidance vector field of Lawrence, Frew & Pisano (2008), evaluated at the next frame's
first sample ``p = p_K + Δ v_old`` with ``r = p_xy − ŝ``, ``ρ = |r|``,
``r⊥ = (−r_y, r_x)`` and ``σ = +1`` counter-clockwise (``−1`` clockwise):

.. math::

    \hat u = -\frac{(\rho^2 - R^2)\, r - 2\sigma\rho R\, r_\perp}{\rho\,(\rho^2 + R^2)},

a unit vector everywhere (``|(ρ² − R²) r − 2σρR r⊥| = ρ(ρ² + R²)``): towards ``ŝ`` far away,
along the circle on it, outwards inside it. A frame is a straight segment of length
``L = A K Δ``, so the heading is turned towards the centre by half the arc angle it spans,
``σ (L / 2R)``, weighted by ``2ρR/(ρ² + R²)`` (1 on the circle, towards 0 far from it): on the
circle each frame is then a chord. At ``ρ = 0`` every heading points outwards, as the field
does near the centre: the old heading is kept (documented fallback).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.planners.base import (
    DEFAULT_MAX_SPEED_MPS,
    Plan,
    apply_limits,
    check_candidates,
    check_flight_matches,
    check_speed_limits,
    frame_duration_s,
    heading_rad,
    last_velocity_mps,
    level_velocity_mps,
    max_heading_change_rad,
    next_frame_start_m,
    nominal_speed_mps,
)
from scenarios.types import FlightPlan, MeasurementSet, positive_finite

FloatArray = NDArray[np.float64]
Direction = Literal["ccw", "cw"]


def orbit_direction(offset_m: ArrayLike, radius_m: float, *, clockwise: bool = False) -> FloatArray:
    """The unit vector of the guidance field at ``r = p_xy − ŝ`` (module docstring), (2,).

    Raises ``ValueError`` at ``r = 0``, where the field is undefined.
    """
    r = np.asarray(offset_m, dtype=float)[:2]
    rho = float(np.hypot(*r))
    if rho == 0.0:
        raise ValueError("offset_m: the field is undefined at the centre of the orbit")
    sign = -1.0 if clockwise else 1.0
    perpendicular = np.array([-r[1], r[0]])
    field = -((rho**2 - radius_m**2) * r - 2.0 * sign * rho * radius_m * perpendicular)
    return field / (rho * (rho**2 + radius_m**2))


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbitPlanner:
    """Circle the current estimate at ``radius_m`` (module docstring).

    Parameters
    ----------
    radius_m : float
        Horizontal radius of the orbit about ``candidates_m[0]`` (default 30 m).
    direction : {"ccw", "cw"}
        Counter-clockwise (default) or clockwise, seen from above.
    speed_mps : float or None
        The speed; None: the first frame's speed.
    max_speed_mps : float
        V_max (default 20 m/s).
    max_turn_rate_dps : float or None
        Optional turn-rate limit (heading clipped, speed kept).
    """

    name: ClassVar[str] = "orbit"

    radius_m: float = 30.0
    direction: Direction = "ccw"
    speed_mps: float | None = None
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS
    max_turn_rate_dps: float | None = None

    def __post_init__(self) -> None:
        positive_finite(self.radius_m, "radius_m")
        if self.direction not in ("ccw", "cw"):
            raise ValueError(f"direction: expected 'ccw' or 'cw', got {self.direction!r}")
        check_speed_limits(
            max_speed_mps=self.max_speed_mps,
            speed_mps=self.speed_mps,
            max_turn_rate_dps=self.max_turn_rate_dps,
        )

    def plan(
        self,
        flight: FlightPlan,
        candidates_m: ArrayLike,
        data: MeasurementSet,
        *,
        covariance_m2: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> Plan:
        """The next frame's level velocity along the guidance field about ``candidates_m[0]``."""
        check_flight_matches(flight, data)
        centre = check_candidates(candidates_m)[0]
        speed = min(nominal_speed_mps(flight, self.speed_mps), self.max_speed_mps)
        old = last_velocity_mps(flight)
        offset = next_frame_start_m(flight)[:2] - centre
        rho = float(np.hypot(*offset))
        radius = float(self.radius_m)
        sign = -1.0 if self.direction == "cw" else 1.0
        if rho <= 1e-9 * max(radius, 1.0):
            heading = heading_rad(old)
            heading = 0.0 if not math.isfinite(heading) else heading
            message = "above the orbit's centre: kept the old heading (outwards)"
        else:
            field = orbit_direction(offset, radius, clockwise=self.direction == "cw")
            chord = speed * frame_duration_s(flight) / (2.0 * radius)
            weight = 2.0 * rho * radius / (rho**2 + radius**2)
            heading = math.atan2(field[1], field[0]) + sign * chord * weight
            message = f"orbit of radius {radius:g} m, {self.direction}"
        velocity, acted = apply_limits(
            level_velocity_mps(speed, heading)[:2],
            old,
            max_speed_mps=self.max_speed_mps,
            max_heading_change=max_heading_change_rad(flight, self.max_turn_rate_dps),
        )
        message += "".join(f", limited by {name}" for name in acted)
        return Plan(
            planner=self.name,
            velocity_mps=velocity,
            message=message,
            diagnostics={"distance_to_centre_m": rho, "radius_m": radius},
        )
