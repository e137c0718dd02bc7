"""One estimate scored against the truth: the per-estimate columns of a trial row.

:func:`estimate_columns` gives the :data:`~comparison.trial_rows.ESTIMATE_COLUMNS` of a row:
the position and its error, the error once the mirror ambiguity is resolved (MATH §7), the
side of the track, the covariance and the two NEES (:func:`normalized_error_squared`, with
:func:`mirrored_covariance` for a candidate across the track). The track is that of one frame
(:func:`frame_track`); in a closed loop, that of the first frame the estimator uses
(:func:`ambiguity_track`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from comparison.trial_rows import ESTIMATE_COLUMNS
from estimators.base import Estimate
from scenarios.fisher import inverse_2x2
from scenarios.types import MeasurementSet

Track = tuple[np.ndarray, np.ndarray]
"""A point of a frame's track and its horizontal unit direction."""


def frame_track(geometry: MeasurementSet, frame: int) -> Track | None:
    """A point and the horizontal unit direction of ``frame``'s track, or None when hovering."""
    first = int(np.argmax(geometry.frame == frame))
    velocity = np.asarray(geometry.velocity_mps[first, :2], dtype=float)
    speed = float(np.hypot(*velocity))
    if speed == 0.0:
        return None
    return np.asarray(geometry.position_m[first, :2], dtype=float), velocity / speed


def ambiguity_track(data: MeasurementSet, frame: int, frames: Any) -> Track | None:
    """The track whose mirror ambiguity an estimator faces at ``frame`` (closed loop, MATH §7).

    The first frame the estimator uses: ``frame`` itself for ``frames="last"``, frame 0 for
    ``"all"``, the first listed frame up to ``frame`` otherwise. A cumulative estimator's side
    is judged against the first track, the ambiguity a turn must resolve: the side of a later
    track is ill-defined when a planner flies through the emitter's horizontal position (the
    truth then lies within centimetres of that track's plane).
    """
    if isinstance(frames, str) and frames == "last":
        first = frame
    elif isinstance(frames, Sequence) and not isinstance(frames, str):
        chosen = [int(f) for f in frames if 0 <= int(f) <= frame]
        if not chosen:
            return None
        first = min(chosen)
    else:
        first = 0
    return frame_track(data, first)


def estimate_columns(
    estimate: Estimate,
    truth_m: np.ndarray,
    track: Track | None,
    runtime_s: float,
) -> tuple[Any, ...]:
    """The per-estimate columns of a trial row, in the order of
    :data:`~comparison.trial_rows.ESTIMATE_COLUMNS`.

    ``error_side_resolved_m`` uses the candidate nearest to the truth (MATH §7). ``nees`` is
    the returned position's error against the estimator's covariance; ``nees_side_resolved``
    the nearest candidate's error against *that candidate's* covariance: the covariance
    reflected across ``track`` when the candidate lies on the other side of it than the
    returned position (its mirror image, MATH §7), else the covariance as given.
    ``wrong_side`` is 1.0 when the returned position and the truth are strictly on opposite
    sides of the vertical plane through ``track``, NaN when the position lies in that plane (on
    neither side). Every error column is NaN for a failed estimate.
    """
    nan = math.nan
    success = bool(estimate.success)
    truth = np.asarray(truth_m, dtype=float)[:2]
    position = np.asarray(estimate.position_m, dtype=float) if success else np.full(2, nan)
    candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    error_m = float(np.hypot(*(position - truth)))
    side_resolved_m, nearest = nan, position
    if success:
        pool = candidates if len(candidates) else position[None, :]
        distances = np.hypot(*(pool - truth).T)
        if np.isfinite(distances).any():
            nearest = pool[int(np.nanargmin(distances))]
            side_resolved_m = float(np.nanmin(distances))
    side_of = _signed_cross_track(track)
    wrong_side = nan
    if success and track is not None and np.isfinite(position).all():
        side_estimate, side_truth = side_of(position), side_of(truth)
        scale = max(abs(side_truth), float(np.hypot(*(position - track[0]))))
        on_plane = abs(side_estimate) <= 1e-9 * scale
        # an estimate in the track's vertical plane is on neither side: NaN, not a lucky 0
        wrong_side = nan if on_plane else (1.0 if side_estimate * side_truth < 0.0 else 0.0)
    cov = (nan, nan, nan)
    nees = nees_side_resolved = nan
    if estimate.covariance_m2 is not None:
        covariance = np.asarray(estimate.covariance_m2, dtype=float)
        cov = (float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1]))
        nees = normalized_error_squared(position - truth, covariance)
        if track is not None and side_of(nearest) * side_of(position) < 0.0:
            covariance = mirrored_covariance(covariance, track[1])
        nees_side_resolved = normalized_error_squared(nearest - truth, covariance)
    values = {
        "x_m": float(position[0]),
        "y_m": float(position[1]),
        "error_m": error_m,
        "error_side_resolved_m": side_resolved_m,
        "wrong_side": wrong_side,
        "ambiguous": bool(estimate.ambiguous),
        "success": success,
        "n_candidates": len(candidates),
        "candidates_json": json.dumps(jsonable(candidates.tolist())),
        "cov_xx_m2": cov[0],
        "cov_xy_m2": cov[1],
        "cov_yy_m2": cov[2],
        "nees": nees,
        "nees_side_resolved": nees_side_resolved,
        "runtime_s": float(runtime_s),
        "message": str(estimate.message),
        "diagnostics_json": json.dumps(jsonable(dict(estimate.diagnostics)), sort_keys=True),
    }
    return tuple(values[column] for column in ESTIMATE_COLUMNS)


def _signed_cross_track(track: Track | None) -> Any:
    """``point ↦`` signed distance from the vertical plane through ``track`` (0 without one)."""
    if track is None:
        return lambda point: 0.0
    (ox, oy), (dx, dy) = track
    return lambda point: float(dx * (point[1] - oy) - dy * (point[0] - ox))


def mirrored_covariance(covariance_m2: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """``R P Rᵀ`` with ``R = 2 d dᵀ − I`` the reflection across a line of unit direction ``d``:
    the covariance of the mirror image of an estimate (MATH §7)."""
    d = np.asarray(direction, dtype=float).reshape(2)
    reflection = 2.0 * np.outer(d, d) - np.eye(2)
    return reflection @ covariance_m2 @ reflection.T


def normalized_error_squared(error_m: np.ndarray, covariance_m2: np.ndarray) -> float:
    """``eᵀ P⁻¹ e`` (NEES, 2 degrees of freedom); NaN when ``P`` is singular or not finite
    (:func:`scenarios.fisher.inverse_2x2`)."""
    error = np.asarray(error_m, dtype=float)
    return float(error @ inverse_2x2(covariance_m2) @ error)


def jsonable(value: Any) -> Any:
    """JSON-ready: arrays to lists, numpy scalars to Python, non-finite floats to null."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def estimate_to_dict(estimate: Estimate, truth_emitter_m: Any | None) -> dict[str, Any]:
    """``Estimate.to_dict()`` plus ``error_m`` and ``error_side_resolved_m`` given a truth.

    ``error_side_resolved_m`` is the distance from the truth to the nearest candidate: the
    error with the mirror side resolved (MATH §7).
    """
    result = estimate.to_dict()
    if truth_emitter_m is not None:
        truth = np.asarray(truth_emitter_m, dtype=float)
        error = float(np.linalg.norm(estimate.position_m - truth))
        candidates = estimate.candidates_m
        result["error_m"] = error if math.isfinite(error) else None
        result["error_side_resolved_m"] = (
            float(np.min(np.linalg.norm(candidates - truth, axis=1))) if len(candidates) else None
        )
    return result
