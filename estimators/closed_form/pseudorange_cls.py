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
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from estimators.closed_form.cls_rows import LocalFrame, horizontal_speed_mps, project_out
from estimators.closed_form.gtrs_indefinite import (
    IndefiniteGtrsSolution,
    solve_gtrs_indefinite,
    stationary_points,
)
from scenarios import measurement_model as model
from scenarios.fisher import gram_information
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
Reference = Literal["centre", "first"] | int
OffsetMethod = Literal["relaxed", "profile"]

HYPERBOLOID = np.array([1.0, 1.0, -1.0])
"""The diagonal of D for ``θ = (x', y', ρ_j)``."""


@dataclass(frozen=True, slots=True, eq=False)
class PseudorangeSolution:
    """Minimisers of the pseudo-range CLS in world coordinates (module text).

    Attributes
    ----------
    candidates_m : (n, 2)
        Every global minimiser on the physical sheet (2 in the hard case), world metres.
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


@dataclass(frozen=True, slots=True, eq=False)
class _Rows:
    """Raw rows in the local frame, one entry per sample (the ToA row of ``ref`` is unused)."""

    ref: int
    A_d: FloatArray | None  # (N, 3)
    b_d: FloatArray | None  # (N,)
    nuisance: FloatArray | None  # (N, 2): columns of δ and w on the Doppler rows
    A_t: FloatArray  # (N, 3)
    b_t: FloatArray  # (N,)
    h_ref: float
    q: FloatArray  # (N, 2)
    h: FloatArray  # (N,)
    gv: FloatArray | None  # γ|v_xy| per sample


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


def pseudorange_frame(data: MeasurementSet, ref: int) -> LocalFrame:
    """Origin at ``p_j``'s xy, scale the RMS of the horizontal spread and the heights.

    The pseudo-ranges cannot set the scale (they carry β); the heights and the spread can.
    """
    position = data.position_m
    origin = position[ref, :2].copy()
    spread = np.mean(np.sum((position[:, :2] - position[:, :2].mean(axis=0)) ** 2, axis=1))
    heights = np.mean((position[:, 2] - data.emitter_height_m) ** 2)
    scale = float(np.sqrt(spread + heights))
    return LocalFrame(origin_m=origin, scale_m=scale if scale > 0.0 else 1.0)


def pseudorange_rows(
    data: MeasurementSet, frame: LocalFrame, ref: int, *, carrier_offset_unknown: bool
) -> _Rows:
    """The rows of the module text in the local frame (unweighted)."""
    position = frame.positions(data.position_m)
    q = position[:, :2]  # the frame's origin is p_j's xy
    h = position[:, 2] - data.emitter_height_m / frame.scale_m
    d = (data.range_m - data.range_m[ref]) / frame.scale_m
    A_t = np.column_stack([-2.0 * q, -2.0 * d])
    b_t = d**2 - np.sum(q**2, axis=1) - h**2 + h[ref] ** 2
    A_d = b_d = nuisance = gv = None
    if data.doppler_hz is not None:
        velocity = data.velocity_mps
        speed = horizontal_speed_mps(velocity)
        gamma = data.gamma_per_m
        f = data.doppler_hz
        gv = gamma * speed
        A_d = np.column_stack([velocity[:, :2] / speed[:, None], -f / gv])
        b_d = (np.einsum("ij,ij->i", velocity[:, :2], q) + velocity[:, 2] * h + d * f / gamma) / (
            speed
        )
        if carrier_offset_unknown:
            nuisance = np.column_stack([d / gv, 1.0 / gv])
    return _Rows(ref, A_d, b_d, nuisance, A_t, b_t, float(h[ref]), q, h, gv)


def _whitened_system(
    rows: _Rows, rho: FloatArray, f_bar: FloatArray | None, sigma_f: float, sigma_r: float
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """``(A, b, nuisance)`` whitened by the exact second moments of the module text.

    ``rho`` are the ranges and ``f_bar`` the offset-free Doppler (local units) at which the
    moments are evaluated.
    """
    n = len(rows.b_t)
    keep = np.arange(n) != rows.ref
    s2 = sigma_r**2
    a_t = 2.0 * rho
    var_t = 4.0 * rho**2 * s2 + 6.0 * s2**2
    n_extra = 0 if rows.nuisance is None else 2
    # columns: θ (3), rhs (1), nuisance (0 or 2), low-rank U (2)
    T = np.column_stack([rows.A_t, rows.b_t, np.zeros((n, n_extra)), s2**0.5 * a_t, 0 * rho])
    T[:, -1] = np.sqrt(2.0) * s2
    if rows.A_d is None:
        blocks = T[keep] / np.sqrt(var_t[keep])[:, None]
    else:
        a_d = np.where(keep, f_bar / rows.gv, 0.0)
        var_d = (rho**2 * sigma_f**2 + keep * (f_bar**2 * s2 + 2.0 * sigma_f**2 * s2)) / rows.gv**2
        cov = 2.0 * rho * f_bar * s2 / rows.gv
        nuisance = np.zeros((n, 0)) if rows.nuisance is None else rows.nuisance
        D = np.column_stack([rows.A_d, rows.b_d, nuisance, s2**0.5 * a_d, np.zeros(n)])
        l11 = np.sqrt(var_d)
        D = D / l11[:, None]
        l21 = cov[keep] / l11[keep]
        l22 = np.sqrt(var_t[keep] - l21**2)
        blocks = np.vstack([D, (T[keep] - l21[:, None] * D[keep]) / l22[:, None]])
    X, U = blocks[:, :-2], blocks[:, -2:]
    # (I + ŨŨᵀ)^(-1/2) = I + P (diag(1/√(1 + s²)) − I) Pᵀ for Ũ = P S Rᵀ
    P, S, _ = np.linalg.svd(U, full_matrices=False)
    X = X + P @ ((1.0 / np.sqrt(1.0 + S**2) - 1.0)[:, None] * (P.T @ X))
    A, b = X[:, :3], X[:, 3]
    return A, b, (X[:, 4:] if n_extra else None)


def _moments_at(rows: _Rows, theta: FloatArray | None, data: MeasurementSet):
    """Ranges and offset-free Doppler (local units) for the weights: stage 1 or at ``theta``."""
    n = len(rows.b_t)
    if theta is None:
        rho = np.ones(n)  # ρ̃ = the frame scale
        f_bar = None
        if data.doppler_hz is not None:
            f = data.doppler_hz
            f_bar = f - f.mean() if rows.nuisance is not None else f.copy()
        return rho, f_bar
    offset = np.column_stack([rows.q - theta[:2], rows.h])
    rho = np.linalg.norm(offset, axis=1)
    f_bar = None
    if data.doppler_hz is not None:
        radial = np.einsum("ij,ij->i", data.velocity_mps, offset) / rho
        f_bar = -data.gamma_per_m * radial
    return rho, f_bar


def solve_pseudorange_cls(
    data: MeasurementSet,
    *,
    carrier_offset_unknown: bool,
    stages: int = 2,
    reference: Reference = "centre",
    offset_method: OffsetMethod = "relaxed",
    hard_case_rtol: float = 1e-10,
) -> PseudorangeSolution:
    """Every global minimiser of the pseudo-range CLS with b unknown (module text, MATH §15).

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
    offset_method : "relaxed" or "profile"
        With δ unknown: ``"relaxed"`` is the closed form, (δ, w) free and projected out;
        ``"profile"`` then restores ``w = ρ_jδ`` and minimises the exact GLS cost over δ
        (:func:`profile_offset`, a scalar root search, one GTRS per step), with the weights
        of the last relaxed stage.

    If the global minimiser lies on the wrong sheet (``ρ_j < 0``, possible only at high
    noise) the lowest-cost stationary point on the physical sheet is returned instead and
    ``status`` says so; ``success`` is false when there is none or no definite interval.
    """
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
    offset_unknown = carrier_offset_unknown and data.doppler_hz is not None
    ref = reference_sample(data.position_m, reference)
    frame = pseudorange_frame(data, ref)
    rows = pseudorange_rows(data, frame, ref, carrier_offset_unknown=offset_unknown)
    sigma_r = data.noise.toa_s * data.speed_of_light_mps / frame.scale_m
    sigma_f = data.noise.doppler_hz if data.doppler_hz is not None else 1.0
    constraint = (HYPERBOLOID, np.zeros(3), -(rows.h_ref**2))

    theta_w: FloatArray | None = None
    for _ in range(int(stages)):
        rho, f_bar = _moments_at(rows, theta_w, data)
        A_full, b_full, N = _whitened_system(rows, rho, f_bar, sigma_f, sigma_r)
        A, b = (A_full, b_full) if N is None else project_out(A_full, b_full, N)
        gtrs = solve_gtrs_indefinite(A, b, *constraint, hard_case_rtol=hard_case_rtol)
        points, status = gtrs.points, gtrs.status
        if len(points) and np.all(points[:, 2] < 0.0):
            points, status = _physical_sheet_fallback(A, b, constraint)
        if len(points) == 0:
            break
        theta_w = points[0]

    profile = None
    if offset_unknown and offset_method == "profile" and len(points):
        relaxed = np.linalg.lstsq(N, b_full - A_full @ points[0], rcond=None)[0]
        step = max(abs(relaxed[1] / points[0, 2] - relaxed[0]), sigma_f / np.sqrt(len(N)))
        try:
            profile = profile_offset(
                A_full, b_full, N, constraint, relaxed[0], step, hard_case_rtol=hard_case_rtol
            )
        except (RuntimeError, ValueError):  # a GTRS without minimiser on the way, or no sign
            profile = None  # change of the slope: keep the relaxed estimate, and say so
        if profile is not None:
            delta, gtrs, _ = profile
            A, b = _offset_system(A_full, b_full, N, delta)
            points, status = gtrs.points, gtrs.status
            if len(points) and np.all(points[:, 2] < 0.0):
                points, status = _physical_sheet_fallback(A, b, constraint)
    elif offset_method not in ("relaxed", "profile"):
        raise ValueError(f"offset_method: expected 'relaxed' or 'profile', got {offset_method!r}")

    on_sheet = bool(len(gtrs.points) and np.all(gtrs.points[:, 2] > 0.0))
    diagnostics: dict[str, Any] = {
        "success": bool(len(points)),
        "status": status,
        "multiplier": gtrs.multiplier,
        "interval": gtrs.interval.tolist(),
        "hard_case": gtrs.hard_case,
        "hard_end": gtrs.hard_end,
        "rank": gtrs.rank,
        "reference_sample": ref,
        "sheet": ["+" if rho_j > 0 else "−" for rho_j in gtrs.points[:, 2]],
        "on_physical_sheet": on_sheet,
        "global_cost": float(gtrs.costs.min()) if len(gtrs.costs) else float("nan"),
        "stages": int(stages),
        "offset_method": offset_method if offset_unknown else None,
    }
    candidates = frame.to_world(points[:, :2]) if len(points) else np.zeros((0, 2))
    emission, offset = _nuisance_estimates(data, candidates, offset_unknown)
    if offset_unknown and offset_method == "profile" and profile is None:
        diagnostics["offset_method"] = "relaxed (profile failed)"
    if offset_unknown and len(points) and profile is None:
        relaxed = np.linalg.lstsq(N, b_full - A_full @ points[0], rcond=None)[0]
        diagnostics["relaxed_carrier_offset_hz"] = float(relaxed[0])
        diagnostics["relaxation_gap_hz"] = float(relaxed[1] / points[0, 2] - relaxed[0])
    if profile is not None:
        diagnostics["profile_evaluations"] = profile[2]
        if len(points):
            offset = np.full(len(points), profile[0])
    costs = np.sum((points @ A.T - b) ** 2, axis=1) if len(points) else np.zeros(0)
    return PseudorangeSolution(
        candidates_m=candidates,
        costs=costs,
        emission_time_s=emission,
        carrier_offset_hz=offset,
        reference_range_m=points[:, 2] * frame.scale_m if len(points) else np.zeros(0),
        diagnostics=diagnostics,
        gtrs=gtrs,
        frame=frame,
        A=A,
        b=b,
    )


def _offset_system(
    A: FloatArray, b: FloatArray, N: FloatArray, delta: float
) -> tuple[FloatArray, FloatArray]:
    """The rows with δ given and ``w = ρ_jδ`` restored: ``(A + δ N_w e₃ᵀ) θ = b − δ N_δ``."""
    A_delta = A.copy()
    A_delta[:, 2] += delta * N[:, 1]
    return A_delta, b - delta * N[:, 0]


def profile_offset(
    A: FloatArray,
    b: FloatArray,
    N: FloatArray,
    constraint: tuple[FloatArray, FloatArray, float],
    delta0: float,
    step: float,
    *,
    hard_case_rtol: float = 1e-10,
) -> tuple[float, IndefiniteGtrsSolution, int]:
    """Minimise the exact cost ``min_θ ‖(A + δN_w e₃ᵀ)θ − (b − δN_δ)‖²`` over δ (hyperboloid).

    ``A, b, N`` are whitened rows of the relaxed system (columns of N: δ, w), ``constraint``
    the ``(d, g, c)`` of the hyperboloid. The constraint
    does not depend on δ, so by the envelope theorem the profile's derivative is
    ``2 rᵀ(θ*₃ N_w + N_δ)`` at the GTRS minimiser θ* (r its residual): a root search on it
    (expanding from ``delta0`` by ``step`` until the sign changes, then Brent) reaches the
    minimum to rounding, where a search on the cost alone stops at ``√ε``. Returns
    ``(δ*, the GTRS at δ*, evaluations)``.
    """
    cache: dict[float, IndefiniteGtrsSolution] = {}

    def slope(delta: float) -> float:
        A_delta, b_delta = _offset_system(A, b, N, delta)
        solution = solve_gtrs_indefinite(
            A_delta, b_delta, *constraint, hard_case_rtol=hard_case_rtol
        )
        cache[delta] = solution
        if len(solution.points) == 0:
            raise RuntimeError(f"profile_offset: no minimiser at δ = {delta!r}")
        theta = solution.points[0]
        residual = A_delta @ theta - b_delta
        return float(2.0 * residual @ (theta[2] * N[:, 1] + N[:, 0]))

    low = high = float(delta0)
    s_low = s_high = slope(low)
    width = max(float(step), np.finfo(float).eps * max(abs(delta0), 1.0))
    for _ in range(60):
        if s_low < 0.0 < s_high or s_low == 0.0 or s_high == 0.0:
            break
        if not (np.isfinite(s_low) and np.isfinite(s_high)):
            raise RuntimeError("profile_offset: the slope is not finite")
        if s_low >= 0.0:
            low -= width
            s_low = slope(low)
        if s_high <= 0.0:
            high += width
            s_high = slope(high)
        width *= 2.0
    if s_low == 0.0 or s_high == 0.0:
        delta = low if s_low == 0.0 else high
    elif not s_low < 0.0 < s_high:
        raise RuntimeError("profile_offset: no sign change of the slope found")
    else:
        delta = brentq(slope, low, high, xtol=1e-300, rtol=4 * np.finfo(float).eps)
        slope(delta)
    return float(delta), cache[delta], len(cache)


def _physical_sheet_fallback(
    A: FloatArray, b: FloatArray, constraint: tuple[FloatArray, FloatArray, float]
) -> tuple[FloatArray, str]:
    """The lowest-cost stationary point with ``ρ_j > 0`` (the minimiser over that sheet)."""
    points, _, _ = stationary_points(A, b, *constraint)
    physical = points[points[:, 2] > 0.0]
    if len(physical) == 0:
        return np.zeros((0, 3)), "wrong-sheet-no-physical-point"
    return physical[:1], "wrong-sheet-fallback"


def _nuisance_estimates(
    data: MeasurementSet, candidates_m: FloatArray, offset_unknown: bool
) -> tuple[FloatArray, FloatArray | None]:
    """``b̂ = mean(r_k − ρ̂_k)/c`` and, when unknown, ``δ̂ = mean(f_k − f_k(ŝ))`` per candidate."""
    if len(candidates_m) == 0:
        return np.zeros(0), (np.zeros(0) if offset_unknown else None)
    ranges = model.slant_range_m(data.position_m, candidates_m, data.emitter_height_m)
    beta = np.mean(data.range_m - ranges, axis=-1)
    emission = beta / data.speed_of_light_mps
    offset = None
    if offset_unknown:
        doppler = model.doppler_hz(
            data.position_m,
            data.velocity_mps,
            candidates_m,
            data.gamma_per_m,
            data.emitter_height_m,
        )
        offset = np.mean(data.doppler_hz - doppler, axis=-1)
    return emission, offset


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
    "PseudorangeSolution",
    "profile_offset",
    "pseudorange_frame",
    "pseudorange_rows",
    "reference_sample",
    "relaxed_fisher_information",
    "solve_pseudorange_cls",
]
