r"""Summary metrics of Monte Carlo trials, and statements of where the CRLB is attained.

:func:`summarize` turns the tidy trial rows of :func:`comparison.engine.read_trials` (one row
per estimator × scenario × point × frame × trial, and planner in a closed loop) into one row per
(scenario, point, frame, estimator), and planner when the rows have planners:

- ``rmse_m`` :math:`= \sqrt{\tfrac1n\sum_i e_i^2}` over the successful trials, with a 95%
  percentile-bootstrap interval (``rmse_ci_low_m``, ``rmse_ci_high_m``);
- ``rmse_side_resolved_m``: the same with the error of the candidate nearest to the truth
  (MATH §7), i.e. the error once the mirror ambiguity is resolved, and its interval;
- ``mean_error_m`` (the paper's "accuracy", MATH §14), ``median_error_m``, ``cep50_m``,
  ``p95_error_m``, ``bias_x_m``, ``bias_y_m``;
- ``crlb_rmse_m`` (:math:`\sqrt{\operatorname{tr}\,\mathrm{CRLB}}`, MATH §8; in a closed
  loop, where every trial flies its own trajectory, the root mean square of the trials'
  bounds) and the efficiencies ``rmse_m / crlb_rmse_m`` and
  ``rmse_side_resolved_m / crlb_rmse_m``;
- ``wrong_side_rate``, ``ambiguous_rate``, ``success_rate``, ``nees_mean`` with its 95%
  chi-square band, ``runtime_median_s``.

The SNR axis scales every reference σ by :math:`10^{-\mathrm{SNR}/20}` (MATH §2).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy import stats

FloatArray = NDArray[np.float64]

TRIAL_COLUMNS: tuple[str, ...] = (
    "experiment",
    "scenario",
    "point",
    "snr_db",
    "planner",
    "estimator",
    "frame",
    "trial",
    "truth_x_m",
    "truth_y_m",
    "x_m",
    "y_m",
    "error_m",
    "error_side_resolved_m",
    "wrong_side",
    "ambiguous",
    "success",
    "n_candidates",
    "candidates_json",
    "cov_xx_m2",
    "cov_xy_m2",
    "cov_yy_m2",
    "nees",
    "crlb_rmse_m",
    "runtime_s",
    "message",
    "diagnostics_json",
)
"""Every fixed column of a trial frame; the swept-parameter columns come on top of these.
``planner`` is optional (empty in open-loop runs)."""

REQUIRED_TRIAL_COLUMNS: tuple[str, ...] = (
    "scenario",
    "point",
    "snr_db",
    "estimator",
    "frame",
    "truth_x_m",
    "truth_y_m",
    "x_m",
    "y_m",
    "error_m",
    "error_side_resolved_m",
    "wrong_side",
    "ambiguous",
    "success",
    "nees",
    "crlb_rmse_m",
    "runtime_s",
)
"""The trial columns :func:`summarize` reads."""

CONTRACT_METRIC_NAMES: tuple[str, ...] = (
    "n_trials",
    "rmse_m",
    "rmse_ci_low_m",
    "rmse_ci_high_m",
    "rmse_side_resolved_m",
    "mean_error_m",
    "median_error_m",
    "cep50_m",
    "p95_error_m",
    "bias_x_m",
    "bias_y_m",
    "crlb_rmse_m",
    "efficiency",
    "efficiency_side_resolved",
    "wrong_side_rate",
    "ambiguous_rate",
    "success_rate",
    "nees_mean",
    "runtime_median_s",
)
"""The metric columns every summary has, in this order."""

EXTRA_METRIC_NAMES: tuple[str, ...] = (
    "n_successes",
    "rmse_side_resolved_ci_low_m",
    "rmse_side_resolved_ci_high_m",
    "n_nees",
    "nees_band_low",
    "nees_band_high",
)
"""Metric columns that follow the contracted ones (counts and the intervals they need)."""

METRIC_NAMES: tuple[str, ...] = CONTRACT_METRIC_NAMES + EXTRA_METRIC_NAMES
"""Every metric column of :func:`summarize`'s result, in order (from ``n_trials`` on)."""

METRIC_DESCRIPTIONS: dict[str, str] = {
    "n_trials": "trials run (successful or not)",
    "n_successes": "trials whose estimator returned a position",
    "rmse_m": "root mean square error of the returned position, successful trials",
    "rmse_ci_low_m": "lower end of the 95% percentile-bootstrap interval of rmse_m",
    "rmse_ci_high_m": "upper end of the 95% percentile-bootstrap interval of rmse_m",
    "rmse_side_resolved_m": "RMSE of the candidate nearest to the truth (MATH §7)",
    "rmse_side_resolved_ci_low_m": "lower end of the bootstrap interval of the side-resolved RMSE",
    "rmse_side_resolved_ci_high_m": "upper end of the bootstrap interval of the side-resolved RMSE",
    "mean_error_m": "mean distance error, the paper's 'accuracy' (MATH §14)",
    "median_error_m": "median distance error",
    "cep50_m": "circular error probable: radius about the truth holding 50% of the estimates "
    "(the median distance error)",
    "p95_error_m": "95th percentile of the distance error",
    "bias_x_m": "mean of x_m - truth_x_m",
    "bias_y_m": "mean of y_m - truth_y_m",
    "crlb_rmse_m": "√trace(CRLB) for the estimator's modalities and frames (MATH §8); the "
    "root mean square over trials when each trial flew its own trajectory (closed loop)",
    "efficiency": "rmse_m / crlb_rmse_m (1 attains the bound)",
    "efficiency_side_resolved": "rmse_side_resolved_m / crlb_rmse_m",
    "wrong_side_rate": (
        "fraction of successful estimates off the track plane that lie on the wrong side (MATH §7)"
    ),
    "ambiguous_rate": "fraction of successful estimates flagged ambiguous (MATH §7)",
    "success_rate": "fraction of trials with a returned position",
    "n_nees": "successful trials with a covariance",
    "nees_mean": "mean NEES eᵀP⁻¹e, e from the side-resolved candidate (2 when consistent)",
    "nees_band_low": "2.5% point of the mean of n_nees consistent 2-dof NEES values",
    "nees_band_high": "97.5% point of the mean of n_nees consistent 2-dof NEES values",
    "runtime_median_s": "median wall time of one estimate",
}
"""One line per metric column, for captions and the report."""

DEFAULT_N_BOOTSTRAP = 1000
"""Bootstrap resamples per group for the RMSE intervals."""

ATTAINMENT_TOLERANCE = 0.10
"""Relative distance to √CRLB within which the bound counts as attained."""

MIN_SUCCESS_RATE = 0.99
"""Smallest success rate at which an estimator can be said to attain the bound."""


def has_planners(frame: pd.DataFrame) -> bool:
    """True when the rows come from a closed loop: a ``planner`` column with a label."""
    if "planner" not in frame.columns:
        return False
    labels = frame["planner"]
    return bool((labels.notna() & (labels.astype(str) != "")).any())


def attainment_criterion(
    tolerance: float = ATTAINMENT_TOLERANCE, min_success_rate: float = MIN_SUCCESS_RATE
) -> str:
    """The attainment criterion of :func:`crlb_attainment`, in words (for reports)."""
    return (
        "An estimator attains the CRLB at a sweep point when the 95% bootstrap interval of "
        "its RMSE overlaps the band from "
        f"{1 - tolerance:g}·√CRLB to {1 + tolerance:g}·√CRLB and at least "
        f"{100 * min_success_rate:g}% of its estimates succeed. The RMSE is the "
        "side-resolved one (error of the candidate nearest to the truth, MATH §7) for an "
        "estimator that flags any estimate at that point as ambiguous, and the RMSE of the "
        "returned position otherwise; √CRLB is the bound for the modalities and frames that "
        "estimator uses (MATH §8). An interval wholly below the band is reported as "
        "'below the bound' (a biased estimate, which the unbiased bound does not cover); "
        "per-frame runs are judged on their last frame."
    )


def nees_band(n: ArrayLike, confidence: float = 0.95) -> tuple[FloatArray, FloatArray]:
    """Two-sided interval for the mean of ``n`` independent 2-dof NEES values.

    If the estimator's covariance is consistent, each NEES is χ²(2) and ``n`` times their mean
    is χ²(2n) (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2), so the mean lies in
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


def bootstrap_rmse_interval(
    squared_errors_m2: ArrayLike,
    groups: ArrayLike,
    n_groups: int,
    *,
    n_bootstrap: int = DEFAULT_N_BOOTSTRAP,
    rng: np.random.Generator,
    confidence: float = 0.95,
    max_draws: int = 2**22,
) -> tuple[FloatArray, FloatArray]:
    """Percentile-bootstrap interval of the RMSE of every group, vectorised over groups.

    Each group's squared errors are resampled with replacement ``n_bootstrap`` times;
    the interval is the ``(1 ± confidence)/2`` quantiles of the resampled RMSEs (Efron &
    Tibshirani 1993, §13.3). Groups are processed in blocks of at most about ``max_draws``
    random indices, so memory stays bounded; there is no loop over trials.

    Parameters
    ----------
    squared_errors_m2 : (n,)
        Squared errors; NaN entries (failed trials) are left out.
    groups : (n,) int
        Group index of each entry, in ``0 .. n_groups - 1``.
    n_groups : int
    n_bootstrap : int
        Resamples per group.
    rng : numpy.random.Generator
        Source of the resampling indices (seeded by the caller).
    confidence : float
    max_draws : int
        Memory bound: random indices drawn at once.

    Returns
    -------
    low, high : (n_groups,)
        NaN for a group without finite errors.
    """
    if int(n_bootstrap) != n_bootstrap or n_bootstrap < 1:
        raise ValueError(f"n_bootstrap: must be a whole number >= 1, got {n_bootstrap!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence!r}")
    values = np.asarray(squared_errors_m2, dtype=float)
    codes = np.asarray(groups, dtype=np.int64)
    keep = np.isfinite(values)
    values, codes = values[keep], codes[keep]
    order = np.argsort(codes, kind="stable")
    values, codes = values[order], codes[order]
    counts = np.bincount(codes, minlength=n_groups)
    starts = np.cumsum(counts) - counts
    low = np.full(n_groups, np.nan)
    high = np.full(n_groups, np.nan)
    filled = np.flatnonzero(counts)
    if filled.size == 0:
        return low, high
    # Consecutive non-empty groups are contiguous in `values`; cut them into blocks of about
    # `budget` entries each (a group larger than the budget forms its own block).
    budget = max(max_draws // int(n_bootstrap), 1)
    offsets = np.cumsum(counts[filled]) - counts[filled]
    block_of = offsets // budget
    block_edges = np.flatnonzero(np.diff(block_of, prepend=-1))
    quantiles = [(1 - confidence) / 2, (1 + confidence) / 2]
    for first, last in zip(block_edges, [*block_edges[1:], filled.size], strict=True):
        block = filled[first:last]
        size = counts[block]
        begin = starts[block[0]]
        segment = values[begin : starts[block[-1]] + size[-1]]
        owner = np.repeat(np.arange(block.size), size)
        local_start = starts[block] - begin
        draws = rng.integers(0, size[owner], size=(int(n_bootstrap), owner.size))
        draws += local_start[owner]
        sums = np.add.reduceat(segment[draws], local_start, axis=1)
        resampled_rmse = np.sqrt(sums / size)
        low[block], high[block] = np.quantile(resampled_rmse, quantiles, axis=0)
    return low, high


def swept_columns_of(trials: pd.DataFrame) -> list[str]:
    """The swept-parameter columns of a trial frame (every column not in the contract)."""
    fixed = set(TRIAL_COLUMNS)
    return [column for column in trials.columns if column not in fixed]


def _check_trials(trials: pd.DataFrame, swept: Sequence[str]) -> None:
    if not isinstance(trials, pd.DataFrame):
        raise ValueError(
            f"trials: expected a pandas DataFrame from comparison.engine.read_trials, "
            f"got {type(trials).__name__}"
        )
    missing = [c for c in (*REQUIRED_TRIAL_COLUMNS, *swept) if c not in trials.columns]
    if missing:
        raise ValueError(
            f"trials: missing columns {missing}; pass the frame returned by "
            "comparison.engine.read_trials (one row per estimator, scenario, point, frame "
            "and trial)"
        )
    if len(trials) == 0:
        raise ValueError("trials: the frame has no rows; run the experiment first")
    for column in ("snr_db", *swept):
        if not pd.api.types.is_numeric_dtype(trials[column]):
            raise ValueError(f"{column}: swept values must be numbers, got {trials[column].dtype}")


def _ordered_codes(values: pd.Series) -> NDArray[np.int64]:
    """Integer codes in order of first appearance (estimators keep the experiment's order)."""
    codes, _ = pd.factorize(values, sort=False)
    return codes.astype(np.int64)


def summarize(
    trials: pd.DataFrame,
    *,
    n_bootstrap: int = DEFAULT_N_BOOTSTRAP,
    seed: int | np.random.SeedSequence = 0,
    confidence: float = 0.95,
    swept_columns: Sequence[str] | None = None,
) -> pd.DataFrame:
    """One row of metrics per (scenario, point, frame, estimator), and planner in a closed loop.

    ``n_trials`` counts every trial; the error metrics, the wrong-side and ambiguous rates and
    the NEES use the successful trials only; ``success_rate`` and ``runtime_median_s`` use
    every trial. ``crlb_rmse_m`` is the rows' ``crlb_rmse_m`` when it is constant within a
    group (one flight for all trials), else their root mean square: each closed-loop trial
    flies its own trajectory, and ``E[e²] ≥ E[tr CRLB(trajectory)]`` makes the RMS of the
    per-trial bounds the reference for the RMSE (a reference, not a strict bound, since the
    trajectory depends on earlier noise). ``cep50_m`` is the radius about the truth holding
    half the estimates, which is the median distance error (``median_error_m``) by
    definition.

    Parameters
    ----------
    trials : pandas.DataFrame
        The rows of :func:`comparison.engine.read_trials`.
    n_bootstrap : int
        Resamples for the RMSE intervals (:func:`bootstrap_rmse_interval`).
    seed : int or numpy.random.SeedSequence
        Seed of the bootstrap's generator: the same trials and seed give the same intervals.
    confidence : float
        Coverage of the bootstrap intervals and of the NEES band.
    swept_columns : sequence of str, optional
        The swept-parameter columns; by default every column outside the contract, in the
        frame's order (:func:`swept_columns_of`).

    Returns
    -------
    pandas.DataFrame
        Columns ``scenario, snr_db, <swept>, frame, estimator`` and then :data:`METRIC_NAMES`;
        rows ordered by scenario (first appearance), point, frame, estimator (first
        appearance). With planners (:func:`has_planners`) a ``planner`` column follows
        ``frame`` and rows are ordered by scenario, point, planner, frame, estimator.
    """
    swept = list(swept_columns_of(trials) if swept_columns is None else swept_columns)
    _check_trials(trials, swept)
    success = trials["success"].to_numpy(dtype=bool)
    planners = has_planners(trials)
    keyed = ("scenario", "estimator", "planner") if planners else ("scenario", "estimator")
    codes = {key: _ordered_codes(trials[key]) for key in keyed}
    group_frame = pd.DataFrame(
        {
            "scenario": codes["scenario"],
            "point": trials["point"].to_numpy(dtype=np.int64),
            "planner": codes["planner"] if planners else 0,
            "frame": trials["frame"].to_numpy(dtype=np.int64),
            "estimator": codes["estimator"],
        }
    )
    group_keys = ["scenario", "point", "planner", "frame", "estimator"]
    group = group_frame.groupby(group_keys, sort=True).ngroup().to_numpy(np.int64)
    n_groups = int(group.max()) + 1

    def successful(column: str) -> FloatArray:
        return np.where(success, trials[column].to_numpy(dtype=float), np.nan)

    error = successful("error_m")
    side_error = successful("error_side_resolved_m")
    work = pd.DataFrame(
        {
            "group": group,
            "error": error,
            "squared_error": error**2,
            "squared_side_error": side_error**2,
            "error_x": successful("x_m") - trials["truth_x_m"].to_numpy(dtype=float),
            "error_y": successful("y_m") - trials["truth_y_m"].to_numpy(dtype=float),
            "wrong_side": successful("wrong_side"),
            "ambiguous": np.where(success, trials["ambiguous"].to_numpy(dtype=float), np.nan),
            "success": success.astype(float),
            "nees": successful("nees"),
            "runtime": trials["runtime_s"].to_numpy(dtype=float),
            "crlb": trials["crlb_rmse_m"].to_numpy(dtype=float),
            "crlb_squared": trials["crlb_rmse_m"].to_numpy(dtype=float) ** 2,
        }
    )
    by_group = work.groupby("group", sort=True)
    stats_frame = by_group.agg(
        n_trials=("success", "size"),
        n_successes=("success", "sum"),
        mean_squared=("squared_error", "mean"),
        mean_squared_side=("squared_side_error", "mean"),
        mean_error_m=("error", "mean"),
        median_error_m=("error", "median"),
        bias_x_m=("error_x", "mean"),
        bias_y_m=("error_y", "mean"),
        crlb_rmse_m=("crlb", "mean"),
        crlb_low=("crlb", "min"),
        crlb_high=("crlb", "max"),
        crlb_mean_squared=("crlb_squared", "mean"),
        wrong_side_rate=("wrong_side", "mean"),
        ambiguous_rate=("ambiguous", "mean"),
        success_rate=("success", "mean"),
        n_nees=("nees", "count"),
        nees_mean=("nees", "mean"),
        runtime_median_s=("runtime", "median"),
    )
    stats_frame["p95_error_m"] = by_group["error"].quantile(0.95)

    rng = np.random.default_rng(seed)
    rmse_low, rmse_high = bootstrap_rmse_interval(
        work["squared_error"],
        group,
        n_groups,
        n_bootstrap=n_bootstrap,
        rng=rng,
        confidence=confidence,
    )
    side_low, side_high = bootstrap_rmse_interval(
        work["squared_side_error"],
        group,
        n_groups,
        n_bootstrap=n_bootstrap,
        rng=rng,
        confidence=confidence,
    )
    band_low, band_high = nees_band(stats_frame["n_nees"].to_numpy(), confidence)

    rmse = np.sqrt(stats_frame["mean_squared"].to_numpy())
    rmse_side = np.sqrt(stats_frame["mean_squared_side"].to_numpy())
    # one flight for every trial: the common bound; one per trial (closed loop): their RMS
    crlb = np.where(
        stats_frame["crlb_low"].to_numpy() == stats_frame["crlb_high"].to_numpy(),
        stats_frame["crlb_rmse_m"].to_numpy(),
        np.sqrt(stats_frame["crlb_mean_squared"].to_numpy()),
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        efficiency = np.where(crlb > 0, rmse / crlb, np.nan)
        efficiency_side = np.where(crlb > 0, rmse_side / crlb, np.nan)
    metrics = pd.DataFrame(
        {
            "n_trials": stats_frame["n_trials"].to_numpy(dtype=np.int64),
            "rmse_m": rmse,
            "rmse_ci_low_m": rmse_low,
            "rmse_ci_high_m": rmse_high,
            "rmse_side_resolved_m": rmse_side,
            "mean_error_m": stats_frame["mean_error_m"].to_numpy(),
            "median_error_m": stats_frame["median_error_m"].to_numpy(),
            "cep50_m": stats_frame["median_error_m"].to_numpy(),
            "p95_error_m": stats_frame["p95_error_m"].to_numpy(),
            "bias_x_m": stats_frame["bias_x_m"].to_numpy(),
            "bias_y_m": stats_frame["bias_y_m"].to_numpy(),
            "crlb_rmse_m": crlb,
            "efficiency": efficiency,
            "efficiency_side_resolved": efficiency_side,
            "wrong_side_rate": stats_frame["wrong_side_rate"].to_numpy(),
            "ambiguous_rate": stats_frame["ambiguous_rate"].to_numpy(),
            "success_rate": stats_frame["success_rate"].to_numpy(),
            "nees_mean": stats_frame["nees_mean"].to_numpy(),
            "runtime_median_s": stats_frame["runtime_median_s"].to_numpy(),
            "n_successes": stats_frame["n_successes"].to_numpy(dtype=np.int64),
            "rmse_side_resolved_ci_low_m": side_low,
            "rmse_side_resolved_ci_high_m": side_high,
            "n_nees": stats_frame["n_nees"].to_numpy(dtype=np.int64),
            "nees_band_low": band_low,
            "nees_band_high": band_high,
        }
    )
    # The key columns of each group: its first row (they are constant within a group).
    first_rows = np.unique(group, return_index=True)[1]
    key_columns = ["scenario", "snr_db", *swept, "frame", *(["planner"] if planners else [])]
    key_columns.append("estimator")
    keys = trials.iloc[first_rows][key_columns]
    keys = keys.reset_index(drop=True).astype({"snr_db": float, "frame": np.int64})
    return pd.concat([keys, metrics], axis=1)[[*key_columns, *METRIC_NAMES]]


# --------------------------------------------------------------------------------------------
# where the bound is attained
# --------------------------------------------------------------------------------------------


def summary_swept_columns(summary: pd.DataFrame) -> list[str]:
    """The swept-parameter columns of a summary: those between ``snr_db`` and ``frame``."""
    columns = list(summary.columns)
    for name in ("scenario", "snr_db", "frame", "estimator"):
        if name not in columns:
            raise ValueError(
                f"summary: missing column {name!r}; pass the frame returned by summarize"
            )
    return columns[columns.index("snr_db") + 1 : columns.index("frame")]


def judged_rmse(summary: pd.DataFrame) -> pd.DataFrame:
    """The RMSE each row is judged on, with its interval and efficiency.

    The side-resolved RMSE (MATH §7) where the estimator flagged any estimate of the row as
    ambiguous, the RMSE of the returned position otherwise.

    Returns
    -------
    pandas.DataFrame
        Columns ``side_resolved`` (bool), ``rmse_m``, ``low_m``, ``high_m``, ``efficiency``,
        indexed like ``summary``.
    """
    side = summary["ambiguous_rate"].fillna(0.0).to_numpy() > 0

    def pick(resolved: str, returned: str) -> FloatArray:
        return np.where(side, summary[resolved].to_numpy(float), summary[returned].to_numpy(float))

    return pd.DataFrame(
        {
            "side_resolved": side,
            "rmse_m": pick("rmse_side_resolved_m", "rmse_m"),
            "low_m": pick("rmse_side_resolved_ci_low_m", "rmse_ci_low_m"),
            "high_m": pick("rmse_side_resolved_ci_high_m", "rmse_ci_high_m"),
            "efficiency": pick("efficiency_side_resolved", "efficiency"),
        },
        index=summary.index,
    )


def attainment_status(
    summary: pd.DataFrame,
    *,
    tolerance: float = ATTAINMENT_TOLERANCE,
    min_success_rate: float = MIN_SUCCESS_RATE,
) -> pd.Series:
    """Classify every summary row against the bound (:func:`attainment_criterion`).

    Returns
    -------
    pandas.Series of str
        ``"attains"``, ``"above"`` (interval wholly above ``(1 + tolerance)·√CRLB``),
        ``"below"`` (wholly below ``(1 − tolerance)·√CRLB``), ``"failures"`` (interval in the
        band but fewer than ``min_success_rate`` successes) or ``"undefined"`` (no finite
        bound, or no successful estimate).
    """
    if not tolerance > 0:
        raise ValueError(f"tolerance: must be > 0, got {tolerance!r}")
    judged = judged_rmse(summary)
    bound = summary["crlb_rmse_m"].to_numpy(float)
    low, high = judged["low_m"].to_numpy(), judged["high_m"].to_numpy()
    defined = np.isfinite(bound) & (bound > 0) & np.isfinite(low) & np.isfinite(high)
    with np.errstate(invalid="ignore"):
        above = low > (1 + tolerance) * bound
        below = high < (1 - tolerance) * bound
        enough = summary["success_rate"].to_numpy(float) >= min_success_rate
    status = np.select(
        [~defined, above, below, ~enough],
        ["undefined", "above", "below", "failures"],
        default="attains",
    )
    return pd.Series(status, index=summary.index, name="attainment")


_UNITS = {"_db": "dB", "_m": "m", "_s": "s", "_hz": "Hz", "_mps": "m/s", "_m2": "m²"}


def parameter_label(column: str) -> tuple[str, str]:
    """Display name and unit of a swept column: ``snr_db`` → ``("SNR", "dB")``."""
    if column == "snr_db":
        return "SNR", "dB"
    for suffix in sorted(_UNITS, key=len, reverse=True):
        if column.endswith(suffix):
            return column, _UNITS[suffix]
    return column, ""


def _number(value: float) -> str:
    return f"{value:.4g}"


def _ratio(value: float) -> str:
    return f"{value:.3g}"


def _with_unit(text: str, unit: str) -> str:
    return f"{text} {unit}" if unit else text


def _ranges(chosen: Sequence[float], every: Sequence[float]) -> list[tuple[float, float]]:
    """Runs of consecutive values of ``every`` (sorted) that are all in ``chosen``."""
    chosen_set = set(chosen)
    runs: list[tuple[float, float]] = []
    current: list[float] = []
    for value in sorted(set(every)):
        if value in chosen_set:
            current.append(value)
        elif current:
            runs.append((current[0], current[-1]))
            current = []
    if current:
        runs.append((current[0], current[-1]))
    return runs


def _describe_points(rows: pd.DataFrame, all_rows: pd.DataFrame, varying: list[str]) -> str:
    """Words for where ``rows`` lie among ``all_rows`` ("SNR from −10 to 30 dB")."""
    if len(varying) == 1:
        column = varying[0]
        name, unit = parameter_label(column)
        runs = _ranges(rows[column].tolist(), all_rows[column].tolist())
        parts = [_number(a) if a == b else f"{_number(a)} to {_number(b)}" for a, b in runs]
        lead = "from " if len(runs) == 1 and runs[0][0] != runs[0][1] else ""
        return _with_unit(f"{name} {lead}" + ", ".join(parts), unit)
    if not varying:
        name, unit = parameter_label("snr_db")
        return _with_unit(f"{name} {_number(float(rows['snr_db'].iloc[0]))}", unit)
    counted = f"{len(rows)} of {len(all_rows)} points"
    if len(rows) <= 3:
        listed = "; ".join(_describe_point(row, varying) for _, row in rows.iterrows())
        return f"{counted} ({listed})"
    return counted


def _describe_point(row: pd.Series, varying: list[str]) -> str:
    columns = varying or ["snr_db"]
    return ", ".join(
        _with_unit(f"{parameter_label(c)[0]} {_number(float(row[c]))}", parameter_label(c)[1])
        for c in columns
    )


def crlb_attainment(
    summary: pd.DataFrame,
    *,
    tolerance: float = ATTAINMENT_TOLERANCE,
    min_success_rate: float = MIN_SUCCESS_RATE,
) -> list[str]:
    """Sentences stating, per scenario and estimator, where the CRLB is attained.

    The criterion (:func:`attainment_criterion`): at a sweep point an estimator attains the
    bound when the 95% bootstrap interval of its judged RMSE (side-resolved, MATH §7, if any
    estimate at the point is flagged ambiguous; of the returned position otherwise) overlaps
    ``[(1 − tolerance)·√CRLB, (1 + tolerance)·√CRLB]`` and at least ``min_success_rate`` of its
    estimates succeed. A point is therefore declared not attained only when the data exclude
    the band at 95% confidence (or too many estimates fail), not because the point estimate of
    the RMSE strayed outside it. Per-frame runs are judged on the last frame of each point.
    Every number comes from ``summary``.

    Parameters
    ----------
    summary : pandas.DataFrame
        The result of :func:`summarize` (or its CSV, read back).
    tolerance : float
        Relative half-width of the band around √CRLB.
    min_success_rate : float

    Returns
    -------
    list of str
        One sentence per (scenario, estimator), in the summary's order.
    """
    swept = summary_swept_columns(summary)
    missing = [c for c in METRIC_NAMES if c not in summary.columns]
    if missing:
        raise ValueError(f"summary: missing columns {missing}; pass the frame from summarize")
    planners = has_planners(summary)
    point_keys = ["scenario", "snr_db", *swept, *(["planner"] if planners else []), "estimator"]
    last = summary["frame"] == summary.groupby(point_keys, sort=False)["frame"].transform("max")
    rows = summary[last].copy()
    rows["status"] = attainment_status(rows, tolerance=tolerance, min_success_rate=min_success_rate)
    judged = judged_rmse(rows)
    rows["judged_efficiency"] = judged["efficiency"]
    rows["side_resolved"] = judged["side_resolved"]
    sentences: list[str] = []
    for scenario, in_scenario in rows.groupby("scenario", sort=False):
        varying = [c for c in ("snr_db", *swept) if in_scenario[c].nunique() > 1]
        by = ["planner", "estimator"] if planners else ["estimator"]
        for key, own in in_scenario.groupby(by, sort=False):
            key = key if isinstance(key, tuple) else (key,)
            who = f"{key[1]} (planner {key[0]})" if planners else str(key[0])
            sentences.append(_attainment_sentence(who, str(scenario), own, varying, tolerance))
    return sentences


def _attainment_sentence(
    estimator: str, scenario: str, own: pd.DataFrame, varying: list[str], tolerance: float
) -> str:
    which = (
        " (side-resolved RMSE)"
        if own["side_resolved"].all()
        else " (side-resolved RMSE where ambiguous)"
        if own["side_resolved"].any()
        else ""
    )
    status = own["status"]
    attains = own[status == "attains"]
    defined = own[status != "undefined"]
    if defined.empty:
        return f"{estimator}: the bound is undefined on {scenario} (singular Fisher information)."
    if len(attains) == len(own):
        where = "at every point" if len(own) > 1 else "at its single point"
        return (
            f"{estimator} attains the CRLB{which} on {scenario} {where} "
            f"({_describe_points(attains, own, varying)}; efficiency "
            f"{_ratio(own['judged_efficiency'].min())} to "
            f"{_ratio(own['judged_efficiency'].max())})."
        )
    clauses = []
    if attains.empty:
        finite = defined[np.isfinite(defined["judged_efficiency"])]
        best = finite.loc[(finite["judged_efficiency"] - 1).abs().idxmin()]
        head = (
            f"{estimator} does not attain the CRLB{which} on {scenario} at any point "
            f"(efficiency closest to 1: {_ratio(best['judged_efficiency'])} at "
            f"{_describe_point(best, varying)})"
        )
    else:
        head = (
            f"{estimator} attains the CRLB{which} on {scenario} at "
            f"{_describe_points(attains, own, varying)}"
        )
    above = own[status == "above"]
    if not above.empty and not (attains.empty and (status == "below").sum() == 0):
        worst = above.loc[above["judged_efficiency"].idxmax()]
        clauses.append(
            f"{'not' if len(attains) else 'above the band'} at "
            f"{_describe_points(above, own, varying)} (efficiency up to "
            f"{_ratio(worst['judged_efficiency'])} at {_describe_point(worst, varying)})"
        )
    below = own[status == "below"]
    if not below.empty:
        clauses.append(
            f"its RMSE is more than {100 * tolerance:g}% below √CRLB at "
            f"{_describe_points(below, own, varying)} (a biased estimate, which the bound "
            "does not cover)"
        )
    failures = own[status == "failures"]
    if not failures.empty:
        clauses.append(
            f"too many estimates fail at {_describe_points(failures, own, varying)} "
            f"(success rate down to {_ratio(failures['success_rate'].min())})"
        )
    undefined = own[status == "undefined"]
    if not undefined.empty:
        clauses.append(f"the bound is undefined at {_describe_points(undefined, own, varying)}")
    return "; ".join([head, *clauses]) + "."


def format_number(value: object, digits: int = 4) -> str:
    """How the report prints a number: ``digits`` significant digits, ``NaN`` for missing."""
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, int | np.integer):
        return str(int(value))
    number = float(value)  # type: ignore[arg-type]
    if math.isnan(number):
        return "NaN"
    return f"{number:.{digits}g}"
