"""Direct position determination (docs/math.md §22): the emitter's position from the received
bursts' IQ samples in one maximum-likelihood search (A. Amar and A. J. Weiss, IEEE Trans. Signal
Processing 56(11), 2008), the bursts' complex amplitudes profiled out.

- :func:`direct_position`: every trial's estimate as :class:`~estimators.batch.BatchEstimates`
  (coarse grid over a per-burst (frequency, delay) table, Newton ascent of the exact
  likelihood, the mirror rule); :class:`DirectPosition` its thin class (``estimate_iq``,
  ``estimate_iq_batch``);
- :func:`profiled_log_likelihood`: ``L(s)`` from :func:`scenarios.signal.burst_model`;
- :func:`search_grid`: the coarse stage's region and spacing.

It reads samples, not measurement sets: it is registered as ``dpd`` among the estimators of
the samples (:data:`estimators.registry.SAMPLE_LEVEL`), which experiments with a ``[signal]``
table and ``emitterbench estimate`` on a recording run; a measurement set is refused.
"""

from estimators.dpd.coarse import SearchGrid, search_grid
from estimators.dpd.dpd import DirectPosition, check_iq, direct_position
from estimators.dpd.likelihood import profiled_log_likelihood

__all__ = [
    "DirectPosition",
    "SearchGrid",
    "check_iq",
    "direct_position",
    "profiled_log_likelihood",
    "search_grid",
]
