r"""Where the frame-by-frame estimators start when nuisance parameters are unknown (MATH §5, §7,
§15).

The closed form of MATH §5 (:func:`estimators.sequential.mirror_hypotheses.first_frame_candidates`)
needs the emitter's carrier and emission time. On the first frame (a straight segment, MATH §0) a
linear least squares replaces it (:func:`closed_form_point`). In the track's frame (origin
``o`` the frame's mean position, along-track unit ``d``, left normal ``n``, sample ``k`` at
along-track ``t_k`` and height ``h_k = z_k − z_s`` above the emitter, emitter at
``o + a d + c n``) the ranges ``(r_k − β)² = (t_k − a)² + c² + h_k²`` and the Doppler·range
products ``(f_k − δ)(r_k − β) = −γ(|v_xy|(t_k − a) + v_z h_k)`` (MATH §3 with the offsets) are
linear in ``u = (β, δ, a, C, P)``, ``C = a² + c² − β²``, ``P = δβ``:

.. math::

    r_k^2 - t_k^2 - h_k^2 = 2\beta r_k - 2 a t_k + C,\qquad
    f_k r_k + \gamma |v_{xy}| t_k + \gamma v_z h_k = \beta f_k + \delta r_k
        + \gamma|v_{xy}| a - P

(the known offsets' columns dropped; the measured values are centred first, which only
re-references δ and β). It is exact on noise-free data, and ``c = √(C − a² + β²)``.

On one frame these data fix the emitter only weakly (on ``turn`` at 0 dB the nuisance CRLB of
the first frame is 16 m with δ unknown and 95 m with both, against 1.06 m with both known).
With noise ``C − a² + β²`` often comes out negative, which puts the start on the track's
vertical plane: a saddle of the frame's likelihood when both offsets are unknown, whose
minimum lies metres off the plane along a valley so flat (a χ² drop of 0.3 over 10 m at
20 dB) that the iterated update's saddle escape does not reach it (it failed on 58 of 200
trials of ``turn`` at 20 dB). So :func:`profile_scan` also searches the cross-track distance
on a grid with the nuisance values profiled out (:func:`profiled_errors`), and the lower of the
two points starts (:func:`straight_frame_starts`), with its mirror image (MATH §7). The first
update then iterates to the frame's maximum likelihood (MATH §10).

**The height unknown** (MATH §7, §8). A straight track leaves the emitter on a circle about
it: the data fix its along-track coordinate and its distance ``R`` from the track, not the
angle. :func:`circle_starts` finds ``(a, R)`` as above with the emitter assumed at the UAV's
own (mean) height, where the horizontal cross-track distance is ``R`` itself, and puts starts
on the circle's lower half, at the depressions :data:`START_DEPRESSIONS_DEG` below the UAV on
both sides of the track (the emitter is below the UAV, MATH §7); the frames after a second
heading decide among them (:mod:`estimators.sequential.ekf`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.convergence import EstimationFailure
from estimators.frame_model import FrameModel
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sequential.nuisance_states import NuisanceFrame, profile_nuisance
from scenarios.geometry import StraightTrack

FloatArray = NDArray[np.float64]

SCAN_POINTS = 64
"""Cross-track grid intervals of :func:`profile_scan`."""

SCAN_STEPS = 12
"""Gauss-Newton steps in the along-track coordinate at each point of :func:`profile_scan`."""

START_DEPRESSIONS_DEG = (10.0, 30.0, 50.0, 70.0)
"""Angles below the horizontal through the track of the 3-D starts on the ambiguity circle
(:func:`circle_starts`), on each side."""


def _track_frame(frame: NuisanceFrame) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """``(origin, along, normal, |v_xy|)`` of a straight frame (module text). Raises
    :class:`EstimationFailure` without horizontal motion."""
    velocity = frame.velocity_mps[0]
    speed = float(np.hypot(velocity[0], velocity[1]))
    if not speed > 0.0:
        raise EstimationFailure("the first frame has no horizontal motion to start from")
    along = velocity[:2] / speed
    normal = np.array([-along[1], along[0]])
    return frame.position_m[:, :2].mean(axis=0), along, normal, speed


def closed_form_point(frame: NuisanceFrame) -> FloatArray:
    """The left point ``o + a d + c n`` of the linear least squares of the module text
    (``c = 0`` when ``C − a² + β² ≤ 0``); exact on noise-free data."""
    origin, along, normal, speed = _track_frame(frame)
    position, velocity = frame.position_m, frame.velocity_mps[0]
    t = (position[:, :2] - origin) @ along
    h = position[:, 2] - frame.emitter_height_m
    k = frame.n_samples
    f, r = frame.measured[:k], frame.measured[k:]
    carrier = "carrier_offset_hz" in frame.names
    emission = "emission_time_s" in frame.names
    f = f - f.mean() if carrier else f  # re-references δ
    r = r - r.mean() if emission else r  # re-references β
    gamma, sigma_f, sigma_r = frame.gamma_per_m, frame.sigma[0], frame.sigma[k]
    one, zero = np.ones(k), np.zeros(k)
    # columns (β, δ, a, C, P); the Doppler·range rows in units of σ_f, the ranges' of 2σ_r
    doppler = np.column_stack([f, r, gamma * speed * one, zero, -one]) / sigma_f
    ranges = np.column_stack([2.0 * r, zero, -2.0 * t, one, zero]) / (2.0 * sigma_r)
    lhs = np.concatenate(
        [
            (f * r + gamma * speed * t + gamma * velocity[2] * h) / sigma_f,
            (r**2 - t**2 - h**2) / (2.0 * sigma_r),
        ]
    )
    keep = [emission, carrier, True, True, carrier and emission]
    rows = np.vstack([doppler, ranges])[:, keep]
    norms = np.linalg.norm(rows, axis=0)
    norms[norms == 0.0] = 1.0
    solution = np.linalg.lstsq(rows / norms, lhs, rcond=None)[0] / norms
    names = [
        name for name, kept in zip(("beta", "delta", "a", "C", "P"), keep, strict=True) if kept
    ]
    u = dict(zip(names, solution.tolist(), strict=True))
    beta, a = u.get("beta", 0.0), u["a"]
    cross_sq = u["C"] - a * a + beta * beta
    cross = math.sqrt(cross_sq) if cross_sq > 0.0 else 0.0
    return origin + a * along + cross * normal


def profiled_errors(frame: NuisanceFrame, points_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(e, E_s)`` at emitter positions ``(M, 2)`` with the nuisance values profiled out
    (:func:`~estimators.sequential.nuisance_states.profile_nuisance`): the whitened residuals and
    their derivative in ``(x, y)``, projected off the nuisance columns (centred per affected
    modality: one σ each), shapes ``(M, 2K)`` and ``(M, 2K, 2)``."""
    points = np.asarray(points_m, dtype=float)
    predicted, jacobian = frame.base.predicted_and_jacobian(points)
    k = frame.n_samples
    # rows as (modality, sample): a modality's offset profiled out is a mean over its samples,
    # both modalities at once when both offsets are unknown
    residual = (predicted - frame.measured).reshape(*predicted.shape[:-1], 2, k)
    derivative = jacobian.reshape(*predicted.shape[:-1], 2, k, 2)
    rows = [0 if name == "carrier_offset_hz" else 1 for name in frame.names]
    modality = slice(None) if len(rows) == 2 else rows[0]
    residual[..., modality, :] -= residual[..., modality, :].mean(axis=-1, keepdims=True)
    derivative[..., modality, :, :] -= derivative[..., modality, :, :].mean(axis=-2, keepdims=True)
    residual, jacobian = residual.reshape(predicted.shape), derivative.reshape(jacobian.shape)
    return residual / frame.sigma, jacobian / frame.sigma[:, None]


def profiled_along(
    frame: NuisanceFrame, points_m: ArrayLike, direction: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """``(e, E_s d)`` of :func:`profiled_errors` at ``(M, 2)`` points with the derivative taken
    along one unit direction ``d`` only (what :func:`profile_scan`'s steps need), from the
    forward model's components (:meth:`~estimators.frame_model.FrameModel.components`): shapes
    ``(M, 2K)`` each."""
    d = np.asarray(direction, dtype=float)
    doppler, ranges = frame.base.components(np.asarray(points_m, dtype=float), 1)
    k = frame.n_samples
    both = np.empty((2, *doppler.shape[1:-1], 2 * k))  # e, then E_s d, before centring
    np.subtract(doppler[0], frame.measured[:k], out=both[0, ..., :k])
    np.subtract(ranges[0], frame.measured[k:], out=both[0, ..., k:])
    np.add(doppler[1] * d[0], doppler[2] * d[1], out=both[1, ..., :k])
    np.add(ranges[1] * d[0], ranges[2] * d[1], out=both[1, ..., k:])
    for name in frame.names:  # an offset profiled out: its modality's rows centred
        rows = both[..., :k] if name == "carrier_offset_hz" else both[..., k:]
        rows -= np.add.reduce(rows, axis=-1, keepdims=True) / k  # their mean
    both /= frame.sigma
    return both[0], both[1]


def profile_scan(frame: NuisanceFrame, start_m: ArrayLike) -> FloatArray:
    """The lowest point of the profiled cost ``‖e‖²`` (nuisance values profiled out) along the
    cross-track distances ``c = 2L j / SCAN_POINTS`` (``L`` the mean range at ``start_m``) on
    the frame's left, the along-track coordinate of each found by ``SCAN_STEPS``
    Gauss-Newton steps from ``start_m``'s. The Doppler's zero crossing fixes the along-track
    coordinate sharply, the cross-track distance only weakly: on one frame with both offsets
    unknown the profiled cost is nearly flat in ``c`` and its minimum may lie beyond a saddle on
    the track's vertical plane (where the closed form lands when its ``c²`` comes out
    negative). Returns ``(x, y)``."""
    origin, along, normal, _ = _track_frame(frame)
    start = np.asarray(start_m, dtype=float)
    length = frame.base.mean_range_m(start)
    c = 2.0 * length * np.linspace(0.0, 1.0, SCAN_POINTS + 1)
    a = np.full_like(c, float((start - origin) @ along))
    for _ in range(SCAN_STEPS):
        points = origin + a[:, None] * along + c[:, None] * normal
        e, derivative = profiled_along(frame, points, along)
        curvature = np.einsum("mk,mk->m", derivative, derivative)
        step = -np.einsum("mk,mk->m", derivative, e) / np.maximum(curvature, 1e-300)
        a = a + np.clip(step, -0.25 * length, 0.25 * length)
    points = origin + a[:, None] * along + c[:, None] * normal
    e, _ = profiled_along(frame, points, along)  # the residuals alone (a cheap derivative)
    chi2 = np.einsum("mk,mk->m", e, e)
    chi2[~np.isfinite(chi2)] = np.inf
    return points[int(np.argmin(chi2))]


def straight_frame_starts(frame: NuisanceFrame) -> FloatArray:
    """Starting states ``(n_candidates, n)`` on one straight frame (module text): of the
    closed form's point and :func:`profile_scan`'s, the one of lower profiled cost, then its
    mirror image across the track (none on the track), each with the profiled nuisance values
    (:func:`~estimators.sequential.nuisance_states.profile_nuisance`) in the frame's state.
    Raises :class:`EstimationFailure` without horizontal motion."""
    origin, _, normal, _ = _track_frame(frame)
    closed = closed_form_point(frame)
    points = np.array([closed, profile_scan(frame, closed)])
    e, _ = profiled_along(frame, points, normal)
    chi2 = np.einsum("mk,mk->m", e, e)
    best = points[1] if chi2[1] < chi2[0] else points[0]  # ties: the exact closed form
    offset = best - origin
    cross = float(offset @ normal)
    mirrored = best - 2.0 * cross * normal
    pair = [best, mirrored] if cross != 0.0 else [best]
    return np.array([frame.state(p, profile_nuisance([frame], p)) for p in pair])


def height_starts(frames: Sequence[FrameModel | NuisanceFrame]) -> FloatArray:
    """:func:`circle_starts` of the first of ``frames`` (3-D models), once they leave one
    straight track; raises :class:`EstimationFailure` while they are on one (the height is not
    fixed: :data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`, MATH §7)."""
    track = StraightTrack.of_frame(frames[0])
    for frame in frames[1:]:
        track = None if track is None else track.extended(frame)
    if track is not None:
        raise EstimationFailure(STRAIGHT_TRACK_HEIGHT)
    return circle_starts(frames[0])


def circle_starts(frame: FrameModel | NuisanceFrame) -> FloatArray:
    """Starting states ``(n_starts, n)`` with the height unknown (module text): the points of
    the first straight frame's ambiguity circle at :data:`START_DEPRESSIONS_DEG` below the
    UAV on both sides of the track, with the profiled nuisance values (if any) in the frame's
    state. ``frame`` is a 3-D model (``dimension == 3``). Raises :class:`EstimationFailure`
    without horizontal motion."""
    nuisance = isinstance(frame, NuisanceFrame)
    base = frame.base if nuisance else frame
    height = float(np.mean(base.position_m[:, 2]))
    plane = NuisanceFrame(
        replace(base, dimension=2, emitter_height_m=height),
        frame.names if nuisance else (),
        frame.speed_of_light_mps if nuisance else math.nan,
    )
    origin, along, normal, _ = _track_frame(plane)
    best = straight_frame_starts(plane)[0]  # (x, y, physical nuisance values) at the UAV height
    offset = best[:2] - origin
    a, radius = float(offset @ along), abs(float(offset @ normal))
    starts = []
    for side in (1.0, -1.0):
        for depression in np.radians(START_DEPRESSIONS_DEG):
            horizontal = origin + a * along + side * radius * math.cos(depression) * normal
            position = np.append(horizontal, height - radius * math.sin(depression))
            starts.append(frame.state(position, best[2:]) if nuisance else position)
    return np.array(starts)
