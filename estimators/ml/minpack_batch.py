r"""MINPACK's Levenberg-Marquardt for many two-unknown least-squares problems at once.

``lmder`` of MINPACK (More 1978; ``x_scale="jac"``, ``factor=100``, the method
``scipy.optimize.least_squares(method="lm")`` calls): QR with column pivoting of the Jacobian
(``qrfac``), the Levenberg-Marquardt parameter by Newton's method on the trust-region equation
(``lmpar``, at most 10 iterations), the damped system by Givens rotations (``qrsolv``), and the
step bound, acceptance and the ``ftol``/``xtol``/``gtol`` tests, with the problems along the
first axis of every array: two unknowns make every matrix 2 × 2 and every loop of ``lmpar`` and
``qrsolv`` a fixed sequence of elementwise operations. Residuals are kept rows first,
``(m, P)``. This is the reference solver of ``ml`` (one trial is a batch of one); scipy's
``least_squares`` is its cross-check in the tests, at a tolerance. Norms are plain
``√Σ v²`` (MINPACK's ``enorm`` scales only components below ``3.8e-20`` or above
``1.3e19 / m``, which no whitened residual reaches); a problem whose residuals or Jacobian turn
non-finite stops there (``info`` 0).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

Residuals = Callable[[IntArray, FloatArray], FloatArray]
"""``(problems (k,), points (k, 2)) -> residuals (m, k)``."""
Jacobian = Callable[[IntArray, FloatArray], tuple[FloatArray, FloatArray]]
"""``(problems (k,), points (k, 2)) -> (∂e/∂x₁, ∂e/∂x₂)``, each ``(m, k)``."""

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


def enorm2(a: FloatArray, b: FloatArray) -> tuple[FloatArray, BoolArray]:
    """The norm of the 2-vectors ``(a, b)``, and where it is not finite."""
    norm = np.sqrt(a * a + b * b)
    return norm, ~np.isfinite(norm)


def column_dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """``Σ_i a[i, j] b[i, j]`` for each column ``j`` of two ``(m, k)`` arrays."""
    return column_sums(a * b)


@dataclass(frozen=True, slots=True, eq=False)
class LmderBatch:
    """Where ``lmder`` ended for each problem.

    Attributes
    ----------
    x : (P, 2)
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


def _pick(flag: BoolArray, if_true: FloatArray, if_false: FloatArray) -> FloatArray:
    return np.where(flag, if_true, if_false)


class _Factor:
    """``qrfac`` and the ``Qᵀf`` of ``lmder`` for some problems: the pivoted ``R``, ``Qᵀf``.

    Columns ``c0, c1`` of the Jacobian and the residuals ``fvec`` are ``(m, k)``."""

    def __init__(self, c0: FloatArray, c1: FloatArray, fvec: FloatArray) -> None:
        norm0, odd0 = enorm_rows(c0)
        norm1, odd1 = enorm_rows(c1)
        self.acnorm = (norm0, norm1)
        pivot = norm1 > norm0
        self.pivot = pivot
        a0 = _pick(pivot, c1, c0)
        a1 = _pick(pivot, c0, c1)
        ajnorm = _pick(pivot, norm1, norm0)
        self.odd = odd0 | odd1
        safe = np.where(ajnorm == 0.0, 1.0, ajnorm)
        safe = np.where(a0[0] < 0.0, -safe, safe)
        a0 = a0 / safe
        a0[0] = a0[0] + 1.0
        temp = column_dot(a0, a1) / a0[0]
        a1 = a1 - temp * a0
        self.r00 = -safe
        self.r01 = a1[0].copy()
        tail = a1[1:]
        ajnorm1, odd2 = enorm_rows(tail)
        self.odd |= odd2
        full = ajnorm1 != 0.0
        signed = np.where(tail[0] < 0.0, -ajnorm1, ajnorm1)
        signed = np.where(full, signed, 1.0)
        tail = tail / signed
        tail[0] = tail[0] + 1.0
        self.r11 = np.where(full, -signed, -ajnorm1)
        # Qᵀf with the Householder vectors, as lmder forms qtf
        temp = -column_dot(a0, fvec) / a0[0]
        work = fvec + a0 * temp
        self.q0 = work[0].copy()
        rest = work[1:]
        temp = -column_dot(tail, rest) / tail[0]
        rest = rest + tail * temp
        self.q1 = np.where(full, rest[0], work[1])


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
    return _pick(use_cot, cos_a, cos_b), _pick(use_cot, sin_a, sin_b)


def _qrsolv(
    r00: FloatArray,
    r01: FloatArray,
    r11: FloatArray,
    pivot: BoolArray,
    d0: FloatArray,
    d1: FloatArray,
    q0: FloatArray,
    q1: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, BoolArray]:
    """``qrsolv`` for n = 2: ``x`` (original order), ``sdiag`` and the rotated ``r₁₀``."""
    dp0 = _pick(pivot, d1, d0)
    dp1 = _pick(pivot, d0, d1)
    wa0, wa1 = q0, q1
    r10 = r01
    # column 0: the diagonal entry dp0 against r00, then what it leaves against r11
    s0, s1, qtbpj = dp0, np.zeros_like(dp0), np.zeros_like(dp0)
    cs, sn = _givens(r00, s0)
    rot00 = r00 * cs
    rot00 = rot00 + sn * s0
    temp = cs * wa0 + sn * qtbpj
    qtbpj = -sn * wa0 + cs * qtbpj
    wa0 = temp
    temp = cs * r10 + sn * s1
    s1 = -sn * r10 + cs * s1
    r10 = temp
    more = s1 != 0.0
    cs, sn = _givens(r11, s1)
    rot11 = r11 * cs
    rot11 = rot11 + sn * s1
    temp = cs * wa1 + sn * qtbpj
    rot11 = _pick(more, rot11, r11)
    wa1 = _pick(more, temp, wa1)
    sdiag0 = rot00
    # column 1: the diagonal entry dp1 against the rotated r11
    zero = np.zeros_like(dp1)
    cs, sn = _givens(rot11, dp1)
    last = rot11 * cs
    last = last + sn * dp1
    wa1 = cs * wa1 + sn * zero
    sdiag1 = last
    odd = ~np.isfinite(sdiag0) | ~np.isfinite(sdiag1)
    wa1 = (wa1 - 0.0) / sdiag1
    wa0 = (wa0 - (0.0 + r10 * wa1)) / sdiag0
    return _pick(pivot, wa1, wa0), _pick(pivot, wa0, wa1), sdiag0, sdiag1, r10, odd


def _lmpar(
    factors: dict[str, NDArray],
    diag: FloatArray,
    delta: FloatArray,
    par: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """``lmpar`` from the pivoted ``R`` and ``Qᵀf`` in ``factors``: the solution ``x`` (original
    order; the step is ``−x``), the parameter, and where it was odd."""
    r00, r01, r11 = factors["r00"], factors["r01"], factors["r11"]
    q0, q1, pivot = factors["q0"], factors["q1"], factors["pivot"]
    d0, d1 = diag[:, 0], diag[:, 1]
    dp0 = _pick(pivot, d1, d0)
    dp1 = _pick(pivot, d0, d1)
    full = r11 != 0.0
    w1 = np.where(full, q1 / r11, 0.0)
    w0 = np.where(full, (q0 - r01 * w1) / r00, q0 / r00)
    x0 = _pick(pivot, w1, w0)
    x1 = _pick(pivot, w0, w1)
    e0, e1 = d0 * x0, d1 * x1
    dxnorm, odd = enorm2(e0, e1)
    fp = dxnorm - delta
    newton = ~(fp <= 0.1 * delta)
    par = np.where(newton, par, 0.0)
    idx = np.flatnonzero(newton)
    if idx.size == 0:
        return x0, x1, par, odd
    # lower bound parl (zero without full rank), upper bound paru
    r00, r01, r11, q0, q1 = r00[idx], r01[idx], r11[idx], q0[idx], q1[idx]
    pv, full_i = pivot[idx], full[idx]
    dd0, dd1, dp0i, dp1i = d0[idx], d1[idx], dp0[idx], dp1[idx]
    dx, fpi, dl = dxnorm[idx], fp[idx], delta[idx]
    ep0 = _pick(pv, e1[idx], e0[idx])
    ep1 = _pick(pv, e0[idx], e1[idx])
    v0 = dp0i * (ep0 / dx)
    v1 = dp1i * (ep1 / dx)
    v0 = (v0 - 0.0) / r00
    v1 = (v1 - (0.0 + r01 * v0)) / r11
    temp, odd_t = enorm2(v0, v1)
    parl = np.where(full_i, ((fpi / dl) / temp) / temp, 0.0)
    g0 = (0.0 + r00 * q0) / dp0i
    g1 = ((0.0 + r01 * q0) + r11 * q1) / dp1i
    gnorm, odd_g = enorm2(g0, g1)
    paru = gnorm / dl
    paru = np.where(paru == 0.0, DWARF / np.fmin(dl, 0.1), paru)
    p = np.fmin(np.fmax(par[idx], parl), paru)
    p = np.where(p == 0.0, gnorm / dx, p)
    bad = (odd_t & full_i) | odd_g
    out0, out1, outp = x0[idx].copy(), x1[idx].copy(), p.copy()
    # Newton's iteration on ‖D x(par)‖ = Δ, each problem until its own exit
    live = np.arange(idx.size)
    for iteration in range(1, LMPAR_ITERATIONS + 1):
        p_l = p[live]
        p_l = np.where(p_l == 0.0, np.fmax(DWARF, paru[live] * 0.001), p_l)
        root = np.sqrt(p_l)
        a0, a1, s0, s1, r10, odd_q = _qrsolv(
            r00[live],
            r01[live],
            r11[live],
            pv[live],
            root * dd0[live],
            root * dd1[live],
            q0[live],
            q1[live],
        )
        e0l, e1l = dd0[live] * a0, dd1[live] * a1
        dxl, odd_d = enorm2(e0l, e1l)
        bad[live] |= odd_q | odd_d
        old = fpi[live]
        fpl = dxl - dl[live]
        out0[live], out1[live], outp[live] = a0, a1, p_l
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
        pv_l = pv[live]
        e0l, e1l, dxl = e0l[keep], e1l[keep], dxl[keep]
        s0, s1, r10 = s0[keep], s1[keep], r10[keep]
        u0 = dp0i[live] * (_pick(pv_l, e1l, e0l) / dxl)
        u1 = dp1i[live] * (_pick(pv_l, e0l, e1l) / dxl)
        u0 = u0 / s0
        u1 = u1 - r10 * u0
        u1 = u1 / s1
        temp, odd_u = enorm2(u0, u1)
        parc = ((fpl / dl[live]) / temp) / temp
        bad[live] |= odd_u
        pl = parl[live]
        pu = paru[live]
        parl[live] = np.where(fpl > 0.0, np.fmax(pl, p_l), pl)
        paru[live] = np.where(fpl < 0.0, np.fmin(pu, p_l), pu)
        p[live] = np.fmax(parl[live], p_l + parc)
    x0[idx], x1[idx], par[idx] = out0, out1, outp
    odd[idx] |= bad
    return x0, x1, par, odd


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
    n = len(x0)
    x = np.array(x0, dtype=float).reshape(n, 2)
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
    diag = np.zeros((n, 2))
    need_jacobian = np.ones(n, dtype=bool)
    names = ("r00", "r01", "r11", "q0", "q1", "pivot")
    stored = {name: np.zeros(n, dtype=bool if name == "pivot" else float) for name in names}
    active = ~odd
    while True:
        idx = np.flatnonzero(active & need_jacobian)
        if idx.size:
            factor = _Factor(*jacobian(idx, x[idx]), latest.take(idx))
            for name in names:
                stored[name][idx] = getattr(factor, name)
            acn0, acn1 = factor.acnorm
            odd[idx] |= factor.odd
            init = idx[first[idx]]
            pos = np.searchsorted(idx, init)
            d_init = np.column_stack(
                [
                    np.where(acn0[pos] == 0.0, 1.0, acn0[pos]),
                    np.where(acn1[pos] == 0.0, 1.0, acn1[pos]),
                ]
            )
            diag[init] = d_init
            xn, odd_x = enorm2(d_init[:, 0] * x[init, 0], d_init[:, 1] * x[init, 1])
            odd[init] |= odd_x
            xnorm[init] = xn
            dl = FACTOR * xn
            delta[init] = np.where(dl == 0.0, FACTOR, dl)
            fn = fnorm[idx]
            g = np.zeros(idx.size)
            r00, r01, r11 = factor.r00, factor.r01, factor.r11
            q0, q1, pivot = factor.q0, factor.q1, factor.pivot
            l0 = _pick(pivot, acn1, acn0)
            l1 = _pick(pivot, acn0, acn1)
            s0 = 0.0 + r00 * (q0 / fn)
            s1 = (0.0 + r01 * (q0 / fn)) + r11 * (q1 / fn)
            g = np.where((fn != 0.0) & (l0 != 0.0), np.fmax(g, np.abs(s0 / l0)), g)
            g = np.where((fn != 0.0) & (l1 != 0.0), np.fmax(g, np.abs(s1 / l1)), g)
            gnorm[idx] = g
            info[idx] = np.where(g <= gtol, 4, info[idx])
            diag[idx, 0] = np.fmax(diag[idx, 0], acn0)
            diag[idx, 1] = np.fmax(diag[idx, 1], acn1)
            need_jacobian[idx] = False
            active &= (info == 0) & ~odd
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        factors = {name: stored[name][idx] for name in names}
        sx0, sx1, p, odd_p = _lmpar(factors, diag[idx], delta[idx], par[idx])
        odd[idx] |= odd_p
        w0, w1 = -sx0, -sx1
        xt = np.column_stack([x[idx, 0] + w0, x[idx, 1] + w1])
        pnorm, odd_n = enorm2(diag[idx, 0] * w0, diag[idx, 1] * w1)
        odd[idx] |= odd_n
        dl = np.where(first[idx], np.fmin(delta[idx], pnorm), delta[idx])
        ft = residuals(idx, xt)
        nfev[idx] += 1
        fnorm1, odd_f = enorm_rows(ft)
        odd[idx] |= odd_f
        fn = fnorm[idx]
        quotient = fnorm1 / fn
        actred = np.where(0.1 * fnorm1 < fn, 1.0 - quotient * quotient, -1.0)
        pivot = factors["pivot"]
        t0 = _pick(pivot, w1, w0)
        t1 = _pick(pivot, w0, w1)
        wa30 = (0.0 + factors["r00"] * t0) + factors["r01"] * t1
        wa31 = 0.0 + factors["r11"] * t1
        norm3, odd_3 = enorm2(wa30, wa31)
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
        xn, odd_x = enorm2(diag[moved, 0] * x[moved, 0], diag[moved, 1] * x[moved, 1])
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
