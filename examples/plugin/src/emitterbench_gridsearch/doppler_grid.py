r"""Doppler-only maximum likelihood by grid search and local refinement.

With Gaussian Doppler noise of one standard deviation ``σ_f`` (MATH §1), the negative
log-likelihood of the emitter ``s = (x_s, y_s)`` is, up to a constant, half of

.. math::

    C(s) = \sum_k \Big(\frac{f_k - f_k(s)}{\sigma_f}\Big)^2,\qquad
    f_k(s) = -\gamma\, v_k^\top \frac{p_k - s}{\lVert p_k - s\rVert}

(physical sign, received minus carrier). ``C`` is not convex, so it is evaluated on a square
grid centred on the track; the lowest grid cells that are lower than their eight neighbours
start a Levenberg-Marquardt refinement (``scipy.optimize.least_squares``, analytic Jacobian
from :func:`scenarios.measurement_model.doppler_jacobian`). Every refined minimum whose cost
ties the best (relative gap ``cost_rtol``) is a candidate. On a straight track ``C`` is
symmetric about the track's vertical plane (MATH §7): only starts on one side are refined and
:func:`estimators.base.finalize_estimate` adds the mirror images.

Doppler alone localises (its Fisher information is nonsingular, MATH §8), but less well than
Doppler with ToA. The covariance reported is the inverse Doppler Fisher information at the
estimate, the CRLB evaluated there.

The grid model does not depend on the trial, so :meth:`DopplerGridSearch.estimate_batch`
evaluates it once for a whole batch of Monte Carlo trials.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from estimators.base import Capabilities, Estimate, finalize_estimate, require_modalities
from scenarios import measurement_model as model
from scenarios.geometry import cross_track_m, mirror_across_line, straight_track_line
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class DopplerGridSearch:
    """Doppler-only maximum likelihood: a grid search, then Levenberg-Marquardt refinement.

    Parameters
    ----------
    search_radius_m : float
        Half the side of the square searched, centred on the mean UAV position (metres). The
        emitter should lie inside; a minimum refined outside it is reported in ``message``.
    grid_points : int
        Grid cells per side (at least 3); the grid step is ``2 search_radius_m /
        (grid_points − 1)``.
    n_starts : int
        How many of the lowest grid minima are refined (at least 1).
    cost_rtol : float
        Refined minima within this relative cost gap of the best are all candidates.

    Notes
    -----
    :meth:`capabilities` declares a noise-free tolerance of 1e-5 m: the refinement stops when
    a step is shorter than ``1e-8`` times the search radius, so a noise-free candidate lies
    within a few micrometres of the emitter, not within the 1e-6 m of an exact closed form.
    """

    name: ClassVar[str] = "doppler-grid"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler"})

    search_radius_m: float = 200.0
    grid_points: int = 61
    n_starts: int = 3
    cost_rtol: float = 1e-6

    def __post_init__(self) -> None:
        radius = self.search_radius_m
        if isinstance(radius, bool) or not isinstance(radius, int | float):
            raise ValueError(f"search_radius_m: expected a number of metres, got {radius!r}")
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"search_radius_m: must be finite and > 0, got {radius!r}")
        for option, minimum in (("grid_points", 3), ("n_starts", 1)):
            value = getattr(self, option)
            if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
                raise ValueError(f"{option}: expected a whole number >= {minimum}, got {value!r}")
        rtol = self.cost_rtol
        if isinstance(rtol, bool) or not isinstance(rtol, int | float) or not 0 <= rtol < math.inf:
            raise ValueError(f"cost_rtol: expected a finite number >= 0, got {rtol!r}")

    # -- the Estimator interface ---------------------------------------------------------------

    def capabilities(self) -> Capabilities:
        """Doppler only, every frame, batch-capable; exact to 1e-5 m (see Notes)."""
        return Capabilities(
            modalities=frozenset({"doppler"}),
            frames="all",
            batch=True,
            noise_free_tolerance_m=1e-5,
            tolerance_reason=(
                "Levenberg-Marquardt stops when a step is shorter than 1e-8 of the search "
                "radius (2e-6 m by default)"
            ),
        )

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """Locate the emitter from ``data``'s Doppler; ``rng`` breaks a mirror tie."""
        require_modalities(self, data)
        _check_samples(data)
        grid = self._grid(data)
        cost = grid_cost(data, grid, data.doppler_hz[None, :])[0]
        return self._refine(data, grid, cost, rng)

    def estimate_batch(
        self, batch: MeasurementBatch, *, rngs: list[np.random.Generator] | None = None
    ) -> list[Estimate]:
        """One estimate per trial; the grid model is evaluated once for the whole batch."""
        if not isinstance(batch, MeasurementBatch):
            raise TypeError(
                f"batch: expected a scenarios.types.MeasurementBatch, got {type(batch).__name__}"
            )
        trials = list(batch)
        require_modalities(self, trials[0])
        _check_samples(batch.geometry)
        if rngs is None:
            rngs = [None] * len(trials)
        grid = self._grid(batch.geometry)
        costs = grid_cost(batch.geometry, grid, batch.doppler_hz)
        return [
            self._refine(data, grid, cost, rng)
            for data, cost, rng in zip(trials, costs, rngs, strict=True)
        ]

    # -- internals ------------------------------------------------------------------------------

    def _grid(self, data: MeasurementSet) -> FloatArray:
        """Cell centres, shape (grid_points, grid_points, 2), around the mean UAV position."""
        centre = data.position_m[:, :2].mean(axis=0)
        axis = np.linspace(-self.search_radius_m, self.search_radius_m, self.grid_points)
        x, y = np.meshgrid(centre[0] + axis, centre[1] + axis, indexing="ij")
        return np.stack([x, y], axis=-1)

    def _refine(
        self,
        data: MeasurementSet,
        grid: FloatArray,
        cost: FloatArray,
        rng: np.random.Generator | None,
    ) -> Estimate:
        starts = lowest_local_minima(grid, cost, self.n_starts)
        line = straight_track_line(data.position_m, data.velocity_mps)
        if line is not None:  # MATH §7: one side suffices, finalize_estimate adds the mirrors
            left = cross_track_m(starts, *line) >= 0.0
            starts = np.where(left[:, None], starts, mirror_across_line(starts, *line))
        minima, costs, evaluations = [], [], 0
        for start in starts:
            point, value, nfev = refine_doppler_ml(data, start, self.search_radius_m)
            evaluations += nfev
            if point is not None:
                minima.append(point)
                costs.append(value)
        if not minima:
            return Estimate.failed(
                self.name,
                "no refinement converged; widen search_radius_m or raise grid_points",
                n_starts=len(starts),
                nfev=evaluations,
            )
        points, values = distinct_minima(np.array(minima), np.array(costs), self.search_radius_m)
        centre = data.position_m[:, :2].mean(axis=0)
        outside = np.max(np.abs(points[0] - centre)) > self.search_radius_m
        estimate = finalize_estimate(
            self.name,
            points,
            values,
            data,
            rng=rng,
            cost_rtol=self.cost_rtol,
            message="minimum outside the search square; widen search_radius_m" if outside else "",
            diagnostics={
                "cost": float(values[0]),
                "n_starts": len(starts),
                "n_minima": len(values),
                "nfev": evaluations,
                "grid_step_m": 2.0 * self.search_radius_m / (self.grid_points - 1),
            },
        )
        # the CRLB at the returned candidate (a mirror image has the mirrored bound)
        covariance = doppler_crlb_m2(data, estimate.position_m)
        return dataclasses.replace(estimate, covariance_m2=covariance)


# --------------------------------------------------------------------------------------------
# pure functions
# --------------------------------------------------------------------------------------------


def _check_samples(data: MeasurementSet) -> None:
    if data.n_samples < 2:
        raise ValueError(
            f"doppler_hz: Doppler-only localisation needs at least 2 samples for 2 unknowns, "
            f"got {data.n_samples}; use more samples or frames"
        )


def grid_cost(data: MeasurementSet, grid_m: FloatArray, doppler_hz: FloatArray) -> FloatArray:
    """``Σ_k (f_k − f_k(s))²`` (Hz²) for every trial and grid cell, shape (n_trials, *grid).

    ``doppler_hz`` has shape (n_trials, N); the geometry is ``data``'s. The model is evaluated
    once, and the squares are expanded so that no (n_trials, n_cells, N) array is built.
    """
    cells = grid_m.reshape(-1, 2)
    predicted = model.doppler_hz(
        data.position_m, data.velocity_mps, cells, data.gamma_per_m, data.emitter_height_m
    )  # (n_cells, N)
    measured = np.asarray(doppler_hz, dtype=float)
    cost = (
        np.sum(measured**2, axis=1)[:, None]
        - 2.0 * measured @ predicted.T
        + np.sum(predicted**2, axis=1)[None, :]
    )
    return cost.reshape(len(measured), *grid_m.shape[:-1])


def lowest_local_minima(grid_m: FloatArray, cost: FloatArray, count: int) -> FloatArray:
    """The ``count`` lowest cells no higher than their eight neighbours, shape (≤ count, 2)."""
    padded = np.pad(cost, 1, constant_values=np.inf)
    rows, cols = cost.shape
    neighbours = [
        padded[1 + di : 1 + di + rows, 1 + dj : 1 + dj + cols]
        for di in (-1, 0, 1)
        for dj in (-1, 0, 1)
        if di or dj
    ]
    is_minimum = np.all([cost <= n for n in neighbours], axis=0)
    index = np.flatnonzero(is_minimum)
    best = index[np.argsort(cost.reshape(-1)[index], kind="stable")[:count]]
    return grid_m.reshape(-1, 2)[best]


def refine_doppler_ml(
    data: MeasurementSet, start_m: FloatArray, length_scale_m: float
) -> tuple[FloatArray | None, float, int]:
    """Levenberg-Marquardt on the whitened Doppler residuals from ``start_m``.

    Solved in units of ``length_scale_m`` around the start. Returns ``(point, C(point),
    nfev)``; the point is None when the solver did not converge.
    """
    sigma = data.noise.doppler_hz
    origin = np.asarray(start_m, dtype=float)

    def residual(u: FloatArray) -> FloatArray:
        emitter = origin + length_scale_m * u
        predicted = model.doppler_hz(
            data.position_m, data.velocity_mps, emitter, data.gamma_per_m, data.emitter_height_m
        )
        return (predicted - data.doppler_hz) / sigma

    def jacobian(u: FloatArray) -> FloatArray:
        emitter = origin + length_scale_m * u
        rows = model.doppler_jacobian(
            data.position_m, data.velocity_mps, emitter, data.gamma_per_m, data.emitter_height_m
        )
        return rows * (length_scale_m / sigma)

    result = least_squares(
        residual, np.zeros(2), jac=jacobian, method="lm", xtol=1e-8, ftol=1e-15, gtol=1e-15
    )
    point = origin + length_scale_m * result.x
    cost = 2.0 * float(result.cost)
    if result.status <= 0 or not (np.all(np.isfinite(point)) and math.isfinite(cost)):
        return None, math.nan, int(result.nfev)
    return point, cost, int(result.nfev)


def distinct_minima(
    points_m: FloatArray, costs: FloatArray, length_scale_m: float
) -> tuple[FloatArray, FloatArray]:
    """Minima closer than ``1e-6 length_scale_m`` merged (the lower cost kept), best first."""
    kept: list[int] = []
    for index in np.argsort(costs, kind="stable"):
        if all(np.linalg.norm(points_m[index] - points_m[j]) > 1e-6 * length_scale_m for j in kept):
            kept.append(int(index))
    return points_m[kept], costs[kept]


def doppler_crlb_m2(data: MeasurementSet, emitter_m: FloatArray) -> FloatArray | None:
    """Inverse Doppler Fisher information ``(Σ ∇f_k ∇f_kᵀ / σ_f²)⁻¹`` (MATH §8), or None."""
    rows = (
        model.doppler_jacobian(
            data.position_m, data.velocity_mps, emitter_m, data.gamma_per_m, data.emitter_height_m
        )
        / data.noise.doppler_hz
    )
    information = rows.T @ rows
    a, b, d = information[0, 0], information[0, 1], information[1, 1]
    determinant = a * d - b * b
    if not determinant > 1e-12 * abs(a * d):
        return None
    return np.array([[d, -b], [-b, a]]) / determinant
