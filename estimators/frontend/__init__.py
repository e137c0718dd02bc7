"""The per-burst front end: from a burst of complex baseband samples to one measurement and its
variance (docs/math.md §19).

- :func:`tone_frequency`: a tone's frequency (zero-padded FFT peak, Jacobsen's interpolation,
  Newton steps to the periodogram's maximum, the ML), its variance from the Rife-Boorstyn bound
  at the burst's estimated SNR (:class:`ToneFrequency`);
- :func:`burst_delay`: a known burst's delay (upsampled correlation peak, a parabola, Newton
  steps to the maximum of the correlation's magnitude with the fractional delay applied in the
  frequency domain, the ML with the carrier phase unknown), its variance from the delay bound
  at the burst's RMS bandwidth and estimated SNR (:class:`BurstDelay`);
- each flags the bursts below threshold (:func:`below_threshold`), whose estimates are likely
  outliers that their bound does not describe;
- :func:`measure_bursts`: both on one window per burst of a :class:`~scenarios.signal.BurstPlan`,
  the measured Doppler and ToA (:class:`BurstMeasurements`), and :func:`measurement_set`,
  :func:`measurement_batch` the measurement files today's estimators read (docs/math.md §20).

Every function is vectorised over bursts: ``(..., N)`` samples give ``(...)`` results, and a
burst's result does not depend on the others. No estimator of a position lives here.
"""

from estimators.frontend.bounds import (
    FALSE_ALARM_PROBABILITY,
    below_threshold,
    burst_snr,
    delay_crb_s2,
    rife_boorstyn_variance_hz2,
    rms_bandwidth_hz,
)
from estimators.frontend.delay import BurstDelay, burst_delay
from estimators.frontend.frequency import ToneFrequency, tone_frequency
from estimators.frontend.measure import (
    BurstMeasurements,
    measure_bursts,
    measurement_batch,
    measurement_set,
    outlier_rate,
    search_cells_hz,
    track_doppler_search_hz,
)

__all__ = [
    "FALSE_ALARM_PROBABILITY",
    "BurstDelay",
    "BurstMeasurements",
    "ToneFrequency",
    "below_threshold",
    "burst_delay",
    "burst_snr",
    "delay_crb_s2",
    "measure_bursts",
    "measurement_batch",
    "measurement_set",
    "outlier_rate",
    "rife_boorstyn_variance_hz2",
    "rms_bandwidth_hz",
    "search_cells_hz",
    "tone_frequency",
    "track_doppler_search_hz",
]
