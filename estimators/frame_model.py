r"""One frame's stacked, whitened measurement model (MATH §1, §8, §10), shared by the frame-by-frame
estimators (:mod:`estimators.sequential.ekf`, :mod:`estimators.sequential.gtsam_smoother`).

A frame of K samples gives ``m = 2K`` measurements ``z = [f_1..f_K, r_1..r_K]``, Doppler in Hz
(physical sign) and ToA as range ``r_k = c τ_k`` in metres with ``σ_r = c σ_τ``. Its whitened
error and Jacobian are

.. math::

    e(s) = \frac{h(s) - z}{\sigma},\qquad
    E(s) = \frac{\partial e}{\partial s} = \Big[\frac{\nabla f_k}{\sigma_f};\
    \frac{c\,\nabla \tau_k}{\sigma_r}\Big]_k ,\qquad J_{\text{frame}}(s) = E^\top E

(predicted minus measured, GTSAM's sign convention), ``J_frame`` being the frame's Fisher
information of MATH §8. ``s`` is ``(x_s, y_s)`` at the known height, or ``(x_s, y_s, z_s)`` when
the frame declares the height unknown (``dimension`` 3: Jacobians ``(2K, 3)``, Hessians
``3 × 3``). :class:`FrameModel` holds the frame as plain arrays, so it pickles and can
be rebuilt into filter or factor-graph objects inside any worker process.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.fisher import gram_information
from scenarios.nuisance import position_dimension
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]


HESSIAN_SLOTS = {2: [[0, 1], [1, 2]], 3: [[0, 1, 2], [1, 3, 4], [2, 4, 5]]}
"""The unique second derivatives (``xx, xy, yy``; ``xx, xy, xz, yy, yz, zz``) as the symmetric
``d × d`` Hessian (:func:`scenarios.measurement_model.derivative_components`)."""


def read_only(*arrays: FloatArray) -> None:
    """Mark arrays read-only: a frozen dataclass alone does not stop in-place writes."""
    for array in arrays:
        array.flags.writeable = False


@dataclass(frozen=True, slots=True, eq=False)
class FrameModel:
    """One frame's Doppler and range measurements with the forward model of MATH §1.

    Attributes
    ----------
    position_m, velocity_mps : (K, 3)
        UAV position and velocity of each sample.
    measured : (2K,)
        ``z = [f_1..f_K (Hz), r_1..r_K (m)]``, ranges ``r_k = c τ_k``.
    sigma : (2K,)
        ``[σ_f, …, σ_r, …]``, ``σ_r = c σ_τ``.
    gamma_per_m, emitter_height_m : float
        ``γ = f0 / c`` and the known emitter height ``z_s``.
    time_s : float
        Mean sample time of the frame (for the random-walk step between frames).
    dimension : int
        The emitter's coordinates: 2, ``(x_s, y_s)`` at the known height
        ``emitter_height_m``, or 3, ``(x_s, y_s, z_s)`` with the height unknown (MATH §8;
        ``emitter_height_m`` is then not read). Jacobians are ``(2K, dimension)``.
    """

    position_m: FloatArray
    velocity_mps: FloatArray
    measured: FloatArray
    sigma: FloatArray
    gamma_per_m: float
    emitter_height_m: float
    time_s: float
    dimension: int = 2
    _planes: tuple[FloatArray, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # the samples' coordinates and velocities as contiguous planes, once: ``p_x, p_y,
        # p_z − z_s, v_x, v_y, v_z``, each (K,), what every evaluation subtracts the emitter from
        # (``p_z`` itself in 3-D: the height is then the emitter's third coordinate)
        position, velocity = self.position_m, self.velocity_mps
        height = 0.0 if self.dimension == 3 else np.asarray(self.emitter_height_m, dtype=float)
        planes = (
            np.ascontiguousarray(position[:, 0]),
            np.ascontiguousarray(position[:, 1]),
            position[:, 2] - height,
            np.ascontiguousarray(velocity[:, 0]),
            np.ascontiguousarray(velocity[:, 1]),
            np.ascontiguousarray(velocity[:, 2]),
        )
        read_only(*planes)
        object.__setattr__(self, "_planes", planes)

    @classmethod
    def from_measurements(cls, frame: MeasurementSet) -> FrameModel:
        """Stack one frame's Doppler and ToA; raise ``ValueError`` naming a missing field. The
        emitter has three coordinates when the frame declares its height unknown
        (:func:`scenarios.nuisance.position_dimension`)."""
        missing = [
            name
            for name, value in (("doppler_hz", frame.doppler_hz), ("toa_s", frame.toa_s))
            if value is None
        ]
        if missing:
            raise ValueError(
                f"{', '.join(missing)}: the frame-by-frame estimators need Doppler and ToA "
                "in every frame; add them or choose an estimator that works without them"
            )
        k = frame.n_samples
        c = frame.speed_of_light_mps
        arrays = {
            "position_m": np.array(frame.position_m, dtype=float),
            "velocity_mps": np.array(frame.velocity_mps, dtype=float),
            "measured": np.concatenate([frame.doppler_hz, c * frame.toa_s]),
            "sigma": np.concatenate(
                [np.full(k, frame.noise.doppler_hz), np.full(k, c * frame.noise.toa_s)]
            ),
        }
        read_only(*arrays.values())
        return cls(
            **arrays,
            gamma_per_m=frame.gamma_per_m,
            emitter_height_m=frame.emitter_height_m,
            time_s=float(np.mean(frame.time_s)),
            dimension=position_dimension(frame.unknowns),
        )

    @property
    def n_rows(self) -> int:
        """``m = 2K``, the stacked measurements."""
        return len(self.measured)

    @classmethod
    def stacked(cls, frames: Sequence[FrameModel]) -> FrameModel:
        """Several frames as one model: every Doppler row, then every range row."""
        sizes = [len(frame.position_m) for frame in frames]

        def blocks(name: str, part: int) -> FloatArray:
            return np.concatenate(
                [
                    getattr(frame, name)[part * k : (part + 1) * k]
                    for frame, k in zip(frames, sizes, strict=True)
                ]
            )

        return cls(
            position_m=np.concatenate([frame.position_m for frame in frames]),
            velocity_mps=np.concatenate([frame.velocity_mps for frame in frames]),
            measured=np.concatenate([blocks("measured", 0), blocks("measured", 1)]),
            sigma=np.concatenate([blocks("sigma", 0), blocks("sigma", 1)]),
            gamma_per_m=frames[0].gamma_per_m,
            emitter_height_m=frames[0].emitter_height_m,
            time_s=float(np.mean([frame.time_s for frame in frames])),
            dimension=frames[0].dimension,
        )

    def derivatives(
        self, emitter_m: ArrayLike, order: int, *, per_sample: bool = False
    ) -> tuple[FloatArray, FloatArray]:
        """The Doppler and range rows with their derivatives up to ``order``, each
        ``(..., K, n)`` (:func:`scenarios.measurement_model.doppler_range_derivatives`).

        ``per_sample``: ``emitter_m`` has shape (K, d), one emitter position per sample. In 3-D
        the derivatives are in ``(x_s, y_s, z_s)``
        (:func:`scenarios.measurement_model.derivative_components`).
        """
        if per_sample:
            doppler, ranges = model.doppler_range_derivatives(
                self.position_m[:, None, :],
                self.velocity_mps[:, None, :],
                emitter_m,
                self.gamma_per_m,
                self.emitter_height_m,
                order=order,
                dimension=self.dimension,
            )
            return doppler[:, 0], ranges[:, 0]
        return model.doppler_range_derivatives(
            self.position_m,
            self.velocity_mps,
            emitter_m,
            self.gamma_per_m,
            self.emitter_height_m,
            order=order,
            dimension=self.dimension,
        )

    def components(self, emitter_m: ArrayLike, order: int) -> tuple[FloatArray, FloatArray]:
        """The Doppler and range rows with their derivatives up to ``order``, components first,
        each ``(n, ..., K)`` (:func:`scenarios.measurement_model.derivatives_of_offsets` on the
        cached planes), at emitter positions ``(..., d)`` (in 3-D the derivatives in
        ``(x_s, y_s, z_s)``)."""
        emitter = np.asarray(emitter_m, dtype=float)
        px, py, dz, vx, vy, vz = self._planes
        if emitter.ndim == 1:
            dx, dy = px - emitter[0], py - emitter[1]
            if self.dimension == 3:
                dz = dz - emitter[2]
        else:
            dx, dy = px - emitter[..., 0, None], py - emitter[..., 1, None]
            if self.dimension == 3:
                dz = dz - emitter[..., 2, None]
        return model.derivatives_of_offsets(
            dx, dy, dz, (vx, vy, vz), self.gamma_per_m, order=order, dimension=self.dimension
        )

    def _evaluate(
        self, emitter_m: ArrayLike, with_jacobian: bool, *, per_sample: bool = False
    ) -> tuple[FloatArray, FloatArray | None]:
        """``h(s)`` and, if asked, ``∂h/∂s`` in the emitter's ``d`` coordinates (MATH §1, §8),
        one pass over the samples."""
        emitter = np.asarray(emitter_m, dtype=float)
        d = self.dimension
        if per_sample:  # sample k against emitter k: the planes minus (K,) components
            px, py, dz, vx, vy, vz = self._planes
            doppler, ranges = model.derivatives_of_offsets(
                px - emitter[:, 0],
                py - emitter[:, 1],
                dz - emitter[:, 2] if d == 3 else dz,
                (vx, vy, vz),
                self.gamma_per_m,
                order=int(with_jacobian),
                dimension=d,
            )
        else:
            doppler, ranges = self.components(emitter, int(with_jacobian))
        predicted = np.concatenate([doppler[0], ranges[0]], axis=-1)
        if not with_jacobian:
            return predicted, None
        k = doppler.shape[-1]
        jacobian = np.empty((*predicted.shape, d))
        for i in range(d):
            jacobian[..., :k, i] = doppler[1 + i]
            jacobian[..., k:, i] = ranges[1 + i]
        return predicted, jacobian

    def predicted(self, emitter_m: ArrayLike) -> FloatArray:
        """``h(s) = [f_k(s); ρ_k(s)]`` (MATH §1), shape ``(..., 2K)``."""
        return self._evaluate(emitter_m, with_jacobian=False)[0]

    def jacobian(self, emitter_m: ArrayLike) -> FloatArray:
        """``∂h/∂s = [∇f_k; c ∇τ_k]`` (MATH §8), shape ``(..., 2K, d)``."""
        jacobian = self._evaluate(emitter_m, with_jacobian=True)[1]
        assert jacobian is not None
        return jacobian

    def predicted_and_jacobian(self, emitter_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(h(s), ∂h/∂s)`` in one pass (:meth:`predicted`, :meth:`jacobian`)."""
        predicted, jacobian = self._evaluate(emitter_m, with_jacobian=True)
        assert jacobian is not None
        return predicted, jacobian

    def whitened_error(self, emitter_m: ArrayLike) -> FloatArray:
        """``e(s) = (h(s) − z)/σ`` (MATH §10, predicted minus measured), shape ``(..., 2K)``."""
        return (self.predicted(emitter_m) - self.measured) / self.sigma

    def whitened_jacobian(self, emitter_m: ArrayLike) -> FloatArray:
        """``E(s) = ∂e/∂s``, shape ``(..., 2K, d)``."""
        return self.jacobian(emitter_m) / self.sigma[:, None]

    def whitened_error_and_jacobian(self, emitter_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(e(s), E(s))`` in one pass (what a factor-graph linearisation needs)."""
        predicted, jacobian = self._evaluate(emitter_m, with_jacobian=True)
        assert jacobian is not None
        return (predicted - self.measured) / self.sigma, jacobian / self.sigma[:, None]

    def whitened_error_and_jacobian_per_sample(
        self, emitter_per_sample_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """``(e, E)`` with sample ``k`` evaluated at ``emitter_per_sample_m[k]`` (shape (K, d)).

        For a :meth:`stacked` model of frames that measure different emitter variables.
        """
        emitter = np.asarray(emitter_per_sample_m, dtype=float)
        predicted, jacobian = self._evaluate(emitter, with_jacobian=True, per_sample=True)
        assert jacobian is not None
        return (predicted - self.measured) / self.sigma, jacobian / self.sigma[:, None]

    def hessian(self, emitter_m: ArrayLike, *, per_sample: bool = False) -> FloatArray:
        """``∂²h/∂s²`` of every row, shape ``(2K, d, d)`` (MATH §8, from
        :func:`scenarios.measurement_model.doppler_range_derivatives`; ``per_sample``:
        ``emitter_m`` has shape (K, d), as in :meth:`whitened_error_and_jacobian_per_sample`)."""
        emitter = np.asarray(emitter_m, dtype=float)
        first = 1 + self.dimension  # the second derivatives' first component
        pairs = HESSIAN_SLOTS[self.dimension]
        if not per_sample and emitter.ndim == 1:  # one emitter: components first, one pass
            doppler, ranges = self.components(emitter, 2)
            second = np.concatenate([doppler[first:], ranges[first:]], axis=-1).T  # xx, xy, …
            return second[:, pairs]
        doppler, ranges = self.derivatives(emitter, 2, per_sample=per_sample)
        second = np.concatenate([doppler[:, first:], ranges[:, first:]])  # xx, xy, …
        return second[:, pairs]

    def curvature_terms(
        self, emitter_m: ArrayLike, error: ArrayLike, *, per_sample: bool = False
    ) -> FloatArray:
        """``e_k ∇²e_k`` of every row, shape ``(2K, d, d)``: summed, the part of the exact
        Hessian of ``½‖e‖²`` that Gauss-Newton's ``EᵀE`` leaves out (``error`` is ``e`` at
        ``emitter_m``)."""
        e = np.asarray(error, dtype=float)
        return (e / self.sigma)[:, None, None] * self.hessian(emitter_m, per_sample=per_sample)

    def information(self, emitter_m: ArrayLike) -> FloatArray:
        """The frame's Fisher information ``EᵀE`` (MATH §8), shape ``(..., d, d)``.

        The same quantity as :func:`scenarios.fisher.fisher_information` of the frame's ToA and
        Doppler: the range rows ``c∇τ_k/(c σ_τ)`` equal ``∇τ_k/σ_τ``. Formed from ``E`` (the
        rows the filter linearises with) by :func:`scenarios.fisher.gram_information`.
        """
        return gram_information(self.whitened_jacobian(emitter_m))

    def mean_range_m(self, emitter_m: ArrayLike) -> float:
        """Mean slant range to ``emitter_m``: the frame's length scale."""
        distance = model.slant_range_m(self.position_m, emitter_m, self.emitter_height_m)
        return float(np.mean(distance))
