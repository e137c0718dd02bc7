r"""The local refinement of direct position determination (docs/math.md §22): a trust-region
Newton ascent of a smooth function of a 2-D position, many rows at once.

The function gives its value, gradient and Hessian at a point together (for ``L``, analytic:
:func:`estimators.dpd.likelihood.profiled_log_likelihood_derivatives`). The step is Newton's, ``−H⁻¹g``, where
``H`` is negative definite, else ``−(H − μI)⁻¹g`` with ``μ = λ_max(H) + |g|/r`` (a climb of the
quadratic model at most the trust radius ``r`` long); it is clipped to the trust radius and
taken when ``L`` does not fall (the radius doubles after a clipped step taken, and drops to a
quarter of a step refused). A row converges when a step taken, or the radius, is below ``xtol``,
or when its next step is an unclipped Newton step below ``xtol`` (the maximum is then within
``xtol``, and the row stays where it is).
Each iteration evaluates the trial points of every active row, in one call of the function
(its derivatives ready for the next step when taken): every row is vectorised with the
others.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

Objective = Callable[[NDArray[np.int64], FloatArray], tuple[FloatArray, FloatArray, FloatArray]]
"""``objective(rows, points)``: the function of row ``rows[i]`` at ``points[i]`` ``(m, 2)``, its
gradient and its Hessian: ``(m,)``, ``(m, 2)``, ``(m, 2, 2)``."""


@dataclass(frozen=True, slots=True, eq=False)
class Ascent:
    """Each row's end: ``position_m`` ``(m, 2)``, ``value`` and ``hessian`` ``(m, 2, 2)`` there,
    ``converged`` and the function's evaluations, ``iterations``."""

    position_m: FloatArray
    value: FloatArray
    hessian: FloatArray
    converged: BoolArray
    iterations: IntArray


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


ABANDON_GAIN = 4.0
"""A competing row is abandoned when its value plus this many times its quadratic model's rise
is still below its group's best less the margin: the model's rise is the lobe's remaining
height where the Hessian holds, and four times it leaves room for the lobe's departure from
the quadratic."""


def _hopeless(
    value: FloatArray,
    gradient: FloatArray,
    hessian: FloatArray,
    group: IntArray,
    margin: Callable[[IntArray, FloatArray], FloatArray],
) -> BoolArray:
    """The rows that cannot reach their group's best (:func:`newton_ascent`)."""
    finite = np.where(np.isfinite(value), value, -np.inf)
    best = np.full(group.max() + 1, -np.inf)
    np.maximum.at(best, group, finite)
    hxx, hxy, hyy = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    det = hxx * hyy - hxy * hxy
    concave = (hxx < 0.0) & (det > 0.0)
    gx, gy = gradient.T
    safe = np.where(concave, det, 1.0)
    rise = 0.5 * (-(hyy * gx * gx - 2.0 * hxy * gx * gy + hxx * gy * gy) / safe)
    reach = value + ABANDON_GAIN * np.where(concave, rise, 0.0)
    return reach < best[group] - margin(group, best[group])


def newton_ascent(
    objective: Objective,
    start_m: FloatArray,
    *,
    radius_m: float,
    xtol_m: float,
    max_iterations: int,
    group: IntArray | None = None,
    margin: Callable[[IntArray, FloatArray], FloatArray] | None = None,
) -> Ascent:
    """Maximise ``objective`` from each row's ``start_m`` ``(m, 2)`` (module text). Rows of
    one ``group`` compete: with ``margin(groups, best)`` (the level, per row, by which a row may
    lie below its group's best value ``best`` and still matter), a row whose Hessian is negative
    definite and whose value plus ``ABANDON_GAIN`` times its quadratic model's rise
    ``½ gᵀ(−H)⁻¹g`` is below its group's best value less the margin, or whose Hessian is not
    and whose value is, is abandoned (not converged)."""
    m = len(start_m)
    position = np.array(start_m, dtype=float)
    value, gradient, hessian = objective(np.arange(m), position)
    radius = np.full(m, float(radius_m))
    active = np.isfinite(value) & np.isfinite(gradient).all(axis=1)
    converged = np.zeros(m, dtype=bool)
    iterations = np.ones(m, dtype=np.int64)
    for _ in range(max_iterations):
        if margin is not None and group is not None:
            active &= ~_hopeless(value, gradient, hessian, group, margin)
        if not active.any():
            break
        live = np.flatnonzero(active)
        step = _ascent_step(gradient[live], hessian[live], radius[live])
        length = np.hypot(step[:, 0], step[:, 1])
        h = hessian[live]
        newton = (h[:, 0, 0] < 0.0) & (h[:, 0, 0] * h[:, 1, 1] - h[:, 0, 1] * h[:, 1, 0] > 0.0)
        settled = newton & (length <= xtol_m) & (length < radius[live])
        converged[live[settled]] = True  # the maximum within xtol: no need to go there
        active[live[settled]] = False
        live, step, length = live[~settled], step[~settled], length[~settled]
        if not len(live):
            break
        trial, trial_gradient, trial_hessian = objective(live, position[live] + step)
        iterations[live] += 1
        taken = trial >= value[live]
        clipped = length >= radius[live] * (1.0 - 1e-12)
        moved = live[taken]
        position[moved] += step[taken]
        value[moved] = trial[taken]
        gradient[moved], hessian[moved] = trial_gradient[taken], trial_hessian[taken]
        radius[live] = np.where(
            taken, np.where(clipped, 2.0 * radius[live], radius[live]), length / 4.0
        )
        broken = ~(
            np.isfinite(gradient[live]).all(axis=1) & np.isfinite(hessian[live]).all(axis=(1, 2))
        )
        active[live[broken]] = False
        done = (taken & (length <= xtol_m)) | (~taken & (radius[live] <= xtol_m))
        converged[live[done & ~broken]] = True
        active[live[done]] = False
    return Ascent(
        position_m=position,
        value=value,
        hessian=hessian,
        converged=converged,
        iterations=iterations,
    )
