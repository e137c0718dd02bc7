r"""The closed-form CLS of MATH §3-§6 for a whole :class:`~scenarios.types.MeasurementBatch`.

The rows of :mod:`estimators.closed_form.cls_rows`, the two-stage whitening of MATH §6 and the GTRS
of MATH §5 (:mod:`estimators.closed_form.gtrs_batch`) evaluated for every trial at once, then the
hard-case pair left of the last heading first (:func:`solve_chunk`) and the mirror rule of
:func:`~estimators.base.finalize_estimate` (:func:`estimators.batch.finalize_columns`).

Layout: the trials share one geometry, so every per-sample quantity is an array of shape
``(K, n)`` (sample × trial) and every per-trial scalar one of shape ``(n,)``; trials are
processed in chunks of about :data:`CHUNK_ELEMENTS` samples × trials (:func:`solve_trials`).
:func:`estimate_columns` finishes a batch as columns, :func:`estimate_trial` one trial, the
batch of one, as its :class:`~estimators.base.Estimate`.

Rows in the local frame of each trial (``L`` its scale, ``X`` the sample offsets from the
frame's origin in metres, ``r`` the ToA ranges, ``f`` the Doppler shifts):

- Doppler (MATH §3): ``[v̂ᵀ, 0] r = P/L`` with ``P = (v·(X, z) − v_z z_s + r f/γ)/|v_xy|``;
- ToA (MATH §4): ``[−2X/L, −2Y/L, 1] r = Q/L²`` with ``Q = r² − |X|² − (z − z_s)²``;
- whitening (MATH §6) with ``λ₁₁ = √N/(γ|v|)``, ``λ₂₁ = 2 r f σ_r²/√N``,
  ``λ₂₂ = √(4r²σ_r² + 2σ_r⁴ − λ₂₁²)`` and ``N = r²σ_f² + f²σ_r² + σ_f²σ_r²`` (metres; the
  per-sample 2×2 Cholesky factor of the pair's covariance, in the local frame ``λ₁₁/L`` and
  ``λ/L²``): Doppler ``L[v̂ᵀ, 0]/λ₁₁ · r = P/λ₁₁``, ToA
  ``[−L(2X + c v̂)/λ₂₂, L²/λ₂₂] r = (Q − λ₂₁ P/λ₁₁)/λ₂₂`` with ``c = λ₂₁/λ₁₁``.

With an unknown carrier offset δ (MATH §15) the Doppler rows get δ's column
``r/(γ|v_xy|)`` (whitened with them, so the ToA rows get ``−c·r/(γ|v_xy|)/λ₂₂``), which the GTRS
projects out (:class:`~estimators.closed_form.gtrs_batch.NormalEquations`).

This is the only implementation of the closed forms: one trial is the batch of one
(:func:`estimate_trial`). A trial whose GTRS has no finite minimiser is a failed estimate; a
tie with no side prior draws ``rng.integers`` from the trial's own generator, in trial order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate
from estimators.batch import BatchEstimates, check_rngs
from estimators.closed_form.cls_rows import horizontal_speed_mps
from estimators.closed_form.gtrs_batch import GtrsBatch, RowBlock, solve_gtrs_batch
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT, finalize_columns
from scenarios import measurement_model as model
from scenarios.geometry import flight_plane, straight_track_lines
from scenarios.nuisance import position_dimension
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
SolveOne = Callable[[MeasurementSet, np.random.Generator | None], Estimate]
"""``estimate(data, rng=rng)`` of one trial, after the checks the batch made once."""

CHUNK_ELEMENTS = 131_072
"""Samples × trials per chunk of the vectorised solve: large enough that numpy's per-call
overhead is small, small enough that the working arrays stay in cache."""
MAX_CHUNK = 16_384
"""Trials per chunk at most."""
MAX_CANDIDATES = 4
"""Candidate slots per trial: a hard-case pair and, on a straight track, their mirrors."""

HARD_CASE_MESSAGE = "hard case: mirror pair (MATH §5)"
FAILED_MESSAGE = "CLS: the GTRS has no finite minimiser (MATH §5); check the data for NaN"

COLLINEAR_RTOL = 1e-13
"""Samples on one line and flying along it to this relative precision: every row of the CLS
then annihilates one vector (MATH §5), and its rank is 2 without a null-vector check."""


@dataclass(frozen=True, slots=True, eq=False)
class SharedGeometry:
    """What every trial of a batch shares: the samples used and their constants."""

    used: MeasurementSet
    columns: NDArray[np.int64]
    origin: FloatArray
    spread_sq: float
    offset: FloatArray  # (K, 2) X, Y
    z: FloatArray  # (K,)
    unit: FloatArray  # (K, 2) v̂
    speed: FloatArray  # (K,)
    velocity: FloatArray  # (K, 3)
    frame_starts: NDArray[np.int64]
    frame_counts: FloatArray
    line: tuple[FloatArray, FloatArray] | None
    collinear: bool
    mean_xy: FloatArray
    column: dict[str, FloatArray]
    offset_unknown: bool
    dimension: int = 2
    plane: tuple[FloatArray, FloatArray] | None = None
    """In 3-D, the plane the flight lies and flies in (a level turn, two legs), or None: the
    mirror rule adds each candidate's reflection through it (MATH §7)."""

    @classmethod
    def of(
        cls,
        batch: MeasurementBatch | MeasurementSet,
        frames: str,
        *,
        origin_m: FloatArray | None = None,
        dimension: int = 2,
    ) -> SharedGeometry:
        """The samples of ``frames`` of a batch's geometry, or of one trial's; the local
        frame's origin is their mean horizontal position unless ``origin_m`` is given.

        ``dimension`` 3: the emitter's height a coordinate (the rows of MATH §3-§5 in three
        coordinates; ``cls`` asks for it when the data declare the height unknown); 2: the
        height the data give, ``emitter_height_m`` (with the height unknown, the height a
        caller assumes: the starts of ``ml`` at assumed heights)."""
        geometry = batch.geometry if isinstance(batch, MeasurementBatch) else batch
        used = geometry.select_frames(frames)
        if frames == "last":
            columns = np.flatnonzero(geometry.frame == geometry.frame[-1])
        else:
            columns = np.arange(geometry.n_samples)
        position = used.position_m
        k = len(position)
        mean_xy = np.add.reduce(position[:, :2], axis=0) / k  # (np.mean's bits)
        origin = mean_xy if origin_m is None else np.asarray(origin_m)
        offset = position[:, :2] - origin
        spread_sq = float(np.add.reduce(np.add.reduce(offset * offset, axis=1)) / k)
        velocity = used.velocity_mps
        speed = horizontal_speed_mps(velocity)
        # frames never decrease (MeasurementSet checks it): each starts where it changes
        frame = used.frame
        change = np.ones(k, dtype=bool)
        np.not_equal(frame[1:], frame[:-1], out=change[1:])
        bounds = np.append(np.flatnonzero(change), k)
        starts, counts = bounds[:-1], bounds[1:] - bounds[:-1]
        unit = velocity[:, :2] / speed[:, None]
        # with the height a coordinate (MATH §5) the rows' frame has its z at 0: the data's
        # emitter_height_m (what an estimator ignoring the height assumes) is not read
        dz = position[:, 2] - (used.emitter_height_m if dimension == 2 else 0.0)
        names = ("x", "y", "-2x", "-2y", "ux", "uy", "-ux", "-uy", "vx", "vy", "vz", "dz", "gv")
        names += ("-2z", "uz", "-uz")
        per_sample = np.empty((len(names), k, 1))  # (K, 1) columns that broadcast against (K, n)
        per_sample[0:2, :, 0] = offset.T
        per_sample[2:4, :, 0] = -2.0 * offset.T
        per_sample[4:6, :, 0] = unit.T
        per_sample[6:8, :, 0] = -unit.T
        per_sample[8:11, :, 0] = velocity.T
        per_sample[11, :, 0] = dz
        per_sample[12, :, 0] = used.gamma_per_m * speed
        per_sample[13, :, 0] = -2.0 * position[:, 2]
        per_sample[14, :, 0] = velocity[:, 2] / speed  # v_z/|v_xy|: the height's Doppler column
        per_sample[15, :, 0] = -per_sample[14, :, 0]
        # collinear to COLLINEAR_RTOL implies straight to the default 1e-9
        line, collinear_line = straight_track_lines(position, velocity, (1e-9, COLLINEAR_RTOL))
        return cls(
            used=used,
            columns=columns,
            origin=origin,
            spread_sq=spread_sq,
            offset=offset,
            z=position[:, 2].copy(),
            unit=unit,
            speed=speed,
            velocity=velocity,
            frame_starts=starts,
            frame_counts=counts.astype(float),
            line=line,
            collinear=line is not None and collinear_line is not None,
            mean_xy=mean_xy,
            column=dict(zip(names, per_sample, strict=True)),
            offset_unknown="carrier_offset_hz" in used.unknowns,
            dimension=dimension,
            plane=flight_plane(position, velocity) if dimension == 3 else None,
        )

    def frame_sums(self, values: FloatArray) -> FloatArray:
        """Sums over the samples of each frame of ``values`` (K, n): shape (F, n)."""
        return np.add.reduceat(values, self.frame_starts, axis=0)


@dataclass(frozen=True, slots=True, eq=False)
class SolvedTrials:
    """What the vectorised CLS decides for each of ``n`` trials, before the tie-break draws.

    ``candidates`` (n, 4, d) holds trial ``i``'s kept candidates in its first
    ``n_candidates[i]`` slots; ``chosen`` is the returned one unless ``draw`` (a tie with no
    prior: ``rng.integers(n_candidates)`` decides); ``failed`` trials have no finite answer,
    ``degenerate`` ones failed because one straight track cannot fix the height (d = 3).
    ``carrier_offset_hz`` is δ at the first candidate when it is unknown (MATH §15).
    """

    candidates: FloatArray
    n_candidates: NDArray[np.int64]
    chosen: NDArray[np.int64]
    draw: NDArray[np.bool_]
    ambiguous: NDArray[np.bool_]
    failed: NDArray[np.bool_]
    hard_case: NDArray[np.bool_]
    multiplier: FloatArray
    rank: NDArray[np.int64]
    carrier_offset_hz: FloatArray | None
    degenerate: NDArray[np.bool_]


def solve_trials(
    shared: SharedGeometry,
    rows: str,
    ranges: FloatArray,
    doppler: FloatArray,
    side_prior_m: tuple[float, float] | None,
) -> SolvedTrials:
    """The CLS of every trial: ``ranges`` and ``doppler`` (n, K) on the samples used, in
    chunks of about :data:`CHUNK_ELEMENTS` (one chunk for one trial)."""
    n = len(ranges)
    k = shared.used.n_samples
    chunk = n if n == 1 else int(np.clip(CHUNK_ELEMENTS // max(k, 1), 256, MAX_CHUNK))
    parts = [
        _solve_part(
            shared,
            rows,
            ranges[start : start + chunk],
            doppler[start : start + chunk],
            side_prior_m,
        )
        for start in range(0, n, chunk)
    ]
    if len(parts) == 1:
        return parts[0]
    return SolvedTrials(
        *(
            None
            if getattr(parts[0], name) is None
            else np.concatenate([getattr(part, name) for part in parts])
            for name in SolvedTrials.__slots__
        )
    )


def _solve_part(
    shared: SharedGeometry,
    rows: str,
    ranges: FloatArray,
    doppler: FloatArray,
    side_prior_m: tuple[float, float] | None,
) -> SolvedTrials:
    """:func:`solve_trials` of one chunk (n, K)."""
    n = len(ranges)
    d = shared.dimension
    if d == 3 and shared.line is not None:  # a circle of minimisers (MATH §7): no solve
        return _degenerate(n)
    if n == 1:  # numpy sums one column in another order: solve it as two, keep one
        r, f = np.repeat(ranges.T, 2, axis=1), np.repeat(doppler.T, 2, axis=1)
    else:
        r, f = np.ascontiguousarray(ranges.T), np.ascontiguousarray(doppler.T)
    with np.errstate(all="ignore"):
        world, solution = solve_chunk(shared, rows, r, f)
        hard = solution.hard_case[:n]
        # on a straight track the hard case hands over its left point only: the other is
        # that one's mirror image, which the mirror rule adds (cls.ordered_candidates)
        count = solution.count[:n]
        if shared.line is not None:
            count = count - hard
        # with the height a coordinate, a flight in one plane (a level turn, two legs) leaves
        # the reflection through it: the rule adds it and drops what lies above the UAV (MATH
        # §7), whether or not the solve's hard case found both
        ceiling = {} if d == 2 else {"ceiling_m": float(np.max(shared.z)), "plane": shared.plane}
        final = finalize_columns(
            world[:n],
            count,
            _ordered_costs(solution.costs[:n], hard),
            shared.mean_xy,
            shared.line,
            side_prior_m=side_prior_m,
            **ceiling,
        )
    candidates = final.candidates
    if candidates.shape[1] < MAX_CANDIDATES:  # every chunk holds the same width
        padded = np.full((n, MAX_CANDIDATES, d), np.nan)
        padded[:, : candidates.shape[1]] = candidates
        candidates = padded
    return SolvedTrials(
        candidates,
        final.n_candidates,
        final.chosen,
        final.draw,
        final.ambiguous,
        solution.failed[:n] | final.invalid,
        hard,
        solution.multiplier[:n],
        solution.rank[:n],
        None if not shared.offset_unknown else solution.nuisance[:n, 0],
        np.zeros(n, dtype=bool),
    )


def _degenerate(n: int) -> SolvedTrials:
    """``n`` trials failed for :data:`STRAIGHT_TRACK_HEIGHT`."""
    return SolvedTrials(
        np.full((n, MAX_CANDIDATES, 3), np.nan),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=bool),
        np.zeros(n, dtype=bool),
        np.ones(n, dtype=bool),
        np.zeros(n, dtype=bool),
        np.full(n, np.nan),
        np.full(n, -1, dtype=np.int64),
        None,
        np.ones(n, dtype=bool),
    )


def _diagnostics(
    solved: SolvedTrials, rows: str, shared: SharedGeometry
) -> dict[str, NDArray[np.generic]]:
    """The diagnostics columns."""
    n = len(solved.rank)
    columns: dict[str, NDArray[np.generic]] = {
        "multiplier": solved.multiplier,
        "hard_case": solved.hard_case,
        "rank": solved.rank,
        "stages": np.full(n, 2 if rows == "weighted" else 1, dtype=np.int64),
        "n_samples": np.full(n, shared.used.n_samples, dtype=np.int64),
    }
    if solved.carrier_offset_hz is not None:
        columns["carrier_offset_hz"] = solved.carrier_offset_hz
    columns["straight_track"] = np.full(n, shared.line is not None)
    return columns


def estimate_columns(
    name: str,
    rows: str,
    frames: str,
    batch: MeasurementBatch,
    rngs: Sequence[np.random.Generator | None] | None,
    side_prior_m: tuple[float, float] | None,
) -> BatchEstimates:
    """The CLS estimates of every trial of ``batch``, as columns (see module docstring)."""
    n = batch.n_trials
    generators = check_rngs(rngs, n)
    shared = SharedGeometry.of(batch, frames, dimension=position_dimension(batch.geometry.unknowns))
    speed_of_light = shared.used.speed_of_light_mps
    ranges = speed_of_light * batch.toa_s[:, shared.columns]
    doppler = batch.doppler_hz[:, shared.columns]
    solved = solve_trials(shared, rows, ranges, doppler, side_prior_m)
    chosen = solved.chosen
    draw_tie_breaks(generators, solved.draw & ~solved.failed, solved.n_candidates, chosen)
    position = solved.candidates[np.arange(n), np.minimum(chosen, MAX_CANDIDATES - 1)]
    ok = ~solved.failed
    return BatchEstimates(
        estimator=name,
        position_m=np.where(ok[:, None], position, np.nan),
        candidates_m=np.where(ok[:, None, None], solved.candidates, np.nan),
        n_candidates=np.where(ok, solved.n_candidates, 0),
        ambiguous=solved.ambiguous & ok,
        success=ok.copy(),
        message_code=np.where(
            ok, np.where(solved.hard_case, 1, 0), np.where(solved.degenerate, 3, 2)
        ).astype(np.int64),
        messages=("", HARD_CASE_MESSAGE, FAILED_MESSAGE, STRAIGHT_TRACK_HEIGHT),
        diagnostics=_diagnostics(solved, rows, shared),
    )


def estimate_trial(
    name: str,
    rows: str,
    frames: str,
    data: MeasurementSet,
    rng: np.random.Generator | None,
    side_prior_m: tuple[float, float] | None,
    fit: Callable[[FloatArray], dict[str, Any]],
) -> Estimate:
    """:func:`estimate_columns` of one trial, ``data``, as its :class:`Estimate`: the same
    vectorised solve (:func:`solve_trials`) on a batch of one, without the batch's columns.
    ``fit(position (1, d))`` gives the goodness-of-fit diagnostics of a success."""
    shared = SharedGeometry.of(data, frames, dimension=position_dimension(data.unknowns))
    ranges = shared.used.speed_of_light_mps * data.toa_s[shared.columns][None]
    solved = solve_trials(shared, rows, ranges, data.doppler_hz[shared.columns][None], side_prior_m)
    diagnostics = {
        key: value[0].item() for key, value in _diagnostics(solved, rows, shared).items()
    }
    if solved.failed[0]:
        message = STRAIGHT_TRACK_HEIGHT if solved.degenerate[0] else FAILED_MESSAGE
        return Estimate.failed(name, message, dimension=shared.dimension, **diagnostics)
    count = int(solved.n_candidates[0])
    chosen = int(solved.chosen[0])
    if solved.draw[0] and rng is not None:
        chosen = int(rng.integers(count))
    position = solved.candidates[:1, min(chosen, MAX_CANDIDATES - 1)]
    hard = bool(solved.hard_case[0])
    return Estimate(
        estimator=name,
        position_m=position[0],
        candidates_m=solved.candidates[0, :count],
        ambiguous=bool(solved.ambiguous[0]),
        message=HARD_CASE_MESSAGE if hard else "",
        diagnostics={**diagnostics, **fit(position)},
    )


def draw_tie_breaks(
    generators: Sequence[np.random.Generator | None],
    draw: NDArray[np.bool_],
    n_kept: NDArray[np.int64],
    chosen: NDArray[np.int64],
) -> None:
    """``chosen[i] = generators[i].integers(n_kept[i])`` for every trial ``i`` that ``draw``s
    and has a generator, in trial order (``chosen`` updated in place). Trial order matters only
    when trials share a generator; it is kept all the same."""
    index = [i for i in np.flatnonzero(draw).tolist() if generators[i] is not None]
    counts = n_kept[index].tolist()
    chosen[index] = [generators[i].integers(c) for i, c in zip(index, counts, strict=True)]


def system_of_trial(
    data: MeasurementSet,
    rows: str,
    *,
    origin_m: FloatArray | None = None,
    scale_m: float | None = None,
    weights_at_local_xy: FloatArray | None = None,
    last_stage: bool = False,
    dimension: int = 2,
) -> tuple[FloatArray, FloatArray, FloatArray | None, float]:
    """The stacked rows ``A`` (m, d + 1), ``b`` (m,) of one trial (``data``, every sample) in its
    local frame, as the solver sums them, δ's column (m,) or None, and the frame's scale.

    The frame is the solver's (centred on the samples, scaled by the RMS of their spread and
    ranges) unless ``origin_m`` and ``scale_m`` are given. ``weighted`` rows are whitened at the
    measurements, at ``weights_at_local_xy``, or (``last_stage``) at the stage-1 estimate: the
    system whose minimisers ``estimate`` returns. ``dimension`` as for
    :meth:`SharedGeometry.of` (3: rows over ``(x, y, z, ‖s‖²)``).
    """
    shared = SharedGeometry.of(data, "all", origin_m=origin_m, dimension=dimension)
    r = (shared.used.speed_of_light_mps * data.toa_s)[:, None]
    f = data.doppler_hz[:, None]
    if scale_m is None:
        scale = np.sqrt(shared.spread_sq + np.mean(r * r, axis=0))
        scale = np.where(scale > 0.0, scale, 1.0)
    else:
        scale = np.array([float(scale_m)])
    rows_of = RowsOfChunk(shared, r, f, scale)
    weights_at = None
    if weights_at_local_xy is not None:
        weights_at = tuple(
            np.asarray(weights_at_local_xy, dtype=float).reshape(shared.dimension, 1)
        )
    elif last_stage and rows == "weighted":
        with np.errstate(all="ignore"):
            first = solve_gtrs_batch(rows_of.blocks(rows), 1)
        pick = int(_second_left(shared, first)[0])
        weights_at = tuple(c[:1, pick] for c in first.points)
    blocks = rows_of.blocks(rows, weights_at=weights_at)

    def column(values: FloatArray | None, n_rows: int) -> FloatArray:
        if values is None:
            return np.zeros(n_rows)
        return np.broadcast_to(values, (n_rows, 1))[:, 0]

    A = np.concatenate(
        [
            np.column_stack(
                [column(part, block.n_rows) for part in block.columns(shared.dimension)]
            )
            for block in blocks
        ]
    )
    b = np.concatenate([block.b[:, 0] for block in blocks])
    offset = None
    if any(block.ac is not None for block in blocks):
        offset = np.concatenate([column(block.ac, block.n_rows) for block in blocks])
    return A, b, offset, float(scale[0])


def _ordered_costs(costs: FloatArray, hard_case: NDArray[np.bool_]) -> FloatArray:
    """The costs (n, 2) handed to the mirror rule: a hard-case pair's both at the smaller one."""
    pair_best = np.minimum.reduce(costs, axis=1, keepdims=True)
    return np.where(hard_case[:, None], pair_best, costs)


def solve_chunk(
    shared: SharedGeometry, rows: str, r: FloatArray, f: FloatArray
) -> tuple[FloatArray, GtrsBatch]:
    """World candidates (n, 2, d), a hard-case pair left of the last heading first (with the
    height a coordinate, the lower first), and the solution of the last stage (its points and
    ``nuisance`` in the same order)."""
    scale = np.sqrt(shared.spread_sq + np.add.reduce(r * r, axis=0) / len(r))  # (np.mean's bits)
    scale[~(scale > 0.0)] = 1.0  # (NaN too)
    rows_of = RowsOfChunk(shared, r, f, scale)
    # rows with an exact null vector: one straight track (2-D), a level flight (3-D, MATH §5)
    deficient = shared.collinear if shared.dimension == 2 else bool(np.ptp(shared.z) == 0.0)
    n = r.shape[1]
    solution = solve_gtrs_batch(
        rows_of.blocks(rows), n, rank=rows != "weighted", rank_deficient=deficient
    )
    if rows == "weighted":
        # stage 2: weights at the stage-1 estimate (MATH §6); of a hard-case pair, at the point
        # left of the last heading (on a straight track both give the same weights)
        first = _second_left(shared, solution)
        local = tuple(np.where(first, c[:, 1], c[:, 0]) for c in solution.points)
        solution = solve_gtrs_batch(
            rows_of.blocks(rows, weights_at=local),
            n,
            rank=True,
            rank_deficient=deficient,
        )
    swap = _second_left(shared, solution)
    for name in ("x", "y", "z", "costs", "nuisance") if swap.any() else ():
        values = getattr(solution, name)
        if values is not None:
            values[swap] = values[swap, ::-1]
    world = np.empty((n, 2, shared.dimension))
    np.multiply(solution.x, scale[:, None], out=world[..., 0])
    world[..., 0] += shared.origin[0]
    np.multiply(solution.y, scale[:, None], out=world[..., 1])
    world[..., 1] += shared.origin[1]
    if solution.z is not None:  # the frame's z is the world's (MATH §5)
        np.multiply(solution.z, scale[:, None], out=world[..., 2])
    return world, solution


def candidates_of_trial(data: MeasurementSet, *, dimension: int = 2) -> FloatArray:
    """The weighted CLS's minimisers of one trial (every sample), before the mirror rule:
    (1, d) or, in the hard case, the pair (2, d), the point left of the last heading first
    (with the height a coordinate, the lower first); (0, d) when the GTRS has no finite
    minimiser. The same solve as a batch's
    (:func:`solve_chunk`), for the starts of another estimator. ``dimension`` as for
    :meth:`SharedGeometry.of` (2 by default: at the data's ``emitter_height_m``)."""
    shared = SharedGeometry.of(data, "all", dimension=dimension)
    r = np.repeat((shared.used.speed_of_light_mps * data.toa_s)[:, None], 2, axis=1)
    f = np.repeat(data.doppler_hz[:, None], 2, axis=1)  # two columns: a batch's sums
    with np.errstate(all="ignore"):
        world, solution = solve_chunk(shared, "weighted", r, f)
    if solution.failed[0]:
        return np.empty((0, shared.dimension))
    return world[0, : int(solution.count[0])]


def _second_left(shared: SharedGeometry, solution: GtrsBatch) -> NDArray[np.bool_]:
    """Whether the second of each hard-case pair lies left of the last heading (False off the
    hard case): the order handed to the mirror rule, so that which point a tie-break returns
    does not depend on the rounding of the two costs. With the height a coordinate, whether
    the second is the lower (the pair of a level flight is one above the other, MATH §7)."""
    if solution.z is not None:
        return solution.hard_case & (solution.z[:, 1] < solution.z[:, 0])
    velocity = shared.velocity[-1]
    across = (solution.x[:, 0] - solution.x[:, 1]) * -velocity[1] + (
        solution.y[:, 0] - solution.y[:, 1]
    ) * velocity[0]
    return solution.hard_case & (across < 0.0)


class RowsOfChunk:
    """The row blocks of one chunk for each row variant (see the module docstring)."""

    def __init__(
        self, shared: SharedGeometry, r: FloatArray, f: FloatArray, scale: FloatArray
    ) -> None:
        used = shared.used
        self.shared = shared
        self.r, self.f, self.scale = r, f, scale
        self.gamma = used.gamma_per_m
        self.height = used.emitter_height_m if shared.dimension == 2 else 0.0
        self.three_d = shared.dimension == 3
        velocity = shared.velocity
        self.vp = (
            velocity[:, 0] * shared.offset[:, 0]
            + velocity[:, 1] * shared.offset[:, 1]
            + velocity[:, 2] * shared.z
        )
        self.g_sq = shared.offset[:, 0] ** 2 + shared.offset[:, 1] ** 2
        # δ's column in the Doppler rows, r/(γ|v_xy|) in metres per hertz (MATH §15)
        self.offset = r / (self.gamma * shared.speed[:, None]) if shared.offset_unknown else None

    # -- right-hand sides in metres ---------------------------------------------------------

    def doppler_rhs(self) -> FloatArray:
        """``P = (v·(X, z) − v_z z_s + r f/γ)/|v_xy|`` (K, n)."""
        shared = self.shared
        constant = self.vp - shared.velocity[:, 2] * self.height
        return (constant[:, None] + self.r * self.f / self.gamma) / shared.speed[:, None]

    def toa_rhs(self, *, height_term: bool = True) -> FloatArray:
        """``Q = r² − |X|² − (z − z_s)²`` (K, n), or without the height term."""
        shared = self.shared
        constant = self.g_sq + ((shared.z - self.height) ** 2 if height_term else 0.0)
        return self.r * self.r - constant[:, None]

    def toa_block(self, *, height_term: bool = True, zero_offset: bool = False) -> RowBlock:
        """Unweighted squared-range rows in the local frame (MATH §4); with ``zero_offset``,
        δ's column in them (zero: the ranges do not depend on δ)."""
        inv = 1.0 / self.scale
        offset = self.shared.offset
        return RowBlock(
            ax=(-2.0 * offset[:, :1]) * inv,
            ay=(-2.0 * offset[:, 1:]) * inv,
            az=np.ones((len(offset), 1)),
            b=self.toa_rhs(height_term=height_term) * (inv * inv),
            ac=np.zeros((len(offset), 1)) if zero_offset else None,
            ah=self.shared.column["-2z"] * inv if self.three_d else None,
        )

    def blocks(
        self, rows: str, *, weights_at: tuple[FloatArray, ...] | None = None
    ) -> list[RowBlock]:
        """The row blocks of ``rows``; ``weighted`` ones whitened at the measurements or at the
        local point ``weights_at`` (``x, y`` or, with the height a coordinate, ``x, y, z``, each
        (n,))."""
        shared = self.shared
        inv = 1.0 / self.scale
        if rows == "weighted":
            return self._whitened(weights_at)
        if rows == "per-sample":
            return [
                RowBlock(
                    ax=shared.unit[:, :1] * inv,
                    ay=shared.unit[:, 1:] * inv,
                    az=None,
                    b=self.doppler_rhs() * (inv * inv),
                    ac=None if self.offset is None else self.offset * (inv * inv),
                    ah=shared.column["uz"] * inv if self.three_d else None,
                ),
                self.toa_block(zero_offset=self.offset is not None),
            ]
        if self.three_d:
            raise ValueError(
                f"rows: {rows!r} rows take the emitter's height as known (MATH §3); with it "
                "unknown use 'weighted' or 'per-sample'"
            )
        if rows == "per-frame":
            counts = shared.frame_counts[:, None]
            starts = shared.frame_starts
            mean_unit = np.add.reduceat(shared.unit, starts, axis=0) / counts
            speed_sq = np.sum(shared.velocity[starts, :2] ** 2, axis=1)
            weight = (shared.frame_counts * speed_sq)[:, None] * inv
            mean_rhs = shared.frame_sums(self.doppler_rhs() * inv) / counts
            return [
                RowBlock(
                    ax=mean_unit[:, :1] * weight,
                    ay=mean_unit[:, 1:] * weight,
                    az=None,
                    b=mean_rhs * weight,
                ),
                self.toa_block(),
            ]
        if rows == "as-printed":
            velocity = shared.velocity
            v1 = velocity[:, 0]
            row_x = np.add.reduceat(v1 * v1, shared.frame_starts)[:, None]
            row_y = np.add.reduceat(v1 * velocity[:, 1], shared.frame_starts)[:, None]
            rhs = (self.r * self.f / self.gamma + self.vp[:, None]) * (v1[:, None] * inv)
            return [
                RowBlock(
                    ax=row_x * inv,
                    ay=row_y * inv,
                    az=None,
                    b=shared.frame_sums(rhs) * inv,
                ),
                self.toa_block(height_term=False),
            ]
        raise ValueError(f"rows: unknown row variant {rows!r}")

    def _whitened(self, weights_at: tuple[FloatArray, ...] | None) -> list[RowBlock]:
        """Per-sample Doppler and ToA rows whitened pair by pair (MATH §6).

        The moments are evaluated at the measured ``(r, f)`` or, with ``weights_at`` (local
        ``x, y`` per trial, and ``z`` with the height a coordinate), at that point. Written with
        in-place operations: this is the
        largest part of the batch's work.
        """
        shared, scale = self.shared, self.scale
        column = shared.column
        noise = shared.used.noise
        sr2 = (noise.toa_s * shared.used.speed_of_light_mps) ** 2
        sf2 = noise.doppler_hz**2
        if weights_at is None:
            rho, doppler = self.r, self.f
        else:  # the noise-free Doppler and range at that point (MATH §1)
            doppler, ranges = model.derivatives_of_offsets(
                column["x"] - weights_at[0] * scale,
                column["y"] - weights_at[1] * scale,
                column["dz"] if len(weights_at) == 2 else column["dz"] - weights_at[2] * scale,
                (column["vx"], column["vy"], column["vz"]),
                self.gamma,
                order=0,
            )
            doppler, rho = doppler[0], ranges[0]
        rho_sq = rho * rho
        root = rho_sq * sf2
        spare = np.multiply(doppler, doppler)
        spare *= sr2
        root += spare
        root += sf2 * sr2
        np.sqrt(root, out=root)
        inv11 = np.divide(column["gv"], root)  # 1/λ₁₁
        l21 = rho * doppler
        l21 *= 2.0 * sr2
        l21 /= root  # λ₂₁
        inv22 = np.multiply(rho_sq, 4.0 * sr2, out=rho_sq)
        inv22 += 2.0 * sr2 * sr2
        inv22 -= np.multiply(l21, l21, out=spare)
        np.sqrt(inv22, out=inv22)
        np.divide(1.0, inv22, out=inv22)  # 1/λ₂₂
        beta = self._doppler_rhs_cached * inv11  # whitened Doppler right side
        ratio = np.multiply(l21, inv11, out=root)  # c = λ₂₁/λ₁₁
        offset_d = offset_t = None
        if self.offset is not None:  # δ's column, whitened with the Doppler rows (MATH §15)
            offset_d = self.offset * inv11
            offset_t = -(l21 * offset_d) * inv22
        weight = np.multiply(inv11, scale, out=inv11)
        toa_b = np.multiply(l21, beta, out=l21)
        np.subtract(self._toa_rhs_cached, toa_b, out=toa_b)
        toa_b *= inv22
        toa_weight = np.multiply(inv22, scale, out=inv22)
        toa_x = np.multiply(ratio, column["-ux"])
        toa_x += column["-2x"]
        toa_x *= toa_weight
        doppler_h = toa_h = None
        if self.three_d:  # the height's columns (MATH §5): v_z/|v_xy| and −2z, whitened alike
            doppler_h = column["uz"] * weight
            toa_h = np.multiply(ratio, column["-uz"])
            toa_h += column["-2z"]
            toa_h *= toa_weight
        toa_y = np.multiply(ratio, column["-uy"], out=ratio)
        toa_y += column["-2y"]
        toa_y *= toa_weight
        return [
            RowBlock(
                ax=column["ux"] * weight,
                ay=column["uy"] * weight,
                az=None,
                b=beta,
                ac=offset_d,
                ah=doppler_h,
            ),
            RowBlock(ax=toa_x, ay=toa_y, az=toa_weight * scale, b=toa_b, ac=offset_t, ah=toa_h),
        ]

    @cached_property
    def _doppler_rhs_cached(self) -> FloatArray:
        return self.doppler_rhs()

    @cached_property
    def _toa_rhs_cached(self) -> FloatArray:
        return self.toa_rhs()
