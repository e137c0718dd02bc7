r"""The forward model of MATH §1 and its Jacobians in the emitter's ``(x_s, y_s)`` (MATH §8).

.. math::

    \rho_k = \lVert p_k - s \rVert,\qquad u_k = (p_k - s)/\rho_k

    f_k = -\gamma\, v_k^\top u_k + \delta \quad\text{(Doppler, received minus carrier, Hz)}

    \tau_k = \rho_k / c + b \quad\text{(one-way time of arrival, s)}

    P_k = P_0 - 10\,\eta\,\log_{10}(\rho_k / d_0) \quad\text{(received power, dBm)}

with ``s = (x_s, y_s, z_s)`` and ``z_s`` known; the carrier offset δ and the emission time b
are zero for a cooperative emitter and nuisance parameters otherwise (MATH §15). Pure functions, vectorised: ``position_m`` and
``velocity_mps`` have shape ``(..., N, 3)``, ``emitter_m`` has shape ``(..., 2)``; leading axes
broadcast, so one call evaluates many trials, many candidate emitters or many geometries.
Noise-free values come out with shape ``(..., N)``, Jacobians with shape ``(..., N, 2)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.types import RssModel

FloatArray = NDArray[np.float64]

_TEN_OVER_LN10 = 10.0 / np.log(10.0)


def _offset_components(
    position_m: ArrayLike, emitter_m: ArrayLike, emitter_height_m: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The components of ``p_k − s`` and ``ρ_k``, each ``(..., N)`` (``dz`` broadcasts): the
    functions below work on these planes rather than on a trailing axis of three (numpy
    reduces over three entries as slowly as over thousands)."""
    position = np.asarray(position_m, dtype=float)
    emitter = np.asarray(emitter_m, dtype=float)
    dx = position[..., 0] - emitter[..., 0, None]
    dy = position[..., 1] - emitter[..., 1, None]
    dz = position[..., 2] - float(emitter_height_m)
    distance = np.sqrt(dx * dx + dy * dy + dz * dz)
    return dx, dy, dz, distance


def emitter_offsets_m(
    position_m: ArrayLike, emitter_m: ArrayLike, emitter_height_m: float = 0.0
) -> FloatArray:
    """``p_k − s`` in 3-D, shape ``(..., N, 3)`` (MATH §0)."""
    dx, dy, dz, _ = _offset_components(position_m, emitter_m, emitter_height_m)
    return np.stack(np.broadcast_arrays(dx, dy, dz), axis=-1)


def slant_range_m(
    position_m: ArrayLike, emitter_m: ArrayLike, emitter_height_m: float = 0.0
) -> FloatArray:
    """``ρ_k = ‖p_k − s‖`` (MATH §0), shape ``(..., N)``."""
    return _offset_components(position_m, emitter_m, emitter_height_m)[3]


def doppler_hz(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    gamma_per_m: float,
    emitter_height_m: float = 0.0,
    carrier_offset_hz: float = 0.0,
) -> FloatArray:
    """Noise-free Doppler ``f_k = −γ v_kᵀ u_k + δ`` with the physical sign (MATH §1, §15).

    The paper's eq ``fd`` has the opposite sign; convert at the boundary of paper-faithful code.
    ``carrier_offset_hz`` is δ, the emitter's carrier minus the nominal ``f0``.
    """
    offset = emitter_offsets_m(position_m, emitter_m, emitter_height_m)
    distance = np.linalg.norm(offset, axis=-1)
    radial_speed = np.einsum("...i,...i->...", np.asarray(velocity_mps, dtype=float), offset)
    return -gamma_per_m * radial_speed / distance + carrier_offset_hz


def toa_s(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    speed_of_light_mps: float,
    emitter_height_m: float = 0.0,
    emission_time_s: float = 0.0,
) -> FloatArray:
    """Noise-free one-way time of arrival ``τ_k = ρ_k / c + b`` (MATH §1, §15, paper eq
    ``TOA``); ``emission_time_s`` is b, when the emitter sent relative to the receiver's clock."""
    return slant_range_m(position_m, emitter_m, emitter_height_m) / speed_of_light_mps + (
        emission_time_s
    )


def rss_dbm(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    rss_model: RssModel,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """Noise-free received power ``P_k = P0 − 10 η log10(ρ_k / d0)`` (MATH §1)."""
    distance = slant_range_m(position_m, emitter_m, emitter_height_m)
    return rss_model.reference_power_dbm - 10.0 * rss_model.path_loss_exponent * np.log10(
        distance / rss_model.reference_distance_m
    )


def toa_jacobian(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    speed_of_light_mps: float,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂τ_k/∂(x_s, y_s) = −u_k,xy / c`` (MATH §8), shape ``(..., N, 2)``."""
    dx, dy, _, distance = _offset_components(position_m, emitter_m, emitter_height_m)
    return np.stack([-(dx / distance), -(dy / distance)], axis=-1) / speed_of_light_mps


def doppler_jacobian(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    gamma_per_m: float,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂f_k/∂(x_s, y_s) = γ (v_k − (v_kᵀu_k) u_k)_xy / ρ_k`` (MATH §8), shape ``(..., N, 2)``."""
    dx, dy, dz, distance = _offset_components(position_m, emitter_m, emitter_height_m)
    velocity = np.asarray(velocity_mps, dtype=float)
    vx, vy, vz = velocity[..., 0], velocity[..., 1], velocity[..., 2]
    ux, uy, uz = dx / distance, dy / distance, dz / distance
    radial = vx * ux + vy * uy + vz * uz
    scale = gamma_per_m / distance
    return np.stack([(vx - radial * ux) * scale, (vy - radial * uy) * scale], axis=-1)


def rss_jacobian(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    rss_model: RssModel,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂P_k/∂(x_s, y_s) = (10 η / ln 10) u_k,xy / ρ_k`` (MATH §8), shape ``(..., N, 2)``."""
    dx, dy, _, distance = _offset_components(position_m, emitter_m, emitter_height_m)
    slope = _TEN_OVER_LN10 * rss_model.path_loss_exponent / (distance * distance)
    return np.stack([dx * slope, dy * slope], axis=-1)
