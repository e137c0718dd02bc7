r"""The closed-form Doppler-ToA constrained least squares (MATH §3-§6) and the paper's versions.

Three estimators share one pipeline, the vectorised solve of :mod:`estimators.closed_form.cls_batch`:

``cls`` (:class:`Cls`)
    The corrected method: one Doppler·range row per sample (§3), squared-range rows with the
    height term (§4), the exact GTRS solve whose hard case returns both mirror minimisers (§5),
    and two-stage optimal weighting by the exact second moments (§6), which makes it invariant
    to the unit system, the speed and the heading. With the emitter's height unknown the same
    solve in three coordinates (§5): a level flight's reflection through its plane is returned
    beside the emitter (the mirror rule keeps the one below the UAV), one straight track fails
    in one line, and with the emission time unknown too the data are refused (the pseudo-range
    form of §15 is 2-D).
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
its local frame; :mod:`estimators.closed_form.constrained_ls`), so that ``emitterbench validate
--estimator`` can check its candidates against the exact optimum and the SDP relaxation (MATH §5,
§11).

Each also solves a whole :class:`~scenarios.types.MeasurementBatch` at once:
``estimate_columns(batch, rngs=...)`` returns a :class:`~estimators.batch.BatchEstimates` (one
array per field) and ``estimate_batch`` the same as one :class:`Estimate` per trial. Trial ``i``
gets exactly what ``estimate(batch.trial(i), rng=rngs[i])`` returns, tie-break included; the
vectorised path is :mod:`estimators.closed_form.cls_batch`.

In the hard case the pair is handed to the mirror rule in a fixed order, the point left of the
last heading first (:func:`ordered_candidates`), so that which point a tie-break returns does not
depend on the rounding of the two costs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from estimators.base import (
    Capabilities,
    Estimate,
    check_rng,
    check_side_prior,
    finalize_estimate,
    require_batch,
    require_modalities,
)
from estimators.batch import BatchEstimates, EstimatesOfColumns
from estimators.closed_form.cls_batch import estimate_columns, estimate_trial, system_of_trial
from estimators.closed_form.cls_rows import (
    LocalFrame,
    project_out,
)
from estimators.closed_form.constrained_ls import ConstrainedLS
from estimators.closed_form.pseudorange_cls import (
    OffsetMethod,
    check_offset_method,
    estimate_pseudorange_columns,
    solve_pseudorange_cls,
)
from estimators.goodness_of_fit import FIT_KEYS, fit_of, with_fit, with_fit_columns
from scenarios.geometry import straight_track_line
from scenarios.nuisance import HEIGHT_UNKNOWN, position_dimension
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
Rows = Literal["weighted", "per-sample", "per-frame", "as-printed"]
Frames = Literal["all", "last"]


def cls_rows(
    data: MeasurementSet,
    frame: LocalFrame,
    rows: Rows,
    *,
    weights_at_local_xy: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The stacked system ``B⁺ r = p⁺`` of MATH §5 in ``frame``, for one row variant: the rows
    the solver sums (:func:`~estimators.closed_form.cls_batch.system_of_trial`).

    ``weighted``: per-sample Doppler and ToA rows, whitened per sample with the MATH §6
    covariances evaluated at the measured ``(r_k, f_k)`` or, when ``weights_at_local_xy`` is
    given, at that estimate. The unweighted variants keep the SI-unit objective of the paper
    (MATH §3, "Row scale in the unweighted system"). With an unknown carrier offset in
    ``data.unknowns`` (``weighted`` and ``per-sample`` rows) δ's column is projected out
    (MATH §15).
    """
    A, b, offset, _ = system_of_trial(
        data,
        rows,
        origin_m=frame.origin_m,
        scale_m=frame.scale_m,
        weights_at_local_xy=weights_at_local_xy,
        dimension=position_dimension(data.unknowns),
    )
    return (A, b) if offset is None else project_out(A, b, offset)


def _estimate_pseudorange(
    name: str,
    data: MeasurementSet,
    rng: np.random.Generator | None,
    side_prior_m: tuple[float, float] | None,
    offset_method: OffsetMethod = "relaxed",
) -> Estimate:
    """One trial with an unknown emission time: the pseudo-range closed form, an indefinite
    GTRS (MATH §15, :mod:`estimators.closed_form.pseudorange_cls`), finished by the mirror
    rule of :func:`~estimators.base.finalize_estimate`."""
    offset_unknown = "carrier_offset_hz" in data.unknowns
    solution = solve_pseudorange_cls(
        data, carrier_offset_unknown=offset_unknown, offset_method=offset_method
    )
    info = solution.diagnostics
    nuisance = {"emission_time_s": float(solution.emission_time_s[0])}
    if solution.carrier_offset_hz is not None:
        nuisance["carrier_offset_hz"] = float(solution.carrier_offset_hz[0])
    diagnostics = {
        key: info[key] for key in ("status", "multiplier", "hard_case", "rank", "stages")
    }
    if not info["success"] or not len(solution.candidates_m):
        return Estimate.failed(
            name, f"pseudo-range closed form: {info['status']} (MATH §15)", **diagnostics
        )
    candidates, costs = _ordered_candidates(
        solution.candidates_m, solution.costs, bool(info["hard_case"]), data
    )
    notes = ["hard case: mirror pair (MATH §15)"] if info["hard_case"] else []
    if not info.get("on_physical_sheet", True):
        notes.append(
            "the global minimiser has a negative reference range: the best point "
            "on the physical sheet is returned (MATH §15)"
        )
    return finalize_estimate(
        name,
        candidates,
        costs,
        data,
        rng=rng,
        side_prior_m=side_prior_m,
        message="; ".join(notes),
        diagnostics={**diagnostics, "n_samples": data.n_samples, **nuisance},
    )


def _ordered_candidates(
    candidates: FloatArray, costs: FloatArray, hard_case: bool, data: MeasurementSet
) -> tuple[FloatArray, FloatArray]:
    """The pseudo-range form's candidates and costs handed to the mirror rule.

    The hard case's two minimisers have equal cost (MATH §5); their computed costs differ only
    by rounding, so ordering them by cost would let the rounding decide which comes first, and
    with it which one a tie-break by ``rng`` returns. Instead the point to the left of the last
    sample's heading comes first, at the smaller cost. On a straight track the other point is
    that one's mirror image (MATH §7), which ``finalize_estimate`` adds; elsewhere both go.
    """
    if not hard_case or len(candidates) != 2:
        return candidates, costs
    velocity = data.velocity_mps[-1]
    left = np.array([-velocity[1], velocity[0]])
    if (candidates[0] - candidates[1]) @ left < 0.0:
        candidates = candidates[::-1]
    best = np.full(2, np.min(costs))
    if straight_track_line(data.position_m, data.velocity_mps) is not None:
        return candidates[:1], best[:1]
    return candidates, best


def _constrained_ls(rows: Rows, frames: Frames, data: MeasurementSet) -> ConstrainedLS:
    """The rows whose minimisers ``estimate`` returns: the last stage's, frames used, δ
    projected out."""
    if "emission_time_s" in data.unknowns:
        raise ValueError(
            "unknowns: with an unknown emission time the CLS is an indefinite GTRS over "
            "(x, y, ρ_j) (MATH §15), not the paraboloid GTRS of §5 that constrained_ls describes"
        )
    used = data.select_frames(frames)
    A, b, offset, scale = system_of_trial(
        used, rows, last_stage=True, dimension=position_dimension(data.unknowns)
    )
    if offset is not None:
        A, b = project_out(A, b, offset)
    frame = LocalFrame(origin_m=used.position_m[:, :2].mean(axis=0), scale_m=scale)
    return ConstrainedLS.in_frame(A, b, frame)


def _check_options(frames: str, side_prior_m: object) -> None:
    if frames not in ("all", "last"):
        raise ValueError(f"frames: expected 'all' or 'last', got {frames!r}")
    check_side_prior(side_prior_m)


@lru_cache(maxsize=64)
def _declared(estimator: _Batches) -> Capabilities:
    """``estimator._declare()``, cached by the estimator's options (its fields: equal
    estimators of one class declare the same). Module level, so that an instance holds only its
    options (the constructor rule of :mod:`estimators.checks`)."""
    return estimator._declare()


class _Batches(EstimatesOfColumns):
    """``estimate``, ``estimate_batch`` and ``estimate_columns`` of the closed forms.

    ``estimate`` is the batch's answer for a batch of one: the same vectorised solve
    (:func:`estimators.closed_form.cls_batch.solve_trials`) with one trial, finished as one
    :class:`Estimate` instead of columns (:func:`~estimators.closed_form.cls_batch.estimate_trial`),
    so a run's row, a batch's column and ``estimate`` of the same trial are the same bits however
    the trials were chunked or called; an unknown carrier offset is a column of the same rows,
    projected out. With an unknown emission time (MATH §15) the columns are the pseudo-range
    closed form's, every trial at once
    (:func:`~estimators.closed_form.pseudorange_cls.estimate_pseudorange_columns`), and
    ``estimate`` runs the same solver on a batch of one.
    """

    name: ClassVar[str]
    frames: Frames
    side_prior_m: tuple[float, float] | None

    def _rows(self) -> Rows:
        raise NotImplementedError

    def _options(self, data: MeasurementSet) -> dict[str, Any]:
        return {}

    def capabilities(self) -> Capabilities:
        """What the estimator declares (:meth:`_declare`), built once per set of options
        (:func:`_declared`): every call reads it (the checks, the goodness of fit)."""
        try:
            return _declared(self)
        except TypeError:  # an option that cannot be hashed (a list as side_prior_m, say)
            return self._declare()

    def _declare(self) -> Capabilities:
        raise NotImplementedError

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        check_rng(rng)
        if "emission_time_s" in data.unknowns and HEIGHT_UNKNOWN in data.unknowns:
            return with_fit(self, self._columns_of_one(data, rng).estimate(0), data)
        if "emission_time_s" in data.unknowns:
            return with_fit(self, self._solve_one(data, rng), data)
        return estimate_trial(
            self.name,
            self._rows(),
            self.frames,
            data,
            rng,
            self.side_prior_m,
            lambda position: self._fit(data, position),
        )

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS:
        """The system ``estimate`` minimises: the last stage's rows (with ``optimal``
        weighting, stage 2's) on the frames used, an unknown carrier offset projected out."""
        require_modalities(self, data)
        return _constrained_ls(self._rows(), self.frames, data)

    def _fit(self, data: MeasurementSet, position_m: FloatArray) -> dict[str, Any]:
        """The goodness of fit (MATH §17) at ``position_m`` (1, d), as ``with_fit_columns``
        computes it for a batch of one (the same arrays, the same bits)."""
        value, dof = fit_of(self, data, position_m)
        return dict(zip(FIT_KEYS, (float(value[0]), int(dof)), strict=True))

    def _solve_one(self, data: MeasurementSet, rng: np.random.Generator | None) -> Estimate:
        """One trial with an unknown emission time (the pseudo-range form, MATH §15)."""
        return _estimate_pseudorange(
            self.name,
            data.select_frames(self.frames),
            rng,
            self.side_prior_m,
            **self._options(data),
        )

    def _columns_of_one(
        self, data: MeasurementSet, rng: np.random.Generator | None
    ) -> BatchEstimates:
        """One trial with the emission time and the height unknown: the pseudo-range columns
        of its batch of one (MATH §15, "The emitter's height unknown")."""
        return estimate_pseudorange_columns(
            self.name,
            MeasurementBatch.of_one(data),
            self.frames,
            [rng],
            self.side_prior_m,
            self._solve_one,
            **self._options(data),
        )

    def estimate_columns(
        self,
        batch: MeasurementBatch,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> BatchEstimates:
        """``estimate_batch`` as columns, without an object per trial."""
        require_batch(self, batch)
        if "emission_time_s" in batch.geometry.unknowns:  # MATH §15: vectorised
            columns = estimate_pseudorange_columns(
                self.name,
                batch,
                self.frames,
                rngs,
                self.side_prior_m,
                self._solve_one,
                **self._options(batch.geometry),
            )
            return with_fit_columns(self, columns, batch)
        return self._columns(batch, rngs)

    def _columns(
        self, batch: MeasurementBatch, rngs: Sequence[np.random.Generator | None] | None
    ) -> BatchEstimates:
        """:func:`estimators.closed_form.cls_batch.estimate_columns` with this estimator's options,
        and the goodness of fit of every trial (MATH §17)."""
        columns = estimate_columns(
            self.name,
            self._rows(),
            self.frames,
            batch,
            rngs,
            self.side_prior_m,
        )
        return with_fit_columns(self, columns, batch)


@dataclass(frozen=True, kw_only=True)
class Cls(_Batches):
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
    offset_method : {"relaxed", "profile", "two-stage"}
        With both the carrier offset and the emission time unknown (MATH §15): ``relaxed`` is
        the closed form (``w = ρ_j δ`` relaxed and projected out), ``profile`` minimises the
        exact cost over δ by a scalar search, one GTRS per step: no longer closed form, but
        without the relaxation's price; ``two-stage`` corrects the relaxed answer by a second
        closed-form stage, the measurement model linearised about it: closed form, without
        the price.

    An unknown carrier offset is projected out of the rows; an unknown emission time turns the
    ranges into pseudo-ranges, whose differences give the indefinite GTRS of MATH §15
    (``weighting="optimal"`` only).
    """

    name: ClassVar[str] = "cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    weighting: Literal["optimal", "none"] = "optimal"
    frames: Frames = "all"
    side_prior_m: tuple[float, float] | None = None
    offset_method: OffsetMethod = "relaxed"

    def __post_init__(self) -> None:
        if self.weighting not in ("optimal", "none"):
            raise ValueError(f"weighting: expected 'optimal' or 'none', got {self.weighting!r}")
        check_offset_method(self.offset_method)
        _check_options(self.frames, self.side_prior_m)

    def _rows(self) -> Rows:
        return "weighted" if self.weighting == "optimal" else "per-sample"

    def _declare(self) -> Capabilities:
        """Doppler and ToA on the frames used; the optimal weighting is unit-invariant (MATH §6)."""
        return Capabilities(
            modalities=self.requires,
            frames=self.frames,
            batch=True,
            unit_invariant=self.weighting == "optimal",
            unknowns=frozenset(
                {"carrier_offset_hz", "emission_time_s", HEIGHT_UNKNOWN}
                if self.weighting == "optimal"
                else {"carrier_offset_hz", HEIGHT_UNKNOWN}
            ),
        )

    def _options(self, data: MeasurementSet) -> dict[str, Any]:
        return {"offset_method": self.offset_method} if "emission_time_s" in data.unknowns else {}


@dataclass(frozen=True, kw_only=True)
class _PaperRows(_Batches):
    """The paper's two variants: unweighted, Doppler and ToA, every frame or the last."""

    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    frames: Frames = "last"
    side_prior_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        _check_options(self.frames, self.side_prior_m)

    def _declare(self) -> Capabilities:
        # No unknown carrier offset: the frame's mean row loses the within-frame variation of
        # δ's column r_k/(γ|v|), so δ would take a frame's whole Doppler information (§15).
        return Capabilities(modalities=self.requires, frames=self.frames, batch=True)


@dataclass(frozen=True, kw_only=True)
class ClsPaper(_PaperRows):
    """The paper's unweighted CLS with the errata fixed (MATH §3-§5, paper eq ``finalest``).

    One projected Doppler row per frame at the paper's scale ``K|v|²``, a residual in m³/s²
    (MATH §3, "Row scale in the unweighted system"), and the squared-range rows with the
    height term, in m² (MATH §4), solved exactly (MATH §5). Unweighted, so its answer depends
    on the unit system, as the paper's does; ``frames="last"`` is Algorithm 1.
    """

    name: ClassVar[str] = "cls-paper"

    def _rows(self) -> Rows:
        return "per-frame"


@dataclass(frozen=True, kw_only=True)
class ClsAsPrinted(_PaperRows):
    """The paper's CLS as printed (first-row Doppler line, no height term); λ solved exactly.

    Labelled as the printed version wherever it appears; it shows what the errata cost.
    """

    name: ClassVar[str] = "cls-as-printed"

    def _rows(self) -> Rows:
        return "as-printed"
