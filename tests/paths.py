"""How a test compares two code paths that compute one quantity: the rule, stated once.

Two code paths that compute one quantity with different floating-point operations agree to
rounding, never to the bit: a batch and one trial at a time, columns and ``Estimate``
objects, a batch of one and a batch of sixty (BLAS picks its kernels by the arrays' sizes),
the engine's rows of a batch estimator and of a per-trial plug-in, an estimator and a
reference implementation. The same sum rounds differently under OpenBLAS's AVX-512
(``SkylakeX``) kernels than under its ``Haswell`` ones, so a bit-equality between two paths
holds on one CPU and fails on another. Such tests are marked ``@pytest.mark.paths`` and
compare through this module; the README's test command runs them once more under a second
OpenBLAS kernel (``tests/test_kernels.py``). Bit equality is asserted only where the same code
runs on the same arrays (worker counts, ``--resume``, chunkings that hand an estimator the
same arrays, the same call twice): such tests are marked ``@pytest.mark.bits(reason)``.
``tests/test_architecture.py`` checks both.

The rule. Rounding of relative size ``EPS`` in the inputs of a problem whose condition number
is ``κ`` moves its answer by up to about ``κ · EPS`` of the answer's scale. Two paths agree when
each quantity differs by at most ``SAFETY · κ · EPS`` times its scale:

- a covariance ``C = J⁻¹`` (``J`` the Fisher information at the estimate): ``κ = cond(C)``,
  scale ``‖C‖`` (2-norm). Inverting ``J`` divides by ``det J = J₁₁J₂₂ − J₁₂²``, whose
  cancellation turns ``EPS`` of rounding in ``J`` into ``κ · EPS`` in ``C``. (An emitter 5 cm
  from a straight track's plane: ``κ ≈ 4e12``, a covariance of 2e10 m² known to ~1e-3 of
  itself, and two paths find it ~5e-4 apart.)
- a position (the returned point and each candidate): scale ``L``, the geometry's length
  scale (:func:`length_scale_m`: coordinates of that size round at ``EPS · L``), and ``κ`` the
  estimate's sensitivity, measured (:func:`sensitivity`): how far the estimate moves, in
  units of ``L``, per relative change of the measurements, the condition number of the
  problem as the estimator poses it (a closed form's algebra can be worse conditioned than
  the likelihood: on the ``paper`` family, with a ToA σ of 300 km, ``cls`` puts a candidate
  335 km out 1500 ``EPS · L`` apart between paths, where its measured ``κ`` is 57). It is
  measured only for a pair further apart than ``SAFETY · EPS · L`` (``κ = 1``), and never
  below one. A batch path that bounds its own rounding and leaves to the one-trial path
  every trial it cannot certify (the closed forms'
  :data:`estimators.closed_form.gtrs_batch.POSITION_RTOL` of the local unit) agrees within that
  certified bound too.
- a number derived from those (an error, a NEES, a cost, a multiplier): the same
  ``SAFETY · κ · EPS`` of the scale of what it is made of (stated where it is compared). A
  trial row (:func:`row_problems`) takes ``κ`` from its covariance, or without one from the
  Fisher information at the truth (:func:`fisher_condition`).
- what is not a rounded number (flags, counts, messages, the order of candidates, a
  generator's draws) is equal.
- the goodness of fit ``fit_chi2`` (MATH §17) is a function of the position and the data:
  its gap between paths is its slope times the positions' gap, which needs the data. So it is
  not compared between paths (:data:`POSITION_STATISTICS`); the positions are, by the rule
  above, and every path's value is checked to be the statistic at its own position, bit for
  bit (``tests/estimators/test_goodness_of_fit.py``). ``fit_dof``, a count, is equal.

``SAFETY = 64``: a trial's sums run over its whitened rows (up to a few thousand); the rounding
of such a sum taken in another order is a random walk of about ``√m · EPS`` of its terms, and
``64 = √4096``. Observed on this suite's families (AVX-512 and Haswell kernels): ``ml``'s
covariances up to ``1.2 κ EPS ‖C‖`` apart and its positions within 2 ulps of ``L``; ``cls``'s
positions up to ``26 κ EPS L`` apart with ``κ`` measured, and within its certified bound.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from estimators.base import Estimate
from estimators.closed_form.cls_rows import LocalFrame
from scenarios.fisher import fisher_information
from scenarios.types import MeasurementSet

EPS = float(np.finfo(float).eps)
SAFETY = 64.0
"""The rounding of a sum of up to 4096 terms taken in another order, in units of ``EPS``."""

POSITION_STATISTICS = ("fit_chi2",)
"""Diagnostics keys and trial columns that are functions of the returned position and the
data, not compared between paths (the goodness of fit, MATH §17; see the module text)."""

SENSITIVITY_STEP = 2.0**-30
"""The relative change of the measurements :func:`sensitivity` makes (~1e-9: far above
rounding, far below where the estimate stops being linear in the data)."""


def condition(matrix: ArrayLike) -> float:
    """The 2-norm condition number of a symmetric 2×2 matrix; ``inf`` if singular or not
    finite."""
    m = np.asarray(matrix, dtype=float)
    if not np.isfinite(m).all():
        return math.inf
    values = np.abs(np.linalg.eigvalsh(m))
    return math.inf if values.min() == 0.0 else float(values.max() / values.min())


def length_scale_m(data: MeasurementSet, frames: Any, position_m: ArrayLike) -> float:
    """``L = max(‖p‖∞, the local frame's scale)`` of the frames an estimator uses: the size of
    the coordinates a position is rounded in (MATH §5)."""
    used = data.select_frames(frames)
    scale = LocalFrame.fit(used.position_m, used.range_m).scale_m
    position = np.asarray(position_m, dtype=float)
    return max(float(np.max(np.abs(position[np.isfinite(position)]), initial=0.0)), scale)


def sensitivity(
    estimate: Callable[[MeasurementSet], Estimate], data: MeasurementSet, reference: Estimate
) -> float:
    """The estimate's condition number, measured: ``estimate`` of ``data`` with every
    measurement changed by ``±SENSITIVITY_STEP`` of itself (signs from a fixed seed), and the
    largest distance of a reference candidate (or the position) from the nearest new one, in
    units of ``L`` per ``SENSITIVITY_STEP``. ``inf`` when the new estimate has no point."""
    signs = np.random.default_rng(20).choice([-1.0, 1.0], size=(3, len(data.time_s)))
    changed = {
        name: getattr(data, name) * (1.0 + SENSITIVITY_STEP * sign)
        for name, sign in zip(("doppler_hz", "toa_s", "rss_dbm"), signs, strict=True)
        if getattr(data, name) is not None
    }
    moved = estimate(replace(data, **changed))
    old = _points(reference)
    new = _points(moved)
    if len(old) == 0:
        return 1.0
    if len(new) == 0:
        return math.inf
    distance = np.linalg.norm(old[:, None, :] - new[None, :, :], axis=2).min(axis=1).max()
    length = float(np.max(np.abs(old)))
    return max(1.0, float(distance) / max(length, EPS) / SENSITIVITY_STEP)


def _points(estimate: Estimate) -> np.ndarray:
    points = np.vstack([estimate.candidates_m.reshape(-1, 2), estimate.position_m[None, :]])
    return points[np.isfinite(points).all(axis=1)]


def position_problems(
    what: str, reference: ArrayLike, other: ArrayLike, length_m: float, kappa: float = 1.0
) -> list[str]:
    """Points ``(k, 2)`` (or one point) of two paths within ``SAFETY · κ · EPS · L`` of each
    other; NaN equals NaN."""
    a = np.atleast_2d(np.asarray(reference, dtype=float))
    b = np.atleast_2d(np.asarray(other, dtype=float))
    if a.shape != b.shape or not (np.isnan(a) == np.isnan(b)).all():
        return [f"{what}: {a.tolist()} vs {b.tolist()}"]
    gap = float(np.nanmax(np.abs(a - b), initial=0.0))
    allowed = SAFETY * kappa * EPS * length_m
    if gap == 0.0 or gap <= allowed:
        return []
    return [
        f"{what}: {a.tolist()} vs {b.tolist()} ({gap:.3g} m apart, allowed {allowed:.3g} = "
        f"SAFETY·κ·EPS·L, κ = {kappa:.3g}, L = {length_m:.4g} m)"
    ]


def covariance_problems(reference: ArrayLike | None, other: ArrayLike | None) -> list[str]:
    """Two covariances within ``SAFETY · cond(C) · EPS · ‖C‖``; None and all-NaN both mean
    "no covariance" and must agree."""
    a = None if reference is None else np.asarray(reference, dtype=float)
    b = None if other is None else np.asarray(other, dtype=float)
    a = None if a is not None and np.isnan(a).all() else a
    b = None if b is not None and np.isnan(b).all() else b
    if a is None or b is None:
        return [] if a is None and b is None else [f"covariance {a} vs {b}"]
    norm = float(np.linalg.norm(a, ord=2))
    allowed = SAFETY * condition(a) * EPS * norm
    gap = float(np.linalg.norm(a - b, ord=2))
    if gap <= allowed:
        return []
    return [f"covariance {a.tolist()} vs {b.tolist()} (‖ΔC‖ {gap:.3g} > {allowed:.3g})"]


def number_problems(
    what: str, reference: Any, other: Any, scale: float, kappa: float = 1.0
) -> list[str]:
    """Two numbers within ``SAFETY · kappa · EPS · scale`` (NaN equals NaN)."""
    if reference is None or other is None:
        return [] if reference is other else [f"{what} {reference!r} vs {other!r}"]
    a, b = float(reference), float(other)
    if math.isnan(a) or math.isnan(b):
        return [] if math.isnan(a) and math.isnan(b) else [f"{what} {a!r} vs {b!r}"]
    if a == b or abs(a - b) <= SAFETY * kappa * EPS * abs(scale):
        return []
    return [f"{what} {a!r} vs {b!r} (allowed {SAFETY * kappa * EPS * abs(scale):.3g})"]


def value_problems(what: str, reference: Any, other: Any, kappa: float) -> list[str]:
    """Two diagnostic values (nested lists and dicts): floats within ``SAFETY · kappa · EPS``
    of their magnitude, everything else, types included, equal."""
    if type(reference) is not type(other):
        return [f"{what}: {type(reference).__name__} vs {type(other).__name__}"]
    if isinstance(reference, float):
        return number_problems(what, reference, other, max(abs(reference), abs(other)), kappa)
    if isinstance(reference, list | tuple):
        if len(reference) != len(other):
            return [f"{what} {reference!r} vs {other!r}"]
        return [
            p
            for i, (x, y) in enumerate(zip(reference, other, strict=True))
            for p in value_problems(f"{what}[{i}]", x, y, kappa)
        ]
    if isinstance(reference, dict):
        if list(reference) != list(other):
            return [f"{what} keys {list(reference)} vs {list(other)}"]
        return [p for k in reference for p in value_problems(k, reference[k], other[k], kappa)]
    return [] if reference == other else [f"{what} {reference!r} vs {other!r}"]


def estimate_problems(
    reference: Estimate,
    other: Estimate,
    length_m: float,
    *,
    sensitivity: Callable[[], float] | None = None,
    certified_m: float = 0.0,
    scales: Mapping[str, tuple[float, float]] | None = None,
    ignore: Sequence[str] = (),
) -> list[str]:
    """Every way two paths' estimates of one trial differ beyond the rule (empty: they agree).

    The estimator's name, ``success``, ``ambiguous``, the message and the number of
    candidates are equal; the candidates (in order) and the position agree as positions at
    ``κ = 1``, else at ``κ = sensitivity()`` (the estimate's, measured; without it ``κ = 1``),
    or within ``certified_m``, the error bound a batch path certifies for its points; the
    covariance as a covariance; the diagnostics have the same keys in the same order,
    equal non-float values, and floats within ``SAFETY · κ · EPS`` of ``scale`` where
    ``scales`` gives ``key → (scale, κ)``, else of their own magnitude (κ = 1). ``ignore``
    names diagnostics left out (a solver's timings).
    """
    problems = [
        f"{field} {getattr(reference, field)!r} vs {getattr(other, field)!r}"
        for field in ("estimator", "success", "ambiguous", "message")
        if getattr(reference, field) != getattr(other, field)
    ]

    def points(kappa: float) -> list[str]:
        kappa = max(kappa, certified_m / (SAFETY * EPS * length_m))
        return [
            *position_problems(
                "candidates", reference.candidates_m, other.candidates_m, length_m, kappa
            ),
            *position_problems("position", reference.position_m, other.position_m, length_m, kappa),
        ]

    found = points(1.0)
    if found and sensitivity is not None:
        found = points(sensitivity())
    problems += found
    problems += covariance_problems(reference.covariance_m2, other.covariance_m2)
    mine = {k: v for k, v in reference.diagnostics.items() if k not in ignore}
    theirs = {k: v for k, v in other.diagnostics.items() if k not in ignore}
    if list(mine) != list(theirs):
        return [*problems, f"diagnostics keys {list(mine)} vs {list(theirs)}"]
    for key, value in mine.items():
        if key in POSITION_STATISTICS:
            continue
        if scales and key in scales and isinstance(value, float):
            scale, kappa = scales[key]
            problems += number_problems(key, value, theirs[key], scale, kappa)
        else:
            problems += value_problems(key, value, theirs[key], 1.0)
    return problems


# --------------------------------------------------------------------------------------------
# rows of the trials table (comparison.trial_rows), as the engine writes or scores them
# --------------------------------------------------------------------------------------------

POSITION_COLUMNS = (
    "x_m",
    "y_m",
    "error_m",
    "error_side_resolved_m",
    "x_side_resolved_m",
    "y_side_resolved_m",
)
"""Positions, and distances made of them (an error moves by at most what its point moves)."""
COVARIANCE_COLUMNS = ("cov_xx_m2", "cov_xy_m2", "cov_yy_m2")
NEES_COLUMNS = ("nees", "nees_side_resolved")
"""``eᵀC⁻¹e``: relative, at ``κ = cond(C)`` (the inverse of ``C`` carries it)."""
JSON_COLUMNS = ("candidates_json", "diagnostics_json")


def fisher_condition(data: MeasurementSet, modalities: str = "toa+doppler") -> float:
    """``κ`` of the Fisher information at the truth over ``data`` (noise-free data of a
    scenario): the conditioning of a row whose estimate has no covariance of its own."""
    return condition(fisher_information(data, data.truth_emitter_m, modalities))


def row_problems(reference: Mapping[str, Any], other: Mapping[str, Any], kappa: float) -> list:
    """Two paths' values of one trial row (a mapping column → value) within the rule.

    Positions, candidates and errors within ``SAFETY · κ · EPS · L`` (``L`` the largest
    coordinate of the row: the estimate, its candidates and the truth); ``κ`` is
    ``cond(C)`` of the row's covariance where it has one, else ``kappa`` (the information's
    at the truth, :func:`fisher_condition`). The covariance and NEES columns by the
    covariance rule; floats in ``diagnostics_json`` within ``SAFETY · κ · EPS`` of their
    magnitude; every other column equal (NaN equals NaN).
    """
    if set(reference) != set(other):
        return [f"columns {sorted(reference)} vs {sorted(other)}"]
    covariance = [reference.get(c) for c in COVARIANCE_COLUMNS]
    has_covariance = all(c is not None and not _nan(c) for c in covariance)
    if has_covariance:
        xx, xy, yy = (float(c) for c in covariance)
        kappa = condition([[xx, xy], [xy, yy]])
    candidates = json.loads(reference["candidates_json"]) if "candidates_json" in reference else []
    coordinates = [reference.get(c) for c in ("x_m", "y_m", "truth_x_m", "truth_y_m")]
    coordinates += [v for point in candidates for v in point]
    length_m = max([abs(float(v)) for v in coordinates if v is not None and not _nan(v)] + [1.0])
    problems = []
    for column, value in reference.items():
        theirs = other[column]
        if column in POSITION_COLUMNS:
            problems += number_problems(column, value, theirs, length_m, kappa)
        elif column in COVARIANCE_COLUMNS and has_covariance:
            problems += covariance_problems(_matrix(reference), _matrix(other))[:1]
        elif column in NEES_COLUMNS and has_covariance and not _nan(value):
            problems += number_problems(column, value, theirs, abs(float(value)), kappa)
        elif column == "candidates_json":
            a, b = json.loads(value), json.loads(theirs)
            if len(a) != len(b):
                problems.append(f"{column} {value} vs {theirs}")
            else:
                for x, y in zip(np.ravel(a).tolist(), np.ravel(b).tolist(), strict=True):
                    problems += number_problems(column, x, y, length_m, kappa)
        elif column == "diagnostics_json":
            a, b = json.loads(value), json.loads(theirs)
            if isinstance(a, dict) and isinstance(b, dict) and list(a) == list(b):
                a, b = (_without_position_statistics(d) for d in (a, b))
            problems += value_problems(column, a, b, kappa)
        elif column in POSITION_STATISTICS:  # reported by both paths or by neither
            if _nan(value) != _nan(theirs):
                problems.append(f"{column} {value!r} vs {theirs!r}")
        elif not _same(value, theirs):
            problems.append(f"{column} {value!r} vs {theirs!r}")
    return problems


def frame_problems(
    reference: pd.DataFrame, other: pd.DataFrame, kappa: float | Callable[[Any], float]
) -> list[str]:
    """:func:`row_problems` of two trial frames row by row (the same columns, rows in the same
    order, the same dtypes); ``kappa`` a number or a function of the reference row."""
    if list(reference.columns) != list(other.columns) or len(reference) != len(other):
        return [f"frames of {reference.shape} and {other.shape}: {list(other.columns)}"]
    differing = [c for c in reference.columns if reference[c].dtype != other[c].dtype]
    if differing:
        return [f"dtypes of {differing}"]
    problems = []
    rows = zip(reference.to_dict("records"), other.to_dict("records"), strict=True)
    for i, (a, b) in enumerate(rows):
        found = row_problems(a, b, kappa(a) if callable(kappa) else kappa)
        problems += [f"row {i}: {p}" for p in found]
    return problems


def _without_position_statistics(diagnostics: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in diagnostics.items() if k not in POSITION_STATISTICS}


def _matrix(row: Mapping[str, Any]) -> np.ndarray:
    xx, xy, yy = (float(row[c]) for c in COVARIANCE_COLUMNS)
    return np.array([[xx, xy], [xy, yy]])


def _nan(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)


def _same(a: Any, b: Any) -> bool:
    """Equal values, NaN equal to NaN, types too (a bool is not an int)."""
    if _nan(a) or _nan(b):
        return _nan(a) and _nan(b)
    return type(a) is type(b) and a == b
