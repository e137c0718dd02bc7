"""Finding planners by name: the built-ins, or any ``package.module:Class``.

Built-ins (one file per MATH section):

- ``constant``: no design, the last velocity again (:mod:`scenarios.planners.constant`);
- ``paper``: the paper's zero-residual rule, corrected (MATH §12, :mod:`scenarios.planners.paper`);
- ``fisher``: the A- or D-optimal heading of the next frame (MATH §13,
  :mod:`scenarios.planners.fisher`);
- ``orbit``: circle the current estimate at a given radius (:mod:`scenarios.planners.orbit`).
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from scenarios.planners.base import Planner
from scenarios.planners.constant import ConstantPlanner
from scenarios.planners.fisher import FisherPlanner
from scenarios.planners.orbit import OrbitPlanner
from scenarios.planners.paper import PaperPlanner

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


def planner_class(name: str) -> type:
    """The class of planner ``name``, or the class at ``package.module:Class``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"planner: expected a name, got {name!r}")
    if ":" in name:
        module_name, _, attribute = name.partition(":")
        try:
            return getattr(importlib.import_module(module_name), attribute)
        except ImportError as error:
            raise ValueError(f"planner: cannot import {module_name!r} ({error})") from None
        except AttributeError:
            raise ValueError(f"planner: module {module_name!r} has no {attribute!r}") from None
    if name not in PLANNERS:
        raise ValueError(
            f"planner: unknown name {name!r}; known planners: {', '.join(PLANNERS)} "
            "(or give 'package.module:Class')"
        )
    return PLANNERS[name]


def get_planner(name: str, **options: Any) -> Planner:
    """Construct planner ``name`` with keyword ``options``; errors name the option and the fix."""
    cls = planner_class(name)
    accepted = sorted(p for p in inspect.signature(cls).parameters if p != "self")
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise ValueError(
            f"{unknown[0]}: not an option of planner {name!r}; "
            f"its options: {', '.join(accepted) or 'none'}"
        )
    try:
        planner = cls(**options)
    except TypeError as error:
        raise ValueError(
            f"options: planner {name!r} rejected {sorted(options)} ({error})"
        ) from None
    if not isinstance(planner, Planner):
        raise ValueError(
            f"planner {name!r}: {cls.__name__} lacks the Planner interface "
            "(needs name and plan(flight, candidates_m, data, *, covariance_m2=None, rng=None))"
        )
    return planner
