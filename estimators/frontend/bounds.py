r"""The per-burst bounds, the burst's SNR estimated from the burst itself, and the threshold
flag (docs/math.md §19).

- the bounds, whose one home is the signal model (:mod:`scenarios.signal`, MATH §18), used
  here at the SNR a burst shows:
- :func:`~scenarios.signal.rife_boorstyn_variance_hz2`: the Cramér-Rao bound of a tone's frequency, amplitude and
  phase unknown (D. C. Rife and R. R. Boorstyn, "Single-tone parameter estimation from
  discrete-time observations", IEEE Trans. Information Theory 20(5), 1974), in its exact
  finite-``N`` form ``var(ω̂) ≥ 6 / (SNR · N (N² − 1))`` rad²/sample², ``SNR = |b|²/σ²`` per
  sample.
- :func:`~scenarios.signal.delay_crb_s2`: the bound of a known burst's delay, amplitude and carrier phase unknown,
  ``1 / (8π² B_rms² SNR_burst)`` with :func:`~scenarios.signal.rms_bandwidth_hz` the reference's RMS bandwidth
  about its spectral centroid.
- :func:`burst_snr`: the fitted signal's energy over the noise variance estimated from the
  residual, ``SNR_burst = |C|² / (E_s σ̂²)``; under noise alone its value at one candidate is
  exponential with mean 1.
- :func:`below_threshold`: a burst whose peak does not exceed what noise alone reaches over
  the burst's ``N`` cells with probability :data:`FALSE_ALARM_PROBABILITY`,
  ``SNR_burst < ln(N / p_fa)``, is flagged: its estimate is likely an outlier and its bound
  does not describe its error.
"""

from __future__ import annotations

import numpy as np

from scenarios.signal import delay_crb_s2, rife_boorstyn_variance_hz2, rms_bandwidth_hz

FALSE_ALARM_PROBABILITY = 1e-3
"""The probability that a burst of noise alone passes the threshold flag (docs/math.md §19)."""


def burst_snr(
    peak: np.ndarray, reference_energy: float, total_energy: np.ndarray, n_samples: int
) -> np.ndarray:
    """``|C|² / (E_s σ̂²)`` with ``σ̂² = (Σ|x|² − |C|²/E_s) / (N − 1)``, the residual's power
    after the fitted amplitude (docs/math.md §19); ``peak`` is the complex correlation ``C``
    of the samples with the reference of energy ``E_s`` at the estimate."""
    fitted = (peak.real**2 + peak.imag**2) / reference_energy  # no hypot: same bits any length
    residual = np.maximum(
        total_energy - fitted, np.finfo(float).eps * total_energy + np.finfo(float).tiny
    )
    return fitted / (residual / (n_samples - 1))


def below_threshold(
    snr: np.ndarray, n_cells: int, false_alarm: float = FALSE_ALARM_PROBABILITY
) -> np.ndarray:
    """``SNR_burst < ln(n_cells / p_fa)``: the peak is within what noise alone reaches over
    ``n_cells`` independent cells with probability ``p_fa`` (docs/math.md §19)."""
    return np.asarray(snr) < np.log(n_cells / false_alarm)


__all__ = [
    "FALSE_ALARM_PROBABILITY",
    "below_threshold",
    "burst_snr",
    "delay_crb_s2",
    "rife_boorstyn_variance_hz2",
    "rms_bandwidth_hz",
]
