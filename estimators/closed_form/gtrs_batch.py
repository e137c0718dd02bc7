r"""The GTRS of MATH §5 (paper eq ``finalest``, corrected), solved for many systems at once.

.. math::

    \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad \lVert s \rVert^2 - r_w = 0,
    \qquad r = (s, \lVert s \rVert^2)

with ``s = (x_s, y_s)`` (the emitter's height known, ``d = 2``) or ``s = (x_s, y_s, z_s)`` (the
height a coordinate, ``d = 3``): a generalized trust-region subproblem. With ``M = AᵀA``,
``q = Aᵀb``, ``D = diag(I_d, 0)`` and ``g = (0, …, 0, −½)`` the stationarity condition is
``(M + λD) r = q − λg`` (the paper drops the transpose), and the global minimiser is the
stationary point with ``M + λD ⪰ 0`` (Moré 1993; Beck, Stoica & Li 2008). This is the one
implementation, for both dimensions: one system (:func:`estimators.closed_form.gtrs.solve_gtrs`)
is a batch of one.

Every per-system scalar is an array of shape ``(n,)`` and the rows of the stacked systems are
given as :class:`RowBlock` columns of shape ``(R, n)`` (row × system), so that every operation
is one numpy call over the whole batch.

- ``M`` and ``q`` are summed over the rows (:func:`~estimators.closed_form.gtrs_rank.row_dot`,
  whose order does not depend on the batch); eliminating ``r_w`` with the Schur complement
  ``S = M_ss − m mᵀ/M_ww`` (``m = M[:d, w]``, ``w = d`` the index of ``r_w``),
  ``S = U diag(μ₁ ≤ … ≤ μ_d) Uᵀ`` (in closed form for ``d = 2``, :func:`eigen_2x2`; by
  ``numpy.linalg.eigh`` for ``d = 3``), ``a = q_s − m q_w/M_ww``, ``h = m/(2M_ww)``,
  ``ã = Uᵀa``, ``h̃ = Uᵀh``, ``e = ã + μ h̃``: ``ỹ_i(λ) + h̃_i = e_i/(μ_i + λ)`` and
  ``φ(λ) = Σ e_i²/(μ_i + λ)² − ‖h̃‖² − (q_w + λ/2)/M_ww``, strictly decreasing on ``λ > −μ₁``.
- Hard case, the normal case here (MATH §5): when ``e₁ = 0`` (every single straight frame in
  2-D, every level flight in 3-D: ``A`` has a null vector) the pole at ``−μ₁`` disappears. If
  ``φ(−μ₁)`` without the ``e₁`` term is negative and ``|e₁| ≤ rtol·μ_d·√(−φ(−μ₁))``,
  ``λ* = −μ₁`` and the minimisers are ``ỹ₁ = −h̃₁ ± √(−φ(−μ₁))``: the emitter and its mirror
  image (across the track in 2-D, through the flight plane in 3-D), kept as a pair when their
  costs are equal to rounding (:func:`equal_to_rounding`).
- Otherwise the root of the secular equation ``φ(−μ₁ + s) = 0`` is found by Newton's method
  from a lower bound of the root. ``φ`` is convex and strictly decreasing in ``s > 0``, so
  every Newton iterate stays below the root and the iterates increase monotonically to it:
  no bracketing is needed, and only the systems that have not converged are iterated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from estimators.closed_form.gtrs_rank import RANK_RTOL, numerical_rank, numerical_rank_3d, row_dot

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
    """Rows ``[ax, ay, (ah,) az] r = b`` of many systems: arrays of shape (R, n) or (R, 1).

    ``r = (x, y, ‖s‖²)`` with the emitter's height known, ``r = (x, y, z, ‖s‖²)`` when it is a
    coordinate (MATH §5): ``ah`` is the height's column, ``None`` in 2-D; ``az`` is the column
    of ``‖s‖²``, ``None`` a zero column (the Doppler rows of MATH §3). ``ac`` is the column of
    a free linear unknown ``t`` (an unknown carrier offset, MATH §15), ``[ax, ay, az] r + ac t
    = b``, which the solver projects out: ``None`` when there is none. The dimension of a list
    of blocks is 3 when any block has ``ah`` (:func:`row_dimension`).
    """

    ax: FloatArray
    ay: FloatArray
    az: FloatArray | None
    b: FloatArray
    ac: FloatArray | None = None
    ah: FloatArray | None = None

    @property
    def n_rows(self) -> int:
        return int(self.b.shape[0])

    def columns(self, dimension: int) -> list[FloatArray | None]:
        """The ``dimension + 1`` columns of ``A``, the position's then ``‖s‖²``'s (None: zero)."""
        if dimension == 2:
            return [self.ax, self.ay, self.az]
        return [self.ax, self.ay, self.ah, self.az]

    def take(self, index: IntArray) -> RowBlock:
        """The systems ``index`` (columns of trial-wise arrays; broadcast columns kept)."""

        def pick(column: FloatArray | None) -> FloatArray | None:
            if column is None or column.shape[1] == 1:
                return column
            return np.ascontiguousarray(column[:, index])  # (fancy indexing gives F order)

        return RowBlock(
            pick(self.ax), pick(self.ay), pick(self.az), pick(self.b), pick(self.ac), pick(self.ah)
        )

    def per_point(self) -> RowBlock:
        """The columns as (R, 1, n), to meet points of shape (p, n)."""

        def column(values: FloatArray | None) -> FloatArray | None:
            return None if values is None else values[:, None, :]

        return RowBlock(
            column(self.ax),
            column(self.ay),
            column(self.az),
            column(self.b),
            column(self.ac),
            column(self.ah),
        )

    def residual(self, point: Sequence[FloatArray]) -> FloatArray:
        """``A r − b`` at ``r = (s, ‖s‖²)`` for each system, ``point`` the coordinates of
        ``s``, each (n,), shape (R, n) (or (R, n, p) for the columns of :meth:`per_point` and
        coordinates (p, n))."""
        out = self.ax * point[0]
        out += self.ay * point[1]
        if self.ah is not None:
            out += self.ah * point[2]
        out -= self.b
        if self.az is not None:
            out += self.az * squared_norm(point)
        return out


def squared_norm(point: Sequence[FloatArray]) -> FloatArray:
    """``‖s‖²`` of the coordinates ``point``, summed in their order."""
    total = point[0] * point[0]
    for coordinate in point[1:]:
        total = total + coordinate * coordinate
    return total


def row_dimension(blocks: Sequence[RowBlock]) -> int:
    """The dimension of the position the rows describe: 3 when any block has a height column."""
    return 3 if any(block.ah is not None for block in blocks) else 2


@dataclass(frozen=True, slots=True, eq=False)
class NormalEquations:
    """``M = AᵀA`` (``M[i][j]`` of shape (n,), lists), ``q = Aᵀb``, ``‖b‖²`` and the row count, per
    system, for ``r`` of ``dimension + 1`` entries, ``‖s‖²`` last (index ``w``).

    With a free unknown's column ``c`` in the rows (:attr:`RowBlock.ac`) these are of the rows
    projected off ``c`` (MATH §15): ``M − m_c m_cᵀ/‖c‖²``, ``q − m_c (cᵀb)/‖c‖²``,
    ``‖b‖² − (cᵀb)²/‖c‖²`` with ``m_c = Aᵀc``; ``nuisance`` keeps ``m_c`` (``"c"``, d + 1 (n,)),
    ``cᵀb`` and ``‖c‖²`` (``"cb"``, ``"cc"``) for the unknown's value at a point,
    :meth:`nuisance_at`.
    """

    M: list[list[FloatArray]]
    q: list[FloatArray]
    bb: FloatArray
    n_rows: int
    dimension: int
    nuisance: dict[str, FloatArray] | None = None

    @classmethod
    def of(cls, blocks: list[RowBlock], n: int) -> NormalEquations:
        d = row_dimension(blocks)
        k = d + 1
        sums: dict[tuple[str, int, int], FloatArray] = {}

        def add(key: tuple[str, int, int], left: FloatArray, right: FloatArray) -> None:
            total = row_dot(left, right, n)
            sums[key] = total if key not in sums else sums[key] + total

        for block in blocks:
            columns = block.columns(d)
            b, ac = block.b, block.ac
            add(("bb", 0, 0), b, b)
            for i in range(k):
                if columns[i] is None:
                    continue
                add(("q", i, 0), columns[i], b)
                for j in range(i, k):
                    if columns[j] is not None:
                        add(("M", i, j), columns[i], columns[j])
                if ac is not None:
                    add(("c", i, 0), columns[i], ac)
            if ac is not None:
                add(("cb", 0, 0), b, ac)
                add(("cc", 0, 0), ac, ac)
        zero = np.zeros(n)
        M = [[zero] * k for _ in range(k)]
        for i in range(k):
            for j in range(i, k):
                M[i][j] = M[j][i] = sums.get(("M", i, j), zero)
        q = [sums.get(("q", i, 0), zero) for i in range(k)]
        bb = sums[("bb", 0, 0)]
        nuisance = None
        if ("cc", 0, 0) in sums:
            column = [sums.get(("c", i, 0), zero) for i in range(k)]
            cb, cc = sums[("cb", 0, 0)], sums[("cc", 0, 0)]
            nuisance = {"c": column, "cb": cb, "cc": cc}
            inv = 1.0 / cc
            for i in range(k):
                for j in range(i, k):
                    M[i][j] = M[j][i] = M[i][j] - column[i] * column[j] * inv
                q[i] = q[i] - column[i] * cb * inv
            bb = bb - cb * cb * inv
        return cls(
            M=M,
            q=q,
            bb=bb,
            n_rows=sum(block.n_rows for block in blocks),
            dimension=d,
            nuisance=nuisance,
        )

    def nuisance_at(self, points: Sequence[FloatArray]) -> FloatArray:
        """The free unknown's least-squares value ``cᵀ(b − A r)/‖c‖²`` at ``r = (s, ‖s‖²)``
        (the coordinates of ``s`` each of shape (n, k)); NaN where the point is."""
        c = self.nuisance
        if c is None:
            raise ValueError("the rows have no free unknown's column")
        column = c["c"]
        out = c["cb"][:, None] - column[0][:, None] * points[0]
        for i in range(1, self.dimension):
            out = out - column[i][:, None] * points[i]
        out = out - column[self.dimension][:, None] * squared_norm(points)
        return out / c["cc"][:, None]

    @property
    def trace(self) -> FloatArray:
        """``‖A‖_F²``."""
        total = self.M[0][0] + self.M[1][1]
        for i in range(2, self.dimension + 1):
            total = total + self.M[i][i]
        return total


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
        No finite minimiser: non-finite rows, no ToA row (``M_ww = 0``), or a secular equation
        whose iteration failed.
    nuisance : (n, 2) or None
        The free unknown's value at each point (:meth:`NormalEquations.nuisance_at`), when the
        rows have its column.
    z : (n, 2) or None
        The height of each minimiser when the rows have a height column (3-D), else None.
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
    z: FloatArray | None = None

    @property
    def points(self) -> list[FloatArray]:
        """The coordinates of the minimisers, ``[x, y]`` or ``[x, y, z]``, each (n, 2)."""
        return [self.x, self.y] if self.z is None else [self.x, self.y, self.z]

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


def eigen_symmetric(
    S: list[list[FloatArray]],
) -> tuple[list[FloatArray], list[FloatArray], list[list[FloatArray]]]:
    """Eigenvalues ``μ₁ ≤ … ≤ μ_d`` of the symmetric ``S`` (``S[i][j]`` of shape (n,)), the
    gaps ``μ_i − μ₁`` (i ≥ 2) and the eigenvectors, ``U[j][i]`` the j-th entry of the i-th.

    ``d = 2``: the closed form :func:`eigen_2x2` (its gap without cancellation); ``d ≥ 3``:
    ``numpy.linalg.eigh`` on the stacked (n, d, d) matrices.
    """
    d = len(S)
    if d == 2:
        mu1, mu2, gap, c, s = eigen_2x2(S[0][0], S[0][1], S[1][1])
        return [mu1, mu2], [gap], [[c, -s], [s, c]]
    stacked = np.stack([np.stack(row, axis=-1) for row in S], axis=-2)
    values, vectors = np.linalg.eigh(stacked)
    mu = [np.ascontiguousarray(values[:, i]) for i in range(d)]
    gaps = [np.maximum(mu[i] - mu[0], 0.0) for i in range(1, d)]
    U = [[np.ascontiguousarray(vectors[:, j, i]) for i in range(d)] for j in range(d)]
    return mu, gaps, U


def _pole_term(e: FloatArray, gap: FloatArray, power: int) -> FloatArray:
    """``e²/gap^power``, ``0`` where ``e = gap = 0`` and ``inf`` where only the gap is 0."""
    positive = gap > 0.0
    if positive.all():
        return e * e / gap**power
    return np.where(
        positive, e * e / np.where(positive, gap, 1.0) ** power, np.where(e == 0, 0.0, np.inf)
    )


@dataclass(frozen=True, slots=True, eq=False)
class Spectrum:
    """The Schur complement's eigen-decomposition and the secular equation's coefficients.

    ``S = M_ss − m mᵀ/M_ww = U diag(μ₁ ≤ … ≤ μ_d) Uᵀ`` (``m = M[:d, w]``), ``a = q_s − m q_w/M_ww``,
    ``h = m/(2M_ww)``, ``ã = Uᵀa``, ``h̃ = Uᵀh``, ``e = ã + μ h̃`` (lists over the eigen-axes,
    each (n,)); ``φ(−μ₁ + s) = e₁²/s² + Σ_{i≥2} e_i²/(g_i + s)² − base − s/(2M_ww)`` with the
    gaps ``g_i = μ_i − μ₁``.
    """

    mu: list[FloatArray]
    gaps: list[FloatArray]
    U: list[list[FloatArray]]
    a_t: list[FloatArray]
    h_t: list[FloatArray]
    e: list[FloatArray]
    h_sq: FloatArray
    base: FloatArray
    second_at_pole: FloatArray
    phi_pole: FloatArray
    m_ww: FloatArray

    @classmethod
    def of(cls, ne: NormalEquations) -> Spectrum:
        M, q, d = ne.M, ne.q, ne.dimension
        m_ww, q_w = M[d][d], q[d]
        S = [[M[i][j] for j in range(d)] for i in range(d)]
        for i in range(d):
            for j in range(i, d):
                S[i][j] = S[j][i] = M[i][j] - M[i][d] * M[j][d] / m_ww
        mu, gaps, U = eigen_symmetric(S)
        a = [q[i] - M[i][d] * q_w / m_ww for i in range(d)]
        h = [M[i][d] / (2.0 * m_ww) for i in range(d)]

        def rotate(values: list[FloatArray]) -> list[FloatArray]:
            out = []
            for i in range(d):
                total = U[0][i] * values[0]
                for j in range(1, d):
                    total = total + U[j][i] * values[j]
                out.append(total)
            return out

        a_t, h_t = rotate(a), rotate(h)
        e = [a_t[i] + mu[i] * h_t[i] for i in range(d)]
        h_sq = squared_norm(h_t)
        base = h_sq + (q_w - 0.5 * mu[0]) / m_ww
        second_at_pole = _pole_term(e[1], gaps[0], 2)
        for i in range(2, d):
            second_at_pole = second_at_pole + _pole_term(e[i], gaps[i - 1], 2)
        return cls(
            mu=mu,
            gaps=gaps,
            U=U,
            a_t=a_t,
            h_t=h_t,
            e=e,
            h_sq=h_sq,
            base=base,
            second_at_pole=second_at_pole,
            phi_pole=second_at_pole - base,
            m_ww=m_ww,
        )

    @property
    def dimension(self) -> int:
        return len(self.mu)

    def take(self, index: IntArray) -> Spectrum:
        if index.size == self.mu[0].size:
            return self

        def pick(value):  # (arrays, and lists of them)
            if isinstance(value, list):
                return [pick(item) for item in value]
            return value[index]

        return Spectrum(**{name: pick(getattr(self, name)) for name in self.__slots__})

    def to_rows(self, y: Sequence[FloatArray]) -> list[FloatArray]:
        """Eigenbasis coordinates back to the rows' coordinates: ``U ỹ`` (of (n,) or (p, n)
        points)."""
        out = []
        for j in range(self.dimension):
            total = self.U[j][0] * y[0]
            for i in range(1, self.dimension):
                total = total + self.U[j][i] * y[i]
            out.append(total)
        return out


def solve_gtrs_batch(
    blocks: list[RowBlock],
    n: int,
    *,
    hard_case_rtol: float = 1e-10,
    rank: bool = False,
    rank_deficient: bool = False,
) -> GtrsBatch:
    """Every global minimiser of ``‖A r − b‖²`` s.t. ``‖s‖² = r_w`` for ``n`` systems, ``r =
    (s, r_w)`` with ``s`` of 2 or 3 coordinates (:func:`row_dimension`).

    The systems are the columns of ``blocks`` (see the module docstring for the method).
    ``hard_case_rtol``: the hard case is considered when the root of φ would lie within
    ``hard_case_rtol · μ_d`` of the pole ``−μ₁``, and declared only if the two points of the
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
    d = ne.dimension
    trace = ne.trace
    finite = np.isfinite(trace) & np.isfinite(sum(ne.q) + ne.bb) & (sp.m_ww > 0.0)
    failed = ~finite
    mu_scale = np.maximum(np.abs(sp.mu[-1]), TINY)
    gaps_safe = [gap if (gap > 0.0).all() else np.where(gap > 0.0, gap, 1.0) for gap in sp.gaps]

    # hard-case screen (MATH §5): φ(−μ₁) < 0 and |e₁| ≤ rtol·μ_d·√(−φ(−μ₁))
    negative = sp.phi_pole < 0.0
    width = np.sqrt(np.where(negative, -sp.phi_pole, 0.0))
    screen = negative & (np.abs(sp.e[0]) <= rtol * mu_scale * width) & finite

    points = [np.full((n, 2), np.nan) for _ in range(d)]
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
        w = pick(width)
        # (2, m): the pair point-major, so that numpy's loops run over the systems
        tilde = [-sub.h_t[0] + _PAIR_SIGNS[:, None] * w]
        tilde += [sub.e[i] / pick(gaps_safe[i - 1]) - sub.h_t[i] for i in range(1, d)]
        pair = sub.to_rows(tilde)
        rows = take_systems(blocks, idx, n)
        pair_costs = _cost(rows, pair).T
        pair = [coordinate.T for coordinate in pair]
        square = squared_norm(pair)
        norms = np.maximum.reduce(np.sqrt(square + square * square), axis=1)
        # a small but real e₁ (two headings a few millidegrees apart) passes the screen, yet
        # the pair's costs then differ by 4|e₁|√(−φ(−μ₁)): the pair only when they are equal
        equal = equal_to_rounding(
            pair_costs, norms, np.sqrt(pick(trace)), np.sqrt(pick(ne.bb)), ne.n_rows
        )
        if every and equal.all():
            hard[:] = True
            for target, values in zip(points, pair, strict=True):
                target[:] = values
            costs[:] = pair_costs
            multiplier[:] = -sp.mu[0]
        else:
            keep = idx[equal]
            hard[keep] = True
            for target, values in zip(points, pair, strict=True):
                target[keep] = values[equal]
            costs[keep] = pair_costs[equal]
            multiplier[keep] = -sp.mu[0][keep]

    # --- the unique root of the secular equation
    idx = np.flatnonzero(finite & ~hard)
    if idx.size:
        sub = sp.take(idx)
        shift, diverged = _secular_root(sub, sp.phi_pole[idx])
        ratio = [np.where(shift > 0.0, sub.e[0] / np.where(shift > 0.0, shift, 1.0), 0.0)]
        for i in range(1, d):
            den = sub.gaps[i - 1] + shift
            ratio.append(np.where(den > 0.0, sub.e[i] / np.where(den > 0.0, den, 1.0), 0.0))
        root = sub.to_rows([ratio[i] - sub.h_t[i] for i in range(d)])
        for target, values in zip(points, root, strict=True):
            target[idx, 0] = values
        costs[idx, 0] = _cost(take_systems(blocks, idx, n), root)
        multiplier[idx] = shift - sub.mu[0]
        failed[idx] |= diverged
    nuisance = None if ne.nuisance is None else ne.nuisance_at(points)

    ranks = np.full(n, -1, dtype=np.int64)
    if want_rank and d == 2:
        ranks = numerical_rank(
            blocks,
            ne,
            sp.mu[0],
            sp.mu[1],
            _svd_rank,
            take_systems,
            deficient=want_rank == "deficient",
        )
    elif want_rank:
        ranks = numerical_rank_3d(
            blocks, ne, sp.mu, _svd_rank, take_systems, deficient=want_rank == "deficient"
        )
    for values in points:
        failed |= ~np.isfinite(values[:, 0])
    failed |= ~np.isfinite(costs[:, 0])
    return GtrsBatch(
        x=points[0],
        y=points[1],
        count=np.where(hard, 2, 1).astype(np.int64),
        costs=costs,
        multiplier=multiplier,
        hard_case=hard,
        rank=ranks,
        failed=failed,
        nuisance=nuisance,
        z=points[2] if d == 3 else None,
    )


def _cost(blocks: list[RowBlock], point: Sequence[FloatArray]) -> FloatArray:
    """``‖A r − b‖²`` at ``r = (s, ‖s‖²)`` (``point`` the coordinates of ``s``), summed row by
    row (:func:`row_dot`); with a free unknown's column ``c``, at its best value ``t = cᵀ(b −
    A r)/‖c‖²``: the residual ``A r + c t − b`` is formed before it is squared (subtracting
    ``(cᵀ(A r − b))²/‖c‖²`` from the unprojected cost would lose the digits of a small cost to
    a large one)."""
    shape = point[0].shape
    if point[0].ndim == 2:  # p points per system, (p, n): the rows' columns as (R, 1, n)
        blocks = [block.per_point() for block in blocks]
    residuals = [block.residual(point) for block in blocks]
    if any(block.ac is not None for block in blocks):
        along = np.zeros(shape)
        norm = np.zeros(shape)
        for block, residual in zip(blocks, residuals, strict=True):
            if block.ac is not None:
                along += row_dot(block.ac, residual, shape)
                norm += row_dot(block.ac, block.ac, shape)
        step = along / norm
        residuals = [
            residual if block.ac is None else residual - block.ac * step
            for block, residual in zip(blocks, residuals, strict=True)
        ]
    total = np.zeros(shape)
    for residual in residuals:
        total += row_dot(residual, residual, shape)
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
    d = sp.dimension
    e1_sq, base = sp.e[0] * sp.e[0], sp.base
    e_sq = [sp.e[i] * sp.e[i] for i in range(1, d)]
    slope_linear = 0.5 / sp.m_ww
    steep = 2.0 * _pole_term(sp.e[1], sp.gaps[0], 3)
    for i in range(2, d):
        steep = steep + 2.0 * _pole_term(sp.e[i], sp.gaps[i - 1], 3)
    steep = steep + slope_linear
    tangent_root = np.where(phi_pole > 0.0, phi_pole / steep, 0.0)
    tangent_root = np.where(np.isfinite(tangent_root), tangent_root, 0.0)
    bound_pole = np.abs(sp.e[0]) / np.sqrt(2.0 * np.maximum(-phi_pole, 0.0))
    bound_slope = np.cbrt(e1_sq / (2.0 * steep))
    pole_bound = 0.9 * np.minimum(bound_pole, bound_slope)
    pole_bound = np.where((sp.e[0] != 0.0) & np.isfinite(pole_bound), pole_bound, 0.0)
    shift = np.maximum(tangent_root, pole_bound)

    failed = np.zeros(shift.shape, dtype=bool)
    active = np.flatnonzero(shift > 0.0)  # else e₁ = 0 and R(0) ≤ 0: the root is on the pole
    for _ in range(NEWTON_ITERATIONS):
        if active.size == 0:
            break
        s = shift[active]
        inv = 1.0 / s
        first = e1_sq[active] * inv * inv
        den = sp.gaps[0][active] + s
        second = e_sq[0][active] / (den * den)
        slope = 2.0 * second / den
        for i in range(2, d):
            den = sp.gaps[i - 1][active] + s
            term = e_sq[i - 1][active] / (den * den)
            second = second + term
            slope = slope + 2.0 * term / den
        value = first + second - base[active] - s * slope_linear[active]
        derivative = 2.0 * first * inv + slope + slope_linear[active]
        step = value / derivative
        done = (value <= 0.0) | (step <= 2.0 * EPS * s) | ~np.isfinite(step)
        shift[active] = np.where(done, s, s + step)
        failed[active[~np.isfinite(step) & (value > 0.0)]] = True
        active = active[~done]
    failed[active] = True
    return np.where(failed | (shift < 1e-250), 0.0, shift), failed


def _svd_rank(blocks: list[RowBlock], n: int) -> IntArray:
    """The numerical rank from the singular values of the stacked rows (n, R, d + 1)."""
    d = row_dimension(blocks)
    columns = []
    for block in blocks:
        shape = (block.n_rows, n)
        columns.append(
            np.stack(
                [
                    np.zeros(shape) if column is None else np.broadcast_to(column, shape)
                    for column in block.columns(d)
                ],
                -1,
            )
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
