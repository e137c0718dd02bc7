"""The signal model (MATH §18): the bursts carry the Doppler and ToA of the measurement model,
the noise has the power of the C/N0 given, trials are seeded one per trial, bad plans are
refused in one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.signal import (
    BurstPlan,
    burst_envelope,
    burst_model,
    burst_rms_bandwidth_hz,
    burst_shift_samples,
    burst_truth,
    chip_sequence,
    delay_bound_s2,
    frequency_bound_hz2,
    received_bursts,
    window_offsets_s,
)
from scenarios.simulate import noise_free, trial_seeds

# turn: two legs; beacon-pass: 406 MHz, 1 kHz carrier offset and 12.3 ms emission time unknown;
# roof-beacon: the same with a 3-D emitter (height unknown)
SCENARIOS = ("turn", "beacon-pass", "roof-beacon")

BPSK = BurstPlan(
    waveform="bpsk",
    burst_s=1e-3,
    sample_rate_hz=2e5,
    chip_rate_hz=5e4,
    cn0_dbhz=60.0,
    guard_s=1e-4,
)
CW = BurstPlan(waveform="cw", burst_s=2e-3, sample_rate_hz=1e5, cn0_dbhz=60.0)


@pytest.mark.parametrize("name", SCENARIOS)
@pytest.mark.parametrize("plan", [CW, BPSK], ids=["cw", "bpsk"])
def test_phase_slope_at_each_burst_centre_is_the_model_doppler(name: str, plan: BurstPlan) -> None:
    scenario = get_scenario(name)
    data = noise_free(scenario)
    bursts = received_bursts(scenario, plan, trial_seeds(3, 2), noise=False)
    # remove the known chips and the drawn carrier phase; the rest is exp(j φ(t))
    truth = burst_truth(scenario, plan)
    inside = np.abs(truth.envelope) > 0.5  # the guards hold rounding only
    tone = (
        bursts.samples * np.conj(truth.envelope) * np.exp(-1j * bursts.carrier_phase_rad)[..., None]
    )
    offsets = window_offsets_s(plan)[inside[0]]
    expected = model.doppler_hz(
        data.position_m,
        data.velocity_mps,
        data.truth_emitter_m,
        data.gamma_per_m,
        data.emitter_height_m,
        data.truth_carrier_offset_hz or 0.0,
    )
    for trial in tone:
        phase = np.unwrap(np.angle(trial[:, inside[0]]), axis=-1)
        # a quadratic over the symmetric window: its linear term is the slope at the centre
        slopes = np.polynomial.polynomial.polyfit(offsets, phase.T, 2)[1] / (2.0 * np.pi)
        np.testing.assert_allclose(slopes, expected, rtol=1e-6, atol=0.0)


@pytest.mark.parametrize("name", SCENARIOS)
def test_delay_within_a_burst_is_the_model_toa_along_the_straight_frame(name: str) -> None:
    scenario = get_scenario(name)
    data = noise_free(scenario)
    truth = burst_truth(scenario, BPSK)
    offsets = window_offsets_s(BPSK)
    moved = data.position_m[:, None, :] + offsets[None, :, None] * data.velocity_mps[:, None, :]
    toa = model.toa_s(
        moved,
        data.truth_emitter_m[..., None, :],
        data.speed_of_light_mps,
        data.emitter_height_m,
        data.truth_emission_time_s or 0.0,
    )
    np.testing.assert_allclose(truth.delay_s, toa, rtol=1e-12, atol=0.0)
    # the envelope is the burst emitted at e_k, delayed by τ_k: s(t − e_k − τ_k), the
    # sampled chips; D_k is zero to the rounding of t_k (1e-14 s, 1e-9 samples)
    since_emission = truth.time_s - truth.emission_time_s[:, None] - truth.toa_s[:, None]
    expected = burst_envelope(BPSK, since_emission)
    np.testing.assert_allclose(truth.envelope, expected, rtol=0.0, atol=1e-7)
    offsets = np.broadcast_to(window_offsets_s(BPSK), since_emission.shape)
    np.testing.assert_allclose(since_emission, offsets, rtol=0.0, atol=1e-12)
    centre = BPSK.n_samples // 2  # even window: t_k lies halfway between two samples
    at_centre = 0.5 * (truth.delay_s[:, centre - 1] + truth.delay_s[:, centre])
    exact = model.toa_s(
        data.position_m,
        data.truth_emitter_m,
        data.speed_of_light_mps,
        data.emitter_height_m,
        data.truth_emission_time_s or 0.0,
    )
    np.testing.assert_allclose(at_centre, exact, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("name", SCENARIOS)
def test_correlation_peak_gives_the_model_toa(name: str) -> None:
    scenario = get_scenario(name)
    data = noise_free(scenario)
    bursts = received_bursts(scenario, BPSK, trial_seeds(5, 1), noise=False)
    per_chip = round(BPSK.sample_rate_hz / BPSK.chip_rate_hz)
    replica = np.repeat(chip_sequence(BPSK), per_chip)
    # the correlator is tuned to each burst's Doppler (1 kHz on the beacon: a cycle a burst)
    doppler = burst_truth(scenario, BPSK).doppler_hz[:, None]
    samples = bursts.samples[0] * np.exp(-2j * np.pi * doppler * window_offsets_s(BPSK))
    n_lags = BPSK.n_samples - len(replica) + 1
    lags = np.lib.stride_tricks.sliding_window_view(samples, len(replica), axis=-1)
    power = np.abs(lags @ replica) ** 2  # (n_bursts, n_lags)
    peak = np.argmax(power, axis=-1)
    assert np.all((peak > 0) & (peak < n_lags - 1))
    rows = np.arange(len(peak))
    left, mid, right = power[rows, peak - 1], power[rows, peak], power[rows, peak + 1]
    fraction = 0.5 * (left - right) / (left - 2.0 * mid + right)
    # the replica's centre at lag L sits at sample L + (len(replica) − 1)/2
    start = bursts.time_s[:, 0]
    arrival = start + (peak + fraction + (len(replica) - 1) / 2.0) / BPSK.sample_rate_hz
    toa = arrival - bursts.emission_time_s
    exact = model.toa_s(
        data.position_m,
        data.truth_emitter_m,
        data.speed_of_light_mps,
        data.emitter_height_m,
        data.truth_emission_time_s or 0.0,
    )
    np.testing.assert_allclose(toa, exact, rtol=0.0, atol=0.01 / BPSK.sample_rate_hz)
    np.testing.assert_allclose(bursts.time_s.mean(axis=-1), data.time_s, rtol=0, atol=1e-12)


def test_noise_power_per_sample_is_n0_times_the_sample_rate() -> None:
    scenario = get_scenario("turn")
    plan = BurstPlan(
        waveform="bpsk",
        burst_s=1e-3,
        sample_rate_hz=1e5,
        chip_rate_hz=1e4,
        cn0_dbhz=37.0,
        received_power_w=2.5,
    )
    seeds = trial_seeds(11, 3)
    noisy = received_bursts(scenario, plan, seeds).samples
    clean = received_bursts(scenario, plan, seeds, noise=False).samples
    noise = (noisy - clean).ravel()  # 3 trials x 20 bursts x 100 samples
    n0 = 2.5 / 10.0**3.7
    expected = n0 * plan.sample_rate_hz
    assert plan.noise_density_w_per_hz == pytest.approx(n0, rel=1e-14)
    # 6000 complex samples: the power's relative standard error is 1/sqrt(6000) = 1.3%
    assert np.mean(np.abs(noise) ** 2) == pytest.approx(expected, rel=0.05)
    assert np.var(noise.real) == pytest.approx(expected / 2.0, rel=0.07)
    assert np.var(noise.imag) == pytest.approx(expected / 2.0, rel=0.07)
    assert abs(np.mean(noise)) < 5.0 * np.sqrt(expected / noise.size)
    # the clean part has the power C; the burst's SNR is C T / N0
    np.testing.assert_allclose(np.abs(clean) ** 2, 2.5, rtol=1e-7)
    assert plan.burst_snr == pytest.approx(2.5 * 1e-3 / n0, rel=1e-12)


def test_same_seed_same_bits_and_trials_do_not_depend_on_their_count() -> None:
    scenario = get_scenario("beacon-pass")
    five = received_bursts(scenario, BPSK, trial_seeds(7, 5), dtype=np.complex64)
    again = received_bursts(scenario, BPSK, trial_seeds(7, 5), dtype=np.complex64)
    two = received_bursts(scenario, BPSK, trial_seeds(7, 2), dtype=np.complex64)
    other = received_bursts(scenario, BPSK, trial_seeds(8, 2), dtype=np.complex64)
    assert five.samples.dtype == np.complex64
    assert five.samples.shape == (5, 40, BPSK.n_samples)
    np.testing.assert_array_equal(five.samples, again.samples)
    np.testing.assert_array_equal(five.samples[:2], two.samples)
    np.testing.assert_array_equal(five.carrier_phase_rad[:2], two.carrier_phase_rad)
    assert not np.any(five.samples[:2] == other.samples)
    # the trials differ from each other: phases and noise are each trial's own
    assert not np.any(five.carrier_phase_rad[0] == five.carrier_phase_rad[1])


def test_chips_are_a_seeded_pm1_sequence_and_a_tone_is_constant() -> None:
    chips = chip_sequence(BPSK)
    assert chips.shape == (50,)
    assert set(np.unique(chips)) == {-1.0, 1.0}
    np.testing.assert_array_equal(chips, chip_sequence(BPSK))
    reseeded = dataclasses.replace(BPSK, chip_seed=1)
    assert np.any(chip_sequence(reseeded) != chips)
    truth = burst_truth(get_scenario("turn"), CW)
    np.testing.assert_allclose(truth.envelope, 1.0, rtol=0.0, atol=1e-12)
    guarded = burst_truth(get_scenario("turn"), BPSK)
    guard = BPSK.n_guard_samples
    assert guard == 20
    np.testing.assert_allclose(guarded.envelope[:, :guard], 0.0, rtol=0.0, atol=1e-7)
    np.testing.assert_allclose(guarded.envelope[:, -guard:], 0.0, rtol=0.0, atol=1e-7)
    np.testing.assert_allclose(np.abs(guarded.envelope[:, guard:-guard]), 1.0, atol=1e-7)


def test_frequency_bound_is_the_inverse_fisher_information_of_a_tone_with_unknown_phase() -> None:
    # μ_n = a exp(j(θ + 2π f t_n)), noise CN(0, N0 fs): J = (2/σ²) Re Σ ∂μ*∂μ, θ profiled
    t = window_offsets_s(CW)
    sigma2 = CW.noise_density_w_per_hz * CW.sample_rate_hz
    d_frequency = 2.0 * np.pi * t
    j_ff = 2.0 * CW.received_power_w / sigma2 * np.sum(d_frequency**2)
    j_ft = 2.0 * CW.received_power_w / sigma2 * np.sum(d_frequency)
    j_tt = 2.0 * CW.received_power_w / sigma2 * len(t)
    assert 1.0 / frequency_bound_hz2(CW) == pytest.approx(j_ff - j_ft**2 / j_tt, rel=1e-10)
    n, burst_t = CW.n_burst_samples, CW.burst_s
    large_n = 6.0 / ((2.0 * np.pi) ** 2 * CW.burst_snr * burst_t**2)
    assert frequency_bound_hz2(CW) == pytest.approx(large_n * n * n / (n * n - 1.0), rel=1e-12)


def test_delay_bound_is_the_inverse_fisher_information_of_the_band_limited_burst() -> None:
    # over the whole window: the burst and its guards of silence, whose edges carry delay too
    burst = burst_truth(get_scenario("turn"), BPSK).envelope[0]
    frequency = np.fft.fftfreq(BPSK.n_samples, 1.0 / BPSK.sample_rate_hz)
    derivative = np.fft.ifft(2j * np.pi * frequency * np.fft.fft(burst))  # ds/dt, band-limited
    sigma2 = BPSK.noise_density_w_per_hz * BPSK.sample_rate_hz
    information = 2.0 * BPSK.received_power_w / sigma2 * np.sum(np.abs(derivative) ** 2)
    assert 1.0 / delay_bound_s2(BPSK) == pytest.approx(information, rel=1e-6)
    # a rectangular chip's bandwidth grows with the receiver's band; a tone's is zero
    assert 0.3 * BPSK.chip_rate_hz < burst_rms_bandwidth_hz(BPSK) < BPSK.sample_rate_hz / 2.0
    assert burst_rms_bandwidth_hz(CW) == 0.0


GOOD = {"waveform": "bpsk", "burst_s": 1e-3, "sample_rate_hz": 2e5, "chip_rate_hz": 5e4}


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"waveform": "qpsk"}, "waveform"),
        ({"burst_s": -1e-3}, "burst_s"),
        ({"burst_s": "long"}, "burst_s"),
        ({"sample_rate_hz": float("nan")}, "sample_rate_hz"),
        ({"burst_s": 1.00001e-3}, "burst_s"),
        ({"burst_s": 5e-6}, "burst_s"),
        ({"cn0_dbhz": float("inf")}, "cn0_dbhz"),
        ({"chip_rate_hz": None}, "chip_rate_hz"),
        ({"chip_rate_hz": 3e4}, "chip_rate_hz"),
        ({"chip_rate_hz": 4e5}, "chip_rate_hz"),
        ({"chip_rate_hz": 0.0}, "chip_rate_hz"),
        ({"chip_seed": 1.5}, "chip_seed"),
        ({"chip_seed": -1}, "chip_seed"),
        ({"received_power_w": 0.0}, "received_power_w"),
        ({"guard_s": -1e-4}, "guard_s"),
        ({"guard_s": 1.2e-5}, "guard_s"),
    ],
)
def test_bad_plans_are_refused_in_one_line_naming_the_field(change: dict, field: str) -> None:
    with pytest.raises(ValueError) as error:
        BurstPlan(**{"cn0_dbhz": 40.0, **GOOD, **change})
    message = str(error.value)
    assert message.startswith(f"{field}: ") and "\n" not in message


def test_bad_sources_and_a_too_slow_receiver_are_refused_in_one_line() -> None:
    scenario = get_scenario("beacon-pass")  # Doppler about 1 kHz with the carrier offset
    slow = BurstPlan(waveform="cw", burst_s=1e-2, sample_rate_hz=1e3, cn0_dbhz=40.0)
    for source, plan, field in (
        (scenario, slow, "sample_rate_hz"),
        (noise_free(scenario).without_truth(), CW, "truth_emitter_m"),
        ("beacon-pass", CW, "source"),
    ):
        with pytest.raises(ValueError) as error:
            received_bursts(source, plan, trial_seeds(0, 1))
        assert str(error.value).startswith(f"{field}: ") and "\n" not in str(error.value)
    with pytest.raises(ValueError, match=r"^seeds: "):
        received_bursts(scenario, CW, [])
    with pytest.raises(ValueError, match=r"^dtype: "):
        received_bursts(scenario, CW, [0], dtype=np.float64)


@pytest.mark.parametrize("name", SCENARIOS)
def test_the_model_at_hypotheses_is_the_model_one_hypothesis_at_a_time(name: str) -> None:
    scenario = get_scenario(name)
    data = noise_free(scenario)
    truth = burst_truth(scenario, BPSK)
    emitter = np.asarray(data.truth_emitter_m, dtype=float)
    rng = np.random.default_rng(4)
    hypotheses = emitter + rng.normal(0.0, 300.0, (2, 3, emitter.size))
    offsets = rng.normal(0.0, 50.0, (2, 3))
    many = burst_model(data, BPSK, hypotheses, truth.emission_time_s, carrier_offset_hz=offsets)
    assert many.shape == (2, 3, *truth.envelope.shape)
    for index in np.ndindex(2, 3):
        one = burst_model(
            data,
            BPSK,
            hypotheses[index],
            truth.emission_time_s,
            carrier_offset_hz=offsets[index],
        )
        np.testing.assert_allclose(many[index], one, rtol=0.0, atol=1e-12)
    # a hypothesis's shift is its extra delay in samples; at the truth the model is the burst
    shift = burst_shift_samples(data, BPSK, hypotheses, truth.emission_time_s)
    extra_m = model.slant_range_m(data.position_m, hypotheses, data.emitter_height_m)
    extra_m = extra_m - model.slant_range_m(data.position_m, emitter, data.emitter_height_m)
    b = data.truth_emission_time_s or 0.0
    expected = BPSK.sample_rate_hz * (extra_m / data.speed_of_light_mps - b)
    np.testing.assert_allclose(shift, expected, rtol=0.0, atol=1e-6)
    at_truth = burst_model(
        data,
        BPSK,
        emitter,
        truth.emission_time_s,
        carrier_offset_hz=data.truth_carrier_offset_hz or 0.0,
        emission_time_s=b,
    )
    np.testing.assert_allclose(
        at_truth, truth.envelope * np.exp(1j * truth.phase_rad), rtol=0.0, atol=1e-12
    )
