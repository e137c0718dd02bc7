r"""Exact global solution of a GTRS with an indefinite diagonal constraint (MATH §15).

.. math::

    \min_\theta \lVert A\theta - b\rVert^2 \quad\text{s.t.}\quad
    \theta^\top D\theta + 2g^\top\theta = c, \qquad D = \operatorname{diag}(d),

with every ``d_i ≠ 0`` and both signs present. The closed form of the unknown emission time
(:mod:`estimators.closed_form.pseudorange_cls`) has ``θ = (x − x_j, y − y_j, ρ_j)``, ``D = diag(1,
1, −1)``, ``g = 0``, ``c = −(z_j − z_s)²``: a hyperboloid of two sheets, the physical one ``ρ_j >
0``.

**Optimality** (Moré 1993, "Generalizations of the trust region problem"). With
``M = AᵀA`` and ``q = Aᵀb``, a regular feasible θ* (``Dθ* + g ≠ 0``) is a global minimiser iff
for some λ

.. math::

    (M + \lambda D)\,\theta^* = q - \lambda g, \qquad M + \lambda D \succeq 0 .

``M + λD ≻ 0`` holds on an open interval ``I = (λ_lo, λ_hi)`` (empty when the pencil is not
definite, e.g. ``A`` annihilates a direction with ``uᵀDu = 0``). Because D has both signs both
ends are finite: ``det(M + λD)`` has ``n_pos`` roots below I and ``n_neg`` above it.

**Diagonalising the pencil.** Pick ``λ₀ ∈ I`` (the midpoint of the two roots of
``det(M + λD)`` that bound I), factor ``M + λ₀D = LLᵀ`` and ``L⁻¹DL⁻ᵀ = W diag(ν) Wᵀ``
(``ν`` has the inertia of D). In ``y = WᵀLᵀθ``, with ``μ = λ − λ₀``,
``α = WᵀL⁻¹(q − λ₀g)``, ``e = WᵀL⁻¹g``, ``κ = e/ν`` and ``β = α + κ``:

.. math::

    y_i(\mu) = \frac{\beta_i}{1 + \mu\nu_i} - \kappa_i, \qquad
    \varphi(\mu) = \theta^\top D\theta + 2g^\top\theta - c
      = \sum_i \frac{\nu_i \beta_i^2}{(1 + \mu\nu_i)^2} - \sum_i \frac{e_i^2}{\nu_i} - c .

``I`` is ``μ ∈ (−1/ν_max, −1/ν_min)``, and there
``φ'(μ) = −2 Σ ν_i²β_i²/(1 + μν_i)³ < 0``: φ is strictly decreasing, from ``+∞`` at the lower
end (the pole of the largest ν > 0) to ``−∞`` at the upper end (the smallest ν < 0). So the
root in I is unique and is bracketed and found by Brent's method, with the denominators
written as offsets from the nearer end so that a root close to a pole keeps its precision.

**Hard case.** If ``β_max = 0`` the lower pole disappears and φ is finite there; if then
``φ(λ_lo) ≤ 0`` the root is not in I, ``λ* = λ_lo``, ``M + λ*D`` is singular and every
``y`` with ``y_max = −κ_max ± t``, ``t = √(−φ_rest/ν_max)`` (``φ_rest``: φ at the pole without
the vanished term) is a global minimiser: **two minimisers of exactly equal cost** (the
Lagrangian is constant along the null line of ``M + λ*D``). Symmetrically at the upper end when
``β_min = 0`` and ``φ(λ_hi) ≥ 0``, with ``t = √(φ_rest/|ν_min|)``. A repeated extreme ν in
the hard case makes the minimisers a circle; two of its points are returned and
``continuum`` is set. :func:`stationary_points` lists every real root of the secular
equation (stationary points with ``M + λD`` indefinite too), for minimising over one sheet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from estimators.closed_form.gtrs import costs_equal_to_rounding
from estimators.closed_form.gtrs_rounding import RANK_RTOL

FloatArray = NDArray[np.float64]

_EPS = np.finfo(float).eps


@dataclass(frozen=True, slots=True, eq=False)
class IndefiniteGtrsSolution:
    """Every global minimiser of the indefinite GTRS, with the diagnostics of the solve.

    Attributes
    ----------
    points : (n, dim)
        The global minimisers (1, or 2 in the hard case; 0 when ``status`` is
        ``"no-definite-interval"``).
    costs : (n,)
        ``‖Aθ − b‖²`` at each point.
    multiplier : float
        λ*, NaN without a definite interval.
    interval : (2,)
        ``(λ_lo, λ_hi)``, where ``M + λD ≻ 0``.
    hard_case : bool
        λ* is an end of the interval and ``M + λ*D`` is singular.
    hard_end : str or None
        ``"lower"`` or ``"upper"`` in the hard case.
    continuum : bool
        The hard case with a repeated extreme eigenvalue: a circle of minimisers, two returned.
    rank : int
        Numerical rank of ``A``.
    status : str
        ``"interior-root"``, ``"hard-case"`` or ``"no-definite-interval"``.
    """

    points: FloatArray
    costs: FloatArray
    multiplier: float
    interval: FloatArray
    hard_case: bool
    hard_end: str | None
    continuum: bool
    rank: int
    status: str


@dataclass(frozen=True, slots=True, eq=False)
class _Pencil:
    """The simultaneous diagonalisation of ``(M + λ₀D, D)`` and the secular data."""

    lam0: float
    back: FloatArray  # θ = back @ y, back = L⁻ᵀ W
    nu: FloatArray
    beta: FloatArray
    kappa: FloatArray
    offset: float  # Σ e²/ν + c

    def theta(self, y: FloatArray) -> FloatArray:
        return y @ self.back.T


def indefinite_cost(A: ArrayLike, b: ArrayLike, theta: ArrayLike) -> FloatArray:
    """``‖Aθ − b‖²`` for ``theta`` of shape (..., dim)."""
    residual = np.asarray(theta, dtype=float) @ np.asarray(A, dtype=float).T - np.asarray(b)
    return np.sum(residual**2, axis=-1)


def constraint_value(theta: ArrayLike, d: ArrayLike, g: ArrayLike, c: float) -> FloatArray:
    """``θᵀDθ + 2gᵀθ − c`` for ``theta`` of shape (..., dim): zero on the constraint."""
    theta = np.asarray(theta, dtype=float)
    return np.sum(np.asarray(d) * theta**2 + 2.0 * np.asarray(g) * theta, axis=-1) - c


def solve_gtrs_indefinite(
    A: ArrayLike,
    b: ArrayLike,
    d: ArrayLike,
    g: ArrayLike | None = None,
    c: float = 0.0,
    *,
    hard_case_rtol: float = 1e-10,
) -> IndefiniteGtrsSolution:
    """Every global minimiser of ``‖Aθ − b‖²`` s.t. ``θᵀdiag(d)θ + 2gᵀθ = c`` (module text).

    Parameters
    ----------
    A : (m, dim)
    b : (m,)
    d : (dim,)
        The diagonal of D: no zero, both signs.
    g : (dim,), optional
        Zero by default.
    c : float
    hard_case_rtol : float
        The hard case is considered when the root would lie within ``hard_case_rtol`` times the
        interval's width of an end, and declared only if the two points then have costs equal
        to rounding; otherwise the unique root is returned.

    Raises
    ------
    ValueError
        If ``d`` has a zero or a single sign, or the shapes disagree.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    d = np.asarray(d, dtype=float)
    dim = A.shape[1]
    g = np.zeros(dim) if g is None else np.asarray(g, dtype=float)
    if d.shape != (dim,) or g.shape != (dim,) or b.shape != (A.shape[0],):
        raise ValueError(f"A, b, d, g: shapes {A.shape}, {b.shape}, {d.shape}, {g.shape} disagree")
    if np.any(d == 0.0) or not (np.any(d > 0.0) and np.any(d < 0.0)):
        raise ValueError(f"d: expected nonzero entries of both signs, got {d.tolist()}")
    singular_values = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(singular_values > max(singular_values[0], _EPS) * RANK_RTOL))
    M, q = A.T @ A, A.T @ b
    pencil = _diagonalise(M, q, d, g, float(c))
    if pencil is None:
        return IndefiniteGtrsSolution(
            points=np.zeros((0, dim)),
            costs=np.zeros(0),
            multiplier=float("nan"),
            interval=np.array([np.nan, np.nan]),
            hard_case=False,
            hard_end=None,
            continuum=False,
            rank=rank,
            status="no-definite-interval",
        )
    nu, beta, kappa = pencil.nu, pencil.beta, pencil.kappa
    mu_lo, mu_hi = -1.0 / nu[-1], -1.0 / nu[0]
    width = mu_hi - mu_lo
    interval = pencil.lam0 + np.array([mu_lo, mu_hi])
    # denominators 1 + μν at the two ends, computed without cancellation
    den_at_lo = (nu[-1] - nu) / nu[-1]
    den_at_hi = (nu - nu[0]) / -nu[0]

    for end, den0, index, sign in (("lower", den_at_lo, -1, 1.0), ("upper", den_at_hi, 0, -1.0)):
        group = den0 <= 1e-12  # the extreme eigenvalue (repeated: a circle of minimisers)
        rest = float(np.sum(nu[~group] * beta[~group] ** 2 / den0[~group] ** 2) - pencil.offset)
        t_sq = -rest / nu[index]
        if t_sq < 0.0:
            continue
        t = np.sqrt(t_sq)
        if np.linalg.norm(beta[group]) > hard_case_rtol * width * abs(nu[index]) * max(t, _EPS):
            continue
        y = np.where(group, -kappa, 0.0)
        y[~group] = beta[~group] / den0[~group] - kappa[~group]
        ys = np.array([y, y])
        ys[0, index] += t
        ys[1, index] -= t
        points = pencil.theta(ys)
        costs = indefinite_cost(A, b, points)
        if costs_equal_to_rounding(costs, A, b, points):
            return IndefiniteGtrsSolution(
                points=points,
                costs=costs,
                multiplier=float(interval[0] if sign > 0 else interval[1]),
                interval=interval,
                hard_case=True,
                hard_end=end,
                continuum=bool(np.count_nonzero(group) > 1),
                rank=rank,
                status="hard-case",
            )

    mu, den = _interior_root(nu, beta, pencil.offset, mu_lo, mu_hi)
    ratio = np.divide(beta, den, out=np.zeros_like(beta), where=den != 0.0)
    points = pencil.theta((ratio - kappa)[None, :])
    return IndefiniteGtrsSolution(
        points=points,
        costs=indefinite_cost(A, b, points),
        multiplier=float(pencil.lam0 + mu),
        interval=interval,
        hard_case=False,
        hard_end=None,
        continuum=False,
        rank=rank,
        status="interior-root",
    )


def stationary_points(
    A: ArrayLike, b: ArrayLike, d: ArrayLike, g: ArrayLike | None = None, c: float = 0.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Every regular stationary point off the poles: the real roots of the secular equation.

    Clearing the denominators of ``φ(μ) = 0`` gives a polynomial of degree ``2·dim``; each real
    root (refined by Newton steps on φ) is a KKT point, with ``M + λD`` indefinite unless λ is
    in I. Their lowest-cost member on a chosen part of the constraint (one sheet of a
    hyperboloid) is that part's minimiser when it is attained at a regular point off the
    poles. Returns ``(points (n, dim), costs (n,), multipliers (n,))``, by cost; empty
    without a definite interval.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    d = np.asarray(d, dtype=float)
    dim = A.shape[1]
    g = np.zeros(dim) if g is None else np.asarray(g, dtype=float)
    pencil = _diagonalise(A.T @ A, A.T @ b, d, g, float(c))
    if pencil is None:
        return np.zeros((0, dim)), np.zeros(0), np.zeros(0)
    nu, beta = pencil.nu, pencil.beta
    factors = [np.polynomial.Polynomial([1.0, v]) ** 2 for v in nu]
    poly = -pencil.offset * np.prod(factors)
    for i in range(dim):
        others = np.prod([factors[j] for j in range(dim) if j != i])
        poly = poly + nu[i] * beta[i] ** 2 * others
    roots = poly.roots()
    scale = max(1.0, float(np.max(np.abs(roots)))) if len(roots) else 1.0
    real = np.sort(roots[np.abs(roots.imag) <= 1e-6 * scale].real)
    tolerance_scale = 1.0 + abs(pencil.offset) + float(np.sum(np.abs(nu) * beta**2))

    def secular(mu: float) -> tuple[float, float]:
        den = 1.0 + mu * nu
        if np.any(np.abs(den) < 1e-14):
            return np.inf, 0.0
        phi = float(np.sum(nu * beta**2 / den**2) - pencil.offset)
        return phi, float(-2.0 * np.sum(nu**2 * beta**2 / den**3))

    found = []
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for root in real:
            mu, (phi, slope) = root, secular(root)
            for _ in range(8):  # Newton on φ itself, kept only while |φ| decreases
                if not (np.isfinite(phi) and np.isfinite(slope)) or slope == 0.0:
                    break
                trial = mu - phi / slope
                phi_trial, slope_trial = secular(trial)
                if not abs(phi_trial) < abs(phi):
                    break
                mu, phi, slope = trial, phi_trial, slope_trial
            if abs(phi) <= 1e-8 * tolerance_scale:  # drops spurious near-real roots
                found.append((mu, beta / (1.0 + mu * nu) - pencil.kappa))
    if not found:
        return np.zeros((0, dim)), np.zeros(0), np.zeros(0)
    points = pencil.theta(np.array([y for _, y in found]))
    costs = indefinite_cost(A, b, points)
    order = np.argsort(costs)
    multipliers = pencil.lam0 + np.array([mu for mu, _ in found])
    return points[order], costs[order], multipliers[order]


def _diagonalise(
    M: FloatArray, q: FloatArray, d: FloatArray, g: FloatArray, c: float
) -> _Pencil | None:
    """The pencil at an interior ``λ₀`` (module text), or None if ``M + λD ≻ 0`` nowhere."""
    lam0 = _interior_multiplier(M, d)
    if lam0 is None:
        return None
    try:
        L = np.linalg.cholesky(M + lam0 * np.diag(d))
    except np.linalg.LinAlgError:
        return None
    L_inv = np.linalg.inv(L)  # small and well conditioned: λ₀ is mid-interval
    K = (L_inv * d[None, :]) @ L_inv.T  # L⁻¹ D L⁻ᵀ
    nu, W = np.linalg.eigh(0.5 * (K + K.T))
    if not (nu[0] < 0.0 < nu[-1]):
        return None
    back = L_inv.T @ W  # L⁻ᵀ W
    alpha = back.T @ (q - lam0 * g)  # Wᵀ L⁻¹ (q − λ₀ g)
    e = back.T @ g
    kappa = e / nu
    return _Pencil(
        lam0=lam0,
        back=back,
        nu=nu,
        beta=alpha + kappa,
        kappa=kappa,
        offset=float(np.sum(e * kappa) + c),
    )


def _interior_multiplier(M: FloatArray, d: FloatArray) -> float | None:
    """A λ with ``M + λD ≻ 0``: the midpoint of the roots of ``det(M + λD)`` around I.

    With ``T = |D|^(-1/2)`` and ``J = sign(D)``, ``M + λD = T⁻¹(TMT + λJ)T⁻¹``, so the roots are
    the eigenvalues of ``−J TMT``; ``n_pos`` of them lie below I and ``n_neg`` above.
    """
    t = 1.0 / np.sqrt(np.abs(d))
    J = np.sign(d)
    Mt = t[:, None] * M * t[None, :]
    roots = np.linalg.eigvals(-J[:, None] * Mt)
    scale = max(1.0, float(np.max(np.abs(roots))))
    n_pos = int(np.count_nonzero(d > 0))
    if np.all(np.abs(roots.imag) <= 1e-8 * scale):
        ordered = np.sort(roots.real)
        low, high = ordered[n_pos - 1], ordered[n_pos]
        if high > low:
            return float(0.5 * (low + high))
    try:  # roots too close to separate: λ = 0 still serves if M itself is definite
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return None
    return 0.0


def _interior_root(
    nu: FloatArray, beta: FloatArray, offset: float, mu_lo: float, mu_hi: float
) -> tuple[float, FloatArray]:
    """The root of the decreasing φ in ``(μ_lo, μ_hi)`` and the denominators ``1 + μν`` there.

    φ(0) decides the half; the root is then sought as an offset from that half's end, whose
    pole term is evaluated as ``offset · ν`` exactly. A root on the pole itself (a vanishing
    β, but unequal hard-case costs) returns that end.
    """
    phi_mid = float(np.sum(nu * beta**2) - offset)  # μ = 0: every denominator is 1
    if phi_mid > 0.0:  # root in (0, μ_hi): offset u from the upper end, φ increasing in u
        base, slope, span, sign = (nu - nu[0]) / -nu[0], -nu, mu_hi, -1.0
    else:  # root in (μ_lo, 0]: offset s from the lower end, φ decreasing in s
        base, slope, span, sign = (nu[-1] - nu) / nu[-1], nu, -mu_lo, 1.0

    def phi(gap: float) -> float:
        den = base + gap * slope
        return float(sign * (np.sum(nu * beta**2 / den**2) - offset))

    if phi_mid == 0.0:
        return 0.0, np.ones_like(nu)
    # sign·φ < 0 at gap = span (the middle) and → +∞ at gap → 0 unless the pole term vanished
    low = 0.5 * span
    tiny = np.finfo(float).tiny
    while phi(low) <= 0.0:
        low *= 0.5
        if low < tiny * 1e6:
            return (mu_hi if sign < 0 else mu_lo), base
    high = span
    if phi(high) > 0.0:  # rounding at the middle: the root is at μ = 0
        return 0.0, np.ones_like(nu)
    gap = brentq(phi, low, high, xtol=1e-300, rtol=4 * _EPS, maxiter=500)
    mu = mu_hi - gap if sign < 0 else mu_lo + gap
    return mu, base + gap * slope


__all__ = [
    "IndefiniteGtrsSolution",
    "constraint_value",
    "indefinite_cost",
    "solve_gtrs_indefinite",
    "stationary_points",
]
