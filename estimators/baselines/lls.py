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

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Capabilities, Estimate, finalize_estimate, require_modalities
from estimators.closed_form.cls_rows import LocalFrame, toa_rows
from estimators.goodness_of_fit import with_fit
from scenarios.types import MeasurementSet, RssModel

FloatArray = NDArray[np.float64]
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


def _minimum_norm_lstsq(A: FloatArray, b: FloatArray) -> tuple[FloatArray, float, int]:
    """``numpy.linalg.lstsq`` with the rank threshold :data:`RANK_RTOL`; residual recomputed.

    ``lstsq`` reports no residual for a rank-deficient system, so it is evaluated here.
    """
    solution, _, rank, _ = np.linalg.lstsq(A, b, rcond=RANK_RTOL)
    residual = A @ solution - b
    return solution, float(residual @ residual), int(rank)


def solve_lls_toa(
    position_m: ArrayLike, range_m: ArrayLike, emitter_height_m: float = 0.0
) -> LinearLsSolution:
    """Ordinary least squares on the squared-range rows with ``r_z`` free (MATH §9, §4).

    Solves ``[−2x_k, −2y_k, 1] (x_s, y_s, r_z) = r_k² − x_k² − y_k² − (z_k − z_s)²`` (paper eq
    ``Beq``, height term included) for the minimum-norm ``(x_s, y_s, r_z)`` in the centred,
    scaled local frame, and drops ``r_z``.

    Parameters
    ----------
    position_m : (N, 3)
        UAV positions.
    range_m : (N,)
        Measured ranges ``r_k = c τ_k`` (MATH §1).
    emitter_height_m : float
        The known ``z_s``.

    Returns
    -------
    LinearLsSolution
        Rank 3 with two headings; rank 2 on a straight track, where the minimum-norm solution
        lies on the track (its cross-track coordinate is unobservable to this system).
    """
    position = np.asarray(position_m, dtype=float)
    ranges = np.asarray(range_m, dtype=float)
    frame = LocalFrame.fit(position, ranges)
    A, b = toa_rows(
        frame.positions(position), ranges / frame.scale_m, emitter_height_m / frame.scale_m
    )
    solution, cost, rank = _minimum_norm_lstsq(A, b)
    return LinearLsSolution(
        position_m=frame.to_world(solution[:2]),
        cost_m4=cost * frame.scale_m**4,
        rank=rank,
        n_unknowns=3,
        frame=frame,
    )


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


def solve_lls_rss(
    position_m: ArrayLike,
    rss_dbm: ArrayLike,
    rss_model: RssModel,
    rss_sigma_db: float,
    emitter_height_m: float = 0.0,
    *,
    reference: Reference = "strongest",
) -> tuple[LinearLsSolution, int | None]:
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

    Parameters
    ----------
    position_m : (N, 3)
    rss_dbm : (N,)
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
    (LinearLsSolution, int or None)
        The solution (rank 2 with two headings, 1 on a straight track) and the index of the
        reference sample (None for ``reference="mean"``).

    Raises
    ------
    ValueError
        With fewer than two samples (no difference row).
    """
    if reference not in ("strongest", "mean"):
        raise ValueError(f"reference: expected 'strongest' or 'mean', got {reference!r}")
    position = np.asarray(position_m, dtype=float)
    power = np.asarray(rss_dbm, dtype=float)
    if len(power) < 2:
        raise ValueError(
            f"rss_dbm: LLS-RSS needs at least two samples to form a difference row, "
            f"got {len(power)}; use more samples or frames"
        )
    distance_sq = rss_squared_distance_m2(power, rss_model, rss_sigma_db)
    frame = LocalFrame.fit(position, np.sqrt(distance_sq))
    local = frame.positions(position)
    xy = local[:, :2]
    height_sq = (local[:, 2] - emitter_height_m / frame.scale_m) ** 2
    # equation k: ‖p_k,xy‖² + (z_k − z_s)² − d̂_k² = 2 p_k,xyᵀ s − ‖s‖²
    known = np.sum(xy**2, axis=1) + height_sq - distance_sq / frame.scale_m**2
    if reference == "strongest":
        index: int | None = int(np.argmax(power))
        others = np.arange(len(power)) != index
        A = 2.0 * (xy[others] - xy[index])
        b = known[others] - known[index]
    else:
        index = None
        A = 2.0 * (xy - xy.mean(axis=0))
        b = known - known.mean()
    solution, cost, rank = _minimum_norm_lstsq(A, b)
    result = LinearLsSolution(
        position_m=frame.to_world(solution),
        cost_m4=cost * frame.scale_m**4,
        rank=rank,
        n_unknowns=2,
        frame=frame,
    )
    return result, index


def _check_frames(frames: str) -> None:
    if frames not in ("all", "last"):
        raise ValueError(f"frames: expected 'all' or 'last', got {frames!r}")


def _lls_estimate(
    name: str,
    solution: Any,
    used: MeasurementSet,
    rng: np.random.Generator | None,
    **diagnostics: Any,
) -> Estimate:
    """The estimate of an LLS solution: failed if non-finite, else rank and cost reported."""
    if not np.all(np.isfinite(solution.position_m)):
        return Estimate.failed(name, "least squares returned a non-finite solution")
    return finalize_estimate(
        name,
        solution.position_m,
        [solution.cost_m4],
        used,
        rng=rng,
        message=_rank_message(solution),
        diagnostics={
            "cost_m4": solution.cost_m4,
            "rank": solution.rank,
            "rank_deficient": solution.rank_deficient,
            **diagnostics,
        },
    )


def _rank_message(solution: LinearLsSolution) -> str:
    if not solution.rank_deficient:
        return ""
    return (
        f"rank-deficient system (rank {solution.rank} of {solution.n_unknowns}): minimum-norm "
        "solution; a straight track cannot fix the cross-track coordinate (MATH §9)"
    )


@dataclass(frozen=True, kw_only=True)
class LlsToa:
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

    def capabilities(self) -> Capabilities:
        """One unit in every row (m², or dB-derived m²): unit-invariant."""
        return Capabilities(modalities=self.requires, frames=self.frames, unit_invariant=True)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        used = data.select_frames(self.frames)
        solution = solve_lls_toa(used.position_m, used.range_m, used.emitter_height_m)
        estimate = _lls_estimate(self.name, solution, used, rng, n_samples=used.n_samples)
        return with_fit(self, estimate, data)


@dataclass(frozen=True, kw_only=True)
class LlsRss:
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

    def capabilities(self) -> Capabilities:
        """One unit in every row (m², or dB-derived m²): unit-invariant."""
        return Capabilities(modalities=self.requires, frames=self.frames, unit_invariant=True)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        used = data.select_frames(self.frames)
        assert used.rss_model is not None and used.noise.rss_db is not None  # MeasurementSet
        solution, reference = solve_lls_rss(
            used.position_m,
            used.rss_dbm,
            used.rss_model,
            used.noise.rss_db,
            used.emitter_height_m,
            reference=self.reference,
        )
        estimate = _lls_estimate(
            self.name,
            solution,
            used,
            rng,
            reference_sample=-1 if reference is None else reference,
            bias_factor=rss_bias_factor(used.noise.rss_db, used.rss_model.path_loss_exponent),
            n_samples=used.n_samples,
        )
        return with_fit(self, estimate, data)
