"""The checks of an estimator that estimates the emitter's height (MATH §7, §8): run when its
``Capabilities.unknowns`` contains ``"emitter_height_m"``, on the reference problems with the
height unknown (:data:`~estimators.checks.reference_problems.HEIGHT_PROBLEMS`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.checks.exactness import check_candidates_at_optima
from estimators.checks.reference_problems import reference_problem, select_frames
from estimators.checks.results import (
    check_failed,
    declared_capabilities,
    estimate_or_fail,
    require_success,
)
from estimators.checks.tolerances import problem_tolerance_m
from scenarios.simulate import noise_free


def check_exact_with_the_height_unknown(estimator: Any) -> None:
    """Noise-free ``climb-height`` and ``turn-height`` (the height unknown): the answer has
    three coordinates, a candidate is the emitter ``(x, y, z)`` within the tolerance, and no
    candidate is above the UAV (on the level turn the reflection through the flight plane fits
    the data equally: the emitter is below the UAV, MATH §7)."""
    capabilities = declared_capabilities(estimator)
    for name in ("climb-height", "turn-height"):
        problem = reference_problem(name)
        what = f"noise-free {problem.label} data (the emitter's height unknown)"
        optima = problem.optima_for(capabilities.frames)
        if len(optima) == 0:  # the frames used are one straight track: nothing to locate
            continue
        estimate = estimate_or_fail(estimator, problem.data(), what)
        require_success(estimate, what)
        position = np.asarray(estimate.position_m, dtype=float)
        candidates = np.asarray(estimate.candidates_m, dtype=float)
        if position.shape != (3,) or candidates.ndim != 2 or candidates.shape[1] != 3:
            check_failed(
                f"on {what} position_m has shape {position.shape} and candidates_m "
                f"{candidates.shape}; with the height estimated a position is (x, y, z): "
                "position_m (3,), candidates_m (k, 3), covariance_m2 (3, 3)"
            )
        tolerance = problem_tolerance_m(capabilities, problem)
        check_candidates_at_optima(
            candidates,
            optima,
            what,
            problem,
            capabilities,
            tolerance,
            "Estimate the height with the position: the data determine (x, y, z)",
        )
        used = select_frames(noise_free(problem.scenario), capabilities.frames)
        ceiling = float(np.max(used.position_m[:, 2])) if used is not None else np.inf
        above = candidates[candidates[:, 2] > ceiling + tolerance]
        if len(above):
            check_failed(
                f"on {what} the candidate {above[0].tolist()} is above the UAV's highest "
                f"sample ({ceiling:g} m); the emitter is below the UAV (MATH §7): finish with "
                "finalize_estimate (or finalize_columns with ceiling_m), which drops it"
            )


def check_straight_track_cannot_fix_the_height(estimator: Any) -> None:
    """Noise-free ``climb-straight-height``, one straight track with the height unknown: every
    point of a circle about the track fits the data (MATH §7), so the estimate fails, with a
    one-line message and a NaN position of three coordinates (or a one-line ``ValueError``)."""
    problem = reference_problem("climb-straight-height")
    what = f"noise-free {problem.label} data (one straight track, the height unknown)"
    try:
        estimate = estimator.estimate(problem.data())
    except ValueError as error:
        if "\n" in str(error) or not str(error).strip():
            check_failed(f"the ValueError raised on {what} is not one line: {str(error)!r}")
        return
    except Exception as error:
        check_failed(
            f"estimate raised {type(error).__name__} on {what}: {error}; fail the estimate "
            "(or raise ValueError) with one line"
        )
    if getattr(estimate, "success", True):
        check_failed(
            f"estimate succeeded on {what} at {np.asarray(estimate.position_m).tolist()}; one "
            "straight track leaves the emitter on a circle about it when its height is unknown "
            "(MATH §7): fail with a one-line reason (finalize_estimate does)"
        )
    message = str(estimate.message)
    position = np.asarray(estimate.position_m, dtype=float)
    if not message.strip() or "\n" in message:
        check_failed(f"the failed estimate on {what} needs a one-line message, got {message!r}")
    if position.shape != (3,) or not np.all(np.isnan(position)):
        check_failed(
            f"the failed estimate on {what} has position_m {position.tolist()}; a failure has "
            "a NaN position of three coordinates (Estimate.failed(..., dimension=3))"
        )
