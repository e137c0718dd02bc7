r"""The GTRS of MATH §5 solved for many independent systems at once (one per Monte Carlo trial).

The same mathematics as :func:`estimators.closed_form.gtrs.solve_gtrs`, written over arrays: every
per-trial scalar is an array of shape ``(n,)`` and the rows of the stacked systems are given
as :class:`RowBlock` columns of shape ``(R, n)`` (row × trial), so that every operation is
one numpy call over the whole batch.

- ``M = AᵀA`` and ``q = Aᵀb`` are summed over the rows; the Schur complement
  ``S = M_xy − m mᵀ/M₃₃`` and its 2×2 eigen-decomposition are closed forms.
- The hard case (MATH §5) is screened and confirmed as in
:func:`~estimators.closed_form.gtrs.solve_gtrs`:
  ``φ(−μ₁) < 0`` without the ``e₁`` term, ``|e₁| ≤ rtol·μ₂·√(−φ(−μ₁))``, and the two points'
  costs equal to rounding (:func:`equal_to_rounding`, the one rule both solvers use).
- Otherwise the root of the secular equation ``φ(−μ₁ + s) = 0`` is found by Newton's method
  from a lower bound of the root. ``φ`` is convex and strictly decreasing in ``s > 0``, so
  every Newton iterate stays below the root and the iterates increase monotonically to it:
  no bracketing is needed, and only the trials that have not converged are iterated.

Rounding makes a few of these choices undecidable from the batch's own arithmetic: a
threshold met to within the rounding of the quantities compared (the hard-case screen, the
equal-cost test, the numerical rank), or a point whose coordinates the rounding of ``φ``
moves by more than :data:`POSITION_RTOL`. The one-trial solver decides those cases by its own
rounding, which no other sequence of operations reproduces, so such trials are flagged in
``uncertain`` and the caller solves them one at a time. Elsewhere the answers agree with the
one-trial solver's to about ``1e-12`` of the frame's scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from estimators.closed_form.gtrs_rounding import (
    RANK_RTOL,
    Magnitudes,
    RoundingBounds,
    numerical_rank,
    root_point_error,
    row_dot,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

EPS = float(np.finfo(float).eps)
TINY = float(np.finfo(float).tiny)

POSITION_RTOL = 1e-10
"""Largest rounding error of a point, relative to the local frame's unit length, that the
batch accepts; a trial whose error bound is larger is ``uncertain``."""

DECISION_MARGIN = 8.0
"""A quantity must clear its threshold by this factor (or by this many rounding errors) for
the batch to take the same branch as the one-trial solver without solving it again."""

NEWTON_ITERATIONS = 100


@dataclass(frozen=True, slots=True)
class RowBlock:
    """Rows ``[ax, ay, az] r = b`` of many systems: arrays of shape (R, n) or (R, 1).

    ``az=None`` is a zero third column (the Doppler rows of MATH §3).
    """

    ax: FloatArray
    ay: FloatArray
    az: FloatArray | None
    b: FloatArray

    @property
    def n_rows(self) -> int:
        return int(self.b.shape[0])

    def take(self, index: IntArray) -> RowBlock:
        """The systems ``index`` (columns of trial-wise arrays; broadcast columns kept)."""

        def pick(column: FloatArray | None) -> FloatArray | None:
            if column is None or column.shape[1] == 1:
                return column
            return np.ascontiguousarray(column[:, index])  # (fancy indexing gives F order)

        return RowBlock(pick(self.ax), pick(self.ay), pick(self.az), pick(self.b))

    def residual(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """``A r − b`` at ``r = (x, y, x² + y²)`` for each system, shape (R, n)."""
        out = self.ax * x
        out += self.ay * y
        out -= self.b
        if self.az is not None:
            out += self.az * (x * x + y * y)
        return out


@dataclass(frozen=True, slots=True, eq=False)
class NormalEquations:
    """``M = AᵀA`` (its six entries), ``q = Aᵀb``, ``‖b‖²`` and the row count, per system."""

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

    @classmethod
    def of(cls, blocks: list[RowBlock], n: int) -> NormalEquations:
        sums: dict[str, FloatArray] = {}

        def add(key: str, left: FloatArray, right: FloatArray) -> None:
            total = row_dot(left, right, n)
            sums[key] = total if key not in sums else sums[key] + total

        for block in blocks:
            ax, ay, az, b = block.ax, block.ay, block.az, block.b
            for key, left, right in (
                ("m11", ax, ax),
                ("m12", ax, ay),
                ("m22", ay, ay),
                ("q1", ax, b),
                ("q2", ay, b),
                ("bb", b, b),
            ):
                add(key, left, right)
            if az is not None:
                for key, left, right in (
                    ("m13", ax, az),
                    ("m23", ay, az),
                    ("m33", az, az),
                    ("q3", az, b),
                ):
                    add(key, left, right)
        zero = np.zeros(n)
        keys = ("m11", "m12", "m13", "m22", "m23", "m33", "q1", "q2", "q3", "bb")
        return cls(
            **{key: sums.get(key, zero) for key in keys},
            n_rows=sum(block.n_rows for block in blocks),
        )

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
    uncertain : (n,)
        A choice within rounding of its threshold, or a point whose rounding error may exceed
        :data:`POSITION_RTOL`: solve these systems one at a time.
    """

    x: FloatArray
    y: FloatArray
    count: IntArray
    costs: FloatArray
    multiplier: FloatArray
    hard_case: BoolArray
    rank: IntArray
    uncertain: BoolArray

    def first(self) -> GtrsBatch:
        """The first system alone."""
        return GtrsBatch(**{name: getattr(self, name)[:1] for name in self.__slots__})

    def replace_trials(self, index: IntArray, other: GtrsBatch) -> None:
        """Overwrite trials ``index`` with ``other``'s (in place; the arrays are owned)."""
        for name in ("x", "y", "count", "costs", "multiplier", "hard_case", "rank", "uncertain"):
            getattr(self, name)[index] = getattr(other, name)


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
        second_at_pole = np.where(
            positive, e2 * e2 / np.where(positive, gap, 1.0) ** 2, np.where(e2 == 0, 0.0, np.inf)
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
        """Eigenbasis coordinates back to the rows' ``(x, y)``: ``U ỹ``."""
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

    The systems are the columns of ``blocks``; see :func:`estimators.closed_form.gtrs.solve_gtrs`
    for the method and ``hard_case_rtol``. ``rank=True`` also computes the numerical rank of each
    ``A`` (:func:`~estimators.closed_form.gtrs_rounding.numerical_rank`). The rounding bounds behind
    ``uncertain`` are first the free Cauchy-Schwarz ones; the systems they leave in doubt are
    solved again with the sums of magnitudes
    (:class:`~estimators.closed_form.gtrs_rounding.Magnitudes`).
    """
    with np.errstate(all="ignore"):
        want_rank = "deficient" if rank and rank_deficient else rank
        solution = _solve(blocks, n, hard_case_rtol, want_rank, tight=False)
        doubt = np.flatnonzero(solution.uncertain & np.isfinite(solution.multiplier))
        if doubt.size:
            sub = take_systems(blocks, doubt, n)
            again = _solve(sub, doubt.size, hard_case_rtol, want_rank, tight=True)
            solution.replace_trials(doubt, again)
        return solution


def _solve(
    blocks: list[RowBlock], n: int, rtol: float, want_rank: bool | str, tight: bool
) -> GtrsBatch:
    ne = NormalEquations.of(blocks, n)
    sp = Spectrum.of(ne)
    mag = Magnitudes.of(blocks, n) if tight else Magnitudes.bound(ne)
    err = RoundingBounds.of(ne, mag, sp)
    finite = np.isfinite(ne.trace) & np.isfinite(ne.q1 + ne.q2 + ne.q3 + ne.bb) & (ne.m33 > 0.0)
    uncertain = ~finite
    mu_scale = np.maximum(np.abs(sp.mu2), TINY)
    gap_safe = np.where(sp.gap > 0.0, sp.gap, 1.0)

    # hard-case screen (MATH §5): φ(−μ₁) < 0 and |e₁| ≤ rtol·μ₂·√(−φ(−μ₁)). It needs
    # |e₂| < gap·√base and |e₁| ≤ rtol·μ₂·√base, so ‖e‖ = ‖a + S h‖, which no choice of basis
    # changes, rules it out beyond that (an isotropic S, say, whose eigenbasis is arbitrary)
    negative = sp.phi_pole < 0.0
    width = np.sqrt(np.where(negative, -sp.phi_pole, 0.0))
    # the hard-case points have |ỹ₁ + h̃₁| = width and |ỹ₂ + h̃₂| = |e₂|/gap, both ≤ √base
    reach_y = np.sqrt(np.maximum(sp.base, 0.0))
    pole_y1 = np.abs(sp.h_t1) + width
    pole_y2 = np.abs(sp.h_t2) + np.minimum(np.abs(sp.e2) / gap_safe, reach_y)
    err_e1, err_e2 = err.rotated(sp, *err.e(sp, pole_y1, pole_y2))
    root_e2 = np.sqrt(sp.second_at_pole)
    err_gap = err.s11 + err.s22
    err_phi_pole = (
        err.base
        + 2.0 * root_e2 * (err_e2 + root_e2 * err_gap) / gap_safe
        + 4.0 * EPS * sp.second_at_pole
    )
    err_width = err_phi_pole / (2.0 * np.maximum(width, TINY))
    threshold = rtol * mu_scale * width
    err_threshold = rtol * (mu_scale * err_width + err.s22 * width)
    screen = negative & (np.abs(sp.e1) <= threshold) & finite
    margin = DECISION_MARGIN
    reach_e = np.sqrt(np.maximum(sp.base + margin * err.base, 0.0)) * (
        sp.gap + margin * err_gap + rtol * (mu_scale + margin * err.s22)
    )
    point_e1, point_e2 = err.e(sp, pole_y1, pole_y2)
    possibly_hard = finite & (np.hypot(sp.e1, sp.e2) - margin * (point_e1 + point_e2) <= reach_e)
    uncertain |= possibly_hard & ~(sp.gap > 0.0)
    uncertain |= possibly_hard & (np.abs(sp.phi_pole) <= margin * err_phi_pole)
    uncertain |= (
        possibly_hard
        & negative
        & (np.abs(np.abs(sp.e1) - threshold) <= margin * (err_e1 + err_threshold))
    )

    x = np.full((n, 2), np.nan)
    y = np.full((n, 2), np.nan)
    costs = np.full((n, 2), np.nan)
    multiplier = np.full(n, np.nan)
    hard = np.zeros(n, dtype=bool)

    # --- hard case: the two points of the null line on the paraboloid
    idx = np.flatnonzero(screen)
    if idx.size:
        sub = sp.take(idx)
        g = gap_safe[idx]
        y2 = sub.e2 / g - sub.h_t2
        w = width[idx]
        px = np.empty((idx.size, 2))
        py = np.empty((idx.size, 2))
        for j, sign in enumerate((1.0, -1.0)):
            px[:, j], py[:, j] = sub.to_rows(-sub.h_t1 + sign * w, y2)
        rows = take_systems(blocks, idx, n)
        pair_costs = np.column_stack([_cost(rows, px[:, j], py[:, j]) for j in range(2)])
        norms = np.sqrt(px**2 + py**2 + (px**2 + py**2) ** 2).max(axis=1)
        equal, doubt = equal_to_rounding(
            pair_costs, norms, np.sqrt(ne.trace[idx]), np.sqrt(ne.bb[idx]), ne.n_rows
        )
        error = (
            err_width[idx]
            + point_e2[idx] / g
            + np.abs(sub.e2) * err_gap[idx] / g**2
            + err.h1[idx]
            + err.h2[idx]
            + err.turn[idx] * (w + np.abs(y2) + np.abs(sub.h_t1))
        )
        reach = 1.0 + np.sqrt(np.max(px**2 + py**2, axis=1))
        uncertain[idx] |= doubt | (error > POSITION_RTOL * reach)
        keep = idx[equal]
        hard[keep] = True
        x[keep], y[keep], costs[keep] = px[equal], py[equal], pair_costs[equal]
        multiplier[keep] = -sp.mu1[keep]

    # --- the unique root of the secular equation
    idx = np.flatnonzero(finite & ~hard)
    if idx.size:
        sub = sp.take(idx)
        shift, failed = _secular_root(sub, sp.phi_pole[idx])
        ratio1 = np.where(shift > 0.0, sub.e1 / np.where(shift > 0.0, shift, 1.0), 0.0)
        den2 = sub.gap + shift
        ratio2 = np.where(den2 > 0.0, sub.e2 / np.where(den2 > 0.0, den2, 1.0), 0.0)
        y1, y2 = ratio1 - sub.h_t1, ratio2 - sub.h_t2
        px, py = sub.to_rows(y1, y2)
        x[idx, 0], y[idx, 0] = px, py
        costs[idx, 0] = _cost(take_systems(blocks, idx, n), px, py)
        multiplier[idx] = shift - sub.mu1
        sub_err = err.take(idx)
        e1_err, e2_err = sub_err.e(sub, y1, y2)
        base_err = sub_err.base + 4.0 * EPS * (
            ratio1**2 + ratio2**2 + np.abs(sub.base) + shift / sub.m33
        )
        move1, move2 = root_point_error(
            ratio1, ratio2, shift, den2, 0.5 / sub.m33, e1_err, e2_err, base_err
        )
        error = move1 + move2 + sub_err.h1 + sub_err.h2
        # near the pole the first coordinate is ±√(−φ) with the sign of e₁: where e₁ is
        # rounding, the side (a move of 2|e₁/s|) is the rounding's choice
        reach = POSITION_RTOL * (1.0 + np.hypot(px, py))
        sign_in_doubt = (np.abs(sub.e1) <= margin * e1_err) & (2.0 * np.abs(ratio1) > reach)
        uncertain[idx] |= failed | sign_in_doubt | (error > reach)

    ranks = np.full(n, -1, dtype=np.int64)
    if want_rank:
        ranks = numerical_rank(
            blocks,
            ne,
            sp.mu1,
            sp.mu2,
            err_gap,
            _svd_rank,
            take_systems,
            deficient=want_rank == "deficient",
        )
    uncertain |= ~np.isfinite(x[:, 0]) | ~np.isfinite(y[:, 0])
    return GtrsBatch(
        x=x,
        y=y,
        count=np.where(hard, 2, 1).astype(np.int64),
        costs=costs,
        multiplier=multiplier,
        hard_case=hard,
        rank=ranks,
        uncertain=uncertain,
    )


def _cost(blocks: list[RowBlock], x: FloatArray, y: FloatArray) -> FloatArray:
    """``‖A r − b‖²`` at ``r = (x, y, x² + y²)``, summed row by row as the one-trial solver."""
    total = np.zeros(x.shape)
    for block in blocks:
        residual = block.residual(x, y)
        total += row_dot(residual, residual, x.size)
    return total


def equal_to_rounding(
    costs: FloatArray,
    point_norms: FloatArray,
    a_norm: FloatArray,
    b_norm: FloatArray,
    n_rows: int,
) -> tuple[BoolArray, BoolArray]:
    """Whether each pair's two hard-case costs are equal to the rounding of their evaluation,
    and whether that answer is in doubt (MATH §5; ``gtrs.solve_gtrs`` uses the same rule).

    The residual ``A r − b`` is computed with an error up to ``δ = ε √m (‖A‖_F ‖r‖ + ‖b‖)``,
    so a cost ``C`` is known to about ``2 √C δ + δ²``; the pair is equal when its costs differ
    by at most 16 times that plus a relative ``1e-12``. On exactly straight frames the gap stays
    below that rounding term. The gap ``max − min`` is itself rounding (or a real difference);
    the answer is in doubt when the gap is within a factor :data:`DECISION_MARGIN` of the
    tolerance, where another order of the same operations may decide either way.
    """
    delta = EPS * np.sqrt(n_rows) * (a_norm * point_norms + b_norm)
    best = np.min(costs, axis=1)
    tolerance = 1e-12 * best + 16.0 * (2.0 * np.sqrt(best) * delta + delta**2)
    spread = np.max(costs, axis=1) - best
    equal = spread <= tolerance
    doubt = (spread > tolerance / DECISION_MARGIN) & (spread < tolerance * DECISION_MARGIN)
    return equal, doubt | ~np.isfinite(spread)


def _secular_root(sp: Spectrum, phi_pole: FloatArray) -> tuple[FloatArray, BoolArray]:
    """The root ``s > 0`` of ``φ(−μ₁ + s)``, by Newton's method from a lower bound.

    ``φ(s) = e₁²/s² + R(s)`` with ``R`` convex and decreasing. Two lower bounds of the root:
    the zero of ``R``'s tangent at 0 (when ``R(0) > 0``), and the point where ``e₁²/s²``
    still outweighs ``−R(0) − R'(0)s`` (when ``e₁ ≠ 0``). From their maximum every Newton
    step stays left of the root. Returns the root and whether it was not found (or is 0, the
    one-trial solver's answer when ``φ(0⁺) ≤ 0``: those trials are left to it).
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

    failed = shift <= 0.0  # e₁ = 0 and R(0) ≤ 0: the root sits on the pole
    active = np.flatnonzero(~failed)
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
    # the one-trial solver returns 0 for a root below ~1e-305
    failed |= shift < 1e-250
    return np.where(failed, 0.0, shift), failed


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
    singular = np.linalg.svd(A, compute_uv=False)
    finite = np.all(np.isfinite(singular), axis=1)
    rank = np.sum(singular > singular[:, :1] * RANK_RTOL, axis=1)
    return np.where(finite, rank, 0).astype(np.int64)
