r"""The graph of the GTSAM smoother with nuisance variables, in GTSAM and in numpy (MATH §8, §15).

The factors of :mod:`estimators.sequential.smoother_nuisance`: one ``CustomFactor`` per frame on
``[X(t), N(0)]`` (:func:`nuisance_factor`; the frames on ``X(0)`` of a static emitter stacked into
one), the emitter variables ``X(t)`` as in
:mod:`estimators.sequential.smoother_graph` and one ``gtsam`` vector ``N(0)`` holding the unknown
nuisance parameters in the physical state of :mod:`estimators.sequential.nuisance_states` (δ in Hz,
then ``β = c b`` in metres), with diffuse priors on ``X(0)`` and ``N(0)`` and random-walk links
(:func:`nuisance_graph`). :func:`nuisance_fit` evaluates the same graph in numpy (dense algebra
over its ``dV + n_u`` unknowns, ``d = 3`` with the height unknown): cost, decrements, Laplace
evidence, covariance, the data's information about the position with the nuisance eliminated
(MATH §15) and the Hessian that says whether a stationary point is a saddle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import EstimationFailure, negative_curvature
from estimators.sequential.nuisance_states import (
    NuisanceFrame,
    position_information,
    stacked_frames,
)
from estimators.sequential.smoother_graph import point_at

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# the factor and the graph
# --------------------------------------------------------------------------------------------


def nuisance_factor(frame: NuisanceFrame, position_key: int, nuisance_key: int) -> Any:
    """ONE ``CustomFactor`` on ``[position_key, nuisance_key]`` for a frame's stacked whitened
    residuals (unit noise); the position a ``Point2``, or a ``Point3`` with the height unknown.
    Both Jacobian blocks are set as 2-D arrays, ``(2K, d)`` and
    ``(2K, n_u)``: GTSAM 4.3 segfaults on a 1-D one and accepts a wrong width silently
    (a trap of GTSAM 4.3's Python bindings)."""
    import gtsam

    d = frame.dimension

    def error(this: Any, values: Any, jacobians: Any) -> FloatArray:
        position = point_at(values, position_key, d)
        state = np.concatenate([position, values.atVector(nuisance_key)])
        if jacobians is None:
            return np.ascontiguousarray(frame.whitened_error(state))
        e, E = frame.whitened_error_and_jacobian(state)
        jacobians[0] = np.ascontiguousarray(E[:, :d])
        jacobians[1] = np.ascontiguousarray(E[:, d:])
        return np.ascontiguousarray(e)

    noise = gtsam.noiseModel.Unit.Create(frame.n_rows)
    return gtsam.CustomFactor(noise, [position_key, nuisance_key], error)


def nuisance_graph(
    frames: Sequence[NuisanceFrame],
    prior_state: FloatArray,
    prior_sigmas: FloatArray,
    steps: FloatArray,
    *,
    random_walk: bool,
    first: int = 0,
) -> Any:
    """The graph of ``frames[first:]`` (module text): one factor per frame and the random-walk
    links into them (a static emitter: one factor of those frames stacked,
    :func:`~estimators.sequential.nuisance_states.stacked_frames`), with the diffuse priors on ``X(0)`` and ``N(0)`` when ``first == 0`` (the
    whole graph; a later ``first`` gives the factors a streaming update adds)."""
    import gtsam
    from gtsam.symbol_shorthand import N, X

    d = frames[0].dimension
    prior = gtsam.PriorFactorPoint3 if d == 3 else gtsam.PriorFactorPoint2
    between = gtsam.BetweenFactorPoint3 if d == 3 else gtsam.BetweenFactorPoint2
    graph = gtsam.NonlinearFactorGraph()
    if first == 0:
        graph.add(
            prior(
                X(0), np.array(prior_state[:d]), gtsam.noiseModel.Diagonal.Sigmas(prior_sigmas[:d])
            )
        )
        graph.add(
            gtsam.PriorFactorVector(
                N(0), np.array(prior_state[d:]), gtsam.noiseModel.Diagonal.Sigmas(prior_sigmas[d:])
            )
        )
    if not random_walk:  # every frame on X(0): one factor, one callback per evaluation
        if first < len(frames):
            graph.add(nuisance_factor(stacked_frames(frames[first:]), X(0), N(0)))
        return graph
    for t in range(first, len(frames)):
        graph.add(nuisance_factor(frames[t], X(t), N(0)))
        if t > 0:
            noise = gtsam.noiseModel.Isotropic.Sigma(d, float(steps[t - 1]))
            graph.add(between(X(t - 1), X(t), np.zeros(d), noise))
    return graph


def nuisance_values(theta: FloatArray, n_variables: int, dimension: int = 2) -> Any:
    """``gtsam.Values`` of a flat state ``θ = (X(0), …, X(V−1), N(0))``, each ``X`` of
    ``dimension`` coordinates."""
    import gtsam
    from gtsam.symbol_shorthand import N, X

    d = dimension
    values = gtsam.Values()
    for i in range(n_variables):
        values.insert(X(i), np.array(theta[d * i : d * i + d]))
    values.insert(N(0), np.array(theta[d * n_variables :]))
    return values


def read_values(values: Any, n_variables: int, dimension: int = 2) -> FloatArray:
    """The flat state of ``values`` (:func:`nuisance_values`)."""
    from gtsam.symbol_shorthand import N, X

    positions = [point_at(values, X(i), dimension) for i in range(n_variables)]
    return np.concatenate([*positions, values.atVector(N(0))]).astype(float)


# --------------------------------------------------------------------------------------------
# the fit of the graph in numpy
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class NuisanceFit:
    """The graph's fit at a flat state ``θ`` (:func:`nuisance_fit`), as
    :class:`~estimators.sequential.smoother_graph.ChainFit`: ``chi2``, ``log_evidence``,
    ``decrement``, ``step_m`` (Newton where the Hessian is positive definite, else Gauss-Newton;
    shaped as ``θ``), ``covariance`` (the inverse Gauss-Newton information of the whole state),
    ``data_information`` (the data's information of the position with the nuisance eliminated,
    MATH §15) and ``uniform_hessian`` (the exact Hessian for one shift of every emitter variable
    and of the nuisance)."""

    chi2: float
    log_evidence: float
    decrement: float
    step_m: FloatArray
    covariance: FloatArray
    data_information: FloatArray
    uniform_hessian: FloatArray

    def saddle_direction(self) -> FloatArray | None:
        """A unit direction of negative curvature of :attr:`uniform_hessian`, or None."""
        return negative_curvature(self.uniform_hessian)


def nuisance_fit(
    frames: Sequence[NuisanceFrame],
    theta: FloatArray,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_state: FloatArray,
    prior_sigmas: FloatArray,
) -> NuisanceFit:
    """Cost, decrement, evidence and covariance of the graph at ``θ`` (dense algebra over the
    ``dV + n_u`` unknowns). Raises :class:`EstimationFailure` when the Gauss-Newton information
    is not positive definite or not finite."""
    n_u = len(frames[0].names)
    d = frames[0].dimension
    n_var = (len(theta) - n_u) // d
    size = len(theta)
    nuisance = slice(d * n_var, size)
    information = np.zeros((size, size))
    curvature = np.zeros((size, size))
    gradient = np.zeros(size)
    data = np.zeros((d + n_u, d + n_u))
    chi2 = 0.0
    if random_walk:
        groups = list(enumerate(frames))
    else:  # every frame on X(0): one stacked evaluation (physical state: no reference)
        groups = [(0, stacked_frames(frames))]
    for variable, frame in groups:
        state = np.concatenate([theta[d * variable : d * variable + d], theta[nuisance]])
        e, E = frame.whitened_error_and_jacobian(state)
        index = np.r_[d * variable : d * variable + d, d * n_var : size]
        block = E.T @ E
        information[np.ix_(index, index)] += block
        curvature[np.ix_(index, index)] += np.sum(frame.curvature_terms(state, e), axis=0)
        gradient[index] += E.T @ e
        data += block
        chi2 += float(e @ e)
    prior_index = np.r_[0:d, d * n_var : size]
    weights = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
    offset = theta[prior_index] - prior_state
    chi2 += float(np.sum(weights * offset**2))
    information[prior_index, prior_index] += weights
    gradient[prior_index] += weights * offset
    if random_walk:
        for t in range(1, n_var):
            w = 1.0 / float(step_sigmas[t - 1]) ** 2
            a, b = slice(d * t - d, d * t), slice(d * t, d * t + d)
            link = theta[b] - theta[a]
            chi2 += w * float(link @ link)
            for i, j, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
                information[i, j] += sign * w * np.eye(d)
            gradient[b] += w * link
            gradient[a] -= w * link
    try:
        factor = np.linalg.cholesky(information)
    except np.linalg.LinAlgError:
        raise EstimationFailure(
            "the graph's information is not positive definite at the estimate"
        ) from None
    if not np.all(np.isfinite(factor)):
        raise EstimationFailure("the graph's information is not finite at the estimate")
    log_det = 2.0 * float(np.sum(np.log(np.diag(factor))))
    inverse_factor = np.linalg.inv(factor)
    covariance = inverse_factor.T @ inverse_factor
    gn_step = -covariance @ gradient
    decrement = float(-gradient @ gn_step)
    step = gn_step
    hessian = information + curvature
    try:
        np.linalg.cholesky(hessian)
        newton_step = -np.linalg.solve(hessian, gradient)
        newton = float(-gradient @ newton_step)
        if math.isfinite(newton):
            step, decrement = newton_step, min(decrement, newton)
    except np.linalg.LinAlgError:
        pass
    uniform = np.zeros((size, d + n_u))  # every emitter variable and the nuisance shifted
    uniform[: d * n_var, :d] = np.tile(np.eye(d), (n_var, 1))
    uniform[d * n_var :, d:] = np.eye(n_u)
    return NuisanceFit(
        chi2=chi2,
        log_evidence=float(-0.5 * chi2 - 0.5 * log_det),
        decrement=decrement,
        step_m=step,
        covariance=0.5 * (covariance + covariance.T),
        data_information=position_information(data, d),
        uniform_hessian=uniform.T @ hessian @ uniform,
    )
