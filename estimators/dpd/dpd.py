r"""Direct position determination (docs/math.md §22): the emitter's position from the received
bursts' samples in one maximum-likelihood search, without per-burst measurements.

A. Amar and A. J. Weiss, "Localization of narrowband radio emitters based on Doppler frequency
shifts", IEEE Trans. Signal Processing 56(11), 2008: the likelihood of the position with every
burst's complex amplitude profiled out, ``L(s) = Σ_k |u_k(s)ᴴ x_k|² / ‖u_k(s)‖²``
(:func:`estimators.dpd.likelihood.profiled_log_likelihood`), maximised over the position ``s``
in two stages: the coarse grid of :mod:`estimators.dpd.coarse` (a per-burst table of
(frequency, delay) correlations, looked up) and the Newton ascent of
:mod:`estimators.dpd.refine` on the exact ``L`` (:func:`scenarios.signal.burst_model`) from the
grid's best local maxima. On one straight track ``L`` is the same at the mirror image through
the track (§7): the search keeps the left side and the mirror rule
(:func:`estimators.mirror_rule.finalize_columns`) returns both.

Scope: a cooperative emitter (carrier offset and emission time known: the bursts' nominal
emission times are the schedule) at a known height; the 2-D position. :func:`direct_position`
is vectorised over trials; :class:`DirectPosition` is its thin class.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Estimate, check_side_prior, hovering_problem
from estimators.batch import BatchEstimates, check_rngs
from estimators.closed_form.cls_batch import draw_tie_breaks
from estimators.dpd.coarse import (
    ZOOM,
    ZOOM_LEVELS,
    coarse_maxima,
    contending_maxima,
    correlation_table,
    grid_log_likelihood,
    search_grid,
    zoomed_starts,
)
from estimators.dpd.likelihood import profiled_log_likelihood_derivatives
from estimators.dpd.refine import newton_ascent
from estimators.interface import Capabilities
from estimators.mirror_rule import finalize_columns
from scenarios.geometry import TrackSoFar, cross_track_m, mirror_across_line
from scenarios.signal import BurstPlan
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
Rngs = Sequence[np.random.Generator | None] | None

NAME = "dpd"

XTOL_FRACTION = 1e-7
"""The refinement stops at a step below this fraction of the grid's spacing (§22)."""

ABANDON_SIGMAS = 10.0
"""A start is abandoned when even its lobe's predicted top lies this many standard deviations
of the likelihood's noise below the trial's best value so far: ``L`` at a point where the bursts
explain the energy ``L`` carries a noise term of variance ``2 L σ²`` (§22)."""

MERGE_FRACTION = 1e-4
"""Refined maxima closer than this fraction of the grid's spacing are one (§22)."""

CHUNK_VALUES = 1 << 18
"""Values computed at once (complex model samples, table look-ups): a few MB; larger blocks
leave the cache and run slower per value."""

NO_CONVERGENCE = (
    "dpd: the refinement converged from none of the coarse maxima within max_iterations; "
    "raise max_iterations or n_starts (MATH §22)"
)


def check_iq(
    geometry: MeasurementSet, plan: BurstPlan, samples: ArrayLike, schedule_s: ArrayLike
) -> tuple[NDArray[np.complex128], FloatArray]:
    """The samples ``(n_trials, n_bursts, n_samples)`` as complex and the schedule, or one
    ``ValueError`` line naming the field at fault."""
    if not isinstance(geometry, MeasurementSet):
        raise ValueError(
            f"geometry: expected a MeasurementSet (the flight), got {type(geometry).__name__}"
        )
    if not isinstance(plan, BurstPlan):
        raise ValueError(f"plan: expected a BurstPlan, got {type(plan).__name__}")
    if geometry.unknowns:
        raise ValueError(
            f"unknowns: the geometry declares {list(geometry.unknowns)} unknown; DPD here "
            "estimates the position only, for a cooperative emitter at a known height"
        )
    try:
        x = np.asarray(samples, dtype=np.complex128)
    except (TypeError, ValueError):
        raise ValueError(
            f"samples: expected complex numbers, got {type(samples).__name__}"
        ) from None
    n_bursts = geometry.n_samples
    if x.ndim != 3 or x.shape[0] < 1 or x.shape[1] != n_bursts:
        raise ValueError(
            f"samples: expected shape (n_trials, {n_bursts}, {plan.n_samples}) (one window per "
            f"burst of the geometry), got {x.shape}"
        )
    if x.shape[2] != plan.n_samples:
        raise ValueError(
            f"samples: each window holds {x.shape[2]} samples, the plan's window "
            f"{plan.n_samples} (plan.n_samples); give the plan the samples were recorded with"
        )
    bad = ~np.isfinite(x).all(axis=(1, 2))
    if bad.any():
        raise ValueError(
            f"samples: NaN or infinite values in trial {int(np.argmax(bad))}; give finite samples"
        )
    try:
        schedule = np.asarray(schedule_s, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"schedule_s: expected {n_bursts} times in seconds, got {type(schedule_s).__name__}"
        ) from None
    if schedule.shape != (n_bursts,) or not np.isfinite(schedule).all():
        raise ValueError(
            f"schedule_s: expected {n_bursts} finite times in seconds (one per burst), got "
            f"shape {schedule.shape}"
        )
    return x, schedule


def check_search_radius(search_radius_m: object) -> None:
    """``search_radius_m``: None or a positive finite number of metres, else one line."""
    if search_radius_m is None:
        return
    if (
        isinstance(search_radius_m, bool)
        or not isinstance(search_radius_m, int | float)
        or not 0.0 < search_radius_m < np.inf
    ):
        raise ValueError(
            f"search_radius_m: expected a positive number of metres (the area of interest's "
            f"half-side about the track's centre) or None, got {search_radius_m!r}"
        )


def direct_position(
    geometry: MeasurementSet,
    plan: BurstPlan,
    samples: ArrayLike,
    schedule_s: ArrayLike,
    *,
    n_starts: int = 4,
    max_grid_side: int = 256,
    max_iterations: int = 50,
    cost_rtol: float = 1e-6,
    side_prior_m: ArrayLike | None = None,
    covariance: bool = True,
    search_radius_m: float | None = None,
    rngs: Rngs = None,
) -> BatchEstimates:
    """The DPD estimate of every trial's emitter position (docs/math.md §22), estimator name
    ``"dpd"``.

    Parameters
    ----------
    geometry : MeasurementSet
        The flight (positions, velocities and times at the bursts' centres, γ, c, the emitter's
        height); no ``unknowns`` (a cooperative emitter at a known height).
    plan : BurstPlan
        The bursts and the receiver the samples were recorded with.
    samples : (n_trials, n_bursts, n_samples) complex
        Each trial's windows, one per burst (``n_samples = plan.n_samples``).
    schedule_s : (n_bursts,)
        The bursts' nominal emission times e_k.
    n_starts : int
        The coarse grid's best local maxima refined per trial.
    max_grid_side : int
        At most this many grid points along each axis (the spacing grows to fit).
    max_iterations : int
        Newton iterations per start.
    cost_rtol, side_prior_m, rngs
        The mirror rule's tie level, side prior and tie-break generators (MATH §7).
    covariance : bool
        Report ``σ̂² (−∇²L)⁻¹`` at the estimate, the inverse observed information of the
        profiled likelihood (σ̂² the noise's power per sample from the residual).
    search_radius_m : float or None
        The half-side of the square searched about the track's centre, metres (the area of
        interest); None: :func:`estimators.dpd.coarse.search_radius_of`, ten times the
        flight's horizontal extent.

    The search region and the grid's spacing are those of
    :func:`estimators.dpd.coarse.search_grid`: the positions whose bursts all stay within
    their windows, the spacing a quarter of the likelihood's main lobe (``1/T`` in each burst's
    Doppler, a chip in its delay) mapped to metres by the largest gradients the geometry allows.
    Each coarse maximum moves to the best point of local grids of an eighth of the spacing,
    then of a 64th (:func:`estimators.dpd.coarse.zoomed_starts`); the refinement
    (:func:`estimators.dpd.refine.newton_ascent`) starts there with a trust radius of that
    last step, the analytic derivatives of ``L``, and stops at
    :data:`XTOL_FRACTION` of it. A trial none of whose starts converges is a failed estimate.
    """
    x, schedule = check_iq(geometry, plan, samples, schedule_s)
    for name, value, least in (
        ("n_starts", n_starts, 1),
        ("max_grid_side", max_grid_side, 3),
        ("max_iterations", max_iterations, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
            raise ValueError(f"{name}: expected a whole number >= {least}, got {value!r}")
    check_side_prior(side_prior_m)
    check_search_radius(search_radius_m)
    n = len(x)
    generators = check_rngs(rngs, n)
    hovering = hovering_problem(geometry)
    if hovering is not None:
        return BatchEstimates.failed(n, hovering, estimator=NAME, covariance=covariance)
    track = TrackSoFar.of(geometry)
    line = None if track.straight is None else (track.straight.origin_m, track.straight.direction)

    # coarse: the tabulated likelihood on the grid, its best local maxima (left of a straight
    # track only), each moved to the best point of a local grid about it
    grid = search_grid(geometry, plan, schedule, max_side=max_grid_side, radius_m=search_radius_m)
    width = min(n_starts, len(grid.points_m))
    per_trial = x.shape[1] * x.shape[2] * len(grid.axes.shift_samples)
    chunk = max(1, CHUNK_VALUES // per_trial)
    power = np.concatenate(
        [correlation_table(plan, x[i : i + chunk], grid.axes) for i in range(0, n, chunk)]
    )
    coarse = grid_log_likelihood(power, grid)
    best, best_values, found = coarse_maxima(coarse, grid, width, line)
    energy = np.sum(x.real**2 + x.imag**2, axis=(1, 2))
    dof = x.shape[1] * (x.shape[2] - 1)

    def margin(trials: NDArray[np.int64], best: FloatArray) -> FloatArray:
        """``ABANDON_SIGMAS`` standard deviations of the noise in ``L`` at ``best``."""
        noise_w = np.maximum(energy[trials] - best, 0.0) / dof
        return ABANDON_SIGMAS * np.sqrt(2.0 * np.maximum(best, 0.0) * noise_w)

    top = np.max(coarse, axis=1)
    found = contending_maxima(
        best_values,
        found,
        grid,
        margin(np.arange(n), top),
    )
    per_trial = width * (2 * ZOOM + 1) ** 2 * x.shape[1] * 9  # the local grids' look-ups
    chunk = max(1, CHUNK_VALUES // per_trial)
    starts = np.concatenate(
        [
            zoomed_starts(
                geometry, plan, schedule, power[i : i + chunk], grid, best[i : i + chunk], line
            )
            for i in range(0, n, chunk)
        ]
    )

    # refine: the exact likelihood's Newton ascent from every start found, all trials at once
    trial_of, slot_of = np.nonzero(found)
    rows_per_call = max(1, CHUNK_VALUES // (8 * x.shape[1] * x.shape[2]))

    def objective(
        rows: NDArray[np.int64], points: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        value, gradient, hessian = (
            np.empty(len(rows)),
            np.empty((len(rows), 2)),
            np.empty((len(rows), 2, 2)),
        )
        for first in range(0, len(rows), rows_per_call):
            part = slice(first, first + rows_per_call)
            v, g, h = profiled_log_likelihood_derivatives(
                geometry, plan, x[trial_of[rows[part]]], schedule, points[part, None]
            )
            value[part], gradient[part], hessian[part] = v[:, 0], g[:, 0], h[:, 0]
        return value, gradient, hessian

    ascent = newton_ascent(
        objective,
        starts[trial_of, slot_of],
        radius_m=grid.spacing_m / ZOOM**ZOOM_LEVELS,
        xtol_m=XTOL_FRACTION * grid.spacing_m,
        max_iterations=max_iterations,
        group=trial_of,
        margin=margin,
    )
    position = np.full((n, width, 2), np.nan)
    value = np.full((n, width), -np.inf)
    hessian = np.full((n, width, 2, 2), np.nan)
    iterations = np.zeros((n, width), dtype=np.int64)
    ok = ascent.converged
    position[trial_of[ok], slot_of[ok]] = ascent.position_m[ok]
    value[trial_of[ok], slot_of[ok]] = ascent.value[ok]
    hessian[trial_of[ok], slot_of[ok]] = ascent.hessian[ok]
    iterations[trial_of, slot_of] = ascent.iterations
    if line is not None:  # a maximum refined across the track: its mirror image, same L
        right = cross_track_m(position, *line) < 0.0
        position[right] = mirror_across_line(position[right], *line)
        hessian[right] = _reflected(hessian[right], line[1])
        # a maximum on the track (within the merge distance) is its own mirror image: one point
        cross = cross_track_m(position, *line)
        on = cross <= MERGE_FRACTION * grid.spacing_m
        normal = np.array([-line[1][1], line[1][0]])
        position[on] -= cross[on][:, None] * normal
    candidates, count, kept = _distinct(position, value, MERGE_FRACTION * grid.spacing_m)

    final = finalize_columns(
        candidates,
        count,
        -np.take_along_axis(value, kept, axis=1),
        track.centre_m,
        line,
        side_prior_m=side_prior_m,
        cost_rtol=cost_rtol,
    )
    success = ~final.invalid
    chosen = final.chosen.copy()
    draw_tie_breaks(generators, final.draw & success, final.n_candidates, chosen)
    rows = np.arange(n)
    chosen = np.minimum(chosen, final.candidates.shape[1] - 1)
    answer = final.candidates[rows, chosen]
    source = final.source[rows, chosen]
    slot = np.take_along_axis(kept, np.maximum(source % max(width, 1), 0)[:, None], axis=1)[:, 0]
    best = value[rows, slot]
    noise_w = np.maximum(energy - best, 0.0) / (x.shape[1] * (x.shape[2] - 1))
    diagnostics: dict[str, Any] = {
        "profiled_log_likelihood": np.where(success, best, np.nan),
        "noise_variance_w": np.where(success, noise_w, np.nan),
        "iterations": iterations[rows, slot],
        "n_converged": np.bincount(trial_of[ok], minlength=n).astype(np.int64),
        "grid_spacing_m": np.full(n, grid.spacing_m),
        "straight_track": np.full(n, line is not None),
    }
    covariance_m2 = None
    if covariance:
        information = -hessian[rows, slot]
        if line is not None:
            mirrored = source >= width
            information[mirrored] = _reflected(information[mirrored], line[1])
        covariance_m2 = _inverse_information(information) * noise_w[:, None, None]
        covariance_m2[~success] = np.nan
    return BatchEstimates(
        estimator=NAME,
        position_m=np.where(success[:, None], answer, np.nan),
        candidates_m=np.where(success[:, None, None], final.candidates, np.nan),
        n_candidates=np.where(success, final.n_candidates, 0),
        ambiguous=final.ambiguous & success,
        success=success,
        message_code=np.where(success, 0, 1).astype(np.int64),
        messages=("", NO_CONVERGENCE),
        diagnostics=diagnostics,
        covariance_m2=covariance_m2,
    )


def _distinct(
    position: FloatArray, value: FloatArray, merge_m: float
) -> tuple[FloatArray, NDArray[np.int64], NDArray[np.int64]]:
    """Each trial's refined maxima, best first, one of any closer than ``merge_m``: the
    candidates ``(n, w, 2)`` (the first ``count`` given) and the slot each came from."""
    order = np.argsort(-value, axis=1, kind="stable")
    points = np.take_along_axis(position, order[..., None], axis=1)
    valid = np.isfinite(np.take_along_axis(value, order, axis=1))
    keep = valid.copy()
    for j in range(1, points.shape[1]):
        gap = np.linalg.norm(points[:, :j] - points[:, j : j + 1], axis=-1)
        keep[:, j] &= ~np.any(keep[:, :j] & (gap <= merge_m), axis=1)
    front = np.argsort(~keep, axis=1, kind="stable")
    kept = np.take_along_axis(order, front, axis=1)
    candidates = np.take_along_axis(points, front[..., None], axis=1)
    return candidates, keep.sum(axis=1).astype(np.int64), kept


def _reflected(matrix: FloatArray, direction: FloatArray) -> FloatArray:
    """``M A Mᵀ`` with the reflection ``M = 2ddᵀ − I`` across the track's direction ``d``."""
    d = np.asarray(direction, dtype=float)
    reflection = 2.0 * np.outer(d, d) - np.eye(2)
    return reflection @ matrix @ reflection.T


def _inverse_information(information: FloatArray) -> FloatArray:
    """The inverse of each 2×2 information (symmetrised); NaN where it is not positive
    definite."""
    a, b, c = (
        information[:, 0, 0],
        0.5 * (information[:, 0, 1] + information[:, 1, 0]),
        information[:, 1, 1],
    )
    det = a * c - b * b
    definite = (a > 0.0) & (det > 0.0)
    safe = np.where(definite, det, 1.0)
    inverse = np.stack([np.stack([c, -b], -1), np.stack([-b, a], -1)], -2) / safe[:, None, None]
    inverse[~definite] = np.nan
    return inverse


@dataclass(frozen=True, kw_only=True)
class DirectPosition:
    """Direct position determination from the bursts' samples (docs/math.md §22): the thin
    class around :func:`direct_position`, its options as fields. It reads samples, not
    measurement sets: registered among the estimators of the samples
    (:data:`estimators.registry.SAMPLE_LEVEL`), its ``estimate`` refuses a measurement set.

    Parameters
    ----------
    n_starts : int
        The coarse grid's best local maxima refined per trial.
    max_grid_side : int
        At most this many grid points along each axis.
    max_iterations : int
        Newton iterations per start.
    cost_rtol : float
        Maxima within this relative gap of the best are all candidates (MATH §7).
    side_prior_m : (x, y) or None
        A rough emitter position; picks the nearer of equal-likelihood candidates (MATH §7).
    covariance : bool
        Report the inverse observed information at the estimate.
    search_radius_m : float or None
        The area of interest's half-side about the track's centre, metres; None: ten times the
        flight's horizontal extent (:func:`estimators.dpd.coarse.search_radius_of`).
    """

    name: ClassVar[str] = NAME
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    """The bursts carry a Doppler and a delay each: the bound a DPD answer is held to is that
    of both, at the σ's the bursts allow (the signal-level bound, §21)."""

    n_starts: int = 4
    max_grid_side: int = 256
    max_iterations: int = 50
    cost_rtol: float = 1e-6
    side_prior_m: tuple[float, float] | None = None
    covariance: bool = True
    search_radius_m: float | None = None

    def __post_init__(self) -> None:
        for option, least in (("n_starts", 1), ("max_grid_side", 3), ("max_iterations", 1)):
            value = getattr(self, option)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{option}: expected a whole number >= {least}, got {value!r}")
        if not (isinstance(self.cost_rtol, int | float) and 0.0 <= self.cost_rtol < np.inf):
            raise ValueError(f"cost_rtol: expected a finite number >= 0, got {self.cost_rtol!r}")
        if not isinstance(self.covariance, bool):
            raise ValueError(f"covariance: expected true or false, got {self.covariance!r}")
        check_side_prior(self.side_prior_m)
        check_search_radius(self.search_radius_m)

    def capabilities(self) -> Capabilities:
        """What it uses (MATH §8): every burst's Doppler and delay, from every frame."""
        return Capabilities(modalities=self.requires, frames="all")

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """Refused in one line: DPD reads the received samples, which a measurement set has
        not (:meth:`estimate_iq`)."""
        raise ValueError(
            "estimator: dpd locates from the received samples, not from measurements; give it "
            "a recording (emitterbench estimate REC.sigmf-meta --estimator dpd) or run it in "
            "an experiment with a [signal] table"
        )

    def estimate_iq_batch(
        self,
        geometry: MeasurementSet,
        plan: BurstPlan,
        samples: ArrayLike,
        schedule_s: ArrayLike,
        *,
        rngs: Rngs = None,
    ) -> BatchEstimates:
        """:func:`direct_position` of ``samples`` ``(n_trials, n_bursts, n_samples)``."""
        return direct_position(
            geometry,
            plan,
            samples,
            schedule_s,
            n_starts=self.n_starts,
            max_grid_side=self.max_grid_side,
            max_iterations=self.max_iterations,
            cost_rtol=self.cost_rtol,
            side_prior_m=self.side_prior_m,
            covariance=self.covariance,
            search_radius_m=self.search_radius_m,
            rngs=rngs,
        )

    def estimate_iq(
        self,
        geometry: MeasurementSet,
        plan: BurstPlan,
        samples: ArrayLike,
        schedule_s: ArrayLike,
        *,
        rng: np.random.Generator | None = None,
    ) -> Estimate:
        """One trial's estimate from its samples ``(n_bursts, n_samples)``: the batch of one."""
        x = np.asarray(samples)
        if x.ndim != 2:
            raise ValueError(
                f"samples: expected one trial's windows (n_bursts, n_samples), got shape {x.shape}"
            )
        return self.estimate_iq_batch(geometry, plan, x[None], schedule_s, rngs=[rng]).estimate(0)
