r"""The GTSAM smoother with the unknown nuisance parameters as variables (MATH §7, §10, §15).

When the data declare the emitter's carrier offset δ or emission time b unknown
(``data.unknowns``), :class:`estimators.sequential.gtsam_smoother.GtsamSmoother` solves this graph
instead of its cooperative one (:mod:`estimators.sequential.smoother_graph`, unchanged without
unknowns).

**The graph** (:mod:`estimators.sequential.nuisance_graph`). The emitter variables are as without
nuisance (one ``X(0)``, or one ``X(t)`` per frame linked by random-walk steps); one more variable
``N(0)``, a ``gtsam`` vector, holds the unknown ones in the physical state of
:mod:`estimators.sequential.nuisance_states` (δ in Hz, then ``β = c b`` in metres), constant over
the pass. Each frame adds ONE ``CustomFactor`` on ``[X(t), N(0)]`` with the stacked whitened
residuals and two 2-D Jacobian blocks, ``E_s`` of MATH §8 and the constant 0/1 columns
``∂f_k/∂δ = 1``, ``∂r_k/∂β = 1`` over σ; with a static emitter the frames of a solve are
stacked into one such factor on ``[X(0), N(0)]`` (the same residuals, one Python call per
evaluation of the graph; a streaming update adds the new frame's own). Diffuse priors sit on ``X(0)`` and ``N(0)`` at the
hypothesis's start (:func:`~estimators.sequential.nuisance_states.diffuse_sigmas`); the starts are
those of
:mod:`estimators.sequential.nuisance_starts`. With a static emitter the optimum is the maximum
likelihood of ``(s, δ, β)`` over all frames (MATH §10), whose ``(x, y)`` error attains the nuisance
CRLB of :func:`scenarios.fisher.fisher_information` at high SNR.

**Solve and checks** (:func:`lm_solve`). Levenberg-Marquardt on the whole graph (ended by
:data:`LM_RELATIVE_ERROR_TOL`), then the checks
of :mod:`estimators.sequential.smoother_batch` on the numpy fit of the same graph (its
χ², decrement, Laplace evidence ``−½χ² − ½ log det Λ``, exact Hessian): converged when the
decrement is at most ``DECREMENT_TOL`` without a cost rise; short of that Newton's method on the
fit finishes it; a saddle (negative curvature of the Hessian for one shift of every emitter
variable and of the nuisance) is left along the negative curvature. The reported covariance is
GTSAM's marginal of the last emitter variable, the ``(x, y)`` block of the inverse information.

**Streaming** (:func:`update`). Each hypothesis keeps an ISAM2 holding its graph, the nuisance
``N(0)`` one of its variables, in the per-process cache of
:mod:`estimators.sequential.smoother_hypotheses` (a missing one is seeded at the hypothesis's
optimum on the earlier frames, so the state stays a picklable value). An update adds only the new
frame's factor (and link) and steps ISAM2 until no variable needs relinearising
(:func:`isam2_update`): old factors stay linearised where they were. Newton's method on the numpy
fit of the whole graph then finishes ISAM2's estimate (one or two steps: ISAM2's Gauss-Newton
estimate from a stale linearisation is off by a fraction of its step), and the checks above
decide: converged, the cost not above the previous optimum's plus the new frame's residuals
there, no saddle. So the streamed optimum is the batch one, at a cost per update that does not
re-solve the graph. An update that fails its checks (or where GTSAM raised) falls back to
Levenberg-Marquardt on the whole graph from the previous optimum and from the hypothesis's start
(:func:`streamed_solve`), reported (``fallback="batch"``, ``fallback_reason``, ``fallbacks``).
Mirror hypotheses (MATH §7), their Laplace weights, merging and pruning are as without nuisance.

**Starts from later frames** (:func:`rescued`). The first frame fixes the emitter only weakly
once an offset is unknown, so at low SNR both of its starts can lead to a wrong local minimum
after a turn (on ``turn`` at 0 dB with δ unknown, one trial in 300: ``χ² = 120`` for 40
measurements, where the optimum near the emitter has 29). When the best hypothesis off a
straight track misfits the data, ``χ² > χ²_m(1 − MISFIT_ALPHA)`` (``m`` measurements), the
start pairs of later frames (all of them in batch, the new one when streaming), with the
nuisance values profiled over every frame, are solved too, and the lowest that beats it joins
the hypotheses (its weight decides; ``diagnostics["misfit_restart"]`` and the message say so).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate
from estimators.convergence import (
    COST_ROUNDING_RTOL,
    DECREMENT_TOL,
    EstimationFailure,
    escape_probes,
)
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sequential.mirror_hypotheses import (
    DIFFUSE_PRIOR_SCALE,
    MERGE_RTOL,
    hypothesis_starts,
    smoother_estimate,
)
from estimators.sequential.nuisance_graph import (
    NuisanceFit,
    nuisance_fit,
    nuisance_graph,
    nuisance_values,
    read_values,
)
from estimators.sequential.nuisance_starts import height_starts, straight_frame_starts
from estimators.sequential.nuisance_states import (
    NuisanceFrame,
    diffuse_sigmas,
    frame_model,
    nuisance_diagnostics,
    nuisance_names,
    profile_nuisance,
    stacked_frames,
)
from estimators.sequential.smoother_batch import (
    COST_RISE_RTOL,
    gtsam_levenberg_marquardt,
    linear_solver,
)
from estimators.sequential.smoother_graph import newton_descent, step_sigmas_m
from estimators.sequential.smoother_hypotheses import (
    ANCHOR_KEY,
    MAX_ISAM2_STEPS,
    POLISH_HALVINGS,
    POLISH_RTOL,
    RELINEARIZE_RTOL,
    SmootherState,
    checkin,
    checkout,
    isam2_params,
    pruned_hypotheses,
)
from scenarios.geometry import StraightTrack
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# one hypothesis: Levenberg-Marquardt, checked
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class NuisanceHypothesis:
    """One mirror hypothesis at its optimum: the flat state ``θ`` (emitter variables, then
    δ, β), the last variable's covariance, the physical nuisance covariance, the Laplace weight,
    the data's ``(x, y)`` information (MATH §15) and the start its priors are centred on."""

    theta: FloatArray
    n_variables: int
    covariance_m2: FloatArray
    nuisance_covariance: FloatArray
    log_weight: float
    data_information: FloatArray
    prior_state: FloatArray
    chi2: float
    decrement: float
    token: str = ""

    @property
    def dimension(self) -> int:
        """The emitter variables' coordinates: 2, or 3 with the height unknown."""
        return (len(self.theta) - len(self.nuisance_covariance)) // self.n_variables

    @property
    def estimates_m(self) -> FloatArray:
        d = self.dimension
        return self.theta[: d * self.n_variables].reshape(-1, d)

    @property
    def nuisance(self) -> FloatArray:
        return self.theta[self.dimension * self.n_variables :]

    def mirrored(self, track: StraightTrack) -> NuisanceHypothesis:
        """The reflection across a straight track (MATH §7): positions mirrored, δ and β not."""
        positions = track.mirror_point(self.estimates_m).ravel()
        prior = self.prior_state.copy()
        prior[:2] = track.mirror_point(prior[:2])
        return replace(
            self,
            theta=np.concatenate([positions, self.nuisance]),
            covariance_m2=track.mirror_covariance(self.covariance_m2),
            data_information=track.mirror_covariance(self.data_information),
            prior_state=prior,
            token="",
        )

    def extended(self, random_walk: bool) -> FloatArray:
        """The warm start for one more frame: the new variable at the last one."""
        if not random_walk:
            return self.theta
        last = self.estimates_m[-1]
        return np.concatenate([self.estimates_m.ravel(), last, self.nuisance])


@dataclass(frozen=True, slots=True)
class Problem:
    """What every solve of one estimate shares: the frames, the random-walk steps, the diffuse
    priors' σ and the Levenberg-Marquardt cap."""

    frames: tuple[NuisanceFrame, ...]
    steps: FloatArray
    prior_sigmas: FloatArray
    random_walk: bool
    max_iterations: int
    _measuring: tuple[NuisanceFrame, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # a static emitter: the frames stacked once (stacked_frames), for every graph and fit
        static = not self.random_walk and len(self.frames) > 1
        measuring = (stacked_frames(self.frames),) if static else self.frames
        object.__setattr__(self, "_measuring", measuring)

    @property
    def n_variables(self) -> int:
        return len(self.frames) if self.random_walk else 1

    @property
    def dimension(self) -> int:
        """The emitter variables' coordinates: 2, or 3 with the height unknown."""
        return self.frames[0].dimension

    def graph(self, prior_state: FloatArray, first: int = 0) -> Any:
        """The factor graph of ``frames[first:]`` (:func:`nuisance_graph`)."""
        return nuisance_graph(
            self._measuring if first == 0 else self.frames,
            prior_state,
            self.prior_sigmas,
            self.steps,
            random_walk=self.random_walk,
            first=first,
        )

    def fit(self, theta: FloatArray, prior_state: FloatArray) -> NuisanceFit:
        return nuisance_fit(
            self._measuring,
            theta,
            random_walk=self.random_walk,
            step_sigmas=self.steps,
            prior_state=prior_state,
            prior_sigmas=self.prior_sigmas,
        )


LM_RELATIVE_ERROR_TOL = 1e-10
"""Levenberg-Marquardt ends after an iteration that lowered the graph's error by at most this
fraction. At 1e-15 it ran on to the rounding floor: after the last step that counts, some
twenty more evaluations of the graph while the damping climbed to its ceiling and every
shorter step was rejected at rounding level. The decrement checks below decide convergence."""


def _converged(fit: NuisanceFit) -> bool:
    return fit.decrement <= max(DECREMENT_TOL, COST_ROUNDING_RTOL * fit.chi2)


def lm_solve(
    problem: Problem, start: FloatArray, prior_state: FloatArray, *, escape: bool = True
) -> tuple[NuisanceHypothesis, int, str]:
    """Levenberg-Marquardt on the whole graph from the flat state ``start``, checked (module
    text). Returns ``(hypothesis, iterations, fallback)`` (``""``, ``"newton"`` or
    ``"saddle-escape"``); raises :class:`EstimationFailure` when it did not converge."""
    n_var, d = problem.n_variables, problem.dimension
    graph = problem.graph(prior_state)
    result, start_error, end_error, iterations = gtsam_levenberg_marquardt(
        graph,
        nuisance_values(start, n_var, d),
        problem.max_iterations,
        relative_error_tol=LM_RELATIVE_ERROR_TOL,
        solver=linear_solver(d, problem.random_walk),
    )
    if not end_error <= start_error * (1.0 + COST_RISE_RTOL):
        raise EstimationFailure("Levenberg-Marquardt raised the cost")
    theta = read_values(result, n_var, d)
    fit = problem.fit(theta, prior_state)
    fallback = ""
    if not _converged(fit):  # finish it by Newton's method on the whole graph
        theta, fit, n_newton, _ = newton_descent(
            partial(problem.fit, prior_state=prior_state), theta, fit
        )
        iterations += n_newton
        fallback = "newton"
        if not _converged(fit) or not fit.chi2 <= 2.0 * end_error * (1.0 + COST_RISE_RTOL):
            raise EstimationFailure(
                f"Levenberg-Marquardt did not converge (decrement {fit.decrement:.3g} > "
                f"{DECREMENT_TOL:g}), nor did Newton's method after it"
            )
    direction = fit.saddle_direction()
    if direction is not None:
        saddle = "the solve stopped at a saddle point of the cost (negative curvature)"
        if not escape:
            raise EstimationFailure(saddle)
        full = np.concatenate([np.tile(direction[:d], n_var), direction[d:]])
        length = float(problem.prior_sigmas[0]) / DIFFUSE_PRIOR_SCALE
        best, best_chi2 = None, fit.chi2
        for probe in escape_probes(theta, full, length):
            try:
                chi2 = problem.fit(probe, prior_state).chi2
            except EstimationFailure:
                continue
            if chi2 < best_chi2:
                best, best_chi2 = probe, chi2
        if best is None:
            raise EstimationFailure(f"{saddle}; no lower start off it")
        escaped, more, _ = lm_solve(problem, best, prior_state, escape=False)
        return escaped, iterations + more, "saddle-escape"
    return _hypothesis(problem, graph, result, theta, fit, prior_state), iterations, fallback


def _hypothesis(
    problem: Problem,
    graph: Any,
    result: Any,
    theta: FloatArray,
    fit: NuisanceFit,
    prior_state: FloatArray,
) -> NuisanceHypothesis:
    """The hypothesis at ``θ``: GTSAM's marginal covariance of the last emitter variable (the
    fit's where GTSAM's Marginals raise or ``θ`` moved past LM's result)."""
    import gtsam
    from gtsam.symbol_shorthand import X

    n_var, d = problem.n_variables, problem.dimension
    last = slice(d * n_var - d, d * n_var)
    covariance = fit.covariance[last, last]
    if np.array_equal(theta, read_values(result, n_var, d)):
        try:
            covariance = np.asarray(
                gtsam.Marginals(graph, result).marginalCovariance(X(n_var - 1)), dtype=float
            )
        except RuntimeError:
            pass
    return NuisanceHypothesis(
        theta=np.array(theta, dtype=float),
        n_variables=n_var,
        covariance_m2=0.5 * (covariance + covariance.T),
        nuisance_covariance=fit.covariance[d * n_var :, d * n_var :],
        log_weight=fit.log_evidence,
        data_information=fit.data_information,
        prior_state=np.array(prior_state, dtype=float),
        chi2=fit.chi2,
        decrement=fit.decrement,
    )


def best_solve(
    problem: Problem, starts: Sequence[FloatArray], prior_state: FloatArray
) -> tuple[NuisanceHypothesis, int, str]:
    """The first start's checked solve; if it fails, the lowest-cost converged solve of the
    others. Returns ``(hypothesis, iterations, fallback_reason)`` (empty when the first start
    converged); raises :class:`EstimationFailure` with every reason when none did."""
    reasons = []
    best: tuple[NuisanceHypothesis, int] | None = None
    for index, start in enumerate(starts):
        try:
            hypothesis, iterations, _ = lm_solve(problem, start, prior_state)
        except EstimationFailure as error:
            reasons.append(str(error))
            continue
        if index == 0:
            return hypothesis, iterations, ""
        if best is None or hypothesis.chi2 < best[0].chi2:
            best = (hypothesis, iterations)
    if best is None:
        raise EstimationFailure("; ".join(dict.fromkeys(reasons)))
    return best[0], best[1], "; ".join(dict.fromkeys(reasons))


# --------------------------------------------------------------------------------------------
# streaming: the nuisance as ISAM2 variables
# --------------------------------------------------------------------------------------------

NUISANCE_ANCHOR_KEYS = (ANCHOR_KEY, ANCHOR_KEY + 1)
"""``gtsam.symbol('z', 0)`` and ``('z', 1)``: two disconnected anchor variables with unit priors
that keep a static graph's updates incremental (``X(0)`` and ``N(0)`` are then half of the
variables, below the 65 % at which ISAM2 re-eliminates in batch;
:mod:`estimators.sequential.smoother_hypotheses`)."""


def seeded_isam2(
    problem: Problem, theta: FloatArray, prior_state: FloatArray, length_scale_m: float
) -> Any:
    """A new ISAM2 holding every frame of ``problem``, linearised at ``θ`` (one bare update, no
    step taken), with the anchors of :data:`NUISANCE_ANCHOR_KEYS`."""
    import gtsam

    graph = problem.graph(prior_state)
    values = nuisance_values(theta, problem.n_variables)
    for key in NUISANCE_ANCHOR_KEYS:
        graph.add(gtsam.PriorFactorPoint2(key, np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
        values.insert(key, np.zeros(2))
    isam = gtsam.ISAM2(isam2_params(length_scale_m))
    isam.update(graph, values)
    return isam


def isam2_update(
    problem: Problem, hypothesis: NuisanceHypothesis, length_scale_m: float
) -> tuple[NuisanceHypothesis, int]:
    """One streaming update of a hypothesis (module text, "Streaming"): its ISAM2 (from the
    per-process cache, or seeded at its optimum on the earlier frames) gets the last frame's
    factor (and link), steps until no variable needs relinearising, and Newton's method on the
    exact fit finishes ISAM2's estimate. Returns ``(hypothesis, iterations)`` (ISAM2 steps plus
    Newton iterations); raises :class:`EstimationFailure` when the result fails its checks (not
    converged, the cost rose from the previous optimum's, a saddle) or GTSAM raised."""
    import gtsam
    from gtsam.symbol_shorthand import X

    n_frames, n_var, t = len(problem.frames), problem.n_variables, len(problem.frames) - 1
    prior_state = hypothesis.prior_state
    threshold = RELINEARIZE_RTOL * length_scale_m
    start = hypothesis.extended(problem.random_walk)
    new_frame = problem.frames[-1]
    residual = new_frame.whitened_error(
        np.concatenate([start[2 * n_var - 2 : 2 * n_var], start[2 * n_var :]])
    )
    start_chi2 = hypothesis.chi2 + float(residual @ residual)  # the new variable adds no step
    try:
        isam = checkout(hypothesis.token, n_frames - 1)
        if isam is None:
            earlier = replace(
                problem,
                frames=problem.frames[:-1],
                steps=problem.steps[: max(n_frames - 2, 0)],
            )
            isam = seeded_isam2(earlier, hypothesis.theta, prior_state, length_scale_m)
        graph = problem.graph(prior_state, first=t)
        values = gtsam.Values()
        if problem.random_walk:
            values.insert(X(t), np.array(start[2 * t : 2 * t + 2]))
        isam.update(graph, values)
        steps = 1
        while np.max(np.abs(np.asarray(isam.getDelta().vector()))) >= threshold:
            if steps >= MAX_ISAM2_STEPS:
                break
            isam.update()
            steps += 1
        estimate = read_values(isam.calculateEstimate(), n_var)
    except RuntimeError as error:
        raise EstimationFailure(f"ISAM2 failed: {error}") from None
    fit_of = partial(problem.fit, prior_state=prior_state)
    fit = None
    if np.all(np.isfinite(estimate)):
        try:
            fit = fit_of(estimate)
        except EstimationFailure:
            fit = None
    if fit is None or not fit.chi2 <= start_chi2:
        # ISAM2's undamped steps went uphill (the flat valley of a straight pass): Newton's
        # method starts from the previous optimum instead, and the ISAM2 is seeded anew
        estimate, fit, isam = start, fit_of(start), None
    theta, fit, n_newton, _ = newton_descent(
        fit_of,
        estimate,
        fit,
        step_tolerance_m=POLISH_RTOL * length_scale_m,
        halvings=POLISH_HALVINGS,
    )
    problems = []
    if not _converged(fit):
        problems.append(f"not converged (decrement {fit.decrement:.3g})")
    if not fit.chi2 <= start_chi2 + COST_RISE_RTOL * max(start_chi2, 1.0):
        problems.append(f"the cost rose from {start_chi2:.6g} to {fit.chi2:.6g}")
    if fit.saddle_direction() is not None:
        problems.append("it ended at a saddle point of the cost (negative curvature)")
    if problems:
        raise EstimationFailure("; ".join(problems))
    last = slice(2 * n_var - 2, 2 * n_var)
    covariance = fit.covariance[last, last]
    return (
        NuisanceHypothesis(
            theta=np.array(theta, dtype=float),
            n_variables=n_var,
            covariance_m2=covariance,
            nuisance_covariance=fit.covariance[2 * n_var :, 2 * n_var :],
            log_weight=fit.log_evidence,
            data_information=fit.data_information,
            prior_state=np.array(prior_state, dtype=float),
            chi2=fit.chi2,
            decrement=fit.decrement,
            token="" if isam is None else checkin(isam, n_frames),
        ),
        steps + n_newton,
    )


def streamed_solve(
    problem: Problem, hypothesis: NuisanceHypothesis, length_scale_m: float
) -> tuple[NuisanceHypothesis, int, str]:
    """:func:`isam2_update`; when it fails, the fallback: :func:`best_solve` of the whole graph
    from the previous optimum and from the hypothesis's start. Returns ``(hypothesis,
    iterations, fallback_reason)`` (empty when ISAM2's update passed its checks)."""
    try:
        updated, iterations = isam2_update(problem, hypothesis, length_scale_m)
        return updated, iterations, ""
    except EstimationFailure as error:
        reason = f"ISAM2: {error}"
    restart = _flat_start(hypothesis.prior_state, problem.n_variables)
    starts = [hypothesis.extended(problem.random_walk), restart]
    try:
        solved, iterations, more = best_solve(problem, starts, hypothesis.prior_state)
    except EstimationFailure as error:
        raise EstimationFailure(
            f"{reason}; the re-solve of the whole graph failed too: {error}"
        ) from None
    return solved, iterations, f"{reason}; {more}" if more else reason


# --------------------------------------------------------------------------------------------
# the estimator's state, batch and streaming
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class NuisanceSmootherState(SmootherState):
    """:class:`~estimators.sequential.smoother_hypotheses.SmootherState` with nuisance frames and
    hypotheses (MATH §15) and the prior's standard deviations of the nuisance variables; an
    immutable, picklable value (no GTSAM object)."""

    prior_sigmas: FloatArray = field(default_factory=lambda: np.empty(0))


def _problem(
    frames: tuple[NuisanceFrame, ...], prior_sigmas: FloatArray, options: dict[str, Any]
) -> Problem:
    random_walk = options["process_noise_mps"] > 0.0
    steps = step_sigmas_m(frames, options["process_noise_mps"]) if random_walk else np.empty(0)
    return Problem(frames, steps, prior_sigmas, random_walk, options["max_iterations"])


def _flat_start(state: FloatArray, n_variables: int, dimension: int = 2) -> FloatArray:
    d = dimension
    return np.concatenate([np.tile(state[:d], n_variables), state[d:]])


MISFIT_ALPHA = 1e-3
"""False-alarm level of the misfit test of :func:`rescued` (as the cooperative smoother's)."""


def rescued(
    problem: Problem, hypotheses: list[NuisanceHypothesis], frames: Sequence[NuisanceFrame]
) -> tuple[list[NuisanceHypothesis], str]:
    """``hypotheses`` and, when the best misfits the data, the lowest converged solve from the
    start pairs of ``frames`` that beats it (module text, "Starts from later frames"), with
    the note saying so (empty when none was added)."""
    from scipy.special import chdtri

    best = min(h.chi2 for h in hypotheses)
    measurements = sum(frame.n_rows for frame in problem.frames)
    if not best > chdtri(measurements, MISFIT_ALPHA):
        return hypotheses, ""
    found: tuple[NuisanceHypothesis, int] | None = None
    for index, frame in enumerate(frames):
        try:
            pair = straight_frame_starts(frame)
        except EstimationFailure:
            continue
        for start in pair:
            state = np.concatenate([start[:2], profile_nuisance(problem.frames, start[:2])])
            try:
                solved, _, _ = lm_solve(problem, _flat_start(state, problem.n_variables), state)
            except EstimationFailure:
                continue
            if solved.chi2 < (best if found is None else found[0].chi2):
                found = (solved, index)
    if found is None:
        return hypotheses, ""
    frame_index = len(problem.frames) - len(frames) + found[1]
    return [*hypotheses, found[0]], (
        f"the optimum from the first frame's starts misfits the data (χ² {best:.6g} for "
        f"{measurements} measurements); frame {frame_index}'s start found χ² {found[0].chi2:.6g}"
    )


def estimate(
    data: MeasurementSet, options: dict[str, Any], rng: np.random.Generator | None
) -> Estimate:
    """The batch estimate (``GtsamSmoother.estimate`` with unknowns): every hypothesis's full
    graph solved and checked. ``options``: ``name``, ``process_noise_mps``,
    ``max_iterations``."""
    names = nuisance_names(data)
    frames = tuple(frame_model(frame, names) for frame in data.iter_frames())
    if frames[0].dimension == 3:  # the height unknown
        try:
            state = height_start(frames, options, mode="batch")  # type: ignore[arg-type]
        except EstimationFailure as error:
            return Estimate.failed(options["name"], str(error), frames=len(frames))
        return estimate_state(state, options, rng)
    try:
        starts = straight_frame_starts(frames[0])
        length_scale = frames[0].mean_range_m(starts[0])
        sigmas = diffuse_sigmas(frames[0], length_scale)
        problem = _problem(frames, sigmas, options)
        first_track = StraightTrack.of_frame(frames[0])
        track = first_track
        for frame in frames[1:]:
            track = None if track is None else track.extended(frame)
        chosen = hypothesis_starts(starts, first_track, track)
        hypotheses, fallbacks, iterations = [], [], 0
        solved: dict[bytes, tuple[NuisanceHypothesis, int, str]] = {}
        for start in chosen:
            # a start on the first track is its own mirror image: the same solve, done once
            key = start.tobytes()
            if key not in solved:
                solved[key] = lm_solve(problem, _flat_start(start, problem.n_variables), start)
            hypothesis, n, fallback = solved[key]
            hypotheses.append(hypothesis)
            fallbacks.append(fallback)
            iterations = max(iterations, n)
        restart = ""
        if track is None:
            hypotheses, restart = rescued(problem, hypotheses, frames[1:])
    except EstimationFailure as error:
        return Estimate.failed(options["name"], f"batch solve: {error}", frames=len(frames))
    state = NuisanceSmootherState(
        frames=frames,
        hypotheses=tuple(hypotheses),
        track=track,
        length_scale_m=length_scale,
        prior_sigmas=sigmas,
        iterations=iterations,
        diagnostics={
            "mode": "batch",
            "max_iterations": options["max_iterations"],
            "decrement": max(h.decrement for h in hypotheses),
            "lm_fallback": "+".join(dict.fromkeys(f for f in fallbacks if f)) or "none",
            "misfit_restart": restart,
        },
    )
    return estimate_state(state, options, rng)


def update(
    state: NuisanceSmootherState, frame: MeasurementSet, options: dict[str, Any]
) -> NuisanceSmootherState:
    """The state after one more frame: every hypothesis's ISAM2 extended by it
    (:func:`streamed_solve`, module text "Streaming"); a hypothesis whose update fails its
    checks is re-solved whole by Levenberg-Marquardt (a fallback, reported)."""
    names = state.frames[0].names if state.frames else nuisance_names(frame)
    model = frame_model(frame, names)
    assert isinstance(model, NuisanceFrame)
    frames = (*state.frames, model)
    if state.failure:
        return replace(state, frames=frames)
    try:
        if model.dimension == 3:
            return _height_update(state, frames, options)
        if not state.frames:
            starts = straight_frame_starts(model)
            length_scale = model.mean_range_m(starts[0])
            track = StraightTrack.of_frame(model)
            state = replace(
                state,
                length_scale_m=length_scale,
                prior_sigmas=diffuse_sigmas(model, length_scale),
            )
            problem = _problem(frames, state.prior_sigmas, options)
            chosen = hypothesis_starts(starts, track, track)
            solved = [best_solve(problem, [_flat_start(s, 1)], s) for s in chosen]
        else:
            track = None if state.track is None else state.track.extended(model)
            problem = _problem(frames, state.prior_sigmas, options)
            previous = list(state.hypotheses)
            if state.track is not None and track is None:  # off the line: fork the mirror
                first = state.hypotheses[0]
                mirror = first.mirrored(state.track)
                distance = np.linalg.norm(mirror.estimates_m[-1] - first.estimates_m[-1])
                if distance > MERGE_RTOL * state.length_scale_m:
                    previous.append(mirror)
            solved = [streamed_solve(problem, h, state.length_scale_m) for h in previous]
    except EstimationFailure as error:
        return replace(state, frames=frames, failure=str(error))
    updated = [hypothesis for hypothesis, _, _ in solved]
    restart = ""
    if track is None:
        updated, restart = rescued(problem, updated, frames[-1:])
        updated = pruned_hypotheses(updated, state.length_scale_m)
    reasons = [reason for _, _, reason in solved if reason]
    return replace(
        state,
        frames=frames,
        hypotheses=tuple(updated),
        track=track,
        iterations=max(n for _, n, _ in solved),
        diagnostics={
            **state.diagnostics,
            "decrement": max(h.decrement for h in updated),
            "misfit_restart": restart,
        },
        fallback_reason="; ".join(dict.fromkeys(reasons)),
        fallbacks=state.fallbacks + bool(reasons),
    )


def estimate_state(
    state: NuisanceSmootherState, options: dict[str, Any], rng: np.random.Generator | None
) -> Estimate:
    """The estimate of the last emitter variable, with the returned hypothesis's nuisance
    values in ``diagnostics`` (``carrier_offset_hz``, ``emission_time_s``, MATH §15)."""
    name = options["name"]
    if not state.frames:
        return Estimate.failed(name, "no frame has been processed yet", frames=0)
    d = state.frames[0].dimension  # 3 with the height unknown
    height = d == 3
    if state.failure:
        return Estimate.failed(name, state.failure, dimension=d, frames=state.n_frames)
    if height and not state.hypotheses:  # every frame so far on one straight track
        return Estimate.failed(name, STRAIGHT_TRACK_HEIGHT, dimension=3, frames=state.n_frames)
    hypotheses = state.all_hypotheses()
    diagnostics: dict[str, Any] = {"mode": "streaming", **state.diagnostics}
    notes = [diagnostics["misfit_restart"]] if diagnostics.get("misfit_restart") else []
    if diagnostics["mode"] == "streaming":
        diagnostics.update(
            fallback="batch" if state.fallback_reason else "none",
            fallback_reason=state.fallback_reason,
            fallbacks=state.fallbacks,
        )
        if state.fallback_reason:
            notes.append(
                f"ISAM2's update of frame {state.n_frames - 1} failed its checks "
                f"({state.fallback_reason}); fell back to Levenberg-Marquardt on the whole graph"
            )
    result = smoother_estimate(
        name,
        state,
        hypotheses,
        rng=rng,
        notes=notes,
        diagnostics=diagnostics,
        random_walk=options["process_noise_mps"] > 0.0,
        ceiling_m=max(float(f.position_m[:, 2].max()) for f in state.frames) if height else None,
    )
    if not result.success:
        return result
    chosen = min(
        hypotheses, key=lambda h: float(np.linalg.norm(h.estimates_m[-1] - result.position_m))
    )
    extra = nuisance_diagnostics(
        state.frames[0].names,
        chosen.nuisance,
        chosen.nuisance_covariance,
        state.frames[0].speed_of_light_mps,
    )
    return replace(result, diagnostics={**result.diagnostics, **extra})


# --------------------------------------------------------------------------------------------
# the height unknown (MATH §7, §8)
# --------------------------------------------------------------------------------------------


def height_start(
    frames: tuple[NuisanceFrame, ...], options: dict[str, Any], *, mode: str
) -> NuisanceSmootherState:
    """The hypotheses with the height unknown too: Levenberg-Marquardt on the whole graph (a
    ``Point3`` and the nuisance vector) from each start on the first frame's ambiguity circle
    below the UAV (:func:`~estimators.sequential.nuisance_starts.height_starts`); the converged
    ones, merged and pruned. Raises :class:`EstimationFailure` on a straight track
    (:data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`) or when no solve converged."""
    starts = height_starts(frames)
    length_scale = frames[0].mean_range_m(starts[0])
    sigmas = diffuse_sigmas(frames[0], length_scale)
    problem = _problem(frames, sigmas, options)
    hypotheses, fallbacks, reasons, iterations = [], [], [], 0
    for start, initial in _height_initial_values(problem, starts, length_scale, options):
        try:
            hypothesis, n, fallback = lm_solve(problem, initial, start)
        except EstimationFailure as error:
            reasons.append(str(error))
            continue
        hypotheses.append(hypothesis)
        fallbacks.append(fallback)
        iterations = max(iterations, n)
    if not hypotheses:
        raise EstimationFailure(f"batch solve: {'; '.join(dict.fromkeys(reasons))}")
    return NuisanceSmootherState(
        frames=frames,
        hypotheses=tuple(pruned_hypotheses(hypotheses, length_scale)),
        track=None,
        length_scale_m=length_scale,
        prior_sigmas=sigmas,
        iterations=iterations,
        diagnostics={
            "mode": mode,
            "max_iterations": options["max_iterations"],
            "decrement": max(h.decrement for h in hypotheses),
            "lm_fallback": "+".join(dict.fromkeys(f for f in fallbacks if f)) or "none",
        },
    )


def _height_initial_values(
    problem: Problem, starts: FloatArray, length_scale_m: float, options: dict[str, Any]
) -> list[tuple[FloatArray, FloatArray]]:
    """Each hypothesis's ``(prior state, flat initial state)`` with the height unknown, as in
    the cooperative smoother (:mod:`estimators.sequential.gtsam_smoother`, "The height
    unknown"): each start for a static emitter; with a random walk, every frame's variable at
    the static optimum (and its nuisance values) reached from a start, each optimum once, or
    at the start where that solve did not converge. On noise-free climbing turns with one or
    both offsets unknown (σ's at 100 dB) the walk from a start on the first frame's circle took up
    to 0.34 s of CPU time a batch estimate, from the static optima 0.02-0.1 s."""
    if not problem.random_walk:
        return [(start, _flat_start(start, 1, 3)) for start in starts]
    static = _problem(problem.frames, problem.prior_sigmas, {**options, "process_noise_mps": 0.0})
    initial: list[tuple[FloatArray, FloatArray]] = []
    for start in starts:
        state = start
        try:
            state = lm_solve(static, _flat_start(start, 1, 3), start)[0].theta
        except EstimationFailure:
            pass  # the walk starts at the start itself (and its solve is checked)
        if all(
            np.linalg.norm(state[:3] - flat[:3]) > MERGE_RTOL * length_scale_m
            for _, flat in initial
        ):
            initial.append((start, _flat_start(state, problem.n_variables, 3)))
    return initial


def _height_update(
    state: NuisanceSmootherState, frames: tuple[NuisanceFrame, ...], options: dict[str, Any]
) -> NuisanceSmootherState:
    """A streaming update with the height unknown (as the cooperative smoother's): the frames
    of the first straight track wait, the first frame off it starts the hypotheses
    (:func:`height_start`), a later frame re-solves each hypothesis's whole graph by checked
    Levenberg-Marquardt from its previous optimum."""
    if not state.hypotheses:
        if len(frames) == 1:
            track = StraightTrack.of_frame(frames[0])
        else:
            track = None if state.track is None else state.track.extended(frames[-1])
        if track is not None:
            return replace(state, frames=frames, track=track)
        return height_start(frames, options, mode="streaming")
    problem = _problem(frames, state.prior_sigmas, options)
    solved = [
        lm_solve(problem, h.extended(problem.random_walk), h.prior_state) for h in state.hypotheses
    ]
    updated = [hypothesis for hypothesis, _, _ in solved]
    return replace(
        state,
        frames=frames,
        hypotheses=tuple(pruned_hypotheses(updated, state.length_scale_m)),
        iterations=max(n for _, n, _ in solved),
        diagnostics={**state.diagnostics, "decrement": max(h.decrement for h in updated)},
    )
