r"""The Fisher information of the emitter's ``(x_s, y_s)`` and its 2×2 inverse (MATH §8).

With independent Gaussian noise the information is a sum over the samples ``k`` and the
modalities used,

.. math::

    J = \sum_k \Big( \frac{\nabla\tau_k \nabla\tau_k^\top}{\sigma_\tau^2}
        + \frac{\nabla f_k \nabla f_k^\top}{\sigma_f^2}
        + \frac{\nabla P_k \nabla P_k^\top}{\sigma_P^2} \Big)
      = \sum_{\text{rows}} g\,g^\top,\qquad g = \nabla h / \sigma,
    \qquad \mathrm{CRLB} = J^{-1},\qquad \text{RMSE bound} = \sqrt{\operatorname{tr} J^{-1}},

with the gradients of :mod:`scenarios.measurement_model` and the σ's, ``γ``, ``c``, the emitter
height and the RSS model of a :class:`~scenarios.types.MeasurementSet`. It depends only on the
world (geometry and noise), not on measured values, so it lives beside the measurement model
and everything downstream (planners, estimators, comparison) uses this one copy.

Layers, each vectorised: ``position_m`` and ``velocity_mps`` have shape ``(..., N, 3)`` and
``emitter_m`` shape ``(..., 2)``, leading axes broadcasting as in the measurement model (many
emitter positions for a geometry map, many headings for a planner):

- :func:`whitened_gradients`: the rows ``g = ∇h_k/σ``, one block of ``N`` per modality;
- :func:`gram_information`: ``Σ g gᵀ`` of any stack of such rows (the one place the sum is
  formed);
- :func:`per_sample_information`: ``J_k`` of each sample; :func:`information_at_samples`: ``J``
  of given samples; :func:`fisher_information` and :func:`fisher_information_per_frame`: ``J``
  of a measurement set's own samples, all of them or per frame and accumulated;
- :func:`regular_2x2`, :func:`inverse_2x2`, :func:`rmse_bound_m`: the 2×2 algebra of the bound.

Modalities are ``"toa"``, ``"doppler"``, ``"rss"`` or a combination, given as a tuple or as a
string joined by ``+`` (``"toa+doppler"``); see :func:`parse_modalities`.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.types import MODALITIES, MeasurementSet

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

MODALITY_SETS: dict[str, tuple[str, ...]] = {
    "toa": ("toa",),
    "doppler": ("doppler",),
    "rss": ("rss",),
    "toa+doppler": ("toa", "doppler"),
}
"""The modality subsets reported by ``emitterbench crlb``."""

SINGULAR_RTOL = 1e-12
"""A symmetric 2×2 matrix counts as singular when ``det ≤ SINGULAR_RTOL · |J₁₁ J₂₂|``."""

_SIGMA_FIELD = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_db"}


def parse_modalities(modalities: str | Iterable[str]) -> tuple[str, ...]:
    """The modalities as a tuple, in the order given.

    A string is a key of :data:`MODALITY_SETS` or names joined by ``+``; any other iterable
    holds the names. Raises ``ValueError`` for an empty set or a name not in
    :data:`~scenarios.types.MODALITIES`.
    """
    if isinstance(modalities, str):
        modalities = MODALITY_SETS.get(modalities, tuple(modalities.split("+")))
    chosen = tuple(modalities)
    unknown = sorted(set(chosen) - set(MODALITIES))
    if unknown or not chosen:
        raise ValueError(f"modalities: expected a subset of {MODALITIES}, got {chosen!r}")
    return chosen


def _whitened_blocks(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str],
) -> list[FloatArray]:
    """One ``∇h_k/σ`` block of shape ``(..., N, 2)`` per modality, in the order given."""
    emitter = np.asarray(emitter_m, dtype=float)
    blocks = []
    for modality in parse_modalities(modalities):
        sigma = data.noise.for_modality(modality)
        if sigma is None:
            raise ValueError(
                f"noise.{_SIGMA_FIELD[modality]}: needed for the {modality} information but not "
                "given; give the σ or drop the modality"
            )
        if modality == "toa":
            gradient = model.toa_jacobian(
                position_m, emitter, data.speed_of_light_mps, data.emitter_height_m
            )
        elif modality == "doppler":
            gradient = model.doppler_jacobian(
                position_m, velocity_mps, emitter, data.gamma_per_m, data.emitter_height_m
            )
        else:
            if data.rss_model is None:
                raise ValueError("rss_model: needed for the RSS information but not given")
            gradient = model.rss_jacobian(
                position_m, emitter, data.rss_model, data.emitter_height_m
            )
        blocks.append(gradient / sigma)
    return blocks


def whitened_gradients(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
) -> FloatArray:
    """The rows ``g = ∇h_k/σ`` of MATH §8 at the given samples, shape ``(..., M·N, 2)``.

    Parameters
    ----------
    position_m, velocity_mps : (..., N, 3)
        Sample positions and velocities (need not be ``data``'s own: a planned frame works).
    emitter_m : (..., 2)
        Where the gradients are taken; leading axes broadcast with the samples'.
    data : MeasurementSet
        Supplies the constants: the σ's, ``γ``, ``c``, the emitter height, the RSS model. A
        modality absent from its measurements may still be used if its σ is given (the
        information does not need measured values).
    modalities : str or iterable of str
        See :func:`parse_modalities`; the ``M`` blocks of ``N`` rows follow this order.

    Raises ``ValueError`` naming a missing σ or RSS model.
    """
    blocks = _whitened_blocks(position_m, velocity_mps, emitter_m, data, modalities)
    return np.concatenate(blocks, axis=-2)


def gram_information(whitened_rows: ArrayLike) -> FloatArray:
    """``J = Σ_rows g gᵀ`` of whitened gradient rows ``(..., n_rows, 2)``: shape ``(..., 2, 2)``.

    With the rows of :func:`whitened_gradients` this is the information of MATH §8; any other
    stack of rows ``∇h/σ`` of independent Gaussian measurements gives its information too.
    """
    rows = np.asarray(whitened_rows, dtype=float)
    return np.einsum("...ki,...kj->...ij", rows, rows)


def per_sample_information(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
) -> FloatArray:
    """Each sample's term ``J_k = Σ_modalities ∇h_k∇h_kᵀ/σ²`` of MATH §8, shape ``(..., N, 2, 2)``.

    Arguments as for :func:`whitened_gradients`; summed over ``N`` it is
    :func:`information_at_samples`.
    """
    blocks = np.stack(_whitened_blocks(position_m, velocity_mps, emitter_m, data, modalities))
    return np.einsum("m...ki,m...kj->...kij", blocks, blocks)


def information_at_samples(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
) -> FloatArray:
    """``J`` of MATH §8 over the given samples, units 1/m², shape ``(..., 2, 2)``.

    Arguments as for :func:`whitened_gradients`: the samples may be any (a planned frame,
    many headings at once), the constants are ``data``'s.
    """
    return gram_information(
        whitened_gradients(position_m, velocity_mps, emitter_m, data, modalities)
    )


def whitened_jacobian(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str] = "toa+doppler"
) -> FloatArray:
    """Rows ``∇h_k/σ`` of every sample of ``data`` and modality, shape ``(..., n_rows, 2)``.

    :func:`whitened_gradients` at ``data``'s own samples (MATH §8); ``emitter_m`` is
    ``(..., 2)``.
    """
    return whitened_gradients(data.position_m, data.velocity_mps, emitter_m, data, modalities)


def fisher_information(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str] = "toa+doppler"
) -> FloatArray:
    """``J`` of MATH §8 over all samples of ``data``, shape ``(..., 2, 2)`` for ``emitter_m``
    of shape ``(..., 2)`` (many emitter positions in one call: a geometry map)."""
    return gram_information(whitened_jacobian(data, emitter_m, modalities))


def fisher_information_per_frame(
    data: MeasurementSet, emitter_m: ArrayLike, modalities: str | Iterable[str] = "toa+doppler"
) -> tuple[FloatArray, FloatArray]:
    """Information of each frame and accumulated up to each frame (MATH §8).

    Returns ``(per_frame, accumulated)``, each of shape ``(n_frames, ..., 2, 2)`` for
    ``emitter_m`` of shape ``(..., 2)``, frames in the order of ``data.frames``;
    ``per_frame[l]`` is :func:`fisher_information` of frame ``l``'s samples and
    ``accumulated[l]`` the running sum ``Σ_{l' ≤ l} per_frame[l']``.
    """
    rows = whitened_jacobian(data, emitter_m, modalities)
    row_frame = np.tile(data.frame, rows.shape[-2] // len(data.frame))
    per_frame = np.stack(
        [gram_information(rows[..., row_frame == frame, :]) for frame in data.frames]
    )
    return per_frame, np.cumsum(per_frame, axis=0)


def regular_2x2(matrix: ArrayLike) -> BoolArray:
    """Where a symmetric 2×2 matrix ``(..., 2, 2)`` is regular, shape ``(...)``.

    Regular: ``det > SINGULAR_RTOL · |J₁₁ J₂₂|`` (a negative determinant, NaN or ``inf``
    entries count as singular). Reads ``J₁₁``, ``J₁₂`` and ``J₂₂``.
    """
    J = np.asarray(matrix, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    return det > SINGULAR_RTOL * np.maximum(np.abs(a * d), np.finfo(float).tiny)


def inverse_2x2(matrix: ArrayLike) -> FloatArray:
    """The inverse of symmetric 2×2 matrices ``(..., 2, 2)`` (an information or a covariance).

    ``[[d, −b], [−b, a]] / (a d − b²)`` from ``a = J₁₁``, ``b = J₁₂``, ``d = J₂₂``; NaN where
    the matrix is singular (:func:`regular_2x2`). Applied to ``J`` it is the CRLB of MATH §8.
    """
    J = np.asarray(matrix, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = (
            np.stack([np.stack([d, -b], -1), np.stack([-b, a], -1)], -2) / det[..., None, None]
        )
    inverse[~regular_2x2(J)] = np.nan
    return inverse


def rmse_bound_m(information: ArrayLike) -> FloatArray:
    """``√trace(J⁻¹)`` of information ``(..., 2, 2)``: the RMSE bound in metres (MATH §8),
    shape ``(...)``; NaN where ``J`` is singular."""
    covariance = inverse_2x2(information)
    return np.sqrt(covariance[..., 0, 0] + covariance[..., 1, 1])
