r"""Rounding bounds for the batch GTRS (:mod:`estimators.closed_form.gtrs_batch`): how far rounding
may move the quantities its choices and its points depend on.

Two solvers that evaluate the same formulas in a different order (the batch's closed forms and
the one-trial solver's BLAS and LAPACK) agree to rounding; they take the same branch wherever a
quantity clears its threshold by more than both their rounding errors, and they return points
that agree to the propagated rounding. These bounds decide which trials the batch may answer
and which it must leave to the one-trial solver.

A sum of ``R`` products carries an error of about ``√R·ε`` times the sum of the products'
magnitudes (:class:`Magnitudes`). From ``M`` and ``q`` the errors propagate, component by
component in the eigenbasis of the Schur complement ``S``:

- ``a = q_xy − m q₃/M₃₃`` and ``h = m/(2M₃₃)`` by first-order propagation;
- ``S`` by ``Δ`` (entrywise), which in the eigenbasis is bounded by ``|U|ᵀΔ|U|`` (``E``);
- ``e = ã + μ h̃``: a perturbation ``δS`` of ``S`` acts on the solution of
  ``(S + λI)(y + h) = a + S h`` as ``δe = −δS̃ ỹ``, so ``|δe_i| ≤ δã_i + |μ_i| δh̃_i + Σ_j E_ij
  |ỹ_j|``. A rotation of the eigenbasis (by about ``E₁₂/gap``) changes the components of ``e`` but
  no point computed in one consistent basis: it counts only where a component of ``e`` is compared
  with a threshold (the hard-case screen).

The bounds are meant as upper bounds: measured against the one-trial solver over the test
families they were 1.5 to 10⁴ times larger than the differences seen, and every decision must
clear its threshold by a further factor ``DECISION_MARGIN``
(:mod:`estimators.closed_form.gtrs_batch`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

EPS = float(np.finfo(float).eps)
TINY = float(np.finfo(float).tiny)

RANK_RTOL = 1e-10
"""Singular values above ``RANK_RTOL`` times the largest count (``gtrs.solve_gtrs``)."""


def row_dot(left: FloatArray, right: FloatArray, n: int) -> FloatArray:
    """``Σ_rows left·right`` for each of ``n`` systems, (R, n) arrays or (R, 1) columns.

    Always the sequential sum over the rows, system by system, ``s = 0; s += l_i r_i``:
    numpy's own sums change their order with the shape (a single column is summed pairwise),
    and a system's result must not depend on its batch, to the bit. A reduction over the
    outer axis of a row-major ``(R, n ≥ 2)`` array adds row after row; a single column is
    summed by ``cumsum``, which adds in order too.
    """
    product = np.multiply(left, right)
    if product.shape[1] == 1:
        total = np.cumsum(product[:, 0])[-1] + 0.0 if len(product) else 0.0
        return np.full(n, total)
    return np.add.reduce(product, axis=0, initial=0.0)


@dataclass(frozen=True, slots=True, eq=False)
class Magnitudes:
    """Sums of the magnitudes of the products summed into ``M`` and ``q`` (their rounding
    scale): ``Σ|a_i a_j|`` and ``Σ|a_i b|``. :meth:`bound` replaces them by the
    Cauchy-Schwarz bounds ``√(M_ii M_jj)`` and ``√(M_ii ‖b‖²)``, which cost nothing."""

    m12: FloatArray
    m13: FloatArray
    m23: FloatArray
    q1: FloatArray
    q2: FloatArray
    q3: FloatArray

    @classmethod
    def bound(cls, ne) -> Magnitudes:
        return cls(
            m12=np.sqrt(ne.m11 * ne.m22),
            m13=np.sqrt(ne.m11 * ne.m33),
            m23=np.sqrt(ne.m22 * ne.m33),
            q1=np.sqrt(ne.m11 * ne.bb),
            q2=np.sqrt(ne.m22 * ne.bb),
            q3=np.sqrt(ne.m33 * ne.bb),
        )

    @classmethod
    def of(cls, blocks, n: int) -> Magnitudes:
        sums = dict.fromkeys(("m12", "m13", "m23", "q1", "q2", "q3"), np.zeros(n))
        for block in blocks:
            ax, ay, b = np.abs(block.ax), np.abs(block.ay), np.abs(block.b)
            pairs = {"m12": (ax, ay), "q1": (ax, b), "q2": (ay, b)}
            if block.az is not None:
                az = np.abs(block.az)
                pairs |= {"m13": (ax, az), "m23": (ay, az), "q3": (az, b)}
            for key, (left, right) in pairs.items():
                sums[key] = sums[key] + row_dot(left, right, n)
        return cls(**sums)


@dataclass(frozen=True, slots=True, eq=False)
class RoundingBounds:
    """Rounding bounds of the eigenbasis quantities of one batch (see the module docstring)."""

    a1: FloatArray  # δã₁
    a2: FloatArray  # δã₂
    h1: FloatArray  # δh̃₁
    h2: FloatArray  # δh̃₂
    s11: FloatArray  # E = |U|ᵀ Δ |U|
    s12: FloatArray
    s22: FloatArray
    base: FloatArray  # δ(‖h̃‖² + (q₃ − μ₁/2)/M₃₃)
    turn: FloatArray  # rotation of the eigenbasis, radians (at most 1)

    @classmethod
    def of(cls, ne, mag: Magnitudes, sp) -> RoundingBounds:
        """``ne``: :class:`~estimators.closed_form.gtrs_batch.NormalEquations`; ``sp``: its
        ``Spectrum``."""
        unit = 2.0 * EPS * np.sqrt(ne.n_rows)
        m13, m23, m33, q3 = ne.m13, ne.m23, ne.m33, ne.q3
        abs13, abs23 = mag.m13 + np.abs(m13), mag.m23 + np.abs(m23)
        q3_scale = mag.q3 + np.abs(q3)
        a1 = unit * (mag.q1 + (mag.m13 * np.abs(q3) + np.abs(m13) * q3_scale) / m33)
        a2 = unit * (mag.q2 + (mag.m23 * np.abs(q3) + np.abs(m23) * q3_scale) / m33)
        h1 = unit * abs13 / (2.0 * m33)
        h2 = unit * abs23 / (2.0 * m33)
        d11 = unit * (ne.m11 + abs13 * abs13 / m33)
        d22 = unit * (ne.m22 + abs23 * abs23 / m33)
        d12 = unit * (mag.m12 + abs13 * abs23 / m33)
        c, s = np.abs(sp.c), np.abs(sp.s)
        cc, ss, cs = c * c, s * s, c * s
        s11 = cc * d11 + 2.0 * cs * d12 + ss * d22
        s22 = ss * d11 + 2.0 * cs * d12 + cc * d22
        s12 = cs * (d11 + d22) + (cc + ss) * d12
        h_t1, h_t2 = np.abs(sp.h_t1), np.abs(sp.h_t2)
        err_ht1, err_ht2 = c * h1 + s * h2, s * h1 + c * h2
        base = (
            2.0 * (h_t1 * err_ht1 + h_t2 * err_ht2)
            + unit * q3_scale / m33
            + s11 / (2.0 * m33)
            + 4.0 * EPS * (sp.h_sq + np.abs(q3 / m33) + np.abs(sp.mu1) / m33)
        )
        return cls(
            a1=c * a1 + s * a2,
            a2=s * a1 + c * a2,
            h1=err_ht1,
            h2=err_ht2,
            s11=s11,
            s12=s12,
            s22=s22,
            base=base,
            turn=np.minimum(s12 / np.maximum(sp.gap, TINY), 1.0),
        )

    def take(self, index) -> RoundingBounds:
        if index.size == self.a1.size:
            return self
        return RoundingBounds(**{name: getattr(self, name)[index] for name in self.__slots__})

    def e(self, sp, y1: FloatArray, y2: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Bounds on ``δe₁, δe₂`` for a point ``ỹ = (y1, y2)`` (eigenbasis), ``sp`` the
        spectrum of the same trials."""
        y1, y2 = np.abs(y1), np.abs(y2)
        mu1, mu2 = np.abs(sp.mu1), np.abs(sp.mu2)
        e1 = (
            self.a1
            + mu1 * self.h1
            + self.s11 * y1
            + self.s12 * y2
            + EPS * (np.abs(sp.a_t1) + mu1 * np.abs(sp.h_t1))
        )
        e2 = (
            self.a2
            + mu2 * self.h2
            + self.s12 * y1
            + self.s22 * y2
            + EPS * (np.abs(sp.a_t2) + mu2 * np.abs(sp.h_t2))
        )
        return e1, e2

    def rotated(self, sp, e1: FloatArray, e2: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``δe`` with the eigenbasis' rotation: for comparing a component with a threshold."""
        mu1, mu2 = np.abs(sp.mu1), np.abs(sp.mu2)
        return (
            e1 + self.turn * (np.abs(sp.a_t2) + mu2 * np.abs(sp.h_t2)),
            e2 + self.turn * (np.abs(sp.a_t1) + mu1 * np.abs(sp.h_t1)),
        )


def root_point_error(
    ratio1: FloatArray,
    ratio2: FloatArray,
    shift: FloatArray,
    den2: FloatArray,
    slope_linear: FloatArray,
    err_e1: FloatArray,
    err_e2: FloatArray,
    err_base: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """How far the point ``ỹ = (e₁/s, e₂/(g+s)) − h̃`` of the secular root moves when ``e`` and
    ``φ``'s constant part move by up to their errors (implicit function theorem).

    With ``φ(s) = e₁²/s² + e₂²/(g+s)² − base − s k`` and ``D = −φ'(s) = P₁ + P₂ + k``,
    ``P₁ = 2r₁²/s``, ``P₂ = 2r₂²/(g+s)`` (``r₁ = e₁/s``, ``r₂ = e₂/(g+s)``):
    ``∂ỹ₁/∂e₁ = (P₂ + k)/(sD)`` (small when the pole dominates: the first coordinate is then
    ``±√(−φ)``, whatever ``e₁``), ``∂s/∂e₂ = 2r₂/((g+s)D)``, ``∂s/∂base = −1/D`` and
    ``∂ỹ₁/∂s = −r₁/s``; likewise for ``ỹ₂``. Returns the bounds on ``|δỹ₁|, |δỹ₂|``.
    """
    inv1 = 1.0 / np.maximum(shift, TINY)
    inv2 = 1.0 / np.maximum(den2, TINY)
    pole1 = 2.0 * ratio1**2 * inv1
    pole2 = 2.0 * ratio2**2 * inv2
    slope = pole1 + pole2 + slope_linear
    abs1, abs2 = np.abs(ratio1), np.abs(ratio2)
    ds_e1 = 2.0 * abs1 * inv1 * err_e1 / slope
    ds_e2 = 2.0 * abs2 * inv2 * err_e2 / slope
    ds_base = err_base / slope
    first = (pole2 + slope_linear) * inv1 / slope * err_e1 + abs1 * inv1 * (ds_e2 + ds_base)
    second = (pole1 + slope_linear) * inv2 / slope * err_e2 + abs2 * inv2 * (ds_e1 + ds_base)
    return first, second


def numerical_rank(
    blocks: list,
    ne,
    mu1: FloatArray,
    mu2: FloatArray,
    err_mu: FloatArray,
    svd_rank: Callable[[list, int], IntArray],
    take_systems: Callable[[list, IntArray, int], list],
    *,
    deficient: bool = False,
) -> IntArray:
    """``#{σ_i > RANK_RTOL · σ_1}`` of each ``A``, as ``gtrs.solve_gtrs`` counts it.

    Certified without an SVD where possible: with ``t = ‖A‖_F² = tr M``,
    ``c₂`` the sum of the principal 2×2 minors of ``M`` and ``det M = M₃₃ μ₁ μ₂``,
    ``σ₃² ≥ det M / c₂`` and ``σ₂² ≥ c₂ / (2t)``, and ``σ₃ ≤ ‖A u‖`` for the unit null-vector
    estimate ``u`` (the largest column of ``adj M``). Each bound must clear the threshold by a
    factor 10; the other systems get ``svd_rank`` of their rows (the SVD, as the one-trial
    solver). ``deficient=True`` states that every ``A`` has a null vector up to rounding
    (``σ₃ ≤ 1e-13 σ₁``: the rows of one straight track, MATH §5), which replaces ``‖A u‖``.
    """
    m11, m12, m13, m22, m23, m33 = ne.m11, ne.m12, ne.m13, ne.m22, ne.m23, ne.m33
    trace = ne.trace
    c11 = m22 * m33 - m23 * m23
    c22 = m11 * m33 - m13 * m13
    c33 = m11 * m22 - m12 * m12
    c12 = m13 * m23 - m12 * m33
    c13 = m12 * m23 - m13 * m22
    c23 = m12 * m13 - m11 * m23
    minors = c11 + c22 + c33
    minors_error = 8.0 * EPS * trace * trace
    sigma1_sq_low = trace / 3.0
    ratio_sq = (RANK_RTOL * 10.0) ** 2

    rank = np.full(trace.shape, -1, dtype=np.int64)
    det_low = m33 * np.maximum(mu1 - err_mu, 0.0) * np.maximum(mu2 - err_mu, 0.0)
    full = det_low / (minors + minors_error) > ratio_sq * trace
    rank[full] = 3

    # null vector: the largest column of adj M
    column = np.argmax(np.stack([c11, c22, c33]), axis=0)
    u1 = np.choose(column, [c11, c12, c13])
    u2 = np.choose(column, [c12, c22, c23])
    u3 = np.choose(column, [c13, c23, c33])
    norm = np.sqrt(u1 * u1 + u2 * u2 + u3 * u3)
    if deficient:
        sigma2_sq_low = (minors - minors_error) / (2.0 * trace)
        rank[~full & (sigma2_sq_low > ratio_sq * trace)] = 2
        todo = np.zeros(0, dtype=np.int64)
    else:
        todo = np.flatnonzero(~full & (norm > 0.0) & np.isfinite(norm))
    if todo.size:
        v1, v2, v3 = u1[todo] / norm[todo], u2[todo] / norm[todo], u3[todo] / norm[todo]
        residual_sq = np.zeros(todo.size)
        for sub in take_systems(blocks, todo, trace.size):
            image = sub.ax * v1 + sub.ay * v2
            if sub.az is not None:
                image = image + sub.az * v3
            residual_sq = residual_sq + row_dot(image, image, todo.size)
        deficient = residual_sq <= (RANK_RTOL / 10.0) ** 2 * sigma1_sq_low[todo]
        sigma2_sq_low = (minors[todo] - minors_error[todo]) / (2.0 * trace[todo])
        two = deficient & (sigma2_sq_low > ratio_sq * trace[todo])
        rank[todo[two]] = 2
    exact = np.flatnonzero((rank < 0) & np.isfinite(trace))
    if exact.size:
        rank[exact] = svd_rank(take_systems(blocks, exact, trace.size), exact.size)
    return rank
