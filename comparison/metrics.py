r"""Summary metrics of Monte Carlo trials.

:func:`summarize` turns the tidy trial rows of :func:`comparison.engine.read_trials` (one row
per estimator × scenario × point × frame × trial, and planner in a closed loop) into one row per
(scenario, point, frame, estimator), and planner when the rows have planners:

- ``rmse_m`` :math:`= \sqrt{\tfrac1n\sum_i e_i^2}` over the successful trials, with a 95%
  studentized-bootstrap interval (``rmse_ci_low_m``, ``rmse_ci_high_m``;
  :mod:`comparison.verdicts` says why that method);
- ``rmse_side_resolved_m``: the same with the error of the candidate nearest to the truth
  (MATH §7), i.e. the error once the mirror ambiguity is resolved, and its interval;
- ``mean_error_m`` (the paper's "accuracy", MATH §14), ``median_error_m``, ``cep50_m``,
  ``p95_error_m``, ``bias_x_m``, ``bias_y_m``;
- ``crlb_rmse_m`` (:math:`\sqrt{\operatorname{tr}\,\mathrm{CRLB}}`, MATH §8; in a closed
  loop, where every trial flies its own trajectory, the root mean square of the trials'
  bounds) and the efficiencies ``rmse_m / crlb_rmse_m`` and
  ``rmse_side_resolved_m / crlb_rmse_m``;
- rates with their counts beside them: ``wrong_side_rate`` over ``n_side_judged`` estimates
  off the track, ``success_rate`` over ``n_trials``, ``nees_mean`` and
  ``nees_side_resolved_mean`` over ``n_nees`` with the 95% chi-square band;
- ``fit_rejected_rate`` over ``n_fit_judged``: the share of estimates whose goodness of fit
  (``fit_chi2`` on ``fit_dof``, MATH §17) is rejected at 1%;
- the verdicts of :mod:`comparison.verdicts`: ``verdict`` (``attains``, ``above``, ``below``,
  ``inconclusive``) with ``verdict_reason``, judged on ``efficiency_judged`` and its interval,
  and ``nees_verdict``.

The SNR axis scales every reference σ by :math:`10^{-\mathrm{SNR}/20}` (MATH §2).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from comparison.intervals import (
    DEFAULT_N_BOOTSTRAP,
    AxisEfficiencies,
    axis_squared_errors,
    bias_intervals,
    nees_band,
    studentized_bootstrap_interval,
    tail_share,
)
from comparison.trial_rows import REQUIRED_TRIAL_COLUMNS, TRIAL_COLUMNS
from comparison.verdicts import efficiency_verdicts, nees_verdicts
from estimators.goodness_of_fit import fit_judged, fit_rejected

FloatArray = NDArray[np.float64]

N_INTERVALS = 4
"""Bootstrap intervals of a group, each drawing a seed per key: the RMSE, the side-resolved
RMSE and the two principal axes."""

SUMMARY_CHUNK_ROWS = 250_000
"""Trial rows :func:`summarize` works at a time (whole points: a point of more is one chunk)."""


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
    "nees_judged_mean",
    "runtime_median_s",
)
"""The metric columns every summary has, in this order."""

EXTRA_METRIC_NAMES: tuple[str, ...] = (
    "n_successes",
    "rmse_side_resolved_ci_low_m",
    "rmse_side_resolved_ci_high_m",
    "n_side_judged",
    "n_nees",
    "nees_band_low",
    "nees_band_high",
    "nees_verdict",
    "nees_side_resolved_mean",
    "nees_returned_incl_wrong_side_mean",
    "crlb_rmse_median_m",
    "verdict_basis",
    "efficiency_judged",
    "efficiency_judged_ci_low",
    "efficiency_judged_ci_high",
    "bias_judged_x_m",
    "bias_judged_y_m",
    "bias_judged_m",
    "bias_ratio",
    "bias_ratio_ci_low",
    "bias_ratio_ci_high",
    "efficiency_major_axis",
    "efficiency_major_axis_ci_low",
    "efficiency_major_axis_ci_high",
    "efficiency_minor_axis",
    "efficiency_minor_axis_ci_low",
    "efficiency_minor_axis_ci_high",
    "tail_share",
    "verdict",
    "verdict_reason",
    "fit_rejected_rate",
    "n_fit_judged",
)
"""Columns that follow the contracted ones: counts beside the rates, intervals, verdicts."""

TEXT_METRIC_NAMES: frozenset[str] = frozenset(
    {"verdict_basis", "verdict", "verdict_reason", "nees_verdict"}
)
"""The metric columns that hold words, not numbers."""

SUMMARY_TRIAL_COLUMNS: tuple[str, ...] = (
    *REQUIRED_TRIAL_COLUMNS,
    "planner",
    "trial",
    "x_side_resolved_m",
    "y_side_resolved_m",
    "crlb_xx_m2",
    "crlb_xy_m2",
    "crlb_yy_m2",
    "fit_chi2",
    "fit_dof",
)
"""The trial columns :func:`summarize` reads (with the swept ones): the required ones, and
those it reads when present."""

METRIC_NAMES: tuple[str, ...] = CONTRACT_METRIC_NAMES + EXTRA_METRIC_NAMES
"""Every metric column of :func:`summarize`'s result, in order (from ``n_trials`` on)."""

METRIC_DESCRIPTIONS: dict[str, str] = {
    "n_trials": "trials run (successful or not)",
    "n_successes": "trials whose estimator returned a position",
    "rmse_m": "root mean square error of the returned position, successful trials",
    "rmse_ci_low_m": "lower end of the 95% studentized-bootstrap interval of rmse_m",
    "rmse_ci_high_m": "upper end of the 95% studentized-bootstrap interval of rmse_m",
    "rmse_side_resolved_m": "RMSE of the candidate nearest to the truth (MATH §7)",
    "rmse_side_resolved_ci_low_m": "lower end of the interval of the side-resolved RMSE",
    "rmse_side_resolved_ci_high_m": "upper end of the interval of the side-resolved RMSE",
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
        "fraction of the n_side_judged estimates off the track plane that lie on the other side "
        "of the track from the truth (MATH §7)"
    ),
    "n_side_judged": "successful estimates off the track plane: the wrong-side rate's count",
    "ambiguous_rate": "fraction of successful estimates flagged ambiguous (MATH §7)",
    "success_rate": "fraction of the n_trials trials with a returned position",
    "n_nees": "successful trials with a covariance: the count of the judged NEES mean",
    "nees_judged_mean": "mean NEES eᵀP⁻¹e of verdict_basis's error against its covariance (the "
    "one nees_verdict judges; 2 when consistent)",
    "nees_side_resolved_mean": "mean NEES of the candidate nearest to the truth against that "
    "candidate's covariance (the returned one reflected across the track for the mirror image)",
    "nees_returned_incl_wrong_side_mean": "mean NEES of the returned position against its "
    "covariance, wrong-side trials included (each a mirror image away: huge when the side is "
    "a coin toss)",
    "nees_band_low": "2.5% point of the mean of n_nees consistent 2-dof NEES values",
    "nees_band_high": "97.5% point of the mean of n_nees consistent 2-dof NEES values",
    "crlb_rmse_median_m": "median over trials of √trace(CRLB); equals crlb_rmse_m in an open "
    "loop, and shows how skewed the per-trial bounds of a closed loop are",
    "verdict_basis": "side-resolved where the estimator flagged any estimate of the row as "
    "ambiguous, else returned: the error the verdicts judge",
    "efficiency_judged": "the efficiency of verdict_basis",
    "efficiency_judged_ci_low": "lower end of its 95% interval",
    "efficiency_judged_ci_high": "upper end of its 95% interval",
    "bias_judged_x_m": "mean x error of verdict_basis (side-resolved where ambiguous)",
    "bias_judged_y_m": "mean y error of verdict_basis",
    "bias_judged_m": "norm of the mean error of verdict_basis: the bias the verdict judges",
    "bias_ratio": "bias_judged_m / crlb_rmse_m; attains needs its whole 95% interval at most "
    "0.3, beyond 0.3 is biased",
    "bias_ratio_ci_low": "lower end of its 95% interval (Hotelling's region for the mean)",
    "bias_ratio_ci_high": "upper end of its 95% interval",
    "efficiency_major_axis": "RMSE/√CRLB along the CRLB's major principal axis (the judged "
    "error); an unbiased estimator is at or above 1 along every axis",
    "efficiency_major_axis_ci_low": "lower end of its 95% interval",
    "efficiency_major_axis_ci_high": "upper end of its 95% interval",
    "efficiency_minor_axis": "RMSE/√CRLB along the CRLB's minor principal axis",
    "efficiency_minor_axis_ci_low": "lower end of its 95% interval",
    "efficiency_minor_axis_ci_high": "upper end of its 95% interval",
    "tail_share": "share of the judged squared error carried by the largest 1% of the trials",
    "verdict": "attains, above, below, biased or inconclusive (comparison.verdicts)",
    "verdict_reason": "the numbers behind the verdict",
    "nees_verdict": "consistent, optimistic (covariance too small), pessimistic or inconclusive "
    "for the judged NEES against its chi-square band; 'no covariance' when there is none",
    "fit_rejected_rate": "fraction of the n_fit_judged estimates whose fit is rejected at 1%: "
    "the whitened residual χ² of the data at the answer above the 99% point of χ²(fit_dof) "
    "(MATH §17); about 1% when the model, its σ's and constants hold and the answer is the "
    "best fit, more with an outlier, a wrong σ or constant, or an answer far from the best fit",
    "n_fit_judged": "successful estimates that report a goodness of fit with at least one "
    "degree of freedom: the count of fit_rejected_rate",
    "runtime_median_s": "median wall time of one estimate: one call's time for an estimator "
    "called per trial; a batch call's time divided by its trials for a batch estimator; the "
    "frame's update and estimate_state for a streamed one",
}
"""One line per metric column, for captions and the report."""


def has_planners(frame: pd.DataFrame) -> bool:
    """True when the rows come from a closed loop: a ``planner`` column with a label."""
    if "planner" not in frame.columns:
        return False
    labels = frame["planner"]
    return bool((labels.notna() & (labels.astype(str) != "")).any())


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
    chunk_rows: int = SUMMARY_CHUNK_ROWS,
) -> pd.DataFrame:
    """One row of metrics per (scenario, point, frame, estimator), and planner in a closed loop.

    ``n_trials`` counts every trial; the error metrics, the wrong-side and ambiguous rates and
    the NEES use the successful trials only (with their counts ``n_successes``,
    ``n_side_judged``, ``n_nees``); ``success_rate`` and ``runtime_median_s`` use
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
        Resamples for the RMSE intervals
        (:func:`comparison.verdicts.studentized_bootstrap_interval`).
    seed : int or numpy.random.SeedSequence
        Seed of the bootstrap's generator: the same trials and seed give the same intervals.
    confidence : float
        Coverage of the bootstrap intervals and of the NEES band.
    swept_columns : sequence of str, optional
        The swept-parameter columns; by default every column outside the contract, in the
        frame's order (:func:`swept_columns_of`).
    chunk_rows : int
        Rows worked at a time, whole points (:func:`summarize_chunks`): the result is the
        same for any value.

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
    planners = has_planners(trials)
    keyed = ("scenario", "estimator", "planner") if planners else ("scenario", "estimator")
    orders = {key: tuple(pd.unique(trials[key])) for key in keyed}  # first appearance
    scenario = _ordered_codes(trials["scenario"])
    point = trials["point"].to_numpy(dtype=np.int64)
    frame = trials["frame"].to_numpy(dtype=np.int64)
    n_trial_sets = len(pd.DataFrame({"s": scenario, "p": point, "f": frame}).drop_duplicates())
    order = np.lexsort((point, scenario))  # stable: a group's rows keep their order
    starts = np.flatnonzero(
        np.diff(scenario[order], prepend=-1) | np.diff(point[order], prepend=-1)
    )
    cuts = [0]
    for start in starts[1:].tolist():  # whole points, chunk_rows or more at a time
        if start - cuts[-1] >= chunk_rows:
            cuts.append(start)
    chunks = (trials.iloc[order[a:b]] for a, b in itertools.pairwise([*cuts, len(order)]))
    return summarize_chunks(
        chunks,
        orders=orders,
        n_trial_sets=n_trial_sets,
        swept_columns=swept,
        n_bootstrap=n_bootstrap,
        seed=seed,
        confidence=confidence,
    )


def summarize_chunks(
    chunks: Iterable[pd.DataFrame],
    *,
    orders: Mapping[str, Sequence[str]],
    n_trial_sets: int,
    swept_columns: Sequence[str] | None = None,
    n_bootstrap: int = DEFAULT_N_BOOTSTRAP,
    seed: int | np.random.SeedSequence = 0,
    confidence: float = 0.95,
) -> pd.DataFrame:
    """:func:`summarize` of trial rows given a chunk at a time (memory: one chunk's).

    Every (scenario, point) lies in one chunk, and chunks come in the order of their
    scenarios (``orders["scenario"]``) and points; ``orders`` gives the order of the rows'
    ``scenario``, ``estimator`` and, in a closed loop, ``planner`` labels, and
    ``n_trial_sets`` the number of distinct (scenario, point, frame). The result does not
    depend on the chunking: the bootstrap's keys get their seeds from one draw of ``seed``'s
    generator for all of them (:data:`N_INTERVALS` rows of ``n_trial_sets``), as they would
    all at once, and every other number is a function of one group's rows.
    """
    planners = "planner" in orders and any(str(label) != "" for label in orders["planner"])
    keyed = ("scenario", "estimator", "planner") if planners else ("scenario", "estimator")
    rng = np.random.default_rng(seed)
    key_seeds = rng.integers(0, 2**63, size=(N_INTERVALS, int(n_trial_sets)))
    parts = []
    used = 0
    for chunk in chunks:
        if len(chunk) == 0:
            continue
        swept = list(swept_columns_of(chunk) if swept_columns is None else swept_columns)
        _check_trials(chunk, swept)
        codes = {key: _codes_in(chunk[key], orders[key]) for key in keyed}
        part, n_sets = _summarize_points(
            chunk,
            codes,
            key_seeds[:, used:],
            planners=planners,
            swept=swept,
            n_bootstrap=n_bootstrap,
            confidence=confidence,
        )
        parts.append(part)
        used += n_sets
        del chunk, codes  # before the next chunk is read
    if not parts:
        raise ValueError("trials: the frame has no rows; run the experiment first")
    if used != n_trial_sets:
        raise ValueError(
            f"n_trial_sets: the chunks hold {used} (scenario, point, frame), not {n_trial_sets}; "
            "give each point whole, in one chunk"
        )
    return pd.concat(parts, ignore_index=True)


def _codes_in(values: pd.Series, order: Sequence[str]) -> NDArray[np.int64]:
    """Each value's position in ``order``."""
    codes = pd.Index(list(order)).get_indexer(values)
    if (codes < 0).any():
        raise ValueError(f"{values.name}: labels {sorted(set(values[codes < 0]))} not in {order}")
    return codes.astype(np.int64)


def _summarize_points(
    trials: pd.DataFrame,
    codes: Mapping[str, NDArray[np.int64]],
    key_seeds: NDArray[np.int64],
    *,
    planners: bool,
    swept: Sequence[str],
    n_bootstrap: int,
    confidence: float,
) -> tuple[pd.DataFrame, int]:
    """The summary rows of whole points, and how many trial sets (seeds' keys) they used."""
    success = trials["success"].to_numpy(dtype=bool)
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
    trial_set = group_frame.groupby(["scenario", "point", "frame"], sort=True).ngroup()
    trial_set = trial_set.to_numpy(np.int64)
    del group_frame  # memory: a chunk may be a million rows

    def successful(column: str) -> FloatArray:
        return np.where(success, trials[column].to_numpy(dtype=float), np.nan)

    def optional(column: str) -> FloatArray:  # NaN in run folders of earlier versions
        if column not in trials.columns:
            return np.full(len(trials), np.nan)
        return trials[column].to_numpy(dtype=float)

    error = successful("error_m")
    side_error = successful("error_side_resolved_m")

    def error_vector(x: FloatArray, y: FloatArray) -> FloatArray:
        return np.stack([x, y], axis=1) - trials[["truth_x_m", "truth_y_m"]].to_numpy(float)

    returned_vector = error_vector(successful("x_m"), successful("y_m"))
    work = pd.DataFrame(
        {
            "group": group,
            "error": error,
            "squared_error": error**2,
            "squared_side_error": side_error**2,
            "error_x": returned_vector[:, 0],
            "error_y": returned_vector[:, 1],
            "wrong_side": successful("wrong_side"),
            "ambiguous": np.where(success, trials["ambiguous"].to_numpy(dtype=float), np.nan),
            "success": success.astype(float),
            "nees": successful("nees"),
            "nees_side": successful("nees_side_resolved"),
            "runtime": trials["runtime_s"].to_numpy(dtype=float),
            "crlb": trials["crlb_rmse_m"].to_numpy(dtype=float),
            "crlb_squared": trials["crlb_rmse_m"].to_numpy(dtype=float) ** 2,
        },
        copy=False,  # the columns as they are, not copied into one block
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
        crlb_median=("crlb", "median"),
        wrong_side_rate=("wrong_side", "mean"),
        n_side_judged=("wrong_side", "count"),
        ambiguous_rate=("ambiguous", "mean"),
        success_rate=("success", "mean"),
        n_nees=("nees", "count"),
        n_nees_side=("nees_side", "count"),
        nees_mean=("nees", "mean"),
        nees_side_mean=("nees_side", "mean"),
        runtime_median_s=("runtime", "median"),
    )
    stats_frame["p95_error_m"] = by_group["error"].quantile(0.95)
    del by_group, error, side_error
    work = work[["squared_error", "squared_side_error"]]  # what is left to do needs these

    # Estimators (and planners) that saw the same trials are resampled on the same trials.
    first_of_group = np.unique(group, return_index=True)[1]
    pairs = trial_set[first_of_group]
    n_trial_sets = int(pairs.max()) + 1
    seeds = iter(key_seeds[:, :n_trial_sets])  # one row per interval, in the order drawn
    in_trial_order = np.lexsort((trials["trial"].to_numpy(), group))

    def interval_m(squared: pd.Series) -> tuple[FloatArray, FloatArray]:
        low, high = studentized_bootstrap_interval(
            squared.to_numpy()[in_trial_order],
            group[in_trial_order],
            n_groups,
            pairs=pairs,
            n_bootstrap=n_bootstrap,
            key_seeds=next(seeds),
            confidence=confidence,
        )
        return np.sqrt(low), np.sqrt(high)

    rmse_low, rmse_high = interval_m(work["squared_error"])
    side_low, side_high = interval_m(work["squared_side_error"])
    rmse = np.sqrt(stats_frame["mean_squared"].to_numpy())
    rmse_side = np.sqrt(stats_frame["mean_squared_side"].to_numpy())
    # one flight for every trial: the common bound; one per trial (closed loop): their RMS
    crlb = np.where(
        stats_frame["crlb_low"].to_numpy() == stats_frame["crlb_high"].to_numpy(),
        stats_frame["crlb_rmse_m"].to_numpy(),
        np.sqrt(stats_frame["crlb_mean_squared"].to_numpy()),
    )

    def per_bound(value: FloatArray) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(crlb > 0, value / crlb, np.nan)

    # The verdicts judge the side-resolved error where any estimate is flagged ambiguous.
    side = stats_frame["ambiguous_rate"].fillna(0.0).to_numpy() > 0

    def judged(resolved: FloatArray, returned: FloatArray) -> FloatArray:
        return np.where(side, resolved, returned)

    judged_squared = np.where(
        side[group], work["squared_side_error"].to_numpy(), work["squared_error"].to_numpy()
    )
    n_judged = np.bincount(group[np.isfinite(judged_squared)], minlength=n_groups)
    efficiency_judged = per_bound(judged(rmse_side, rmse))
    judged_low = per_bound(judged(side_low, rmse_low))
    judged_high = per_bound(judged(side_high, rmse_high))
    tail = tail_share(judged_squared, group, n_groups)
    # formed only now (memory: a chunk may be a million rows)
    side_vector = error_vector(optional("x_side_resolved_m"), optional("y_side_resolved_m"))
    side_vector = np.where(success[:, None], side_vector, np.nan)
    judged_vector = np.where(side[group][:, None], side_vector, returned_vector)
    del side_vector, returned_vector
    bias = bias_intervals(judged_vector, group, n_groups, crlb, confidence)
    xx, xy, yy = (optional(f"crlb_{k}_m2") for k in ("xx", "xy", "yy"))
    crlb_matrix = np.stack([xx, xy, xy, yy], axis=1).reshape(-1, 2, 2)
    axis_squared = axis_squared_errors(judged_vector, crlb_matrix)
    del xx, xy, yy, crlb_matrix
    axis_intervals = [interval_m(pd.Series(q)) for q in axis_squared.T]
    axes = AxisEfficiencies(
        efficiency=np.sqrt(pd.DataFrame(axis_squared).groupby(group, sort=True).mean().to_numpy()),
        low=np.stack([low for low, _ in axis_intervals], axis=1),
        high=np.stack([high for _, high in axis_intervals], axis=1),
    )
    verdict, verdict_reason = efficiency_verdicts(
        n_judged=n_judged,
        n_trials=stats_frame["n_trials"].to_numpy(),
        efficiency=efficiency_judged,
        low=judged_low,
        high=judged_high,
        tail=tail,
        bias=bias,
        axes=axes,
    )
    n_nees = judged(stats_frame["n_nees_side"].to_numpy(), stats_frame["n_nees"].to_numpy())
    band_low, band_high = nees_band(n_nees, confidence)
    nees_judged = judged(stats_frame["nees_side_mean"].to_numpy(), stats_frame["nees_mean"])
    # goodness of fit (MATH §17): the share of the judged successes rejected at 1%
    fit = np.where(success, optional("fit_chi2"), np.nan), optional("fit_dof")
    n_fit_judged = np.bincount(group[fit_judged(*fit)], minlength=n_groups)
    n_fit_rejected = np.bincount(group[fit_rejected(*fit)], minlength=n_groups)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit_rejected_rate = np.where(n_fit_judged > 0, n_fit_rejected / n_fit_judged, np.nan)
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
            "efficiency": per_bound(rmse),
            "efficiency_side_resolved": per_bound(rmse_side),
            "wrong_side_rate": stats_frame["wrong_side_rate"].to_numpy(),
            "ambiguous_rate": stats_frame["ambiguous_rate"].to_numpy(),
            "success_rate": stats_frame["success_rate"].to_numpy(),
            "nees_judged_mean": np.asarray(nees_judged, dtype=float),
            "runtime_median_s": stats_frame["runtime_median_s"].to_numpy(),
            "n_successes": stats_frame["n_successes"].to_numpy(dtype=np.int64),
            "rmse_side_resolved_ci_low_m": side_low,
            "rmse_side_resolved_ci_high_m": side_high,
            "n_side_judged": stats_frame["n_side_judged"].to_numpy(dtype=np.int64),
            "n_nees": n_nees.astype(np.int64),
            "nees_band_low": band_low,
            "nees_band_high": band_high,
            "nees_verdict": nees_verdicts(nees_judged, n_nees, band_low, band_high),
            "nees_side_resolved_mean": stats_frame["nees_side_mean"].to_numpy(),
            "nees_returned_incl_wrong_side_mean": stats_frame["nees_mean"].to_numpy(),
            "crlb_rmse_median_m": stats_frame["crlb_median"].to_numpy(),
            "verdict_basis": np.where(side, "side-resolved", "returned"),
            "efficiency_judged": efficiency_judged,
            "efficiency_judged_ci_low": judged_low,
            "efficiency_judged_ci_high": judged_high,
            "bias_judged_x_m": bias.mean_m[:, 0],
            "bias_judged_y_m": bias.mean_m[:, 1],
            "bias_judged_m": bias.norm_m,
            "bias_ratio": bias.ratio,
            "bias_ratio_ci_low": bias.low,
            "bias_ratio_ci_high": bias.high,
            "efficiency_major_axis": axes.efficiency[:, 0],
            "efficiency_major_axis_ci_low": axes.low[:, 0],
            "efficiency_major_axis_ci_high": axes.high[:, 0],
            "efficiency_minor_axis": axes.efficiency[:, 1],
            "efficiency_minor_axis_ci_low": axes.low[:, 1],
            "efficiency_minor_axis_ci_high": axes.high[:, 1],
            "tail_share": tail,
            "verdict": verdict,
            "verdict_reason": verdict_reason,
            "fit_rejected_rate": fit_rejected_rate,
            "n_fit_judged": n_fit_judged.astype(np.int64),
        }
    )
    # The key columns of each group: its first row (they are constant within a group).
    first_rows = np.unique(group, return_index=True)[1]
    key_columns = ["scenario", "snr_db", *swept, "frame", *(["planner"] if planners else [])]
    key_columns.append("estimator")
    keys = trials.iloc[first_rows][key_columns]
    keys = keys.reset_index(drop=True).astype({"snr_db": float, "frame": np.int64})
    return pd.concat([keys, metrics], axis=1)[[*key_columns, *METRIC_NAMES]], n_trial_sets


# --------------------------------------------------------------------------------------------
# reading a summary
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


_UNITS = {"_db": "dB", "_m": "m", "_s": "s", "_hz": "Hz", "_mps": "m/s", "_m2": "m²"}


def parameter_label(column: str) -> tuple[str, str]:
    """Display name and unit of a swept column: ``snr_db`` → ``("SNR", "dB")``."""
    if column == "snr_db":
        return "SNR", "dB"
    for suffix in sorted(_UNITS, key=len, reverse=True):
        if column.endswith(suffix):
            return column, _UNITS[suffix]
    return column, ""


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
