r"""The smoother's mirror hypotheses as plain arrays, and the live ISAM2 behind each.

A hypothesis (:class:`SmootherHypothesis`) holds its optimum, covariance, Laplace weight and
fit (:meth:`SmootherHypothesis.fitted`), and the *recipe* that rebuilds its ISAM2; the state
(:class:`SmootherState`) holds every frame seen and the hypotheses.

**Why a private per-process cache of ISAM2 objects.** ``CustomFactor`` cannot be pickled and
an ISAM2 holds them, so the state (:class:`SmootherState`) keeps only plain arrays: every
frame's measurements, each hypothesis's estimates and the *recipe* that rebuilds its ISAM2 (its
first batch of frames and their initial values). Rebuilding the ISAM2 from that recipe at every
frame would make streaming cost grow with the number of frames, which is what ISAM2 exists to
avoid. So the live ISAM2 (:class:`LiveGraph`, with the expansion kept beside it) is kept in a
module-level LRU cache keyed by a random token stored in the hypothesis. ``update`` *takes* the
entry out of the cache and files the extended one under a new token; if the entry is missing
(another process after unpickling, an evicted entry, or an old state extended a second time) it
is replayed from the recipe with exactly the same sequence of operations (:func:`replay_live`),
so the result never depends on the cache: the state stays a pure value. :func:`checkout` takes
an entry out, :func:`checkin` files one.

**Only new factors enter ISAM2.** An update adds the frame's factor (and its random-walk link);
ISAM2 relinearises a variable only when its step from its linearisation point ``θ`` reaches
:data:`RELINEARIZE_RTOL` of the length scale, and it is stepped again only while some variable
does (:func:`converge`). Once converged, a new frame therefore costs one factor evaluation. Two
GTSAM details make that hold. ISAM2 re-eliminates *in batch*, re-linearising every factor, when
at least 65 % of its variables are affected by an update (``ISAM2::recalculate``); with a static
emitter the one variable ``X(0)`` is always affected, so a second, disconnected variable (an
anchor with a unit prior, :data:`ANCHOR_KEY`) keeps the updates incremental. And a relinearised
variable's frames are evaluated in one vectorised pass (:meth:`LiveGraph.expand`) that the
factors' callbacks then read (:func:`~estimators.sequential.smoother_graph.frame_factor`).

**Exact answers from a stale linearisation.** With the old factors linearised at ``θ``, ISAM2's
Gauss-Newton solution misses the residuals' own curvature, ``Σ e_k ∇²e_k``, times the distance
from ``θ``: off by ``~10⁻³ |s − θ|`` on ``paper-1m``. So each variable's frames are also kept
to third order about ``θ`` (:class:`~estimators.sequential.smoother_graph.Expansion`; additive: a
new frame adds its terms, a relinearised variable is re-expanded, nothing else is re-evaluated).
Once ISAM2 has converged its estimate is finished by Newton's method on that expansion
(:meth:`LiveGraph.solution`), and the fit the checks read (cost, decrement, saddle, evidence,
marginal information) comes from the expansion too, exact to ``~(|s − θ|/ρ)³``; a point outside
:data:`TRUST_RADIUS` thresholds of ``θ`` (ISAM2 stopped while still moving) is evaluated
exactly instead. It factorises by QR: Cholesky squares the condition number of a diffuse prior
against a tight random-walk link and reports an indeterminate system.
"""

from __future__ import annotations

import math
import uuid
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.convergence import EstimationFailure
from estimators.frame_model import FrameModel, read_only
from estimators.sequential.mirror_hypotheses import (
    DIFFUSE_PRIOR_SCALE,
    fisher_rank,
    surviving_hypotheses,
    with_mirror,
)
from estimators.sequential.smoother_graph import (
    N_TERMS,
    ChainFit,
    Expansion,
    chain_fit,
    expansion_terms,
    fit_from_sums,
    graph_part,
    newton_descent,
    values_of,
)
from scenarios.geometry import StraightTrack

FloatArray = NDArray[np.float64]

RELINEARIZE_RTOL = 5e-4
"""ISAM2 relinearises a variable whose step from its linearisation point reaches this times
the length scale (ISAM2's ``relinearizeThreshold``, every update)."""

TRUST_RADIUS = 2.0
"""The expansion is read within this many relinearisation thresholds of its point; farther, the
graph is evaluated exactly. (On ``paper-1m-turn``, 200 trials × 10 frames, the streamed optima
are within ``8·10⁻⁸`` m at 0 dB and ``5·10⁻⁷`` m, ``4·10⁻⁸`` posterior σ, at −10 dB of the
exact ones: the expansion's error grows as the cube of the distance from its point.)"""

MAX_ISAM2_STEPS = 21
"""ISAM2 updates per frame, at most, while iterating to the optimum: the one that adds the
frame's factors and up to 20 more."""

POLISH_RTOL = 1e-10
"""The Newton finish on the expansion stops once its step is below this times the length scale
in every coordinate (ISAM2 alone used to stop at ``10⁻⁸``)."""

POLISH_HALVINGS = 8
"""Step halvings of the Newton finish on the expansion before it counts as stalled."""

ANCHOR_KEY = 0x7A00000000000000
"""``gtsam.symbol('z', 0)``: the static graph's disconnected anchor variable (module text)."""

LIVE_CACHE_SIZE = 32
"""ISAM2 objects kept per process (see the module text)."""

_LIVE_ISAM2: OrderedDict[str, tuple[Any, int]] = OrderedDict()


# --------------------------------------------------------------------------------------------
# hypotheses and state
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class SmootherHypothesis:
    """One mirror hypothesis of the smoother, as plain arrays.

    Attributes
    ----------
    estimates_m : (n_variables, 2)
        Current optimum of every emitter variable (one when static).
    covariance_m2 : (2, 2)
        Marginal covariance of the last variable.
    log_weight : float
        :func:`~estimators.sequential.smoother_graph.chain_fit`'s log evidence at the optimum.
    data_information : (2, 2)
        Accumulated Fisher information of the data (MATH §8).
    prior_mean_m : (2,)
        Centre of the diffuse prior on ``X(0)``.
    start_frames : int
        How many frames the ISAM2's first update held (the recipe that rebuilds it).
    start_values_m : (n, 2)
        Initial values of that first update.
    token : str
        Key of the live ISAM2 in this process's cache.
    chi2, decrement : float
        The graph's ``χ²`` and decrement at the optimum
        (:func:`~estimators.sequential.smoother_graph.chain_fit`).
    start_iterated : bool
        Whether the first update was iterated to the optimum (False: a re-seed at a batch
        optimum after a fallback, one bare ``update``); part of the recipe.
    saddle : bool
        The optimum is a saddle point of the cost
        (:meth:`~estimators.sequential.smoother_graph.ChainFit.saddle_direction`).
    """

    estimates_m: FloatArray
    covariance_m2: FloatArray
    log_weight: float
    data_information: FloatArray
    prior_mean_m: FloatArray
    start_frames: int
    start_values_m: FloatArray
    token: str
    chi2: float = math.nan
    decrement: float = math.nan
    start_iterated: bool = True
    saddle: bool = False

    def __post_init__(self) -> None:
        read_only(
            self.estimates_m,
            self.covariance_m2,
            self.data_information,
            self.prior_mean_m,
            self.start_values_m,
        )

    @classmethod
    def fitted(
        cls,
        frames: Sequence[FrameModel],
        estimates: FloatArray,
        covariance: FloatArray,
        prior_mean_m: FloatArray,
        prior_sigma_m: float,
        steps: FloatArray,
        *,
        random_walk: bool,
        **recipe: Any,
    ) -> SmootherHypothesis:
        """The hypothesis at ``estimates`` (one row per variable), weighed and checked by
        :func:`~estimators.sequential.smoother_graph.chain_fit`, with GTSAM's ``covariance`` of the
        last variable (:meth:`from_fit`). Raises :class:`EstimationFailure` on a non-finite estimate
        or covariance."""
        if not np.all(np.isfinite(estimates)):
            raise EstimationFailure("GTSAM returned a non-finite estimate")
        fit = chain_fit(
            frames,
            estimates,
            random_walk=random_walk,
            step_sigmas=steps,
            prior_mean_m=prior_mean_m,
            prior_sigma_m=prior_sigma_m,
        )
        return cls.from_fit(fit, estimates, covariance, prior_mean_m, **recipe)

    @classmethod
    def from_fit(
        cls,
        fit: ChainFit,
        estimates: FloatArray,
        covariance: FloatArray | None,
        prior_mean_m: FloatArray,
        *,
        start_frames: int = 0,
        start_values_m: FloatArray | None = None,
        token: str = "",
        start_iterated: bool = True,
    ) -> SmootherHypothesis:
        """The hypothesis at ``estimates`` with its ``fit``. The covariance of the last variable
        is ``covariance`` (GTSAM's) or, when that is None or not finite and the data determine
        the emitter, the inverse of the fit's marginal information (the same matrix, from the
        QR-free 2×2 block elimination: GTSAM's Cholesky calls a diffuse prior against a tight
        random-walk link indeterminate)."""
        d = len(fit.data_information)
        if covariance is None:
            covariance = np.full((d, d), np.nan)
        covariance = np.asarray(covariance, dtype=float)
        if not np.all(np.isfinite(covariance)) and fisher_rank(fit.data_information) == d:
            try:
                covariance = np.linalg.inv(fit.last_information)
            except np.linalg.LinAlgError:
                covariance = np.full((d, d), np.nan)
            if not (np.all(np.isfinite(covariance)) and np.all(np.linalg.eigvalsh(covariance) > 0)):
                raise EstimationFailure("GTSAM could not compute the marginal covariance")
        return cls(
            estimates_m=np.asarray(estimates, dtype=float),
            covariance_m2=0.5 * (covariance + covariance.T),
            log_weight=fit.log_evidence,
            data_information=fit.data_information,
            prior_mean_m=np.asarray(prior_mean_m, dtype=float),
            start_frames=start_frames,
            start_values_m=np.empty((0, d)) if start_values_m is None else start_values_m,
            token=token,
            chi2=fit.chi2,
            decrement=fit.decrement,
            start_iterated=start_iterated,
            saddle=fit.saddle_direction() is not None,
        )

    def mirrored(self, track: StraightTrack) -> SmootherHypothesis:
        """The reflection across a straight track (MATH §7); it has no ISAM2 of its own."""
        return SmootherHypothesis(
            estimates_m=track.mirror_point(self.estimates_m),
            covariance_m2=track.mirror_covariance(self.covariance_m2),
            log_weight=self.log_weight,
            data_information=track.mirror_covariance(self.data_information),
            prior_mean_m=track.mirror_point(self.prior_mean_m),
            start_frames=0,
            start_values_m=np.empty((0, 2)),
            token="",
            chi2=self.chi2,
            decrement=self.decrement,
            saddle=self.saddle,
        )


@dataclass(frozen=True, slots=True, eq=False)
class SmootherState:
    """The frames seen and each hypothesis's optimum; an immutable, picklable value.

    While ``track`` is not None the second hypothesis is the reflection of the first.
    ``fallback_reason`` is why the last update fell back to the batch solve (empty: it did
    not), ``fallbacks`` how many updates so far did.
    """

    frames: tuple[FrameModel, ...] = ()
    hypotheses: tuple[SmootherHypothesis, ...] = ()
    track: StraightTrack | None = None
    length_scale_m: float = math.nan
    iterations: int = 0
    failure: str = ""
    diagnostics: dict[str, Any] = field(default_factory=dict)
    fallback_reason: str = ""
    fallbacks: int = 0

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def all_hypotheses(self) -> tuple[SmootherHypothesis, ...]:
        """The explicit hypotheses plus, on a straight track, the mirror of the first."""
        return with_mirror(self.hypotheses, self.track)


# --------------------------------------------------------------------------------------------
# ISAM2
# --------------------------------------------------------------------------------------------


def isam2_params(length_scale_m: float) -> Any:
    """ISAM2's parameters: relinearise a variable whose step reaches :data:`RELINEARIZE_RTOL`
    of the length scale, checked at every update; Gauss-Newton with a zero wildfire threshold;
    QR factorisation."""
    import gtsam

    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(RELINEARIZE_RTOL * length_scale_m)
    params.relinearizeSkip = 1
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
    # QR on the Jacobian, not Cholesky on JᵀJ: the diffuse prior against a tight
    # random-walk link squares to a condition number Cholesky calls indeterminate
    params.setFactorization("QR")
    return params


@dataclass(eq=False)
class LiveGraph:
    """One hypothesis's ISAM2 and the third-order expansion of its frames about ISAM2's
    linearisation point, kept in step (module text).

    Attributes
    ----------
    isam : gtsam.ISAM2
    frames : list of FrameModel
        The frames whose factors ISAM2 holds.
    expansion : Expansion
        Per variable, about ``expansion.theta_m``: ISAM2's linearisation point.
    linearised : list
        Per frame, ``(point, e, E)`` at its variable's linearisation point, read by the factors'
        callbacks (:func:`~estimators.sequential.smoother_graph.frame_factor`).
    random_walk : bool
    threshold_m : float
        ISAM2's relinearisation threshold.
    length_scale_m : float
    """

    isam: Any
    frames: list[FrameModel]
    expansion: Expansion
    linearised: list[Any]
    random_walk: bool
    threshold_m: float
    length_scale_m: float

    @property
    def theta_m(self) -> FloatArray:
        return self.expansion.theta_m

    def delta(self) -> FloatArray:
        """ISAM2's step from the linearisation point, one row per variable."""
        from gtsam.symbol_shorthand import X

        delta = self.isam.getDelta()
        if not self.random_walk:
            return np.asarray(delta.at(X(0)), dtype=float).reshape(1, 2)
        return np.asarray(delta.vector(), dtype=float)[: 2 * len(self.theta_m)].reshape(-1, 2)

    def estimate(self) -> FloatArray:
        """ISAM2's estimate ``θ + δ`` (``calculateEstimate``), one row per variable."""
        return self.theta_m + self.delta()

    def expand(self, variables: NDArray[np.int64], points_m: FloatArray) -> None:
        """Re-expand ``variables`` about ``points_m``: all their frames in one pass."""
        self.theta_m[variables] = points_m
        if self.random_walk:
            frames = [self.frames[j] for j in variables]
            terms, linearised = expansion_terms(frames, points_m)
            self.expansion.terms[variables] = terms
            for j, entry in zip(variables, linearised, strict=True):
                self.linearised[j] = entry
        else:
            points = np.repeat(points_m, len(self.frames), axis=0)
            terms, linearised = expansion_terms(self.frames, points)
            self.expansion.terms[0] = np.sum(terms, axis=0)
            self.linearised[:] = linearised

    def update(
        self,
        graph: Any = None,
        values: Any = None,
        frames: Sequence[FrameModel] = (),
        points_m: FloatArray | None = None,
    ) -> None:
        """One ISAM2 update, adding ``graph`` (the factors of ``frames``) and ``values``.

        The variables it relinearises (``|δ_j|∞ ≥`` the threshold: GTSAM's own test, made
        before the new factors are linearised) are re-expanded at ``θ_j + δ_j`` first; then the
        new frames are expanded about their variable's linearisation point (``points_m``: the
        new variables' initial values in the random walk; ``X(0)``'s in the static graph)."""
        import gtsam

        if not self.isam.empty():
            delta = self.delta()
            moving = np.flatnonzero(np.max(np.abs(delta), axis=1) >= self.threshold_m)
            if moving.size:
                self.expand(moving, self.theta_m[moving] + delta[moving])
        if frames:
            if not self.random_walk:
                points_m = np.repeat(self.theta_m, len(frames), axis=0)
            self._add_frames(frames, np.asarray(points_m, dtype=float).reshape(-1, 2))
        self.isam.update(
            gtsam.NonlinearFactorGraph() if graph is None else graph,
            gtsam.Values() if values is None else values,
        )

    def _add_frames(self, frames: Sequence[FrameModel], points_m: FloatArray) -> None:
        terms, linearised = expansion_terms(frames, points_m)
        self.frames.extend(frames)
        self.linearised.extend(linearised)
        if self.random_walk:
            self.expansion.theta_m = np.vstack([self.theta_m, points_m])
            self.expansion.terms = np.vstack([self.expansion.terms, terms])
        else:
            self.expansion.terms[0] += np.sum(terms, axis=0)

    def solution(
        self,
        prior_mean_m: FloatArray,
        prior_sigma_m: float,
        step_sigmas: FloatArray,
        *,
        polish: bool,
    ) -> tuple[FloatArray, ChainFit]:
        """ISAM2's estimate (finished, with ``polish``, by Newton's method on the expansion)
        and the graph's fit there: from the expansion within :data:`TRUST_RADIUS` thresholds
        of the linearisation point, else evaluated exactly."""
        estimate = self.estimate()
        if not np.all(np.isfinite(estimate)):
            raise EstimationFailure("GTSAM returned a non-finite estimate")
        radius = TRUST_RADIUS * self.threshold_m
        if not np.max(np.abs(estimate - self.theta_m)) <= radius:
            return estimate, chain_fit(
                self.frames,
                estimate,
                random_walk=self.random_walk,
                step_sigmas=step_sigmas,
                prior_mean_m=prior_mean_m,
                prior_sigma_m=prior_sigma_m,
            )

        def fit_of(estimates_m: FloatArray) -> ChainFit:
            return fit_from_sums(
                self.expansion.at(estimates_m),
                estimates_m,
                random_walk=self.random_walk,
                step_sigmas=step_sigmas,
                prior_mean_m=prior_mean_m,
                prior_sigma_m=prior_sigma_m,
            )

        fit = fit_of(estimate)
        if polish:
            polished, polished_fit, _, _ = newton_descent(
                fit_of,
                estimate,
                fit,
                step_tolerance_m=POLISH_RTOL * self.length_scale_m,
                halvings=POLISH_HALVINGS,
            )
            if np.max(np.abs(polished - self.theta_m)) <= radius:
                return polished, polished_fit
        return estimate, fit


def converge(live: LiveGraph) -> tuple[int, bool]:
    """After an update (counted as the first step), step ISAM2 until it would relinearise no
    variable. Returns ``(steps, still_moving)``: ``still_moving`` when a variable still needs
    relinearising at the cap :data:`MAX_ISAM2_STEPS`."""
    steps = 1
    while np.max(np.abs(live.delta())) >= live.threshold_m:
        if steps >= MAX_ISAM2_STEPS:
            return steps, True
        live.update()
        steps += 1
    return steps, False


def new_live(
    frames: tuple[FrameModel, ...],
    start_values_m: FloatArray,
    prior_mean_m: FloatArray,
    steps: FloatArray,
    length_scale_m: float,
    *,
    random_walk: bool,
    iterate: bool,
) -> tuple[LiveGraph, int, bool]:
    """A new ISAM2 holding ``frames`` at once, linearised at ``start_values_m`` and, with
    ``iterate``, stepped to the optimum (:func:`converge`). Returns
    ``(live, steps, still_moving)``."""
    import gtsam

    start = np.array(start_values_m, dtype=float).reshape(-1, 2)
    live = LiveGraph(
        isam=gtsam.ISAM2(isam2_params(length_scale_m)),
        frames=[],
        expansion=(
            Expansion(np.empty((0, 2)), np.empty((0, N_TERMS)))
            if random_walk
            else Expansion(start.copy(), np.zeros((1, N_TERMS)))
        ),
        linearised=[],
        random_walk=random_walk,
        threshold_m=RELINEARIZE_RTOL * length_scale_m,
        length_scale_m=length_scale_m,
    )
    graph = graph_part(
        frames,
        0,
        len(frames),
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=DIFFUSE_PRIOR_SCALE * length_scale_m,
        linearised=live.linearised,
    )
    values = values_of(start)
    if not random_walk:
        graph.add(gtsam.PriorFactorPoint2(ANCHOR_KEY, np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
        values.insert(ANCHOR_KEY, np.zeros(2))
    live.update(graph, values, frames, start)
    if not iterate:
        return live, 0, False
    n_steps, moving = converge(live)
    return live, n_steps, moving


def add_frame(
    live: LiveGraph,
    frames: tuple[FrameModel, ...],
    steps: FloatArray,
    prior_sigma: float,
    *,
    random_walk: bool,
) -> tuple[int, bool]:
    """Add the last of ``frames`` (its factor and, in the random walk, its variable, starting at
    ISAM2's estimate of the previous one) and step to the optimum (:func:`converge`)."""
    import gtsam
    from gtsam.symbol_shorthand import X

    t = len(frames) - 1
    values = gtsam.Values()
    point = None
    if random_walk:
        point = live.estimate()[-1:]
        values.insert(X(t), np.array(point[0]))
    graph = graph_part(
        frames,
        t,
        t + 1,
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=None,
        prior_sigma_m=prior_sigma,
        linearised=live.linearised,
    )
    live.update(graph, values, frames[t:], point)
    return converge(live)


def replay_live(
    hypothesis: SmootherHypothesis,
    frames: tuple[FrameModel, ...],
    steps: FloatArray,
    length_scale_m: float,
    *,
    random_walk: bool,
) -> LiveGraph:
    """Rebuild a hypothesis's ISAM2 from its recipe, by the same operations as streaming."""
    prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
    start = hypothesis.start_frames
    live, _, _ = new_live(
        frames[:start],
        hypothesis.start_values_m,
        hypothesis.prior_mean_m,
        steps,
        length_scale_m,
        random_walk=random_walk,
        iterate=hypothesis.start_iterated,
    )
    for stop in range(start + 1, len(frames) + 1):
        add_frame(live, frames[:stop], steps, prior_sigma, random_walk=random_walk)
    return live


# --------------------------------------------------------------------------------------------
# the per-process cache
# --------------------------------------------------------------------------------------------


def checkout(token: str, n_frames: int) -> Any:
    """Take the live ISAM2 filed under ``token`` if it holds ``n_frames`` frames."""
    entry = _LIVE_ISAM2.pop(token, None)
    if entry is None or entry[1] != n_frames:
        return None
    return entry[0]


def checkin(isam: Any, n_frames: int) -> str:
    """File ``isam`` under a fresh token; evict the least recently filed beyond the limit."""
    token = uuid.uuid4().hex
    _LIVE_ISAM2[token] = (isam, n_frames)
    while len(_LIVE_ISAM2) > LIVE_CACHE_SIZE:
        _LIVE_ISAM2.popitem(last=False)
    return token


def discard(token: str) -> None:
    """Drop the live ISAM2 filed under ``token``, if any."""
    _LIVE_ISAM2.pop(token, None)


def pruned_hypotheses(hypotheses: Sequence[Any], length_scale_m: float) -> list[Any]:
    """The hypotheses that survive (:func:`~estimators.sequential.mirror_hypotheses.
    surviving_hypotheses`, merged and pruned by their last estimate, weight and covariance),
    the live ISAM2 of each pruned one dropped from the cache."""
    kept, _ = surviving_hypotheses(
        [h.estimates_m[-1] for h in hypotheses],
        [h.log_weight for h in hypotheses],
        length_scale_m,
        [h.covariance_m2 for h in hypotheses],
    )
    for index, hypothesis in enumerate(hypotheses):
        if index not in kept:
            discard(hypothesis.token)
    return [hypotheses[i] for i in kept]
