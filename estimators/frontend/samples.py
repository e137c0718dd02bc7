"""The front end's inputs checked once: bursts of complex baseband samples, a reference
waveform, a sample rate (docs/math.md §19). Bad input is one line naming the argument."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from scenarios.fields import positive_finite

MIN_SAMPLES = 4
"""The fewest samples a burst may hold: three grid cells around a peak and one more."""

BLOCK_BURSTS = 64
"""Bursts computed together: a block's zero-padded spectra stay in cache (a third faster than
2,000 at once) and the memory stays bounded however many bursts a call holds."""


def burst_rows(samples: object, name: str = "samples") -> np.ndarray:
    """``samples`` as an ``(n, N)`` complex array (any leading shape flattened), checked."""
    try:
        bursts = np.asarray(samples, dtype=complex)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of complex samples") from None
    if bursts.ndim == 0 or bursts.shape[-1] < MIN_SAMPLES:
        raise ValueError(
            f"{name}: the last axis holds a burst's samples; give at least {MIN_SAMPLES}, "
            f"got shape {bursts.shape}"
        )
    if not np.all(np.isfinite(bursts)):
        raise ValueError(f"{name}: every sample must be finite (no NaN or inf)")
    return bursts.reshape(-1, bursts.shape[-1])


def reference_waveform(reference: object, n_samples: int) -> np.ndarray:
    """``reference`` as a 1-D complex array of at most ``n_samples`` samples, not all zero."""
    try:
        waveform = np.asarray(reference, dtype=complex)
    except (TypeError, ValueError):
        raise ValueError("reference: expected an array of samples") from None
    if waveform.ndim != 1 or not 1 <= waveform.size <= n_samples:
        raise ValueError(
            f"reference: expected a 1-D waveform of 1 to {n_samples} samples (the bursts' "
            f"length), got shape {waveform.shape}"
        )
    if not np.all(np.isfinite(waveform)) or not np.any(waveform):
        raise ValueError("reference: must be finite and not all zero")
    return waveform


def sample_rate(value: object) -> float:
    """The sample rate in Hz, finite and > 0."""
    return positive_finite(value, "sample_rate_hz")


def by_blocks(
    rows: np.ndarray, compute: Callable[[np.ndarray], tuple[np.ndarray, ...]]
) -> tuple[np.ndarray, ...]:
    """``compute`` on blocks of :data:`BLOCK_BURSTS` rows of ``rows``, its per-row outputs
    concatenated: each row's result is the one it has alone."""
    blocks = [
        compute(rows[start : start + BLOCK_BURSTS]) for start in range(0, len(rows), BLOCK_BURSTS)
    ]
    return tuple(np.concatenate(parts) for parts in zip(*blocks, strict=True))
