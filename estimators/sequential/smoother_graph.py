r"""The factor graph of :class:`estimators.sequential.gtsam_smoother.GtsamSmoother`, in GTSAM and in
numpy.

One emitter variable ``X(0)`` when the emitter is static (``process_noise_mps = 0``), else one
variable ``X(t)`` per frame linked by random-walk ``BetweenFactorPoint2(X(t−1), X(t), 0,
σ = q Δt_t)``. Each frame adds ONE vectorised ``CustomFactor`` for its stacked, whitened Doppler
and range residuals ``e(s) = (h(s) − z)/σ`` with their ``(2K, 2)`` Jacobian
(:class:`estimators.frame_model.FrameModel`; a unit noise model, since the residual is already
whitened), and a diffuse ``PriorFactorPoint2`` sits on ``X(0)`` (:func:`graph_part`).

:func:`chain_fit` evaluates the same graph in numpy, the same way in batch and streaming: its
cost ``χ²``, the Laplace log evidence that weighs a hypothesis, the decrement that says whether
a point is converged, the Newton step and the marginal information of the last variable. It
reads the data through per-variable sums (:class:`VariableSums`: ``Σe²``, ``Σ e∇e``, ``Σ ∇e∇eᵀ``,
``Σ e∇²e`` of the frames on each variable; :func:`fit_from_sums` adds the prior and the links).

**The data to third order (streaming).** Streaming keeps, for every variable, those sums about
ISAM2's linearisation point ``θ`` to third order (:class:`Expansion`): with ``δ = s − θ``,
``χ²(s) ≈ c + 2gᵀδ + δᵀHδ + ⅓T[δ,δ,δ]`` (``H``, ``T`` the exact second and third derivatives
of half the cost) and ``Λ(s) ≈ Λ + D[δ] + ½D₂[δ,δ]``. They are additive over frames, so a new
frame adds its own terms at ``θ`` and only a relinearised variable is re-expanded. The
gradient and the information they give are off by ``O(|δ|³)``: on ``paper-1m`` at
``|δ| = 1`` cm, ``8·10⁻⁸`` (whitened) and ``8·10⁻¹²`` relative.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import combinations_with_replacement
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.convergence import (
    DECREMENT_TOL,
    HALVINGS,
    NEWTON_ITERATIONS,
    NEWTON_RTOL,
    EstimationFailure,
    negative_curvature,
)
from estimators.frame_model import FrameModel
from scenarios.measurement_model import doppler_range_derivatives

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# the factor and the graph
# --------------------------------------------------------------------------------------------


def frame_factor(
    frame: FrameModel, key: int, linearised: list[Any] | None = None, index: int = 0
) -> Any:
    """ONE ``CustomFactor`` for a frame's stacked whitened residuals ``e(s)`` (unit noise).

    The variable is a ``Point2``, or a ``Point3`` with the height unknown (the frame's
    ``dimension``). The Jacobian is set as a 2-D ``(2K, d)`` array: GTSAM 4.3 segfaults on a
    1-D one and
    accepts a wrong width silently (GTSAM 4.3's Python bindings). ``linearised[index]``, if given and not
    None, holds ``(point, e, E)`` already evaluated (the streaming smoother evaluates every
    frame of a relinearised variable in one vectorised pass, :func:`expansion_terms`); it is
    used when GTSAM asks for exactly that point, and the frame is evaluated otherwise.
    """
    import gtsam

    d = frame.dimension

    def error(this: Any, values: Any, jacobians: Any) -> FloatArray:
        emitter = point_at(values, key, d)
        cached = None if linearised is None else linearised[index]
        if cached is not None and all(cached[0][i] == emitter[i] for i in range(d)):
            e, E = cached[1], cached[2]
        elif jacobians is None:
            return np.ascontiguousarray(frame.whitened_error(emitter))
        else:
            e, E = frame.whitened_error_and_jacobian(emitter)
        if jacobians is not None:
            jacobians[0] = np.ascontiguousarray(E)
        return np.ascontiguousarray(e)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(frame.n_rows), [key], error)


def point_at(values: Any, key: int, dimension: int) -> FloatArray:
    """The emitter variable ``key`` of ``values``: a ``Point2``, or a ``Point3`` in 3-D."""
    return values.atPoint3(key) if dimension == 3 else values.atPoint2(key)


def variable_of_frame(n_frames: int, random_walk: bool) -> NDArray[np.int64]:
    """The index of the emitter variable each frame measures: all 0, or one per frame."""
    return np.arange(n_frames) if random_walk else np.zeros(n_frames, dtype=np.int64)


def step_sigmas_m(frames: Sequence[FrameModel], process_noise_mps: float) -> FloatArray:
    """``q Δt_t`` between consecutive frames, shape (n_frames − 1,)."""
    times = np.array([frame.time_s for frame in frames])
    steps = process_noise_mps * np.abs(np.diff(times))
    if np.any(steps <= 0.0):
        raise ValueError(
            "time_s: with process_noise_mps > 0 consecutive frames need distinct mean times"
        )
    return steps


def graph_part(
    frames: Sequence[FrameModel],
    first: int,
    stop: int,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_mean_m: FloatArray | None,
    prior_sigma_m: float,
    linearised: list[Any] | None = None,
) -> Any:
    """The factors frames ``first..stop−1`` add: frame factors, random-walk links, the prior
    (``linearised``: the frames' evaluations the factors may read, :func:`frame_factor`)."""
    import gtsam
    from gtsam.symbol_shorthand import X

    d = frames[0].dimension
    prior = gtsam.PriorFactorPoint3 if d == 3 else gtsam.PriorFactorPoint2
    between = gtsam.BetweenFactorPoint3 if d == 3 else gtsam.BetweenFactorPoint2
    graph = gtsam.NonlinearFactorGraph()
    if prior_mean_m is not None:
        graph.add(
            prior(
                X(0), np.asarray(prior_mean_m), gtsam.noiseModel.Isotropic.Sigma(d, prior_sigma_m)
            )
        )
    for t in range(first, stop):
        graph.add(frame_factor(frames[t], X(t if random_walk else 0), linearised, t))
        if random_walk and t > 0:
            noise = gtsam.noiseModel.Isotropic.Sigma(d, float(step_sigmas[t - 1]))
            graph.add(between(X(t - 1), X(t), np.zeros(d), noise))
    return graph


def values_of(estimates_m: ArrayLike, first: int = 0) -> Any:
    """``gtsam.Values`` with ``X(first + i) = estimates_m[i]`` (rows of 2 or 3 coordinates: a
    ``Point2`` or a ``Point3``)."""
    import gtsam
    from gtsam.symbol_shorthand import X

    values = gtsam.Values()
    points = np.asarray(estimates_m, dtype=float)
    for i, point in enumerate(points.reshape(-1, points.shape[-1] if points.ndim > 1 else 2)):
        values.insert(X(first + i), np.array(point))
    return values


def marginal_covariance(compute: Any, dimension: int = 2) -> FloatArray:
    """GTSAM's marginal covariance, or NaN where GTSAM finds the system indeterminate.

    GTSAM raises a bare ``RuntimeError`` ("Indeterminate linear system") when the information
    is numerically singular; whether that matters is decided by
    :func:`~estimators.sequential.mirror_hypotheses.fisher_rank` (the covariance is withheld when
    the data's information is rank-deficient, and a failure is reported otherwise).
    """
    try:
        return np.asarray(compute(), dtype=float)
    except RuntimeError:
        return np.full((dimension, dimension), np.nan)


# --------------------------------------------------------------------------------------------
# evidence and information (numpy, the same in batch and streaming)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class ChainFit:
    """The graph's fit at a point (:func:`chain_fit`).

    Attributes
    ----------
    chi2 : float
        Sum of every squared whitened residual of the graph (frames, random-walk links, prior).
    log_evidence : float
        ``−½χ² − ½ log det Λ`` (Laplace, up to a constant shared by the hypotheses).
    decrement : float
        The smaller of the Gauss-Newton and Newton decrements over every variable (χ² units):
        the cost reduction a quadratic model still predicts (convergence, ``DECREMENT_TOL``).
    gauss_newton_decrement, newton_decrement : float
        ``gᵀΛ⁻¹g`` and ``gᵀH⁻¹g`` (``inf`` where ``H`` is not positive definite).
    last_information : (2, 2)
        The Gauss-Newton marginal information of the last variable (prior and links included):
        the inverse of the covariance GTSAM's ``Marginals`` computes.
    step_m : (n_variables, 2)
        The Newton step ``−H⁻¹g`` where ``H`` is positive definite, else the Gauss-Newton step
        ``−Λ⁻¹g`` (:func:`~estimators.sequential.smoother_batch.newton_polish`).
    data_information : (2, 2)
        ``Σ_t E_tᵀE_t`` (MATH §8), each frame at its variable.
    uniform_hessian : (2, 2)
        The exact Hessian of half the cost for one shift applied to every variable (the
        random-walk links do not see it): the 2×2 Hessian itself for a static emitter.
    """

    chi2: float
    log_evidence: float
    decrement: float
    data_information: FloatArray
    uniform_hessian: FloatArray
    gauss_newton_decrement: float
    newton_decrement: float
    last_information: FloatArray
    step_m: FloatArray

    def saddle_direction(self) -> FloatArray | None:
        """A unit direction of negative curvature of :attr:`uniform_hessian` beyond rounding
        (``SADDLE_RTOL``): the point is a saddle, not a minimum. None otherwise."""
        return negative_curvature(self.uniform_hessian)


@dataclass(frozen=True, slots=True, eq=False)
class VariableSums:
    """The frames' terms of the graph summed per emitter variable ``j``, at a point.

    Attributes
    ----------
    chi2 : (n,)
        ``Σ e_k²`` over the rows of the frames on ``j``.
    gradient : (n, 2)
        ``Σ e_k ∇e_k``: the gradient of half their cost.
    information : (n, 2, 2)
        ``Σ ∇e_k ∇e_kᵀ``: their Gauss-Newton information.
    curvature : (n, 2, 2)
        ``Σ e_k ∇²e_k``: what the exact Hessian adds to it.
    """

    chi2: FloatArray
    gradient: FloatArray
    information: FloatArray
    curvature: FloatArray


def data_sums(
    frames: Sequence[FrameModel], estimates_m: ArrayLike, *, random_walk: bool
) -> VariableSums:
    """:class:`VariableSums` of every frame evaluated at its variable (all at once), in the
    frames' ``d`` coordinates."""
    d = frames[0].dimension
    estimates = np.asarray(estimates_m, dtype=float).reshape(-1, d)
    n = len(estimates)
    variables = variable_of_frame(len(frames), random_walk)
    stacked = FrameModel.stacked(frames)
    sample_variable = np.repeat(variables, [len(frame.position_m) for frame in frames])
    at_sample = estimates[sample_variable]
    e, E = stacked.whitened_error_and_jacobian_per_sample(at_sample)
    row_variable = np.concatenate([sample_variable, sample_variable])
    terms = stacked.curvature_terms(at_sample, e, per_sample=True)
    if n == 1:
        chi2 = np.array([float(e @ e)])
    else:
        chi2 = np.bincount(row_variable, weights=e * e, minlength=n)
    information = np.zeros((n, d, d))
    curvature = np.zeros((n, d, d))
    gradient = np.zeros((n, d))
    for i, j in combinations_with_replacement(range(d), 2):
        information[:, i, j] = np.bincount(row_variable, weights=E[:, i] * E[:, j], minlength=n)
        curvature[:, i, j] = np.bincount(row_variable, weights=terms[:, i, j], minlength=n)
        information[:, j, i] = information[:, i, j]
        curvature[:, j, i] = curvature[:, i, j]
    for i in range(d):
        gradient[:, i] = np.bincount(row_variable, weights=E[:, i] * e, minlength=n)
    return VariableSums(chi2, gradient, information, curvature)


def chain_fit(
    frames: Sequence[FrameModel],
    estimates_m: ArrayLike,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_mean_m: ArrayLike,
    prior_sigma_m: float,
) -> ChainFit:
    r"""Cost, Laplace log evidence and decrement of one hypothesis's graph.

    .. math::

        \log Z \approx -\tfrac12\,\chi^2(\hat s) - \tfrac12\log\det\Lambda(\hat s),
        \qquad \delta = \min\big(g^\top \Lambda^{-1} g,\ g^\top H^{-1} g\big)

    with ``χ²`` the sum of every squared whitened residual of the graph (frames, random-walk
    links, prior), ``g`` its half-gradient, ``Λ`` its Gauss-Newton information, block
    tridiagonal over the variables, and ``H = Λ + Σ e_k ∇²e_k`` the exact Hessian (its term
    used only when positive definite; :func:`estimators.convergence.stationarity_decrement`).
    The frames are evaluated exactly (:func:`data_sums`); :func:`fit_from_sums` does the rest.

    Raises :class:`EstimationFailure` when ``Λ`` is not positive definite or not finite.
    """
    return fit_from_sums(
        data_sums(frames, estimates_m, random_walk=random_walk),
        estimates_m,
        random_walk=random_walk,
        step_sigmas=step_sigmas,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=prior_sigma_m,
    )


def fit_from_sums(
    sums: VariableSums,
    estimates_m: ArrayLike,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_mean_m: ArrayLike,
    prior_sigma_m: float,
) -> ChainFit:
    """:func:`chain_fit` from the frames' :class:`VariableSums` at ``estimates_m``: the prior
    and the random-walk links (exactly quadratic) are added here. Log determinant and
    decrements come from a block ``LDLᵀ`` elimination in order: ``S_0 = D_0``,
    ``S_t = D_t − w_t² S_{t−1}⁻¹`` and ``y_t = g_t + w_t S_{t−1}⁻¹ y_{t−1}`` give
    ``log det = Σ log det S_t`` and ``gᵀ(·)⁻¹g = Σ y_tᵀ S_t⁻¹ y_t`` (``w_t = 1/σ_t²``, the
    link's information)."""
    d = sums.gradient.shape[-1]
    estimates = np.asarray(estimates_m, dtype=float).reshape(-1, d)
    n = len(estimates)
    prior_information = 1.0 / prior_sigma_m**2
    offset = estimates[0] - np.asarray(prior_mean_m, dtype=float)
    chi2 = float(offset @ offset) * prior_information + float(np.sum(sums.chi2))
    data_information = np.sum(sums.information, axis=0)
    blocks = np.array(sums.information, dtype=float)
    gradient = np.array(sums.gradient, dtype=float)
    curvature = sums.curvature
    blocks[0] += prior_information * np.eye(d)
    gradient[0] += prior_information * offset
    links = np.zeros(max(n - 1, 0))
    if random_walk:
        links = 1.0 / np.asarray(step_sigmas, dtype=float)[: n - 1] ** 2
        steps = np.diff(estimates, axis=0)
        chi2 += float(np.sum(links * np.sum(steps**2, axis=1)))
        blocks[:-1] += links[:, None, None] * np.eye(d)
        blocks[1:] += links[:, None, None] * np.eye(d)
        gradient[1:] += links[:, None] * steps
        gradient[:-1] -= links[:, None] * steps
    log_det, gauss_newton, last_information, gn_solution = _block_elimination(
        blocks, links, gradient
    )
    if not math.isfinite(log_det):
        raise EstimationFailure("the graph's information is not positive definite at the estimate")
    _, newton, _, newton_solution = _block_elimination(blocks + curvature, links, gradient)
    return ChainFit(
        chi2=chi2,
        log_evidence=float(-0.5 * chi2 - 0.5 * log_det),
        decrement=min(gauss_newton, newton),
        data_information=data_information,
        uniform_hessian=data_information
        + np.sum(curvature, axis=0)
        + prior_information * np.eye(d),
        gauss_newton_decrement=gauss_newton,
        newton_decrement=newton,
        last_information=last_information,
        step_m=-(newton_solution if math.isfinite(newton) else gn_solution),
    )


def _block_elimination(
    blocks: FloatArray, links: FloatArray, gradient: FloatArray
) -> tuple[float, float, FloatArray, FloatArray]:
    """``(log det A, gᵀA⁻¹g, S_last, A⁻¹g)`` of the block tridiagonal ``A`` (diagonal
    ``blocks``, off-diagonal ``−w_t I``) by :func:`fit_from_sums`'s elimination, then back
    substitution ``x_t = S_t⁻¹(y_t + w_{t+1} x_{t+1})``. ``S_last``, the last Schur complement,
    is the marginal information of the last variable. NaN (and an infinite decrement) if ``A``
    is not positive definite. 2×2 blocks in closed form, on Python floats: two passes over the
    variables. 3×3 blocks (the height unknown) by :func:`_block_elimination_general`.
    """
    n = len(blocks)
    if np.shape(blocks)[-1] != 2:
        return _block_elimination_general(blocks, links, gradient)
    failed = (math.nan, math.inf, np.full((2, 2), np.nan), np.full((n, 2), np.nan))
    diagonal = np.asarray(blocks, dtype=float).reshape(n, 4)[:, [0, 1, 3]].tolist()
    weights = [*np.asarray(links, dtype=float).tolist(), 0.0]
    rhs = np.asarray(gradient, dtype=float).tolist()
    schur: list[tuple[float, float, float]] = []  # a, b, d of each S_t
    eliminated: list[tuple[float, float]] = []  # y_t
    log_det = decrement = 0.0
    a, b, d = diagonal[0]
    y0, y1 = rhs[0]
    for t in range(n):
        det = a * d - b * b
        if not (det > 0.0 and a > 0.0 and math.isfinite(det)):
            return failed
        schur.append((a, b, d))
        eliminated.append((y0, y1))
        log_det += math.log(det)
        u0, u1 = (d * y0 - b * y1) / det, (a * y1 - b * y0) / det  # S⁻¹y
        decrement += y0 * u0 + y1 * u1
        if t + 1 < n:
            w = weights[t]
            w2 = w * w / det
            next_a, next_b, next_d = diagonal[t + 1]
            a, b, d = next_a - w2 * d, next_b + w2 * b, next_d - w2 * a
            y0, y1 = rhs[t + 1][0] + w * u0, rhs[t + 1][1] + w * u1
    solution = [(0.0, 0.0)] * n
    x0 = x1 = 0.0
    for t in range(n - 1, -1, -1):
        a, b, d = schur[t]
        w = weights[t] if t + 1 < n else 0.0
        r0, r1 = eliminated[t][0] + w * x0, eliminated[t][1] + w * x1
        det = a * d - b * b
        x0, x1 = (d * r0 - b * r1) / det, (a * r1 - b * r0) / det
        solution[t] = (x0, x1)
    a, b, d = schur[-1]
    last = np.array([[a, b], [b, d]])
    return (
        log_det,
        decrement if math.isfinite(decrement) else math.inf,
        last,
        np.array(solution, dtype=float).reshape(n, 2),
    )


def _block_elimination_general(
    blocks: FloatArray, links: FloatArray, gradient: FloatArray
) -> tuple[float, float, FloatArray, FloatArray]:
    """:func:`_block_elimination` for ``d × d`` blocks, by Cholesky factors: the same
    recursion ``S_t = D_t − w_t² S_{t−1}⁻¹``, ``y_t = g_t + w_t S_{t−1}⁻¹ y_{t−1}``, back
    substitution ``x_t = S_t⁻¹(y_t + w_{t+1} x_{t+1})``."""
    n, d = len(blocks), np.shape(blocks)[-1]
    failed = (math.nan, math.inf, np.full((d, d), np.nan), np.full((n, d), np.nan))
    weights = [*np.asarray(links, dtype=float).tolist(), 0.0]
    rhs = np.asarray(gradient, dtype=float)
    schur, eliminated = [], []
    log_det = decrement = 0.0
    S, y = np.array(blocks[0], dtype=float), rhs[0].copy()
    for t in range(n):
        try:
            factor = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return failed
        if not np.all(np.isfinite(factor)):
            return failed
        inverse = np.linalg.inv(S)
        schur.append((S, inverse))
        eliminated.append(y)
        log_det += 2.0 * float(np.sum(np.log(np.diag(factor))))
        u = inverse @ y
        decrement += float(y @ u)
        if t + 1 < n:
            w = weights[t]
            S = blocks[t + 1] - w * w * inverse
            y = rhs[t + 1] + w * u
    solution = np.zeros((n, d))
    x = np.zeros(d)
    for t in range(n - 1, -1, -1):
        w = weights[t] if t + 1 < n else 0.0
        x = schur[t][1] @ (eliminated[t] + w * x)
        solution[t] = x
    return (
        log_det,
        decrement if math.isfinite(decrement) else math.inf,
        np.array(schur[-1][0]),
        solution,
    )


def chain_log_evidence(
    frames: Sequence[FrameModel],
    estimates_m: ArrayLike,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_mean_m: ArrayLike,
    prior_sigma_m: float,
) -> tuple[float, FloatArray]:
    """``(log_evidence, data_information)`` of :func:`chain_fit`: the hypothesis's Laplace
    weight and the data's Fisher information (its rank says whether the data determine the
    emitter)."""
    fit = chain_fit(
        frames,
        estimates_m,
        random_walk=random_walk,
        step_sigmas=step_sigmas,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=prior_sigma_m,
    )
    return fit.log_evidence, fit.data_information


def newton_descent(
    fit_of: Callable[[FloatArray], ChainFit],
    estimates_m: FloatArray,
    fit_now: ChainFit | None = None,
    *,
    tolerance: float = NEWTON_RTOL * DECREMENT_TOL,
    step_tolerance_m: float = 0.0,
    halvings: int = HALVINGS,
) -> tuple[FloatArray, ChainFit, int, bool]:
    """Newton's method on a graph's fit (:attr:`ChainFit.step_m`, halved while the cost rises)
    until the decrement is at most ``tolerance`` or, with ``step_tolerance_m``, until the step
    is shorter than that in every coordinate (a cost then counts as risen only beyond its
    rounding). Returns ``(estimates, fit, iterations, stalled)``; ``stalled`` when no shorter
    step lowered the cost."""
    estimates = np.array(estimates_m, dtype=float)
    if fit_now is None:
        fit_now = fit_of(estimates)
    iterations = 0
    while iterations < NEWTON_ITERATIONS:
        step = fit_now.step_m
        if step_tolerance_m > 0.0:
            if not np.max(np.abs(step)) >= step_tolerance_m:
                break
        elif not fit_now.decrement > tolerance:
            break
        slack = 8.0 * np.finfo(float).eps * abs(fit_now.chi2) if step_tolerance_m > 0.0 else 0.0
        iterations += 1
        for _ in range(halvings):
            trial = estimates + step
            try:
                trial_fit = fit_of(trial)
            except EstimationFailure:
                trial_fit = None
            if trial_fit is not None and trial_fit.chi2 <= fit_now.chi2 + slack:
                break
            step = 0.5 * step
        else:
            return estimates, fit_now, iterations, True
        estimates, fit_now = trial, trial_fit
    return estimates, fit_now, iterations, False


# --------------------------------------------------------------------------------------------
# the data to third order about a linearisation point (streaming)
# --------------------------------------------------------------------------------------------

N_TERMS = 43
"""Columns of :func:`expansion_terms`: ``Σe²`` (1), ``g`` (2), ``H`` (4), ``T`` (8), ``Λ`` (4),
``D`` (8), ``D₂`` (16), full tensors flattened."""


def _combination_matrix() -> FloatArray:
    """``(100, N_TERMS)``: every term of :class:`Expansion` as a sum of entries of the Gram
    matrix ``Σ v vᵀ`` of a row's ``v = [e, ∇e (x, y), ∇²e (xx, xy, yy), ∇³e (xxx, xxy, xyy,
    yyy)]`` (:func:`expansion_terms`)."""

    def e2(*ab: int) -> int:  # column of ∇²e_ab
        return 3 + sum(ab)

    def e3(*abc: int) -> int:  # column of ∇³e_abc
        return 6 + sum(abc)

    columns: list[list[tuple[int, int]]] = [[(0, 0)]]
    pairs = [(a, b) for a in (0, 1) for b in (0, 1)]
    triples = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    columns += [[(0, 1 + a)] for a in (0, 1)]
    columns += [[(1 + a, 1 + b), (0, e2(a, b))] for a, b in pairs]
    columns += [
        [(e2(a, b), 1 + c), (e2(a, c), 1 + b), (e2(b, c), 1 + a), (0, e3(a, b, c))]
        for a, b, c in triples
    ]
    columns += [[(1 + a, 1 + b)] for a, b in pairs]
    columns += [[(e2(a, c), 1 + b), (1 + a, e2(b, c))] for a, b, c in triples]
    columns += [
        [(e3(a, c, d), 1 + b), (e2(a, c), e2(b, d)), (e2(a, d), e2(b, c)), (1 + a, e3(b, c, d))]
        for a, b in pairs
        for c, d in pairs
    ]
    matrix = np.zeros((100, N_TERMS))
    for column, entries in enumerate(columns):
        for i, j in entries:
            matrix[10 * i + j, column] += 1.0
    return matrix


_GRAM_TO_TERMS = _combination_matrix()


def _whitened_derivatives(
    frames: Sequence[FrameModel], points_m: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    r"""Every row of ``frames``, frame ``i`` at ``points_m[i]`` (Doppler rows of all the frames,
    then their range rows): ``v = [e, ∇e, ∇²e, ∇³e]`` (unique components, 10 columns, from
    :func:`scenarios.measurement_model.doppler_range_derivatives`), and ``e``, ``∇e`` as
    :class:`~estimators.frame_model.FrameModel` computes them (the same function, so a cached
    linearisation equals a fresh one).
    """
    points = np.asarray(points_m, dtype=float).reshape(-1, 2)
    if len(frames) == 1:  # one new frame per update: no stacking
        frame = frames[0]
        measured, sigma = frame.measured, frame.sigma
        doppler, ranges = frame.derivatives(points[0], 3)
    else:
        counts = [len(frame.position_m) for frame in frames]
        pairs = list(zip(frames, counts, strict=True))
        measured = np.concatenate(
            [f.measured[:k] for f, k in pairs] + [f.measured[k:] for f, k in pairs]
        )
        sigma = np.concatenate([f.sigma[:k] for f, k in pairs] + [f.sigma[k:] for f, k in pairs])
        doppler, ranges = doppler_range_derivatives(  # one emitter per sample: (K, 1, ·)
            np.concatenate([frame.position_m for frame in frames])[:, None, :],
            np.concatenate([frame.velocity_mps for frame in frames])[:, None, :],
            np.repeat(points, counts, axis=0),
            np.repeat([frame.gamma_per_m for frame in frames], counts)[:, None],
            np.repeat([frame.emitter_height_m for frame in frames], counts)[:, None],
            order=3,
        )
        doppler, ranges = doppler[:, 0], ranges[:, 0]
    derivatives = np.concatenate([doppler, ranges])
    e = (derivatives[:, 0] - measured) / sigma
    rows = derivatives / sigma[:, None]
    rows[:, 0] = e
    return rows, e, rows[:, 1:3]


def expansion_terms(
    frames: Sequence[FrameModel], points_m: ArrayLike
) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray, FloatArray]]]:
    """Each frame's third-order terms at its point (:class:`Expansion`), shape
    ``(n_frames, N_TERMS)``, and its ``(point, e, E)`` for :func:`frame_factor`."""
    points = np.asarray(points_m, dtype=float).reshape(-1, 2)
    rows, e, e_jacobian = _whitened_derivatives(frames, points)
    counts = [len(frame.position_m) for frame in frames]
    n_samples = int(np.sum(counts))
    if len(frames) == 1:
        gram = (rows.T @ rows).reshape(1, 100)
    else:
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        outer = (rows[:, :, None] * rows[:, None, :]).reshape(-1, 100)
        gram = np.add.reduceat(outer[:n_samples], starts) + np.add.reduceat(
            outer[n_samples:], starts
        )
    linearised = []
    start = 0
    for frame_index, k in enumerate(counts):
        doppler, ranges = slice(start, start + k), slice(n_samples + start, n_samples + start + k)
        linearised.append(
            (
                points[frame_index].copy(),
                np.concatenate([e[doppler], e[ranges]]),
                np.concatenate([e_jacobian[doppler], e_jacobian[ranges]]),
            )
        )
        start += k
    return gram @ _GRAM_TO_TERMS, linearised


@dataclass(eq=False, slots=True)
class Expansion:
    r"""The frames' terms of every variable to third order about its point ``θ_j`` (module
    text): ``terms[j]`` holds ``c = Σe²``, ``g``, ``H`` and ``T`` (the first three derivatives
    of half the cost), ``Λ = Σ∇e∇eᵀ`` and its first two derivatives ``D``, ``D₂``, all at
    ``θ_j`` and summed over the frames on ``j`` (:func:`expansion_terms`).
    """

    theta_m: FloatArray
    terms: FloatArray

    def at(self, estimates_m: ArrayLike) -> VariableSums:
        r""":class:`VariableSums` at ``s = θ + δ`` from the expansion:
        ``χ² = c + 2gᵀδ + δᵀHδ + ⅓T[δ,δ,δ]``, ``∇(½χ²) = g + Hδ + ½T[δ,δ]``,
        ``∇²(½χ²) = H + T[δ]``, ``Λ = Λ_θ + D[δ] + ½D₂[δ,δ]``; the curvature is
        ``∇²(½χ²) − Λ``."""
        delta = np.asarray(estimates_m, dtype=float).reshape(-1, 2) - self.theta_m
        n = len(delta)
        terms = self.terms
        c, g = terms[:, 0], terms[:, 1:3]
        h, t = terms[:, 3:7].reshape(n, 2, 2), terms[:, 7:15].reshape(n, 2, 2, 2)
        lam, d = terms[:, 15:19].reshape(n, 2, 2), terms[:, 19:27].reshape(n, 2, 2, 2)
        d2 = terms[:, 27:43].reshape(n, 2, 2, 2, 2)
        t_delta = np.einsum("nabc,nc->nab", t, delta)
        t_delta2 = np.einsum("nab,nb->na", t_delta, delta)
        h_delta = np.einsum("nab,nb->na", h, delta)
        hessian = h + t_delta
        information = (
            lam
            + np.einsum("nabc,nc->nab", d, delta)
            + 0.5 * np.einsum("nabcd,nc,nd->nab", d2, delta, delta)
        )
        chi2 = c + np.einsum("na,na->n", 2.0 * g + h_delta + t_delta2 / 3.0, delta)
        return VariableSums(
            chi2=chi2,
            gradient=g + h_delta + 0.5 * t_delta2,
            information=information,
            curvature=hessian - information,
        )
