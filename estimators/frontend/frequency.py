r"""The frequency of a tone in one burst of complex baseband samples, every burst at once
(docs/math.md §19).

For the samples ``x_n = b e^{j(ω n + φ)} + w_n`` the ML frequency maximises the periodogram
``P(ω) = |Σ_n x_n e^{-jω n'}|²`` (``n' = n − (N−1)/2``, centred so that the curvature does not
carry the phase). :func:`tone_frequency` finds its peak on a zero-padded FFT, interpolates it
with Jacobsen's estimator (E. Jacobsen and P. Kootsookos, "Fast, accurate frequency
estimators", IEEE Signal Processing Magazine 24(3), 2007), and refines it by Newton steps on the
exact periodogram (:func:`~estimators.frontend.peak.newton_to_peak`); its variance is the
Rife-Boorstyn bound at the SNR estimated from the same burst
(:func:`~estimators.frontend.bounds.rife_boorstyn_variance_hz2`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.frontend.bounds import below_threshold, burst_snr, rife_boorstyn_variance_hz2
from estimators.frontend.peak import NEWTON_STEPS, newton_to_peak
from estimators.frontend.samples import burst_rows, by_blocks, sample_rate

ZERO_PADDING = 4
"""The coarse FFT's length over the burst's: the grid spacing is a quarter bin."""


@dataclass(frozen=True)
class ToneFrequency:
    """Per burst (the samples' leading shape): the frequency in ``[-fs/2, fs/2)``, its variance
    from the Rife-Boorstyn bound, the burst's estimated SNR and whether it is below threshold
    (docs/math.md §19)."""

    frequency_hz: np.ndarray
    variance_hz2: np.ndarray
    burst_snr: np.ndarray
    below_threshold: np.ndarray


def jacobsen_offset(spectrum: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """Jacobsen's offset, in grid steps, of the peak of the ``(n, M)`` complex ``spectrum`` from
    its largest bin ``peak``: ``Re[(X₋ − X₊) / (2X₀ − X₋ − X₊)]``, clipped to ``[-1/2, 1/2]``
    (docs/math.md §19)."""
    rows = np.arange(spectrum.shape[0])
    size = spectrum.shape[1]
    left, centre = spectrum[rows, (peak - 1) % size], spectrum[rows, peak]
    right = spectrum[rows, (peak + 1) % size]
    numerator, denominator = left - right, 2.0 * centre - left - right
    size2 = denominator.real**2 + denominator.imag**2  # real arithmetic: see newton_to_peak
    flat = size2 == 0.0
    dot = numerator.real * denominator.real + numerator.imag * denominator.imag
    offset = dot / np.where(flat, 1.0, size2)
    return np.clip(np.where(flat, 0.0, offset), -0.5, 0.5)


def periodogram_peak(
    bursts: np.ndarray, zero_padding: int, newton_steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram's maximum of each ``(n, N)`` burst: ``ω̂`` in rad/sample in ``[-π, π)``
    and ``A(ω̂) = Σ_n x_n e^{-jω̂ n'}`` (docs/math.md §19)."""
    n = bursts.shape[1]
    size = zero_padding * n
    spectrum = np.fft.fft(bursts, size, axis=-1)
    peak = np.argmax(spectrum.real**2 + spectrum.imag**2, axis=-1)
    grid_rad = 2.0 * np.pi / size
    start = (peak + jacobsen_offset(spectrum, peak)) * grid_rad
    centred = np.arange(n) - 0.5 * (n - 1)
    omega, value = newton_to_peak(bursts, -centred, start, grid_rad, newton_steps)
    return (omega + np.pi) % (2.0 * np.pi) - np.pi, value


def tone_frequency(
    samples: np.ndarray,
    sample_rate_hz: float,
    *,
    zero_padding: int = ZERO_PADDING,
    newton_steps: int = NEWTON_STEPS,
) -> ToneFrequency:
    """The ML frequency of a tone in each burst of ``samples`` (``(..., N)`` complex baseband),
    with its Rife-Boorstyn variance and the threshold flag (docs/math.md §19)."""
    rate_hz = sample_rate(sample_rate_hz)
    bursts = burst_rows(samples)
    n = bursts.shape[1]
    omega, value = by_blocks(
        bursts, lambda block: periodogram_peak(block, zero_padding, newton_steps)
    )
    energy = (bursts.real**2 + bursts.imag**2).sum(axis=-1)
    snr = burst_snr(value, float(n), energy, n)
    shape = np.shape(samples)[:-1]
    return ToneFrequency(
        frequency_hz=(omega * rate_hz / (2.0 * np.pi)).reshape(shape),
        variance_hz2=rife_boorstyn_variance_hz2(snr, n, rate_hz).reshape(shape),
        burst_snr=snr.reshape(shape),
        below_threshold=below_threshold(snr, n).reshape(shape),
    )
