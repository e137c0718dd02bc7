r"""Summaries of Monte Carlo trials: one row of metrics per group of trials.

:func:`summarize` turns the tidy trial rows of :func:`comparison.engine.read_trials` (one row
per estimator × scenario × point × frame × trial, and planner in a closed loop) into one row per
(scenario, point, frame, estimator), and planner when the rows have planners. Its metric
columns are the entries of :mod:`comparison.metric_registry` (:data:`METRIC_NAMES`), each with
its unit, description and computation: the RMSE and its 95% studentized-bootstrap interval
(:mod:`comparison.verdicts` says why that method), the side-resolved RMSE (MATH §7), the
paper's "accuracy" (MATH §14), the CRLB (MATH §8) and the efficiencies, rates with their counts
beside them, the NEES and its chi-square band, the goodness of fit (MATH §17) and the verdicts
(MATH §16). :func:`summarize_chunks` does the same a chunk of whole points at a time.

The SNR axis scales every reference σ by :math:`10^{-\mathrm{SNR}/20}` (MATH §2).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from comparison.intervals import DEFAULT_N_BOOTSTRAP
from comparison.metric_groups import INTERVAL_SEED_ROWS, Groups, position_dimension_of
from comparison.metric_groups import SUMMARY_TRIAL_COLUMNS as SUMMARY_TRIAL_COLUMNS
from comparison.metric_registry import CONTRACT_METRIC_NAMES as CONTRACT_METRIC_NAMES
from comparison.metric_registry import METRIC_NAMES as METRIC_NAMES
from comparison.metric_registry import METRICS
from comparison.trial_rows import (
    COORDINATES,
    REQUIRED_TRIAL_COLUMNS,
    TRIAL_COLUMNS,
    dimension_columns,
)

N_INTERVALS = len(INTERVAL_SEED_ROWS)
"""Bootstrap intervals of a group, each drawing a seed per key: the RMSE, the side-resolved
RMSE and the two principal axes."""

SUMMARY_CHUNK_ROWS = 250_000
"""Trial rows :func:`summarize` works at a time (whole points: a point of more is one chunk)."""


def has_planners(frame: pd.DataFrame) -> bool:
    """True when the rows come from a closed loop: a ``planner`` column with a label."""
    if "planner" not in frame.columns:
        return False
    labels = frame["planner"]
    return bool((labels.notna() & (labels.astype(str) != "")).any())


def swept_columns_of(trials: pd.DataFrame) -> list[str]:
    """The swept-parameter columns of a trial frame (every column not in the contract, nor a
    coordinate or matrix entry of a 3-D position: :func:`~comparison.trial_rows.dimension_columns`)."""
    fixed = {*TRIAL_COLUMNS, *dimension_columns(len(COORDINATES))}
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

    Each metric column is an entry of :mod:`comparison.metric_registry`, computed in order
    for the groups of a chunk (:class:`comparison.metric_groups.Groups`): the error metrics,
    the wrong-side and ambiguous rates and the NEES over the successful trials (their counts
    beside them), ``success_rate`` and ``runtime_median_s`` over every trial.

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
    """The summary rows of whole points, and how many trial sets (seeds' keys) they used.

    In a 3-D run (an emitter of unknown height) the groups whose answers are horizontal (a
    scenario with the height known, or an estimator that assumes it) are summarised in 2-D,
    apart from the others, each trial set keeping its seeds, their ``rmse_horizontal_m`` and
    ``crlb_horizontal_m`` their ``rmse_m`` and ``crlb_rmse_m``; the rows then come back in the
    groups' order."""
    horizontal = _horizontal_rows(trials, codes, planners)
    kinds = [horizontal] if horizontal is not None and horizontal.all() else []
    if horizontal is not None and horizontal.any() and not horizontal.all():
        kinds = [horizontal, ~horizontal]
    if not kinds:  # one dimension: the rows as they are
        part, groups = _summarize_rows(
            trials, codes, key_seeds, planners, swept, n_bootstrap, confidence
        )
        return part, groups.n_trial_sets
    trial_set = _trial_set_codes(trials, codes)
    parts, order = [], []
    for rows in kinds:
        flat = rows is horizontal
        subset = trials[rows]
        if flat:
            subset = subset.drop(columns=[c for c in _Z_COLUMNS if c in subset.columns])
        sets = np.unique(trial_set[rows])
        part, groups = _summarize_rows(
            subset,
            {key: value[rows] for key, value in codes.items()},
            key_seeds[:, sets],
            planners,
            swept,
            n_bootstrap,
            confidence,
        )
        if flat:  # a horizontal answer's horizontal parts are its whole
            part["rmse_horizontal_m"] = part["rmse_m"]
            part["crlb_horizontal_m"] = part["crlb_rmse_m"]
        parts.append(part)
        first = groups.first_rows
        order.append(
            np.column_stack(
                [
                    codes["scenario"][rows][first],
                    subset["point"].to_numpy(np.int64)[first],
                    codes["planner"][rows][first] if planners else np.zeros(len(first), int),
                    subset["frame"].to_numpy(np.int64)[first],
                    codes["estimator"][rows][first],
                ]
            )
        )
    keys = np.concatenate(order)
    merged = pd.concat(parts, ignore_index=True)
    ranked = np.lexsort(keys.T[::-1])
    columns = [*(c for c in merged.columns if c not in METRIC_NAMES), *METRIC_NAMES]
    merged = merged[[c for c in columns if c in merged.columns]]
    return merged.iloc[ranked].reset_index(drop=True), int(trial_set.max()) + 1


_Z_COLUMNS = tuple(c for c in dimension_columns(3) if c not in dimension_columns(2))
"""The columns a 3-D trial table adds to a 2-D one (dropped for the groups scored in 2-D)."""


def _horizontal_rows(
    trials: pd.DataFrame, codes: Mapping[str, NDArray[np.int64]], planners: bool
) -> NDArray[np.bool_] | None:
    """In a 3-D table, the rows of groups scored in 2-D: none of their rows has a height
    (``z_m``) or a vertical bound (``crlb_zz_m2``); None in a 2-D table."""
    if position_dimension_of(trials.columns) < 3:
        return None
    has_height = np.isfinite(trials["z_m"].to_numpy(dtype=float))
    if "crlb_zz_m2" in trials.columns:
        has_height |= np.isfinite(trials["crlb_zz_m2"].to_numpy(dtype=float))
    group = pd.DataFrame(
        {
            "scenario": codes["scenario"],
            "point": trials["point"].to_numpy(np.int64),
            "planner": codes["planner"] if planners else 0,
            "frame": trials["frame"].to_numpy(np.int64),
            "estimator": codes["estimator"],
            "height": has_height,
        }
    )
    keys = ["scenario", "point", "planner", "frame", "estimator"]
    return ~group.groupby(keys, sort=False)["height"].transform("any").to_numpy(dtype=bool)


def _trial_set_codes(
    trials: pd.DataFrame, codes: Mapping[str, NDArray[np.int64]]
) -> NDArray[np.int64]:
    """Each row's trial set (scenario, point, frame), numbered as :class:`Groups` numbers
    them: the column of ``key_seeds`` it draws from."""
    frame = pd.DataFrame(
        {
            "scenario": codes["scenario"],
            "point": trials["point"].to_numpy(np.int64),
            "frame": trials["frame"].to_numpy(np.int64),
        }
    )
    return frame.groupby(["scenario", "point", "frame"], sort=True).ngroup().to_numpy(np.int64)


def _summarize_rows(
    trials: pd.DataFrame,
    codes: Mapping[str, NDArray[np.int64]],
    key_seeds: NDArray[np.int64],
    planners: bool,
    swept: Sequence[str],
    n_bootstrap: int,
    confidence: float,
) -> tuple[pd.DataFrame, Groups]:
    """The summary rows of the groups of ``trials`` (positions of one dimension)."""
    dimension = position_dimension_of(trials.columns)
    metrics_here = [m for m in METRICS if m.dimension <= dimension]
    groups = Groups(
        trials,
        codes,
        key_seeds,
        planners=planners,
        aggregates={m.name: m.aggregate for m in metrics_here if m.aggregate is not None},
        n_bootstrap=n_bootstrap,
        confidence=confidence,
    )
    for metric in metrics_here:  # in order: a rule reads the metrics before it
        groups.values[metric.name] = metric.value(groups)
    metrics = pd.DataFrame(groups.values)
    # The key columns of each group: its first row (they are constant within a group).
    key_columns = ["scenario", "snr_db", *swept, "frame", *(["planner"] if planners else [])]
    key_columns.append("estimator")
    keys = trials.iloc[groups.first_rows][key_columns]
    keys = keys.reset_index(drop=True).astype({"snr_db": float, "frame": np.int64})
    return pd.concat([keys, metrics], axis=1), groups


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
    """Display name and unit of a swept column: ``snr_db`` → ``("SNR", "dB")``, ``cn0_dbhz``
    → ``("C/N0", "dB-Hz")``."""
    if column == "snr_db":
        return "SNR", "dB"
    if column == "cn0_dbhz":
        return "C/N0", "dB-Hz"
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
