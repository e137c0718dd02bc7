"""One instance judged: the closed form against the SDP relaxation, and an estimator's
candidates against the closed form's minimisers (MATH §5, §11)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from comparison.crosscheck.instances import FloatArray, ValidationInstance
from estimators.base import Estimate
from estimators.closed_form.constrained_ls import PROTOCOL_METHOD, ConstrainedLS
from estimators.closed_form.gtrs import GtrsSolution, constrained_cost, solve_gtrs
from estimators.mirror_rule import MERGE_RTOL
from estimators.sdp.sdp_cls import SdpSolution, solve_sdp_relaxation

NOT_RUN = "not_run"
"""Status of an instance on which the estimator raised: no rows, no SDP."""


@dataclass(frozen=True, slots=True)
class CandidateCheck:
    """An estimator's candidates on its own rows against the closed-form minimisers.

    Attributes
    ----------
    estimate_success : bool
        The estimate succeeded (a failed estimate has no candidates).
    n_candidates : int
        Candidates the estimator returned.
    n_minimisers : int
        Global minimisers of the closed form (2 in the hard case).
    max_rel_cost_gap : float
        Largest ``|cost − f*| / f*`` over the candidates, each lifted onto the paraboloid;
        NaN without candidates.
    max_distance_m, max_distance_rel : float
        Hausdorff distance between the candidates and the closed-form minimisers (those due),
        in metres and of the length scale (inf without candidates; NaN without candidates
        when no minimiser is due).
    n_missing : int
        Closed-form minimisers with no candidate within the distance tolerance.
    n_extra : int
        Candidates that are not global minimisers (cost above the optimum beyond the
        tolerance, or away from every minimiser).
    n_below : int
        Candidates whose cost is below the closed-form optimum beyond the tolerance.
    n_above_uav : int
        Closed-form minimisers above the UAV's highest sample (the height unknown): the
        mirror rule drops them ("the emitter is below the UAV", MATH §7), so they are not due,
        and the distances are to the others.
    """

    estimate_success: bool
    n_candidates: int
    n_minimisers: int
    max_rel_cost_gap: float
    max_distance_m: float
    max_distance_rel: float
    n_missing: int
    n_extra: int
    n_below: int = 0
    n_above_uav: int = 0


@dataclass(frozen=True, slots=True)
class InstanceResult:
    """The closed form and the SDP on one instance, and where they disagree.

    Distances are in metres; ``*_rel`` divides by the length scale. ``argmin_distance_m`` is
    NaN on hard instances, ``pair_distance_m`` NaN on unique-minimiser ones. ``candidates``
    is set when an estimator was validated (:func:`check_candidates`).
    """

    family: str
    seed: int
    status: str
    hard_case: bool
    sdp_rank: int
    multiplier: float
    sdp_multiplier: float
    closed_form_value: float
    sdp_value: float
    rel_objective_gap: float
    argmin_distance_m: float
    argmin_distance_rel: float
    pair_distance_m: float
    pair_distance_rel: float
    length_scale_m: float
    closed_form_time_s: float
    sdp_time_s: float
    tolerance_rung: int = 1
    reasons: tuple[str, ...] = ()
    multiplier_rel: float = float("nan")
    inequality_rel_gap: float = float("nan")
    candidates: CandidateCheck | None = None

    @property
    def sdp_failed(self) -> bool:
        return self.status not in ("optimal", NOT_RUN)

    @property
    def agrees(self) -> bool:
        return not self.reasons


def relative_objective_gap(sdp_value: float, closed_form_value: float) -> float:
    """``|v_sdp − v_cf| / max(|v_cf|, tiny)``."""
    return abs(sdp_value - closed_form_value) / max(abs(closed_form_value), np.finfo(float).tiny)


def point_set_distance(first: FloatArray, second: FloatArray) -> float:
    """Hausdorff distance between two point sets (n, d) and (m, d); inf if one is empty."""
    first = np.asarray(first, dtype=float)
    d = first.shape[-1]
    first = first.reshape(-1, d)
    second = np.asarray(second, dtype=float).reshape(-1, d)
    if len(first) == 0 or len(second) == 0:
        return float("inf")
    pairwise = np.linalg.norm(first[:, None, :] - second[None, :, :], axis=-1)
    return float(max(pairwise.min(axis=1).max(), pairwise.min(axis=0).max()))


def compare_solutions(
    instance: ValidationInstance,
    closed_form: GtrsSolution,
    sdp: SdpSolution,
    *,
    closed_form_time_s: float,
    rtol_objective: float,
    rtol_argmin: float,
) -> InstanceResult:
    """Judge one instance: objective gap, argmin or mirror-pair distance, solver status.

    Points are compared in all ``d`` coordinates of the rows (``(x, y)``, or ``(x, y, z)`` with
    the height unknown), in the local frame's unit."""
    scale = instance.length_scale_m
    d = instance.dimension
    value = float(np.min(closed_form.costs))
    reasons: list[str] = []
    gap = argmin = pair = float("nan")
    if not sdp.optimal:
        reasons.append(f"SDP failed: solver status {sdp.status}: {sdp.message}")
    if sdp.has_solution:
        gap = relative_objective_gap(sdp.value, value)
        if not gap <= rtol_objective:
            reasons.append(f"relative objective gap {gap:.3g} > {rtol_objective:g}")
        cf_points = closed_form.points[:, :d]
        if closed_form.hard_case:
            pair = point_set_distance(sdp.points[:, :d], cf_points)
            if not pair <= rtol_argmin:
                reasons.append(
                    f"hard case: SDP pair ({len(sdp.points)} points, rank {sdp.rank}) is "
                    f"{pair:.3g} (of the length scale) from the closed-form mirror pair"
                )
        else:
            best = sdp.points[int(np.argmin(sdp.costs)), :d]
            argmin = float(np.min(np.linalg.norm(cf_points - best, axis=1)))
            if not argmin <= rtol_argmin:
                reasons.append(
                    f"unique minimiser: SDP argmin is {argmin:.3g} (of the length scale) from "
                    f"the closed form's (SDP rank {sdp.rank})"
                )
                point_gaps = [relative_objective_gap(cost, value) for cost in sdp.costs]
                if len(point_gaps) == 2 and max(point_gaps) <= rtol_objective:
                    reasons.append(
                        "both points recovered from the SDP's lift attain the closed-form "
                        f"optimum (relative gaps {point_gaps[0]:.3g}, {point_gaps[1]:.3g}): the "
                        "closed form returned one minimiser of a mirror pair (MATH §5)"
                    )
    return InstanceResult(
        family=instance.family,
        seed=instance.seed,
        status=sdp.status,
        hard_case=bool(closed_form.hard_case),
        sdp_rank=sdp.rank,
        multiplier=closed_form.multiplier,
        sdp_multiplier=sdp.multiplier,
        closed_form_value=value,
        sdp_value=sdp.value,
        rel_objective_gap=gap,
        argmin_distance_m=argmin * scale,
        argmin_distance_rel=argmin,
        pair_distance_m=pair * scale,
        pair_distance_rel=pair,
        length_scale_m=scale,
        closed_form_time_s=closed_form_time_s,
        sdp_time_s=sdp.wall_time_s,
        tolerance_rung=sdp.rung,
        reasons=tuple(reasons),
    )


def validate_instance(
    instance: ValidationInstance,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    solver: str = "CLARABEL",
) -> tuple[InstanceResult, GtrsSolution, SdpSolution]:
    """Run the closed form and the SDP on the instance's rows.

    The equality (Shor) relaxation is judged against the closed form. The inequality relaxation
    ``r_z >= ‖y‖²`` (in 3-D ``r_w >= ‖s‖²``) is solved too, for the report only: it is tight
    exactly when λ* >= 0 (MATH §11). ``multiplier_rel = λ*/‖A_s‖₂²`` (λ* acts on the block of
    ``s``, ``(x, y)`` or ``(x, y, z)``, only) and
    ``inequality_rel_gap`` (its value below the closed form's, relative) record it.
    """
    started = time.perf_counter()
    closed_form = solve_gtrs(instance.A, instance.b)
    closed_form_time = time.perf_counter() - started
    sdp = solve_sdp_relaxation(instance.A, instance.b, relaxation="equality", solver=solver)
    result = compare_solutions(
        instance,
        closed_form,
        sdp,
        closed_form_time_s=closed_form_time,
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
    )
    inequality = solve_sdp_relaxation(
        instance.A, instance.b, relaxation="inequality", solver=solver
    )
    value = float(np.min(closed_form.costs))
    result = replace(
        result,
        multiplier_rel=closed_form.multiplier
        / np.linalg.norm(instance.A[:, : instance.dimension], 2) ** 2,
        inequality_rel_gap=(value - inequality.value) / max(abs(value), np.finfo(float).tiny)
        if inequality.has_solution
        else float("nan"),
    )
    return result, closed_form, sdp


# --------------------------------------------------------------------------------------------
# an estimator's own closed form
# --------------------------------------------------------------------------------------------


def estimator_label(estimator: Any) -> str:
    """The estimator's ``name``, else its class name."""
    name = getattr(estimator, "name", None)
    return name if isinstance(name, str) else type(estimator).__name__


def check_protocol(estimator: Any) -> None:
    """Raise ``ValueError`` naming the method to add when ``estimator`` cannot be validated."""
    kind = type(estimator)
    where = f"{kind.__module__}:{kind.__qualname__}"
    if not callable(getattr(estimator, "estimate", None)):
        raise ValueError(f"estimator: {where} has no estimate(data) method; it is not an estimator")
    if not callable(getattr(estimator, PROTOCOL_METHOD, None)):
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r} ({where}) does not expose the constrained "
            f"least squares it minimises; add a method {PROTOCOL_METHOD}(self, data) returning "
            "an estimators.closed_form.constrained_ls.ConstrainedLS (the rows A, b and their local "
            "frame whose minimisers estimate(data) returns; see docs/writing-an-estimator.md)"
        )
    requires = frozenset(getattr(estimator, "requires", ()))
    extra = sorted(requires - {"doppler", "toa"})
    if extra:
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r} requires {', '.join(extra)}; the "
            "validation instances carry Doppler and ToA measurements only"
        )


def check_candidates(
    problem: ConstrainedLS,
    estimate: Estimate,
    closed_form: GtrsSolution,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    ceiling_m: float | None = None,
) -> tuple[CandidateCheck, tuple[str, ...]]:
    """Judge the estimator's candidates on its own rows ``problem`` (MATH §5).

    Each candidate ``s`` (``(x, y)``, or ``(x, y, z)`` with the height a coordinate) is lifted
    to ``r = (s, ‖s‖²)`` in the rows' frame, so it lies on the constraint surface, and its cost
    is compared with the closed-form optimum ``f*``. A candidate is a global minimiser when
    ``|cost − f*| <= rtol_objective · f*`` and it lies within ``rtol_argmin`` (of the length
    scale) of a closed-form minimiser; every closed-form minimiser that is due must have such a
    candidate (both mirror images in the hard case). In 3-D ``ceiling_m``, the UAV's highest
    sample height, is required: a minimiser above it is not due, as the mirror rule drops it
    (MATH §7: a level flight's reflection through its plane), and when none is due a failed
    estimate (no candidates) agrees. The largest distance is over the
    candidates (to the nearest minimiser) and the due minimisers (to the nearest candidate):
    the Hausdorff distance when every minimiser is due. Returns the check and the reasons it
    fails (empty when it passes).
    """
    d = problem.dimension
    minimisers = closed_form.points[:, :d]
    due = np.ones(len(minimisers), dtype=bool)
    if d == 3:
        if ceiling_m is None:
            raise ValueError("ceiling_m: the 3-D check needs the UAV's highest sample height")
        heights = problem.to_world(minimisers)[:, 2]
        due = heights <= ceiling_m + MERGE_RTOL * max(abs(ceiling_m), 1.0)
    optimum = float(np.min(closed_form.costs))
    width = np.shape(estimate.candidates_m)[-1]
    if not estimate.success or len(estimate.candidates_m) == 0 or width != d:
        # no candidate: infinitely far from a due minimiser; with none due, nothing to measure
        far = float("inf") if due.any() else float("nan")
        check = CandidateCheck(
            estimate_success=bool(estimate.success),
            n_candidates=0,
            n_minimisers=len(minimisers),
            max_rel_cost_gap=float("nan"),
            max_distance_m=far,
            max_distance_rel=far,
            n_missing=int(due.sum()),
            n_extra=0,
            n_above_uav=int((~due).sum()),
        )
        if estimate.success and len(estimate.candidates_m) and width != d:
            return check, (
                f"the candidates have {width} coordinates, the rows of constrained_ls {d}",
            )
        if not due.any():  # every global minimiser above the UAV: no answer is the rule's
            return check, ()
        why = estimate.message or "no candidates"
        return check, (f"estimate failed: {why}",)
    local = problem.to_local(estimate.candidates_m)
    costs = constrained_cost(problem.A, problem.b, local)
    gaps = (costs - optimum) / max(abs(optimum), np.finfo(float).tiny)
    distances = np.linalg.norm(local[:, None, :] - minimisers[None, :, :], axis=-1)
    near = distances <= rtol_argmin
    below = gaps < -rtol_objective
    extra = ~below & ((gaps > rtol_objective) | ~near.any(axis=1))
    missing = due & ~near.any(axis=0)
    largest = max(distances.min(axis=1).max(), distances[:, due].min(axis=0).max(initial=0.0))
    check = CandidateCheck(
        estimate_success=True,
        n_candidates=len(local),
        n_minimisers=len(minimisers),
        max_rel_cost_gap=float(np.max(np.abs(gaps))),
        max_distance_m=float(largest) * problem.scale_m,
        max_distance_rel=float(largest),
        n_missing=int(missing.sum()),
        n_extra=int(extra.sum()),
        n_below=int(below.sum()),
        n_above_uav=int((~due).sum()),
    )
    reasons = []
    if extra.any():
        reasons.append(
            f"{check.n_extra} of {check.n_candidates} candidate(s) not a global minimiser: "
            f"relative cost gap up to {float(np.max(gaps[extra])):.3g} (tolerance "
            f"{rtol_objective:g}), {float(np.max(distances[extra].min(axis=1))):.3g} of the "
            "length scale from the nearest closed-form minimiser"
        )
    if missing.any():
        if not closed_form.hard_case:
            kind = "unique minimiser"
        elif due.all():
            kind = "hard case: both mirror minimisers must be returned"
        else:
            kind = "hard case: the minimiser below the UAV must be returned"
        reasons.append(
            f"{check.n_missing} of {int(due.sum())} closed-form minimiser(s) not among the "
            f"candidates ({kind}; the nearest candidate is "
            f"{float(np.max(distances[:, missing].min(axis=0))):.3g} of the length scale away)"
        )
    if below.any():
        reasons.append(
            f"{check.n_below} candidate(s) below the closed-form optimum by up to "
            f"{float(-np.min(gaps)):.3g} (relative): the closed form missed the global minimum"
        )
    return check, tuple(reasons)


@dataclass(frozen=True, slots=True, eq=False)
class EstimatorRun:
    """Everything computed on one instance for an estimator (what :func:`replay` prints)."""

    instance: ValidationInstance
    estimate: Estimate | None
    problem: ConstrainedLS | None
    closed_form: GtrsSolution | None
    sdp: SdpSolution | None
    error: str = ""


def _not_run_result(instance: ValidationInstance, reason: str) -> InstanceResult:
    nan = float("nan")
    return InstanceResult(
        family=instance.family,
        seed=instance.seed,
        status=NOT_RUN,
        hard_case=False,
        sdp_rank=0,
        multiplier=nan,
        sdp_multiplier=nan,
        closed_form_value=nan,
        sdp_value=nan,
        rel_objective_gap=nan,
        argmin_distance_m=nan,
        argmin_distance_rel=nan,
        pair_distance_m=nan,
        pair_distance_rel=nan,
        length_scale_m=nan,
        closed_form_time_s=nan,
        sdp_time_s=nan,
        reasons=(reason,),
    )


def validate_estimator_instance(
    instance: ValidationInstance,
    estimator: Any,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    solver: str = "CLARABEL",
) -> tuple[InstanceResult, EstimatorRun]:
    """Run ``estimator`` on the instance's measurements and judge it on its own rows.

    ``estimate(data)`` and ``constrained_ls(data)`` see the measurements without the truth.
    The closed form and the SDP are compared on the returned rows as in
    :func:`validate_instance`, and the candidates as in :func:`check_candidates`. An exception
    raised by the estimator is recorded as a disagreement; ``constrained_ls`` returning
    anything but a :class:`~estimators.closed_form.constrained_ls.ConstrainedLS` raises
    ``ValueError``.
    """
    data = instance.data.without_truth()
    try:
        estimate = estimator.estimate(data)
        problem = getattr(estimator, PROTOCOL_METHOD)(data)
    except Exception as error:
        reason = f"estimator raised {type(error).__name__}: {error}"
        return _not_run_result(instance, reason), EstimatorRun(
            instance, None, None, None, None, error=reason
        )
    if not isinstance(problem, ConstrainedLS):
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r}.{PROTOCOL_METHOD}(data) returned "
            f"{type(problem).__name__}; return an "
            "estimators.closed_form.constrained_ls.ConstrainedLS"
        )
    on_rows = replace(
        instance,
        frame=problem.frame,
        rows=f"{estimator_label(estimator)}.{PROTOCOL_METHOD}",
        A=problem.A,
        b=problem.b,
        parameters=dict(
            instance.parameters,
            rows=f"{estimator_label(estimator)}.{PROTOCOL_METHOD}",
            n_rows=len(problem.b),
        ),
    )
    result, closed_form, sdp = validate_instance(
        on_rows, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin, solver=solver
    )
    check, reasons = check_candidates(
        problem,
        estimate,
        closed_form,
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
        ceiling_m=float(np.max(data.position_m[:, 2])) if problem.dimension == 3 else None,
    )
    result = replace(result, candidates=check, reasons=reasons + result.reasons)
    return result, EstimatorRun(on_rows, estimate, problem, closed_form, sdp)
