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

from scenarios import measurement_model
from scenarios.signal import (
    BurstPlan,
    burst_model,
    burst_model_factors,
    range_change_m,
    shifted_envelope_derivatives,
    window_offsets_s,
)
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


def profiled_log_likelihood_derivatives(
    geometry: MeasurementSet,
    plan: BurstPlan,
    samples: ArrayLike,
    schedule_s: ArrayLike,
    emitter_m: ArrayLike,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    r"""``L``, ``∇L`` and ``∇²L`` (docs/math.md §22) at hypotheses ``emitter_m`` ``(..., H, 2)``
    for the samples ``(..., n_bursts, n_samples)``: ``(..., H)``, ``(..., H, 2)`` and
    ``(..., H, 2, 2)``, analytic; ``L`` is :func:`profiled_log_likelihood`'s expression.

    With ``u = e^{jφ} e``, ``e = s̃(n − D_k)`` (:func:`scenarios.signal.burst_model`), ``A_k =
    u_kᴴ x_k`` and ``E_k = ‖u_k‖²`` (the same whatever ``s``: its derivatives vanish),
    ``∂_i L = Σ_k 2 Re(Ā_k ∂_i A_k)/E_k`` and ``∂_ij L = Σ_k 2 Re(∂_j Ā_k ∂_i A_k + Ā_k ∂_ij
    A_k)/E_k``, where, with ``P = ē y``, ``Q = ē' y`` and ``y = e^{−jφ} x``,

    .. math::

        ∂_i A = \sum_n \big(−jφ_i P + D_i Q\big), \quad
        ∂_{ij} A = \sum_n \big((−jφ_{ij} − φ_iφ_j) P − j(φ_i D_j + φ_j D_i) Q
        + D_i D_j \bar e'' y + D_{ij} Q\big),

    ``e', e''`` the envelope's derivatives in the delay
    (:func:`scenarios.signal.shifted_envelope_derivatives`); ``φ_i = 2πγ Δŵ_i``, ``Δŵ = ŵ(t) −
    ŵ_k`` the change of the unit vector ``ŵ = w/ρ`` from the emitter to the UAV (horizontal
    components) and ``φ_ij = −2πγ ((δ_ij − ŵ(t)_i ŵ(t)_j)/ρ(t) − (δ_ij − ŵ_i ŵ_j)/ρ_k)``,
    written without cancellation as ``−2πγ (δ_ij c − ŵ_i ŵ_j c − (ŵ_i Δŵ_j + Δŵ_i ŵ_j + Δŵ_i
    Δŵ_j)/ρ(t))``, ``c = 1/ρ(t) − 1/ρ_k``; ``D_i = −f_s ŵ_i / c_light`` and ``D_ij = f_s (δ_ij −
    ŵ_i ŵ_j) / (c_light ρ_k)``. The sums over the samples are one product with the weights
    ``Δŵ_i``, ``Δŵ_i Δŵ_j``, ``c``, ``Δŵ_i/ρ(t)`` and ``Δŵ_i Δŵ_j/ρ(t)``."""
    emitter = np.asarray(emitter_m, dtype=float)
    x = np.asarray(samples)[..., None, :, :]
    carrier, shift = burst_model_factors(geometry, plan, emitter, schedule_s)
    envelope, slope, curvature = shifted_envelope_derivatives(plan, shift)
    model = carrier * envelope  # burst_model's numbers
    dot_re = np.sum(model.real * x.real + model.imag * x.imag, axis=-1)
    dot_im = np.sum(model.real * x.imag - model.imag * x.real, axis=-1)
    energy = np.sum(model.real * model.real + model.imag * model.imag, axis=-1)
    value = np.sum((dot_re * dot_re + dot_im * dot_im) / energy, axis=-1)
    a = dot_re + 1j * dot_im  # A_k (..., H, K)

    # the phase's derivatives along each window, without cancellation (docs/math.md §21)
    w = measurement_model.emitter_offsets_m(geometry.position_m, emitter, geometry.emitter_height_m)
    rho = np.sqrt(np.einsum("...ki,...ki->...k", w, w))  # (..., H, K)
    change = range_change_m(geometry, plan, emitter)  # ρ(t) − ρ_k (..., H, K, N)
    inverse_range = 1.0 / (rho[..., None] + change)
    relative = change / rho[..., None]
    dt = window_offsets_s(plan)
    velocity = np.asarray(geometry.velocity_mps, dtype=float)
    unit = w[..., :2] / rho[..., None]  # ŵ_k (..., H, K, 2)
    weights = np.empty((*change.shape[:-1], 11, change.shape[-1]))  # (..., H, K, 11, N)
    du = weights[..., 0:2, :]  # Δŵ_i
    for i in (0, 1):
        np.multiply(w[..., i, None], relative, out=du[..., i, :])
        np.subtract(dt * velocity[:, i, None], du[..., i, :], out=du[..., i, :])
        du[..., i, :] *= inverse_range
    np.multiply(du[..., 0, :], du[..., 0, :], out=weights[..., 2, :])
    np.multiply(du[..., 0, :], du[..., 1, :], out=weights[..., 3, :])
    np.multiply(du[..., 1, :], du[..., 1, :], out=weights[..., 4, :])
    np.multiply(relative, inverse_range, out=weights[..., 5, :])
    weights[..., 5, :] *= -1.0  # 1/ρ(t) − 1/ρ_k
    np.multiply(weights[..., :5, :], inverse_range[..., None, :], out=weights[..., 6:, :])
    y = np.conj(carrier) * x
    p = np.conj(model) * x
    q = np.conj(slope) * y
    r = np.sum(np.conj(curvature) * y, axis=-1)
    sums = weights @ p.view(float).reshape(*p.shape, 2)  # (..., H, K, 11, 2): Σ weight · P
    ps = sums[..., 0] + 1j * sums[..., 1]
    sums = du @ q.view(float).reshape(*q.shape, 2)
    qs = sums[..., 0] + 1j * sums[..., 1]  # Σ Δŵ_i Q
    q_0 = np.sum(q, axis=-1)

    k = 2.0 * np.pi * geometry.gamma_per_m
    pairs = ((0, 0), (0, 1), (1, 1))
    p_1 = k * ps[..., :2]  # Σ φ_i P
    p_11 = np.empty((*ps.shape[:-1], 2, 2), dtype=complex)
    p_2 = np.empty_like(p_11)
    for index, (i, j) in enumerate(pairs):
        p_11[..., i, j] = p_11[..., j, i] = k * k * ps[..., 2 + index]
        curve = (
            (i == j) * ps[..., 5]
            - unit[..., i] * unit[..., j] * ps[..., 5]
            - unit[..., i] * ps[..., 6 + j]
            - ps[..., 6 + i] * unit[..., j]
            - ps[..., 8 + index]
        )
        p_2[..., i, j] = p_2[..., j, i] = -k * curve  # Σ φ_ij P
    q_1 = k * qs  # Σ φ_i Q
    rate = plan.sample_rate_hz / geometry.speed_of_light_mps
    d_1 = -rate * unit  # ∂D_k/∂s (..., H, K, 2)
    d_2 = rate * (np.eye(2) - unit[..., :, None] * unit[..., None, :]) / rho[..., None, None]

    da = -1j * p_1 + d_1 * q_0[..., None]  # ∂_i A (..., H, K, 2)
    dda = (
        -1j * p_2
        - p_11
        - 1j * (q_1[..., :, None] * d_1[..., None, :] + d_1[..., :, None] * q_1[..., None, :])
        + d_1[..., :, None] * d_1[..., None, :] * r[..., None, None]
        + d_2 * q_0[..., None, None]
    )  # ∂_ij A
    scale = 2.0 / energy
    gradient = np.sum((np.conj(a)[..., None] * da).real * scale[..., None], axis=-2)
    hessian = np.sum(
        (np.conj(da)[..., None, :] * da[..., :, None] + np.conj(a)[..., None, None] * dda).real
        * scale[..., None, None],
        axis=-3,
    )
    return value, gradient, hessian
