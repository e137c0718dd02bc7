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

Nuisance parameters (MATH §15). With an unknown carrier offset δ every Doppler row gains the
column ``∂f_k/∂δ = 1``, with an unknown emission time b every ToA row the column
``∂τ_k/∂b = 1``. The ``(x_s, y_s)`` block of the inverse of the enlarged information is the
inverse of its Schur complement, and because each nuisance column is constant over one
modality's rows (one σ) and zero elsewhere, that complement is the Gram matrix of the rows with
each affected modality's block *centred* over its samples: ``J = Σ (g − ḡ)(g − ḡ)ᵀ``. So
``unknowns`` centres blocks and everything else is unchanged; accumulated information per frame
centres over the samples up to each frame (it is not a sum of per-frame terms then).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.nuisance import AFFECTED_MODALITY, parse_unknowns
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
    unknowns: Iterable[str] = (),
) -> list[FloatArray]:
    """One ``∇h_k/σ`` block of shape ``(..., N, 2)`` per modality, in the order given; the
    block of a modality with an unknown nuisance parameter centred over its samples (§15)."""
    emitter = np.asarray(emitter_m, dtype=float)
    centred = {AFFECTED_MODALITY[name] for name in parse_unknowns(unknowns)}
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
        if modality in centred:
            gradient = gradient - gradient.mean(axis=-2, keepdims=True)
        blocks.append(gradient / sigma)
    return blocks


def whitened_gradients(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] = (),
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
    unknowns : iterable of str
        Nuisance parameters to eliminate (MATH §15): the affected blocks are centred over these
        samples. Default none: the samples alone, with the emitter's carrier and clock known.

    Raises ``ValueError`` naming a missing σ or RSS model.
    """
    blocks = _whitened_blocks(position_m, velocity_mps, emitter_m, data, modalities, unknowns)
    return np.concatenate(blocks, axis=-2)


def gram_information(whitened_rows: ArrayLike, *, row_axis: int = -2) -> FloatArray:
    """``J = Σ_rows g gᵀ`` of whitened gradient rows ``(..., n_rows, p)``: shape ``(..., p, p)``.

    With the rows of :func:`whitened_gradients` (``p = 2``) this is the information of MATH §8;
    any other stack of rows ``∇h/σ`` of independent Gaussian measurements gives its information
    too (a filter's state of ``p`` entries). ``row_axis`` names the axis of the rows when it is
    not the one before the last (``0``: rows first, ``(n_rows, ..., p)``). The rows are added
    in order, ``s = 0; s += g gᵀ``, so an entry depends on its own stack of rows alone, whatever
    the other stacks, their number or the layout: the batch and one-trial paths of an
    estimator get the same bits.
    """
    rows = np.asarray(whitened_rows, dtype=float)
    axis = row_axis % max(rows.ndim, 1)
    if rows.ndim < 2 or axis == rows.ndim - 1:
        raise ValueError(
            f"whitened_rows: expected rows along axis {row_axis} and the gradient last, got "
            f"shape {rows.shape}"
        )
    p = rows.shape[-1]
    pairs = [(i, j) for i in range(p) for j in range(i, p)]
    products = np.stack([rows[..., i] * rows[..., j] for i, j in pairs], axis=-1)
    if products.shape[axis] == 0:
        sums = np.zeros(products.shape[:axis] + products.shape[axis + 1 :])
    else:  # a reduction over an outer axis of a contiguous array adds row after row
        sums = np.add.reduce(products, axis=axis, initial=0.0)
    information = np.empty((*sums.shape[:-1], p, p))
    for k, (i, j) in enumerate(pairs):
        information[..., i, j] = sums[..., k]
        information[..., j, i] = sums[..., k]
    return information


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
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """Rows ``∇h_k/σ`` of every sample of ``data`` and modality, shape ``(..., n_rows, 2)``.

    :func:`whitened_gradients` at ``data``'s own samples (MATH §8); ``emitter_m`` is
    ``(..., 2)``. ``unknowns`` defaults to ``data.unknowns`` (MATH §15); ``()`` gives the rows
    of a cooperative emitter.
    """
    unknowns = data.unknowns if unknowns is None else unknowns
    return whitened_gradients(
        data.position_m, data.velocity_mps, emitter_m, data, modalities, unknowns=unknowns
    )


def fisher_information(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """``J`` of MATH §8 over all samples of ``data``, shape ``(..., 2, 2)`` for ``emitter_m``
    of shape ``(..., 2)`` (many emitter positions in one call: a geometry map).

    With ``data.unknowns`` (or ``unknowns``) it is the information left for ``(x_s, y_s)`` once
    the nuisance parameters are estimated too, the Schur complement of MATH §15; pass
    ``unknowns=()`` for the bound with them known (the price of an unknown is the ratio).
    """
    return gram_information(whitened_jacobian(data, emitter_m, modalities, unknowns=unknowns))


def fisher_information_per_frame(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Information of each frame and accumulated up to each frame (MATH §8, §15).

    Returns ``(per_frame, accumulated)``, each of shape ``(n_frames, ..., 2, 2)`` for
    ``emitter_m`` of shape ``(..., 2)``, frames in the order of ``data.frames``;
    ``per_frame[l]`` is :func:`fisher_information` of frame ``l``'s samples and
    ``accumulated[l]`` that of the samples of frames ``<= l``: the running sum
    ``Σ_{l' ≤ l} per_frame[l']`` for a cooperative emitter. With nuisance parameters
    (``unknowns``, default ``data.unknowns``) a frame's rows are centred over the samples up to
    it, ``Σ g gᵀ − (Σ g)(Σ g)ᵀ / n`` per affected modality, so the accumulated information is
    formed from running sums rather than added up.
    """
    unknowns = parse_unknowns(data.unknowns if unknowns is None else unknowns)
    chosen = parse_modalities(modalities)
    blocks = _whitened_blocks(data.position_m, data.velocity_mps, emitter_m, data, chosen)
    centred = {AFFECTED_MODALITY[name] for name in unknowns}
    per_frame, accumulated = [], 0.0
    for modality, rows in zip(chosen, blocks, strict=True):
        grams = np.stack([gram_information(rows[..., data.frame == f, :]) for f in data.frames])
        if modality not in centred:
            per_frame.append(grams)
            accumulated = accumulated + np.cumsum(grams, axis=0)
            continue
        sums = np.stack([rows[..., data.frame == f, :].sum(axis=-2) for f in data.frames])
        counts = np.array([np.count_nonzero(data.frame == f) for f in data.frames], dtype=float)
        shape = (-1,) + (1,) * (sums.ndim - 1)
        outer = np.einsum("...i,...j->...ij", sums, sums)
        per_frame.append(grams - outer / counts.reshape(shape)[..., None])
        running = np.cumsum(sums, axis=0)
        accumulated = accumulated + (
            np.cumsum(grams, axis=0)
            - np.einsum("...i,...j->...ij", running, running)
            / np.cumsum(counts).reshape(shape)[..., None]
        )
    return sum(per_frame), accumulated


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
