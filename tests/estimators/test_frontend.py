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
# bad input: one line naming the argument
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: tone_frequency(np.ones(3), SAMPLE_RATE_HZ), "samples"),
        (lambda: tone_frequency(np.full(8, np.nan), SAMPLE_RATE_HZ), "samples"),
        (lambda: tone_frequency(np.ones(8), 0.0), "sample_rate_hz"),
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
