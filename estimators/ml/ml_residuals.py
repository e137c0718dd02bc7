"""The whitened residuals of MATH §10 and their Jacobian, as one elementwise evaluation.

:class:`ResidualModel` evaluates the forward model of :mod:`scenarios.measurement_model`
(MATH §1, §8) for the maximum-likelihood search: the residuals ``e`` of
:func:`estimators.ml.ml.whitened_residuals` and ``∂e/∂(x_s, y_s)``, one pass over per-sample
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
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.ml.minpack_batch import column_sums
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class ResidualModel:
    """The residuals of :func:`whitened_residuals` and their Jacobian, elementwise.

    The forward model of :mod:`scenarios.measurement_model` (MATH §1, §8) written as one fixed
    sequence of elementwise operations on per-sample constants: a row's value depends on its
    inputs alone, whatever the layout (:mod:`estimators.ml.ml_batch` keeps rows first,
    :meth:`by_sample`). The constants
    have shape ``(N,)``; emitter coordinates ``x, y`` broadcast against them.
    """

    px: FloatArray
    py: FloatArray
    dz_sq: FloatArray
    vx: FloatArray
    vy: FloatArray
    vz_dz: FloatArray
    gamma: float
    light: float
    sigma: tuple[float, float, float]
    rss: tuple[float, float, float]  # P0, 10 η, d0
    centred: tuple[bool, bool] = (False, False)  # Doppler, ToA blocks profiled (MATH §15)
    sample_axis: int = -1
    toa: bool = True  # a ToA block (False: Doppler alone, MATH §15)

    @classmethod
    def of(cls, data: MeasurementSet) -> ResidualModel:
        position, velocity, noise, rss = data.position_m, data.velocity_mps, data.noise, None
        dz = position[:, 2] - data.emitter_height_m
        if data.rss_model is not None:
            rss = data.rss_model
        return cls(
            px=position[:, 0],
            py=position[:, 1],
            dz_sq=dz * dz,
            vx=velocity[:, 0],
            vy=velocity[:, 1],
            vz_dz=velocity[:, 2] * dz,
            gamma=data.gamma_per_m,
            light=data.speed_of_light_mps,
            sigma=(noise.doppler_hz, noise.toa_s, np.nan if noise.rss_db is None else noise.rss_db),
            rss=(np.nan,) * 3
            if rss is None
            else (
                rss.reference_power_dbm,
                10.0 * rss.path_loss_exponent,
                rss.reference_distance_m,
            ),
            centred=(
                "carrier_offset_hz" in data.unknowns,
                "emission_time_s" in data.unknowns,
            ),
            toa=data.toa_s is not None,
        )

    def by_sample(self) -> ResidualModel:
        """The same constants as columns ``(N, 1)``: rows first, emitters along the last axis."""
        names = ("px", "py", "dz_sq", "vx", "vy", "vz_dz")
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

    def _geometry(self, x: ArrayLike, y: ArrayLike) -> tuple[FloatArray, ...]:
        """``p_k − s`` in the plane, ``ρ_k`` and ``v_kᵀ(p_k − s)`` (in-place where possible)."""
        dx, dy = self.px - x, self.py - y
        distance = dx * dx
        distance += dy * dy
        distance += self.dz_sq
        np.sqrt(distance, out=distance)
        radial = self.vx * dx
        radial += self.vy * dy
        radial += self.vz_dz
        return dx, dy, distance, radial

    def _blocks(self, out: FloatArray | None, count: int, shape: tuple[int, ...]) -> list[Any]:
        """``count`` outputs of ``shape``: consecutive row slices of ``out`` (rows first,
        ``(count·N, k)``) so that no concatenation follows, or new arrays."""
        if out is None:
            return [None] * count
        n = shape[0]
        return [out[i * n : (i + 1) * n] for i in range(count)]

    def residuals(
        self,
        x: ArrayLike,
        y: ArrayLike,
        doppler: ArrayLike,
        toa: ArrayLike,
        rss: ArrayLike | None,
        *,
        out: FloatArray | None = None,
    ) -> list[FloatArray]:
        """The Doppler, ToA and (``rss`` given) RSS blocks of ``e`` at ``(x, y)``; with
        ``out`` (rows first) written into its consecutive row slices."""
        _, _, distance, radial = self._geometry(x, y)
        sigma_f, sigma_t, sigma_p = self.sigma
        count = 1 + self.toa + (rss is not None)
        slots = self._blocks(out, count, distance.shape)
        predicted = np.multiply(self.gamma, radial, out=radial)
        predicted /= distance
        predicted = np.add(doppler, predicted, out=_same(predicted, doppler))
        blocks = [np.divide(predicted, sigma_f, out=slots[0])]
        if self.toa:
            delay = np.divide(distance, self.light, out=slots[1])
            delay = np.subtract(toa, delay, out=_same(delay, toa))
            blocks.append(np.divide(delay, sigma_t, out=delay))
        if rss is not None:
            p0, ten_eta, d0 = self.rss
            power = p0 - ten_eta * np.log10(distance / d0)
            blocks.append(np.divide(np.subtract(rss, power), sigma_p, out=slots[-1]))
        return self._profiled(blocks) if any(self.centred) else blocks

    def jacobian(
        self,
        x: ArrayLike,
        y: ArrayLike,
        use_rss: bool,
        *,
        out: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[list[FloatArray], list[FloatArray]]:
        """``∂e/∂x_s`` and ``∂e/∂y_s``, each as the blocks of :meth:`residuals`; with ``out``
        (two rows-first arrays) written into their consecutive row slices."""
        dx, dy, distance, radial = self._geometry(x, y)
        sigma_f, sigma_t, sigma_p = self.sigma
        count = 1 + self.toa + use_rss
        slots_x = self._blocks(None if out is None else out[0], count, distance.shape)
        slots_y = self._blocks(None if out is None else out[1], count, distance.shape)
        inverse = np.divide(1.0, distance, out=distance)  # ρ is not needed after this
        ux, uy = dx * inverse, dy * inverse
        along = np.multiply(radial, inverse, out=radial)
        # ∂e_f/∂s = −γ (v − (vᵀu) u)_xy / (ρ σ_f)
        weight = np.multiply(inverse, -self.gamma / sigma_f)
        jx, jy = [], []
        for unit, speed, slots, into in ((ux, self.vx, slots_x, jx), (uy, self.vy, slots_y, jy)):
            across = np.multiply(along, unit)
            np.subtract(speed, across, out=across)
            into.append(
                np.multiply(across, weight, out=slots[0] if slots[0] is not None else across)
            )
        if self.toa:
            jx.append(np.multiply(ux, 1.0 / (self.light * sigma_t), out=slots_x[1]))
            jy.append(np.multiply(uy, 1.0 / (self.light * sigma_t), out=slots_y[1]))
        if use_rss:
            slope = np.multiply(inverse, inverse)
            slope *= -self.rss[1] / (np.log(10.0) * sigma_p)
            jx.append(np.multiply(dx, slope, out=slots_x[-1]))
            jy.append(np.multiply(dy, slope, out=slots_y[-1]))
        if any(self.centred):
            return self._profiled(jx), self._profiled(jy)
        return jx, jy


def _same(result: FloatArray, other: ArrayLike) -> FloatArray | None:
    """``result`` as the output of an operation with ``other`` when that keeps its shape."""
    return result if np.shape(other) == result.shape or np.ndim(other) == 0 else None


def profiled_offsets(data: MeasurementSet, emitter_m: ArrayLike) -> dict[str, float]:
    """The least-squares values of the unknown nuisance parameters at ``emitter_m`` (MATH §15):
    ``δ = mean_k(f_k + γ v_kᵀu_k)`` and ``b = mean_k(τ_k − ρ_k/c)``, keyed by their names; empty
    for a cooperative emitter."""
    from scenarios import measurement_model as model

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
