r"""The starts of ``ml`` (MATH §10) for a batch of trials, with the bound of their error.

:meth:`MaximumLikelihood._starts <estimators.ml.ml.MaximumLikelihood>`,
:func:`~estimators.ml.ml_starts.doppler_frame_starts` and
:func:`~estimators.ml.ml.straight_track_starts` for every trial of a chunk at once
(:mod:`estimators.ml.ml_batch`). The batch computes the CLS candidates and the Doppler-only fit
differently from the one-trial path (``cls_batch``'s solver, a closed-form least-squares fit), so
each start carries a bound on its distance from the one-trial start (metres); every choice the
starts go through (the side a start is folded to, which of two starts is merged into the other and
their order, on the track's plane or off it) is *in doubt* where that bound could reverse it. The
caller then rounds the starts to the grid of :func:`~estimators.ml.ml.on_start_grid`, where the
bound decides the last doubt, and finds the starts of the trials in doubt with the one-trial code.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.closed_form.cls_batch import solve_chunk
from estimators.closed_form.gtrs_batch import POSITION_RTOL

if TYPE_CHECKING:
    from estimators.ml.ml_batch import SharedContext

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

START_ERROR_FACTOR = 4.0
"""The batch CLS answer is within ``POSITION_RTOL (1 + |u|)`` of the one-trial one (local
units); starts are trusted to this multiple of that."""
MERGE_RTOL = 1e-6
"""Minima closer than ``MERGE_RTOL`` times the local length scale are one minimum."""
ON_TRACK_RTOL = 1e-6
"""A start this close (relative) to a straight track's vertical plane gets a second start off it."""
START_GRID = 2.0**-16
"""Starts are rounded to this grid in local units (:mod:`estimators.ml.ml`, "Reproducibility")."""
FIT_ERROR_RTOL = 1e-12
"""Relative error allowed for the closed-form Doppler fit, times its condition number."""
DISTANCE_RTOL = 1e-12
"""A distance within this (relative) of a merge threshold is in doubt."""


def on_start_grid(local_xy: ArrayLike) -> FloatArray:
    """Starts in local units rounded to ``START_GRID`` (:mod:`estimators.ml.ml`,
    "Reproducibility")."""
    return np.round(np.asarray(local_xy, dtype=float) / START_GRID) * START_GRID


def batch_starts(
    context: SharedContext, trials: IntArray, ranges: FloatArray, scale: FloatArray
) -> tuple[FloatArray, IntArray, FloatArray, BoolArray]:
    """Each trial's starts in world coordinates, in ``estimate``'s order: ``(starts (n, S, 2),
    count, error bound (n, S) in metres, doubt)``."""
    n = len(trials)
    r = np.ascontiguousarray(ranges.T)
    f = np.ascontiguousarray(context.doppler[trials].T)
    single = n == 1
    if single:  # as cls_batch: the sums of one column run in another order
        r, f = np.repeat(r, 2, axis=1), np.repeat(f, 2, axis=1)
    world, solution, doubt = solve_chunk(context.shared, "weighted", r, f)
    if single:
        world, doubt, solution = world[:1], doubt[:1], solution.first()
    doubt = doubt | solution.uncertain
    slots = [world[:, 0], world[:, 1]]
    valid = [np.ones(n, dtype=bool), solution.count > 1]
    local = (world - context.origin) / scale[:, None, None]
    bound = START_ERROR_FACTOR * POSITION_RTOL * (1.0 + np.hypot(local[..., 0], local[..., 1]))
    error = [bound[:, 0] * scale, bound[:, 1] * scale]
    for j in range(2):
        doubt |= valid[j] & ~np.all(np.isfinite(slots[j]), axis=1)
    if context.doppler_start:
        pair, present, fit_error, fit_doubt = _doppler_starts(context, trials)
        slots += [pair[:, 0], pair[:, 1]]
        valid += [present, present]
        error += [fit_error, fit_error]
        doubt |= fit_doubt
    points = np.stack(slots, axis=1)
    valid_a = np.column_stack(valid)
    error_a = np.column_stack(error)
    if context.line is None:
        order = np.argsort(~valid_a, axis=1, kind="stable")
        points = np.take_along_axis(points, order[..., None], axis=1)
        error_a = np.take_along_axis(error_a, order, axis=1)
        return points, valid_a.sum(axis=1), error_a, doubt
    return _straight_track_starts(context, trials, points, valid_a, error_a, scale, doubt)


def _straight_track_starts(
    context: SharedContext,
    trials: IntArray,
    points: FloatArray,
    valid: BoolArray,
    error: FloatArray,
    scale: FloatArray,
    doubt: BoolArray,
) -> tuple[FloatArray, IntArray, FloatArray, BoolArray]:
    """:func:`~estimators.ml.ml.straight_track_starts` for every trial, with error bounds."""
    assert context.line is not None
    (ox, oy), (dx, dy) = context.line
    n, width, _ = points.shape
    offset_x, offset_y = points[..., 0] - ox, points[..., 1] - oy
    cross = dx * offset_y - dy * offset_x
    along = offset_x * dx + offset_y * dy
    mirrored = np.stack(
        [ox + 2.0 * along * dx - offset_x, oy + 2.0 * along * dy - offset_y], axis=-1
    )
    eps = np.finfo(float).eps
    rounding = 8.0 * eps * (np.abs(points).max(-1) + np.hypot(ox, oy))
    error = error + rounding
    unsure_side = np.abs(cross) <= error
    error = error + np.where(unsure_side, 2.0 * np.abs(cross), 0.0)
    points = np.where((cross < 0.0)[..., None], mirrored, points)
    size = np.where(valid, np.abs(cross), np.inf)
    order = np.argsort(size, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    size = np.take_along_axis(size, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    error = np.take_along_axis(error, order, axis=1)
    threshold = MERGE_RTOL * scale
    kept: list[BoolArray] = []
    for i in range(width):
        keep = valid[:, i].copy()
        for j in range(i):
            ddx, ddy = points[:, i, 0] - points[:, j, 0], points[:, i, 1] - points[:, j, 1]
            distance = np.sqrt(ddx * ddx + ddy * ddy)
            together = error[:, i] + error[:, j]
            # which of two starts comes first is the rounding's choice: harmless only for
            # two starts that are one within their errors (either is then the kept one)
            swap = valid[:, i] & valid[:, j] & (np.abs(size[:, i] - size[:, j]) <= together)
            same = distance <= together
            doubt |= swap & ~same
            grown = np.maximum(error[:, j], together + distance)
            error[:, j] = np.where(swap & same & kept[j], grown, error[:, j])
            compared = valid[:, i] & kept[j]
            limit = together + DISTANCE_RTOL * threshold
            doubt |= compared & (np.abs(distance - threshold) <= limit)
            keep &= ~(compared & (distance <= threshold))
        kept.append(keep)
    keep = np.column_stack(kept)
    order = np.argsort(~keep, axis=1, kind="stable")
    points = np.take_along_axis(points, order[..., None], axis=1)
    size = np.take_along_axis(size, order, axis=1)
    error = np.take_along_axis(error, order, axis=1)
    keep = np.take_along_axis(keep, order, axis=1)
    on_limit = ON_TRACK_RTOL * scale[:, None]
    doubt |= np.any(keep & (np.abs(size - on_limit) <= error), axis=1)
    on_track = keep & (size <= on_limit)
    extra, extra_error = _off_plane_copies(context, trials, points, error, scale)
    count = keep.sum(axis=1)
    out = np.full((n, 2 * width, 2), np.nan)
    out_error = np.zeros((n, 2 * width))
    out[:, :width] = points
    out_error[:, :width] = error
    rows = np.arange(n)
    filled = count.copy()
    for j in range(width):
        at = rows[on_track[:, j]]
        out[at, filled[at]] = extra[at, j]
        out_error[at, filled[at]] = extra_error[at, j]
        filled[at] += 1
    return out, filled, out_error, doubt


def _off_plane_copies(
    context: SharedContext,
    trials: IntArray,
    points: FloatArray,
    error: FloatArray,
    scale: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Each start moved off the track's plane by the cross-track distance the ranges imply
    (``straight_track_starts``), and the error bound of the copy (metres)."""
    assert context.line is not None
    _, (dx, dy) = context.line
    used = context.used
    position = used.position_m
    ranges = used.speed_of_light_mps * context.toa[trials]  # (n, K)
    horizontal_sq = ranges**2 - (position[:, 2] - used.emitter_height_m) ** 2
    along = (position[None, None, :, 0] - points[..., 0, None]) * dx + (
        position[None, None, :, 1] - points[..., 1, None]
    ) * dy  # (n, S, K)
    terms = horizontal_sq[:, None, :] - along**2
    offset_sq = np.mean(terms, axis=-1)
    floor = (0.1 * scale[:, None]) ** 2
    offset = np.sqrt(np.maximum(offset_sq, floor))
    normal = np.array([-dy, dx])
    copies = points + offset[..., None] * normal
    eps = np.finfo(float).eps
    mean_along = np.abs(np.mean(along, axis=-1))
    spread = np.mean(np.abs(horizontal_sq)[:, None, :] + along**2, axis=-1)
    change = (2.0 * mean_along * error + 64.0 * eps * spread) / (2.0 * offset)
    return copies, error + change + 8.0 * eps * np.abs(copies).max(-1)


def _doppler_starts(
    context: SharedContext, trials: IntArray
) -> tuple[FloatArray, BoolArray, FloatArray, BoolArray]:
    """:func:`~estimators.ml.ml_starts.doppler_frame_starts` of every trial's last frame: the pair
    ``(n, 2, 2)``, where it exists, its error bound (metres) and doubt."""
    n = len(trials)
    none = (np.full((n, 2, 2), np.nan), np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n, bool))
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
        variance = np.sum(ds * ds, axis=1)
        closest = np.sum(ds * da, axis=1) / variance
        along_s = mean_along - closest * mean_slope
        # the condition of [1, slope] in least squares, for the error bound
        gram = np.stack(
            [total, (weight * slope).sum(axis=1), (weight * slope**2).sum(axis=1)], axis=1
        )
        half_trace = 0.5 * (gram[:, 0] + gram[:, 2])
        radius = np.hypot(0.5 * (gram[:, 0] - gram[:, 2]), gram[:, 1])
        condition = (half_trace + radius) / (half_trace - radius)
        size = np.abs(along_s) + np.abs(closest) * (1.0 + np.max(np.abs(slope), axis=1))
        size = size + np.max(np.abs(along))
        fit_error = FIT_ERROR_RTOL * condition * size
        height = float(np.mean(position[:, 2])) - used.emitter_height_m
        excess = closest**2 - height**2
        cross = np.sqrt(np.maximum(excess, 0.0))
        excess_error = 2.0 * np.abs(closest) * fit_error + 4.0 * np.finfo(float).eps * closest**2
        doubt = present & (np.abs(excess) <= excess_error)
        cross_error = np.where(excess > 0.0, excess_error / (2.0 * np.maximum(cross, 1e-300)), 0.0)
        origin = position[0, :2]
        on_line = origin + (along_s - origin @ direction)[:, None] * direction
        normal = np.array([-direction[1], direction[0]])
        pair = np.stack(
            [on_line + cross[:, None] * normal, on_line - cross[:, None] * normal], axis=1
        )
    finite = np.isfinite(along_s) & np.isfinite(closest)
    doubt |= present & ~(np.isfinite(condition) & (condition > 0.0))
    present &= finite
    error = fit_error * (1.0 + np.abs(mean_slope)) + cross_error
    error = error + 8.0 * np.finfo(float).eps * np.abs(pair).max(axis=(1, 2))
    return pair, present, np.where(present, error, 0.0), doubt & present
