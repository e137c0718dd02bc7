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
:class:`StraightTrack` is that line kept frame by frame, and :class:`TrackSoFar` what the mirror
rule (:func:`estimators.base.finalize_estimate`) reads of the samples, kept frame by frame, so
that a streaming estimator can apply the rule without the samples
(:func:`estimators.base.finalize_from_track`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.fields import vector_text

FloatArray = NDArray[np.float64]

KINEMATIC_RTOL = 1e-6
"""Relative tolerance of :func:`check_straight_frames` (that of ``emitterbench fly``)."""

_ROUNDING = 16 * np.finfo(float).eps
_TINY = float(np.finfo(float).tiny)
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
    return straight_track_lines(position_m, velocity_mps, (rtol,))[0]


def straight_track_lines(
    position_m: ArrayLike, velocity_mps: ArrayLike, rtols: tuple[float, ...]
) -> list[tuple[FloatArray, FloatArray] | None]:
    """:func:`straight_track_line` at each relative tolerance of ``rtols``, from one
    decomposition of the samples."""
    xy = np.asarray(position_m, dtype=float)[:, :2]
    v_xy = np.asarray(velocity_mps, dtype=float)[:, :2]
    origin = np.add.reduce(xy, axis=0) / len(xy)  # their mean
    spread = xy - origin
    # principal direction of the samples, else of the velocities (a single sample)
    basis = spread if spread.any() else v_xy
    if not basis.any():
        return [None] * len(rtols)
    _, singular, vt = np.linalg.svd(basis, full_matrices=False)
    direction = vt[0]
    scale = max(singular[0], _TINY)
    speed = np.sqrt(v_xy[:, 0] * v_xy[:, 0] + v_xy[:, 1] * v_xy[:, 1])
    cross = np.abs(v_xy[:, 0] * direction[1] - v_xy[:, 1] * direction[0])
    lines: list[tuple[FloatArray, FloatArray] | None] = []
    for rtol in rtols:
        straight = not (len(singular) > 1 and singular[1] > rtol * scale)
        lines.append((origin, direction) if straight and not (cross > rtol * speed).any() else None)
    return lines


def flight_plane(
    position_m: ArrayLike, velocity_mps: ArrayLike, *, rtol: float = 1e-9
) -> tuple[FloatArray, FloatArray] | None:
    """The plane every sample lies in and flies in, when the flight is no single line, else
    None (MATH §7, the emitter's height unknown).

    Returns ``(origin_m, normal)``, a point of the plane (the samples' mean) and its unit
    normal, both (3,): the smallest right singular vector of the samples' offsets from their
    mean stacked over their velocities times the flight's duration, when its singular value is
    at most ``rtol`` times the largest and the middle one is not (a line, or one point, has no
    one plane: None). A level flight's plane is horizontal; any two straight legs span one.
    The reflection through it leaves every sample and velocity, hence every measurement, as
    they are.
    """
    position = np.asarray(position_m, dtype=float).reshape(-1, 3)
    velocity = np.asarray(velocity_mps, dtype=float).reshape(-1, 3)
    origin = np.add.reduce(position, axis=0) / len(position)
    spread = position - origin
    speed = float(np.max(np.sqrt(np.einsum("ij,ij->i", velocity, velocity)), initial=0.0))
    extent = float(np.max(np.sqrt(np.einsum("ij,ij->i", spread, spread)), initial=0.0))
    duration = extent / speed if speed > 0.0 else 1.0
    _, singular, vt = np.linalg.svd(np.vstack([spread, velocity * duration]))
    if singular[0] <= _TINY or singular[1] <= rtol * singular[0]:
        return None
    if singular[2] > rtol * singular[0]:
        return None
    return origin, vt[2]


def reflect_through_plane(
    points_m: ArrayLike, origin_m: ArrayLike, normal: ArrayLike
) -> FloatArray:
    """Reflect points (..., 3) through the plane through ``origin_m`` of unit ``normal``."""
    points = np.asarray(points_m, dtype=float)
    normal = np.asarray(normal, dtype=float)
    height = (points - np.asarray(origin_m, dtype=float)) @ normal
    return points - 2.0 * height[..., None] * normal


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


@dataclass(frozen=True, slots=True, eq=False)
class StraightTrack:
    """The horizontal line every sample so far lies on and flies along (MATH §7).

    Build it from samples (:meth:`of_samples`, :meth:`of_frame`: None when they do not lie on
    one line) and extend it frame by frame (:meth:`extended`: None once a frame leaves it).
    Checking a new frame costs the same at frame 2 as at frame 1000: only the first and last
    sample positions and one velocity are kept.

    Attributes
    ----------
    origin_m, direction : (2,)
        The line, as :func:`straight_track_line` gives it for the samples it was built from: a
        point of it (their mean horizontal position) and its unit direction. Extending the
        track keeps them (the new samples lie on the line).
    ends_m : (2, 3)
        The first and the last sample positions so far.
    velocity_mps : (3,)
        The first sample's velocity.
    """

    origin_m: FloatArray
    direction: FloatArray
    ends_m: FloatArray
    velocity_mps: FloatArray

    def __post_init__(self) -> None:
        for name in ("origin_m", "direction", "ends_m", "velocity_mps"):
            value = np.array(getattr(self, name), dtype=float)
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @classmethod
    def of_samples(cls, position_m: ArrayLike, velocity_mps: ArrayLike) -> StraightTrack | None:
        """The line of samples (N, 3) and their velocities (N, 3), or None (MATH §7)."""
        position = np.asarray(position_m, dtype=float).reshape(-1, 3)
        velocity = np.asarray(velocity_mps, dtype=float).reshape(-1, 3)
        line = straight_track_line(position, velocity)
        if line is None:
            return None
        return cls(
            origin_m=line[0],
            direction=line[1],
            ends_m=np.array(position[[0, -1]], dtype=float),
            velocity_mps=np.array(velocity[0], dtype=float),
        )

    @classmethod
    def of_frame(cls, frame: Any) -> StraightTrack | None:
        """:meth:`of_samples` of a frame (anything with ``position_m`` and ``velocity_mps``)."""
        return cls.of_samples(frame.position_m, frame.velocity_mps)

    def extended(self, frame: Any) -> StraightTrack | None:
        """This track if ``frame`` continues it, else None (the frame turns off it)."""
        positions = np.vstack([self.ends_m, frame.position_m])
        velocities = np.vstack([self.velocity_mps, self.velocity_mps, frame.velocity_mps])
        if straight_track_line(positions, velocities) is None:
            return None
        ends = np.array([self.ends_m[0], frame.position_m[-1]], dtype=float)
        return StraightTrack(
            origin_m=self.origin_m,
            direction=self.direction,
            ends_m=ends,
            velocity_mps=self.velocity_mps,
        )

    def line(self) -> tuple[FloatArray, FloatArray]:
        """``(origin_m, direction)`` of the line, both (2,)."""
        return self.origin_m, self.direction

    def mirror_point(self, points_m: ArrayLike) -> FloatArray:
        """Reflection of points (..., 2) across the track (MATH §7)."""
        return mirror_across_line(points_m, self.origin_m, self.direction)

    def mirror_covariance(self, covariance_m2: ArrayLike) -> FloatArray:
        """``M C Mᵀ`` with the reflection ``M = 2ddᵀ − I`` (a covariance or an information)."""
        reflection = 2.0 * np.outer(self.direction, self.direction) - np.eye(2)
        return reflection @ np.asarray(covariance_m2, dtype=float) @ reflection.T

    def cross_track_m(self, points_m: ArrayLike) -> FloatArray:
        """Signed distance of points (..., 2) from the track, positive on its left."""
        return cross_track_m(points_m, self.origin_m, self.direction)


@dataclass(frozen=True, slots=True, eq=False)
class TrackSoFar:
    """What the mirror rule of MATH §7 reads of the samples so far, kept frame by frame.

    :func:`estimators.base.finalize_estimate` reads three things of the samples: the straight
    track they lie on, if any (each candidate's mirror image across it is added), their
    mean horizontal position (candidates closer than ``1e-9`` of their largest distance from it
    are one point) and, for 3-D candidates, their highest height. A streaming estimator keeps this value in its state (:meth:`of` on the
    first frame, :meth:`extended` on each next one) and finishes its estimate with
    :func:`estimators.base.finalize_from_track`, without the samples.

    Attributes
    ----------
    n_samples : int
    centre_m : (2,)
        The samples' mean horizontal position.
    straight : StraightTrack or None
        The line every sample so far lies on and flies along; None once the UAV turned.
    highest_m : float
        The samples' highest height: with the emitter's height estimated, a candidate above it
        is not an answer (the emitter is below the UAV, MATH §7).
    """

    n_samples: int
    centre_m: FloatArray
    straight: StraightTrack | None
    highest_m: float

    def __post_init__(self) -> None:
        centre = np.array(self.centre_m, dtype=float).reshape(2)
        centre.flags.writeable = False
        object.__setattr__(self, "centre_m", centre)

    @classmethod
    def of(cls, samples: Any) -> TrackSoFar:
        """The track of ``samples`` (anything with ``position_m`` and ``velocity_mps``)."""
        position = np.asarray(samples.position_m, dtype=float).reshape(-1, 3)
        return cls(
            n_samples=len(position),
            centre_m=position[:, :2].mean(axis=0),
            straight=StraightTrack.of_samples(position, samples.velocity_mps),
            highest_m=float(position[:, 2].max()),
        )

    def extended(self, frame: Any) -> TrackSoFar:
        """The track after one more ``frame`` of samples."""
        position = np.asarray(frame.position_m, dtype=float).reshape(-1, 3)
        n_samples = self.n_samples + len(position)
        step = (position[:, :2].sum(axis=0) - len(position) * self.centre_m) / n_samples
        return TrackSoFar(
            n_samples=n_samples,
            centre_m=self.centre_m + step,
            straight=None if self.straight is None else self.straight.extended(frame),
            highest_m=max(self.highest_m, float(position[:, 2].max())),
        )
