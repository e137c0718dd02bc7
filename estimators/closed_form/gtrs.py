r"""The constrained least squares of MATH §5 for one stacked system ``A r = b``.

:func:`solve_gtrs` is :func:`~estimators.closed_form.gtrs_batch.solve_gtrs_batch` on a batch of
one (the method is described there); :func:`constrained_cost` is the objective. Both serve the
systems an estimator describes with ``constrained_ls`` (``emitterbench validate``), the SDP
relaxation's cross-check (MATH §11) and plug-ins that keep their own rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.closed_form.gtrs_batch import RowBlock, solve_gtrs_batch

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class GtrsSolution:
    """Global minimisers of MATH §5.

    Attributes
    ----------
    points : (n, d + 1)
        ``r = (s, ‖s‖²)`` of every global minimiser (1 or 2; 2 only in the hard case), ``s =
        (x, y)`` or, for rows with a height column, ``(x, y, z)``.
    costs : (n,)
        ``‖A r − b‖²`` at each point.
    multiplier : float
        λ*, the Lagrange multiplier (MATH §5).
    hard_case : bool
        ``λ* = −μ₁`` with the matrix ``M + λ*D`` singular (MATH §5).
    rank : int
        Numerical rank of ``A`` (2-D: 2 on one straight frame, 3 with two headings; 3-D: 3 on
        a level flight, 4 with a change of altitude).
    """

    points: FloatArray
    costs: FloatArray
    multiplier: float
    hard_case: bool
    rank: int


def constrained_cost(A: ArrayLike, b: ArrayLike, xy: ArrayLike) -> FloatArray:
    """``‖A (s, ‖s‖²) − b‖²`` for points ``s`` of shape (..., d), ``A`` (m, d + 1): the
    objective of §5 (``d = 2``, ``(x, y)``, or ``d = 3``, ``(x, y, z)``)."""
    xy = np.asarray(xy, dtype=float)
    r = np.concatenate([xy, np.sum(xy**2, axis=-1, keepdims=True)], axis=-1)
    residual = r @ np.asarray(A, dtype=float).T - np.asarray(b, dtype=float)
    return np.sum(residual**2, axis=-1)


def solve_gtrs(A: ArrayLike, b: ArrayLike, *, hard_case_rtol: float = 1e-10) -> GtrsSolution:
    """Every global minimiser of ``‖A r − b‖²`` s.t. ``‖s‖² = r_w`` (MATH §5).

    Parameters
    ----------
    A : (m, 3) or (m, 4)
        Stacked rows (ToA rows of §4, Doppler rows of §3, optionally whitened as in §6) over
        ``r = (x, y, x² + y²)``, or over ``r = (x, y, z, x² + y² + z²)`` with the emitter's
        height a coordinate, preferably in a frame centred on the data and scaled to order one.
    b : (m,)
    hard_case_rtol : float
        See :func:`~estimators.closed_form.gtrs_batch.solve_gtrs_batch`.

    Raises
    ------
    ValueError
        If ``A`` is not (m, 3) or (m, 4) with ``b`` (m,), if they are not finite, or if the last
        column of ``A`` is zero (no ToA rows): ``r_w`` is then unconstrained.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    if A.ndim != 2 or A.shape[1] not in (3, 4) or b.shape != (A.shape[0],):
        raise ValueError(
            f"A, b: expected shapes (m, 3) or (m, 4) and (m,), got {A.shape} and {b.shape} "
            "(MATH §5)"
        )
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        raise ValueError("A, b: the rows hold NaN or infinite values; pass finite rows")
    if not np.any(A[:, -1] != 0.0):
        raise ValueError(
            "A: the r_z column is zero (the last column); the CLS needs at least one ToA row "
            "(MATH §4)"
        )
    height = A[:, 2:3] if A.shape[1] == 4 else None
    rows = RowBlock(ax=A[:, :1], ay=A[:, 1:2], az=A[:, -1:], b=b[:, None], ah=height)
    solution = solve_gtrs_batch([rows], 1, hard_case_rtol=hard_case_rtol, rank=True)
    if solution.failed[0]:
        raise ArithmeticError("the secular equation of MATH §5 has no finite root for A, b")
    count = int(solution.count[0])
    s = np.column_stack([coordinate[0, :count] for coordinate in solution.points])
    return GtrsSolution(
        points=np.column_stack([s, np.sum(s**2, axis=1)]),
        costs=solution.costs[0, :count].copy(),
        multiplier=float(solution.multiplier[0]),
        hard_case=bool(solution.hard_case[0]),
        rank=int(solution.rank[0]),
    )
