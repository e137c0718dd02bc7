"""From bursts to a measurement file (docs/math.md §20): noise-free the measured Doppler and ToA
are the geometry's, with noise the σ's written are the errors' own, below threshold the
outliers are counted and flagged, the set round-trips through an estimator, a burst in a batch
is the burst alone.

The bursts are the signal model's (:func:`scenarios.signal.received_bursts`) on ``beacon-pass``
(a Doppler of about 1 kHz: its carrier offset) and ``turn``. The plan: bursts of T = 0.1 ms at
2.56 MHz (256 samples, 64 chips of 4 samples, 16 samples of guard on each side), so that
``|f| T ≈ 0.1``.

Tolerance of the statistical test: the sample variance of ``M = 2000`` Gaussian errors has the
relative standard deviation ``√(2/M) = 3.2%``; 10% is 3.2 of them (as in test_frontend).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimators.frontend import (
    FALSE_ALARM_PROBABILITY,
    measure_bursts,
    measurement_batch,
    measurement_set,
    outlier_rate,
)
from estimators.frontend.measure import doppler_cells_hz
from estimators.registry import make_estimator
from scenarios import get_scenario
from scenarios.measurement_model import emitter_offsets_m
from scenarios.signal import BurstPlan, noise_at_cn0, received_bursts
from scenarios.simulate import noise_free, trial_seeds
from scenarios.types import NoiseSigmas

SAMPLE_RATE_HZ = 2.56e6
BURST_S = 1e-4
VARIANCE_RTOL = 0.10
"""3.2 standard deviations of a variance estimated from 2,000 draws (module docstring)."""
EPS = np.finfo(float).eps


def plan_of(waveform: str, cn0_dbhz: float = 70.0) -> BurstPlan:
    """SNR_burst = C/N0 · T: 30 dB at 70 dB-Hz."""
    return BurstPlan(
        waveform=waveform,
        burst_s=BURST_S,
        sample_rate_hz=SAMPLE_RATE_HZ,
        chip_rate_hz=6.4e5,
        cn0_dbhz=cn0_dbhz,
        guard_s=16 / SAMPLE_RATE_HZ,
    )


def measured_trials(
    name: str, plan: BurstPlan, seeds, *, noise: bool = True, doppler_search_hz=None
):
    geometry = noise_free(get_scenario(name))
    received = received_bursts(geometry, plan, seeds, noise=noise)
    measured = measure_bursts(
        received.samples,
        plan,
        time_s=geometry.time_s,
        emission_time_s=received.emission_time_s,
        doppler_search_hz=doppler_search_hz,
    )
    return geometry, measured


# --------------------------------------------------------------------------------------------
# noise-free: the geometry's Doppler and ToA
# --------------------------------------------------------------------------------------------


def assert_the_geometry_s(geometry, measured, plan: BurstPlan) -> None:
    """Doppler: the periodogram's peak is the slope of the phase's least-squares line over the
    burst, which the phase's cubic term ``f'' Δt³/6`` moves by ``f'' T²/40``; along a straight
    line ``|f''| = γ|ρ⃛| ≤ 3γ|v|³/ρ²``; plus rounding, ``4ε f_s``. ToA: ``t_k − e_k`` rounds
    ``e_k = t_k − τ_k`` (``ε |t_k|``) and the delay itself converges to rounding: ``4ε (|t_k| +
    |τ_k|)`` plus 10⁻⁹ sample."""
    rate_hz = plan.sample_rate_hz
    speed = np.max(np.linalg.norm(geometry.velocity_mps, axis=-1))
    nearest = np.min(
        np.linalg.norm(
            emitter_offsets_m(
                geometry.position_m, geometry.truth_emitter_m, geometry.emitter_height_m
            ),
            axis=-1,
        )
    )
    cubic_hz = 3 * geometry.gamma_per_m * speed**3 / nearest**2 * plan.burst_s**2 / 40
    doppler_error = np.abs(measured.doppler_hz[0] - geometry.doppler_hz)
    assert np.all(doppler_error <= cubic_hz + 4 * EPS * rate_hz), doppler_error.max()
    assert not measured.below_threshold.any()
    if plan.waveform == "cw":
        assert measured.toa_s is None and measured.toa_variance_s2 is None
        return
    toa_tolerance_s = 4 * EPS * (np.abs(geometry.time_s) + np.abs(geometry.toa_s))
    toa_error = np.abs(measured.toa_s[0] - geometry.toa_s)
    assert np.all(toa_error <= toa_tolerance_s + 1e-9 / rate_hz), toa_error.max()


def measured_with_search(received, plan, geometry, doppler_search_hz):
    """The front end on ``received``'s bursts, a Doppler search of ±``doppler_search_hz``."""
    return measure_bursts(
        received.samples,
        plan,
        time_s=geometry.time_s,
        emission_time_s=received.emission_time_s,
        doppler_search_hz=doppler_search_hz,
    )


@pytest.mark.parametrize("name", ["beacon-pass", "turn"])
@pytest.mark.parametrize("waveform", ["bpsk", "cw"])
def test_noise_free_the_measured_doppler_and_toa_are_the_geometry_s(name, waveform) -> None:
    """The tolerances of :func:`assert_the_geometry_s`."""
    plan = plan_of(waveform)
    geometry, measured = measured_trials(name, plan, [5], noise=False)
    assert_the_geometry_s(geometry, measured, plan)


def test_with_a_doppler_search_ten_cycles_a_burst_are_measured_noise_free() -> None:
    """beacon-pass with ``simulate-iq``'s default bursts (10 ms, 400 kHz, 100 kchip/s): its
    Doppler of up to 1,020 Hz turns ``f T = 10`` cycles over a burst. Searched over ±1.2 kHz
    the Doppler and the ToA are the geometry's within the noise-free tolerances (cubic term
    ``f'' T²/40`` = 8·10⁻⁶ Hz here); without the search the first pass correlates at zero
    Doppler, where the chips keep ``sinc²(10) = 0`` of the burst, and the ToA is lost."""
    plan = BurstPlan(
        waveform="bpsk", burst_s=1e-2, sample_rate_hz=4e5, chip_rate_hz=1e5, cn0_dbhz=70.0
    )
    geometry, measured = measured_trials(
        "beacon-pass", plan, [5], noise=False, doppler_search_hz=1200.0
    )
    assert_the_geometry_s(geometry, measured, plan)
    _, blind = measured_trials("beacon-pass", plan, [5], noise=False)
    assert np.median(np.abs(blind.toa_s[0] - geometry.toa_s)) > 1 / plan.chip_rate_hz


def test_a_noise_free_beacon_pass_recording_round_trips_through_cls() -> None:
    """The measured set gives ``cls`` the emitter, the carrier offset and the emission time:
    the measured ToA's rounding is ``c · 4ε · 19.5 s ≈ 5 µm`` of range, so 10 µm."""
    scenario = get_scenario("beacon-pass")
    geometry, measured = measured_trials("beacon-pass", plan_of("bpsk"), [5], noise=False)
    data = measurement_set(geometry, measured.trial(0))
    assert data.modalities == {"doppler", "toa"} and data.unknowns == geometry.unknowns
    estimate = make_estimator("cls").estimate(data)
    assert estimate.success and not estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [scenario.emitter_m], rtol=0, atol=1e-5)
    assert estimate.diagnostics["carrier_offset_hz"] == pytest.approx(
        scenario.carrier_offset_hz, abs=1e-6
    )
    assert estimate.diagnostics["emission_time_s"] == pytest.approx(
        scenario.emission_time_s, abs=1e-14
    )


@pytest.mark.parametrize("name", ["beacon-pass", "turn"])
@pytest.mark.parametrize("waveform", ["bpsk", "cw"])
def test_noise_free_the_frequency_sought_within_the_search_is_the_geometry_s(
    name, waveform
) -> None:
    """With ``doppler_search_hz`` ±1.2 kHz the frequency is sought within ±(1.2 kHz + 1/T),
    which holds beacon-pass's Doppler (up to 1,020 Hz) and turn's: the tolerances of
    :func:`assert_the_geometry_s`, none flagged."""
    plan = plan_of(waveform)
    geometry, measured = measured_trials(name, plan, [5], noise=False, doppler_search_hz=1200.0)
    assert_the_geometry_s(geometry, measured, plan)


@pytest.mark.parametrize(
    ("waveform", "whole_count", "band_count"), [("cw", 358, 4), ("bpsk", 242, 2)]
)
def test_near_threshold_the_doppler_search_s_band_has_fewer_frequency_outliers(
    waveform, whole_count, band_count
) -> None:
    """2,000 bursts (50 trials of beacon-pass) at 50 dB-Hz, SNR_burst 10 dB: over the whole band
    (no search) the Doppler of ``whole_count`` is more than a bin ``1/T`` off (a noise peak
    among the 256 bins of the burst), within ±1.2 kHz (plus the bin's margin: 2.2 cells)
    ``band_count``; counts of about 300 and 3 (standard deviations about 16 and 2) differ far
    beyond their sampling error: a ratio above 20 is asserted. Every Doppler measured is within
    ``±(D + 1/T)``."""
    plan = plan_of(waveform, cn0_dbhz=50.0)
    geometry = noise_free(get_scenario("beacon-pass"))
    received = received_bursts(geometry, plan, trial_seeds(2480, 50))
    counts = []
    for doppler_search_hz in (None, 1200.0):
        measured = measure_bursts(
            received.samples,
            plan,
            time_s=geometry.time_s,
            emission_time_s=received.emission_time_s,
            doppler_search_hz=doppler_search_hz,
        )
        counts.append(int(outlier_rate(measured, plan, geometry.doppler_hz)[0]))
    # the counts, not asserted to the burst: a burst whose two highest peaks tie to rounding may
    # go either way on another CPU's FFT
    message = f"outliers {counts[0]} over the whole band, {counts[1]} within it"
    assert counts[0] >= 0.8 * whole_count and counts[1] <= 5 * band_count + 5, message
    assert 20 * counts[1] < counts[0], message
    assert np.all(np.abs(measured.doppler_hz) <= (1200.0 + 1 / plan.burst_s) * (1 + 1e-12))


# --------------------------------------------------------------------------------------------
# with noise: the σ's written are the errors' own; below threshold, outliers flagged
# --------------------------------------------------------------------------------------------


def test_far_above_threshold_the_sigmas_written_are_the_errors_own() -> None:
    """2,000 bursts (50 trials of beacon-pass) at SNR_burst = 30 dB: the errors over the σ's
    of each trial's set, and over those of the batch (the bounds at the plan's C/N0), have
    variance 1 within 10%; each trial's σ² is the plan's bound within 10% (its own sampling
    error is about 1.5%: the SNR estimated from 40 bursts)."""
    plan = plan_of("bpsk")
    geometry, measured = measured_trials("beacon-pass", plan, trial_seeds(2420, 50))
    assert not measured.below_threshold.any()
    assert outlier_rate(measured, plan, geometry.doppler_hz, geometry.toa_s) == (0, 2000)
    bound = noise_at_cn0(plan)
    doppler, toa = [], []
    for index in range(50):
        data = measurement_set(geometry, measured.trial(index))
        assert data.noise.doppler_hz**2 / bound.doppler_hz**2 == pytest.approx(1.0, abs=0.1)
        assert data.noise.toa_s**2 / bound.toa_s**2 == pytest.approx(1.0, abs=0.1)
        doppler.append((data.doppler_hz - geometry.doppler_hz) / data.noise.doppler_hz)
        toa.append((data.toa_s - geometry.toa_s) / data.noise.toa_s)
    batch = measurement_batch(geometry, measured, bound)
    assert batch.n_trials == 50 and batch.geometry.noise == bound
    for normalised in (
        np.concatenate(doppler),
        np.concatenate(toa),
        (batch.doppler_hz - geometry.doppler_hz) / bound.doppler_hz,
        (batch.toa_s - geometry.toa_s) / bound.toa_s,
    ):
        assert np.mean(normalised**2) == pytest.approx(1.0, abs=VARIANCE_RTOL)
        assert abs(np.mean(normalised)) < 4 / np.sqrt(normalised.size)


def test_a_doppler_search_measures_five_cycles_a_burst_at_the_bounds() -> None:
    """1,000 bursts (25 trials of beacon-pass) of 5 ms at 100 kHz (25 kchip/s, 500 samples)
    and SNR_burst = 30 dB: the Doppler of up to 1,020 Hz turns ``f T ≈ 5`` cycles a burst.
    Searched over ±1,050 Hz (43 cells) no burst is flagged or an outlier, and the errors over
    the σ's written per burst, and over the bounds at the plan's C/N0, have variance 1 within
    10% (2.2 standard deviations of a variance from 1,000 draws, √(2/1000) = 4.5%). Without the
    search the first pass correlates at zero Doppler, where the chips keep ``sinc²(5) ≈ 0`` of
    the burst: at least 90% of the same bursts are outliers or flagged (997 outliers, none
    flagged: the final delay and frequency lock on the chips' sidelobes at full SNR)."""
    plan = BurstPlan(
        waveform="bpsk", burst_s=5e-3, sample_rate_hz=1e5, chip_rate_hz=2.5e4, cn0_dbhz=53.0
    )
    geometry = noise_free(get_scenario("beacon-pass"))
    received = received_bursts(geometry, plan, trial_seeds(2460, 25))

    def measured(doppler_search_hz):
        return measured_with_search(received, plan, geometry, doppler_search_hz)

    searched = measured(1050.0)
    assert not searched.below_threshold.any()
    assert outlier_rate(searched, plan, geometry.doppler_hz, geometry.toa_s) == (0, 1000)
    bound = noise_at_cn0(plan)
    doppler_error = searched.doppler_hz - geometry.doppler_hz
    toa_error = searched.toa_s - geometry.toa_s
    for normalised in (
        doppler_error / np.sqrt(searched.doppler_variance_hz2),
        toa_error / np.sqrt(searched.toa_variance_s2),
        doppler_error / bound.doppler_hz,
        toa_error / bound.toa_s,
    ):
        assert np.mean(normalised**2) == pytest.approx(1.0, abs=VARIANCE_RTOL)
        assert abs(np.mean(normalised)) < 4 / np.sqrt(normalised.size)
    blind = measured(None)
    count, total = outlier_rate(blind, plan, geometry.doppler_hz, geometry.toa_s)
    far = np.abs(blind.doppler_hz - geometry.doppler_hz) > 1 / plan.burst_s
    far |= np.abs(blind.toa_s - geometry.toa_s) > 1 / plan.chip_rate_hz
    assert count == far.sum() and (far | blind.below_threshold).sum() >= 0.9 * total, count


@pytest.mark.parametrize("search_hz", [0.0, 100.0, 1111.0, 1112.0, 25_000.0])
def test_the_doppler_cells_put_every_doppler_of_the_span_within_half_a_cell(search_hz) -> None:
    """The cells are ``f_s/(4N)`` apart (2,222 Hz for the 288-sample window), symmetric about
    0, and the fewest that leave no Doppler of ``[−D, D]`` more than half a cell from one
    (brute force on a fine grid of the span; one cell fewer on each side leaves the ends
    out). ``D ≤ f_s/(8N)`` (1,111 Hz) is the one cell 0."""
    plan = plan_of("bpsk")
    spacing_hz = SAMPLE_RATE_HZ / (4 * plan.n_samples)
    cells_hz = doppler_cells_hz(search_hz, plan)
    np.testing.assert_allclose(np.diff(cells_hz), spacing_hz, rtol=1e-12)
    np.testing.assert_array_equal(cells_hz, -cells_hz[::-1])
    span_hz = np.linspace(-search_hz, search_hz, 10_001)
    farthest_hz = np.max(np.min(np.abs(span_hz[:, None] - cells_hz), axis=-1))
    assert farthest_hz <= spacing_hz / 2 * (1 + 1e-12)
    assert (cells_hz.size == 1) == (search_hz <= spacing_hz / 2)
    if cells_hz.size > 1:
        assert search_hz - cells_hz[-2] > spacing_hz / 2  # one cell fewer would not do


def test_a_search_of_zero_is_no_search_and_its_flag_counts_the_cells() -> None:
    """Noise alone (C/N0 of 0 dB-Hz) in 1,000 windows: a search of 0 Hz is the pass without
    one, to the bit; with ±1.2 kHz (3 cells) every burst whose final delay's SNR is below
    ``ln(N M / p_fa)`` is flagged, among them some between ``ln(N / p_fa)`` and it (8 here:
    the frequency sought within the search's band, the final delay's SNR of noise alone
    exceeds ``ln(N / p_fa)`` in about 1% of the windows, none of the first 200)."""
    plan = plan_of("bpsk", cn0_dbhz=0.0)
    geometry = noise_free(get_scenario("beacon-pass"))
    received = received_bursts(geometry, plan, trial_seeds(2470, 25))

    def measured(doppler_search_hz):
        return measured_with_search(received, plan, geometry, doppler_search_hz)

    none, zero = measured(None), measured(0.0)
    for field in dataclasses.fields(none):
        assert np.array_equal(getattr(none, field.name), getattr(zero, field.name))
    searched = measured(1200.0)
    n, cells = plan.n_samples, doppler_cells_hz(1200.0, plan).size
    assert cells == 3
    low = searched.burst_snr < np.log(n * cells / FALSE_ALARM_PROBABILITY)
    assert searched.below_threshold[low].all()
    between = low & (searched.burst_snr >= np.log(n / FALSE_ALARM_PROBABILITY))
    assert between.sum() > 0


def test_below_threshold_the_outliers_are_counted_and_flagged() -> None:
    """At 40 dB-Hz (SNR_burst = 0 dB) most bursts land on a noise peak (a Doppler more than a
    bin ``1/T`` or a ToA more than a chip off): at least 90% of 200, at least 99% of them
    flagged (the counts in the message). A set is still written, but its σ's are not the
    errors' own: the SNR estimated at the largest noise peak is above the true one, so the σ is
    below the bound at the plan's C/N0, and the errors are far above it."""
    plan = plan_of("bpsk", cn0_dbhz=40.0)
    geometry, measured = measured_trials("beacon-pass", plan, trial_seeds(2430, 5))
    count, total = outlier_rate(measured, plan, geometry.doppler_hz, geometry.toa_s)
    far = np.abs(measured.doppler_hz - geometry.doppler_hz) > 1 / BURST_S
    far |= np.abs(measured.toa_s - geometry.toa_s) > 1 / plan.chip_rate_hz
    flagged = measured.below_threshold
    message = f"{count} outliers of {total}, {flagged[far].sum()} of them flagged"
    assert total == 200 and count == far.sum() >= 0.9 * total, message
    assert flagged[far].sum() >= 0.99 * count, message
    data = measurement_set(geometry, measured.trial(0))
    assert data.noise.doppler_hz < noise_at_cn0(plan).doppler_hz
    assert (
        np.sqrt(np.mean((data.doppler_hz - geometry.doppler_hz) ** 2)) > 10 * data.noise.doppler_hz
    )


def test_at_threshold_a_known_emission_time_refuses_toa_outliers_unless_dropped() -> None:
    """turn (emission time known) at 50 dB-Hz (SNR_burst 10 dB): a ToA outlier kilometres
    short of the UAV's height is refused by the set's own check, naming the entry; with
    ``drop_flagged`` the set holds the bursts not flagged."""
    plan = plan_of("bpsk", cn0_dbhz=50.0)
    geometry, measured = measured_trials("turn", plan, trial_seeds(2450, 1))
    one = measured.trial(0)
    with pytest.raises(ValueError, match=r"^toa_s\[1\]: the range"):
        measurement_set(geometry, one)
    kept = measurement_set(geometry, one, drop_flagged=True)
    assert kept.n_samples == (~one.below_threshold).sum() == 10
    np.testing.assert_array_equal(kept.toa_s, one.toa_s[~one.below_threshold])
    np.testing.assert_array_equal(kept.time_s, geometry.time_s[~one.below_threshold])


# --------------------------------------------------------------------------------------------
# every burst at once is one at a time; a flight in blocks is the flight at once
# --------------------------------------------------------------------------------------------


@pytest.mark.bits("the same functions on the same rows: a batch of bursts and each burst alone")
@pytest.mark.parametrize("doppler_search_hz", [None, 1200.0])
def test_a_burst_in_a_batch_is_the_burst_alone_and_blocks_are_the_whole(doppler_search_hz) -> None:
    """160 bursts near threshold (three blocks of ``BLOCK_BURSTS`` and more), each against
    itself alone; the flight measured in two blocks against the flight at once; without a
    Doppler search and with one (±1.2 kHz: three cells of 2.2 kHz at ``N`` = 288)."""
    plan = plan_of("bpsk", cn0_dbhz=52.0)
    geometry = noise_free(get_scenario("beacon-pass"))
    received = received_bursts(geometry, plan, trial_seeds(2440, 4))
    samples, time_s, emission_s = received.samples, geometry.time_s, received.emission_time_s
    search = {"doppler_search_hz": doppler_search_hz}
    whole = measure_bursts(samples, plan, time_s=time_s, emission_time_s=emission_s, **search)
    fields = [field.name for field in dataclasses.fields(whole)]
    for trial, burst in ((0, 0), (1, 23), (1, 24), (2, 39), (3, 17)):
        keep = slice(burst, burst + 1)
        alone = measure_bursts(
            samples[trial, keep],
            plan,
            time_s=time_s[keep],
            emission_time_s=emission_s[keep],
            **search,
        )
        for name in fields:
            assert np.array_equal(getattr(whole, name)[trial, burst], getattr(alone, name)[0])
    parts = [
        measure_bursts(
            samples[:, keep],
            plan,
            time_s=time_s[keep],
            emission_time_s=emission_s[keep],
            **search,
        )
        for keep in (slice(0, 13), slice(13, None))
    ]
    for name in fields:
        joined = np.concatenate([getattr(part, name) for part in parts], axis=-1)
        assert np.array_equal(joined, getattr(whole, name)), name


# --------------------------------------------------------------------------------------------
# bad input: one line naming the field
# --------------------------------------------------------------------------------------------


def bad_calls():
    plan = plan_of("bpsk")
    good = np.ones((3, plan.n_samples), dtype=complex)
    times = np.arange(3.0)
    nan = good.copy()
    nan[1, 5] = np.nan
    geometry = noise_free(get_scenario("turn"))
    three = measure_bursts(good, plan, time_s=times, emission_time_s=times)

    def searched(doppler_search_hz):
        return measure_bursts(
            good, plan, time_s=times, emission_time_s=times, doppler_search_hz=doppler_search_hz
        )

    return [
        (lambda: measure_bursts(good[:, 1:], plan, time_s=times, emission_time_s=times), "samples"),
        (lambda: measure_bursts(nan, plan, time_s=times, emission_time_s=times), "samples"),
        (lambda: measure_bursts(good[:0], plan, time_s=[], emission_time_s=[]), "samples"),
        (lambda: measure_bursts(good, plan, time_s=times[:2], emission_time_s=times), "time_s"),
        (
            lambda: measure_bursts(good, plan, time_s=times, emission_time_s=times[:, None]),
            "emission_time_s",
        ),
        (lambda: measure_bursts(good, "bpsk", time_s=times, emission_time_s=times), "plan"),
        (lambda: searched(-1.0), "doppler_search_hz"),
        (lambda: searched(float("nan")), "doppler_search_hz"),
        (lambda: searched("wide"), "doppler_search_hz"),
        (lambda: searched(2e6), "doppler_search_hz"),  # beyond f_s/2
        (lambda: measurement_set(geometry, three), "measured"),
        (lambda: measurement_batch(geometry, three, NoiseSigmas(doppler_hz=1.0)), "measured"),
        (
            lambda: measurement_set(
                noise_free(get_scenario("turn")).take(np.arange(20) < 3),
                dataclasses.replace(three, below_threshold=np.ones(3, dtype=bool)),
                drop_flagged=True,
            ),
            "measured.below_threshold",
        ),
    ]


@pytest.mark.parametrize("index", range(13))
def test_bad_input_is_one_line_naming_the_field(index: int) -> None:
    call, field = bad_calls()[index]
    with pytest.raises(ValueError) as raised:
        call()
    message = str(raised.value)
    assert message.startswith(f"{field}: ") and "\n" not in message, message
