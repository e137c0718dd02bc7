r"""The nuisance parameters of a non-cooperative emitter as extra constant states (MATH §15).

With an unknown carrier offset δ every Doppler sample is ``f_k = −γ v_kᵀu_k + δ + w_k``, with an
unknown emission time b every one-way ToA is ``τ_k = ρ_k/c + b + n_k``, i.e. the range
``r_k = c τ_k = ρ_k + β + c n_k`` with ``β = c b`` in metres. The frame-by-frame estimators
(:mod:`estimators.sequential.ekf`, :mod:`estimators.sequential.gtsam_smoother`) carry the unknown
ones beside the emitter as constant states (no process noise on them), only the declared ones, in
the order δ (Hz), then β (m). :class:`NuisanceFrame` is :class:`~estimators.frame_model.FrameModel`
with that state: the same whitened error ``e(θ) = (h(θ) − z)/σ`` and Jacobian, so every iterated
update of :mod:`estimators.convergence` runs on it unchanged.

**Two parametrisations.** Without a reference (the smoother) the state is the physical one,

.. math::

    \theta = (x_s, y_s, \delta, \beta),\qquad h_k = [f_k(s) + \delta;\ \rho_k(s) + \beta],
    \qquad \partial f_k/\partial\delta = 1,\quad \partial r_k/\partial\beta = 1 .

With a reference sample ``(p₀, v₀)`` (the EKF: the first frame's mean position and velocity)
the nuisance states are the offset measurements *at the reference*,
``D = δ + f₀(s)`` and ``R = β + ρ₀(s)`` (``f₀``, ``ρ₀`` the noise-free Doppler and range of a
sample at ``p₀`` flying ``v₀``), so that

.. math::

    h_k = [f_k(s) - f_0(s) + D;\ \rho_k(s) - \rho_0(s) + R],\qquad
    \partial h_k/\partial s = [\nabla f_k - \nabla f_0;\ \nabla\rho_k - \nabla\rho_0],\quad
    \partial f_k/\partial D = \partial r_k/\partial R = 1 .

Both describe the same model (``(s, δ, β) ↦ (s, D, R)`` is a smooth bijection with a unit
triangular Jacobian, so the maximum likelihood, the ``(x, y)`` block of the inverse Fisher
information and every Laplace weight are the same). They differ in how *Gaussian* the
posterior looks. On one straight frame the cross-track distance ``c`` is fixed only weakly
once δ and β are unknown, and along that valley β must follow the mean range,
``β ≈ β̄ − c²/(2ρ)``: a banana in ``(c, β)``, which a filter that keeps the first frames as one
Gaussian linearises once and for all. In ``(c, R)`` the valley is nearly straight (``R`` is
what the ranges measure directly). Over 100 trials on ``paper-1m-turn`` with both unknown,
the IEKF's RMSE was 26× the nuisance CRLB at 20 dB and 2.5× at 40 dB in the physical
state, and 0.97× at both in the referenced one. The reference lies on the first frame's track
and flies along it, so ``D`` and ``R`` are unchanged by the mirror reflection (MATH §7).
The physical values are read back as ``δ = D − f₀(s)``, ``β = R − ρ₀(s)``
(:meth:`NuisanceFrame.physical_nuisance`, :meth:`NuisanceFrame.physical_covariance`).

**The position's information and covariance.** The reported covariance is the position's block
of the state's; the data's information about the position is the Schur complement of the
state's (:func:`position_information`), which over accumulated frames is the nuisance
information of :func:`scenarios.fisher.fisher_information` (MATH §8, §15: the affected rows
centred).

**The diffuse prior** (:func:`diffuse_information`) on the nuisance states is centred on the
start, like the position's (:mod:`estimators.sequential.mirror_hypotheses`): ``σ =
DIFFUSE_PRIOR_SCALE ×`` ``γ max|v|`` (the largest Doppler shift) for δ and ``×`` the length scale
for β. The starts are in :mod:`estimators.sequential.nuisance_starts`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.frame_model import FrameModel, read_only
from estimators.sequential.mirror_hypotheses import DIFFUSE_PRIOR_SCALE
from scenarios.fisher import gram_information
from scenarios.geometry import StraightTrack
from scenarios.nuisance import (
    HEIGHT_UNKNOWN,
    nuisance_unknowns,
    position_dimension,
    unknowns_used,
)
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]

NUISANCE_UNKNOWNS = frozenset({"carrier_offset_hz", "emission_time_s"})
"""What the frame-by-frame estimators declare in ``Capabilities.unknowns`` (MATH §15)."""

FRAME_MODALITIES = ("doppler", "toa")
"""The modalities of a frame model (:class:`~estimators.frame_model.FrameModel`)."""

_ROW = {"carrier_offset_hz": 0, "emission_time_s": 1}
"""The block of rows (Doppler 0, ranges 1) each nuisance parameter enters."""


def nuisance_names(data: MeasurementSet) -> tuple[str, ...]:
    """The unknown nuisance parameters of ``data`` that enter Doppler or ToA, in state order
    (the height, a coordinate of the position, is not one)."""
    return unknowns_used(nuisance_unknowns(data.unknowns), FRAME_MODALITIES)


def reference_sample(frame: MeasurementSet) -> FrameModel:
    """A one-sample model at the frame's mean position flying its mean velocity (module text):
    the reference of the referenced parametrisation. Its measurements are unused."""
    position = np.array(frame.position_m, dtype=float).mean(axis=0, keepdims=True)
    velocity = np.array(frame.velocity_mps, dtype=float).mean(axis=0, keepdims=True)
    measured, sigma = np.zeros(2), np.ones(2)
    read_only(position, velocity, measured, sigma)
    return FrameModel(
        position_m=position,
        velocity_mps=velocity,
        measured=measured,
        sigma=sigma,
        gamma_per_m=frame.gamma_per_m,
        emitter_height_m=frame.emitter_height_m,
        time_s=float(np.mean(frame.time_s)),
        dimension=position_dimension(frame.unknowns),
    )


def frame_model(
    frame: MeasurementSet, names: tuple[str, ...], reference: FrameModel | None = None
) -> FrameModel | NuisanceFrame:
    """The frame's model: :class:`FrameModel` with no unknowns (unchanged), else
    :class:`NuisanceFrame` carrying ``names`` (referenced to ``reference`` if given)."""
    base = FrameModel.from_measurements(frame)
    if not names:
        return base
    return NuisanceFrame(
        base=base, names=names, speed_of_light_mps=frame.speed_of_light_mps, reference=reference
    )


def stacked_frames(frames: Sequence[NuisanceFrame]) -> NuisanceFrame:
    """Frames measuring one emitter position as ONE :class:`NuisanceFrame` in the physical state
    (no reference): every Doppler row, then every range row (:meth:`FrameModel.stacked`); a
    single frame as it is."""
    if len(frames) == 1:
        return frames[0]
    base = FrameModel.stacked([frame.base for frame in frames])
    return NuisanceFrame(base, frames[0].names, frames[0].speed_of_light_mps)


def check_same_unknowns(names: tuple[str, ...], frame: MeasurementSet, dimension: int = 2) -> None:
    """Raise ``ValueError`` when a later frame declares other unknowns than the first (the
    nuisance ``names``; the height unknown when the position had ``dimension`` 3)."""
    if nuisance_names(frame) != names or position_dimension(frame.unknowns) != dimension:
        raise ValueError(
            f"unknowns: this frame declares {list(frame.unknowns)} but the earlier frames "
            f"declared {list(names) + ([HEIGHT_UNKNOWN] if dimension == 3 else [])}; the "
            "unknowns are the same over a pass (MATH §8, §15)"
        )


# --------------------------------------------------------------------------------------------
# the frame model with nuisance states
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class NuisanceFrame:
    """One frame's model in the state ``θ = (x_s, y_s, nuisance…)`` (module text).

    Attributes
    ----------
    base : FrameModel
        The frame's Doppler and ranges with the cooperative model of MATH §1.
    names : tuple of str
        The unknown nuisance parameters, a non-empty ordered subset of
        ``("carrier_offset_hz", "emission_time_s")``.
    speed_of_light_mps : float
        ``c``, to report ``b = β / c``.
    reference : FrameModel or None
        None: the state holds δ (Hz) and β (m). A one-sample model (:func:`reference_sample`):
        it holds ``D = δ + f₀(s)`` (Hz) and ``R = β + ρ₀(s)`` (m) at that sample.
    """

    base: FrameModel
    names: tuple[str, ...]
    speed_of_light_mps: float
    reference: FrameModel | None = None
    _columns: FloatArray = field(init=False, repr=False)
    _joint: FrameModel | None = field(init=False, repr=False)
    _base_rows: NDArray[np.intp] = field(init=False, repr=False)
    _reference_rows: NDArray[np.intp] = field(init=False, repr=False)
    _last: list[Any] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # the 0/1 columns A once, and the frame with its reference sample as ONE model: every
        # evaluation is one pass over the K + 1 samples (rows of the base, then of the reference)
        k = len(self.base.position_m)
        columns = np.zeros((2 * k, len(self.names)))
        for j, name in enumerate(self.names):
            columns[_ROW[name] * k : (_ROW[name] + 1) * k, j] = 1.0
        read_only(columns)
        joint = None if self.reference is None else FrameModel.stacked([self.base, self.reference])
        base_rows = np.concatenate([np.arange(k), np.arange(k + 1, 2 * k + 1)])
        reference_rows = np.array([k + _ROW[name] * (k + 1) for name in self.names])
        object.__setattr__(self, "_columns", columns)
        object.__setattr__(self, "_joint", joint)
        object.__setattr__(self, "_base_rows", base_rows)
        object.__setattr__(self, "_reference_rows", reference_rows)
        # the last single state evaluated, [state bytes, h, ∂h/∂θ or None] (see _rows)
        object.__setattr__(self, "_last", [b"", None, None])

    # -- the frame's data, as FrameModel ------------------------------------------------------

    @property
    def position_m(self) -> FloatArray:
        return self.base.position_m

    @property
    def velocity_mps(self) -> FloatArray:
        return self.base.velocity_mps

    @property
    def measured(self) -> FloatArray:
        return self.base.measured

    @property
    def sigma(self) -> FloatArray:
        return self.base.sigma

    @property
    def gamma_per_m(self) -> float:
        return self.base.gamma_per_m

    @property
    def emitter_height_m(self) -> float:
        return self.base.emitter_height_m

    @property
    def time_s(self) -> float:
        return self.base.time_s

    @property
    def n_rows(self) -> int:
        return self.base.n_rows

    @property
    def n_samples(self) -> int:
        return len(self.base.position_m)

    @property
    def dimension(self) -> int:
        """The emitter's coordinates ``d``: 2, or 3 with the height unknown (MATH §8)."""
        return self.base.dimension

    @property
    def n_state(self) -> int:
        """``d +`` the number of nuisance states."""
        return self.base.dimension + len(self.names)

    def columns(self) -> FloatArray:
        """``A``, shape ``(2K, n_u)``: the nuisance states' 0/1 columns, 1 on the Doppler rows
        for δ (or D), on the range rows for β (or R) (MATH §15)."""
        return self._columns

    # -- the reference's offsets g(s): D = δ + g_δ(s), R = β + g_β(s) -------------------------

    def offsets(self, position_m: ArrayLike) -> FloatArray:
        """``g(s) = (f₀(s), ρ₀(s))`` of the declared names at the reference, shape
        ``(..., n_u)``; zero without a reference (:func:`reference_offsets`)."""
        return reference_offsets(self.reference, self.names, position_m)

    def offsets_jacobian(self, position_m: ArrayLike) -> FloatArray:
        """``∂g/∂s``, shape ``(..., n_u, d)`` (:func:`reference_offsets_jacobian`)."""
        return reference_offsets_jacobian(self.reference, self.names, position_m)

    # -- the model ------------------------------------------------------------------------------

    def _rows(self, state: ArrayLike, with_jacobian: bool) -> tuple[FloatArray, FloatArray | None]:
        """``h(θ)`` and, if asked, ``∂h/∂θ`` (module text) from one pass of the forward model over
        the samples and the reference (:meth:`FrameModel.components`): each nuisance state
        shifts its block of rows, its reference value (and gradient) subtracted."""
        theta = np.asarray(state, dtype=float)
        # an iterated update evaluates its accepted point again (its cost, the convergence check,
        # the information): one state's values are kept and given back for the same bits
        key = theta.tobytes() if theta.ndim == 1 else None
        last = self._last
        if key is not None and last[0] == key and (last[2] is not None or not with_jacobian):
            return last[1], last[2] if with_jacobian else None
        model = self.base if self._joint is None else self._joint
        d = self.dimension
        doppler, ranges = model.components(theta[..., :d], int(with_jacobian))
        k = self.n_samples
        blocks = (doppler, ranges)
        rows = np.concatenate([doppler[..., :k], ranges[..., :k]], axis=-1)  # value, ∂x, ∂y(, ∂z)
        for j, name in enumerate(self.names):
            row = _ROW[name]
            block = rows[..., row * k : (row + 1) * k]
            shift = theta[..., d + j]
            if self._joint is not None:
                reference = blocks[row][..., k]  # the reference sample's value and gradient
                shift = shift - reference[0]
                block[1:] -= reference[1:, ..., None]
            block[0] += shift[..., None]
        predicted = rows[0]
        jacobian = None
        if with_jacobian:
            jacobian = np.empty((*predicted.shape, self.n_state))
            for i in range(d):
                jacobian[..., i] = rows[1 + i]
            jacobian[..., d:] = self._columns
        if key is not None:
            read_only(predicted, *(() if jacobian is None else (jacobian,)))
            last[:] = [key, predicted, jacobian]
        return predicted, jacobian

    def predicted(self, state: ArrayLike) -> FloatArray:
        """``h(θ)`` (module text), shape ``(..., 2K)``."""
        return self._rows(state, with_jacobian=False)[0]

    def predicted_and_jacobian(self, state: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(h(θ), ∂h/∂θ)`` (:meth:`predicted`, :meth:`jacobian`) in one pass over the samples
        and the reference."""
        predicted, jacobian = self._rows(state, with_jacobian=True)
        assert jacobian is not None
        return predicted, jacobian

    def jacobian(self, state: ArrayLike) -> FloatArray:
        """``∂h/∂θ = [∇h_k − A ∂g/∂s | A]`` (MATH §8, §15), shape ``(..., 2K, n)``."""
        return self.predicted_and_jacobian(state)[1]

    def whitened_error(self, state: ArrayLike) -> FloatArray:
        """``e(θ) = (h(θ) − z)/σ`` (predicted minus measured), shape ``(..., 2K)``."""
        return (self.predicted(state) - self.measured) / self.sigma

    def whitened_jacobian(self, state: ArrayLike) -> FloatArray:
        """``E(θ) = ∂e/∂θ``, shape ``(..., 2K, n)``."""
        return self.jacobian(state) / self.sigma[:, None]

    def whitened_error_and_jacobian(self, state: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(e(θ), E(θ))`` in one pass (:meth:`predicted_and_jacobian`)."""
        predicted, jacobian = self.predicted_and_jacobian(state)
        return (predicted - self.measured) / self.sigma, jacobian / self.sigma[:, None]

    def hessian(self, state: ArrayLike) -> FloatArray:
        """``∂²h/∂θ²`` of every row, shape ``(2K, n, n)``: MATH §8's (minus the reference's,
        in the referenced state) in the position's ``d × d`` block, zero elsewhere (the nuisance
        states enter linearly)."""
        theta = np.asarray(state, dtype=float)
        d = self.dimension
        hessian = np.zeros((self.n_rows, self.n_state, self.n_state))
        if self._joint is None:
            hessian[:, :d, :d] = self.base.hessian(theta[:d])
        else:
            joint = self._joint.hessian(theta[:d])
            hessian[:, :d, :d] = joint[self._base_rows]
            reference = joint[self._reference_rows]  # (n_u, d, d)
            hessian[:, :d, :d] -= np.einsum("kj,jab->kab", self._columns, reference)
        return hessian

    def curvature_terms(self, state: ArrayLike, error: ArrayLike) -> FloatArray:
        """``e_k ∇²e_k`` of every row, shape ``(2K, n, n)`` (as
        :meth:`FrameModel.curvature_terms`)."""
        e = np.asarray(error, dtype=float)
        return (e / self.sigma)[:, None, None] * self.hessian(state)

    def information(self, state: ArrayLike) -> FloatArray:
        """The frame's Fisher information of the whole state, ``EᵀE``, shape ``(n, n)``."""
        return gram_information(self.whitened_jacobian(state))

    def mean_range_m(self, state: ArrayLike) -> float:
        """Mean slant range to the emitter: the frame's length scale."""
        return self.base.mean_range_m(np.asarray(state, dtype=float)[: self.dimension])

    def doppler_scale_hz(self) -> float:
        """``γ max|v_k|``: the largest Doppler shift the frame can show."""
        speed = float(np.max(np.linalg.norm(self.velocity_mps, axis=1)))
        return self.gamma_per_m * speed

    # -- physical values -----------------------------------------------------------------------

    def state(self, position_m: ArrayLike, nuisance: ArrayLike) -> FloatArray:
        """The state of an emitter position and physical nuisance values ``(δ, β)``."""
        position = np.asarray(position_m, dtype=float)
        values = np.asarray(nuisance, dtype=float) + self.offsets(position)
        return np.concatenate([position, values], axis=-1)

    def position_map(self, state: ArrayLike) -> FloatArray:
        """``∂θ/∂s`` at fixed physical nuisance, shape ``(n, d)``: ``[I; ∂g/∂s]``. A random
        step ``ν`` of the emitter moves the state by ``M ν`` (the EKF's process noise)."""
        theta = np.asarray(state, dtype=float)
        d = self.dimension
        return np.vstack([np.eye(d), self.offsets_jacobian(theta[:d])])


def reference_offsets(
    reference: FrameModel | None, names: tuple[str, ...], position_m: ArrayLike
) -> FloatArray:
    """``g(s)``: the noise-free Doppler ``f₀(s)`` (for δ) and range ``ρ₀(s)`` (for β) at the
    reference sample, shape ``(..., n_u)``; zero without a reference (module text)."""
    position = np.asarray(position_m, dtype=float)
    if reference is None:
        return np.zeros((*position.shape[:-1], len(names)))
    return reference.predicted(position)[..., [_ROW[name] for name in names]]


def reference_offsets_jacobian(
    reference: FrameModel | None, names: tuple[str, ...], position_m: ArrayLike
) -> FloatArray:
    """``∂g/∂s`` of :func:`reference_offsets`, shape ``(..., n_u, d)`` (MATH §8)."""
    position = np.asarray(position_m, dtype=float)
    if reference is None:
        return np.zeros((*position.shape[:-1], len(names), position.shape[-1]))
    return reference.jacobian(position)[..., [_ROW[name] for name in names], :]


def physical_nuisance(
    reference: FrameModel | None,
    names: tuple[str, ...],
    state: ArrayLike,
    covariance: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """The physical ``(δ, β)`` of a state and their covariance: ``θ_n − g(s)`` and the
    nuisance block of ``T C Tᵀ``, ``T = [[I, 0], [−∂g/∂s, I]]`` (module text)."""
    theta = np.asarray(state, dtype=float)
    d = len(theta) - len(names)
    transform = np.eye(len(theta))
    transform[d:, :d] = -reference_offsets_jacobian(reference, names, theta[:d])
    full = transform @ np.asarray(covariance, dtype=float) @ transform.T
    return theta[d:] - reference_offsets(reference, names, theta[:d]), full[d:, d:]


# --------------------------------------------------------------------------------------------
# the position's share of a state's information, covariance, mirror image
# --------------------------------------------------------------------------------------------


def position_information(information: ArrayLike, dimension: int = 2) -> FloatArray:
    """``J_ss − J_sn J_nn⁻¹ J_ns``: the information left for the position's ``dimension``
    coordinates once the nuisance states are estimated too (MATH §15); a ``d × d`` input is
    returned as it is."""
    J = np.asarray(information, dtype=float)
    d = dimension
    if J.shape == (d, d):
        return J
    try:
        coupling = np.linalg.solve(J[d:, d:], J[d:, :d])
    except np.linalg.LinAlgError:
        return np.full((d, d), np.nan)
    schur = J[:d, :d] - J[:d, d:] @ coupling
    return 0.5 * (schur + schur.T)


def mirror_state(track: StraightTrack, state: ArrayLike) -> FloatArray:
    """The reflection of a state across a straight track (MATH §7): the position mirrored, the
    nuisance states unchanged (the measurements, and the reference on the track, are the
    same; so is a height, the third coordinate of a 3-D position). A 2-vector as
    :meth:`StraightTrack.mirror_point`."""
    theta = np.asarray(state, dtype=float)
    if theta.shape[-1] == 2:
        return track.mirror_point(theta)
    return np.concatenate([track.mirror_point(theta[..., :2]), theta[..., 2:]], axis=-1)


def mirror_matrix(track: StraightTrack, matrix: ArrayLike) -> FloatArray:
    """``M C Mᵀ`` with ``M = diag(reflection, I)``: a state covariance or information mirrored
    (the height's row, in 3-D, unchanged). A 2×2 as :meth:`StraightTrack.mirror_covariance`."""
    C = np.asarray(matrix, dtype=float)
    if C.shape == (2, 2):
        return track.mirror_covariance(C)
    _, direction = track.line()
    reflection = np.eye(len(C))
    reflection[:2, :2] = 2.0 * np.outer(direction, direction) - np.eye(2)
    return reflection @ C @ reflection.T


def nuisance_diagnostics(
    names: Iterable[str],
    nuisance: ArrayLike,
    covariance: ArrayLike | None,
    speed_of_light_mps: float,
) -> dict[str, Any]:
    """``Estimate.diagnostics`` entries of the estimated physical nuisance values ``(δ, β)``
    (``covariance``: theirs, ``(n_u, n_u)``): ``carrier_offset_hz`` (δ) and
    ``emission_time_s`` (``b = β/c``), each with its standard deviation
    (``carrier_offset_sigma_hz``, ``emission_time_sigma_s``; NaN without a covariance)."""
    values = np.asarray(nuisance, dtype=float)
    variances = (
        np.full(len(values), np.nan)
        if covariance is None
        else np.diag(np.asarray(covariance, dtype=float))
    )
    out: dict[str, Any] = {}
    for j, name in enumerate(names):
        sigma = math.sqrt(variances[j]) if variances[j] >= 0.0 else math.nan
        if name == "carrier_offset_hz":
            out["carrier_offset_hz"] = float(values[j])
            out["carrier_offset_sigma_hz"] = sigma
        else:
            out["emission_time_s"] = float(values[j]) / speed_of_light_mps
            out["emission_time_sigma_s"] = sigma / speed_of_light_mps
    return out


def profile_nuisance(frames: Iterable[NuisanceFrame], position_m: ArrayLike) -> FloatArray:
    """The physical nuisance values that fit the frames best for a fixed emitter position:
    ``δ̂ = mean(f_k − f_k(s))`` and ``β̂ = mean(r_k − ρ_k(s))`` over their samples (exact
    least squares for fixed ``s``: one σ per modality)."""
    frames = list(frames)
    position = np.asarray(position_m, dtype=float)
    residual = np.concatenate(
        [np.reshape(f.measured - f.base.predicted(position), (2, -1)) for f in frames], axis=1
    )
    return np.array([residual[_ROW[name]].mean() for name in frames[0].names])


# --------------------------------------------------------------------------------------------
# the diffuse prior
# --------------------------------------------------------------------------------------------


def diffuse_sigmas(frame: NuisanceFrame, length_scale_m: float) -> FloatArray:
    """The diffuse prior's σ of each state (module text): ``DIFFUSE_PRIOR_SCALE ×`` the length
    scale (position, β or R) or ``γ max|v|`` (δ or D)."""
    scales = [length_scale_m] * frame.dimension
    for name in frame.names:
        scales.append(frame.doppler_scale_hz() if name == "carrier_offset_hz" else length_scale_m)
    return DIFFUSE_PRIOR_SCALE * np.asarray(scales)


def diffuse_information(frame: NuisanceFrame, length_scale_m: float) -> FloatArray:
    """The diffuse prior's information on the whole state, ``diag(1/σ²)``
    (:func:`diffuse_sigmas`)."""
    return np.diag(1.0 / diffuse_sigmas(frame, length_scale_m) ** 2)
