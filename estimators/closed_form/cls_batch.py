r"""The closed-form CLS of MATH §3-§6 for a whole :class:`~scenarios.types.MeasurementBatch`.

The rows of :mod:`estimators.closed_form.cls_rows`, the two-stage whitening of MATH §6 and the GTRS
of MATH §5 (:mod:`estimators.closed_form.gtrs_batch`) evaluated for every trial at once, then the
candidate order of :func:`estimators.closed_form.cls.ordered_candidates` and the mirror rule of
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
  ``l``'s of :func:`~estimators.closed_form.cls_rows.whiten_sample_pairs` are ``λ₁₁/L`` and
  ``λ/L²``): Doppler ``L[v̂ᵀ, 0]/λ₁₁ · r = P/λ₁₁``, ToA
  ``[−L(2X + c v̂)/λ₂₂, L²/λ₂₂] r = (Q − λ₂₁ P/λ₁₁)/λ₂₂`` with ``c = λ₂₁/λ₁₁``.

Trials whose choices the batch cannot certify (``GtrsBatch.uncertain``, the flags of
:func:`~estimators.batch.finalize_columns`) are solved one at a time by the caller's
``solve_one``, with their own generator; every other trial draws ``rng.integers`` exactly
when and as the one-trial path does, in trial order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate
from estimators.batch import BatchEstimates, check_rngs, finalize_columns
from estimators.closed_form.cls_rows import horizontal_speed_mps
from estimators.closed_form.gtrs_batch import GtrsBatch, RowBlock, solve_gtrs_batch
from scenarios.geometry import straight_track_line
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
SolveOne = Callable[[MeasurementSet, np.random.Generator | None], Estimate]
"""The one-trial path: ``estimate(data, rng=rng)`` after the checks the batch made once."""

CHUNK_ELEMENTS = 131_072
"""Samples × trials per chunk of the vectorised solve: large enough that numpy's per-call
overhead is small, small enough that the working arrays stay in cache."""
MAX_CHUNK = 16_384
"""Trials per chunk at most."""

HARD_CASE_MESSAGE = "hard case: mirror pair (MATH §5)"
SIDE_RTOL = 1e-6
"""A hard-case pair is ordered by side only when its points differ across the last heading by
more than this times the frame's scale."""

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

    @classmethod
    def of(cls, batch: MeasurementBatch | MeasurementSet, frames: str) -> SharedGeometry:
        """The samples of ``frames`` of a batch's geometry, or of one trial's."""
        geometry = batch.geometry if isinstance(batch, MeasurementBatch) else batch
        used = geometry.select_frames(frames)
        if frames == "last":
            columns = np.flatnonzero(geometry.frame == geometry.frame[-1])
        else:
            columns = np.arange(geometry.n_samples)
        position = used.position_m
        origin = position[:, :2].mean(axis=0)
        offset = position[:, :2] - origin
        spread_sq = float(np.mean(np.sum(offset**2, axis=1)))
        velocity = used.velocity_mps
        speed = horizontal_speed_mps(velocity)
        _, starts, counts = np.unique(used.frame, return_index=True, return_counts=True)
        unit = velocity[:, :2] / speed[:, None]
        dz = position[:, 2] - used.emitter_height_m
        per_sample = {  # (K, 1) columns that broadcast against (K, n) arrays
            "x": offset[:, 0],
            "y": offset[:, 1],
            "-2x": -2.0 * offset[:, 0],
            "-2y": -2.0 * offset[:, 1],
            "ux": unit[:, 0],
            "uy": unit[:, 1],
            "-ux": -unit[:, 0],
            "-uy": -unit[:, 1],
            "vx": velocity[:, 0],
            "vy": velocity[:, 1],
            "vz_dz": velocity[:, 2] * dz,
            "dz_sq": dz * dz,
            "gv": used.gamma_per_m * speed,
        }
        line = straight_track_line(position, velocity)
        # collinear to COLLINEAR_RTOL implies straight to the default 1e-9
        collinear = line is not None and (
            straight_track_line(position, velocity, rtol=COLLINEAR_RTOL) is not None
        )
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
            collinear=collinear,
            mean_xy=position[:, :2].mean(axis=0),
            column=dict(
                zip(per_sample, np.stack(list(per_sample.values()))[..., None], strict=True)
            ),
        )

    def frame_sums(self, values: FloatArray) -> FloatArray:
        """Sums over the samples of each frame of ``values`` (K, n): shape (F, n)."""
        return np.add.reduceat(values, self.frame_starts, axis=0)


@dataclass(frozen=True, slots=True, eq=False)
class SolvedTrials:
    """What the vectorised CLS decides for each of ``n`` trials, before the tie-break draws.

    ``candidates`` (n, 4, 2) holds trial ``i``'s kept candidates in its first
    ``n_candidates[i]`` slots; ``chosen`` is the returned one unless ``draw`` (a tie with no
    prior: ``rng.integers(n_candidates)`` decides); ``uncertain`` trials are left to the
    one-trial path (module docstring).
    """

    candidates: FloatArray
    n_candidates: NDArray[np.int64]
    chosen: NDArray[np.int64]
    draw: NDArray[np.bool_]
    ambiguous: NDArray[np.bool_]
    uncertain: NDArray[np.bool_]
    hard_case: NDArray[np.bool_]
    multiplier: FloatArray
    rank: NDArray[np.int64]


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
    kept = np.full((n, 4, 2), np.nan)
    n_kept = np.zeros(n, dtype=np.int64)
    chosen = np.zeros(n, dtype=np.int64)
    draw = np.zeros(n, dtype=bool)
    ambiguous = np.zeros(n, dtype=bool)
    uncertain = np.zeros(n, dtype=bool)
    hard = np.zeros(n, dtype=bool)
    multiplier = np.full(n, np.nan)
    rank = np.zeros(n, dtype=np.int64)
    chunk = n if n == 1 else int(np.clip(CHUNK_ELEMENTS // max(k, 1), 256, MAX_CHUNK))
    for start in range(0, n, chunk):
        part = slice(start, min(start + chunk, n))
        r = np.ascontiguousarray(ranges[part].T)
        f = np.ascontiguousarray(doppler[part].T)
        single = r.shape[1] == 1
        if single:  # numpy sums one column in another order: solve it as two, keep one
            r, f = np.repeat(r, 2, axis=1), np.repeat(f, 2, axis=1)
        with np.errstate(all="ignore"):
            world, solution, doubt = solve_chunk(shared, rows, r, f)
            if single:
                world, doubt = world[:1], doubt[:1]
                solution = solution.first()
            # on a straight track the hard case hands over its left point only: the other is
            # that one's mirror image, which the mirror rule adds (cls.ordered_candidates)
            count = solution.count
            if shared.line is not None:
                count = np.where(solution.hard_case, 1, count)
            final = finalize_columns(
                world,
                count,
                _ordered_costs(solution),
                shared.mean_xy,
                shared.line,
                side_prior_m=side_prior_m,
            )
        width = final.candidates.shape[1]
        kept[part, :width] = final.candidates
        n_kept[part] = final.n_candidates
        chosen[part] = final.chosen
        draw[part] = final.draw
        ambiguous[part] = final.ambiguous
        uncertain[part] = solution.uncertain | doubt | final.uncertain
        hard[part] = solution.hard_case
        multiplier[part] = solution.multiplier
        rank[part] = solution.rank
    return SolvedTrials(kept, n_kept, chosen, draw, ambiguous, uncertain, hard, multiplier, rank)


def _diagnostics(
    solved: SolvedTrials, rows: str, shared: SharedGeometry
) -> dict[str, NDArray[np.generic]]:
    """The diagnostics columns, in the one-trial path's key order."""
    n = len(solved.rank)
    return {
        "multiplier": solved.multiplier,
        "hard_case": solved.hard_case,
        "rank": solved.rank,
        "stages": np.full(n, 2 if rows == "weighted" else 1, dtype=np.int64),
        "n_samples": np.full(n, shared.used.n_samples, dtype=np.int64),
        "straight_track": np.full(n, shared.line is not None),
    }


def estimate_columns(
    name: str,
    rows: str,
    frames: str,
    batch: MeasurementBatch,
    rngs: Sequence[np.random.Generator | None] | None,
    side_prior_m: tuple[float, float] | None,
    solve_one: SolveOne,
) -> BatchEstimates:
    """The CLS estimates of every trial of ``batch``, as columns (see module docstring)."""
    n = batch.n_trials
    generators = check_rngs(rngs, n)
    shared = SharedGeometry.of(batch, frames)
    speed_of_light = shared.used.speed_of_light_mps
    ranges = speed_of_light * batch.toa_s[:, shared.columns]
    doppler = batch.doppler_hz[:, shared.columns]
    solved = solve_trials(shared, rows, ranges, doppler, side_prior_m)
    chosen, uncertain = solved.chosen, solved.uncertain
    redo, recomputed = draw_and_redo(
        name, solve_one, batch, generators, uncertain, solved.draw, solved.n_candidates, chosen
    )
    position = solved.candidates[np.arange(n), np.minimum(chosen, 3)]
    ok = ~uncertain
    columns = BatchEstimates(
        estimator=name,
        position_m=np.where(ok[:, None], position, np.nan),
        candidates_m=solved.candidates,
        n_candidates=np.where(ok, solved.n_candidates, 0),
        ambiguous=solved.ambiguous & ok,
        success=ok.copy(),
        message_code=np.where(solved.hard_case & ok, 1, 0).astype(np.int64),
        messages=("", HARD_CASE_MESSAGE),
        diagnostics=_diagnostics(solved, rows, shared),
    )
    return columns.with_trials(redo, recomputed)


def estimate_trial(
    name: str,
    rows: str,
    frames: str,
    data: MeasurementSet,
    rng: np.random.Generator | None,
    side_prior_m: tuple[float, float] | None,
    solve_one: SolveOne,
    fit: Callable[[FloatArray], dict[str, Any]],
) -> Estimate:
    """:func:`estimate_columns` of one trial, ``data``, as its :class:`Estimate`: the same
    vectorised solve (:func:`solve_trials`) on a batch of one, without the batch's columns.
    ``fit(position (1, 2))`` gives the goodness-of-fit diagnostics of a success."""
    shared = SharedGeometry.of(data, frames)
    ranges = shared.used.speed_of_light_mps * data.toa_s[shared.columns][None]
    solved = solve_trials(shared, rows, ranges, data.doppler_hz[shared.columns][None], side_prior_m)
    if solved.uncertain[0]:
        estimate = _solve_one_safely(name, solve_one, data, rng)
        if not estimate.success:
            return estimate
        return replace(
            estimate, diagnostics={**estimate.diagnostics, **fit(estimate.position_m[None])}
        )
    count = int(solved.n_candidates[0])
    chosen = int(solved.chosen[0])
    if solved.draw[0] and rng is not None:
        chosen = int(rng.integers(count))
    position = solved.candidates[:1, min(chosen, 3)]
    hard = bool(solved.hard_case[0])
    diagnostics = {
        key: value[0].item() for key, value in _diagnostics(solved, rows, shared).items()
    }
    return Estimate(
        estimator=name,
        position_m=position[0],
        candidates_m=solved.candidates[0, :count],
        ambiguous=bool(solved.ambiguous[0]),
        message=HARD_CASE_MESSAGE if hard else "",
        diagnostics={**diagnostics, **fit(position)},
    )


def draw_and_redo(
    name: str,
    solve_one: SolveOne,
    batch: MeasurementBatch,
    generators: list[np.random.Generator | None],
    uncertain: NDArray[np.bool_],
    draw: NDArray[np.bool_],
    n_kept: NDArray[np.int64],
    chosen: NDArray[np.int64],
) -> tuple[NDArray[np.int64], list[Estimate]]:
    """In trial order: solve the uncertain trials one at a time, and draw the tie-break of the
    others that need one (``chosen`` is updated in place). Trial order matters only when
    trials share a generator; it is kept all the same."""
    absent = generators.count(None)
    if absent in (0, len(generators)):
        has_generator = np.full(len(generators), absent == 0)
    else:
        has_generator = np.array([g is not None for g in generators], dtype=bool)
    drawing = draw & has_generator & ~uncertain
    redo = np.flatnonzero(uncertain)
    if redo.size == 0:
        index = np.flatnonzero(drawing).tolist()
        counts = n_kept[index].tolist()
        chosen[index] = [generators[i].integers(c) for i, c in zip(index, counts, strict=True)]
        return redo, []
    recomputed = []
    for i in np.flatnonzero(uncertain | drawing).tolist():
        if uncertain[i]:
            recomputed.append(_solve_one_safely(name, solve_one, batch.trial(i), generators[i]))
        else:
            chosen[i] = generators[i].integers(n_kept[i])
    return redo, recomputed


def _solve_one_safely(
    name: str, solve_one: SolveOne, data: MeasurementSet, rng: np.random.Generator | None
) -> Estimate:
    """The one-trial path; an exception becomes a failed estimate, as a run records it."""
    try:
        return solve_one(data, rng)
    except Exception as error:
        return Estimate.failed(name, f"{type(error).__name__}: {error}")


def _ordered_costs(solution: GtrsBatch) -> FloatArray:
    """The costs handed to the mirror rule: a hard-case pair's both at the smaller one."""
    pair_best = np.min(solution.costs, axis=1)
    return np.where(solution.hard_case[:, None], pair_best[:, None], solution.costs)


def solve_chunk(
    shared: SharedGeometry, rows: str, r: FloatArray, f: FloatArray
) -> tuple[FloatArray, GtrsBatch, NDArray[np.bool_]]:
    """World candidates (n, 2, 2) in the one-trial path's order, the solution and doubts."""
    used = shared.used
    n = r.shape[1]
    scale = np.sqrt(shared.spread_sq + np.mean(r * r, axis=0))
    scale = np.where(scale > 0.0, scale, 1.0)
    rows_of = RowsOfChunk(shared, r, f, scale)
    deficient = shared.collinear
    solution = solve_gtrs_batch(
        rows_of.blocks(rows), n, rank=rows != "weighted", rank_deficient=deficient
    )
    doubt = solution.uncertain.copy()
    if rows == "weighted":
        # stage 2: weights at the stage-1 estimate, ``points[0]`` (MATH §6). On a straight
        # track both mirror candidates give the same weights; elsewhere which of the pair is
        # first is the one-trial path's eigenvector sign, so a pair is left to it
        if not shared.collinear:
            doubt |= solution.hard_case
        local_x, local_y = solution.x[:, 0], solution.y[:, 0]
        solution = solve_gtrs_batch(
            rows_of.blocks(rows, weights_at=(local_x, local_y)),
            n,
            rank=True,
            rank_deficient=deficient,
        )
        doubt |= solution.uncertain
    world = np.stack(
        [
            solution.x * scale[:, None] + shared.origin[0],
            solution.y * scale[:, None] + shared.origin[1],
        ],
        axis=-1,
    )
    # the hard-case pair left of the last heading first (cls.ordered_candidates)
    velocity = used.velocity_mps[-1]
    left = np.array([-velocity[1], velocity[0]])
    across = (world[:, 0] - world[:, 1]) @ left
    swap = solution.hard_case & (across < 0.0)
    world[swap] = world[swap, ::-1]
    doubt |= solution.hard_case & (np.abs(across) <= SIDE_RTOL * scale * np.linalg.norm(left))
    return world, solution, doubt


class RowsOfChunk:
    """The row blocks of one chunk for each row variant (see the module docstring)."""

    def __init__(
        self, shared: SharedGeometry, r: FloatArray, f: FloatArray, scale: FloatArray
    ) -> None:
        used = shared.used
        self.shared = shared
        self.r, self.f, self.scale = r, f, scale
        self.gamma = used.gamma_per_m
        self.height = used.emitter_height_m
        velocity = shared.velocity
        self.vp = (
            velocity[:, 0] * shared.offset[:, 0]
            + velocity[:, 1] * shared.offset[:, 1]
            + velocity[:, 2] * shared.z
        )
        self.g_sq = shared.offset[:, 0] ** 2 + shared.offset[:, 1] ** 2

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

    def toa_block(self, *, height_term: bool = True) -> RowBlock:
        """Unweighted squared-range rows in the local frame (MATH §4)."""
        inv = 1.0 / self.scale
        offset = self.shared.offset
        return RowBlock(
            ax=(-2.0 * offset[:, :1]) * inv,
            ay=(-2.0 * offset[:, 1:]) * inv,
            az=np.ones((len(offset), 1)),
            b=self.toa_rhs(height_term=height_term) * (inv * inv),
        )

    def blocks(
        self, rows: str, *, weights_at: tuple[FloatArray, FloatArray] | None = None
    ) -> list[RowBlock]:
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
                ),
                self.toa_block(),
            ]
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

    def _whitened(self, weights_at: tuple[FloatArray, FloatArray] | None) -> list[RowBlock]:
        """Per-sample Doppler and ToA rows whitened pair by pair (MATH §6).

        The moments are evaluated at the measured ``(r, f)`` or, with ``weights_at`` (local
        ``x, y`` per trial), at that point. Written with in-place operations: this is the
        largest part of the batch's work.
        """
        shared, scale = self.shared, self.scale
        column = shared.column
        noise = shared.used.noise
        sr2 = (noise.toa_s * shared.used.speed_of_light_mps) ** 2
        sf2 = noise.doppler_hz**2
        if weights_at is None:
            rho, doppler = self.r, self.f
        else:
            dx = column["x"] - weights_at[0] * scale
            dy = column["y"] - weights_at[1] * scale
            doppler = dx * column["vx"]
            doppler += np.multiply(dy, column["vy"])
            doppler += column["vz_dz"]
            rho = np.multiply(dx, dx, out=dx)
            rho += np.multiply(dy, dy, out=dy)
            rho += column["dz_sq"]
            np.sqrt(rho, out=rho)
            doppler /= rho
            doppler *= -self.gamma
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
        weight = np.multiply(inv11, scale, out=inv11)
        toa_b = np.multiply(l21, beta, out=l21)
        np.subtract(self._toa_rhs_cached, toa_b, out=toa_b)
        toa_b *= inv22
        toa_weight = np.multiply(inv22, scale, out=inv22)
        toa_x = np.multiply(ratio, column["-ux"])
        toa_x += column["-2x"]
        toa_x *= toa_weight
        toa_y = np.multiply(ratio, column["-uy"], out=ratio)
        toa_y += column["-2y"]
        toa_y *= toa_weight
        return [
            RowBlock(ax=column["ux"] * weight, ay=column["uy"] * weight, az=None, b=beta),
            RowBlock(ax=toa_x, ay=toa_y, az=toa_weight * scale, b=toa_b),
        ]

    @cached_property
    def _doppler_rhs_cached(self) -> FloatArray:
        return self.doppler_rhs()

    @cached_property
    def _toa_rhs_cached(self) -> FloatArray:
        return self.toa_rhs()
