"""Direct position determination (docs/math.md §22): exact on noise-free bursts (both mirror
candidates on one straight frame), its answer a maximum of the exact likelihood, its errors at
the measurement-level CRLB far above threshold, a trial in a batch the trial alone, bad input
refused in one line.

The bursts are drawn by :func:`scenarios.signal.received_bursts` (the same
:func:`scenarios.signal.burst_model` the estimator evaluates). Tolerances:

- noise-free: the likelihood ``L`` is computed as sums of ``K N`` products, so it is known to
  about ``K N ε`` of itself; positions closer to the truth than the ``δ`` at which ``L`` falls
  by that much, ``½ δ² λ_min(−∇²L) = K N ε L``, cannot be told apart by ``L``. The estimate
  must be within ``δ`` (a fraction of a millimetre on ``turn``; errors observed ~1e-7 m).
- the CRLB: with ``M`` trials of an efficient estimator, ``eᵀ J e`` is χ² with 2 degrees of
  freedom, mean 2 and variance 4, so its mean over ``M`` trials over 2 has the standard
  deviation ``1/√M``; the test allows 4 of them. The seeds are fixed.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from estimators.dpd import DirectPosition, direct_position, profiled_log_likelihood, search_grid
from estimators.dpd.coarse import (
    TABLE_STEP,
    correlation_table,
    grid_log_likelihood,
    tabulated_log_likelihood,
)
from estimators.dpd.dpd import XTOL_FRACTION
from estimators.dpd.likelihood import profiled_log_likelihood_derivatives
from scenarios import get_scenario
from scenarios.fisher import fisher_information
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.signal import (
    BurstPlan,
    ReceivedBursts,
    delay_bound_s2,
    frequency_bound_hz2,
    received_bursts,
)
from scenarios.simulate import noise_free, trial_seeds
from scenarios.types import MeasurementSet, NoiseSigmas

EPS = float(np.finfo(float).eps)
RATE_HZ = 102400.0


def plan_at(cn0_dbhz: float, *, guard: int = 3, rate_hz: float = RATE_HZ) -> BurstPlan:
    """BPSK bursts of 10 ms at ``rate_hz``, 4 samples a chip, ``guard`` samples each side."""
    return BurstPlan(
        waveform="bpsk",
        burst_s=1e-2,
        sample_rate_hz=rate_hz,
        chip_rate_hz=rate_hz / 4,
        cn0_dbhz=cn0_dbhz,
        guard_s=guard / rate_hz,
    )


@cache
def geometry_of(name: str) -> MeasurementSet:
    return noise_free(get_scenario(name))


def bursts(name: str, plan: BurstPlan, n: int, seed: int, *, noise: bool) -> ReceivedBursts:
    seeds = np.random.SeedSequence(seed).spawn(n)
    return received_bursts(geometry_of(name), plan, seeds, noise=noise)


def hessian_at(name: str, plan: BurstPlan, samples: np.ndarray, schedule, point) -> np.ndarray:
    """``∇²L`` at ``point`` by central differences of 0.1 m (``L`` is quadratic to 1e-3 of
    itself over that on these geometries)."""
    h = 0.1
    offsets = h * np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [-1, -1]])
    c, xp, xm, yp, ym, pp, mm = profiled_log_likelihood(
        geometry_of(name), plan, samples, schedule, point + offsets
    )
    hxx, hyy = (xp - 2 * c + xm) / h**2, (yp - 2 * c + ym) / h**2
    hxy = (pp + mm - xp - xm - yp - ym + 2 * c) / (2 * h**2)
    return np.array([[hxx, hxy], [hxy, hyy]])


def rounding_radius_m(name: str, plan: BurstPlan, samples: np.ndarray, schedule) -> float:
    """``δ`` of the module text at the truth: where ``L`` falls by its own rounding."""
    truth = geometry_of(name).truth_emitter_m
    value = profiled_log_likelihood(geometry_of(name), plan, samples, schedule, truth[None])[0]
    curvature = np.min(np.linalg.eigvalsh(-hessian_at(name, plan, samples, schedule, truth)))
    terms = samples.shape[0] * samples.shape[1]
    return float(np.sqrt(2.0 * terms * EPS * value / curvature))


def test_noise_free_on_a_turn_is_the_truth() -> None:
    plan = plan_at(50.0)
    received = bursts("turn", plan, 2, 1, noise=False)
    found = direct_position(geometry_of("turn"), plan, received.samples, received.emission_time_s)
    truth = geometry_of("turn").truth_emitter_m
    assert found.success.all() and not found.ambiguous.any()
    for i in range(2):
        radius = rounding_radius_m("turn", plan, received.samples[i], received.emission_time_s)
        assert found.n_candidates[i] == 1
        assert np.linalg.norm(found.position_m[i] - truth) <= radius, (found.position_m, radius)


def test_noise_free_on_one_straight_frame_gives_both_mirror_candidates() -> None:
    plan = plan_at(50.0)
    geometry = geometry_of("paper")
    received = bursts("paper", plan, 1, 2, noise=False)
    found = direct_position(geometry, plan, received.samples, received.emission_time_s)
    line = straight_track_line(geometry.position_m, geometry.velocity_mps)
    assert line is not None and found.success[0] and found.ambiguous[0]
    assert found.n_candidates[0] == 2
    truth = geometry.truth_emitter_m
    expected = np.array([truth, mirror_across_line(truth, *line)])
    radius = rounding_radius_m("paper", plan, received.samples[0], received.emission_time_s)
    candidates = found.candidates_m[0, :2]
    distance = np.linalg.norm(candidates[:, None] - expected[None], axis=-1)
    assert np.min(distance, axis=1).max() <= radius, (candidates, radius)
    assert np.min(distance, axis=0).max() <= radius  # each of the pair is found


def test_the_tabulated_likelihood_is_the_exact_one_to_its_interpolation() -> None:
    """The coarse stage's first-order model (a tone at ``f_k(s)``, the burst at ``D_k(s)``),
    interpolated biquadratically at steps ``r`` = ``TABLE_STEP`` of the widths ``w`` of the
    peak: at most ``max|g‴| (rw)³/(9√3)`` with ``|g‴| ≤ 16/w³``, ``16 r³/(9√3)`` of the peak
    along each axis (``estimators.dpd.coarse.TABLE_STEP``)."""
    plan = plan_at(60.0)
    geometry = geometry_of("turn")
    received = bursts("turn", plan, 1, 3, noise=True)
    grid = search_grid(geometry, plan, received.emission_time_s)
    near = np.argsort(np.linalg.norm(grid.points_m - geometry.truth_emitter_m, axis=1))[:40]
    power = correlation_table(plan, received.samples, grid.axes)
    coarse = tabulated_log_likelihood(
        power, grid.axes, grid.doppler_hz[near][None], grid.shift_samples[near][None]
    )[0]
    assert np.allclose(grid_log_likelihood(power, grid)[0, near], coarse)  # the sparse lookup
    exact = profiled_log_likelihood(
        geometry, plan, received.samples[0], received.emission_time_s, grid.points_m[near]
    )
    bound = 2 * 16 * TABLE_STEP**3 / (9 * np.sqrt(3))
    assert np.max(np.abs(coarse - exact)) <= bound * np.max(exact)


def test_the_analytic_derivatives_are_the_likelihoods() -> None:
    """``profiled_log_likelihood_derivatives``: ``L`` the likelihood's own (the same
    expression), ``∇L`` the central differences of ``L`` and ``∇²L`` those of ``∇L`` at a step
    of 1 mm, a millionth of the peak's width on ``turn`` (their truncation, ``h²/6`` of the
    third derivative, is ~1e-7 of the values; their rounding ``ε L / h`` ~1e-7 of ``∇L``),
    with a delay slope (a guard) and noise, at points a few widths off the truth."""
    plan = plan_at(40.0)
    geometry = geometry_of("turn")
    received = bursts("turn", plan, 1, 6, noise=True)
    x, schedule = received.samples[0], received.emission_time_s
    points = geometry.truth_emitter_m + np.array([[3.0, -2.0], [-40.0, 25.0]])
    value, gradient, hessian = profiled_log_likelihood_derivatives(
        geometry, plan, x, schedule, points
    )
    np.testing.assert_allclose(
        value, profiled_log_likelihood(geometry, plan, x, schedule, points), rtol=1e-12
    )
    h = 1e-3
    for axis in range(2):
        step = h * np.eye(2)[axis]
        up = profiled_log_likelihood_derivatives(geometry, plan, x, schedule, points + step)
        down = profiled_log_likelihood_derivatives(geometry, plan, x, schedule, points - step)
        scale = np.abs(gradient).max(axis=1)
        difference = (up[0] - down[0]) / (2 * h)
        assert np.all(np.abs(difference - gradient[:, axis]) <= 1e-5 * scale)
        curvature = (up[1] - down[1]) / (2 * h)
        scale = np.abs(hessian).max(axis=(1, 2))[:, None]
        assert np.all(np.abs(curvature - hessian[:, :, axis]) <= 1e-5 * scale)


@cache
def noisy_estimate(cn0_dbhz: float, n: int, seed: int):
    plan = plan_at(cn0_dbhz, guard=0, rate_hz=RATE_HZ / 4)
    received = bursts("turn", plan, n, seed, noise=True)
    found = direct_position(geometry_of("turn"), plan, received.samples, received.emission_time_s)
    return plan, received, found


def test_the_refined_maximum_is_a_maximum() -> None:
    """``L`` at the answer is at least ``L`` on a 9 × 9 grid about it at a fortieth of the
    smallest standard deviation the estimate reports (``L`` falls there by ``σ̂²/3200`` of the
    noise power, far above its rounding ``K N ε L``)."""
    plan, received, found = noisy_estimate(40.0, 3, 4)
    geometry = geometry_of("turn")
    for i in range(3):
        position = found.position_m[i]
        sigma = np.sqrt(np.min(np.linalg.eigvalsh(found.covariance_m2[i])))
        offsets = np.arange(-4, 5) * sigma / 40
        local = position + np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)
        values = profiled_log_likelihood(
            geometry, plan, received.samples[i], received.emission_time_s, local
        )
        at = values[len(local) // 2]
        rounding = received.samples.shape[1] * received.samples.shape[2] * EPS * at
        assert at >= values.max() - rounding, (at, values.max())


def crlb_information(plan: BurstPlan) -> np.ndarray:
    """The measurement-level Fisher information at the truth (MATH §8) with the σ's of the
    plan's bounds (MATH §18)."""
    geometry = dataclasses.replace(
        geometry_of("turn"),
        rss_dbm=None,
        rss_model=None,
        noise=NoiseSigmas(
            doppler_hz=np.sqrt(frequency_bound_hz2(plan)), toa_s=np.sqrt(delay_bound_s2(plan))
        ),
    )
    return fisher_information(geometry, geometry.truth_emitter_m, "toa+doppler", unknowns=())


@pytest.mark.slow
def test_far_above_threshold_the_errors_attain_the_crlb() -> None:
    trials = 300
    plan, _, found = noisy_estimate(50.0, trials, 5)
    assert found.success.all()
    error = found.position_m - geometry_of("turn").truth_emitter_m
    information = crlb_information(plan)
    nees = np.einsum("ti,ij,tj->t", error, information, error)
    assert abs(np.mean(nees) / 2 - 1) <= 4 / np.sqrt(trials), np.mean(nees) / 2
    # the reported covariance is the errors' own too
    reported = np.einsum("ti,tij,tj->t", error, np.linalg.inv(found.covariance_m2), error)
    assert abs(np.mean(reported) / 2 - 1) <= 4 / np.sqrt(trials), np.mean(reported) / 2


def test_a_trial_in_a_batch_is_the_trial_alone() -> None:
    """The batch and each trial alone run the same steps on the same samples; the refinement
    stops at a step below ``XTOL_FRACTION`` of the grid's spacing, so the two may differ by
    rounding amplified up to that (the coarse grid, the starts and the candidates' count are
    the same)."""
    plan, received, batch = noisy_estimate(40.0, 3, 4)
    estimator = DirectPosition()
    tolerance = 10 * XTOL_FRACTION * float(batch.diagnostics["grid_spacing_m"][0])
    for i in range(3):
        alone = estimator.estimate_iq(
            geometry_of("turn"), plan, received.samples[i], received.emission_time_s
        )
        assert alone.success and len(alone.candidates_m) == batch.n_candidates[i]
        np.testing.assert_allclose(alone.position_m, batch.position_m[i], rtol=0, atol=tolerance)


def test_a_refinement_that_does_not_converge_is_a_failed_estimate() -> None:
    plan, received, _ = noisy_estimate(40.0, 3, 4)
    found = DirectPosition(max_iterations=1).estimate_iq_batch(
        geometry_of("turn"), plan, received.samples, received.emission_time_s
    )
    assert not found.success.any() and np.isnan(found.position_m).all()
    assert "converged from none" in found.message(0)


def test_bad_input_is_one_line_naming_the_field() -> None:
    plan = plan_at(50.0)
    received = bursts("turn", plan, 1, 1, noise=False)
    geometry, x, schedule = geometry_of("turn"), received.samples, received.emission_time_s
    unknown = noise_free(get_scenario("turn-noncooperative"))
    nan = x.copy()
    nan[0, 3, 7] = np.nan
    cases = [
        ((unknown, plan, x, schedule), "unknowns: .*position only"),
        ((geometry, plan, nan, schedule), "samples: NaN"),
        ((geometry, plan, x[:, :5], schedule), "samples: expected shape"),
        ((geometry, plan, x[..., :-1], schedule), "samples: .*plan.n_samples"),
        ((geometry, plan, x, schedule[:-1]), "schedule_s:"),
    ]
    for arguments, message in cases:
        with pytest.raises(ValueError, match=message) as raised:
            direct_position(*arguments)
        assert "\n" not in str(raised.value)
    with pytest.raises(ValueError, match="n_starts"):
        DirectPosition(n_starts=0)


def test_half_an_orbit_is_found_in_the_area_of_interest_and_the_radius_is_checked() -> None:
    """Half an orbit at a slow chip rate (a chip is 117 km): the window allows ±132 km, where
    a grid of 256 a side steps 1 km over the peak (it found the emitter 2 km off); the default
    area of interest, ten flight extents about the track's centre, holds the truth and a grid
    that resolves the Doppler's lobe (MATH §22)."""
    plan = BurstPlan(
        waveform="bpsk",
        burst_s=0.1,
        sample_rate_hz=10240.0,
        chip_rate_hz=2560.0,
        guard_s=4.0 / 10240.0,
        cn0_dbhz=40.0,
    )
    scenario = get_scenario("orbit", frames=6)
    received = received_bursts(scenario, plan, trial_seeds(3, 2))
    geometry = noise_free(scenario)
    found = direct_position(
        geometry.without_truth(), plan, received.samples, received.emission_time_s
    )
    assert found.success.all()
    assert found.diagnostics["grid_spacing_m"][0] < 20.0
    # at 40 dB-Hz the bound is about 0.3 m: within 5 of it
    assert np.all(np.linalg.norm(found.position_m - geometry.truth_emitter_m, axis=1) < 2.0)
    far = direct_position(
        geometry.without_truth(),
        plan,
        received.samples,
        received.emission_time_s,
        search_radius_m=2.0e5,
    )
    assert far.diagnostics["grid_spacing_m"][0] > 1000.0
    for bad in (0.0, -1.0, float("nan"), "wide"):
        with pytest.raises(ValueError, match="search_radius_m: expected a positive number"):
            DirectPosition(search_radius_m=bad)
