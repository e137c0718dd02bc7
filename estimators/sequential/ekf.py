r"""Frame-by-frame Kalman filtering of the emitter position with the mirror pair (MATH §1, §7, §8).

State ``s = (x_s, y_s)`` (a 1-D array: filterpy broadcasts a (2, 1) one), a random walk between frames

.. math::

    s_{t} = s_{t-1} + \nu_t,\qquad \nu_t \sim N\big(0, (q\,\Delta t_t)^2 I\big)

with ``q = process_noise_mps`` (0: a static emitter) and ``Δt_t`` the time between the frames'
mean sample times. Each frame is one update with its stacked measurements
``z = [f_1..f_K, c τ_1..c τ_K]`` (Doppler in Hz, physical sign; ToA as range in metres, MATH §1)
and ``R = diag(σ_f², …, σ_r², …)``, ``σ_r = c σ_τ``.

**Initialisation without counting the first frame twice.** The closed form
(:class:`estimators.closed_form.cls.Cls`, MATH §5-§6) on the first frame gives the mirror
candidates. They serve only as *starting points*: the first frame's update runs from each candidate
with a diffuse prior (:mod:`estimators.sequential.mirror_hypotheses`), in information form, i.e.
Gauss-Newton to the first frame's maximum likelihood; its covariance is the inverse Fisher
information there (MATH §8). The first frame's data thus enter once, through that update. Later
frames are (iterated) EKF updates by filterpy's ``ExtendedKalmanFilter``, or unscented updates
(``filter="ukf"``, filterpy's ``UnscentedKalmanFilter``).

**Iterated EKF.** ``max_iterations > 1`` relinearises at the updated mean (the IEKF:
Gauss-Newton on the frame's posterior, with step halving when the cost rises), each pass a
filterpy update of the same prior with the measurement function linearised at the current
iterate, ``h(s) ≈ h(s_i) + H_i (s − s_i)``; ``max_iterations=1`` is the plain EKF. On the
paper geometry at 0 dB (4 frames east, 6 north) one pass already reaches the accumulated CRLB,
because the first frame is iterated to its maximum likelihood. At −15 dB the prediction after
the turn is metres off and one pass is not enough: over 400 trials the plain EKF's RMSE was
14 % above the CRLB with a mean NEES of 2.64, the IEKF's 2 % above with 2.12.

**Convergence.** Every iterated update (the first frame's and the IEKF's) reports whether it
converged (:class:`estimators.convergence.SolverReport`: iterations against the cap, the
decrement of the frame's posterior cost against ``DECREMENT_TOL``, no cost rise). Near the
track Gauss-Newton creeps along a flat valley and stops short of the on-track minimum (at
−20 dB on ``paper-1m-turn``, on the first frame of 33 of 500 trials, a median 0.14 m and up to
0.35 m short, reported as a success); then Newton's method with the exact Hessian finishes the
update from the last iterate (the documented fallback,
:func:`estimators.convergence.finish_update`). A start on the track's vertical plane (the
closed form's on-track candidate) stays on it by symmetry after the posterior's minimum has
moved off the track, so an update that ends at a saddle of the posterior cost restarts off it
along the negative curvature (the mirror hypothesis covers the other side); the conformance
check ``check_leaves_the_track`` holds every estimator to leaving such a start once the data put
the emitter off the track. On that sweep 140
of 5000 updates took a fallback (51 Newton, 89 saddle restarts), all before the turn, and none
failed; at 0 dB none did.
``message`` and ``diagnostics`` say so (``fallback`` ``"newton"`` or ``"saddle-escape"``,
``fallback_reason``, the running count ``fallbacks``). If that does not converge either, or
the cost rose, the estimate fails with the reason from then on (a later frame cannot undo a
wrong update). The last update's figures are in ``diagnostics``
(``update_iterations``, ``max_iterations``, ``decrement``, ``converged``). The plain EKF
(``max_iterations=1``) and the UKF make one pass by design and are not checked.

**Mirror hypotheses** (MATH §7). One filter per mirror candidate, weighted by the frames'
predictive likelihoods (:func:`estimators.convergence.laplace_log_likelihood`, the innovation
likelihood ``N(z; h(s̄), H P̄ Hᵀ + R)`` evaluated at the iterated mode), pruned when one weight
exceeds ``1 − 1e−9``. While the track is straight the second filter is the exact reflection of
the first, so the weights stay exactly equal and the estimate ambiguous. After a turn the mirror
filter is pulled to the true side but held short by its prior, linearised on the mirror side:
at −20 dB on ``paper-1m-turn`` 44 % of the trials reported that second candidate, a median
1.9 m from the first. The two are one answer when their weighted Gaussians form a unimodal
mixture; they are then merged, the heavier kept with the weights added
(:func:`estimators.sequential.mirror_hypotheses.surviving_hypotheses`, ``single_mode``).

**Unknown nuisance parameters** (MATH §15). When the data declare the carrier offset δ or the
emission time b unknown (``data.unknowns``), they are carried as constant states after the
position (:mod:`estimators.sequential.nuisance_states`): no process noise on them, the emitter's
random step moving them only through their reference (``M ν``), their Jacobian columns 1 on their
rows. They are held as the offset Doppler and pseudo-range at the first frame's mean sample
(``D = δ + f₀(s)``, ``R = c b + ρ₀(s)``), where the first frames' likelihood is close to
Gaussian: in the physical ``(δ, c b)`` the IEKF's RMSE on ``paper-1m-turn`` with both unknown
was 26× the nuisance CRLB at 20 dB, in ``(D, R)`` 0.97×. The closed form cannot start the
first frame then; the linear rows and the cross-track scan of
:mod:`estimators.sequential.nuisance_starts` do, with a diffuse prior on every state, and the first
update is iterated to the frame's maximum likelihood as before. The reported covariance is the state
covariance's position block; ``diagnostics`` add the returned hypothesis's ``carrier_offset_hz``
and ``emission_time_s`` (physical values, with ``…_sigma_hz``, ``…_sigma_s``). What the filter
cannot fix is the first frames' own non-Gaussian posterior: one straight frame with an
unknown offset fixes the emitter only along a curve (the first frame's nuisance CRLB on
``turn`` is 16 m with δ unknown, 35 m with b unknown, against 1.06 m with both known, at
0 dB), and the Gaussian that summarises it biases the updates after the turn until the SNR is
high. Over 300 trials on ``turn`` the RMSE was 3.3× the nuisance CRLB at 10 dB, 1.24× at 20 dB
and 0.99× at 40 dB with δ unknown; 8.6×, 4.1× and 1.02× with b unknown; 1.04×, 1.01× and
1.00× with both (the smoother, :mod:`estimators.sequential.smoother_nuisance`, which relinearises
every frame, was within 1.04× at 0 dB in all three). The UKF (``filter="ukf"``) is worse at 20 dB
(1.7× with δ unknown, 2.5× with both) and as good at 40 dB.

**The height unknown** (MATH §7, §8). When the data declare ``"emitter_height_m"`` unknown the
state is ``(x_s, y_s, z_s)`` (then the nuisance states) and the covariance 3×3 (the frame
model in three coordinates, :class:`~estimators.frame_model.FrameModel`). A straight track
leaves a circle of equally likely emitters, which no Gaussian summarises: the frames of the
first straight track wait in the state (the estimate fails with the mirror rule's one line,
:data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`), and the first frame off the line starts
the hypotheses from all of them at once: from points of the first frame's circle below the UAV
(:func:`~estimators.sequential.nuisance_starts.circle_starts`), each iterated to the frames'
maximum likelihood, the converged ones merged and pruned. In a level flight a hypothesis above
the UAV is replaced by its reflection through the flight plane (the same likelihood), and a
hypothesis above the UAV's highest sample is no answer ("the emitter is below the UAV").
Later frames are the updates above in the 3-D state.

The state (:class:`EkfState`) is a frozen value of plain arrays; filterpy objects live only
inside one ``update`` call, so the state and the estimator pickle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from estimators.base import Capabilities, Estimate, require_modalities
from estimators.convergence import (
    EstimationFailure,
    SolverReport,
    finish_iterations,
    iterated_update,
    laplace_log_likelihood,
    lower_cost_step,
    map_cost,
    symmetric_inverse,
)
from estimators.frame_model import FrameModel, read_only
from estimators.goodness_of_fit import with_fit
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sequential.mirror_hypotheses import (
    diffuse_prior_information,
    first_frame_candidates,
    fisher_rank,
    hypotheses_estimate,
    hypothesis_starts,
    surviving_hypotheses,
    with_mirror,
)
from estimators.sequential.nuisance_starts import circle_starts, straight_frame_starts
from estimators.sequential.nuisance_states import (
    NUISANCE_UNKNOWNS,
    NuisanceFrame,
    check_same_unknowns,
    diffuse_information,
    frame_model,
    mirror_matrix,
    mirror_state,
    nuisance_diagnostics,
    nuisance_names,
    physical_nuisance,
    position_information,
    reference_sample,
)
from scenarios.geometry import StraightTrack
from scenarios.nuisance import HEIGHT_UNKNOWN, position_dimension
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
FilterKind = Literal["ekf", "ukf"]

STEP_RTOL = 1e-10
"""The IEKF stops when a step is shorter than ``STEP_RTOL ×`` the mean slant range."""

UKF_SIGMA_POINTS = {"alpha": 1.0, "beta": 2.0, "kappa": 1.0}
"""Van der Merwe's scaled sigma points for a 2-D state (``n + κ = 3``, Julier's choice)."""


def ukf_sigma_points(n: int) -> dict[str, float]:
    """The sigma-point parameters for an ``n``-dimensional state: :data:`UKF_SIGMA_POINTS` for
    the emitter alone; with nuisance states (MATH §15) ``κ = max(3 − n, 0)`` (Julier's
    ``n + κ = 3`` where it keeps the weights non-negative)."""
    if n == 2:
        return UKF_SIGMA_POINTS
    return {**UKF_SIGMA_POINTS, "kappa": float(max(3 - n, 0))}


FIRST_FRAME_ITERATIONS = 50
"""Gauss-Newton iterations of the first frame's update (to its maximum likelihood), at most."""

LEVEL_RTOL = 1e-9
"""A flight is level when its sample heights spread less than ``LEVEL_RTOL ×`` the range."""


def update_diagnostics(reports: list[SolverReport]) -> dict[str, Any]:
    """The last update's solver figures for ``Estimate.diagnostics``: the most iterations any
    hypothesis used, the cap (a Newton fallback's iterations included in both), the largest
    decrement (None for a single pass), whether every
    hypothesis converged, and the fallback taken (``"none"``, ``"newton"``,
    ``"saddle-escape"``) with its reason."""
    decrements = [r.decrement for r in reports if not math.isnan(r.decrement)]
    fallbacks = [r.fallback for r in reports if r.fallback]
    reasons = [r.fallback_reason for r in reports if r.fallback]
    return {
        "update_iterations": max(r.iterations for r in reports),
        "max_iterations": max(r.max_iterations for r in reports),
        "decrement": max(decrements) if decrements else None,
        "converged": all(r.converged for r in reports),
        "fallback": "+".join(dict.fromkeys(fallbacks)) or "none",
        "fallback_reason": "; ".join(dict.fromkeys(reasons)),
    }


# --------------------------------------------------------------------------------------------
# state
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class EkfHypothesis:
    """One mirror hypothesis: a Gaussian belief and its accumulated log likelihood.

    Attributes
    ----------
    mean_m : (n,)
        The state: ``(x_s, y_s)`` (``(x_s, y_s, z_s)`` with the height unknown), then the
        unknown nuisance parameters if any (δ in Hz, ``β = c b`` in metres;
        :mod:`estimators.sequential.nuisance_states`, MATH §15).
    covariance_m2 : (n, n)
    log_weight : float
        Sum of the frames' log predictive likelihoods (up to a constant shared by all).
    data_information : (n, n)
        Accumulated Fisher information of the data (MATH §8) at the updates' linearisation
        points, without prior or process noise; the rank of its position part
        (:func:`~estimators.sequential.nuisance_states.position_information`) says whether the data
        determine ``s``.
    """

    mean_m: FloatArray
    covariance_m2: FloatArray
    log_weight: float
    data_information: FloatArray

    def __post_init__(self) -> None:
        read_only(self.mean_m, self.covariance_m2, self.data_information)

    def mirrored(self, track: StraightTrack) -> EkfHypothesis:
        """The reflection across a straight track: same likelihood by MATH §7."""
        return EkfHypothesis(
            mean_m=mirror_state(track, self.mean_m),
            covariance_m2=mirror_matrix(track, self.covariance_m2),
            log_weight=self.log_weight,
            data_information=mirror_matrix(track, self.data_information),
        )

    def reflected(self, height_m: float) -> EkfHypothesis:
        """The reflection through the horizontal plane at ``height_m`` of a 3-D state
        (``z_s ↦ 2h − z_s``): same likelihood for a level flight at that height (MATH §7; the
        referenced nuisance states, of a level reference sample, unchanged)."""
        flip = np.ones(len(self.mean_m))
        flip[2] = -1.0
        mean = self.mean_m.copy()
        mean[2] = 2.0 * height_m - mean[2]
        return EkfHypothesis(
            mean_m=mean,
            covariance_m2=flip[:, None] * self.covariance_m2 * flip,
            log_weight=self.log_weight,
            data_information=flip[:, None] * self.data_information * flip,
        )


@dataclass(frozen=True, slots=True, eq=False)
class EkfState:
    """Everything the filter knows after some frames; an immutable value.

    While ``track`` is not None (every frame so far on one straight line), ``hypotheses`` holds
    only the first hypothesis and the second is its reflection across ``track``. ``nuisance``
    names the unknown nuisance parameters carried in the state after the position (MATH §15;
    empty for a cooperative emitter), as offset measurements at the ``reference`` sample (the
    first frame's mean; :mod:`estimators.sequential.nuisance_states`); ``speed_of_light_mps``
    converts ``β`` to ``b``.

    With the height unknown (``dimension`` 3) the frames of the first straight track wait in
    ``pending`` (no hypothesis yet: a straight track cannot fix the height) until a frame
    leaves the line; ``highest_m`` is the UAV's highest sample height so far (MATH §7: a
    hypothesis above it is no answer).
    """

    hypotheses: tuple[EkfHypothesis, ...] = ()
    track: StraightTrack | None = None
    length_scale_m: float = math.nan
    time_s: float = math.nan
    n_frames: int = 0
    iterations: int = 0
    failure: str = ""
    diagnostics: dict[str, Any] = field(default_factory=dict)
    nuisance: tuple[str, ...] = ()
    reference: FrameModel | None = None
    speed_of_light_mps: float = math.nan
    dimension: int = 2
    pending: tuple[FrameModel | NuisanceFrame, ...] = ()
    highest_m: float = -math.inf

    def all_hypotheses(self) -> tuple[EkfHypothesis, ...]:
        """The explicit hypotheses plus, on a straight track, the mirror of the first."""
        return with_mirror(self.hypotheses, self.track)


# --------------------------------------------------------------------------------------------
# one update
# --------------------------------------------------------------------------------------------


def filterpy_update(
    kf: Any,
    frame: FrameModel | NuisanceFrame,
    prior_mean_m: FloatArray,
    prior_covariance_m2: FloatArray,
    predicted: FloatArray,
    jacobian: FloatArray,
    linearised_at: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """filterpy's update of the prior ``(s̄, P̄)`` with the measurement function linearised at
    ``linearised_at``, ``h(s) ≈ h(s_i) + H_i (s − s_i)`` (``predicted``, ``jacobian``: ``h(s_i)``
    and ``H_i``): the new mean and filterpy's Joseph-form covariance."""
    kf.x = prior_mean_m.copy()  # 1-D x: filterpy would broadcast a (2, 1) x
    kf.P = prior_covariance_m2.copy()
    kf.update(
        frame.measured,
        HJacobian=lambda _x: jacobian,
        Hx=lambda x: predicted + jacobian @ (x - linearised_at),
    )
    return np.array(kf.x, dtype=float), np.array(kf.P, dtype=float)


def ekf_update(
    frame: FrameModel | NuisanceFrame,
    prior_mean_m: FloatArray,
    prior_covariance_m2: FloatArray,
    *,
    max_iterations: int,
) -> tuple[FloatArray, FloatArray, SolverReport]:
    r"""One (iterated) EKF update by filterpy's ``ExtendedKalmanFilter``.

    Pass ``i`` linearises at the iterate ``s_i`` and applies the standard update to the prior
    ``(s̄, P̄)``: ``s_{i+1} = s̄ + K_i (z − h(s_i) − H_i (s̄ − s_i))``,
    ``K_i = P̄ H_iᵀ (H_i P̄ H_iᵀ + R)⁻¹`` (Gauss-Newton on the frame's posterior). The iterate is
    computed in information form, ``s_{i+1} = s_i − (P̄⁻¹ + H_iᵀR⁻¹H_i)⁻¹ g_i`` with ``g_i`` the
    cost's gradient, which is the same step without the gain's loss of ``cond(P̄)·ε``; the
    step ``s_{i+1} − s_i`` is halved while the posterior cost rises. Stops when a step is
    shorter than ``STEP_RTOL ×`` the range; the covariance is filterpy's Joseph-form ``P`` of
    the last pass (:func:`filterpy_update`, run once, on that pass's linearisation: the earlier
    passes' filterpy means are not used).

    Returns ``(mean_m, covariance_m2, report)``. The report (:class:`SolverReport`) says whether
    the iterate converged: the decrement
    (:func:`~estimators.convergence.stationarity_decrement`) of the frame's posterior cost at
    most ``DECREMENT_TOL`` and a cost no higher than at the prior mean. If it did not, Newton's
    method takes over from the last iterate (:func:`~estimators.convergence.finish_update`,
    ``report.fallback == "newton"``) and the covariance is the inverse posterior information
    at its result. ``max_iterations == 1`` is the plain EKF: one pass by design, reported as
    such (it makes no claim to reach the mode). With a :class:`NuisanceFrame` the state is
    ``(x_s, y_s, δ?, β?)`` (MATH §15) and everything above holds in that state.
    """
    from filterpy.kalman import ExtendedKalmanFilter

    prior_information = np.linalg.inv(prior_covariance_m2)
    scale = frame.mean_range_m(prior_mean_m)
    kf = ExtendedKalmanFilter(dim_x=len(prior_mean_m), dim_z=frame.n_rows)
    kf.R = np.diag(frame.sigma**2)
    point = prior_mean_m.copy()
    h_at_point, H = frame.predicted_and_jacobian(point)
    cost = map_cost(frame, point, prior_mean_m, prior_information, predicted=h_at_point)
    start_cost = cost
    mean, covariance = point, prior_covariance_m2
    iterations = 0
    small_step = stalled = False
    while iterations < max_iterations:
        iterations += 1
        linearised = (h_at_point, H, point)  # the last pass's linearisation: the covariance's
        if max_iterations == 1:
            mean, covariance = filterpy_update(
                kf, frame, prior_mean_m, prior_covariance_m2, *linearised
            )
            break
        # the iterate: the same Gauss-Newton step in information form, −(Λ̄ + EᵀE)⁻¹ g. The
        # filter's gain P̄Hᵀ(HP̄Hᵀ + R)⁻¹ is that step in exact arithmetic, but loses cond(P̄)·ε
        # of the prior's spread: after a first frame with nuisance states (cond(P̄) ≈ 4e13) it
        # is off by more than the step itself near the mode, and the iteration stalls at
        # rounding's whim. The filter's Joseph-form covariance is kept.
        whitened = H / frame.sigma[:, None]
        residual = (h_at_point - frame.measured) / frame.sigma
        gradient = whitened.T @ residual + prior_information @ (point - prior_mean_m)
        mean = point - np.linalg.solve(prior_information + whitened.T @ whitened, gradient)
        # the filter's own update first, evaluated once for its cost and, if taken, the next
        # linearisation; step halving (lower_cost_step) only when it raised the cost
        h_at_mean, H_at_mean = frame.predicted_and_jacobian(mean)
        mean_cost = map_cost(frame, mean, prior_mean_m, prior_information, predicted=h_at_mean)
        if mean_cost <= cost:
            point, cost, step = mean, mean_cost, mean - point
            h_at_point, H = h_at_mean, H_at_mean
        else:
            lower = lower_cost_step(
                frame, prior_mean_m, prior_information, point, mean - point, cost, first_trial=mean
            )
            if lower is None:
                mean = point  # no decrease along the Gauss-Newton direction
                stalled = True
                break
            point, cost, step = lower
            mean = point
            h_at_point, H = frame.predicted_and_jacobian(point)
        if np.linalg.norm(step) <= STEP_RTOL * scale:
            small_step = True
            break
    if max_iterations > 1:  # filterpy's pass on the last linearisation: its covariance
        _, covariance = filterpy_update(kf, frame, prior_mean_m, prior_covariance_m2, *linearised)
    covariance = 0.5 * (covariance + covariance.T)
    if max_iterations == 1:
        return mean, covariance, SolverReport(1, 1, float("nan"), True)
    # the report, then the documented fallbacks (Newton's method; a restart off a saddle); after
    # one the covariance is the inverse posterior information (what a last filterpy pass gives)
    mean, _, information, report = finish_iterations(
        frame,
        prior_mean_m,
        prior_information,
        mean,
        cost,
        start_cost=start_cost,
        iterations=iterations,
        max_iterations=max_iterations,
        stalled=stalled,
        small_step=small_step,
        what="the iterated EKF update",
    )
    if report.fallback:
        covariance = symmetric_inverse(information)
    return mean, covariance, report


def ukf_update(
    frame: FrameModel | NuisanceFrame, prior_mean_m: FloatArray, prior_covariance_m2: FloatArray
) -> tuple[FloatArray, FloatArray, float]:
    """One unscented update by filterpy's ``UnscentedKalmanFilter`` (identity motion), in the
    state of ``frame`` (with nuisance states, MATH §15, :func:`ukf_sigma_points`).

    Returns ``(mean_m, covariance_m2, log_likelihood)``, the last ``log N(y; 0, S)`` plus
    ``½ log det R`` (the convention of :func:`estimators.convergence.laplace_log_likelihood`).
    """
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    n = len(prior_mean_m)
    points = MerweScaledSigmaPoints(n, **ukf_sigma_points(n))
    kf = UnscentedKalmanFilter(
        dim_x=n, dim_z=frame.n_rows, dt=1.0, hx=frame.predicted, fx=lambda x, _dt: x, points=points
    )
    kf.x = prior_mean_m.copy()
    kf.P = prior_covariance_m2.copy()
    kf.Q = np.zeros((n, n))
    kf.R = np.diag(frame.sigma**2)
    kf.predict()
    kf.update(frame.measured)
    y, S = np.asarray(kf.y, dtype=float), np.asarray(kf.S, dtype=float)
    _, logdet_S = np.linalg.slogdet(S)
    log_likelihood = -0.5 * float(y @ np.linalg.solve(S, y)) - 0.5 * logdet_S
    log_likelihood += float(np.sum(np.log(frame.sigma)))
    covariance = np.array(kf.P, dtype=float)
    return np.array(kf.x, dtype=float), 0.5 * (covariance + covariance.T), log_likelihood


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Ekf:
    """Iterated EKF (or UKF) over frames, one filter per mirror hypothesis (MATH §7, §8).

    Parameters
    ----------
    filter : {"ekf", "ukf"}
        ``ekf``: filterpy's ``ExtendedKalmanFilter``, iterated (IEKF) up to
        ``max_iterations`` times per frame; ``ukf``: filterpy's ``UnscentedKalmanFilter``
        (with the IEKF update while the data's Fisher information is still rank-deficient,
        e.g. an emitter on the track, where sigma points would sample the diffuse prior).
    process_noise_mps : float
        ``q``: the emitter's random-walk step between frames has standard deviation ``q Δt``
        per axis (``Δt`` between the frames' mean sample times). 0: a static emitter.
    max_iterations : int
        IEKF passes per frame (1: the plain EKF). The first frame is always iterated to its
        maximum likelihood.
    """

    name: ClassVar[str] = "ekf"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    required_modules: ClassVar[tuple[str, ...]] = ("filterpy",)

    filter: FilterKind = "ekf"
    process_noise_mps: float = 0.0
    max_iterations: int = 20

    def __post_init__(self) -> None:
        if self.filter not in ("ekf", "ukf"):
            raise ValueError(f"filter: expected 'ekf' or 'ukf', got {self.filter!r}")
        q = self.process_noise_mps
        if not isinstance(q, int | float) or not math.isfinite(q) or q < 0:
            raise ValueError(f"process_noise_mps: must be a finite number >= 0, got {q!r}")
        n = self.max_iterations
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {n!r}")

    def capabilities(self) -> Capabilities:
        return Capabilities(
            modalities=self.requires,
            modules=self.required_modules,
            sequential=True,
            unit_invariant=self.process_noise_mps == 0.0,  # q is in m/s
            unknowns=NUISANCE_UNKNOWNS | {HEIGHT_UNKNOWN},
        )

    # -- the SequentialEstimator pair ----------------------------------------------------------

    def init(self) -> EkfState:
        """No frame yet."""
        return EkfState()

    def update(self, state: EkfState, frame: MeasurementSet) -> EkfState:
        """The state after one more frame (``frame``: that frame's samples only). Unknown
        nuisance parameters (``frame.unknowns``, MATH §15) are carried as constant states."""
        require_modalities(self, frame)
        names = nuisance_names(frame)
        dimension = position_dimension(frame.unknowns)
        if state.n_frames:
            check_same_unknowns(state.nuisance, frame, state.dimension)
        reference = state.reference
        if names and reference is None:
            reference = reference_sample(frame)
        model = frame_model(frame, names, reference)
        if state.failure:
            return replace(state, n_frames=state.n_frames + 1)
        highest = max(state.highest_m, float(np.max(model.position_m[:, 2])))
        try:
            if dimension == 3 and (state.n_frames == 0 or state.pending):
                return self._straight_update(state, frame, model, highest)
            if state.n_frames == 0:
                return self._first_update(frame, model)
            return replace(self._next_update(state, model), highest_m=highest)
        except (EstimationFailure, np.linalg.LinAlgError) as error:
            return replace(
                state,
                n_frames=state.n_frames + 1,
                failure=str(error),
                nuisance=names,
                reference=reference,
                speed_of_light_mps=frame.speed_of_light_mps,
                dimension=dimension,
                pending=(),
            )

    def estimate_state(
        self, state: EkfState, *, rng: np.random.Generator | None = None
    ) -> Estimate:
        """The estimate after the frames seen (``rng`` breaks an exact mirror tie)."""
        if state.failure:
            return Estimate.failed(self.name, state.failure, frames=state.n_frames)
        if state.n_frames == 0:
            return Estimate.failed(self.name, "no frame has been processed yet", frames=0)
        if state.pending:  # the height unknown and every frame on one straight track
            return Estimate.failed(
                self.name, STRAIGHT_TRACK_HEIGHT, dimension=3, frames=state.n_frames
            )
        d = state.dimension
        hypotheses = state.all_hypotheses()
        notes = []
        fallback = state.diagnostics.get("fallback", "none")
        if fallback != "none":
            notes.append(
                f"the update of frame {state.n_frames - 1} needed a fallback ({fallback}): "
                f"{state.diagnostics['fallback_reason']}; Newton's method finished it"
            )
        estimate = hypotheses_estimate(
            self.name,
            [h.mean_m[:d] for h in hypotheses],
            [h.covariance_m2[:d, :d] for h in hypotheses],
            [h.log_weight for h in hypotheses],
            [position_information(h.data_information, d) for h in hypotheses],
            straight_track=state.track is not None,
            ceiling_m=state.highest_m if d == 3 else None,
            length_scale_m=state.length_scale_m,
            rng=rng,
            notes=notes,
            diagnostics=dict(
                state.diagnostics,
                frames=state.n_frames,
                filter=self.filter,
                iterations=state.iterations,
            ),
        )
        if not state.nuisance or not estimate.success:
            return estimate
        # the returned hypothesis's physical nuisance values δ, b (MATH §15)
        chosen = min(
            hypotheses, key=lambda h: float(np.linalg.norm(h.mean_m[:d] - estimate.position_m))
        )
        values, covariance = physical_nuisance(
            state.reference, state.nuisance, chosen.mean_m, chosen.covariance_m2
        )
        extra = nuisance_diagnostics(state.nuisance, values, covariance, state.speed_of_light_mps)
        return replace(estimate, diagnostics={**estimate.diagnostics, **extra})

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """Stream ``data.iter_frames()`` through :meth:`init`/:meth:`update`."""
        require_modalities(self, data)
        state = self.init()
        for frame in data.iter_frames():
            state = self.update(state, frame)
        return with_fit(self, self.estimate_state(state, rng=rng), data)

    # -- internals ----------------------------------------------------------------------------

    def _first_update(self, frame: MeasurementSet, model: FrameModel | NuisanceFrame) -> EkfState:
        if isinstance(model, NuisanceFrame):  # no closed form with unknowns: MATH §15 rows
            candidates = straight_frame_starts(model)
        else:
            candidates = first_frame_candidates(frame)
        track = StraightTrack.of_frame(model)
        starts = hypothesis_starts(candidates, track, track)
        length_scale = model.mean_range_m(candidates[0])
        if isinstance(model, NuisanceFrame):
            prior_information = diffuse_information(model, length_scale)
        else:
            prior_information = diffuse_prior_information(length_scale)
        hypotheses = []
        reports = []
        for start in starts:
            mean, information, log_likelihood, report = iterated_update(
                model, start, prior_information, max_iterations=FIRST_FRAME_ITERATIONS
            )
            if not report.converged:
                raise EstimationFailure(f"frame 0: {report.reason}")
            reports.append(report)
            hypotheses.append(
                EkfHypothesis(
                    mean_m=mean,
                    covariance_m2=symmetric_inverse(information),
                    log_weight=log_likelihood,
                    data_information=model.information(mean),
                )
            )
        return EkfState(
            hypotheses=tuple(hypotheses),
            track=track,
            length_scale_m=length_scale,
            time_s=model.time_s,
            n_frames=1,
            iterations=max(r.iterations for r in reports),
            diagnostics={
                "first_frame_candidates": len(candidates),
                **update_diagnostics(reports),
                "fallbacks": int(any(r.fallback for r in reports)),
            },
            nuisance=model.names if isinstance(model, NuisanceFrame) else (),
            reference=model.reference if isinstance(model, NuisanceFrame) else None,
            speed_of_light_mps=frame.speed_of_light_mps,
        )

    def _straight_update(
        self,
        state: EkfState,
        frame: MeasurementSet,
        model: FrameModel | NuisanceFrame,
        highest_m: float,
    ) -> EkfState:
        """The height unknown, no hypothesis yet: a frame on the first straight track waits
        (MATH §7: the track leaves a circle); the first frame off it starts the hypotheses
        from the waiting frames and itself at once (:meth:`_height_start`)."""
        if state.n_frames == 0:
            track = StraightTrack.of_frame(model)
        else:
            assert state.track is not None  # frames wait only while the track is straight
            track = state.track.extended(model)
        pending = (*state.pending, model)
        names = model.names if isinstance(model, NuisanceFrame) else ()
        if track is not None:
            return replace(
                state,
                track=track,
                time_s=model.time_s,
                n_frames=state.n_frames + 1,
                nuisance=names,
                reference=model.reference if isinstance(model, NuisanceFrame) else None,
                speed_of_light_mps=frame.speed_of_light_mps,
                dimension=3,
                pending=pending,
                highest_m=highest_m,
            )
        return self._height_start(pending, frame, highest_m)

    def _height_start(
        self,
        pending: tuple[FrameModel | NuisanceFrame, ...],
        frame: MeasurementSet,
        highest_m: float,
    ) -> EkfState:
        """The hypotheses with the height unknown, from the frames of the first straight
        track and the first frame off it solved as one (the emitter static over them): from
        the starts on the first frame's ambiguity circle
        (:func:`~estimators.sequential.nuisance_starts.circle_starts`), each iterated to their
        maximum likelihood with a diffuse prior; those that converge are the hypotheses,
        merged and pruned as after a turn (MATH §7). In a level flight a hypothesis above the
        UAV is replaced by its reflection through the flight plane (same likelihood)."""
        first = pending[0]
        if isinstance(first, NuisanceFrame):
            model: FrameModel | NuisanceFrame = NuisanceFrame(
                FrameModel.stacked([m.base for m in pending]),  # type: ignore[union-attr]
                first.names,
                first.speed_of_light_mps,
                reference=first.reference,
            )
        else:
            model = FrameModel.stacked(pending)  # type: ignore[arg-type]
        starts = circle_starts(first)
        length_scale = model.mean_range_m(starts[0])
        if isinstance(model, NuisanceFrame):
            prior_information = diffuse_information(model, length_scale)
        else:
            prior_information = diffuse_prior_information(length_scale, 3)
        heights = model.position_m[:, 2]
        level = float(np.ptp(heights)) <= LEVEL_RTOL * length_scale
        hypotheses = []
        reports = []
        for start in starts:
            mean, information, log_likelihood, report = iterated_update(
                model, start, prior_information, max_iterations=FIRST_FRAME_ITERATIONS
            )
            reports.append(report)
            if not report.converged:
                continue
            hypothesis = EkfHypothesis(
                mean_m=mean,
                covariance_m2=symmetric_inverse(information),
                log_weight=log_likelihood,
                data_information=model.information(mean),
            )
            if level and mean[2] > heights[0]:
                hypothesis = hypothesis.reflected(float(np.mean(heights)))
            hypotheses.append(hypothesis)
        if not hypotheses:
            raise EstimationFailure(f"frames 0-{len(pending) - 1}: {reports[0].reason}")
        kept, log_weights = surviving_hypotheses(
            [h.mean_m[:3] for h in hypotheses],
            [h.log_weight for h in hypotheses],
            length_scale,
            [h.covariance_m2[:3, :3] for h in hypotheses],
        )
        top = float(log_weights[0])
        return EkfState(
            hypotheses=tuple(
                replace(hypotheses[i], log_weight=float(w) - top)
                for i, w in zip(kept, log_weights, strict=True)
            ),
            track=None,
            length_scale_m=length_scale,
            time_s=pending[-1].time_s,
            n_frames=len(pending),
            iterations=max(r.iterations for r in reports),
            diagnostics={
                "first_frame_candidates": len(starts),
                **update_diagnostics(reports),
                "fallbacks": int(any(r.fallback for r in reports)),
            },
            nuisance=first.names if isinstance(first, NuisanceFrame) else (),
            reference=first.reference if isinstance(first, NuisanceFrame) else None,
            speed_of_light_mps=frame.speed_of_light_mps,
            dimension=3,
            highest_m=highest_m,
        )

    def _next_update(self, state: EkfState, model: FrameModel | NuisanceFrame) -> EkfState:
        track = None if state.track is None else state.track.extended(model)
        hypotheses = state.hypotheses if track is not None else state.all_hypotheses()
        d = state.dimension
        step_m = self.process_noise_mps * abs(model.time_s - state.time_s)
        process_covariance = step_m**2 * np.eye(d)
        updated = []
        reports = []
        for hypothesis in hypotheses:
            prior_mean = hypothesis.mean_m
            if isinstance(model, NuisanceFrame):
                # δ and b are constant (MATH §15): only the emitter steps, which moves the
                # referenced nuisance states with it (M ν, estimators.sequential.nuisance_states)
                move = model.position_map(prior_mean)
                prior_covariance = hypothesis.covariance_m2 + move @ process_covariance @ move.T
            else:
                prior_covariance = hypothesis.covariance_m2 + process_covariance
            # sigma points spread along a direction the data do not yet fix would sample the
            # diffuse prior hundreds of kilometres away: linearise (IEKF) until the data do
            information = position_information(hypothesis.data_information, d)
            if self.filter == "ukf" and fisher_rank(information) == d:
                mean, covariance, log_likelihood = ukf_update(model, prior_mean, prior_covariance)
                report = SolverReport(1, 1, float("nan"), True)
            else:
                mean, covariance, report = ekf_update(
                    model, prior_mean, prior_covariance, max_iterations=self.max_iterations
                )
                if not report.converged:
                    raise EstimationFailure(f"frame {state.n_frames}: {report.reason}")
                prior_information = np.linalg.inv(prior_covariance)
                log_likelihood = laplace_log_likelihood(
                    map_cost(model, mean, prior_mean, prior_information),
                    prior_information,
                    np.linalg.inv(covariance),
                )
            if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(covariance))):
                raise EstimationFailure(f"the {self.filter} update diverged (non-finite state)")
            reports.append(report)
            updated.append(
                EkfHypothesis(
                    mean_m=mean,
                    covariance_m2=covariance,
                    log_weight=hypothesis.log_weight + log_likelihood,
                    data_information=hypothesis.data_information + model.information(mean),
                )
            )
        if track is None:
            # off the line: near-duplicates (one mode reached from both sides) merge by
            # covariance as well as by position (estimators.sequential.mirror_hypotheses, "Merging")
            kept, log_weights = surviving_hypotheses(
                [h.mean_m[:d] for h in updated],
                [h.log_weight for h in updated],
                state.length_scale_m,
                [h.covariance_m2[:d, :d] for h in updated],
            )
            top = float(log_weights[0])
            updated = [
                replace(updated[i], log_weight=float(w) - top)
                for i, w in zip(kept, log_weights, strict=True)
            ]
        return replace(
            state,
            hypotheses=tuple(updated),
            track=track,
            time_s=model.time_s,
            n_frames=state.n_frames + 1,
            iterations=max(r.iterations for r in reports),
            diagnostics={
                **state.diagnostics,
                **update_diagnostics(reports),
                "fallbacks": state.diagnostics.get("fallbacks", 0)
                + any(r.fallback for r in reports),
            },
        )
