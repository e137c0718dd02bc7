r"""The closed-form Doppler-ToA constrained least squares (MATH §3-§6) and the paper's versions.

Three estimators share one pipeline, :func:`solve_doppler_toa_cls`:

``cls`` (:class:`Cls`)
    The corrected method: one Doppler·range row per sample (§3), squared-range rows with the
    height term (§4), the exact GTRS solve whose hard case returns both mirror minimisers (§5),
    and two-stage optimal weighting by the exact second moments (§6), which makes it invariant
    to the unit system, the speed and the heading.
``cls-paper`` (:class:`ClsPaper`)
    The paper's unweighted system with its errata fixed: one projected Doppler row per frame at
    the paper's scale ``K|v|²`` (MATH §3), the height term, the transpose, λ solved exactly.
``cls-as-printed`` (:class:`ClsAsPrinted`)
    The printed formulas: the first row of the rank-one Doppler system and no height term, λ
    solved exactly. On the paper's own scenario its noise-free answer is (35, ±52.2), not
    (35, ±15). Kept only to show what the errors cost.

Unweighted variants minimise the rows as written in SI units, as the paper does: a ToA residual
in m², the paper's Doppler rows (``cls-paper``, ``cls-as-printed``) in m³/s², the per-sample unit
rows of ``cls(weighting="none")`` in metres. In an unweighted least squares the scale of a row is
its weight, so these variants depend on the unit system (MATH §3, §6); the weighted ``cls`` does
not. All are solved in a centred, scaled frame for conditioning.

Each exposes the system it minimises, ``constrained_ls(data)`` (the rows of the last stage, in
its local frame; :mod:`estimators.constrained_ls`), so that ``emitterbench validate --estimator``
can check its candidates against the exact optimum and the SDP relaxation (MATH §5, §11).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from estimators.base import Capabilities, Estimate, finalize_estimate, require_modalities
from estimators.cls_rows import (
    LocalFrame,
    doppler_rows,
    doppler_rows_as_printed,
    frame_mean_rows,
    horizontal_speed_mps,
    paper_row_scale_m2ps2,
    sample_pair_covariance,
    toa_rows,
    whiten_sample_pairs,
)
from estimators.constrained_ls import ConstrainedLS
from estimators.gtrs import GtrsSolution, solve_gtrs
from scenarios import measurement_model as model
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
Rows = Literal["weighted", "per-sample", "per-frame", "as-printed"]
Frames = Literal["all", "last"]


@dataclass(frozen=True, slots=True, eq=False)
class ClsSolution:
    """Minimisers in world coordinates with the GTRS diagnostics of the last stage.

    ``A``, ``b`` are the rows of the last stage in ``frame``: the system ``gtrs`` solves.
    """

    candidates_m: FloatArray
    costs: FloatArray
    gtrs: GtrsSolution
    frame: LocalFrame
    stages: int
    A: FloatArray
    b: FloatArray


def cls_rows(
    data: MeasurementSet,
    frame: LocalFrame,
    rows: Rows,
    *,
    weights_at_local_xy: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The stacked system ``B⁺ r = p⁺`` of MATH §5 in the local frame, for one row variant.

    ``weighted``: per-sample Doppler and ToA rows, whitened per sample with
    the MATH §6 covariances evaluated at the measured ``(r_k, f_k)`` or, when
    ``weights_at_local_xy`` is given, at that estimate. The unweighted variants rescale the
    Doppler rows so the objective is the SI-unit one of the paper.
    """
    position = frame.positions(data.position_m)
    range_local = data.range_m / frame.scale_m
    height = data.emitter_height_m / frame.scale_m
    gamma = data.gamma_per_m
    if rows == "as-printed":
        A_d, b_d = doppler_rows_as_printed(
            data.frame, position, data.velocity_mps, range_local, data.doppler_hz, gamma
        )
        A_t, b_t = toa_rows(position, range_local, height, height_term=False)
    else:
        A_d, b_d = doppler_rows(
            position, data.velocity_mps, range_local, data.doppler_hz, gamma, height
        )
        range_sigma = data.noise.toa_s * data.speed_of_light_mps / frame.scale_m
        if rows == "weighted":
            A_t, b_t = toa_rows(position, range_local, height)
            if weights_at_local_xy is None:
                rho, doppler = range_local, data.doppler_hz
            else:
                rho = model.slant_range_m(position, weights_at_local_xy, height)
                doppler = model.doppler_hz(
                    position, data.velocity_mps, weights_at_local_xy, gamma, height
                )
            covariance = sample_pair_covariance(
                rho,
                doppler,
                horizontal_speed_mps(data.velocity_mps),
                gamma,
                data.noise.doppler_hz,
                range_sigma,
            )
            return whiten_sample_pairs(A_d, b_d, A_t, b_t, *covariance)
        A_t, b_t = toa_rows(position, range_local, height)
        if rows == "per-frame":
            A_d, b_d = frame_mean_rows(data.frame, A_d, b_d)
    # Unweighted in SI units, a ToA residual in m². In the local frame lengths shrink by L, so a
    # ToA residual shrinks by L² and a unit-row Doppler residual (metres) by L: the Doppler rows
    # get the factor 1/L (L in metres), times the row's own SI scale. The per-sample rows keep
    # the unit scale (a residual in metres); the paper's per-frame row has the scale K|v|², a
    # residual in m³/s² (MATH §3, "Row scale in the unweighted system").
    doppler_weight = np.full(len(b_d), 1.0 / frame.scale_m)
    if rows == "per-frame":
        doppler_weight *= paper_row_scale_m2ps2(data.frame, data.velocity_mps)
    return (
        np.vstack([A_d * doppler_weight[:, None], A_t]),
        np.concatenate([b_d * doppler_weight, b_t]),
    )


def solve_doppler_toa_cls(
    data: MeasurementSet,
    rows: Rows = "weighted",
    *,
    stages: int = 2,
    hard_case_rtol: float = 1e-10,
) -> ClsSolution:
    """Every global minimiser of the Doppler-ToA CLS (MATH §3-§6), in world coordinates.

    ``stages`` applies to ``weighted`` rows: stage 1 weights from the data, stage 2 from the
    stage-1 estimate (both mirror candidates give the same weights, MATH §6).
    """
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    solution = solve_gtrs(A, b, hard_case_rtol=hard_case_rtol)
    n_stages = 1
    if rows == "weighted":
        for _ in range(stages - 1):
            A, b = cls_rows(data, frame, rows, weights_at_local_xy=solution.points[0, :2])
            solution = solve_gtrs(A, b, hard_case_rtol=hard_case_rtol)
            n_stages += 1
    return ClsSolution(
        candidates_m=frame.to_world(solution.points[:, :2]),
        costs=solution.costs,
        gtrs=solution,
        frame=frame,
        stages=n_stages,
        A=A,
        b=b,
    )


def _estimate(
    name: str,
    rows: Rows,
    frames: Frames,
    data: MeasurementSet,
    rng: np.random.Generator | None,
    side_prior_m: tuple[float, float] | None,
    **solve_options,
) -> Estimate:
    used = data.select_frames(frames)
    solution = solve_doppler_toa_cls(used, rows, **solve_options)
    gtrs = solution.gtrs
    return finalize_estimate(
        name,
        solution.candidates_m,
        solution.costs,
        used,
        rng=rng,
        side_prior_m=side_prior_m,
        message="hard case: mirror pair (MATH §5)" if gtrs.hard_case else "",
        diagnostics={
            "multiplier": gtrs.multiplier,
            "hard_case": gtrs.hard_case,
            "rank": gtrs.rank,
            "stages": solution.stages,
            "n_samples": used.n_samples,
        },
    )


def _constrained_ls(rows: Rows, frames: Frames, data: MeasurementSet) -> ConstrainedLS:
    """The rows whose minimisers :func:`_estimate` returns: the last stage's, frames used."""
    solution = solve_doppler_toa_cls(data.select_frames(frames), rows)
    return ConstrainedLS.in_frame(solution.A, solution.b, solution.frame)


def _check_frames(frames: str) -> None:
    if frames not in ("all", "last"):
        raise ValueError(f"frames: expected 'all' or 'last', got {frames!r}")


@dataclass(frozen=True, kw_only=True)
class Cls:
    """The corrected closed-form CLS (MATH §3-§6): weighted, exact GTRS, both mirror minimisers.

    Parameters
    ----------
    weighting : {"optimal", "none"}
        ``optimal``: two-stage whitening by the exact second moments (MATH §6).
        ``none``: the same per-sample rows unweighted, in SI units.
    frames : {"all", "last"}
        Use every frame so far, or only the last (as the paper does).
    side_prior_m : (x, y) or None
        A rough emitter position; picks the nearer mirror candidate (MATH §7).
    """

    name: ClassVar[str] = "cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    weighting: Literal["optimal", "none"] = "optimal"
    frames: Frames = "all"
    side_prior_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.weighting not in ("optimal", "none"):
            raise ValueError(f"weighting: expected 'optimal' or 'none', got {self.weighting!r}")
        _check_frames(self.frames)

    def _rows(self) -> Rows:
        return "weighted" if self.weighting == "optimal" else "per-sample"

    def capabilities(self) -> Capabilities:
        """Doppler and ToA on the frames used; the optimal weighting is unit-invariant (MATH §6)."""
        return Capabilities(
            modalities=self.requires,
            frames=self.frames,
            unit_invariant=self.weighting == "optimal",
        )

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        return _estimate(self.name, self._rows(), self.frames, data, rng, self.side_prior_m)

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS:
        """The system ``estimate`` minimises: with ``optimal`` weighting, stage 2's rows."""
        require_modalities(self, data)
        return _constrained_ls(self._rows(), self.frames, data)


@dataclass(frozen=True, kw_only=True)
class ClsPaper:
    """The paper's unweighted CLS with the errata fixed (MATH §3-§5, paper eq ``finalest``).

    One projected Doppler row per frame at the paper's scale ``K|v|²``, a residual in m³/s²
    (MATH §3, "Row scale in the unweighted system"), and the squared-range rows with the
    height term, in m² (MATH §4), solved exactly (MATH §5). Unweighted, so its answer depends
    on the unit system, as the paper's does; ``frames="last"`` is Algorithm 1.
    """

    name: ClassVar[str] = "cls-paper"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    frames: Frames = "last"
    side_prior_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        _check_frames(self.frames)

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, frames=self.frames)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        return _estimate(self.name, "per-frame", self.frames, data, rng, self.side_prior_m)

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS:
        """The system ``estimate`` minimises (unweighted, SI-unit rows, frames used)."""
        require_modalities(self, data)
        return _constrained_ls("per-frame", self.frames, data)


@dataclass(frozen=True, kw_only=True)
class ClsAsPrinted:
    """The paper's CLS as printed (first-row Doppler line, no height term); λ solved exactly.

    Labelled as the printed version wherever it appears; it shows what the errata cost.
    """

    name: ClassVar[str] = "cls-as-printed"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    frames: Frames = "last"
    side_prior_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        _check_frames(self.frames)

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, frames=self.frames)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        return _estimate(self.name, "as-printed", self.frames, data, rng, self.side_prior_m)

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS:
        """The system ``estimate`` minimises (the printed rows, frames used)."""
        require_modalities(self, data)
        return _constrained_ls("as-printed", self.frames, data)
