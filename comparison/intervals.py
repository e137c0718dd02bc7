r"""Intervals of the numbers the verdicts judge (MATH §16), each computed from the trials.

- :func:`studentized_bootstrap_interval`: the bootstrap-t interval of a group's mean, for the
  mean squared error (the efficiency's interval) and the mean squared error along each
  principal axis of the CRLB (:func:`axis_squared_errors`); estimators that saw the same trials
  are resampled on the same trials.
- :func:`bias_intervals`: the mean error vector of a group and Hotelling's interval of its
  norm (:class:`BiasIntervals`).
- :func:`tail_share`: how much of a group's sum its largest 1% carry.
- :func:`nees_band`: the χ² band of a mean of consistent NEES values.

Why a studentized bootstrap for the mean squared error: the squared errors are skewed
(χ²-like when the estimator is efficient) and at low SNR heavy-tailed; a resample without the
few huge errors looks efficient, so the percentile interval's lower end says the bound is
plausible when the sample says otherwise. The bootstrap-t divides each resample's deviation by
its own standard error (Hall 1988; Efron & Tibshirani 1993, sec. 12.5); docs/math.md §16 gives
the derivation and the measured coverage.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from comparison.scoring import distance_m
from comparison.trial_rows import SCORED_DIMENSION
from estimators.goodness_of_fit import chi2_quantile

FloatArray = NDArray[np.float64]

TAIL_FRACTION = 0.01
"""The heavy-tail rule looks at the largest ``TAIL_FRACTION`` of the trials (at least one)."""

DEFAULT_N_BOOTSTRAP = 2000
"""Bootstrap resamples per group."""

AXIS_NAMES = ("major", "minor")
"""The principal axes of a 2×2 CRLB, largest variance first (:func:`axis_names` of 2)."""


def axis_names(dimension: int) -> tuple[str, ...]:
    """The principal axes of a ``d × d`` CRLB, largest variance first: ``major, minor`` for
    ``d = 2``, ``major, middle, minor`` for ``d = 3``."""
    if dimension == 2:
        return AXIS_NAMES
    if dimension == 3:
        return ("major", "middle", "minor")
    raise ValueError(f"dimension: principal axes are named for 2 or 3 coordinates, not {dimension}")


def largest_eigenvalue(matrix: ArrayLike) -> FloatArray:
    """The largest eigenvalue of symmetric matrices ``(..., d, d)``, shape ``(...)``; NaN where
    an entry is not finite. ``d = 2`` in closed form, ``m + √(((a − d)/2)² + b²)`` with
    ``m = (a + d)/2`` (``hypot`` against overflow); larger ones by ``eigvalsh``."""
    S = np.asarray(matrix, dtype=float)
    if S.shape[-1] == 2:
        a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
        return 0.5 * (a + d) + np.hypot(0.5 * (a - d), b)
    largest = np.full(S.shape[:-2], np.nan)
    finite = np.isfinite(S).all(axis=(-2, -1))
    if finite.any():
        largest[finite] = np.linalg.eigvalsh(S[finite])[..., -1]
    return largest


def short_number(value: float) -> str:
    """A number in a verdict's reason: three significant digits, ``∞`` for infinity."""
    return "∞" if value == np.inf else f"{value:.3g}"


def _grouped(values: ArrayLike, groups: ArrayLike, n_groups: int):
    """Finite values sorted by group, with each group's count and start."""
    values = np.asarray(values, dtype=float)
    codes = np.asarray(groups, dtype=np.int64)
    keep = np.isfinite(values)
    values, codes = values[keep], codes[keep]
    order = np.argsort(codes, kind="stable")
    values, codes = values[order], codes[order]
    counts = np.bincount(codes, minlength=n_groups)
    starts = np.cumsum(counts) - counts
    return values, codes, counts, starts


def studentized_bootstrap_interval(
    values: ArrayLike,
    groups: ArrayLike,
    n_groups: int,
    *,
    rng: np.random.Generator | None = None,
    key_seeds: ArrayLike | None = None,
    pairs: ArrayLike | None = None,
    n_bootstrap: int = DEFAULT_N_BOOTSTRAP,
    confidence: float = 0.95,
    max_draws: int = 2**24,
    threads: int | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Studentized (bootstrap-t) interval of the mean of every group.

    For a group with mean ``m`` and standard error ``se = s/√n``, every resample ``b`` gives
    ``t*_b = (m*_b − m)/se*_b``; the interval is ``[m − t*_{1−α/2} se, m − t*_{α/2} se]``
    (Efron & Tibshirani 1993, sec. 12.5), its lower end clipped at 0 for nonnegative data. A
    resample with ``se* = 0`` counts as ``t* = 0`` if its mean equals ``m`` and ``±∞``
    otherwise, so an interval may be unbounded above.

    Groups with the same ``pairs`` key are resampled with the same trial indices (for equal
    counts; the same uniform draws otherwise): estimators that saw the same trials are compared
    on the same resamples, as they were on the same data, so two estimators with the same
    errors get the same interval.

    The draws: ``rng`` gives every key a seed (keys in ascending order; or the caller gives
    them, ``key_seeds``, so that groups summarized a few at a time draw as all at once); the
    key's generator gives a ``(n_bootstrap, size)`` array ``U`` of uniforms, ``size`` the
    largest count of its groups, and a group of ``n`` values resamples the indices
    ``⌊n U[:, :n]⌋``. The result
    depends on nothing else: keys of equal counts are worked in blocks, on ``threads``
    threads, with the same numbers as one group at a time.

    Parameters
    ----------
    values : (n,)
        The data, e.g. squared errors; NaN entries (failed trials) are left out.
    groups : (n,) int
        Group index of each entry, in ``0 .. n_groups - 1``; within a group, entries in trial
        order.
    n_groups : int
    rng : numpy.random.Generator, optional
        Source of the resampling (seeded by the caller); one ``integers(0, 2**63)`` per key.
    key_seeds : (number of keys,) int, optional
        The keys' seeds instead of ``rng``'s (keys in ascending order).
    pairs : (n_groups,) int, optional
        The resampling key of every group (default: its own index).
    n_bootstrap : int
    confidence : float
    max_draws : int
        Memory bound: resampled values held at once per thread.
    threads : int, optional
        Threads working the blocks (default: the cores, at most :data:`MAX_THREADS`).

    Returns
    -------
    low, high : (n_groups,)
        NaN for a group with fewer than two finite values.
    """
    if int(n_bootstrap) != n_bootstrap or n_bootstrap < 2:
        raise ValueError(f"n_bootstrap: must be a whole number >= 2, got {n_bootstrap!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence!r}")
    values, _, counts, starts = _grouped(values, groups, n_groups)
    keys = np.arange(n_groups) if pairs is None else np.asarray(pairs, dtype=np.int64)
    n_bootstrap = int(n_bootstrap)
    alpha = 1.0 - confidence
    k_low = math.floor(alpha / 2 * n_bootstrap)
    k_high = min(math.ceil((1 - alpha / 2) * n_bootstrap) - 1, n_bootstrap - 1)
    unique_keys, key_of_group = np.unique(keys, return_inverse=True)
    if key_seeds is None:
        if rng is None:
            raise ValueError("rng: give a numpy Generator or the keys' seeds (key_seeds)")
        key_seeds = rng.integers(0, 2**63, size=unique_keys.size)
    key_seeds = np.asarray(key_seeds, dtype=np.int64)
    # the keys with a group of two values or more, in order, each with those groups
    resampled = np.flatnonzero(counts >= 2)
    members = resampled[np.argsort(key_of_group[resampled], kind="stable")]
    member_keys = key_of_group[members]
    ends = np.flatnonzero(np.diff(member_keys, prepend=-1, append=-1))
    work = [
        _KeyDraws(int(key_seeds[member_keys[a]]), members[a:b], counts[members[a:b]])
        for a, b in itertools.pairwise(ends)
    ]
    low = np.full(n_groups, np.nan)
    high = np.full(n_groups, np.nan)
    blocks = _blocks(work, n_bootstrap, max_draws)
    plan = _Plan(values, starts, n_bootstrap, max_draws, k_low, k_high, low, high)
    if threads is None:
        threads = min(MAX_THREADS, os.cpu_count() or 1)
    if min(len(blocks), int(threads)) <= 1:
        for block in blocks:
            plan.run(block)
    else:  # each block writes its own groups: the same numbers in any order
        with ThreadPoolExecutor(min(len(blocks), int(threads))) as pool:
            list(pool.map(plan.run, blocks))
    return low, high


MAX_THREADS = 4
"""Most threads :func:`studentized_bootstrap_interval` works on by default (numpy releases the
interpreter lock in the generation, the gathers and the sums that take its time)."""

BLOCK_DRAWS = 2**19
"""Resampled values a block of keys aims at: enough to work many small groups per numpy call,
few enough to stay in the processor's cache. A key of more (7 estimators × 500 trials ×
2000 resamples) is worked a few rows of draws at a time, which the generator's stream makes
the same numbers."""


@dataclass(frozen=True)
class _KeyDraws:
    """One resampling key: its generator's seed, its groups and their counts (each ≥ 2)."""

    seed: int
    groups: NDArray[np.int64]
    counts: NDArray[np.int64]


def _blocks(work: list[_KeyDraws], n_bootstrap: int, max_draws: int) -> list[list[_KeyDraws]]:
    """Consecutive keys in blocks of about :data:`BLOCK_DRAWS` resampled values."""
    blocks: list[list[_KeyDraws]] = []
    current: list[_KeyDraws] = []
    held = 0
    aim = min(BLOCK_DRAWS, max_draws)
    for key in work:
        size = int(key.counts.sum()) * n_bootstrap
        if current and held + size > aim:
            blocks.append(current)
            current, held = [], 0
        current.append(key)
        held += size
    if current:
        blocks.append(current)
    return blocks


@dataclass(frozen=True)
class _Plan:
    """The data and settings every block of :func:`studentized_bootstrap_interval` shares;
    each block writes its own groups' ends into ``low`` and ``high``."""

    values: FloatArray
    starts: NDArray[np.int64]
    n_bootstrap: int
    max_draws: int
    k_low: int
    k_high: int
    low: FloatArray
    high: FloatArray

    def run(self, block: list[_KeyDraws]) -> None:
        """The intervals of the groups of ``block``."""
        groups = np.concatenate([key.groups for key in block])
        counts = np.concatenate([key.counts for key in block])
        owner = np.repeat(np.arange(len(block)), [key.groups.size for key in block])
        deviations, means, ses = [], np.empty(groups.size), np.empty(groups.size)
        for i, (group, n) in enumerate(zip(groups.tolist(), counts.tolist(), strict=True)):
            sample = self.values[self.starts[group] : self.starts[group] + n]
            means[i] = float(sample.mean())
            deviation = sample - means[i]  # centred, so the variances do not cancel
            deviations.append(deviation)
            ses[i] = math.sqrt(float(deviation @ deviation) / (n - 1) / n)
        sizes = [int(key.counts.max()) for key in block]
        by_count = [(int(n), np.flatnonzero(counts == n)) for n in np.unique(counts).tolist()]
        t = np.empty((groups.size, self.n_bootstrap))
        # rows of draws at a time: the block's resampled values stay within the cache's aim
        held = min(self.max_draws, BLOCK_DRAWS) // max(int(counts.sum()), 1)
        rows = max(1, min(self.n_bootstrap, held))
        generators = [np.random.default_rng(key.seed) for key in block]
        for begin in range(0, self.n_bootstrap, rows):
            end = min(begin + rows, self.n_bootstrap)
            uniforms = [
                generator.random((end - begin, size))
                for generator, size in zip(generators, sizes, strict=True)
            ]
            for n, same in by_count:
                t[same, begin:end] = self._t(n, same, owner, uniforms, deviations)
        t.partition((self.k_low, self.k_high), axis=1)  # in place: t is not needed after
        low_t, high_t = t[:, [self.k_low, self.k_high]].T
        with np.errstate(invalid="ignore"):
            lower = means - high_t * ses
            upper = means - low_t * ses
        self.low[groups] = np.where(0.0 > lower, 0.0, lower)  # as max(lower, 0.0), NaN kept
        self.high[groups] = np.where(np.isnan(upper), np.inf, upper)

    @staticmethod
    def _t(
        n: int,
        same: NDArray[np.int64],
        owner: NDArray[np.int64],
        uniforms: list[FloatArray],
        deviations: list[FloatArray],
    ) -> FloatArray:
        """``t*`` of the groups ``same`` (all of ``n`` values) on these rows of draws."""
        rows = uniforms[0].shape[0]
        resampled = np.empty((same.size, rows, n))
        draws: dict[int, NDArray[np.intp]] = {}
        for i, member in enumerate(same.tolist()):
            key = int(owner[member])
            if key not in draws:  # the groups of a key share its draws: ⌊n U⌋
                draws[key] = np.empty((rows, n), dtype=np.intp)
                np.multiply(uniforms[key][:, :n], n, out=draws[key], casting="unsafe")
            np.take(deviations[member], draws[key], out=resampled[i], mode="clip")
        s1 = resampled.sum(axis=2)
        shift = s1 / n  # m* − m
        s2 = np.einsum("gij,gij->gi", resampled, resampled)
        se_star = np.sqrt(np.maximum(s2 - s1 * shift, 0.0) / (n - 1) / n)
        with np.errstate(divide="ignore", invalid="ignore"):
            part = np.where(se_star > 0, shift / se_star, np.sign(shift) * np.inf)
        return np.where(np.isnan(part), 0.0, part)


def tail_share(
    values: ArrayLike, groups: ArrayLike, n_groups: int, fraction: float = TAIL_FRACTION
) -> FloatArray:
    """Share of each group's sum carried by its largest ``fraction`` of values (at least one).

    NaN for a group without finite values or with a zero sum.
    """
    values, codes, counts, starts = _grouped(values, groups, n_groups)
    order = np.lexsort((-values, codes))
    values, codes = values[order], codes[order]
    rank = np.arange(values.size) - starts[codes]
    top = rank < np.maximum(np.ceil(fraction * counts), 1)[codes]
    top_sum = np.bincount(codes[top], weights=values[top], minlength=n_groups)
    total = np.bincount(codes, weights=values, minlength=n_groups)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, top_sum / total, np.nan)


@dataclass(frozen=True, slots=True, eq=False)
class BiasIntervals:
    """The mean error (bias) of every group, its norm's interval, and the bound it is judged
    against; the relative values (``ratio``, ``low``, ``high``) are in units of √trace(CRLB).

    Attributes
    ----------
    mean_m : (m, d)
        The mean error vector.
    low_m, high_m : (m,)
        The 95% interval of its norm (:func:`bias_intervals`).
    bound_m : (m,)
        √trace(CRLB) of each group.
    """

    mean_m: FloatArray
    low_m: FloatArray
    high_m: FloatArray
    bound_m: FloatArray

    @property
    def norm_m(self) -> FloatArray:
        """``‖mean_m‖`` (:func:`~comparison.scoring.distance_m`)."""
        return distance_m(self.mean_m)

    def _relative(self, value_m: FloatArray) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.bound_m > 0, value_m / self.bound_m, np.nan)

    @property
    def ratio(self) -> FloatArray:
        return self._relative(self.norm_m)

    @property
    def low(self) -> FloatArray:
        return self._relative(self.low_m)

    @property
    def high(self) -> FloatArray:
        return self._relative(self.high_m)

    def text(self, i: int) -> str:
        """Row ``i``'s bias in words, with its interval."""
        if not np.isfinite(self.high[i]):
            return "the bias (not measured: fewer than 3 errors, or no side-resolved position)"
        return (
            f"bias {short_number(self.norm_m[i])} m = {short_number(self.ratio[i])} √CRLB, 95% interval "
            f"[{short_number(self.low[i])}, {short_number(self.high[i])}]"
        )


def bias_intervals(
    error_m: ArrayLike,
    groups: ArrayLike,
    n_groups: int,
    bound_m: ArrayLike,
    confidence: float = 0.95,
) -> BiasIntervals:
    """The mean error of every group and a confidence interval of its norm.

    Hotelling's region for the mean of ``n`` ``d``-vectors with sample covariance ``S`` is the
    ellipsoid ``n (b − b̄)ᵀ S⁻¹ (b − b̄) ≤ T²``,
    ``T² = d(n − 1)/(n − d) F_{d,n−d}(confidence)`` (Anderson 2003, sec. 5.3). It reaches at
    most ``r = √(T² λ_max(S)/n)`` from its centre, so ``‖b‖`` lies in
    ``[max(‖b̄‖ − r, 0), ‖b̄‖ + r]`` with at least that confidence (the interval of the norm over
    the ellipsoid's enclosing sphere: conservative where ``S`` is elongated).

    Parameters
    ----------
    error_m : (n, d)
        Each trial's error vector (``d`` its coordinates, 2 or 3); rows with a NaN (failed
        trials) are left out.
    groups : (n,) int
    n_groups : int
    bound_m : (n_groups,)
        √trace(CRLB) of each group, which the relative values are in units of.
    confidence : float

    Returns
    -------
    BiasIntervals
        NaN for a group with fewer than ``d + 1`` finite errors.
    """
    error = np.asarray(error_m, dtype=float)
    p = error.shape[-1]
    error = error.reshape(-1, p)
    codes = np.asarray(groups, dtype=np.int64)
    keep = np.isfinite(error).all(axis=1)
    error, codes = error[keep], codes[keep]
    count = np.bincount(codes, minlength=n_groups).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.stack(
            [np.bincount(codes, weights=error[:, k], minlength=n_groups) / count for k in range(p)],
            axis=1,
        )
        d = error - mean[codes]  # centred, so the covariance does not cancel
        scatter = np.empty((n_groups, p, p))
        for i in range(p):
            for j in range(i, p):
                entry = np.bincount(codes, weights=d[:, i] * d[:, j], minlength=n_groups)
                scatter[:, i, j] = scatter[:, j, i] = entry / (count - 1)
        valid = count >= p + 1
        largest = np.where(valid, largest_eigenvalue(np.where(valid[:, None, None], scatter, 0)), 0)
        t2 = np.where(
            valid,
            # the F(p, n − p) quantile, what scipy.stats.f.ppf computes (to the bit)
            p * (count - 1) / (count - p) * special.fdtri(p, np.maximum(count - p, 1), confidence),
            np.nan,
        )
        reach = np.sqrt(t2 * np.maximum(largest, 0.0) / count)
    norm = distance_m(mean)
    mean[~valid] = np.nan
    return BiasIntervals(
        mean_m=mean,
        low_m=np.where(valid, np.maximum(norm - reach, 0.0), np.nan),
        high_m=np.where(valid, norm + reach, np.nan),
        bound_m=np.asarray(bound_m, dtype=float),
    )


@dataclass(frozen=True, slots=True, eq=False)
class AxisEfficiencies:
    """The efficiency along each principal axis of the CRLB (:func:`axis_names`), with its
    95% interval: arrays of shape ``(m, d)``."""

    efficiency: FloatArray
    low: FloatArray
    high: FloatArray


AXIS_BLOCK_ROWS = 2**16
"""Rows :func:`axis_squared_errors` works at a time (its memory: a few arrays of this many)."""


def axis_squared_errors(error_m: ArrayLike, crlb_m2: ArrayLike) -> FloatArray:
    """Each error's squared component along each principal axis of its CRLB, over that axis's
    variance: ``(uₖᵀe)²/λₖ`` for the eigenpairs of the CRLB, largest ``λ`` first.

    For an unbiased efficient estimator each has mean 1; for any unbiased estimator at least
    1, since ``E[eeᵀ] ⪰ CRLB``. Shapes: ``error_m (n, d)``, ``crlb_m2 (n, d, d)`` → ``(n, d)``;
    NaN where the CRLB is not finite. Rows with the same CRLB (one flight for all trials) share
    one eigen-decomposition.
    """
    crlb = np.asarray(crlb_m2, dtype=float)
    d = crlb.shape[-1]
    crlb = crlb.reshape(-1, d, d)
    error = np.asarray(error_m, dtype=float).reshape(-1, d)
    if len(error) > AXIS_BLOCK_ROWS:  # the same numbers a block of rows at a time
        blocks = range(0, len(error), AXIS_BLOCK_ROWS)
        return np.concatenate(
            [
                axis_squared_errors(error[i : i + AXIS_BLOCK_ROWS], crlb[i : i + AXIS_BLOCK_ROWS])
                for i in blocks
            ]
        )
    out = np.full((len(error), d), np.nan)
    finite = np.isfinite(crlb).all(axis=(1, 2))
    if not finite.any():
        return out
    distinct, inverse = np.unique(crlb[finite].reshape(-1, d * d), axis=0, return_inverse=True)
    variances, axes = np.linalg.eigh(distinct.reshape(-1, d, d))
    variances, axes = variances[:, ::-1], axes[:, :, ::-1]  # largest variance first
    along = np.einsum("nk,nkj->nj", error[finite], axes[inverse.reshape(-1)])
    with np.errstate(divide="ignore", invalid="ignore"):
        out[finite] = along**2 / variances[inverse.reshape(-1)]
    return out


def nees_band(
    n: ArrayLike, confidence: float = 0.95, *, dof: int = SCORED_DIMENSION
) -> tuple[FloatArray, FloatArray]:
    """Two-sided interval for the mean of ``n`` independent NEES values of ``dof`` degrees of
    freedom (the coordinates of the position ``d``: 2, or 3 with the height estimated; the
    default is :data:`~comparison.trial_rows.SCORED_DIMENSION`).

    If the estimator's covariance is consistent, each NEES is χ²(dof) and ``n`` times their
    mean is χ²(dof·n) (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2), so the mean lies in
    ``chi2.ppf([α/2, 1 − α/2], dof·n) / n`` with probability ``confidence``.

    Parameters
    ----------
    n : int or array of int
        Number of NEES values averaged; 0 gives NaN.
    confidence : float
        Coverage of the band, in (0, 1).
    dof : int
        Degrees of freedom of each NEES value.

    Returns
    -------
    low, high : arrays shaped like ``n``
    """
    if int(dof) != dof or dof < 1:
        raise ValueError(f"dof: a whole number of degrees of freedom >= 1, got {dof!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence!r}")
    count = np.asarray(n, dtype=float)
    if np.any(count < 0):
        raise ValueError("n: counts of NEES values must be >= 0")
    alpha = 1.0 - confidence
    with np.errstate(divide="ignore", invalid="ignore"):
        total = np.where(count > 0, float(dof) * count, np.nan)
        low = chi2_quantile(alpha / 2, total) / count
        high = chi2_quantile(1 - alpha / 2, total) / count
    return np.asarray(low, dtype=float), np.asarray(high, dtype=float)
