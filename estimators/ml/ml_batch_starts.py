r"""The starts of ``ml`` (MATH §10) for a batch of trials.

Every candidate of the corrected CLS (MATH §5-§6) is a start: for the whole chunk at once
(:func:`estimators.closed_form.cls_batch.solve_chunk`), and for a trial that solver leaves
undecided, or any trial with a nuisance parameter unknown, from the closed form's own one-trial
code (:func:`closed_form_starts`: the pseudo-range CLS with an unknown emission time, LLS-ToA
when the CLS cannot start, e.g. a hovering sample, and from Doppler alone the local minima of
the profiled Doppler cost on a grid, MATH §15). Optionally also the Doppler-only fit of the
last frame (:func:`doppler_frame_starts`), useful when the ranges are useless.

On a straight track the likelihood is mirror-symmetric, so starts are folded to one side (the
mirror minima are added by the mirror rule); a start on the track's vertical plane, where the
cross-track gradient vanishes, gets a second start off it, so that both the off-track mirror
pair and the on-track minimum of MATH §5 are reachable (:func:`fold_to_one_side`).

With the emitter's height unknown (MATH §8) the starts are these at a few heights
(:func:`start_heights`: from the height the data assume, the take-off ground, up to just
below the UAV, which the emitter is below): each height's closed form gives ``(x, y)``, the
height the third coordinate.

Each start is then rounded to a grid of ``START_GRID`` local units (:func:`on_start_grid`,
~1e−6 of the length scale, far below any start's own error): the search's path is a function
of the data, not of the last bits of the closed-form solve.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.baselines.lls import solve_lls_toa
from estimators.closed_form.cls_batch import candidates_of_trial, solve_chunk
from estimators.closed_form.pseudorange_cls import solve_pseudorange_batch, solve_pseudorange_cls
from estimators.ml.ml_starts import doppler_grid_starts
from scenarios.types import MeasurementBatch, MeasurementSet

if TYPE_CHECKING:
    from estimators.ml.ml_batch import SharedContext

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

COINCIDENT_RTOL = 1e-6
"""Two starts, or two minima, closer than this times the local length scale are one point
(Levenberg-Marquardt stops within ``xtol = 1e-10`` relative of a minimum; a flat valley
across a track's plane spreads its end points wider)."""
ON_TRACK_RTOL = 1e-6
"""A start this close (relative) to a straight track's vertical plane gets a second start off it."""
START_GRID = 2.0**-16
"""Starts are rounded to this grid in local units (module text)."""


HEIGHT_FRACTIONS = (0.0, 0.5, 0.9)
"""The starts' heights (height unknown) between the ground and the UAV's lowest altitude
(:func:`start_heights`)."""


def start_heights(data: MeasurementSet) -> tuple[float, ...]:
    """The heights of the starts with the height unknown (module text): ``HEIGHT_FRACTIONS``
    of the way from the ground the data assume (``emitter_height_m``, the take-off ground, a
    guess only) to the lowest altitude of the UAV; when the UAV is not above that ground, as
    far below its lowest altitude as the track's horizontal spread (at least 1 m)."""
    lowest = float(np.min(data.position_m[:, 2]))
    depth = lowest - data.emitter_height_m
    if not depth > 0.0:
        xy = data.position_m[:, :2]
        depth = max(float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1)))), 1.0)
    return tuple(lowest - depth * (1.0 - fraction) for fraction in HEIGHT_FRACTIONS)


def at_height(batch: MeasurementBatch, height_m: float) -> MeasurementBatch:
    """``batch`` with the emitter's assumed height ``height_m`` (its unknowns kept): the
    closed-form starts at that height."""
    geometry = dataclasses.replace(batch.geometry, emitter_height_m=height_m)
    return dataclasses.replace(batch, geometry=geometry)


def on_start_grid(local_xy: ArrayLike) -> FloatArray:
    """Starts in local units rounded to ``START_GRID`` (module text)."""
    return np.round(np.asarray(local_xy, dtype=float) / START_GRID) * START_GRID


def closed_form_starts(data: MeasurementSet, fallback_lls: bool) -> tuple[FloatArray, str, str]:
    """One trial's closed-form starts ``(k, 2)`` (``k = 0``: none), how they were found and a
    note: the CLS candidates, or the LLS-ToA solution when the CLS fails and ``fallback_lls``;
    with an unknown emission time the pseudo-range closed form's; from Doppler alone the local
    minima of the profiled cost on a grid (MATH §15)."""
    none = np.empty((0, 2))
    if data.toa_s is None:
        return doppler_grid_starts(data).reshape(-1, 2), "doppler-grid", ""
    try:
        if "emission_time_s" in data.unknowns:
            unknown_offset = "carrier_offset_hz" in data.unknowns
            solution = solve_pseudorange_cls(data, carrier_offset_unknown=unknown_offset)
            candidates = solution.candidates_m
        else:
            candidates = candidates_of_trial(data)
        if np.all(np.isfinite(candidates)) and len(candidates):
            return np.asarray(candidates, dtype=float).reshape(-1, 2), "cls", ""
        reason = "CLS returned no finite candidate"
    except (ValueError, np.linalg.LinAlgError) as error:
        reason = f"CLS failed ({error})"
    if not fallback_lls or "emission_time_s" in data.unknowns:
        return none, "none", reason
    lls = solve_lls_toa(data.position_m, data.range_m, data.emitter_height_m)
    if not np.all(np.isfinite(lls.position_m)):
        return none, "none", f"{reason}; LLS-ToA returned a non-finite solution"
    return lls.position_m[None, :], "lls-toa", f"{reason}; started from LLS-ToA"


def pseudorange_starts(
    context: SharedContext,
    trials: IntArray,
    method: NDArray[np.object_],
    note: NDArray[np.object_],
) -> dict[int, FloatArray]:
    """With an unknown emission time, every trial's starts from the pseudo-range closed form
    solved for all of them at once (:func:`solve_pseudorange_batch`, whose trial ``i`` is what
    :func:`closed_form_starts` gets from it alone): ``{i: (k, 2)}``, ``method`` and ``note``
    filled in. Empty when the batch refuses the geometry: each trial then says why alone."""
    speed_of_light = context.used.speed_of_light_mps
    try:
        solution = solve_pseudorange_batch(
            context.used,
            speed_of_light * context.toa[trials],
            context.doppler[trials],
            carrier_offset_unknown="carrier_offset_hz" in context.used.unknowns,
        )
    except (ValueError, np.linalg.LinAlgError):
        return {}
    found = {}
    for i, count in enumerate(solution.count.tolist()):
        candidates = solution.candidates_m[i, :count]
        if count and np.all(np.isfinite(candidates)):
            found[i], method[i], note[i] = candidates, "cls", ""
        else:
            found[i], method[i] = np.empty((0, 2)), "none"
            note[i] = "CLS returned no finite candidate"
    return found


def find_starts(
    context: SharedContext, trials: IntArray, scale: FloatArray
) -> tuple[FloatArray, IntArray, NDArray[np.object_], NDArray[np.object_]]:
    """Each trial's starts in world coordinates (module text): ``(starts (n, S, d), count,
    start method (n,), note (n,))``, the first ``count[i]`` slots of trial ``i`` valid."""
    if context.dimension == 3:
        return _starts_at_heights(context, trials, scale)
    n = len(trials)
    method = np.full(n, "cls", dtype=object)
    note = np.full(n, "", dtype=object)
    points = np.full((n, 2, 2), np.nan)
    valid = np.zeros((n, 2), dtype=bool)
    redo = np.ones(n, dtype=bool)
    if context.cls_geometry is not None:
        r = context.used.speed_of_light_mps * np.ascontiguousarray(context.toa[trials].T)
        f = np.ascontiguousarray(context.doppler[trials].T)
        world, solution = solve_chunk(context.cls_geometry, "weighted", r, f)
        points[:] = world
        valid[:, 0], valid[:, 1] = True, solution.count > 1
        # where the CLS has no finite answer, a trial says why alone (or starts from LLS-ToA)
        redo = solution.failed | np.any(valid & ~np.isfinite(world).all(-1), axis=1)
    found = pseudorange_starts(context, trials, method, note) if context.pseudo_ranges else {}
    for i in np.flatnonzero(redo).tolist():
        if i in found:
            continue
        found[i], method[i], note[i] = closed_form_starts(
            context.trial_data(int(trials[i])), context.estimator.fallback_lls
        )
    width = max([2, *(len(p) for p in found.values())])
    if width > 2:
        points = np.concatenate([points, np.full((n, width - 2, 2), np.nan)], axis=1)
        valid = np.concatenate([valid, np.zeros((n, width - 2), dtype=bool)], axis=1)
    for i, p in found.items():
        points[i], valid[i] = np.nan, False
        points[i, : len(p)], valid[i, : len(p)] = p, True
    if not context.uses_toa:
        return points, valid.sum(axis=1), method, note
    if context.doppler_start:
        pair, present = doppler_frame_starts(context, trials)
        present &= valid.any(axis=1)
        points = np.concatenate([points, pair], axis=1)
        valid = np.concatenate([valid, present[:, None], present[:, None]], axis=1)
    if context.line is not None:
        return (*fold_to_one_side(context, trials, points, valid, scale), method, note)
    order = np.argsort(~valid, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    return points, valid.sum(axis=1), method, note


def _starts_at_heights(
    context: SharedContext, trials: IntArray, scale: FloatArray
) -> tuple[FloatArray, IntArray, NDArray[np.object_], NDArray[np.object_]]:
    """:func:`find_starts` with the height unknown: the starts of each of the context's
    heights (:func:`start_heights`), that height their third coordinate, in height order; the
    method and note of the first height that gives a start."""
    n = len(trials)
    parts, valid = [], []
    method = np.full(n, "none", dtype=object)
    note = np.full(n, "", dtype=object)
    for height, at in context.heights:
        points, count, found, said = find_starts(at, trials, scale)
        parts.append(np.concatenate([points, np.full((*points.shape[:2], 1), height)], axis=-1))
        valid.append(np.arange(points.shape[1])[None, :] < count[:, None])
        first = (method == "none") & (count > 0)
        method[first], note[first] = found[first], said[first]
        unset = (method == "none") & (note == "")
        note[unset] = said[unset]
    points, present = np.concatenate(parts, axis=1), np.concatenate(valid, axis=1)
    order = np.argsort(~present, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    return points, present.sum(axis=1), method, note


def fold_to_one_side(
    context: SharedContext,
    trials: IntArray,
    points: FloatArray,
    valid: BoolArray,
    scale: FloatArray,
) -> tuple[FloatArray, IntArray]:
    """Starts folded to the left of a straight track, one of each coincident pair kept, by
    distance from the track's plane, with a second start for those on it (module text)."""
    assert context.line is not None
    (ox, oy), (dx, dy) = context.line
    n, width, _ = points.shape
    offset_x, offset_y = points[..., 0] - ox, points[..., 1] - oy
    cross = dx * offset_y - dy * offset_x
    along = offset_x * dx + offset_y * dy
    mirrored = np.stack(
        [ox + 2.0 * along * dx - offset_x, oy + 2.0 * along * dy - offset_y], axis=-1
    )
    points = np.where((cross < 0.0)[..., None], mirrored, points)
    size = np.where(valid, np.abs(cross), np.inf)
    order = np.argsort(size, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    size = np.take_along_axis(size, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    threshold = COINCIDENT_RTOL * scale
    kept: list[BoolArray] = []
    for i in range(width):
        keep = valid[:, i].copy()
        for j in range(i):
            ddx, ddy = points[:, i, 0] - points[:, j, 0], points[:, i, 1] - points[:, j, 1]
            keep &= ~(kept[j] & (np.sqrt(ddx * ddx + ddy * ddy) <= threshold))
        kept.append(keep)
    keep = np.column_stack(kept)
    order = np.argsort(~keep, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    size = np.take_along_axis(size, order, axis=1)
    keep = np.take_along_axis(keep, order, axis=1)
    on_track = keep & (size <= ON_TRACK_RTOL * scale[:, None])
    count = keep.sum(axis=1)
    out = np.full((n, 2 * width, 2), np.nan)
    out[:, :width] = np.where(keep[..., None], points, np.nan)
    if on_track.any():
        extra = _off_plane_copies(context, trials, points, scale)
        rows = np.arange(n)
        for j in range(width):
            at = rows[on_track[:, j]]
            out[at, count[at]] = extra[at, j]
            count[at] += 1
    return out, count


def _off_plane_copies(
    context: SharedContext, trials: IntArray, points: FloatArray, scale: FloatArray
) -> FloatArray:
    """Each start moved off the track's plane by the cross-track distance the ranges imply,
    ``√mean(r_k² − (z_k − z_s)² − a_k²)`` with ``a_k`` the along-track offset (at least
    ``0.1`` of the length scale)."""
    assert context.line is not None
    _, (dx, dy) = context.line
    used = context.used
    position = used.position_m
    ranges = used.speed_of_light_mps * context.toa[trials]  # (n, K)
    horizontal_sq = ranges**2 - (position[:, 2] - used.emitter_height_m) ** 2
    along = (position[None, None, :, 0] - points[..., 0, None]) * dx + (
        position[None, None, :, 1] - points[..., 1, None]
    ) * dy  # (n, S, K)
    offset_sq = np.mean(horizontal_sq[:, None, :] - along**2, axis=-1)
    offset = np.sqrt(np.maximum(offset_sq, (0.1 * scale[:, None]) ** 2))
    return points + offset[..., None] * np.array([-dy, dx])


def doppler_frame_starts(context: SharedContext, trials: IntArray) -> tuple[FloatArray, BoolArray]:
    """Doppler-only starting points from each trial's last frame, when it is straight and
    level: a mirror pair ``(n, 2, 2)``, and where it exists.

    With ``g_k = f_k/(γ|v|) = −v̂ᵀu_k = −a_k/ρ_k`` (physical sign, MATH §1), ``a_k`` the
    along-track offset ``v̂ᵀ(p_k − s)`` and ``ρ_0`` the distance from the emitter to the line of
    flight, ``ρ_k² = a_k² + ρ_0²`` gives ``a_k = −ρ_0 g_k/√(1 − g_k²)``, so

    ``v̂ᵀp_k = v̂ᵀs − ρ_0 g_k/√(1 − g_k²)``

    is linear in ``(v̂ᵀs, ρ_0)``: least squares over the frame's samples with ``|g_k| < 0.999``
    (at least two), then the cross-track distance ``√(ρ_0² − (z − z_s)²)`` on both sides.
    Independent of the ToA, so it still starts the search near the emitter when the ranges
    are useless (the paper's ``c σ_τ = 300 km``).
    """
    n = len(trials)
    none = (np.full((n, 2, 2), np.nan), np.zeros(n, dtype=bool))
    used = context.used
    columns = np.flatnonzero(used.frame == used.frame[-1])
    velocity, position = used.velocity_mps[columns], used.position_m[columns]
    if len(columns) < 2 or np.ptp(velocity, axis=0).any() or velocity[0, 2] != 0.0:
        return none
    speed = float(np.linalg.norm(velocity[0]))
    if not speed > 0.0:
        return none
    direction = velocity[0, :2] / speed
    g = context.doppler[trials][:, columns] / (used.gamma_per_m * speed)
    usable = np.abs(g) < 0.999
    present = np.count_nonzero(usable, axis=1) >= 2
    with np.errstate(all="ignore"):
        along = position[:, 0] * direction[0] + position[:, 1] * direction[1]
        slope = np.where(usable, -g / np.sqrt(1.0 - g**2), 0.0)
        weight = usable.astype(float)
        total = weight.sum(axis=1)
        mean_slope = (weight * slope).sum(axis=1) / total
        mean_along = (weight * along).sum(axis=1) / total
        ds = weight * (slope - mean_slope[:, None])
        da = weight * (along - mean_along[:, None])
        closest = np.sum(ds * da, axis=1) / np.sum(ds * ds, axis=1)
        along_s = mean_along - closest * mean_slope
        height = float(np.mean(position[:, 2])) - used.emitter_height_m
        cross = np.sqrt(np.maximum(closest**2 - height**2, 0.0))
        origin = position[0, :2]
        on_line = origin + (along_s - origin @ direction)[:, None] * direction
        normal = np.array([-direction[1], direction[0]])
        pair = np.stack(
            [on_line + cross[:, None] * normal, on_line - cross[:, None] * normal], axis=1
        )
    present &= np.isfinite(along_s) & np.isfinite(closest)
    return pair, present
