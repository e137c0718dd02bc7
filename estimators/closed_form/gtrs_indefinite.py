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
root in I is unique and is bracketed and found by a safeguarded Newton iteration (every
system of a batch at once), with the denominators written as offsets from the nearer end so
that a root close to a pole keeps its precision.

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

from estimators.closed_form.gtrs_batch import equal_to_rounding
from estimators.closed_form.gtrs_rank import RANK_RTOL

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

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


HARD_ENDS = (None, "lower", "upper")
"""``hard_end`` of :class:`IndefiniteGtrsBatch` indexes this: no hard case, or its end."""

STATUSES = ("interior-root", "hard-case", "no-definite-interval")
"""``status`` of :class:`IndefiniteGtrsBatch` indexes this."""


@dataclass(frozen=True, slots=True, eq=False)
class IndefiniteGtrsBatch:
    """:class:`IndefiniteGtrsSolution` of ``n`` systems, field by field (systems first).

    Attributes
    ----------
    points : (n, 2, dim)
        System ``i``'s global minimisers are ``points[i, :count[i]]``; NaN beyond.
    count : (n,)
        0 (no definite interval), 1, or 2 (the hard case).
    costs : (n, 2)
        ``‖Aθ − b‖²`` at the points; NaN beyond ``count``.
    multiplier : (n,)
    interval : (n, 2)
    hard_end : (n,)
        An index into :data:`HARD_ENDS`: 0 (not the hard case), 1 (lower), 2 (upper).
    continuum : (n,) bool
    rank : (n,)
    definite : (n,) bool
        False where ``M + λD ≻ 0`` nowhere (status ``"no-definite-interval"``).
    """

    points: FloatArray
    count: IntArray
    costs: FloatArray
    multiplier: FloatArray
    interval: FloatArray
    hard_end: IntArray
    continuum: BoolArray
    rank: IntArray
    definite: BoolArray

    @property
    def hard_case(self) -> BoolArray:
        return self.hard_end > 0

    @property
    def status(self) -> IntArray:
        """An index into :data:`STATUSES` per system."""
        return np.where(self.definite, np.where(self.hard_case, 1, 0), 2)

    def solution(self, index: int) -> IndefiniteGtrsSolution:
        """System ``index`` as an :class:`IndefiniteGtrsSolution`."""
        count = int(self.count[index])
        return IndefiniteGtrsSolution(
            points=self.points[index, :count].copy(),
            costs=self.costs[index, :count].copy(),
            multiplier=float(self.multiplier[index]),
            interval=self.interval[index].copy(),
            hard_case=bool(self.hard_case[index]),
            hard_end=HARD_ENDS[int(self.hard_end[index])],
            continuum=bool(self.continuum[index]),
            rank=int(self.rank[index]),
            status=STATUSES[int(self.status[index])],
        )


@dataclass(frozen=True, slots=True, eq=False)
class _Pencil:
    """The simultaneous diagonalisation of ``(M + λ₀D, D)`` and the secular data, per system
    (placeholders where ``definite`` is false)."""

    definite: BoolArray  # (n,)
    lam0: FloatArray  # (n,)
    back: FloatArray  # (n, dim, dim): θ = back @ y, back = L⁻ᵀ W
    nu: FloatArray  # (n, dim), ascending
    beta: FloatArray  # (n, dim)
    kappa: FloatArray  # (n, dim)
    offset: FloatArray  # (n,): Σ e²/ν + c

    def theta(self, y: FloatArray) -> FloatArray:
        """``θ = back y`` for ``y`` of shape (n, k, dim)."""
        return y @ np.swapaxes(self.back, -1, -2)


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

    The batch of one of :func:`solve_gtrs_indefinite_batch`.

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
    if A.ndim != 2 or b.shape != A.shape[:1]:
        raise ValueError(f"A, b: shapes {A.shape}, {b.shape} disagree (expected (m, dim), (m,))")
    batch = solve_gtrs_indefinite_batch(A[None], b[None], d, g, c, hard_case_rtol=hard_case_rtol)
    return batch.solution(0)


def solve_gtrs_indefinite_batch(
    A: ArrayLike,
    b: ArrayLike,
    d: ArrayLike,
    g: ArrayLike | None = None,
    c: ArrayLike = 0.0,
    *,
    hard_case_rtol: float = 1e-10,
) -> IndefiniteGtrsBatch:
    """:func:`solve_gtrs_indefinite` of ``n`` systems at once (module text).

    ``A`` (n, m, dim), ``b`` (n, m); ``d`` and ``g`` (dim,) are shared, ``c`` a float or (n,).
    The pencil is diagonalised for every system by numpy's stacked factorisations, the hard
    case is decided per system, and the secular root is found for all at once
    (:func:`_interior_root`).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    d = np.asarray(d, dtype=float)
    if A.ndim != 3:
        raise ValueError(f"A: expected shape (n, m, dim), got {A.shape}")
    n, _, dim = A.shape
    g = np.zeros(dim) if g is None else np.asarray(g, dtype=float)
    if d.shape != (dim,) or g.shape != (dim,) or b.shape != A.shape[:2]:
        raise ValueError(f"A, b, d, g: shapes {A.shape}, {b.shape}, {d.shape}, {g.shape} disagree")
    if np.any(d == 0.0) or not (np.any(d > 0.0) and np.any(d < 0.0)):
        raise ValueError(f"d: expected nonzero entries of both signs, got {d.tolist()}")
    c = np.broadcast_to(np.asarray(c, dtype=float), (n,))
    points = np.full((n, 2, dim), np.nan)
    costs = np.full((n, 2), np.nan)
    count = np.zeros(n, dtype=np.int64)
    multiplier = np.full(n, np.nan)
    interval = np.full((n, 2), np.nan)
    hard_end = np.zeros(n, dtype=np.int64)
    continuum = np.zeros(n, dtype=bool)
    if n == 0:
        rank = np.zeros(0, dtype=np.int64)
        return IndefiniteGtrsBatch(
            points, count, costs, multiplier, interval, hard_end, continuum, rank, count > 0
        )
    singular_values = np.linalg.svd(A, compute_uv=False)
    floor = np.maximum(singular_values[:, 0], _EPS) * RANK_RTOL
    rank = np.sum(singular_values > floor[:, None], axis=1).astype(np.int64)
    At = np.swapaxes(A, -1, -2)
    M, q = At @ A, (At @ b[..., None])[..., 0]
    with np.errstate(all="ignore"):  # the placeholders of systems without a definite interval
        pencil = _diagonalise(M, q, d, g, c)
        definite = pencil.definite
        nu, beta, kappa = pencil.nu, pencil.beta, pencil.kappa
        mu_lo, mu_hi = -1.0 / nu[:, -1], -1.0 / nu[:, 0]
        width = mu_hi - mu_lo
        interval[definite] = (pencil.lam0[:, None] + np.column_stack([mu_lo, mu_hi]))[definite]
        # denominators 1 + μν at the two ends, computed without cancellation
        den_at_lo = (nu[:, -1:] - nu) / nu[:, -1:]
        den_at_hi = (nu - nu[:, :1]) / -nu[:, :1]
        for code, den0, index in ((1, den_at_lo, -1), (2, den_at_hi, 0)):
            group = den0 <= 1e-12  # the extreme eigenvalue (repeated: a circle of minimisers)
            safe = np.where(group, 1.0, den0)
            rest = np.sum(np.where(group, 0.0, nu * beta**2 / safe**2), axis=1) - pencil.offset
            t_sq = -rest / nu[:, index]
            t = np.sqrt(np.maximum(t_sq, 0.0))
            vanished = np.sqrt(np.sum(np.where(group, beta, 0.0) ** 2, axis=1))
            tolerance = hard_case_rtol * width * np.abs(nu[:, index]) * np.maximum(t, _EPS)
            trying = np.flatnonzero(definite & (hard_end == 0) & (t_sq >= 0.0))
            trying = trying[~(vanished[trying] > tolerance[trying])]
            if trying.size == 0:
                continue
            y = np.where(group, -kappa, beta / safe - kappa)[trying]
            ys = np.stack([y, y], axis=1)
            ys[:, 0, index] += t[trying]
            ys[:, 1, index] -= t[trying]
            pair = ys @ np.swapaxes(pencil.back[trying], -1, -2)
            pair_costs = _batch_costs(A[trying], b[trying], pair)
            equal = equal_to_rounding(
                pair_costs,
                np.max(np.linalg.norm(pair, axis=2), axis=1),
                np.sqrt(np.sum(A[trying] ** 2, axis=(1, 2))),
                np.linalg.norm(b[trying], axis=1),
                b.shape[1],
            )
            accepted = trying[equal]
            points[accepted] = pair[equal]
            costs[accepted] = pair_costs[equal]
            count[accepted] = 2
            hard_end[accepted] = code
            continuum[accepted] = np.count_nonzero(group[accepted], axis=1) > 1
            multiplier[accepted] = interval[accepted, code - 1]

        interior = np.flatnonzero(definite & (hard_end == 0))
        if interior.size:
            mu, den = _interior_root(
                nu[interior],
                beta[interior],
                pencil.offset[interior],
                mu_lo[interior],
                mu_hi[interior],
            )
            ratio = np.divide(beta[interior], den, out=np.zeros_like(den), where=den != 0.0)
            y = (ratio - kappa[interior])[:, None, :]
            point = y @ np.swapaxes(pencil.back[interior], -1, -2)
            points[interior, :1] = point
            costs[interior, :1] = _batch_costs(A[interior], b[interior], point)
            count[interior] = 1
            multiplier[interior] = pencil.lam0[interior] + mu
    return IndefiniteGtrsBatch(
        points=points,
        count=count,
        costs=costs,
        multiplier=multiplier,
        interval=interval,
        hard_end=hard_end,
        continuum=continuum,
        rank=rank,
        definite=definite,
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
    with np.errstate(all="ignore"):
        pencil = _diagonalise((A.T @ A)[None], (A.T @ b)[None], d, g, np.array([float(c)]))
    if not pencil.definite[0]:
        return np.zeros((0, dim)), np.zeros(0), np.zeros(0)
    nu, beta, kappa = pencil.nu[0], pencil.beta[0], pencil.kappa[0]
    offset = float(pencil.offset[0])
    factors = [np.polynomial.Polynomial([1.0, v]) ** 2 for v in nu]
    poly = -offset * np.prod(factors)
    for i in range(dim):
        others = np.prod([factors[j] for j in range(dim) if j != i])
        poly = poly + nu[i] * beta[i] ** 2 * others
    roots = poly.roots()
    scale = max(1.0, float(np.max(np.abs(roots)))) if len(roots) else 1.0
    real = np.sort(roots[np.abs(roots.imag) <= 1e-6 * scale].real)
    tolerance_scale = 1.0 + abs(offset) + float(np.sum(np.abs(nu) * beta**2))

    def secular(mu: float) -> tuple[float, float]:
        den = 1.0 + mu * nu
        if np.any(np.abs(den) < 1e-14):
            return np.inf, 0.0
        phi = float(np.sum(nu * beta**2 / den**2) - offset)
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
                found.append((mu, beta / (1.0 + mu * nu) - kappa))
    if not found:
        return np.zeros((0, dim)), np.zeros(0), np.zeros(0)
    points = np.array([y for _, y in found]) @ pencil.back[0].T
    costs = indefinite_cost(A, b, points)
    order = np.argsort(costs)
    multipliers = pencil.lam0[0] + np.array([mu for mu, _ in found])
    return points[order], costs[order], multipliers[order]


def _diagonalise(
    M: FloatArray, q: FloatArray, d: FloatArray, g: FloatArray, c: FloatArray
) -> _Pencil:
    """The pencil of each system at an interior ``λ₀`` (module text); ``definite`` is false
    where ``M + λD ≻ 0`` nowhere (the other fields are then placeholders)."""
    dim = q.shape[1]
    lam0, definite = _interior_multiplier(M, d)
    shifted = M + lam0[:, None, None] * np.diag(d)
    shifted[~definite] = np.eye(dim)
    L, factored = _cholesky(shifted)
    definite = definite & factored
    L_inv = np.linalg.inv(L)  # small and well conditioned: λ₀ is mid-interval
    K = (L_inv * d) @ np.swapaxes(L_inv, -1, -2)  # L⁻¹ D L⁻ᵀ
    nu, W = np.linalg.eigh(0.5 * (K + np.swapaxes(K, -1, -2)))
    definite = definite & (nu[:, 0] < 0.0) & (nu[:, -1] > 0.0)
    back = np.swapaxes(L_inv, -1, -2) @ W  # L⁻ᵀ W
    back_t = np.swapaxes(back, -1, -2)
    alpha = (back_t @ (q - lam0[:, None] * g)[..., None])[..., 0]  # Wᵀ L⁻¹ (q − λ₀ g)
    e = back_t @ g
    kappa = e / nu
    return _Pencil(
        definite=definite,
        lam0=lam0,
        back=back,
        nu=nu,
        beta=alpha + kappa,
        kappa=kappa,
        offset=np.sum(e * kappa, axis=1) + c,
    )


def _cholesky(matrices: FloatArray) -> tuple[FloatArray, BoolArray]:
    """Lower Cholesky factors of a stack, and which factored (the others: the identity)."""
    try:
        return np.linalg.cholesky(matrices), np.ones(len(matrices), dtype=bool)
    except np.linalg.LinAlgError:  # numpy refuses the whole stack: factor one at a time
        factors = np.broadcast_to(np.eye(matrices.shape[-1]), matrices.shape).copy()
        factored = np.zeros(len(matrices), dtype=bool)
        for i, matrix in enumerate(matrices):
            try:
                factors[i] = np.linalg.cholesky(matrix)
                factored[i] = True
            except np.linalg.LinAlgError:
                pass
        return factors, factored


def _interior_multiplier(M: FloatArray, d: FloatArray) -> tuple[FloatArray, BoolArray]:
    """A λ with ``M + λD ≻ 0`` per system: the midpoint of the roots of ``det(M + λD)``
    around I, and whether there is one.

    With ``T = |D|^(-1/2)`` and ``J = sign(D)``, ``M + λD = T⁻¹(TMT + λJ)T⁻¹``, so the roots are
    the eigenvalues of ``−J TMT``; ``n_pos`` of them lie below I and ``n_neg`` above.
    """
    t = 1.0 / np.sqrt(np.abs(d))
    J = np.sign(d)
    Mt = t[:, None] * M * t[None, :]
    roots = np.linalg.eigvals(-J[:, None] * Mt)
    scale = np.maximum(1.0, np.max(np.abs(roots), axis=1))
    n_pos = int(np.count_nonzero(d > 0))
    ordered = np.sort(roots.real, axis=1)
    low, high = ordered[:, n_pos - 1], ordered[:, n_pos]
    separated = np.all(np.abs(roots.imag) <= 1e-8 * scale[:, None], axis=1) & (high > low)
    lam0 = np.where(separated, 0.5 * (low + high), 0.0)
    for i in np.flatnonzero(~separated):  # too close to separate: λ = 0 serves if M ≻ 0
        _, factored = _cholesky(M[i : i + 1])
        separated[i] = factored[0]
    return lam0, separated


def _interior_root(
    nu: FloatArray, beta: FloatArray, offset: FloatArray, mu_lo: FloatArray, mu_hi: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The root of each decreasing φ in ``(μ_lo, μ_hi)`` and the denominators ``1 + μν`` there.

    φ(0) decides the half; the root is then sought as an offset ``gap`` from that half's end,
    whose pole term is evaluated as ``gap · ν`` exactly, by :func:`_decreasing_root`. A root on
    the pole itself (a vanishing β, but unequal hard-case costs) returns that end.
    """
    weight = nu * beta**2
    phi_mid = np.sum(weight, axis=1) - offset  # μ = 0: every denominator is 1
    upper = phi_mid > 0.0  # root in (0, μ_hi): offset from the upper end, φ increasing in it
    base = np.where(upper[:, None], (nu - nu[:, :1]) / -nu[:, :1], (nu[:, -1:] - nu) / nu[:, -1:])
    slope = np.where(upper[:, None], -nu, nu)
    span = np.where(upper, mu_hi, -mu_lo)
    sign = np.where(upper, -1.0, 1.0)

    def phi(gap: FloatArray, rows: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        """sign·φ and its derivative in ``gap``, for the systems ``rows``."""
        at = _every_or(rows, len(nu))
        row_slope = slope[at]
        den = base[at] + gap[:, None] * row_slope
        term = weight[at] / den**2
        row_sign = sign[at]
        value = row_sign * (np.sum(term, axis=1) - offset[at])
        derivative = row_sign * np.sum(-2.0 * term * row_slope / den, axis=1)
        return value, derivative

    middle = phi_mid == 0.0
    pole = np.zeros(len(nu), dtype=bool)
    # sign·φ < 0 at gap = span (the middle) and → +∞ at gap → 0 unless the pole term vanished
    low = 0.5 * span
    active = np.flatnonzero(~middle)
    tiny = np.finfo(float).tiny
    while active.size:
        active = active[phi(low[active], active)[0] <= 0.0]
        low[active] *= 0.5
        hit = low[active] < tiny * 1e6
        pole[active[hit]] = True
        active = active[~hit]
    high = span.copy()
    rows = np.flatnonzero(~middle & ~pole)
    at_middle = phi(high[rows], rows)[0] > 0.0  # rounding at the middle: the root is at μ = 0
    middle[rows[at_middle]] = True
    rows = rows[~at_middle]
    gap = np.zeros(len(nu))
    gap[rows] = _decreasing_root(lambda x, at: phi(x, rows[at]), low[rows], high[rows])
    mu = np.where(upper, mu_hi - gap, mu_lo + gap)
    den = base + gap[:, None] * slope
    mu[pole] = np.where(upper, mu_hi, mu_lo)[pole]
    den[pole] = base[pole]
    mu[middle] = 0.0
    den[middle] = 1.0
    return mu, den


def _decreasing_root(function, low: FloatArray, high: FloatArray) -> FloatArray:
    """The root in ``[low, high]`` (``0 < low``, value > 0 at ``low``, ≤ 0 at ``high``) of
    each of a set of strictly decreasing functions, to full precision.

    ``function(x, at)`` returns the values and derivatives at ``x`` of the functions ``at``
    (indices into the set). A safeguarded Newton iteration (Numerical Recipes' ``rtsafe``) on
    the model of a pole at 0, ``f ≈ a/x² + c`` matched to the value and slope at ``x`` (exact
    when only the pole term varies; a Newton step where the model has no root): the step when
    it stays inside the bracket and halves the step before last, else a bisection of the
    bracket (geometric while its ends are more than a factor 4 apart). It stops when a step is
    below ``4ε`` of the point, or the bracket below ``4ε`` of its end.
    """
    low, high = low.copy(), high.copy()
    x = high.copy()
    previous = np.full(len(low), np.inf)  # the last step taken
    active = np.arange(len(low))
    for _ in range(200):
        if active.size == 0:
            break
        at = _every_or(active, len(low))
        x_a = x[at].copy()
        value, derivative = function(x_a, active)
        positive = value > 0.0
        lo = np.where(positive, x_a, low[at])
        hi = np.where(positive, high[at], x_a)  # a zero value ends the search at x
        newton = value / derivative  # minus Newton's step
        # the model's root x·√r, r = f′x/(2f + f′x), as the step x(r − 1)/(√r + 1)
        slope_x = derivative * x_a
        denominator = 2.0 * value + slope_x
        ratio = slope_x / denominator
        modelled = (-2.0 * value / denominator) * x_a / (np.sqrt(np.abs(ratio)) + 1.0)
        step = np.where(ratio > 0.0, modelled, -newton)
        following = x_a + step
        accept = (following > lo) & (following < hi)
        finished = (np.abs(newton) <= 4.0 * _EPS * x_a) | (hi - lo <= 4.0 * _EPS * hi)
        accept &= np.abs(step) <= 0.5 * np.abs(previous[at])
        if not np.all(accept | finished):  # bisect the bracket where the step is refused
            bisect = np.where(hi > 4.0 * lo, np.sqrt(lo * hi), 0.5 * (lo + hi))
            following = np.where(accept | finished, following, bisect)
        if finished.any():  # converged: x, or its last step when that stays in the bracket
            kept = finished & ~((following > lo) & (following < hi))
            following = np.where(kept, x_a, following)
        previous[at] = following - x_a
        x[at] = following
        low[at], high[at] = lo, hi
        active = active[~finished]
    return x


def _every_or(index: NDArray[np.int64], n: int) -> NDArray[np.int64] | slice:
    """``index`` (sorted, distinct, in ``range(n)``), or the slice of all when it is all:
    a batch of one, or a batch whose systems all go on, is then not gathered."""
    return slice(None) if len(index) == n else index


def _batch_costs(A: FloatArray, b: FloatArray, points: FloatArray) -> FloatArray:
    """``‖Aθ − b‖²`` for ``points`` (n, k, dim) of the systems ``A`` (n, m, dim), ``b`` (n, m)."""
    residual = points @ np.swapaxes(A, -1, -2) - b[:, None, :]
    return np.sum(residual**2, axis=-1)


__all__ = [
    "HARD_ENDS",
    "STATUSES",
    "IndefiniteGtrsBatch",
    "IndefiniteGtrsSolution",
    "constraint_value",
    "indefinite_cost",
    "solve_gtrs_indefinite",
    "solve_gtrs_indefinite_batch",
    "stationary_points",
]
