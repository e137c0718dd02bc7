r"""A GTSAM factor-graph smoother over frames, one graph per mirror hypothesis (MATH §7, §8, §10).

**The graph.** One emitter variable ``X(0)`` when the emitter is static
(``process_noise_mps = 0``, the default), else one variable ``X(t)`` per frame linked by
random-walk ``BetweenFactorPoint2(X(t−1), X(t), 0, σ = q Δt_t)``. Each frame adds ONE
vectorised ``CustomFactor`` for its stacked, whitened Doppler and range residuals
``e(s) = (h(s) − z)/σ`` with their ``(2K, 2)`` Jacobian (:class:`estimators.hypotheses.FrameModel`;
a unit noise model, since the residual is already whitened). A diffuse ``PriorFactorPoint2`` on
``X(0)`` at the hypothesis's starting candidate keeps every linear system regular (it moves a
well-determined estimate by a relative ``~1e−10``); that the data themselves determine the
emitter is checked separately, from the rank of the accumulated Fisher information (MATH §8),
because GTSAM's Levenberg-Marquardt returns garbage on an underdetermined graph without raising
and ISAM2/Marginals raise a bare ``RuntimeError`` (DEPENDENCIES §1).

With a static emitter the optimum is the maximum likelihood over all frames (MATH §10). The
reported covariance is GTSAM's marginal covariance of the last variable (the inverse Fisher
information at the estimate in the static case).

**Batch and streaming.** :meth:`GtsamSmoother.estimate` builds each hypothesis's full graph and
runs Levenberg-Marquardt; :meth:`GtsamSmoother.update` extends an ISAM2 per hypothesis by one
frame. ISAM2 takes one Gauss-Newton step per ``update``; it is stepped again (with a zero
wildfire threshold and a relinearisation threshold of ``1e−8`` of the length scale) until no
variable needs relinearising, so streaming converges to the same optimum as the batch solve.
ISAM2 factorises by QR: Cholesky squares the condition number of a diffuse prior against a
tight random-walk link and reports an indeterminate system. With a static emitter every
frame's factor sits on the one variable, so each relinearisation re-evaluates all of them and
the cost per frame grows with the number of frames; ISAM2 saves work in the random-walk chain,
where only the recent variables move.
Hypothesis weights are Laplace approximations of each hypothesis's evidence at its optimum,
``−½χ²(ŝ) − ½ log det Λ(ŝ)`` (:func:`chain_log_evidence`), computed the same way in both
modes. Pruning is decided after every frame when streaming and once on all the data in batch;
the two differ only if a hypothesis's weight crosses ``1e−9`` and then climbs back.

**Why a private per-process cache of ISAM2 objects.** ``CustomFactor`` cannot be pickled and
an ISAM2 holds them, so the state (:class:`SmootherState`) keeps only plain arrays: every
frame's measurements, each hypothesis's estimates and the *recipe* that rebuilds its ISAM2 (its
first batch of frames and their initial values). Rebuilding the ISAM2 from that recipe at every
frame would make streaming cost grow with the number of frames, which is what ISAM2 exists to
avoid. So the live ISAM2 is kept in a module-level LRU cache keyed by a random token stored in
the hypothesis. ``update`` *takes* the entry out of the cache and files the extended ISAM2 under
a new token; if the entry is missing (another process after unpickling, an evicted entry, or an
old state extended a second time) the ISAM2 is replayed from the recipe with exactly the same
sequence of operations, so the result never depends on the cache: the state stays a pure value.
"""

from __future__ import annotations

import math
import uuid
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Estimate, require_modalities
from estimators.hypotheses import (
    DIFFUSE_PRIOR_SCALE,
    MERGE_RTOL,
    EstimationFailure,
    FrameModel,
    StraightTrack,
    first_frame_candidates,
    fisher_rank,
    hypotheses_estimate,
    read_only,
    surviving_hypotheses,
)
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]

RELINEARIZE_RTOL = 1e-8
"""ISAM2 relinearises a variable whose step exceeds this times the length scale."""

MAX_ISAM2_STEPS = 20
"""Extra ISAM2 steps per frame, at most, while iterating to the optimum."""

LIVE_CACHE_SIZE = 32
"""ISAM2 objects kept per process (see the module text)."""

_LIVE_ISAM2: OrderedDict[str, tuple[Any, int]] = OrderedDict()


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


def _marginal_covariance(compute: Any) -> FloatArray:
    """GTSAM's marginal covariance, or NaN where GTSAM finds the system indeterminate.

    GTSAM raises a bare ``RuntimeError`` ("Indeterminate linear system") when the information
    is numerically singular; whether that matters is decided by :func:`fisher_rank` (the
    covariance is withheld when the data's information is rank-deficient, and a failure is
    reported otherwise).
    """
    try:
        return np.asarray(compute(), dtype=float)
    except RuntimeError:
        return np.full((2, 2), np.nan)


# --------------------------------------------------------------------------------------------
# evidence and information (numpy, the same in batch and streaming)
# --------------------------------------------------------------------------------------------


def chain_log_evidence(
    frames: Sequence[FrameModel],
    estimates_m: ArrayLike,
    *,
    random_walk: bool,
    step_sigmas: FloatArray,
    prior_mean_m: ArrayLike,
    prior_sigma_m: float,
) -> tuple[float, FloatArray]:
    r"""Laplace log evidence of one hypothesis and the data's Fisher information.

    .. math::

        \log Z \approx -\tfrac12\,\chi^2(\hat s) - \tfrac12\log\det\Lambda(\hat s)

    up to a constant shared by the hypotheses, with ``χ²`` the sum of every squared whitened
    residual of the graph (frames, random-walk links, prior) and ``Λ`` its Gauss-Newton
    information, block tridiagonal over the variables; its log determinant is accumulated by
    block elimination in order (``S_t = D_t − W_t S_{t−1}⁻¹ W_t``).

    Returns ``(log_evidence, data_information)``, the latter ``Σ_t E_tᵀE_t`` (MATH §8) at each
    frame's variable: its rank says whether the data determine the emitter.
    """
    estimates = np.asarray(estimates_m, dtype=float).reshape(-1, 2)
    variables = variable_of_frame(len(frames), random_walk)
    offset = estimates[0] - np.asarray(prior_mean_m, dtype=float)
    chi2 = float(offset @ offset) / prior_sigma_m**2
    # every frame at once, each sample at its frame's variable
    sample_variable = np.repeat(variables, [len(frame.position_m) for frame in frames])
    e, E = FrameModel.stacked(frames).whitened_error_and_jacobian_per_sample(
        estimates[sample_variable]
    )
    chi2 += float(e @ e)
    data_information = E.T @ E
    blocks = np.zeros((len(estimates), 2, 2))
    if random_walk:
        row_variable = np.concatenate([sample_variable, sample_variable])
        for i, j in ((0, 0), (0, 1), (1, 1)):
            blocks[:, i, j] = np.bincount(
                row_variable, weights=E[:, i] * E[:, j], minlength=len(estimates)
            )
        blocks[:, 1, 0] = blocks[:, 0, 1]
    else:
        blocks[0] = data_information
    blocks[0] += np.eye(2) / prior_sigma_m**2
    log_det = 0.0
    if random_walk:
        links = 1.0 / np.asarray(step_sigmas, dtype=float) ** 2
        steps = np.diff(estimates, axis=0)
        chi2 += float(np.sum(links * np.sum(steps**2, axis=1)))
        blocks[:-1] += links[:, None, None] * np.eye(2)
        blocks[1:] += links[:, None, None] * np.eye(2)
        # S_0 = D_0, S_t = D_t − w_t² S_{t−1}⁻¹ (2×2 in closed form), log det Λ = Σ log det S_t
        a, b, d = (float(x) for x in (blocks[0, 0, 0], blocks[0, 0, 1], blocks[0, 1, 1]))
        for t in range(1, len(estimates)):
            det = a * d - b * b
            log_det += math.log(det)
            w2 = float(links[t - 1]) ** 2 / det
            a, b, d = (
                float(blocks[t, 0, 0]) - w2 * d,
                float(blocks[t, 0, 1]) + w2 * b,
                float(blocks[t, 1, 1]) - w2 * a,
            )
        log_det += math.log(a * d - b * b)
    else:
        log_det = float(np.linalg.slogdet(blocks[0])[1])
    return float(-0.5 * chi2 - 0.5 * log_det), data_information


# --------------------------------------------------------------------------------------------
# state
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
        :func:`chain_log_evidence` at the optimum.
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
    """

    estimates_m: FloatArray
    covariance_m2: FloatArray
    log_weight: float
    data_information: FloatArray
    prior_mean_m: FloatArray
    start_frames: int
    start_values_m: FloatArray
    token: str

    def __post_init__(self) -> None:
        read_only(
            self.estimates_m,
            self.covariance_m2,
            self.data_information,
            self.prior_mean_m,
            self.start_values_m,
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
        )


@dataclass(frozen=True, slots=True, eq=False)
class SmootherState:
    """The frames seen and each hypothesis's optimum; an immutable, picklable value.

    While ``track`` is not None the second hypothesis is the reflection of the first.
    """

    frames: tuple[FrameModel, ...] = ()
    hypotheses: tuple[SmootherHypothesis, ...] = ()
    track: StraightTrack | None = None
    length_scale_m: float = math.nan
    iterations: int = 0
    failure: str = ""
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def all_hypotheses(self) -> tuple[SmootherHypothesis, ...]:
        if self.track is None or not self.hypotheses:
            return self.hypotheses
        return (*self.hypotheses, self.hypotheses[0].mirrored(self.track))


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class GtsamSmoother:
    """Factor-graph smoother (GTSAM 4.3): LM in batch, ISAM2 streaming, per mirror hypothesis.

    Parameters
    ----------
    process_noise_mps : float
        ``q``: one variable per frame linked by random-walk steps of standard deviation
        ``q Δt`` per axis. 0 (default): one variable, a static emitter; the optimum is then the
        maximum likelihood over all frames (MATH §10).
    max_iterations : int
        Levenberg-Marquardt iterations of the batch solve, at most.
    """

    name: ClassVar[str] = "gtsam-smoother"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    process_noise_mps: float = 0.0
    max_iterations: int = 100

    def __post_init__(self) -> None:
        q = self.process_noise_mps
        if not isinstance(q, int | float) or not math.isfinite(q) or q < 0:
            raise ValueError(f"process_noise_mps: must be a finite number >= 0, got {q!r}")
        n = self.max_iterations
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {n!r}")

    @property
    def random_walk(self) -> bool:
        return self.process_noise_mps > 0.0

    # -- batch ----------------------------------------------------------------------------------

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """Levenberg-Marquardt on every hypothesis's full graph."""
        require_modalities(self, data)
        frame_data = list(data.iter_frames())
        frames = tuple(FrameModel.from_measurements(frame) for frame in frame_data)
        steps = step_sigmas_m(frames, self.process_noise_mps) if self.random_walk else np.empty(0)
        try:
            candidates = first_frame_candidates(frame_data[0])
            length_scale = frames[0].mean_range_m(candidates[0])
            prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale
            first_track = StraightTrack.of_frame(frames[0])
            track = first_track
            for frame in frames[1:]:
                track = None if track is None else track.extended(frame)
            if first_track is None:
                starts = candidates
            elif track is not None:
                starts = candidates[:1]
            else:
                starts = np.vstack([candidates[:1], first_track.mirror_point(candidates[:1])])
            hypotheses = []
            iterations = 0
            for start in starts:
                hypothesis, n_iter = self._batch_hypothesis(frames, start, steps, prior_sigma)
                hypotheses.append(hypothesis)
                iterations = max(iterations, n_iter)
        except EstimationFailure as error:
            return Estimate.failed(self.name, str(error), frames=len(frames))
        state = SmootherState(
            frames=frames,
            hypotheses=tuple(hypotheses),
            track=track,
            length_scale_m=length_scale,
            iterations=iterations,
            diagnostics={"first_frame_candidates": len(candidates), "mode": "batch"},
        )
        return self.estimate_state(state, rng=rng)

    def _batch_hypothesis(
        self,
        frames: tuple[FrameModel, ...],
        start_m: FloatArray,
        steps: FloatArray,
        prior_sigma_m: float,
    ) -> tuple[SmootherHypothesis, int]:
        import gtsam
        from gtsam.symbol_shorthand import X

        n_variables = len(frames) if self.random_walk else 1
        graph = graph_part(
            frames,
            0,
            len(frames),
            random_walk=self.random_walk,
            step_sigmas=steps,
            prior_mean_m=start_m,
            prior_sigma_m=prior_sigma_m,
        )
        initial = values_of(np.tile(start_m, (n_variables, 1)))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.max_iterations)
        params.setRelativeErrorTol(1e-15)
        params.setAbsoluteErrorTol(1e-15)
        try:
            optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
            result = optimizer.optimize()
        except RuntimeError as error:
            raise EstimationFailure(f"GTSAM failed in the batch solve ({error})") from None
        estimates = np.array([result.atPoint2(X(i)) for i in range(n_variables)])
        covariance = _marginal_covariance(
            lambda: gtsam.Marginals(graph, result).marginalCovariance(X(n_variables - 1))
        )
        return (
            self._hypothesis(frames, estimates, covariance, start_m, prior_sigma_m, steps),
            int(optimizer.iterations()),
        )

    def _hypothesis(
        self,
        frames: Sequence[FrameModel],
        estimates: FloatArray,
        covariance: FloatArray,
        prior_mean_m: FloatArray,
        prior_sigma_m: float,
        steps: FloatArray,
        *,
        start_frames: int = 0,
        start_values_m: FloatArray | None = None,
        token: str = "",
    ) -> SmootherHypothesis:
        if not np.all(np.isfinite(estimates)):
            raise EstimationFailure("GTSAM returned a non-finite estimate")
        log_weight, information = chain_log_evidence(
            frames,
            estimates,
            random_walk=self.random_walk,
            step_sigmas=steps,
            prior_mean_m=prior_mean_m,
            prior_sigma_m=prior_sigma_m,
        )
        covariance = np.asarray(covariance, dtype=float)
        if not np.all(np.isfinite(covariance)) and fisher_rank(information) == 2:
            raise EstimationFailure("GTSAM could not compute the marginal covariance")
        return SmootherHypothesis(
            estimates_m=np.asarray(estimates, dtype=float),
            covariance_m2=0.5 * (covariance + covariance.T),
            log_weight=log_weight,
            data_information=information,
            prior_mean_m=np.asarray(prior_mean_m, dtype=float),
            start_frames=start_frames,
            start_values_m=np.empty((0, 2)) if start_values_m is None else start_values_m,
            token=token,
        )

    # -- the SequentialEstimator pair -------------------------------------------------------------

    def init(self) -> SmootherState:
        """No frame yet."""
        return SmootherState()

    def update(self, state: SmootherState, frame: MeasurementSet) -> SmootherState:
        """The state after one more frame: each hypothesis's ISAM2 extended and re-optimised."""
        require_modalities(self, frame)
        model = FrameModel.from_measurements(frame)
        frames = (*state.frames, model)
        if state.failure:
            return replace(state, frames=frames)
        steps = step_sigmas_m(frames, self.process_noise_mps) if self.random_walk else np.empty(0)
        try:
            if not state.frames:
                return self._first_update(frame, model, steps)
            return self._next_update(state, frames, steps)
        except EstimationFailure as error:
            return replace(state, frames=frames, failure=str(error))

    def estimate_state(
        self, state: SmootherState, *, rng: np.random.Generator | None = None
    ) -> Estimate:
        """The estimate of the last emitter variable (``rng`` breaks an exact mirror tie)."""
        if state.failure:
            return Estimate.failed(self.name, state.failure, frames=state.n_frames)
        if not state.frames:
            return Estimate.failed(self.name, "no frame has been processed yet", frames=0)
        hypotheses = state.all_hypotheses()
        return hypotheses_estimate(
            self.name,
            [h.estimates_m[-1] for h in hypotheses],
            [h.covariance_m2 for h in hypotheses],
            [h.log_weight for h in hypotheses],
            [h.data_information for h in hypotheses],
            straight_track=state.track is not None,
            length_scale_m=state.length_scale_m,
            rng=rng,
            diagnostics={
                "mode": "streaming",
                **state.diagnostics,
                "frames": state.n_frames,
                "iterations": state.iterations,
                "random_walk": self.random_walk,
            },
        )

    # -- streaming internals ----------------------------------------------------------------------

    def _first_update(
        self, frame: MeasurementSet, model: FrameModel, steps: FloatArray
    ) -> SmootherState:
        candidates = first_frame_candidates(frame)
        track = StraightTrack.of_frame(model)
        starts = candidates[:1] if track is not None else candidates
        length_scale = model.mean_range_m(candidates[0])
        frames = (model,)
        hypotheses = []
        iterations = 0
        for start in starts:
            hypothesis, n_iter = self._start_isam2(
                frames, start[None, :], start, steps, length_scale
            )
            hypotheses.append(hypothesis)
            iterations = max(iterations, n_iter)
        return SmootherState(
            frames=frames,
            hypotheses=tuple(hypotheses),
            track=track,
            length_scale_m=length_scale,
            iterations=iterations,
            diagnostics={"first_frame_candidates": len(candidates)},
        )

    def _next_update(
        self, state: SmootherState, frames: tuple[FrameModel, ...], steps: FloatArray
    ) -> SmootherState:
        model = frames[-1]
        track = None if state.track is None else state.track.extended(model)
        updated = []
        iterations = 0
        for hypothesis in state.hypotheses:
            extended, n_iter = self._extend_isam2(state, hypothesis, frames, steps)
            updated.append(extended)
            iterations = max(iterations, n_iter)
        if state.track is not None and track is None:
            # the first frame off the line: fork the mirror hypothesis with its own ISAM2
            first = state.hypotheses[0]
            mirror = first.mirrored(state.track)
            distance = np.linalg.norm(mirror.estimates_m[-1] - first.estimates_m[-1])
            if distance > MERGE_RTOL * state.length_scale_m:
                start_values = mirror.estimates_m
                if self.random_walk:
                    start_values = np.vstack([start_values, start_values[-1:]])
                forked, n_iter = self._start_isam2(
                    frames, start_values, mirror.prior_mean_m, steps, state.length_scale_m
                )
                updated.append(forked)
                iterations = max(iterations, n_iter)
        if track is None:
            kept, _ = surviving_hypotheses(
                [h.estimates_m[-1] for h in updated],
                [h.log_weight for h in updated],
                state.length_scale_m,
            )
            for index, hypothesis in enumerate(updated):
                if index not in kept:
                    _LIVE_ISAM2.pop(hypothesis.token, None)
            updated = [updated[i] for i in kept]
        return replace(
            state, frames=frames, hypotheses=tuple(updated), track=track, iterations=iterations
        )

    def _isam2_params(self, length_scale_m: float) -> Any:
        import gtsam

        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE_RTOL * length_scale_m)
        params.relinearizeSkip = 1
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        # QR on the Jacobian, not Cholesky on JᵀJ: the diffuse prior against a tight
        # random-walk link squares to a condition number Cholesky calls indeterminate
        params.setFactorization("QR")
        return params

    def _iterate(self, isam: Any, new_graph: Any, new_values: Any) -> int:
        """Add factors, then step ISAM2 until no variable needs relinearising."""
        isam.update(new_graph, new_values)
        steps = 0
        while steps < MAX_ISAM2_STEPS:
            steps += 1
            if isam.update().getVariablesRelinearized() == 0:
                break
        return steps

    def _start_isam2(
        self,
        frames: tuple[FrameModel, ...],
        start_values_m: FloatArray,
        prior_mean_m: FloatArray,
        steps: FloatArray,
        length_scale_m: float,
    ) -> tuple[SmootherHypothesis, int]:
        """A new ISAM2 holding ``frames`` at once, started at ``start_values_m``."""
        import gtsam

        prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
        try:
            isam = gtsam.ISAM2(self._isam2_params(length_scale_m))
            graph = graph_part(
                frames,
                0,
                len(frames),
                random_walk=self.random_walk,
                step_sigmas=steps,
                prior_mean_m=prior_mean_m,
                prior_sigma_m=prior_sigma,
            )
            n_iter = self._iterate(isam, graph, values_of(start_values_m))
        except RuntimeError as error:
            raise EstimationFailure(f"GTSAM ISAM2 failed ({error})") from None
        token = self._checkin(isam, len(frames))
        hypothesis = self._read_isam2(
            isam,
            frames,
            prior_mean_m,
            prior_sigma,
            steps,
            start_frames=len(frames),
            start_values_m=np.array(start_values_m, dtype=float),
            token=token,
        )
        return hypothesis, n_iter

    def _extend_isam2(
        self,
        state: SmootherState,
        hypothesis: SmootherHypothesis,
        frames: tuple[FrameModel, ...],
        steps: FloatArray,
    ) -> tuple[SmootherHypothesis, int]:
        """The hypothesis's ISAM2 (cached, else replayed) with the last frame added."""
        prior_sigma = DIFFUSE_PRIOR_SCALE * state.length_scale_m
        try:
            isam = self._checkout(hypothesis.token, state.n_frames)
            if isam is None:
                isam = self._replay(hypothesis, frames[:-1], steps, state.length_scale_m)
            n_iter = self._add_frame(isam, frames, steps, prior_sigma)
        except RuntimeError as error:
            raise EstimationFailure(f"GTSAM ISAM2 failed ({error})") from None
        token = self._checkin(isam, len(frames))
        extended = self._read_isam2(
            isam,
            frames,
            hypothesis.prior_mean_m,
            prior_sigma,
            steps,
            start_frames=hypothesis.start_frames,
            start_values_m=hypothesis.start_values_m,
            token=token,
        )
        return extended, n_iter

    def _add_frame(
        self, isam: Any, frames: tuple[FrameModel, ...], steps: FloatArray, prior_sigma: float
    ) -> int:
        """Add the last of ``frames`` to ``isam`` and iterate to the optimum."""
        import gtsam
        from gtsam.symbol_shorthand import X

        t = len(frames) - 1
        graph = graph_part(
            frames,
            t,
            t + 1,
            random_walk=self.random_walk,
            step_sigmas=steps,
            prior_mean_m=None,
            prior_sigma_m=prior_sigma,
        )
        values = gtsam.Values()
        if self.random_walk:
            values.insert(X(t), np.array(isam.calculateEstimatePoint2(X(t - 1))))
        return self._iterate(isam, graph, values)

    def _replay(
        self,
        hypothesis: SmootherHypothesis,
        frames: tuple[FrameModel, ...],
        steps: FloatArray,
        length_scale_m: float,
    ) -> Any:
        """Rebuild a hypothesis's ISAM2 from its recipe, by the same operations as streaming."""
        import gtsam

        prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
        isam = gtsam.ISAM2(self._isam2_params(length_scale_m))
        start = hypothesis.start_frames
        graph = graph_part(
            frames,
            0,
            start,
            random_walk=self.random_walk,
            step_sigmas=steps,
            prior_mean_m=hypothesis.prior_mean_m,
            prior_sigma_m=prior_sigma,
        )
        self._iterate(isam, graph, values_of(hypothesis.start_values_m))
        for stop in range(start + 1, len(frames) + 1):
            self._add_frame(isam, frames[:stop], steps, prior_sigma)
        return isam

    def _read_isam2(
        self,
        isam: Any,
        frames: tuple[FrameModel, ...],
        prior_mean_m: FloatArray,
        prior_sigma: float,
        steps: FloatArray,
        **recipe: Any,
    ) -> SmootherHypothesis:
        from gtsam.symbol_shorthand import X

        n_variables = len(frames) if self.random_walk else 1
        try:
            estimate = isam.calculateBestEstimate()
        except RuntimeError as error:
            raise EstimationFailure(f"GTSAM ISAM2 failed ({error})") from None
        estimates = np.array([estimate.atPoint2(X(i)) for i in range(n_variables)])
        covariance = _marginal_covariance(lambda: isam.marginalCovariance(X(n_variables - 1)))
        return self._hypothesis(
            frames, estimates, covariance, prior_mean_m, prior_sigma, steps, **recipe
        )

    # -- the per-process ISAM2 cache --------------------------------------------------------------

    @staticmethod
    def _checkout(token: str, n_frames: int) -> Any:
        """Take the live ISAM2 filed under ``token`` if it holds ``n_frames`` frames."""
        entry = _LIVE_ISAM2.pop(token, None)
        if entry is None or entry[1] != n_frames:
            return None
        return entry[0]

    @staticmethod
    def _checkin(isam: Any, n_frames: int) -> str:
        """File ``isam`` under a fresh token; evict the least recently filed beyond the limit."""
        token = uuid.uuid4().hex
        _LIVE_ISAM2[token] = (isam, n_frames)
        while len(_LIVE_ISAM2) > LIVE_CACHE_SIZE:
            _LIVE_ISAM2.popitem(last=False)
        return token
