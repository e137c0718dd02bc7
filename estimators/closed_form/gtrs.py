r"""Exact solution of the constrained least squares of MATH §5 (paper eq ``finalest``, corrected).

.. math::

    \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad r_x^2 + r_y^2 - r_z = 0,
    \qquad r = (x_s, y_s, x_s^2 + y_s^2)

a generalized trust-region subproblem (GTRS). With ``M = AᵀA``, ``q = Aᵀb``, ``D = diag(1,1,0)``
and ``g = (0, 0, −½)`` the stationarity condition is ``(M + λD) r = q − λg`` (the paper drops the
transpose), and the global minimiser is the stationary point with ``M + λD ⪰ 0`` (Moré 1993;
Beck, Stoica & Li 2008).

Derivation used here. Eliminating ``r_z`` with the Schur complement of ``M33``,
``S = M[:2,:2] − m mᵀ/M33`` with ``m = M[:2, 2]``, and writing ``S = U diag(μ₁ ≤ μ₂) Uᵀ``,
``a = q[:2] − m q₃/M33``, ``h = m/(2 M33)``, ``ã = Uᵀa``, ``h̃ = Uᵀh``, ``e = ã + μ h̃``:

.. math::

    \tilde y_i(\lambda) + \tilde h_i = \frac{e_i}{\mu_i + \lambda},\qquad
    \varphi(\lambda) = \lVert y\rVert^2 - r_z
      = \sum_i \frac{e_i^2}{(\mu_i+\lambda)^2} - \lVert\tilde h\rVert^2 - \frac{q_3 + \lambda/2}{M_{33}}

``φ`` is strictly decreasing on ``λ > −μ₁`` (the interval where ``M + λD ≻ 0``), so its single
root is found by a bracketed scalar method (Brent).

Hard case, the normal case here (MATH §5). When ``e₁ = 0`` (every single straight frame: ``A``
has rank 2) the pole at ``−μ₁`` disappears. If ``φ(−μ₁)`` computed without the ``e₁`` term is
negative, ``λ* = −μ₁`` and the minimisers are ``ỹ₁ = −h̃₁ ± √(−φ(−μ₁))``: the emitter and its
mirror image across the track, of exactly equal cost. Otherwise the root lies inside the interval
and the minimiser is unique (the least-squares line misses the paraboloid; it lies on the track's
vertical plane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from estimators.closed_form.gtrs_batch import equal_to_rounding
from estimators.closed_form.gtrs_rounding import RANK_RTOL

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class GtrsSolution:
    """Global minimisers of MATH §5.

    Attributes
    ----------
    points : (n, 3)
        ``r = (x, y, x² + y²)`` of every global minimiser (1 or 2; 2 only in the hard case).
    costs : (n,)
        ``‖A r − b‖²`` at each point.
    multiplier : float
        λ*, the Lagrange multiplier (MATH §5).
    hard_case : bool
        ``λ* = −μ₁`` with the matrix ``M + λ*D`` singular (MATH §5).
    rank : int
        Numerical rank of ``A`` (2 on one straight frame, 3 with two headings).
    """

    points: FloatArray
    costs: FloatArray
    multiplier: float
    hard_case: bool
    rank: int


def constrained_cost(A: ArrayLike, b: ArrayLike, xy: ArrayLike) -> FloatArray:
    """``‖A (x, y, x²+y²) − b‖²`` for points ``xy`` of shape (..., 2): the objective of §5."""
    xy = np.asarray(xy, dtype=float)
    r = np.concatenate([xy, np.sum(xy**2, axis=-1, keepdims=True)], axis=-1)
    residual = r @ np.asarray(A, dtype=float).T - np.asarray(b, dtype=float)
    return np.sum(residual**2, axis=-1)


def solve_gtrs(A: ArrayLike, b: ArrayLike, *, hard_case_rtol: float = 1e-10) -> GtrsSolution:
    """Every global minimiser of ``‖A r − b‖²`` s.t. ``r_x² + r_y² = r_z`` (MATH §5).

    Parameters
    ----------
    A : (m, 3)
        Stacked rows (ToA rows of §4, Doppler rows of §3, optionally whitened as in §6),
        preferably in a frame centred on the data and scaled to order one.
    b : (m,)
    hard_case_rtol : float
        The hard case is considered when the root of φ would lie within
        ``hard_case_rtol · μ₂`` of the pole ``−μ₁``, and declared only if the two points of the
        null line then have costs equal to rounding (they differ by ``4|e₁|√(−φ(−μ₁))``);
        otherwise the unique root is returned.

    Raises
    ------
    ValueError
        If the third column of ``A`` is zero (no ToA rows): ``r_z`` is then unconstrained.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    M = A.T @ A
    q = A.T @ b
    m, m33, q3 = M[:2, 2], M[2, 2], q[2]
    if not m33 > 0.0:
        raise ValueError("A: the r_z column is zero; the CLS needs at least one ToA row (MATH §4)")
    singular_values = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(singular_values > singular_values[0] * RANK_RTOL))

    S = M[:2, :2] - np.outer(m, m) / m33
    mu, U = np.linalg.eigh(S)  # ascending, μ₁ ≤ μ₂
    a_t = U.T @ (q[:2] - m * q3 / m33)
    h_t = U.T @ (m / (2.0 * m33))
    e = a_t + mu * h_t
    mu_scale = max(abs(mu[1]), np.finfo(float).tiny)
    h_sq = float(h_t @ h_t)

    gap = mu[1] - mu[0]
    second_at_pole = e[1] ** 2 / gap**2 if gap > 0 else (0.0 if e[1] == 0 else np.inf)

    def phi(shift: float, include_first: bool = True) -> float:
        """φ(λ) at λ = −μ₁ + shift (MATH §5); the e₁ term dropped when ``include_first`` is off."""
        lam = shift - mu[0]
        first = (e[0] / shift) ** 2 if include_first else 0.0  # shift² underflows first
        second = e[1] ** 2 / (gap + shift) ** 2 if shift > 0 else second_at_pole
        return float(first + second - h_sq - (q3 + lam / 2.0) / m33)

    phi_pole = phi(0.0, include_first=False)
    hard = False
    if phi_pole < 0.0 and abs(e[0]) <= hard_case_rtol * mu_scale * np.sqrt(-phi_pole):
        # Hard case: λ* = −μ₁, both points of the null line on the paraboloid (MATH §5).
        lam = -mu[0]
        y2 = (e[1] / gap if gap > 0 else 0.0) - h_t[1]
        half_width = np.sqrt(-phi_pole)
        y_t = np.array([[-h_t[0] + half_width, y2], [-h_t[0] - half_width, y2]])
        points, costs = _lift_and_cost(y_t @ U.T, A, b)
        # A small but real e₁ (two headings a few millidegrees apart) passes the screen above,
        # yet the pair's costs then differ by 4|e₁|√(−φ(−μ₁)): keep the pair only when its costs
        # agree to rounding, else the minimiser is the unique root below.
        hard = costs_equal_to_rounding(costs, A, b, points)
    if not hard:
        shift = _root_of_decreasing(phi, e, mu_scale)
        lam = shift - mu[0]
        denominator = np.array([shift, gap + shift])  # μ + λ, without cancellation
        ratio = np.divide(e, denominator, out=np.zeros(2), where=denominator > 0)
        points, costs = _lift_and_cost((ratio - h_t)[None, :] @ U.T, A, b)
    return GtrsSolution(
        points=points, costs=costs, multiplier=float(lam), hard_case=hard, rank=rank
    )


def _lift_and_cost(xy: FloatArray, A: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Points ``r = (x, y, x² + y²)`` (n, 3) and their costs ``‖A r − b‖²`` (n,)."""
    points = np.column_stack([xy, np.sum(xy**2, axis=1)])
    return points, np.sum((points @ A.T - b) ** 2, axis=1)


def costs_equal_to_rounding(
    costs: FloatArray, A: FloatArray, b: FloatArray, points: FloatArray
) -> bool:
    """Whether two hard-case costs ``‖A r − b‖²`` differ by no more than the rounding of their
    evaluation: :func:`~estimators.closed_form.gtrs_batch.equal_to_rounding` (the rule and its
    bound) for this one pair of points ``r`` (the rows of ``points``)."""
    equal, _ = equal_to_rounding(
        costs[None],
        np.max(np.linalg.norm(points, axis=1))[None],
        np.linalg.norm(A)[None],
        np.linalg.norm(b)[None],
        len(b),
    )
    return bool(equal[0])


def _root_of_decreasing(phi, e: FloatArray, scale: float) -> float:
    """The root in ``shift > 0`` of φ(−μ₁ + shift), strictly decreasing from φ(0⁺) to −∞.

    Returns 0 when φ(0⁺) ≤ 0 (the root sits on the pole: ``e₁ = 0`` and φ touches zero there).
    """
    tiny = np.finfo(float).tiny
    low = max(abs(e[0]), scale * 1e-12, tiny)
    for _ in range(2000):
        if phi(low) > 0.0:
            break
        low *= 0.5
        if low < tiny * 1e3:
            return 0.0
    high = max(2.0 * low, scale, 1.0)
    while phi(high) > 0.0:
        low, high = high, 2.0 * high
    return brentq(phi, low, high, xtol=1e-300, rtol=4 * np.finfo(float).eps, maxiter=500)
