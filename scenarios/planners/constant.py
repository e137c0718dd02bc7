"""No design: the ``constant`` planner repeats the last frame's velocity.

The paper's "without trajectory optimization" case (Section 5, Figure 3). A straight track never
resolves the mirror ambiguity (MATH §7).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from scenarios.planners.base import (
    DEFAULT_MAX_SPEED_MPS,
    Plan,
    check_flight_matches,
    check_speed_limits,
    last_velocity_mps,
)
from scenarios.types import FlightPlan, MeasurementSet


@dataclass(frozen=True, slots=True, kw_only=True)
class ConstantPlanner:
    """No design: the last frame's velocity again (capped at ``max_speed_mps``).

    Parameters
    ----------
    max_speed_mps : float
        V_max (default 20 m/s).
    max_turn_rate_dps : float or None
        Accepted for a uniform interface; a constant velocity never turns.
    """

    name: ClassVar[str] = "constant"

    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS
    max_turn_rate_dps: float | None = None

    def __post_init__(self) -> None:
        check_speed_limits(
            max_speed_mps=self.max_speed_mps, max_turn_rate_dps=self.max_turn_rate_dps
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
        """The last velocity; the estimate is not used (it may even be a failed one)."""
        check_flight_matches(flight, data)
        velocity = last_velocity_mps(flight)
        speed = float(np.hypot(*velocity[:2]))
        message = "held the last velocity"
        if speed > self.max_speed_mps:
            velocity[:2] *= self.max_speed_mps / speed
            message += ", limited by max_speed"
        return Plan(planner=self.name, velocity_mps=velocity, message=message)
