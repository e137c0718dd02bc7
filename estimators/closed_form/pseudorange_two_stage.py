r"""The second stage of the two-stage pseudo-range closed form (MATH §15, "The two-stage closed
form").

The relaxed closed form (:mod:`estimators.closed_form.pseudorange_cls`) frees ``w = ρ_jδ`` and
works on rows that carry products of the noise (``η_k²`` in the squared-range differences, the
measured ``f_k`` and ``d_k`` among the regressors). Its estimate ``ŝ₁`` is exact without noise,
and its error is of first order in the noise. The second stage goes back to the measurements
themselves and linearises their model about ``ŝ₁``: with ``Δ = s − ŝ₁``,

- ``f_k = f_k(ŝ₁) + ∇f_k(ŝ₁)ᵀΔ + δ + w_k``,
- ``r_k = ρ_k(ŝ₁) + ∇ρ_k(ŝ₁)ᵀΔ + β + ε_k``,

up to terms of second order in ``Δ``. That is linear in ``(Δ, δ, β)`` with white noise of
known variances. Its weighted least squares is one closed form: δ and β are eliminated by
centring each affected block of whitened residuals ``e`` and gradients ``G`` over its samples
(the profiled likelihood of MATH §15), and ``Δ̂ = (GᵀG)⁻¹Gᵀe``, a 2×2 solve per candidate (3×3
with the emitter's height unknown: ``s = (x, y, z)`` and G gains the height's column). Every
relation the first stage relaxed holds in this model by construction, ``w = ρ_jδ`` among them.
To first order ``ŝ₂ = ŝ₁ + Δ̂`` has the error of the maximum-likelihood estimate, whose
covariance is the CRLB; what remains is of second order in the noise.

A step that raises the profiled cost (the linearisation stretched, at low SNR) is halved
until it does not; one longer than the shortest range to the samples leaves ``ŝ₁``. On one
straight frame the model is symmetric about the track's vertical plane, so the step maps a
mirror pair to a mirror pair (MATH §7): both candidates are corrected; in 3-D a level flight's
model is symmetric about its plane, and the reflection pair maps to a reflection pair alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

HALVINGS = 6
"""How many times a step that raises the profiled cost is halved before ``ŝ₁`` is kept."""


@dataclass(frozen=True, slots=True, eq=False)
class LinearisedCorrection:
    """:func:`linearised_correction` of a stack of candidates ``(..., d)``, d = 2 or 3.

    Attributes
    ----------
    emitter_m : (..., d)
        ``ŝ₂``, or ``ŝ₁`` where the step was not accepted; NaN where ``ŝ₁`` is.
    cost : (...,)
        The profiled cost ``‖e‖²`` (whitened, nuisance blocks centred) at ``emitter_m``.
    accepted : (...,)
        The step lowered the cost (or kept it).
    """

    emitter_m: FloatArray
    cost: FloatArray
    accepted: BoolArray


def profiled_residuals(
    geometry: MeasurementSet,
    range_m: ArrayLike,
    doppler_hz: ArrayLike | None,
    emitter_m: ArrayLike,
    *,
    carrier_offset_unknown: bool,
    gradients: bool,
) -> tuple[FloatArray, FloatArray | None]:
    """Whitened residuals ``e`` (..., M) at ``emitter_m`` (..., d), measured minus predicted
    over σ, the ToA block (pseudo-ranges) centred, the Doppler block centred when the carrier
    offset is unknown (MATH §15); with ``gradients`` also ``G = ∂h/∂s / σ`` (..., M, d),
    centred alike, so that ``e(ŝ + Δ) ≈ e(ŝ) − GΔ``. ``d = 3``: the emitter's height is the
    third coordinate (unknown), else ``geometry.emitter_height_m``.

    ``range_m`` and ``doppler_hz`` are the pseudo-ranges ``cτ_k`` and the Doppler (or None)
    on the samples of ``geometry``, shaped like ``emitter_m``'s leading axes (or broadcasting
    against them) with the samples last. The Doppler block comes first, then the ToA block.
    """
    emitter = np.asarray(emitter_m, dtype=float)
    dimension = emitter.shape[-1]
    position, velocity = geometry.position_m, geometry.velocity_mps
    height = emitter[..., 2, None] if dimension == 3 else geometry.emitter_height_m
    doppler, ranges = model.derivatives_of_offsets(  # the noise-free model (MATH §1)
        position[:, 0] - emitter[..., 0, None],
        position[:, 1] - emitter[..., 1, None],
        position[:, 2] - height,
        (velocity[:, 0], velocity[:, 1], velocity[:, 2]),
        geometry.gamma_per_m,
        order=1 if gradients else 0,
        values=doppler_hz is not None,
        dimension=dimension,
    )
    sigma_r = geometry.noise.toa_s * geometry.speed_of_light_mps
    gradient = slice(1, 1 + dimension)
    blocks = [((np.asarray(range_m) - ranges[0]) / sigma_r, True)]
    slopes = [(ranges[gradient] / sigma_r, True)] if gradients else []
    if doppler_hz is not None:
        sigma_f = geometry.noise.doppler_hz
        blocks.insert(0, ((np.asarray(doppler_hz) - doppler[0]) / sigma_f, carrier_offset_unknown))
        if gradients:
            slopes.insert(0, (doppler[gradient] / sigma_f, carrier_offset_unknown))
    residual = np.concatenate([_centred(block, centre) for block, centre in blocks], axis=-1)
    if not gradients:
        return residual, None
    G = np.concatenate([_centred(block, centre) for block, centre in slopes], axis=-1)
    return residual, np.moveaxis(G, 0, -1)


def _centred(block: FloatArray, centre: bool) -> FloatArray:
    """``block`` less its mean over the samples (the last axis) when ``centre``."""
    return block - block.mean(axis=-1, keepdims=True) if centre else block


def _solve_normal_3(G: FloatArray, e: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(GᵀG)⁻¹Gᵀe`` and ``det GᵀG`` of a stack ``G`` (t, M, 3), ``e`` (t, M), by the adjugate
    of the 3×3 normal matrix: sums over the samples and products entry by entry, so a
    candidate's step has the same bits in a stack of any size."""
    N = [[np.sum(G[..., i] * G[..., j], axis=-1) for j in range(3)] for i in range(3)]
    r = [np.sum(G[..., i] * e, axis=-1) for i in range(3)]
    adjugate = [
        [
            N[(j + 1) % 3][(i + 1) % 3] * N[(j + 2) % 3][(i + 2) % 3]
            - N[(j + 1) % 3][(i + 2) % 3] * N[(j + 2) % 3][(i + 1) % 3]
            for j in range(3)
        ]
        for i in range(3)
    ]
    determinant = sum(N[0][j] * adjugate[j][0] for j in range(3))
    step = np.stack([sum(adjugate[i][j] * r[j] for j in range(3)) for i in range(3)], axis=-1)
    return step / determinant[..., None], determinant


def linearised_correction(
    geometry: MeasurementSet,
    range_m: ArrayLike,
    doppler_hz: ArrayLike | None,
    emitter_m: ArrayLike,
    *,
    carrier_offset_unknown: bool = True,
) -> LinearisedCorrection:
    """The second stage (module text) from the first stage's candidates ``emitter_m``
    (..., d), world metres, every candidate of every trial at once (d = 3: the height is
    estimated too, a 3×3 step).

    ``range_m`` and ``doppler_hz`` are each trial's pseudo-ranges ``cτ_k`` and Doppler on the
    samples of ``geometry`` (samples last, broadcasting against the candidates' leading axes:
    ``(n, 1, K)`` for ``(n, c, d)`` candidates). The emission time is unknown (the pseudo-range
    form); the carrier offset too when ``carrier_offset_unknown``.

    The step ``Δ̂`` is taken whole if it lowers the profiled cost, else halved up to
    :data:`HALVINGS` times until it does; a singular ``GᵀG`` or a step longer than the
    shortest range from ``ŝ₁`` to the samples (the linearisation out of its range) leaves
    ``ŝ₁``.
    """
    start = np.asarray(emitter_m, dtype=float)
    shape, dimension = start.shape[:-1], start.shape[-1]
    n_samples = geometry.n_samples
    ranges = np.broadcast_to(range_m, (*shape, n_samples)).reshape(-1, n_samples)
    doppler = None
    if doppler_hz is not None:
        doppler = np.broadcast_to(doppler_hz, (*shape, n_samples)).reshape(-1, n_samples)
    start = start.reshape(-1, dimension)
    options = {"carrier_offset_unknown": carrier_offset_unknown}
    with np.errstate(all="ignore"):  # NaN candidates (none found) stay NaN
        e, G = profiled_residuals(geometry, ranges, doppler, start, gradients=True, **options)
        assert G is not None
        if dimension == 2:
            a = np.sum(G[..., 0] ** 2, axis=-1)  # GᵀG = [[a, b], [b, c]], Gᵀe = (p, q)
            b = np.sum(G[..., 0] * G[..., 1], axis=-1)
            c = np.sum(G[..., 1] ** 2, axis=-1)
            p = np.sum(G[..., 0] * e, axis=-1)
            q = np.sum(G[..., 1] * e, axis=-1)
            determinant = a * c - b * b
            step = np.stack([c * p - b * q, a * q - b * p], axis=-1) / determinant[..., None]
        else:
            step, determinant = _solve_normal_3(G, e)
        nearest = np.min(
            model.slant_range_m(geometry.position_m, start, geometry.emitter_height_m), axis=-1
        )
        cost = np.sum(e**2, axis=-1)
        emitter = start.copy()
        accepted = np.zeros(len(start), dtype=bool)
        trying = np.flatnonzero((determinant > 0.0) & (np.sqrt(np.sum(step**2, -1)) <= nearest))
        for halving in range(HALVINGS + 1):
            moved = start[trying] + step[trying] * 0.5**halving
            after, _ = profiled_residuals(
                geometry,
                ranges[trying],
                None if doppler is None else doppler[trying],
                moved,
                gradients=False,
                **options,
            )
            cost_after = np.sum(after**2, axis=-1)
            lower = cost_after <= cost[trying]
            done = trying[lower]
            emitter[done], cost[done], accepted[done] = moved[lower], cost_after[lower], True
            trying = trying[~lower]
            if trying.size == 0:
                break
    return LinearisedCorrection(
        emitter_m=emitter.reshape(*shape, dimension),
        cost=cost.reshape(shape),
        accepted=accepted.reshape(shape),
    )


__all__ = ["HALVINGS", "LinearisedCorrection", "linearised_correction", "profiled_residuals"]
