r"""The closed form when the emission time is unknown: pseudo-ranges and a hyperboloid (MATH §15).

With an unknown emission time b the ToA ranges are pseudo-ranges ``r_k = cτ_k = ρ_k + β + ε_k``,
``β = cb``. Differences to a reference sample j cancel β: ``d_k = r_k − r_j``, and noise-free
``ρ_k = ρ_j + d_k``. In the local frame centred on ``p_j`` (``s' = s_xy − p_j,xy``,
``q_k = p_k,xy − p_j,xy``, ``h_k = z_k − z_s``) the unknown is ``θ = (s', ρ_j)`` and

- squared-range differences, ``k ≠ j``: ``ρ_k² − ρ_j² = d_k² + 2d_kρ_j``, i.e.
  ``[−2q_kᵀ, −2d_k] θ = d_k² − ‖q_k‖² − h_k² + h_j²``;
- Doppler·range rows (§3 with ``ρ_k = ρ_j + d_k``), every k:
  ``[v̂_kᵀ, −f_k/(γ|v_k|)] θ = (v_{k,xy}ᵀq_k + v_{z,k}h_k + d_k f_k/γ)/|v_k|``;
- with the carrier offset δ unknown too, ``(ρ_j + d_k)(f_k − δ)`` adds ``(δ d_k + w)/(γ|v_k|)``
  on the left, ``w = ρ_jδ``; (δ, w) are treated as two free unknowns and projected out. That
  is exact at noise-free; it relaxes ``w = ρ_jδ``, which costs the information of one extra
  Doppler nuisance column ``1/ρ_k`` (:func:`relaxed_fisher_information`);
- the constraint ``‖s'‖² − ρ_j² = −h_j²``, the hyperboloid of two sheets of
  :mod:`estimators.closed_form.gtrs_indefinite` (``D = diag(1, 1, −1)``); ``ρ_j > 0`` is the
  physical sheet.

**Weighting** (the analogue of §6). With ``η_k = ε_k − ε_j`` the row residuals at the truth are
exactly ``e_D,k = −(ρ_k w_k + f̄_k η_k + η_k w_k)/(γ|v_k|)`` and ``e_T,k = −(2ρ_kη_k + η_k²)``
(``f̄_k`` the Doppler without offset, ``η_j = 0``). With ``E η_kη_l = σ_r²(1 + δ_kl)`` their
second moments are per-sample 2×2 blocks, ``var D_k = (ρ_k²σ_f² + f̄_k²σ_r² +
2σ_f²σ_r²)/(γ|v_k|)²``, ``var T_k = 4ρ_k²σ_r² + 6σ_r⁴``, ``cov = 2ρ_k f̄_k σ_r²/(γ|v_k|)`` (only
``ρ_j²σ_f²/(γ|v_j|)²`` for ``D_j``), plus a rank-two part from the shared ``ε_j``: ``σ_r² a aᵀ +
2σ_r⁴ t tᵀ`` with ``a = (f̄_k/(γ|v_k|) [k ≠ j], 2ρ_k)`` and ``t`` the indicator of the ToA rows. The
rows are whitened by the block Cholesky factors and then by ``(I + ŨŨᵀ)^(−1/2)``; the nuisance
columns are projected out of the whitened rows, so the cost is the profiled generalised least
squares. Stage 1 evaluates the moments at ``ρ_k = ρ̃`` (the frame scale) and ``f̄_k = f_k`` (δ
known) or ``f_k − mean f`` (δ unknown); stage 2 at the stage-1 estimate. Whitening makes the
estimate invariant to the unit system. The reference is the sample nearest the centroid of the
track: to first order the weighted estimate does not depend on the choice (every reference spans the
same β-free differences and ``ε_j`` is carried in the weights), and a central
reference keeps ``q_k`` and ``d_k`` at half the pass, the apex of the hyperboloid mid-track.

Emission time and offset per candidate: ``β̂ = mean_k(r_k − ρ̂_k)``, ``δ̂ = mean_k(f_k − f_k(ŝ))``,
their maximum-likelihood values given ``ŝ``. On one straight frame the rows annihilate
``(v⊥, 0)``: the hard case, the emitter and its mirror at equal cost (MATH §7).

``offset_method="profile"`` undoes the relaxation: with δ given, ``w = ρ_jδ`` makes the rows
the b-only rows of ``f_k − δ``, so the exact GLS cost is a GTRS per δ, minimised over δ by a
scalar search (:func:`profile_offset`). Not a closed form any more, but efficient.

``offset_method="two-stage"`` keeps the closed form and re-imposes what the relaxation freed in
a second stage: the measurement model linearised about the relaxed estimate, one weighted least
squares in the correction, δ and β (:mod:`estimators.closed_form.pseudorange_two_stage`).

**The emitter's height unknown** (``dimension=3``; MATH §15, "The emitter's height unknown").
The frame's origin is ``p_j`` itself, ``q_k = p_k − p_j`` has three coordinates and
``θ = (x', y', z', ρ_j)``: the squared-range differences ``[−2q_kᵀ, −2d_k] θ = d_k² − ‖q_k‖²``,
the Doppler rows ``[v_kᵀ/|v_{k,xy}|, −f_k/(γ|v_{k,xy}|)] θ = (v_kᵀq_k + d_k f_k/γ)/|v_{k,xy}|``,
the same δ columns and weights, and the cone ``‖s'‖² − ρ_j² = 0`` (:data:`CONE`) for the
hyperboloid. A flight in one plane (a level one among them) leaves the height's component
normal to it to the cone: the hard case, the emitter and its reflection through the plane at
one cost, of which the mirror rule keeps the one below the UAV; a straight track fails.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import hovering_problem
from estimators.batch import BatchEstimates, check_rngs
from estimators.closed_form.cls_batch import SolveOne, draw_tie_breaks
from estimators.closed_form.cls_rows import LocalFrame, horizontal_speed_mps, project_out
from estimators.closed_form.gtrs_indefinite import STATUSES as GTRS_STATUSES
from estimators.closed_form.gtrs_indefinite import (
    IndefiniteGtrsBatch,
    IndefiniteGtrsSolution,
    solve_gtrs_indefinite_batch,
    stationary_points,
)
from estimators.closed_form.pseudorange_two_stage import linearised_correction
from estimators.mirror_rule import finalize_columns
from scenarios import measurement_model as model
from scenarios.fisher import gram_information
from scenarios.geometry import moves_horizontally, single_horizontal_point, straight_track_line
from scenarios.nuisance import position_dimension
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
Reference = Literal["centre", "first"] | int
OffsetMethod = Literal["relaxed", "profile", "two-stage"]
OFFSET_METHODS: tuple[OffsetMethod, ...] = ("relaxed", "profile", "two-stage")
"""The values of ``offset_method`` (module text, MATH §15)."""

HYPERBOLOID = np.array([1.0, 1.0, -1.0])
"""The diagonal of D for ``θ = (x', y', ρ_j)``."""

CONE = np.array([1.0, 1.0, 1.0, -1.0])
"""The diagonal of D for ``θ = (x', y', z', ρ_j)``, the emitter's height unknown (MATH §15)."""

_GTRS_FIELDS = tuple(f.name for f in fields(IndefiniteGtrsBatch))
_EPS = np.finfo(float).eps

WRONG_SHEET_NOTE = (
    "the global minimiser has a negative reference range: the best point on the physical "
    "sheet is returned (MATH §15)"
)


@dataclass(frozen=True, slots=True, eq=False)
class PseudorangeSolution:
    """Minimisers of the pseudo-range CLS in world coordinates (module text).

    Attributes
    ----------
    candidates_m : (n, d)
        Every global minimiser on the physical sheet (2 in the hard case), world metres:
        ``(x, y)``, or ``(x, y, z)`` with the height estimated.
    costs : (n,)
        The whitened, projected cost at each candidate.
    emission_time_s : (n,)
        b̂ per candidate.
    carrier_offset_hz : (n,) or None
        δ̂ per candidate when the offset is unknown.
    reference_range_m : (n,)
        ρ̂_j per candidate, metres.
    diagnostics : dict
        ``success``, ``status`` (of the GTRS, or ``"wrong-sheet-fallback"``), ``multiplier``,
        ``interval``, ``hard_case``, ``hard_end``, ``rank``, ``reference_sample``,
        ``sheet`` (``"+"``/``"−"`` of the global minimisers), ``on_physical_sheet``,
        ``global_cost``, ``stages``; with δ unknown ``relaxed_carrier_offset_hz`` and
        ``relaxation_gap_hz`` (``w/ρ̂_j − δ`` of the free (δ, w), zero at noise-free).
    gtrs : IndefiniteGtrsSolution
        The last stage's solve, in the local frame.
    frame : LocalFrame
        Centred on the reference sample.
    A, b : the last stage's whitened, projected rows in ``θ`` (local units).
    """

    candidates_m: FloatArray
    costs: FloatArray
    emission_time_s: FloatArray
    carrier_offset_hz: FloatArray | None
    reference_range_m: FloatArray
    diagnostics: dict[str, Any]
    gtrs: IndefiniteGtrsSolution
    frame: LocalFrame
    A: FloatArray = field(repr=False)
    b: FloatArray = field(repr=False)


STATUSES = (*GTRS_STATUSES, "wrong-sheet-fallback", "wrong-sheet-no-physical-point")
"""``status`` of :class:`PseudorangeBatch` indexes this: the GTRS's, or the fallback's."""


@dataclass(frozen=True, slots=True, eq=False)
class PseudorangeBatch:
    """The pseudo-range CLS of ``n`` trials of one geometry, field by field (trials first).

    Attributes
    ----------
    reference_sample : int
    frame : LocalFrame
        Centred on the reference sample (the trials share it).
    constraint : ``(d, g, c)``
        The hyperboloid ``‖s'‖² − ρ_j² = −h_j²`` in the local frame (the cone, ``c = 0``, with
        the height estimated).
    points : (n, 2, p)
        The returned minimisers ``θ = (x', y', ρ_j)`` (``(x', y', z', ρ_j)`` with the height
        estimated, p = 4) in the local frame: trial ``i``'s are
        ``points[i, :count[i]]`` (the global ones, or the physical sheet's), NaN beyond.
    count : (n,)
    status : (n,)
        An index into :data:`STATUSES`.
    gtrs : IndefiniteGtrsBatch
        Each trial's last solve (the last stage it reached).
    A, b : (n, m, p), (n, m)
        The last stage's whitened, projected rows; ``A_full``, ``b_full`` and ``nuisance``
        (None with δ known) the same rows before the projection.
    candidates_m, costs, emission_time_s, reference_range_m : (n, 2, d), (n, 2), (n, 2), (n, 2)
        Per returned point, NaN beyond ``count``; ``carrier_offset_hz`` (n, 2) or None.
    profiled, profile_evaluations : (n,), (n,)
        With ``offset_method="profile"``: the trials whose δ is the profile's (the others keep
        the relaxed estimate) and the slope evaluations of each search.
    corrected : (n,)
        With ``offset_method="two-stage"``: the trials whose every returned point is the second
        stage's (:mod:`~estimators.closed_form.pseudorange_two_stage`; a step that did not lower
        the cost leaves the relaxed point). ``points``, the candidates and their nuisance
        estimates are then the second stage's, ``costs`` its profiled cost; ``A``, ``b`` and
        ``gtrs`` stay the relaxed stage's.
    """

    reference_sample: int
    frame: LocalFrame
    constraint: tuple[FloatArray, FloatArray, float]
    points: FloatArray
    count: IntArray
    status: IntArray
    gtrs: IndefiniteGtrsBatch
    A: FloatArray = field(repr=False)
    b: FloatArray = field(repr=False)
    A_full: FloatArray = field(repr=False)
    b_full: FloatArray = field(repr=False)
    nuisance: FloatArray | None = field(repr=False)
    candidates_m: FloatArray
    costs: FloatArray
    emission_time_s: FloatArray
    carrier_offset_hz: FloatArray | None
    reference_range_m: FloatArray
    profiled: BoolArray
    profile_evaluations: IntArray
    corrected: BoolArray

    @property
    def on_physical_sheet(self) -> BoolArray:
        """Every global minimiser has ``ρ_j > 0``."""
        valid = np.arange(2)[None, :] < self.gtrs.count[:, None]
        positive = np.where(valid, self.gtrs.points[..., -1] > 0.0, True)
        return (self.gtrs.count > 0) & np.all(positive, axis=1)


@dataclass(frozen=True, slots=True, eq=False)
class _Rows:
    """Raw rows in the local frame, (trials, samples) (the ToA row of ``ref`` is unused)."""

    ref: int
    A_d: FloatArray | None  # (n, K, p): p = 3 unknowns (x', y', ρ_j), 4 with z'
    b_d: FloatArray | None  # (n, K)
    nuisance: FloatArray | None  # (n, K, 2): columns of δ and w on the Doppler rows
    A_t: FloatArray  # (n, K, p)
    b_t: FloatArray  # (n, K)
    h_ref: float  # z_j − z_s (local), 0 with the height unknown (the frame's origin is p_j)
    q: FloatArray  # (K, d): p_k − p_j, horizontal (d = 2) or 3-D (d = 3)
    h: FloatArray  # (K,): z_k − z_s (local) with the height known; q_z with it unknown
    gv: FloatArray | None  # (K,) γ|v_xy| per sample
    doppler_hz: FloatArray | None  # (n, K)

    def take(self, trials: NDArray[np.int64]) -> _Rows:
        """The rows of the trials ``trials``."""

        def part(value: FloatArray | None) -> FloatArray | None:
            return None if value is None else value[trials]

        return replace(
            self,
            A_d=part(self.A_d),
            b_d=part(self.b_d),
            nuisance=part(self.nuisance),
            A_t=self.A_t[trials],
            b_t=self.b_t[trials],
            doppler_hz=part(self.doppler_hz),
        )


def reference_sample(position_m: ArrayLike, reference: Reference = "centre") -> int:
    """The index j of the reference sample: nearest the centroid (``"centre"``), 0 or an int."""
    position = np.asarray(position_m, dtype=float)
    if reference == "centre":
        return int(np.argmin(np.sum((position - position.mean(axis=0)) ** 2, axis=1)))
    if reference == "first":
        return 0
    index = int(reference)
    if not 0 <= index < len(position):
        raise ValueError(f"reference: sample {index} outside 0..{len(position) - 1}")
    return index


def pseudorange_frame(data: MeasurementSet, ref: int, dimension: int = 2) -> LocalFrame:
    """Origin at ``p_j``'s xy, scale the RMS of the horizontal spread and the heights.

    The pseudo-ranges cannot set the scale (they carry β); the heights and the spread can:
    above the emitter, or with its height estimated (``dimension`` 3) above ``z = 0`` (the
    take-off ground). The frame's height origin is then ``z_j`` (:func:`frame_origin_m`).
    """
    position = data.position_m
    origin = position[ref, :2].copy()
    spread = np.mean(np.sum((position[:, :2] - position[:, :2].mean(axis=0)) ** 2, axis=1))
    ground = data.emitter_height_m if dimension == 2 else 0.0
    heights = np.mean((position[:, 2] - ground) ** 2)
    scale = float(np.sqrt(spread + heights))
    return LocalFrame(origin_m=origin, scale_m=scale if scale > 0.0 else 1.0)


def frame_origin_m(
    geometry: MeasurementSet, frame: LocalFrame, ref: int, dimension: int = 2
) -> FloatArray:
    """The world point of the local origin, in the coordinates estimated: ``p_j``'s xy (2,),
    or ``p_j`` (3,) with the emitter's height estimated (``world = origin + scale · local``)."""
    if dimension == 2:
        return frame.origin_m
    return np.append(frame.origin_m, geometry.position_m[ref, 2])


def pseudorange_rows(
    geometry: MeasurementSet,
    frame: LocalFrame,
    ref: int,
    range_m: FloatArray,
    doppler_hz: FloatArray | None,
    *,
    carrier_offset_unknown: bool,
    dimension: int = 2,
) -> _Rows:
    """The rows of the module text in the local frame (unweighted), for the trials' pseudo-
    ranges ``range_m`` and Doppler ``doppler_hz`` (n, K) on the samples of ``geometry``.

    With the emitter's height estimated (``dimension`` 3) the frame's origin is ``p_j`` itself, ``q_k = p_k − p_j`` has three coordinates and θ = (x', y', z', ρ_j): the height's
    column is ``−2q_{k,z}`` in the squared-range differences and ``v_{z,k}/|v_{k,xy}|`` in the
    Doppler rows (MATH §15, "The emitter's height unknown")."""
    position = frame.positions(geometry.position_m)
    if dimension == 2:
        q = position[:, :2]  # the frame's origin is p_j's xy
        h = position[:, 2] - geometry.emitter_height_m / frame.scale_m
        h_ref = float(h[ref])
    else:
        q = position.copy()
        q[:, 2] -= q[ref, 2]  # the frame's origin is p_j
        h, h_ref = q[:, 2], 0.0
    d = (range_m - range_m[:, ref : ref + 1]) / frame.scale_m
    n, k = d.shape
    A_t = np.empty((n, k, dimension + 1))
    A_t[:, :, :dimension] = -2.0 * q
    A_t[:, :, dimension] = -2.0 * d
    if dimension == 2:
        b_t = d**2 - (np.sum(q**2, axis=1) + h**2 - h[ref] ** 2)
    else:
        b_t = d**2 - np.sum(q**2, axis=1)
    A_d = b_d = nuisance = gv = None
    if doppler_hz is not None:
        velocity = geometry.velocity_mps
        speed = horizontal_speed_mps(velocity)
        gamma = geometry.gamma_per_m
        f = doppler_hz
        gv = gamma * speed
        A_d = np.empty((n, k, dimension + 1))
        A_d[:, :, :dimension] = velocity[:, :dimension] / speed[:, None]
        A_d[:, :, dimension] = -f / gv
        geometric = np.sum(velocity[:, :2] * q[:, :2], axis=1) + velocity[:, 2] * h
        b_d = (geometric + d * f / gamma) / speed
        if carrier_offset_unknown:
            nuisance = np.stack([d / gv, np.broadcast_to(1.0 / gv, d.shape)], axis=-1)
    return _Rows(ref, A_d, b_d, nuisance, A_t, b_t, h_ref, q, h, gv, doppler_hz)


def _whitened_system(
    rows: _Rows, rho: FloatArray, f_bar: FloatArray | None, sigma_f: float, sigma_r: float
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """``(A, b, nuisance)`` of every trial whitened by the exact second moments of the module
    text.

    ``rho`` are the ranges and ``f_bar`` the offset-free Doppler (local units, (n, K)) at which
    the moments are evaluated.
    """
    n, k = rows.b_t.shape
    p = rows.A_t.shape[-1]  # the unknowns θ: 3, or 4 with the height
    keep = np.arange(k) != rows.ref
    s2 = sigma_r**2
    var_t = 4.0 * rho**2 * s2 + 6.0 * s2**2
    n_extra = 0 if rows.nuisance is None else 2
    # columns: θ (p), rhs (1), nuisance (0 or 2), low-rank U (2)
    width = p + 3 + n_extra
    T = np.zeros((n, k, width))
    T[:, :, :p] = rows.A_t
    T[:, :, p] = rows.b_t
    T[:, :, -2] = s2**0.5 * (2.0 * rho)
    T[:, :, -1] = np.sqrt(2.0) * s2
    if rows.A_d is None:
        blocks = T[:, keep] / np.sqrt(var_t[:, keep])[..., None]
    else:
        gv = rows.gv
        a_d = np.where(keep, f_bar / gv, 0.0)
        var_d = (rho**2 * sigma_f**2 + keep * (f_bar**2 * s2 + 2.0 * sigma_f**2 * s2)) / gv**2
        cov = 2.0 * rho * f_bar * s2 / gv
        D = np.zeros((n, k, width))
        D[:, :, :p] = rows.A_d
        D[:, :, p] = rows.b_d
        if n_extra:
            D[:, :, p + 1 : p + 3] = rows.nuisance
        D[:, :, -2] = s2**0.5 * a_d
        l11 = np.sqrt(var_d)
        D = D / l11[..., None]
        l21 = cov[:, keep] / l11[:, keep]
        l22 = np.sqrt(var_t[:, keep] - l21**2)
        blocks = np.concatenate([D, (T[:, keep] - l21[..., None] * D[:, keep]) / l22[..., None]], 1)
    X, U = blocks[..., :-2], blocks[..., -2:]
    # (I + ŨŨᵀ)^(-1/2) = I + P (diag(1/√(1 + s²)) − I) Pᵀ for Ũ = P S Rᵀ
    P, S, _ = np.linalg.svd(U, full_matrices=False)
    X = X + P @ ((1.0 / np.sqrt(1.0 + S**2) - 1.0)[..., None] * (np.swapaxes(P, -1, -2) @ X))
    A, b = X[..., :p], X[..., p]
    return A, b, (X[..., p + 1 :] if n_extra else None)


def _moments_at(
    rows: _Rows, theta: FloatArray | None, geometry: MeasurementSet
) -> tuple[FloatArray, FloatArray | None]:
    """Ranges and offset-free Doppler (local units, (n, K)) for the weights: stage 1, or at
    each trial's ``theta`` (n, p)."""
    n, k = rows.b_t.shape
    f = rows.doppler_hz
    if theta is None:
        rho = np.ones((n, k))  # ρ̃ = the frame scale
        f_bar = None
        if f is not None:
            f_bar = f - f.mean(axis=1, keepdims=True) if rows.nuisance is not None else f.copy()
        return rho, f_bar
    velocity = geometry.velocity_mps
    heights = rows.h if rows.q.shape[1] == 2 else rows.h - theta[:, None, 2]
    doppler, ranges = model.derivatives_of_offsets(  # the noise-free model (MATH §1)
        rows.q[..., 0] - theta[:, None, 0],
        rows.q[..., 1] - theta[:, None, 1],
        heights,
        (velocity[:, 0], velocity[:, 1], velocity[:, 2]),
        geometry.gamma_per_m,
        order=0,
        values=f is not None,
    )
    return ranges[0], None if f is None else doppler[0]


def check_dimension(dimension: object) -> None:
    """One line naming the field when ``dimension`` is neither 2 nor 3."""
    if dimension not in (2, 3):
        raise ValueError(
            f"dimension: expected 2 (the emitter at the data's height) or 3 (its height "
            f"estimated), got {dimension!r}"
        )


def check_offset_method(offset_method: object) -> None:
    """One line naming the field and its values when ``offset_method`` is none of them."""
    if offset_method not in OFFSET_METHODS:
        *first, last = (repr(method) for method in OFFSET_METHODS)
        expected = f"{', '.join(first)} or {last}"
        raise ValueError(f"offset_method: expected {expected}, got {offset_method!r}")


def _check_options(data: MeasurementSet, carrier_offset_unknown: bool, stages: int) -> None:
    if data.toa_s is None:
        raise ValueError("toa_s: the pseudo-range closed form needs ToA measurements (MATH §15)")
    if (
        "carrier_offset_hz" in data.unknowns
        and not carrier_offset_unknown
        and (data.doppler_hz is not None)
    ):
        raise ValueError(
            "carrier_offset_unknown: the data declare the carrier offset unknown; pass "
            "carrier_offset_unknown=True, or data.assuming_known() to see the bias"
        )
    if int(stages) != stages or stages < 1:
        raise ValueError(f"stages: must be a whole number >= 1, got {stages!r}")


def solve_pseudorange_batch(
    geometry: MeasurementSet,
    range_m: ArrayLike,
    doppler_hz: ArrayLike | None,
    *,
    carrier_offset_unknown: bool,
    stages: int = 2,
    reference: Reference = "centre",
    offset_method: OffsetMethod = "relaxed",
    hard_case_rtol: float = 1e-10,
    dimension: int = 2,
) -> PseudorangeBatch:
    """The relaxed pseudo-range CLS (module text, MATH §15) of ``n`` trials at once.

    ``geometry`` gives the samples (positions, velocities, constants, noise σ; its own
    measurements are not used), ``range_m`` the trials' pseudo-ranges ``cτ_k`` and
    ``doppler_hz`` their Doppler (or None), both (n, K). Every trial goes through the same
    arrays: the rows, the weighting stages, the indefinite GTRS
    (:func:`~estimators.closed_form.gtrs_indefinite.solve_gtrs_indefinite_batch`); a trial
    whose global minimisers all lie on the wrong sheet gets the lowest-cost stationary point on
    the physical one, and a trial without a minimiser stops at the stage it reached. With δ
    unknown and ``offset_method="profile"`` the last stage's rows then go to
    :func:`profile_offset` (every trial at once), from the relaxed (δ, w); with
    ``offset_method="two-stage"`` every returned point goes to the second stage,
    :func:`~estimators.closed_form.pseudorange_two_stage.linearised_correction` (every trial
    and candidate at once), whose profiled cost becomes the candidate's cost.

    ``dimension`` 3 estimates the emitter's height too: θ = (x', y', z', ρ_j) on the cone
    ``‖s'‖² = ρ_j²`` (MATH §15, "The emitter's height unknown"), candidates ``(n, 2, 3)``. With
    2 (the default) the emitter is at ``geometry.emitter_height_m``, the height the data assume
    when they declare it unknown (``ml`` starts so at a few heights).
    """
    check_offset_method(offset_method)
    if int(stages) != stages or stages < 1:
        raise ValueError(f"stages: must be a whole number >= 1, got {stages!r}")
    check_dimension(dimension)
    # C order: a trial's rows then reduce in the same order in a batch of any size
    ranges = np.ascontiguousarray(range_m, dtype=float)
    doppler = None if doppler_hz is None else np.ascontiguousarray(doppler_hz, dtype=float)
    offset_unknown = carrier_offset_unknown and doppler is not None
    ref = reference_sample(geometry.position_m, reference)
    frame = pseudorange_frame(geometry, ref, dimension)
    rows = pseudorange_rows(
        geometry,
        frame,
        ref,
        ranges,
        doppler,
        carrier_offset_unknown=offset_unknown,
        dimension=dimension,
    )
    sigma_r = geometry.noise.toa_s * geometry.speed_of_light_mps / frame.scale_m
    sigma_f = geometry.noise.doppler_hz if doppler is not None else 1.0
    if dimension == 2:
        constraint = (HYPERBOLOID, np.zeros(3), -(rows.h_ref**2))
    else:  # ‖s'‖² − ρ_j² = 0: the cone of MATH §15
        constraint = (CONE, np.zeros(4), 0.0)
    origin = frame_origin_m(geometry, frame, ref, dimension)

    n = len(ranges)
    points = np.full((n, 2, dimension + 1), np.nan)
    count = np.zeros(n, dtype=np.int64)
    status = np.zeros(n, dtype=np.int64)
    last: dict[str, Any] = {}
    active = np.arange(n)
    with np.errstate(all="ignore"):
        for stage in range(int(stages)):
            part = rows if len(active) == n else rows.take(active)
            theta = None if stage == 0 else points[active, 0]
            rho, f_bar = _moments_at(part, theta, geometry)
            A_full, b_full, N = _whitened_system(part, rho, f_bar, sigma_f, sigma_r)
            A, b = (A_full, b_full) if N is None else project_out(A_full, b_full, N)
            gtrs = solve_gtrs_indefinite_batch(A, b, *constraint, hard_case_rtol=hard_case_rtol)
            found, found_count, found_status = gtrs.points.copy(), gtrs.count.copy(), gtrs.status
            valid = np.arange(2)[None, :] < found_count[:, None]
            wrong = (found_count > 0) & np.all(np.where(valid, found[..., -1] < 0.0, True), axis=1)
            for i in np.flatnonzero(wrong):
                fallback, reason = _physical_sheet_fallback(A[i], b[i], constraint)
                found[i] = np.nan
                found[i, : len(fallback)] = fallback
                found_count[i] = len(fallback)
                found_status[i] = STATUSES.index(reason)
            points[active], count[active], status[active] = found, found_count, found_status
            arrays = {"A": A, "b": b, "A_full": A_full, "b_full": b_full, "nuisance": N}
            arrays |= {name: getattr(gtrs, name) for name in _GTRS_FIELDS}
            for key, value in arrays.items():
                if value is None or len(active) == n:  # every trial reached this stage
                    last[key] = value
                    continue
                last[key] = last[key].copy()  # one stage's arrays, now merged with the next's
                last[key][active] = value
            active = active[found_count > 0]
            if active.size == 0:
                break
        profiled = np.zeros(n, dtype=bool)
        evaluations = np.zeros(n, dtype=np.int64)
        delta = None
        trials = np.flatnonzero(count > 0)
        if offset_unknown and offset_method == "profile" and trials.size:
            N = last["nuisance"][trials]
            A_full, b_full = last["A_full"][trials], last["b_full"][trials]
            theta = points[trials, 0]
            residual = b_full - (A_full @ theta[..., None])[..., 0]
            relaxed = (np.linalg.pinv(N) @ residual[..., None])[..., 0]  # the free (δ, w)
            step = np.maximum(
                np.abs(relaxed[:, 1] / theta[:, -1] - relaxed[:, 0]), sigma_f / np.sqrt(N.shape[1])
            )
            profile = profile_offset(
                A_full, b_full, N, constraint, relaxed[:, 0], step, hard_case_rtol=hard_case_rtol
            )
            evaluations[trials] = profile.evaluations
            found = np.flatnonzero(profile.found)
            done = trials[found]
            delta = profile.carrier_offset_hz[found]
            A, b = _offset_system(A_full[found], b_full[found], N[found], delta)
            at_delta = profile.gtrs
            for key in ("A", "b", *_GTRS_FIELDS):
                last[key] = last[key].copy()
            last["A"][done], last["b"][done] = A, b
            for name in _GTRS_FIELDS:
                last[name][done] = getattr(at_delta, name)[found]
            points[done] = at_delta.points[found]
            count[done] = at_delta.count[found]
            status[done] = at_delta.status[found]
            valid = np.arange(2)[None, :] < count[done, None]
            wrong = np.all(np.where(valid, points[done, :, -1] < 0.0, True), axis=1)
            for i in np.flatnonzero(wrong & (count[done] > 0)):
                fallback, reason = _physical_sheet_fallback(A[i], b[i], constraint)
                points[done[i]] = np.nan
                points[done[i], : len(fallback)] = fallback
                count[done[i]] = len(fallback)
                status[done[i]] = STATUSES.index(reason)
            profiled[done] = True
        gtrs_last = IndefiniteGtrsBatch(**{name: last[name] for name in _GTRS_FIELDS})
        valid = np.arange(2)[None, :] < count[:, None]
        residual = points @ np.swapaxes(last["A"], -1, -2) - last["b"][:, None, :]
        costs = np.where(valid, np.sum(residual**2, axis=-1), np.nan)
        candidates = points[..., :dimension] * frame.scale_m + origin
        corrected = np.zeros(n, dtype=bool)
        if offset_unknown and offset_method == "two-stage" and trials.size:
            second = linearised_correction(
                geometry, ranges[trials, None], doppler[trials, None], candidates[trials]
            )
            candidates[trials] = second.emitter_m
            costs[trials] = second.cost
            local = (second.emitter_m - origin) / frame.scale_m
            points[trials, :, :dimension] = local
            points[trials, :, -1] = np.sqrt(np.sum(local**2, axis=-1) + rows.h_ref**2)
            corrected[trials] = np.all(second.accepted | ~valid[trials], axis=1)
        emission, offset = _nuisance_estimates(
            geometry, ranges, doppler, candidates, offset_unknown
        )
        if delta is not None:  # the profile's δ for its points
            offset[profiled] = np.where(valid[profiled], delta[:, None], np.nan)
    return PseudorangeBatch(
        reference_sample=ref,
        frame=frame,
        constraint=constraint,
        points=points,
        count=count,
        status=status,
        gtrs=gtrs_last,
        A=last["A"],
        b=last["b"],
        A_full=last["A_full"],
        b_full=last["b_full"],
        nuisance=last["nuisance"],
        candidates_m=candidates,
        costs=costs,
        emission_time_s=emission,
        carrier_offset_hz=offset,
        reference_range_m=points[..., -1] * frame.scale_m,
        profiled=profiled,
        profile_evaluations=evaluations,
        corrected=corrected,
    )


def solve_pseudorange_cls(
    data: MeasurementSet,
    *,
    carrier_offset_unknown: bool,
    stages: int = 2,
    reference: Reference = "centre",
    offset_method: OffsetMethod = "relaxed",
    hard_case_rtol: float = 1e-10,
    dimension: int = 2,
) -> PseudorangeSolution:
    """Every global minimiser of the pseudo-range CLS with b unknown (module text, MATH §15).

    The relaxed closed form is :func:`solve_pseudorange_batch`'s batch of one.

    Parameters
    ----------
    data : MeasurementSet
        Needs ToA (pseudo-ranges); Doppler optional. The emission time is treated as unknown
        whether or not ``data.unknowns`` says so (with b known it is estimated, near 0).
    carrier_offset_unknown : bool
        Also treat δ as unknown (relaxed, projected out). Must be true when ``data.unknowns``
        declares it.
    stages : int
        Weighting stages (1: moments at the frame scale; 2+: at the previous estimate).
    reference : "centre", "first" or int
        The reference sample j.
    offset_method : "relaxed", "profile" or "two-stage"
        With δ unknown: ``"relaxed"`` is the closed form, (δ, w) free and projected out;
        ``"profile"`` then restores ``w = ρ_jδ`` and minimises the exact GLS cost over δ
        (:func:`profile_offset`, a scalar root search, one GTRS per step), with the weights
        of the last relaxed stage; ``"two-stage"`` corrects the relaxed candidates by the
        second stage of :mod:`~estimators.closed_form.pseudorange_two_stage` (closed form).
    dimension : 2 or 3
        3: estimate the emitter's height too, ``(x, y, z)`` candidates (MATH §15, "The
        emitter's height unknown"); 2: the emitter at ``data.emitter_height_m``.

    If the global minimiser lies on the wrong sheet (``ρ_j < 0``, possible only at high
    noise) the lowest-cost stationary point on the physical sheet is returned instead and
    ``status`` says so; ``success`` is false when there is none or no definite interval.
    """
    _check_options(data, carrier_offset_unknown, stages)
    offset_unknown = carrier_offset_unknown and data.doppler_hz is not None
    batch = solve_pseudorange_batch(
        data,
        data.range_m[None],
        None if data.doppler_hz is None else data.doppler_hz[None],
        carrier_offset_unknown=carrier_offset_unknown,
        stages=stages,
        reference=reference,
        offset_method=offset_method,
        hard_case_rtol=hard_case_rtol,
        dimension=dimension,
    )
    ref, frame = batch.reference_sample, batch.frame
    count = int(batch.count[0])
    points, status = batch.points[0, :count], STATUSES[int(batch.status[0])]
    gtrs = batch.gtrs.solution(0)
    A, b = batch.A[0], batch.b[0]
    A_full, b_full = batch.A_full[0], batch.b_full[0]
    N = None if batch.nuisance is None else batch.nuisance[0]
    candidates = batch.candidates_m[0, :count]
    emission = batch.emission_time_s[0, :count]
    offset = None if batch.carrier_offset_hz is None else batch.carrier_offset_hz[0, :count]
    costs = batch.costs[0, :count]
    profiled = bool(batch.profiled[0])

    on_sheet = bool(len(gtrs.points) and np.all(gtrs.points[:, -1] > 0.0))
    diagnostics: dict[str, Any] = {
        "success": bool(len(points)),
        "status": status,
        "multiplier": gtrs.multiplier,
        "interval": gtrs.interval.tolist(),
        "hard_case": gtrs.hard_case,
        "hard_end": gtrs.hard_end,
        "rank": gtrs.rank,
        "reference_sample": ref,
        "sheet": ["+" if rho_j > 0 else "−" for rho_j in gtrs.points[:, -1]],
        "on_physical_sheet": on_sheet,
        "global_cost": float(gtrs.costs.min()) if len(gtrs.costs) else float("nan"),
        "stages": int(stages),
        "offset_method": offset_method if offset_unknown else None,
    }
    if offset_unknown and offset_method == "profile" and not profiled:
        diagnostics["offset_method"] = "relaxed (profile failed)"
    if offset_unknown and offset_method == "two-stage":
        diagnostics["second_stage_accepted"] = bool(batch.corrected[0])
    elif offset_unknown and len(points) and not profiled:
        relaxed = np.linalg.lstsq(N, b_full - A_full @ points[0], rcond=None)[0]
        diagnostics["relaxed_carrier_offset_hz"] = float(relaxed[0])
        diagnostics["relaxation_gap_hz"] = float(relaxed[1] / points[0, -1] - relaxed[0])
    if profiled:
        diagnostics["profile_evaluations"] = int(batch.profile_evaluations[0])
    return PseudorangeSolution(
        candidates_m=candidates,
        costs=costs,
        emission_time_s=emission,
        carrier_offset_hz=offset,
        reference_range_m=points[:, -1] * frame.scale_m if len(points) else np.zeros(0),
        diagnostics=diagnostics,
        gtrs=gtrs,
        frame=frame,
        A=A,
        b=b,
    )


def _offset_system(
    A: FloatArray, b: FloatArray, N: FloatArray, delta: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The rows with δ given and ``w = ρ_jδ`` restored: ``(A + δ N_w e_ρᵀ) θ = b − δ N_δ``, per
    trial (``A`` (n, m, p), ``b`` (n, m), ``N`` (n, m, 2), ``delta`` (n,); ``e_ρ`` selects
    ``ρ_j``, the last unknown)."""
    A_delta = A.copy()
    A_delta[..., -1] += delta[:, None] * N[..., 1]
    return A_delta, b - delta[:, None] * N[..., 0]


@dataclass(frozen=True, slots=True, eq=False)
class ProfiledOffset:
    """:func:`profile_offset` of ``n`` trials: δ* (n,), the GTRS at δ*, whether the search
    found it (else the relaxed estimate stays), and the slope evaluations per trial."""

    carrier_offset_hz: FloatArray
    gtrs: IndefiniteGtrsBatch
    found: BoolArray
    evaluations: IntArray


def profile_offset(
    A: FloatArray,
    b: FloatArray,
    N: FloatArray,
    constraint: tuple[FloatArray, FloatArray, float],
    delta0: FloatArray,
    step: FloatArray,
    *,
    hard_case_rtol: float = 1e-10,
) -> ProfiledOffset:
    """Minimise the exact cost ``min_θ ‖(A + δN_w e_ρᵀ)θ − (b − δN_δ)‖²`` over δ (hyperboloid,
    or cone with the height unknown), for ``n`` trials at once.

    ``A, b, N`` are whitened rows of the relaxed systems (n, m, ·) (columns of N: δ, w),
    ``constraint`` the ``(d, g, c)`` of the hyperboloid. The constraint does not depend on δ,
    so by the envelope theorem the profile's derivative is ``2 rᵀ(ρ*_j N_w + N_δ)`` at the GTRS
    minimiser θ* (r its residual): a root search on it (expanding from ``delta0`` by ``step``
    until the sign changes, then Brent's method, :func:`_brent_root`) reaches the minimum to
    rounding, where a search on the cost alone stops at ``√ε``. Each step solves
    the GTRS of every trial still searching at once. A trial whose GTRS has no minimiser on the
    way, or whose slope changes no sign, is not ``found``.
    """
    n = len(A)
    evaluations = np.zeros(n, dtype=np.int64)

    def slope(delta: FloatArray, at: NDArray[np.int64]) -> tuple[FloatArray, IndefiniteGtrsBatch]:
        A_delta, b_delta = _offset_system(A[at], b[at], N[at], delta)
        gtrs = solve_gtrs_indefinite_batch(
            A_delta, b_delta, *constraint, hard_case_rtol=hard_case_rtol
        )
        evaluations[at] += 1
        theta = gtrs.points[:, 0]
        residual = (A_delta @ theta[..., None])[..., 0] - b_delta
        value = 2.0 * np.sum(residual * (theta[:, -1:] * N[at][..., 1] + N[at][..., 0]), axis=1)
        return np.where(gtrs.count > 0, value, np.nan), gtrs

    delta0 = np.asarray(delta0, dtype=float)
    every = np.arange(n)
    low, high = delta0.copy(), delta0.copy()
    s_low = slope(delta0, every)[0]
    s_high = s_low.copy()
    width = np.maximum(step, _EPS * np.maximum(np.abs(delta0), 1.0))
    failed = np.zeros(n, dtype=bool)
    for _ in range(60):
        bracketed = ((s_low < 0.0) & (s_high > 0.0)) | (s_low == 0.0) | (s_high == 0.0)
        failed |= ~bracketed & ~(np.isfinite(s_low) & np.isfinite(s_high))
        searching = np.flatnonzero(~bracketed & ~failed)
        if searching.size == 0:
            break
        lower = searching[s_low[searching] >= 0.0]
        if lower.size:
            low[lower] -= width[lower]
            s_low[lower] = slope(low[lower], lower)[0]
        upper = searching[s_high[searching] <= 0.0]
        if upper.size:
            high[upper] += width[upper]
            s_high[upper] = slope(high[upper], upper)[0]
        width[searching] *= 2.0
    at_low = ~failed & (s_low == 0.0)
    at_high = ~failed & ~at_low & (s_high == 0.0)
    inside = ~failed & ~at_low & ~at_high & (s_low < 0.0) & (s_high > 0.0)
    failed |= ~(at_low | at_high | inside)
    delta = np.where(at_low, low, high)
    rows = np.flatnonzero(inside)
    if rows.size:
        delta[rows], lost = _brent_root(
            lambda x, at: slope(x, rows[at])[0], low[rows], high[rows], s_low[rows], s_high[rows]
        )
        failed[rows[lost]] = True
    delta[failed] = np.nan
    found = np.flatnonzero(~failed)
    value, at_delta = slope(delta[found], found)
    failed[found[np.isnan(value)]] = True
    merged = {}  # the GTRS at δ* of the trials found; NaN and zeros for the others
    for name in _GTRS_FIELDS:
        value_found = getattr(at_delta, name)
        column = np.zeros((n, *value_found.shape[1:]), dtype=value_found.dtype)
        if column.dtype.kind == "f":
            column[:] = np.nan
        column[found] = value_found
        merged[name] = column
    return ProfiledOffset(
        carrier_offset_hz=np.where(failed, np.nan, delta),
        gtrs=IndefiniteGtrsBatch(**merged),
        found=~failed,
        evaluations=evaluations,
    )


def _brent_root(
    function, low: FloatArray, high: FloatArray, f_low: FloatArray, f_high: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """The root in ``[low, high]`` of each of a set of functions whose values at the ends have
    opposite signs, by Brent's method step for step as scipy's ``brentq`` takes it
    (``xtol = 1e-300``, ``rtol = 4ε``, 100 iterations), every function of the set at once.

    ``function(x, at)`` returns the values at ``x`` of the functions ``at`` (indices into the
    set); a NaN value, or no convergence in 100 iterations, loses that function (the second
    result).
    """
    xtol, rtol = 1e-300, 4.0 * _EPS
    xpre, xcur, fpre, fcur = low.copy(), high.copy(), f_low.copy(), f_high.copy()
    xblk, fblk = np.zeros_like(xpre), np.zeros_like(xpre)
    spre, scur = np.zeros_like(xpre), np.zeros_like(xpre)
    lost = np.zeros(len(xpre), dtype=bool)
    active = np.arange(len(xpre))
    for _ in range(100):
        at = active
        xp, xc, xb = xpre[at], xcur[at], xblk[at]
        fp, fc, fb = fpre[at], fcur[at], fblk[at]
        sp, sc = spre[at], scur[at]
        straddle = (fp != 0.0) & (fc != 0.0) & (np.signbit(fp) != np.signbit(fc))
        xb, fb = np.where(straddle, xp, xb), np.where(straddle, fp, fb)
        sp, sc = np.where(straddle, xc - xp, sp), np.where(straddle, xc - xp, sc)
        swap = np.abs(fb) < np.abs(fc)
        xp, xc, xb = np.where(swap, xc, xp), np.where(swap, xb, xc), np.where(swap, xc, xb)
        fp, fc, fb = np.where(swap, fc, fp), np.where(swap, fb, fc), np.where(swap, fc, fb)
        delta = (xtol + rtol * np.abs(xc)) / 2.0
        sbis = (xb - xc) / 2.0
        converged = (fc == 0.0) | (np.abs(sbis) < delta)
        xcur[at], xpre[at], xblk[at] = xc, xp, xb
        fcur[at], fpre[at], fblk[at] = fc, fp, fb
        spre[at], scur[at] = sp, sc
        active = at[~converged]
        if active.size == 0:
            break
        keep = ~converged
        xp, xc, xb, fp, fc, fb = xp[keep], xc[keep], xb[keep], fp[keep], fc[keep], fb[keep]
        sp, sc, delta, sbis = sp[keep], sc[keep], delta[keep], sbis[keep]
        with np.errstate(all="ignore"):
            interpolate = -fc * (xc - xp) / (fc - fp)
            dpre = (fp - fc) / (xp - xc)
            dblk = (fb - fc) / (xb - xc)
            extrapolate = -fc * (fb * dblk - fp * dpre) / (dblk * dpre * (fb - fp))
        stry = np.where(xp == xb, interpolate, extrapolate)
        trying = (np.abs(sp) > delta) & (np.abs(fc) < np.abs(fp))
        good = trying & (2.0 * np.abs(stry) < np.minimum(np.abs(sp), 3.0 * np.abs(sbis) - delta))
        sp, sc = np.where(good, sc, sbis), np.where(good, stry, sbis)
        xp, fp = xc, fc
        xc = xc + np.where(np.abs(sc) > delta, sc, np.where(sbis > 0.0, delta, -delta))
        fc = function(xc, active)
        xpre[active], fpre[active], xcur[active], fcur[active] = xp, fp, xc, fc
        spre[active], scur[active] = sp, sc
        lost[active[np.isnan(fc)]] = True
        active = active[~np.isnan(fc)]
    lost[active] = True  # no convergence in 100 iterations
    return xcur, lost


def _physical_sheet_fallback(
    A: FloatArray, b: FloatArray, constraint: tuple[FloatArray, FloatArray, float]
) -> tuple[FloatArray, str]:
    """The lowest-cost stationary point with ``ρ_j > 0`` (the minimiser over that sheet)."""
    points, _, _ = stationary_points(A, b, *constraint)
    physical = points[points[:, -1] > 0.0]
    if len(physical) == 0:
        return np.zeros((0, A.shape[-1])), "wrong-sheet-no-physical-point"
    return physical[:1], "wrong-sheet-fallback"


def _nuisance_estimates(
    geometry: MeasurementSet,
    range_m: FloatArray,
    doppler_hz: FloatArray | None,
    candidates_m: FloatArray,
    offset_unknown: bool,
) -> tuple[FloatArray, FloatArray | None]:
    """``b̂ = mean(r_k − ρ̂_k)/c`` and, when unknown, ``δ̂ = mean(f_k − f_k(ŝ))`` per candidate:
    ``candidates_m`` (n, c, 2), or (n, c, 3) with the height, of the trials' ``range_m`` and
    ``doppler_hz`` (n, K)."""
    ranges = model.slant_range_m(geometry.position_m, candidates_m, geometry.emitter_height_m)
    emission = np.mean(range_m[:, None, :] - ranges, axis=-1) / geometry.speed_of_light_mps
    offset = None
    if offset_unknown:
        doppler = model.doppler_hz(
            geometry.position_m,
            geometry.velocity_mps,
            candidates_m,
            geometry.gamma_per_m,
            geometry.emitter_height_m,
        )
        offset = np.mean(doppler_hz[:, None, :] - doppler, axis=-1)
    return emission, offset


def estimate_pseudorange_columns(
    name: str,
    batch: MeasurementBatch,
    frames: str,
    rngs: Sequence[np.random.Generator | None] | None,
    side_prior_m: tuple[float, float] | None,
    solve_one: SolveOne,
    offset_method: OffsetMethod = "relaxed",
) -> BatchEstimates:
    """The pseudo-range closed form's estimates of every trial of ``batch``, as columns.

    What ``estimate`` of :mod:`estimators.closed_form.cls` returns trial by trial with an
    unknown emission time (MATH §15): :func:`solve_pseudorange_batch` on the frames used, the
    hard-case pair left of the last heading first (with the height unknown: the lower first)
    and the mirror rule of :func:`~estimators.mirror_rule.finalize_columns`; ties draw from
    each trial's generator, in trial order. When the samples used hover every trial goes to
    ``solve_one``, whose ``finalize_estimate`` fails it with the reason (with the height
    unknown: every trial fails here, with it). With the emitter's height unknown the columns
    are 3-D, a candidate above the UAV is dropped, and a straight
    track fails every trial with :data:`~estimators.mirror_rule.STRAIGHT_TRACK_HEIGHT`.
    """
    n = batch.n_trials
    generators = check_rngs(rngs, n)
    geometry = batch.geometry
    used = geometry.select_frames(frames)
    dimension = position_dimension(used.unknowns)
    hovering = hovering_problem(used)
    if hovering is not None and dimension == 3:
        return BatchEstimates.failed(n, hovering, estimator=name, dimension=3)
    if single_horizontal_point(used.position_m) and not moves_horizontally(used.velocity_mps):
        redo = [solve_one(batch.trial(i), rng) for i, rng in enumerate(generators)]
        return BatchEstimates.from_estimates(name, redo)
    if frames == "last":
        columns = np.flatnonzero(geometry.frame == geometry.frame[-1])
    else:
        columns = np.arange(geometry.n_samples)
    offset_unknown = "carrier_offset_hz" in used.unknowns
    solution = solve_pseudorange_batch(
        used,
        geometry.speed_of_light_mps * batch.toa_s[:, columns],
        None if batch.doppler_hz is None else batch.doppler_hz[:, columns],
        carrier_offset_unknown=offset_unknown,
        offset_method=offset_method,
        dimension=dimension,
    )
    success = solution.count > 0
    hard = solution.gtrs.hard_case
    # ordered_candidates: the hard-case pair left of the last heading first (3-D: the lower
    # first), at one cost; on a straight track (2-D) only that one (the mirror rule adds the
    # other)
    candidates, count = solution.candidates_m.copy(), solution.count.copy()
    three_d = candidates.shape[-1] == 3
    pair = hard & (count == 2)
    if three_d:
        swap = pair & (candidates[:, 0, 2] > candidates[:, 1, 2])
    else:
        velocity = used.velocity_mps[-1]
        left = np.array([-velocity[1], velocity[0]])
        swap = pair & ((candidates[:, 0] - candidates[:, 1]) @ left < 0.0)
    candidates[swap] = candidates[swap, ::-1]
    costs = np.where(pair[:, None], np.min(solution.costs, axis=1)[:, None], solution.costs)
    line = straight_track_line(used.position_m, used.velocity_mps)
    if line is not None and not three_d:
        count = np.where(pair, 1, count)
    ceiling = float(used.position_m[:, 2].max()) if three_d else None
    with np.errstate(invalid="ignore"):
        final = finalize_columns(
            candidates,
            count,
            costs,
            used.position_m[:, :2].mean(axis=0),
            line,
            side_prior_m=side_prior_m,
            ceiling_m=ceiling,
        )
    ok = success & ~final.invalid
    n_kept = np.where(ok, final.n_candidates, 0)
    chosen = final.chosen.copy()
    draw_tie_breaks(generators, final.draw & ok, n_kept, chosen)
    width = final.candidates.shape[1]
    position = final.candidates[np.arange(n), np.minimum(chosen, width - 1)]
    pair_note = (
        "hard case: the emitter and its reflection through the flight plane (MATH §15)"
        if three_d
        else "hard case: mirror pair (MATH §15)"
    )
    messages = [
        "",
        pair_note,
        WRONG_SHEET_NOTE,
        f"{pair_note}; {WRONG_SHEET_NOTE}",
        *(f"pseudo-range closed form: {status} (MATH §15)" for status in STATUSES),
        final.problem or "pseudo-range closed form: no finite candidate (MATH §15)",
    ]
    wrong_sheet = ~solution.on_physical_sheet
    # a geometry that locates nothing (final.problem) says so for every trial
    fails = success | bool(final.problem)
    code = np.where(
        ok, hard + 2 * wrong_sheet, np.where(fails, len(messages) - 1, 4 + solution.status)
    )
    diagnostics: dict[str, NDArray[Any]] = {
        "status": np.array(STATUSES, dtype=object)[solution.status],
        "multiplier": solution.gtrs.multiplier,
        "hard_case": hard,
        "rank": solution.gtrs.rank,
        "stages": np.full(n, 2, dtype=np.int64),
        "n_samples": np.full(n, used.n_samples, dtype=np.int64),
        "emission_time_s": solution.emission_time_s[:, 0],
    }
    if solution.carrier_offset_hz is not None:
        diagnostics["carrier_offset_hz"] = solution.carrier_offset_hz[:, 0]
    diagnostics["straight_track"] = np.full(n, line is not None)
    columns_out = BatchEstimates(
        estimator=name,
        position_m=np.where(ok[:, None], position, np.nan),
        candidates_m=np.where(ok[:, None, None], final.candidates, np.nan),
        n_candidates=np.where(ok, n_kept, 0),
        ambiguous=final.ambiguous & ok,
        success=ok,
        message_code=code.astype(np.int64),
        messages=tuple(messages),
        diagnostics=diagnostics,
    )
    return columns_out


def relaxed_fisher_information(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    *,
    unknowns: Iterable[str] = ("carrier_offset_hz", "emission_time_s"),
) -> FloatArray:
    """The information for ``(x_s, y_s)`` of the model the relaxed closed form fits (2, 2).

    Relaxing ``w = ρ_jδ`` turns the Doppler model into
    ``f_k = −γv_kᵀu_k + δ + ω/ρ_k`` with one more free nuisance ω (``= w − ρ_jδ``, true
    value 0). The bound of that model projects the whitened Doppler gradients off
    ``span{1, 1/ρ_k}`` and centres the ToA gradients (b unknown). ``unknowns`` without the
    carrier offset gives the ordinary b-unknown information (no relaxation).
    """
    emitter = np.asarray(emitter_m, dtype=float)
    blocks = [
        model.toa_jacobian(data.position_m, emitter, data.speed_of_light_mps, data.emitter_height_m)
        / data.noise.toa_s
    ]
    if "emission_time_s" in unknowns:
        blocks[0] = blocks[0] - blocks[0].mean(axis=0)
    if data.doppler_hz is not None:
        gradient = (
            model.doppler_jacobian(
                data.position_m, data.velocity_mps, emitter, data.gamma_per_m, data.emitter_height_m
            )
            / data.noise.doppler_hz
        )
        if "carrier_offset_hz" in unknowns:
            rho = model.slant_range_m(data.position_m, emitter, data.emitter_height_m)
            Qn, _ = np.linalg.qr(np.column_stack([np.ones_like(rho), 1.0 / rho]))
            gradient = gradient - Qn @ (Qn.T @ gradient)
        blocks.append(gradient)
    return gram_information(np.vstack(blocks))


__all__ = [
    "HYPERBOLOID",
    "STATUSES",
    "WRONG_SHEET_NOTE",
    "ProfiledOffset",
    "PseudorangeBatch",
    "PseudorangeSolution",
    "estimate_pseudorange_columns",
    "profile_offset",
    "pseudorange_frame",
    "pseudorange_rows",
    "reference_sample",
    "relaxed_fisher_information",
    "solve_pseudorange_batch",
    "solve_pseudorange_cls",
]
