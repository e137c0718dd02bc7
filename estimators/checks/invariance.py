"""The checks of invariances and declared capabilities: the estimate moves with the geometry
(rigid motions), does not depend on the unit of length when it claims so, and uses exactly the
modalities and frames it declares."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Capabilities, Estimate
from estimators.checks.reference_problems import (
    CHECK_SEED_ENV,
    NOISY_SNR_DB,
    ReferenceProblem,
    check_seed,
    reference_problem,
    reference_rng,
    select_frames,
)
from estimators.checks.results import (
    FIELD_OF_MODALITY,
    check_failed,
    declared_capabilities,
    estimate_or_fail,
    not_an_estimate,
    require_success,
)
from estimators.checks.tolerances import EXACT_RTOL, agreement_tolerance_m, problem_tolerance_m
from scenarios.types import MODALITIES, MeasurementSet

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# moved and rescaled geometries
# --------------------------------------------------------------------------------------------


def moved(data: MeasurementSet, matrix: FloatArray, offset_m: FloatArray) -> MeasurementSet:
    """The data of the geometry moved by ``x ↦ matrix x + offset_m`` in the horizontal plane.

    ``matrix`` is orthogonal (a rotation or a reflection): positions and velocities move, and
    every noise-free Doppler, ToA and RSS value is unchanged (they depend on distances and
    on ``vᵀu`` only), so the measured values are kept as they are.
    """
    matrix = np.asarray(matrix, dtype=float)
    position = np.array(data.position_m)
    velocity = np.array(data.velocity_mps)
    position[:, :2] = position[:, :2] @ matrix.T + np.asarray(offset_m, dtype=float)
    velocity[:, :2] = velocity[:, :2] @ matrix.T
    return replace(data, position_m=position, velocity_mps=velocity, truth_emitter_m=None)


def in_kilometres(data: MeasurementSet) -> MeasurementSet:
    """The same measurements in km: positions, velocities, c, the emitter height and the RSS
    reference distance divided by 1000; τ, f, P and every σ unchanged."""
    rss_model = data.rss_model
    if rss_model is not None:
        rss_model = replace(rss_model, reference_distance_m=rss_model.reference_distance_m / 1e3)
    return replace(
        data,
        position_m=data.position_m / 1000.0,
        velocity_mps=data.velocity_mps / 1000.0,
        speed_of_light_mps=data.speed_of_light_mps / 1000.0,
        emitter_height_m=data.emitter_height_m / 1000.0,
        rss_model=rss_model,
        truth_emitter_m=None,
    )


def rigid_motions(seed: int) -> list[tuple[str, FloatArray, FloatArray]]:
    """``(description, matrix, offset_m)`` of a translation, a rotation and a reflection drawn
    from ``seed``: a shift by 1-5 km, a turn by 20-340° about a point within 3 km of the
    origin, a reflection across a line through such a point."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))

    def direction(angle: float) -> FloatArray:
        return np.array([math.cos(angle), math.sin(angle)])

    shift = rng.uniform(1000.0, 5000.0) * direction(rng.uniform(0.0, 2 * math.pi))
    angle = math.radians(rng.uniform(20.0, 340.0))
    centre = rng.uniform(-3000.0, 3000.0, size=2)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    tilt = rng.uniform(0.0, math.pi)
    through = rng.uniform(-3000.0, 3000.0, size=2)
    reflection = np.array(
        [[math.cos(2 * tilt), math.sin(2 * tilt)], [math.sin(2 * tilt), -math.cos(2 * tilt)]]
    )
    return [
        (f"translated by ({shift[0]:.1f}, {shift[1]:.1f}) m", np.eye(2), shift),
        (
            f"rotated by {math.degrees(angle):.1f}° about ({centre[0]:.1f}, {centre[1]:.1f}) m",
            rotation,
            centre - rotation @ centre,
        ),
        (
            f"reflected across the line through ({through[0]:.1f}, {through[1]:.1f}) m at "
            f"{math.degrees(tilt):.1f}° from east",
            reflection,
            through - reflection @ through,
        ),
    ]


# --------------------------------------------------------------------------------------------
# invariances
# --------------------------------------------------------------------------------------------


def _matching_gap(expected: FloatArray, got: FloatArray) -> float:
    """Largest distance from a point of either set to the nearest point of the other."""
    if len(expected) != len(got):
        return math.inf
    if len(expected) == 0:
        return 0.0
    distance = np.linalg.norm(expected[:, None, :] - got[None, :, :], axis=-1)
    return float(max(np.max(np.min(distance, axis=1)), np.max(np.min(distance, axis=0))))


def _follows(
    before: Estimate,
    after: Estimate,
    mapped: Callable[[FloatArray], FloatArray],
    tolerance: float,
) -> str:
    """Empty if ``after`` is ``before`` mapped (candidates as sets; the position too when
    there is no tie), else what differs."""
    if before.ambiguous != after.ambiguous:
        return f"ambiguous {before.ambiguous} became {after.ambiguous}"
    expected = mapped(np.asarray(before.candidates_m, dtype=float).reshape(-1, 2))
    got = np.asarray(after.candidates_m, dtype=float).reshape(-1, 2)
    if len(got) != len(expected):
        return (
            f"the candidates are {got.tolist()}, not the {len(expected)} moved ones "
            f"{expected.tolist()}"
        )
    gap = _matching_gap(expected, got)
    if not gap <= tolerance:
        return (
            f"the candidates are {got.tolist()}, the moved ones {expected.tolist()} (gap "
            f"{gap:.3g} m, tolerance {tolerance:.3g} m)"
        )
    if not before.ambiguous and np.shape(before.position_m) == np.shape(after.position_m) == (2,):
        position = mapped(np.asarray(before.position_m, dtype=float)[None, :])[0]
        gap = float(np.linalg.norm(position - after.position_m))
        if not gap <= tolerance:
            return f"position_m is {after.position_m.tolist()}, moved {position.tolist()}"
    return ""


def _answer_differences(a: Any, b: Any, tolerance: float) -> list[str]:
    """How two answers differ: success, ambiguity, candidates as sets, the position when
    there is no tie (empty: the same answer)."""
    if not (isinstance(a, Estimate) and isinstance(b, Estimate)):
        return [not_an_estimate(b if isinstance(a, Estimate) else a)]
    if a.success != b.success:
        return [f"success {a.success} vs {b.success} ({b.message or a.message!r})"]
    difference = _follows(a, b, lambda points: points, tolerance)
    return [difference] if difference else []


def _invariance_tolerance_m(
    capabilities: Capabilities, problem: ReferenceProblem, data: MeasurementSet
) -> float:
    """The noise-free tolerance of ``problem``, or rounding (:data:`EXACT_RTOL`) at the
    largest coordinate of the moved ``data`` when that is larger."""
    extent = float(np.max(np.abs(data.position_m[:, :2])))
    return max(problem_tolerance_m(capabilities, problem), EXACT_RTOL * extent)


def check_equivariant_under_rigid_motions(estimator: Any) -> None:
    """Translating, rotating or reflecting the geometry (UAV positions and velocities, hence
    the emitter) moves every candidate the same way, within the tolerance, on noisy data of a
    straight frame (``paper-1m``) and of two climbing headings (``climb``). The motions are
    drawn from the check seed; the measured values do not change under them (MATH §1)."""
    capabilities = declared_capabilities(estimator)
    seed = check_seed()
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        what = f"noisy {problem.label} data"
        before = estimate_or_fail(
            estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=reference_rng()
        )
        require_success(before, what)
        for description, matrix, offset in rigid_motions(seed):
            where = f"{what} {description} (check seed {seed}; replay with {CHECK_SEED_ENV}={seed})"
            moved_data = moved(problem.data(snr_db=NOISY_SNR_DB), matrix, offset)
            tolerance = _invariance_tolerance_m(capabilities, problem, moved_data)
            after = estimate_or_fail(estimator, moved_data, where, rng=reference_rng())
            require_success(after, where)
            difference = _follows(
                before, after, lambda points, m=matrix, o=offset: points @ m.T + o, tolerance
            )
            if difference:
                check_failed(
                    f"on {where}, {difference}. The estimate must move with the geometry: use "
                    "positions relative to the samples and directions relative to the velocity, "
                    "with no fixed origin, axis or heading (the paper's first-row Doppler line "
                    "of MATH §3 depends on the heading, for one)"
                )


def check_unit_invariant(estimator: Any) -> None:
    """(Only when ``Capabilities.unit_invariant`` is claimed.) The same noisy data in
    kilometres (positions, velocities, c, the emitter height and the RSS reference distance
    divided by 1000; τ, f, P and every σ unchanged) give the same candidates, scaled (MATH §6).
    """
    capabilities = declared_capabilities(estimator)
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        data = problem.data(snr_db=NOISY_SNR_DB)
        what = f"noisy {problem.label} data"
        metres = estimate_or_fail(
            estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=reference_rng()
        )
        require_success(metres, what)
        kilometres = estimate_or_fail(
            estimator, in_kilometres(data), what + " in kilometres", rng=reference_rng()
        )
        require_success(kilometres, what + " in kilometres")
        scaled = replace(
            kilometres,
            position_m=1000.0 * np.asarray(kilometres.position_m),
            candidates_m=1000.0 * np.asarray(kilometres.candidates_m),
        )
        difference = _follows(
            metres,
            scaled,
            lambda points: points,
            _invariance_tolerance_m(capabilities, problem, data),
        )
        if difference:
            check_failed(
                f"on {what} in kilometres (times 1000), {difference}. It claims "
                "unit_invariant=True: weight every residual by its σ (MATH §6) and use no "
                "length or speed constant in metres; or declare unit_invariant=False"
            )


# --------------------------------------------------------------------------------------------
# the declared capabilities are truthful
# --------------------------------------------------------------------------------------------


def check_unused_modalities_ignored(estimator: Any) -> None:
    """Removing a modality that ``Capabilities.modalities`` does not list (one at a time and
    all together) changes nothing, on noisy data of ``paper-1m`` and ``climb`` that carry all
    three: the comparison scores an estimator against the CRLB of what it declares."""
    capabilities = declared_capabilities(estimator)
    unused = [m for m in MODALITIES if m not in capabilities.modalities]
    if not unused:
        return
    removals = [(m,) for m in unused] + ([tuple(unused)] if len(unused) > 1 else [])
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        what = f"noisy {problem.label} data"
        full = estimate_or_fail(
            estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=reference_rng()
        )
        require_success(full, what)
        for removed in removals:
            fields_ = ", ".join(FIELD_OF_MODALITY[m] for m in removed)
            declared = sorted(capabilities.modalities)
            try:
                reduced = estimator.estimate(
                    problem.data(snr_db=NOISY_SNR_DB).without(*removed), rng=reference_rng()
                )
            except ValueError as error:
                head = str(error).split(": ", 1)[0]
                if any(FIELD_OF_MODALITY[m] in head for m in removed):
                    check_failed(
                        f"without {fields_} the estimate raises ValueError({str(error)!r}), "
                        f"so it reads them, but capabilities().modalities is {declared}; "
                        f"declare {list(removed)} in Capabilities.modalities"
                    )
                raise AssertionError(
                    f"{what} without {fields_}, which it does not declare, raised "
                    f"ValueError({str(error)!r}); a modality outside "
                    f"capabilities().modalities ({declared}) must not matter"
                ) from error
            except Exception as error:
                raise AssertionError(
                    f"{what} without {fields_} raised {type(error).__name__}: {error}; a "
                    f"modality outside capabilities().modalities ({declared}) must not matter"
                ) from error
            differences = _answer_differences(full, reduced, agreement_tolerance_m(estimator))
            if differences:
                check_failed(
                    f"removing {fields_} from {what} changed the estimate: "
                    f"{'; '.join(differences)}; it uses them, but capabilities().modalities "
                    f"is {declared}: declare {list(removed)} in Capabilities.modalities (or "
                    "stop reading them)"
                )


def check_uses_the_declared_frames(estimator: Any) -> None:
    """``Capabilities.frames`` is truthful, on noisy data of ``turn`` and ``climb``: with
    ``frames="last"`` (or listed frames), dropping the other frames changes nothing; with
    ``frames="all"``, dropping the first frame changes the estimate."""
    capabilities = declared_capabilities(estimator)
    frames = capabilities.frames
    for name in ("turn", "climb"):
        problem = reference_problem(name)
        data = problem.data(snr_db=NOISY_SNR_DB)
        what = f"noisy {problem.label} data"
        full = estimate_or_fail(
            estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=reference_rng()
        )
        require_success(full, what)
        if frames == "all":
            first = int(data.frame[0])
            later = estimate_or_fail(
                estimator,
                data.take(data.frame != first),
                what + " without frame 0",
                rng=reference_rng(),
            )
            if not _answer_differences(full, later, agreement_tolerance_m(estimator)):
                check_failed(
                    f"dropping frame {first} of {what} did not change the estimate, yet "
                    "capabilities().frames is 'all'; declare the frames it uses "
                    "(Capabilities(frames='last') for the last frame only)"
                )
            continue
        used = select_frames(data, frames)
        if used is None:
            continue
        kept = estimate_or_fail(
            estimator, used, f"{what}, frames {frames!r} only", rng=reference_rng()
        )
        differences = _answer_differences(full, kept, agreement_tolerance_m(estimator))
        if differences:
            check_failed(
                f"keeping only frames {frames!r} (as declared) of {what} changed the estimate: "
                f"{'; '.join(differences)}; it uses other frames too: declare frames='all' (or "
                "the frames it reads)"
            )
