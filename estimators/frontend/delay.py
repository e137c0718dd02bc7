r"""The delay of a known burst in one window of complex baseband samples, every window at once
(docs/math.md §19).

For the samples ``x_n = b s(n − τ) + w_n`` (``b`` complex: amplitude and the unknown carrier
phase; ``s`` the reference, delayed by a fraction of a sample in the frequency domain,
``S_k e^{-j2π f_k τ}``, modulo the window) the ML delay maximises the magnitude of the complex
correlation ``|C(τ)|² = |Σ_k X_k S_k^* e^{j2π f_k τ}|² / N²``. :func:`burst_delay` finds its
peak on the correlation upsampled by zero-padding the cross-spectrum, interpolates it with a
parabola through the three largest magnitudes, and refines it by Newton steps on the exact
``|C(τ)|²`` (:func:`~estimators.frontend.peak.newton_to_peak`); its variance is the delay bound
at the SNR estimated from the same window (:func:`~estimators.frontend.bounds.delay_crb_s2`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.frontend.bounds import (
    below_threshold,
    burst_snr,
    delay_crb_s2,
    rms_bandwidth_hz,
)
from estimators.frontend.peak import NEWTON_STEPS, newton_to_peak, parabola_vertex
from estimators.frontend.samples import (
    burst_rows,
    by_blocks,
    reference_waveform,
    sample_rate,
)

UPSAMPLING = 4
"""The coarse correlation's samples per sample: the grid spacing is a quarter sample."""


@dataclass(frozen=True)
class BurstDelay:
    """Per window (the samples' leading shape): the delay in ``[0, N/fs)`` of the reference's
    first sample from the window's, its variance from the delay bound, the burst's estimated
    SNR and whether it is below threshold (docs/math.md §19)."""

    delay_s: np.ndarray
    variance_s2: np.ndarray
    burst_snr: np.ndarray
    below_threshold: np.ndarray


def upsampled_correlation(cross_spectrum: np.ndarray, upsampling: int) -> np.ndarray:
    """``C(m / U) / (U N)`` for ``m = 0 … U·N − 1`` (``U = upsampling``) from the ``(n, N)``
    cross-spectrum ``X_k S_k^* / N``: the spectrum zero-padded between its positive and
    negative frequencies (those of ``numpy.fft.fftfreq``), inverse transformed
    (docs/math.md §19)."""
    rows, n = cross_spectrum.shape
    positive = (n + 1) // 2
    padded = np.zeros((rows, upsampling * n), dtype=complex)
    padded[:, :positive] = cross_spectrum[:, :positive]
    padded[:, upsampling * n - (n - positive) :] = cross_spectrum[:, positive:]
    return np.fft.ifft(padded, axis=-1)


def correlation_peak(
    windows: np.ndarray, reference_spectrum: np.ndarray, upsampling: int, newton_steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """The maximum of ``|C(τ)|`` for each ``(n, N)`` window: ``τ̂`` in samples in ``[0, N)``
    and the complex correlation ``C(τ̂)`` (docs/math.md §19)."""
    n = windows.shape[1]
    spectrum, ref = np.fft.fft(windows, axis=-1), reference_spectrum
    cross = np.empty_like(spectrum)  # X S* / N in real arithmetic (peak.newton_to_peak says why)
    cross.real = (spectrum.real * ref.real + spectrum.imag * ref.imag) / n
    cross.imag = (spectrum.imag * ref.real - spectrum.real * ref.imag) / n
    correlation = upsampled_correlation(cross, upsampling)
    magnitude = np.sqrt(correlation.real**2 + correlation.imag**2)
    peak = np.argmax(magnitude, axis=-1)
    rows, size = np.arange(windows.shape[0]), upsampling * n
    offset = parabola_vertex(
        magnitude[rows, (peak - 1) % size],
        magnitude[rows, peak],
        magnitude[rows, (peak + 1) % size],
    )
    start = (peak + offset) / upsampling
    rates = 2.0 * np.pi * np.fft.fftfreq(n)
    tau, value = newton_to_peak(cross, rates, start, 1.0 / upsampling, newton_steps)
    tau = tau % n
    return np.where(tau >= n, tau - n, tau), value  # a rounding below 0 is 0, not N


def burst_delay(
    samples: np.ndarray,
    reference: np.ndarray,
    sample_rate_hz: float,
    *,
    upsampling: int = UPSAMPLING,
    newton_steps: int = NEWTON_STEPS,
) -> BurstDelay:
    """The ML delay of ``reference`` (real or complex, at most ``N`` samples) in each window of
    ``samples`` (``(..., N)`` complex baseband), the carrier phase unknown, with its variance
    from the delay bound and the threshold flag (docs/math.md §19)."""
    rate_hz = sample_rate(sample_rate_hz)
    windows = burst_rows(samples)
    n = windows.shape[1]
    waveform = reference_waveform(reference, n)
    reference_spectrum = np.fft.fft(waveform, n)
    tau, value = by_blocks(
        windows, lambda block: correlation_peak(block, reference_spectrum, upsampling, newton_steps)
    )
    energy = (windows.real**2 + windows.imag**2).sum(axis=-1)
    reference_energy = float(np.sum(np.abs(waveform) ** 2))
    snr = burst_snr(value, reference_energy, energy, n)
    bandwidth_hz = rms_bandwidth_hz(waveform, rate_hz, n)
    shape = np.shape(samples)[:-1]
    return BurstDelay(
        delay_s=(tau / rate_hz).reshape(shape),
        variance_s2=delay_crb_s2(snr, bandwidth_hz).reshape(shape),
        burst_snr=snr.reshape(shape),
        below_threshold=below_threshold(snr, n).reshape(shape),
    )
