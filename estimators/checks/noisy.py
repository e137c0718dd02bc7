"""The checks on noisy data (MATH §8): the error is near the Cramér-Rao bound, the answer
follows the emitter, and it leaves the track once the data put the emitter off it."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.checks.forward_model import crlb_rmse_m, whitened_misfit
from estimators.checks.reference_problems import (
    DATA_SEED,
    RNG_SEED,
    on_track_start_data,
    reference_problem,
    reference_rng,
    select_frames,
)
from estimators.checks.results import (
    check_failed,
    declared_capabilities,
    estimate_or_fail,
    is_sequential,
    require_success,
    streamed_estimate,
)
from estimators.checks.tolerances import (
    CRLB_FACTOR,
    CRLB_SNR_DB,
    CRLB_TRIALS,
    noise_free_tolerance_m,
)
from scenarios.catalog import get_scenario
from scenarios.geometry import StraightTrack
from scenarios.simulate import simulate


def check_noisy_error_near_crlb(estimator: Any) -> None:
    """On :data:`CRLB_TRIALS` seeded trials at :data:`CRLB_SNR_DB` of a straight frame
    (``paper-1m``) and of ``far-turn``, the side-resolved RMSE (nearest candidate to the
    emitter) is at most :data:`CRLB_FACTOR` times the CRLB √trace(J⁻¹) of the declared
    modalities and frames (MATH §8). Catches an estimate that ignores the data or collapses
    onto the track when there is noise."""
    capabilities = declared_capabilities(estimator)
    modalities = sorted(capabilities.modalities)
    for name in ("paper-1m", "far-turn"):
        problem = reference_problem(name)
        batch = problem.trials(snr_db=CRLB_SNR_DB, n_trials=CRLB_TRIALS)
        truth = problem.emitter_m
        errors = []
        for index in range(batch.n_trials):
            what = f"noisy trial {index} of {problem.label} at {CRLB_SNR_DB:g} dB"
            estimate = estimate_or_fail(
                estimator, batch.trial(index), what, rng=np.random.default_rng(RNG_SEED + index)
            )
            require_success(estimate, what)
            candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
            if len(candidates) == 0:
                check_failed(f"no candidate on {what}; candidates_m must hold position_m")
            errors.append(float(np.min(np.linalg.norm(candidates - truth, axis=1))))
        used = select_frames(batch.geometry, capabilities.frames)
        bound = crlb_rmse_m(used if used is not None else batch.geometry, truth, modalities)
        rmse = float(np.sqrt(np.mean(np.square(errors))))
        if not rmse <= CRLB_FACTOR * bound:
            check_failed(
                f"on {batch.n_trials} noisy trials of {problem.label} at {CRLB_SNR_DB:g} dB the "
                f"side-resolved RMSE (nearest candidate to the emitter {truth.tolist()}) is "
                f"{rmse:.3g} m, {rmse / bound:.3g} times the CRLB √trace(J⁻¹) = {bound:.3g} m of "
                f"the {'+'.join(modalities)} data it declares (frames {capabilities.frames!r}; "
                f"limit {CRLB_FACTOR:g}×); median error {np.median(errors):.3g} m. The answer "
                "must follow the noisy measurements: an estimate that ignores them, or lands on "
                "the track when they are noisy, fails here even if it is exact without noise"
            )


def check_estimate_moves_with_the_emitter(estimator: Any) -> None:
    """The same flight (``turn``) and the same noise draw at :data:`CRLB_SNR_DB`, with the
    emitter at (35, 15) m and then at (−15, 45) m: the answer (the candidate nearest each
    emitter) moves at least half as far as the emitter, in its direction."""
    base = get_scenario("turn")
    emitters = (np.array([35.0, 15.0]), np.array([-15.0, 45.0]))
    found = []
    for emitter in emitters:
        data = simulate(base.replace(emitter_m=emitter), snr_db=CRLB_SNR_DB, seed=DATA_SEED)
        what = f"noisy 'turn' data with the emitter at {emitter.tolist()}"
        estimate = estimate_or_fail(estimator, data.without_truth(), what, rng=reference_rng())
        require_success(estimate, what)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            check_failed(f"no candidate on {what}; candidates_m must hold position_m")
        found.append(candidates[np.argmin(np.linalg.norm(candidates - emitter, axis=1))])
    shift = emitters[1] - emitters[0]
    along = float((found[1] - found[0]) @ shift / np.linalg.norm(shift))
    if not along >= 0.5 * float(np.linalg.norm(shift)):
        check_failed(
            f"the emitter moved {np.linalg.norm(shift):.1f} m, from {emitters[0].tolist()} to "
            f"{emitters[1].tolist()} (same flight, same noise), but the answer moved "
            f"{along:.3g} m that way, from {found[0].tolist()} to {found[1].tolist()}: the "
            "estimate does not follow the measurements. Compute it from the data"
        )


def check_leaves_the_track(estimator: Any) -> None:
    """On the data of :func:`~estimators.checks.reference_problems.on_track_start_data` (the
    first frame's ranges 3 m short, so that the closed form on it alone returns one point on
    the track, MATH §5; then the same track, then a turn), the answer leaves the track: no
    candidate lies on the first frame's track (within the noise-free tolerance), and the one
    nearest the emitter is within ``χ √trace(J⁻¹) +`` that tolerance of it, where ``J`` is the
    Fisher information (MATH §8) of the declared modalities and frames at the emitter and ``χ``
    the whitened misfit of those data there (:func:`~estimators.checks.forward_model.
    whitened_misfit`): to first order, data ``χ`` σ from an emitter's noise-free values move
    the maximum likelihood no further (MATH §10). A sequential estimator is judged on
    ``estimate`` and on ``init``/``update``/``estimate_state`` over the frames. Catches a
    filter or a solver started on the closed form's on-track candidate that never leaves the
    track's vertical plane: by symmetry nothing pulls it off while the track is straight, and
    with no cross-track variance left (that frame's Fisher information is rank-deficient
    there) not even the turn does."""
    capabilities = declared_capabilities(estimator)
    modalities = sorted(capabilities.modalities)
    data, exact, truth = on_track_start_data()
    track = StraightTrack.of_frame(data.select_frames([int(data.frame[0])]))
    assert track is not None  # the first frame is one straight frame
    used = select_frames(data, capabilities.frames)
    used_exact = select_frames(exact, capabilities.frames)
    what = "the on-track-start data (first frame's ranges 3 m short, then a turn)"
    if used is None or used_exact is None:
        check_failed(f"the declared frames {capabilities.frames!r} select no sample of {what}")
    assert used is not None and used_exact is not None
    exact_m = noise_free_tolerance_m(estimator)
    misfit = whitened_misfit(used, truth, modalities)
    bound = crlb_rmse_m(used_exact, truth, modalities)
    tolerance = misfit * bound + exact_m
    answers = [("estimate", estimate_or_fail(estimator, data, what, rng=reference_rng()))]
    if is_sequential(estimator):
        answers.append(("streamed frame by frame", _stream_checked(estimator, data, what)))
    problems = []
    for how, estimate in answers:
        require_success(estimate, f"{what} ({how})")
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            check_failed(f"no candidate on {what} ({how}); candidates_m must hold position_m")
        offsets = track.cross_track_m(candidates)
        errors = np.linalg.norm(candidates - truth, axis=1)
        nearest = int(np.argmin(errors))
        on_track = [
            c.tolist() for c, o in zip(candidates, offsets, strict=True) if abs(o) <= exact_m
        ]
        if on_track:
            problems.append(
                f"{how}, the candidate(s) {on_track} lie on the first frame's track (cross-track "
                f"offset within {exact_m:.3g} m), where the closed form of the first frame alone "
                f"puts the emitter, while the truth is {abs(track.cross_track_m(truth)):.3g} m "
                "off it"
            )
        if not errors[nearest] <= tolerance:
            problems.append(
                f"{how}, the candidate nearest the emitter {truth.tolist()}, "
                f"{np.round(candidates[nearest], 3).tolist()} ({offsets[nearest]:.3g} m off the "
                f"first frame's track), is {errors[nearest]:.3g} m from it, beyond "
                f"χ √trace(J⁻¹) + {exact_m:.3g} m = {misfit:.3g} × {bound:.3g} m + "
                f"{exact_m:.3g} m = {tolerance:.3g} m for the {'+'.join(modalities)} data it "
                f"declares (frames {capabilities.frames!r})"
            )
    if problems:
        check_failed(
            f"on {what}: {'; '.join(problems)}. A filter or solver started at the first frame's "
            "on-track candidate stays on the track's vertical plane by symmetry; it must be able "
            "to leave it: keep the cross-track variance the data do not fix there (the first "
            "frame's Fisher information is rank-deficient on the track), leave a saddle along "
            "its negative curvature, or start the mirror hypotheses off the track"
        )


def _stream_checked(estimator: Any, data: Any, what: str) -> Any:
    """:func:`~estimators.checks.results.streamed_estimate`; an exception becomes a failure."""
    try:
        return streamed_estimate(estimator, data, rng=reference_rng())
    except Exception as error:
        raise AssertionError(
            f"streaming {what} raised {type(error).__name__}: {error}; valid data must give an "
            "Estimate"
        ) from error
