"""The validity rules of an estimate, checked on columns of trials at once.

Every estimate passes through here, built-in or plug-in, one at a time or as columns:
:class:`~estimators.base.Estimate` applies :func:`invalid_estimates` to itself (a stack of one)
when it is built, and :class:`~estimators.batch.BatchEstimates` to its columns when they are
built, so the run's rows (per-trial estimates and columnar results alike), ``emitterbench
estimate`` and the conformance suite see the same verdict. An estimate that breaks a rule is
refused: it becomes a failed estimate (NaN position, no candidates, no covariance, ``success``
false) whose message starts with :data:`INVALID` and names the rule, followed by the
estimator's own message, e.g. ``"invalid estimate: covariance_m2 is not symmetric positive
semi-definite (smallest eigenvalue -3.1 m²; tolerance 1e-09 of its norm, 4.38 m²); return None
when there is none; converged"``.

The rules, in the order they are checked (the first broken one is named):

1. **Real.** ``position_m``, ``candidates_m`` and ``covariance_m2`` hold real numbers, for every
   estimate, failed or not: a complex value whose imaginary part is not exactly zero is
   refused, never cast (numpy's cast would drop the imaginary part in silence).
2. **A success is finite.** Its ``position_m`` and every candidate are finite.
3. **A success's position is one of its candidates** (MATH §7): ``candidates_m`` is not empty
   and the nearest candidate lies within :data:`POSITION_RTOL` ``× max(1 m, |x|, |y|, |z|)`` of
   ``position_m``: rounding of coordinates of that size, nothing more (a refined position is
   a candidate; report it as one).
4. **A success's covariance is a covariance**: None, all NaN (the columns' "none"), or finite,
   symmetric and positive semi-definite to rounding: ``max |Pᵢⱼ − Pⱼᵢ|`` and the negative part of
   the smallest eigenvalue of ``(P + Pᵀ)/2`` at most :data:`COVARIANCE_RTOL` ``× ‖P‖_F``
   (a covariance ``E[e eᵀ]`` is symmetric PSD; the NEES ``eᵀP⁻¹e`` of any other matrix can be
   negative, MATH §16).

A position has :data:`POSITION_DIMENSIONS` coordinates, ``(x, y)`` or ``(x, y, z)``
(:func:`position_dimension`); the candidates and the covariance have as many. Every rule is
written for ``d`` coordinates; the 2×2 covariance's eigenvalue is in closed form, a larger one
is checked by ``eigvalsh``.

A failed estimate is checked for rule 1 only: its position is NaN and nothing else of it is
scored. The check costs about 0.3 µs a trial on columns and 20-35 µs for one
:class:`~estimators.base.Estimate` (measured in ``benchmarks/bench_validity.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

POSITION_DIMENSIONS = (2, 3)
"""The coordinates a position may have: ``(x_s, y_s)`` at a known emitter height, or
``(x_s, y_s, z_s)``."""

INVALID = "invalid estimate: "
"""How the message of a refused estimate begins."""

POSITION_RTOL = 1e-9
"""A success's position lies within this times ``max(1 m, |x|, |y|, |z|)`` of a candidate: about
10⁷ ulps of its coordinates, far above the rounding of any computation of a coordinate and far
below any distance that matters (1 µm at 1 km)."""

COVARIANCE_RTOL = 1e-9
"""Asymmetry and negative eigenvalue allowed in a covariance, relative to its Frobenius norm.

Rounding moves the eigenvalues of a computed ``d × d`` covariance by about ``ε ‖P‖`` (Weyl; ε ≈
2.2e-16 per operation), so 1e-9 leaves a plug-in's own arithmetic (an LU inverse, ``A P Aᵀ``,
a sum of many terms) a wide margin. The built-ins need none of it: on 544 covariances of
``ml``, ``ekf`` and ``gtsam-smoother`` (``paper-1m``, ``paper-10m`` and ``turn`` with emitters
up to 2×10⁵ m away or 1 mm from the track, frames of 3 and 10 samples, 0 to 90 dB;
``λmax/λmin`` up to 4×10²¹),
each was exactly symmetric with no negative eigenvalue. A covariance singular to rounding
(a negative eigenvalue within the tolerance) is kept; its NEES is NaN, as for any singular
covariance (:func:`scenarios.fisher.inverse_symmetric`)."""


def numeric_array(value: Any, field: str) -> NDArray[Any]:
    """``value`` as a new float array, or a complex one when it holds complex numbers (which
    :func:`invalid_estimates` then judges); ``ValueError`` naming ``field`` otherwise."""
    array = np.asarray(value)
    kind = array.dtype.kind
    try:
        if kind in "biuf":
            return array.astype(float)
        if kind == "c":
            return array.astype(complex)
        try:
            return np.array(value, dtype=float)
        except TypeError:
            return np.array(value, dtype=complex)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{field}: expected numbers, got {value!r} ({error})") from None


def position_dimension(size: int, field: str = "position_m") -> int:
    """The number of coordinates of a position of ``size`` numbers, checked to be one of
    :data:`POSITION_DIMENSIONS`; ``ValueError`` naming ``field`` otherwise."""
    if size not in POSITION_DIMENSIONS:
        raise ValueError(
            f"{field}: expected (x, y) or (x, y, z) in metres, got {size} numbers; return the "
            "emitter's horizontal position, or all three coordinates when its height is estimated"
        )
    return size


def real_part(array: NDArray[Any]) -> NDArray[np.float64]:
    """The float array of a real or complex one (the imaginary part checked to be zero)."""
    return np.ascontiguousarray(array.real, dtype=float)


def invalid_estimates(
    position_m: ArrayLike,
    candidates_m: ArrayLike,
    n_candidates: ArrayLike,
    covariance_m2: ArrayLike | None,
    success: ArrayLike,
) -> dict[int, str]:
    """``{trial: reason}`` for every trial that breaks a rule of the module docstring.

    Parameters
    ----------
    position_m : (n, d), candidates_m : (n, k, d)
        Trial ``i``'s candidates are ``candidates_m[i, :n_candidates[i]]``. Float or complex;
        ``d`` one of :data:`POSITION_DIMENSIONS`.
    n_candidates : (n,) int
    covariance_m2 : (n, d, d) or None
    success : (n,) bool

    Each reason starts with :data:`INVALID`. Vectorised over the trials; Python runs only
    for the reasons of the trials refused (none on the common path).
    """
    position = np.asarray(position_m)
    candidates = np.asarray(candidates_m)
    count = np.asarray(n_candidates, dtype=np.int64)
    ok = np.asarray(success, dtype=bool)
    k = candidates.shape[1]
    slot = np.arange(k) < count[:, None]
    covariance = None if covariance_m2 is None else np.asarray(covariance_m2)
    unreal = {
        "position_m": _imaginary(position, (1,)),
        "candidates_m": _imaginary(candidates, (1, 2), slot[..., None]),
        "covariance_m2": None if covariance is None else _imaginary(covariance, (1, 2)),
    }
    p, c = real_part(position), real_part(candidates)
    with np.errstate(invalid="ignore", over="ignore"):
        finite_position = np.isfinite(p).all(axis=1)
        finite_candidates = (np.isfinite(c) | ~slot[..., None]).all(axis=(1, 2))
        gap = (
            np.hypot(c[..., 0] - p[:, None, 0], c[..., 1] - p[:, None, 1])
            if p.shape[1] == 2
            else np.sqrt(np.sum((c - p[:, None]) ** 2, axis=-1))
        )
        nearest = np.min(np.where(slot, gap, np.inf), axis=1, initial=np.inf)
        scale = np.maximum(np.max(np.abs(p), axis=1, initial=0.0), 1.0)
        bad = ~(finite_position & finite_candidates & (nearest <= POSITION_RTOL * scale))
        if covariance is not None:
            P = real_part(covariance)
            given = ~np.isnan(P).all(axis=(1, 2))
            asymmetry, smallest, norm = _covariance_measures(P)
            tolerance = COVARIANCE_RTOL * norm
            # a NaN or infinite entry makes the norm NaN or infinite
            valid = (asymmetry <= tolerance) & (smallest >= -tolerance) & np.isfinite(norm)
            bad |= given & ~valid
    refused = ok & bad
    for flags in unreal.values():
        if flags is not None:
            refused |= flags
    if not refused.any():
        return {}
    reasons = {}
    for i in np.flatnonzero(refused).tolist():
        reasons[i] = INVALID + _reason(
            i, unreal, position, candidates, count, covariance, bool(ok[i]), nearest, scale
        )
    return reasons


def _imaginary(
    array: NDArray[Any], axes: tuple[int, ...], where: NDArray[np.bool_] | None = None
) -> NDArray[np.bool_] | None:
    """Which trials hold a non-zero imaginary part (None for a real array)."""
    if array.dtype.kind != "c":
        return None
    nonzero = array.imag != 0
    if where is not None:
        nonzero &= where
    return nonzero.any(axis=axes)


def _covariance_measures(
    P: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``max |Pᵢⱼ − Pⱼᵢ|``, the smallest eigenvalue of ``(P + Pᵀ)/2`` and ``‖P‖_F`` of each
    ``(d, d)``. For ``(2, 2)`` in closed form, ``λ = m − √(((a − d)/2)² + b²)`` with
    ``m = (a + d)/2`` (hypot against overflow); larger ones by ``eigvalsh`` (NaN where an entry
    is not finite)."""
    if P.shape[-1] == 2:
        a, b, c, d = P[:, 0, 0], P[:, 0, 1], P[:, 1, 0], P[:, 1, 1]
        smallest = 0.5 * (a + d) - np.hypot(0.5 * (a - d), 0.5 * (b + c))
        return np.abs(b - c), smallest, np.hypot(np.hypot(a, b), np.hypot(c, d))
    transposed = np.swapaxes(P, -1, -2)
    asymmetry = np.max(np.abs(P - transposed), axis=(1, 2), initial=0.0)
    finite = np.isfinite(P).all(axis=(1, 2))
    smallest = np.full(len(P), np.nan)
    if finite.any():
        smallest[finite] = np.linalg.eigvalsh(0.5 * (P + transposed)[finite])[:, 0]
    return asymmetry, smallest, np.sqrt(np.sum(P**2, axis=(1, 2)))


def _numbers(values: NDArray[Any]) -> str:
    """``(1, 2.5)`` or ``(1+2j, 3+0j)``: a few numbers for a message."""
    return "(" + ", ".join(f"{v:.6g}" for v in values.ravel().tolist()) + ")"


def _reason(
    i: int,
    unreal: dict[str, NDArray[np.bool_] | None],
    position: NDArray[Any],
    candidates: NDArray[Any],
    count: NDArray[np.int64],
    covariance: NDArray[Any] | None,
    success: bool,
    nearest: NDArray[np.float64],
    scale: NDArray[np.float64],
) -> str:
    """The first rule trial ``i`` breaks, with the numbers that break it."""
    points = candidates[i, : count[i]]
    for field, flags in unreal.items():
        if flags is not None and flags[i]:
            values = {"position_m": position, "covariance_m2": covariance}.get(field)
            shown = "; ".join(map(_numbers, points)) if values is None else _numbers(values[i])
            return (
                f"{field} is not real {shown}; return real numbers (a complex value is never cast)"
            )
    p, c = real_part(position[i]), real_part(points)
    shown = {"position_m": _numbers(p), "candidates_m": "; ".join(map(_numbers, c)) or "none"}
    if not np.isfinite(p).all():
        return f"position_m is not finite {shown['position_m']}"
    if not np.isfinite(c).all():
        return f"candidates_m is not finite: {shown['candidates_m']}"
    if len(points) == 0:
        return (
            f"candidates_m is empty, so position_m {shown['position_m']} is not one of its "
            "candidates; list it among them (MATH §7)"
        )
    if nearest[i] > POSITION_RTOL * scale[i]:
        return (
            f"position_m {shown['position_m']} is not one of its candidates_m "
            f"{shown['candidates_m']}: {nearest[i]:.3g} m from the nearest (tolerance "
            f"{POSITION_RTOL * scale[i]:.3g} m); return one of the candidates (MATH §7)"
        )
    dim = position.shape[-1]
    P = real_part(covariance[i]) if covariance is not None and success else np.zeros((dim, dim))
    if not np.isfinite(P).all():
        return f"covariance_m2 is not finite {_numbers(P)}; return None when there is none"
    with np.errstate(invalid="ignore", over="ignore"):
        asymmetry, smallest, norm = (float(v[0]) for v in _covariance_measures(P[None]))
    if asymmetry > COVARIANCE_RTOL * norm:
        j, k = np.unravel_index(np.argmax(np.abs(P - P.T)), P.shape)
        j, k = min(j, k), max(j, k)
        what = f"covariance_m2[{j}, {k}] = {P[j, k]:.6g} but covariance_m2[{k}, {j}] = {P[k, j]:.6g} m²"
    else:
        what = f"smallest eigenvalue {smallest:.3g} m²"
    return (
        f"covariance_m2 is not symmetric positive semi-definite ({what}; tolerance "
        f"{COVARIANCE_RTOL:g} of its norm, {norm:.3g} m²); return None when there is none"
    )


def refused_message(reason: str, message: str) -> str:
    """The message of a refused estimate: the reason, then the estimator's own message."""
    return f"{reason}; {message}" if message else reason
