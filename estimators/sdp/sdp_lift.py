r"""The lifted CLS of MATH §11 in numbers: rows, compression, whitening, recovery from a lift.

Pure numpy, no solver, written for ``n`` systems at once (a leading axis of length ``n``; one
Monte Carlo trial each), with one-system wrappers. ``r = (s, ‖s‖²)`` has ``d + 1`` entries: ``d = 2``
with the emitter's height known, ``d = 3`` with it a coordinate (every function reads ``d`` from
its arrays' shapes; the lift is ``(d + 2) × (d + 2)``). :class:`ChunkRows` stacks the CLS rows of
a chunk of trials (those of :mod:`estimators.closed_form.cls_batch`, MATH §3-§6).
:func:`compress_stacked` turns the stacked rows ``A r = b`` of each system into the (d+1)×(d+1)
triangle of ``A = QR`` (``‖A r − b‖² = ‖R r − Qᵀb‖² + ρ²``), so the solver's problem does not depend on the
number of samples. :func:`whiten_batch` writes the lifted problem around the least-squares point
``r₀`` in whitened coordinates ``r = r₀ + L w`` (``L = V diag(ℓ_i)`` from the SVD of ``R``), which
makes the objective ``O(1)`` in every direction; without it Clarabel stops with gaps near 1e−4
or with ``InsufficientProgress`` (seen on weighted two-heading rows). :func:`recover_batch`
reads the minimisers of MATH §5 back from an optimal lift: one point from a rank-one lift, the
mirror pair from a rank-two one; :func:`read_lifts` adds their costs, the relaxation value and
the lift in the local frame.

Every system's numbers depend on that system alone, to the last bit, whichever other systems
share the call: the factorisations are LAPACK calls per matrix (numpy's stacked
``qr``/``svd``/``eigh``), and every small matrix product is written as elementwise operations
summed left to right (:func:`matmul_small`), never as a reduction whose order numpy chooses
from the shape. So one trial solved alone gets exactly the numbers it gets in a batch.

The solvers that produce the lift are in :mod:`estimators.sdp.sdp_solvers`; the estimator and
the status discipline in :mod:`estimators.sdp.sdp_cls`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.closed_form.cls_batch import RowsOfChunk, SharedGeometry
from estimators.closed_form.gtrs_batch import RowBlock, row_dimension

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

RANK_RTOL = 1e-6
"""An eigenvalue of the whitened lift below ``RANK_RTOL`` times the largest counts as zero."""


def z_rows(size: int) -> NDArray[np.intp]:
    """The rows and columns of a lift of ``size = d + 2`` over ``(s, 1)``: ``Z``, without the
    row of ``r_w``."""
    return np.array([*range(size - 2), size - 1])


_SINGULAR_RTOL = 1e-12
_TINY = float(np.finfo(float).tiny)


def matmul_small(A: FloatArray, B: FloatArray) -> FloatArray:
    """``A @ B`` for stacks of small matrices, (..., p, q) @ (..., q, r): the products
    ``A_ik B_kj`` elementwise, then summed over ``k`` left to right with elementwise additions
    (no BLAS, no reduction whose order numpy picks): the same bits for a matrix whatever the
    stack around it."""
    products = A[..., :, :, None] * B[..., None, :, :]
    out = products[..., 0, :]
    for k in range(1, A.shape[-1]):
        out = out + products[..., k, :]
    return out


def _matvec(A: FloatArray, x: FloatArray) -> FloatArray:
    """``A @ x`` for stacks (..., p, q) @ (..., q), as :func:`matmul_small`."""
    products = A * x[..., None, :]
    out = products[..., 0]
    for k in range(1, A.shape[-1]):
        out = out + products[..., k]
    return out


def _dot(u: FloatArray, v: FloatArray) -> FloatArray:
    """``u · v`` over the last axis, summed left to right."""
    out = u[..., 0] * v[..., 0]
    for k in range(1, u.shape[-1]):
        out = out + u[..., k] * v[..., k]
    return out


def _squared_norm(u: FloatArray) -> FloatArray:
    """``‖u‖²`` over the last axis, summed left to right."""
    return _dot(u, u)


def _transpose(A: FloatArray) -> FloatArray:
    return np.swapaxes(A, -1, -2)


def object_column(values: Sequence[Any]) -> NDArray[np.object_]:
    """A 1-D object array holding ``values`` as they are (lists stay lists)."""
    return np.fromiter(values, dtype=object, count=len(values))


def symmetric_eigenvalues(M: ArrayLike) -> FloatArray:
    """Eigenvalues of the symmetric ``M`` (..., k, k) (lower triangle read), ascending."""
    return np.linalg.eigvalsh(np.asarray(M, dtype=float))


# --------------------------------------------------------------------------------------------
# rows and QR compression
# --------------------------------------------------------------------------------------------


def stack_rows(blocks: list[RowBlock], width: int) -> FloatArray:
    """The augmented systems ``[A | b]`` of ``width`` trials from row blocks of shape (R, width)
    or (R, 1) (:class:`~estimators.closed_form.gtrs_batch.RowBlock`, ``az=None`` a zero column),
    block after block: shape (width, rows, d + 2)."""
    d = row_dimension(blocks)
    out = np.empty((width, sum(block.n_rows for block in blocks), d + 2))
    at = 0
    for block in blocks:
        end = at + block.n_rows
        for column, values in enumerate((*block.columns(d), block.b)):
            out[:, at:end, column] = 0.0 if values is None else values.T
        at = end
    return out


class ChunkRows:
    """The CLS rows of ``m`` trials of one geometry in their local frames, from
    :mod:`estimators.closed_form.cls_batch` (the rows of ``cls``'s batch, MATH §3-§6).

    ``ranges`` and ``doppler`` are (m, K). The local frame of each trial is centred on the
    samples and scaled by ``L = √(spread² + mean r²)``; numpy sums a single column in another
    order than several, so one trial is computed as two identical ones (and one kept).
    """

    def __init__(self, shared: SharedGeometry, ranges: FloatArray, doppler: FloatArray) -> None:
        self.m = len(ranges)
        r, f = np.ascontiguousarray(ranges.T), np.ascontiguousarray(doppler.T)
        if self.m == 1:
            r, f = np.repeat(r, 2, axis=1), np.repeat(f, 2, axis=1)
        self.width = r.shape[1]
        scale = np.sqrt(shared.spread_sq + np.mean(r * r, axis=0))
        self.scale = np.where(scale > 0.0, scale, 1.0)
        self.rows_of = RowsOfChunk(shared, r, f, self.scale)

    def systems(self, rows: str, weights_at: tuple[FloatArray, ...] | None) -> FloatArray:
        """``[A | b]`` of every trial (m, 2K, d + 2) for the row variant ``rows`` (``weighted``
        with the weights at the local ``weights_at = (x, y)`` or ``(x, y, z)`` (m,) of each
        trial, or at the data when None; ``per-sample``)."""
        if weights_at is not None and self.m == 1:
            weights_at = tuple(np.repeat(values, 2) for values in weights_at)
        with np.errstate(all="ignore"):
            blocks = self.rows_of.blocks(rows, weights_at=weights_at)
            return stack_rows(blocks, self.width)[: self.m]


def compress_stacked(rows: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """QR compression of ``n`` augmented systems ``[A | b]`` of shape (n, m, p) (finite),
    ``p = d + 2``.

    One Householder QR per system (LAPACK ``dgeqrf``): its triangle is ``[[R, c], [0, ±ρ]]``,
    so ``Q`` is never formed and ``ρ`` comes out of the factorisation rather than from
    ``b − Q Qᵀ b``. Returns ``R`` (n, p − 1, p − 1) upper triangular, ``c = Qᵀb`` (n, p − 1)
    (zero rows appended when ``m < p − 1``) and ``ρ²`` (n,).
    """
    n, m, p = rows.shape
    q = p - 1
    factor = np.linalg.qr(rows, mode="r")  # (n, min(m, p), p), upper triangular
    k = min(m, q)
    R = np.zeros((n, q, q))
    c = np.zeros((n, q))
    R[:, :k] = factor[:, :k, :q]
    c[:, :k] = factor[:, :k, q]
    residual_sq = factor[:, q, q] ** 2 if m > q else np.zeros(n)
    return R, c, residual_sq


def compress_rows(A: ArrayLike, b: ArrayLike) -> tuple[FloatArray, FloatArray, float]:
    """QR compression ``‖A r − b‖² = ‖R r − c‖² + ρ²`` (MATH §11) of one system.

    Parameters
    ----------
    A : (m, 3) or (m, 4)
        Over ``r = (x, y, x² + y²)``, or ``(x, y, z, ‖s‖²)`` with the height a coordinate.
    b : (m,)

    Returns
    -------
    R : (d + 1, d + 1)
        Upper triangle of ``A = QR`` (zero rows appended when ``m < d + 1``).
    c : (d + 1,)
        ``Qᵀ b`` (zeros appended likewise).
    residual_sq : float
        ``ρ² = ‖b − Q Qᵀ b‖²``, the part of the cost no ``r`` can change.

    Raises
    ------
    ValueError
        If ``A`` is not (m, 3) or (m, 4) with m >= 1, ``b`` not (m,), or an entry is not finite.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    if A.ndim != 2 or A.shape[1] not in (3, 4) or A.shape[0] < 1:
        raise ValueError(
            f"A: expected the stacked rows with shape (m, 3) or (m, 4), m >= 1; got {A.shape}"
        )
    m, q = A.shape
    if b.shape != (m,):
        raise ValueError(f"b: expected shape ({m},) to match A, got {b.shape}")
    augmented = np.empty((1, m, q + 1))
    augmented[0, :, :q] = A
    augmented[0, :, q] = b
    if not np.isfinite(augmented).all():
        raise ValueError("A/b: the stacked rows contain NaN or infinity; check the measurements")
    R, c, residual_sq = compress_stacked(augmented)
    return R[0], c[0], float(residual_sq[0])


def compressed_cost(
    R: FloatArray, c: FloatArray, residual_sq: FloatArray, xy: FloatArray
) -> FloatArray:
    """``‖A (s, ‖s‖²) − b‖² = ‖R r − c‖² + ρ²`` at points ``s`` (n, k, d): (n, k)."""
    r = np.concatenate([xy, _squared_norm(xy)[..., None]], axis=-1)
    residual = matmul_small(r, _transpose(R)) - c[:, None, :]
    return _dot(residual, residual) + residual_sq[:, None]


# --------------------------------------------------------------------------------------------
# whitening
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class WhitenedRelaxation:
    """The relaxation's data of one system in the solver's coordinates ``r = r₀ + L w``.

    Attributes (``p = d + 2`` the size of the lift)
    ----------
    objective : (p, p)
        ``H_w / s``: ``tr(H_w W_w) = ‖A r − b‖²`` on rank-one lifts of ``(w, 1)``.
    constraint : (p, p)
        ``C_w / κ``: ``tr(C_w W_w) = ‖s‖² − r_w`` on rank-one lifts.
    origin : (p − 1,)
        ``r₀``, the minimum-norm least-squares point of ``R r = c``.
    basis : (p − 1, p − 1)
        ``L``.
    objective_scale : float
        ``s``; the relaxation value is ``s · tr(objective · W_w)``.
    constraint_scale : float
        ``κ``.
    transform : (p, p)
        ``T = [[L, r₀], [0, 1]]``: ``(r, 1) = T (w, 1)``.
    """

    objective: FloatArray
    constraint: FloatArray
    origin: FloatArray
    basis: FloatArray
    objective_scale: float
    constraint_scale: float
    transform: FloatArray

    def to_local(self, lift_w: ArrayLike) -> FloatArray:
        """The lift of ``(r, 1)`` from that of ``(w, 1)``: ``T W_w Tᵀ``."""
        return local_lift(self.transform, np.asarray(lift_w, dtype=float))

    def points(self, w: ArrayLike) -> FloatArray:
        """``r = r₀ + L w`` for rows ``w`` of shape (..., p − 1)."""
        return self.origin + np.asarray(w, dtype=float) @ self.basis.T


@dataclass(frozen=True, slots=True, eq=False)
class WhitenedBatch:
    """:class:`WhitenedRelaxation` of ``n`` systems, field by field with a leading axis."""

    objective: FloatArray  # (n, p, p)
    constraint: FloatArray  # (n, p, p)
    origin: FloatArray  # (n, p - 1)
    basis: FloatArray  # (n, p - 1, p - 1)
    objective_scale: FloatArray  # (n,)
    constraint_scale: FloatArray  # (n,)
    transform: FloatArray  # (n, p, p)

    def take(self, index: IntArray) -> WhitenedBatch:
        """The systems ``index``."""
        return WhitenedBatch(
            *(getattr(self, name)[index] for name in WhitenedBatch.__dataclass_fields__)
        )

    def trial(self, index: int) -> WhitenedRelaxation:
        return WhitenedRelaxation(
            objective=self.objective[index],
            constraint=self.constraint[index],
            origin=self.origin[index],
            basis=self.basis[index],
            objective_scale=float(self.objective_scale[index]),
            constraint_scale=float(self.constraint_scale[index]),
            transform=self.transform[index],
        )


def local_lift(transform: FloatArray, lift_w: FloatArray) -> FloatArray:
    """``T W_w Tᵀ`` for (..., p, p) stacks."""
    return matmul_small(matmul_small(transform, lift_w), _transpose(transform))


def paraboloid_residual(r: ArrayLike) -> FloatArray:
    """``‖s‖² − r_w`` for points ``r = (s, r_w)`` (..., d + 1): zero on the constraint of
    MATH §5."""
    r = np.asarray(r, dtype=float)
    return _squared_norm(r[..., :-1]) - r[..., -1]


def whiten_batch(R: FloatArray, c: FloatArray, residual_sq: FloatArray) -> WhitenedBatch:
    """Write the lifted problem of MATH §11 of each system around ``r₀`` in whitened coordinates.

    With ``R = U Σ Vᵀ``, ``r₀ = V Σ⁺ Uᵀ c`` and ``e = c − R r₀``, the cost is
    ``‖R L w − e‖² + ρ²``. Choosing ``L = V diag(ℓ_i)``, ``ℓ_i = min(√s / σ_i, ℓ_max)``, makes
    its quadratic part ``diag(min(1, σ_i² ℓ_max² / s))·s``: order one in every direction once
    divided by ``s``. The scale is the least-squares residual ``s = ρ² + ‖e‖²``, a lower bound
    on the optimum, so the solver sees ``f*/s ≥ 1`` and its relative gap criterion holds the
    value to a relative accuracy; when that residual vanishes (three rows, noise-free data) it
    is floored at 1e−9 times the excess cost of a cheap feasible point (the vertical projection
    of ``r₀`` or, when that could lift the scale above its floor, a crossing of the weakest
    direction ``v₃`` with the paraboloid). ``ℓ_max = 1 + ‖r₀‖`` bounds the weak directions by
    the frame's length scale.

    ``R`` (n, d + 1, d + 1), ``c`` (n, d + 1), ``residual_sq`` (n,), all finite.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _whiten(R, c, residual_sq)


def _whiten(R: FloatArray, c: FloatArray, residual_sq: FloatArray) -> WhitenedBatch:
    n, q = R.shape[:2]  # q = d + 1 entries of r
    p = q + 1
    U, sigma, Vt = np.linalg.svd(R)
    V = _transpose(Vt)
    cutoff = _SINGULAR_RTOL * np.maximum(sigma[:, :1], _TINY)
    inverse = np.where(sigma > cutoff, 1.0 / sigma, 0.0)
    origin = _matvec(V, inverse * _matvec(_transpose(U), c))
    misfit = c - _matvec(R, origin)
    misfit_sq = _dot(misfit, misfit)
    position = origin[:, :-1]

    floor = residual_sq + misfit_sq
    projection = np.concatenate([position, _squared_norm(position)[:, None]], axis=-1)
    residual = _matvec(R, projection) - c
    upper = _dot(residual, residual) - misfit_sq
    need = floor < 1e-9 * upper
    if need.any():  # only they could lift the scale above its floor (they can only lower it)
        crossings, count = line_paraboloid_points(origin[need], Vt[need, q - 1])
        residuals = matmul_small(crossings, _transpose(R[need])) - c[need, None, :]
        excess = _dot(residuals, residuals) - misfit_sq[need, None]
        excess = np.where(np.arange(2) < count[:, None], excess, np.inf)
        upper[need] = np.minimum(upper[need], np.minimum(excess[:, 0], excess[:, 1]))
    scale = np.maximum(np.maximum(floor, 1e-9 * np.maximum(upper, 0.0)), 1e-300)

    length_max = 1.0 + np.sqrt(_squared_norm(origin))
    lengths = np.where(
        sigma > 0.0,
        np.minimum(np.sqrt(scale)[:, None] / sigma, length_max[:, None]),
        length_max[:, None],
    )
    # T = [[L, r0], [0, 1]] maps (w, 1) to (r, 1); its top rows M = [L | r0] give both blocks
    transform = np.zeros((n, p, p))
    transform[:, :q, :q] = V * lengths[:, None, :]
    transform[:, :q, q] = origin
    transform[:, q, q] = 1.0
    top = transform[:, :q]
    # H_w = Gᵀ G + ρ² e_pe_pᵀ with G = [R L | −e] = R M − [0 | c]
    G = matmul_small(R, top)
    G[:, :, q] -= c
    H = matmul_small(_transpose(G), G)
    H[:, q, q] = floor
    # C_w = KᵀK − ½(e_p m_wᵀ + m_w e_pᵀ) with K = M[:d] (the rows of s), m_w = M[d] (r_w's)
    K = top[:, : q - 1]
    C = matmul_small(_transpose(K), K)
    half_z = 0.5 * top[:, q - 1]
    C[:, q] -= half_z
    C[:, :, q] -= half_z
    constraint_scale = np.abs(C).reshape(n, p * p).max(axis=1)
    return WhitenedBatch(
        objective=H / scale[:, None, None],
        constraint=C / constraint_scale[:, None, None],
        origin=origin,
        basis=transform[:, :q, :q].copy(),
        objective_scale=scale,
        constraint_scale=constraint_scale,
        transform=transform,
    )


def whiten_relaxation(R: FloatArray, c: FloatArray, residual_sq: float) -> WhitenedRelaxation:
    """:func:`whiten_batch` for one system."""
    whitened = whiten_batch(
        np.asarray(R, dtype=float)[None], np.asarray(c, dtype=float)[None], np.array([residual_sq])
    )
    return whitened.trial(0)


# --------------------------------------------------------------------------------------------
# the line through a point and the paraboloid
# --------------------------------------------------------------------------------------------


def quadratic_roots(
    a: FloatArray, half_b: FloatArray, c: FloatArray
) -> tuple[FloatArray, IntArray]:
    """Real roots of ``a t² + 2 half_b t + c = 0`` (cancellation-free), ascending, for arrays
    (n,): roots (n, 2) (NaN past ``count``) and their count (n,)."""
    with np.errstate(all="ignore"):
        discriminant = half_b * half_b - a * c
        q = -(half_b + np.copysign(np.sqrt(np.maximum(discriminant, 0.0)), half_b))
        first, second = q / a, c / q
        linear = -c / (2.0 * half_b)
    low = np.where(first <= second, first, second)
    high = np.where(first <= second, second, first)
    quadratic = (a > 0.0) & (discriminant >= 0.0)
    double = quadratic & (q == 0.0)
    two = quadratic & ~double
    single = (a <= 0.0) & (half_b != 0.0)
    roots = np.full((len(a), 2), np.nan)
    roots[:, 0] = np.where(two, low, np.where(double, 0.0, np.where(single, linear, np.nan)))
    roots[:, 1] = np.where(two, high, np.nan)
    count = np.where(two, 2, np.where(double | single, 1, 0)).astype(np.int64)
    return roots, count


def line_paraboloid_points(point: FloatArray, direction: FloatArray) -> tuple[FloatArray, IntArray]:
    """The (0 to 2) points ``point + t·direction`` with ``‖s‖² = r_w``, for ``n`` lines
    (point, direction (n, d + 1)): points (n, 2, d + 1) (NaN past ``count``) and the count
    (n,)."""
    position, along = point[:, :-1], direction[:, :-1]
    a = _squared_norm(along)
    half_b = _dot(position, along) - 0.5 * direction[:, -1]
    c = _squared_norm(position) - point[:, -1]
    roots, count = quadratic_roots(a, half_b, c)
    return point[:, None, :] + roots[:, :, None] * direction[:, None, :], count


# --------------------------------------------------------------------------------------------
# recovery of the minimisers from an optimal lift
# --------------------------------------------------------------------------------------------


def recover_batch(
    lift_w: FloatArray,
    origin: FloatArray,
    basis: FloatArray,
    *,
    rank_rtol: float = RANK_RTOL,
) -> tuple[FloatArray, IntArray, IntArray]:
    """The points of MATH §5 encoded in optimal lifts (MATH §11), and the lifts' ranks.

    Rank one: the single point ``r = r₀ + L w`` read from the last column. Rank two (the hard
    case): ``W_w = α ŵ₁ŵ₁ᵀ + (1 − α) ŵ₂ŵ₂ᵀ``, so the Schur complement ``W_ww − w wᵀ`` is
    ``α(1−α) (w₁ − w₂)(w₁ − w₂)ᵀ``; both minimisers are the points of the line through ``w``
    along its principal eigenvector that satisfy ``‖y‖² = r_z``. Since
    ``tr(C W) = ‖y‖² − r_z + tr(Schur_yy) ≤ 0`` holds for both relaxations, that line always
    crosses the paraboloid (when rounding says otherwise, the centre alone is returned).

    ``lift_w`` (n, p, p) finite whitened lifts, ``origin`` (n, p − 1) and ``basis`` (n, p − 1,
    p − 1) of their :class:`WhitenedBatch`. Returns points (n, 2, p − 1) in the local frame
    (NaN past the count), their count (n,) and the rank (n,).
    """
    W = 0.5 * (lift_w + _transpose(lift_w))
    q = W.shape[-1] - 1
    eigenvalues = np.linalg.eigvalsh(W)
    cutoff = rank_rtol * np.maximum(eigenvalues[:, -1], _TINY)
    rank = np.count_nonzero(eigenvalues > cutoff[:, None], axis=1).astype(np.int64)
    corner = W[:, q, q]
    w = W[:, :q, q] / corner[:, None]
    centre = origin + _matvec(basis, w)
    points = np.full((len(W), 2, q), np.nan)
    points[:, 0] = centre
    count = np.ones(len(W), dtype=np.int64)
    pair = rank >= 2
    if pair.any():
        wp = w[pair]
        schur = W[pair, :q, :q] / corner[pair, None, None] - wp[:, :, None] * wp[:, None, :]
        principal = np.linalg.eigh(0.5 * (schur + _transpose(schur)))[1][:, :, -1]
        direction = _matvec(basis[pair], principal)
        crossing, crossings = line_paraboloid_points(centre[pair], direction)
        found = crossings > 0
        at = np.flatnonzero(pair)[found]
        points[at] = crossing[found]
        count[at] = crossings[found]
    return points, count, np.maximum(rank, 1)


def recover_minimisers(
    lift_w: ArrayLike, whitened: WhitenedRelaxation, *, rank_rtol: float = RANK_RTOL
) -> tuple[FloatArray, int]:
    """:func:`recover_batch` for one system: ``(points (k, d + 1) in the local frame, rank)``."""
    points, count, rank = recover_batch(
        np.asarray(lift_w, dtype=float)[None],
        whitened.origin[None],
        whitened.basis[None],
        rank_rtol=rank_rtol,
    )
    return points[0, : count[0]], int(rank[0])


# --------------------------------------------------------------------------------------------
# reading solved lifts
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class ReadLifts:
    """What the optimal whitened lifts of ``n`` systems say: the recovered points (n, 2, d + 1)
    and their count, the rank, the CLS costs of the points (n, 2), the relaxation value, the
    lift in the local frame (n, d + 2, d + 2), and whether points, costs and value are finite (only
    the finite ones are kept: elsewhere NaN, count and rank 0)."""

    points: FloatArray
    count: IntArray
    rank: IntArray
    costs: FloatArray
    value: FloatArray
    lift: FloatArray
    finite: NDArray[np.bool_]


def trace_product(H: FloatArray, W: FloatArray) -> FloatArray:
    """``tr(H W)`` for symmetric stacks (n, p, p): the entrywise products summed row by row,
    then the row sums, left to right."""
    product = H * W
    rows = product[:, :, 0]
    for k in range(1, product.shape[-1]):
        rows = rows + product[:, :, k]
    total = rows[:, 0]
    for k in range(1, rows.shape[-1]):
        total = total + rows[:, k]
    return total


def read_lifts(
    lift_w: FloatArray,
    whitened: WhitenedBatch,
    R: FloatArray,
    c: FloatArray,
    residual_sq: FloatArray,
    read: NDArray[np.bool_],
    *,
    rank_rtol: float = RANK_RTOL,
) -> ReadLifts:
    """For the systems ``read`` (n,) (their whitened lifts ``lift_w`` (n, p, p) finite):
    the points (:func:`recover_batch`), their costs ``‖R r − c‖² + ρ²``, the value
    ``s · tr(H_w W_w)`` and the local lift ``T W_w Tᵀ``."""
    n = len(lift_w)
    index = np.flatnonzero(read)
    every = index.size == n  # the usual case: no copies
    if index.size == 0:
        return _unread(n, lift_w.shape[-1])
    if not every:
        lift_w, whitened = lift_w[index], whitened.take(index)
        R, c, residual_sq = R[index], c[index], residual_sq[index]
    with np.errstate(all="ignore"):
        points, count, rank = recover_batch(
            lift_w, whitened.origin, whitened.basis, rank_rtol=rank_rtol
        )
        valid = np.arange(2) < count[:, None]
        costs = np.where(valid, compressed_cost(R, c, residual_sq, points[:, :, :-1]), np.nan)
        value = whitened.objective_scale * trace_product(whitened.objective, lift_w)
        lift = local_lift(whitened.transform, lift_w)
    finite = (
        (np.isfinite(points).all(axis=2) | ~valid).all(axis=1)
        & (np.isfinite(costs) | ~valid).all(axis=1)
        & np.isfinite(value)
    )
    found = ReadLifts(points, count, rank, costs, value, lift, finite)
    if every and finite.all():
        return found
    out = _unread(n, lift_w.shape[-1])
    kept = index[finite]
    for name in ReadLifts.__dataclass_fields__:
        getattr(out, name)[kept] = getattr(found, name)[finite]
    return out


def _unread(n: int, size: int) -> ReadLifts:
    return ReadLifts(
        points=np.full((n, 2, size - 1), np.nan),
        count=np.zeros(n, dtype=np.int64),
        rank=np.zeros(n, dtype=np.int64),
        costs=np.full((n, 2), np.nan),
        value=np.full(n, np.nan),
        lift=np.full((n, size, size), np.nan),
        finite=np.zeros(n, dtype=bool),
    )


def lift_spectra(lift: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For local lifts (n, p, p): the eigenvalues of the lift (n, p) and of MATH §11's ``Z``
    (n, p − 1), descending, and ``‖s‖² − r_w`` of the relaxed point (last column); NaN for a
    lift that is not finite."""
    n, p = lift.shape[:2]
    rows = z_rows(p)
    finite = np.isfinite(lift).all(axis=(1, 2))
    lift_eigenvalues = np.full((n, p), np.nan)
    z_eigenvalues = np.full((n, p - 1), np.nan)
    if finite.any():
        lifts = lift[finite]
        lift_eigenvalues[finite] = symmetric_eigenvalues(lifts)[:, ::-1]
        z_eigenvalues[finite] = symmetric_eigenvalues(lifts[:, rows][:, :, rows])[:, ::-1]
    with np.errstate(all="ignore"):
        residual = np.where(finite, paraboloid_residual(lift[:, : p - 1, p - 1]), np.nan)
    return lift_eigenvalues, z_eigenvalues, residual
