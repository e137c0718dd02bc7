r"""The factor graph of :class:`estimators.gtsam_smoother.GtsamSmoother`, in GTSAM and in numpy.

One emitter variable ``X(0)`` when the emitter is static (``process_noise_mps = 0``), else one
variable ``X(t)`` per frame linked by random-walk ``BetweenFactorPoint2(X(t−1), X(t), 0,
σ = q Δt_t)``. Each frame adds ONE vectorised ``CustomFactor`` for its stacked, whitened Doppler
and range residuals ``e(s) = (h(s) − z)/σ`` with their ``(2K, 2)`` Jacobian
(:class:`estimators.frame_model.FrameModel`; a unit noise model, since the residual is already
whitened), and a diffuse ``PriorFactorPoint2`` sits on ``X(0)`` (:func:`graph_part`).

:func:`chain_fit` evaluates the same graph in numpy, the same way in batch and streaming: its
cost ``χ²``, the Laplace log evidence that weighs a hypothesis, the decrement that says whether
a point is converged, the Newton step and the marginal information of the last variable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.convergence import EstimationFailure, negative_curvature
from estimators.frame_model import FrameModel

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# the factor and the graph
# --------------------------------------------------------------------------------------------


def frame_factor(frame: FrameModel, key: int) -> Any:
    """ONE ``CustomFactor`` for a frame's stacked whitened residuals ``e(s)`` (unit noise).

    The Jacobian is set as a 2-D ``(2K, 2)`` array: GTSAM 4.3 segfaults on a 1-D one and
    accepts a wrong width silently (DEPENDENCIES §1).
    """
    import gtsam

    def error(this: Any, values: Any, jacobians: Any) -> FloatArray:
        emitter = values.atPoint2(this.keys()[0])
        if jacobians is None:
            return np.ascontiguousarray(frame.whitened_error(emitter))
        e, E = frame.whitened_error_and_jacobian(emitter)
        jacobians[0] = np.ascontiguousarray(E)
        return np.ascontiguousarray(e)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(frame.n_rows), [key], error)


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
) -> Any:
    """The factors frames ``first..stop−1`` add: frame factors, random-walk links, the prior."""
    import gtsam
    from gtsam.symbol_shorthand import X

    graph = gtsam.NonlinearFactorGraph()
    if prior_mean_m is not None:
        graph.add(
            gtsam.PriorFactorPoint2(
                X(0), np.asarray(prior_mean_m), gtsam.noiseModel.Isotropic.Sigma(2, prior_sigma_m)
            )
        )
    for t in range(first, stop):
        graph.add(frame_factor(frames[t], X(t if random_walk else 0)))
        if random_walk and t > 0:
            noise = gtsam.noiseModel.Isotropic.Sigma(2, float(step_sigmas[t - 1]))
            graph.add(gtsam.BetweenFactorPoint2(X(t - 1), X(t), np.zeros(2), noise))
    return graph


def values_of(estimates_m: ArrayLike, first: int = 0) -> Any:
    """``gtsam.Values`` with ``X(first + i) = estimates_m[i]``."""
    import gtsam
    from gtsam.symbol_shorthand import X

    values = gtsam.Values()
    for i, point in enumerate(np.asarray(estimates_m, dtype=float).reshape(-1, 2)):
        values.insert(X(first + i), np.array(point))
    return values


def marginal_covariance(compute: Any) -> FloatArray:
    """GTSAM's marginal covariance, or NaN where GTSAM finds the system indeterminate.

    GTSAM raises a bare ``RuntimeError`` ("Indeterminate linear system") when the information
    is numerically singular; whether that matters is decided by
    :func:`~estimators.mirror_hypotheses.fisher_rank` (the covariance is withheld when the data's
    information is rank-deficient, and a failure is reported otherwise).
    """
    try:
        return np.asarray(compute(), dtype=float)
    except RuntimeError:
        return np.full((2, 2), np.nan)


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
        ``−Λ⁻¹g`` (:func:`~estimators.smoother_batch.newton_polish`).
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
    Log determinant and decrements come from a block ``LDLᵀ`` elimination in order:
    ``S_0 = D_0``, ``S_t = D_t − w_t² S_{t−1}⁻¹`` and ``y_t = g_t + w_t S_{t−1}⁻¹ y_{t−1}`` give
    ``log det = Σ log det S_t`` and ``gᵀ(·)⁻¹g = Σ y_tᵀ S_t⁻¹ y_t`` (``w_t = 1/σ_t²``, the
    link's information).

    Raises :class:`EstimationFailure` when ``Λ`` is not positive definite or not finite.
    """
    estimates = np.asarray(estimates_m, dtype=float).reshape(-1, 2)
    n = len(estimates)
    variables = variable_of_frame(len(frames), random_walk)
    prior_information = 1.0 / prior_sigma_m**2
    offset = estimates[0] - np.asarray(prior_mean_m, dtype=float)
    chi2 = float(offset @ offset) * prior_information
    # every frame at once, each sample at its frame's variable
    stacked = FrameModel.stacked(frames)
    sample_variable = np.repeat(variables, [len(frame.position_m) for frame in frames])
    at_sample = estimates[sample_variable]
    e, E = stacked.whitened_error_and_jacobian_per_sample(at_sample)
    chi2 += float(e @ e)
    data_information = E.T @ E
    row_variable = np.concatenate([sample_variable, sample_variable])
    terms = stacked.curvature_terms(at_sample, e, per_sample=True)
    blocks = np.zeros((n, 2, 2))
    curvature = np.zeros((n, 2, 2))
    gradient = np.zeros((n, 2))
    for i, j in ((0, 0), (0, 1), (1, 1)):
        blocks[:, i, j] = np.bincount(row_variable, weights=E[:, i] * E[:, j], minlength=n)
        curvature[:, i, j] = np.bincount(row_variable, weights=terms[:, i, j], minlength=n)
    blocks[:, 1, 0] = blocks[:, 0, 1]
    curvature[:, 1, 0] = curvature[:, 0, 1]
    for i in (0, 1):
        gradient[:, i] = np.bincount(row_variable, weights=E[:, i] * e, minlength=n)
    blocks[0] += prior_information * np.eye(2)
    gradient[0] += prior_information * offset
    links = np.zeros(max(n - 1, 0))
    if random_walk:
        links = 1.0 / np.asarray(step_sigmas, dtype=float) ** 2
        steps = np.diff(estimates, axis=0)
        chi2 += float(np.sum(links * np.sum(steps**2, axis=1)))
        blocks[:-1] += links[:, None, None] * np.eye(2)
        blocks[1:] += links[:, None, None] * np.eye(2)
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
        + prior_information * np.eye(2),
        gauss_newton_decrement=gauss_newton,
        newton_decrement=newton,
        last_information=last_information,
        step_m=-(newton_solution if math.isfinite(newton) else gn_solution),
    )


def _block_elimination(
    blocks: FloatArray, links: FloatArray, gradient: FloatArray
) -> tuple[float, float, FloatArray, FloatArray]:
    """``(log det A, gᵀA⁻¹g, S_last, A⁻¹g)`` of the block tridiagonal ``A`` (diagonal
    ``blocks``, off-diagonal ``−w_t I``) by :func:`chain_fit`'s elimination, then back
    substitution ``x_t = S_t⁻¹(y_t + w_{t+1} x_{t+1})``. ``S_last``, the last Schur complement,
    is the marginal information of the last variable. NaN (and an infinite decrement) if ``A``
    is not positive definite. 2×2 blocks in closed form, floats: two passes over the variables.
    """
    n = len(blocks)
    failed = (math.nan, math.inf, np.full((2, 2), np.nan), np.full((n, 2), np.nan))
    schur = np.empty((n, 3))  # a, b, d of each S_t
    eliminated = np.empty((n, 2))  # y_t
    log_det = decrement = 0.0
    a, b, d = (float(x) for x in (blocks[0, 0, 0], blocks[0, 0, 1], blocks[0, 1, 1]))
    y0, y1 = float(gradient[0, 0]), float(gradient[0, 1])
    for t in range(len(blocks)):
        det = a * d - b * b
        if not (det > 0.0 and a > 0.0 and math.isfinite(det)):
            return failed
        schur[t] = a, b, d
        eliminated[t] = y0, y1
        log_det += math.log(det)
        u0, u1 = (d * y0 - b * y1) / det, (a * y1 - b * y0) / det  # S⁻¹y
        decrement += y0 * u0 + y1 * u1
        if t + 1 < len(blocks):
            w = float(links[t])
            w2 = w * w / det
            a, b, d = (
                float(blocks[t + 1, 0, 0]) - w2 * d,
                float(blocks[t + 1, 0, 1]) + w2 * b,
                float(blocks[t + 1, 1, 1]) - w2 * a,
            )
            y0, y1 = float(gradient[t + 1, 0]) + w * u0, float(gradient[t + 1, 1]) + w * u1
    solution = np.empty((n, 2))
    x0 = x1 = 0.0
    for t in range(n - 1, -1, -1):
        a, b, d = (float(v) for v in schur[t])
        w = float(links[t]) if t + 1 < n else 0.0
        r0, r1 = float(eliminated[t, 0]) + w * x0, float(eliminated[t, 1]) + w * x1
        det = a * d - b * b
        x0, x1 = (d * r0 - b * r1) / det, (a * r1 - b * r0) / det
        solution[t] = x0, x1
    last = np.array([[schur[-1, 0], schur[-1, 1]], [schur[-1, 1], schur[-1, 2]]])
    return log_det, decrement if math.isfinite(decrement) else math.inf, last, solution


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
