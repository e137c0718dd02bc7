r"""Iterated updates of one frame and when they count as converged (no silent divergence).

The frame-by-frame estimators (:mod:`estimators.sequential.ekf`,
:mod:`estimators.sequential.gtsam_smoother`) and
:mod:`estimators.ml.ml` solve for the posterior mode of one frame's whitened model
(:class:`~estimators.frame_model.FrameModel`) given a Gaussian prior in information form
(:func:`iterated_update`), and report how the solve ended (:class:`SolverReport`).

**Convergence.** An iterate counts as converged only when its decrement, in χ² units, is at most
:data:`DECREMENT_TOL`. The decrement is the smaller of the Gauss-Newton decrement ``gᵀΛ⁻¹g``
and, where the exact Hessian ``H = Λ + Σ_k e_k ∇²e_k`` is positive definite, the Newton
decrement ``gᵀH⁻¹g`` (``g`` the gradient of half the cost, ``Λ`` its Gauss-Newton information;
Boyd & Vandenberghe §9.5.1). Either is the cost reduction its quadratic model still predicts,
and its square root the distance to the optimum in standard deviations of the posterior: the
criterion reads "within ``√DECREMENT_TOL`` posterior σ of a local minimum". Near the track the
Gauss-Newton model degenerates (the cross-track Jacobian vanishes on the track while the
residuals' own curvature does not), so its decrement stays large arbitrarily close to an
on-track minimum and its steps are metres long; the Newton decrement there is the true, tiny
remaining reduction. A step-length test would be fooled either way. :class:`SolverReport`
records the iterations used against the cap, the decrement and why a solve did not converge; the
estimators turn a non-converged solve into a fallback or a failed estimate, never a silent
success.

**Fallbacks.** A Gauss-Newton solve that did not converge (and did not raise the cost) is
finished by Newton's method with the exact Hessian (:func:`newton_refine`); a converged point
that is a saddle of the posterior cost is restarted off it along the negative curvature
(:func:`escape_probes`). :func:`finish_update` applies both.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.frame_model import FrameModel

FloatArray = NDArray[np.float64]

DECREMENT_TOL = 1e-4
"""An iterate is converged when its decrement (:func:`stationarity_decrement`, χ² units) is at
most this: it is then within ``0.01`` posterior standard deviations of a local minimum (see the
module text)."""

COST_ROUNDING_RTOL = 1e-10
"""...or when the decrement is below this fraction of the cost itself: a cost reduction that
small cannot be resolved in floating point (a hypothesis the data have refuted, whose χ² is
~1e12 on noise-free data, is then converged where it is, and its weight prunes it)."""

SADDLE_RTOL = 1e-9
"""An eigenvalue of an exact Hessian below ``−SADDLE_RTOL ×`` the largest is negative curvature
(the Hessian sums ``2K`` terms: its rounding is ``~1e−13`` relative): a saddle, not a minimum."""

ESCAPE_PROBES = 40
"""Points ``s + 2⁻ᵏ L v`` (``k < ESCAPE_PROBES``, ``L`` the length scale) probed along a saddle's
negative-curvature direction ``v`` for a start off it."""

NEWTON_ITERATIONS = 20
"""Newton steps of :func:`newton_refine`, at most (it converges quadratically: 2-5 are used)."""

NEWTON_RTOL = 1e-8
""":func:`newton_refine` stops once the decrement is below ``NEWTON_RTOL × DECREMENT_TOL``."""

HALVINGS = 30
"""Step halvings tried before an iteration counts as stalled (no shorter step lowers the cost)."""


class EstimationFailure(RuntimeError):
    """A solver could not produce an estimate; the estimators turn it into ``Estimate.failed``."""


# --------------------------------------------------------------------------------------------
# convergence
# --------------------------------------------------------------------------------------------


def _decrement(information: FloatArray, gradient: FloatArray) -> float:
    """``gᵀA⁻¹g`` for a positive definite ``A``; ``inf`` if ``A`` is not (or not finite)."""
    if not (np.all(np.isfinite(gradient)) and np.all(np.isfinite(information))):
        return float("inf")
    try:
        factor = np.linalg.cholesky(0.5 * (information + information.T))
    except np.linalg.LinAlgError:
        return float("inf")
    whitened = np.linalg.solve(factor, gradient)
    value = float(whitened @ whitened)
    return value if np.isfinite(value) else float("inf")


def stationarity_decrement(
    information: ArrayLike, curvature: ArrayLike, gradient: ArrayLike
) -> float:
    """``min(gᵀΛ⁻¹g, gᵀH⁻¹g)``, ``H = Λ + curvature`` (the latter only if ``H ≻ 0``).

    ``information`` is the Gauss-Newton ``Λ``, ``curvature`` the residuals' own
    ``Σ e_k ∇²e_k`` (:meth:`FrameModel.curvature_terms`) and ``gradient`` that of half the
    cost; χ² units. See the module text ("Convergence").
    """
    Lambda = np.asarray(information, dtype=float)
    g = np.asarray(gradient, dtype=float)
    return min(_decrement(Lambda, g), _decrement(Lambda + np.asarray(curvature, dtype=float), g))


@dataclass(frozen=True, slots=True)
class SolverReport:
    """How an iterative solve ended (see the module text, "Convergence").

    Attributes
    ----------
    iterations, max_iterations : int
        Iterations used and the cap (a Newton refinement's included).
    decrement : float
        :func:`stationarity_decrement` at the returned point (χ² units).
    converged : bool
        ``decrement <= DECREMENT_TOL`` and the cost did not rise.
    reason : str
        Empty when converged; otherwise what happened (iteration cap, stall, cost rise).
    fallback : str
        ``"newton"`` when Gauss-Newton did not converge and :func:`newton_refine` took over,
        ``"saddle-escape"`` when the solve stopped at a saddle and was restarted off it
        (``fallback_reason`` says why); empty otherwise.
    fallback_reason : str
    cost_rose : bool
        The solve ended above its starting cost (a divergence; no fallback is tried).
    """

    iterations: int
    max_iterations: int
    decrement: float
    converged: bool
    reason: str = ""
    fallback: str = ""
    fallback_reason: str = ""
    cost_rose: bool = False


def convergence_report(
    iterations: int,
    max_iterations: int,
    decrement: float,
    *,
    stalled: bool,
    small_step: bool = False,
    cost_rose: bool = False,
    cost: float = 0.0,
    what: str = "Gauss-Newton",
) -> SolverReport:
    """Classify the end of an iterative solve: converged, iteration cap, stall or cost rise.

    Converged means ``decrement <= max(DECREMENT_TOL, COST_ROUNDING_RTOL · cost)`` without a
    cost rise, however the solver stopped (``cost``: the χ² at the returned point). Otherwise
    the reason names the stop: ``stalled`` (no step lowered the cost), the cap, ``small_step``
    (the steps became negligible away from a minimum) or an early stop.
    """
    if cost_rose:
        return SolverReport(
            iterations, max_iterations, decrement, False, f"{what} raised the cost", cost_rose=True
        )
    if decrement <= max(DECREMENT_TOL, COST_ROUNDING_RTOL * cost):
        return SolverReport(iterations, max_iterations, decrement, True)
    if stalled:
        why = "stalled (no step lowers the cost)"
    elif small_step:
        why = "took negligible steps"
    elif iterations >= max_iterations:
        why = f"reached its iteration cap ({max_iterations})"
    else:
        why = "stopped early"
    return SolverReport(
        iterations,
        max_iterations,
        decrement,
        False,
        f"{what} {why} without converging (decrement {decrement:.3g} > {DECREMENT_TOL:g})",
    )


# --------------------------------------------------------------------------------------------
# Gaussian updates in information form
# --------------------------------------------------------------------------------------------


def map_cost(
    frame: FrameModel,
    emitter_m: ArrayLike,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    *,
    predicted: ArrayLike | None = None,
) -> float:
    """``‖e(s)‖² + (s − s̄)ᵀ Λ̄ (s − s̄)``: twice the negative log posterior of one update
    (``predicted``: ``h(s)`` if the caller has evaluated it)."""
    if predicted is None:
        error = frame.whitened_error(emitter_m)
    else:
        error = (np.asarray(predicted, dtype=float) - frame.measured) / frame.sigma
    offset = np.asarray(emitter_m, dtype=float) - np.asarray(prior_mean_m, dtype=float)
    return float(error @ error + offset @ np.asarray(prior_information) @ offset)


def laplace_log_likelihood(
    cost: float, prior_information: ArrayLike, posterior_information: ArrayLike
) -> float:
    r"""Log predictive likelihood of one frame by Laplace's method, up to a shared constant.

    For ``z = h(s) + w``, ``w ~ N(0, R)``, prior ``s ~ N(s̄, Λ̄⁻¹)`` and ``Λ = Λ̄ + EᵀE`` at the
    posterior mode ``ŝ``:

    .. math::

        \log p(z) \approx -\tfrac12\,\mathrm{cost}(\hat s)
            - \tfrac12\big(\log\det\Lambda - \log\det\bar\Lambda\big)
            - \tfrac12 \log\det(2\pi R)

    the last term, the same for every hypothesis of a frame, is left out. For a linear model it
    is the exact ``log N(z; h(s̄), H P̄ Hᵀ + R)`` (matrix determinant lemma); iterated to the mode
    it is the likelihood an iterated EKF should weigh hypotheses by (MATH §7).
    """
    _, logdet_post = np.linalg.slogdet(np.asarray(posterior_information, dtype=float))
    _, logdet_prior = np.linalg.slogdet(np.asarray(prior_information, dtype=float))
    return float(-0.5 * cost - 0.5 * (logdet_post - logdet_prior))


def cost_derivatives(
    frame: FrameModel, prior_mean: FloatArray, prior_information: FloatArray, point: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(Λ̄ + EᵀE, Σ e_k ∇²e_k, g)`` of one frame's posterior cost at ``point``."""
    e, E = frame.whitened_error_and_jacobian(point)
    return (
        prior_information + E.T @ E,
        np.sum(frame.curvature_terms(point, e), axis=0),
        E.T @ e + prior_information @ (point - prior_mean),
    )


def symmetric_inverse(information: ArrayLike) -> FloatArray:
    """``Λ⁻¹`` symmetrised (a covariance from an information matrix)."""
    covariance = np.linalg.inv(np.asarray(information, dtype=float))
    return 0.5 * (covariance + covariance.T)


# --------------------------------------------------------------------------------------------
# iterated updates and their fallbacks
# --------------------------------------------------------------------------------------------


def lower_cost_step(
    frame: FrameModel,
    prior_mean: FloatArray,
    prior_information: FloatArray,
    point: FloatArray,
    step: FloatArray,
    cost: float,
    *,
    first_trial: FloatArray | None = None,
) -> tuple[FloatArray, float, FloatArray] | None:
    """Step halving: the first of ``point + 2⁻ⁱ step`` (``i <`` :data:`HALVINGS`) whose posterior
    cost (:func:`map_cost`) is at most ``cost``, as ``(trial, trial_cost, 2⁻ⁱ step)``; None when
    none is (a stall). ``first_trial`` is tried in place of ``point + step`` (a filter's own
    update, the same point up to rounding). The halvings after the first trial are evaluated
    together, in one pass of the model over all of them (each cost summed as :func:`map_cost`
    sums it)."""
    trial = point + step if first_trial is None else first_trial
    trial_cost = map_cost(frame, trial, prior_mean, prior_information)
    if trial_cost <= cost:
        return trial, trial_cost, step
    steps = step * 0.5 ** np.arange(1, HALVINGS)[:, None]
    trials = point + steps
    errors = frame.whitened_error(trials)
    offsets = trials - np.asarray(prior_mean, dtype=float)
    information = np.asarray(prior_information)
    for i in range(HALVINGS - 1):
        trial_cost = float(errors[i] @ errors[i] + offsets[i] @ information @ offsets[i])
        if trial_cost <= cost:
            return trials[i].copy(), trial_cost, steps[i].copy()
    return None


def finish_iterations(
    frame: FrameModel,
    prior_mean: FloatArray,
    prior_information: FloatArray,
    point: FloatArray,
    cost: float,
    *,
    start_cost: float,
    iterations: int,
    max_iterations: int,
    stalled: bool,
    small_step: bool,
    what: str,
) -> tuple[FloatArray, float, FloatArray, SolverReport]:
    """The end of an iterated update at ``point`` (cost ``cost``, from ``start_cost``): its
    :func:`convergence_report`, with the decrement there (``inf`` at a non-finite point), then
    :func:`finish_update`'s fallbacks. Returns ``(point, cost, posterior_information, report)``."""
    derivatives = (
        cost_derivatives(frame, prior_mean, prior_information, point)
        if np.all(np.isfinite(point))
        else None
    )
    decrement = float("inf") if derivatives is None else stationarity_decrement(*derivatives)
    report = convergence_report(
        iterations,
        max_iterations,
        decrement,
        stalled=stalled,
        small_step=small_step,
        cost_rose=not cost <= start_cost,
        cost=cost,
        what=what,
    )
    return finish_update(
        frame, prior_mean, prior_information, point, cost, report, derivatives=derivatives
    )


def newton_fallback_report(
    report: SolverReport,
    iterations: int,
    decrement: float,
    *,
    stalled: bool,
    cost_rose: bool,
    cost: float,
    fallback: str,
) -> SolverReport:
    """The report of Newton's method run for ``iterations`` after the solve of ``report`` did not
    converge (or stopped at a saddle): iterations and caps added, ``fallback`` set and
    ``fallback_reason`` the old report's reason."""
    refined = convergence_report(
        report.iterations + iterations,
        report.max_iterations + NEWTON_ITERATIONS,
        decrement,
        stalled=stalled,
        cost_rose=cost_rose,
        cost=cost,
        what="Newton's method",
    )
    return replace(
        refined,
        reason=f"{report.reason}; {refined.reason}" if refined.reason else "",
        fallback=fallback,
        fallback_reason=report.reason,
    )


def newton_refine(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    start_m: ArrayLike,
    *,
    max_iterations: int = NEWTON_ITERATIONS,
) -> tuple[FloatArray, float, int, bool]:
    r"""Newton's method on one frame's posterior cost: the fallback when Gauss-Newton stalls.

    Steps ``−H⁻¹g`` with the exact Hessian ``H = Λ̄ + EᵀE + Σ e_k ∇²e_k`` while it is positive
    definite (else the Gauss-Newton step), halved while the cost rises, until the decrement is
    negligible. Near the track, where Gauss-Newton's model misses the curvature that holds an
    on-track minimum and creeps along the valley for hundreds of iterations (0.17 m short of the
    optimum after 1000 in one trial of ``paper-1m-turn`` at −20 dB), Newton reaches it in a few
    steps.

    Returns ``(point, cost, iterations, stalled)``.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = np.asarray(start_m, dtype=float).copy()
    cost = map_cost(frame, point, prior_mean, Lambda)
    iterations = 0
    while iterations < max_iterations:
        information, curvature, gradient = cost_derivatives(frame, prior_mean, Lambda, point)
        if stationarity_decrement(information, curvature, gradient) <= NEWTON_RTOL * DECREMENT_TOL:
            break
        iterations += 1
        hessian = information + curvature
        try:
            np.linalg.cholesky(hessian)
            step = -np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            step = -np.linalg.solve(information, gradient)
        lower = lower_cost_step(frame, prior_mean, Lambda, point, step, cost)
        if lower is None:
            return point, cost, iterations, True
        point, cost, _ = lower
    return point, cost, iterations, False


def negative_curvature(hessian: ArrayLike) -> FloatArray | None:
    """A unit direction of negative curvature of a ``d × d`` Hessian beyond rounding
    (:data:`SADDLE_RTOL`), or None: a stationary point with one is a saddle, not a minimum."""
    values, vectors = np.linalg.eigh(np.asarray(hessian, dtype=float))
    if values[0] < -SADDLE_RTOL * max(abs(float(values[-1])), np.finfo(float).tiny):
        return vectors[:, 0]
    return None


def escape_probes(point_m: ArrayLike, direction: ArrayLike, length_m: float) -> FloatArray:
    """``point + 2⁻ᵏ L v`` for ``k < ESCAPE_PROBES``: where to look for a start off a saddle."""
    scales = length_m * 0.5 ** np.arange(ESCAPE_PROBES)
    return np.asarray(point_m, dtype=float) + scales[:, None] * np.asarray(direction, dtype=float)


def finish_update(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    point_m: ArrayLike,
    cost: float,
    report: SolverReport,
    *,
    derivatives: tuple[FloatArray, FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, float, FloatArray, SolverReport]:
    """The documented fallbacks of an iterated update, then the final report.

    1. Gauss-Newton did not converge (and did not raise the cost): :func:`newton_refine`
       finishes it (``report.fallback == "newton"``).
    2. The converged point is a saddle of the posterior cost (the exact Hessian has negative
       curvature, :func:`negative_curvature`): a start on the track's vertical plane stays on
       it by symmetry after the minimum has moved off the track. :func:`newton_refine` restarts
       from the lowest of :func:`escape_probes` along the negative curvature
       (``report.fallback == "saddle-escape"``); without a lower converged point the report is
       not converged.

    ``derivatives``: :func:`cost_derivatives` at ``point_m`` if the caller has them (they are
    reused while the point stays). Returns ``(point, cost, posterior_information, report)``.
    Raises :class:`EstimationFailure` on a non-finite point.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = np.asarray(point_m, dtype=float)
    if not report.converged and not report.cost_rose and np.all(np.isfinite(point)):
        point, cost, report = _refined(frame, prior_mean, Lambda, point, report, "newton")
        derivatives = None
    if report.converged:
        if derivatives is None:
            derivatives = cost_derivatives(frame, prior_mean, Lambda, point)
        information, curvature, _ = derivatives
        direction = negative_curvature(information + curvature)
        if direction is not None:
            saddle = "the update stopped at a saddle point of the posterior cost"
            probes = escape_probes(point, direction, frame.mean_range_m(point))
            costs = [map_cost(frame, probe, prior_mean, Lambda) for probe in probes]
            best = int(np.argmin(costs))
            escaped = False
            if costs[best] < cost:
                start = replace(report, converged=False, reason=saddle)
                refined, refined_cost, refined_report = _refined(
                    frame, prior_mean, Lambda, probes[best], start, "saddle-escape"
                )
                if refined_report.converged and refined_cost < cost:
                    point, cost, report, escaped = refined, refined_cost, refined_report, True
                    derivatives = None
            if not escaped:
                report = replace(
                    report, converged=False, reason=f"{saddle}; no lower minimum was found off it"
                )
    if derivatives is None:
        E = frame.whitened_jacobian(point)
        information = Lambda + E.T @ E
    else:
        information = derivatives[0]  # Λ̄ + EᵀE at this point
    if not np.all(np.isfinite(point)) or not np.all(np.isfinite(information)):
        raise EstimationFailure("the iterated update diverged (non-finite estimate)")
    return point, cost, information, report


def _refined(
    frame: FrameModel,
    prior_mean: FloatArray,
    Lambda: FloatArray,
    point: FloatArray,
    report: SolverReport,
    fallback: str,
) -> tuple[FloatArray, float, SolverReport]:
    """:func:`newton_refine` from ``point`` after ``report``'s solve: the new point, its cost
    and the report (``fallback`` set, ``fallback_reason`` the old report's reason)."""
    start_cost = map_cost(frame, point, prior_mean, Lambda)
    point, cost, n_newton, stalled = newton_refine(frame, prior_mean, Lambda, point)
    decrement = stationarity_decrement(*cost_derivatives(frame, prior_mean, Lambda, point))
    return (
        point,
        cost,
        newton_fallback_report(
            report,
            n_newton,
            decrement,
            stalled=stalled,
            cost_rose=not cost <= start_cost,
            cost=cost,
            fallback=fallback,
        ),
    )


def iterated_update(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    *,
    start_m: ArrayLike | None = None,
    max_iterations: int = 50,
    step_rtol: float = 1e-12,
) -> tuple[FloatArray, FloatArray, float, SolverReport]:
    r"""Posterior mode of one frame given a Gaussian prior: the iterated EKF in information form.

    Gauss-Newton on ``‖e(s)‖² + (s − s̄)ᵀΛ̄(s − s̄)`` with step halving when the cost rises,

    .. math::

        s_{i+1} = s_i - (\bar\Lambda + E_i^\top E_i)^{-1}
                  \big(E_i^\top e_i + \bar\Lambda (s_i - \bar s)\big)

    started at ``start_m`` (default the prior mean), until a step is shorter than
    ``step_rtol ×`` the range. With a diffuse ``Λ̄`` this is the frame's maximum likelihood,
    started at a closed-form candidate (MATH §10); the information form stays exact where a
    covariance-form gain would lose the digits of a huge prior variance. If Gauss-Newton has
    not converged then (decrement above :data:`DECREMENT_TOL`: its cap, a stall, or negligible
    steps in a near-track valley), :func:`newton_refine` takes over (:func:`finish_update`).

    Returns
    -------
    mean_m : (d,)
        ``d`` the coordinates of the frame's position (those of ``prior_mean_m``).
    posterior_information : (d, d)
        ``Λ̄ + EᵀE`` at the mode.
    log_likelihood : float
        :func:`laplace_log_likelihood` at the mode.
    report : SolverReport
        Iterations against the cap, the decrement, whether the Newton fallback ran and whether
        the result converged; the caller decides what a non-converged update means.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = prior_mean.copy() if start_m is None else np.asarray(start_m, dtype=float).copy()
    scale = max(frame.mean_range_m(point), np.finfo(float).tiny)
    h, H = frame.predicted_and_jacobian(point)
    cost = map_cost(frame, point, prior_mean, Lambda, predicted=h)
    start_cost = cost
    iterations = 0
    small_step = stalled = False
    while iterations < max_iterations:
        iterations += 1
        e, E = (h - frame.measured) / frame.sigma, H / frame.sigma[:, None]  # e(s), E(s)
        information = Lambda + E.T @ E
        gradient = E.T @ e + Lambda @ (point - prior_mean)
        step = -np.linalg.solve(information, gradient)
        # the full step evaluated once, for its cost and, if taken, the next linearisation;
        # step halving (lower_cost_step) only when it raised the cost
        trial = point + step
        h, H = frame.predicted_and_jacobian(trial)
        trial_cost = map_cost(frame, trial, prior_mean, Lambda, predicted=h)
        if trial_cost <= cost:
            point, cost = trial, trial_cost
        else:
            lower = lower_cost_step(frame, prior_mean, Lambda, point, step, cost)
            if lower is None:
                stalled = True  # no decrease along the Gauss-Newton direction
                break
            point, cost, step = lower
            h, H = frame.predicted_and_jacobian(point)
        if np.linalg.norm(step) <= step_rtol * scale:
            small_step = True
            break
    point, cost, information, report = finish_iterations(
        frame,
        prior_mean,
        Lambda,
        point,
        cost,
        start_cost=start_cost,
        iterations=iterations,
        max_iterations=max_iterations,
        stalled=stalled,
        small_step=small_step,
        what="Gauss-Newton",
    )
    return point, information, laplace_log_likelihood(cost, Lambda, information), report
