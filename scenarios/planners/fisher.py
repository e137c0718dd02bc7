r"""The Fisher-optimal heading of the next frame (MATH §13, beyond the paper).

With the information of the frames flown, ``J_past``, and that of the next frame flown at
heading ``ψ`` and fixed speed ``A``, ``J_next(ψ)``, both at the current estimate ``ŝ`` (MATH §8)

.. math::

    J(\psi) = J_{past} + J_{next}(\psi),\qquad
    \psi^* = \arg\min_\psi\ \operatorname{tr} J(\psi)^{-1}\ \ \text{(A-optimal)}
    \quad\text{or}\quad -\log\det J(\psi)\ \ \text{(D-optimal)}.

``J = Σ_k ∇h_k∇h_kᵀ/σ²`` over the samples and modalities (ToA and Doppler by default), from
:mod:`scenarios.fisher` with the σ's of the data. The next frame's samples are
``p_{K+1} + jΔ u(ψ)``, ``j = 0 … K−1``, ``u(ψ) = A(cos ψ, sin ψ, 0)``, starting at
``p_{K+1} = p_K + Δ v_old`` (the flight's kinematics).

With two mirror candidates (MATH §7) the criterion is evaluated at each and the worst
(``aggregate="worst"``, default) or the mean (``"mean"``) is minimised: the heading must be
good wherever the emitter is. ``J_past`` is the information of the frames flown at each
candidate (``past="frames"``, default) or, with ``past="covariance"``, the inverse of the
estimate's covariance when one is given.

With nuisance parameters (a non-cooperative emitter, MATH §15) the next frame shares the
carrier offset and emission time of the frames flown, so ``J(ψ)`` is the information of the
union of their samples with one δ and one b (:class:`scenarios.fisher.InformationStatistics`),
not ``J_past + J_next``; for a cooperative emitter the two are the same. With
``past="covariance"`` only the 2×2 covariance is known of the past, so the next frame's
information is taken with its own δ and b (a lower bound on what it adds).

The search is vectorised over headings: ``n_headings`` equally spaced headings (the whole
circle, or the window the turn-rate limit allows), then ``refine_rounds`` rounds of 21
headings spanning ±1 step around the best, each round dividing the step by 10.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.fisher import InformationStatistics, information_statistics, regular_2x2
from scenarios.planners.base import (
    DEFAULT_MAX_SPEED_MPS,
    Plan,
    check_candidates,
    check_covariance,
    check_flight_matches,
    check_speed_limits,
    heading_rad,
    last_velocity_mps,
    level_velocity_mps,
    max_heading_change_rad,
    next_frame_start_m,
    nominal_speed_mps,
)
from scenarios.types import MODALITIES, FlightPlan, MeasurementSet

FloatArray = NDArray[np.float64]
Criterion = Literal["A", "D"]
Aggregate = Literal["worst", "mean"]
Past = Literal["frames", "covariance"]

REFINE_POINTS = 21
"""Headings per refinement round (spanning ±1 step of the previous round)."""

HEADING_TIE_RTOL = 1e-9
"""Headings whose criterion is within this (relative) of the best tie: the least turn from the
current heading wins, then the turn to the left. A straight track's mirror candidates make the
criterion symmetric about it, so the best headings come in mirror pairs of equal value, which
rounding alone would otherwise decide between."""

TURN_RESOLUTION_RAD = 1e-9
"""Turns equal to this are equal (a heading and its mirror image about the current one)."""


def next_frame_geometry(
    start_m: ArrayLike,
    headings_rad: ArrayLike,
    speed_mps: float,
    samples_per_frame: int,
    sample_interval_s: float,
) -> tuple[FloatArray, FloatArray]:
    """Positions and velocities of the next frame at each heading, each ``(n_ψ, K, 3)``."""
    headings = np.asarray(headings_rad, dtype=float).reshape(-1)
    velocity = speed_mps * np.stack(
        [np.cos(headings), np.sin(headings), np.zeros_like(headings)], axis=-1
    )
    steps = np.arange(samples_per_frame) * sample_interval_s
    position = np.asarray(start_m, dtype=float) + steps[None, :, None] * velocity[:, None, :]
    return position, np.broadcast_to(velocity[:, None, :], position.shape)


def design_criterion(information: ArrayLike, criterion: Criterion = "A") -> FloatArray:
    """``tr J⁻¹`` (``"A"``, m²) or ``−log det J`` (``"D"``) of 2×2 matrices ``(..., 2, 2)``.

    +inf where ``J`` is singular (not positive definite: :func:`scenarios.fisher.regular_2x2`
    and ``J₁₁ > 0``).
    """
    J = np.asarray(information, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    regular = regular_2x2(J) & (a > 0)
    safe = np.where(regular, det, 1.0)
    value = (a + d) / safe if criterion == "A" else -np.log(safe)
    return np.where(regular, value, np.inf)


def heading_objective(
    headings_rad: ArrayLike,
    *,
    past_information: ArrayLike | InformationStatistics,
    candidates_m: ArrayLike,
    start_m: ArrayLike,
    speed_mps: float,
    samples_per_frame: int,
    sample_interval_s: float,
    data: MeasurementSet,
    modalities: Sequence[str] = ("toa", "doppler"),
    criterion: Criterion = "A",
    aggregate: Aggregate = "worst",
) -> FloatArray:
    """The criterion of MATH §13 at each heading, aggregated over the candidates, ``(n_ψ,)``.

    ``past_information`` is ``(n_c, 2, 2)``, one ``J_past`` per candidate, or the statistics of
    the frames flown at the candidates (:func:`past_statistics`), whose nuisance parameters
    the next frame then shares (MATH §15). With a matrix the next frame's own nuisance
    parameters (``data.unknowns``) are eliminated within it.
    """
    candidates = np.asarray(candidates_m, dtype=float).reshape(-1, 2)
    position, velocity = next_frame_geometry(
        start_m, headings_rad, speed_mps, samples_per_frame, sample_interval_s
    )
    # (n_c, 1, 2) against (n_ψ, K, 3) broadcasts to (n_c, n_ψ, ...)
    upcoming = information_statistics(
        position, velocity, candidates[:, None, :], data, modalities, unknowns=data.unknowns
    )
    if isinstance(past_information, InformationStatistics):
        information = past_information.joined(upcoming).information()
    else:
        past = np.asarray(past_information, dtype=float).reshape(len(candidates), 2, 2)
        information = past[:, None] + upcoming.information()
    values = design_criterion(information, criterion)
    if aggregate == "worst":
        return values.max(axis=0)
    with np.errstate(invalid="ignore"):
        return values.mean(axis=0)


def past_statistics(
    data: MeasurementSet, candidates_m: ArrayLike, modalities: Sequence[str] = ("toa", "doppler")
) -> InformationStatistics:
    """The statistics of the information of ``data``'s samples at each candidate, one group
    of leading shape ``(n_c, 1)`` (to meet a planned frame's ``(n_c, n_ψ)``), its nuisance
    parameters ``data.unknowns`` left to be shared with the next frame (MATH §8, §15)."""
    candidates = np.asarray(candidates_m, dtype=float).reshape(-1, 2)
    return information_statistics(
        data.position_m,
        data.velocity_mps,
        candidates[:, None, :],
        data,
        modalities,
        unknowns=data.unknowns,
    )


def least_turn_argmin(values: FloatArray, headings_rad: FloatArray, centre_rad: float) -> int:
    """The index of the best value; of headings that tie (:data:`HEADING_TIE_RTOL`), the one
    turning least from ``centre_rad``, then the one turning left: a choice that the rounding of
    two mirror-symmetric values cannot change."""
    best = float(np.min(values))
    if not math.isfinite(best):
        return int(np.argmin(values))
    near = np.flatnonzero(values <= best + HEADING_TIE_RTOL * abs(best))
    turn = np.angle(np.exp(1j * (headings_rad[near] - centre_rad)))  # in (−π, π]
    size = np.round(np.abs(turn) / TURN_RESOLUTION_RAD)
    return int(near[np.lexsort((-turn, size))[0]])


def best_heading_rad(
    objective: Callable[[FloatArray], FloatArray],
    *,
    centre_rad: float,
    half_width_rad: float,
    n_headings: int,
    refine_rounds: int,
) -> tuple[float, float]:
    """Minimise ``objective(headings) -> values`` over a heading window; ``(ψ*, value)``.

    The window is the whole circle when ``half_width_rad >= π`` (``n_headings`` headings,
    step ``2π/n``), else ``centre ± half_width`` (``n_headings`` headings, both ends
    included), the best of them by :func:`least_turn_argmin`. Then ``refine_rounds`` rounds of
    :data:`REFINE_POINTS` headings over ±1 step around the best, kept inside the window, each
    round's step a tenth of the previous.
    """
    full_circle = half_width_rad >= math.pi
    if full_circle:
        step = 2 * math.pi / n_headings
        grid = centre_rad + step * np.arange(n_headings)
    else:
        grid = np.linspace(centre_rad - half_width_rad, centre_rad + half_width_rad, n_headings)
        step = 2 * half_width_rad / max(n_headings - 1, 1)
    values = objective(grid)
    best = least_turn_argmin(values, grid, centre_rad)
    heading, value = float(grid[best]), float(values[best])
    for _ in range(refine_rounds):
        local = heading + np.linspace(-step, step, REFINE_POINTS)
        if not full_circle:
            local = np.clip(local, centre_rad - half_width_rad, centre_rad + half_width_rad)
        local_values = objective(local)
        index = int(np.argmin(local_values))
        if local_values[index] <= value:
            heading, value = float(local[index]), float(local_values[index])
        step /= 10.0
    return heading, value


@dataclass(frozen=True, slots=True, kw_only=True)
class FisherPlanner:
    """The heading that minimises the next CRLB at the estimate (MATH §13; module docstring).

    Parameters
    ----------
    criterion : {"A", "D"}
        A-optimal ``tr (J_past + J_next)⁻¹`` (default) or D-optimal ``−log det``.
    aggregate : {"worst", "mean"}
        Over the estimate's candidates (the mirror pair, MATH §7).
    past : {"frames", "covariance"}
        ``J_past`` from the frames flown, or the inverse of the estimate's covariance (when
        given; otherwise from the frames).
    modalities : tuple of str
        Modalities of the information (default ToA and Doppler).
    n_headings : int
        Headings of the first grid (default 360: 1° over the whole circle).
    refine_rounds : int
        Local refinement rounds (default 2: a final resolution of 0.01° on the default grid).
    speed_mps : float or None
        The speed ``A``; None: the first frame's speed.
    max_speed_mps : float
        V_max (default 20 m/s).
    max_turn_rate_dps : float or None
        Optional turn-rate limit: the search is restricted to the reachable headings.
    """

    name: ClassVar[str] = "fisher"

    criterion: Criterion = "A"
    aggregate: Aggregate = "worst"
    past: Past = "frames"
    modalities: tuple[str, ...] = ("toa", "doppler")
    n_headings: int = 360
    refine_rounds: int = 2
    speed_mps: float | None = None
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS
    max_turn_rate_dps: float | None = None

    def __post_init__(self) -> None:
        if self.criterion not in ("A", "D"):
            raise ValueError(f"criterion: expected 'A' or 'D', got {self.criterion!r}")
        if self.aggregate not in ("worst", "mean"):
            raise ValueError(f"aggregate: expected 'worst' or 'mean', got {self.aggregate!r}")
        if self.past not in ("frames", "covariance"):
            raise ValueError(f"past: expected 'frames' or 'covariance', got {self.past!r}")
        modalities = (self.modalities,) if isinstance(self.modalities, str) else self.modalities
        if not modalities or any(m not in MODALITIES for m in modalities):
            raise ValueError(
                f"modalities: expected a non-empty subset of {MODALITIES}, got {self.modalities!r}"
            )
        object.__setattr__(self, "modalities", tuple(modalities))
        for name, minimum in (("n_headings", 3), ("refine_rounds", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < minimum:
                raise ValueError(f"{name}: expected a whole number >= {minimum}, got {value!r}")
        check_speed_limits(
            max_speed_mps=self.max_speed_mps,
            speed_mps=self.speed_mps,
            max_turn_rate_dps=self.max_turn_rate_dps,
        )

    def plan(
        self,
        flight: FlightPlan,
        candidates_m: ArrayLike,
        data: MeasurementSet,
        *,
        covariance_m2: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> Plan:
        """The next frame's level velocity at speed ``min(A, V_max)`` and heading ``ψ*``.

        Raises
        ------
        ValueError
            A zero nominal speed, a missing σ, malformed candidates, or a candidate at a
            sample position (the range is zero and the information undefined).
        """
        check_flight_matches(flight, data)
        candidates = check_candidates(candidates_m)
        covariance = check_covariance(covariance_m2)
        speed = min(nominal_speed_mps(flight, self.speed_mps), self.max_speed_mps)
        start = next_frame_start_m(flight)
        ranges = model.slant_range_m(data.position_m, candidates[:, None, :], data.emitter_height_m)
        if float(np.min(ranges)) <= 1e-9 * max(float(np.max(ranges)), 1.0):
            raise ValueError(
                "candidates_m: a candidate coincides with a UAV sample position, where the "
                "information is undefined (zero range); check the estimate"
            )
        if (
            self.past == "covariance"
            and covariance is not None
            and np.all(np.linalg.eigvalsh(covariance) > 0)
        ):
            past: FloatArray | InformationStatistics = np.broadcast_to(
                np.linalg.inv(covariance), (len(candidates), 2, 2)
            )
            source = "covariance"
        else:
            past = past_statistics(data, candidates, self.modalities)
            source = "frames"

        def objective(headings: FloatArray) -> FloatArray:
            return heading_objective(
                headings,
                past_information=past,
                candidates_m=candidates,
                start_m=start,
                speed_mps=speed,
                samples_per_frame=flight.samples_per_frame,
                sample_interval_s=flight.sample_interval_s,
                data=data,
                modalities=self.modalities,
                criterion=self.criterion,
                aggregate=self.aggregate,
            )

        old = last_velocity_mps(flight)
        old_heading = heading_rad(old)
        window = max_heading_change_rad(flight, self.max_turn_rate_dps)
        if not math.isfinite(old_heading):
            old_heading, window = 0.0, math.pi  # hovering: every heading is reachable
        heading, value = best_heading_rad(
            objective,
            centre_rad=old_heading,
            half_width_rad=window,
            n_headings=int(self.n_headings),
            refine_rounds=int(self.refine_rounds),
        )
        if not math.isfinite(value):
            return Plan(
                planner=self.name,
                velocity_mps=old,
                message="held the last velocity: the information is singular at every heading",
                diagnostics={"objective": value, "past": source},
            )
        turn = math.degrees(float((heading - old_heading + math.pi) % (2 * math.pi) - math.pi))
        return Plan(
            planner=self.name,
            velocity_mps=level_velocity_mps(speed, heading),
            message=f"{self.criterion}-optimal heading, {self.aggregate} over "
            f"{len(candidates)} candidate(s)",
            diagnostics={
                "objective": value,
                "heading_deg": math.degrees(heading),
                "turn_deg": turn,
                "past": source,
                "speed_mps": speed,
            },
        )
