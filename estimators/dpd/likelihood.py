r"""The likelihood of an emitter position given the received bursts, the bursts' complex
amplitudes profiled out (docs/math.md §22).

Burst ``k``'s samples are ``x_k = b_k u_k(s) + n_k``, ``u_k(s)`` the unit-amplitude model of
:func:`scenarios.signal.burst_model` and ``b_k`` an unknown complex amplitude (the received
amplitude and the carrier phase). Maximising over every ``b_k`` leaves

.. math::

    L(s) = \sum_k \frac{|u_k(s)^H x_k|^2}{\|u_k(s)\|^2},

the energy of the samples the model explains, so that ``−(Σ‖x_k‖² − L(s)) / σ²`` is the
log-likelihood up to a constant (σ² the noise's power per sample) and the maximum-likelihood
position maximises ``L``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.signal import BurstPlan, burst_model
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


def profiled_log_likelihood(
    geometry: MeasurementSet,
    plan: BurstPlan,
    samples: ArrayLike,
    schedule_s: ArrayLike,
    emitter_m: ArrayLike,
) -> FloatArray:
    """``L(s) = Σ_k |u_k(s)ᴴ x_k|² / ‖u_k(s)‖²`` (docs/math.md §22) for hypotheses ``emitter_m``
    ``(..., H, 2)`` and the samples ``(..., n_bursts, n_samples)`` of the same leading shape
    (one trial's samples per row of hypotheses), ``(..., H)``; ``u_k`` is
    :func:`scenarios.signal.burst_model` for a cooperative emitter at the geometry's height, the
    bursts' nominal emission times ``schedule_s``."""
    model = burst_model(geometry, plan, emitter_m, schedule_s)
    x = np.asarray(samples)[..., None, :, :]
    # uᴴx and ‖u‖² in real arithmetic: the same bits for a trial whatever its neighbours
    dot_re = np.sum(model.real * x.real + model.imag * x.imag, axis=-1)
    dot_im = np.sum(model.real * x.imag - model.imag * x.real, axis=-1)
    energy = np.sum(model.real * model.real + model.imag * model.imag, axis=-1)
    return np.sum((dot_re * dot_re + dot_im * dot_im) / energy, axis=-1)
