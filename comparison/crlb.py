r"""Fisher information and the Cramér-Rao lower bound for the emitter's ``(x_s, y_s)`` (MATH §8).

.. math::

    J = \sum_k \Big( \frac{\nabla\tau_k \nabla\tau_k^\top}{\sigma_\tau^2}
        + \frac{\nabla f_k \nabla f_k^\top}{\sigma_f^2}
        + \frac{\nabla P_k \nabla P_k^\top}{\sigma_P^2} \Big),
    \qquad \mathrm{CRLB} = J^{-1},\qquad \text{RMSE bound} = \sqrt{\operatorname{tr} J^{-1}}

over the samples and the modalities used, with the gradients of
:mod:`scenarios.measurement_model`. Vectorised: ``emitter_m`` of shape ``(..., 2)`` evaluates
many emitter positions (a geometry map) in one call; per-frame and accumulated information
come from :func:`fisher_information_per_frame`.

Doppler alone gives a nonsingular ``J``: the paper's claim that one UAV cannot localise from
Doppler alone is false (MATH §8).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.types import MODALITIES, MeasurementSet

FloatArray = NDArray[np.float64]

MODALITY_SETS: dict[str, tuple[str, ...]] = {
    "toa": ("toa",),
    "doppler": ("doppler",),
    "rss": ("rss",),
    "toa+doppler": ("toa", "doppler"),
}
"""The modality subsets reported by ``emitterbench crlb``."""


def _modalities(modalities: str | Iterable[str]) -> tuple[str, ...]:
    if isinstance(modalities, str):
        modalities = MODALITY_SETS.get(modalities, tuple(modalities.split("+")))
    chosen = tuple(modalities)
    unknown = sorted(set(chosen) - set(MODALITIES))
    if unknown or not chosen:
        raise ValueError(f"modalities: expected a subset of {MODALITIES}, got {chosen!r}")
    return chosen


def whitened_jacobian(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str]
) -> FloatArray:
    """Rows ``∇h_k / σ`` of every sample and modality, shape ``(..., n_rows, 2)`` (MATH §8).

    The σ's and the RSS model come from ``data``; a modality absent from the data may still be
    used here if its σ is known (the bound does not need the measured values).
    """
    emitter = np.asarray(emitter_m, dtype=float)
    blocks = []
    for modality in _modalities(modalities):
        sigma = data.noise.for_modality(modality)
        if sigma is None:
            field = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_db"}[modality]
            raise ValueError(f"noise.{field}: needed for the {modality} bound but not given")
        if modality == "toa":
            gradient = model.toa_jacobian(
                data.position_m, emitter, data.speed_of_light_mps, data.emitter_height_m
            )
        elif modality == "doppler":
            gradient = model.doppler_jacobian(
                data.position_m,
                data.velocity_mps,
                emitter,
                data.gamma_per_m,
                data.emitter_height_m,
            )
        else:
            if data.rss_model is None:
                raise ValueError("rss_model: needed for the RSS bound but not given")
            gradient = model.rss_jacobian(
                data.position_m, emitter, data.rss_model, data.emitter_height_m
            )
        blocks.append(gradient / sigma)
    return np.concatenate(blocks, axis=-2)


def fisher_information(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str] = "toa+doppler"
) -> FloatArray:
    """``J`` of MATH §8 over all samples of ``data``, shape ``(..., 2, 2)``."""
    rows = whitened_jacobian(data, emitter_m, modalities)
    return np.einsum("...ki,...kj->...ij", rows, rows)


def fisher_information_per_frame(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str] = "toa+doppler"
) -> tuple[FloatArray, FloatArray]:
    """Information of each frame and accumulated up to each frame.

    Returns ``(per_frame, accumulated)``, each of shape ``(n_frames, ..., 2, 2)``, frames in the
    order of ``data.frames``.
    """
    per_frame = np.stack(
        [fisher_information(frame, emitter_m, modalities) for frame in data.iter_frames()]
    )
    return per_frame, np.cumsum(per_frame, axis=0)


def crlb_m2(information: ArrayLike) -> FloatArray:
    """``J⁻¹``; NaN where ``J`` is singular (an unobservable geometry), shape ``(..., 2, 2)``."""
    J = np.asarray(information, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    scale = np.maximum(np.abs(a * d), np.finfo(float).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = (
            np.stack([np.stack([d, -b], -1), np.stack([-b, a], -1)], -2) / det[..., None, None]
        )
    singular = ~(det > 1e-12 * scale)
    inverse[singular] = np.nan
    return inverse


def rmse_bound_m(information: ArrayLike) -> FloatArray:
    """``√trace(J⁻¹)``: the RMSE bound in metres (MATH §8); NaN where ``J`` is singular."""
    covariance = crlb_m2(information)
    return np.sqrt(covariance[..., 0, 0] + covariance[..., 1, 1])
