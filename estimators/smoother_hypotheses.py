r"""The smoother's mirror hypotheses as plain arrays, and the live ISAM2 behind each.

A hypothesis (:class:`SmootherHypothesis`) holds its optimum, covariance, Laplace weight and
fit (:meth:`SmootherHypothesis.fitted`), and the *recipe* that rebuilds its ISAM2; the state
(:class:`SmootherState`) holds every frame seen and the hypotheses.

**Why a private per-process cache of ISAM2 objects.** ``CustomFactor`` cannot be pickled and
an ISAM2 holds them, so the state (:class:`SmootherState`) keeps only plain arrays: every
frame's measurements, each hypothesis's estimates and the *recipe* that rebuilds its ISAM2 (its
first batch of frames and their initial values). Rebuilding the ISAM2 from that recipe at every
frame would make streaming cost grow with the number of frames, which is what ISAM2 exists to
avoid. So the live ISAM2 is kept in a module-level LRU cache keyed by a random token stored in
the hypothesis. ``update`` *takes* the entry out of the cache and files the extended ISAM2 under
a new token; if the entry is missing (another process after unpickling, an evicted entry, or an
old state extended a second time) the ISAM2 is replayed from the recipe with exactly the same
sequence of operations (:func:`replay_isam2`), so the result never depends on the cache: the
state stays a pure value. :func:`checkout` takes an entry out, :func:`checkin` files one.

ISAM2 takes one Gauss-Newton step per ``update``; it is stepped again (with a zero wildfire
threshold and a relinearisation threshold of :data:`RELINEARIZE_RTOL` of the length scale)
until no variable needs relinearising (:func:`iterate_isam2`). It factorises by QR: Cholesky
squares the condition number of a diffuse prior against a tight random-walk link and reports an
indeterminate system.
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
from estimators.mirror_hypotheses import DIFFUSE_PRIOR_SCALE, StraightTrack, fisher_rank
from estimators.smoother_graph import chain_fit, graph_part, values_of

FloatArray = NDArray[np.float64]

RELINEARIZE_RTOL = 1e-8
"""ISAM2 relinearises a variable whose step exceeds this times the length scale."""

MAX_ISAM2_STEPS = 20
"""Extra ISAM2 steps per frame, at most, while iterating to the optimum."""

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
        :func:`~estimators.smoother_graph.chain_fit`'s log evidence at the optimum.
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
        (:func:`~estimators.smoother_graph.chain_fit`).
    start_iterated : bool
        Whether the first update was iterated to the optimum (False: a re-seed at a batch
        optimum after a fallback, one bare ``update``); part of the recipe.
    saddle : bool
        The optimum is a saddle point of the cost
        (:meth:`~estimators.smoother_graph.ChainFit.saddle_direction`).
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
        start_frames: int = 0,
        start_values_m: FloatArray | None = None,
        token: str = "",
        start_iterated: bool = True,
    ) -> SmootherHypothesis:
        """The hypothesis at ``estimates`` (one row per variable), weighed and checked by
        :func:`~estimators.smoother_graph.chain_fit`, with GTSAM's ``covariance`` of the last
        variable (from the fit when GTSAM found it indeterminate but the data determine the
        emitter). Raises :class:`EstimationFailure` on a non-finite estimate or covariance."""
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
        covariance = np.asarray(covariance, dtype=float)
        if not np.all(np.isfinite(covariance)) and fisher_rank(fit.data_information) == 2:
            # GTSAM's Marginals factorises by Cholesky, which calls a diffuse prior against a
            # tight random-walk link indeterminate; the same marginal from the QR-free 2×2
            # block elimination of chain_fit is well defined
            try:
                covariance = np.linalg.inv(fit.last_information)
            except np.linalg.LinAlgError:
                covariance = np.full((2, 2), np.nan)
            if not (np.all(np.isfinite(covariance)) and np.all(np.linalg.eigvalsh(covariance) > 0)):
                raise EstimationFailure("GTSAM could not compute the marginal covariance")
        return cls(
            estimates_m=np.asarray(estimates, dtype=float),
            covariance_m2=0.5 * (covariance + covariance.T),
            log_weight=fit.log_evidence,
            data_information=fit.data_information,
            prior_mean_m=np.asarray(prior_mean_m, dtype=float),
            start_frames=start_frames,
            start_values_m=np.empty((0, 2)) if start_values_m is None else start_values_m,
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
        if self.track is None or not self.hypotheses:
            return self.hypotheses
        return (*self.hypotheses, self.hypotheses[0].mirrored(self.track))


# --------------------------------------------------------------------------------------------
# ISAM2
# --------------------------------------------------------------------------------------------


def isam2_params(length_scale_m: float) -> Any:
    """ISAM2's parameters: relinearise beyond :data:`RELINEARIZE_RTOL` of the length scale at
    every update, Gauss-Newton with a zero wildfire threshold, QR factorisation."""
    import gtsam

    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(RELINEARIZE_RTOL * length_scale_m)
    params.relinearizeSkip = 1
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
    # QR on the Jacobian, not Cholesky on JᵀJ: the diffuse prior against a tight
    # random-walk link squares to a condition number Cholesky calls indeterminate
    params.setFactorization("QR")
    return params


def iterate_isam2(isam: Any, new_graph: Any, new_values: Any) -> tuple[int, bool]:
    """Add factors, then step ISAM2 until no variable needs relinearising.

    Returns ``(steps, still_moving)``: ``still_moving`` when the last step still
    relinearised a variable (the cap :data:`MAX_ISAM2_STEPS` was reached).
    """
    isam.update(new_graph, new_values)
    steps = 0
    moving = True
    while steps < MAX_ISAM2_STEPS:
        steps += 1
        if isam.update().getVariablesRelinearized() == 0:
            moving = False
            break
    return steps, moving


def new_isam2(
    frames: tuple[FrameModel, ...],
    start_values_m: FloatArray,
    prior_mean_m: FloatArray,
    steps: FloatArray,
    length_scale_m: float,
    *,
    random_walk: bool,
    iterate: bool,
) -> tuple[Any, int, bool]:
    """A new ISAM2 holding ``frames`` at once, linearised at ``start_values_m`` and, with
    ``iterate``, stepped to the optimum. Returns ``(isam, steps, still_moving)``."""
    import gtsam

    isam = gtsam.ISAM2(isam2_params(length_scale_m))
    graph = graph_part(
        frames,
        0,
        len(frames),
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=prior_mean_m,
        prior_sigma_m=DIFFUSE_PRIOR_SCALE * length_scale_m,
    )
    if not iterate:
        isam.update(graph, values_of(start_values_m))
        return isam, 0, False
    n_steps, moving = iterate_isam2(isam, graph, values_of(start_values_m))
    return isam, n_steps, moving


def add_frame(
    isam: Any,
    frames: tuple[FrameModel, ...],
    steps: FloatArray,
    prior_sigma: float,
    *,
    random_walk: bool,
) -> tuple[int, bool]:
    """Add the last of ``frames`` to ``isam`` and iterate to the optimum."""
    import gtsam
    from gtsam.symbol_shorthand import X

    t = len(frames) - 1
    graph = graph_part(
        frames,
        t,
        t + 1,
        random_walk=random_walk,
        step_sigmas=steps,
        prior_mean_m=None,
        prior_sigma_m=prior_sigma,
    )
    values = gtsam.Values()
    if random_walk:
        values.insert(X(t), np.array(isam.calculateEstimatePoint2(X(t - 1))))
    return iterate_isam2(isam, graph, values)


def replay_isam2(
    hypothesis: SmootherHypothesis,
    frames: tuple[FrameModel, ...],
    steps: FloatArray,
    length_scale_m: float,
    *,
    random_walk: bool,
) -> Any:
    """Rebuild a hypothesis's ISAM2 from its recipe, by the same operations as streaming."""
    prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
    start = hypothesis.start_frames
    isam, _, _ = new_isam2(
        frames[:start],
        hypothesis.start_values_m,
        hypothesis.prior_mean_m,
        steps,
        length_scale_m,
        random_walk=random_walk,
        iterate=hypothesis.start_iterated,
    )
    for stop in range(start + 1, len(frames) + 1):
        add_frame(isam, frames[:stop], steps, prior_sigma, random_walk=random_walk)
    return isam


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
