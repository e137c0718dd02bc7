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

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import DECREMENT_TOL
from estimators.ml.minpack_batch import column_dot

if TYPE_CHECKING:
    from estimators.ml.ml_batch import SharedContext

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

HESSIAN_STEP_RTOL = 1e-6
"""Central-difference step of the exact Hessian (module text), relative to the length scale."""
WELL_CONDITIONED = 1e-6
"""``JᵀJ`` with ``det > WELL_CONDITIONED · J₁₁ J₂₂`` (condition number below ~4e6) gives the
Gauss-Newton decrement from its normal equations."""
RANK_RTOL = 1e-10
"""A Jacobian whose second column, orthogonalised, is below this fraction of the first has
rank one."""


def decrements(
    context: SharedContext,
    trial: IntArray,
    world: FloatArray,
    scale: FloatArray,
    jacobian: tuple[FloatArray, FloatArray],
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


def _gauss_newton_decrement(jac: tuple[FloatArray, FloatArray], residual: FloatArray) -> FloatArray:
    """``‖P_J e‖²`` per problem; ``J``'s columns and ``e`` are ``(m, k)``.

    From the normal equations, ``gᵀ(JᵀJ)⁻¹g`` with ``g = Jᵀe`` (five sums), where ``JᵀJ`` is
    well conditioned (its rounding then moves the value by ~1e-8 relative); the rest by
    orthogonalising the columns (:func:`_orthogonal_decrement`).
    """
    c0, c1 = jac
    a, b, d = column_dot(c0, c0), column_dot(c0, c1), column_dot(c1, c1)
    g0, g1 = column_dot(c0, residual), column_dot(c1, residual)
    with np.errstate(all="ignore"):
        det = a * d - b * b
        value = (d * g0 * g0 - 2.0 * b * g0 * g1 + a * g1 * g1) / det
    well = (det > WELL_CONDITIONED * a * d) & np.isfinite(value)
    rest = np.flatnonzero(~well)
    if rest.size:
        value[rest] = _orthogonal_decrement(
            c0.take(rest, axis=1), c1.take(rest, axis=1), residual.take(rest, axis=1)
        )
    return value


def _orthogonal_decrement(c0: FloatArray, c1: FloatArray, residual: FloatArray) -> FloatArray:
    """:func:`_gauss_newton_decrement` by Gram-Schmidt on the two columns (twice), for a
    Jacobian of rank one or close to it."""
    n0, n1 = np.sqrt(column_dot(c0, c0)), np.sqrt(column_dot(c1, c1))
    swap = n1 > n0
    a = np.where(swap, c1, c0)
    b = np.where(swap, c0, c1)
    norm = np.maximum(n0, n1)
    with np.errstate(all="ignore"):
        unit = a / norm
        v = b - column_dot(unit, b) * unit
        v = v - column_dot(unit, v) * unit
        r22 = np.sqrt(column_dot(v, v))
        first = column_dot(unit, residual)
        second = column_dot(v, residual) / r22
    rank_two = r22 > RANK_RTOL * norm
    return np.where(norm > 0.0, first * first, 0.0) + np.where(rank_two, second * second, 0.0)


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
    for axis in np.eye(2):
        shift = step[:, None] * axis
        columns.append((gradient(world + shift) - gradient(world - shift)) / (2.0 * step[:, None]))
    hessian = np.stack(columns, axis=-1)
    hessian = 0.5 * (hessian + np.swapaxes(hessian, -1, -2))
    g = gradient(world)
    a, b, d = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    with np.errstate(all="ignore"):
        det = a * d - b * b
        value = (d * g[:, 0] ** 2 - 2.0 * b * g[:, 0] * g[:, 1] + a * g[:, 1] ** 2) / det
    return np.where((a > 0.0) & (det > 0.0) & np.isfinite(value), value, np.inf)
