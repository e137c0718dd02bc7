"""Bursts per second per core of the per-burst front end (docs/math.md §19) against a plain
numpy transcription of the same steps.

For N = 1,024 samples a burst (``--samples``), on ``--bursts`` bursts (2,000 by default) at a
per-burst SNR of 20 dB, each made here with numpy (a tone at a random frequency; a BPSK burst of
128 chips of 4 samples at a random fractional delay, both with a random carrier phase):

- ``front end``: :func:`estimators.frontend.tone_frequency` and
  :func:`estimators.frontend.burst_delay` on every burst at once;
- ``numpy``: a plain transcription written here, one burst at a time: the same zero-padded FFT
  (or upsampled correlation), the same interpolation, the same three Newton steps on the exact
  periodogram (or correlation), the same SNR and bound, in a Python loop over bursts on the
  first ``min(bursts, 500)`` bursts (its cost per burst does not depend on their number);
- ``measure_bursts``: the whole front end of docs/math.md §20 on BPSK windows of the signal
  model (:func:`scenarios.signal.received_bursts` on ``turn``, ``N`` samples at the same rate,
  4 samples a chip, the same SNR): the delay, the chips removed, the frequency, the delay again
  and the ToA, per burst;
- ``search``: :func:`measure_bursts` on ``beacon-pass``'s bursts as ``simulate-iq`` draws them
  by default (BPSK, 10 ms at 400 kHz, 100 kchip/s, ``N = 4000``, burst SNR 30 dB), without a
  Doppler search and with one of ±1.2 kHz (97 cells, docs/math.md §20), and the ratio of the
  two (``--search-bursts`` bursts, 80 by default);
- ``band``: :func:`tone_frequency` on the same tones with the peak sought within ``±2`` bins
  (``band_hz``, docs/math.md §19) against the whole band, and :func:`measure_bursts` on the
  ``measure`` windows with ``doppler_search_hz`` ``f_s/(8N)`` (one Doppler cell, docs/math.md
  §20: only the frequency's band, ±1.1 bins, differs) against None; each with the ratio of the
  times.

Times are CPU seconds of this process (``time.process_time``, the least of three runs,
:func:`cpu_time.best_cpu_s`) with BLAS held to one thread; printed as bursts per second per
core, with the ratio front end / numpy and the largest difference between the two answers in
units of the bound's σ. The issue's target is at least 1,000 bursts per second per core.

Run: ``python benchmarks/bench_frontend.py [--bursts M] [--samples N]``. Timings depend on the
machine and its load; nothing here is a pass/fail criterion.
"""

from __future__ import annotations

import argparse
import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402
from cpu_time import best_cpu_s  # noqa: E402

from estimators.frontend import burst_delay, measure_bursts, tone_frequency  # noqa: E402
from scenarios import get_scenario  # noqa: E402
from scenarios.signal import BurstPlan, received_bursts  # noqa: E402
from scenarios.simulate import noise_free, trial_seeds  # noqa: E402

SAMPLE_RATE_HZ = 1.0e6
SNR_DB = 20.0
STEPS = 3
PAD = 4


def newton_one(weights, rates, theta, limit):
    """Three Newton steps on |Σ w e^{j u θ}|² for one burst, written plainly."""
    for _ in range(STEPS):
        terms = weights * np.exp(1j * rates * theta)
        a, a1, a2 = terms.sum(), (1j * rates * terms).sum(), (-(rates**2) * terms).sum()
        slope = 2 * (np.conj(a) * a1).real
        curvature = 2 * (abs(a1) ** 2 + (np.conj(a) * a2).real)
        step = -slope / curvature if curvature < 0 else 0.5 * limit * np.sign(slope)
        theta += min(max(step, -limit), limit)
    return theta, (weights * np.exp(1j * rates * theta)).sum()


def snr_one(peak, reference_energy, x):
    total = np.vdot(x, x).real
    fitted = abs(peak) ** 2 / reference_energy
    return fitted / (max(total - fitted, 1e-300) / (x.size - 1))


def numpy_frequency(samples):
    """One burst at a time: frequency (Hz), variance (Hz²)."""
    n = samples.shape[1]
    centred = np.arange(n) - (n - 1) / 2
    out = []
    for x in samples:
        spectrum = np.fft.fft(x, PAD * n)
        k = int(np.argmax(np.abs(spectrum)))
        left, mid, right = spectrum[k - 1], spectrum[k], spectrum[(k + 1) % (PAD * n)]
        delta = float(np.clip(((left - right) / (2 * mid - left - right)).real, -0.5, 0.5))
        grid = 2 * np.pi / (PAD * n)
        omega, peak = newton_one(x, -centred, (k + delta) * grid, grid)
        omega = (omega + np.pi) % (2 * np.pi) - np.pi
        snr = snr_one(peak, n, x) / n
        variance = 6 / (snr * n * (n**2 - 1)) * (SAMPLE_RATE_HZ / (2 * np.pi)) ** 2
        out.append((omega * SAMPLE_RATE_HZ / (2 * np.pi), variance))
    return np.array(out)


def numpy_delay(windows, reference):
    """One window at a time: delay (s), variance (s²)."""
    n = windows.shape[1]
    spectrum_ref = np.fft.fft(reference, n)
    frequency = np.fft.fftfreq(n)
    power = np.abs(spectrum_ref) ** 2
    centroid = np.sum(frequency * power) / power.sum()
    bandwidth2 = np.sum((frequency - centroid) ** 2 * power) / power.sum()
    energy = np.sum(np.abs(reference) ** 2)
    half = (n + 1) // 2
    out = []
    for x in windows:
        cross = np.fft.fft(x) * np.conj(spectrum_ref)
        padded = np.concatenate([cross[:half], np.zeros((PAD - 1) * n), cross[half:]])
        magnitude = np.abs(np.fft.ifft(padded))
        m = int(np.argmax(magnitude))
        left, mid, right = magnitude[m - 1], magnitude[m], magnitude[(m + 1) % (PAD * n)]
        delta = float(np.clip(0.5 * (left - right) / (left - 2 * mid + right), -0.5, 0.5))
        tau, peak = newton_one(cross / n, 2 * np.pi * frequency, (m + delta) / PAD, 1 / PAD)
        snr = snr_one(peak, energy, x)
        variance = 1 / (8 * np.pi**2 * bandwidth2 * snr) / SAMPLE_RATE_HZ**2
        out.append(((tau % n) / SAMPLE_RATE_HZ, variance))
    return np.array(out)


def bursts(count: int, n: int, rng: np.random.Generator):
    sigma = np.sqrt(10 ** (-SNR_DB / 10) / 2)
    noise = sigma * (rng.standard_normal((2, count, n)) + 1j * rng.standard_normal((2, count, n)))
    phase = np.exp(2j * np.pi * rng.random((2, count, 1)))
    frequency_hz = rng.uniform(-0.4, 0.4, count) * SAMPLE_RATE_HZ
    tones = np.exp(2j * np.pi * np.outer(frequency_hz, np.arange(n)) / SAMPLE_RATE_HZ)
    reference = np.repeat(rng.choice([-1.0, 1.0], 128), 4)
    delay = rng.uniform(0.1, 0.4, count) * n
    shift = np.exp(-2j * np.pi * np.outer(delay, np.fft.fftfreq(n)))
    delayed = np.fft.ifft(np.fft.fft(reference, n) * shift, axis=-1)
    tone_samples = tones * phase[0] + noise[0] * np.sqrt(n)
    delay_samples = delayed * phase[1] + noise[1] * np.sqrt(reference.size)
    return tone_samples, delay_samples, reference


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bursts", type=int, default=2000)
    parser.add_argument("--samples", type=int, default=1024)
    parser.add_argument("--search-bursts", type=int, default=80)
    arguments = parser.parse_args()
    count, n = arguments.bursts, arguments.samples
    tone_samples, delay_samples, reference = bursts(count, n, np.random.default_rng(24))
    few = min(count, 500)
    print(f"N = {n} samples a burst, {count} bursts ({few} for numpy), {SNR_DB:g} dB, CPU time")
    print(f"{'':10s} {'front end':>16s} {'numpy':>16s} {'ratio':>7s} {'max |diff|/σ':>13s}")
    for name, vectorised, plain in (
        (
            "frequency",
            lambda: tone_frequency(tone_samples, SAMPLE_RATE_HZ),
            lambda: numpy_frequency(tone_samples[:few]),
        ),
        (
            "delay",
            lambda: burst_delay(delay_samples, reference, SAMPLE_RATE_HZ),
            lambda: numpy_delay(delay_samples[:few], reference),
        ),
    ):
        fast_rate = count / best_cpu_s(vectorised)
        plain_rate = few / best_cpu_s(plain)
        found, transcribed = vectorised(), plain()
        value = found.frequency_hz if name == "frequency" else found.delay_s
        variance = found.variance_hz2 if name == "frequency" else found.variance_s2
        difference = np.max(np.abs(value[:few] - transcribed[:, 0]) / np.sqrt(variance[:few]))
        print(
            f"{name:10s} {fast_rate:10.0f} b/s/c {plain_rate:10.0f} b/s/c "
            f"{fast_rate / plain_rate:7.2f} {difference:13.2e}"
        )

    measure_rate = measure_bursts_rate(count, n)
    print(f"{'measure':10s} {measure_rate:10.0f} b/s/c  (measure_bursts, bpsk: the whole §20)")
    band_hz = 2 * SAMPLE_RATE_HZ / n
    whole_rate = count / best_cpu_s(lambda: tone_frequency(tone_samples, SAMPLE_RATE_HZ))
    band_rate = count / best_cpu_s(
        lambda: tone_frequency(tone_samples, SAMPLE_RATE_HZ, band_hz=band_hz)
    )
    print(
        f"{'band':10s} {band_rate:10.0f} b/s/c against {whole_rate:.0f} for the whole band: "
        f"{whole_rate / band_rate:.2f} times the time (tone_frequency, ±{band_hz:g} Hz)"
    )
    one_cell_hz = SAMPLE_RATE_HZ / (8 * n)
    band_measure = measure_bursts_rate(count, n, one_cell_hz)
    print(
        f"{'':10s} {band_measure:10.0f} b/s/c against {measure_rate:.0f} for the whole band: "
        f"{measure_rate / band_measure:.2f} times the time (measure_bursts, ±{one_cell_hz:g} Hz)"
    )
    without, searched = search_rates(arguments.search_bursts, SEARCH_HZ)
    print(
        f"{'search':10s} {searched:10.1f} b/s/c against {without:.1f} without: "
        f"{without / searched:.1f} times the time (beacon-pass, T = 10 ms, "
        f"±{SEARCH_HZ:g} Hz)"
    )


def measure_bursts_rate(count: int, n: int, doppler_search_hz: float | None = None) -> float:
    """Bursts per second per core of :func:`measure_bursts` on ``count`` BPSK windows of ``n``
    samples received on ``turn`` (whole trials of its 20 bursts), with ``doppler_search_hz``."""
    burst_s = n / SAMPLE_RATE_HZ
    plan = BurstPlan(
        waveform="bpsk",
        burst_s=burst_s,
        sample_rate_hz=SAMPLE_RATE_HZ,
        chip_rate_hz=SAMPLE_RATE_HZ / 4,
        cn0_dbhz=SNR_DB - 10 * np.log10(burst_s),
    )
    geometry = noise_free(get_scenario("turn"))
    received = received_bursts(geometry, plan, trial_seeds(24, -(-count // geometry.n_samples)))
    return bursts_per_cpu_s(received, plan, geometry, doppler_search_hz)


def bursts_per_cpu_s(received, plan: BurstPlan, geometry, doppler_search_hz: float | None) -> float:
    """Bursts per second per core of :func:`measure_bursts` on ``received`` (best of the CPU
    times of :func:`cpu_time.best_cpu_s`)."""

    def run():
        return measure_bursts(
            received.samples,
            plan,
            time_s=geometry.time_s,
            emission_time_s=received.emission_time_s,
            doppler_search_hz=doppler_search_hz,
        )

    return received.samples[..., 0].size / best_cpu_s(run)


SEARCH_HZ = 1200.0


def search_rates(count: int, search_hz: float) -> tuple[float, float]:
    """Bursts per second per core of :func:`measure_bursts` without a Doppler search and with
    one of ``±search_hz``, on ``count`` of beacon-pass's bursts as simulate-iq draws them."""
    plan = BurstPlan(
        waveform="bpsk", burst_s=1e-2, sample_rate_hz=4e5, chip_rate_hz=1e5, cn0_dbhz=50.0
    )
    geometry = noise_free(get_scenario("beacon-pass"))
    trials = -(-count // geometry.n_samples)
    received = received_bursts(geometry, plan, trial_seeds(24, trials))
    without = bursts_per_cpu_s(received, plan, geometry, None)
    return without, bursts_per_cpu_s(received, plan, geometry, search_hz)


if __name__ == "__main__":
    main()
