r"""The signal-level bound (MATH §21): the Fisher information of the position in the samples.

Burst ``k``'s samples are ``x_kn = a e^{jθ_k} u_kn(ϑ) + w_kn``, ``u`` the one model of the
bursts (:func:`scenarios.signal.burst_model`, unit amplitude, zero carrier phase), ``a = √C``,
θ_k an unknown phase per burst and ``w ~ CN(0, N0 f_s)``. The parameters ϑ are the position
(``d`` coordinates) and, when unknown, the carrier offset δ and the emission time b. With the
per-burst complex amplitude ``a e^{jθ_k}`` profiled (its Schur complement),

.. math::

    J = \frac{2C}{N_0 f_s} \sum_k \operatorname{Re}\big(D_k^H P_k^\perp D_k\big),
    \qquad P_k^\perp = I - \frac{u_k u_k^H}{u_k^H u_k},

``D_k = ∂u_k/∂ϑ`` (:func:`burst_model_jacobian`), and the bound on the position is the
position's block of ``J⁻¹`` (:func:`signal_crlb_m2`). Above threshold it equals the
measurement-level bound of MATH §8 with the σ's of the burst (MATH §18:
:func:`measurement_crlb_at_plan_m2`). Pure numpy, vectorised over bursts and samples (and, for
the Jacobian, over hypotheses).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.fisher import fisher_information, inverse_symmetric
from scenarios.nuisance import nuisance_unknowns
from scenarios.signal import (
    BurstPlan,
    burst_envelope,
    burst_model_factors,
    burst_truth,
    noise_at_cn0,
    range_change_m,
    shifted_envelope_derivatives,
    window_offsets_s,
)
from scenarios.simulate import noise_free
from scenarios.types import MeasurementSet, Scenario

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complexfloating]


def _envelope_and_slope(plan: BurstPlan, shift_samples: FloatArray) -> tuple[ComplexArray, ...]:
    """``s̃(n − D)`` and ``∂s̃(n − D)/∂D`` for shifts ``D`` ``(...)``, each ``(..., n_samples)``
    (:func:`scenarios.signal.shifted_envelope_derivatives`, MATH §18, §21). A burst constant
    over its window (a tone without guards) has no slope: exactly zero."""
    envelope, slope = shifted_envelope_derivatives(plan, shift_samples, order=1)
    sampled = burst_envelope(plan, window_offsets_s(plan))
    if np.all(sampled == sampled[0]):
        return envelope, np.zeros_like(envelope)
    return envelope, slope


def _model_and_jacobian(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    schedule_s: ArrayLike,
    carrier_offset_hz: ArrayLike,
    emission_time_s: ArrayLike,
    unknowns: Iterable[str],
) -> tuple[ComplexArray, ComplexArray]:
    """``u`` ``(..., n_bursts, n_samples)`` and ``∂u/∂ϑ`` ``(..., n_bursts, n_samples, p)``."""
    emitter = np.asarray(emitter_m, dtype=float)
    d = emitter.shape[-1]
    nuisances = nuisance_unknowns(unknowns)
    carrier, shift = burst_model_factors(
        geometry,
        plan,
        emitter,
        schedule_s,
        carrier_offset_hz=carrier_offset_hz,
        emission_time_s=emission_time_s,
    )
    envelope, slope = _envelope_and_slope(plan, shift)
    burst = carrier * envelope
    moved = carrier * slope  # ∂u/∂D_k
    # ∂φ/∂s = 2πγ (ū(t) − ū_k), ū(t) = w(t)/ρ(t) the unit vector from the emitter, and
    # ū(t) − ū_k = (Δt v − w_k (ρ(t) − ρ_k)/ρ_k)/ρ(t), without cancellation
    w = model.emitter_offsets_m(geometry.position_m, emitter, geometry.emitter_height_m)
    rho = np.sqrt(np.einsum("...ki,...ki->...k", w, w))[..., None]
    change = range_change_m(geometry, plan, emitter)
    dt = window_offsets_s(plan)
    velocity = np.asarray(geometry.velocity_mps, dtype=float)[:, None, :d]
    unit_change = (dt[:, None] * velocity - w[..., None, :d] * (change / rho)[..., None]) / (
        rho + change
    )[..., None]
    phase_gradient = 2.0 * np.pi * geometry.gamma_per_m * unit_change
    shift_gradient = plan.sample_rate_hz * model.toa_jacobian(
        geometry.position_m, emitter, geometry.speed_of_light_mps, geometry.emitter_height_m
    )
    columns = [
        1j * burst[..., None] * phase_gradient + moved[..., None] * shift_gradient[..., None, :]
    ]
    if "carrier_offset_hz" in nuisances:
        columns.append((2j * np.pi * dt * burst)[..., None])
    if "emission_time_s" in nuisances:
        columns.append((plan.sample_rate_hz * moved)[..., None])
    return burst, np.concatenate(columns, axis=-1)


def burst_model_jacobian(
    geometry: MeasurementSet,
    plan: BurstPlan,
    emitter_m: ArrayLike,
    schedule_s: ArrayLike,
    *,
    carrier_offset_hz: ArrayLike = 0.0,
    emission_time_s: ArrayLike = 0.0,
    unknowns: Iterable[str] = (),
) -> ComplexArray:
    """``∂u/∂ϑ`` of :func:`scenarios.signal.burst_model` (MATH §18, §21), analytic, shape
    ``(..., n_bursts, n_samples, p)`` for hypotheses ``emitter_m`` ``(..., d)``.

    The columns: the position's ``d`` coordinates, then, when named in ``unknowns``, the
    carrier offset δ (``"carrier_offset_hz"``, per Hz) and the emission time b
    (``"emission_time_s"``, per s), in that order. With ``u = e^{jφ(t)} s̃(n − D_k)``,
    ``∂u/∂ϑ = j u ∂φ/∂ϑ + e^{jφ} ∂s̃/∂D · ∂D_k/∂ϑ``: the phase's from ``∂ρ(t)/∂s =
    −(p(t) − s)/ρ(t)`` (``∂φ/∂δ = 2πΔt``), the envelope's in the frequency domain (``−j2π f_m``
    times the shifted spectrum) with ``∂D_k/∂s = f_s ∂τ_k/∂s`` and ``∂D_k/∂b = f_s``. The
    other arguments are those of :func:`scenarios.signal.burst_model`.
    """
    return _model_and_jacobian(
        geometry, plan, emitter_m, schedule_s, carrier_offset_hz, emission_time_s, unknowns
    )[1]


def _truth(geometry: MeasurementSet) -> tuple[FloatArray, float, float]:
    if geometry.truth_emitter_m is None:
        raise ValueError("truth_emitter_m: the bound is taken at the truth; give data with truth")
    return (
        np.asarray(geometry.truth_emitter_m, dtype=float),
        geometry.truth_carrier_offset_hz or 0.0,
        geometry.truth_emission_time_s or 0.0,
    )


def signal_fisher_information(
    geometry: MeasurementSet,
    plan: BurstPlan,
    schedule_s: ArrayLike,
    *,
    unknowns: Iterable[str] = (),
) -> FloatArray:
    """``J = (2C/(N0 f_s)) Σ_k Re(D_kᴴ P⊥_k D_k)`` at the truth of ``geometry`` (MATH §21),
    shape ``(p, p)``: the information of the bursts' samples on the position (``d`` coordinates,
    those of ``geometry.truth_emitter_m``) and the nuisances named in ``unknowns`` (δ, b;
    the columns of :func:`burst_model_jacobian`), each burst's complex amplitude (amplitude and
    carrier phase) profiled. ``schedule_s`` is the bursts' nominal emission times e_k
    (:func:`scenarios.signal.burst_truth`'s ``emission_time_s``); C/N0 is the plan's.

    A tone without guards does not depend on b (its envelope is constant): b's row and column
    are then zero, and :func:`signal_crlb_m2` leaves it out, as the measurement level does with
    a Doppler-only bound.
    """
    emitter, offset_hz, emission_s = _truth(geometry)
    burst, jacobian = _model_and_jacobian(
        geometry, plan, emitter, schedule_s, offset_hz, emission_s, unknowns
    )
    energy = np.einsum("kn,kn->k", burst.conj(), burst).real
    projection = np.einsum("kn,knp->kp", burst.conj(), jacobian)  # u_kᴴ D_k
    gram = np.einsum("knp,knq->pq", jacobian.conj(), jacobian).real
    profiled = np.einsum("kp,kq->pq", projection.conj() / energy[:, None], projection).real
    snr_per_sample = 10.0 ** (plan.cn0_dbhz / 10.0) / plan.sample_rate_hz  # C / (N0 f_s)
    information = 2.0 * snr_per_sample * (gram - profiled)
    return 0.5 * (information + information.T)


def position_information(information: ArrayLike, dimension: int) -> FloatArray:
    """The information left on the first ``dimension`` parameters once the others (nuisances)
    are estimated too: the Schur complement ``J_ss − J_sn J_nn⁻¹ J_ns`` (MATH §15, §21), whose
    inverse is the position's block of ``J⁻¹``. A nuisance with no information (a zero
    diagonal: it does not enter the samples) is left out. Formed on the matrix scaled to unit
    diagonal, so that parameters in different units (m, Hz, s) do not spoil the solve; NaN
    where the nuisances' block is singular."""
    J = np.asarray(information, dtype=float)
    diagonal = np.diagonal(J).copy()
    kept = np.concatenate([np.arange(dimension), dimension + np.flatnonzero(diagonal[dimension:])])
    J = J[np.ix_(kept, kept)]
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero diagonal: NaN, singular
        scale = 1.0 / np.sqrt(np.diagonal(J))
        normed = J * scale[:, None] * scale[None, :]
    ss, sn, nn = (
        normed[:dimension, :dimension],
        normed[:dimension, dimension:],
        normed[dimension:, dimension:],
    )
    try:
        complement = ss - sn @ np.linalg.solve(nn, sn.T) if nn.size else ss
    except np.linalg.LinAlgError:  # the nuisances cannot be told apart from each other
        return np.full((dimension, dimension), np.nan)
    complement = 0.5 * (complement + complement.T)
    position_scale = 1.0 / scale[:dimension]
    return complement * position_scale[:, None] * position_scale[None, :]


def signal_crlb_m2(
    geometry: MeasurementSet,
    plan: BurstPlan,
    schedule_s: ArrayLike,
    *,
    unknowns: Iterable[str] = (),
) -> FloatArray:
    """The position's block of the inverse of :func:`signal_fisher_information`, m², shape
    ``(d, d)`` (MATH §21): the signal-level CRLB, amplitude, phase and the named nuisances
    eliminated. NaN where the information is singular."""
    information = signal_fisher_information(geometry, plan, schedule_s, unknowns=unknowns)
    dimension = np.asarray(geometry.truth_emitter_m).shape[-1]
    return inverse_symmetric(position_information(information, dimension))


def _geometry_of(source: Scenario | MeasurementSet) -> MeasurementSet:
    if isinstance(source, Scenario):
        return noise_free(source)
    if isinstance(source, MeasurementSet):
        return source
    raise ValueError(
        f"source: expected a Scenario or a MeasurementSet, got {type(source).__name__}"
    )


def signal_crlb_at_plan_m2(
    source: Scenario | MeasurementSet,
    plan: BurstPlan,
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """The signal-level CRLB of the position, m², ``(d, d)``, for one (scenario, plan) point
    (MATH §21): :func:`signal_crlb_m2` at the truth, the schedule that of
    :func:`scenarios.signal.burst_truth`, ``unknowns`` the data's unless given. ``√trace`` is
    the RMSE bound the comparison draws beside the estimators from IQ."""
    geometry = _geometry_of(source)
    schedule = burst_truth(geometry, plan).emission_time_s
    unknowns = geometry.unknowns if unknowns is None else unknowns
    return signal_crlb_m2(geometry, plan, schedule, unknowns=unknowns)


def measurement_crlb_at_plan_m2(
    source: Scenario | MeasurementSet,
    plan: BurstPlan,
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """The measurement-level CRLB of MATH §8 (and §15), m², ``(d, d)``, with the σ's of
    :func:`scenarios.signal.noise_at_cn0`: what a front end attaining its per-burst bounds gives the two-step
    estimators. Doppler and ToA for ``"bpsk"``, Doppler alone for ``"cw"``. Equal to
    :func:`signal_crlb_at_plan_m2` above threshold, up to what MATH §21 lists."""
    geometry = _geometry_of(source)
    noise = noise_at_cn0(plan)
    modalities = "doppler" if noise.toa_s is None else "toa+doppler"
    # a tone's ToA σ is not used (Doppler alone): the data keep theirs
    sigmas = {"doppler_hz": noise.doppler_hz} | (
        {} if noise.toa_s is None else {"toa_s": noise.toa_s}
    )
    data = replace(geometry, noise=replace(geometry.noise, **sigmas))
    unknowns = geometry.unknowns if unknowns is None else unknowns
    point = np.asarray(geometry.truth_emitter_m, dtype=float)
    return inverse_symmetric(fisher_information(data, point, modalities, unknowns=unknowns))
