"""Finding planners by name: the built-ins, or any ``package.module:Class``; checking options.

Built-ins (one file per MATH section):

- ``constant``: no design, the last velocity again (:mod:`scenarios.planners.constant`);
- ``paper``: the paper's zero-residual rule, corrected (MATH §12, :mod:`scenarios.planners.paper`);
- ``fisher``: the A- or D-optimal heading of the next frame (MATH §13,
  :mod:`scenarios.planners.fisher`);
- ``orbit``: circle the current estimate at a given radius (:mod:`scenarios.planners.orbit`).

A ``package.module:Class`` is imported (importing a module runs its code), and what it names
is used only if it is a class with the planner interface (:func:`planner_class_problems`):
nothing of it is called before. :func:`check_options` checks keyword options against a
constructor's signature and simple annotations before the class is built
(:mod:`scenarios.plugins`, the loader estimators use too).
"""

from __future__ import annotations

import inspect
from typing import Any

from scenarios.planners.base import Planner
from scenarios.planners.constant import ConstantPlanner
from scenarios.planners.fisher import FisherPlanner
from scenarios.planners.orbit import OrbitPlanner
from scenarios.planners.paper import PaperPlanner
from scenarios.plugins import check_options, checked_class, import_target, method_takes

PLANNERS: dict[str, type] = {
    cls.name: cls for cls in (ConstantPlanner, PaperPlanner, FisherPlanner, OrbitPlanner)
}
"""The built-in planners by name."""

PLANNER_SUMMARIES: dict[str, str] = {
    "constant": "no design: the last velocity again (the paper's Fig. 3 baseline)",
    "paper": "the paper's zero-residual heading rule, corrected (MATH §12)",
    "fisher": "A-/D-optimal heading of the next frame, worst case over mirrors (MATH §13)",
    "orbit": "circle the current estimate at a given radius (guidance vector field)",
}
"""One line per built-in planner (``emitterbench list``)."""

PLANNER_INTERFACE = (
    "a class with the class attribute name and "
    "plan(flight, candidates_m, data, *, covariance_m2=None, rng=None)"
)


def planner_class_problems(cls: type) -> list[str]:
    """What a class lacks to be a planner (empty: nothing), read without calling any of it."""
    problems = []
    name = inspect.getattr_static(cls, "name", None)
    if not isinstance(name, str) or not name:
        problems.append("the class attribute name (a non-empty string) is missing")
    return problems + method_takes(cls, "plan", ("covariance_m2", "rng"))


def planner_class(name: str) -> type:
    """The class of planner ``name``, or the class at ``package.module:Class``, checked."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"planner: expected a name, got {name!r}")
    if ":" in name:
        target = import_target(name, "planner")
    elif name in PLANNERS:
        target = PLANNERS[name]
    else:
        raise ValueError(
            f"planner: unknown name {name!r}; known planners: {', '.join(PLANNERS)} "
            "(or give 'package.module:Class')"
        )
    return checked_class(name, target, "planner", planner_class_problems, PLANNER_INTERFACE)


def get_planner(name: str, **options: Any) -> Planner:
    """Construct planner ``name`` with keyword ``options``; errors name the option and the fix."""
    cls = planner_class(name)
    check_options(cls, options, f"planner {name!r}")
    try:
        planner = cls(**options)
    except ValueError:
        raise  # the constructor's own check, naming the option
    except Exception as error:  # a plug-in may fail in any way: one line, not a traceback
        raise ValueError(
            f"options: planner {name!r} rejected {sorted(options)} "
            f"({type(error).__name__}: {error})"
        ) from None
    if not isinstance(planner, Planner):
        raise ValueError(
            f"planner: {name!r} built a {cls.__name__} that lacks the planner interface; "
            f"give {PLANNER_INTERFACE}"
        )
    return planner
