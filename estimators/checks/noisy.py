"""The checks on noisy data (MATH §8): the error is near the Cramér-Rao bound, and the answer
follows the emitter."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.checks.forward_model import crlb_rmse_m
from estimators.checks.reference_problems import (
    DATA_SEED,
    RNG_SEED,
    _rng,
    reference_problem,
    select_frames,
)
from estimators.checks.results import _capabilities, _fail, _run, _succeeded
from estimators.checks.tolerances import CRLB_FACTOR, CRLB_SNR_DB, CRLB_TRIALS
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate


def check_noisy_error_near_crlb(estimator: Any) -> None:
    """On :data:`CRLB_TRIALS` seeded trials at :data:`CRLB_SNR_DB` of a straight frame
    (``paper-1m``) and of ``far-turn``, the side-resolved RMSE (nearest candidate to the
    emitter) is at most :data:`CRLB_FACTOR` times the CRLB √trace(J⁻¹) of the declared
    modalities and frames (MATH §8). Catches an estimate that ignores the data or collapses
    onto the track when there is noise."""
    capabilities = _capabilities(estimator)
    modalities = sorted(capabilities.modalities)
    for name in ("paper-1m", "far-turn"):
        problem = reference_problem(name)
        batch = problem.trials(snr_db=CRLB_SNR_DB, n_trials=CRLB_TRIALS)
        truth = problem.emitter_m
        errors = []
        for index in range(batch.n_trials):
            what = f"noisy trial {index} of {problem.label} at {CRLB_SNR_DB:g} dB"
            estimate = _run(
                estimator, batch.trial(index), what, rng=np.random.default_rng(RNG_SEED + index)
            )
            _succeeded(estimate, what)
            candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
            if len(candidates) == 0:
                _fail(f"no candidate on {what}; candidates_m must hold position_m")
            errors.append(float(np.min(np.linalg.norm(candidates - truth, axis=1))))
        used = select_frames(batch.geometry, capabilities.frames)
        bound = crlb_rmse_m(used if used is not None else batch.geometry, truth, modalities)
        rmse = float(np.sqrt(np.mean(np.square(errors))))
        if not rmse <= CRLB_FACTOR * bound:
            _fail(
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
        estimate = _run(estimator, data.without_truth(), what, rng=_rng())
        _succeeded(estimate, what)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            _fail(f"no candidate on {what}; candidates_m must hold position_m")
        found.append(candidates[np.argmin(np.linalg.norm(candidates - emitter, axis=1))])
    shift = emitters[1] - emitters[0]
    along = float((found[1] - found[0]) @ shift / np.linalg.norm(shift))
    if not along >= 0.5 * float(np.linalg.norm(shift)):
        _fail(
            f"the emitter moved {np.linalg.norm(shift):.1f} m, from {emitters[0].tolist()} to "
            f"{emitters[1].tolist()} (same flight, same noise), but the answer moved "
            f"{along:.3g} m that way, from {found[0].tolist()} to {found[1].tolist()}: the "
            "estimate does not follow the measurements. Compute it from the data"
        )
