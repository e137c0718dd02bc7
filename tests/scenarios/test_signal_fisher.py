"""The signal-level bound (MATH §21): the analytic Jacobian of the burst model against finite
differences, the information symmetric positive definite and scaling with C/N0, and the bound
equal to the measurement-level one (MATH §8, §15) at the σ's of the plan's bursts (MATH §18)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scenarios.catalog import get_scenario
from scenarios.fisher import inverse_symmetric
from scenarios.signal import (
    BurstPlan,
    burst_envelope,
    burst_model,
    burst_rms_bandwidth_hz,
    burst_truth,
    delay_bound_s2,
    frequency_bound_hz2,
    noise_at_cn0,
    rms_bandwidth_hz,
    window_offsets_s,
)
from scenarios.signal_fisher import (
    burst_model_jacobian,
    measurement_crlb_at_plan_m2,
    position_information,
    signal_crlb_at_plan_m2,
    signal_crlb_m2,
    signal_fisher_information,
)
from scenarios.simulate import noise_free

NUISANCES = ("carrier_offset_hz", "emission_time_s")

# no guards: the window is the burst, as the per-burst bounds of MATH §18 assume
BPSK = BurstPlan(waveform="bpsk", burst_s=1e-3, sample_rate_hz=2e5, chip_rate_hz=5e4, cn0_dbhz=50.0)
CW = BurstPlan(waveform="cw", burst_s=2e-3, sample_rate_hz=1e5, cn0_dbhz=50.0)
GUARDED = replace(BPSK, guard_s=1e-4)


def within_burst_change(name: str, plan: BurstPlan) -> float:
    """``(|v| T / ρ)²`` at its largest: the relative size of what the per-burst bounds leave
    out, the Doppler's change over a burst (its rate and its dependence on the position)."""
    data = noise_free(get_scenario(name))
    emitter = np.zeros(3)
    emitter[: len(data.truth_emitter_m)] = data.truth_emitter_m
    if len(data.truth_emitter_m) == 2:
        emitter[2] = data.emitter_height_m
    ranges = np.linalg.norm(data.position_m - emitter, axis=-1)
    speeds = np.linalg.norm(data.velocity_mps, axis=-1)
    return float(np.max(speeds * plan.burst_s / ranges) ** 2)


@pytest.mark.parametrize("name", ["turn", "beacon-pass", "roof-beacon"])
@pytest.mark.parametrize("plan", [CW, GUARDED], ids=["cw", "bpsk-guarded"])
def test_jacobian_is_the_central_difference_of_the_burst_model(name: str, plan: BurstPlan) -> None:
    data = noise_free(get_scenario(name))
    schedule = burst_truth(data, plan).emission_time_s
    # off the truth (a hypothesis), with an offset and an emission time, so every term is live
    emitter = np.asarray(data.truth_emitter_m) + 0.3
    offset_hz, emission_s = 1003.0, 0.0123 + 2e-6
    analytic = burst_model_jacobian(
        data,
        plan,
        emitter,
        schedule,
        carrier_offset_hz=offset_hz,
        emission_time_s=emission_s,
        unknowns=NUISANCES,
    )
    d = len(emitter)
    assert analytic.shape == (data.n_samples, plan.n_samples, d + 2)

    def model(point: np.ndarray) -> np.ndarray:
        return burst_model(
            data,
            plan,
            point[:d],
            schedule,
            carrier_offset_hz=point[d],
            emission_time_s=point[d + 1],
        )

    # each step 1e-4 of the scale over which the model bends: the nearest range for the
    # position, 1/T for the offset (a cycle over the burst), a sample for the emission time
    nearest_m = float(np.min(np.linalg.norm(data.position_m[:, :2] - emitter[:2], axis=-1)))
    scales = [nearest_m] * d + [1.0 / plan.burst_s, 1.0 / plan.sample_rate_hz]
    point = np.concatenate([emitter, [offset_hz, emission_s]])
    for column, scale in enumerate(scales):
        step = np.zeros_like(point)
        step[column] = 1e-4 * scale
        central = (model(point + step) - model(point - step)) / (2.0 * step[column])
        wider = (model(point + 2 * step) - model(point - 2 * step)) / (4.0 * step[column])
        size = np.max(np.abs(analytic[..., column]))
        if size == 0.0:  # a tone without guards has no envelope slope: b does not enter
            assert column == d + 1 and plan.waveform == "cw"
            assert np.max(np.abs(central)) < 1e-6
            continue
        # the central difference's own error (truncation ∝ h², 3 times its error at h, and
        # rounding in the delay D_k) is measured by the two steps' difference
        error = np.max(np.abs(central - analytic[..., column]))
        spread = np.max(np.abs(central - wider))
        assert error <= 4.0 * spread + 1e-12 * size, (column, error, spread, size)
        assert error <= 1e-5 * size, (column, error, size)


def test_jacobian_is_vectorised_over_hypotheses() -> None:
    data = noise_free(get_scenario("beacon-pass"))
    schedule = burst_truth(data, BPSK).emission_time_s
    hypotheses = np.asarray(data.truth_emitter_m) + np.array([[0.0, 0.0], [5.0, -3.0], [-40, 7]])
    batch = burst_model_jacobian(data, BPSK, hypotheses, schedule, unknowns=NUISANCES)
    assert batch.shape == (3, data.n_samples, BPSK.n_samples, 4)
    for index, hypothesis in enumerate(hypotheses):
        alone = burst_model_jacobian(data, BPSK, hypothesis, schedule, unknowns=NUISANCES)
        np.testing.assert_allclose(
            batch[index], alone, rtol=1e-12, atol=1e-12 * np.abs(alone).max()
        )


@pytest.mark.parametrize("name", ["turn", "beacon-pass", "roof-beacon"])
@pytest.mark.parametrize("plan", [CW, BPSK, GUARDED], ids=["cw", "bpsk", "bpsk-guarded"])
def test_information_is_symmetric_positive_definite(name: str, plan: BurstPlan) -> None:
    data = noise_free(get_scenario(name))
    schedule = burst_truth(data, plan).emission_time_s
    unknowns = ("carrier_offset_hz",) if plan is CW else NUISANCES
    information = signal_fisher_information(data, plan, schedule, unknowns=unknowns)
    p = len(data.truth_emitter_m) + len(unknowns)
    assert information.shape == (p, p)
    np.testing.assert_array_equal(information, information.T)
    scale = 1.0 / np.sqrt(np.diagonal(information))
    correlation = information * scale[:, None] * scale[None, :]
    assert np.min(np.linalg.eigvalsh(correlation)) > 1e-9
    np.linalg.cholesky(correlation)  # raises unless positive definite


def test_a_tone_without_guards_carries_no_emission_time() -> None:
    data = noise_free(get_scenario("beacon-pass"))
    schedule = burst_truth(data, CW).emission_time_s
    information = signal_fisher_information(data, CW, schedule, unknowns=NUISANCES)
    np.testing.assert_array_equal(information[-1], 0.0)
    np.testing.assert_array_equal(information[:, -1], 0.0)
    both = signal_crlb_m2(data, CW, schedule, unknowns=NUISANCES)
    offset_only = signal_crlb_m2(data, CW, schedule, unknowns=("carrier_offset_hz",))
    np.testing.assert_array_equal(both, offset_only)


def test_bound_scales_as_ten_to_minus_cn0_over_ten() -> None:
    data = noise_free(get_scenario("turn"))
    schedule = burst_truth(data, BPSK).emission_time_s
    bound = signal_crlb_m2(data, BPSK, schedule, unknowns=NUISANCES)
    for step_db in (-7.0, 10.0, 23.0):
        louder = replace(BPSK, cn0_dbhz=BPSK.cn0_dbhz + step_db)
        expected = bound * 10.0 ** (-step_db / 10.0)
        np.testing.assert_allclose(
            signal_crlb_m2(data, louder, schedule, unknowns=NUISANCES), expected, rtol=1e-12
        )


@pytest.mark.parametrize("name", ["turn", "beacon-pass", "roof-beacon"])
@pytest.mark.parametrize("plan", [CW, BPSK], ids=["cw", "bpsk"])
@pytest.mark.parametrize("unknown", [False, True], ids=["cooperative", "unknowns"])
def test_signal_bound_is_the_measurement_bound_at_the_plans_sigmas(
    name: str, plan: BurstPlan, unknown: bool
) -> None:
    scenario = get_scenario(name)
    data = noise_free(scenario)
    # cooperative: δ and b known; else both unknown (the height, when unknown, stays a
    # coordinate of the position)
    height = tuple(u for u in data.unknowns if u not in NUISANCES)
    unknowns = (*NUISANCES, *height) if unknown else height
    signal = signal_crlb_at_plan_m2(scenario, plan, unknowns=unknowns)
    measured = measurement_crlb_at_plan_m2(scenario, plan, unknowns=unknowns)
    d = len(data.truth_emitter_m)
    assert signal.shape == measured.shape == (d, d)
    # per burst the frequency and delay are sufficient locally and decouple (MATH §21); the
    # Rife-Boorstyn bound is exact in N, so what differs is the Doppler's change within a
    # burst, information of relative size (|v| T / ρ)² (about 1e-7 here) of the cooperative
    # information; with δ and b unknown the bound grows by the price of the unknowns (its
    # square in variance) and that information, which δ does not touch (a rate), weighs as
    # much more: the tolerance is ε times the variance's price
    cooperative = measurement_crlb_at_plan_m2(scenario, plan, unknowns=height)
    price = np.trace(measured) / np.trace(cooperative)
    tolerance = within_burst_change(name, plan) * max(1.0, price) + 1e-10
    assert np.trace(signal) / np.trace(measured) == pytest.approx(1.0, rel=tolerance, abs=0.0)
    np.testing.assert_allclose(signal, measured, rtol=tolerance, atol=tolerance * np.trace(signal))


@pytest.mark.parametrize("name", ["turn", "beacon-pass"])
def test_guards_add_the_bursts_edges_to_the_delay_information(name: str) -> None:
    """With guards the window holds the burst's start and end against silence: the plan's
    delay bound is that of the window's RMS bandwidth, larger than the burst's own samples'
    (MATH §18), and the two bounds agree as without guards (MATH §21)."""
    scenario = get_scenario(name)
    data = noise_free(scenario)
    signal = signal_crlb_at_plan_m2(scenario, GUARDED, unknowns=data.unknowns)
    plan_bound = measurement_crlb_at_plan_m2(scenario, GUARDED, unknowns=data.unknowns)
    tolerance = within_burst_change(name, GUARDED) + 1e-10
    np.testing.assert_allclose(
        signal, plan_bound, rtol=tolerance, atol=tolerance * np.trace(signal)
    )
    n_guard, n_burst = GUARDED.n_guard_samples, GUARDED.n_burst_samples
    own = window_offsets_s(GUARDED)[n_guard : n_guard + n_burst]
    alone = rms_bandwidth_hz(burst_envelope(GUARDED, own), GUARDED.sample_rate_hz)
    assert burst_rms_bandwidth_hz(GUARDED) > 1.01 * alone


def test_position_information_is_the_inverse_of_the_position_block() -> None:
    rng = np.random.default_rng(22)
    rows = rng.standard_normal((9, 5)) * np.array([1.0, 2.0, 3.0, 1e3, 1e-6])
    information = rows.T @ rows
    expected = np.linalg.inv(information)[:3, :3]
    np.testing.assert_allclose(
        np.linalg.inv(position_information(information, 3)), expected, rtol=1e-10
    )
    # a coordinate the samples do not see, or nuisances they cannot tell apart: NaN
    blind = information.copy()
    blind[0, :] = blind[:, 0] = 0.0
    assert np.all(np.isnan(inverse_symmetric(position_information(blind, 3))))
    twins = information.copy()
    twins[4, :], twins[:, 4] = twins[3, :], twins[:, 3]
    twins[4, 4] = twins[3, 3]
    assert np.all(np.isnan(inverse_symmetric(position_information(twins, 3))))


def test_noise_at_cn0_is_the_bursts_bounds() -> None:
    noise = noise_at_cn0(BPSK)
    assert noise.doppler_hz == pytest.approx(np.sqrt(frequency_bound_hz2(BPSK)), rel=1e-15)
    assert noise.toa_s == pytest.approx(np.sqrt(delay_bound_s2(BPSK)), rel=1e-15)
    assert noise_at_cn0(CW).toa_s is None


def test_bad_input_is_one_line_naming_the_field() -> None:
    data = noise_free(get_scenario("turn"))
    schedule = burst_truth(data, BPSK).emission_time_s
    with pytest.raises(ValueError, match=r"^truth_emitter_m: "):
        signal_fisher_information(replace(data, truth_emitter_m=None), BPSK, schedule)
    with pytest.raises(ValueError, match=r"^source: "):
        signal_crlb_at_plan_m2("turn", BPSK)  # type: ignore[arg-type]
