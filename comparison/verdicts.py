r"""Verdicts: does an estimator attain the CRLB, is its covariance consistent, and from which SNR.

Every verdict is computed from numbers that are printed beside it, and says ``inconclusive``
(with the reason) whenever those numbers cannot support a claim.

Efficiency verdict (one per summary row)
    The efficiency is ``η = RMSE / √CRLB`` (MATH §8), with the side-resolved RMSE (MATH §7)
    where the estimator flagged any estimate of the row as ambiguous. Its 95% interval comes
    from a studentized bootstrap of the mean squared error (:func:`studentized_bootstrap_interval`).
    The CRLB bounds unbiased estimators only, so two more numbers are judged: the bias
    ``β = ‖E[e]‖ / √CRLB`` with its interval (:func:`bias_intervals`), and the efficiency along
    each principal axis of the CRLB (:func:`axis_squared_errors`), since an unbiased estimator
    is at or above the bound in every direction (``E[eeᵀ] ⪰ CRLB``). The verdict is

    - ``attains``: the whole interval of η lies inside :data:`EFFICIENCY_BAND`, the whole
      interval of ``β`` at or below :data:`BIAS_LIMIT`, no axis wholly above the band, at least
      :data:`MIN_TRIALS` successful trials, a success rate of at least :data:`MIN_SUCCESS_RATE`,
      and no heavy tail (the largest 1% of the trials carry at most :data:`TAIL_SHARE_LIMIT` of
      the squared error);
    - ``biased``: the whole interval of ``β`` lies beyond :data:`BIAS_LIMIT`, or along an axis
      the whole interval lies below the band (only a biased estimator gets there): η is then
      no claim on the bound, whatever its value (unless η lies above the band by more than the
      bias explains, which stays ``above``);
    - ``above``: the whole interval of η, or of the efficiency along an axis, lies above the
      band;
    - ``below``: the whole interval of η lies below the band, with no bias resolved (only a
      biased estimator can be below the bound);
    - ``inconclusive``: anything else: too few trials, too many failures, heavy tails, an
      interval that straddles an edge of the band or a bias interval that reaches past the
      limit, or no finite bound.

Why a studentized bootstrap
    The squared errors of an estimator are skewed (χ²-like when it is efficient) and, at low
    SNR or far from the geometry it was built for, heavy-tailed: a few trials land kilometres
    away. The percentile bootstrap of the RMSE then fails on its lower side: resamples that
    happen to omit the few huge errors give an RMSE near the bound, and the interval's lower end
    says the bound is plausible when the sample says it is not (``ml`` on ``paper`` at 0 dB:
    RMSE 12.9 km against √CRLB 35 m, percentile interval [21 m, 22 km]). The studentized
    (bootstrap-t) interval of the mean divides each resample's deviation by that resample's own
    standard error: resamples without the outliers have a tiny standard error, hence a huge
    ``|t|``, which widens the *upper* end, while the lower end is set by resamples with as many
    outliers or more, which have large standard errors. It is second-order accurate for the mean
    of a skewed distribution (Hall 1988; Efron & Tibshirani 1993, sec. 12.5), where the percentile
    interval is first-order only, and it needs no parametric assumption. The heavy-tail rule
    then keeps an ``attains`` from resting on a sample whose mean is set by a handful of trials.

NEES verdict
    The mean NEES of ``n`` consistent 2-dof values lies in ``χ²₂ₙ`` quantiles ``/ n``
    (:func:`nees_band`): ``consistent`` inside the band, ``optimistic`` above it (the reported
    covariance is too small), ``pessimistic`` below it, ``inconclusive`` with fewer than
    :data:`MIN_TRIALS` values, ``no covariance`` for an estimator that reports none.

Threshold SNR
    Per scenario and estimator of an SNR sweep: the lowest SNR from which every higher point
    ``attains`` (:func:`threshold_snr`); NaN when the highest point does not.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy import stats

FloatArray = NDArray[np.float64]

EFFICIENCY_BAND: tuple[float, float] = (0.9, 1.1)
"""An estimator attains the CRLB when the 95% interval of its efficiency lies inside this."""

MIN_TRIALS = 30
"""Fewer successful trials than this give no verdict (``inconclusive``)."""

MIN_SUCCESS_RATE = 0.99
"""Smallest success rate at which an estimator can be said to attain the bound."""

TAIL_FRACTION = 0.01
"""The heavy-tail rule looks at the largest ``TAIL_FRACTION`` of the trials (at least one)."""

TAIL_SHARE_LIMIT = 0.25
"""Heavy tail: the largest 1% of the trials carry more than this share of the squared error.
An efficient estimator's largest 1% carry about 6% (exponential squared errors, n ≥ 100)."""

DEFAULT_N_BOOTSTRAP = 2000
"""Bootstrap resamples per group."""

BIAS_LIMIT = 0.3
"""``attains`` needs the whole 95% interval of the bias ``‖E[e]‖ / √trace(CRLB)`` at or below
this; a row whose whole interval lies beyond it is ``biased``. A bias of 0.3 √CRLB adds 9% of
the bound's mean squared error (docs/math.md, Verdicts and intervals)."""

AXIS_NAMES = ("major", "minor")
"""The principal axes of the CRLB, largest variance first."""

VERDICTS = ("attains", "above", "below", "biased", "inconclusive")
NEES_VERDICTS = ("consistent", "optimistic", "pessimistic", "inconclusive", "no covariance")


# --------------------------------------------------------------------------------------------
# intervals
# --------------------------------------------------------------------------------------------


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
    rng: np.random.Generator,
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

    The draws: ``rng`` gives every key a seed (keys in ascending order); the key's generator
    gives a ``(n_bootstrap, size)`` array ``U`` of uniforms, ``size`` the largest count of its
    groups, and a group of ``n`` values resamples the indices ``⌊n U[:, :n]⌋``. The result
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
    rng : numpy.random.Generator
        Source of the resampling (seeded by the caller).
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
    key_seeds = rng.integers(0, 2**63, size=unique_keys.size)
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
    mean_m : (m, 2)
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
        return np.hypot(self.mean_m[:, 0], self.mean_m[:, 1])

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
            f"bias {_fmt(self.norm_m[i])} m = {_fmt(self.ratio[i])} √CRLB, 95% interval "
            f"[{_fmt(self.low[i])}, {_fmt(self.high[i])}]"
        )


def bias_intervals(
    error_m: ArrayLike,
    groups: ArrayLike,
    n_groups: int,
    bound_m: ArrayLike,
    confidence: float = 0.95,
) -> BiasIntervals:
    """The mean error of every group and a confidence interval of its norm.

    Hotelling's region for the mean of ``n`` 2-vectors with sample covariance ``S`` is the
    ellipse ``n (b − b̄)ᵀ S⁻¹ (b − b̄) ≤ T²``, ``T² = 2(n − 1)/(n − 2) F₂,ₙ₋₂(confidence)``
    (Anderson 2003, sec. 5.3). It reaches at most ``r = √(T² λ_max(S)/n)`` from its centre, so
    ``‖b‖`` lies in ``[max(‖b̄‖ − r, 0), ‖b̄‖ + r]`` with at least that confidence (the interval
    of the norm over the ellipse's enclosing circle: conservative where ``S`` is elongated).

    Parameters
    ----------
    error_m : (n, 2)
        Each trial's error vector; rows with a NaN (failed trials) are left out.
    groups : (n,) int
    n_groups : int
    bound_m : (n_groups,)
        √trace(CRLB) of each group, which the relative values are in units of.
    confidence : float

    Returns
    -------
    BiasIntervals
        NaN for a group with fewer than three finite errors.
    """
    error = np.asarray(error_m, dtype=float).reshape(-1, 2)
    codes = np.asarray(groups, dtype=np.int64)
    keep = np.isfinite(error).all(axis=1)
    error, codes = error[keep], codes[keep]
    count = np.bincount(codes, minlength=n_groups).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.stack(
            [np.bincount(codes, weights=error[:, k], minlength=n_groups) / count for k in (0, 1)],
            axis=1,
        )
        d = error - mean[codes]  # centred, so the covariance does not cancel
        sxx, sxy, syy = (
            np.bincount(codes, weights=a * b, minlength=n_groups) / (count - 1)
            for a, b in ((d[:, 0], d[:, 0]), (d[:, 0], d[:, 1]), (d[:, 1], d[:, 1]))
        )
        largest = 0.5 * (sxx + syy) + np.hypot(0.5 * (sxx - syy), sxy)
        valid = count >= 3
        t2 = np.where(
            valid,
            2 * (count - 1) / (count - 2) * stats.f.ppf(confidence, 2, np.maximum(count - 2, 1)),
            np.nan,
        )
        reach = np.sqrt(t2 * np.maximum(largest, 0.0) / count)
    norm = np.hypot(mean[:, 0], mean[:, 1])
    mean[~valid] = np.nan
    return BiasIntervals(
        mean_m=mean,
        low_m=np.where(valid, np.maximum(norm - reach, 0.0), np.nan),
        high_m=np.where(valid, norm + reach, np.nan),
        bound_m=np.asarray(bound_m, dtype=float),
    )


@dataclass(frozen=True, slots=True, eq=False)
class AxisEfficiencies:
    """The efficiency along each principal axis of the CRLB (:data:`AXIS_NAMES`), with its
    95% interval: arrays of shape ``(m, 2)``."""

    efficiency: FloatArray
    low: FloatArray
    high: FloatArray


def axis_squared_errors(error_m: ArrayLike, crlb_m2: ArrayLike) -> FloatArray:
    """Each error's squared component along each principal axis of its CRLB, over that axis's
    variance: ``(uₖᵀe)²/λₖ`` for the eigenpairs of the CRLB, largest ``λ`` first.

    For an unbiased efficient estimator each has mean 1; for any unbiased estimator at least
    1, since ``E[eeᵀ] ⪰ CRLB``. Shapes: ``error_m (n, 2)``, ``crlb_m2 (n, 2, 2)`` → ``(n, 2)``;
    NaN where the CRLB is not finite. Rows with the same CRLB (one flight for all trials) share
    one eigen-decomposition.
    """
    error = np.asarray(error_m, dtype=float).reshape(-1, 2)
    crlb = np.asarray(crlb_m2, dtype=float).reshape(-1, 2, 2)
    out = np.full((len(error), 2), np.nan)
    finite = np.isfinite(crlb).all(axis=(1, 2))
    if not finite.any():
        return out
    distinct, inverse = np.unique(crlb[finite].reshape(-1, 4), axis=0, return_inverse=True)
    variances, axes = np.linalg.eigh(distinct.reshape(-1, 2, 2))
    variances, axes = variances[:, ::-1], axes[:, :, ::-1]  # largest variance first
    along = np.einsum("nk,nkj->nj", error[finite], axes[inverse.reshape(-1)])
    with np.errstate(divide="ignore", invalid="ignore"):
        out[finite] = along**2 / variances[inverse.reshape(-1)]
    return out


def _above_along(axes: AxisEfficiencies, i: int, band_high: float) -> str:
    """Along which principal axis of the CRLB row ``i`` lies wholly above the band, in words;
    empty when along none. The trace efficiency can sit in the band while the error along the
    bound's thin axis is several times the bound there (a curved likelihood valley)."""
    return "; ".join(
        f"along the CRLB's {name} axis its RMSE is {_fmt(axes.efficiency[i, k])} of the bound's, "
        f"95% interval [{_fmt(axes.low[i, k])}, {_fmt(axes.high[i, k])}], above {band_high:g}"
        for k, name in enumerate(AXIS_NAMES)
        if axes.low[i, k] > band_high
    )


def _bias_explains(efficiency: float, bias: BiasIntervals, i: int, band_high: float) -> bool:
    """Whether the bias alone lifts row ``i`` above the band: without it (``η² − β²``, the
    variance's share of the efficiency) the row would not lie above ``band_high``."""
    return bool(efficiency**2 - bias.ratio[i] ** 2 <= band_high**2)


def nees_band(n: ArrayLike, confidence: float = 0.95) -> tuple[FloatArray, FloatArray]:
    """Two-sided interval for the mean of ``n`` independent 2-dof NEES values.

    If the estimator's covariance is consistent, each NEES is χ²(2) and ``n`` times their mean
    is χ²(2n) (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2), so the mean lies in
    ``chi2.ppf([α/2, 1 − α/2], 2n) / n`` with probability ``confidence``.

    Parameters
    ----------
    n : int or array of int
        Number of NEES values averaged; 0 gives NaN.
    confidence : float
        Coverage of the band, in (0, 1).

    Returns
    -------
    low, high : arrays shaped like ``n``
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence!r}")
    count = np.asarray(n, dtype=float)
    if np.any(count < 0):
        raise ValueError("n: counts of NEES values must be >= 0")
    alpha = 1.0 - confidence
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(count > 0, 2.0 * count, np.nan)
        low = stats.chi2.ppf(alpha / 2, dof) / count
        high = stats.chi2.ppf(1 - alpha / 2, dof) / count
    return np.asarray(low, dtype=float), np.asarray(high, dtype=float)


# --------------------------------------------------------------------------------------------
# verdicts
# --------------------------------------------------------------------------------------------


def _fmt(value: float) -> str:
    return "∞" if value == np.inf else f"{value:.3g}"


def efficiency_verdicts(
    *,
    n_judged: ArrayLike,
    n_trials: ArrayLike,
    efficiency: ArrayLike,
    low: ArrayLike,
    high: ArrayLike,
    tail: ArrayLike,
    bias: BiasIntervals,
    axes: AxisEfficiencies,
    band: tuple[float, float] = EFFICIENCY_BAND,
) -> tuple[NDArray[np.str_], list[str]]:
    """The efficiency verdict of every row and its reason (module docstring).

    Parameters
    ----------
    n_judged : (m,)
        Successful trials with a finite judged error.
    n_trials : (m,)
        Every trial, failed ones included (the success rate is ``n_judged / n_trials``).
    efficiency, low, high : (m,)
        The judged efficiency and its 95% interval (NaN: no finite bound or no estimate).
    tail : (m,)
        :func:`tail_share` of the judged squared errors.
    bias : BiasIntervals
        The judged error's mean and its interval, relative to √trace(CRLB)
        (:func:`bias_intervals`, :meth:`BiasIntervals.relative_to`).
    axes : AxisEfficiencies
        The efficiency along each principal axis of the CRLB, with intervals.
    band : (low, high)

    Returns
    -------
    verdicts : (m,) str
        One of :data:`VERDICTS`.
    reasons : list of str
    """
    band_low, band_high = band
    if not 0 < band_low < 1 < band_high:
        raise ValueError(f"band: expected 0 < low < 1 < high, got {band!r}")
    n = np.asarray(n_judged, dtype=float)
    total = np.asarray(n_trials, dtype=float)
    eta = np.asarray(efficiency, dtype=float)
    lo, hi = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    share = np.asarray(tail, dtype=float)
    verdicts: list[str] = []
    reasons: list[str] = []
    for i in range(len(n)):
        interval = f"efficiency {_fmt(eta[i])}, 95% interval [{_fmt(lo[i])}, {_fmt(hi[i])}]"
        counted = f"n = {int(n[i])}"
        heavy = bool(share[i] > TAIL_SHARE_LIMIT)
        tail_note = (
            f"heavy tail: the largest 1% of the trials carry {100 * share[i]:.0f}% of the "
            "squared error"
        )
        rate = n[i] / total[i] if total[i] > 0 else math.nan
        biased_by = _bias_finding(bias, axes, i, band_low)
        if n[i] == 0:
            verdict, reason = "inconclusive", "no successful estimate"
        elif not (np.isfinite(eta[i]) and np.isfinite(lo[i])):
            verdict, reason = "inconclusive", "no finite bound (singular Fisher information)"
        elif n[i] < MIN_TRIALS:
            verdict = "inconclusive"
            reason = f"too few trials: {int(n[i])} < {MIN_TRIALS} ({interval})"
        elif lo[i] > band_high and not (biased_by and _bias_explains(eta[i], bias, i, band_high)):
            verdict = "above"
            reason = f"{interval} lies above {band_high:g} ({counted})"
            reason += f"; {tail_note}" if heavy else ""
            reason += f"; also {biased_by}" if biased_by else ""
        elif biased_by:
            verdict = "biased"
            reason = (
                f"{biased_by}; the CRLB bounds only unbiased estimators, so its {interval} "
                f"says nothing about the bound ({counted})"
            )
        elif above_along := _above_along(axes, i, band_high):
            verdict = "above"
            reason = f"{above_along}, though its {interval} ({counted})"
        elif hi[i] < band_low:
            verdict = "below"
            reason = (
                f"{interval} lies below {band_low:g} ({counted}): only a biased estimator can "
                "be below the bound, and these trials do not resolve its bias"
            )
        elif rate < MIN_SUCCESS_RATE:
            verdict = "inconclusive"
            reason = (
                f"only {100 * rate:.1f}% of the estimates succeeded ({int(n[i])} of "
                f"{int(total[i])}; {100 * MIN_SUCCESS_RATE:g}% needed); {interval}"
            )
        elif heavy:
            verdict, reason = "inconclusive", f"{tail_note} ({interval}, {counted})"
        elif not bias.high[i] <= BIAS_LIMIT:
            verdict = "inconclusive"
            reason = (
                f"{bias.text(i)} may reach past {BIAS_LIMIT:g} √CRLB ({interval}, {counted}); "
                "more trials would tell whether it is negligible"
            )
        elif band_low <= lo[i] and hi[i] <= band_high:
            verdict = "attains"
            reason = (
                f"{interval} inside [{band_low:g}, {band_high:g}], {bias.text(i)} within "
                f"{BIAS_LIMIT:g} √CRLB ({counted})"
            )
        else:
            verdict = "inconclusive"
            reason = (
                f"{interval} straddles an edge of [{band_low:g}, {band_high:g}] ({counted}); "
                "more trials would narrow it"
            )
        verdicts.append(verdict)
        reasons.append(reason)
    return np.asarray(verdicts, dtype=str), reasons


def _bias_finding(bias: BiasIntervals, axes: AxisEfficiencies, i: int, band_low: float) -> str:
    """What shows row ``i``'s estimator biased, in words; empty when nothing does.

    Either its mean error is beyond :data:`BIAS_LIMIT` √CRLB (the whole interval), or along a
    principal axis of the CRLB its error is below the bound (the whole interval below the
    band's low edge), which no unbiased estimator can reach (``E[eeᵀ] ⪰ CRLB``).
    """
    found = []
    if bias.low[i] > BIAS_LIMIT:
        found.append(f"{bias.text(i)} lies beyond {BIAS_LIMIT:g} √CRLB")
    for k, name in enumerate(AXIS_NAMES):
        if axes.high[i, k] < band_low:
            found.append(
                f"along the CRLB's {name} axis its RMSE is {_fmt(axes.efficiency[i, k])} of the "
                f"bound's, 95% interval [{_fmt(axes.low[i, k])}, {_fmt(axes.high[i, k])}], "
                "below what any unbiased estimator reaches"
            )
    return "; ".join(found)


def nees_verdicts(
    nees_mean: ArrayLike, n_nees: ArrayLike, band_low: ArrayLike, band_high: ArrayLike
) -> NDArray[np.str_]:
    """``consistent``, ``optimistic``, ``pessimistic``, ``inconclusive`` or ``no covariance``."""
    mean = np.asarray(nees_mean, dtype=float)
    n = np.asarray(n_nees, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.select(
            [n == 0, n < MIN_TRIALS, mean > band_high, mean < band_low],
            ["no covariance", "inconclusive", "optimistic", "pessimistic"],
            default="consistent",
        ).astype(str)


def verdict_criterion(band: tuple[float, float] = EFFICIENCY_BAND) -> str:
    """The efficiency verdict's rule in words (for reports and captions)."""
    return (
        f"attains: the whole 95% interval of the efficiency (RMSE/√CRLB, side-resolved where "
        f"the estimator flags ambiguity, MATH §7) lies inside [{band[0]:g}, {band[1]:g}], the "
        f"bias (the mean error over √CRLB) is at most {BIAS_LIMIT:g} over its whole interval, "
        f"no principal axis of the CRLB is wholly above the band, with at least {MIN_TRIALS} "
        f"successful trials, {100 * MIN_SUCCESS_RATE:g}% successes and no heavy tail (the "
        f"largest 1% of the trials carrying more than {100 * TAIL_SHARE_LIMIT:g}% of the "
        f"squared error); biased: the bias lies beyond {BIAS_LIMIT:g}, or along an axis the "
        "error is below the bound (the CRLB bounds only unbiased estimators, so the efficiency "
        "of a biased one says nothing about it); above / below: the whole interval lies outside "
        "the band; inconclusive: anything else. The intervals are a studentized bootstrap of "
        "the mean squared error, honest when a few trials land far away, and Hotelling's region "
        "for the mean error (docs/math.md, Verdicts and intervals)."
    )


def threshold_snr(summary: pd.DataFrame, group_by: list[str]) -> pd.DataFrame:
    """The lowest SNR from which every higher point of an SNR sweep attains the bound.

    Parameters
    ----------
    summary : pandas.DataFrame
        Rows with ``snr_db`` and ``verdict``, one per SNR point within each group (the caller
        passes the last frame of each point, and only sweeps over SNR).
    group_by : list of str
        The columns naming a curve, e.g. ``["scenario", "estimator"]``.

    Returns
    -------
    pandas.DataFrame
        ``group_by`` columns, ``threshold_snr_db`` (NaN when the highest point does not
        attain), ``n_points`` and ``n_attains``, groups in order of first appearance.
    """
    rows = []
    for key, own in summary.groupby(group_by, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        ordered = own.sort_values("snr_db", ascending=False)
        attains = ordered["verdict"].to_numpy() == "attains"
        run = int(np.argmin(attains)) if not attains.all() else len(attains)
        threshold = float(ordered["snr_db"].iloc[run - 1]) if run > 0 else math.nan
        rows.append((*key, threshold, len(own), int(attains.sum())))
    return pd.DataFrame(rows, columns=[*group_by, "threshold_snr_db", "n_points", "n_attains"])
