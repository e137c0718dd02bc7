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
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
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


def iterated_update(
    frame: FrameModel,
    prior_mean_m: ArrayLike,
    prior_information: ArrayLike,
    *,
    start_m: ArrayLike | None = None,
    max_iterations: int = 50,
    step_rtol: float = 1e-12,
) -> tuple[FloatArray, FloatArray, float, int]:
    r"""Posterior mode of one frame given a Gaussian prior: the iterated EKF in information form.

    Gauss-Newton on ``‖e(s)‖² + (s − s̄)ᵀΛ̄(s − s̄)`` with step halving when the cost rises,

    .. math::

        s_{i+1} = s_i - (\bar\Lambda + E_i^\top E_i)^{-1}
                  \big(E_i^\top e_i + \bar\Lambda (s_i - \bar s)\big)

    started at ``start_m`` (default the prior mean). With a diffuse ``Λ̄`` this is the frame's
    maximum likelihood, started at a closed-form candidate (MATH §10); the 2×2 information form
    stays exact where a covariance-form gain would lose the digits of a huge prior variance.

    Returns
    -------
    mean_m : (2,)
    posterior_information : (2, 2)
        ``Λ̄ + EᵀE`` at the mode.
    log_likelihood : float
        :func:`laplace_log_likelihood` at the mode.
    iterations : int
    """
    prior_mean = np.asarray(prior_mean_m, dtype=float)
    Lambda = np.asarray(prior_information, dtype=float)
    point = prior_mean.copy() if start_m is None else np.asarray(start_m, dtype=float).copy()
    scale = max(frame.mean_range_m(point), np.finfo(float).tiny)
    cost = map_cost(frame, point, prior_mean, Lambda)
    iterations = 0
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
            break  # no decrease along the Gauss-Newton direction: at the mode to rounding
        point, cost = trial, trial_cost
        if np.linalg.norm(step) <= step_rtol * scale:
            break
    E = frame.whitened_jacobian(point)
    information = Lambda + E.T @ E
    if not np.all(np.isfinite(point)) or not np.all(np.isfinite(information)):
        raise EstimationFailure("the iterated update diverged (non-finite estimate)")
    return point, information, laplace_log_likelihood(cost, Lambda, information), iterations


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


def surviving_hypotheses(
    means_m: ArrayLike, log_weights: ArrayLike, length_scale_m: float
) -> tuple[list[int], FloatArray]:
    """Indices of the hypotheses to keep and their log weights, heaviest first.

    Two hypotheses at the same point (closer than ``MERGE_RTOL × length_scale_m``) are one:
    the heavier is kept with the weights added. Then every hypothesis whose normalised weight
    is below ``PRUNE_WEIGHT`` is dropped (MATH §7: the geometry has decided).
    """
    means = np.asarray(means_m, dtype=float).reshape(-1, 2)
    log_w = np.asarray(log_weights, dtype=float).reshape(-1)
    order = np.argsort(-log_w, kind="stable")
    kept: list[int] = []
    merged: list[float] = []
    for index in order:
        for slot, other in enumerate(kept):
            if np.linalg.norm(means[index] - means[other]) <= MERGE_RTOL * length_scale_m:
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
) -> Estimate:
    """The :class:`Estimate` of a set of weighted hypotheses (MATH §7).

    Candidates are the surviving hypotheses' means, heaviest first; ``position_m`` is the
    heaviest, an exact tie (a straight track) broken by ``rng`` or, without one, by order.
    ``ambiguous`` while more than one hypothesis lives or the track is straight. The
    covariance is the returned hypothesis's own (the error given that its side is right); it is
    withheld (None) when the accumulated Fisher information ``data_information`` of that
    hypothesis is rank-deficient, because then the data do not determine the emitter to first
    order and any finite covariance would be the diffuse prior's, not the data's.
    """
    check_rng(rng)
    means = np.asarray(means_m, dtype=float).reshape(-1, 2)
    kept, log_w = surviving_hypotheses(means, log_weights, length_scale_m)
    weights = normalised_weights(log_w)
    index = 0
    tied = np.flatnonzero(log_w == log_w[0])
    if len(tied) > 1 and rng is not None:
        index = int(tied[rng.integers(len(tied))])
    chosen = kept[index]
    information = np.asarray(data_information, dtype=float).reshape(-1, 2, 2)[chosen]
    rank = fisher_rank(information)
    covariance = np.asarray(covariances_m2[chosen], dtype=float) if rank == 2 else None
    message = ""
    if rank < 2:
        message = (
            f"Fisher information of the data has rank {rank} < 2: the emitter is not "
            "determined to first order (e.g. it lies on the track); covariance not reported"
        )
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
