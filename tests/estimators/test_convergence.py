"""No silent divergence: a streamed estimate that succeeds is the optimum of its frames.

At −20 dB on ``paper-1m-turn`` the smoother's ISAM2 (undamped Gauss-Newton) walked off to
hundreds of kilometres on the straight frames and still reported a success with an empty
message; the iterated EKF reported one answer twice after the turn. These tests stream frames
0..9 through ``init``/``update``/``estimate_state`` and hold every successful estimate to the
maximum likelihood of the same frames (MATH §10), in units of the accumulated √CRLB (MATH §8).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from comparison.crlb import fisher_information, rmse_bound_m
from estimators.registry import make_estimator
from estimators.sequential.mirror_hypotheses import single_mode
from scenarios import get_scenario, simulate, trial_seeds

pytest.importorskip("gtsam")

SCENARIO = "paper-1m-turn"
SNR_DB = -20.0
TURN_FRAME = 4
"""Frames 4+ of ``paper-1m-turn`` are flown on the new heading."""

NEAR_CRLB = 1.0
"""A successful streamed estimate lies within this many √CRLB of the nearest ML candidate of
the same frames. Streaming and batch reach the same optimum; over 500 trials × 10 frames at
−20 dB the largest gap measured was 0.08 √CRLB; before the checks it reached 2·10⁵ √CRLB."""


def ml_gap_in_crlb(data, frame: int, estimate, ml) -> float:
    """Distance from ``estimate`` to the nearest ML candidate of frames ``0..frame``, in √CRLB."""
    seen = data.up_to_frame(frame)
    reference = ml.estimate(seen)
    assert reference.success, reference.message
    bound = float(
        rmse_bound_m(fisher_information(seen, get_scenario(SCENARIO).emitter_m, "toa+doppler"))
    )
    gap = np.min(np.linalg.norm(reference.candidates_m - estimate.position_m, axis=1))
    return float(gap) / bound


def streamed_estimates(estimator, data):
    state = estimator.init()
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
        yield state, estimator.estimate_state(state)


def test_reproducer_falls_back_to_the_batch_solve_instead_of_diverging() -> None:
    """Trial 330 of seed 757: ISAM2 diverged to (216742, 13815) on frame 0 and stayed off for
    frames 0-3 with ``success=True`` and no message. Now every frame is within 1 √CRLB of the
    ML and of the batch solve, and each fallback says so."""
    data = simulate(get_scenario(SCENARIO), snr_db=SNR_DB, seed=trial_seeds(757, 500)[330])
    smoother, ml = make_estimator("gtsam-smoother"), make_estimator("ml")
    fallbacks = 0
    for frame, (_, estimate) in enumerate(streamed_estimates(smoother, data)):
        assert estimate.success, estimate.message
        assert np.all(np.isfinite(estimate.candidates_m))
        assert ml_gap_in_crlb(data, frame, estimate, ml) < NEAR_CRLB
        batch = smoother.estimate(data.up_to_frame(frame))
        assert batch.success, batch.message
        gap = np.min(np.linalg.norm(batch.candidates_m - estimate.position_m, axis=1))
        assert gap < 1e-3
        if estimate.diagnostics["fallback"] == "batch":
            fallbacks += 1
            assert "fell back to the batch solve" in estimate.message
            assert estimate.diagnostics["fallback_reason"]
        else:
            assert estimate.diagnostics["fallback"] == "none"
            assert estimate.diagnostics["fallback_reason"] == ""
    # frame 0 itself diverged: it must be one of the fallbacks
    first = smoother.estimate_state(smoother.update(smoother.init(), data.take(data.frame == 0)))
    assert first.diagnostics["fallback"] == "batch"
    assert "the cost rose" in first.diagnostics["fallback_reason"]
    np.testing.assert_allclose(first.position_m[0], 34.73, atol=0.01)
    assert fallbacks >= 2
    assert first.diagnostics["fallbacks"] == 1


N_SWEEP = 60


def test_smoother_sweep_never_reports_a_diverged_success() -> None:
    """60 trials at −20 dB, every frame: success within 1 √CRLB of the ML of the same frames.

    Before the checks, 16 of these 60 trials reported successes more than 1 √CRLB off (36
    estimates; 4 of them 30 to 2·10⁵ √CRLB off with an empty message). The fallbacks that
    replace them are counted and each is announced.
    """
    scenario = get_scenario(SCENARIO)
    smoother, ml = make_estimator("gtsam-smoother"), make_estimator("ml")
    gaps = []
    fallbacks = 0
    for seed in trial_seeds(757, N_SWEEP):
        data = simulate(scenario, snr_db=SNR_DB, seed=seed)
        for frame, (_, estimate) in enumerate(streamed_estimates(smoother, data)):
            assert estimate.success, estimate.message
            gaps.append(ml_gap_in_crlb(data, frame, estimate, ml))
            if estimate.diagnostics.get("fallback") == "batch":
                fallbacks += 1
                assert "fell back to the batch solve" in estimate.message
    print(f"largest gap {max(gaps):.3g} sqrt(CRLB), {fallbacks} fallbacks")
    assert max(gaps) < NEAR_CRLB
    assert fallbacks > 0  # the sweep exercises the fallback


N_EKF = 100


def test_ekf_reports_one_answer_after_the_turn() -> None:
    """100 trials at −20 dB, frames 4-9: no two surviving hypotheses form a unimodal mixture
    (the merge threshold), so no estimate after the turn has two candidates.

    Before the merge, 43 of these 100 trials kept a second candidate after the turn (236
    estimates), a median 1.9 m from the first: one answer reported twice.
    """
    scenario = get_scenario(SCENARIO)
    ekf = make_estimator("ekf")
    duplicates = 0
    post_turn = 0
    for seed in trial_seeds(757, N_EKF):
        data = simulate(scenario, snr_db=SNR_DB, seed=seed)
        for frame, (state, estimate) in enumerate(streamed_estimates(ekf, data)):
            if frame < TURN_FRAME:
                continue
            post_turn += 1
            assert estimate.success, estimate.message
            for a, b in itertools.combinations(state.hypotheses, 2):
                if single_mode(
                    a.log_weight, a.mean_m, a.covariance_m2, b.log_weight, b.mean_m, b.covariance_m2
                ):
                    duplicates += 1
            if len(estimate.candidates_m) > 1:
                duplicates += 1
    assert post_turn == N_EKF * 6
    assert duplicates == 0


def test_single_mode_is_the_two_gaussian_bimodality_limit() -> None:
    """Equal weights and covariances: one mode iff the Mahalanobis distance is at most 2."""
    eye = np.eye(2)
    assert single_mode(0.0, [0.0, 0.0], eye, 0.0, [1.99, 0.0], eye)
    assert not single_mode(0.0, [0.0, 0.0], eye, 0.0, [2.01, 0.0], eye)
    # the lighter of two unequal weights bumps the density less: one mode further out
    assert single_mode(0.0, [0.0, 0.0], eye, -17.0, [2.4, 0.0], eye)
    # a true mirror pair after a turn (30 m apart, σ ≈ 1 m) keeps two modes at any such weight
    assert not single_mode(0.0, [35.0, 15.0], eye, -20.0, [35.0, -15.0], eye)
    # a covariance that is not positive definite never merges
    assert not single_mode(0.0, [0.0, 0.0], eye, 0.0, [0.1, 0.0], np.diag([1.0, -1.0]))


SADDLE_SNR_DB = -10.0


@pytest.mark.parametrize(
    ("name", "near_crlb"),
    # the EKF is not the ML of all frames (it linearised the earlier ones): a wider margin,
    # still well below the saddle's 6-8 √CRLB
    [("gtsam-smoother", NEAR_CRLB), ("ekf", 3.0)],
)
def test_on_track_saddle_is_left_for_the_off_track_minimum(name: str, near_crlb: float) -> None:
    """Trial 11 of seed 757 (300 trials) at −10 dB: the first frame's closed form lies on the
    track's vertical plane, and by symmetry every later iterate stayed there, at a saddle
    (35.1, 0) 6-8 √CRLB from the ML pair (35.5, ±12) on frames 2-3, reported as a success.
    Both estimators now leave the saddle along its negative curvature."""
    data = simulate(get_scenario(SCENARIO), snr_db=SADDLE_SNR_DB, seed=trial_seeds(757, 300)[11])
    estimator, ml = make_estimator(name), make_estimator("ml")
    escaped = False
    for frame, (_, estimate) in enumerate(streamed_estimates(estimator, data)):
        assert estimate.success, estimate.message
        assert ml_gap_in_crlb(data, frame, estimate, ml) < near_crlb
        if 1 <= frame < TURN_FRAME:
            assert abs(estimate.position_m[1]) > 5.0  # off the track, not the saddle at y = 0
        escaped |= "saddle" in estimate.diagnostics.get("fallback_reason", "")
    assert escaped
