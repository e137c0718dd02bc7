"""Running an estimator inside a check, and judging what it returns.

:func:`estimate_or_fail` turns an exception on valid data into a failure that names the data; the
``*_problems`` functions list everything wrong with a result (empty: it conforms);
:func:`result_differences` compares two results bit for bit or within a tolerance.
"""

from __future__ import annotations

import copy
import inspect
import math
from collections.abc import Mapping
from dataclasses import fields, is_dataclass
from typing import Any

import numpy as np

from estimators.base import Capabilities, Estimate, capabilities_of
from estimators.validity import INVALID, invalid_estimates
from scenarios.types import MEASURED_FIELD, MeasurementSet

FIELD_OF_MODALITY = MEASURED_FIELD
"""The :class:`~scenarios.types.MeasurementSet` field of each modality (exported to plug-in
authors under this name; :data:`scenarios.types.MEASURED_FIELD`)."""

_RULES = (
    ": a valid estimate holds real numbers, and a success a finite position that is one of its "
    "candidates and a symmetric positive semi-definite covariance or None (estimators.validity; "
    "'Valid estimates' in docs/writing-an-estimator.md)"
)


def check_failed(message: str) -> None:
    """Fail the check with ``message`` on one line (its whitespace collapsed)."""
    raise AssertionError(" ".join(message.split()))


def estimate_or_fail(
    estimator: Any,
    data: MeasurementSet,
    what: str,
    *,
    rng: np.random.Generator | None = None,
) -> Any:
    """``estimator.estimate(data, rng=rng)``; an exception becomes a failure naming ``what``."""
    try:
        return estimator.estimate(data, rng=rng)
    except Exception as error:
        raise AssertionError(
            f"estimate raised {type(error).__name__} on {what}: {error}; valid data must give an "
            "Estimate (a failure to estimate is Estimate.failed(...), not an exception)"
        ) from error


def require_success(estimate: Any, what: str) -> None:
    if not isinstance(estimate, Estimate):
        check_failed(
            f"estimate returned {type(estimate).__name__} on {what}, not an "
            "estimators.base.Estimate; build the result with Estimate(...) or finalize_estimate"
        )
    if not estimate.success:
        check_failed(
            f"estimate failed on {what} (message: {estimate.message!r}); these data determine "
            "the emitter, so it should succeed there: return Estimate.failed only when the data "
            "cannot give an answer"
        )


def constructor_parameters(estimator: Any) -> list[inspect.Parameter]:
    """The parameters of ``type(estimator)``'s constructor, ``self`` excluded."""
    return list(inspect.signature(type(estimator)).parameters.values())


def params_of(estimator: Any) -> dict[str, Any]:
    """``{parameter: stored value}`` for every constructor parameter stored under its name."""
    return {
        p.name: getattr(estimator, p.name)
        for p in constructor_parameters(estimator)
        if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and hasattr(estimator, p.name)
    }


def declared_capabilities(estimator: Any) -> Capabilities:
    """``capabilities_of(estimator)``; a broken declaration becomes a failure saying so."""
    try:
        return capabilities_of(estimator)
    except Exception as error:
        raise AssertionError(
            f"capabilities() failed ({type(error).__name__}: {error}); return an "
            "estimators.base.Capabilities(modalities=frozenset({...}), ...)"
        ) from error


def same_value(a: Any, b: Any) -> bool:
    """Deep equality for parameters and states: arrays by value, dtype and shape; NaN == NaN."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return False
        if a.shape != b.shape or a.dtype != b.dtype:
            return False
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if type(a) is not type(b):
        return False
    if isinstance(a, Mapping):
        return a.keys() == b.keys() and all(same_value(a[k], b[k]) for k in a)
    if is_dataclass(a):
        return all(same_value(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return True
    try:
        return bool(a == b)
    except Exception:
        return False


def object_state(obj: Any) -> dict[str, Any]:
    """Every instance attribute (``__dict__`` and ``__slots__``), deep-copied."""
    state = dict(getattr(obj, "__dict__", {}))
    for klass in type(obj).__mro__:
        slots = klass.__dict__.get("__slots__", ())
        for slot in (slots,) if isinstance(slots, str) else slots:
            if slot not in ("__dict__", "__weakref__") and hasattr(obj, slot):
                state[slot] = getattr(obj, slot)
    return copy.deepcopy(state)


def result_differences(a: Estimate, b: Estimate, *, atol_m: float | None) -> list[str]:
    """How two estimates differ: bit for bit (``atol_m=None``) or within ``atol_m``.

    With a tolerance, candidates compare as sets and messages and diagnostics are ignored;
    without, everything but timing diagnostics must be identical.
    """
    out = []
    for field in ("estimator", "success", "ambiguous"):
        if getattr(a, field) != getattr(b, field):
            out.append(f"{field} {getattr(a, field)!r} vs {getattr(b, field)!r}")
    pa, pb = np.asarray(a.position_m, dtype=float), np.asarray(b.position_m, dtype=float)
    ca = np.asarray(a.candidates_m, dtype=float).reshape(-1, 2)
    cb = np.asarray(b.candidates_m, dtype=float).reshape(-1, 2)
    if atol_m is None:
        if not same_value(pa, pb):
            out.append(f"position_m {pa.tolist()} vs {pb.tolist()}")
        if not same_value(ca, cb):
            out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()}")
        ka, kb = a.covariance_m2, b.covariance_m2
        if (ka is None) != (kb is None) or (ka is not None and not same_value(ka, kb)):
            out.append("covariance_m2 differs")
        if a.message != b.message:
            out.append(f"message {a.message!r} vs {b.message!r}")
        da = {k: v for k, v in dict(a.diagnostics).items() if not _is_timing(k)}
        db = {k: v for k, v in dict(b.diagnostics).items() if not _is_timing(k)}
        keys = sorted(k for k in da.keys() | db.keys() if not same_value(da.get(k), db.get(k)))
        if keys:
            out.append(f"diagnostics {keys} differ")
        return out
    if pa.shape != pb.shape or not np.allclose(pa, pb, rtol=0.0, atol=atol_m, equal_nan=True):
        out.append(f"position_m {pa.tolist()} vs {pb.tolist()} (tolerance {atol_m:g} m)")
    if ca.shape != cb.shape or not np.allclose(
        _sorted_rows(ca), _sorted_rows(cb), rtol=0.0, atol=atol_m
    ):
        out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()} (tolerance {atol_m:g} m)")
    return out


def _is_timing(key: Any) -> bool:
    """A diagnostics key naming a time in seconds (``solve_time_s``): exempt from equality."""
    return isinstance(key, str) and "time" in key and key.endswith("_s")


def _sorted_rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort((points[:, 0], points[:, 1]))] if len(points) else points


def _is_json_scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | bool | int | float | np.bool_ | np.number)


def result_problems(estimate: Any, estimator: Any) -> list[str]:
    """Everything wrong with one result's types, shapes and consistency (empty: conforms)."""
    if not isinstance(estimate, Estimate):
        return [not_an_estimate(estimate)]
    problems = []
    name = getattr(estimator, "name", None)
    if estimate.estimator != name:
        problems.append(
            f"estimator is {estimate.estimator!r} but the class name is {name!r}; "
            "pass self.name to Estimate/finalize_estimate"
        )
    position = estimate.position_m
    if not isinstance(position, np.ndarray) or position.shape != (2,):
        problems.append(
            f"position_m has shape {np.shape(position)}; expected (2,): (x_s, y_s) in metres, "
            "the emitter height is known (MATH §0)"
        )
    candidates = estimate.candidates_m
    if not isinstance(candidates, np.ndarray) or candidates.ndim != 2 or candidates.shape[1] != 2:
        problems.append(f"candidates_m has shape {np.shape(candidates)}; expected (n, 2)")
    if type(estimate.ambiguous) is not bool:
        problems.append(f"ambiguous is {type(estimate.ambiguous).__name__}; expected bool")
    problems += _diagnostics_problems(estimate.diagnostics)
    problems += failure_problems(estimate)
    if problems or not estimate.success:
        return problems
    # Estimate applies the rules when it is built; again here, for one changed since
    covariance = estimate.covariance_m2
    broken = invalid_estimates(
        position[None],
        candidates[None],
        [len(candidates)],
        None if covariance is None else np.asarray(covariance)[None],
        [True],
    )
    if broken:
        problems.append(f"{broken[0]}{_RULES}")
    if len(candidates) > 1 and not estimate.ambiguous:
        problems.append(
            f"{len(candidates)} equal-cost candidates but ambiguous is False; several "
            "candidates mean the data cannot choose (MATH §7)"
        )
    return problems


def failure_problems(estimate: Any) -> list[str]:
    """What breaks "a failed estimate is data": ``success`` a bool, ``message`` a str, a NaN
    position and a message when it failed, a finite position when it succeeded; and an
    estimate refused by :mod:`estimators.validity` (a plug-in's bug, whatever the data)."""
    if not isinstance(estimate, Estimate):
        return [not_an_estimate(estimate)]
    if type(estimate.success) is not bool:
        return [f"success is {type(estimate.success).__name__}; expected bool"]
    if not isinstance(estimate.message, str):
        return [f"message is {type(estimate.message).__name__}; expected str"]
    if estimate.message.startswith(INVALID):
        return [f"the Estimate was refused, {estimate.message!r}{_RULES}"]
    position = np.asarray(estimate.position_m, dtype=float)
    if not estimate.success:
        problems = []
        if not np.all(np.isnan(position)):
            problems.append(
                f"success is False but position_m is {position.tolist()}; a failed estimate "
                "has a NaN position (use Estimate.failed)"
            )
        if not estimate.message.strip():
            problems.append("success is False with an empty message; say why it failed")
        return problems
    if not np.all(np.isfinite(position)):
        return [
            f"success is True but position_m is {position.tolist()}; return "
            "Estimate.failed(name, reason) when there is no finite answer"
        ]
    return []


def not_an_estimate(result: Any) -> str:
    """The failure text of a result that is not an :class:`~estimators.base.Estimate`."""
    return (
        f"returned {type(result).__name__}, not an estimators.base.Estimate; build the "
        "result with Estimate(...), Estimate.failed(...) or finalize_estimate(...)"
    )


def _diagnostics_problems(diagnostics: Any) -> list[str]:
    if not isinstance(diagnostics, Mapping):
        return [f"diagnostics is {type(diagnostics).__name__}; expected a mapping"]
    problems = []
    for key, value in diagnostics.items():
        if not isinstance(key, str):
            problems.append(f"diagnostics key {key!r} is not a string")
        elif not (
            _is_json_scalar(value)
            or (isinstance(value, list | tuple) and all(_is_json_scalar(v) for v in value))
        ):
            problems.append(
                f"diagnostics[{key!r}] is {type(value).__name__}; diagnostics hold JSON-able "
                "scalars (str, bool, int, float, None) or flat lists of them"
            )
    return problems


def is_sequential(estimator: Any) -> bool:
    """Whether ``estimator`` is fed frame by frame (``init``, ``update``, ``estimate_state``)."""
    return all(callable(getattr(estimator, m, None)) for m in ("init", "update", "estimate_state"))


def streamed_estimate(
    estimator: Any, data: MeasurementSet, *, rng: np.random.Generator | None
) -> Any:
    """A sequential estimator's estimate of ``data`` fed to it frame by frame."""
    state = estimator.init()
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
    return estimator.estimate_state(state, rng=rng)
