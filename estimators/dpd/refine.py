r"""The local refinement of direct position determination (docs/math.md §22): a trust-region
Newton ascent of a smooth function of a 2-D position, many rows at once.

The derivatives are central differences of the function itself (a step ``h``): the gradient
``(L(s + h e_i) − L(s − h e_i)) / 2h`` and the Hessian from the same four points, the centre
and ``L(s + h e_x + h e_y)``: five new values a stencil. The step is Newton's, ``−H⁻¹g``, where
``H`` is negative definite, else ``−(H − μI)⁻¹g`` with ``μ = λ_max(H) + |g|/r`` (a climb of the
quadratic model at most the trust radius ``r`` long); it is clipped to the trust radius and
taken when ``L`` does not fall (the radius doubles after a clipped step taken, and drops to a
quarter of a step refused). A row converges when a step taken, or the radius, is below ``xtol``.
Each iteration evaluates the stencils of the rows that moved and the trial points of every
active row, in two calls of the function: every row is vectorised with the others.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

Objective = Callable[[NDArray[np.int64], FloatArray], FloatArray]
"""``objective(rows, points)``: the function of row ``rows[i]`` at ``points[i]`` ``(m, H, 2)``,
``(m, H)``."""

STENCIL = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [1.0, 1.0]])
"""The stencil's offsets, in units of the difference step."""


@dataclass(frozen=True, slots=True, eq=False)
class Ascent:
    """Each row's end: ``position_m`` ``(m, 2)``, ``value`` there, the finite-difference
    ``hessian`` ``(m, 2, 2)`` of the last stencil (at the last point or within ``xtol`` of it),
    ``converged`` and the stencils evaluated, ``iterations``."""

    position_m: FloatArray
    value: FloatArray
    hessian: FloatArray
    converged: BoolArray
    iterations: IntArray


def _derivatives(centre: FloatArray, values: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """The gradient ``(m, 2)`` and Hessian ``(m, 2, 2)`` from the centre's value and the five
    of :data:`STENCIL`."""
    xp, xm, yp, ym, xy = values.T
    gradient = np.stack([xp - xm, yp - ym], axis=-1) / (2.0 * h)
    hxx = (xp - 2.0 * centre + xm) / h**2
    hyy = (yp - 2.0 * centre + ym) / h**2
    hxy = (xy - xp - yp + centre) / h**2
    hessian = np.stack([np.stack([hxx, hxy], -1), np.stack([hxy, hyy], -1)], -2)
    return gradient, hessian


def _ascent_step(gradient: FloatArray, hessian: FloatArray, radius: FloatArray) -> FloatArray:
    """The trust-region step: Newton's where the Hessian is negative definite (clipped to
    ``radius``), else ``−(H − μI)⁻¹ g`` with ``μ = λ_max + |g| / radius``, which is at most
    ``radius`` long and climbs the quadratic model."""
    hxx, hxy, hyy = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    det = hxx * hyy - hxy * hxy
    concave = (hxx < 0.0) & (det > 0.0)
    gx, gy = gradient.T
    norm = np.hypot(gx, gy)
    largest = 0.5 * (hxx + hyy) + np.hypot(0.5 * (hxx - hyy), hxy)
    shift = np.where(concave, 0.0, largest + norm / radius)
    axx, ayy = hxx - shift, hyy - shift
    det = axx * ayy - hxy * hxy
    safe = np.where(det > 0.0, det, 1.0)
    step = -np.stack([ayy * gx - hxy * gy, axx * gy - hxy * gx], axis=-1) / safe[:, None]
    step[det <= 0.0] = 0.0
    length = np.hypot(step[:, 0], step[:, 1])
    scale = np.minimum(1.0, radius / np.where(length > 0.0, length, 1.0))
    return step * scale[:, None]


def newton_ascent(
    objective: Objective,
    start_m: FloatArray,
    *,
    difference_m: float,
    radius_m: float,
    xtol_m: float,
    max_iterations: int,
) -> Ascent:
    """Maximise ``objective`` from each row's ``start_m`` ``(m, 2)`` (module text)."""
    m = len(start_m)
    rows = np.arange(m)
    position = np.array(start_m, dtype=float)
    value = objective(rows, position[:, None])[:, 0]
    radius = np.full(m, float(radius_m))
    gradient, hessian = np.zeros((m, 2)), np.full((m, 2, 2), np.nan)
    active = np.isfinite(value)
    stale = active.copy()  # rows whose stencil is to be evaluated at their position
    converged = np.zeros(m, dtype=bool)
    iterations = np.zeros(m, dtype=np.int64)
    for _ in range(max_iterations):
        if not active.any():
            break
        moved = np.flatnonzero(stale & active)
        if len(moved):
            values = objective(moved, position[moved, None] + difference_m * STENCIL)
            gradient[moved], hessian[moved] = _derivatives(value[moved], values, difference_m)
            iterations[moved] += 1
            broken = ~np.isfinite(values).all(axis=1)
            active[moved[broken]] = False
        live = np.flatnonzero(active)
        step = _ascent_step(gradient[live], hessian[live], radius[live])
        trial = objective(live, (position[live] + step)[:, None])[:, 0]
        length = np.hypot(step[:, 0], step[:, 1])
        taken = trial >= value[live]
        clipped = length >= radius[live] * (1.0 - 1e-12)
        position[live[taken]] += step[taken]
        value[live[taken]] = trial[taken]
        radius[live] = np.where(
            taken, np.where(clipped, 2.0 * radius[live], radius[live]), length / 4.0
        )
        stale[live] = taken
        done = (taken & (length <= xtol_m)) | (~taken & (radius[live] <= xtol_m))
        converged[live[done]] = True
        active[live[done]] = False
    return Ascent(
        position_m=position,
        value=value,
        hessian=hessian,
        converged=converged,
        iterations=iterations,
    )
