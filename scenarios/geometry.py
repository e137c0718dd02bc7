"""The mirror ambiguity of a straight track (MATH §7).

Reflecting the emitter across the vertical plane through a straight track changes no noise-free
Doppler, ToA or RSS value: for every sample ``p_k`` on the line and ``v_k`` along it,
``vᵀ(p − Rs) = (Rv)ᵀ(p − s) = vᵀ(p − s)`` and ``‖p − Rs‖ = ‖p − s‖``. So whenever all samples lie
on one horizontal line and fly along it, every estimator must report both mirror candidates.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def straight_track_line(
    position_m: ArrayLike, velocity_mps: ArrayLike, *, rtol: float = 1e-9
) -> tuple[FloatArray, FloatArray] | None:
    """The horizontal line all samples lie on and fly along, or None if there is none.

    Returns ``(origin_m, direction)``: a point of the line and its unit direction, both (2,).
    The mirror ambiguity of MATH §7 holds exactly when this is not None.
    """
    xy = np.asarray(position_m, dtype=float)[:, :2]
    v_xy = np.asarray(velocity_mps, dtype=float)[:, :2]
    origin = xy.mean(axis=0)
    spread = xy - origin
    # principal direction of the samples, else of the velocities (a single sample)
    basis = spread if np.any(spread) else v_xy
    if not np.any(basis):
        return None
    _, singular, vt = np.linalg.svd(basis, full_matrices=False)
    direction = vt[0]
    scale = max(singular[0], np.finfo(float).tiny)
    if len(singular) > 1 and singular[1] > rtol * scale:
        return None
    speed = np.linalg.norm(v_xy, axis=1)
    cross = np.abs(v_xy[:, 0] * direction[1] - v_xy[:, 1] * direction[0])
    if np.any(cross > rtol * speed):
        return None
    return origin, direction


def mirror_across_line(
    points_m: ArrayLike, origin_m: ArrayLike, direction: ArrayLike
) -> FloatArray:
    """Reflect points (..., 2) across the line through ``origin_m`` along unit ``direction``."""
    points = np.asarray(points_m, dtype=float)
    origin = np.asarray(origin_m, dtype=float)
    direction = np.asarray(direction, dtype=float)
    offset = points - origin
    along = offset @ direction
    return origin + 2.0 * along[..., None] * direction - offset


def cross_track_m(points_m: ArrayLike, origin_m: ArrayLike, direction: ArrayLike) -> FloatArray:
    """Signed distance of points (..., 2) from the line, positive on its left."""
    offset = np.asarray(points_m, dtype=float) - np.asarray(origin_m, dtype=float)
    return direction[0] * offset[..., 1] - direction[1] * offset[..., 0]
