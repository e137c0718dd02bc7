r"""A GTSAM factor-graph smoother over frames, one graph per mirror hypothesis (MATH §7, §8, §10).

**The graph** (:mod:`estimators.sequential.smoother_graph`). One emitter variable ``X(0)`` when the
emitter is static (``process_noise_mps = 0``, the default), else one variable ``X(t)`` per frame
linked by random-walk steps of ``σ = q Δt_t``. Each frame adds ONE vectorised ``CustomFactor``
for its stacked, whitened Doppler and range residuals
(:class:`estimators.frame_model.FrameModel`). A diffuse prior on ``X(0)`` at the hypothesis's
starting candidate keeps every linear system regular (it moves a well-determined estimate by a
relative ``~1e−10``); that the data themselves determine the emitter is checked separately, from
the rank of the accumulated Fisher information (MATH §8), because GTSAM's Levenberg-Marquardt
returns garbage on an underdetermined graph without raising and ISAM2/Marginals raise a bare
``RuntimeError`` (traps of GTSAM 4.3's Python bindings).

With a static emitter the optimum is the maximum likelihood over all frames (MATH §10). The
reported covariance is the marginal covariance of the last variable at the estimate (the inverse
Fisher information in the static case): GTSAM's ``Marginals`` in batch, the inverse of the same
marginal information from the graph's 2×2 block elimination when streaming.

**Batch and streaming.** :meth:`GtsamSmoother.estimate` builds each hypothesis's full graph and
runs Levenberg-Marquardt; :meth:`GtsamSmoother.update` adds the new frame's factor (and link) to
an ISAM2 per hypothesis and steps it until no variable needs relinearising
(:mod:`estimators.sequential.smoother_hypotheses`, which also says why the live ISAM2 objects sit in
a private per-process cache). Only new factors enter ISAM2, and a variable is relinearised only
when its step from its linearisation point reaches ``5·10⁻⁴`` of the length scale, so once
converged a frame costs one factor evaluation however many frames came before. Beside each
ISAM2 its frames are kept to third order about ISAM2's linearisation point (additive per-frame
sums, :class:`~estimators.sequential.smoother_graph.Expansion`): ISAM2's Gauss-Newton estimate,
which with old factors linearised at a stale point is ~``10⁻³`` of the distance off, is finished
there by Newton's method, and every check below reads its cost, decrement and curvature from those
sums, so streaming converges to the same optimum as the batch solve. Hypothesis weights are
Laplace approximations of each hypothesis's evidence at its optimum,
``−½χ²(ŝ) − ½ log det Λ(ŝ)`` (:func:`~estimators.sequential.smoother_graph.chain_fit`), computed the
same way in both modes. Pruning is decided after every frame when streaming and once on all the data
in batch; the two differ only if a hypothesis's weight crosses ``1e−9`` and then climbs back.

**Convergence and the batch fallback (no silent divergence).** ISAM2 takes undamped Gauss-Newton
steps. Near the track, where the data barely fix the cross-track coordinate (every emitter close
to the line of a straight track, common at low SNR), those steps are metres to kilometres long
and ISAM2 can walk off to hundreds of kilometres while the batch Levenberg-Marquardt, which
damps its steps, stays at the optimum. On ``paper-1m-turn`` at −20 dB, 34 streamed estimates in
17 of 500 trials were more than 5 √CRLB (up to 2·10⁵ √CRLB) from the maximum likelihood of the
same frames with ``success=True`` and an empty message, all before the turn. So every streaming
update is checked, per hypothesis, against the whitened cost ``χ²`` of the graph and the
decrement ``δ`` at the result (:func:`~estimators.sequential.smoother_graph.fit_from_sums` on the
expansion, or :func:`~estimators.sequential.smoother_graph.chain_fit` on the frames when the result
lies outside the expansion's trust radius;
``δ ≤ DECREMENT_TOL`` is convergence, "Convergence" in :mod:`estimators.convergence`). The
update is rejected when

- ``δ > DECREMENT_TOL`` at the result: ISAM2 still relinearising at its step cap
  (:data:`~estimators.sequential.smoother_hypotheses.MAX_ISAM2_STEPS`), or stopped away from a
  stationary point;
- the cost rose: ``χ²`` at the result above ``χ²`` of the update's starting point (the previous
  optimum's ``χ²`` plus the new frame's residuals there), beyond rounding
  (:data:`~estimators.sequential.smoother_batch.COST_RISE_RTOL`);
- the result is a saddle point: the exact Hessian has negative curvature
  (:meth:`~estimators.sequential.smoother_graph.ChainFit.saddle_direction`). A hypothesis started at
  the closed form's on-track candidate stays on the track's vertical plane by symmetry after the
  minimum has moved off it;
- GTSAM raised, or returned a non-finite estimate;
- the result misfits the data, ``χ² > χ²_m(1 − α)`` (``m`` measurements; the graph's residual
  has ``m`` degrees of freedom, prior and random-walk rows counted against their unknowns),
  *and* a batch solve of the same frames reaches a cost lower by more than ``χ²_p(1 − α)``
  (``p`` unknowns): by Wilks' theorem the ISAM2 point then lies outside the batch optimum's
  ``1 − α`` confidence region. ``α =`` :data:`CONVERGENCE_ALPHA`.

A rejected update falls back to the batch solve (Levenberg-Marquardt on all the hypothesis's
frames, from the previous optimum and from its starting candidate; cheap for a 2-D unknown),
``message`` and ``diagnostics`` say so (``fallback="batch"``, ``fallback_reason``, the running
count ``fallbacks``), and its ISAM2 is re-seeded at the batch optimum. If the batch solve fails
its own checks too, the estimate fails with both reasons. The batch solve
(:mod:`estimators.sequential.smoother_batch`; also :meth:`GtsamSmoother.estimate`) is checked the
same way. Levenberg-Marquardt short of convergence (its cap, or a stall, with ``δ > DECREMENT_TOL``;
in the flat near-track valley it can need hundreds of iterations) is finished by Newton's method on
the whole graph, and a saddle is left along its negative curvature
(``diagnostics["lm_fallback"]``); a result that still has not converged, or ends above its
starting cost, is a failure. On the −20 dB sweep above, 207 of 5000 streamed updates fell back
(86 saddles, 121 steps that did not converge, 67 of them raising the cost), all before the turn,
and none failed; at 0 dB none fell back.

**Unknown nuisance parameters** (MATH §15). When the data declare the carrier offset δ or the
emission time b unknown, everything above is replaced by
:mod:`estimators.sequential.smoother_nuisance`: the same graph with one more variable holding them
(δ in Hz, ``c b`` in metres; the frame factors' Jacobians gain the constant columns ``∂f_k/∂δ = 1``,
``∂r_k/∂(c b) = 1``), started by :mod:`estimators.sequential.nuisance_starts`, solved by checked
Levenberg-Marquardt in batch and, when streaming, by ISAM2 with the nuisance one of its variables
(each update adds the new frame's factor; Newton's method on the whole graph's fit finishes it,
Levenberg-Marquardt on the whole graph is the checked fallback); their values are reported in
``diagnostics``.

**The height unknown** (MATH §7, §8). The emitter variables are ``Point3``, the frame factors'
Jacobians ``(2K, 3)``. A straight track leaves a circle: the batch solve fails with the mirror
rule's line and streaming keeps the frames of the first straight track without a hypothesis;
with a second heading every hypothesis starts from a point of the first frame's circle below
the UAV (:func:`~estimators.sequential.nuisance_starts.height_starts`) and is solved by the
checked Levenberg-Marquardt above; with a random walk every frame's variable starts at the
static optimum reached from that point (one frame alone leaves its variable on its own circle),
and Levenberg-Marquardt's steps are solved by QR, not Cholesky
(:func:`~estimators.sequential.smoother_batch.linear_solver`: the links alone hold each
variable along its frame's circle, and at high SNR GTSAM's Cholesky calls that system
indeterminate). The streaming expansion to third order is in ``(x, y)``, so
a streaming update re-solves each hypothesis's whole graph from its previous optimum instead of
extending an ISAM2 (a cost that grows with the frames: 4.5 ms against ISAM2's 0.7 ms at the
sixteenth frame of a climbing flight). A hypothesis above the UAV's highest sample is no answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from estimators.base import Capabilities, Estimate, require_modalities
from estimators.convergence import COST_ROUNDING_RTOL, DECREMENT_TOL, EstimationFailure
from estimators.frame_model import FrameModel
from estimators.goodness_of_fit import with_fit
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sequential import smoother_nuisance
from estimators.sequential.mirror_hypotheses import (
    DIFFUSE_PRIOR_SCALE,
    MERGE_RTOL,
    first_frame_candidates,
    hypothesis_starts,
    smoother_estimate,
)
from estimators.sequential.nuisance_starts import height_starts
from estimators.sequential.nuisance_states import (
    NUISANCE_UNKNOWNS,
    check_same_unknowns,
    nuisance_names,
)
from estimators.sequential.smoother_batch import COST_RISE_RTOL, best_lm_solve, lm_solve
from estimators.sequential.smoother_graph import chain_fit, step_sigmas_m
from estimators.sequential.smoother_hypotheses import (
    MAX_ISAM2_STEPS,
    LiveGraph,
    SmootherHypothesis,
    SmootherState,
    add_frame,
    checkin,
    checkout,
    discard,
    new_live,
    pruned_hypotheses,
    replay_live,
)
from scenarios.geometry import StraightTrack
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]

CONVERGENCE_ALPHA = 1e-3
"""False-alarm level of the χ² tests that compare a streaming result with the batch optimum
(module text): a misfit ``χ² > χ²_m(1 − α)`` calls for a batch solve, and a batch optimum
lower by more than ``χ²_p(1 − α)`` replaces the ISAM2 result."""


@dataclass(frozen=True, slots=True, eq=False)
class _Outcome:
    """One hypothesis after one streaming update: its state, the ISAM2 steps taken and, if it
    fell back to the batch solve, why."""

    hypothesis: SmootherHypothesis
    steps: int
    fallback_reason: str = ""


def _chi2_quantile(dof: int) -> float:
    """``χ²_dof(1 − CONVERGENCE_ALPHA)``: the upper quantile of the module text's tests."""
    from scipy.special import chdtri

    return float(chdtri(dof, CONVERGENCE_ALPHA))


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
    required_modules: ClassVar[tuple[str, ...]] = ("gtsam",)

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

    def capabilities(self) -> Capabilities:
        return Capabilities(
            modalities=self.requires,
            modules=self.required_modules,
            sequential=True,
            unit_invariant=self.process_noise_mps == 0.0,  # q is in m/s
            unknowns=NUISANCE_UNKNOWNS | {HEIGHT_UNKNOWN},
        )

    def _nuisance_options(self) -> dict[str, Any]:
        """What :mod:`estimators.sequential.smoother_nuisance` needs of this estimator."""
        return {
            "name": self.name,
            "process_noise_mps": self.process_noise_mps,
            "max_iterations": self.max_iterations,
        }

    # -- batch ----------------------------------------------------------------------------------

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """Levenberg-Marquardt on every hypothesis's full graph, each solve checked (module text).
        With unknown nuisance parameters (``data.unknowns``, MATH §15) the graph carries them
        as one more variable (:mod:`estimators.sequential.smoother_nuisance`). The goodness of fit
        of the answer is in ``diagnostics`` (MATH §17)."""
        return with_fit(self, self._solve_graph(data, rng), data)

    def _solve_graph(self, data: MeasurementSet, rng: np.random.Generator | None) -> Estimate:
        require_modalities(self, data)
        if nuisance_names(data):
            return smoother_nuisance.estimate(data, self._nuisance_options(), rng)
        frame_data = list(data.iter_frames())
        frames = tuple(FrameModel.from_measurements(frame) for frame in frame_data)
        steps = step_sigmas_m(frames, self.process_noise_mps) if self.random_walk else np.empty(0)
        n_variables = len(frames) if self.random_walk else 1
        if frames[0].dimension == 3:  # the height unknown
            try:
                state = self._height_start(frames, steps, mode="batch")
            except EstimationFailure as error:
                return Estimate.failed(self.name, str(error), dimension=3, frames=len(frames))
            return self.estimate_state(state, rng=rng)
        try:
            candidates = first_frame_candidates(frame_data[0])
            length_scale = frames[0].mean_range_m(candidates[0])
            prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale
            first_track = StraightTrack.of_frame(frames[0])
            track = first_track
            for frame in frames[1:]:
                track = None if track is None else track.extended(frame)
            starts = hypothesis_starts(candidates, first_track, track)
            hypotheses = []
            reports = []
            for start in starts:
                hypothesis, report = lm_solve(
                    frames,
                    np.tile(start, (n_variables, 1)),
                    start,
                    steps,
                    prior_sigma,
                    random_walk=self.random_walk,
                    max_iterations=self.max_iterations,
                )
                if not report.converged:
                    raise EstimationFailure(f"batch solve: {report.reason}")
                hypotheses.append(hypothesis)
                reports.append(report)
        except EstimationFailure as error:
            return Estimate.failed(self.name, str(error), frames=len(frames))
        state = SmootherState(
            frames=frames,
            hypotheses=tuple(hypotheses),
            track=track,
            length_scale_m=length_scale,
            iterations=max(r.iterations for r in reports),
            diagnostics={
                "first_frame_candidates": len(candidates),
                "mode": "batch",
                "max_iterations": self.max_iterations,
                "decrement": max(r.decrement for r in reports),
                "lm_fallback": "+".join(dict.fromkeys(r.fallback for r in reports if r.fallback))
                or "none",
            },
        )
        return self.estimate_state(state, rng=rng)

    # -- the SequentialEstimator pair -------------------------------------------------------------

    def init(self) -> SmootherState:
        """No frame yet."""
        return SmootherState()

    def update(
        self, state: SmootherState | smoother_nuisance.NuisanceSmootherState, frame: MeasurementSet
    ) -> SmootherState | smoother_nuisance.NuisanceSmootherState:
        """The state after one more frame: each hypothesis's ISAM2 extended, re-optimised and
        checked; a hypothesis whose update did not converge falls back to the batch solve.
        With unknown nuisance parameters (MATH §15) they are one more ISAM2 variable
        (:func:`estimators.sequential.smoother_nuisance.update`)."""
        require_modalities(self, frame)
        if isinstance(state, smoother_nuisance.NuisanceSmootherState):
            check_same_unknowns(state.frames[0].names, frame, state.frames[0].dimension)
            return smoother_nuisance.update(state, frame, self._nuisance_options())
        if nuisance_names(frame):
            if state.frames:
                check_same_unknowns((), frame, state.frames[0].dimension)
            fresh = smoother_nuisance.NuisanceSmootherState()
            return smoother_nuisance.update(fresh, frame, self._nuisance_options())
        model = FrameModel.from_measurements(frame)
        if state.frames and model.dimension != state.frames[0].dimension:
            check_same_unknowns((), frame, state.frames[0].dimension)
        frames = (*state.frames, model)
        if state.failure:
            return replace(state, frames=frames)
        steps = step_sigmas_m(frames, self.process_noise_mps) if self.random_walk else np.empty(0)
        try:
            if model.dimension == 3:
                return self._height_update(state, frames, steps)
            if not state.frames:
                return self._first_update(frame, model, steps)
            return self._next_update(state, frames, steps)
        except EstimationFailure as error:
            return replace(state, frames=frames, failure=str(error))

    def estimate_state(
        self,
        state: SmootherState | smoother_nuisance.NuisanceSmootherState,
        *,
        rng: np.random.Generator | None = None,
    ) -> Estimate:
        """The estimate of the last emitter variable (``rng`` breaks an exact mirror tie); with
        unknown nuisance parameters their values are in ``diagnostics`` (MATH §15)."""
        if isinstance(state, smoother_nuisance.NuisanceSmootherState):
            return smoother_nuisance.estimate_state(state, self._nuisance_options(), rng)
        if not state.frames:
            return Estimate.failed(self.name, "no frame has been processed yet", frames=0)
        d = state.frames[0].dimension  # 3 with the height unknown
        if state.failure:
            return Estimate.failed(self.name, state.failure, dimension=d, frames=state.n_frames)
        if d == 3 and not state.hypotheses:  # every frame so far on one straight track
            return Estimate.failed(
                self.name, STRAIGHT_TRACK_HEIGHT, dimension=3, frames=state.n_frames
            )
        hypotheses = state.all_hypotheses()
        diagnostics: dict[str, Any] = {"mode": "streaming", **state.diagnostics}
        notes = []
        if diagnostics["mode"] == "streaming":
            diagnostics.update(
                fallback="batch" if state.fallback_reason else "none",
                fallback_reason=state.fallback_reason,
                fallbacks=state.fallbacks,
                max_isam2_steps=MAX_ISAM2_STEPS,
            )
            if state.fallback_reason:
                notes.append(
                    f"ISAM2's update of frame {state.n_frames - 1} failed its convergence checks "
                    f"({state.fallback_reason}); fell back to the batch solve "
                    f"(Levenberg-Marquardt on all {state.n_frames} frames)"
                )
        return smoother_estimate(
            self.name,
            state,
            hypotheses,
            rng=rng,
            notes=notes,
            diagnostics=diagnostics,
            random_walk=self.random_walk,
            ceiling_m=max(float(f.position_m[:, 2].max()) for f in state.frames)
            if d == 3
            else None,
        )

    # -- the height unknown ----------------------------------------------------------------------

    def _height_start(
        self, frames: tuple[FrameModel, ...], steps: FloatArray, *, mode: str
    ) -> SmootherState:
        """The hypotheses with the height unknown (MATH §7, §8): Levenberg-Marquardt on all
        ``frames`` from each start on the first frame's ambiguity circle below the UAV
        (:func:`~estimators.sequential.nuisance_starts.height_starts`); the converged ones,
        merged and pruned. Raises :class:`EstimationFailure` on a straight track (the height
        is not fixed: :data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`) or when no solve
        converged."""
        starts = height_starts(frames)
        length_scale = frames[0].mean_range_m(starts[0])
        prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale
        hypotheses, reports, reasons = [], [], []
        for start, initial in self._height_initial_values(frames, starts, length_scale):
            try:
                hypothesis, report = lm_solve(
                    frames,
                    initial,
                    start,
                    steps,
                    prior_sigma,
                    random_walk=self.random_walk,
                    max_iterations=self.max_iterations,
                )
            except EstimationFailure as error:
                reasons.append(str(error))
                continue
            reports.append(report)
            if report.converged:
                hypotheses.append(hypothesis)
            else:
                reasons.append(report.reason)
        if not hypotheses:
            raise EstimationFailure(f"batch solve: {'; '.join(dict.fromkeys(reasons))}")
        return SmootherState(
            frames=frames,
            hypotheses=tuple(pruned_hypotheses(hypotheses, length_scale)),
            track=None,
            length_scale_m=length_scale,
            iterations=max(r.iterations for r in reports),
            diagnostics={
                "first_frame_candidates": len(starts),
                "mode": mode,
                "max_iterations": self.max_iterations,
                "decrement": max(h.decrement for h in hypotheses),
                "lm_fallback": "+".join(dict.fromkeys(r.fallback for r in reports if r.fallback))
                or "none",
            },
        )

    def _height_initial_values(
        self, frames: tuple[FrameModel, ...], starts_m: FloatArray, length_scale_m: float
    ) -> list[tuple[FloatArray, FloatArray]]:
        """Each hypothesis's start with the height unknown (MATH §7): ``(prior mean, initial
        values)``, one row of initial values per variable. A static emitter: each of
        ``starts_m`` (points of the first frame's circle). A random walk: every frame's
        variable at the static optimum of all ``frames`` reached from a start (the walk's
        optimum as ``q → 0``; on every frame's circle when the data are exact), each optimum
        once (closer than ``MERGE_RTOL`` of the length scale is one), or at the start itself
        where that solve did not converge.

        Why not the start for every frame: each frame alone leaves its own circle (MATH §7),
        and a later frame's variable started on the first frame's circle is metres to a
        hundred metres off its own, with only the links ``1/(qΔt)²`` to pull it along the
        circles. From three of the four starts on the far side of the track, noise-free
        ``climb-height`` (σ's at 100 dB, ``q = 0.5`` m/s) took Levenberg-Marquardt's 100
        iterations and Newton's method after it (0.13 s a batch estimate, 0.5 s on a
        16-frame climbing flight); from the static optima, a few iterations (0.03 s, 0.09 s;
        CPU time).
        """
        if not self.random_walk:
            return [(start, start[None, :]) for start in starts_m]
        prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
        initial: list[tuple[FloatArray, FloatArray]] = []
        for start in starts_m:
            point = start
            try:
                static, report = lm_solve(
                    frames,
                    start[None, :],
                    start,
                    np.empty(0),
                    prior_sigma,
                    random_walk=False,
                    max_iterations=self.max_iterations,
                )
                if report.converged:
                    point = static.estimates_m[0]
            except EstimationFailure:
                pass  # the walk starts at the start itself (and its solve is checked)
            if all(
                np.linalg.norm(point - values[0]) > MERGE_RTOL * length_scale_m
                for _, values in initial
            ):
                initial.append((start, np.tile(point, (len(frames), 1))))
        return initial

    def _height_update(
        self, state: SmootherState, frames: tuple[FrameModel, ...], steps: FloatArray
    ) -> SmootherState:
        """A streaming update with the height unknown: the frames of the first straight track
        wait (no hypothesis), the first frame off it starts the hypotheses
        (:meth:`_height_start`), and every later frame re-solves each hypothesis's whole graph
        by checked Levenberg-Marquardt from its previous optimum (the streaming expansion of
        :mod:`estimators.sequential.smoother_graph` is in ``(x, y)``)."""
        if not state.hypotheses:
            track = (
                StraightTrack.of_frame(frames[0])
                if len(frames) == 1
                else None
                if state.track is None
                else state.track.extended(frames[-1])
            )
            if track is not None:
                return replace(state, frames=frames, track=track)
            return self._height_start(frames, steps, mode="streaming")
        updated, reports = [], []
        for hypothesis in state.hypotheses:
            start_values = hypothesis.estimates_m
            if self.random_walk:  # the new variable starts at the last one
                start_values = np.vstack([start_values, start_values[-1:]])
            solved, report = lm_solve(
                frames,
                start_values,
                hypothesis.prior_mean_m,
                steps,
                DIFFUSE_PRIOR_SCALE * state.length_scale_m,
                random_walk=self.random_walk,
                max_iterations=self.max_iterations,
            )
            if not report.converged:
                raise EstimationFailure(f"frame {len(frames) - 1}: {report.reason}")
            updated.append(solved)
            reports.append(report)
        return replace(
            state,
            frames=frames,
            hypotheses=tuple(pruned_hypotheses(updated, state.length_scale_m)),
            iterations=max(r.iterations for r in reports),
            diagnostics={
                **state.diagnostics,
                "decrement": max(h.decrement for h in updated),
                "lm_fallback": "+".join(dict.fromkeys(r.fallback for r in reports if r.fallback))
                or "none",
            },
        )

    # -- streaming internals ----------------------------------------------------------------------

    def _first_update(
        self, frame: MeasurementSet, model: FrameModel, steps: FloatArray
    ) -> SmootherState:
        candidates = first_frame_candidates(frame)
        track = StraightTrack.of_frame(model)
        starts = hypothesis_starts(candidates, track, track)
        length_scale = model.mean_range_m(candidates[0])
        frames = (model,)
        outcomes = [
            self._checked_update(frames, steps, length_scale, start, start[None, :], None)
            for start in starts
        ]
        state = SmootherState(
            frames=frames,
            track=track,
            length_scale_m=length_scale,
            diagnostics={"first_frame_candidates": len(candidates)},
        )
        return self._with_outcomes(state, outcomes, track)

    def _next_update(
        self, state: SmootherState, frames: tuple[FrameModel, ...], steps: FloatArray
    ) -> SmootherState:
        track = None if state.track is None else state.track.extended(frames[-1])
        outcomes = []
        for hypothesis in state.hypotheses:
            start_values = hypothesis.estimates_m
            if self.random_walk:  # the new variable starts at the last one (as add_frame)
                start_values = np.vstack([start_values, start_values[-1:]])
            outcomes.append(
                self._checked_update(
                    frames,
                    steps,
                    state.length_scale_m,
                    hypothesis.prior_mean_m,
                    start_values,
                    hypothesis,
                )
            )
        if state.track is not None and track is None:
            # the first frame off the line: fork the mirror hypothesis with its own ISAM2
            first = state.hypotheses[0]
            mirror = first.mirrored(state.track)
            distance = np.linalg.norm(mirror.estimates_m[-1] - first.estimates_m[-1])
            if distance > MERGE_RTOL * state.length_scale_m:
                start_values = mirror.estimates_m
                if self.random_walk:
                    start_values = np.vstack([start_values, start_values[-1:]])
                outcomes.append(
                    self._checked_update(
                        frames, steps, state.length_scale_m, mirror.prior_mean_m, start_values, None
                    )
                )
        return self._with_outcomes(replace(state, frames=frames), outcomes, track)

    def _with_outcomes(
        self,
        state: SmootherState,
        outcomes: list[_Outcome],
        track: StraightTrack | None,
    ) -> SmootherState:
        """The state holding the updated hypotheses (merged and pruned once off a straight track)
        and the update's solver figures."""
        updated = [outcome.hypothesis for outcome in outcomes]
        if track is None:
            updated = pruned_hypotheses(updated, state.length_scale_m)
        reasons = [outcome.fallback_reason for outcome in outcomes if outcome.fallback_reason]
        return replace(
            state,
            hypotheses=tuple(updated),
            track=track,
            iterations=max(outcome.steps for outcome in outcomes),
            diagnostics={
                **state.diagnostics,
                "decrement": max(outcome.hypothesis.decrement for outcome in outcomes),
            },
            fallback_reason="; ".join(dict.fromkeys(reasons)),
            fallbacks=state.fallbacks + bool(reasons),
        )

    def _checked_update(
        self,
        frames: tuple[FrameModel, ...],
        steps: FloatArray,
        length_scale_m: float,
        prior_mean_m: FloatArray,
        start_values_m: FloatArray,
        previous: SmootherHypothesis | None,
    ) -> _Outcome:
        """One hypothesis's ISAM2 update (a new ISAM2 when ``previous`` is None, else the
        previous one extended by the last frame), checked; the batch solve if it failed.

        ``start_values_m`` is where the update starts (the previous optimum, the new variable
        at the last one): the cost must not rise from there. See the module text.
        """
        prior_sigma = DIFFUSE_PRIOR_SCALE * length_scale_m
        if previous is None:
            start_chi2 = chain_fit(
                frames,
                start_values_m,
                random_walk=self.random_walk,
                step_sigmas=steps,
                prior_mean_m=prior_mean_m,
                prior_sigma_m=prior_sigma,
            ).chi2
        else:  # the previous optimum's cost, plus the new frame's (the new variable adds no step)
            residual = frames[-1].whitened_error(start_values_m[-1])
            start_chi2 = previous.chi2 + float(residual @ residual)
        problems: list[str] = []
        candidate: SmootherHypothesis | None = None
        n_steps, moving = 0, False
        token = ""
        try:
            if previous is None:
                live, n_steps, moving = new_live(
                    frames,
                    start_values_m,
                    prior_mean_m,
                    steps,
                    length_scale_m,
                    random_walk=self.random_walk,
                    iterate=True,
                )
                recipe: dict[str, Any] = {
                    "start_frames": len(frames),
                    "start_values_m": np.array(start_values_m, dtype=float),
                    "start_iterated": True,
                }
            else:
                live = checkout(previous.token, len(frames) - 1)
                if live is None:
                    live = replay_live(
                        previous, frames[:-1], steps, length_scale_m, random_walk=self.random_walk
                    )
                n_steps, moving = add_frame(
                    live, frames, steps, prior_sigma, random_walk=self.random_walk
                )
                recipe = {
                    "start_frames": previous.start_frames,
                    "start_values_m": previous.start_values_m,
                    "start_iterated": previous.start_iterated,
                }
            token = checkin(live, len(frames))
            candidate = self._read_isam2(
                live, frames, prior_mean_m, prior_sigma, steps, moving=moving, token=token, **recipe
            )
        except (RuntimeError, EstimationFailure) as error:
            discard(token)
            problems.append(f"ISAM2 failed: {error}")
        if candidate is not None:
            if not candidate.chi2 <= start_chi2 + COST_RISE_RTOL * max(start_chi2, 1.0):
                problems.append(f"the cost rose from {start_chi2:.6g} to {candidate.chi2:.6g}")
            tolerance = max(DECREMENT_TOL, COST_ROUNDING_RTOL * candidate.chi2)
            if not candidate.decrement <= tolerance:
                how = (
                    f"still relinearising after {n_steps} steps (the cap)"
                    if moving
                    else f"stopped after {n_steps} steps"
                )
                problems.append(f"{how} with decrement {candidate.decrement:.3g} > {tolerance:g}")
            if candidate.saddle:
                problems.append("it ended at a saddle point of the cost (negative curvature)")
        batch_solve = partial(
            best_lm_solve,
            frames,
            steps,
            prior_mean_m,
            prior_sigma,
            [start_values_m, np.tile(prior_mean_m, (len(start_values_m), 1))],
            random_walk=self.random_walk,
            max_iterations=self.max_iterations,
        )
        batch: SmootherHypothesis | None = None
        if candidate is not None and not problems:
            misfit = _chi2_quantile(sum(frame.n_rows for frame in frames))
            if candidate.chi2 <= misfit:
                return _Outcome(candidate, n_steps)
            # a misfit: is the batch optimum of the same frames much better?
            try:
                batch = batch_solve()
            except EstimationFailure:
                return _Outcome(candidate, n_steps)  # ISAM2 passed its checks; keep it
            far = _chi2_quantile(2 * len(candidate.estimates_m))
            if not candidate.chi2 - batch.chi2 > far:
                return _Outcome(candidate, n_steps)
            problems.append(
                f"its cost {candidate.chi2:.6g} misfits the {len(frames)} frames and is above "
                f"the batch optimum's {batch.chi2:.6g} by more than the "
                f"{1 - CONVERGENCE_ALPHA:g} quantile of χ²({2 * len(candidate.estimates_m)})"
            )
        if candidate is not None:
            discard(candidate.token)
        reason = "; ".join(problems)
        if batch is None:
            try:
                batch = batch_solve()
            except EstimationFailure as error:
                raise EstimationFailure(
                    f"ISAM2 did not converge on frame {len(frames) - 1} ({reason}) and the "
                    f"batch fallback failed too: {error}"
                ) from None
        return _Outcome(self._reseeded(batch, frames, steps, length_scale_m), n_steps, reason)

    def _reseeded(
        self,
        batch: SmootherHypothesis,
        frames: tuple[FrameModel, ...],
        steps: FloatArray,
        length_scale_m: float,
    ) -> SmootherHypothesis:
        """The batch hypothesis with a fresh ISAM2 linearised at its optimum (one bare update,
        no Gauss-Newton step taken), the recipe that rebuilds it, and its cache token."""
        token = ""
        try:
            live, _, _ = new_live(
                frames,
                batch.estimates_m,
                batch.prior_mean_m,
                steps,
                length_scale_m,
                random_walk=self.random_walk,
                iterate=False,
            )
            token = checkin(live, len(frames))
        except RuntimeError:
            pass  # no live ISAM2: the next update replays the recipe (and is checked)
        return replace(
            batch,
            start_frames=len(frames),
            start_values_m=batch.estimates_m,
            start_iterated=False,
            token=token,
        )

    def _read_isam2(
        self,
        live: LiveGraph,
        frames: tuple[FrameModel, ...],
        prior_mean_m: FloatArray,
        prior_sigma: float,
        steps: FloatArray,
        *,
        moving: bool = False,
        **recipe: Any,
    ) -> SmootherHypothesis:
        """The hypothesis at ISAM2's estimate: finished on the expansion unless ISAM2 was still
        relinearising (:meth:`~estimators.sequential.smoother_hypotheses.LiveGraph.solution`), with
        the fit there and the inverse of the last variable's marginal information."""
        estimates, fit = live.solution(prior_mean_m, prior_sigma, steps, polish=not moving)
        try:
            covariance = np.linalg.inv(fit.last_information)
        except np.linalg.LinAlgError:
            covariance = None
        return SmootherHypothesis.from_fit(fit, estimates, covariance, prior_mean_m, **recipe)
