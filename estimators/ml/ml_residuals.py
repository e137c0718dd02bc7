"""The whitened residuals of MATH §10 and their Jacobian, as one elementwise evaluation.

:class:`ResidualModel` evaluates the forward model of :mod:`scenarios.measurement_model`
(MATH §1, §8) for the maximum-likelihood search: the residuals ``e`` of
:func:`estimators.ml.ml.whitened_residuals` and ``∂e/∂s``, one pass over per-sample
constants with no layout-dependent kernel. A value therefore depends on its inputs alone:
residuals last (constants ``(N,)``, :func:`~estimators.ml.ml.whitened_residuals`) and rows
first (:meth:`ResidualModel.by_sample`, constants ``(N, 1)``, one trial per column, the search
of :mod:`estimators.ml.ml_batch`) compute the same values, and a trial's column the same bits
whatever its batch.

With an unknown carrier offset or emission time (MATH §15) the likelihood is profiled over it:
for a given emitter the best δ (or b) is the mean of the affected block's residual, so the
residual left is that block *centred* over the samples, and its Jacobian is the centred
Jacobian (the centring is linear and does not depend on the emitter). The search over
``(x_s, y_s)`` is then the search over ``(x_s, y_s, δ, b)`` (variable projection), and the
Gram matrix of the centred Jacobian is the nuisance Fisher information of MATH §15. Rows first,
the centring sums each column in order (:func:`~estimators.ml.minpack_batch.column_sums`).

With the emitter's height unknown (MATH §8, ``dimension`` 3) the emitter is ``(x_s, y_s, z_s)``:
the height is a coordinate of every evaluation (``z_k − z_s`` from the samples' ``pz``), the
Jacobian has a third column, ``∂ρ_k/∂z_s = −(z_k − z_s)/ρ_k`` and
``∂f_k/∂z_s = (γ v_z + f_k (z_k − z_s)/ρ_k)/ρ_k`` (:func:`scenarios.measurement_model.doppler_jacobian`).

With the height unknown and a terrain in the data (:mod:`scenarios.terrain`) the residual ends
with the prior's row, the emitter's offset above the ground measured as 0 with σ_m:
``e = (0 − (z_s − h(x_s, y_s)))/σ_m``, ``∂e/∂s = −(−h_x, −h_y, 1)/σ_m`` (minus the row of
:func:`scenarios.fisher.terrain_row`). ``‖e‖²`` is then minus twice the log-posterior, and its
minimum the MAP (MATH §8, §10); the Gram matrix of the Jacobian is the prior-augmented
information.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.ml.minpack_batch import column_sums
from scenarios import measurement_model as model
from scenarios.nuisance import HEIGHT_UNKNOWN, position_dimension
from scenarios.terrain import Terrain, offset_above_surface_m, offset_gradient
from scenarios.types import MeasurementSet, RssModel

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class ResidualModel:
    """The residuals of :func:`whitened_residuals` and their Jacobian, elementwise.

    The forward model of :func:`scenarios.measurement_model.derivatives_of_offsets` and
    :func:`~scenarios.measurement_model.rss_of_ranges` (MATH §1, §8) on per-sample constants:
    a row's value depends on its inputs alone, whatever the layout
    (:mod:`estimators.ml.ml_batch` keeps rows first, :meth:`by_sample`). The constants have
    shape ``(N,)``; an emitter ``point``, its coordinates ``(x, y)`` or ``(x, y, z)``
    (``dimension``), broadcasts against them.
    """

    px: FloatArray
    py: FloatArray
    pz: FloatArray
    dz: FloatArray  # z_k − z_s with the height known (dimension 2)
    vx: FloatArray
    vy: FloatArray
    vz: FloatArray
    gamma: float
    light: float
    sigma: tuple[float, float, float]
    rss_model: RssModel | None
    centred: tuple[bool, bool] = (False, False)  # Doppler, ToA blocks profiled (MATH §15)
    sample_axis: int = -1
    toa: bool = True  # a ToA block (False: Doppler alone, MATH §15)
    dimension: int = 2  # 3: the height a coordinate of the emitter (MATH §8)
    terrain: Terrain | None = None  # the prior's row, with dimension 3 (module text)

    @classmethod
    def of(cls, data: MeasurementSet) -> ResidualModel:
        position, velocity, noise = data.position_m, data.velocity_mps, data.noise
        return cls(
            px=position[:, 0],
            py=position[:, 1],
            pz=position[:, 2],
            dz=position[:, 2] - data.emitter_height_m,
            vx=velocity[:, 0],
            vy=velocity[:, 1],
            vz=velocity[:, 2],
            gamma=data.gamma_per_m,
            light=data.speed_of_light_mps,
            sigma=(noise.doppler_hz, noise.toa_s, np.nan if noise.rss_db is None else noise.rss_db),
            rss_model=data.rss_model,
            centred=(
                "carrier_offset_hz" in data.unknowns,
                "emission_time_s" in data.unknowns,
            ),
            toa=data.toa_s is not None,
            dimension=position_dimension(data.unknowns),
            terrain=data.terrain if HEIGHT_UNKNOWN in data.unknowns else None,
        )

    @property
    def prior(self) -> bool:
        """Whether the residual ends with the terrain prior's row (module text)."""
        return self.terrain is not None and self.dimension == 3

    def _prior_point(self, point: Sequence[ArrayLike]) -> FloatArray:
        """The emitter ``(..., 3)`` laid out as a row of the blocks: ``(1, k)`` rows first,
        ``(..., 1)`` samples last."""
        stacked = np.stack(np.broadcast_arrays(*point[:3]), axis=-1)
        return stacked[None] if self.sample_axis == 0 else stacked

    def _prior_residual(self, point: Sequence[ArrayLike], out: FloatArray | None) -> FloatArray:
        """``(0 − (z_s − h(x_s, y_s)))/σ_m`` (module text), one row."""
        assert self.terrain is not None
        offset = offset_above_surface_m(self.terrain, self._prior_point(point))
        return np.multiply(offset, -1.0 / self.terrain.sigma_m, out=out)

    def _prior_jacobian(
        self, point: Sequence[ArrayLike], out: Sequence[FloatArray | None]
    ) -> list[FloatArray]:
        """``∂e/∂x_s, ∂e/∂y_s, ∂e/∂z_s`` of the prior's row: ``(h_x, h_y, −1)/σ_m``."""
        assert self.terrain is not None
        gradient = offset_gradient(self.terrain, self._prior_point(point))
        scale = -1.0 / self.terrain.sigma_m
        return [np.multiply(gradient[..., axis], scale, out=out[axis]) for axis in range(3)]

    def by_sample(self) -> ResidualModel:
        """The same constants as columns ``(N, 1)``: rows first, emitters along the last axis."""
        names = ("px", "py", "pz", "dz", "vx", "vy", "vz")
        changes = {n: getattr(self, n)[:, None] for n in names}
        return dataclasses.replace(self, **changes, sample_axis=0)

    def _profiled(self, blocks: list[FloatArray]) -> list[FloatArray]:
        """The Doppler and ToA blocks centred over the samples where their offset is unknown."""
        centred = [self.centred[0], *([self.centred[1]] if self.toa else [])]
        for index, block in enumerate(blocks[: len(centred)]):
            if centred[index]:
                if self.sample_axis == 0:  # rows first: a trial's mean whatever its batch
                    block -= column_sums(block) / len(block)
                else:
                    block -= block.mean(axis=self.sample_axis, keepdims=True)
        return blocks

    def _model(
        self, point: Sequence[ArrayLike], order: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Doppler and range (order 0), or their first derivatives in ``(x_s, y_s)`` (order 1)
        with the range and (``dimension`` 3) the Doppler's value, components first
        (:func:`scenarios.measurement_model.derivatives_of_offsets`); and ``z_k − z_s``."""
        dz = self.dz if self.dimension == 2 else self.pz - point[2]
        doppler, ranges = model.derivatives_of_offsets(
            self.px - point[0],
            self.py - point[1],
            dz,
            (self.vx, self.vy, self.vz),
            self.gamma,
            order=order,
            values=order == 0 or self.dimension == 3,
        )
        return doppler, ranges, dz

    def _blocks(self, out: FloatArray | None, count: int, shape: tuple[int, ...]) -> list[Any]:
        """``count`` outputs of ``shape``: consecutive row slices of ``out`` (rows first,
        ``(count·N, k)``) so that no concatenation follows, or new arrays."""
        if out is None:
            return [None] * count
        n = shape[0]
        return [out[i * n : (i + 1) * n] for i in range(count)]

    def residuals(
        self,
        point: Sequence[ArrayLike],
        doppler: ArrayLike,
        toa: ArrayLike,
        rss: ArrayLike | None,
        *,
        out: FloatArray | None = None,
    ) -> list[FloatArray]:
        """The Doppler, ToA and (``rss`` given) RSS blocks of ``e`` at ``point`` (its
        coordinates), measured minus predicted over σ; with ``out`` (rows first) written into
        its consecutive row slices."""
        predicted, ranges, _ = self._model(point, 0)
        sigma_f, sigma_t, sigma_p = self.sigma
        count = 1 + self.toa + (rss is not None)
        slots = self._blocks(out, count, ranges.shape[1:])
        blocks = [_whitened(doppler, predicted[0], sigma_f, slots[0])]
        if self.toa:
            blocks.append(_whitened(toa, ranges[0] / self.light, sigma_t, slots[1]))
        if rss is not None:
            assert self.rss_model is not None
            power = model.rss_of_ranges(ranges, self.rss_model)[0]
            blocks.append(_whitened(rss, power, sigma_p, slots[-1]))
        blocks = self._profiled(blocks) if any(self.centred) else blocks
        if self.prior:  # after the profiling: the prior has no nuisance parameter
            blocks.append(self._prior_residual(point, None if out is None else out[-1:]))
        return blocks

    def jacobian(
        self,
        point: Sequence[ArrayLike],
        use_rss: bool,
        *,
        out: Sequence[FloatArray] | None = None,
    ) -> tuple[list[FloatArray], ...]:
        """``∂e/∂x_s``, ``∂e/∂y_s`` (and ``∂e/∂z_s``, ``dimension`` 3), each ``−∇h/σ`` as the
        blocks of :meth:`residuals`; with ``out`` (one rows-first array per coordinate)
        written into their consecutive row slices."""
        doppler, ranges, dz = self._model(point, 1)
        sigma_f, sigma_t, sigma_p = self.sigma
        count = 1 + self.toa + use_rss
        shape = ranges.shape[1:]
        d = self.dimension
        slots = [
            self._blocks(None if out is None else out[axis], count, shape) for axis in range(d)
        ]
        doppler_gradient, range_gradient = [doppler[1], doppler[2]], [ranges[1], ranges[2]]
        if d == 3:  # the height's entries (module text)
            distance = ranges[0]
            minus_uz = np.negative(dz) / distance
            range_gradient.append(minus_uz)
            doppler_gradient.append((self.gamma * self.vz - doppler[0] * minus_uz) / distance)
        power = None
        if use_rss:
            assert self.rss_model is not None
            stacked = ranges if d == 2 else np.stack([ranges[0], *range_gradient])
            power = model.rss_of_ranges(stacked, self.rss_model, d)
        columns: tuple[list[FloatArray], ...] = tuple([] for _ in range(d))
        for axis, (into, slot) in enumerate(zip(columns, slots, strict=True)):
            into.append(np.multiply(doppler_gradient[axis], -1.0 / sigma_f, out=slot[0]))
            if self.toa:
                scale = -1.0 / (self.light * sigma_t)
                into.append(np.multiply(range_gradient[axis], scale, out=slot[1]))
            if power is not None:
                into.append(np.multiply(power[1 + axis], -1.0 / sigma_p, out=slot[-1]))
        if any(self.centred):
            columns = tuple(self._profiled(column) for column in columns)
        if self.prior:
            rows = [None if out is None else out[axis][-1:] for axis in range(d)]
            for column, row in zip(columns, self._prior_jacobian(point, rows), strict=True):
                column.append(row)
        return columns


def _whitened(
    measured: ArrayLike, predicted: FloatArray, sigma: float, out: FloatArray | None
) -> FloatArray:
    """``(z − h)/σ`` (into ``out`` if given)."""
    residual = np.subtract(measured, predicted, out=_same(predicted, measured))
    return np.divide(residual, sigma, out=out if out is not None else residual)


def _same(result: FloatArray, other: ArrayLike) -> FloatArray | None:
    """``result`` as the output of an operation with ``other`` when that keeps its shape."""
    return result if np.shape(other) == result.shape or np.ndim(other) == 0 else None


def profiled_offsets(data: MeasurementSet, emitter_m: ArrayLike) -> dict[str, float]:
    """The least-squares values of the unknown nuisance parameters at ``emitter_m`` (MATH §15):
    ``δ = mean_k(f_k + γ v_kᵀu_k)`` and ``b = mean_k(τ_k − ρ_k/c)``, keyed by their names; empty
    for a cooperative emitter."""
    out = {}
    if "carrier_offset_hz" in data.unknowns and data.doppler_hz is not None:
        predicted = model.doppler_hz(
            data.position_m, data.velocity_mps, emitter_m, data.gamma_per_m, data.emitter_height_m
        )
        out["carrier_offset_hz"] = float(np.mean(data.doppler_hz - predicted))
    if "emission_time_s" in data.unknowns and data.toa_s is not None:
        predicted = model.toa_s(
            data.position_m, emitter_m, data.speed_of_light_mps, data.emitter_height_m
        )
        out["emission_time_s"] = float(np.mean(data.toa_s - predicted))
    return out
