r"""MINPACK's Levenberg-Marquardt for many small least-squares problems at once.

``lmder`` of MINPACK (More 1978; ``x_scale="jac"``, ``factor=100``, the method
``scipy.optimize.least_squares(method="lm")`` calls): QR with column pivoting of the Jacobian
(``qrfac``), the Levenberg-Marquardt parameter by Newton's method on the trust-region equation
(``lmpar``, at most 10 iterations), the damped system by Givens rotations (``qrsolv``), and the
step bound, acceptance and the ``ftol``/``xtol``/``gtol`` tests, with the problems along the
first axis of every array: with ``n`` unknowns (2 or 3: the emitter's ``(x, y)``, or
``(x, y, z)`` with its height unknown) every matrix is ``n × n`` and every loop of ``qrfac``,
``lmpar`` and ``qrsolv`` runs over the ``n`` unknowns as MINPACK's does, each step an
elementwise operation over the problems (a problem's own column order, its pivoting, is an
index per problem). Residuals are kept rows first,
``(m, P)``. This is the reference solver of ``ml`` (one trial is a batch of one); scipy's
``least_squares`` is its cross-check in the tests, at a tolerance. Norms are plain
``√Σ v²`` (MINPACK's ``enorm`` scales only components below ``3.8e-20`` or above
``1.3e19 / m``, which no whitened residual reaches); a problem whose residuals or Jacobian turn
non-finite stops there (``info`` 0).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

Residuals = Callable[[IntArray, FloatArray], FloatArray]
"""``(problems (k,), points (k, n)) -> residuals (m, k)``."""
Jacobian = Callable[[IntArray, FloatArray], Sequence[FloatArray]]
"""``(problems (k,), points (k, n)) -> (∂e/∂x₁, ..., ∂e/∂xₙ)``, each ``(m, k)``."""

EPSMCH = 2.220446049250313e-16
DWARF = 2.2250738585072014e-308
FACTOR = 100.0
"""MINPACK's initial step bound factor, as ``least_squares`` passes it."""
LMPAR_ITERATIONS = 10

INFO_CODES = {
    1: "ftol",
    2: "xtol",
    3: "ftol+xtol",
    4: "gtol",
    5: "max_nfev",
    6: "ftol",
    7: "xtol",
    8: "gtol",
}
"""MINPACK's ``info`` as the tolerance met (6-8: the tolerance is below the rounding, met all
the same) or the evaluation cap."""

TERMINATION_MESSAGES = {
    "max_nfev": "The maximum number of function evaluations is exceeded.",
    "gtol": "`gtol` termination condition is satisfied.",
    "ftol": "`ftol` termination condition is satisfied.",
    "xtol": "`xtol` termination condition is satisfied.",
    "ftol+xtol": "Both `ftol` and `xtol` termination conditions are satisfied.",
}
"""How each ending is told (``least_squares``'s wording, kept for the estimates' messages)."""


def column_sums(values: FloatArray) -> FloatArray:
    """``Σ_i values[i, j]`` for each column of an ``(m, k)`` array, adding row after row: a
    column's sum is then the same bits whatever columns stand beside it (a trial's answer does
    not depend on its batch; one trial is the batch of one). numpy reduces a C-contiguous
    ``(m, k ≥ 2)`` array over its first axis row after row; a single column would be summed
    pairwise, so it is summed beside a copy of itself."""
    values = np.ascontiguousarray(values)
    if values.ndim == 2 and values.shape[1] == 1:
        return np.add.reduce(np.repeat(values, 2, axis=1), axis=0)[:1]
    return np.add.reduce(values, axis=0)


def enorm_rows(values: FloatArray) -> tuple[FloatArray, BoolArray]:
    """The Euclidean norm of each column ``(m, k)``, and where it is not finite."""
    norm = np.sqrt(column_sums(values * values))
    return norm, ~np.isfinite(norm)


def enorm_list(components: Sequence[FloatArray]) -> tuple[FloatArray, BoolArray]:
    """The norm of the vectors of ``components`` (one array per component, summed in
    order), and where it is not finite."""
    total = components[0] * components[0]
    for value in components[1:]:
        total = total + value * value
    norm = np.sqrt(total)
    return norm, ~np.isfinite(norm)


def column_dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """``Σ_i a[i, j] b[i, j]`` for each column ``j`` of two ``(m, k)`` arrays."""
    return column_sums(a * b)


@dataclass(frozen=True, slots=True, eq=False)
class LmderBatch:
    """Where ``lmder`` ended for each problem.

    Attributes
    ----------
    x : (P, n)
        The returned point.
    fvec : (m, P)
        The residuals there (``least_squares``'s ``fun``).
    info : (P,)
        MINPACK's ``info``: 1 ``ftol``, 2 ``xtol``, 3 both, 4 ``gtol``, 5 evaluation cap,
        6-8 tolerances too small; 0 where ``odd``.
    nfev : (P,)
        Residual evaluations.
    odd : (P,)
        The residuals or the Jacobian turned non-finite (module text).
    """

    x: FloatArray
    fvec: FloatArray
    info: IntArray
    nfev: IntArray
    odd: BoolArray


def _permuted(order: IntArray, values: Sequence[FloatArray]) -> FloatArray:
    """``values[order[i]][i]`` for each problem ``i``: the entry of each problem's own column
    ``order`` (a selection, exact)."""
    if len(values) == 2:
        return np.where(order == 1, values[1], values[0])
    return np.choose(order, values)


class _Factor:
    """``qrfac`` with column pivoting and the ``Qᵀf`` of ``lmder`` for some problems.

    ``columns`` (``n`` arrays ``(m, k)``) are the Jacobian's, ``fvec`` ``(m, k)`` the residuals.
    ``r`` ``(n, n, k)`` holds the upper triangle of the pivoted ``R`` (row ``i``, column
    ``j``), ``perm`` ``(n, k)`` the original column of each pivoted one (MINPACK's ``ipvt``),
    ``q`` ``(n, k)`` the first ``n`` entries of ``Qᵀf``, ``acnorm`` the columns' norms."""

    def __init__(self, columns: Sequence[FloatArray], fvec: FloatArray) -> None:
        n = len(columns)
        k = fvec.shape[1]
        found = [enorm_rows(column) for column in columns]
        self.acnorm = [norm for norm, _ in found]
        self.odd = np.logical_or.reduce([odd for _, odd in found])
        a = list(columns)
        rdiag = list(self.acnorm)
        wa = list(self.acnorm)
        perm = [np.full(k, j, dtype=np.int64) for j in range(n)]
        self.r = np.zeros((n, n, k))
        self.q = np.zeros((n, k))
        work = fvec
        for j in range(n):
            # the column of largest remaining norm to position j (the first on a tie)
            best = rdiag[j]
            if j + 1 < n:
                kmax = np.full(k, j, dtype=np.int64)
                for col in range(j + 1, n):
                    bigger = rdiag[col] > best
                    kmax = np.where(bigger, col, kmax)
                    best = np.where(bigger, rdiag[col], best)
                for col in range(j + 1, n):
                    swap = kmax == col
                    if not swap.any():
                        continue
                    a[j], a[col] = np.where(swap, a[col], a[j]), np.where(swap, a[j], a[col])
                    for i in range(j):  # the rows of R above: MINPACK swaps whole columns
                        self.r[i, j], self.r[i, col] = (
                            np.where(swap, self.r[i, col], self.r[i, j]),
                            np.where(swap, self.r[i, j], self.r[i, col]),
                        )
                    if j + 2 < n:  # the norms of the columns still to be pivoted
                        rdiag[col] = np.where(swap, rdiag[j], rdiag[col])
                        wa[col] = np.where(swap, wa[j], wa[col])
                    perm[j], perm[col] = (
                        np.where(swap, perm[col], perm[j]),
                        np.where(swap, perm[j], perm[col]),
                    )
            # the Householder vector of column j, rows j..m
            if j == 0:
                ajnorm = best  # the chosen column's whole norm, computed above
            else:
                ajnorm, odd = enorm_rows(a[j])
                self.odd |= odd
            full = ajnorm != 0.0
            signed = np.where(a[j][0] < 0.0, -ajnorm, ajnorm)
            signed = np.where(full, signed, 1.0)
            v = a[j] / signed
            v[0] = v[0] + 1.0
            self.r[j, j] = np.where(full, -signed, -ajnorm)
            for col in range(j + 1, n):
                temp = column_dot(v, a[col]) / v[0]
                updated = a[col] - temp * v
                if not full.all():
                    updated = np.where(full, updated, a[col])
                self.r[j, col] = updated[0]
                if j + 2 < n and col > j:  # the norms that choose the next pivots
                    known = rdiag[col] != 0.0
                    ratio = updated[0] / rdiag[col]
                    down = rdiag[col] * np.sqrt(np.fmax(0.0, 1.0 - ratio * ratio))
                    again = known & (0.05 * (down / wa[col]) ** 2 <= EPSMCH)
                    if again.any():
                        fresh, odd = enorm_rows(updated[1:])
                        self.odd |= odd & again
                        down = np.where(again, fresh, down)
                        wa[col] = np.where(again, fresh, wa[col])
                    rdiag[col] = np.where(known, down, rdiag[col])
                a[col] = updated[1:]
            # Qᵀf with the Householder vectors, as lmder forms qtf
            temp = -column_dot(v, work) / v[0]
            moved = work + v * temp
            self.q[j] = np.where(full, moved[0], work[0])
            if j + 1 < n:
                work = (moved if full.all() else np.where(full, moved, work))[1:]
        self.perm = np.array(perm)


class _LatestResiduals:
    """Each problem's residuals at its current point, ``(m, P)``, kept as the blocks the
    evaluations returned: accepted columns are appended, never written into one array (numpy
    writes columns of a rows-first array twenty times slower than it gathers them)."""

    def __init__(self, first: FloatArray) -> None:
        self.blocks = [first]
        self.column = np.arange(first.shape[1])  # of each problem, in the blocks side by side
        self.size = first.shape[1]

    def accept(self, problems: IntArray, values: FloatArray) -> None:
        """``values`` ``(m, len(problems))`` are now the residuals of ``problems``."""
        self.blocks.append(values)
        self.column[problems] = self.size + np.arange(len(problems))
        self.size += len(problems)

    def take(self, problems: IntArray) -> FloatArray:
        """The residuals of ``problems``, ``(m, k)``, C-contiguous."""
        last = self.blocks[-1]
        where = self.column[problems] - (self.size - last.shape[1])
        if where.size == 0 or where.min() >= 0:
            return last.take(where, axis=1)
        return self.all().take(self.column[problems], axis=1)

    def all(self) -> FloatArray:
        if len(self.blocks) > 1:
            self.blocks = [np.concatenate(self.blocks, axis=1)]
        return self.blocks[0]


def _givens(rkk: FloatArray, sk: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``qrsolv``'s rotation eliminating ``sk`` against ``rkk``: ``(cos, sin)``."""
    use_cot = np.abs(rkk) < np.abs(sk)
    cot = rkk / sk
    sin_a = 0.5 / np.sqrt(0.25 + 0.25 * (cot * cot))
    cos_a = sin_a * cot
    tan = sk / rkk
    cos_b = 0.5 / np.sqrt(0.25 + 0.25 * (tan * tan))
    sin_b = cos_b * tan
    return np.where(use_cot, cos_a, cos_b), np.where(use_cot, sin_a, sin_b)


def _qrsolv(
    r: FloatArray, perm: IntArray, diag: Sequence[FloatArray], qtb: FloatArray
) -> tuple[list[FloatArray], list[FloatArray], FloatArray, BoolArray]:
    """``qrsolv``: the solution ``x`` of ``min ‖(R; D P) x − (Qᵀb; 0)‖`` (original order),
    ``sdiag`` and the rotated strict lower triangle ``s`` (``s[i, j]``, ``i > j``), and where
    it was odd. ``r`` ``(n, n, k)`` upper, ``diag`` the ``n`` scalings in original order."""
    n = len(qtb)
    s = r.copy()  # s[i, j], i > j: the rotated lower triangle; s[j, j]: the rotated diagonal
    wa = [qtb[j] for j in range(n)]
    sdiag: list[FloatArray] = [np.zeros_like(qtb[0])] * n
    for j in range(n):
        for i in range(j + 1, n):
            s[i, j] = r[j, i]
    for j in range(n):
        row = [np.zeros_like(qtb[0]) for _ in range(n)]
        row[j] = _permuted(perm[j], diag)
        qtbpj = np.zeros_like(qtb[0])
        for kk in range(j, n):
            more = row[kk] != 0.0
            cs, sn = _givens(s[kk, kk], row[kk])
            rotated = s[kk, kk] * cs
            rotated = rotated + sn * row[kk]
            temp = cs * wa[kk] + sn * qtbpj
            qtbpj = np.where(more, -sn * wa[kk] + cs * qtbpj, qtbpj)
            s[kk, kk] = np.where(more, rotated, s[kk, kk])
            wa[kk] = np.where(more, temp, wa[kk])
            for i in range(kk + 1, n):
                temp = cs * s[i, kk] + sn * row[i]
                row[i] = np.where(more, -sn * s[i, kk] + cs * row[i], row[i])
                s[i, kk] = np.where(more, temp, s[i, kk])
        sdiag[j] = s[j, j].copy()
    odd = np.logical_or.reduce([~np.isfinite(value) for value in sdiag])
    # back substitution; a zero sdiag zeroes its entry and the ones after it (MINPACK's nsing)
    singular = np.zeros_like(odd)
    for j in range(n):
        singular = singular | (sdiag[j] == 0.0)
        wa[j] = np.where(singular, 0.0, wa[j])
    for j in reversed(range(n)):
        total = np.zeros_like(wa[j])
        for i in range(j + 1, n):
            total = total + s[i, j] * wa[i]
        solved = (wa[j] - total) / sdiag[j]
        wa[j] = np.where(sdiag[j] == 0.0, wa[j], solved) if singular.any() else solved
    x = _unpermuted(perm, wa)
    return x, sdiag, s, odd


def _unpermuted(perm: IntArray, values: Sequence[FloatArray]) -> list[FloatArray]:
    """``x[perm[j]] = values[j]``: pivoted entries back in the original order."""
    n = len(values)
    if n == 2:
        return [
            np.where(perm[0] == 1, values[1], values[0]),
            np.where(perm[0] == 1, values[0], values[1]),
        ]
    inverse = np.argsort(perm, axis=0)
    return [np.choose(inverse[col], values) for col in range(n)]


def _lmpar(
    r: FloatArray,
    perm: IntArray,
    q: FloatArray,
    diag: FloatArray,
    delta: FloatArray,
    par: FloatArray,
) -> tuple[list[FloatArray], FloatArray, BoolArray]:
    """``lmpar`` from the pivoted ``R`` (``(n, n, k)``), ``perm`` and ``Qᵀf`` (``q``,
    ``(n, k)``): the solution ``x`` (original order; the step is ``−x``), the parameter, and
    where it was odd. ``diag`` is ``(k, n)``."""
    n = len(q)
    d = [diag[:, col] for col in range(n)]
    dp = [_permuted(perm[j], d) for j in range(n)]
    # the Gauss-Newton direction; a zero diagonal of R zeroes its entry and the later ones
    rank = np.ones(len(delta), dtype=bool)
    ranks = []
    for j in range(n):
        rank = rank & (r[j, j] != 0.0)
        ranks.append(rank)
    full = ranks[-1]
    w = [np.where(ranks[j], q[j], 0.0) for j in range(n)]
    for j in reversed(range(n)):
        solved = w[j] / r[j, j]
        w[j] = np.where(ranks[j], solved, w[j])
        for i in range(j):
            w[i] = np.where(ranks[j], w[i] - r[i, j] * w[j], w[i])
    x = _unpermuted(perm, w)
    e = [d[col] * x[col] for col in range(n)]
    dxnorm, odd = enorm_list(e)
    fp = dxnorm - delta
    newton = ~(fp <= 0.1 * delta)
    par = np.where(newton, par, 0.0)
    idx = np.flatnonzero(newton)
    if idx.size == 0:
        return x, par, odd
    # lower bound parl (zero without full rank), upper bound paru
    r_i, q_i, perm_i, full_i = r[..., idx], q[:, idx], perm[:, idx], full[idx]
    d_i = [value[idx] for value in d]
    dp_i = [value[idx] for value in dp]
    dx, fpi, dl = dxnorm[idx], fp[idx], delta[idx]
    e_i = [value[idx] for value in e]
    v = [dp_i[j] * (_permuted(perm_i[j], e_i) / dx) for j in range(n)]
    for j in range(n):
        total = np.zeros_like(dx)
        for i in range(j):
            total = total + r_i[i, j] * v[i]
        v[j] = (v[j] - total) / r_i[j, j]
    temp, odd_t = enorm_list(v)
    parl = np.where(full_i, ((fpi / dl) / temp) / temp, 0.0)
    g = []
    for j in range(n):
        total = np.zeros_like(dx)
        for i in range(j + 1):
            total = total + r_i[i, j] * q_i[i]
        g.append(total / dp_i[j])
    gnorm, odd_g = enorm_list(g)
    paru = gnorm / dl
    paru = np.where(paru == 0.0, DWARF / np.fmin(dl, 0.1), paru)
    p = np.fmin(np.fmax(par[idx], parl), paru)
    p = np.where(p == 0.0, gnorm / dx, p)
    bad = (odd_t & full_i) | odd_g
    out = [value[idx].copy() for value in x]
    outp = p.copy()
    # Newton's iteration on ‖D x(par)‖ = Δ, each problem until its own exit
    live = np.arange(idx.size)
    for iteration in range(1, LMPAR_ITERATIONS + 1):
        p_l = p[live]
        p_l = np.where(p_l == 0.0, np.fmax(DWARF, paru[live] * 0.001), p_l)
        root = np.sqrt(p_l)
        a, sdiag, s, odd_q = _qrsolv(
            r_i[..., live], perm_i[:, live], [root * value[live] for value in d_i], q_i[:, live]
        )
        el = [d_i[col][live] * a[col] for col in range(n)]
        dxl, odd_d = enorm_list(el)
        bad[live] |= odd_q | odd_d
        old = fpi[live]
        fpl = dxl - dl[live]
        for col in range(n):
            out[col][live] = a[col]
        outp[live] = p_l
        done = (
            (np.abs(fpl) <= 0.1 * dl[live])
            | ((parl[live] == 0.0) & (fpl <= old) & (old < 0.0))
            | (iteration == LMPAR_ITERATIONS)
        )
        fpi[live] = fpl
        keep = ~done
        if not keep.any():
            break
        live, p_l, fpl = live[keep], p_l[keep], fpl[keep]
        perm_l = perm_i[:, live]
        el = [value[keep] for value in el]
        dxl = dxl[keep]
        sdiag = [value[keep] for value in sdiag]
        s = s[..., keep]
        u = [dp_i[j][live] * (_permuted(perm_l[j], el) / dxl) for j in range(n)]
        for j in range(n):
            u[j] = u[j] / sdiag[j]
            for i in range(j + 1, n):
                u[i] = u[i] - s[i, j] * u[j]
        temp, odd_u = enorm_list(u)
        parc = ((fpl / dl[live]) / temp) / temp
        bad[live] |= odd_u
        pl = parl[live]
        pu = paru[live]
        parl[live] = np.where(fpl > 0.0, np.fmax(pl, p_l), pl)
        paru[live] = np.where(fpl < 0.0, np.fmin(pu, p_l), pu)
        p[live] = np.fmax(parl[live], p_l + parc)
    for col in range(n):
        x[col][idx] = out[col]
    par[idx] = outp
    odd[idx] |= bad
    return x, par, odd


def lmder_batch(
    residuals: Residuals,
    jacobian: Jacobian,
    x0: FloatArray,
    *,
    ftol: float,
    xtol: float,
    gtol: float,
    max_nfev: int,
) -> LmderBatch:
    """``lmder`` from ``x0[i]`` for every problem ``i`` with the tolerances ``ftol``, ``xtol``,
    ``gtol`` and at most ``max_nfev`` residual evaluations (module text; what
    ``least_squares(fun, x0[i], jac=jac, method="lm", ...)`` computes, to rounding);
    ``residuals`` and ``jacobian`` evaluate any subset. Divisions by zero and overflows are
    the arithmetic's (a problem turned non-finite stops with ``info`` 0), not warnings."""
    with np.errstate(all="ignore"):
        return _lmder(residuals, jacobian, x0, ftol=ftol, xtol=xtol, gtol=gtol, max_nfev=max_nfev)


def _lmder(
    residuals: Residuals,
    jacobian: Jacobian,
    x0: FloatArray,
    *,
    ftol: float,
    xtol: float,
    gtol: float,
    max_nfev: int,
) -> LmderBatch:
    """:func:`lmder_batch`, under its ``np.errstate``."""
    n, d = np.shape(x0)
    x = np.array(x0, dtype=float).reshape(n, d)
    everyone = np.arange(n)
    fvec = np.array(residuals(everyone, x))
    fnorm, odd = enorm_rows(fvec)
    latest = _LatestResiduals(fvec)
    nfev = np.ones(n, dtype=np.int64)
    info = np.zeros(n, dtype=np.int64)
    par = np.zeros(n)
    first = np.ones(n, dtype=bool)  # MINPACK's iter == 1: no step accepted yet
    delta = np.zeros(n)
    xnorm = np.zeros(n)
    gnorm = np.zeros(n)
    diag = np.zeros((n, d))
    need_jacobian = np.ones(n, dtype=bool)
    stored_r = np.zeros((d, d, n))
    stored_q = np.zeros((d, n))
    stored_perm = np.zeros((d, n), dtype=np.int64)
    active = ~odd
    while True:
        idx = np.flatnonzero(active & need_jacobian)
        if idx.size:
            factor = _Factor(list(jacobian(idx, x[idx])), latest.take(idx))
            stored_r[..., idx], stored_q[:, idx] = factor.r, factor.q
            stored_perm[:, idx] = factor.perm
            acnorm = factor.acnorm
            odd[idx] |= factor.odd
            init = idx[first[idx]]
            pos = np.searchsorted(idx, init)
            d_init = np.column_stack([np.where(a[pos] == 0.0, 1.0, a[pos]) for a in acnorm])
            diag[init] = d_init
            xn, odd_x = enorm_list([d_init[:, col] * x[init, col] for col in range(d)])
            odd[init] |= odd_x
            xnorm[init] = xn
            dl = FACTOR * xn
            delta[init] = np.where(dl == 0.0, FACTOR, dl)
            fn = fnorm[idx]
            g = np.zeros(idx.size)
            r, q, perm = factor.r, factor.q, factor.perm
            for j in range(d):
                norm_j = _permuted(perm[j], acnorm)
                total = np.zeros(idx.size)
                for i in range(j + 1):
                    total = total + r[i, j] * (q[i] / fn)
                g = np.where((fn != 0.0) & (norm_j != 0.0), np.fmax(g, np.abs(total / norm_j)), g)
            gnorm[idx] = g
            info[idx] = np.where(g <= gtol, 4, info[idx])
            for col in range(d):
                diag[idx, col] = np.fmax(diag[idx, col], acnorm[col])
            need_jacobian[idx] = False
            active &= (info == 0) & ~odd
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        r, q, perm = stored_r[..., idx], stored_q[:, idx], stored_perm[:, idx]
        sx, p, odd_p = _lmpar(r, perm, q, diag[idx], delta[idx], par[idx])
        odd[idx] |= odd_p
        w = [-value for value in sx]
        xt = np.column_stack([x[idx, col] + w[col] for col in range(d)])
        pnorm, odd_n = enorm_list([diag[idx, col] * w[col] for col in range(d)])
        odd[idx] |= odd_n
        dl = np.where(first[idx], np.fmin(delta[idx], pnorm), delta[idx])
        ft = residuals(idx, xt)
        nfev[idx] += 1
        fnorm1, odd_f = enorm_rows(ft)
        odd[idx] |= odd_f
        fn = fnorm[idx]
        quotient = fnorm1 / fn
        actred = np.where(0.1 * fnorm1 < fn, 1.0 - quotient * quotient, -1.0)
        # R Pᵀ w, as lmder forms wa3
        wa3 = [np.zeros(idx.size) for _ in range(d)]
        for j in range(d):
            t = _permuted(perm[j], w)
            for i in range(j + 1):
                wa3[i] = wa3[i] + r[i, j] * t
        norm3, odd_3 = enorm_list(wa3)
        odd[idx] |= odd_3
        temp1 = norm3 / fn
        temp2 = (np.sqrt(p) * pnorm) / fn
        prered = temp1 * temp1 + temp2 * temp2 / 0.5
        dirder = -(temp1 * temp1 + temp2 * temp2)
        ratio = np.where(prered != 0.0, actred / prered, 0.0)
        low = ratio <= 0.25
        temp = np.where(actred < 0.0, (0.5 * dirder) / (dirder + 0.5 * actred), 0.5)
        temp = np.where((0.1 * fnorm1 >= fn) | (temp < 0.1), 0.1, temp)
        high = ~low & ((p == 0.0) | (ratio >= 0.75))
        dl = np.where(low, temp * np.fmin(dl, pnorm / 0.1), dl)
        p = np.where(low, p / temp, p)
        dl = np.where(high, pnorm / 0.5, dl)
        p = np.where(high, p * 0.5, p)
        delta[idx], par[idx] = dl, p
        accept = ratio >= 0.0001
        moved = idx[accept]
        x[moved] = xt[accept]
        latest.accept(moved, ft.take(np.flatnonzero(accept), axis=1))
        xn, odd_x = enorm_list([diag[moved, col] * x[moved, col] for col in range(d)])
        odd[moved] |= odd_x
        xnorm[moved] = xn
        fnorm[moved] = fnorm1[accept]
        first[moved] = False
        need_jacobian[moved] = True
        xn = xnorm[idx]
        small = (np.abs(actred) <= ftol) & (prered <= ftol) & (0.5 * ratio <= 1.0)
        code = np.where(small, 1, 0)
        code = np.where(dl <= xtol * xn, 2, code)
        code = np.where(small & (code == 2), 3, code)
        later = code == 0
        code = np.where(later & (nfev[idx] >= max_nfev), 5, code)
        tiny = (np.abs(actred) <= EPSMCH) & (prered <= EPSMCH) & (0.5 * ratio <= 1.0)
        code = np.where(later & tiny, 6, code)
        code = np.where(later & (dl <= EPSMCH * xn), 7, code)
        code = np.where(later & (gnorm[idx] <= EPSMCH), 8, code)
        info[idx] = code
        active &= (info == 0) & ~odd
    info = np.where(odd, 0, info)
    fvec = latest.all().take(latest.column, axis=1)
    return LmderBatch(x=x, fvec=fvec, info=info, nfev=nfev, odd=odd)
