"""Trajectory design: choose the next frame's velocity from the estimate so far.

Planners belong to the scenario (the flight is scenario data): they take the flight flown
(:class:`~scenarios.types.FlightPlan`), the current estimate as plain arrays (candidates and an
optional covariance) and the measurements, and return a :class:`Plan`. The closed loop that
calls estimators lives in :mod:`comparison.closed_loop`.

=============  =========================================================  ==========
name           what it does                                               docs/math.md
=============  =========================================================  ==========
``constant``   the last velocity again (no design)                        -
``paper``      the paper's zero-residual rule, corrected                  §12
``fisher``     the A-/D-optimal heading of the next frame                 §13
``orbit``      circle the current estimate at a given radius              -
=============  =========================================================  ==========

Look them up with :func:`get_planner`.
"""

from scenarios.planners.base import Plan, Planner, flight_from_measurements
from scenarios.planners.constant import ConstantPlanner
from scenarios.planners.fisher import FisherPlanner
from scenarios.planners.orbit import OrbitPlanner
from scenarios.planners.paper import PaperPlanner
from scenarios.planners.registry import PLANNER_SUMMARIES, PLANNERS, get_planner, planner_class

__all__ = [
    "PLANNERS",
    "PLANNER_SUMMARIES",
    "ConstantPlanner",
    "FisherPlanner",
    "OrbitPlanner",
    "PaperPlanner",
    "Plan",
    "Planner",
    "flight_from_measurements",
    "get_planner",
    "planner_class",
]
