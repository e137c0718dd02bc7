r"""The forward model of MATH §1 and its derivatives in the emitter's ``(x_s, y_s)`` (MATH §8):
the one home of the model the simulation, the bounds, the frame-by-frame filters and the
maximum-likelihood search evaluate.

.. math::

    \rho_k = \lVert p_k - s \rVert,\qquad u_k = (p_k - s)/\rho_k

    f_k = -\gamma\, v_k^\top u_k + \delta \quad\text{(Doppler, received minus carrier, Hz)}

    \tau_k = \rho_k / c + b \quad\text{(one-way time of arrival, s)}

    P_k = P_0 - 10\,\eta\,\log_{10}(\rho_k / d_0) \quad\text{(received power, dBm)}

with ``s = (x_s, y_s, z_s)``; the carrier offset δ and the emission time b are zero for a
cooperative emitter and nuisance parameters otherwise (MATH §15); they enter linearly, with
derivative 1 in their own parameter. Pure functions, vectorised: ``position_m`` and
``velocity_mps`` have shape ``(..., N, 3)``, ``emitter_m`` has shape ``(..., d)``: ``d = 2``,
``(x_s, y_s)`` with the height ``z_s = emitter_height_m`` known, or ``d = 3``, ``(x_s, y_s,
z_s)``, the height a coordinate of the position (``emitter_height_m`` is then not read);
leading axes broadcast, so one call evaluates many trials, many candidate emitters or many
geometries. Noise-free values come out with shape ``(..., N)``, Jacobians (in the
position's ``d`` coordinates) with shape ``(..., N, d)``. :func:`doppler_range_derivatives`
gives the Doppler and range with their derivatives in ``(x_s, y_s)`` to third order (the
frame-by-frame filters and the smoother's expansion), :func:`derivatives_of_offsets` the same
on per-sample components in any layout (the maximum-likelihood search) and
:func:`rss_of_ranges` the received power from them.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations_with_replacement
from math import comb

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.types import RssModel

FloatArray = NDArray[np.float64]

_TEN_OVER_LN10 = 10.0 / np.log(10.0)


def _offset_components(
    position_m: ArrayLike, emitter_m: ArrayLike, emitter_height_m: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The components of ``p_k − s`` and ``ρ_k``, each ``(..., N)`` (``dz`` broadcasts): the
    functions below work on these planes rather than on a trailing axis of three (numpy
    reduces over three entries as slowly as over thousands)."""
    position = np.asarray(position_m, dtype=float)
    emitter = np.asarray(emitter_m, dtype=float)
    dx = position[..., 0] - emitter[..., 0, None]
    dy = position[..., 1] - emitter[..., 1, None]
    dz = position[..., 2] - emitter_height(emitter, emitter_height_m)
    distance = np.sqrt(dx * dx + dy * dy + dz * dz)
    return dx, dy, dz, distance


def emitter_height(emitter_m: ArrayLike, emitter_height_m: ArrayLike = 0.0) -> FloatArray:
    """``z_s``, broadcasting against the samples ``(..., N)``: the third coordinate of a 3-D
    ``emitter_m`` (the height a coordinate of the position), else the known
    ``emitter_height_m``."""
    emitter = np.asarray(emitter_m, dtype=float)
    if emitter.shape[-1] == 3:
        return emitter[..., 2, None]
    return np.asarray(emitter_height_m, dtype=float)


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
    return rss_of_ranges(distance[None], rss_model)[0]


def toa_jacobian(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    speed_of_light_mps: float,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂τ_k/∂s = −u_k / c`` in the position's ``d`` coordinates (MATH §8), shape
    ``(..., N, d)``."""
    dx, dy, dz, distance = _offset_components(position_m, emitter_m, emitter_height_m)
    offsets = (dx, dy, dz)[: np.shape(emitter_m)[-1]]
    return np.stack([-(offset / distance) for offset in offsets], axis=-1) / speed_of_light_mps


def doppler_jacobian(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    gamma_per_m: float,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂f_k/∂s = γ (v_k − (v_kᵀu_k) u_k) / ρ_k`` in the position's ``d`` coordinates
    (MATH §8), shape ``(..., N, d)``.

    The height's entry, ``γ (v_z − (vᵀu) u_z)/ρ``, is ``(γ v_z + f u_z)/ρ`` with the Doppler's
    own value ``f = −γ vᵀu`` (:func:`doppler_range_derivatives` gives the plane's)."""
    doppler, ranges = doppler_range_derivatives(
        position_m, velocity_mps, emitter_m, gamma_per_m, emitter_height_m, order=1
    )
    if np.shape(emitter_m)[-1] != 3:
        return doppler[..., 1:]
    distance = ranges[..., 0]
    dz = np.asarray(position_m, dtype=float)[..., 2] - emitter_height(emitter_m)
    vz = np.asarray(velocity_mps, dtype=float)[..., 2]
    height = (gamma_per_m * vz + doppler[..., 0] * dz / distance) / distance
    return np.concatenate([doppler[..., 1:], height[..., None]], axis=-1)


DERIVATIVE_COMPONENTS = ("", "x", "y", "xx", "xy", "yy", "xxx", "xxy", "xyy", "yyy")
"""The last axis of :func:`doppler_range_derivatives`: the value, then the unique partial
derivatives in ``(x_s, y_s)`` of each order (``"xy"`` is ``∂²/∂x_s∂y_s``)."""

N_COMPONENTS_TO_ORDER = (1, 3, 6, 10)
"""How many :data:`DERIVATIVE_COMPONENTS` the derivatives up to order 0, 1, 2 and 3 fill."""


def _first_last(array: FloatArray) -> FloatArray:
    """A view with the first axis last."""
    return array.transpose((*range(1, array.ndim), 0))


def _index_sets(
    dimension: int,
) -> tuple[tuple[FloatArray, ...], tuple[FloatArray, ...], FloatArray]:
    """``(a, b)`` of the unique second derivatives (``xx, xy, yy`` in 2-D; ``xx, xy, xz, yy,
    yz, zz`` in 3-D), ``(a, b, c)`` of the third, and the slot of the pair ``(a, b)`` among the
    second (symmetric): the order of :data:`DERIVATIVE_COMPONENTS` and
    :func:`derivative_components`."""
    pairs = list(combinations_with_replacement(range(dimension), 2))
    triples = list(combinations_with_replacement(range(dimension), 3))
    slot = np.zeros((dimension, dimension), dtype=np.intp)
    for index, (a, b) in enumerate(pairs):
        slot[a, b] = slot[b, a] = index
    return (
        tuple(np.array(column) for column in zip(*pairs, strict=True)),
        tuple(np.array(column) for column in zip(*triples, strict=True)),
        slot,
    )


_INDEX_SETS = {2: _index_sets(2), 3: _index_sets(3)}
""":func:`_index_sets` of the two position dimensions."""


def derivative_components(dimension: int = 2) -> tuple[str, ...]:
    """The last axis of :func:`doppler_range_derivatives` in ``dimension`` coordinates: the
    value, then the unique partial derivatives of each order (:data:`DERIVATIVE_COMPONENTS` in
    2-D; ``"", "x", "y", "z", "xx", "xy", "xz", "yy", …, "zzz"`` in 3-D)."""
    axes = "xyz"[:dimension]
    derivatives = (
        "".join(axes[i] for i in combination)
        for order in (1, 2, 3)
        for combination in combinations_with_replacement(range(dimension), order)
    )
    return ("", *derivatives)


def n_components(order: int, dimension: int = 2) -> int:
    """How many components the derivatives up to ``order`` fill in ``dimension`` coordinates
    (:data:`N_COMPONENTS_TO_ORDER` in 2-D; 1, 4, 10, 20 in 3-D)."""
    return comb(dimension + order, order)


def derivatives_of_offsets(
    offset_x_m: ArrayLike,
    offset_y_m: ArrayLike,
    offset_z_m: ArrayLike,
    velocity_mps: Sequence[ArrayLike],
    gamma_per_m: ArrayLike,
    *,
    order: int = 1,
    values: bool = True,
    dimension: int = 2,
) -> tuple[FloatArray, FloatArray]:
    """:func:`doppler_range_derivatives` from the components of ``w = p_k − s`` and of ``v_k``
    (``velocity_mps``: three arrays), all broadcasting together like ``gamma_per_m``, in any
    layout: for the callers that keep samples in their own (the maximum-likelihood search, rows
    first). Returns ``(doppler, ranges)``, each ``(n, ...)``, components first: component
    ``j`` of :data:`DERIVATIVE_COMPONENTS` is a contiguous array of the broadcast shape.
    ``values=False`` leaves the Doppler's value ``doppler[0]`` uncomputed (a Jacobian alone).
    ``dimension=3``: the derivatives in ``(x_s, y_s, z_s)``, :func:`derivative_components`
    (``offset_z_m`` then holds ``p_z − z_s`` of the unknown height, like the other two)."""
    if order not in (0, 1, 2, 3):
        raise ValueError(f"order: expected 0, 1, 2 or 3, got {order!r}")
    if dimension not in (2, 3):
        raise ValueError(f"dimension: expected 2 or 3, got {dimension!r}")
    dx, dy = np.asarray(offset_x_m, dtype=float), np.asarray(offset_y_m, dtype=float)
    dz, gamma = np.asarray(offset_z_m, dtype=float), np.asarray(gamma_per_m, dtype=float)
    vx, vy, vz = velocity_mps
    width = n_components(order, dimension)
    shape = np.broadcast(dx, dz).shape
    ranges = np.empty((width, *shape))
    distance = np.multiply(dx, dx, out=ranges[0])
    distance += dy * dy
    distance += dz * dz
    np.sqrt(distance, out=distance)
    radial = vx * dx  # vᵀw
    radial += vy * dy
    try:
        radial += vz * dz
    except ValueError:  # the heights or offsets broadcast wider than the plane offsets
        radial = radial + vz * dz
    if gamma.ndim:
        radial = radial + np.zeros_like(gamma)  # γ per sample: the shape of every result
    doppler = np.empty((width, *radial.shape))
    if values:
        value = np.multiply(gamma, radial, out=doppler[0])
        value /= distance
        np.negative(value, out=value)  # f = −γ vᵀw/ρ
    if order < 1:
        return doppler, ranges
    neg_inverse = np.divide(-1.0, distance)  # −1/ρ: multiplications from here on
    offsets, speeds = (dx, dy, dz)[:dimension], (vx, vy, vz)[:dimension]
    gradient = slice(1, 1 + dimension)
    for i, offset in enumerate(offsets):  # ∇ρ = −u
        np.multiply(offset, neg_inverse, out=ranges[1 + i])
    radial *= neg_inverse  # −vᵀu
    # −t = −(v − (vᵀu) u) from −vᵀu and −u, in place in the Doppler's gradient at order 1
    t = np.empty((dimension, *radial.shape)) if order > 1 else doppler[gradient]
    for i, speed in enumerate(speeds):
        np.subtract(np.multiply(radial, ranges[1 + i], out=t[i]), speed, out=t[i])
    scale = np.multiply(neg_inverse, gamma, out=None if gamma.ndim else neg_inverse)  # −γ/ρ
    np.multiply(t, scale, out=doppler[gradient])  # γ t/ρ
    if order < 2:
        return doppler, ranges
    (a, b), triples, slot = _INDEX_SETS[dimension]
    second = slice(1 + dimension, 1 + dimension + len(a))
    u = -ranges[gradient]
    np.negative(t, out=t)
    np.negative(radial, out=radial)  # vᵀu
    p = u[a] * u[b]
    np.negative(p, out=p)
    for i in range(dimension):
        p[slot[i, i]] += 1.0  # P = I − u uᵀ: xx, xy, yy (xx, xy, xz, yy, yz, zz)
    g2 = gamma / distance**2
    np.multiply(g2, t[a] * u[b] + t[b] * u[a] + radial * p, out=doppler[second])
    np.divide(p, distance, out=ranges[second])
    if order < 3:
        return doppler, ranges
    a, b, c = triples
    ab, ac, bc = slot[a, b], slot[a, c], slot[b, c]
    sum_pu = p[ab] * u[c] + p[ac] * u[b] + p[bc] * u[a]
    sum_tuu = t[a] * u[b] * u[c] + t[b] * u[a] * u[c] + t[c] * u[a] * u[b]
    sum_tp = t[a] * p[bc] + t[b] * p[ac] + t[c] * p[ab]
    third = slice(second.stop, None)
    np.multiply(g2 / distance, 2.0 * sum_tuu + 2.0 * radial * sum_pu - sum_tp, out=doppler[third])
    np.divide(sum_pu, distance**2, out=ranges[third])
    return doppler, ranges


def doppler_range_derivatives(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    gamma_per_m: ArrayLike,
    emitter_height_m: ArrayLike = 0.0,
    *,
    order: int = 1,
    dimension: int = 2,
) -> tuple[FloatArray, FloatArray]:
    r"""The noise-free Doppler ``f_k`` (Hz) and slant range ``ρ_k = c τ_k`` (m) with their
    partial derivatives in ``(x_s, y_s)`` up to ``order`` (0 to 3), from one pass over the
    samples (MATH §1, §8).

    Returns ``(doppler, ranges)``, each of shape ``(..., N, n)`` with ``n`` = 1, 3, 6 or 10:
    the components :data:`DERIVATIVE_COMPONENTS` (value, ``∂x, ∂y``, ``∂xx, ∂xy, ∂yy``,
    ``∂xxx, ∂xxy, ∂xyy, ∂yyy``). Without the nuisance terms: a carrier offset δ adds to
    ``f_k`` and a range offset ``c b`` to ``ρ_k``, each with derivative 1 in its own parameter
    and none in the position (MATH §15). ``gamma_per_m`` and ``emitter_height_m`` may be
    arrays broadcasting against ``(..., N)`` (samples of several frames at once). A 3-D
    ``emitter_m`` gives the height; the derivatives are those in ``(x_s, y_s)`` unless
    ``dimension=3``: then in ``(x_s, y_s, z_s)`` (:func:`derivative_components`, ``n`` = 1, 4,
    10 or 20), the formulas below with the indices over three axes.

    With ``w = p_k − s``, ``ρ = ‖w‖``, ``u = w/ρ``, ``r = vᵀu``, ``t = v − r u`` and
    ``P = I − u uᵀ`` (xy parts, or xyz with ``dimension=3``; indices ``a, b, c``):

    .. math::

        \nabla\rho = -u,\quad \nabla^2\rho = \frac{P}{\rho},\quad
        \nabla^3\rho_{abc} = \frac{\sum_3 P_{ab}u_c}{\rho^2},\qquad
        \nabla f = \frac{\gamma\,t}{\rho},\quad
        \nabla^2 f = \frac{\gamma}{\rho^2}\big(t u^\top + u t^\top + r P\big),

        \nabla^3 f_{abc} = \frac{\gamma}{\rho^3}\Big(2\sum_3 t_a u_b u_c
            + 2r\sum_3 P_{ab} u_c - \sum_3 t_a P_{bc}\Big)

    (``Σ₃``: the three distinct placements of the indices). ToA's derivatives are the
    range's divided by ``c``.
    """
    position = np.asarray(position_m, dtype=float)
    emitter = np.asarray(emitter_m, dtype=float)
    velocity = np.asarray(velocity_mps, dtype=float)
    doppler, ranges = derivatives_of_offsets(
        position[..., 0] - emitter[..., 0, None],
        position[..., 1] - emitter[..., 1, None],
        position[..., 2] - emitter_height(emitter, emitter_height_m),
        (velocity[..., 0], velocity[..., 1], velocity[..., 2]),
        gamma_per_m,
        order=order,
        dimension=dimension,
    )
    return _first_last(doppler), _first_last(ranges)


def rss_jacobian(
    position_m: ArrayLike,
    emitter_m: ArrayLike,
    rss_model: RssModel,
    emitter_height_m: float = 0.0,
) -> FloatArray:
    """``∂P_k/∂s = (10 η / ln 10) u_k / ρ_k`` in the position's ``d`` coordinates (MATH §8),
    shape ``(..., N, d)``."""
    dx, dy, dz, distance = _offset_components(position_m, emitter_m, emitter_height_m)
    offsets = (dx, dy, dz)[: np.shape(emitter_m)[-1]]
    ranges = np.stack([distance, *(-(offset / distance) for offset in offsets)])
    return _first_last(rss_of_ranges(ranges, rss_model, len(offsets))[1:])


def rss_of_ranges(ranges: FloatArray, rss_model: RssModel, dimension: int = 2) -> FloatArray:
    """The received power ``P_k = P0 − 10 η log10(ρ_k / d0)`` (MATH §1) and, when ``ranges``
    holds them, its first derivatives ``∇P_k = −(10 η / ln 10) ∇ρ_k / ρ_k`` (MATH §8), from
    the ranges' components first (:func:`derivatives_of_offsets`, or the range and its
    gradient in the position's ``dimension`` coordinates): shape ``(1 or 1 + dimension,
    ...)``."""
    distance = ranges[0]
    out = np.empty((min(len(ranges), 1 + dimension), *distance.shape))
    ten_eta = 10.0 * rss_model.path_loss_exponent
    np.subtract(
        rss_model.reference_power_dbm,
        ten_eta * np.log10(distance / rss_model.reference_distance_m),
        out=out[0],
    )
    if len(out) > 1:
        np.multiply(
            ranges[1 : len(out)],
            -_TEN_OVER_LN10 * rss_model.path_loss_exponent / distance,
            out=out[1:],
        )
    return out
