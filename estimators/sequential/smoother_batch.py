"""Levenberg-Marquardt on one hypothesis's whole graph, checked, with its two fallbacks.

The batch solve of :class:`estimators.sequential.gtsam_smoother.GtsamSmoother` (its ``estimate``,
and the fallback of a streaming update that failed its checks). The result is converged when the
decrement of :func:`~estimators.sequential.smoother_graph.chain_fit` is at most ``DECREMENT_TOL``
and the cost did not rise (:mod:`estimators.convergence`, "Convergence"). Short of that, Newton's
method on the whole graph finishes it (:func:`newton_polish`); a result at a saddle point is
restarted from the lowest point probed along the negative curvature. Both are reported as the
solve's ``fallback``.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import (
    EstimationFailure,
    SolverReport,
    convergence_report,
    escape_probes,
    newton_fallback_report,
)
from estimators.frame_model import FrameModel
from estimators.sequential.mirror_hypotheses import DIFFUSE_PRIOR_SCALE
from estimators.sequential.smoother_graph import (
    chain_fit,
    graph_part,
    marginal_covariance,
    newton_descent,
    point_at,
    values_of,
)
from estimators.sequential.smoother_hypotheses import SmootherHypothesis

FloatArray = NDArray[np.float64]

LM_LAMBDA_UPPER_BOUND = 1e20
"""Levenberg-Marquardt's damping ceiling. GTSAM's default, 1e5, gives up without a single step
when the start is far from the data (a mirror start after a turn: ``χ² ~ 1e13``, the gradient so
large that a step damped by 1e5 still overshoots), and returns the start unchanged; a higher
ceiling only lets the damping grow until a step lowers the cost."""

COST_RISE_RTOL = 1e-9
"""A cost above the starting cost by more than this (relative) is a rise, not rounding."""


def linear_solver(dimension: int, random_walk: bool) -> str:
    """The linear solver of Levenberg-Marquardt's steps: GTSAM's default, the Cholesky
    factorisation of the damped normal equations, except for a random walk with the height
    unknown, which gets the QR factorisation of the whitened Jacobian.

    Why: in 3-D one frame's data leave its variable free along the frame's circle (MATH §7),
    which only the random-walk links ``1/(qΔt)²`` hold, against the data's ``Σ∇e∇eᵀ`` across
    it. On noise-free ``climb-height`` (σ's at 100 dB, ``q = 0.5`` m/s) that is ``0.16``
    against ``10¹⁰-10¹¹`` m⁻², a condition number ``8·10¹²`` of the normal equations, and
    GTSAM's Cholesky calls such a system indeterminate (the last two diagonal entries of a
    clique's factor more than ``2¹²`` apart) until the damping reaches ``10³``: each step is
    then ``10³-10⁵`` times too short along the circles and 100 iterations end metres off. The
    QR factorisation sees the Jacobian's condition number, its square root (``3·10⁶``), and
    converges in a few iterations. In 2-D, and with one variable, every variable is
    determined by its own frames, and the Cholesky factorisation is kept.
    """
    return "MULTIFRONTAL_QR" if dimension == 3 and random_walk else "MULTIFRONTAL_CHOLESKY"


def gtsam_levenberg_marquardt(
    graph: Any,
    initial: Any,
    max_iterations: int,
    *,
    relative_error_tol: float = 1e-15,
    solver: str = "MULTIFRONTAL_CHOLESKY",
) -> tuple[Any, float, float, int]:
    """GTSAM's Levenberg-Marquardt on ``graph`` from ``initial``, run to ``max_iterations`` (the
    absolute error tolerance at 1e-15, the relative one ``relative_error_tol``: an iteration
    that lowers the error by at most that fraction ends the solve; the damping bounded by
    ``LM_LAMBDA_UPPER_BOUND``; the linear ``solver`` of :func:`linear_solver`): the result,
    the error before and after and the iterations. A GTSAM error is an
    :class:`EstimationFailure`."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType(solver)
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_error_tol)
    params.setAbsoluteErrorTol(1e-15)
    params.setlambdaUpperBound(LM_LAMBDA_UPPER_BOUND)
    try:
        start_error = float(graph.error(initial))
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        result = optimizer.optimize()
        end_error = float(graph.error(result))
    except RuntimeError as error:
        raise EstimationFailure(f"GTSAM failed in the batch solve ({error})") from None
    return result, start_error, end_error, int(optimizer.iterations())


def lm_solve(
    frames: tuple[FrameModel, ...],
    initial_m: FloatArray,
    prior_mean_m: FloatArray,
    steps: FloatArray,
    prior_sigma_m: float,
    *,
    random_walk: bool,
    max_iterations: int,
    escape: bool = True,
) -> tuple[SmootherHypothesis, SolverReport]:
    """Levenberg-Marquardt on the full graph from ``initial_m`` (one row per variable).

    The report is converged when the decrement
    (:func:`~estimators.sequential.smoother_graph.chain_fit`) at the result is at most
    ``DECREMENT_TOL`` and the cost did not rise; otherwise it says whether the iteration cap was
    reached or LM stopped early (no step lowers the cost: a stall). Two documented fallbacks: a
    result short of convergence is finished by Newton's method on the whole graph (``report.fallback
    == "newton"``, :func:`_polished`); a result at a saddle point (the first frame's closed form on
    the track's vertical plane keeps every later iterate on it by symmetry, even once the minimum
    has moved off the track) is restarted, with ``escape``, from the lowest point probed along the
    negative curvature (``report.fallback == "saddle-escape"``). ``GtsamSmoother.estimate`` reports
    them in ``diagnostics["lm_fallback"]``.
    """
    import gtsam
    from gtsam.symbol_shorthand import X

    n_variables = len(frames) if random_walk else 1
    graph = graph_part(
        frames,
        0,
        len(frames),
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=prior_sigma_m,
    )
    d = frames[0].dimension
    result, start_error, end_error, iterations = gtsam_levenberg_marquardt(
        graph, values_of(initial_m), max_iterations, solver=linear_solver(d, random_walk)
    )
    estimates = np.array([point_at(result, X(i), d) for i in range(n_variables)])
    covariance = marginal_covariance(
        lambda: gtsam.Marginals(graph, result).marginalCovariance(X(n_variables - 1)), d
    )
    hypothesis = SmootherHypothesis.fitted(
        frames,
        estimates,
        covariance,
        prior_mean_m,
        prior_sigma_m,
        steps,
        random_walk=random_walk,
    )
    report = convergence_report(
        iterations,
        max_iterations,
        hypothesis.decrement,
        stalled=iterations < max_iterations,
        cost_rose=not end_error <= start_error * (1.0 + COST_RISE_RTOL),
        cost=hypothesis.chi2,
        what="Levenberg-Marquardt",
    )
    if not report.converged and not report.cost_rose:
        hypothesis, report = _polished(
            graph, frames, hypothesis, report, steps, prior_sigma_m, random_walk=random_walk
        )
    if not (escape and report.converged and hypothesis.saddle):
        return hypothesis, report
    # a stationary point that is not a minimum (by symmetry, e.g. on the track's vertical
    # plane): restart from the lowest point probed along the negative curvature
    saddle = (
        "Levenberg-Marquardt stopped at a saddle point of the cost (negative curvature across it)"
    )
    start = _escape_start(frames, hypothesis, steps, prior_sigma_m, random_walk=random_walk)
    if start is not None:
        escaped, escaped_report = lm_solve(
            frames,
            start,
            prior_mean_m,
            steps,
            prior_sigma_m,
            random_walk=random_walk,
            max_iterations=max_iterations,
            escape=False,
        )
        if escaped_report.converged and escaped.chi2 < hypothesis.chi2:
            return escaped, replace(
                escaped_report,
                iterations=iterations + escaped_report.iterations,
                fallback="saddle-escape",
                fallback_reason=saddle,
            )
    return hypothesis, replace(report, converged=False, reason=f"{saddle}; no lower start")


def _polished(
    graph: Any,
    frames: tuple[FrameModel, ...],
    hypothesis: SmootherHypothesis,
    report: SolverReport,
    steps: FloatArray,
    prior_sigma_m: float,
    *,
    random_walk: bool,
) -> tuple[SmootherHypothesis, SolverReport]:
    """Levenberg-Marquardt's result finished by :func:`newton_polish` (the fallback when it
    stops short: in the flat valley near the track it needs hundreds of iterations)."""
    import gtsam
    from gtsam.symbol_shorthand import X

    estimates, n_newton, stalled = newton_polish(
        frames,
        hypothesis.estimates_m,
        hypothesis.prior_mean_m,
        prior_sigma_m,
        steps,
        random_walk=random_walk,
    )
    values = values_of(estimates)
    last = X(len(estimates) - 1)
    covariance = marginal_covariance(
        lambda: gtsam.Marginals(graph, values).marginalCovariance(last), frames[0].dimension
    )
    polished = SmootherHypothesis.fitted(
        frames,
        estimates,
        covariance,
        hypothesis.prior_mean_m,
        prior_sigma_m,
        steps,
        random_walk=random_walk,
    )
    return polished, newton_fallback_report(
        report,
        n_newton,
        polished.decrement,
        stalled=stalled,
        cost_rose=not polished.chi2 <= hypothesis.chi2,
        cost=polished.chi2,
        fallback="newton",
    )


def newton_polish(
    frames: tuple[FrameModel, ...],
    estimates_m: FloatArray,
    prior_mean_m: FloatArray,
    prior_sigma_m: float,
    steps: FloatArray,
    *,
    random_walk: bool,
) -> tuple[FloatArray, int, bool]:
    """Newton's method on the whole graph
    (:func:`~estimators.sequential.smoother_graph.newton_descent`, evaluated exactly) until the
    decrement is negligible. Returns ``(estimates, iterations, stalled)``."""
    fit = partial(
        chain_fit,
        frames,
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=prior_sigma_m,
    )
    estimates, _, iterations, stalled = newton_descent(fit, np.array(estimates_m, dtype=float))
    return estimates, iterations, stalled


def _escape_start(
    frames: tuple[FrameModel, ...],
    hypothesis: SmootherHypothesis,
    steps: FloatArray,
    prior_sigma_m: float,
    *,
    random_walk: bool,
) -> FloatArray | None:
    """The lowest of the points ``ŝ + 2⁻ᵏ L v`` (every variable shifted) along the saddle's
    negative-curvature direction ``v``, if below the saddle's cost."""
    estimates, prior_mean = hypothesis.estimates_m, hypothesis.prior_mean_m
    fit = partial(
        chain_fit,
        frames,
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=prior_mean,
        prior_sigma_m=prior_sigma_m,
    )
    direction = fit(estimates).saddle_direction()
    if direction is None:
        return None
    length = prior_sigma_m / DIFFUSE_PRIOR_SCALE
    best, best_chi2 = None, hypothesis.chi2
    for shift in escape_probes(np.zeros(len(direction)), direction, length):
        trial = estimates + shift
        try:
            chi2 = fit(trial).chi2
        except EstimationFailure:
            continue
        if chi2 < best_chi2:
            best, best_chi2 = trial, chi2
    return best


def best_lm_solve(
    frames: tuple[FrameModel, ...],
    steps: FloatArray,
    prior_mean_m: FloatArray,
    prior_sigma_m: float,
    starts: list[FloatArray],
    *,
    random_walk: bool,
    max_iterations: int,
) -> SmootherHypothesis:
    """The lowest-cost converged Levenberg-Marquardt solve from ``starts``; raises
    :class:`EstimationFailure` with every reason when none converged."""
    best: SmootherHypothesis | None = None
    reasons = []
    for index, start in enumerate(starts):
        if index and np.array_equal(start, starts[0]):
            continue
        try:
            hypothesis, report = lm_solve(
                frames,
                start,
                prior_mean_m,
                steps,
                prior_sigma_m,
                random_walk=random_walk,
                max_iterations=max_iterations,
            )
        except EstimationFailure as error:
            reasons.append(str(error))
            continue
        if not report.converged:
            reasons.append(report.reason)
        elif best is None or hypothesis.chi2 < best.chi2:
            best = hypothesis
    if best is None:
        raise EstimationFailure("; ".join(dict.fromkeys(reasons)))
    return best
