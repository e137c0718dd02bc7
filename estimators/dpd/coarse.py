r"""The coarse stage of direct position determination (docs/math.md §22): the likelihood on a
grid of positions, looked up in a per-burst table of (frequency, delay) correlations.

Within one burst the model of :func:`scenarios.signal.burst_model` is, to first order, a tone
at the hypothesis's Doppler ``f_k(s)`` carrying the burst delayed by ``D_k(s)`` samples. So the
correlation of burst ``k`` with every hypothesis is read off one small table,
``A_k(f, D) = Σ_n x_kn conj(e^{j2πfΔt_n} s̃(n − D))``, over the frequencies the hypotheses can
produce (``|f| ≤ γ|v_k|``) and the delays that keep the burst in its window
(``|D| ≤ guard + 1/2``): ``L(s) ≈ Σ_k |A_k(f_k(s), D_k(s))|² / ‖s̃‖²``, interpolated. The table
costs one product of the samples with a few templates; a grid point then costs a few look-ups
per burst, whatever the burst's length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from scenarios import measurement_model as model
from scenarios.geometry import cross_track_m
from scenarios.signal import (
    BurstPlan,
    burst_rms_bandwidth_hz,
    burst_shift_samples,
    chip_sequence,
    shifted_envelope,
    window_offsets_s,
)
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

SEARCH_EXTENTS = 10.0
"""The default search radius, in the flight's horizontal extents about its centre
(:func:`search_radius_of`)."""

LOBE_FRACTION = 0.25
"""A grid step moves every burst's frequency and delay by at most this fraction of their main
lobes' half-widths (``1/T``, one chip): the best cell lies inside the global maximum's lobe."""

ZOOM = 8
"""The local grids about each coarse maximum: ±ZOOM steps of 1/ZOOM of the spacing, then of
1/ZOOM of that, ``ZOOM_LEVELS`` times."""

ZOOM_LEVELS = 2
"""Two levels put a start within ``spacing / 128`` of the tabulated likelihood's maximum
(about 1 m on ``turn``) for ``2 · 289`` look-ups a burst: the refinement then takes about one
Newton iteration less (27 evaluations of the exact model a start instead of 31)."""

LOBE_FLOOR = (
    np.sinc(LOBE_FRACTION / np.sqrt(2.0)) ** 2 * (1.0 - LOBE_FRACTION / np.sqrt(2.0)) ** 2 - 0.032
)
"""On a grid of ``LOBE_FRACTION`` steps, every lobe's top is within half a diagonal step of a
node, which moves each burst's frequency and delay by at most ``LOBE_FRACTION/√2`` of their
half-widths: the node's coarse ``L`` is at least ``sinc²`` of that (the frequency) times the
square of the BPSK correlation's triangle (the delay), less the interpolation's 3.2%, of the
top's: 0.59 at ``LOBE_FRACTION = 1/4``. A coarse maximum below this fraction of the best one
holds no lobe that can top the best's."""

TABLE_STEP = 0.25
"""The table's steps as a fraction of the widths of the peak of ``|A|²``: near its peak
``|A(f, D)|² ≈ |A|²_max (1 − (2πT_rms δf)² − (2πB_rms δD / f_s)²)``, ``T_rms = T/√12`` the
burst's RMS duration and ``B_rms`` its RMS bandwidth (MATH §18). With steps ``r`` times
``1/(2πT_rms)`` and ``f_s/(2πB_rms)``, three-point interpolation reproduces that quadratic top
and errs by at most ``max|g‴| h³/(9√3)``: for a burst's ``sinc²``, ``|g‴| ≤ 16/w³`` over its
main lobe (``w`` the width), ``16 r³/(9√3)`` = 1.6% of the peak along each axis at
``r = 1/4``."""


@dataclass(frozen=True, slots=True, eq=False)
class TableAxes:
    """The per-burst table's evenly spaced axes (docs/math.md §22): ``frequency_hz`` ``(nf,)``
    and ``shift_samples`` ``(nd,)``, each an odd number (at least three) of nodes."""

    frequency_hz: FloatArray
    shift_samples: FloatArray


@dataclass(frozen=True, slots=True, eq=False)
class SearchGrid:
    """The positions the coarse stage tries (docs/math.md §22): ``x_m`` ``(nx,)`` and ``y_m``
    ``(ny,)``, their points ``points_m`` ``(ny · nx, 2)`` row by row, ``inside`` the points
    whose bursts all stay in their windows, ``spacing_m`` the step, per point and burst the
    Doppler ``doppler_hz`` and shift ``shift_samples`` ``(ny · nx, n_bursts)``, the table's
    ``axes`` and ``lookup``, the sparse ``(ny · nx, n_bursts · nf · nd)`` interpolation of a
    trial's table at every point (the same for every trial: one sparse product serves them),
    and ``resolved``, whether the spacing is the lobe's fraction (not coarsened to fit
    ``max_side``)."""

    x_m: FloatArray
    y_m: FloatArray
    points_m: FloatArray
    inside: BoolArray
    spacing_m: float
    doppler_hz: FloatArray
    shift_samples: FloatArray
    axes: TableAxes
    lookup: sparse.csr_matrix
    resolved: bool


def delay_lobe_samples(plan: BurstPlan) -> float:
    """The half-width of a burst's correlation main lobe in delay, in samples: one chip of a
    BPSK burst, the whole burst of a tone (docs/math.md §22)."""
    return plan.n_burst_samples / len(chip_sequence(plan))


def search_radius_of(geometry: MeasurementSet) -> float:
    """The default search radius about the track's centre (docs/math.md §22):
    :data:`SEARCH_EXTENTS` times the flight's horizontal extent (its samples' largest distance
    from their centre), at least a metre."""
    horizontal = np.asarray(geometry.position_m, dtype=float)[:, :2]
    extent = float(np.max(np.linalg.norm(horizontal - horizontal.mean(axis=0), axis=1)))
    return max(SEARCH_EXTENTS * extent, 1.0)


def search_grid(
    geometry: MeasurementSet,
    plan: BurstPlan,
    schedule_s: ArrayLike,
    *,
    max_side: int = 256,
    radius_m: float | None = None,
) -> SearchGrid:
    """The coarse grid of docs/math.md §22.

    The region: burst ``k``'s window holds its burst while ``|D_k| ≤ G + 1/2`` (``G`` the guard
    in samples), so the emitter lies within ``R_k = c (t_k − e_k + (G + 1/2)/f_s)`` of ``p_k``,
    horizontally within ``√(R_k² − Δz_k²)``, ``Δz_k`` the UAV's height above the emitter; the
    grid covers the intersection of these squares, and ``inside`` keeps its points that satisfy
    every ``|D_k| ≤ G + 1/2``. The spacing: a step moves burst ``k``'s Doppler by at most
    ``γ |v_k| / |Δz_k|`` per metre (the gradient of ``−γ vᵀu`` is at most ``γ|v|/ρ``) and its
    delay by ``f_s / c`` samples per metre, so the step is the smaller of
    ``LOBE_FRACTION · (1/T) · min_k |Δz_k| / (γ|v_k|)`` and
    ``LOBE_FRACTION · chip · c / f_s``, but no finer than ``max_side`` points a side. The
    region is cut to the square of half-side ``radius_m`` about the track's centre (default
    :func:`search_radius_of`): one receiver's Doppler locates within a few track lengths, and
    beyond them its likelihood flattens to a bearing, so a grid over a window kilometres wide
    (a slow chip rate: the delay bounds little) would step over the peak near the track.
    Raises ``ValueError`` naming ``schedule_s`` when no position keeps every burst in its
    window."""
    c = geometry.speed_of_light_mps
    rate = plan.sample_rate_hz
    position = np.asarray(geometry.position_m, dtype=float)
    velocity = np.asarray(geometry.velocity_mps, dtype=float)
    reach = plan.n_guard_samples + 0.5
    flight_s = np.asarray(geometry.time_s, dtype=float) - np.asarray(schedule_s, dtype=float)
    reach_m = c * (flight_s + reach / rate)
    below_m = np.abs(position[:, 2] - geometry.emitter_height_m)
    radius2 = reach_m * reach_m - below_m * below_m
    lower = np.max(position[:, :2] - np.sqrt(np.maximum(radius2, 0.0))[:, None], axis=0)
    upper = np.min(position[:, :2] + np.sqrt(np.maximum(radius2, 0.0))[:, None], axis=0)
    centre = position[:, :2].mean(axis=0)
    radius = search_radius_of(geometry) if radius_m is None else float(radius_m)
    lower, upper = np.maximum(lower, centre - radius), np.minimum(upper, centre + radius)
    if np.any(radius2 < 0.0) or np.any(lower > upper):
        raise ValueError(
            "schedule_s: no emitter position at the known height keeps every burst within its "
            "window; give the bursts' nominal emission times e_k (t_k minus the flight time)"
        )
    speed = np.linalg.norm(velocity, axis=1)
    with np.errstate(divide="ignore"):
        metres_per_hz = np.min(
            np.where(speed > 0.0, below_m / (geometry.gamma_per_m * speed), np.inf)
        )
    step_doppler = LOBE_FRACTION / plan.burst_s * metres_per_hz
    step_delay = LOBE_FRACTION * delay_lobe_samples(plan) * c / rate
    width = float(np.max(upper - lower))
    step = max(min(step_doppler, step_delay), width / (max_side - 1))
    x_m, y_m = (
        np.linspace(lo, hi, int(np.ceil((hi - lo) / step)) + 1 if hi > lo else 1)
        for lo, hi in zip(lower, upper, strict=True)
    )
    grid_x, grid_y = np.meshgrid(x_m, y_m)
    points = np.stack([grid_x.ravel(), grid_y.ravel()], axis=-1)
    shift = burst_shift_samples(geometry, plan, points, schedule_s)
    doppler = model.doppler_hz(
        position, velocity, points, geometry.gamma_per_m, geometry.emitter_height_m
    )
    axes = table_axes(geometry, plan)
    index, weight = interpolation(axes, doppler, shift)
    n_columns = doppler.shape[1] * len(axes.frequency_hz) * len(axes.shift_samples)
    per_row = index.shape[1] * index.shape[2]  # every point reads 9 nodes of every burst
    lookup = sparse.csr_matrix(
        (
            weight.reshape(len(points), per_row).ravel(),
            index.reshape(len(points), per_row).ravel(),
            np.arange(len(points) + 1, dtype=index.dtype) * per_row,
        ),
        shape=(len(points), n_columns),
    )
    return SearchGrid(
        x_m=x_m,
        y_m=y_m,
        points_m=points,
        inside=np.all(np.abs(shift) <= reach, axis=-1),
        spacing_m=step,
        doppler_hz=doppler,
        shift_samples=shift,
        axes=axes,
        lookup=lookup,
        resolved=bool(step <= min(step_doppler, step_delay)),
    )


def _axis(limit: float, step: float) -> FloatArray:
    """``[−limit, limit]`` in an odd number, at least three, of points at most ``step`` apart
    (zero is one)."""
    count = max(3, 2 * int(np.ceil(limit / step)) + 1)
    return np.linspace(-limit, limit, count)


def table_axes(geometry: MeasurementSet, plan: BurstPlan) -> TableAxes:
    """The table's axes (docs/math.md §22): frequencies ``|f| ≤ γ max|v_k|`` plus one step,
    delays ``|D| ≤ G + 1/2``, steps ``TABLE_STEP`` of the widths of the peak (a tone has no
    delay width: three delays). Raises ``ValueError`` naming ``sample_rate_hz`` when the
    Dopplers reach the receiver's band's edge."""
    speed = np.linalg.norm(np.asarray(geometry.velocity_mps, dtype=float), axis=1)
    step_hz = TABLE_STEP * np.sqrt(12.0) / (2.0 * np.pi * plan.burst_s)
    frequency = _axis(geometry.gamma_per_m * float(np.max(speed)) + step_hz, step_hz)
    if frequency[-1] >= plan.sample_rate_hz / 2.0:
        raise ValueError(
            f"sample_rate_hz: the Doppler reaches {frequency[-1]:.6g} Hz, beyond the receiver's "
            f"{plan.sample_rate_hz / 2.0:.6g} Hz; raise sample_rate_hz"
        )
    bandwidth = burst_rms_bandwidth_hz(plan)
    step_samples = (
        TABLE_STEP * plan.sample_rate_hz / (2.0 * np.pi * bandwidth) if bandwidth else np.inf
    )
    return TableAxes(
        frequency_hz=frequency, shift_samples=_axis(plan.n_guard_samples + 0.5, step_samples)
    )


def correlation_table(plan: BurstPlan, samples: ArrayLike, axes: TableAxes) -> FloatArray:
    """Every trial's table ``|A_k(f, D)|² / ‖s̃‖²`` (docs/math.md §22), ``(n_trials, n_bursts,
    nf, nd)`` on ``axes``: one product of the samples with the ``nd`` delayed bursts
    (:func:`scenarios.signal.shifted_envelope`), then with the ``nf`` tones."""
    envelope = shifted_envelope(plan, axes.shift_samples)  # (nd, N)
    energy = np.sum(envelope[0].real ** 2 + envelope[0].imag ** 2)
    tone = np.exp(2j * np.pi * np.outer(axes.frequency_hz, window_offsets_s(plan)))  # (nf, N)
    x = np.asarray(samples)
    removed = x[:, :, None, :] * np.conj(envelope)  # (n, K, nd, N)
    correlation = removed @ np.conj(tone).T  # (n, K, nd, nf)
    power = correlation.real**2 + correlation.imag**2
    return np.swapaxes(power, -1, -2) / energy


def _quadratic(values: FloatArray, axis: FloatArray) -> tuple[NDArray[np.int64], FloatArray]:
    """The nearest inner node's index on evenly spaced ``axis`` (at least three nodes) and the
    three-point Lagrange weights of it and its two neighbours, ``(..., 3)``."""
    position = (values - axis[0]) / (axis[1] - axis[0])
    index = np.clip(np.rint(position).astype(np.int64), 1, len(axis) - 2)
    t = np.clip(position - index, -1.0, 1.0)
    return index, np.stack([0.5 * t * (t - 1.0), 1.0 - t * t, 0.5 * t * (t + 1.0)], axis=-1)


def interpolation(
    axes: TableAxes, doppler_hz: FloatArray, shift_samples: FloatArray
) -> tuple[NDArray[np.integer], FloatArray]:
    """The biquadratic interpolation of the table (docs/math.md §22) at per-burst Dopplers
    ``doppler_hz`` and shifts ``shift_samples`` ``(..., n_bursts)``: the nine nodes of each,
    as indices into a trial's flattened table ``(n_bursts · nf · nd,)``, and their weights,
    ``(..., n_bursts, 9)`` each (int32 indices where they fit). Three nodes a side reproduce a
    peak's quadratic top, so a maximum falls between the nodes where it is, not on a node."""
    nf, nd = len(axes.frequency_hz), len(axes.shift_samples)
    i_f, w_f = _quadratic(doppler_hz, axes.frequency_hz)
    i_d, w_d = _quadratic(shift_samples, axes.shift_samples)
    # int32 where the table's columns fit (the sparse look-up's own index type): half the bytes
    kind = np.int32 if doppler_hz.shape[-1] * nf * nd < 2**31 else np.int64
    base = ((np.arange(doppler_hz.shape[-1]) * nf + i_f) * nd + i_d).astype(kind)
    step = np.add.outer(np.array([-nd, 0, nd]), np.array([-1, 0, 1])).ravel().astype(kind)
    index = base[..., None] + step
    weight = (w_f[..., :, None] * w_d[..., None, :]).reshape(*w_f.shape[:-1], 9)
    return index, weight


def tabulated_log_likelihood(
    power: FloatArray, axes: TableAxes, doppler_hz: FloatArray, shift_samples: FloatArray
) -> FloatArray:
    """The coarse ``L`` (docs/math.md §22) of each trial's hypotheses with per-burst Dopplers
    ``doppler_hz`` and shifts ``shift_samples`` ``(n_trials, P, n_bursts)`` from the trials'
    tables ``power``: each burst's table interpolated (:func:`interpolation`), summed over the
    bursts; ``(n_trials, P)``."""
    n = len(power)
    index, weight = interpolation(axes, doppler_hz, shift_samples)
    picked = np.take_along_axis(power.reshape(n, -1), index.reshape(n, -1), axis=1)
    return np.sum(weight * picked.reshape(index.shape), axis=(-2, -1))


def grid_log_likelihood(power: FloatArray, grid: SearchGrid) -> FloatArray:
    """The coarse ``L`` at every grid point for each trial's table ``power``, ``(n_trials,
    n_points)`` (one sparse product with ``grid.lookup``), ``−inf`` outside the region
    (docs/math.md §22)."""
    coarse = (grid.lookup @ power.reshape(len(power), -1).T).T
    return np.where(grid.inside, coarse, -np.inf)


def coarse_maxima(
    coarse: FloatArray,
    grid: SearchGrid,
    n_starts: int,
    line: tuple[FloatArray, FloatArray] | None,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The ``n_starts`` best local maxima of each trial's coarse ``L`` (a point at least its
    eight neighbours), ``(n_trials, n_starts, 2)``, their values and whether each is one
    (docs/math.md §22).
    On a straight track (``line``) only the points on its left are searched: the likelihood is
    the same at the mirror image (§7), which the mirror rule adds back."""
    n = len(coarse)
    ny, nx = len(grid.y_m), len(grid.x_m)
    values = coarse
    if line is not None:
        left = cross_track_m(grid.points_m, *line) >= 0.0
        values = np.where(left, coarse, -np.inf)
    image = values.reshape(n, ny, nx)
    padded = np.pad(image, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    peak = np.isfinite(image)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                peak &= image >= padded[:, 1 + dy : 1 + dy + ny, 1 + dx : 1 + dx + nx]
    ranked = np.where(peak.reshape(n, -1), values, -np.inf)
    order = np.argsort(-ranked, axis=1, kind="stable")[:, :n_starts]
    values = np.take_along_axis(ranked, order, axis=1)
    return grid.points_m[order], values, np.isfinite(values)


def contending_maxima(
    coarse_values: FloatArray, found: BoolArray, grid: SearchGrid, margin: FloatArray
) -> BoolArray:
    """The coarse maxima ``(n_trials, m)`` (their coarse ``L``, ``found`` those that are) whose
    lobe can hold the global maximum (docs/math.md §22): on a resolved grid, at least
    ``LOBE_FLOOR`` of the trial's best coarse value less ``margin`` ``(n_trials,)`` (the
    values' noise); every one found on a coarsened grid."""
    if not grid.resolved:
        return found
    best = np.max(np.where(found, coarse_values, -np.inf), axis=1)
    return found & (coarse_values >= LOBE_FLOOR * best[:, None] - margin[:, None])


def zoomed_starts(
    geometry: MeasurementSet,
    plan: BurstPlan,
    schedule_s: ArrayLike,
    power: FloatArray,
    grid: SearchGrid,
    starts_m: FloatArray,
    line: tuple[FloatArray, FloatArray] | None,
) -> FloatArray:
    """Each start ``(n_trials, m, 2)`` moved to the best point of the coarse ``L`` on a local
    grid of ±``ZOOM`` steps of a ``ZOOM``-th of the spacing about it, then again at a
    ``ZOOM``-th of that step (``ZOOM_LEVELS``), on the trials' tables ``power``
    (docs/math.md §22): the tabulated likelihood is cheap, and the refinement then starts near
    its maximum. On a straight track the local grids keep the left side and the start stays at
    least half a local step from the track, where the cross-track slope vanishes by
    symmetry."""
    n, m, _ = starts_m.shape
    offsets = np.arange(-ZOOM, ZOOM + 1)
    unit = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)
    moved = starts_m
    for level in range(1, ZOOM_LEVELS + 1):
        step = grid.spacing_m / ZOOM**level
        points = (moved[:, :, None, :] + step * unit).reshape(n, m * len(unit), 2)
        doppler = model.doppler_hz(
            geometry.position_m,
            geometry.velocity_mps,
            points,
            geometry.gamma_per_m,
            geometry.emitter_height_m,
        )
        shift = burst_shift_samples(geometry, plan, points, schedule_s)
        values = tabulated_log_likelihood(power, grid.axes, doppler, shift)
        if line is not None:
            values = np.where(cross_track_m(points, *line) >= 0.0, values, -np.inf)
        best = np.argmax(values.reshape(n, m, -1), axis=-1)
        moved = np.take_along_axis(points.reshape(n, m, -1, 2), best[..., None, None], axis=2)[
            :, :, 0
        ]
        if line is not None:
            direction = np.asarray(line[1], dtype=float)
            lift = np.maximum(0.5 * step - cross_track_m(moved, *line), 0.0)
            moved = moved + lift[..., None] * np.array([-direction[1], direction[0]])
    return moved
