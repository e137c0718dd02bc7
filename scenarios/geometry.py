"""The geometry of a flight: straight frames, the horizontal baseline, the mirror ambiguity.

A frame is one straight segment flown at one velocity (MATH §0); :func:`check_order` and
:func:`check_straight_frames` refuse samples that cannot be such a flight. With every sample at
one horizontal point (:func:`single_horizontal_point`) there is no baseline: ranges and powers
fix only a circle around the point, and without horizontal motion Doppler adds nothing.

The mirror ambiguity of a straight track (MATH §7).

Reflecting the emitter across the vertical plane through a straight track changes no noise-free
Doppler, ToA or RSS value: for every sample ``p_k`` on the line and ``v_k`` along it,
``vᵀ(p − Rs) = (Rv)ᵀ(p − s) = vᵀ(p − s)`` and ``‖p − Rs‖ = ‖p − s‖``. So whenever all samples lie
on one horizontal line and fly along it, every estimator must report both mirror candidates.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.fields import vector_text

FloatArray = NDArray[np.float64]

KINEMATIC_RTOL = 1e-6
"""Relative tolerance of :func:`check_straight_frames` (that of ``emitterbench fly``)."""

_ROUNDING = 16 * np.finfo(float).eps
"""Relative float rounding allowed on top of the tolerances."""


# --------------------------------------------------------------------------------------------
# a flight that can happen
# --------------------------------------------------------------------------------------------


def check_order(frame: NDArray[np.int64], time: FloatArray) -> None:
    """Frames and times never decrease; the message names the first sample out of order."""
    for name, values, unit in (("frame", frame, ""), ("time_s", time, " s")):
        back = np.flatnonzero(np.diff(values) < 0)
        if len(back):
            k = int(back[0]) + 1
            raise ValueError(
                f"{name}[{k}]: {values[k]:g}{unit} comes after {values[k - 1]:g}{unit} at "
                f"{name}[{k - 1}]; order the samples by frame and time (neither may decrease)"
            )


def check_straight_frames(
    frame: NDArray[np.int64], time: FloatArray, position: FloatArray, velocity: FloatArray
) -> None:
    """Raise ``ValueError`` unless each frame is one straight segment flown at one velocity.

    Every sample of a frame has the velocity of the frame's first sample, and consecutive
    samples of a frame follow ``p[k+1] = p[k] + v[k] (t[k+1] − t[k])`` (MATH §0), both to
    within :data:`KINEMATIC_RTOL` of the speed or of the step, plus float rounding. Between
    frames the UAV may turn (and the log may have a gap): nothing is checked there.
    ``frame`` must be sorted (:func:`check_order`).
    """
    first = np.searchsorted(frame, frame, side="left")
    speed = np.linalg.norm(velocity, axis=1)
    change = np.linalg.norm(velocity - velocity[first], axis=1)
    changed = change > KINEMATIC_RTOL * np.maximum(speed, speed[first])
    if changed.any():
        k = int(np.argmax(changed))
        raise ValueError(
            f"velocity_mps[{k}]: {vector_text(velocity[k])} m/s differs from "
            f"{vector_text(velocity[first[k]])} m/s at velocity_mps[{first[k]}], the first "
            f"sample of frame {frame[k]}; a frame is flown at one velocity (MATH §0): give its "
            "samples one velocity, or start a new frame where the velocity changes"
        )
    step = np.diff(position, axis=0)
    expected = velocity[:-1] * np.diff(time)[:, None]
    miss = np.linalg.norm(step - expected, axis=1)
    size = np.maximum(np.linalg.norm(step, axis=1), np.linalg.norm(expected, axis=1))
    norm = np.linalg.norm(position, axis=1)
    rounding = _ROUNDING * (
        norm[1:] + norm[:-1] + speed[:-1] * (np.abs(time[1:]) + np.abs(time[:-1]))
    )
    off = (frame[1:] == frame[:-1]) & (miss > KINEMATIC_RTOL * size + rounding)
    if off.any():
        k = int(np.argmax(off)) + 1
        if time[k] == time[k - 1]:
            raise ValueError(
                f"time_s[{k}]: equals time_s[{k - 1}] = {time[k]:g} s, but the UAV moved "
                f"{vector_text(step[k - 1])} m between them; give each sample its own time"
            )
        raise ValueError(
            f"position_m[{k}]: the step {vector_text(step[k - 1])} m from position_m[{k - 1}] "
            f"is not velocity_mps[{k - 1}] × (time_s[{k}] − time_s[{k - 1}]) = "
            f"{vector_text(expected[k - 1])} m; a frame is one straight segment flown at one "
            "velocity (MATH §0): fix the positions, the velocities or the times"
        )


def single_horizontal_point(position_m: ArrayLike) -> bool:
    """True when every sample is at one horizontal point ``(x, y)``, to float rounding.

    Then the samples span no horizontal baseline (one sample, a hovering UAV, a burst at one
    instant): ranges and powers from one point fix only a circle around it.
    """
    xy = np.asarray(position_m, dtype=float).reshape(-1, 3)[:, :2]
    spread = float(np.max(np.abs(xy - xy[0])))
    return spread <= _ROUNDING * float(np.max(np.abs(xy)))


def moves_horizontally(velocity_mps: ArrayLike) -> bool:
    """True when some sample has a horizontal velocity above float rounding of the speeds."""
    velocity = np.asarray(velocity_mps, dtype=float).reshape(-1, 3)
    horizontal = float(np.max(np.abs(velocity[:, :2])))
    return horizontal > _ROUNDING * float(np.max(np.abs(velocity)))


# --------------------------------------------------------------------------------------------
# the mirror ambiguity of a straight track (MATH §7)
# --------------------------------------------------------------------------------------------


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
