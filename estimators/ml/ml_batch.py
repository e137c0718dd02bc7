r"""``ml`` (MATH §10, with unknowns §15) for a whole :class:`~scenarios.types.MeasurementBatch`:
the one implementation (one trial is a batch of one).

With independent Gaussian noise (MATH §1) the negative log-likelihood of the raw measurements
is, up to a constant, half the squared norm of the whitened residuals

.. math::

    e(s) = \Big[\frac{f_k - f_k(s)}{\sigma_f},\ \frac{\tau_k - \tau_k(s)}{\sigma_\tau},\
    \Big(\frac{P_k - P_k(s)}{\sigma_P}\Big)\Big]_k,\qquad
    \hat s = \arg\min_{(x_s, y_s)} \lVert e(s)\rVert^2

(Doppler with the physical sign, the RSS block optional; a nuisance parameter unknown is
profiled out, :mod:`estimators.ml.ml_residuals`); with the emitter's height unknown the
minimum is over ``(x_s, y_s, z_s)`` (MATH §8, §10), by the same steps in three coordinates.
Vectorised over trials and over each trial's starts:

1. the starts (:mod:`estimators.ml.ml_batch_starts`): every closed-form candidate, folded to
   one side of a straight track, rounded to a grid in the centred, scaled local frame of the
   CLS (the height unknown: those of a few assumed heights,
   :func:`~estimators.ml.ml_batch_starts.start_heights`; a straight track then fails every
   trial before any search, :data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`);
2. Levenberg-Marquardt from every start at once (:func:`estimators.ml.minpack_batch.lmder_batch`,
   MINPACK's ``lmder`` with ``xtol = ftol = gtol = XTOL``, at most ``max_nfev`` evaluations);
3. the convergence audit (:mod:`estimators.ml.ml_batch_audit`): a start converged when a
   tolerance was met *and* its decrement is at most ``DECREMENT_TOL`` (within 0.01 σ of a
   minimum). How each start ended is ``diagnostics["lm_status"]``: ``converged (xtol)`` (or
   ``gtol``, ``ftol``, ``ftol+xtol``), ``iteration cap (max_nfev=200)``, ``stalled (xtol,
   decrement 0.03 > 0.0001)`` (a tolerance met away from a stationary point: the trust region
   collapsed), ``error (...)`` or ``non-finite start``. Only converged starts give minima; the
   estimate fails when no start converged, or when a start that did not converge ended below
   every converged minimum (the optimum found is then not the best the data allow); starts
   that did not converge but ended higher are counted and noted in the message;
4. the minima (:func:`distinct_minima`): two end points closer than ``COINCIDENT_RTOL`` of the
   scale are one minimum (at costs tied within ``XTOL`` the earlier start's point is kept: an
   on-plane start stays on a straight track's plane, its off-plane copy stops a fraction of a
   micrometre off it); on a straight track so is an end point that close to the mirror image
   of a cheaper one (a start that crossed the track reached the same minimum's image: the
   mirror rule adds that image, at a distance the search's tolerance sets, not rounding; at
   costs tied within ``XTOL`` the image on the left of the track is kept), and
   minima within ``cost_rtol`` of the best joined to a better one by a flat valley (no barrier
   at the midpoint) are one; every minimum within ``cost_rtol`` of the best is a candidate (on
   one straight frame the mirror pair has exactly equal cost, MATH §7); on a flight in one
   plane with the height unknown the rule adds each minimum's reflection through it at its cost
   (``plane``: the likelihood is symmetric about the plane, MATH §7), unless
   the data carry a terrain: its prior (the last row of the residual,
   :mod:`estimators.ml.ml_residuals`) breaks that symmetry, the reflections are no minima of
   the posterior, and the starts below the UAV find its minima;
5. the mirror rule and tie-break (:func:`~estimators.mirror_rule.finalize_columns`, which
   also drops a 3-D candidate above the UAV; one
   ``rng.integers`` per trial that draws, in trial order), the covariance, the inverse Fisher
   information ``(JᵀJ)⁻¹`` at the estimate (MATH §8: the CRLB at ``ŝ``), and the diagnostics.

``scipy.optimize.least_squares`` (the same MINPACK method) is the tests' cross-check, at a
tolerance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import (
    Estimate,
    baseline_problem,
    cost_tie_level,
    require_batch,
)
from estimators.batch import BatchEstimates, check_rngs
from estimators.closed_form.cls_batch import SharedGeometry
from estimators.convergence import DECREMENT_TOL
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT, finalize_columns
from estimators.ml.minpack_batch import INFO_CODES, TERMINATION_MESSAGES, column_dot, lmder_batch
from estimators.ml.ml_batch_audit import decrements
from estimators.ml.ml_batch_starts import (
    COINCIDENT_RTOL,
    at_height,
    find_starts,
    on_start_grid,
    start_heights,
)
from estimators.ml.ml_residuals import ResidualModel, profiled_offsets
from estimators.ml.ml_starts import ranges_uninformative
from scenarios.fisher import inverse_symmetric
from scenarios.geometry import (
    cross_track_m,
    flight_plane,
    mirror_across_line,
    straight_track_line,
)
from scenarios.nuisance import position_dimension
from scenarios.types import MeasurementBatch, MeasurementSet

if TYPE_CHECKING:
    from estimators.ml.ml import MaximumLikelihood

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
ObjectArray = NDArray[np.object_]

CHUNK_TRIALS = 1024
"""Trials solved together: large enough that numpy's per-call cost is small, small enough
that an array of residuals of a hundred samples (~1.6 MB) stays near the core's cache (4096
was 1.6× slower on ``paper-1m-turn``)."""

XTOL = 1e-10
"""``xtol``, ``ftol`` and ``gtol`` of the Levenberg-Marquardt search (and the relative cost
tie of the merging of coincident minima)."""

CLS_BATCH_MIN_TRIALS = 8
"""From this many trials the CLS starts are solved for the chunk at once
(:func:`~estimators.closed_form.cls_batch.solve_chunk`); fewer trials take the closed form's
one-trial solve (:func:`~estimators.ml.ml_batch_starts.closed_form_starts`), which costs less
than the batch's set-up (the two agree to ~1e-13 of the scale, far inside the start grid)."""

SINGULAR_NOTE = "singular Fisher information at the estimate: no covariance"
SEARCH_KEYS = ("n_starts", "nfev", "max_nfev", "start_method", "n_samples", "lm_status")


@dataclass(frozen=True, slots=True, eq=False)
class SharedContext:
    """What every trial of the batch shares, and its measured values (frames used)."""

    estimator: MaximumLikelihood
    batch: MeasurementBatch
    used: MeasurementSet  # the geometry of the samples used
    columns: IntArray  # their columns in the batch
    cls_geometry: SharedGeometry | None  # the batch CLS's, where it gives the starts
    model: ResidualModel  # by sample: (K, 1) constants
    doppler: FloatArray  # (n, K)
    toa: FloatArray | None
    doppler_t: FloatArray  # (K, n): the same, samples first
    toa_t: FloatArray | None
    rss_t: FloatArray | None
    origin: FloatArray  # the local frame's origin
    spread_sq: float
    line: tuple[FloatArray, FloatArray] | None
    uses_toa: bool
    doppler_start: bool
    dimension: int  # 3: the height a coordinate of the emitter (MATH §8)
    heights: tuple[tuple[float, SharedContext], ...]  # the starts' heights (dimension 3)
    degenerate: str | None  # why the geometry cannot fix the emitter (dimension 3)
    plane: tuple[FloatArray, FloatArray] | None  # the flight's plane, if one (dimension 3)

    @classmethod
    def of(
        cls, estimator: MaximumLikelihood, batch: MeasurementBatch, dimension: int | None = None
    ) -> SharedContext:
        """The context of ``batch``; ``dimension`` 2 on data whose height is unknown: the
        search at the data's height (the starts at a height, :func:`start_heights`)."""
        geometry = batch.geometry
        if dimension is None:
            dimension = position_dimension(geometry.unknowns)
        used = geometry.select_frames(estimator.frames)
        if estimator.frames == "last":
            columns = np.flatnonzero(geometry.frame == geometry.frame[-1])
        else:
            columns = np.arange(geometry.n_samples)
        uses_toa = estimator.use_toa and batch.toa_s is not None
        cls_geometry = None
        # the batch CLS gives every trial's starts, an unknown carrier offset projected out in
        # its rows; with an unknown emission time the pseudo-range form does (pseudo_ranges)
        batch_cls = uses_toa and "emission_time_s" not in geometry.unknowns
        if batch_cls and dimension == 2 and batch.n_trials >= CLS_BATCH_MIN_TRIALS:
            try:
                cls_geometry = SharedGeometry.of(batch, estimator.frames)
            except ValueError:  # e.g. a hovering sample: the one-trial closed form says why
                cls_geometry = None
        position = used.position_m
        origin = position[:, :2].mean(axis=0)
        spread_sq = float(np.mean(np.sum((position[:, :2] - origin) ** 2, axis=1)))
        degenerate, plane, heights = None, None, ()
        if dimension == 3:
            origin = np.append(origin, position[:, 2].mean())
            if straight_track_line(position, used.velocity_mps) is not None:
                degenerate = STRAIGHT_TRACK_HEIGHT  # a circle of equal cost (MATH §7)
            elif used.terrain is None:  # a terrain prior breaks the symmetry (module text)
                plane = flight_plane(position, used.velocity_mps)
            if degenerate is None:
                heights = tuple(
                    (z, cls.of(estimator, at_height(batch, z), dimension=2))
                    for z in start_heights(used)
                )
        doppler = batch.doppler_hz[:, columns]
        toa = batch.toa_s[:, columns] if uses_toa else None
        rss = batch.rss_dbm[:, columns] if estimator.use_rss else None
        option = estimator.doppler_start
        model = ResidualModel.of(used)
        model = dataclasses.replace(model, toa=uses_toa, dimension=dimension).by_sample()
        return cls(
            estimator=estimator,
            batch=batch,
            used=used,
            columns=columns,
            cls_geometry=cls_geometry,
            model=model,
            doppler=doppler,
            toa=toa,
            doppler_t=np.ascontiguousarray(doppler.T),
            toa_t=None if toa is None else np.ascontiguousarray(toa.T),
            rss_t=None if rss is None else np.ascontiguousarray(rss.T),
            origin=origin,
            spread_sq=spread_sq,
            line=straight_track_line(position, used.velocity_mps),
            uses_toa=uses_toa,
            doppler_start=uses_toa
            and dimension == 2
            and (option is True or (option == "auto" and ranges_uninformative(used))),
            dimension=dimension,
            heights=heights,
            degenerate=degenerate,
            plane=plane,
        )

    def trial_data(self, trial: int) -> MeasurementSet:
        """Trial ``trial``'s samples used, as the estimator sees them."""
        data = self.batch.trial(trial)
        if not self.uses_toa and data.toa_s is not None:
            data = data.without("toa")
        return data.select_frames(self.estimator.frames)

    def frame_scales(self, trials: IntArray) -> FloatArray:
        """The length scale of each trial's local frame (:meth:`LocalFrame.fit
        <estimators.closed_form.cls_rows.LocalFrame.fit>`): the RMS of the samples' spread and
        of the ranges (from Doppler alone, the UAV's height above the emitter)."""
        if self.toa is not None:
            ranges = self.used.speed_of_light_mps * self.toa[trials]
            mean_sq = np.mean(ranges**2, axis=1)
        else:
            height = self.used.position_m[:, 2] - self.used.emitter_height_m
            mean_sq = np.full(len(trials), np.mean(height**2))
        scale = np.sqrt(self.spread_sq + mean_sq)
        return np.where(scale > 0.0, scale, 1.0)

    def residuals(self, trials: IntArray, world: FloatArray) -> FloatArray:
        """The whitened residuals of trials ``trials`` at ``world`` (k, d), rows first:
        ``(m, k)``."""
        rss = None if self.rss_t is None else self.rss_t.take(trials, axis=1)
        toa = None if self.toa_t is None else self.toa_t.take(trials, axis=1)
        out = np.empty((self.n_rows, len(trials)))
        doppler = self.doppler_t.take(trials, axis=1)
        self.model.residuals(list(world.T), doppler, toa, rss, out=out)
        return out

    def jacobian(self, world: FloatArray) -> tuple[FloatArray, ...]:
        """The whitened residuals' Jacobian at ``world`` (k, d): its d columns, each
        ``(m, k)``."""
        out = tuple(np.empty((self.n_rows, len(world))) for _ in range(self.dimension))
        self.model.jacobian(list(world.T), self.rss_t is not None, out=out)
        return out

    @property
    def pseudo_ranges(self) -> bool:
        """Whether the ranges are pseudo-ranges (the emission time unknown, MATH §15) that the
        starts use."""
        return self.uses_toa and "emission_time_s" in self.used.unknowns

    @property
    def n_rows(self) -> int:
        """Rows of the residual: Doppler (and ToA, and RSS) blocks of every sample, and the
        terrain prior's row (:mod:`estimators.ml.ml_residuals`)."""
        blocks = 1 + self.uses_toa + (self.rss_t is not None)
        return self.doppler_t.shape[0] * blocks + self.model.prior


def solve_batch(
    estimator: MaximumLikelihood,
    batch: MeasurementBatch,
    rngs: Sequence[np.random.Generator | None] | None,
    *,
    checked: bool = False,
) -> tuple[BatchEstimates, dict[int, Estimate]]:
    """Every trial of ``batch`` (module text): the columns, and the failed trials as estimates
    with their diagnostics (which columns do not hold). ``checked``: the caller has checked
    the data against the estimator's modalities and options already."""
    if not checked:
        require_batch(estimator, batch)
        estimator.check_measurements(batch.toa_s is not None, batch.rss_dbm is not None)
    generators = check_rngs(rngs, batch.n_trials)
    context = SharedContext.of(estimator, batch)
    if context.degenerate:  # no search can locate the emitter: every trial fails alike
        columns = BatchEstimates.failed(
            batch.n_trials,
            context.degenerate,
            estimator=estimator.name,
            covariance=True,
            dimension=context.dimension,
        )
        return columns, {}
    chunks = [
        _solve_trials(context, np.arange(start, min(start + CHUNK_TRIALS, batch.n_trials)))
        for start in range(0, batch.n_trials, CHUNK_TRIALS)
    ]
    return _assemble(context, chunks, generators)


# --------------------------------------------------------------------------------------------
# one chunk of trials
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class _Chunk:
    """What a chunk's trials found, before the draws."""

    candidates: FloatArray  # (n, k, d)
    n_kept: IntArray
    chosen: IntArray
    draw: BoolArray
    ambiguous: BoolArray
    covariance: FloatArray  # (n, k, d, d): at each candidate, NaN where singular
    diagnostics: dict[str, NDArray[Any]]
    message: ObjectArray
    failed: dict[int, Estimate]  # by index in the chunk


def _solve_trials(context: SharedContext, trials: IntArray) -> _Chunk:
    """Everything of the module text for ``trials`` but the draws."""
    estimator = context.estimator
    n = len(trials)
    scale = context.frame_scales(trials)
    with np.errstate(all="ignore"):
        starts, count, method, note = find_starts(context, trials, scale)
        gridded = on_start_grid((starts - context.origin) / scale[:, None, None])
    width = gridded.shape[1]
    valid = np.arange(width)[None, :] < count[:, None]
    finite = valid & np.isfinite(gridded).all(axis=-1)
    problem_trial, problem_slot = np.nonzero(finite)
    points, costs, info, nfev, decrement = _search(
        context, trials[problem_trial], gridded[problem_trial, problem_slot], scale[problem_trial]
    )
    point_of = np.full((n, width, context.dimension), np.nan)
    cost_of = np.full((n, width), np.inf)
    info_of = np.zeros((n, width), dtype=np.int64)
    nfev_of = np.zeros((n, width), dtype=np.int64)
    decrement_of = np.full((n, width), np.inf)
    point_of[problem_trial, problem_slot] = points
    cost_of[problem_trial, problem_slot] = costs
    info_of[problem_trial, problem_slot] = info
    nfev_of[problem_trial, problem_slot] = nfev
    decrement_of[problem_trial, problem_slot] = decrement
    tolerance_met = (info_of >= 1) & (info_of != 5) & np.isfinite(cost_of)
    converged = finite & tolerance_met & (decrement_of <= DECREMENT_TOL)
    statuses, reasons = _statuses(context, valid, finite, info_of, decrement_of, converged)
    minima, minimum_costs, n_minima = distinct_minima(
        context, trials, np.where(converged[..., None], point_of, np.nan), cost_of, converged, scale
    )
    unconverged_best = np.min(np.where(valid & ~converged, cost_of, np.inf), axis=1)
    best = minimum_costs[:, 0]
    n_converged = converged.sum(axis=1)
    with np.errstate(invalid="ignore"):  # no minimum: best is inf
        below = unconverged_best < best - estimator.cost_rtol * np.abs(best)
    ok = (count > 0) & (n_minima > 0) & ~below
    k = max(int(n_minima.max(initial=1)), 1)
    with np.errstate(all="ignore"):
        final = finalize_columns(
            np.ascontiguousarray(minima[:, :k]),
            np.where(ok, n_minima, 0),
            np.where(np.isfinite(minimum_costs[:, :k]), minimum_costs[:, :k], np.inf),
            context.used.position_m[:, :2].mean(axis=0),
            context.line,
            side_prior_m=estimator.side_prior_m,
            cost_rtol=estimator.cost_rtol,
            ceiling_m=float(context.used.position_m[:, 2].max()),
            plane=context.plane,  # a flight in one plane: the reflections at equal costs
        )
    candidates, n_kept, chosen = final.candidates, final.n_candidates, final.chosen
    draw, ambiguous = final.draw, final.ambiguous
    ok &= ~final.invalid
    message = note.copy()
    dropped = ok & (n_converged < count)
    for i in np.flatnonzero(dropped).tolist():
        text = (
            f"{count[i] - n_converged[i]} of {count[i]} starts did not converge and were "
            f"dropped ({reasons[i]})"
        )
        message[i] = f"{message[i]}; {text}" if message[i] else text
    search = {
        "n_starts": count,
        "nfev": nfev_of.sum(axis=1),
        "max_nfev": np.full(n, estimator.max_nfev, dtype=np.int64),
        "start_method": method,
        "n_samples": np.full(n, context.used.n_samples, dtype=np.int64),
        "lm_status": statuses,
        "n_converged": n_converged,
    }
    diagnostics = {**search, "cost": best, "n_minima": n_minima}
    if context.used.unknowns:
        offsets = [
            profiled_offsets(context.trial_data(int(trials[i])), minima[i, 0]) if ok[i] else {}
            for i in range(n)
        ]
        for key in next((o for o in offsets if o), {}):
            diagnostics[key] = np.array([o.get(key, np.nan) for o in offsets])
    diagnostics["straight_track"] = np.full(n, context.line is not None)
    covariance = _covariances(context, candidates, n_kept, ok)
    failed = {}
    for i in np.flatnonzero(~ok).tolist():
        if count[i] == 0:
            failed[i] = Estimate.failed(
                estimator.name, f"no starting point: {note[i]}", dimension=context.dimension
            )
            continue
        text = f"least squares did not converge from any start: {reasons[i] or 'no start'}"
        if n_minima[i] and below[i]:
            text = (
                f"a start that did not converge ended below every converged minimum "
                f"(cost {unconverged_best[i]:.6g} < {best[i]:.6g}): the optimum was "
                f"not reached ({reasons[i]})"
            )
        trial_diagnostics = {key: _scalar(value[i]) for key, value in search.items()}
        failed[i] = Estimate.failed(
            estimator.name, text, dimension=context.dimension, **trial_diagnostics
        )
    problem = baseline_problem(frozenset({"doppler", "toa"}), context.used)
    if problem is not None:  # hovering: every bearing fits (finalize_estimate's refusal)
        for i in np.flatnonzero(ok).tolist():
            trial_diagnostics = {key: _scalar(value[i]) for key, value in diagnostics.items()}
            trial_diagnostics.pop("straight_track")
            failed[i] = Estimate.failed(
                estimator.name, problem, dimension=context.dimension, **trial_diagnostics
            )
    return _Chunk(
        candidates=candidates,
        n_kept=n_kept,
        chosen=chosen,
        draw=draw,
        ambiguous=ambiguous,
        covariance=covariance,
        diagnostics=diagnostics,
        message=message,
        failed=failed,
    )


def _scalar(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _statuses(
    context: SharedContext,
    valid: BoolArray,
    finite: BoolArray,
    info: IntArray,
    decrement: FloatArray,
    converged: BoolArray,
) -> tuple[ObjectArray, list[str]]:
    """Each trial's ``lm_status`` list (one per start) and the reasons its unconverged starts
    give, joined; one list per pattern of codes of the trials whose starts all converged (a
    few for many trials), shared by its trials."""
    n = len(valid)
    statuses = np.empty(n, dtype=object)
    reasons = [""] * n
    everyone = np.all(converged | ~valid, axis=1)
    pattern = np.where(valid, info, -1).tolist()
    templates: dict[tuple[int, ...], list[str]] = {}
    for i in np.flatnonzero(everyone).tolist():
        key = tuple(pattern[i])
        if key not in templates:
            templates[key] = [f"converged ({INFO_CODES[c]})" for c in key if c >= 0]
        statuses[i] = templates[key]
    cap = context.estimator.max_nfev
    for i in np.flatnonzero(~everyone).tolist():
        found, messages = [], []
        for j in range(int(valid[i].sum())):
            code = INFO_CODES.get(int(info[i, j]), "")
            said = TERMINATION_MESSAGES.get(code, "")
            if not finite[i, j]:
                found.append("non-finite start")
                messages.append("non-finite start")
            elif converged[i, j]:
                found.append(f"converged ({code})")
            elif code == "max_nfev":
                found.append(f"iteration cap (max_nfev={cap})")
                messages.append(f"{said} ({found[-1]})")
            elif code:
                found.append(
                    f"stalled ({code}, decrement {decrement[i, j]:.3g} > {DECREMENT_TOL:g})"
                )
                messages.append(f"{said} but not at a minimum: {found[-1]}")
            else:
                found.append("error (non-finite result)")
                messages.append("the residuals turned non-finite (non-finite result)")
        statuses[i] = found
        reasons[i] = "; ".join(dict.fromkeys(messages))
    return statuses, reasons


def _search(
    context: SharedContext, trial: IntArray, start: FloatArray, scale: FloatArray
) -> tuple[FloatArray, FloatArray, IntArray, IntArray, FloatArray]:
    """Levenberg-Marquardt from each start (local units) of ``trial`` with its frame's
    ``scale``: world points, costs ``‖e‖²``, MINPACK's info, evaluations and the decrement."""
    if len(trial) == 0:
        empty = np.empty(0)
        integers = empty.astype(np.int64)
        return np.empty((0, context.dimension)), empty, integers, integers, empty
    origin = context.origin

    def residuals(index: IntArray, local: FloatArray) -> FloatArray:
        return context.residuals(trial[index], local * scale[index, None] + origin)

    def jacobian(index: IntArray, local: FloatArray) -> list[FloatArray]:
        columns = context.jacobian(local * scale[index, None] + origin)
        return [column * scale[index] for column in columns]

    result = lmder_batch(
        residuals,
        jacobian,
        start,
        ftol=XTOL,
        xtol=XTOL,
        gtol=XTOL,
        max_nfev=context.estimator.max_nfev,
    )
    world = result.x * scale[:, None] + origin
    with np.errstate(all="ignore"):
        costs = column_dot(result.fvec, result.fvec)
        finite = np.all(np.isfinite(world), axis=1) & np.isfinite(costs)
        costs = np.where(finite, costs, np.inf)
        decrement = decrements(context, trial, world, scale, context.jacobian(world), result.fvec)
    return world, costs, np.where(finite, result.info, 0), result.nfev, decrement


# --------------------------------------------------------------------------------------------
# the minima, the mirror rule, the covariance
# --------------------------------------------------------------------------------------------


def distinct_minima(
    context: SharedContext,
    trials: IntArray,
    points: FloatArray,
    costs: FloatArray,
    valid: BoolArray,
    scale: FloatArray,
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Each trial's distinct minima, best first (module text, 4): ``(points, costs, count)``."""
    n, width = costs.shape
    order = np.argsort(np.where(valid, costs, np.inf), axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    costs = np.take_along_axis(np.where(valid, costs, np.inf), order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    threshold = COINCIDENT_RTOL * scale
    kept: list[BoolArray] = []
    start = order.copy()  # the start each kept slot now holds (its original slot)
    for i in range(width):
        merged = np.zeros(n, dtype=bool)
        for j in range(i):
            compared = valid[:, i] & kept[j] & ~merged
            close = compared & (_distance(points[:, i], points[:, j]) <= threshold)
            # the first close one takes this point's place if it is an earlier start at a tie
            tie = costs[:, i] <= costs[:, j] + XTOL * np.abs(costs[:, j])
            take = np.flatnonzero(close & (start[:, i] < start[:, j]) & tie)
            points[take, j], costs[take, j], start[take, j] = (
                points[take, i],
                costs[take, i],
                start[take, i],
            )
            merged |= close
            if context.line is not None:  # the mirror image of a kept minimum: the same one
                origin, direction = context.line
                mirror = points[:, j].copy()  # across the track's vertical plane
                mirror[:, :2] = mirror_across_line(points[:, j, :2], origin, direction)
                twin = compared & (_distance(points[:, i], mirror) <= threshold)
                # of two images at a tie the one on the starts' side (left) is kept: which
                # ends cheaper is rounding, and it orders the mirror rule's candidates
                left = cross_track_m(points[:, i, :2], origin, direction) >= 0.0
                right = cross_track_m(points[:, j, :2], origin, direction) < 0.0
                take = np.flatnonzero(twin & tie & left & right)
                points[take, j], costs[take, j], start[take, j] = (
                    points[take, i],
                    costs[take, i],
                    start[take, i],
                )
                merged |= twin
        kept.append(valid[:, i] & ~merged)
    points, costs, valid = _compact(points, costs, np.column_stack(kept))
    order = np.argsort(costs, axis=1, kind="stable")  # the kept points, back in cost order
    points = np.take_along_axis(points, order[..., None], axis=1)
    costs = np.take_along_axis(costs, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    if valid[:, 1:].any():
        tie = cost_tie_level(costs[:, 0], context.estimator.cost_rtol)
        kept = [valid[:, 0]]
        for i in range(1, valid.shape[1]):
            candidate = valid[:, i] & (costs[:, i] <= tie)
            flat = np.zeros(n, dtype=bool)
            for j in range(i):
                rows = np.flatnonzero(candidate & kept[j] & ~flat)
                if rows.size:
                    middle = 0.5 * (points[rows, i] + points[rows, j])
                    e = context.residuals(trials[rows], middle)
                    flat[rows] = column_dot(e, e) <= tie[rows]
            kept.append(valid[:, i] & ~flat)
        points, costs, valid = _compact(points, costs, np.column_stack(kept))
    return points, costs, valid.sum(axis=1)


def _distance(a: FloatArray, b: FloatArray) -> FloatArray:
    """``‖a − b‖`` of points ``(n, d)``, the squares summed in coordinate order."""
    total = (a[:, 0] - b[:, 0]) * (a[:, 0] - b[:, 0])
    for axis in range(1, a.shape[1]):
        total = total + (a[:, axis] - b[:, axis]) * (a[:, axis] - b[:, axis])
    return np.sqrt(total)


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


def _covariances(
    context: SharedContext, candidates: FloatArray, count: IntArray, wanted: BoolArray
) -> FloatArray:
    """The inverse Fisher information (MATH §8, the Gram matrix ``JᵀJ`` of the whitened
    residuals' Jacobian, summed as :func:`~estimators.ml.minpack_batch.column_sums` sums) at
    each kept candidate of the ``wanted`` trials; NaN where it is singular
    (:func:`scenarios.fisher.inverse_symmetric`)."""
    n, width, d = candidates.shape
    covariance = np.full((n, width, d, d), np.nan)
    slots = (np.arange(width)[None, :] < count[:, None]) & wanted[:, None]
    if slots.any():
        columns = context.jacobian(candidates[slots])
        information = np.empty((len(columns[0][0]), d, d))
        for i in range(d):
            for j in range(i, d):
                information[:, i, j] = information[:, j, i] = column_dot(columns[i], columns[j])
        covariance[slots] = inverse_symmetric(information)
    return covariance


# --------------------------------------------------------------------------------------------
# the columns
# --------------------------------------------------------------------------------------------


def _assemble(
    context: SharedContext, chunks: list[_Chunk], generators: Sequence[Any]
) -> tuple[BatchEstimates, dict[int, Estimate]]:
    """The chunks' trials as columns, the draws made in trial order."""
    n = sum(len(chunk.n_kept) for chunk in chunks)
    width = max(chunk.candidates.shape[1] for chunk in chunks)

    def joined(name: str, fill: Any = np.nan) -> NDArray[Any]:
        parts = []
        for chunk in chunks:
            value = getattr(chunk, name)
            if value.ndim > 1 and value.shape[1] < width:
                pad = np.full((len(value), width - value.shape[1], *value.shape[2:]), fill)
                value = np.concatenate([value, pad.astype(value.dtype)], axis=1)
            parts.append(value)
        return np.concatenate(parts)

    candidates, covariance = joined("candidates"), joined("covariance")
    n_kept, chosen, draw = joined("n_kept"), joined("chosen").copy(), joined("draw")
    ambiguous, message = joined("ambiguous"), joined("message")
    diagnostics = {
        key: np.concatenate([chunk.diagnostics[key] for chunk in chunks])
        for key in chunks[0].diagnostics
    }
    failed: dict[int, Estimate] = {}
    offset = 0
    for chunk in chunks:
        failed.update({offset + i: estimate for i, estimate in chunk.failed.items()})
        offset += len(chunk.n_kept)
    ok = np.ones(n, dtype=bool)
    ok[list(failed)] = False
    for i in np.flatnonzero(draw & ok).tolist():
        if generators[i] is not None:
            chosen[i] = generators[i].integers(n_kept[i])
    rows = np.arange(n)
    chosen = np.minimum(chosen, width - 1)
    position = np.where(ok[:, None], candidates[rows, chosen], np.nan)
    covariance = covariance[rows, chosen]
    singular = ok & np.isnan(covariance).any(axis=(1, 2))
    message = message.astype(object)
    for i in np.flatnonzero(singular).tolist():
        message[i] = f"{message[i]}; {SINGULAR_NOTE}" if message[i] else SINGULAR_NOTE
    counted = np.arange(width)[None, :] < n_kept[:, None]
    unfinite = ok & ~np.isfinite(position).all(axis=1)
    unfinite |= ok & np.any(counted & ~np.isfinite(candidates).all(axis=-1), axis=1)
    for i in np.flatnonzero(unfinite).tolist():
        search = {key: _scalar(diagnostics[key][i]) for key in (*SEARCH_KEYS, "n_converged")}
        failed[i] = Estimate.failed(
            context.estimator.name, "least squares returned a non-finite minimum", **search
        )
        ok[i] = False
    for i, estimate in failed.items():
        message[i] = estimate.message
    texts, codes = np.unique(message.astype(str), return_inverse=True)
    columns = BatchEstimates(
        estimator=context.estimator.name,
        position_m=np.where(ok[:, None], position, np.nan),
        candidates_m=np.where(ok[:, None, None], candidates, np.nan),
        n_candidates=np.where(ok, n_kept, 0),
        ambiguous=ambiguous & ok,
        success=ok,
        message_code=codes.reshape(-1).astype(np.int64),
        messages=tuple(texts.tolist()),
        diagnostics=diagnostics,
        covariance_m2=np.where(ok[:, None, None] & ~singular[:, None, None], covariance, np.nan),
    )
    return columns, failed
