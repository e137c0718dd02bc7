r"""The signal level (MATH §18): complex-baseband samples of known bursts received by the UAV.

The emitter sends one known burst per measurement sample of the flight: a tone (``"cw"``) or a
known ±1 chip sequence (``"bpsk"``, rectangular chips, drawn from a seed). Sample ``k`` of the
flight is the arrival of burst ``k``'s centre: at ``t_k`` the UAV is at ``p_k``, and the burst
was sent at the nominal time ``e_k = t_k − τ_k`` with ``τ_k`` the ToA of MATH §1 and §15 (the
emission time b included). Within the burst the UAV flies ``p(t) = p_k + (t − t_k) v_k`` and the
receiver, tuned to the nominal carrier, records

.. math::

    r(t) = a\, e^{j(\theta + \varphi(t))}\, s\big(t - t_k - (\tau(t) - \tau_k)\big) + n(t),
    \qquad \varphi(t) = -2\pi\gamma\,(\rho(t) - \rho_k) + 2\pi\delta\,(t - t_k),

``s`` the burst centred on zero, ``a = √C``, θ a uniform carrier phase per burst, δ the
carrier offset of §15 and ``n`` complex white Gaussian noise of power ``N0 fs`` per sample. The
phase's slope at ``t_k`` is ``−γ dρ/dt + δ``, the Doppler ``f_k`` of
:func:`scenarios.measurement_model.doppler_hz`. Pure numpy; the thin :class:`BurstPlan` holds
the waveform and the receiver, :func:`received_bursts` draws them over trials.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.fields import finite, positive_finite
from scenarios.simulate import SeedLike, noise_free
from scenarios.types import MeasurementSet, NoiseSigmas, Scenario

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complexfloating]

WAVEFORMS = ("cw", "bpsk")
"""The bursts :class:`BurstPlan` knows: a tone, or a known ±1 chip sequence."""

_WHOLE_TOLERANCE = 1e-9


def _whole_count(value: float, name: str, what: str) -> int:
    """``value`` as a whole number ≥ 2, else one line naming ``name``."""
    count = round(value)
    if count < 2 or abs(value - count) > _WHOLE_TOLERANCE * max(1.0, abs(value)):
        raise ValueError(f"{name}: must give a whole number >= 2 of {what}, got {value:.6g}")
    return count


@dataclass(frozen=True, slots=True, kw_only=True)
class BurstPlan:
    """The bursts and the receiver (MATH §18).

    Parameters
    ----------
    waveform : ``"cw"`` or ``"bpsk"``
        A tone, or a known ±1 chip sequence with rectangular chips.
    burst_s : float
        T, the burst's length; ``burst_s · sample_rate_hz`` samples (a whole number).
    sample_rate_hz : float
        fs, the receiver's complex sample rate.
    cn0_dbhz : float
        C/N0 in dB-Hz: the carrier power over the noise's one-sided density.
    chip_rate_hz : float or None
        The chips per second of ``"bpsk"`` (its main lobe is twice as wide); ``burst_s ·
        chip_rate_hz`` chips and ``sample_rate_hz / chip_rate_hz`` samples per chip, both whole.
        Not used by ``"cw"``.
    chip_seed : int
        The seed of the chip sequence (the same for every burst).
    received_power_w : float
        C, the carrier's power at the receiver (1 by default: only C/N0 matters).
    guard_s : float
        Samples recorded before and after the burst on each side (0 by default); a whole number
        of samples.
    """

    waveform: str
    burst_s: float
    sample_rate_hz: float
    cn0_dbhz: float
    chip_rate_hz: float | None = None
    chip_seed: int = 0
    received_power_w: float = 1.0
    guard_s: float = 0.0
    n_burst_samples: int = field(init=False, repr=False)
    n_guard_samples: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.waveform not in WAVEFORMS:
            raise ValueError(
                f"waveform: expected one of {', '.join(WAVEFORMS)}, got {self.waveform!r}"
            )
        burst = positive_finite(self.burst_s, "burst_s")
        rate = positive_finite(self.sample_rate_hz, "sample_rate_hz")
        object.__setattr__(self, "burst_s", burst)
        object.__setattr__(self, "sample_rate_hz", rate)
        object.__setattr__(self, "cn0_dbhz", finite(self.cn0_dbhz, "cn0_dbhz"))
        power = positive_finite(self.received_power_w, "received_power_w")
        object.__setattr__(self, "received_power_w", power)
        n_burst = _whole_count(burst * rate, "burst_s", "samples at sample_rate_hz")
        object.__setattr__(self, "n_burst_samples", n_burst)
        guard = finite(self.guard_s, "guard_s")
        if guard < 0.0:
            raise ValueError(f"guard_s: must be >= 0, got {guard!r}")
        n_guard = round(guard * rate)
        if abs(guard * rate - n_guard) > _WHOLE_TOLERANCE * max(1.0, guard * rate):
            raise ValueError(f"guard_s: must be a whole number of samples, got {guard * rate:.6g}")
        object.__setattr__(self, "guard_s", guard)
        object.__setattr__(self, "n_guard_samples", n_guard)
        seed = self.chip_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"chip_seed: expected a whole number >= 0, got {seed!r}")
        if self.waveform == "bpsk":
            if self.chip_rate_hz is None:
                raise ValueError("chip_rate_hz: bpsk needs a chip rate (Hz)")
            chips = positive_finite(self.chip_rate_hz, "chip_rate_hz")
            object.__setattr__(self, "chip_rate_hz", chips)
            _whole_count(burst * chips, "chip_rate_hz", "chips in burst_s")
            per_chip = rate / chips
            if per_chip < 1.0 or abs(per_chip - round(per_chip)) > _WHOLE_TOLERANCE * per_chip:
                raise ValueError(
                    f"chip_rate_hz: sample_rate_hz / chip_rate_hz must be a whole number >= 1, "
                    f"got {per_chip:.6g}"
                )

    @property
    def n_samples(self) -> int:
        """Samples per burst's window: the burst and its two guards."""
        return self.n_burst_samples + 2 * self.n_guard_samples

    @property
    def noise_density_w_per_hz(self) -> float:
        """N0 = C / 10^(C/N0 / 10)."""
        return self.received_power_w / 10.0 ** (self.cn0_dbhz / 10.0)

    @property
    def burst_snr(self) -> float:
        """The burst's SNR, its energy over N0: ``C T / N0`` (MATH §18)."""
        return 10.0 ** (self.cn0_dbhz / 10.0) * self.burst_s


def chip_sequence(plan: BurstPlan) -> FloatArray:
    """The burst's ±1 chips (MATH §18): ``burst_s · chip_rate_hz`` of them from ``chip_seed``;
    one chip of +1 for a tone."""
    if plan.waveform == "cw":
        return np.ones(1)
    n_chips = round(plan.burst_s * plan.chip_rate_hz)
    bits = np.random.default_rng(plan.chip_seed).integers(0, 2, n_chips)
    return 1.0 - 2.0 * bits


def burst_envelope(plan: BurstPlan, offset_s: FloatArray) -> FloatArray:
    """``s(x)``, the burst at ``offset_s`` from its centre (MATH §18): the chip holding ``x``
    over ``[−T/2, T/2)``, zero outside."""
    chips = chip_sequence(plan)
    position = (np.asarray(offset_s, dtype=float) + plan.burst_s / 2.0) / plan.burst_s
    index = np.floor(position * len(chips)).astype(np.int64)
    inside = (index >= 0) & (index < len(chips))
    return np.where(inside, chips[np.clip(index, 0, len(chips) - 1)], 0.0)


def window_offsets_s(plan: BurstPlan) -> FloatArray:
    """The receiver's sample times relative to ``t_k``, shape ``(n_samples,)``: symmetric
    about 0, ``1/fs`` apart (half a sample off every chip edge)."""
    return (np.arange(plan.n_samples) - (plan.n_samples - 1) / 2.0) / plan.sample_rate_hz


def _geometry(source: Scenario | MeasurementSet) -> MeasurementSet:
    """The flight and the truth the bursts are drawn from."""
    if isinstance(source, Scenario):
        return noise_free(source)
    if isinstance(source, MeasurementSet):
        if source.truth_emitter_m is None:
            raise ValueError("truth_emitter_m: the bursts need the emitter; give data with truth")
        return source
    raise ValueError(
        f"source: expected a Scenario or a MeasurementSet, got {type(source).__name__}"
    )


def range_change_m(geometry: MeasurementSet, plan: BurstPlan, emitter_m: ArrayLike) -> FloatArray:
    """``ρ(t) − ρ_k`` over every burst's window for an emitter at ``emitter_m`` (MATH §18),
    ``(..., n_bursts, n_samples)`` for hypotheses ``(..., d)``: along the frame's line,
    ``q / (ρ(t) + ρ_k)`` with ``q = Δt (2 wᵀv + Δt ‖v‖²)``, ``w = p_k − s``, computed without
    the cancellation of two ranges of kilometres differing by centimetres."""
    w = model.emitter_offsets_m(geometry.position_m, emitter_m, geometry.emitter_height_m)
    velocity = np.asarray(geometry.velocity_mps, dtype=float)
    rho = np.sqrt(np.einsum("...ki,...ki->...k", w, w))[..., None]
    wv = np.einsum("...ki,ki->...k", w, velocity)[..., None]
    vv = np.einsum("ki,ki->k", velocity, velocity)[:, None]
    dt = window_offsets_s(plan)
    q = dt * (2.0 * wv + dt * vv)
    return q / (np.sqrt(rho * rho + q) + rho)


def burst_phase_rad(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    carrier_offset_hz: ArrayLike = 0.0,
) -> FloatArray:
    """φ(t) ``= −2πγ (ρ(t) − ρ_k) + 2πδ Δt`` over every burst's window (MATH §18),
    ``(..., n_bursts, n_samples)`` for ``emitter_m`` ``(..., d)`` (hypotheses on the leading
    axes; the carrier offset δ, ``carrier_offset_hz``, broadcasts against them)."""
    offset_hz = np.asarray(carrier_offset_hz, dtype=float)[..., None, None]
    change_m = range_change_m(geometry, plan, emitter_m)
    return 2.0 * np.pi * (-geometry.gamma_per_m * change_m + offset_hz * window_offsets_s(plan))


def burst_shift_samples(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    schedule_s: ArrayLike,
    emission_time_s: ArrayLike = 0.0,
) -> FloatArray:
    """``D_k = f_s (τ_k − (t_k − e_k))``, the burst centre's delay past the window's centre in
    samples (MATH §18), ``(..., n_bursts)``: ``τ_k = ρ_k/c + b`` for an emitter at
    ``emitter_m`` ``(..., d)`` with emission time b (``emission_time_s``, broadcasting), e_k the
    schedule ``schedule_s`` ``(n_bursts,)``. Zero at the truth (to rounding)."""
    emission = np.asarray(emission_time_s, dtype=float)[..., None]
    toa = model.toa_s(
        geometry.position_m,
        emitter_m,
        geometry.speed_of_light_mps,
        geometry.emitter_height_m,
        0.0,
    )
    window_s = np.asarray(geometry.time_s, dtype=float) - np.asarray(schedule_s, dtype=float)
    return plan.sample_rate_hz * ((toa - window_s) + emission)


def _delayed_spectrum(plan: BurstPlan, shift_samples: ArrayLike) -> tuple[ComplexArray, FloatArray]:
    """``S_m e^{−j2π f_m D}`` for shifts ``D`` ``(...)``, ``(..., n_samples)``, and the bins'
    ``f_m`` (MATH §18)."""
    burst = np.fft.fft(burst_envelope(plan, window_offsets_s(plan)))
    shift = np.asarray(shift_samples, dtype=float)[..., None]
    frequency = np.fft.fftfreq(plan.n_samples)
    return burst * np.exp(-2j * np.pi * frequency * shift), frequency


def shifted_envelope(plan: BurstPlan, shift_samples: ArrayLike) -> ComplexArray:
    """The sampled burst delayed by ``shift_samples`` ``(...)`` in the frequency domain,
    ``(..., n_samples)`` (MATH §18): ``S_m e^{−j2π f_m D}``, ``f_m`` the bin frequencies of
    ``numpy.fft.fftfreq`` in cycles per sample, as the front end models a delay (§19). A
    band-limited delay modulo the window: valid while the burst stays inside its window
    (``|D|`` within the guard)."""
    return np.fft.ifft(_delayed_spectrum(plan, shift_samples)[0], axis=-1)


def shifted_envelope_derivatives(
    plan: BurstPlan, shift_samples: ArrayLike, order: int = 2
) -> ComplexArray:
    """:func:`shifted_envelope` and its derivatives in the shift up to ``order`` (1 or 2),
    ``s̃(n − D)``, ``∂s̃/∂D`` (and ``∂²s̃/∂D²``), stacked on a leading axis, ``(order + 1, ...,
    n_samples)`` (MATH §18, §21, §22): the delayed spectrum times ``(−j2π f_m)`` to the power
    0, 1, 2, inverse transformed (the first the same numbers as :func:`shifted_envelope`)."""
    delayed, frequency = _delayed_spectrum(plan, shift_samples)
    factor = -2j * np.pi * frequency
    spectra = [delayed, factor * delayed, factor * factor * delayed][: order + 1]
    return np.fft.ifft(np.stack(spectra), axis=-1)


def burst_model_factors(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    schedule_s: ArrayLike,
    *,
    carrier_offset_hz: ArrayLike = 0.0,
    emission_time_s: ArrayLike = 0.0,
) -> tuple[ComplexArray, FloatArray]:
    """The two factors of :func:`burst_model`: the carrier ``e^{jφ(t)}`` ``(..., n_bursts,
    n_samples)`` and the shifts ``D_k`` ``(..., n_bursts)`` at which the envelope is delayed
    (MATH §18); the model is the carrier times :func:`shifted_envelope` at the shifts."""
    phase = burst_phase_rad(geometry, plan, emitter_m, carrier_offset_hz)
    shift = burst_shift_samples(geometry, plan, emitter_m, schedule_s, emission_time_s)
    return np.exp(1j * phase), shift


def burst_model(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    schedule_s: ArrayLike,
    *,
    carrier_offset_hz: ArrayLike = 0.0,
    emission_time_s: ArrayLike = 0.0,
) -> ComplexArray:
    """The noise-free bursts of unit amplitude and zero carrier phase for an emitter at
    ``emitter_m`` (MATH §18), ``(..., n_bursts, n_samples)`` for hypotheses ``(..., d)``:
    ``e^{jφ(t)} s̃(n − D_k)``, :func:`burst_phase_rad` and :func:`shifted_envelope` at
    :func:`burst_shift_samples`. The one model of the samples: the simulator draws around it
    at the truth, and an estimator from the samples evaluates it at its hypotheses.

    ``geometry`` is the flight (positions, velocities, times at the bursts' centres, γ, c, the
    emitter's height when not a coordinate), ``schedule_s`` the bursts' nominal emission
    times e_k; ``carrier_offset_hz`` δ and ``emission_time_s`` b broadcast against the
    hypotheses. The envelope is delayed by the burst centre's delay throughout the burst: its
    change within the burst, ``|v| T / 2c`` (10⁻⁴ samples), is neglected; the phase keeps it.
    """
    carrier, shift = burst_model_factors(
        geometry,
        plan,
        emitter_m,
        schedule_s,
        carrier_offset_hz=carrier_offset_hz,
        emission_time_s=emission_time_s,
    )
    return carrier * shifted_envelope(plan, shift)


@dataclass(frozen=True, slots=True)
class BurstTruth:
    """The noise-free quantities of every burst (MATH §18), each ``(n_bursts, n_samples)``
    unless stated: ``time_s`` the receiver's sample times, ``phase_rad`` φ(t) (without the
    random θ), ``delay_s`` τ(t), ``envelope`` the delayed burst ``s̃(n − D_k)`` of
    :func:`burst_model` (``D_k`` zero to rounding), and per burst ``doppler_hz`` and ``toa_s``
    (``f_k``, ``τ_k`` of MATH §1, §15) and ``emission_time_s = t_k − τ_k``, the schedule."""

    time_s: FloatArray
    phase_rad: FloatArray
    delay_s: FloatArray
    envelope: ComplexArray
    doppler_hz: FloatArray
    toa_s: FloatArray
    emission_time_s: FloatArray


def burst_truth(source: Scenario | MeasurementSet, plan: BurstPlan) -> BurstTruth:
    """The bursts without noise or carrier phase (MATH §18), vectorised over bursts."""
    data = _geometry(source)
    emitter = np.asarray(data.truth_emitter_m, dtype=float)
    offset_hz = data.truth_carrier_offset_hz or 0.0
    emission_s = data.truth_emission_time_s or 0.0
    position, velocity = data.position_m, data.velocity_mps
    doppler = model.doppler_hz(
        position, velocity, emitter, data.gamma_per_m, data.emitter_height_m, offset_hz
    )
    toa = model.toa_s(position, emitter, data.speed_of_light_mps, data.emitter_height_m, emission_s)
    widest = float(np.max(np.abs(doppler)))
    if widest >= plan.sample_rate_hz / 2.0:
        raise ValueError(
            f"sample_rate_hz: the Doppler reaches {widest:.6g} Hz, beyond the receiver's "
            f"{plan.sample_rate_hz / 2.0:.6g} Hz; raise sample_rate_hz"
        )
    time_s = np.asarray(data.time_s, dtype=float)
    schedule = time_s - toa
    change_m = range_change_m(data, plan, emitter)
    dt = window_offsets_s(plan)
    shift = burst_shift_samples(data, plan, emitter, schedule, emission_s)
    return BurstTruth(
        time_s=time_s[:, None] + dt,
        phase_rad=2.0 * np.pi * (-data.gamma_per_m * change_m + offset_hz * dt),
        delay_s=toa[:, None] + change_m / data.speed_of_light_mps,
        envelope=shifted_envelope(plan, shift),
        doppler_hz=doppler,
        toa_s=toa,
        emission_time_s=schedule,
    )


@dataclass(frozen=True, slots=True)
class ReceivedBursts:
    """What the receiver records (MATH §18): ``samples`` ``(n_trials, n_bursts, n_samples)``,
    the sample times ``time_s`` ``(n_bursts, n_samples)``, the nominal emission times of the
    bursts' centres ``emission_time_s`` ``(n_bursts,)`` (the schedule a cooperative receiver
    knows), the drawn ``carrier_phase_rad`` θ ``(n_trials, n_bursts)`` and the noise density."""

    samples: ComplexArray
    time_s: FloatArray
    emission_time_s: FloatArray
    carrier_phase_rad: FloatArray
    noise_density_w_per_hz: float


def received_bursts(
    source: Scenario | MeasurementSet,
    plan: BurstPlan,
    seeds: Sequence[SeedLike],
    *,
    noise: bool = True,
    dtype: type = np.complex128,
) -> ReceivedBursts:
    """The received bursts of ``len(seeds)`` trials, one seed (SeedSequence child) per trial
    (MATH §18).

    Trial ``i`` draws, from ``numpy.random.default_rng(seeds[i])`` in this order, the carrier
    phases θ of its bursts (uniform on ``[0, 2π)``) and a standard-normal block ``(2,
    n_bursts, n_samples)``, the real and imaginary noise scaled by ``√(N0 fs / 2)``: so a
    trial is the same whatever the number of trials drawn beside it. ``noise=False`` keeps the
    phases and draws no noise. ``dtype``: ``complex128`` or ``complex64``.
    """
    if np.dtype(dtype) not in (np.dtype(np.complex64), np.dtype(np.complex128)):
        raise ValueError(f"dtype: expected complex64 or complex128, got {dtype!r}")
    if len(seeds) == 0:
        raise ValueError("seeds: need at least one trial")
    truth = burst_truth(source, plan)
    clean = math.sqrt(plan.received_power_w) * truth.envelope * np.exp(1j * truth.phase_rad)
    shape = clean.shape
    sigma = math.sqrt(plan.noise_density_w_per_hz * plan.sample_rate_hz / 2.0)
    samples = np.empty((len(seeds), *shape), dtype=dtype)
    phases = np.empty((len(seeds), shape[0]))
    for trial, seed in enumerate(seeds):
        rng = np.random.default_rng(seed)
        phases[trial] = rng.uniform(0.0, 2.0 * np.pi, shape[0])
        received = clean * np.exp(1j * phases[trial])[:, None]
        if noise:
            draws = rng.standard_normal((2, *shape))
            received = received + sigma * (draws[0] + 1j * draws[1])
        samples[trial] = received
    return ReceivedBursts(
        samples=samples,
        time_s=truth.time_s,
        emission_time_s=truth.emission_time_s,
        carrier_phase_rad=phases,
        noise_density_w_per_hz=plan.noise_density_w_per_hz,
    )


def rife_boorstyn_variance_hz2(
    burst_snr: ArrayLike, n_samples: int, sample_rate_hz: float
) -> NDArray[np.float64]:
    """The Rife-Boorstyn bound of a tone's frequency over ``n_samples`` samples, amplitude and
    phase unknown (MATH §18, §19), Hz²: ``6 / (SNR · N (N² − 1))`` rad²/sample² at the
    per-sample SNR ``SNR_burst / N``, times ``(f_s / 2π)²``; ``→ 6 / ((2π)² SNR_burst T²)`` for
    large ``N``. Infinite at an SNR of 0."""
    snr_per_sample = np.asarray(burst_snr, dtype=float) / n_samples
    with np.errstate(divide="ignore"):  # a burst of SNR 0 has an infinite variance
        variance_rad2 = 6.0 / (snr_per_sample * n_samples * (n_samples**2 - 1.0))
    return variance_rad2 * (sample_rate_hz / (2.0 * np.pi)) ** 2


def rms_bandwidth_hz(
    waveform: ArrayLike, sample_rate_hz: float, n_samples: int | None = None
) -> float:
    """``B_rms`` of sampled ``waveform`` (zero-padded to ``n_samples``), about its spectral
    centroid, over its DFT (MATH §18): ``√(Σ (f_m − f̄)² |S_m|² / Σ |S_m|²)``. A real envelope
    has its centroid at zero."""
    spectrum = np.abs(np.fft.fft(np.asarray(waveform), n_samples)) ** 2
    frequency = np.fft.fftfreq(len(spectrum))
    weight = spectrum / spectrum.sum()
    centroid = np.sum(weight * frequency)
    return float(np.sqrt(np.sum(weight * (frequency - centroid) ** 2)) * sample_rate_hz)


def delay_crb_s2(burst_snr: ArrayLike, rms_bandwidth: float) -> NDArray[np.float64]:
    """The bound of a known burst's delay, amplitude and carrier phase unknown (MATH §18), s²:
    ``1 / (8π² B_rms² SNR_burst)``. Infinite at an SNR of 0."""
    with np.errstate(divide="ignore"):  # a burst of SNR 0 has an infinite variance
        return 1.0 / (8.0 * np.pi**2 * rms_bandwidth**2 * np.asarray(burst_snr, dtype=float))


def burst_rms_bandwidth_hz(plan: BurstPlan) -> float:
    """``B_rms`` of the plan's burst band-limited to the receiver's band (MATH §18): that of
    its window's samples, guards included (:func:`rms_bandwidth_hz`). The model of the samples
    delays the burst over the whole window (:func:`shifted_envelope`), and the front end models
    it so (§19): with guards the burst's two edges against silence carry delay too (3% more
    ``B_rms²`` for 4 samples a chip)."""
    return rms_bandwidth_hz(burst_envelope(plan, window_offsets_s(plan)), plan.sample_rate_hz)


def frequency_bound_hz2(plan: BurstPlan) -> float:
    """The Rife-Boorstyn bound on a tone's frequency over one of the plan's bursts (MATH §18),
    Hz², at its SNR (:func:`rife_boorstyn_variance_hz2`)."""
    n = plan.n_burst_samples
    return float(rife_boorstyn_variance_hz2(plan.burst_snr, n, plan.sample_rate_hz))


def delay_bound_s2(plan: BurstPlan) -> float:
    """The bound on one of the plan's bursts' delay (MATH §18), s² (:func:`delay_crb_s2`)."""
    return float(delay_crb_s2(plan.burst_snr, burst_rms_bandwidth_hz(plan)))


def noise_at_cn0(plan: BurstPlan) -> NoiseSigmas:
    """The measurement-level σ's at the plan's C/N0 (MATH §18, §20): the square roots of
    :func:`frequency_bound_hz2` and, for ``"bpsk"``, :func:`delay_bound_s2` (a tone carries no
    delay)."""
    delay_s = math.sqrt(delay_bound_s2(plan)) if plan.waveform == "bpsk" else None
    return NoiseSigmas(doppler_hz=math.sqrt(frequency_bound_hz2(plan)), toa_s=delay_s)
