"""The convergence audit of ``ml`` (MATH §10): the decrement at the end of each search.

A search converged when MINPACK met a tolerance *and* the point is stationary: its decrement
``min(‖P_J e‖², gᵀH⁻¹g)`` (χ² units) is at most ``DECREMENT_TOL``
(:mod:`estimators.convergence`). ``‖P_J e‖²`` is the Gauss-Newton decrement (``P_J`` the
projection on the range of the whitened Jacobian ``J``, finite even where ``JᵀJ`` is singular);
``gᵀH⁻¹g`` the Newton decrement with the exact Hessian ``H`` (central differences of the
analytic gradient ``g = Jᵀe``, step ``HESSIAN_STEP_RTOL`` of the length scale: truncation and
rounding both ~1e−11 relative), only where ``H`` is positive definite. Both are evaluated for
every search at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import DECREMENT_TOL
from estimators.ml.minpack_batch import column_dot

if TYPE_CHECKING:
    from estimators.ml.ml_batch import SharedContext

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

HESSIAN_STEP_RTOL = 1e-6
"""Central-difference step of the exact Hessian (module text), relative to the length scale."""
WELL_CONDITIONED = 1e-6
"""``JᵀJ`` with ``det > WELL_CONDITIONED · Π diag`` (two unknowns: a condition number below
~4e6) gives the Gauss-Newton decrement from its normal equations."""
RANK_RTOL = 1e-10
"""A Jacobian column that, orthogonalised against the larger ones, is below this fraction of
the largest adds no rank."""


def decrements(
    context: SharedContext,
    trial: IntArray,
    world: FloatArray,
    scale: FloatArray,
    jacobian: Sequence[FloatArray],
    residual: FloatArray,
) -> FloatArray:
    """The decrement (module text) at each search's end point ``world`` (trials ``trial``,
    frame scales ``scale``), from the residuals' ``jacobian`` columns and ``residual`` there
    (``(m, P)``); inf where it is not finite. The Newton decrement is evaluated only where
    the Gauss-Newton one is above ``DECREMENT_TOL`` (the smaller is taken)."""
    decrement = _gauss_newton_decrement(jacobian, residual)
    # near a track's plane the Gauss-Newton decrement can stay large where the Newton
    # decrement is tiny: evaluate it there
    rest = np.flatnonzero(~(decrement <= DECREMENT_TOL) & np.isfinite(world).all(axis=1))
    if rest.size:
        newton = _newton_decrement(context, trial[rest], world[rest], scale[rest])
        decrement[rest] = np.fmin(decrement[rest], newton)
    return np.where(np.isnan(decrement), np.inf, decrement)


def _quadratic_form(
    matrix: FloatArray, vector: FloatArray, conditioning: float
) -> tuple[FloatArray, BoolArray]:
    """``vᵀ M⁻¹ v`` for symmetric ``M`` ``(P, d, d)`` and ``v`` ``(P, d)`` where ``M`` is
    positive definite (every pivot of its Cholesky factorisation positive) with
    ``det > conditioning · Π diag``, and where that holds; NaN elsewhere. Elementwise over the
    problems (``d`` is 2 or 3: a few operations per entry, no per-problem solve)."""
    d = matrix.shape[-1]
    with np.errstate(all="ignore"):
        lower: dict[tuple[int, int], FloatArray] = {}
        pivots, solved = [], []
        for j in range(d):
            pivot = matrix[:, j, j] - sum((lower[j, k] ** 2 for k in range(j)), 0.0)
            pivots.append(pivot)
            root = np.sqrt(pivot)
            for i in range(j + 1, d):
                off = matrix[:, i, j] - sum((lower[i, k] * lower[j, k] for k in range(j)), 0.0)
                lower[i, j] = off / root
            lower[j, j] = root
            # forward substitution of L w = v, one entry per pivot
            entry = vector[:, j] - sum((lower[j, k] * solved[k] for k in range(j)), 0.0)
            solved.append(entry / root)
        positive = np.logical_and.reduce([pivot > 0.0 for pivot in pivots])
        det = np.prod(pivots, axis=0)
        diagonal = np.prod([matrix[:, j, j] for j in range(d)], axis=0)
        ok = positive & (det > conditioning * diagonal)
        value = sum(entry * entry for entry in solved)
    ok &= np.isfinite(value)
    return np.where(ok, value, np.nan), ok


def _gauss_newton_decrement(jac: Sequence[FloatArray], residual: FloatArray) -> FloatArray:
    """``‖P_J e‖²`` per problem; ``J``'s columns and ``e`` are ``(m, k)``.

    From the normal equations, ``gᵀ(JᵀJ)⁻¹g`` with ``g = Jᵀe``, where ``JᵀJ`` is well
    conditioned (its rounding then moves the value by ~1e-8 relative); the rest by
    orthogonalising the columns (:func:`_orthogonal_decrement`).
    """
    d = len(jac)
    information = np.empty((residual.shape[1], d, d))
    for i in range(d):
        for j in range(i, d):
            information[:, i, j] = information[:, j, i] = column_dot(jac[i], jac[j])
    gradient = np.column_stack([column_dot(column, residual) for column in jac])
    value, well = _quadratic_form(information, gradient, WELL_CONDITIONED)
    rest = np.flatnonzero(~well)
    if rest.size:
        value[rest] = _orthogonal_decrement(
            [column.take(rest, axis=1) for column in jac], residual.take(rest, axis=1)
        )
    return value


def _orthogonal_decrement(columns: Sequence[FloatArray], residual: FloatArray) -> FloatArray:
    """:func:`_gauss_newton_decrement` by Gram-Schmidt on the columns (each twice), largest
    first, for a Jacobian of deficient rank or close to it: the squared projections of ``e``
    on the orthonormal directions of the columns that add rank (``RANK_RTOL``)."""
    norms = np.array([np.sqrt(column_dot(c, c)) for c in columns])  # (d, k)
    order = np.argsort(-norms, axis=0, kind="stable")
    largest = np.max(norms, axis=0)
    total = np.zeros(residual.shape[1])
    basis: list[FloatArray] = []
    with np.errstate(all="ignore"):
        for rank in range(len(columns)):
            v = np.choose(order[rank][None, :], columns)
            for _ in range(2):
                for unit in basis:
                    v = v - column_dot(unit, v) * unit
            size = np.sqrt(column_dot(v, v))
            adds = (size > RANK_RTOL * largest) & (largest > 0.0)
            unit = np.where(adds, v / size, 0.0)
            projection = column_dot(unit, residual)
            total = total + np.where(adds, projection * projection, 0.0)
            basis.append(unit)
    return total


def _newton_decrement(
    context: SharedContext, trial: IntArray, world: FloatArray, scale: FloatArray
) -> FloatArray:
    """``gᵀH⁻¹g`` with the central-difference Hessian (module text); inf where ``H`` is not
    positive definite."""

    def gradient(at: FloatArray) -> FloatArray:
        e = context.residuals(trial, at)
        return np.column_stack([column_dot(column, e) for column in context.jacobian(at)])

    step = HESSIAN_STEP_RTOL * scale
    columns = []
    for axis in np.eye(world.shape[1]):
        shift = step[:, None] * axis
        columns.append((gradient(world + shift) - gradient(world - shift)) / (2.0 * step[:, None]))
    hessian = np.stack(columns, axis=-1)
    hessian = 0.5 * (hessian + np.swapaxes(hessian, -1, -2))
    value, positive = _quadratic_form(hessian, gradient(world), 0.0)
    return np.where(positive, value, np.inf)
