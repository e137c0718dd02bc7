"""Starting points of the maximum-likelihood search that need no closed form (MATH §10).

:func:`ranges_uninformative` says when the ranges carry nothing (the paper's
``c σ_τ = 300 km``: the Doppler fit of the last frame then starts the search too,
:func:`estimators.ml.ml_batch_starts.doppler_frame_starts`); :func:`doppler_grid_starts` starts a
search from Doppler alone, where the cost with an unknown carrier offset has several minima
(MATH §15). The closed-form starts (MATH §5, §15) and the folding of starts on a straight track
are in :mod:`estimators.ml.ml_batch_starts`.
"""

from __future__ import annotations

import dataclasses

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
    model = dataclasses.replace(ResidualModel.of(data), dimension=2)  # at the data's height
    (block,) = model.residuals((x[..., None], y[..., None]), data.doppler_hz, None, None)
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
