r"""The ground as a known surface: a prior on the emitter's height (MATH §8, the terrain prior).

An emitter on a hill, a mast or a roof sits on or near ground whose shape is known from a map.
:class:`Terrain` describes that ground as a plane with, optionally, one smooth hill on it,

.. math::

    h(x, y) = h_0 + g_x x + g_y y
              + A \exp\!\Big(-\frac{(x - c_x)^2 + (y - c_y)^2}{2 w^2}\Big),

(``A = 0``: a plane; ``g = 0``: a hill on level ground), and how far above or below it the
emitter may be, ``σ_m`` (a mast, a building, the map's error): the emitter's offset above the
ground, ``z_s − h(x_s, y_s)``, is a priori Gaussian with mean 0 and standard deviation ``σ_m``.
With the emitter's height unknown (MATH §8) that prior is one more whitened row of the model,

.. math::

    e_{\text{terrain}} = \frac{0 - (z_s - h(x_s, y_s))}{\sigma_m},\qquad
    \nabla\big(z_s - h(x_s, y_s)\big) = (-h_x, -h_y, 1),

which the Fisher information (:mod:`scenarios.fisher`) and ``ml`` (whose answer is then the
MAP) add to the measurements' rows; with the height known the terrain is not used.

Pure numpy functions: :func:`surface_height_m`, :func:`surface_gradient` (``(h_x, h_y)``),
:func:`offset_above_surface_m` and :func:`offset_gradient` of points ``(..., 3)``; the class
holds and checks the numbers and calls them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.fields import MAX_COORDINATE_M, bounded, check_magnitude, frozen_array

FloatArray = NDArray[np.float64]

MAX_SLOPE = 100.0
"""Largest ``|g_x|``, ``|g_y|`` (metres per metre): 89.4°, steeper than any ground."""
HILL_WIDTH_RANGE_M = (1.0, MAX_COORDINATE_M)
"""Accepted hill widths ``w``: narrower than a metre is no smooth ground (and ``(x − c)/w²``
would leave the float range at the coordinate limit)."""
SIGMA_RANGE_M = (1e-9, MAX_COORDINATE_M)
"""Accepted ``σ_m``: from a nanometre (the ground exactly) to the coordinate limit."""

_FIX = "give metres in the scenario's local frame (MATH §0)"


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Terrain:
    """The ground ``h(x, y)`` of the module text and the emitter's spread about it.

    Parameters
    ----------
    sigma_m : float
        ``σ_m``, the standard deviation of the emitter's offset above the ground, metres.
    height_m : float
        ``h_0``, the plane's height at the origin.
    slope : (2,)
        ``(g_x, g_y)``, the plane's rise per metre east and north.
    hill_height_m : float
        ``A``, the hill's height above the plane at its centre (0: no hill; negative: a hollow).
    hill_centre_m : (2,)
        ``(c_x, c_y)``.
    hill_width_m : float
        ``w``, the hill's standard width (its slope is steepest ``w`` from the centre).

    Errors name the field as ``terrain.<field>``.
    """

    sigma_m: float
    height_m: float = 0.0
    slope: FloatArray = (0.0, 0.0)  # type: ignore[assignment]
    hill_height_m: float = 0.0
    hill_centre_m: FloatArray = (0.0, 0.0)  # type: ignore[assignment]
    hill_width_m: float = 1.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        low, high = SIGMA_RANGE_M
        set_(self, "sigma_m", bounded(self.sigma_m, "terrain.sigma_m", low, high, "m", _FIX))
        for name in ("height_m", "hill_height_m"):
            limit = MAX_COORDINATE_M
            set_(
                self,
                name,
                bounded(getattr(self, name), f"terrain.{name}", -limit, limit, "m", _FIX),
            )
        slope = frozen_array(self.slope, "terrain.slope", (2,))
        check_magnitude(slope, "terrain.slope", MAX_SLOPE, "m/m", "give the rise per metre")
        set_(self, "slope", slope)
        centre = frozen_array(self.hill_centre_m, "terrain.hill_centre_m", (2,))
        check_magnitude(centre, "terrain.hill_centre_m", MAX_COORDINATE_M, "m", _FIX)
        set_(self, "hill_centre_m", centre)
        width = bounded(self.hill_width_m, "terrain.hill_width_m", *HILL_WIDTH_RANGE_M, "m", _FIX)
        set_(self, "hill_width_m", width)

    def height_at_m(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
        """:func:`surface_height_m` of this terrain."""
        return surface_height_m(self, x_m, y_m)

    def as_dict(self) -> dict[str, Any]:
        """Plain floats and lists, the ``terrain`` object of a measurement file."""
        return {
            "sigma_m": self.sigma_m,
            "height_m": self.height_m,
            "slope": self.slope.tolist(),
            "hill_height_m": self.hill_height_m,
            "hill_centre_m": self.hill_centre_m.tolist(),
            "hill_width_m": self.hill_width_m,
        }


def _hill(terrain: Terrain, x_m: ArrayLike, y_m: ArrayLike) -> tuple[FloatArray, ...]:
    """``A exp(−r²/(2w²))`` and the offsets ``x − c_x``, ``y − c_y`` from the centre."""
    dx = np.asarray(x_m, dtype=float) - terrain.hill_centre_m[0]
    dy = np.asarray(y_m, dtype=float) - terrain.hill_centre_m[1]
    w = terrain.hill_width_m
    with np.errstate(over="ignore"):  # far from the hill the exponent is −inf: no hill
        bump = terrain.hill_height_m * np.exp(-(dx * dx + dy * dy) / (2.0 * w * w))
    return bump, dx, dy


def surface_height_m(terrain: Terrain, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
    """``h(x, y)`` of the module text, broadcast over ``x_m`` and ``y_m``."""
    bump, _, _ = _hill(terrain, x_m, y_m)
    g_x, g_y = terrain.slope
    return terrain.height_m + g_x * np.asarray(x_m, dtype=float) + g_y * np.asarray(y_m) + bump


def surface_gradient(terrain: Terrain, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
    """``(h_x, h_y) = g − A exp(−r²/(2w²)) (x − c)/w²``, shape ``(..., 2)`` (metres per
    metre)."""
    bump, dx, dy = _hill(terrain, x_m, y_m)
    scale = bump / (terrain.hill_width_m * terrain.hill_width_m)
    return np.stack([terrain.slope[0] - scale * dx, terrain.slope[1] - scale * dy], axis=-1)


def offset_above_surface_m(terrain: Terrain, point_m: ArrayLike) -> FloatArray:
    """``z − h(x, y)`` of points ``(..., 3)``: the emitter's offset above the ground, shape
    ``(...)``; the terrain prior says it is ``N(0, σ_m²)`` (module text)."""
    point = np.asarray(point_m, dtype=float)
    return point[..., 2] - surface_height_m(terrain, point[..., 0], point[..., 1])


def offset_gradient(terrain: Terrain, point_m: ArrayLike) -> FloatArray:
    """``∇(z − h(x, y)) = (−h_x, −h_y, 1)`` of points ``(..., 3)``, shape ``(..., 3)``: divided
    by ``σ_m``, the terrain's row of the whitened Jacobian (MATH §8)."""
    point = np.asarray(point_m, dtype=float)
    slope = surface_gradient(terrain, point[..., 0], point[..., 1])
    return np.concatenate([-slope, np.ones((*slope.shape[:-1], 1))], axis=-1)


__all__ = [
    "HILL_WIDTH_RANGE_M",
    "MAX_SLOPE",
    "SIGMA_RANGE_M",
    "Terrain",
    "offset_above_surface_m",
    "offset_gradient",
    "surface_gradient",
    "surface_height_m",
]
