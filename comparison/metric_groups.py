"""The groups of a chunk of trial rows, and the quantities the metrics are computed from.

A group is one (scenario, point, planner, frame, estimator). :class:`Groups` holds, for the
trial rows of whole points, the group of every row, the per-trial quantities of
:data:`TRIAL_QUANTITIES` aggregated per group, and the inferences several metrics share: the
CRLB reference, which error the verdicts judge (the side-resolved one where an estimate is
flagged ambiguous, MATH §7), the bootstrap intervals, the bias and principal-axis intervals
(:mod:`comparison.intervals`, MATH §16). The metrics themselves are the entries of
:mod:`comparison.metric_registry`; :func:`comparison.metrics.summarize` runs them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from functools import cached_property
from typing import TypeVar

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from pandas.api.typing import SeriesGroupBy

from comparison.intervals import (
    AxisEfficiencies,
    BiasIntervals,
    axis_names,
    axis_squared_errors,
    bias_intervals,
    studentized_bootstrap_interval,
)
from comparison.trial_rows import (
    COORDINATES,
    REQUIRED_TRIAL_COLUMNS,
    SCORED_DIMENSION,
    coordinate_columns,
    matrix_columns,
    matrix_of_values,
)

FloatArray = NDArray[np.float64]
_Shared = TypeVar("_Shared")


def summary_trial_columns(dimension: int = SCORED_DIMENSION) -> tuple[str, ...]:
    """The trial columns a summary of positions of ``dimension`` coordinates reads (with the
    swept ones): the required ones (and, past ``(x, y)``, the further coordinates of the truth
    and the position), and those it reads when present: the side-resolved position and the
    CRLB's entries (:func:`~comparison.trial_rows.coordinate_columns`,
    :func:`~comparison.trial_rows.matrix_columns`)."""
    coordinates = (
        *coordinate_columns("truth_{}_m", dimension),
        *coordinate_columns("{}_m", dimension),
    )
    return (
        *REQUIRED_TRIAL_COLUMNS,
        *(name for name in coordinates if name not in REQUIRED_TRIAL_COLUMNS),
        "planner",
        "trial",
        *coordinate_columns("{}_side_resolved_m", dimension),
        *matrix_columns("crlb", dimension),
        "fit_chi2",
        "fit_dof",
    )


SUMMARY_TRIAL_COLUMNS: tuple[str, ...] = summary_trial_columns()
"""The trial columns a summary of the tables (:data:`~comparison.trial_rows.SCORED_DIMENSION`)
reads. :class:`Groups` reads no other, so a chunked read of these is enough."""

INTERVAL_SEED_ROWS: dict[str, int] = {
    "error": 0,
    "side_resolved": 1,
    "major": 2,
    "minor": 3,
    "middle": 4,
}
"""The row of the seeds drawn per trial set that each bootstrap interval of a group uses (the
principal axes': :func:`~comparison.intervals.axis_names`; ``middle`` only in 3-D, last so
that the rows of 2-D summaries are drawn as before it)."""


def position_dimension_of(columns: Iterable[str]) -> int:
    """``d`` of trial rows with these columns: how many coordinates of the truth they hold,
    ``truth_x_m``, ``truth_y_m`` (and ``truth_z_m``) (:data:`~comparison.trial_rows.COORDINATES`)."""
    present = set(columns)
    names = coordinate_columns("truth_{}_m", len(COORDINATES))
    return next((k for k, name in enumerate(names) if name not in present), len(names))


Aggregation = str | Callable[[SeriesGroupBy], pd.Series]
"""How a per-trial quantity becomes one number per group: a pandas aggregation name
(``"mean"``, ``"median"``, ``"count"``, ``"size"``, ...) or a function of the grouped values."""


TRIAL_QUANTITIES: dict[str, Callable[[Groups], FloatArray]] = {
    "error": lambda g: g.successful("error_m"),
    "squared_error": lambda g: g.successful("error_m") ** 2,
    "squared_side_error": lambda g: g.successful("error_side_resolved_m") ** 2,
    "error_x": lambda g: g.successful("x_m") - g.column("truth_x_m"),
    "error_y": lambda g: g.successful("y_m") - g.column("truth_y_m"),
    "error_z": lambda g: g.successful("z_m") - g.column("truth_z_m"),
    "squared_horizontal_error": lambda g: (
        (g.successful("x_m") - g.column("truth_x_m")) ** 2
        + (g.successful("y_m") - g.column("truth_y_m")) ** 2
    ),
    "squared_vertical_error": lambda g: (g.successful("z_m") - g.column("truth_z_m")) ** 2,
    "crlb_horizontal_squared": lambda g: g.column("crlb_xx_m2") + g.column("crlb_yy_m2"),
    "crlb_vertical_squared": lambda g: g.column("crlb_zz_m2"),
    "wrong_side": lambda g: g.successful("wrong_side"),
    "ambiguous": lambda g: g.successful("ambiguous"),
    "success": lambda g: g.success.astype(float),
    "nees": lambda g: g.successful("nees"),
    "nees_side": lambda g: g.successful("nees_side_resolved"),
    "runtime": lambda g: g.column("runtime_s"),
    "crlb": lambda g: g.column("crlb_rmse_m"),
    "crlb_squared": lambda g: g.column("crlb_rmse_m") ** 2,
}
"""Per-trial quantities a metric may aggregate (``Metric.aggregate``): NaN on a failed trial
for those of the successful trials only. A summary forms those its metrics aggregate (the
height's only in 3-D)."""

SHARED_AGGREGATES: dict[str, tuple[str, Aggregation]] = {
    "mean_squared_error": ("squared_error", "mean"),
    "mean_squared_side_error": ("squared_side_error", "mean"),
    "crlb_mean": ("crlb", "mean"),
    "crlb_low": ("crlb", "min"),
    "crlb_high": ("crlb", "max"),
    "crlb_mean_squared": ("crlb_squared", "mean"),
    "n_nees_returned": ("nees", "count"),
    "n_nees_side": ("nees_side", "count"),
}
"""Aggregates that are no column themselves but that metrics are computed from."""


class Groups:
    """The trial rows of whole points, grouped, and what their metrics are computed from.

    ``aggregates`` names the per-group aggregates to form, each a (quantity of
    :data:`TRIAL_QUANTITIES`, :data:`Aggregation`); they are formed at once, and the
    per-trial quantities dropped, before any metric is read (memory: a chunk may be a million
    rows). ``key_seeds`` has a row of seeds per bootstrap interval
    (:data:`INTERVAL_SEED_ROWS`) and a column per trial set (scenario, point, frame), in order.
    Metrics computed so far are read as ``groups[name]``.
    """

    def __init__(
        self,
        trials: pd.DataFrame,
        codes: Mapping[str, NDArray[np.int64]],
        key_seeds: NDArray[np.int64],
        *,
        planners: bool,
        aggregates: Mapping[str, tuple[str, Aggregation]],
        n_bootstrap: int,
        confidence: float,
    ) -> None:
        self.trials = trials
        self.dimension = position_dimension_of(trials.columns)
        self.readable = frozenset(summary_trial_columns(self.dimension))
        self.n_bootstrap = n_bootstrap
        self.confidence = confidence
        self.success = trials["success"].to_numpy(dtype=bool)
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
        self.group = group_frame.groupby(group_keys, sort=True).ngroup().to_numpy(np.int64)
        self.n_groups = int(self.group.max()) + 1
        trial_set = group_frame.groupby(["scenario", "point", "frame"], sort=True).ngroup()
        del group_frame  # memory: a chunk may be a million rows
        # Estimators (and planners) that saw the same trials are resampled on the same trials.
        self.first_rows = np.unique(self.group, return_index=True)[1]
        self.pairs = trial_set.to_numpy(np.int64)[self.first_rows]
        self.n_trial_sets = int(self.pairs.max()) + 1
        self.key_seeds = key_seeds[:, : self.n_trial_sets]
        self.in_trial_order = np.lexsort((trials["trial"].to_numpy(), self.group))
        self.aggregates, self.squared_errors = self._aggregate({**SHARED_AGGREGATES, **aggregates})
        self.values: dict[str, ArrayLike] = {}
        self._intervals: dict[str, tuple[FloatArray, FloatArray]] = {}
        self._shared: dict[Callable[[Groups], object], object] = {}

    def _aggregate(
        self, aggregates: Mapping[str, tuple[str, Aggregation]]
    ) -> tuple[pd.DataFrame, pd.DataFrame]:
        """The aggregates per group, and the squared errors the intervals still need."""
        used = {"squared_error", "squared_side_error", *(q for q, _ in aggregates.values())}
        work = pd.DataFrame(
            {
                "group": self.group,
                **{name: of(self) for name, of in TRIAL_QUANTITIES.items() if name in used},
            },
            copy=False,  # the columns as they are, not copied into one block
        )
        by_group = work.groupby("group", sort=True)
        named = {name: spec for name, spec in aggregates.items() if isinstance(spec[1], str)}
        formed = by_group.agg(**named)
        for name, (quantity, how) in aggregates.items():
            if not isinstance(how, str):
                formed[name] = how(by_group[quantity])
        return formed, work[["squared_error", "squared_side_error"]]

    # ---------------------------------------------------------------------------------------
    # the trial columns
    # ---------------------------------------------------------------------------------------

    def column(self, column: str) -> FloatArray:
        """A trial column as floats: NaN for an optional one missing in an older run folder."""
        if column not in self.readable:
            raise KeyError(f"{column}: add it to summary_trial_columns so chunked reads load it")
        if column not in self.trials.columns:
            return np.full(len(self.trials), np.nan)
        return self.trials[column].to_numpy(dtype=float)

    def successful(self, column: str) -> FloatArray:
        """A trial column on the successful trials, NaN on the others."""
        return np.where(self.success, self.column(column), np.nan)

    def error_vector(self, template: str) -> FloatArray:
        """``(n, d)`` the position whose coordinate columns ``template`` names (``"{}_m"``,
        ``"{}_side_resolved_m"``) minus the truth."""
        position = [self.column(name) for name in coordinate_columns(template, self.dimension)]
        truth = [self.column(name) for name in coordinate_columns("truth_{}_m", self.dimension)]
        return np.stack(position, axis=1) - np.stack(truth, axis=1)

    def count(self, mask: NDArray[np.bool_]) -> NDArray[np.int64]:
        """How many trials of each group ``mask`` holds."""
        return np.bincount(self.group[mask], minlength=self.n_groups)

    # ---------------------------------------------------------------------------------------
    # per group
    # ---------------------------------------------------------------------------------------

    def __getitem__(self, name: str) -> FloatArray:
        """A metric computed so far, or an aggregate."""
        if name in self.values:
            return np.asarray(self.values[name])
        if name in self.aggregates.columns:
            return self.aggregates[name].to_numpy()
        raise KeyError(f"{name}: neither an aggregate nor a metric computed before this one")

    def once(self, compute: Callable[[Groups], _Shared]) -> _Shared:
        """``compute(self)``, computed once for the groups: what several metrics take apart
        (the verdict and its reason, the NEES band's two ends)."""
        if compute not in self._shared:
            self._shared[compute] = compute(self)
        return self._shared[compute]  # type: ignore[return-value]

    @cached_property
    def crlb(self) -> FloatArray:
        """The CRLB reference (√trace, MATH §8): the rows' ``crlb_rmse_m`` when it is constant
        within a group (one flight for all trials), else their root mean square: each
        closed-loop trial flies its own trajectory, and ``E[e²] ≥ E[tr CRLB(trajectory)]``
        makes the RMS of the per-trial bounds the reference for the RMSE (a reference, not a
        strict bound, since the trajectory depends on earlier noise)."""
        return np.where(
            self["crlb_low"] == self["crlb_high"],
            self["crlb_mean"],
            np.sqrt(self["crlb_mean_squared"]),
        )

    def per_bound(self, value: ArrayLike) -> FloatArray:
        """``value / crlb``, NaN where there is no bound."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.crlb > 0, np.asarray(value) / self.crlb, np.nan)

    @cached_property
    def side(self) -> NDArray[np.bool_]:
        """Groups whose verdicts judge the side-resolved error: any estimate flagged ambiguous."""
        return np.nan_to_num(self["ambiguous_rate"], nan=0.0) > 0

    def judged(self, resolved: ArrayLike, returned: ArrayLike) -> FloatArray:
        """Per group, the side-resolved value where :attr:`side`, else the returned one."""
        return np.where(self.side, resolved, returned)

    def interval_m(self, squared: ArrayLike, name: str) -> tuple[FloatArray, FloatArray]:
        """The 95% studentized-bootstrap interval of the RMS of per-trial ``squared`` errors,
        drawn with the seeds of ``name`` (:data:`INTERVAL_SEED_ROWS`); formed once."""
        if name not in self._intervals:
            low, high = studentized_bootstrap_interval(
                np.asarray(squared)[self.in_trial_order],
                self.group[self.in_trial_order],
                self.n_groups,
                pairs=self.pairs,
                n_bootstrap=self.n_bootstrap,
                key_seeds=self.key_seeds[INTERVAL_SEED_ROWS[name]],
                confidence=self.confidence,
            )
            self._intervals[name] = (np.sqrt(low), np.sqrt(high))
        return self._intervals[name]

    @cached_property
    def judged_squared(self) -> FloatArray:
        """Per trial, the squared error the verdicts judge."""
        errors = self.squared_errors
        return np.where(
            self.side[self.group],
            errors["squared_side_error"].to_numpy(),
            errors["squared_error"].to_numpy(),
        )

    @cached_property
    def judged_vector(self) -> FloatArray:
        """Per trial, the ``(n, d)`` error vector the verdicts judge (NaN on a failed trial)."""
        side_vector = self.error_vector("{}_side_resolved_m")
        returned_vector = self.error_vector("{}_m")
        vector = np.where(self.side[self.group][:, None], side_vector, returned_vector)
        return np.where(self.success[:, None], vector, np.nan)

    @cached_property
    def bias(self) -> BiasIntervals:
        """The judged mean error and its interval against the bound (Hotelling, MATH §16)."""
        return bias_intervals(
            self.judged_vector, self.group, self.n_groups, self.crlb, self.confidence
        )

    @cached_property
    def axes(self) -> AxisEfficiencies:
        """The judged RMSE/√CRLB along the CRLB's principal axes (:func:`axis_names` of ``d``),
        with intervals (MATH §16)."""
        crlb_matrix = matrix_of_values(
            [self.column(name) for name in matrix_columns("crlb", self.dimension)]
        )
        axis_squared = axis_squared_errors(self.judged_vector, crlb_matrix)
        del crlb_matrix
        intervals = [
            self.interval_m(q, name)
            for q, name in zip(axis_squared.T, axis_names(self.dimension), strict=True)
        ]
        efficiency = pd.DataFrame(axis_squared).groupby(self.group, sort=True).mean()
        return AxisEfficiencies(
            efficiency=np.sqrt(efficiency.to_numpy()),
            low=np.stack([low for low, _ in intervals], axis=1),
            high=np.stack([high for _, high in intervals], axis=1),
        )
