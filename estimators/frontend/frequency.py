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
from scenarios.fields import bounded

ZERO_PADDING = 4
"""The coarse FFT's length over the burst's: the grid spacing is a quarter bin."""
BAND_MARGIN_BINS = 1.0
"""The band's margin on each side, in bins ``f_s/N``: a tone within ``±D`` has its nearest grid
bins and its refined peak inside ``±(D + f_s/N)``, which its error reaches only beyond 7
standard deviations above the flag's threshold (docs/math.md §19)."""


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
    bursts: np.ndarray, zero_padding: int, newton_steps: int, band_cycles: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram's maximum of each ``(n, N)`` burst: ``ω̂`` in rad/sample in ``[-π, π)``
    and ``A(ω̂) = Σ_n x_n e^{-jω̂ n'}`` (docs/math.md §19). With ``band_cycles`` ``B`` (cycles
    per sample, below 1/2) the maximum over ``|f| ≤ B``: the largest grid bin there, refined as
    without a band, and a refined peak beyond ``±B`` put on the band's edge (the maximum over the
    band when the periodogram rises towards the edge)."""
    n = bursts.shape[1]
    size = zero_padding * n
    spectrum = np.fft.fft(bursts, size, axis=-1)
    power = spectrum.real**2 + spectrum.imag**2
    if band_cycles is None:
        peak = np.argmax(power, axis=-1)
    else:
        inside = np.flatnonzero(np.abs(np.fft.fftfreq(size)) <= band_cycles)
        peak = inside[np.argmax(power[:, inside], axis=-1)]
    grid_rad = 2.0 * np.pi / size
    start = (peak + jacobsen_offset(spectrum, peak)) * grid_rad
    centred = np.arange(n) - 0.5 * (n - 1)
    omega, value = newton_to_peak(bursts, -centred, start, grid_rad, newton_steps)
    omega = (omega + np.pi) % (2.0 * np.pi) - np.pi
    if band_cycles is not None:
        edge_rad = 2.0 * np.pi * band_cycles
        beyond = np.flatnonzero(np.abs(omega) > edge_rad)
        if beyond.size:
            omega[beyond], value[beyond] = newton_to_peak(
                bursts[beyond], -centred, np.clip(omega[beyond], -edge_rad, edge_rad), grid_rad, 0
            )
    return omega, value


def band_cycles(band_hz: object, n: int, rate_hz: float) -> float | None:
    """The band searched for ``|f| ≤ D`` (``band_hz``, Hz), in cycles/sample: ``(D + f_s/N)/f_s``
    (:data:`BAND_MARGIN_BINS`), None (the whole band) for None or a band reaching ``f_s/2``
    (docs/math.md §19)."""
    if band_hz is None:
        return None
    search_hz = bounded(
        band_hz,
        "band_hz",
        0.0,
        np.inf,
        "Hz",
        "give the largest |frequency| the tone can have, >= 0 (None: the whole band)",
    )
    cycles = search_hz / rate_hz + BAND_MARGIN_BINS / n
    return cycles if cycles < 0.5 else None


def searched_cells(band: float | None, n: int) -> float:
    """The independent cells (bins ``f_s/N``) of the band searched, ``max(1, 2 N B)``, ``N`` for
    the whole band: the flag's count (docs/math.md §19)."""
    return float(n) if band is None else max(1.0, 2.0 * n * band)


def tone_frequency(
    samples: np.ndarray,
    sample_rate_hz: float,
    *,
    band_hz: float | None = None,
    zero_padding: int = ZERO_PADDING,
    newton_steps: int = NEWTON_STEPS,
) -> ToneFrequency:
    """The ML frequency of a tone in each burst of ``samples`` (``(..., N)`` complex baseband),
    with its Rife-Boorstyn variance and the threshold flag (docs/math.md §19).

    ``band_hz`` ``D`` (Hz, ≥ 0): the tone lies within ``±D``, and the peak is sought over
    ``|f| ≤ D + f_s/N`` only (one bin's margin, :data:`BAND_MARGIN_BINS`); the estimate stays
    there, one on the band's edge is flagged (the periodogram's peak lies beyond it), and the
    flag's threshold counts the band's ``2(N D/f_s + 1)`` cells, ``ln(cells / p_fa)``. None (or a
    band reaching ``f_s/2``): the whole band ``[−f_s/2, f_s/2)`` and ``N`` cells.
    """
    rate_hz = sample_rate(sample_rate_hz)
    bursts = burst_rows(samples)
    n = bursts.shape[1]
    band = band_cycles(band_hz, n, rate_hz)
    omega, value = by_blocks(
        bursts, lambda block: periodogram_peak(block, zero_padding, newton_steps, band)
    )
    energy = (bursts.real**2 + bursts.imag**2).sum(axis=-1)
    snr = burst_snr(value, float(n), energy, n)
    flagged = below_threshold(snr, n if band is None else searched_cells(band, n))
    if band is not None:
        flagged |= np.abs(omega) >= 2.0 * np.pi * band
    shape = np.shape(samples)[:-1]
    return ToneFrequency(
        frequency_hz=(omega * rate_hz / (2.0 * np.pi)).reshape(shape),
        variance_hz2=rife_boorstyn_variance_hz2(snr, n, rate_hz).reshape(shape),
        burst_snr=snr.reshape(shape),
        below_threshold=flagged.reshape(shape),
    )
