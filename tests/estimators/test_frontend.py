"""The per-burst front end (docs/math.md §19): exact on noise-free bursts, its variances equal to
its bounds far above threshold, its outliers flagged below, every burst at once as one at a time.

The bursts are made here with a few lines of numpy: a tone ``b e^{j(2π f n/fs + φ)}``, and a
reference delayed by a fraction of a sample in the frequency domain
(``ifft(S_k e^{-j2π f_k τ})``), each times a random carrier phase, plus complex white noise.
The per-burst SNR is the signal's energy over the noise variance per sample, ``Σ|s_n|²/σ²``.

Tolerance of the statistical tests: the sample variance of ``M = 2000`` Gaussian errors has the
relative standard deviation ``√(2/M) = 3.2%`` (χ² with ``M`` degrees of freedom), ±6.2% at 95%;
10% is 3.2 of its standard deviations (a two-sided false failure about once in 600 seeds).
The seeds are fixed, so each run draws the same bursts.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.frontend import (
    below_threshold,
    burst_delay,
    delay_crb_s2,
    rife_boorstyn_variance_hz2,
    rms_bandwidth_hz,
    tone_frequency,
)

N = 1024
SAMPLE_RATE_HZ = 2.0e6
BURSTS = 2000
VARIANCE_RTOL = 0.10
"""3.2 standard deviations of a variance estimated from 2,000 draws (module docstring)."""
CHIPS, SAMPLES_PER_CHIP = 128, 4


def tone(frequency_hz: np.ndarray, phase_rad: np.ndarray) -> np.ndarray:
    n = np.arange(N)
    return np.exp(
        1j * (2 * np.pi * np.outer(frequency_hz, n) / SAMPLE_RATE_HZ + phase_rad[:, None])
    )


def delayed(reference: np.ndarray, delay_samples: np.ndarray, phase_rad: np.ndarray) -> np.ndarray:
    shift = np.exp(-2j * np.pi * np.outer(delay_samples, np.fft.fftfreq(N)))
    return np.fft.ifft(np.fft.fft(reference, N) * shift, axis=-1) * np.exp(1j * phase_rad)[:, None]


def noisy(signal: np.ndarray, energy: float, snr_db: float, rng: np.random.Generator):
    """``signal`` plus complex white noise of variance ``energy / SNR`` per sample."""
    sigma = np.sqrt(energy / 10 ** (snr_db / 10) / 2)
    return signal + sigma * (
        rng.standard_normal(signal.shape) + 1j * rng.standard_normal(signal.shape)
    )


def bpsk(rng: np.random.Generator) -> np.ndarray:
    return np.repeat(rng.choice([-1.0, 1.0], CHIPS), SAMPLES_PER_CHIP)


# --------------------------------------------------------------------------------------------
# noise-free: exact
# --------------------------------------------------------------------------------------------


def test_a_noise_free_tone_on_or_between_bins_is_exact() -> None:
    bin_hz = SAMPLE_RATE_HZ / N
    frequency_hz = np.array(
        [0.0, 3 * bin_hz, 3.37 * bin_hz, -100.5 * bin_hz, 0.4999 * SAMPLE_RATE_HZ]
    )
    found = tone_frequency(tone(frequency_hz, np.linspace(0, 6, 5)), SAMPLE_RATE_HZ)
    assert np.all(np.abs(found.frequency_hz - frequency_hz) < 1e-9 * SAMPLE_RATE_HZ)
    assert not found.below_threshold.any()


def test_a_noise_free_fractional_delay_is_exact_for_real_and_complex_references() -> None:
    rng = np.random.default_rng(24)
    delay_samples = np.array([0.0, 13.5, 200.37, 480.999])
    qpsk = np.repeat(np.exp(1j * np.pi / 2 * rng.integers(0, 4, CHIPS)), SAMPLES_PER_CHIP)
    for reference in (bpsk(rng), qpsk):
        windows = delayed(reference, delay_samples, rng.uniform(0, 2 * np.pi, 4))
        found = burst_delay(windows, reference, SAMPLE_RATE_HZ)
        error_samples = found.delay_s * SAMPLE_RATE_HZ - delay_samples
        assert np.all(np.abs(error_samples) < 1e-6)
        assert not found.below_threshold.any()


# --------------------------------------------------------------------------------------------
# the bounds, against the Fisher information of the sampled model
# --------------------------------------------------------------------------------------------


def fisher_bound(mean: np.ndarray, derivative: np.ndarray, sigma2: float) -> float:
    """The bound of the first parameter of ``mean(θ, b)`` in complex white noise of variance
    ``sigma2``, the complex amplitude ``b`` (real and imaginary part) a nuisance:
    ``J = (2/σ²) Re(DᴴD)`` with ``D = [∂μ/∂θ, μ, jμ]`` at ``b = 1``."""
    columns = np.stack([derivative, mean, 1j * mean], axis=1)
    information = 2.0 / sigma2 * (columns.conj().T @ columns).real
    return float(np.linalg.inv(information)[0, 0])


def test_the_rife_boorstyn_bound_is_the_inverse_fisher_information() -> None:
    n, sigma2 = np.arange(N), 3.0
    omega = 0.3
    mean = np.exp(1j * omega * n)
    bound_rad2 = fisher_bound(mean, 1j * n * mean, sigma2)
    bound_hz2 = bound_rad2 * (SAMPLE_RATE_HZ / (2 * np.pi)) ** 2
    assert rife_boorstyn_variance_hz2(N / sigma2, N, SAMPLE_RATE_HZ) == pytest.approx(
        bound_hz2, rel=1e-9
    )


def test_the_delay_bound_is_the_inverse_fisher_information_off_centre_spectrum_too() -> None:
    rng = np.random.default_rng(7)
    sigma2, tau = 2.0, 100.25
    for reference in (bpsk(rng), bpsk(rng) * np.exp(0.4j * np.arange(CHIPS * SAMPLES_PER_CHIP))):
        spectrum = np.fft.fft(reference, N) * np.exp(-2j * np.pi * np.fft.fftfreq(N) * tau)
        mean = np.fft.ifft(spectrum)
        derivative = np.fft.ifft(-2j * np.pi * np.fft.fftfreq(N) * spectrum)
        bound_s2 = fisher_bound(mean, derivative, sigma2) / SAMPLE_RATE_HZ**2
        snr = np.sum(np.abs(reference) ** 2) / sigma2
        bandwidth_hz = rms_bandwidth_hz(reference, SAMPLE_RATE_HZ, N)
        assert delay_crb_s2(snr, bandwidth_hz) == pytest.approx(bound_s2, rel=1e-9)


# --------------------------------------------------------------------------------------------
# far above threshold: the bounds; below: outliers, flagged
# --------------------------------------------------------------------------------------------


def tone_bursts(snr_db: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    frequency_hz = rng.uniform(-0.4, 0.4, BURSTS) * SAMPLE_RATE_HZ
    signal = tone(frequency_hz, rng.uniform(0, 2 * np.pi, BURSTS))
    return noisy(signal, float(N), snr_db, rng), frequency_hz


def delay_windows(snr_db: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    reference = bpsk(rng)
    delay_samples = rng.uniform(100.0, 400.0, BURSTS)
    signal = delayed(reference, delay_samples, rng.uniform(0, 2 * np.pi, BURSTS))
    windows = noisy(signal, float(np.sum(reference**2)), snr_db, rng)
    return windows, reference, delay_samples / SAMPLE_RATE_HZ


def assert_attains(error: np.ndarray, bound: float, reported: np.ndarray) -> None:
    """Mean squared error within :data:`VARIANCE_RTOL` of the bound, the errors over the
    reported σ of mean square 1 within the same, the mean within 4 standard errors of 0."""
    assert np.mean(error**2) / bound == pytest.approx(1.0, abs=VARIANCE_RTOL)
    assert np.mean(error**2 / reported) == pytest.approx(1.0, abs=VARIANCE_RTOL)
    assert abs(np.mean(error)) < 4 * np.sqrt(bound / error.size)


def test_far_above_threshold_the_frequency_variance_is_the_rife_boorstyn_bound() -> None:
    samples, frequency_hz = tone_bursts(snr_db=30.0, seed=2401)
    found = tone_frequency(samples, SAMPLE_RATE_HZ)
    bound_hz2 = rife_boorstyn_variance_hz2(10**3.0, N, SAMPLE_RATE_HZ)
    assert_attains(found.frequency_hz - frequency_hz, bound_hz2, found.variance_hz2)
    assert not found.below_threshold.any()


def test_far_above_threshold_the_delay_variance_is_the_delay_bound() -> None:
    windows, reference, delay_s = delay_windows(snr_db=30.0, seed=2402)
    found = burst_delay(windows, reference, SAMPLE_RATE_HZ)
    bound_s2 = delay_crb_s2(10**3.0, rms_bandwidth_hz(reference, SAMPLE_RATE_HZ, N))
    assert_attains(found.delay_s - delay_s, bound_s2, found.variance_s2)
    assert not found.below_threshold.any()


def test_below_threshold_the_outliers_are_many_and_flagged() -> None:
    """At −5 dB per burst most estimates land on a noise peak (more than a bin or a chip off);
    the flag marks them (counts in the messages)."""
    samples, frequency_hz = tone_bursts(snr_db=-5.0, seed=2403)
    tone_found = tone_frequency(samples, SAMPLE_RATE_HZ)
    tone_outlier = np.abs(tone_found.frequency_hz - frequency_hz) > SAMPLE_RATE_HZ / N
    windows, reference, delay_s = delay_windows(snr_db=-5.0, seed=2404)
    delay_found = burst_delay(windows, reference, SAMPLE_RATE_HZ)
    delay_outlier = np.abs(delay_found.delay_s - delay_s) * SAMPLE_RATE_HZ > SAMPLES_PER_CHIP
    for outlier, flagged in (
        (tone_outlier, tone_found.below_threshold),
        (delay_outlier, delay_found.below_threshold),
    ):
        message = f"{outlier.sum()} outliers, {flagged[outlier].sum()} flagged, of {BURSTS}"
        assert outlier.sum() >= 0.9 * BURSTS, message
        assert flagged[outlier].sum() >= 0.99 * outlier.sum(), message


def test_the_flag_is_the_false_alarm_threshold_of_noise_alone() -> None:
    """Under noise alone the statistic at one cell is exponential with mean 1: the threshold
    ``ln(N / p_fa)`` passes ``p_fa`` of the cells' maximum over ``N`` of them."""
    assert below_threshold(np.log(N / 1e-3) * 0.999, N)
    assert not below_threshold(np.log(N / 1e-3) * 1.001, N)


# --------------------------------------------------------------------------------------------
# every burst at once is one at a time
# --------------------------------------------------------------------------------------------


@pytest.mark.bits("the same functions on the same rows: a batch of bursts and each row alone")
def test_every_burst_at_once_is_one_at_a_time() -> None:
    """150 bursts (three blocks of ``BLOCK_BURSTS``), each row against itself alone."""
    samples, _ = tone_bursts(snr_db=10.0, seed=2405)
    windows, reference, _ = delay_windows(snr_db=10.0, seed=2406)
    tones = tone_frequency(samples[:150], SAMPLE_RATE_HZ)
    delays = burst_delay(windows[:150], reference, SAMPLE_RATE_HZ)
    for i in (0, 63, 64, 100, 149):
        one_tone = tone_frequency(samples[i], SAMPLE_RATE_HZ)
        one_delay = burst_delay(windows[i], reference, SAMPLE_RATE_HZ)
        for batch, one in ((tones, one_tone), (delays, one_delay)):
            for field in batch.__dataclass_fields__:
                assert np.array_equal(getattr(batch, field)[i], getattr(one, field)), field
    grid = tone_frequency(samples[:6].reshape(2, 3, N), SAMPLE_RATE_HZ)
    assert grid.frequency_hz.shape == (2, 3)
    assert np.array_equal(grid.frequency_hz.ravel(), tones.frequency_hz[:6])


# --------------------------------------------------------------------------------------------
# a band: the tone sought within ±D only (docs/math.md §19)
# --------------------------------------------------------------------------------------------

BIN_HZ = SAMPLE_RATE_HZ / N
BAND_HZ = 2 * BIN_HZ
"""A band of ±2 bins: with its margin of a bin, ``|f| ≤ 3`` bins, 6 cells."""


def band_tones(snr_db: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """:data:`BURSTS` tones uniform within ``±BAND_HZ``, random phases, complex white noise."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    frequency_hz = rng.uniform(-BAND_HZ, BAND_HZ, BURSTS)
    signal = tone(frequency_hz, rng.uniform(0, 2 * np.pi, BURSTS))
    return noisy(signal, float(N), snr_db, rng), frequency_hz


def test_a_noise_free_tone_within_the_band_is_found_as_without_it() -> None:
    """On a bin, between bins and at the band's two ends: within ``10⁻⁹ f_s`` of the truth, as
    the whole band's search finds it, and not flagged."""
    frequency_hz = np.array([0.0, 0.3, -1.7, 2.0, -2.0]) * BIN_HZ
    samples = tone(frequency_hz, np.linspace(0, 6, 5))
    banded = tone_frequency(samples, SAMPLE_RATE_HZ, band_hz=BAND_HZ)
    whole = tone_frequency(samples, SAMPLE_RATE_HZ)
    for found in (banded, whole):
        assert np.all(np.abs(found.frequency_hz - frequency_hz) < 1e-9 * SAMPLE_RATE_HZ)
        assert not found.below_threshold.any()


def test_a_tone_outside_the_band_is_not_found_and_is_flagged() -> None:
    """Every estimate stays within ``±(D + f_s/N)``. Noise-free, a tone within the margin is
    found (0.3 bin past ``D``); one whose peak is past the margin (1.2 and 1.5 bins past ``D``)
    pulls the estimate onto the band's edge, which is flagged. With noise at 10 dB per burst,
    tones 4 to 50 bins outside leave only their sidelobes (at most ``sinc²(3) = 1%`` of the
    tone's power, 0.1 noise variances) in the band, and at least 99% of 500 are flagged (noise
    alone passes 0.3%, the test below)."""
    edge_hz = BAND_HZ + BIN_HZ
    frequency_hz = BAND_HZ + np.array([0.3, 1.2, 1.5]) * BIN_HZ
    found = tone_frequency(tone(frequency_hz, np.zeros(3)), SAMPLE_RATE_HZ, band_hz=BAND_HZ)
    assert abs(found.frequency_hz[0] - frequency_hz[0]) < 1e-9 * SAMPLE_RATE_HZ
    np.testing.assert_allclose(found.frequency_hz[1:], edge_hz, rtol=1e-12)
    np.testing.assert_array_equal(found.below_threshold, [False, True, True])
    rng = np.random.default_rng(np.random.SeedSequence(2412))
    outside_hz = (edge_hz + rng.uniform(4, 50, 500) * BIN_HZ) * rng.choice([-1, 1], 500)
    signal = tone(outside_hz, rng.uniform(0, 2 * np.pi, 500))
    found = tone_frequency(noisy(signal, float(N), 10.0, rng), SAMPLE_RATE_HZ, band_hz=BAND_HZ)
    assert np.all(np.abs(found.frequency_hz) <= edge_hz)
    assert found.below_threshold.sum() >= 0.99 * 500, found.below_threshold.sum()


def test_near_threshold_the_band_has_fewer_outliers() -> None:
    """2,000 tones within ±2 bins at 10 dB per burst: searched over the whole band 571 are more
    than a bin off (a noise peak anywhere in the 1,024 bins beats the tone), within the band 41
    (in 6 cells); counts of 571 and 41 have standard deviations of about 20 and 6, so a ratio
    above 4 (14 here) is far outside their sampling error. Every estimate of the band is within
    it, and where both find the tone they find the same peak."""
    samples, frequency_hz = band_tones(snr_db=10.0, seed=2413)
    whole = tone_frequency(samples, SAMPLE_RATE_HZ)
    banded = tone_frequency(samples, SAMPLE_RATE_HZ, band_hz=BAND_HZ)
    whole_far = np.abs(whole.frequency_hz - frequency_hz) > BIN_HZ
    band_far = np.abs(banded.frequency_hz - frequency_hz) > BIN_HZ
    message = f"outliers: {whole_far.sum()} of {BURSTS} whole, {band_far.sum()} in the band"
    assert whole_far.sum() > 4 * band_far.sum(), message
    assert band_far.sum() < 0.05 * BURSTS, message
    assert np.all(np.abs(banded.frequency_hz) <= BAND_HZ + BIN_HZ)
    both = ~whole_far & ~band_far  # the same peak found: the same estimate
    np.testing.assert_allclose(banded.frequency_hz[both], whole.frequency_hz[both], atol=1e-9)


def test_noise_alone_passes_the_band_s_flag_at_the_rate_of_its_continuous_peak() -> None:
    """20,000 windows of 256 samples of noise alone, a band of ±2 bins (``W = 6`` cells,
    ``t = ln(W/p_fa) = 8.70``). The flag counts independent cells; the peak sought is the
    continuous periodogram's over the band, which crosses ``t`` also between cells: Rice's
    rate gives ``P ≈ (1 + W √(π t/3)) · (1 + t/(N−1))^{−(N−1)}`` (the second factor the
    F-distribution of ``SNR̂`` with its estimated noise, docs/math.md §19): 3.7·10⁻³, 74 of
    20,000, against ``p_fa``'s 20. 69 pass, within 4 standard deviations (34) of 74."""
    n, windows = 256, 20_000
    rate_hz = 2.0e6
    band_hz = 2 * rate_hz / n
    rng = np.random.default_rng(np.random.SeedSequence(2414))
    noise = rng.standard_normal((windows, n)) + 1j * rng.standard_normal((windows, n))
    found = tone_frequency(noise, rate_hz, band_hz=band_hz)
    cells = 2 * (n * band_hz / rate_hz + 1)
    t = np.log(cells / 1e-3)
    rate = (1 + cells * np.sqrt(np.pi * t / 3)) * (1 + t / (n - 1)) ** (-(n - 1))
    expected = rate * windows
    passed = int((~found.below_threshold).sum())
    assert abs(passed - expected) < 4 * np.sqrt(expected), (passed, expected)
    assert passed > 2 * 1e-3 * windows, passed


@pytest.mark.bits("the same functions on the same rows: a batch of bursts and each row alone")
def test_with_a_band_every_burst_at_once_is_one_at_a_time() -> None:
    """150 bursts near threshold, the last 50 with their tone 1.3 bins past the band, whose
    estimates are put on its edge: each row against itself alone."""
    samples, _ = band_tones(snr_db=8.0, seed=2415)
    rng = np.random.default_rng(np.random.SeedSequence(2416))
    past = tone(np.full(50, BAND_HZ + 1.3 * BIN_HZ), rng.uniform(0, 2 * np.pi, 50))
    samples = np.concatenate([samples[:100], noisy(past, float(N), 20.0, rng)])
    tones = tone_frequency(samples, SAMPLE_RATE_HZ, band_hz=BAND_HZ)
    edge = np.flatnonzero(np.abs(tones.frequency_hz) >= (BAND_HZ + BIN_HZ) * (1 - 1e-12))
    assert edge.size > 0
    for i in (0, 63, 64, 100, 149, *edge[:3]):
        one = tone_frequency(samples[i], SAMPLE_RATE_HZ, band_hz=BAND_HZ)
        for field in tones.__dataclass_fields__:
            assert np.array_equal(getattr(tones, field)[i], getattr(one, field)), field


# --------------------------------------------------------------------------------------------
# bad input: one line naming the argument
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: tone_frequency(np.ones(3), SAMPLE_RATE_HZ), "samples"),
        (lambda: tone_frequency(np.full(8, np.nan), SAMPLE_RATE_HZ), "samples"),
        (lambda: tone_frequency(np.ones(8), 0.0), "sample_rate_hz"),
        (lambda: tone_frequency(np.ones(8), SAMPLE_RATE_HZ, band_hz=-1.0), "band_hz"),
        (lambda: tone_frequency(np.ones(8), SAMPLE_RATE_HZ, band_hz=np.nan), "band_hz"),
        (lambda: tone_frequency(np.ones(8), SAMPLE_RATE_HZ, band_hz="wide"), "band_hz"),
        (lambda: burst_delay(np.ones(8), np.ones(9), SAMPLE_RATE_HZ), "reference"),
        (lambda: burst_delay(np.ones(8), np.zeros(4), SAMPLE_RATE_HZ), "reference"),
        (lambda: burst_delay(np.ones(8), np.ones((2, 2)), SAMPLE_RATE_HZ), "reference"),
    ],
)
def test_bad_input_is_one_line_naming_the_argument(call, field: str) -> None:
    with pytest.raises(ValueError) as raised:
        call()
    message = str(raised.value)
    assert message.startswith(f"{field}: ") and "\n" not in message


def test_a_burst_of_zeros_is_flagged_with_an_infinite_variance() -> None:
    """No signal and no noise: nothing to measure, said without a warning (warnings from
    estimators/ are errors in the suite)."""
    tone_found = tone_frequency(np.zeros((2, 16)), SAMPLE_RATE_HZ)
    delay_found = burst_delay(np.zeros((2, 16)), np.ones(4), SAMPLE_RATE_HZ)
    for variance, flagged in (
        (tone_found.variance_hz2, tone_found.below_threshold),
        (delay_found.variance_s2, delay_found.below_threshold),
    ):
        assert np.all(np.isinf(variance)) and flagged.all()
