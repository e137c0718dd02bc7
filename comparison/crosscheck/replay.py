"""Re-run one instance verbosely: the draw, the closed form, the SDP, an estimator's
candidates and the verdict (``emitterbench validate --replay SEED``)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from comparison.crosscheck.compare import (
    EstimatorRun,
    check_protocol,
    estimator_label,
    validate_estimator_instance,
    validate_instance,
)
from comparison.crosscheck.instances import FloatArray, make_instance
from comparison.crosscheck.result import json_clean
from comparison.crosscheck.run import estimator_cli_args


def _matrix_text(matrix: FloatArray) -> str:
    return np.array2string(
        np.asarray(matrix), precision=6, suppress_small=False, max_line_width=100
    )


def replay(
    instance_seed: int,
    family: str,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    estimator: Any = None,
) -> str:
    """Re-run one instance verbosely: the draw, the closed form, the SDP and the verdict.

    With an ``estimator`` (an object or a registry name), the rows are its
    ``constrained_ls(data)`` and its candidates are listed with their costs and gaps.
    """
    text, _ = replay_with_verdict(
        instance_seed,
        family,
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
        estimator=estimator,
    )
    return text


def replay_with_verdict(
    instance_seed: int,
    family: str,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    estimator: Any = None,
) -> tuple[str, bool]:
    """:func:`replay`'s text and whether the instance agrees."""
    if isinstance(estimator, str):
        from estimators.registry import make_estimator

        estimator = make_estimator(estimator)
    if estimator is not None:
        check_protocol(estimator)
    instance = make_instance(family, instance_seed)
    lines = [
        f"instance {family} seed {instance_seed}",
        f"  parameters: {json.dumps(json_clean(instance.parameters))}",
        f"  truth emitter (m): {_matrix_text(instance.data.truth_emitter_m)}",
    ]
    run: EstimatorRun | None = None
    if estimator is None:
        result, closed_form, sdp = validate_instance(
            instance, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
        )
    else:
        result, run = validate_estimator_instance(
            instance, estimator, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
        )
        lines.append(f"estimator {estimator_label(estimator)} ({estimator_cli_args(estimator)})")
        if run.error:
            lines += ["verdict", f"  DISAGREE: {run.error}"]
            return "\n".join(lines) + "\n", False
        assert run.closed_form is not None and run.sdp is not None
        instance, closed_form, sdp = run.instance, run.closed_form, run.sdp
    frame, d = instance.frame, instance.dimension
    world = instance.problem.to_world
    lines += [
        f"  local frame: origin {_matrix_text(frame.origin_m)} m, "
        f"length scale {frame.scale_m:.6g} m",
        f"  rows: {instance.rows}, A {instance.A.shape} (d = {d}), numerical rank "
        f"{closed_form.rank}",
        "closed form (MATH §5)",
        f"  lambda* = {closed_form.multiplier:.10g}, hard case {closed_form.hard_case}",
    ]
    for point, cost in zip(closed_form.points, closed_form.costs, strict=True):
        lines.append(f"  minimiser (m) {_matrix_text(world(point[:d]))}  cost {cost:.12g}")
    lines += [
        "SDP relaxation (MATH §11, equality)",
        f"  status {sdp.status} (tolerance rung {sdp.rung}), iterations {sdp.iterations}, "
        f"solver time "
        f"{sdp.solve_time_s * 1e3:.3f} ms, call {sdp.wall_time_s * 1e3:.3f} ms",
    ]
    if sdp.message:
        lines.append(f"  message: {sdp.message}")
    if sdp.has_solution:
        lines += [
            f"  value {sdp.value:.12g}, lambda (dual) {sdp.multiplier:.10g}, rank {sdp.rank}",
            f"  eigenvalues of Z: {_matrix_text(sdp.z_eigenvalues)}",
            f"  eigenvalues of the lift: {_matrix_text(sdp.lift_eigenvalues)}",
            f"  relaxed r (local): {_matrix_text(sdp.relaxed_point)}",
        ]
        for point, cost in zip(sdp.points, sdp.costs, strict=True):
            lines.append(
                f"  recovered point (m) {_matrix_text(world(point[:d]))}  cost {cost:.12g}"
            )
    if run is not None:
        lines += _estimate_lines(run, float(np.min(closed_form.costs)))
    lines += [
        "verdict",
        f"  relative objective gap {result.rel_objective_gap:.3e} (tolerance {rtol_objective:g})",
    ]
    if result.hard_case:
        lines.append(
            f"  mirror-pair distance {result.pair_distance_m:.3e} m "
            f"({result.pair_distance_rel:.3e} of the length scale; tolerance {rtol_argmin:g})"
        )
    else:
        lines.append(
            f"  argmin distance {result.argmin_distance_m:.3e} m "
            f"({result.argmin_distance_rel:.3e} of the length scale; tolerance {rtol_argmin:g})"
        )
    if result.candidates is not None:
        check = result.candidates
        lines.append(
            f"  candidates: {check.n_candidates} for {check.n_minimisers} minimiser(s)"
            + (f" ({check.n_above_uav} above the UAV, not due)" if check.n_above_uav else "")
            + ", "
            f"max relative cost gap {check.max_rel_cost_gap:.3e}, max distance "
            f"{check.max_distance_m:.3e} m ({check.max_distance_rel:.3e} of the length scale), "
            f"missing {check.n_missing}, extra {check.n_extra}"
        )
    lines.append("  AGREE" if result.agrees else "  DISAGREE: " + "; ".join(result.reasons))
    return "\n".join(lines) + "\n", result.agrees


def _estimate_lines(run: EstimatorRun, optimum: float) -> list[str]:
    """The estimator's answer on one instance, each candidate with its lifted cost and gap."""
    estimate, problem = run.estimate, run.problem
    assert estimate is not None and problem is not None
    lines = [
        f"estimate ({estimate.estimator})",
        f"  success {estimate.success}, ambiguous {estimate.ambiguous}"
        + (f", message: {estimate.message}" if estimate.message else ""),
    ]
    tiny = np.finfo(float).tiny
    for point in estimate.candidates_m:
        cost = float(problem.cost(point))
        lines.append(
            f"  candidate (m) {_matrix_text(point)}  cost {cost:.12g}  "
            f"relative gap {(cost - optimum) / max(abs(optimum), tiny):.3e}"
        )
    return lines
