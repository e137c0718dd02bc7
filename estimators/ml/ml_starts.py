"""Starting points of the maximum-likelihood search that need no closed form (MATH §10).

:func:`doppler_frame_starts` fits one straight, level frame's Doppler alone, for when the ranges
carry nothing (:func:`ranges_uninformative`: the paper's ``c σ_τ = 300 km``);
:func:`doppler_grid_starts` starts a search from Doppler alone, where the cost with an unknown
carrier offset has several minima (MATH §15). The closed-form
starts (MATH §5, §15) and the folding of starts on a straight track are in
:mod:`estimators.ml.ml`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from estimators.ml.ml_residuals import ResidualModel
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


def ranges_uninformative(data: MeasurementSet) -> bool:
    """True when the range noise ``c σ_τ`` exceeds the size of the geometry.

    The size is ``√(mean‖p_k,xy − p̄_xy‖² + mean (z_k − z_s)²)``, the spread of the track and
    its height above the emitter, which bounds the ranges from below; a range error larger than
    that leaves the CLS start (MATH §5) without range information.
    """
    position = data.position_m
    spread_sq = np.mean(np.sum((position[:, :2] - position[:, :2].mean(axis=0)) ** 2, axis=1))
    height_sq = np.mean((position[:, 2] - data.emitter_height_m) ** 2)
    return bool(data.noise.toa_s * data.speed_of_light_mps > np.sqrt(spread_sq + height_sq))


def doppler_frame_starts(frame_data: MeasurementSet) -> FloatArray:
    """Doppler-only starting points from one straight, level frame: a mirror pair, (2, 2).

    With ``g_k = f_k/(γ|v|) = −v̂ᵀu_k = −a_k/ρ_k`` (physical sign, MATH §1), ``a_k`` the
    along-track offset ``v̂ᵀ(p_k − s)`` and ``ρ_0`` the distance from the emitter to the line of
    flight, ``ρ_k² = a_k² + ρ_0²`` gives ``a_k = −ρ_0 g_k/√(1 − g_k²)``, so

    ``v̂ᵀp_k = v̂ᵀs − ρ_0 g_k/√(1 − g_k²)``

    is linear in ``(v̂ᵀs, ρ_0)``: least squares over the frame, then the cross-track distance
    ``√(ρ_0² − (z − z_s)²)`` on both sides. Independent of the ToA, so it still starts the
    search near the emitter when the ranges are useless (the paper's ``c σ_τ = 300 km``).
    Returns an empty (0, 2) array when the frame is not straight and level or the fit fails.
    """
    velocity = frame_data.velocity_mps
    if frame_data.n_samples < 2 or np.ptp(velocity, axis=0).any() or velocity[0, 2] != 0.0:
        return np.empty((0, 2))
    speed = float(np.linalg.norm(velocity[0]))
    if not speed > 0.0:
        return np.empty((0, 2))
    direction = velocity[0, :2] / speed
    g = frame_data.doppler_hz / (frame_data.gamma_per_m * speed)
    usable = np.abs(g) < 0.999
    if np.count_nonzero(usable) < 2:
        return np.empty((0, 2))
    along = frame_data.position_m[usable, :2] @ direction
    slope = -g[usable] / np.sqrt(1.0 - g[usable] ** 2)
    A = np.column_stack([np.ones_like(slope), slope])
    (along_s, closest_m), *_ = np.linalg.lstsq(A, along, rcond=None)
    height_m = float(np.mean(frame_data.position_m[:, 2])) - frame_data.emitter_height_m
    if not (np.isfinite(along_s) and np.isfinite(closest_m)):
        return np.empty((0, 2))
    cross = np.sqrt(max(closest_m**2 - height_m**2, 0.0))
    origin = frame_data.position_m[0, :2]
    on_line = origin + (along_s - origin @ direction) * direction
    normal = np.array([-direction[1], direction[0]])
    return np.vstack([on_line + cross * normal, on_line - cross * normal])


GRID_POINTS = 25
"""Points per axis of :func:`doppler_grid_starts`' grid."""

GRID_STARTS = 4
"""Most local minima of the grid :func:`doppler_grid_starts` returns."""


def doppler_grid_starts(data: MeasurementSet) -> FloatArray:
    """Starts from Doppler alone: the lowest local minima of the (profiled, MATH §15) Doppler
    cost on a square grid around the track, (n, 2) with ``n <= GRID_STARTS``.

    The grid is centred on the track's mean position and spans twice the larger of the track's
    extent and the UAV's mean height above the emitter on each side; a point is a local minimum
    when no neighbour of its 3×3 block is lower. The Doppler-only cost is multimodal (with an
    unknown carrier offset the emitter trades distance for offset), so several starts go to the
    search.
    """
    xy = data.position_m[:, :2]
    centre = xy.mean(axis=0)
    height = float(np.mean(np.abs(data.position_m[:, 2] - data.emitter_height_m)))
    half = 2.0 * max(float(np.ptp(xy, axis=0).max()), height, 1.0)
    axis = np.linspace(-half, half, GRID_POINTS)
    x, y = np.meshgrid(centre[0] + axis, centre[1] + axis, indexing="ij")
    model = ResidualModel.of(data)
    (block,) = model.residuals(x[..., None], y[..., None], data.doppler_hz, None, None)
    cost = np.sum(block**2, axis=-1)
    padded = np.pad(cost, 1, constant_values=np.inf)
    neighbours = np.stack(
        [
            padded[1 + i : 1 + i + GRID_POINTS, 1 + j : 1 + j + GRID_POINTS]
            for i in (-1, 0, 1)
            for j in (-1, 0, 1)
            if (i, j) != (0, 0)
        ]
    )
    minima = np.argwhere(np.all(cost[None] <= neighbours, axis=0) & np.isfinite(cost))
    order = np.argsort(cost[minima[:, 0], minima[:, 1]], kind="stable")[:GRID_STARTS]
    chosen = minima[order]
    return np.column_stack([x[chosen[:, 0], chosen[:, 1]], y[chosen[:, 0], chosen[:, 1]]])
