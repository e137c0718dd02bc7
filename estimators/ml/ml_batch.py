r"""``ml`` (MATH §10) for a whole :class:`~scenarios.types.MeasurementBatch`, equal to rounding.

:meth:`MaximumLikelihood.estimate <estimators.ml.ml.MaximumLikelihood.estimate>` one trial at a
time, vectorised over trials and over each trial's starts:

1. the starts: the CLS candidates of every trial (:mod:`estimators.closed_form.cls_batch`), the
   Doppler-only pair of the last frame where ``doppler_start`` applies (the least-squares fit
   of :func:`~estimators.ml.ml_starts.doppler_frame_starts` in closed form) and, on a straight
   track, the folding, merging, ordering and off-plane copies of
   :func:`~estimators.ml.ml.straight_track_starts`; each start is then rounded to the grid of
   :func:`~estimators.ml.ml.on_start_grid`;
2. Levenberg-Marquardt from every start at once (:func:`estimators.ml.minpack_batch.lmder_batch`,
   MINPACK's operations in MINPACK's order), on residuals and Jacobians computed by the
   one-trial path's own functions: from the same start it returns the same iterate, residuals,
   evaluation count and termination code as ``scipy.optimize.least_squares``;
3. the convergence audit (the Gauss-Newton decrement at the end point, well below
   ``DECREMENT_TOL``), the costs (left-to-right sums, as ``estimate`` forms them), the merging of
   coincident minima (the earlier start's point at a cost tie, as
   :func:`~estimators.ml.ml.solve_maximum_likelihood` merges) and of flat ties, the mirror rule and
   the tie-break (:func:`~estimators.batch.finalize_columns`, one ``rng.integers`` per trial
   that draws), the covariance (the inverse Fisher information at the estimate) and the
   diagnostics.

The starts are the only quantities computed differently from the one-trial path (the batch
CLS, the closed-form fit), each with an error bound: a trial whose start's rounding to the
grid, fold, merge or order could fall either way within that bound has its starts found by
``estimate``'s own code (:meth:`~estimators.ml.ml.MaximumLikelihood.search_starts`, one trial at
a time, a sixth of the cost of ``estimate``) and is searched in the batch all the same. The
mirror rule's margins (:func:`~estimators.batch.finalize_columns`) are wide; a trial inside
them gets :func:`~estimators.base.finalize_estimate` itself on its minima. A trial is then
*in doubt* when its search needs a part of MINPACK not reproduced (``odd``), a start did not
converge (an iteration cap, a stall, an error: the one-trial path then writes the solver's
own messages), its decrement is not clearly below the tolerance, a distance or
Fisher-information test lies within rounding of its threshold, or its search would not start
from the CLS (e.g. the LLS-ToA fallback). Trials in doubt are solved one at a time by
``estimate``, in trial order with their own generators (``recomputed``: none to a few in
2,000 trials of the test families); the others perform ``estimate``'s operations in its
order, so they equal it to rounding (position, candidates, covariance) and exactly in message
and diagnostics; bit for bit where the BLAS kernels round alike, not on every CPU
(OpenBLAS's AVX-512 kernels move near-plane covariances of condition ~1e12 by ~5e-4 relative;
tests/paths.py states the tolerance).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate, finalize_estimate, require_batch
from estimators.batch import BatchEstimates, FinalizedColumns, check_rngs, finalize_columns
from estimators.closed_form.cls_batch import SharedGeometry, draw_and_redo
from estimators.ml.minpack_batch import INFO_CODES, lmder_batch, ordered_sum
from estimators.ml.ml_batch_audit import converged_for_certain
from estimators.ml.ml_batch_starts import (
    DISTANCE_RTOL,
    MERGE_RTOL,
    START_GRID,
    batch_starts,
    on_start_grid,
)
from estimators.ml.ml_residuals import ResidualModel
from estimators.ml.ml_starts import ranges_uninformative
from scenarios.fisher import SINGULAR_RTOL, gram_information, inverse_2x2, regular_2x2
from scenarios.types import MeasurementBatch, MeasurementSet

if TYPE_CHECKING:
    from estimators.ml.ml import MaximumLikelihood

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

CHUNK_TRIALS = 1024
"""Trials solved together: large enough that numpy's per-call cost is small, small enough
that an array of residuals of a hundred samples (~1.6 MB) stays near the core's cache (4096
was 1.6× slower on ``paper-1m-turn``)."""

XTOL = 1e-10
"""``xtol``, ``ftol`` and ``gtol`` of :func:`~estimators.ml.ml.solve_maximum_likelihood` as
``estimate`` calls it (and the relative cost tie of its merging of minima)."""

SINGULAR_NOTE = "singular Fisher information at the estimate: no covariance"
KEYS = (
    "n_starts",
    "nfev",
    "max_nfev",
    "start_method",
    "n_samples",
    "lm_status",
    "n_converged",
    "cost",
    "n_minima",
    "straight_track",
)


@dataclass(frozen=True, slots=True, eq=False)
class SharedContext:
    """What every trial of the batch shares, and its measured values (frames used)."""

    estimator: MaximumLikelihood
    batch: MeasurementBatch
    shared: SharedGeometry
    used: MeasurementSet
    model: ResidualModel  # by sample: (K, 1) constants
    doppler: FloatArray  # (n, K)
    toa: FloatArray
    rss: FloatArray | None
    doppler_t: FloatArray  # (K, n): the same, samples first
    toa_t: FloatArray
    rss_t: FloatArray | None
    origin: FloatArray  # LocalFrame origin
    spread_sq: float
    line: tuple[FloatArray, FloatArray] | None
    doppler_start: bool
    use_rss: bool
    max_nfev: int
    cost_rtol: float
    side_prior_m: tuple[float, float] | None

    @classmethod
    def of(cls, estimator: MaximumLikelihood, batch: MeasurementBatch) -> SharedContext:
        shared = SharedGeometry.of(batch, estimator.frames)
        used = shared.used
        position = used.position_m
        origin = position[:, :2].mean(axis=0)
        spread_sq = np.mean(np.sum((position[:, :2] - origin) ** 2, axis=1))
        option = estimator.doppler_start
        doppler = batch.doppler_hz[:, shared.columns]
        toa = batch.toa_s[:, shared.columns]
        rss = batch.rss_dbm[:, shared.columns] if estimator.use_rss else None
        return cls(
            estimator=estimator,
            batch=batch,
            shared=shared,
            used=used,
            model=ResidualModel.of(used).by_sample(),
            doppler=doppler,
            toa=toa,
            rss=rss,
            doppler_t=np.ascontiguousarray(doppler.T),
            toa_t=np.ascontiguousarray(toa.T),
            rss_t=None if rss is None else np.ascontiguousarray(rss.T),
            origin=origin,
            spread_sq=spread_sq,
            line=shared.line,
            doppler_start=option is True or (option == "auto" and ranges_uninformative(used)),
            use_rss=estimator.use_rss,
            max_nfev=estimator.max_nfev,
            cost_rtol=float(estimator.cost_rtol),
            side_prior_m=estimator.side_prior_m,
        )

    def frame_scales(self, trials: IntArray) -> tuple[FloatArray, FloatArray]:
        """The ranges ``(n, K)`` of ``trials`` and the ``scale_m`` of their
        :meth:`LocalFrame.fit <estimators.closed_form.cls_rows.LocalFrame.fit>`, bit for bit: each
        trial's ranges a contiguous row, whose mean numpy sums as it sums the one-trial range vector
        (the mean over a strided axis would add in another order)."""
        ranges = np.ascontiguousarray(self.used.speed_of_light_mps * self.toa[trials])
        scale = np.sqrt(self.spread_sq + np.mean(ranges**2, axis=1))
        return ranges, np.where(scale > 0.0, scale, 1.0)

    def residuals(self, trials: IntArray, world: FloatArray) -> FloatArray:
        """:func:`~estimators.ml.ml.whitened_residuals` of trials ``trials`` at ``world`` (k, 2),
        rows first: ``(m, k)``."""
        rss = None if self.rss_t is None else self.rss_t.take(trials, axis=1)
        doppler, toa = self.doppler_t.take(trials, axis=1), self.toa_t.take(trials, axis=1)
        out = np.empty((self.n_rows, len(trials)))
        self.model.residuals(world[:, 0], world[:, 1], doppler, toa, rss, out=out)
        return out

    def jacobian(self, world: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:func:`~estimators.ml.ml.whitened_residual_jacobian` at ``world`` (k, 2): its two
        columns, each ``(m, k)``."""
        out = (np.empty((self.n_rows, len(world))), np.empty((self.n_rows, len(world))))
        self.model.jacobian(world[:, 0], world[:, 1], self.use_rss, out=out)
        return out

    @property
    def n_rows(self) -> int:
        """Rows of the residual: Doppler and ToA (and RSS) blocks of every sample."""
        return self.doppler_t.shape[0] * (2 + self.use_rss)


def _uses_toa(estimator: MaximumLikelihood, batch: MeasurementBatch) -> bool:
    return estimator.use_toa and batch.toa_s is not None


def estimate_columns(
    estimator: MaximumLikelihood,
    batch: MeasurementBatch,
    rngs: Sequence[np.random.Generator | None] | None,
) -> BatchEstimates:
    """``estimator.estimate`` of every trial of ``batch`` as columns (module text)."""
    require_batch(estimator, batch)
    n = batch.n_trials
    estimator.check_measurements(batch.toa_s is not None, batch.rss_dbm is not None)
    generators = check_rngs(rngs, n)
    out = _Columns(n)
    context = None
    # nuisance parameters or Doppler alone (MATH §15): one trial at a time
    if estimator.method == "lm" and not batch.geometry.unknowns and _uses_toa(estimator, batch):
        try:
            context = SharedContext.of(estimator, batch)
        except ValueError:  # e.g. a hovering sample: the one-trial path says what it does
            context = None
    if context is None:
        out.doubt[:] = True
    else:
        for start in range(0, n, CHUNK_TRIALS):
            trials = np.arange(start, min(start + CHUNK_TRIALS, n))
            _solve_trials(context, trials, out)

    def solve_one(data: MeasurementSet, rng: np.random.Generator | None) -> Estimate:
        return estimator.estimate_without_fit(data, rng=rng)

    redo, recomputed = draw_and_redo(
        estimator.name,
        solve_one,
        batch,
        generators,
        out.doubt,
        out.draw,
        out.n_kept,
        out.chosen,
    )
    return out.columns(estimator, context).with_trials(redo, recomputed)


class _Columns:
    """The per-trial results, filled chunk by chunk."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.doubt = np.zeros(n, dtype=bool)
        self.candidates = np.full((n, 1, 2), np.nan)
        self.n_kept = np.zeros(n, dtype=np.int64)
        self.chosen = np.zeros(n, dtype=np.int64)
        self.draw = np.zeros(n, dtype=bool)
        self.ambiguous = np.zeros(n, dtype=bool)
        self.n_starts = np.zeros(n, dtype=np.int64)
        self.nfev = np.zeros(n, dtype=np.int64)
        self.info = np.zeros((n, 1), dtype=np.int64)
        self.cost = np.full(n, np.nan)
        self.n_minima = np.zeros(n, dtype=np.int64)
        self.information = np.full((n, 1, 2, 2), np.nan)  # at each candidate

    def widen(self, name: str, width: int, fill: Any) -> None:
        value = getattr(self, name)
        if value.shape[1] < width:
            wider = np.full((self.n, width, *value.shape[2:]), fill, dtype=value.dtype)
            wider[:, : value.shape[1]] = value
            setattr(self, name, wider)

    def columns(
        self, estimator: MaximumLikelihood, context: SharedContext | None
    ) -> BatchEstimates:
        """The columns, once the draws are made (``chosen``)."""
        n, ok = self.n, ~self.doubt
        rows = np.arange(n)
        chosen = np.minimum(self.chosen, self.candidates.shape[1] - 1)
        position = np.where(ok[:, None], self.candidates[rows, chosen], np.nan)
        information = self.information[rows, chosen]
        singular = ~regular_2x2(information)
        covariance = inverse_2x2(information)
        # one status list per distinct pattern of codes (a few for many trials), shared by its
        # trials; BatchEstimates.estimate hands each trial a copy
        width = self.info.shape[1]
        pattern = np.where(np.arange(width)[None, :] < self.n_starts[:, None], self.info, -1)
        keys, which = np.unique(pattern[ok], axis=0, return_inverse=True)
        templates = np.empty(len(keys), dtype=object)
        for j, key in enumerate(keys.tolist()):
            templates[j] = [f"converged ({INFO_CODES[c]})" for c in key if c >= 0]
        statuses = np.empty(n, dtype=object)
        statuses[ok] = templates[which.ravel()]
        n_samples = 0 if context is None else context.used.n_samples
        straight = context is not None and context.line is not None
        diagnostics = {
            "n_starts": self.n_starts,
            "nfev": self.nfev,
            "max_nfev": np.full(n, estimator.max_nfev, dtype=np.int64),
            "start_method": np.full(n, "cls", dtype=object),
            "n_samples": np.full(n, n_samples, dtype=np.int64),
            "lm_status": statuses,
            "n_converged": self.n_starts.copy(),
            "cost": self.cost,
            "n_minima": self.n_minima,
            "straight_track": np.full(n, straight),
        }
        return BatchEstimates(
            estimator=estimator.name,
            position_m=np.where(ok[:, None], position, np.nan),
            candidates_m=self.candidates,
            n_candidates=np.where(ok, self.n_kept, 0),
            ambiguous=self.ambiguous & ok,
            success=ok.copy(),
            message_code=np.where(ok & singular, 1, 0).astype(np.int64),
            messages=("", SINGULAR_NOTE),
            diagnostics={key: diagnostics[key] for key in KEYS},
            covariance_m2=np.where(ok[:, None, None], covariance, np.nan),
        )


# --------------------------------------------------------------------------------------------
# one chunk of trials
# --------------------------------------------------------------------------------------------


def _solve_trials(context: SharedContext, trials: IntArray, out: _Columns) -> None:
    """Everything of ``estimate`` for ``trials`` but the draws and the covariance."""
    n = len(trials)
    ranges, scale = context.frame_scales(trials)
    with np.errstate(all="ignore"):
        starts, count, error, doubt = batch_starts(context, trials, ranges, scale)
        local = (starts - context.origin) / scale[:, None, None]
        gridded = on_start_grid(local)
        slack = error / scale[:, None] + 4.0 * np.finfo(float).eps * (1.0 + np.abs(local).max(-1))
        distance = np.abs(local / START_GRID - gridded / START_GRID).max(-1)
        valid = np.arange(starts.shape[1])[None, :] < count[:, None]
        near_edge = distance >= 0.5 - slack / START_GRID
        doubt |= np.any(valid & (near_edge | ~np.isfinite(gridded).all(-1)), axis=1)
    if doubt.any():
        gridded, count, doubt = _one_trial_starts(context, trials, scale, gridded, count, doubt)
        valid = np.arange(gridded.shape[1])[None, :] < count[:, None]
    problem_trial, problem_slot = np.nonzero(valid & ~doubt[:, None])
    result = _search(
        context,
        trials[problem_trial],
        gridded[problem_trial, problem_slot],
        scale[problem_trial],
    )
    points, costs, info, nfev, fine, ends = result
    width = gridded.shape[1]
    point_of = np.full((n, width, 2), np.nan)
    problem_of = np.full((n, width), -1)
    problem_of[problem_trial, problem_slot] = np.arange(len(problem_trial))
    cost_of = np.full((n, width), np.inf)
    info_of = np.zeros((n, width), dtype=np.int64)
    nfev_of = np.zeros((n, width), dtype=np.int64)
    point_of[problem_trial, problem_slot] = points
    cost_of[problem_trial, problem_slot] = costs
    info_of[problem_trial, problem_slot] = info
    nfev_of[problem_trial, problem_slot] = nfev
    np.logical_or.at(doubt, problem_trial, ~fine)
    doubt |= count == 0
    minima, minimum_costs, n_minima, merge_doubt = _minima(
        context, trials, point_of, cost_of, count, scale
    )
    doubt |= merge_doubt
    final = _finalize(context, minima, minimum_costs, np.where(doubt, 0, n_minima))
    doubt |= final.uncertain
    information, unsure = _information(
        context, final.candidates, final.n_candidates, ~doubt, (point_of, problem_of, ends)
    )
    doubt |= unsure
    out.widen("candidates", final.candidates.shape[1], np.nan)
    out.widen("information", final.candidates.shape[1], np.nan)
    out.widen("info", width, 0)
    out.candidates[trials] = np.nan
    out.candidates[trials, : final.candidates.shape[1]] = final.candidates
    out.information[trials] = np.nan
    out.information[trials, : final.candidates.shape[1]] = information
    out.n_kept[trials] = final.n_candidates
    out.chosen[trials] = final.chosen
    out.draw[trials] = final.draw
    out.ambiguous[trials] = final.ambiguous
    out.doubt[trials] = doubt
    out.n_starts[trials] = count
    out.nfev[trials] = nfev_of.sum(axis=1)
    out.info[trials, :width] = info_of
    out.cost[trials] = minimum_costs[:, 0]
    out.n_minima[trials] = n_minima


def _one_trial_starts(
    context: SharedContext,
    trials: IntArray,
    scale: FloatArray,
    gridded: FloatArray,
    count: IntArray,
    doubt: BoolArray,
) -> tuple[FloatArray, IntArray, BoolArray]:
    """The gridded starts of the trials in ``doubt`` from ``estimate``'s own code
    (:meth:`~estimators.ml.ml.MaximumLikelihood.search_starts`): the same numbers, so only these
    trials' starts are found one at a time and their search stays in the batch. A trial stays
    in doubt when its search would not start from the CLS alone, or its local frame is not
    the batch's (``scale``, ``context.origin``) to the bit."""
    found: dict[int, FloatArray] = {}
    for i in np.flatnonzero(doubt).tolist():
        used = context.batch.trial(int(trials[i])).select_frames(context.estimator.frames)
        try:
            starts, method, note, frame = context.estimator.search_starts(used)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if starts is None or method != "cls" or note or frame.scale_m != scale[i]:
            continue
        local = on_start_grid(frame.to_local(starts))
        if np.array_equal(frame.origin_m, context.origin) and np.isfinite(local).all():
            found[i] = local
    width = max([gridded.shape[1], *(len(local) for local in found.values())])
    if width > gridded.shape[1]:
        wider = np.full((len(gridded), width, 2), np.nan)
        wider[:, : gridded.shape[1]] = gridded
        gridded = wider
    count, doubt = count.copy(), doubt.copy()
    for i, local in found.items():
        gridded[i] = np.nan
        gridded[i, : len(local)] = local
        count[i] = len(local)
        doubt[i] = False
    return gridded, count, doubt


def _finalize(
    context: SharedContext, minima: FloatArray, costs: FloatArray, count: IntArray
) -> FinalizedColumns:
    """:func:`~estimators.batch.finalize_columns` of the minima; the trials where a comparison
    of it is too close to call with its margins (a mirror pair near the merge threshold, two
    near-equal distances to the prior) get :func:`~estimators.base.finalize_estimate` itself,
    the one-trial path's code on the same minima and costs, without drawing."""
    k = max(int(count.max(initial=1)), 1)
    with np.errstate(all="ignore"):
        final = finalize_columns(
            np.ascontiguousarray(minima[:, :k]),
            count,
            np.where(np.isfinite(costs[:, :k]), costs[:, :k], np.inf),
            context.shared.mean_xy,
            context.line,
            side_prior_m=context.side_prior_m,
            cost_rtol=context.cost_rtol,
        )
    again = np.flatnonzero(final.uncertain & (count > 0))
    if again.size == 0:
        return final
    candidates = final.candidates.copy()
    n_kept, chosen = final.n_candidates.copy(), final.chosen.copy()
    draw, uncertain = final.draw.copy(), final.uncertain.copy()
    for i in again.tolist():
        points, values = minima[i, : count[i]], costs[i, : count[i]]
        if not (np.all(np.isfinite(points)) and np.all(np.isfinite(values))):
            continue
        estimate = finalize_estimate(
            context.estimator.name,
            points,
            values,
            context.used,
            side_prior_m=context.side_prior_m,
            cost_rtol=context.cost_rtol,
        )
        kept = estimate.candidates_m
        if not estimate.success or len(kept) > candidates.shape[1]:
            continue
        candidates[i] = np.nan
        candidates[i, : len(kept)] = kept
        n_kept[i] = len(kept)
        chosen[i] = int(np.flatnonzero((kept == estimate.position_m).all(axis=1))[0])
        draw[i] = len(kept) > 1 and context.side_prior_m is None
        uncertain[i] = False
    return replace(
        final,
        candidates=candidates,
        n_candidates=n_kept,
        chosen=chosen,
        draw=draw,
        ambiguous=(n_kept > 1) | (context.line is not None),
        uncertain=uncertain,
    )


def _information(
    context: SharedContext,
    candidates: FloatArray,
    count: IntArray,
    wanted: BoolArray,
    ends: tuple[FloatArray, IntArray, tuple[FloatArray, FloatArray]],
) -> tuple[FloatArray, BoolArray]:
    """The Fisher information (MATH §8) at each kept candidate of the ``wanted`` trials (the
    Gram matrix of the residuals' Jacobian, as :func:`~estimators.ml.ml.fisher_covariance_m2`
    forms it), and the trials where its regularity test (:func:`scenarios.fisher.regular_2x2`)
    is within rounding of its threshold at any candidate (whichever the draw picks). ``ends``
    holds the searches' end points by trial and slot, their problem numbers and the Jacobian
    columns there."""
    n, width, _ = candidates.shape
    information = np.full((n, width, 2, 2), np.nan)
    slots = (np.arange(width)[None, :] < count[:, None]) & wanted[:, None]
    # a candidate that is a search's end point (all but mirror images) has its Jacobian from
    # the convergence audit: the same point, so the same bits
    point_of, problem_of, (end_x, end_y) = ends
    same = np.all(candidates[:, :, None, :] == point_of[:, None, :, :], axis=-1)
    problem = np.where(same.any(-1), np.take_along_axis(problem_of, same.argmax(-1), 1), -1)
    known = slots & (problem >= 0)
    columns = problem[known]
    jx, jy = end_x.take(columns, axis=1), end_y.take(columns, axis=1)
    information[known] = gram_information(np.stack([jx, jy], axis=-1), row_axis=0)
    new = slots & ~known
    if new.any():
        jx, jy = context.jacobian(candidates[new])
        information[new] = gram_information(np.stack([jx, jy], axis=-1), row_axis=0)
    a, b, d = information[..., 0, 0], information[..., 0, 1], information[..., 1, 1]
    with np.errstate(all="ignore"):
        det = a * d - b * b
        reference = np.maximum(np.abs(a * d), np.finfo(float).tiny)
        near = np.abs(det - SINGULAR_RTOL * reference) <= 64.0 * np.finfo(float).eps * reference
    return information, np.any(slots & (near | ~np.isfinite(det)), axis=1)


def _search(
    context: SharedContext, trial: IntArray, start: FloatArray, scale: FloatArray
) -> tuple[FloatArray, FloatArray, IntArray, IntArray, BoolArray, tuple[FloatArray, FloatArray]]:
    """Levenberg-Marquardt from each start (local units) of ``trial`` with its frame's
    ``scale``: world points, costs, MINPACK's info, evaluations, whether the start converged
    for certain, and the residuals' Jacobian at the points (columns ``(m, P)``)."""
    if len(trial) == 0:
        empty = np.empty(0)
        none = np.empty((context.n_rows, 0))
        integers = empty.astype(np.int64)
        return np.empty((0, 2)), empty, integers, integers, empty > 0, (none, none)
    origin = context.origin
    problem_scale = scale

    def residuals(index: IntArray, local: FloatArray) -> FloatArray:
        world = local * problem_scale[index, None] + origin
        return context.residuals(trial[index], world)

    def jacobian(index: IntArray, local: FloatArray) -> tuple[FloatArray, FloatArray]:
        world = local * problem_scale[index, None] + origin
        jx, jy = context.jacobian(world)
        return jx * problem_scale[index], jy * problem_scale[index]

    result = lmder_batch(
        residuals, jacobian, start, ftol=XTOL, xtol=XTOL, gtol=XTOL, max_nfev=context.max_nfev
    )
    world = result.x * problem_scale[:, None] + origin
    with np.errstate(all="ignore"):
        costs = ordered_sum(result.fvec**2)
        finite = np.all(np.isfinite(world), axis=1) & np.isfinite(costs)
        fine = ~result.odd & (result.info >= 1) & (result.info <= 4) & finite
        at_end = context.jacobian(world)
        converged = converged_for_certain(context, trial, world, scale, at_end, result.fvec, fine)
    return world, costs, result.info, result.nfev, fine & converged, at_end


# --------------------------------------------------------------------------------------------
# the minima: coincident ones merged, flat ties merged (ml._distinct_minima, _merge_flat_ties)
# --------------------------------------------------------------------------------------------


def _minima(
    context: SharedContext,
    trials: IntArray,
    points: FloatArray,
    costs: FloatArray,
    count: IntArray,
    scale: FloatArray,
) -> tuple[FloatArray, FloatArray, IntArray, BoolArray]:
    """Each trial's distinct minima, best first: ``(points, costs, count, doubt)``."""
    n, width = costs.shape
    valid = np.arange(width)[None, :] < count[:, None]
    order = np.argsort(np.where(valid, costs, np.inf), axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    costs = np.take_along_axis(costs, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    threshold = MERGE_RTOL * scale
    doubt = np.zeros(n, dtype=bool)
    kept: list[BoolArray] = []
    start = order.copy()  # the start each kept slot now holds (its original slot)
    for i in range(width):
        merged = np.zeros(n, dtype=bool)
        for j in range(i):
            compared = valid[:, i] & kept[j] & ~merged
            dx, dy = points[:, i, 0] - points[:, j, 0], points[:, i, 1] - points[:, j, 1]
            distance = np.sqrt(dx * dx + dy * dy)
            doubt |= compared & (np.abs(distance - threshold) <= DISTANCE_RTOL * threshold)
            close = compared & (distance <= threshold)
            # the first close one takes this point's place if it is an earlier start at a tie
            tie = costs[:, i] <= costs[:, j] + XTOL * np.abs(costs[:, j])
            take = np.flatnonzero(close & (start[:, i] < start[:, j]) & tie)
            points[take, j], costs[take, j], start[take, j] = (
                points[take, i],
                costs[take, i],
                start[take, i],
            )
            merged |= close
        kept.append(valid[:, i] & ~merged)
    points, costs, valid = _compact(points, costs, np.column_stack(kept))
    order = np.argsort(costs, axis=1, kind="stable")  # the kept points, back in cost order
    points = np.take_along_axis(points, order[..., None], axis=1)
    costs = np.take_along_axis(costs, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    if valid[:, 1:].any():
        best = costs[:, 0]
        tie = best + context.cost_rtol * np.abs(best)
        tie = tie + np.finfo(float).eps * 64 * np.maximum(np.abs(best), 1.0)
        kept = [valid[:, 0]]
        for i in range(1, valid.shape[1]):
            candidate = valid[:, i] & (costs[:, i] <= tie)
            flat = np.zeros(n, dtype=bool)
            for j in range(i):
                rows = np.flatnonzero(candidate & kept[j] & ~flat)
                if rows.size:
                    middle = 0.5 * (points[rows, i] + points[rows, j])
                    rows_cost = ordered_sum(context.residuals(trials[rows], middle) ** 2)
                    flat[rows] = rows_cost <= tie[rows]
            kept.append(valid[:, i] & ~flat)
        points, costs, valid = _compact(points, costs, np.column_stack(kept))
    return points, costs, valid.sum(axis=1), doubt


def _compact(
    points: FloatArray, costs: FloatArray, keep: BoolArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The kept slots of each row moved to its front, in order (the others NaN / inf)."""
    order = np.argsort(~keep, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    costs = np.take_along_axis(costs, order, axis=1)
    keep = np.take_along_axis(keep, order, axis=1)
    points = np.where(keep[..., None], points, np.nan)
    return points, np.where(keep, costs, np.inf), keep
