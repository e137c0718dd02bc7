"""The checks of the answers on the reference problems (MATH §7, §14): every optimum is a
candidate on noise-free data, one straight frame gives the mirror pair, a second heading
resolves it."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.checks.forward_model import data_misfit
from estimators.checks.reference_problems import noisy_reference, reference_problem
from estimators.checks.results import (
    check_failed,
    declared_capabilities,
    estimate_or_fail,
    require_success,
)
from estimators.checks.tolerances import (
    MAX_NOISE_FREE_TOLERANCE,
    MISFIT_LIMIT,
    agreement_tolerance_m,
    problem_tolerance_m,
    tolerance_text,
)
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


def _check_exact(estimator: Any, names: Iterable[str]) -> None:
    """Every optimum of the data the estimator uses has a candidate within the tolerance."""
    capabilities = declared_capabilities(estimator)
    for name in names:
        problem = reference_problem(name)
        what = f"noise-free {problem.label} data"
        estimate = estimate_or_fail(estimator, problem.data(), what)
        require_success(estimate, what)
        tolerance = problem_tolerance_m(capabilities, problem)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            check_failed(
                f"no candidate on {what}; candidates_m must hold every equal-cost minimiser"
            )
        check_candidates_at_optima(
            candidates,
            problem.optima_for(capabilities.frames),
            what,
            problem,
            capabilities,
            tolerance,
            "Noise-free data determine the emitter (and its mirror image on one straight "
            "frame): compute the answer from the data; a method that stops short may declare a "
            "looser Capabilities.noise_free_tolerance_m with a tolerance_reason, within "
            f"{MAX_NOISE_FREE_TOLERANCE:g} of the RMS range",
        )


def check_candidates_at_optima(
    candidates: NDArray[np.float64],
    optima: Iterable[NDArray[np.float64]],
    what: str,
    problem: Any,
    capabilities: Any,
    tolerance: float,
    fix: str,
) -> None:
    """Fail naming the first optimum of ``problem`` with no candidate within ``tolerance``
    (the nearest one, its distance and the tolerance), then ``fix``."""
    for optimum in optima:
        distance = np.linalg.norm(candidates - optimum, axis=1)
        nearest = int(np.argmin(distance))
        if not distance[nearest] <= tolerance:
            check_failed(
                f"on {what} no candidate is at the optimum {optimum.tolist()} "
                f"({problem.source}): the nearest, {candidates[nearest].tolist()}, is "
                f"{distance[nearest]:.3g} m away (tolerance "
                f"{tolerance_text(capabilities, problem)}). {fix}"
            )


def check_exact_on_straight_frames(estimator: Any) -> None:
    """Noise-free data of one straight frame (``paper-1m``, ``climb-straight``,
    ``random-straight``): the emitter and its mirror image are both candidates, within the
    tolerance."""
    _check_exact(estimator, ("paper-1m", "climb-straight", "random-straight"))


def check_exact_on_turn(estimator: Any) -> None:
    """Noise-free data with two headings (``turn``): a candidate is the emitter (35, 15) m."""
    _check_exact(estimator, ("turn",))


def check_exact_far_from_origin(estimator: Any) -> None:
    """Noise-free ``far-turn`` data, kilometres from the origin: a candidate is the emitter
    (2400, −1300) m, within 1e-6 m (or 1e-9 of the extent)."""
    _check_exact(estimator, ("far-turn",))


def check_exact_with_climb(estimator: Any) -> None:
    """Noise-free ``climb`` data (``v_z ≠ 0``, emitter 25 m high): a candidate is the emitter."""
    _check_exact(estimator, ("climb",))


def check_exact_on_random_geometry(estimator: Any) -> None:
    """Noise-free data of a geometry drawn anew on each run (``random-turn``, from the check
    seed): a candidate is the emitter."""
    _check_exact(estimator, ("random-turn",))


def _distinct(points: FloatArray, tolerance: float) -> FloatArray:
    kept: list[FloatArray] = []
    for point in points:
        if all(np.linalg.norm(point - other) > tolerance for other in kept):
            kept.append(point)
    return np.array(kept).reshape(-1, 2)


def _mirror_closure(
    candidates: FloatArray, data: MeasurementSet, tolerance: float, what: str
) -> None:
    line = straight_track_line(data.position_m, data.velocity_mps)
    assert line is not None  # the reference frames are straight
    for point, mirror in zip(candidates, mirror_across_line(candidates, *line), strict=True):
        if np.min(np.linalg.norm(candidates - mirror, axis=1)) > tolerance:
            check_failed(
                f"on {what} the candidate {point.tolist()} comes without its mirror image "
                f"{mirror.tolist()} across the track; report both mirror candidates "
                "(MATH §7; finalize_estimate adds them)"
            )


def _ambiguous_on_one_straight_frame(estimate: Any, what: str) -> None:
    if estimate.ambiguous is not True:
        check_failed(
            f"ambiguous is {estimate.ambiguous!r} on {what}; one straight frame cannot tell "
            "the side of the track (MATH §7): report ambiguous=True (finalize_estimate does)"
        )


def check_mirror_pair_reproduces_data(estimator: Any) -> None:
    """One straight frame (``paper-1m``, ``climb-straight``, ``random-straight``): the
    estimate is ``ambiguous``, every candidate reproduces the noise-free data (the
    Gauss-Newton step from it to the data, whitened by the σ's of the modalities it uses, is
    within the tolerance), and there are two distinct candidates, mirror images across the
    track (MATH §7). On noisy data every candidate still comes with its mirror image.

    So a wrong solution fails even when ``finalize_estimate`` adds its mirror image.
    """
    capabilities = declared_capabilities(estimator)
    for name in ("paper-1m", "climb-straight", "random-straight"):
        problem = reference_problem(name)
        data = problem.data()
        what = f"one straight frame (noise-free {problem.label} data)"
        estimate = estimate_or_fail(estimator, data, what)
        require_success(estimate, what)
        _ambiguous_on_one_straight_frame(estimate, what)
        tolerance = problem_tolerance_m(capabilities, problem)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        modalities = sorted(capabilities.modalities & data.modalities)
        fresh = problem.data()  # the estimator may have written to its copy
        for point in candidates:
            rms, step, unexplained = data_misfit(fresh, point, modalities)
            if not (step <= tolerance and unexplained <= MISFIT_LIMIT):
                check_failed(
                    f"on {what} the candidate {point.tolist()} does not reproduce the data: "
                    f"its {'+'.join(modalities)} residuals are {rms:.3g} σ RMS and the data put "
                    f"the emitter {step:.3g} m from it (tolerance "
                    f"{tolerance_text(capabilities, problem)}). Every candidate must fit the "
                    "data: compute the solution from the measurements; adding the mirror image "
                    "of a wrong point (finalize_estimate does) does not make it right"
                )
        distinct = _distinct(candidates, 10.0 * tolerance)
        if len(distinct) < 2:
            check_failed(
                f"on {what} the candidates {candidates.tolist()} are one point; the emitter "
                "and its mirror image across the track are two distinct points that fit the "
                "data equally (MATH §7): report both"
            )
        _mirror_closure(candidates, data, tolerance, what)
    data = noisy_reference("paper-1m")
    what = "one straight frame (noisy 'paper-1m' data)"
    estimate = estimate_or_fail(estimator, data, what)
    require_success(estimate, what)
    _ambiguous_on_one_straight_frame(estimate, what)
    candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    _mirror_closure(candidates, data, agreement_tolerance_m(estimator), what)


def check_not_ambiguous_with_two_headings(estimator: Any) -> None:
    """Noise-free data with a second heading (``turn``, ``far-turn``, ``climb``,
    ``random-turn``) resolve the side: the estimate is not ``ambiguous`` (MATH §7). Runs for
    estimators that declare ``frames="all"``."""
    for name in ("turn", "far-turn", "climb", "random-turn"):
        problem = reference_problem(name)
        what = f"noise-free {problem.label} data"
        estimate = estimate_or_fail(estimator, problem.data(), what)
        require_success(estimate, what)
        if estimate.ambiguous is not False:
            check_failed(
                f"ambiguous is {estimate.ambiguous!r} on {what} (candidates "
                f"{np.asarray(estimate.candidates_m).tolist()}); a second heading removes the "
                "mirror ambiguity (MATH §7): use every frame and report one candidate, or "
                "declare the frames used in Capabilities.frames (e.g. frames='last')"
            )
