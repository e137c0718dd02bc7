r"""From the receiver's bursts to the measurements today's estimators read (docs/math.md §20).

:func:`measure_bursts` runs the per-burst front end of §19 on one window per burst. For a known
BPSK burst: the delay first (:func:`~estimators.frontend.burst_delay` against the plan's sampled
chips), then the chips removed (the reference delayed by the estimate, band-limited, times the
samples) and the tone's frequency (:func:`~estimators.frontend.tone_frequency`), then the delay
again on the window with that tone removed, matched to the burst as received: the first
correlation loses ``sinc²(f T)`` of the burst's energy to the Doppler ``f`` and leaves it in the
residual, so its SNR (and the variance written) would fall with the Doppler. With a Doppler
search (``doppler_search_hz``) the first pass correlates against the chips on a grid of
frequency cells (:func:`doppler_cells_hz`, :func:`searched_doppler_hz`) and starts from the cell
and delay of the largest correlation. For a tone: the frequency only. The ToA is the window's
time plus the burst centre's offset from the window's centre minus the schedule,
``τ̂_k = t_k + Δ̂_k − e_k``. :func:`measurement_set` (one trial)
and :func:`measurement_batch` (many trials) put the measurements into the project's
:class:`~scenarios.types.MeasurementSet` and :class:`~scenarios.types.MeasurementBatch` with the
σ's of the bounds, which far above threshold are the errors' own.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from estimators.frontend.bounds import below_threshold
from estimators.frontend.delay import burst_delay
from estimators.frontend.frequency import tone_frequency
from estimators.frontend.peak import rotated
from estimators.frontend.samples import burst_rows, by_blocks
from scenarios.fields import bounded
from scenarios.signal import BurstPlan, burst_envelope, window_offsets_s
from scenarios.types import MeasurementBatch, MeasurementSet, NoiseSigmas

DOPPLER_CELLS_PER_BIN = 4
"""Frequency cells of the Doppler search per window bin ``f_s/N``: cells ``f_s/(4N)`` apart, at
most ``1/(4T)``, so a Doppler half a cell from the nearest keeps at least ``sinc²(1/8) = 0.95``
(−0.22 dB) of the burst's energy in the first pass (docs/math.md §20)."""
SEARCH_UPSAMPLING = 2
"""The search's delay grid, samples per sample: half a sample, a quarter at most from the peak
(chips of ``L`` samples keep about ``(1 − 1/(4L))²`` of ``|C|²`` there, 0.88 for ``L = 4``); the
delay is then refined at the cell found by :func:`~estimators.frontend.burst_delay` on its
quarter-sample grid (docs/math.md §20). Half the grid of the refinement, half its cost."""
SEARCH_ELEMENTS = 1 << 21
"""Most complex numbers the search holds at once (16 MB in single precision): the cells of a
block of bursts are taken a few at a time, so that the memory does not grow with the span."""


@dataclass(frozen=True)
class BurstMeasurements:
    """Per burst, every array ``(..., n_bursts)`` (docs/math.md §20): the measured Doppler
    (physical sign, MATH §1) and its variance (the Rife-Boorstyn bound at the burst's estimated
    SNR); the ToA and its variance (the delay bound at that SNR), None for a ``"cw"`` plan (a
    tone carries no delay); the burst's estimated SNR (the delay's for ``"bpsk"``, the
    frequency's for ``"cw"``); and the flag, set where the frequency or the delay is below
    threshold (§19)."""

    doppler_hz: np.ndarray
    doppler_variance_hz2: np.ndarray
    toa_s: np.ndarray | None
    toa_variance_s2: np.ndarray | None
    burst_snr: np.ndarray
    below_threshold: np.ndarray

    def trial(self, index: int) -> BurstMeasurements:
        """Trial ``index`` of measurements ``(n_trials, n_bursts)``: every array's row."""
        return BurstMeasurements(
            **{name: None if value is None else value[index] for name, value in vars(self).items()}
        )


def schedule_times(value: object, name: str, n_bursts: int) -> np.ndarray:
    """``value`` as a finite ``(n_bursts,)`` float array, else one line naming ``name``."""
    try:
        times = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of times in seconds") from None
    if times.shape != (n_bursts,):
        raise ValueError(
            f"{name}: expected shape ({n_bursts},), one time per burst of samples, got "
            f"{times.shape}"
        )
    if not np.all(np.isfinite(times)):
        raise ValueError(f"{name}: every time must be finite (no NaN or inf)")
    return times


def chips_removed(
    windows: np.ndarray, reference: np.ndarray, delay_samples: np.ndarray
) -> np.ndarray:
    """``x_n · s̃(n − τ̂)`` per ``(n, N)`` row: the real ``reference`` delayed by ``τ̂`` samples
    in the frequency domain (its Nyquist bin by ``cos(πτ̂)``: the real part) times the samples,
    in real arithmetic (docs/math.md §20)."""
    n = windows.shape[1]
    spectrum = np.fft.fft(reference)
    re, im = rotated(
        spectrum.real, spectrum.imag, -2.0 * np.pi * delay_samples[:, None] * np.fft.fftfreq(n)
    )
    shifted_spectrum = np.empty(re.shape, dtype=complex)
    shifted_spectrum.real, shifted_spectrum.imag = re, im
    shifted = np.fft.ifft(shifted_spectrum, axis=-1).real
    removed = np.empty_like(windows)
    removed.real, removed.imag = windows.real * shifted, windows.imag * shifted
    return removed


def tone_removed(windows: np.ndarray, frequency_cycles: np.ndarray) -> np.ndarray:
    """``x_n e^{−j2π f̂ n'}`` per ``(n, N)`` row, ``f̂`` in cycles/sample and ``n'`` the index
    from the window's centre, in real arithmetic (docs/math.md §20)."""
    n = windows.shape[1]
    phase = -2.0 * np.pi * frequency_cycles[:, None] * (np.arange(n) - 0.5 * (n - 1))
    re, im = rotated(windows.real, windows.imag, phase)
    still = np.empty_like(windows)
    still.real, still.imag = re, im
    return still


def centred(delay_samples: np.ndarray, n: int) -> np.ndarray:
    """A delay in ``[0, N)`` samples of the window-centred reference as the burst centre's
    offset from the window's centre, in ``[−N/2, N/2)`` samples."""
    return np.where(delay_samples >= n / 2.0, delay_samples - n, delay_samples)


def burst_samples(windows: np.ndarray, plan: BurstPlan, offset_samples: np.ndarray) -> np.ndarray:
    """The plan's ``n_burst_samples`` of each ``(n, n_samples)`` row around the burst's centre,
    ``offset_samples`` from the window's, rounded and kept within the window (without guards,
    the whole window)."""
    if plan.n_guard_samples == 0:
        return windows
    guard = plan.n_guard_samples
    start = np.clip(guard + np.rint(offset_samples).astype(np.int64), 0, 2 * guard)
    index = start[:, None] + np.arange(plan.n_burst_samples)
    return np.take_along_axis(windows, index, axis=1)


def doppler_cells_hz(doppler_search_hz: float, plan: BurstPlan) -> np.ndarray:
    """The Doppler search's frequency cells, ``c f_s / (4N)`` for ``c = −K … K`` (``N`` the
    window's samples), ``K = ⌈4 N D / f_s − 1/2⌉`` the fewest that put every ``|f| ≤ D`` within
    half a cell of one (docs/math.md §20); ``D = 0``: the one cell 0."""
    spacing_hz = plan.sample_rate_hz / (DOPPLER_CELLS_PER_BIN * plan.n_samples)
    half = max(0, int(np.ceil(doppler_search_hz / spacing_hz - 0.5)))
    return spacing_hz * np.arange(-half, half + 1)


def searched_doppler_hz(
    windows: np.ndarray, reference_spectrum: np.ndarray, cells_hz: np.ndarray, rate_hz: float
) -> np.ndarray:
    """The cell of ``cells_hz`` (multiples of ``f_s/(4N)``) whose correlation with the chips,
    the window's tone at that cell removed, has the largest ``|C|²`` over the delays of the
    half-sample grid (:data:`SEARCH_UPSAMPLING`), per ``(n, N)`` window (docs/math.md §20).

    Removing a tone of ``c f_s/(4N)`` shifts the spectrum by ``c`` bins of the window zero-padded
    to ``4N``: the ``N``-point spectrum at cell ``c`` is ``X₄[(4k + c) mod 4N]`` (up to a phase
    that ``|C|`` does not see), one FFT per window for all the cells. The cross-spectrum with
    the chips, zero-padded between its positive and negative frequencies as in
    :func:`~estimators.frontend.delay.upsampled_correlation`, is inverse transformed for as
    many cells at a time as :data:`SEARCH_ELEMENTS` allows, in real arithmetic (the products'
    bits do not depend on the neighbours, :func:`~estimators.frontend.peak.newton_to_peak`)
    and in single precision (half the time: only the choice of cell rests on it, and each
    window's spectrum is scaled to a largest part of 1, far from overflow and underflow).
    """
    rows, n = windows.shape
    size, length = DOPPLER_CELLS_PER_BIN * n, SEARCH_UPSAMPLING * n
    spectrum = np.fft.fft(windows, size, axis=-1)
    largest = np.maximum(np.abs(spectrum.real), np.abs(spectrum.imag)).max(axis=-1)
    scale = 1.0 / np.where(largest > 0.0, largest, 1.0)[:, None]  # |C| in single precision
    spectrum_re = (spectrum.real * scale).astype(np.float32)
    spectrum_im = (spectrum.imag * scale).astype(np.float32)
    reference_re = (reference_spectrum.real / n).astype(np.float32)
    reference_im = (reference_spectrum.imag / n).astype(np.float32)
    cells = np.rint(cells_hz * size / rate_hz).astype(np.int64)
    index = (DOPPLER_CELLS_PER_BIN * np.arange(n) + cells[:, None]) % size  # (cells, N)
    positive = (n + 1) // 2
    at_once = max(1, SEARCH_ELEMENTS // (rows * length))
    best = np.full(rows, -np.inf, dtype=np.float32)
    chosen = np.zeros(rows, dtype=np.int64)
    for first in range(0, len(cells), at_once):
        shifted = index[first : first + at_once]
        x_re, x_im = spectrum_re[:, shifted], spectrum_im[:, shifted]  # (rows, cells, N)
        padded = np.zeros((*x_re.shape[:2], length), dtype=np.complex64)
        padded.real[..., :positive] = (x_re * reference_re + x_im * reference_im)[..., :positive]
        padded.imag[..., :positive] = (x_im * reference_re - x_re * reference_im)[..., :positive]
        padded.real[..., length - n + positive :] = (
            x_re[..., positive:] * reference_re[positive:]
            + x_im[..., positive:] * reference_im[positive:]
        )
        padded.imag[..., length - n + positive :] = (
            x_im[..., positive:] * reference_re[positive:]
            - x_re[..., positive:] * reference_im[positive:]
        )
        correlation = np.fft.ifft(padded, axis=-1)
        power = correlation.real**2
        power += correlation.imag**2
        peak_power = power.max(axis=-1)  # (rows, cells)
        cell = np.argmax(peak_power, axis=-1)
        peak = peak_power[np.arange(rows), cell]
        better = peak > best
        best, chosen = np.where(better, peak, best), np.where(better, first + cell, chosen)
    return cells_hz[chosen]


def measure_rows(
    windows: np.ndarray,
    plan: BurstPlan,
    reference: np.ndarray,
    cells_hz: np.ndarray | None,
    band_hz: float | None = None,
) -> tuple[np.ndarray, ...]:
    """The front end on ``(n, n_samples)`` windows: the Doppler, its variance, the burst
    centre's offset from the window's centre (s), its variance, the SNR and the flag
    (docs/math.md §20). ``"bpsk"``: the coarse delay against ``reference`` (the window's
    sampled chips; with ``cells_hz``, of more than one cell, at the searched cell's Doppler
    removed), the chips removed, the frequency, the delay of the window with the tone removed;
    a burst is flagged if the frequency or the final delay is, the delay's threshold counting
    the cells searched. The frequency is sought within ``±band_hz`` (None: the whole band)."""
    rate_hz, n = plan.sample_rate_hz, plan.n_samples
    rows = windows.shape[0]
    if plan.waveform == "cw":
        tone = tone_frequency(
            burst_samples(windows, plan, np.zeros(rows)), rate_hz, band_hz=band_hz
        )
        nothing = np.full(rows, np.nan)
        return (
            tone.frequency_hz,
            tone.variance_hz2,
            nothing,
            nothing,
            tone.burst_snr,
            tone.below_threshold,
        )
    searched = cells_hz is not None and cells_hz.size > 1
    if searched:
        reference_spectrum = np.fft.fft(reference, n)
        cell_hz = searched_doppler_hz(windows, reference_spectrum, cells_hz, rate_hz)
        coarse = burst_delay(tone_removed(windows, cell_hz / rate_hz), reference, rate_hz)
    else:
        coarse = burst_delay(windows, reference, rate_hz)
    coarse_samples = coarse.delay_s * rate_hz  # in [0, N): the reference's shift
    removed = chips_removed(windows, reference, coarse_samples)
    tone = tone_frequency(
        burst_samples(removed, plan, centred(coarse_samples, n)), rate_hz, band_hz=band_hz
    )
    delay = burst_delay(tone_removed(windows, tone.frequency_hz / rate_hz), reference, rate_hz)
    delay_flag = below_threshold(delay.burst_snr, n * cells_hz.size) if searched else None
    return (
        tone.frequency_hz,
        tone.variance_hz2,
        centred(delay.delay_s * rate_hz, n) / rate_hz,
        delay.variance_s2,
        delay.burst_snr,
        tone.below_threshold | (delay.below_threshold if delay_flag is None else delay_flag),
    )


def track_doppler_search_hz(geometry: MeasurementSet) -> float | None:
    """The Doppler search a flight calls for (docs/math.md §20): ``γ max_k ‖v_k‖``, the
    largest ``|γ vᵀu|`` any emitter can give, when the carrier offset is known (0); None when
    the data declare it unknown (MATH §15), which no track bounds."""
    if "carrier_offset_hz" in geometry.unknowns:
        return None
    speed_mps = np.linalg.norm(geometry.velocity_mps, axis=-1)
    return float(geometry.gamma_per_m * np.max(speed_mps))


def search_cells_hz(doppler_search_hz: float | None, plan: BurstPlan) -> np.ndarray | None:
    """The cells of a Doppler search of ``±doppler_search_hz`` (:func:`doppler_cells_hz`),
    None for no search; a span outside ``[0, f_s/2]`` is one line naming it."""
    if doppler_search_hz is None:
        return None
    search_hz = bounded(
        doppler_search_hz,
        "doppler_search_hz",
        0.0,
        0.5 * plan.sample_rate_hz,
        "Hz",
        "give the largest |Doppler| expected, carrier offset included (None: no search)",
    )
    return doppler_cells_hz(search_hz, plan)


def measure_bursts(
    samples: object,
    plan: BurstPlan,
    *,
    time_s: object,
    emission_time_s: object,
    doppler_search_hz: float | None = None,
) -> BurstMeasurements:
    """The Doppler and (``"bpsk"``) the ToA of every burst, with their variances and the flag
    (docs/math.md §20).

    ``samples`` ``(..., n_bursts, n_samples)``: one window of ``plan.n_samples`` per burst,
    centred on ``time_s[k]`` (``t_k``); ``emission_time_s`` ``(n_bursts,)`` the schedule
    ``e_k`` (what :func:`scenarios.signal.received_bursts` returns). The ToA is
    ``t_k + Δ̂_k − e_k``, ``Δ̂_k`` the burst centre's offset from the window's centre. A block of
    bursts is computed at a time and each burst's result does not depend on the others, so a
    caller may stream a recording in blocks of any size (with the matching slices of
    ``time_s`` and ``emission_time_s``).

    The BPSK delay's first pass correlates against the chips. Without ``doppler_search_hz``
    (None) it does so without the Doppler ``f``: it needs ``|f| T`` well below 1 (0.1 loses 3%
    of the burst's energy to that pass, 1 all of it; docs/math.md §20). With it, ``D ≥ 0`` Hz
    and at most ``f_s/2``, the pass searches the frequency cells of :func:`doppler_cells_hz`
    over ``[−D, D]`` (a Doppler within the span loses at most 5% of the energy) and the burst's
    delay flag counts the ``M`` cells, ``SNR̂ < ln(N M / p_fa)``; ``D ≤ f_s/(8N)`` is the one
    cell 0, the pass without a search.

    The frequency (of the chips-removed burst, or of a ``"cw"`` tone, for which ``D`` is the
    span of the frequency's search alone) is sought within ``±D`` too, plus a bin's margin
    (:func:`~estimators.frontend.tone_frequency`'s ``band_hz``), and its flag counts the band's
    cells, not the window's ``N``: a noise peak elsewhere in ``[−f_s/2, f_s/2)`` cannot win.
    ``D = 0`` and None search no Doppler: the frequency is sought over the whole band.
    """
    if not isinstance(plan, BurstPlan):
        raise ValueError(f"plan: expected a BurstPlan, got {type(plan).__name__}")
    windows = burst_rows(samples)
    shape = np.shape(samples)
    if len(shape) < 2 or shape[-1] != plan.n_samples or len(windows) == 0:
        raise ValueError(
            f"samples: expected shape (..., n_bursts, {plan.n_samples}), one window of "
            f"plan.n_samples per burst and at least one burst, got {shape}"
        )
    time = schedule_times(time_s, "time_s", shape[-2])
    emission = schedule_times(emission_time_s, "emission_time_s", shape[-2])
    cells_hz = search_cells_hz(doppler_search_hz, plan)
    band_hz = None
    if cells_hz is not None and doppler_search_hz > 0.0:
        band_hz = float(doppler_search_hz)
    reference = burst_envelope(plan, window_offsets_s(plan))
    doppler, doppler_variance, offset_s, offset_variance, snr, flagged = (
        part.reshape(shape[:-1])
        for part in by_blocks(
            windows, lambda block: measure_rows(block, plan, reference, cells_hz, band_hz)
        )
    )
    bpsk = plan.waveform == "bpsk"
    return BurstMeasurements(
        doppler_hz=doppler,
        doppler_variance_hz2=doppler_variance,
        toa_s=(time - emission) + offset_s if bpsk else None,
        toa_variance_s2=offset_variance if bpsk else None,
        burst_snr=snr,
        below_threshold=flagged,
    )


def bound_at_mean_snr(variance: np.ndarray, flagged: np.ndarray) -> float:
    """``1 / mean(1 / var_k)`` over the bursts not flagged (all of them if every one is): each
    ``var_k`` is a bound ``K / SNR̂_k``, so this is the bound at the mean ``SNR̂``
    (docs/math.md §20)."""
    kept = variance[~flagged] if not flagged.all() else variance
    with np.errstate(divide="ignore"):  # bursts of zeros: infinite variances, refused by name
        return float(1.0 / np.mean(1.0 / kept))


def measured_noise(measured: BurstMeasurements) -> NoiseSigmas:
    """The σ's of one trial: the square root of each bound at the trial's mean estimated burst
    SNR over the bursts not flagged (docs/math.md §20)."""
    flagged = np.asarray(measured.below_threshold)
    toa = measured.toa_variance_s2
    return NoiseSigmas(
        doppler_hz=np.sqrt(bound_at_mean_snr(measured.doppler_variance_hz2, flagged)),
        toa_s=None if toa is None else np.sqrt(bound_at_mean_snr(toa, flagged)),
    )


def check_bursts(geometry: MeasurementSet, doppler_hz: np.ndarray) -> None:
    """``geometry`` a :class:`MeasurementSet` with one sample per measured burst."""
    if not isinstance(geometry, MeasurementSet):
        raise ValueError(f"geometry: expected a MeasurementSet, got {type(geometry).__name__}")
    if np.shape(doppler_hz)[-1] != geometry.n_samples:
        raise ValueError(
            f"measured: {np.shape(doppler_hz)[-1]} bursts for the geometry's "
            f"{geometry.n_samples} samples; measure one burst per sample"
        )


def with_measurements(
    geometry: MeasurementSet, noise: NoiseSigmas, doppler_hz: np.ndarray, toa_s: np.ndarray | None
) -> MeasurementSet:
    """``geometry``'s flight, constants, unknowns and truth with the measured Doppler and ToA
    and their σ's; its RSS dropped (the bursts do not measure it)."""
    check_bursts(geometry, doppler_hz)
    return replace(
        geometry,
        doppler_hz=doppler_hz,
        toa_s=toa_s,
        rss_dbm=None,
        rss_model=None,
        noise=noise,
    )


def measurement_set(
    geometry: MeasurementSet, measured: BurstMeasurements, *, drop_flagged: bool = False
) -> MeasurementSet:
    """One trial's measurement file (docs/math.md §20): ``geometry``'s flight, constants,
    unknowns and truth with the measured Doppler (and ToA), ``measured`` of shape
    ``(n_bursts,)``, one burst per sample.

    The σ's written are the square roots of the bounds at the trial's mean estimated burst SNR
    over the bursts not flagged (all of them if every one is). A :class:`MeasurementSet` holds
    one σ per modality, and no per-sample σ's are needed: the received power is constant over
    the flight (MATH §18), so every burst has the same SNR and the same bound, and the bursts'
    own estimates of it differ only by their estimation noise. The flagged bursts' measurements
    are written too unless ``drop_flagged``, which keeps the samples not flagged only (below
    threshold a ToA outlier may be shorter than the UAV's height, which a set with a known
    emission time refuses).
    """
    if np.ndim(measured.doppler_hz) != 1:
        raise ValueError(
            f"measured: expected one trial, shape (n_bursts,), got "
            f"{np.shape(measured.doppler_hz)}; use measurement_batch for many"
        )
    noise = measured_noise(measured)
    doppler, toa = measured.doppler_hz, measured.toa_s
    if drop_flagged:
        check_bursts(geometry, doppler)
        kept = ~np.asarray(measured.below_threshold)
        if not kept.any():
            raise ValueError(
                "measured.below_threshold: every burst is flagged, nothing is left to write; "
                "measure at a higher C/N0 or keep the flagged bursts"
            )
        geometry = geometry.take(kept)
        doppler, toa = doppler[kept], None if toa is None else toa[kept]
    return with_measurements(geometry, noise, doppler, toa)


def measurement_batch(
    geometry: MeasurementSet, measured: BurstMeasurements, noise: NoiseSigmas
) -> MeasurementBatch:
    """Many trials' measurements (docs/math.md §20), ``measured`` of shape ``(n_trials,
    n_bursts)``, with the σ's ``noise`` shared by the batch (a caller passes the bounds at the
    plan's C/N0, :func:`scenarios.signal.noise_at_cn0`). Every trial's ToAs pass the set's
    checks or the batch is refused: below threshold, with a known emission time, a ToA outlier
    shorter than the UAV's height is (:func:`measurement_set` can drop the flagged bursts)."""
    if np.ndim(measured.doppler_hz) != 2:
        raise ValueError(
            f"measured: expected shape (n_trials, n_bursts), got {np.shape(measured.doppler_hz)}"
        )
    if not isinstance(noise, NoiseSigmas):
        raise ValueError(f"noise: expected NoiseSigmas, got {type(noise).__name__}")
    shared = with_measurements(
        geometry,
        noise,
        measured.doppler_hz[0],
        None if measured.toa_s is None else measured.toa_s[0],
    )
    return MeasurementBatch(
        geometry=shared, doppler_hz=measured.doppler_hz, toa_s=measured.toa_s, rss_dbm=None
    )


def outlier_rate(
    measured: BurstMeasurements,
    plan: BurstPlan,
    doppler_hz: np.ndarray,
    toa_s: np.ndarray | None = None,
    among: np.ndarray | None = None,
) -> tuple[int, int]:
    """``(count, total)`` of the bursts whose Doppler is more than one bin ``1/T`` off the
    true ``doppler_hz``, or (``"bpsk"``, ``toa_s`` given) whose ToA is more than one chip
    ``1/R_c`` off: the outliers no local bound describes (docs/math.md §19, §20). ``among``
    (boolean, ``measured``'s shape): count only those bursts, e.g. ``~measured.below_threshold``
    for the outliers the flag missed."""
    far = np.abs(measured.doppler_hz - doppler_hz) > 1.0 / plan.burst_s
    if toa_s is not None and measured.toa_s is not None:
        far |= np.abs(measured.toa_s - toa_s) > 1.0 / plan.chip_rate_hz
    counted = np.ones(far.shape, dtype=bool) if among is None else np.asarray(among, dtype=bool)
    return int(far[counted].sum()), int(counted.sum())
