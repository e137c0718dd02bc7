r"""The linear least-squares baselines of MATH §9: LLS-ToA and LLS-RSS.

``lls-toa`` (:class:`LlsToa`, Zekavat & Buehrer)
    The squared-range rows of MATH §4 (paper eq ``Beq`` with the height term),
    ``[−2x_k, −2y_k, 1] r = r_k² − x_k² − y_k² − (z_k − z_s)²``, with ``r_z`` a free unknown
    instead of ``x_s² + y_s²``: ordinary least squares in three unknowns.
``lls-rss`` (:class:`LlsRss`, So & Lin, IEEE TSP 2011)
    Received power to an unbiased squared distance, then the differences of the squared-range
    equations against the strongest sample, which cancel ``‖s‖²``: ordinary least squares in
    ``(x_s, y_s)``.

Both are solved by ``numpy.linalg.lstsq`` in a frame centred on the track and scaled to order one
(:class:`~estimators.closed_form.cls_rows.LocalFrame`) and return its minimum-norm solution. On a
straight track neither system has full rank (LLS-ToA rank 2, LLS-RSS rank 1): nothing fixes the
cross-track coordinate, the minimum-norm solution lies on the track, and the estimate says so
in its message and its ``rank`` diagnostic instead of raising. A turn or an orbit gives them full
rank (MATH §9).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import (
    Capabilities,
    Estimate,
    check_rng,
    hovering_problem,
    require_batch,
    require_modalities,
)
from estimators.batch import BatchEstimates, EstimatesOfColumns, check_rngs
from estimators.closed_form.cls_batch import draw_tie_breaks
from estimators.closed_form.cls_rows import LocalFrame
from estimators.closed_form.gtrs_rank import row_dot
from estimators.goodness_of_fit import with_fit_columns
from estimators.mirror_rule import finalize_columns
from scenarios.geometry import straight_track_line
from scenarios.types import MeasurementBatch, MeasurementSet, RssModel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Frames = Literal["all", "last"]
Reference = Literal["strongest", "mean"]

RANK_RTOL = 1e-10
"""Singular values below ``RANK_RTOL`` times the largest count as zero (in the local frame)."""


@dataclass(frozen=True, slots=True, eq=False)
class LinearLsSolution:
    """The minimum-norm least-squares solution of one of the MATH §9 systems.

    Attributes
    ----------
    position_m : (2,)
        ``(x_s, y_s)`` in world coordinates.
    cost_m4 : float
        ``‖A x − b‖²`` at the solution, in m⁴ (both systems are in squared metres).
    rank : int
        Numerical rank of ``A`` (at most ``n_unknowns``).
    n_unknowns : int
        3 for LLS-ToA ``(x_s, y_s, r_z)``, 2 for LLS-RSS.
    frame : LocalFrame
        The centred, scaled frame the system was solved in.
    """

    position_m: FloatArray
    cost_m4: float
    rank: int
    n_unknowns: int
    frame: LocalFrame

    @property
    def rank_deficient(self) -> bool:
        return self.rank < self.n_unknowns


@dataclass(frozen=True, slots=True, eq=False)
class LinearLsColumns:
    """The minimum-norm least-squares solutions of ``n`` trials' MATH §9 systems: positions
    ``(n, 2)`` (world), costs ``‖A x − b‖²`` ``(n,)`` in m⁴, ranks ``(n,)``, each trial's local
    frame (a shared origin, its own scale ``(n,)``) and, for LLS-RSS, the reference sample
    ``(n,)`` (-1 for the mean equation)."""

    position_m: FloatArray
    cost_m4: FloatArray
    rank: NDArray[np.int64]
    n_unknowns: int
    origin_m: FloatArray
    scale_m: FloatArray
    reference: NDArray[np.int64] | None = None

    def solution(self, index: int) -> LinearLsSolution:
        """Trial ``index`` as a :class:`LinearLsSolution`."""
        return LinearLsSolution(
            position_m=self.position_m[index].copy(),
            cost_m4=float(self.cost_m4[index]),
            rank=int(self.rank[index]),
            n_unknowns=self.n_unknowns,
            frame=LocalFrame(origin_m=self.origin_m, scale_m=float(self.scale_m[index])),
        )


def _sample_sums(values: FloatArray, weights: FloatArray | None = None) -> FloatArray:
    """``Σ_k values[i, k] (· weights[i, k])`` for every trial ``i`` of (n, K) arrays, added
    sample after sample (:func:`~estimators.closed_form.gtrs_rank.row_dot`), so that a trial's
    sum does not depend, to the bit, on the batch it is in."""
    left = np.ascontiguousarray(values.T)
    right = np.ones_like(left) if weights is None else np.ascontiguousarray(weights.T)
    return row_dot(left, right, values.shape[0])


def minimum_norm_lstsq(
    A: FloatArray, b: FloatArray
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """The minimum-norm least-squares solutions of ``n`` systems ``A`` (n, m, k), ``b`` (n, m):
    ``x = V Σ⁺ Uᵀ b`` with singular values at most :data:`RANK_RTOL` times the largest taken as
    zero (``numpy.linalg.lstsq``'s rule). Returns ``x`` (n, k), the costs ``‖A x − b‖²`` (n,) and
    the ranks (n,). Every sum runs in a fixed order, trial by trial."""
    U, singular, Vt = np.linalg.svd(A, full_matrices=False)
    kept = singular > RANK_RTOL * singular[:, :1]
    k = A.shape[2]
    projected = np.stack([_sample_sums(U[:, :, j], b) for j in range(k)], axis=1)  # Uᵀ b
    coefficient = np.where(kept, projected / np.where(kept, singular, 1.0), 0.0)
    x = Vt[:, 0, :] * coefficient[:, :1]
    for j in range(1, k):
        x = x + Vt[:, j, :] * coefficient[:, j : j + 1]
    residual = -b
    for j in range(k):
        residual = residual + A[:, :, j] * x[:, j : j + 1]
    return x, _sample_sums(residual, residual), kept.sum(axis=1).astype(np.int64)


def _local_frames(position_m: FloatArray, reach_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each trial's :class:`LocalFrame`: the samples' mean horizontal position (shared) and the
    RMS of their spread and of the trial's ``reach_m`` (n, K) (ranges or distances)."""
    xy = position_m[:, :2]
    origin = xy.mean(axis=0)
    spread_sq = np.mean(np.sum((xy - origin) ** 2, axis=1))
    scale = np.sqrt(spread_sq + _sample_sums(reach_m, reach_m) / reach_m.shape[1])
    return origin, np.where(scale > 0.0, scale, 1.0)


def lls_toa_columns(
    position_m: ArrayLike, range_m: ArrayLike, emitter_height_m: float = 0.0
) -> LinearLsColumns:
    """Ordinary least squares on the squared-range rows with ``r_z`` free (MATH §9, §4), for
    every trial: ``range_m`` (n, K) on the samples ``position_m`` (K, 3).

    Solves ``[−2x_k, −2y_k, 1] (x_s, y_s, r_z) = r_k² − x_k² − y_k² − (z_k − z_s)²`` (paper eq
    ``Beq``, height term included) for the minimum-norm ``(x_s, y_s, r_z)`` in each trial's
    centred, scaled frame, and drops ``r_z``. Rank 3 with two headings; rank 2 on a straight
    track, where the minimum-norm solution lies on the track.
    """
    position = np.asarray(position_m, dtype=float)
    ranges = np.atleast_2d(np.asarray(range_m, dtype=float))
    origin, scale = _local_frames(position, ranges)
    unit = scale[:, None]
    x = (position[:, 0] - origin[0]) / unit
    y = (position[:, 1] - origin[1]) / unit
    height = (position[:, 2] - emitter_height_m) / unit
    r = ranges / unit
    A = np.stack([-2.0 * x, -2.0 * y, np.ones_like(x)], axis=-1)
    b = r * r - x * x - y * y - height * height
    solution, cost, rank = minimum_norm_lstsq(A, b)
    return LinearLsColumns(
        position_m=solution[:, :2] * unit + origin,
        cost_m4=cost * scale**4,
        rank=rank,
        n_unknowns=3,
        origin_m=origin,
        scale_m=scale,
    )


def solve_lls_toa(
    position_m: ArrayLike, range_m: ArrayLike, emitter_height_m: float = 0.0
) -> LinearLsSolution:
    """:func:`lls_toa_columns` of one trial: ``range_m`` (N,) on ``position_m`` (N, 3)."""
    ranges = np.asarray(range_m, dtype=float)[None]
    return lls_toa_columns(position_m, ranges, emitter_height_m).solution(0)


def rss_bias_factor(rss_sigma_db: float, path_loss_exponent: float) -> float:
    """``E[d̂²]/ρ² = exp(½ (σ_P ln10 / (5η))²)``: the bias of the raw squared distance (MATH §9).

    With ``P = P0 − 10η log10(ρ/d0) + e``, ``e ~ N(0, σ_P²)``, the raw
    ``d̂² = d0² 10^((P0 − P)/(5η)) = ρ² exp(−a e)`` with ``a = ln10/(5η)``, whose mean is
    ``ρ² exp(a²σ_P²/2)`` (the log-normal mean).
    """
    a = np.log(10.0) / (5.0 * path_loss_exponent)
    return float(np.exp(0.5 * (rss_sigma_db * a) ** 2))


def rss_squared_distance_m2(
    rss_dbm: ArrayLike, rss_model: RssModel, rss_sigma_db: float
) -> FloatArray:
    """Unbiased squared slant distances from received power (MATH §9; So & Lin 2011).

    ``d̂_k² = d0² 10^((P0 − P_k)/(5η)) / exp(½ (σ_P ln10/(5η))²)``; shape (N,).
    """
    eta = rss_model.path_loss_exponent
    power = np.asarray(rss_dbm, dtype=float)
    raw = rss_model.reference_distance_m**2 * 10.0 ** (
        (rss_model.reference_power_dbm - power) / (5.0 * eta)
    )
    return raw / rss_bias_factor(rss_sigma_db, eta)


def lls_rss_columns(
    position_m: ArrayLike,
    rss_dbm: ArrayLike,
    rss_model: RssModel,
    rss_sigma_db: float,
    emitter_height_m: float = 0.0,
    *,
    reference: Reference = "strongest",
) -> LinearLsColumns:
    """So & Lin's linear least squares on de-biased RSS squared distances (MATH §9).

    With ``d̂_k²`` from :func:`rss_squared_distance_m2` (3-D slant distances) and ``ref`` the
    strongest sample, subtracting the reference equation from
    ``‖p_k,xy‖² − 2 p_k,xyᵀ s + ‖s‖² + (z_k − z_s)² = d̂_k²`` cancels ``‖s‖²``:

    ``2 (p_k − p_ref)_xyᵀ s = ‖p_k,xy‖² − ‖p_ref,xy‖² + (z_k − z_s)² − (z_ref − z_s)²
    − d̂_k² + d̂_ref²``,

    one row per ``k ≠ ref``, solved for the minimum-norm ``(x_s, y_s)`` in the local frame.

    The strongest sample is chosen *because* its power is high, so its noise is biased upwards
    and its squared distance downwards (an order statistic); with many samples at similar
    distances (an orbit) that bias shifts the estimate by several CRLB standard deviations.
    ``reference="mean"`` subtracts the mean equation instead, which has no selection bias.

    Every trial at once: ``rss_dbm`` (n, N) on the samples ``position_m`` (N, 3); a trial's
    reference row is the zero row ``0 = 0``, which changes neither the solution, its cost nor
    the rank.

    Parameters
    ----------
    position_m : (N, 3)
    rss_dbm : (n, N)
        Received power ``P_k`` (MATH §1).
    rss_model : RssModel
        ``P0``, ``d0``, ``η``.
    rss_sigma_db : float
        ``σ_P``, used by the de-biasing factor.
    emitter_height_m : float
    reference : {"strongest", "mean"}
        The equation subtracted from the others: the strongest sample's (So & Lin, MATH §9)
        or the mean of all equations.

    Returns
    -------
    LinearLsColumns
        The solutions (rank 2 with two headings, 1 on a straight track) and each trial's
        reference sample (-1 for ``reference="mean"``).

    Raises
    ------
    ValueError
        With fewer than two samples (no difference row).
    """
    if reference not in ("strongest", "mean"):
        raise ValueError(f"reference: expected 'strongest' or 'mean', got {reference!r}")
    position = np.asarray(position_m, dtype=float)
    power = np.atleast_2d(np.asarray(rss_dbm, dtype=float))
    if power.shape[1] < 2:
        raise ValueError(
            f"rss_dbm: LLS-RSS needs at least two samples to form a difference row, "
            f"got {power.shape[1]}; use more samples or frames"
        )
    distance_sq = rss_squared_distance_m2(power, rss_model, rss_sigma_db)
    origin, scale = _local_frames(position, np.sqrt(distance_sq))
    unit = scale[:, None]
    xy = (position[None, :, :2] - origin) / unit[..., None]
    height = (position[:, 2] - emitter_height_m) / unit
    # equation k: ‖p_k,xy‖² + (z_k − z_s)² − d̂_k² = 2 p_k,xyᵀ s − ‖s‖²
    known = xy[..., 0] * xy[..., 0] + xy[..., 1] * xy[..., 1]
    known = known + height * height - distance_sq / (unit * unit)
    if reference == "strongest":
        index = np.argmax(power, axis=1)
        trials = np.arange(len(power))
        A = 2.0 * (xy - xy[trials, index][:, None, :])
        b = known - known[trials, index][:, None]
    else:
        index = np.full(len(power), -1, dtype=np.int64)
        count = power.shape[1]
        mean_xy = np.stack([_sample_sums(xy[..., j]) / count for j in range(2)], axis=-1)
        A = 2.0 * (xy - mean_xy[:, None, :])
        b = known - (_sample_sums(known) / count)[:, None]
    solution, cost, rank = minimum_norm_lstsq(A, b)
    return LinearLsColumns(
        position_m=solution * unit + origin,
        cost_m4=cost * scale**4,
        rank=rank,
        n_unknowns=2,
        origin_m=origin,
        scale_m=scale,
        reference=index.astype(np.int64),
    )


def solve_lls_rss(
    position_m: ArrayLike,
    rss_dbm: ArrayLike,
    rss_model: RssModel,
    rss_sigma_db: float,
    emitter_height_m: float = 0.0,
    *,
    reference: Reference = "strongest",
) -> tuple[LinearLsSolution, int | None]:
    """:func:`lls_rss_columns` of one trial (``rss_dbm`` (N,)): the solution and the index of
    the reference sample (None for ``reference="mean"``)."""
    power = np.asarray(rss_dbm, dtype=float)[None]
    columns = lls_rss_columns(
        position_m, power, rss_model, rss_sigma_db, emitter_height_m, reference=reference
    )
    assert columns.reference is not None
    index = int(columns.reference[0])
    return columns.solution(0), None if index < 0 else index


def _frames_used(batch: MeasurementBatch, frames: str) -> tuple[MeasurementSet, IntArray]:
    """The geometry of the frames used and their columns in the batch's measurements."""
    geometry = batch.geometry
    if frames == "last":
        return geometry.select_frames(frames), np.flatnonzero(geometry.frame == geometry.frame[-1])
    return geometry, np.arange(geometry.n_samples)


def _check_frames(frames: str) -> None:
    if frames not in ("all", "last"):
        raise ValueError(f"frames: expected 'all' or 'last', got {frames!r}")


NON_FINITE_MESSAGE = "least squares returned a non-finite solution"


def lls_estimate_columns(
    name: str,
    solved: LinearLsColumns,
    used: MeasurementSet,
    rngs: Sequence[np.random.Generator | None] | None,
    diagnostics: Mapping[str, NDArray[Any]],
) -> BatchEstimates:
    """The estimates of LLS solutions (one per trial of ``used``'s geometry): the mirror rule
    of MATH §7 (:func:`~estimators.mirror_rule.finalize_columns`) on each trial's one point, the
    rank and the cost reported; a non-finite solution, or samples that hover, fail."""
    n = len(solved.rank)
    generators = check_rngs(rngs, n)
    hovering = hovering_problem(used)
    finite = np.isfinite(solved.position_m).all(axis=1) & np.isfinite(solved.cost_m4)
    line = straight_track_line(used.position_m, used.velocity_mps)
    final = finalize_columns(
        solved.position_m[:, None],
        finite.astype(np.int64),
        solved.cost_m4[:, None],
        used.position_m[:, :2].mean(axis=0),
        line,
    )
    ok = finite & ~final.invalid & (hovering is None)
    chosen = final.chosen.copy()
    draw_tie_breaks(generators, final.draw & ok, final.n_candidates, chosen)
    width = final.candidates.shape[1]
    position = final.candidates[np.arange(n), np.minimum(chosen, width - 1)]
    deficient = solved.rank < solved.n_unknowns
    messages = ["", NON_FINITE_MESSAGE, hovering or ""]
    code = np.where(finite, np.where(hovering is None, 0, 2), 1)
    for rank in sorted(set(solved.rank[ok & deficient].tolist())):
        code[ok & deficient & (solved.rank == rank)] = len(messages)
        messages.append(_rank_message(rank, solved.n_unknowns))
    return BatchEstimates(
        estimator=name,
        position_m=np.where(ok[:, None], position, np.nan),
        candidates_m=np.where(ok[:, None, None], final.candidates, np.nan),
        n_candidates=np.where(ok, final.n_candidates, 0),
        ambiguous=final.ambiguous & ok,
        success=ok,
        message_code=code.astype(np.int64),
        messages=tuple(messages),
        diagnostics={
            "cost_m4": solved.cost_m4,
            "rank": solved.rank,
            "rank_deficient": deficient,
            **diagnostics,
            "n_samples": np.full(n, used.n_samples, dtype=np.int64),
            "straight_track": np.full(n, line is not None),
        },
    )


def _rank_message(rank: int, n_unknowns: int) -> str:
    return (
        f"rank-deficient system (rank {rank} of {n_unknowns}): minimum-norm "
        "solution; a straight track cannot fix the cross-track coordinate (MATH §9)"
    )


class _LinearLs(EstimatesOfColumns):
    """``estimate`` as the batch of one and ``estimate_batch`` of the LLS baselines."""

    name: ClassVar[str]
    requires: ClassVar[frozenset[str]]
    frames: Frames

    def capabilities(self) -> Capabilities:
        """One unit in every row (m², or dB-derived m²): unit-invariant; trials in batch."""
        return Capabilities(
            modalities=self.requires, frames=self.frames, unit_invariant=True, batch=True
        )

    def _columns(
        self, batch: MeasurementBatch, rngs: Sequence[np.random.Generator | None] | None
    ) -> BatchEstimates:
        raise NotImplementedError

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        check_rng(rng)
        return self.estimate_columns(MeasurementBatch.of_one(data), rngs=[rng]).estimate(0)

    def estimate_columns(
        self,
        batch: MeasurementBatch,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> BatchEstimates:
        """Every trial's estimate as columns, with its goodness of fit (MATH §17)."""
        require_batch(self, batch)
        return with_fit_columns(self, self._columns(batch, rngs), batch)


@dataclass(frozen=True, kw_only=True)
class LlsToa(_LinearLs):
    """Conventional linear least squares on squared ToA ranges, ``r_z`` free (MATH §9).

    Parameters
    ----------
    frames : {"all", "last"}
        Use every frame so far, or only the last.
    """

    name: ClassVar[str] = "lls-toa"
    requires: ClassVar[frozenset[str]] = frozenset({"toa"})

    frames: Frames = "all"

    def __post_init__(self) -> None:
        _check_frames(self.frames)

    def _columns(
        self, batch: MeasurementBatch, rngs: Sequence[np.random.Generator | None] | None
    ) -> BatchEstimates:
        used, columns = _frames_used(batch, self.frames)
        ranges = used.speed_of_light_mps * batch.toa_s[:, columns]
        solved = lls_toa_columns(used.position_m, ranges, used.emitter_height_m)
        return lls_estimate_columns(self.name, solved, used, rngs, {})


@dataclass(frozen=True, kw_only=True)
class LlsRss(_LinearLs):
    """So & Lin's linear least squares on de-biased RSS squared distances (MATH §9).

    Parameters
    ----------
    frames : {"all", "last"}
        Use every frame so far, or only the last.
    reference : {"strongest", "mean"}
        The equation subtracted from the others: the strongest sample's (So & Lin, MATH §9)
        or the mean equation (free of the strongest sample's selection bias).
    """

    name: ClassVar[str] = "lls-rss"
    requires: ClassVar[frozenset[str]] = frozenset({"rss"})

    frames: Frames = "all"
    reference: Reference = "strongest"

    def __post_init__(self) -> None:
        _check_frames(self.frames)
        if self.reference not in ("strongest", "mean"):
            raise ValueError(f"reference: expected 'strongest' or 'mean', got {self.reference!r}")

    def _columns(
        self, batch: MeasurementBatch, rngs: Sequence[np.random.Generator | None] | None
    ) -> BatchEstimates:
        used, columns = _frames_used(batch, self.frames)
        assert used.rss_model is not None and used.noise.rss_db is not None  # MeasurementSet
        solved = lls_rss_columns(
            used.position_m,
            batch.rss_dbm[:, columns],
            used.rss_model,
            used.noise.rss_db,
            used.emitter_height_m,
            reference=self.reference,
        )
        assert solved.reference is not None
        n = len(solved.rank)
        bias = rss_bias_factor(used.noise.rss_db, used.rss_model.path_loss_exponent)
        diagnostics = {"reference_sample": solved.reference, "bias_factor": np.full(n, bias)}
        return lls_estimate_columns(self.name, solved, used, rngs, diagnostics)
