"""The convergence audit of :mod:`estimators.ml.ml_batch`: which searches converged for certain.

:func:`~estimators.ml.ml.ml_decrement` of the one-trial path is ``min(‖P_J e‖², gᵀH⁻¹g)`` and
its search converged when that is below ``DECREMENT_TOL``. The batch evaluates the same two
decrements for every search at once, each with a margin its rounding cannot close
(``DECREMENT_MARGIN``, ``HESSIAN_MARGIN``); a search it cannot certify is left to the
one-trial path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import DECREMENT_TOL

if TYPE_CHECKING:
    from estimators.ml.ml_batch import SharedContext

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

HESSIAN_STEP_RTOL = 1e-6
"""Central-difference step of the exact Hessian (:mod:`estimators.ml.ml`, "Convergence"),
relative to the length scale."""
DECREMENT_MARGIN = 8.0
"""A start is converged for certain when its Gauss-Newton decrement is below
``DECREMENT_TOL / DECREMENT_MARGIN`` (the one-trial decrement is never larger)."""
HESSIAN_MARGIN = 1e-6
"""A Hessian is positive definite for certain when ``det H > HESSIAN_MARGIN · H₁₁ H₂₂`` (its
central differences carry ~1e-11 relative rounding)."""
WELL_CONDITIONED = 1e-6
"""``JᵀJ`` with ``det > WELL_CONDITIONED · J₁₁ J₂₂`` (condition number below ~4e6) gives the
Gauss-Newton decrement from its normal equations."""
RANK_RTOL = 1e-10
"""A Jacobian whose second column, orthogonalised, is below this fraction of the first (but
not zero) leaves the decrement to the one-trial path."""


def converged_for_certain(
    context: SharedContext,
    trial: IntArray,
    world: FloatArray,
    scale: FloatArray,
    jacobian: tuple[FloatArray, FloatArray],
    residual: FloatArray,
    fine: BoolArray,
) -> BoolArray:
    """Whether each search's end point ``world`` (trials ``trial``, frame scales ``scale``)
    passes the one-trial convergence test for certain, from the residuals' ``jacobian``
    columns and ``residual`` there (``(m, P)``); the Newton decrement is evaluated only for
    the ``fine`` searches the Gauss-Newton one leaves undecided."""
    decrement, unsure = _gauss_newton_decrement(jacobian, residual)
    small = ~unsure & (decrement <= DECREMENT_TOL / DECREMENT_MARGIN)
    # near a track's plane the Gauss-Newton decrement can stay large where the Newton
    # decrement (the one-trial path takes the smaller) is tiny: evaluate it there
    rest = np.flatnonzero(fine & ~small)
    if rest.size:
        newton, sure = _newton_decrement(context, trial[rest], world[rest], scale[rest])
        small[rest] = sure & (newton <= DECREMENT_TOL / DECREMENT_MARGIN)
    return small


def _gauss_newton_decrement(
    jac: tuple[FloatArray, FloatArray], residual: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """``‖P_J e‖²`` per problem (:func:`~estimators.ml.ml.ml_decrement`'s Gauss-Newton part), and
    where the rank of ``J`` is too close to call for the one-trial ``lstsq`` to agree. ``J``'s
    columns and ``e`` are ``(m, k)``.

    From the normal equations, ``gᵀ(JᵀJ)⁻¹g`` with ``g = Jᵀe`` (five sums), where ``JᵀJ`` is
    well conditioned (its rounding then moves the value by ~1e-8 relative, far inside
    ``DECREMENT_MARGIN``); the rest by orthogonalising the columns (:func:`_orthogonal_decrement`).
    """
    c0, c1 = jac
    a, b, d = np.sum(c0 * c0, axis=0), np.sum(c0 * c1, axis=0), np.sum(c1 * c1, axis=0)
    g0, g1 = np.sum(c0 * residual, axis=0), np.sum(c1 * residual, axis=0)
    with np.errstate(all="ignore"):
        det = a * d - b * b
        value = (d * g0 * g0 - 2.0 * b * g0 * g1 + a * g1 * g1) / det
    well = (det > WELL_CONDITIONED * a * d) & np.isfinite(value)
    rest = np.flatnonzero(~well)
    unsure = np.zeros(len(value), dtype=bool)
    if rest.size:
        value[rest], unsure[rest] = _orthogonal_decrement(
            c0.take(rest, axis=1), c1.take(rest, axis=1), residual.take(rest, axis=1)
        )
    return value, unsure


def _orthogonal_decrement(
    c0: FloatArray, c1: FloatArray, residual: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """:func:`_gauss_newton_decrement` by Gram-Schmidt on the two columns (twice), for a
    Jacobian of rank one or close to it."""
    n0, n1 = np.sqrt(np.sum(c0 * c0, axis=0)), np.sqrt(np.sum(c1 * c1, axis=0))
    swap = n1 > n0
    a = np.where(swap, c1, c0)
    b = np.where(swap, c0, c1)
    norm = np.maximum(n0, n1)
    with np.errstate(all="ignore"):
        unit = a / norm
        v = b - np.sum(unit * b, axis=0) * unit
        v = v - np.sum(unit * v, axis=0) * unit
        r22 = np.sqrt(np.sum(v * v, axis=0))
        first = np.sum(unit * residual, axis=0)
        second = np.sum(v * residual, axis=0) / r22
    rank_two = r22 > RANK_RTOL * norm
    zero_column = ~np.any(b != 0.0, axis=0)
    value = np.where(norm > 0.0, first * first, 0.0) + np.where(rank_two, second * second, 0.0)
    unsure = ~(rank_two | zero_column) | ~np.isfinite(value)
    return value, unsure


def _newton_decrement(
    context: SharedContext, trial: IntArray, world: FloatArray, scale: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """``gᵀH⁻¹g`` with :func:`~estimators.ml.ml.ml_decrement`'s central-difference Hessian, and
    where ``H`` is positive definite by a margin the one-trial rounding cannot close."""

    def gradient(at: FloatArray) -> FloatArray:
        e = context.residuals(trial, at)
        return np.column_stack([np.sum(column * e, axis=0) for column in context.jacobian(at)])

    step = HESSIAN_STEP_RTOL * scale
    columns = []
    for axis in np.eye(2):
        shift = step[:, None] * axis
        columns.append((gradient(world + shift) - gradient(world - shift)) / (2.0 * step[:, None]))
    hessian = np.stack(columns, axis=-1)
    hessian = 0.5 * (hessian + np.swapaxes(hessian, -1, -2))
    g = gradient(world)
    a, b, d = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    det = a * d - b * b
    with np.errstate(all="ignore"):
        value = (d * g[:, 0] ** 2 - 2.0 * b * g[:, 0] * g[:, 1] + a * g[:, 1] ** 2) / det
    sure = (a > 0.0) & (det > HESSIAN_MARGIN * np.abs(a * d)) & np.isfinite(value)
    return value, sure
