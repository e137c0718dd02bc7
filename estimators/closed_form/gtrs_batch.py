r"""The GTRS of MATH §5 (paper eq ``finalest``, corrected), solved for many systems at once.

.. math::

    \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad r_x^2 + r_y^2 - r_z = 0,
    \qquad r = (x_s, y_s, x_s^2 + y_s^2)

a generalized trust-region subproblem. With ``M = AᵀA``, ``q = Aᵀb``, ``D = diag(1,1,0)`` and
``g = (0, 0, −½)`` the stationarity condition is ``(M + λD) r = q − λg`` (the paper drops the
transpose), and the global minimiser is the stationary point with ``M + λD ⪰ 0`` (Moré 1993;
Beck, Stoica & Li 2008). This is the one implementation: one system
(:func:`estimators.closed_form.gtrs.solve_gtrs`) is a batch of one.

Every per-system scalar is an array of shape ``(n,)`` and the rows of the stacked systems are
given as :class:`RowBlock` columns of shape ``(R, n)`` (row × system), so that every operation
is one numpy call over the whole batch.

- ``M`` and ``q`` are summed over the rows (:func:`~estimators.closed_form.gtrs_rank.row_dot`,
  whose order does not depend on the batch); eliminating ``r_z`` with the Schur complement
  ``S = M_xy − m mᵀ/M₃₃`` (``m = M[:2, 2]``), ``S = U diag(μ₁ ≤ μ₂) Uᵀ`` in closed form,
  ``a = q_xy − m q₃/M₃₃``, ``h = m/(2M₃₃)``, ``ã = Uᵀa``, ``h̃ = Uᵀh``, ``e = ã + μ h̃``:
  ``ỹ_i(λ) + h̃_i = e_i/(μ_i + λ)`` and
  ``φ(λ) = Σ e_i²/(μ_i + λ)² − ‖h̃‖² − (q₃ + λ/2)/M₃₃``, strictly decreasing on ``λ > −μ₁``.
- Hard case, the normal case here (MATH §5): when ``e₁ = 0`` (every single straight frame:
  ``A`` has rank 2) the pole at ``−μ₁`` disappears. If ``φ(−μ₁)`` without the ``e₁`` term is
  negative and ``|e₁| ≤ rtol·μ₂·√(−φ(−μ₁))``, ``λ* = −μ₁`` and the minimisers are
  ``ỹ₁ = −h̃₁ ± √(−φ(−μ₁))``: the emitter and its mirror image across the track, kept as a pair
  when their costs are equal to rounding (:func:`equal_to_rounding`).
- Otherwise the root of the secular equation ``φ(−μ₁ + s) = 0`` is found by Newton's method
  from a lower bound of the root. ``φ`` is convex and strictly decreasing in ``s > 0``, so
  every Newton iterate stays below the root and the iterates increase monotonically to it:
  no bracketing is needed, and only the systems that have not converged are iterated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from estimators.closed_form.gtrs_rank import RANK_RTOL, numerical_rank, row_dot

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

EPS = float(np.finfo(float).eps)
TINY = float(np.finfo(float).tiny)

NEWTON_ITERATIONS = 100

_PAIR_SIGNS = np.array([1.0, -1.0])
"""The hard case's two points, ``−h̃₁ ± √(−φ(−μ₁))``."""


@dataclass(frozen=True, slots=True)
class RowBlock:
    """Rows ``[ax, ay, az] r = b`` of many systems: arrays of shape (R, n) or (R, 1).

    ``az=None`` is a zero third column (the Doppler rows of MATH §3). ``ac`` is the column of
    a free linear unknown ``t`` (an unknown carrier offset, MATH §15), ``[ax, ay, az] r + ac t
    = b``, which the solver projects out: ``None`` when there is none.
    """

    ax: FloatArray
    ay: FloatArray
    az: FloatArray | None
    b: FloatArray
    ac: FloatArray | None = None

    @property
    def n_rows(self) -> int:
        return int(self.b.shape[0])

    def take(self, index: IntArray) -> RowBlock:
        """The systems ``index`` (columns of trial-wise arrays; broadcast columns kept)."""

        def pick(column: FloatArray | None) -> FloatArray | None:
            if column is None or column.shape[1] == 1:
                return column
            return np.ascontiguousarray(column[:, index])  # (fancy indexing gives F order)

        return RowBlock(pick(self.ax), pick(self.ay), pick(self.az), pick(self.b), pick(self.ac))

    def per_point(self) -> RowBlock:
        """The columns as (R, 1, n), to meet points of shape (p, n)."""

        def column(values: FloatArray | None) -> FloatArray | None:
            return None if values is None else values[:, None, :]

        return RowBlock(
            column(self.ax), column(self.ay), column(self.az), column(self.b), column(self.ac)
        )

    def residual(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """``A r − b`` at ``r = (x, y, x² + y²)`` for each system, shape (R, n) (or (R, n, p)
        for the columns of :meth:`per_point` and points (p, n))."""
        out = self.ax * x
        out += self.ay * y
        out -= self.b
        if self.az is not None:
            out += self.az * (x * x + y * y)
        return out


@dataclass(frozen=True, slots=True, eq=False)
class NormalEquations:
    """``M = AᵀA`` (its six entries), ``q = Aᵀb``, ``‖b‖²`` and the row count, per system.

    With a free unknown's column ``c`` in the rows (:attr:`RowBlock.ac`) these are of the rows
    projected off ``c`` (MATH §15): ``M − m_c m_cᵀ/‖c‖²``, ``q − m_c (cᵀb)/‖c‖²``,
    ``‖b‖² − (cᵀb)²/‖c‖²`` with ``m_c = Aᵀc``; ``nuisance`` keeps ``(m_c, cᵀb, ‖c‖²)`` (the
    sums ``c1, c2, c3, cb, cc``) for the unknown's value at a point, :meth:`nuisance_at`.
    """

    m11: FloatArray
    m12: FloatArray
    m13: FloatArray
    m22: FloatArray
    m23: FloatArray
    m33: FloatArray
    q1: FloatArray
    q2: FloatArray
    q3: FloatArray
    bb: FloatArray
    n_rows: int
    nuisance: dict[str, FloatArray] | None = None

    @classmethod
    def of(cls, blocks: list[RowBlock], n: int) -> NormalEquations:
        sums: dict[str, FloatArray] = {}
        for block in blocks:
            ax, ay, az, b, ac = block.ax, block.ay, block.az, block.b, block.ac
            pairs = [("m11", ax, ax), ("m12", ax, ay), ("m22", ay, ay)]
            pairs += [("q1", ax, b), ("q2", ay, b), ("bb", b, b)]
            if az is not None:
                pairs += [("m13", ax, az), ("m23", ay, az), ("m33", az, az), ("q3", az, b)]
            if ac is not None:
                pairs += [("c1", ax, ac), ("c2", ay, ac), ("cb", b, ac), ("cc", ac, ac)]
                if az is not None:
                    pairs.append(("c3", az, ac))
            for key, left, right in pairs:
                total = row_dot(left, right, n)
                sums[key] = total if key not in sums else sums[key] + total
        zero = np.zeros(n)
        keys = ("m11", "m12", "m13", "m22", "m23", "m33", "q1", "q2", "q3", "bb")
        values = {key: sums.get(key, zero) for key in keys}
        nuisance = None
        if "cc" in sums:
            nuisance = {key: sums.get(key, zero) for key in ("c1", "c2", "c3", "cb", "cc")}
            inv = 1.0 / nuisance["cc"]
            column = {"1": nuisance["c1"], "2": nuisance["c2"], "3": nuisance["c3"]}
            for i, j in (("1", "1"), ("1", "2"), ("1", "3"), ("2", "2"), ("2", "3"), ("3", "3")):
                values[f"m{i}{j}"] = values[f"m{i}{j}"] - column[i] * column[j] * inv
            for i in ("1", "2", "3"):
                values[f"q{i}"] = values[f"q{i}"] - column[i] * nuisance["cb"] * inv
            values["bb"] = values["bb"] - nuisance["cb"] * nuisance["cb"] * inv
        return cls(**values, n_rows=sum(block.n_rows for block in blocks), nuisance=nuisance)

    def nuisance_at(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """The free unknown's least-squares value ``cᵀ(b − A r)/‖c‖²`` at ``r = (x, y, x² +
        y²)`` (x, y of shape (n, k)); NaN where the point is."""
        c = self.nuisance
        if c is None:
            raise ValueError("the rows have no free unknown's column")
        z = x * x + y * y
        return (
            c["cb"][:, None] - c["c1"][:, None] * x - c["c2"][:, None] * y - c["c3"][:, None] * z
        ) / c["cc"][:, None]

    @property
    def trace(self) -> FloatArray:
        """``‖A‖_F²``."""
        return self.m11 + self.m22 + self.m33


def take_systems(blocks: list[RowBlock], index: IntArray, n: int) -> list[RowBlock]:
    """The systems ``index`` of ``blocks`` (``blocks`` itself when that is all ``n``)."""
    if index.size == n:
        return blocks
    return [block.take(index) for block in blocks]


@dataclass(frozen=True, slots=True, eq=False)
class GtrsBatch:
    """Global minimisers of MATH §5 for every system of a batch.

    Attributes
    ----------
    x, y : (n, 2)
        Minimisers in the rows' coordinates; the second column is NaN when ``count`` is 1.
    count : (n,)
        1, or 2 in the hard case (MATH §5).
    costs : (n, 2)
        ``‖A r − b‖²`` at each point (NaN for a missing second point).
    multiplier : (n,)
        λ*.
    hard_case : (n,)
    rank : (n,)
        Numerical rank of ``A`` (``-1`` when not asked for).
    failed : (n,)
        No finite minimiser: non-finite rows, no ToA row (``M₃₃ = 0``), or a secular equation
        whose iteration failed.
    nuisance : (n, 2) or None
        The free unknown's value at each point (:meth:`NormalEquations.nuisance_at`), when the
        rows have its column.
    """

    x: FloatArray
    y: FloatArray
    count: IntArray
    costs: FloatArray
    multiplier: FloatArray
    hard_case: BoolArray
    rank: IntArray
    failed: BoolArray
    nuisance: FloatArray | None = None

    def first(self) -> GtrsBatch:
        """The first system alone."""
        return GtrsBatch(
            **{
                name: None if getattr(self, name) is None else getattr(self, name)[:1]
                for name in self.__slots__
            }
        )


def eigen_2x2(
    s11: FloatArray, s12: FloatArray, s22: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Eigenvalues ``μ₁ ≤ μ₂``, their gap and the unit eigenvector ``(c, s)`` of ``μ₁``.

    The eigenvector of ``μ₂`` is ``(−s, c)``. The gap ``2√(d² + s12²)`` is computed directly,
    without cancellation.
    """
    mean = 0.5 * (s11 + s22)
    half_diff = 0.5 * (s11 - s22)
    radius = np.hypot(half_diff, s12)
    mu1 = mean - radius
    mu2 = mean + radius
    # (S − μ₁I) has rows (d + r, b) and (b, r − d); u₁ is orthogonal to the larger one
    big = half_diff >= 0.0
    ux = np.where(big, s12, radius - half_diff)
    uy = np.where(big, -(half_diff + radius), -s12)
    norm = np.hypot(ux, uy)
    isotropic = norm == 0.0
    if not isotropic.any():  # (the usual case: the same quotients, fewer calls)
        return mu1, mu2, 2.0 * radius, ux / norm, uy / norm
    c = np.where(isotropic, 1.0, ux / np.where(isotropic, 1.0, norm))
    s = np.where(isotropic, 0.0, uy / np.where(isotropic, 1.0, norm))
    return mu1, mu2, 2.0 * radius, c, s


@dataclass(frozen=True, slots=True, eq=False)
class Spectrum:
    """The Schur complement's eigen-decomposition and the secular equation's coefficients.

    ``S = M_xy − m mᵀ/M₃₃ = U diag(μ₁ ≤ μ₂) Uᵀ`` with ``u₁ = (c, s)``; ``ã = Uᵀa``,
    ``h̃ = Uᵀh``, ``e = ã + μ h̃``; ``φ(−μ₁ + s) = e₁²/s² + e₂²/(g+s)² − base − s/(2M₃₃)``.
    """

    mu1: FloatArray
    mu2: FloatArray
    gap: FloatArray
    c: FloatArray
    s: FloatArray
    a_t1: FloatArray
    a_t2: FloatArray
    h_t1: FloatArray
    h_t2: FloatArray
    e1: FloatArray
    e2: FloatArray
    h_sq: FloatArray
    base: FloatArray
    second_at_pole: FloatArray
    phi_pole: FloatArray
    m33: FloatArray

    @classmethod
    def of(cls, ne: NormalEquations) -> Spectrum:
        m13, m23, m33, q3 = ne.m13, ne.m23, ne.m33, ne.q3
        mu1, mu2, gap, c, s = eigen_2x2(
            ne.m11 - m13 * m13 / m33, ne.m12 - m13 * m23 / m33, ne.m22 - m23 * m23 / m33
        )
        a1 = ne.q1 - m13 * q3 / m33
        a2 = ne.q2 - m23 * q3 / m33
        h1 = m13 / (2.0 * m33)
        h2 = m23 / (2.0 * m33)
        a_t1, a_t2 = c * a1 + s * a2, -s * a1 + c * a2
        h_t1, h_t2 = c * h1 + s * h2, -s * h1 + c * h2
        e2 = a_t2 + mu2 * h_t2
        h_sq = h_t1 * h_t1 + h_t2 * h_t2
        base = h_sq + (q3 - 0.5 * mu1) / m33
        positive = gap > 0.0
        if positive.all():
            second_at_pole = e2 * e2 / gap**2
        else:
            second_at_pole = np.where(
                positive,
                e2 * e2 / np.where(positive, gap, 1.0) ** 2,
                np.where(e2 == 0, 0.0, np.inf),
            )
        return cls(
            mu1=mu1,
            mu2=mu2,
            gap=gap,
            c=c,
            s=s,
            a_t1=a_t1,
            a_t2=a_t2,
            h_t1=h_t1,
            h_t2=h_t2,
            e1=a_t1 + mu1 * h_t1,
            e2=e2,
            h_sq=h_sq,
            base=base,
            second_at_pole=second_at_pole,
            phi_pole=second_at_pole - base,
            m33=m33,
        )

    def take(self, index: IntArray) -> Spectrum:
        if index.size == self.mu1.size:
            return self
        return Spectrum(**{name: getattr(self, name)[index] for name in self.__slots__})

    def to_rows(self, y1: FloatArray, y2: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Eigenbasis coordinates back to the rows' ``(x, y)``: ``U ỹ`` (of (n,) or (p, n)
        points)."""
        return self.c * y1 - self.s * y2, self.s * y1 + self.c * y2


def solve_gtrs_batch(
    blocks: list[RowBlock],
    n: int,
    *,
    hard_case_rtol: float = 1e-10,
    rank: bool = False,
    rank_deficient: bool = False,
) -> GtrsBatch:
    """Every global minimiser of ``‖A r − b‖²`` s.t. ``r_x² + r_y² = r_z`` for ``n`` systems.

    The systems are the columns of ``blocks`` (see the module docstring for the method).
    ``hard_case_rtol``: the hard case is considered when the root of φ would lie within
    ``hard_case_rtol · μ₂`` of the pole ``−μ₁``, and declared only if the two points of the
    null line then have costs equal to rounding (:func:`equal_to_rounding`; they differ by
    ``4|e₁|√(−φ(−μ₁))``); otherwise the unique root is returned. ``rank=True`` also computes
    the numerical rank of each ``A`` (:func:`~estimators.closed_form.gtrs_rank.numerical_rank`);
    ``rank_deficient=True`` states that every ``A`` has a null vector up to rounding (one
    straight track). A system without a finite minimiser (non-finite rows, no ToA row, a
    secular equation whose Newton iteration fails) is flagged in ``failed``.
    """
    with np.errstate(all="ignore"):
        return _solve(blocks, n, hard_case_rtol, "deficient" if rank and rank_deficient else rank)


def _solve(blocks: list[RowBlock], n: int, rtol: float, want_rank: bool | str) -> GtrsBatch:
    ne = NormalEquations.of(blocks, n)
    sp = Spectrum.of(ne)
    trace = ne.trace
    finite = np.isfinite(trace) & np.isfinite(ne.q1 + ne.q2 + ne.q3 + ne.bb) & (ne.m33 > 0.0)
    failed = ~finite
    mu_scale = np.maximum(np.abs(sp.mu2), TINY)
    gap_safe = sp.gap if (sp.gap > 0.0).all() else np.where(sp.gap > 0.0, sp.gap, 1.0)

    # hard-case screen (MATH §5): φ(−μ₁) < 0 and |e₁| ≤ rtol·μ₂·√(−φ(−μ₁))
    negative = sp.phi_pole < 0.0
    width = np.sqrt(np.where(negative, -sp.phi_pole, 0.0))
    screen = negative & (np.abs(sp.e1) <= rtol * mu_scale * width) & finite

    x = np.full((n, 2), np.nan)
    y = np.full((n, 2), np.nan)
    costs = np.full((n, 2), np.nan)
    multiplier = np.full(n, np.nan)
    hard = np.zeros(n, dtype=bool)

    # --- hard case: the two points of the null line on the paraboloid
    idx = np.flatnonzero(screen)
    if idx.size:
        every = idx.size == n  # (one trial's usual case: nothing to pick)

        def pick(values: FloatArray) -> FloatArray:
            return values if every else values[idx]

        sub = sp.take(idx)
        y2 = sub.e2 / pick(gap_safe) - sub.h_t2
        w = pick(width)
        # (2, m): the pair point-major, so that numpy's loops run over the systems
        px, py = sub.to_rows(-sub.h_t1 + _PAIR_SIGNS[:, None] * w, y2)
        rows = take_systems(blocks, idx, n)
        pair_costs = _cost(rows, px, py).T
        px, py = px.T, py.T
        square = px * px + py * py
        norms = np.maximum.reduce(np.sqrt(square + square * square), axis=1)
        # a small but real e₁ (two headings a few millidegrees apart) passes the screen, yet
        # the pair's costs then differ by 4|e₁|√(−φ(−μ₁)): the pair only when they are equal
        equal = equal_to_rounding(
            pair_costs, norms, np.sqrt(pick(trace)), np.sqrt(pick(ne.bb)), ne.n_rows
        )
        if every and equal.all():
            hard[:] = True
            x[:], y[:], costs[:] = px, py, pair_costs
            multiplier[:] = -sp.mu1
        else:
            keep = idx[equal]
            hard[keep] = True
            x[keep], y[keep], costs[keep] = px[equal], py[equal], pair_costs[equal]
            multiplier[keep] = -sp.mu1[keep]

    # --- the unique root of the secular equation
    idx = np.flatnonzero(finite & ~hard)
    if idx.size:
        sub = sp.take(idx)
        shift, diverged = _secular_root(sub, sp.phi_pole[idx])
        ratio1 = np.where(shift > 0.0, sub.e1 / np.where(shift > 0.0, shift, 1.0), 0.0)
        den2 = sub.gap + shift
        ratio2 = np.where(den2 > 0.0, sub.e2 / np.where(den2 > 0.0, den2, 1.0), 0.0)
        px, py = sub.to_rows(ratio1 - sub.h_t1, ratio2 - sub.h_t2)
        x[idx, 0], y[idx, 0] = px, py
        costs[idx, 0] = _cost(take_systems(blocks, idx, n), px, py)
        multiplier[idx] = shift - sub.mu1
        failed[idx] |= diverged
    nuisance = None if ne.nuisance is None else ne.nuisance_at(x, y)

    ranks = np.full(n, -1, dtype=np.int64)
    if want_rank:
        ranks = numerical_rank(
            blocks, ne, sp.mu1, sp.mu2, _svd_rank, take_systems, deficient=want_rank == "deficient"
        )
    failed |= ~np.isfinite(x[:, 0]) | ~np.isfinite(y[:, 0]) | ~np.isfinite(costs[:, 0])
    return GtrsBatch(
        x=x,
        y=y,
        count=np.where(hard, 2, 1).astype(np.int64),
        costs=costs,
        multiplier=multiplier,
        hard_case=hard,
        rank=ranks,
        failed=failed,
        nuisance=nuisance,
    )


def _cost(blocks: list[RowBlock], x: FloatArray, y: FloatArray) -> FloatArray:
    """``‖A r − b‖²`` at ``r = (x, y, x² + y²)``, summed row by row (:func:`row_dot`); with a
    free unknown's column ``c``, at its best value ``t = cᵀ(b − A r)/‖c‖²``: the residual
    ``A r + c t − b`` is formed before it is squared (subtracting ``(cᵀ(A r − b))²/‖c‖²`` from
    the unprojected cost would lose the digits of a small cost to a large one)."""
    if x.ndim == 2:  # p points per system, (p, n): the rows' columns as (R, 1, n)
        blocks = [block.per_point() for block in blocks]
    residuals = [block.residual(x, y) for block in blocks]
    if any(block.ac is not None for block in blocks):
        along = np.zeros(x.shape)
        norm = np.zeros(x.shape)
        for block, residual in zip(blocks, residuals, strict=True):
            if block.ac is not None:
                along += row_dot(block.ac, residual, x.shape)
                norm += row_dot(block.ac, block.ac, x.shape)
        step = along / norm
        residuals = [
            residual if block.ac is None else residual - block.ac * step
            for block, residual in zip(blocks, residuals, strict=True)
        ]
    total = np.zeros(x.shape)
    for residual in residuals:
        total += row_dot(residual, residual, x.shape)
    return total


def equal_to_rounding(
    costs: FloatArray,
    point_norms: FloatArray,
    a_norm: FloatArray,
    b_norm: FloatArray,
    n_rows: int,
) -> BoolArray:
    """Whether each pair's two hard-case costs are equal to the rounding of their evaluation
    (MATH §5).

    The residual ``A r − b`` is computed with an error up to ``δ = ε √m (‖A‖_F ‖r‖ + ‖b‖)``,
    so a cost ``C`` is known to about ``2 √C δ + δ²``; the pair is equal when its costs differ
    by at most 16 times that plus a relative ``1e-12``. On exactly straight frames the gap stays
    below that rounding term.
    """
    delta = EPS * np.sqrt(n_rows) * (a_norm * point_norms + b_norm)
    best = np.min(costs, axis=1)
    tolerance = 1e-12 * best + 16.0 * (2.0 * np.sqrt(best) * delta + delta**2)
    return np.max(costs, axis=1) - best <= tolerance


def _secular_root(sp: Spectrum, phi_pole: FloatArray) -> tuple[FloatArray, BoolArray]:
    """The root ``s > 0`` of ``φ(−μ₁ + s)``, by Newton's method from a lower bound.

    ``φ(s) = e₁²/s² + R(s)`` with ``R`` convex and decreasing. Two lower bounds of the root:
    the zero of ``R``'s tangent at 0 (when ``R(0) > 0``), and the point where ``e₁²/s²``
    still outweighs ``−R(0) − R'(0)s`` (when ``e₁ ≠ 0``). From their maximum every Newton
    step stays left of the root. Returns the root, 0 when ``φ(0⁺) ≤ 0`` (``e₁ = 0`` and φ
    touches zero on the pole) or when it is below ``1e-250``, and whether the iteration failed.
    """
    e1_sq, e2_sq, gap, base = sp.e1 * sp.e1, sp.e2 * sp.e2, sp.gap, sp.base
    slope_linear = 0.5 / sp.m33
    positive = gap > 0.0
    gap_safe = np.where(positive, gap, 1.0)
    steep = np.where(positive, 2.0 * e2_sq / gap_safe**3, np.where(e2_sq == 0, 0.0, np.inf))
    steep = steep + slope_linear
    tangent_root = np.where(phi_pole > 0.0, phi_pole / steep, 0.0)
    tangent_root = np.where(np.isfinite(tangent_root), tangent_root, 0.0)
    bound_pole = np.abs(sp.e1) / np.sqrt(2.0 * np.maximum(-phi_pole, 0.0))
    bound_slope = np.cbrt(e1_sq / (2.0 * steep))
    pole_bound = 0.9 * np.minimum(bound_pole, bound_slope)
    pole_bound = np.where((sp.e1 != 0.0) & np.isfinite(pole_bound), pole_bound, 0.0)
    shift = np.maximum(tangent_root, pole_bound)

    failed = np.zeros(shift.shape, dtype=bool)
    active = np.flatnonzero(shift > 0.0)  # else e₁ = 0 and R(0) ≤ 0: the root is on the pole
    for _ in range(NEWTON_ITERATIONS):
        if active.size == 0:
            break
        s = shift[active]
        inv = 1.0 / s
        first = e1_sq[active] * inv * inv
        den = gap[active] + s
        second = e2_sq[active] / (den * den)
        value = first + second - base[active] - s * slope_linear[active]
        derivative = 2.0 * first * inv + 2.0 * second / den + slope_linear[active]
        step = value / derivative
        done = (value <= 0.0) | (step <= 2.0 * EPS * s) | ~np.isfinite(step)
        shift[active] = np.where(done, s, s + step)
        failed[active[~np.isfinite(step) & (value > 0.0)]] = True
        active = active[~done]
    failed[active] = True
    return np.where(failed | (shift < 1e-250), 0.0, shift), failed


def _svd_rank(blocks: list[RowBlock], n: int) -> IntArray:
    """The numerical rank from the singular values of the stacked rows (n, R, 3)."""
    columns = []
    for block in blocks:
        shape = (block.n_rows, n)
        az = np.zeros(shape) if block.az is None else np.broadcast_to(block.az, shape)
        columns.append(
            np.stack([np.broadcast_to(block.ax, shape), np.broadcast_to(block.ay, shape), az], -1)
        )
    A = np.concatenate(columns, axis=0).transpose(1, 0, 2)
    if any(block.ac is not None for block in blocks):  # the rows projected off c (MATH §15)
        c = np.concatenate(
            [
                np.zeros((block.n_rows, n))
                if block.ac is None
                else np.broadcast_to(block.ac, (block.n_rows, n))
                for block in blocks
            ]
        ).T[:, :, None]
        A = A - c * (np.sum(c * A, axis=1, keepdims=True) / np.sum(c * c, axis=1, keepdims=True))
    singular = np.linalg.svd(A, compute_uv=False)
    finite = np.all(np.isfinite(singular), axis=1)
    rank = np.sum(singular > singular[:, :1] * RANK_RTOL, axis=1)
    return np.where(finite, rank, 0).astype(np.int64)
