r"""Shared pieces of the frame-by-frame estimators: one frame's whitened model and the mirror pair.

Two things are common to :mod:`estimators.ekf` and :mod:`estimators.gtsam_smoother`.

**One frame's stacked, whitened measurement model** (MATH §1, §8, §10). A frame of K samples
gives ``m = 2K`` measurements ``z = [f_1..f_K, r_1..r_K]``, Doppler in Hz (physical sign) and
ToA as range ``r_k = c τ_k`` in metres with ``σ_r = c σ_τ``. Its whitened error and Jacobian are

.. math::

    e(s) = \frac{h(s) - z}{\sigma},\qquad
    E(s) = \frac{\partial e}{\partial (x_s, y_s)} = \Big[\frac{\nabla f_k}{\sigma_f};\
    \frac{c\,\nabla \tau_k}{\sigma_r}\Big]_k ,\qquad J_{\text{frame}}(s) = E^\top E

(predicted minus measured, GTSAM's sign convention), ``J_frame`` being the frame's Fisher
information of MATH §8. :class:`FrameModel` holds the frame as plain arrays, so it pickles and can
be rebuilt into filter or factor-graph objects inside any worker process.

**The two mirror hypotheses** (MATH §7). On a straight track the emitter and its reflection
across the track give identical measurements, so both estimators carry one hypothesis per mirror
candidate of the first frame's closed form (:class:`estimators.cls.Cls`), weight them by their
measurement likelihood and drop one only when the other dominates. While every frame so far lies
on one straight line (:class:`StraightTrack`), the second hypothesis is *computed* as the exact
reflection of the first: its likelihood is then identical by construction, not merely up to
rounding, and the answer stays ambiguous. The first frame that leaves the line forks the pair,
and from then on each hypothesis is updated on its own.

A diffuse Gaussian prior, ``σ = DIFFUSE_PRIOR_SCALE ×`` the first frame's mean slant range, is
centred on each starting candidate. It changes a well-determined estimate by a relative
``~1e−10`` but keeps every linear system regular when the data do not fix a direction (an
emitter on the track, where the first-order cross-track information vanishes); whether the data
do is decided separately, from the rank of the accumulated Fisher information
(:func:`fisher_rank`), and reported.

**Convergence** (no silent divergence). An iterate counts as converged only when its
decrement, in χ² units, is at most :data:`DECREMENT_TOL`. The decrement is the smaller of the
Gauss-Newton decrement ``gᵀΛ⁻¹g`` and, where the exact Hessian ``H = Λ + Σ_k e_k ∇²e_k`` is
positive definite, the Newton decrement ``gᵀH⁻¹g`` (``g`` the gradient of half the cost, ``Λ``
its Gauss-Newton information; Boyd & Vandenberghe §9.5.1). Either is the cost reduction its
quadratic model still predicts, and its square root the distance to the optimum in standard
deviations of the posterior: the criterion reads "within ``√DECREMENT_TOL`` posterior σ of a
local minimum". Near the track the Gauss-Newton model degenerates (the cross-track Jacobian
vanishes on the track while the residuals' own curvature does not), so its decrement stays
large arbitrarily close to an on-track minimum and its steps are metres long; the Newton
decrement there is the true, tiny remaining reduction. A step-length test would be fooled
either way. :class:`SolverReport` records the iterations used against the cap, the decrement
and why a solve did not converge; the estimators turn a non-converged solve into a fallback or
a failed estimate, never a silent success.

**Merging** (MATH §7). After a turn the mirror hypothesis of an iterated filter is pulled to
the true side, but its Gaussian prior, linearised on the mirror side for every earlier frame,
holds it short: at −20 dB on ``paper-1m-turn`` 44 % of the trials reported such a second
candidate after the turn, a median 1.9 m (at most 5.4 m, Mahalanobis distance at most 3.8)
from the first, with a relative weight between 1 and ``e^−21``. It is not a second answer: the
hypotheses' posterior, the mixture ``Σ_i w_i N(s; μ_i, P_i)``, has one mode there. So, off a
straight track, two hypotheses are merged when their two-component mixture is unimodal
(:func:`single_mode`): every critical point of a two-Gaussian mixture lies on its ridgeline
``x(α) = ((1−α)P_a⁻¹ + αP_b⁻¹)⁻¹((1−α)P_a⁻¹μ_a + αP_b⁻¹μ_b)``, ``α ∈ [0, 1]`` (Ray & Lindsay
2005), so the mixture is unimodal iff its density has no dip along that curve. No tuning
constant is involved; with equal weights and covariances it is the classical Mahalanobis
distance ``≤ 2`` (Eisenberger 1964), while a true mirror pair after a turn (about 30 m apart,
σ ≈ 1 m) always has two modes. The heavier hypothesis is kept, with the weights added. On a
straight track the exact mirror pair is never merged this way (its two minima are distinct,
MATH §5, §7).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Estimate, check_rng
from scenarios import measurement_model as model
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]

PRUNE_WEIGHT = 1e-9
"""A hypothesis whose normalised weight falls below this is dropped (the other has > 1 − 1e−9)."""

MERGE_RTOL = 1e-6
"""Hypotheses closer than ``MERGE_RTOL`` times the length scale are one hypothesis."""

DIFFUSE_PRIOR_SCALE = 1e3
"""The diffuse prior's σ in units of the first frame's mean slant range."""

RANK_RTOL = 1e-10
"""An eigenvalue of the Fisher information below ``RANK_RTOL ×`` the largest counts as zero."""

DECREMENT_TOL = 1e-4
"""An iterate is converged when its decrement (:func:`stationarity_decrement`, χ² units) is at
most this: it is then within ``0.01`` posterior standard deviations of a local minimum (see the
module text)."""

COST_ROUNDING_RTOL = 1e-10
"""...or when the decrement is below this fraction of the cost itself: a cost reduction that
small cannot be resolved in floating point (a hypothesis the data have refuted, whose χ² is
~1e12 on noise-free data, is then converged where it is, and its weight prunes it)."""

SADDLE_RTOL = 1e-9
"""An eigenvalue of an exact Hessian below ``−SADDLE_RTOL ×`` the largest is negative curvature
(the Hessian sums ``2K`` terms: its rounding is ``~1e−13`` relative): a saddle, not a minimum."""

ESCAPE_PROBES = 40
"""Points ``s + 2⁻ᵏ L v`` (``k < ESCAPE_PROBES``, ``L`` the length scale) probed along a saddle's
negative-curvature direction ``v`` for a start off it."""

RIDGELINE_POINTS = 513
"""Points along the ridgeline at which :func:`single_mode` evaluates the mixture density."""


class EstimationFailure(RuntimeError):
    """A solver could not produce an estimate; the estimators turn it into ``Estimate.failed``."""


# --------------------------------------------------------------------------------------------
# one frame's whitened measurement model
# --------------------------------------------------------------------------------------------


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
    """

    position_m: FloatArray
    velocity_mps: FloatArray
    measured: FloatArray
    sigma: FloatArray
    gamma_per_m: float
    emitter_height_m: float
    time_s: float

    @classmethod
    def from_measurements(cls, frame: MeasurementSet) -> FrameModel:
        """Stack one frame's Doppler and ToA; raise ``ValueError`` naming a missing field."""
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
        for array in arrays.values():
            array.flags.writeable = False
        return cls(
            **arrays,
            gamma_per_m=frame.gamma_per_m,
            emitter_height_m=frame.emitter_height_m,
            time_s=float(np.mean(frame.time_s)),
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
        )

    def _evaluate(
        self, emitter_m: ArrayLike, with_jacobian: bool, *, per_sample: bool = False
    ) -> tuple[FloatArray, FloatArray | None]:
        """``h(s)`` and, if asked, ``∂h/∂(x_s, y_s)``, sharing one pass over the samples.

        ``per_sample``: ``emitter_m`` has shape (K, 2), one emitter position per sample.
        """
        if per_sample:
            offset = model.emitter_offsets_m(
                self.position_m[:, None, :], emitter_m, self.emitter_height_m
            )[:, 0, :]
        else:
            offset = model.emitter_offsets_m(self.position_m, emitter_m, self.emitter_height_m)
        distance = np.linalg.norm(offset, axis=-1)
        unit = offset / distance[..., None]
        radial_mps = np.sum(self.velocity_mps * unit, axis=-1)  # v_kᵀ u_k
        # f_k = −γ v_kᵀu_k, ρ_k = ‖p_k − s‖ (MATH §1)
        predicted = np.concatenate([-self.gamma_per_m * radial_mps, distance], axis=-1)
        if not with_jacobian:
            return predicted, None
        # ∇f_k = γ (v_k − (v_kᵀu_k) u_k)_xy / ρ_k and ∇ρ_k = c ∇τ_k = −u_k,xy (MATH §8)
        tangential = self.velocity_mps - radial_mps[..., None] * unit
        doppler = self.gamma_per_m * tangential[..., :2] / distance[..., None]
        return predicted, np.concatenate([doppler, -unit[..., :2]], axis=-2)

    def predicted(self, emitter_m: ArrayLike) -> FloatArray:
        """``h(s) = [f_k(s); ρ_k(s)]`` (MATH §1), shape ``(..., 2K)``."""
        return self._evaluate(emitter_m, with_jacobian=False)[0]

    def jacobian(self, emitter_m: ArrayLike) -> FloatArray:
        """``∂h/∂(x_s, y_s) = [∇f_k; c ∇τ_k]`` (MATH §8), shape ``(..., 2K, 2)``."""
        jacobian = self._evaluate(emitter_m, with_jacobian=True)[1]
        assert jacobian is not None
        return jacobian

    def whitened_error(self, emitter_m: ArrayLike) -> FloatArray:
        """``e(s) = (h(s) − z)/σ`` (MATH §10, predicted minus measured), shape ``(..., 2K)``."""
        return (self.predicted(emitter_m) - self.measured) / self.sigma

    def whitened_jacobian(self, emitter_m: ArrayLike) -> FloatArray:
        """``E(s) = ∂e/∂(x_s, y_s)``, shape ``(..., 2K, 2)``."""
        return self.jacobian(emitter_m) / self.sigma[:, None]

    def whitened_error_and_jacobian(self, emitter_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(e(s), E(s))`` in one pass (what a factor-graph linearisation needs)."""
        predicted, jacobian = self._evaluate(emitter_m, with_jacobian=True)
        assert jacobian is not None
        return (predicted - self.measured) / self.sigma, jacobian / self.sigma[:, None]

    def whitened_error_and_jacobian_per_sample(
        self, emitter_per_sample_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """``(e, E)`` with sample ``k`` evaluated at ``emitter_per_sample_m[k]`` (shape (K, 2)).

        For a :meth:`stacked` model of frames that measure different emitter variables.
        """
        emitter = np.asarray(emitter_per_sample_m, dtype=float)
        predicted, jacobian = self._evaluate(emitter, with_jacobian=True, per_sample=True)
        assert jacobian is not None
        return (predicted - self.measured) / self.sigma, jacobian / self.sigma[:, None]

    def hessian(self, emitter_m: ArrayLike, *, per_sample: bool = False) -> FloatArray:
        r"""``∂²h/∂(x_s, y_s)²`` of every row, shape ``(2K, 2, 2)`` (``per_sample``: ``emitter_m``
        has shape (K, 2), as in :meth:`whitened_error_and_jacobian_per_sample`).

        With ``w = p_k − s``, ``ρ = ‖w‖``, ``u = w/ρ`` (3-D) and xy parts only:

        .. math::

            \nabla^2 \rho_k = \frac{I - u u^\top}{\rho},\qquad
            \nabla^2 f_k = \frac{\gamma}{\rho^2}\big(v u^\top + u v^\top
                + (v^\top u)(I - 3 u u^\top)\big).
        """
        emitter = np.asarray(emitter_m, dtype=float)
        if per_sample:
            offset = model.emitter_offsets_m(
                self.position_m[:, None, :], emitter, self.emitter_height_m
            )[:, 0, :]
        else:
            offset = model.emitter_offsets_m(self.position_m, emitter, self.emitter_height_m)
        distance = np.linalg.norm(offset, axis=-1)
        unit = offset / distance[:, None]
        radial = np.sum(self.velocity_mps * unit, axis=-1)  # vᵀu
        u, v = unit[:, :2], self.velocity_mps[:, :2]
        uu = u[:, :, None] * u[:, None, :]
        eye = np.eye(2)
        doppler = (
            self.gamma_per_m
            / distance[:, None, None] ** 2
            * (
                v[:, :, None] * u[:, None, :]
                + u[:, :, None] * v[:, None, :]
                + radial[:, None, None] * (eye - 3.0 * uu)
            )
        )
        ranges = (eye - uu) / distance[:, None, None]
        return np.concatenate([doppler, ranges])

    def curvature_terms(
        self, emitter_m: ArrayLike, error: ArrayLike, *, per_sample: bool = False
    ) -> FloatArray:
        """``e_k ∇²e_k`` of every row, shape ``(2K, 2, 2)``: summed, the part of the exact
        Hessian of ``½‖e‖²`` that Gauss-Newton's ``EᵀE`` leaves out (``error`` is ``e`` at
        ``emitter_m``)."""
        e = np.asarray(error, dtype=float)
        return (e / self.sigma)[:, None, None] * self.hessian(emitter_m, per_sample=per_sample)

    def information(self, emitter_m: ArrayLike) -> FloatArray:
        """The frame's Fisher information ``EᵀE`` (MATH §8), shape ``(..., 2, 2)``."""
        E = self.whitened_jacobian(emitter_m)
        if E.ndim == 2:
            return E.T @ E
        return np.einsum("...ki,...kj->...ij", E, E)

    def mean_range_m(self, emitter_m: ArrayLike) -> float:
        """Mean slant range to ``emitter_m``: the frame's length scale."""
        distance = model.slant_range_m(self.position_m, emitter_m, self.emitter_height_m)
        return float(np.mean(distance))


# --------------------------------------------------------------------------------------------
# convergence
# --------------------------------------------------------------------------------------------


def _decrement(information: FloatArray, gradient: FloatArray) -> float:
    """``gᵀA⁻¹g`` for a positive definite ``A``; ``inf`` if ``A`` is not (or not finite)."""
    if not (np.all(np.isfinite(gradient)) and np.all(np.isfinite(information))):
        return float("inf")
    try:
        factor = np.linalg.cholesky(0.5 * (information + information.T))
    except np.linalg.LinAlgError:
        return float("inf")
    whitened = np.linalg.solve(factor, gradient)
    value = float(whitened @ whitened)
    return value if np.isfinite(value) else float("inf")


def stationarity_decrement(
    information: ArrayLike, curvature: ArrayLike, gradient: ArrayLike
) -> float:
    """``min(gᵀΛ⁻¹g, gᵀH⁻¹g)``, ``H = Λ + curvature`` (the latter only if ``H ≻ 0``).

    ``information`` is the Gauss-Newton ``Λ``, ``curvature`` the residuals' own
    ``Σ e_k ∇²e_k`` (:meth:`FrameModel.curvature_terms`) and ``gradient`` that of half the
    cost; χ² units. See the module text ("Convergence").
    """
    Lambda = np.asarray(information, dtype=float)
    g = np.asarray(gradient, dtype=float)
    return min(_decrement(Lambda, g), _decrement(Lambda + np.asarray(curvature, dtype=float), g))


@dataclass(frozen=True, slots=True)
class SolverReport:
    """How an iterative solve ended (see the module text, "Convergence").

    Attributes
    ----------
    iterations, max_iterations : int
        Iterations used and the cap (a Newton refinement's included).
    decrement : float
        :func:`stationarity_decrement` at the returned point (χ² units).
    converged : bool
        ``decrement <= DECREMENT_TOL`` and the cost did not rise.
    reason : str
        Empty when converged; otherwise what happened (iteration cap, stall, cost rise).
    fallback : str
        ``"newton"`` when Gauss-Newton did not converge and :func:`newton_refine` took over,
        ``"saddle-escape"`` when the solve stopped at a saddle and was restarted off it
        (``fallback_reason`` says why); empty otherwise.
    fallback_reason : str
    cost_rose : bool
        The solve ended above its starting cost (a divergence; no fallback is tried).
    """

    iterations: int
    max_iterations: int
    decrement: float
    converged: bool
    reason: str = ""
    fallback: str = ""
    fallback_reason: str = ""
    cost_rose: bool = False


def convergence_report(
    iterations: int,
    max_iterations: int,
    decrement: float,
    *,
    stalled: bool,
    small_step: bool = False,
    cost_rose: bool = False,
    cost: float = 0.0,
    what: str = "Gauss-Newton",
) -> SolverReport:
    """Classify the end of an iterative solve: converged, iteration cap, stall or cost rise.

    Converged means ``decrement <= max(DECREMENT_TOL, COST_ROUNDING_RTOL · cost)`` without a
    cost rise, however the solver stopped (``cost``: the χ² at the returned point). Otherwise the reason names the stop: ``stalled`` (no step lowered the cost), the
    cap, ``small_step`` (the steps became negligible away from a minimum) or an early stop.
    """
    if cost_rose:
        return SolverReport(
            iterations, max_iterations, decrement, False, f"{what} raised the cost", cost_rose=True
        )
    if decrement <= max(DECREMENT_TOL, COST_ROUNDING_RTOL * cost):
        return SolverReport(iterations, max_iterations, decrement, True)
    if stalled:
        why = "stalled (no step lowers the cost)"
    elif small_step:
        why = "took negligible steps"
    elif iterations >= max_iterations:
        why = f"reached its iteration cap ({max_iterations})"
    else:
        why = "stopped early"
    return SolverReport(
        iterations,
        max_iterations,
        decrement,
        False,
        f"{what} {why} without converging (decrement {decrement:.3g} > {DECREMENT_TOL:g})",
    )


# --------------------------------------------------------------------------------------------
# Gaussian updates in information form
# --------------------------------------------------------------------------------------------


def map_cost(
    frame: FrameModel,
    emitter_m: ArrayLike,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
) -> float:
    """``‖e(s)‖² + (s − s̄)ᵀ Λ̄ (s − s̄)``: twice the negative log posterior of one update."""
    error = frame.whitened_error(emitter_m)
    offset = np.asarray(emitter_m, dtype=float) - np.asarray(prior_mean_m, dtype=float)
    return float(error @ error + offset @ np.asarray(prior_information) @ offset)


def laplace_log_likelihood(
    cost: float, prior_information: ArrayLike, posterior_information: ArrayLike
) -> float:
    r"""Log predictive likelihood of one frame by Laplace's method, up to a shared constant.

    For ``z = h(s) + w``, ``w ~ N(0, R)``, prior ``s ~ N(s̄, Λ̄⁻¹)`` and ``Λ = Λ̄ + EᵀE`` at the
    posterior mode ``ŝ``:

    .. math::

        \log p(z) \approx -\tfrac12\,\mathrm{cost}(\hat s)
            - \tfrac12\big(\log\det\Lambda - \log\det\bar\Lambda\big)
            - \tfrac12 \log\det(2\pi R)

    the last term, the same for every hypothesis of a frame, is left out. For a linear model it
    is the exact ``log N(z; h(s̄), H P̄ Hᵀ + R)`` (matrix determinant lemma); iterated to the mode
    it is the likelihood an iterated EKF should weigh hypotheses by (MATH §7).
    """
    _, logdet_post = np.linalg.slogdet(np.asarray(posterior_information, dtype=float))
    _, logdet_prior = np.linalg.slogdet(np.asarray(prior_information, dtype=float))
    return float(-0.5 * cost - 0.5 * (logdet_post - logdet_prior))


NEWTON_ITERATIONS = 20
"""Newton steps of :func:`newton_refine`, at most (it converges quadratically: 2-5 are used)."""

NEWTON_RTOL = 1e-8
""":func:`newton_refine` stops once the decrement is below ``NEWTON_RTOL × DECREMENT_TOL``."""


def newton_refine(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    start_m: ArrayLike,
    *,
    max_iterations: int = NEWTON_ITERATIONS,
) -> tuple[FloatArray, float, int, bool]:
    r"""Newton's method on one frame's posterior cost: the fallback when Gauss-Newton stalls.

    Steps ``−H⁻¹g`` with the exact Hessian ``H = Λ̄ + EᵀE + Σ e_k ∇²e_k`` while it is positive
    definite (else the Gauss-Newton step), halved while the cost rises, until the decrement is
    negligible. Near the track, where Gauss-Newton's model misses the curvature that holds an
    on-track minimum and creeps along the valley for hundreds of iterations (0.17 m short of the
    optimum after 1000 in one trial of ``paper-1m-turn`` at −20 dB), Newton reaches it in a few
    steps.

    Returns ``(point, cost, iterations, stalled)``.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = np.asarray(start_m, dtype=float).copy()
    cost = map_cost(frame, point, prior_mean, Lambda)
    iterations = 0
    while iterations < max_iterations:
        e, E = frame.whitened_error_and_jacobian(point)
        information = Lambda + E.T @ E
        curvature = np.sum(frame.curvature_terms(point, e), axis=0)
        gradient = E.T @ e + Lambda @ (point - prior_mean)
        if stationarity_decrement(information, curvature, gradient) <= NEWTON_RTOL * DECREMENT_TOL:
            break
        iterations += 1
        hessian = information + curvature
        try:
            np.linalg.cholesky(hessian)
            step = -np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            step = -np.linalg.solve(information, gradient)
        for _ in range(30):
            trial = point + step
            trial_cost = map_cost(frame, trial, prior_mean, Lambda)
            if trial_cost <= cost:
                break
            step = 0.5 * step
        else:
            return point, cost, iterations, True
        point, cost = trial, trial_cost
    return point, cost, iterations, False


def negative_curvature(hessian: ArrayLike) -> FloatArray | None:
    """A unit direction of negative curvature of a 2×2 Hessian beyond rounding
    (:data:`SADDLE_RTOL`), or None: a stationary point with one is a saddle, not a minimum."""
    values, vectors = np.linalg.eigh(np.asarray(hessian, dtype=float))
    if values[0] < -SADDLE_RTOL * max(abs(float(values[-1])), np.finfo(float).tiny):
        return vectors[:, 0]
    return None


def escape_probes(point_m: ArrayLike, direction: ArrayLike, length_m: float) -> FloatArray:
    """``point + 2⁻ᵏ L v`` for ``k < ESCAPE_PROBES``: where to look for a start off a saddle."""
    scales = length_m * 0.5 ** np.arange(ESCAPE_PROBES)
    return np.asarray(point_m, dtype=float) + scales[:, None] * np.asarray(direction, dtype=float)


def finish_update(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    point_m: ArrayLike,
    cost: float,
    report: SolverReport,
) -> tuple[FloatArray, float, FloatArray, SolverReport]:
    """The documented fallbacks of an iterated update, then the final report.

    1. Gauss-Newton did not converge (and did not raise the cost): :func:`newton_refine`
       finishes it (``report.fallback == "newton"``).
    2. The converged point is a saddle of the posterior cost (the exact Hessian has negative
       curvature, :func:`negative_curvature`): a start on the track's vertical plane stays on
       it by symmetry after the minimum has moved off the track. :func:`newton_refine` restarts
       from the lowest of :func:`escape_probes` along the negative curvature
       (``report.fallback == "saddle-escape"``); without a lower converged point the report is
       not converged.

    Returns ``(point, cost, posterior_information, report)``. Raises
    :class:`EstimationFailure` on a non-finite point.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = np.asarray(point_m, dtype=float)
    if not report.converged and not report.cost_rose and np.all(np.isfinite(point)):
        point, cost, report = _refined(frame, prior_mean, Lambda, point, report, "newton")
    if report.converged:
        information, curvature, _ = cost_derivatives(frame, prior_mean, Lambda, point)
        direction = negative_curvature(information + curvature)
        if direction is not None:
            saddle = "the update stopped at a saddle point of the posterior cost"
            probes = escape_probes(point, direction, frame.mean_range_m(point))
            costs = [map_cost(frame, probe, prior_mean, Lambda) for probe in probes]
            best = int(np.argmin(costs))
            escaped = False
            if costs[best] < cost:
                start = replace(report, converged=False, reason=saddle)
                refined, refined_cost, refined_report = _refined(
                    frame, prior_mean, Lambda, probes[best], start, "saddle-escape"
                )
                if refined_report.converged and refined_cost < cost:
                    point, cost, report, escaped = refined, refined_cost, refined_report, True
            if not escaped:
                report = replace(
                    report, converged=False, reason=f"{saddle}; no lower minimum was found off it"
                )
    E = frame.whitened_jacobian(point)
    information = Lambda + E.T @ E
    if not np.all(np.isfinite(point)) or not np.all(np.isfinite(information)):
        raise EstimationFailure("the iterated update diverged (non-finite estimate)")
    return point, cost, information, report


def _refined(
    frame: FrameModel,
    prior_mean: FloatArray,
    Lambda: FloatArray,
    point: FloatArray,
    report: SolverReport,
    fallback: str,
) -> tuple[FloatArray, float, SolverReport]:
    """:func:`newton_refine` from ``point`` after ``report``'s solve: the new point, its cost
    and the report (``fallback`` set, ``fallback_reason`` the old report's reason)."""
    start_cost = map_cost(frame, point, prior_mean, Lambda)
    point, cost, n_newton, stalled = newton_refine(frame, prior_mean, Lambda, point)
    decrement = stationarity_decrement(*cost_derivatives(frame, prior_mean, Lambda, point))
    refined = convergence_report(
        report.iterations + n_newton,
        report.max_iterations + NEWTON_ITERATIONS,
        decrement,
        stalled=stalled,
        cost_rose=not cost <= start_cost,
        cost=cost,
        what="Newton's method",
    )
    return (
        point,
        cost,
        replace(
            refined,
            reason=f"{report.reason}; {refined.reason}" if refined.reason else "",
            fallback=fallback,
            fallback_reason=report.reason,
        ),
    )


def iterated_update(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    *,
    start_m: ArrayLike | None = None,
    max_iterations: int = 50,
    step_rtol: float = 1e-12,
) -> tuple[FloatArray, FloatArray, float, SolverReport]:
    r"""Posterior mode of one frame given a Gaussian prior: the iterated EKF in information form.

    Gauss-Newton on ``‖e(s)‖² + (s − s̄)ᵀΛ̄(s − s̄)`` with step halving when the cost rises,

    .. math::

        s_{i+1} = s_i - (\bar\Lambda + E_i^\top E_i)^{-1}
                  \big(E_i^\top e_i + \bar\Lambda (s_i - \bar s)\big)

    started at ``start_m`` (default the prior mean), until a step is shorter than
    ``step_rtol ×`` the range. With a diffuse ``Λ̄`` this is the frame's maximum likelihood,
    started at a closed-form candidate (MATH §10); the 2×2 information form stays exact where a
    covariance-form gain would lose the digits of a huge prior variance. If Gauss-Newton has
    not converged then (decrement above :data:`DECREMENT_TOL`: its cap, a stall, or negligible
    steps in a near-track valley), :func:`newton_refine` takes over (:func:`finish_update`).

    Returns
    -------
    mean_m : (2,)
    posterior_information : (2, 2)
        ``Λ̄ + EᵀE`` at the mode.
    log_likelihood : float
        :func:`laplace_log_likelihood` at the mode.
    report : SolverReport
        Iterations against the cap, the decrement, whether the Newton fallback ran and whether
        the result converged; the caller decides what a non-converged update means.
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = prior_mean.copy() if start_m is None else np.asarray(start_m, dtype=float).copy()
    scale = max(frame.mean_range_m(point), np.finfo(float).tiny)
    cost = map_cost(frame, point, prior_mean, Lambda)
    start_cost = cost
    iterations = 0
    small_step = stalled = False
    while iterations < max_iterations:
        iterations += 1
        e, E = frame.whitened_error_and_jacobian(point)
        information = Lambda + E.T @ E
        gradient = E.T @ e + Lambda @ (point - prior_mean)
        step = -np.linalg.solve(information, gradient)
        for _ in range(30):
            trial = point + step
            trial_cost = map_cost(frame, trial, prior_mean, Lambda)
            if trial_cost <= cost:
                break
            step = 0.5 * step
        else:
            stalled = True  # no decrease along the Gauss-Newton direction
            break
        point, cost = trial, trial_cost
        if np.linalg.norm(step) <= step_rtol * scale:
            small_step = True
            break
    decrement = (
        stationarity_decrement(*cost_derivatives(frame, prior_mean, Lambda, point))
        if np.all(np.isfinite(point))
        else float("inf")
    )
    report = convergence_report(
        iterations,
        max_iterations,
        decrement,
        stalled=stalled,
        small_step=small_step,
        cost_rose=not cost <= start_cost,
        cost=cost,
        what="Gauss-Newton",
    )
    point, cost, information, report = finish_update(frame, prior_mean, Lambda, point, cost, report)
    return point, information, laplace_log_likelihood(cost, Lambda, information), report


def cost_derivatives(
    frame: FrameModel, prior_mean: FloatArray, prior_information: FloatArray, point: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(Λ̄ + EᵀE, Σ e_k ∇²e_k, g)`` of one frame's posterior cost at ``point``."""
    e, E = frame.whitened_error_and_jacobian(point)
    return (
        prior_information + E.T @ E,
        np.sum(frame.curvature_terms(point, e), axis=0),
        E.T @ e + prior_information @ (point - prior_mean),
    )


def read_only(*arrays: FloatArray) -> None:
    """Mark arrays read-only: a frozen dataclass alone does not stop in-place writes."""
    for array in arrays:
        array.flags.writeable = False


def diffuse_prior_information(length_scale_m: float) -> FloatArray:
    """``I / σ_d²`` with ``σ_d = DIFFUSE_PRIOR_SCALE × length_scale_m`` (see the module text)."""
    return np.eye(2) / (DIFFUSE_PRIOR_SCALE * length_scale_m) ** 2


def fisher_rank(information: ArrayLike) -> int:
    """Numerical rank of a 2×2 Fisher information (eigenvalues below ``RANK_RTOL × max`` are 0)."""
    eigenvalues = np.linalg.eigvalsh(np.asarray(information, dtype=float))
    top = float(eigenvalues[-1])
    if not top > 0.0:
        return 0
    return int(np.sum(eigenvalues > RANK_RTOL * top))


def symmetric_inverse(information: ArrayLike) -> FloatArray:
    """``Λ⁻¹`` symmetrised (a covariance from an information matrix)."""
    covariance = np.linalg.inv(np.asarray(information, dtype=float))
    return 0.5 * (covariance + covariance.T)


# --------------------------------------------------------------------------------------------
# the straight track and the mirror pair (MATH §7)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class StraightTrack:
    """The horizontal line every sample so far lies on and flies along (MATH §7).

    Kept as the first and last sample positions and one velocity, so that checking a new frame
    costs the same at frame 2 as at frame 1000.
    """

    ends_m: FloatArray
    velocity_mps: FloatArray

    @classmethod
    def of_frame(cls, frame: MeasurementSet | FrameModel) -> StraightTrack | None:
        """The frame's line, or None if its samples do not lie on one (MATH §7)."""
        if straight_track_line(frame.position_m, frame.velocity_mps) is None:
            return None
        ends = np.array(frame.position_m[[0, -1]], dtype=float)
        return cls(ends_m=ends, velocity_mps=np.array(frame.velocity_mps[0], dtype=float))

    def extended(self, frame: MeasurementSet | FrameModel) -> StraightTrack | None:
        """This line if ``frame`` continues it, else None (the frame turns off it)."""
        positions = np.vstack([self.ends_m, frame.position_m])
        velocities = np.vstack([self.velocity_mps, self.velocity_mps, frame.velocity_mps])
        if straight_track_line(positions, velocities) is None:
            return None
        ends = np.array([self.ends_m[0], frame.position_m[-1]], dtype=float)
        return StraightTrack(ends_m=ends, velocity_mps=self.velocity_mps)

    def line(self) -> tuple[FloatArray, FloatArray]:
        """``(origin_m, direction)`` of the line, both (2,)."""
        positions = np.vstack([self.ends_m, self.ends_m[:1]])
        velocities = np.tile(self.velocity_mps, (3, 1))
        line = straight_track_line(positions, velocities)
        assert line is not None  # a StraightTrack is only ever built from a straight line
        return line

    def mirror_point(self, points_m: ArrayLike) -> FloatArray:
        """Reflection of points (..., 2) across the track (MATH §7)."""
        return mirror_across_line(points_m, *self.line())

    def mirror_covariance(self, covariance_m2: ArrayLike) -> FloatArray:
        """``M C Mᵀ`` with the reflection ``M = 2ddᵀ − I`` (a covariance or an information)."""
        _, direction = self.line()
        reflection = 2.0 * np.outer(direction, direction) - np.eye(2)
        return reflection @ np.asarray(covariance_m2, dtype=float) @ reflection.T


def first_frame_candidates(frame: MeasurementSet) -> FloatArray:
    """The corrected closed form's candidates on the first frame (MATH §5-§7), shape (n, 2).

    Raises :class:`EstimationFailure` when the closed form cannot solve this frame.
    """
    from estimators.cls import Cls

    try:
        estimate = Cls().estimate(frame)
    except (np.linalg.LinAlgError, ArithmeticError, RuntimeError) as error:
        raise EstimationFailure(f"the closed form failed on the first frame ({error})") from None
    if not estimate.success or len(estimate.candidates_m) == 0:
        raise EstimationFailure(f"the closed form failed on the first frame: {estimate.message}")
    return np.array(estimate.candidates_m, dtype=float)


# --------------------------------------------------------------------------------------------
# weights, merging, pruning and the reported estimate
# --------------------------------------------------------------------------------------------


def normalised_weights(log_weights: ArrayLike) -> FloatArray:
    """``w_i = exp(ℓ_i) / Σ_j exp(ℓ_j)`` computed without overflow."""
    log_w = np.asarray(log_weights, dtype=float)
    shifted = np.exp(log_w - np.max(log_w))
    return shifted / shifted.sum()


def single_mode(
    log_weight_a: float,
    mean_a: ArrayLike,
    covariance_a: ArrayLike,
    log_weight_b: float,
    mean_b: ArrayLike,
    covariance_b: ArrayLike,
) -> bool:
    """True when ``w_a N(μ_a, P_a) + w_b N(μ_b, P_b)`` has a single mode (module text).

    The density is evaluated along the ridgeline (Ray & Lindsay 2005), which holds every
    critical point of the mixture; the mixture is unimodal iff that profile has no dip (an
    interior point below the maxima on both sides, beyond rounding). False when a mean or a
    weight is not finite, or a covariance not finite and positive definite.
    """
    means = np.array([mean_a, mean_b], dtype=float).reshape(2, 2)
    if not (np.all(np.isfinite(means)) and np.isfinite(log_weight_a) and np.isfinite(log_weight_b)):
        return False
    precisions = []
    log_norms = []
    for covariance in (covariance_a, covariance_b):
        C = np.asarray(covariance, dtype=float)
        if not np.all(np.isfinite(C)):
            return False
        try:
            factor = np.linalg.cholesky(0.5 * (C + C.T))
        except np.linalg.LinAlgError:
            return False
        inverse_factor = np.linalg.inv(factor)
        precisions.append(inverse_factor.T @ inverse_factor)
        log_norms.append(-float(np.sum(np.log(np.diag(factor)))) - np.log(2.0 * np.pi))
    alpha = np.linspace(0.0, 1.0, RIDGELINE_POINTS)[:, None, None]
    blend = (1.0 - alpha) * precisions[0] + alpha * precisions[1]
    rhs = (1.0 - alpha[:, :, 0]) * (precisions[0] @ means[0]) + alpha[:, :, 0] * (
        precisions[1] @ means[1]
    )
    ridge = np.linalg.solve(blend, rhs[..., None])[..., 0]
    log_density = []
    for log_weight, mean, precision, log_norm in zip(
        (log_weight_a, log_weight_b), means, precisions, log_norms, strict=True
    ):
        offset = ridge - mean
        quadratic = np.einsum("ni,ij,nj->n", offset, precision, offset)
        log_density.append(float(log_weight) + log_norm - 0.5 * quadratic)
    profile = np.logaddexp(*log_density)
    if not np.all(np.isfinite(profile)):
        return False
    left = np.maximum.accumulate(profile)
    right = np.maximum.accumulate(profile[::-1])[::-1]
    dip = np.minimum(left, right) - profile
    return bool(np.max(dip) <= 1e-9 * (1.0 + np.max(np.abs(profile))))


def surviving_hypotheses(
    means_m: ArrayLike,
    log_weights: ArrayLike,
    length_scale_m: float,
    covariances_m2: Sequence[ArrayLike] | None = None,
) -> tuple[list[int], FloatArray]:
    """Indices of the hypotheses to keep and their log weights, heaviest first.

    Two hypotheses at the same point (closer than ``MERGE_RTOL × length_scale_m``) are one; with
    ``covariances_m2`` (off a straight track only, see the module text) so are two whose
    weighted Gaussians form a unimodal mixture (:func:`single_mode`). The heavier is kept, with
    the weights added. Then every hypothesis whose normalised weight is below ``PRUNE_WEIGHT``
    is dropped (MATH §7: the geometry has decided).
    """
    means = np.asarray(means_m, dtype=float).reshape(-1, 2)
    log_w = np.asarray(log_weights, dtype=float).reshape(-1)
    order = np.argsort(-log_w, kind="stable")
    kept: list[int] = []
    merged: list[float] = []
    for index in order:
        for slot, other in enumerate(kept):
            same_point = np.linalg.norm(means[index] - means[other]) <= MERGE_RTOL * length_scale_m
            if same_point or (
                covariances_m2 is not None
                and single_mode(
                    merged[slot],
                    means[other],
                    covariances_m2[other],
                    log_w[index],
                    means[index],
                    covariances_m2[index],
                )
            ):
                merged[slot] = float(np.logaddexp(merged[slot], log_w[index]))
                break
        else:
            kept.append(int(index))
            merged.append(float(log_w[index]))
    weights = normalised_weights(merged)
    alive = [slot for slot, weight in enumerate(weights) if weight >= PRUNE_WEIGHT]
    return [kept[slot] for slot in alive], np.array([merged[slot] for slot in alive])


def hypotheses_estimate(
    name: str,
    means_m: ArrayLike,
    covariances_m2: Sequence[ArrayLike],
    log_weights: ArrayLike,
    data_information: ArrayLike,
    *,
    straight_track: bool,
    length_scale_m: float,
    rng: np.random.Generator | None = None,
    diagnostics: dict[str, Any] | None = None,
    notes: Sequence[str] = (),
) -> Estimate:
    """The :class:`Estimate` of a set of weighted hypotheses (MATH §7).

    Candidates are the surviving hypotheses' means (merged as in :func:`surviving_hypotheses`,
    by covariance too once off a straight track), heaviest first; ``position_m`` is the
    heaviest, an exact tie (a straight track) broken by ``rng`` or, without one, by order.
    ``ambiguous`` while more than one hypothesis lives or the track is straight. The
    covariance is the returned hypothesis's own (the error given that its side is right); it is
    withheld (None) when the accumulated Fisher information ``data_information`` of that
    hypothesis is rank-deficient, because then the data do not determine the emitter to first
    order and any finite covariance would be the diffuse prior's, not the data's.
    ``notes`` (e.g. a solver fallback) go into ``message``. A non-finite candidate is a failed
    estimate, never a success.
    """
    check_rng(rng)
    means = np.asarray(means_m, dtype=float).reshape(-1, 2)
    kept, log_w = surviving_hypotheses(
        means, log_weights, length_scale_m, None if straight_track else covariances_m2
    )
    if not np.all(np.isfinite(means[kept])):
        return Estimate.failed(
            name,
            "a hypothesis's estimate is not finite (the solver diverged)",
            **dict(diagnostics or {}),
        )
    weights = normalised_weights(log_w)
    index = 0
    tied = np.flatnonzero(log_w == log_w[0])
    if len(tied) > 1 and rng is not None:
        index = int(tied[rng.integers(len(tied))])
    chosen = kept[index]
    information = np.asarray(data_information, dtype=float).reshape(-1, 2, 2)[chosen]
    rank = fisher_rank(information)
    covariance = np.asarray(covariances_m2[chosen], dtype=float) if rank == 2 else None
    messages = list(notes)
    if rank < 2:
        messages.append(
            f"Fisher information of the data has rank {rank} < 2: the emitter is not "
            "determined to first order (e.g. it lies on the track); covariance not reported"
        )
    message = "; ".join(messages)
    return Estimate(
        estimator=name,
        position_m=means[chosen],
        candidates_m=means[kept],
        ambiguous=len(kept) > 1 or straight_track,
        covariance_m2=covariance,
        success=True,
        message=message,
        diagnostics=dict(
            diagnostics or {},
            weights=tuple(float(w) for w in weights),
            n_hypotheses=len(kept),
            fisher_rank=rank,
            straight_track=straight_track,
        ),
    )
