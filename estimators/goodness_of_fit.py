r"""Goodness of fit at an estimate: the whitened residual χ² of the data used (MATH §17).

.. math::

    \chi^2 = \sum_{\text{modalities used}} \sum_k
             \Big(\frac{z_k - h_k(\hat s) - \hat\nu}{\sigma}\Big)^2,
    \qquad \text{dof} = n - 2 - n_{\text{nuisance}}

over the samples and modalities the estimator uses (its ``capabilities()``: modalities present
in the data, frames), with the forward model ``h`` of :mod:`scenarios.measurement_model` at the
returned position. Where the data declare a nuisance parameter unknown in a modality used
(MATH §15) its least-squares value at the position, the mean of that block's residual, is
taken out (``ν̂``): the block is centred. Under the model, at the true emitter, χ² is
χ²(n); at a fitted answer approximately χ²(n − p) with ``p = 2 + n_nuisance``.

:func:`fit_chi_square` is the statistic, vectorised over trials; :func:`with_fit` and
:func:`with_fit_columns` put it into an estimate's diagnostics (``fit_chi2``, ``fit_dof``) as
every built-in's public ``estimate`` and ``estimate_columns`` finish; :func:`fit_rejected` is the
test at :data:`FIT_TEST_LEVEL`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from estimators.base import Estimate, capabilities_of
from estimators.batch import BatchEstimates
from scenarios import measurement_model as model
from scenarios.nuisance import nuisance_unknowns, unknowns_used
from scenarios.types import MEASURED_FIELD, MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]

FIT_KEYS: tuple[str, str] = ("fit_chi2", "fit_dof")
"""The diagnostics keys (and trial columns) of the statistic and its degrees of freedom."""

FIT_TEST_LEVEL = 0.01
"""A fit is rejected when χ² exceeds the ``1 − FIT_TEST_LEVEL`` quantile of χ²(dof)."""

CHUNK_ELEMENTS = 1 << 14
"""Trials × samples evaluated at once: the forward model's temporaries stay in cache (a whole
batch at once is about 1.7 times slower per trial)."""


def fit_chi_square(
    position_m: ArrayLike,
    geometry: MeasurementSet,
    measured: Mapping[str, ArrayLike],
) -> tuple[FloatArray, int]:
    """χ² of the measurements at ``position_m`` and its degrees of freedom (MATH §17).

    Parameters
    ----------
    position_m : (..., d)
        The estimated emitter, one per trial (leading axes broadcast): ``(x, y)``, or
        ``(x, y, z)`` with the height unknown (MATH §8).
    geometry : MeasurementSet
        The samples used: positions, velocities, constants, noise σ's and ``unknowns``.
    measured : mapping of "doppler", "toa", "rss" to (..., N)
        The measurements of each modality used (Hz, s, dBm).

    Returns ``(chi2 (...), dof)``; ``dof = n − d − (unknown nuisance parameters of the
    modalities used)``, ``n`` the number of measurements. A non-finite position gives NaN.
    """
    s = np.asarray(position_m, dtype=float)
    g = geometry
    rows = max(1, CHUNK_ELEMENTS // g.n_samples)
    if s.ndim == 2 and len(s) > rows:  # trial by trial chunks that stay in cache
        values = {m: np.asarray(v, dtype=float) for m, v in measured.items()}
        parts = [
            fit_chi_square(
                s[i : i + rows],
                g,
                {m: v[i : i + rows] if v.ndim == 2 else v for m, v in values.items()},
            )
            for i in range(0, len(s), rows)
        ]
        return np.concatenate([part for part, _ in parts]), parts[0][1]
    nuisance = nuisance_unknowns(unknowns_used(g.unknowns, measured))
    total = np.zeros(s.shape[:-1])
    for modality, values in measured.items():
        values = np.asarray(values, dtype=float)
        if modality == "doppler":
            predicted = model.doppler_hz(
                g.position_m, g.velocity_mps, s, g.gamma_per_m, g.emitter_height_m
            )
            centred = "carrier_offset_hz" in nuisance
        elif modality == "toa":
            predicted = model.toa_s(g.position_m, s, g.speed_of_light_mps, g.emitter_height_m)
            centred = "emission_time_s" in nuisance
        else:
            assert g.rss_model is not None  # a MeasurementSet with RSS has its model
            predicted = model.rss_dbm(g.position_m, s, g.rss_model, g.emitter_height_m)
            centred = False
        residual = (values - predicted) / g.noise.for_modality(modality)
        if centred:  # the least-squares offset at this position (MATH §15)
            residual = residual - residual.mean(axis=-1, keepdims=True)
        total = total + np.einsum("...k,...k->...", residual, residual)
    dof = len(measured) * g.n_samples - s.shape[-1] - len(nuisance)
    return total, dof


def fit_rejected(chi2_value: ArrayLike, dof: ArrayLike) -> NDArray[np.bool_]:
    """Whether χ² exceeds the ``1 − FIT_TEST_LEVEL`` quantile of χ²(dof): the data do not fit
    the model at the answer (an outlier, a wrong σ, a wrong constant). False where there is
    nothing to judge (``dof < 1`` or χ² not finite)."""
    value = np.asarray(chi2_value, dtype=float)
    freedom = np.asarray(dof, dtype=float)
    judged = fit_judged(value, freedom)
    # one quantile per distinct dof (a run's rows share a few): cheap for a million rows
    distinct, index = np.unique(np.where(judged, freedom, 1.0), return_inverse=True)
    quantile = chi2_quantile(1.0 - FIT_TEST_LEVEL, distinct)
    limit = quantile[index.reshape(np.shape(judged))]
    return judged & (value > limit)


def chi2_quantile(q: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The ``q`` quantile of χ²(dof), ``2·P⁻¹(dof/2, q)`` with ``P`` the regularised lower
    incomplete gamma function: what ``scipy.stats.chi2.ppf(q, dof)`` computes, to the bit, for
    ``0 < q < 1`` and ``dof > 0`` (NaN where ``dof`` is NaN), without importing
    ``scipy.stats`` (a third of a second of every run's start-up)."""
    return 2.0 * special.gammaincinv(np.asarray(dof, dtype=float) / 2.0, q)


def fit_judged(chi2_value: ArrayLike, dof: ArrayLike) -> NDArray[np.bool_]:
    """The trials :func:`fit_rejected` can judge: χ² finite and at least one degree of freedom."""
    value = np.asarray(chi2_value, dtype=float)
    freedom = np.asarray(dof, dtype=float)
    return np.isfinite(value) & np.isfinite(freedom) & (freedom >= 1)


def fit_p_value(chi2_value: float, dof: int) -> float:
    """``P(χ²(dof) > chi2_value)``, the probability of a fit this bad under the model; NaN where
    there is nothing to judge (:func:`fit_judged`)."""
    if not fit_judged(chi2_value, dof):
        return float("nan")
    return float(special.chdtrc(dof, max(float(chi2_value), 0.0)))


def _used(estimator: Any, geometry: MeasurementSet) -> tuple[NDArray[np.bool_] | None, list[str]]:
    """The samples (a mask, None for every sample) and the modalities the estimator uses on
    these data."""
    capabilities = capabilities_of(estimator)
    modalities = [m for m in MEASURED_FIELD if m in capabilities.modalities & geometry.modalities]
    frames = capabilities.frames
    if frames == "all":
        return None, modalities
    if frames == "last":
        mask = geometry.frame == geometry.frame[-1]
    else:
        mask = np.isin(geometry.frame, np.asarray(frames))
    return (None if mask.all() else mask), modalities


def fit_of(
    estimator: Any, data: MeasurementSet | MeasurementBatch, position_m: ArrayLike
) -> tuple[FloatArray, int]:
    """:func:`fit_chi_square` over what ``estimator`` uses of ``data`` (one trial, or a batch
    with ``position_m`` of shape ``(n_trials, 2)``)."""
    geometry = data.geometry if isinstance(data, MeasurementBatch) else data
    mask, modalities = _used(estimator, geometry)
    if (mask is not None and not mask.any()) or not modalities:
        return np.full(np.shape(position_m)[:-1], np.nan), 0
    if mask is None:
        used = geometry
        # (the layout the mask's copy had: the fit's sums see the same arrays)
        measured = {m: np.ascontiguousarray(getattr(data, MEASURED_FIELD[m])) for m in modalities}
    else:
        used = geometry.take(mask)
        measured = {m: np.asarray(getattr(data, MEASURED_FIELD[m]))[..., mask] for m in modalities}
    return fit_chi_square(position_m, used, measured)


def with_fit(estimator: Any, estimate: Estimate, data: MeasurementSet) -> Estimate:
    """``estimate`` with ``fit_chi2`` and ``fit_dof`` in its diagnostics (a success only)."""
    if not estimate.success:
        return estimate
    value, dof = fit_of(estimator, data, estimate.position_m)
    fit = dict(zip(FIT_KEYS, (float(value), int(dof)), strict=True))
    return replace(estimate, diagnostics={**estimate.diagnostics, **fit})


def with_fit_columns(
    estimator: Any, columns: BatchEstimates, batch: MeasurementBatch
) -> BatchEstimates:
    """``columns`` with the diagnostics columns ``fit_chi2`` and ``fit_dof`` (NaN where a trial
    failed), computed for every trial at once; unchanged when no trial succeeded (the columns
    then hold no diagnostics)."""
    if not np.any(columns.success):
        return columns
    value, dof = fit_of(estimator, batch, columns.position_m)
    fit = {FIT_KEYS[0]: value, FIT_KEYS[1]: np.full(len(columns), dof, dtype=np.int64)}
    return replace(columns, diagnostics={**columns.diagnostics, **fit})


def fit_warning(diagnostics: Mapping[str, Any]) -> str | None:
    """One sentence when the estimate's fit (``fit_chi2`` on ``fit_dof``) is rejected at
    :data:`FIT_TEST_LEVEL`, else None (no fit reported, or one that passes)."""
    value, dof = diagnostics.get(FIT_KEYS[0]), diagnostics.get(FIT_KEYS[1])
    if value is None or dof is None or not fit_rejected(value, dof):
        return None
    p = fit_p_value(value, dof)
    chance = f"p = {p:.2g}" if p >= 1e-6 else "p < 1e-6"
    return (
        f"the data do not fit the model at the answer (χ² = {value:.3g} on {dof} degrees of "
        f"freedom, {chance}; MATH §17): an outlier, a wrong noise σ or a wrong constant?"
    )
