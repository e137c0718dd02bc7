r"""The two mirror hypotheses of the frame-by-frame estimators (MATH §7).

On a straight track the emitter and its reflection across the track give identical measurements,
so both estimators (:mod:`estimators.sequential.ekf`, :mod:`estimators.sequential.gtsam_smoother`)
carry one hypothesis per mirror candidate of the first frame's closed form
(:class:`estimators.closed_form.cls.Cls`), weight them by their measurement likelihood and drop one
only when the other dominates. While every frame so far lies on one straight line
(:class:`scenarios.geometry.StraightTrack`), the second hypothesis is *computed* as the exact
reflection of the first (:func:`with_mirror`): its likelihood is then identical by construction, not
merely up to rounding, and the answer stays ambiguous. The first frame that leaves the line forks
the pair, and from then on each hypothesis is updated on its own (:func:`hypothesis_starts`). The
reported position is picked among the hypotheses by the tie rule of
:func:`estimators.base.finalize_estimate` (:func:`estimators.base.choose_candidate`).

A diffuse Gaussian prior, ``σ = DIFFUSE_PRIOR_SCALE ×`` the first frame's mean slant range, is
centred on each starting candidate. It changes a well-determined estimate by a relative
``~1e−10`` but keeps every linear system regular when the data do not fix a direction (an
emitter on the track, where the first-order cross-track information vanishes); whether the data
do is decided separately, from the rank of the accumulated Fisher information
(:func:`fisher_rank`), and reported.

**The height unknown** (MATH §7, §8). The hypotheses are 3-D points (their covariances and
information 3×3); a straight track then leaves a circle, not a pair, so the estimators start
their hypotheses only after a second heading (:func:`~estimators.sequential.nuisance_starts.
circle_starts`), and :func:`hypotheses_estimate` drops a hypothesis above the UAV's highest
sample (``ceiling_m``: the emitter is below the UAV).

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
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Estimate, check_rng, choose_candidate
from estimators.convergence import EstimationFailure
from scenarios.geometry import StraightTrack
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

RIDGELINE_POINTS = 513
"""Points along the ridgeline at which :func:`single_mode` evaluates the mixture density."""


def diffuse_prior_information(length_scale_m: float, dimension: int = 2) -> FloatArray:
    """``I / σ_d²`` with ``σ_d = DIFFUSE_PRIOR_SCALE × length_scale_m`` (see the module text),
    ``dimension × dimension``."""
    return np.eye(dimension) / (DIFFUSE_PRIOR_SCALE * length_scale_m) ** 2


def fisher_rank(information: ArrayLike) -> int:
    """Numerical rank of a Fisher information (eigenvalues below ``RANK_RTOL × max`` are 0)."""
    eigenvalues = np.linalg.eigvalsh(np.asarray(information, dtype=float))
    top = float(eigenvalues[-1])
    if not top > 0.0:
        return 0
    return int(np.sum(eigenvalues > RANK_RTOL * top))


# --------------------------------------------------------------------------------------------
# the mirror pair (MATH §7)
# --------------------------------------------------------------------------------------------


def hypothesis_starts(
    candidates: ArrayLike, first_track: StraightTrack | None, track: StraightTrack | None
) -> FloatArray:
    """Where the hypotheses start (MATH §7), one row each: ``candidates`` are the first frame's
    starting points (positions, or states whose first two entries are the position),
    ``first_track`` that frame's straight track, ``track`` the track of every frame given.

    Not straight: every candidate. Straight and still straight: the first candidate only (the
    second hypothesis is its reflection, computed, :func:`with_mirror`). Straight but the frames
    given at once (a batch solve) leave the line: the first and its reflection, each started
    on its own.
    """
    starts = np.array(candidates, dtype=float)
    if first_track is None:
        return starts
    if track is not None:
        return starts[:1]
    mirror = starts[:1].copy()
    mirror[:, :2] = first_track.mirror_point(starts[:1, :2])
    return np.vstack([starts[:1], mirror])


def with_mirror(hypotheses: Sequence[Any], track: StraightTrack | None) -> tuple[Any, ...]:
    """The explicit hypotheses plus, on a straight track, the reflection of the first
    (``hypothesis.mirrored(track)``): exactly equal weight by construction (MATH §7)."""
    if track is None or not hypotheses:
        return tuple(hypotheses)
    return (*hypotheses, hypotheses[0].mirrored(track))


def first_frame_candidates(frame: MeasurementSet) -> FloatArray:
    """The corrected closed form's candidates on the first frame (MATH §5-§7), shape (n, 2).

    Raises :class:`EstimationFailure` when the closed form cannot solve this frame.
    """
    from estimators.closed_form.cls import Cls

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
    means = np.array([mean_a, mean_b], dtype=float).reshape(2, -1)
    dimension = means.shape[1]
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
        log_norms.append(
            -float(np.sum(np.log(np.diag(factor)))) - 0.5 * dimension * np.log(2.0 * np.pi)
        )
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
    log_w = np.asarray(log_weights, dtype=float).reshape(-1)
    means = np.asarray(means_m, dtype=float).reshape(len(log_w), -1) if len(log_w) else log_w
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
    ceiling_m: float | None = None,
) -> Estimate:
    """The :class:`Estimate` of a set of weighted hypotheses (MATH §7).

    Candidates are the surviving hypotheses' means (merged as in :func:`surviving_hypotheses`,
    by covariance too once off a straight track), heaviest first; ``position_m`` is the
    heaviest, an exact tie (a straight track) broken by ``rng`` or, without one, by order
    (:func:`estimators.base.choose_candidate`, the tie rule of ``finalize_estimate``).
    ``ambiguous`` while more than one hypothesis lives or the track is straight. The
    covariance is the returned hypothesis's own (the error given that its side is right); it is
    withheld (None) when the accumulated Fisher information ``data_information`` of that
    hypothesis is rank-deficient, because then the data do not determine the emitter to first
    order and any finite covariance would be the diffuse prior's, not the data's.
    ``notes`` (e.g. a solver fallback) go into ``message``. A non-finite candidate is a failed
    estimate, never a success. With the height estimated (3-D means) ``ceiling_m`` is the UAV's
    highest sample height: a hypothesis above it is no answer (the mirror rule, MATH §7).
    """
    check_rng(rng)
    means = np.asarray(means_m, dtype=float).reshape(len(covariances_m2), -1)
    dimension = means.shape[1]
    log_weights = np.asarray(log_weights, dtype=float).reshape(-1)
    if ceiling_m is not None:  # those above the UAV weigh nothing
        log_weights = np.where(means[:, 2] > ceiling_m, -np.inf, log_weights)
        if not np.any(np.isfinite(log_weights)):
            return Estimate.failed(
                name, "no hypothesis below the UAV (MATH §7)", **dict(diagnostics or {})
            )
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
    # the tie rule of finalize_estimate: the heaviest, an exact tie broken by rng
    index, _ = choose_candidate(means[kept], log_w[0] - log_w, rng=rng, cost_rtol=0.0)
    chosen = kept[index]
    information = np.asarray(data_information, dtype=float).reshape(-1, dimension, dimension)
    rank = fisher_rank(information[chosen])
    covariance = np.asarray(covariances_m2[chosen], dtype=float) if rank == dimension else None
    messages = list(notes)
    if rank < dimension:
        messages.append(
            f"Fisher information of the data has rank {rank} < {dimension}: the emitter is not "
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


def smoother_estimate(
    name: str,
    state: Any,
    hypotheses: Sequence[Any],
    *,
    rng: np.random.Generator | None,
    notes: list[str],
    diagnostics: dict[str, Any],
    random_walk: bool,
    ceiling_m: float | None = None,
) -> Estimate:
    """:func:`hypotheses_estimate` of a smoother's state (its hypotheses' last positions,
    covariances, weights and data information), with the state's frame and iteration counts
    in the diagnostics; shared by the cooperative and the nuisance smoother (MATH §7, §15);
    ``ceiling_m`` as in :func:`hypotheses_estimate` (3-D)."""
    return hypotheses_estimate(
        name,
        [h.estimates_m[-1] for h in hypotheses],
        [h.covariance_m2 for h in hypotheses],
        [h.log_weight for h in hypotheses],
        [h.data_information for h in hypotheses],
        straight_track=state.track is not None,
        length_scale_m=state.length_scale_m,
        rng=rng,
        notes=notes,
        diagnostics={
            **diagnostics,
            "frames": state.n_frames,
            "iterations": state.iterations,
            "random_walk": random_walk,
        },
        ceiling_m=ceiling_m,
    )
