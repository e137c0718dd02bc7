r"""The numerical rank of the GTRS rows (MATH §5) and the row sums behind the normal equations.

:func:`row_dot` sums products over the rows in one fixed order, so that a system's normal
equations do not depend, to the bit, on the batch it is solved in (worker counts, chunking,
resume). :func:`numerical_rank` counts the singular values of each ``A`` above
:data:`RANK_RTOL` times the largest; it is a diagnostic (2 on one straight frame, 3 with two
headings), certified from the normal equations where they decide it and from an SVD elsewhere.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

EPS = float(np.finfo(float).eps)

RANK_RTOL = 1e-10
"""Singular values above ``RANK_RTOL`` times the largest count in the numerical rank."""


def row_dot(left: FloatArray, right: FloatArray, n: int | tuple[int, ...]) -> FloatArray:
    """``Σ_rows left·right`` for each of ``n`` systems, (R, n) arrays or (R, 1) columns (or
    (R, p, n) arrays: ``p`` points of each system, summed the same way; ``n`` is then the
    result's shape ``(p, n)``).

    Always the sequential sum over the rows, system by system, ``s = 0; s += l_i r_i``:
    numpy's own sums change their order with the shape (a single column is summed pairwise),
    and a system's result must not depend on its batch, to the bit. A reduction over the
    outer axis of a row-major ``(R, n ≥ 2)`` array adds row after row; a single column is
    summed by ``cumsum``, which adds in order too.
    """
    product = np.multiply(left, right)
    if product.size == len(product):  # one column
        total = np.cumsum(product.reshape(-1))[-1] + 0.0 if len(product) else 0.0
        return np.full(n, total)
    return np.add.reduce(product, axis=0, initial=0.0)


def numerical_rank(
    blocks: list,
    ne,
    mu1: FloatArray,
    mu2: FloatArray,
    svd_rank: Callable[[list, int], IntArray],
    take_systems: Callable[[list, IntArray, int], list],
    *,
    deficient: bool = False,
) -> IntArray:
    """``#{σ_i > RANK_RTOL · σ_1}`` of each ``A``.

    Certified without an SVD where possible: with ``t = ‖A‖_F² = tr M``,
    ``c₂`` the sum of the principal 2×2 minors of ``M`` and ``det M = M₃₃ μ₁ μ₂``,
    ``σ₃² ≥ det M / c₂`` and ``σ₂² ≥ c₂ / (2t)``, and ``σ₃ ≤ ‖A u‖`` for the unit null-vector
    estimate ``u`` (the largest column of ``adj M``). Each bound must clear the threshold by a
    factor 10 beyond the rounding of ``μ`` (``8ε√R‖A‖_F²``); the other systems get
    ``svd_rank`` of their rows (the singular values themselves). ``deficient=True`` states that every ``A`` has a null vector up to rounding
    (``σ₃ ≤ 1e-13 σ₁``: the rows of one straight track, MATH §5), which replaces ``‖A u‖``.
    """
    M = ne.M  # (the 2-D rows: r = (x, y, x² + y²))
    m11, m12, m13, m22, m23, m33 = M[0][0], M[0][1], M[0][2], M[1][1], M[1][2], M[2][2]
    trace = ne.trace
    c11 = m22 * m33 - m23 * m23
    c22 = m11 * m33 - m13 * m13
    c33 = m11 * m22 - m12 * m12
    minors = c11 + c22 + c33
    minors_error = 8.0 * EPS * trace * trace
    err_mu = 8.0 * EPS * np.sqrt(ne.n_rows) * trace
    sigma1_sq_low = trace / 3.0
    ratio_sq = (RANK_RTOL * 10.0) ** 2

    rank = np.full(trace.shape, -1, dtype=np.int64)
    det_low = m33 * np.maximum(mu1 - err_mu, 0.0) * np.maximum(mu2 - err_mu, 0.0)
    full = det_low / (minors + minors_error) > ratio_sq * trace
    rank[full] = 3

    todo = np.zeros(0, dtype=np.int64)
    if deficient:
        sigma2_sq_low = (minors - minors_error) / (2.0 * trace)
        rank[~full & (sigma2_sq_low > ratio_sq * trace)] = 2
    elif ne.nuisance is None:  # (with one, ‖A u‖ is of the projected rows: the SVD decides)
        # null vector: the largest column of adj M
        c12 = m13 * m23 - m12 * m33
        c13 = m12 * m23 - m13 * m22
        c23 = m12 * m13 - m11 * m23
        column = np.argmax(np.stack([c11, c22, c33]), axis=0)
        u1 = np.choose(column, [c11, c12, c13])
        u2 = np.choose(column, [c12, c22, c23])
        u3 = np.choose(column, [c13, c23, c33])
        norm = np.sqrt(u1 * u1 + u2 * u2 + u3 * u3)
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


def numerical_rank_3d(
    blocks: list,
    ne,
    mu: list[FloatArray],
    svd_rank: Callable[[list, int], IntArray],
    take_systems: Callable[[list, IntArray, int], list],
    *,
    deficient: bool = False,
) -> IntArray:
    """:func:`numerical_rank` of rows over ``r = (x, y, z, ‖s‖²)`` (the height a coordinate).

    The same certificates one size up, from the elementary symmetric functions ``e_j`` of the
    eigenvalues ``λ₁ ≥ … ≥ λ₄`` of ``M`` (``e₁ = t = tr M``, ``e₂``, ``e₃`` the sums of the
    principal 2×2 and 3×3 minors, ``e₄ = det M = M_ww μ₁ μ₂ μ₃``): ``σ₄² ≥ e₄ / e₃`` (as
    ``e₃ ≥ λ₁λ₂λ₃``) and ``σ₃² ≥ e₃ / (2 e₂)`` (as ``e₃ ≤ λ₃ (λ₁λ₂ + e₂)``), each clearing the
    threshold by a factor 10 beyond the rounding of the minors (``16 ε t^j``) and of ``μ``;
    the second only with ``deficient=True`` (a level flight, whose rows annihilate
    ``(0, 0, 1, 2h)``, MATH §5). The other systems get ``svd_rank`` of their rows.
    """
    M = ne.M
    trace = ne.trace
    index = range(4)
    pairs = [(i, j) for i in index for j in index if i < j]
    e2 = sum(M[i][i] * M[j][j] - M[i][j] * M[i][j] for i, j in pairs)
    e3 = 0.0
    for skip in index:
        a, b, c = (i for i in index if i != skip)
        e3 = e3 + (
            M[a][a] * (M[b][b] * M[c][c] - M[b][c] * M[b][c])
            - M[a][b] * (M[a][b] * M[c][c] - M[b][c] * M[a][c])
            + M[a][c] * (M[a][b] * M[b][c] - M[b][b] * M[a][c])
        )
    err_mu = 8.0 * EPS * np.sqrt(ne.n_rows) * trace
    ratio_sq = (RANK_RTOL * 10.0) ** 2
    rank = np.full(trace.shape, -1, dtype=np.int64)
    det_low = M[3][3]
    for value in mu:
        det_low = det_low * np.maximum(value - err_mu, 0.0)
    e3_error = 16.0 * EPS * trace * trace * trace
    full = det_low / (e3 + e3_error) > ratio_sq * trace
    rank[full] = 4
    if deficient:
        e2_error = 16.0 * EPS * trace * trace
        sigma3_sq_low = (e3 - e3_error) / (2.0 * (e2 + e2_error))
        rank[~full & (sigma3_sq_low > ratio_sq * trace)] = 3
    exact = np.flatnonzero((rank < 0) & np.isfinite(trace))
    if exact.size:
        rank[exact] = svd_rank(take_systems(blocks, exact, trace.size), exact.size)
    return rank
