"""The frame-by-frame estimators with the emitter's height unknown: a 3-D state (MATH §7, §8).

The EKF (:mod:`estimators.sequential.ekf`) and the GTSAM smoother
(:mod:`estimators.sequential.gtsam_smoother`) carry ``(x, y, z)`` (plus the nuisance parameters)
when the data declare ``"emitter_height_m"`` unknown: exact on noise-free climbing and level
turns, a straight track refused in one line, the covariance the 3-D CRLB, the smoother the
maximum likelihood of an independent solver.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.optimize import least_squares

from comparison.crlb import crlb_m2
from estimators.base import require_modalities
from estimators.checks.reference_problems import reference_problem
from estimators.frame_model import FrameModel
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.sequential.ekf import Ekf, EkfHypothesis
from estimators.sequential.gtsam_smoother import GtsamSmoother
from estimators.sequential.mirror_hypotheses import hypotheses_estimate
from scenarios import measurement_model as model
from scenarios.catalog import get_scenario, heading_velocities_mps
from scenarios.fisher import fisher_information
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan, NoiseSigmas, Scenario

BOTH = ("carrier_offset_hz", "emission_time_s")

ESTIMATORS = {
    "ekf": Ekf(),
    "ekf-random-walk": Ekf(process_noise_mps=0.05),
    "smoother": GtsamSmoother(),
    "smoother-random-walk": GtsamSmoother(process_noise_mps=0.05),
}


def height_flight(
    seed: int, *, climb_mps: float, n_frames: int = 4, unknowns=(HEIGHT_UNKNOWN,)
) -> Scenario:
    """A random flight of ``n_frames`` headings (the first two on one line, then turns), the
    emitter 0-60 m above the take-off ground at an unknown height, the UAV 80-200 m up and
    climbing at ``climb_mps`` from the third frame (0: level)."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 360.0)
    turns = rng.uniform(40.0, 140.0, n_frames - 2)
    headings = heading + np.cumsum(np.r_[0.0, 0.0, turns])
    velocities = np.array(heading_velocities_mps(rng.uniform(10.0, 30.0), list(headings)))
    velocities[2:, 2] = climb_mps
    return Scenario(
        name="height",
        emitter_m=rng.uniform(-250.0, 250.0, 2),
        emitter_height_m=rng.uniform(0.0, 60.0),
        flight=FlightPlan(
            start_position_m=[*rng.uniform(-250.0, 250.0, 2), rng.uniform(80.0, 200.0)],
            frame_velocities_mps=velocities,
            samples_per_frame=int(rng.integers(6, 12)),
            sample_interval_s=rng.uniform(0.3, 1.0),
        ),
        carrier_hz=rng.uniform(4e8, 2e9),
        noise=NoiseSigmas(doppler_hz=rng.uniform(0.1, 1.0), toa_s=rng.uniform(3.0, 15.0) / 3e8),
        modalities=("doppler", "toa"),
        carrier_offset_hz=rng.uniform(-900.0, 900.0),
        emission_time_s=rng.uniform(0.0, 1e-3),
        unknowns=unknowns,
    )


def streamed(estimator, data):
    """The state and the estimate after every frame, streamed."""
    state = estimator.init()
    estimates = []
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
        estimates.append(estimator.estimate_state(state))
    return state, estimates


def chi2_at(data, position_m) -> float:
    """``Σ`` of the squared whitened Doppler and range residuals at a 3-D position, the
    unknown offsets (if any) at their least-squares values (the profiled cost, MATH §15)."""
    frame = FrameModel.from_measurements(data)
    assert frame.dimension == 3
    k = data.n_samples
    residual = ((frame.measured - frame.predicted(position_m)) / frame.sigma).reshape(2, k)
    for name, row in (("carrier_offset_hz", 0), ("emission_time_s", 1)):
        if name in data.unknowns:
            residual[row] -= residual[row].mean()
    return float(np.sum(residual**2))


# --------------------------------------------------------------------------------------------
# noise-free exactness
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("unknowns", [(HEIGHT_UNKNOWN,), (*BOTH, HEIGHT_UNKNOWN)], ids=["z", "all"])
@pytest.mark.parametrize("climb_mps", [0.0, 2.5], ids=["level", "climbing"])
@pytest.mark.parametrize("name", list(ESTIMATORS))
@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_turns_give_the_emitter_exactly(seed, name, climb_mps, unknowns) -> None:
    """On noise-free data of a level and of a climbing turn (four frames, the first two on one
    line) every estimator returns ``(x, y, z)`` to ``1e-7`` of the mean range, batch and
    streamed, with a 3×3 covariance; every candidate lies below the UAV. In the level flight the
    reflection of the emitter through the flight plane fits as well (χ² ~ 0: the tie "the
    emitter is below the UAV" breaks, MATH §7); in the climbing one it does not."""
    estimator = ESTIMATORS[name]
    data = noise_free(height_flight(seed, climb_mps=climb_mps, unknowns=unknowns))
    truth = data.truth_emitter_m
    assert truth.shape == (3,)
    scale = float(np.mean(model.slant_range_m(data.position_m, truth)))
    require_modalities(estimator, data)
    batch = estimator.estimate(data)
    _, streamed_estimates = streamed(estimator, data)
    for estimate in (batch, streamed_estimates[-1]):
        assert estimate.success, estimate.message
        assert estimate.position_m.shape == (3,)
        assert estimate.covariance_m2.shape == (3, 3)
        np.testing.assert_allclose(estimate.position_m, truth, rtol=0, atol=1e-7 * scale)
        assert np.all(estimate.candidates_m[:, 2] <= data.position_m[:, 2].max())
    if HEIGHT_UNKNOWN in unknowns and BOTH[0] in unknowns:
        assert batch.diagnostics["carrier_offset_hz"] == pytest.approx(
            data.truth_carrier_offset_hz, abs=1e-6
        )
    reflection = truth.copy()
    reflection[2] = 2.0 * data.position_m[0, 2] - truth[2]
    chi2 = chi2_at(data, reflection)
    if climb_mps == 0.0:
        assert chi2 < 1e-12
    else:
        assert chi2 > 1e3


@pytest.mark.parametrize("scenario", ["hill", "hill-climb", "roof-beacon"])
def test_ukf_in_3d_is_within_a_tenth_of_its_sigma_on_noise_free_data(scenario) -> None:
    """The unscented updates (``filter="ukf"``) in the 3-D state: not exact (sigma points, not
    a linearisation at the mode), but on noise-free data within ``0.1`` of the reported 3×3
    covariance's standard deviations of the emitter (``1e-3`` with the height alone unknown,
    ``0.04`` on ``roof-beacon`` with the offsets unknown too)."""
    data = noise_free(get_scenario(scenario))
    estimate = Ekf(filter="ukf").estimate(data)
    assert estimate.success, estimate.message
    assert estimate.covariance_m2.shape == (3, 3)
    offset = estimate.position_m - data.truth_emitter_m
    assert float(np.sqrt(offset @ np.linalg.solve(estimate.covariance_m2, offset))) < 0.1


@pytest.mark.parametrize("name", ["ekf", "smoother"])
def test_a_straight_track_cannot_fix_the_height(name) -> None:
    """While every frame lies on one straight track the estimate fails with the mirror rule's
    one line (the emitter on a circle about the track); the frame after the turn gives it."""
    estimator = ESTIMATORS[name]
    data = noise_free(height_flight(3, climb_mps=0.0))
    _, estimates = streamed(estimator, data)
    for estimate in estimates[:2]:
        assert not estimate.success
        assert estimate.message == STRAIGHT_TRACK_HEIGHT
    assert all(estimate.success for estimate in estimates[2:])
    assert estimator.estimate(data.select_frames([0, 1])).message == STRAIGHT_TRACK_HEIGHT


@pytest.mark.parametrize("name", ["ekf", "smoother"])
def test_the_height_unknown_in_a_later_frame_is_refused(name) -> None:
    """The unknowns are the same over a pass: a frame that declares the height unknown after
    frames that did not raises ``ValueError`` naming ``unknowns``."""
    estimator = ESTIMATORS[name]
    scenario = height_flight(4, climb_mps=0.0)
    first = next(iter(noise_free(scenario.replace(unknowns=())).iter_frames()))
    later = list(noise_free(scenario).iter_frames())[1]
    state = estimator.update(estimator.init(), first)
    with pytest.raises(ValueError, match=r"^unknowns: "):
        estimator.update(state, later)


@pytest.mark.bits("a pickled state gives the same estimate_state")
@pytest.mark.parametrize("name", ["ekf", "smoother"])
def test_3d_states_pickle(name) -> None:
    """The states with a 3-D hypothesis (and with frames waiting on the first straight track)
    are plain values: a pickled copy gives the same estimate."""
    estimator = ESTIMATORS[name]
    data = simulate(height_flight(5, climb_mps=1.0, unknowns=(*BOTH, HEIGHT_UNKNOWN)), seed=2)
    state = estimator.init()
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
        again = estimator.estimate_state(pickle.loads(pickle.dumps(state)))
        estimate = estimator.estimate_state(state)
        assert again.message == estimate.message
        if estimate.success:
            np.testing.assert_array_equal(again.position_m, estimate.position_m)


# --------------------------------------------------------------------------------------------
# the covariance against the 3-D bound, the optimum against an independent solver
# --------------------------------------------------------------------------------------------


LONG_RUN = "a random climbing flight of 16 frames, every unknown"


@pytest.mark.parametrize("name", ["ekf", "smoother"])
@pytest.mark.parametrize("scenario", ["hill", "hill-climb", "roof-beacon", LONG_RUN])
def test_covariance_is_the_3d_crlb_on_noise_free_frames(name, scenario) -> None:
    """With a static emitter the reported 3×3 covariance after every frame of a noise-free run
    is the CRLB of the frames so far at the truth (MATH §8; the nuisance parameters, if
    unknown, eliminated: MATH §15), to ``1e-6`` relative: the updates are linearised at the
    emitter itself, and the diffuse prior's information is ``1e-6`` of the data's."""
    estimator = ESTIMATORS[name]
    if scenario == LONG_RUN:
        unknowns = (*BOTH, HEIGHT_UNKNOWN)
        data = noise_free(height_flight(6, climb_mps=1.0, n_frames=16, unknowns=unknowns))
    else:
        data = noise_free(get_scenario(scenario))
    truth = data.truth_emitter_m
    _, estimates = streamed(estimator, data)
    for n, estimate in enumerate(estimates, start=1):
        if not estimate.success:
            assert estimate.message == STRAIGHT_TRACK_HEIGHT
            continue
        bound = crlb_m2(fisher_information(data.up_to_frame(n - 1), truth))
        assert bound.shape == (3, 3)
        np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6, atol=0)


def maximum_likelihood(data, start_m) -> np.ndarray:
    """The batch maximum likelihood of ``(x, y, z)`` (and the unknown offsets) by scipy's
    ``least_squares`` on the whitened Doppler and range residuals of all frames, from
    ``start_m``: an independent solver of the same 3-D cost (MATH §10, §15)."""
    frame = FrameModel.from_measurements(data)
    k = data.n_samples
    offsets = [name for name in BOTH if name in data.unknowns]

    def residuals(theta: np.ndarray) -> np.ndarray:
        predicted = frame.predicted(theta[:3]).reshape(2, k)
        for j, name in enumerate(offsets):
            predicted[BOTH.index(name)] += theta[3 + j]
        return (predicted.ravel() - frame.measured) / frame.sigma

    residual = ((frame.measured - frame.predicted(start_m)) / frame.sigma).reshape(2, k)
    start = [
        residual[BOTH.index(name)].mean() * frame.sigma[BOTH.index(name) * k] for name in offsets
    ]
    solution = least_squares(
        residuals,
        np.r_[start_m, start],
        method="trf",
        x_scale="jac",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    assert solution.success
    return solution.x[:3]


@pytest.mark.parametrize("mode", ["batch", "streamed"])
@pytest.mark.parametrize("scenario", ["hill", "hill-climb", "roof-beacon"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_smoother_is_the_batch_maximum_likelihood_on_noisy_data(seed, scenario, mode) -> None:
    """On noisy data (0 dB) the smoother's answer is the optimum scipy's ``least_squares``
    reaches from the truth on the same 3-D cost: within ``1e-3`` standard deviations of the
    bound (the Mahalanobis distance in the Fisher information; scipy stops within
    ``Δχ² ~ 1e-8`` of the optimum in the flat valley of ``roof-beacon``, some ``1e-4`` m), and
    its profiled χ² is no higher than scipy's beyond ``1e-10`` relative. The EKF, which
    linearises each frame once, is within a quarter of a standard deviation of it (0.13 at
    most on these nine trials, on ``roof-beacon``)."""
    data = simulate(get_scenario(scenario), snr_db=0.0, seed=seed)
    truth = data.truth_emitter_m
    optimum = maximum_likelihood(data, truth)
    information = fisher_information(data, truth)

    def deviations(position_m) -> float:
        offset = np.asarray(position_m) - optimum
        return float(np.sqrt(offset @ information @ offset))

    smoother = ESTIMATORS["smoother"]
    estimate = smoother.estimate(data) if mode == "batch" else streamed(smoother, data)[1][-1]
    assert estimate.success, estimate.message
    assert deviations(estimate.position_m) < 1e-3
    best = chi2_at(data, optimum)
    assert chi2_at(data, estimate.position_m) <= best * (1.0 + 1e-10)
    ekf = streamed(ESTIMATORS["ekf"], data)[1][-1]
    assert ekf.success, ekf.message
    assert deviations(ekf.position_m) < 0.25


def test_hypotheses_above_the_uav_are_no_answer() -> None:
    """:func:`hypotheses_estimate` with 3-D means and the UAV's highest sample as ceiling: a
    hypothesis above it weighs nothing (MATH §7), whatever its weight, and with none below the
    estimate fails naming the rule; the EKF hypothesis's reflection through a level flight's
    plane keeps its weight and mirrors the height's rows of its matrices."""
    below, above = np.array([10.0, 20.0, 30.0]), np.array([12.0, 18.0, 170.0])
    covariance = np.diag([1.0, 2.0, 3.0])
    estimate = hypotheses_estimate(
        "test",
        [above, below],
        [covariance, covariance],
        [0.0, -5.0],
        [np.linalg.inv(covariance)] * 2,
        straight_track=False,
        length_scale_m=100.0,
        ceiling_m=100.0,
    )
    assert estimate.success
    np.testing.assert_array_equal(estimate.position_m, below)
    np.testing.assert_array_equal(estimate.candidates_m, [below])
    none = hypotheses_estimate(
        "test",
        [above],
        [covariance],
        [0.0],
        [np.linalg.inv(covariance)],
        straight_track=False,
        length_scale_m=100.0,
        ceiling_m=100.0,
    )
    assert not none.success and none.message == "no hypothesis below the UAV (MATH §7)"
    coupled = np.array([[2.0, 0.1, 0.3], [0.1, 1.0, -0.2], [0.3, -0.2, 4.0]])
    hypothesis = EkfHypothesis(
        mean_m=above.copy(), covariance_m2=coupled, log_weight=-1.5, data_information=coupled
    )
    reflected = hypothesis.reflected(100.0)
    np.testing.assert_array_equal(reflected.mean_m, [12.0, 18.0, 30.0])
    flip = np.diag([1.0, 1.0, -1.0])
    np.testing.assert_array_equal(reflected.covariance_m2, flip @ coupled @ flip)
    assert reflected.log_weight == -1.5


# --------------------------------------------------------------------------------------------
# the random-walk smoother in 3-D against scipy on the same cost
# --------------------------------------------------------------------------------------------


WALK_MPS = 0.5
"""The random walk's ``q`` of the conformance suite's random-walk smoother."""

CLIMB_HEIGHT = "climb-height"


def walk_scenario(name: str, unknowns) -> Scenario:
    """``climb-height`` of the conformance suite (two frames, a climb and a descent) or a
    climbing turn of :func:`height_flight` (``"turn-<seed>"``)."""
    if name == CLIMB_HEIGHT:
        return reference_problem(CLIMB_HEIGHT).scenario.replace(unknowns=unknowns)
    return height_flight(int(name.split("-")[1]), climb_mps=2.5, unknowns=unknowns)


def walk_maximum_likelihood(data, start_m, process_noise_mps: float) -> np.ndarray:
    """The optimum of the random-walk smoother's cost by scipy's ``least_squares``: one
    ``(x, y, z)`` per frame, each frame's whitened Doppler and range residuals at its own
    variable, the links ``(s_t − s_{t−1})/(q Δt_t)`` (``Δt`` between the frames' mean times),
    the unknown offsets (if any) shared by all frames; every variable started at ``start_m``.
    Returns the ``(n_frames, 3)`` positions."""
    frames = [FrameModel.from_measurements(frame) for frame in data.iter_frames()]
    n = len(frames)
    steps = process_noise_mps * np.diff([frame.time_s for frame in frames])
    offsets = [name for name in BOTH if name in data.unknowns]

    def residuals(theta: np.ndarray) -> np.ndarray:
        positions = theta[: 3 * n].reshape(n, 3)
        rows = []
        for frame, position in zip(frames, positions, strict=True):
            predicted = frame.predicted(position).reshape(2, -1)
            for j, name in enumerate(offsets):
                predicted[BOTH.index(name)] += theta[3 * n + j]
            rows.append((predicted.ravel() - frame.measured) / frame.sigma)
        rows.append((np.diff(positions, axis=0) / steps[:, None]).ravel())
        return np.concatenate(rows)

    whole = FrameModel.from_measurements(data)
    residual = (whole.measured - whole.predicted(start_m)).reshape(2, data.n_samples)
    start_offsets = [residual[BOTH.index(name)].mean() for name in offsets]
    solution = least_squares(
        residuals,
        np.r_[np.tile(start_m, n), start_offsets],
        method="trf",
        x_scale="jac",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    assert solution.success
    return solution.x[: 3 * n].reshape(n, 3)


@pytest.mark.parametrize("unknowns", [(HEIGHT_UNKNOWN,), (*BOTH, HEIGHT_UNKNOWN)], ids=["z", "all"])
@pytest.mark.parametrize("name", [CLIMB_HEIGHT, "turn-0", "turn-1", "turn-2"])
def test_random_walk_smoother_is_exact_at_high_snr(name, unknowns) -> None:
    """Noise-free data labelled with the σ's of 100 dB (the conformance suite's), the height
    unknown, the random-walk smoother (``q = 0.5`` m/s): batch and streamed, the last
    variable is scipy's optimum of the same cost (frames and links), which is the emitter, to
    ``1e-7`` of the mean range. Each frame alone leaves its variable on its own circle, held
    along it by the links alone (``1/(qΔt)² = 0.16`` against the data's ``10¹⁰`` m⁻² across
    it on ``climb-height``): with every variable started on the first frame's circle and
    Cholesky steps, every start ended at Levenberg-Marquardt's iteration cap."""
    smoother = GtsamSmoother(process_noise_mps=WALK_MPS)
    data = noise_free(walk_scenario(name, unknowns), snr_db=100.0)
    truth = data.truth_emitter_m
    scale = float(np.mean(model.slant_range_m(data.position_m, truth)))
    optimum = walk_maximum_likelihood(data, truth, WALK_MPS)
    np.testing.assert_allclose(optimum, np.tile(truth, (len(optimum), 1)), atol=1e-9 * scale)
    for estimate in (smoother.estimate(data), streamed(smoother, data)[1][-1]):
        assert estimate.success, estimate.message
        assert estimate.position_m.shape == (3,) and estimate.covariance_m2.shape == (3, 3)
        np.testing.assert_allclose(estimate.position_m, optimum[-1], rtol=0, atol=1e-7 * scale)


@pytest.mark.parametrize("snr_db", [40.0, 0.0])
@pytest.mark.parametrize("name", [CLIMB_HEIGHT, "turn-0", "turn-1"])
@pytest.mark.parametrize("seed", [0, 1])
def test_random_walk_smoother_is_the_walk_optimum_on_noisy_data(seed, name, snr_db) -> None:
    """On noisy data (40 and 0 dB) with the height unknown the random-walk smoother's last
    variable, batch and streamed, is scipy's optimum of the same cost reached from the truth:
    within ``1e-3`` standard deviations of the reported covariance (the Mahalanobis distance;
    ``2·10⁻⁵`` at most on these trials, scipy stopping short in the valley along the
    circles)."""
    smoother = GtsamSmoother(process_noise_mps=WALK_MPS)
    data = simulate(walk_scenario(name, (HEIGHT_UNKNOWN,)), snr_db=snr_db, seed=seed)
    optimum = walk_maximum_likelihood(data, data.truth_emitter_m, WALK_MPS)[-1]
    for estimate in (smoother.estimate(data), streamed(smoother, data)[1][-1]):
        assert estimate.success, estimate.message
        offset = estimate.position_m - optimum
        assert float(np.sqrt(offset @ np.linalg.solve(estimate.covariance_m2, offset))) < 1e-3
