r"""The metrics of a summary: one :class:`Metric` entry each, in the order of the columns.

An entry is the whole of a metric: its column name, unit, description (the report's "Metric
definitions" and the table of docs/writing-an-experiment.md are made from it), the count that
stands beside it when it is a rate or a mean of a subset, and how it is computed for a group
(one scenario, point, planner, frame and estimator) of trial rows:

- ``aggregate=(quantity, how)``: a per-trial quantity of
  :data:`comparison.metric_groups.TRIAL_QUANTITIES` aggregated over the group's trials
  (``"mean"``, ``"median"``, ``"count"``, ... or a function of the grouped values), e.g.
  ``mean_error_m`` (the paper's "accuracy", MATH §14) is ``("error", "mean")``;
- ``rule=``: a function of the :class:`comparison.metric_groups.Groups`, which reads the
  aggregates and the metrics before it by name (``groups["rmse_m"]``) and the inferences
  several metrics share (the CRLB reference, the judged error, the bootstrap, bias and
  principal-axis intervals of MATH §16), e.g. ``rmse_m`` :math:`= \sqrt{\tfrac1n\sum_i e_i^2}`
  over the successful trials is ``sqrt(groups["mean_squared_error"])``.

:func:`comparison.metrics.summarize` computes the entries in order. To add a metric, add its
entry here (a new per-trial quantity goes in ``TRIAL_QUANTITIES``, a trial column it reads in
``SUMMARY_TRIAL_COLUMNS``), and run ``python -m comparison.metric_registry`` to print the docs'
table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from comparison.intervals import nees_band, tail_share
from comparison.metric_groups import Aggregation, FloatArray, Groups
from comparison.verdicts import efficiency_verdicts, nees_verdicts
from estimators.goodness_of_fit import fit_judged, fit_rejected

UNITS: dict[str, str] = {
    "m": "metres",
    "s": "seconds",
    "1": "dimensionless",
    "count": "trials",
    "text": "text",
}
"""The units a metric may have, and how the report and the docs name them."""


@dataclass(frozen=True)
class Metric:
    """One column of a summary: exactly one of ``aggregate`` and ``rule`` says how it is
    computed (module docstring); ``count`` names the metric counting what a rate or a mean is
    taken over."""

    name: str
    unit: str
    description: str
    aggregate: tuple[str, Aggregation] | None = None
    rule: Callable[[Groups], ArrayLike] | None = None
    count: str | None = None
    dimension: int = 2
    """The fewest coordinates a position has for the metric to exist: 3 for those of the
    height (a summary of a run with the emitter's height unknown, MATH §8)."""

    def __post_init__(self) -> None:
        if (self.aggregate is None) == (self.rule is None):
            raise ValueError(f"{self.name}: give exactly one of aggregate and rule")
        if self.unit not in UNITS:
            raise ValueError(f"{self.name}: unit {self.unit!r} is not one of {list(UNITS)}")

    def value(self, groups: Groups) -> ArrayLike:
        """The metric of every group: integers for a count, words for text, else floats."""
        value = groups[self.name] if self.rule is None else self.rule(groups)
        if self.unit == "count":
            return np.asarray(value, dtype=np.int64)
        if self.unit == "text":
            return value
        return np.asarray(value, dtype=float)


def _interval(squared: str, seeds: str, end: int) -> Callable[[Groups], FloatArray]:
    return lambda g: g.interval_m(g.squared_errors[squared], seeds)[end]


def _judged_interval(end: str) -> Callable[[Groups], FloatArray]:
    resolved, returned = f"rmse_side_resolved_ci_{end}_m", f"rmse_ci_{end}_m"
    return lambda g: g.per_bound(g.judged(g[resolved], g[returned]))


def _nees_band(g: Groups) -> tuple[FloatArray, FloatArray]:
    return nees_band(g["n_nees"], g.confidence, dof=g.dimension)


def _verdicts(g: Groups) -> tuple[ArrayLike, list[str]]:
    return efficiency_verdicts(
        n_judged=g.count(np.isfinite(g.judged_squared)),
        n_trials=g["n_trials"],
        efficiency=g["efficiency_judged"],
        low=g["efficiency_judged_ci_low"],
        high=g["efficiency_judged_ci_high"],
        tail=g["tail_share"],
        bias=g.bias,
        axes=g.axes,
    )


def _fit_counts(g: Groups) -> tuple[FloatArray, FloatArray]:
    """Per group, the estimates whose fit is judged and those rejected at 1% (MATH §17)."""
    fit = g.successful("fit_chi2"), g.column("fit_dof")
    return g.count(fit_judged(*fit)), g.count(fit_rejected(*fit))


def _fit_rejected_rate(g: Groups) -> FloatArray:
    n_judged, n_rejected = g.once(_fit_counts)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(n_judged > 0, n_rejected / n_judged, np.nan)


def _axis_metrics(axis: str, index: int, description: str) -> tuple[Metric, ...]:
    """The efficiency along one principal axis of the CRLB and its 95% interval (MATH §16)."""
    name = f"efficiency_{axis}_axis"
    return (
        Metric(name, "1", description, rule=lambda g: g.axes.efficiency[:, index]),
        Metric(
            f"{name}_ci_low",
            "1",
            "lower end of its 95% interval",
            rule=lambda g: g.axes.low[:, index],
        ),
        Metric(
            f"{name}_ci_high",
            "1",
            "upper end of its 95% interval",
            rule=lambda g: g.axes.high[:, index],
        ),
    )


CONTRACT_METRICS: tuple[Metric, ...] = (
    Metric("n_trials", "count", "trials run (successful or not)", aggregate=("success", "size")),
    Metric(
        "rmse_m",
        "m",
        "root mean square error of the returned position, successful trials",
        rule=lambda g: np.sqrt(g["mean_squared_error"]),
    ),
    Metric(
        "rmse_ci_low_m",
        "m",
        "lower end of the 95% studentized-bootstrap interval of rmse_m",
        rule=_interval("squared_error", "error", 0),
    ),
    Metric(
        "rmse_ci_high_m",
        "m",
        "upper end of the 95% studentized-bootstrap interval of rmse_m",
        rule=_interval("squared_error", "error", 1),
    ),
    Metric(
        "rmse_side_resolved_m",
        "m",
        "RMSE of the candidate nearest to the truth (MATH §7)",
        rule=lambda g: np.sqrt(g["mean_squared_side_error"]),
    ),
    Metric(
        "mean_error_m",
        "m",
        "mean distance error, the paper's 'accuracy' (MATH §14)",
        aggregate=("error", "mean"),
    ),
    Metric("median_error_m", "m", "median distance error", aggregate=("error", "median")),
    Metric(
        "cep50_m",
        "m",
        "circular error probable: radius about the truth holding 50% of the estimates "
        "(the median distance error)",
        rule=lambda g: g["median_error_m"],
    ),
    Metric(
        "p95_error_m",
        "m",
        "95th percentile of the distance error",
        aggregate=("error", lambda grouped: grouped.quantile(0.95)),
    ),
    Metric("bias_x_m", "m", "mean of x_m - truth_x_m", aggregate=("error_x", "mean")),
    Metric("bias_y_m", "m", "mean of y_m - truth_y_m", aggregate=("error_y", "mean")),
    Metric(
        "crlb_rmse_m",
        "m",
        "√trace(CRLB) for the estimator's modalities and frames (MATH §8); the root mean "
        "square over trials when each trial flew its own trajectory (closed loop)",
        rule=lambda g: g.crlb,
    ),
    Metric(
        "efficiency",
        "1",
        "rmse_m / crlb_rmse_m (1 attains the bound)",
        rule=lambda g: g.per_bound(g["rmse_m"]),
    ),
    Metric(
        "efficiency_side_resolved",
        "1",
        "rmse_side_resolved_m / crlb_rmse_m",
        rule=lambda g: g.per_bound(g["rmse_side_resolved_m"]),
    ),
    Metric(
        "wrong_side_rate",
        "1",
        "fraction of the n_side_judged estimates off the track plane that lie on the other side "
        "of the track from the truth (MATH §7)",
        aggregate=("wrong_side", "mean"),
        count="n_side_judged",
    ),
    Metric(
        "ambiguous_rate",
        "1",
        "fraction of successful estimates flagged ambiguous (MATH §7)",
        aggregate=("ambiguous", "mean"),
        count="n_successes",
    ),
    Metric(
        "success_rate",
        "1",
        "fraction of the n_trials trials with a returned position",
        aggregate=("success", "mean"),
        count="n_trials",
    ),
    Metric(
        "nees_judged_mean",
        "1",
        "mean NEES eᵀP⁻¹e of verdict_basis's error against its covariance (the one "
        "nees_verdict judges; d when consistent: 2, or 3 with the height estimated)",
        rule=lambda g: g.judged(
            g["nees_side_resolved_mean"], g["nees_returned_incl_wrong_side_mean"]
        ),
        count="n_nees",
    ),
    Metric(
        "runtime_median_s",
        "s",
        "median wall time of one estimate: one call's time for an estimator called per trial; "
        "a batch call's time divided by its trials for a batch estimator; the frame's update "
        "and estimate_state for a streamed one",
        aggregate=("runtime", "median"),
    ),
)
"""The metric columns every summary has first, in this order."""

EXTRA_METRICS: tuple[Metric, ...] = (
    Metric(
        "bias_z_m",
        "m",
        "mean of z_m - truth_z_m (3-D runs: the emitter's height estimated)",
        aggregate=("error_z", "mean"),
        dimension=3,
    ),
    Metric(
        "rmse_horizontal_m",
        "m",
        "RMSE of the returned position's (x, y), successful trials (3-D runs)",
        aggregate=("squared_horizontal_error", lambda grouped: np.sqrt(grouped.mean())),
        dimension=3,
    ),
    Metric(
        "rmse_vertical_m",
        "m",
        "RMSE of the returned position's height z, successful trials (3-D runs)",
        aggregate=("squared_vertical_error", lambda grouped: np.sqrt(grouped.mean())),
        dimension=3,
    ),
    Metric(
        "crlb_horizontal_m",
        "m",
        "√(CRLB_xx + CRLB_yy): the horizontal part of the 3-D bound (3-D runs, MATH §8)",
        aggregate=("crlb_horizontal_squared", lambda grouped: np.sqrt(grouped.mean())),
        dimension=3,
    ),
    Metric(
        "crlb_vertical_m",
        "m",
        "√CRLB_zz: the vertical part of the 3-D bound (3-D runs, MATH §8)",
        aggregate=("crlb_vertical_squared", lambda grouped: np.sqrt(grouped.mean())),
        dimension=3,
    ),
    Metric(
        "n_successes",
        "count",
        "trials whose estimator returned a position",
        aggregate=("success", "sum"),
    ),
    Metric(
        "rmse_side_resolved_ci_low_m",
        "m",
        "lower end of the interval of the side-resolved RMSE",
        rule=_interval("squared_side_error", "side_resolved", 0),
    ),
    Metric(
        "rmse_side_resolved_ci_high_m",
        "m",
        "upper end of the interval of the side-resolved RMSE",
        rule=_interval("squared_side_error", "side_resolved", 1),
    ),
    Metric(
        "n_side_judged",
        "count",
        "successful estimates off the track plane: the wrong-side rate's count",
        aggregate=("wrong_side", "count"),
    ),
    Metric(
        "n_nees",
        "count",
        "successful trials with a covariance: the count of the judged NEES mean",
        rule=lambda g: g.judged(g["n_nees_side"], g["n_nees_returned"]),
    ),
    Metric(
        "nees_band_low",
        "1",
        "2.5% point of the mean of n_nees consistent NEES values of d = 2 (or 3) degrees of freedom",
        rule=lambda g: g.once(_nees_band)[0],
    ),
    Metric(
        "nees_band_high",
        "1",
        "97.5% point of the mean of n_nees consistent NEES values of d = 2 (or 3) degrees of freedom",
        rule=lambda g: g.once(_nees_band)[1],
    ),
    Metric(
        "nees_verdict",
        "text",
        "consistent, optimistic (covariance too small), pessimistic or inconclusive for the "
        "judged NEES against its chi-square band; 'no covariance' when there is none",
        rule=lambda g: nees_verdicts(
            g["nees_judged_mean"], g["n_nees"], g["nees_band_low"], g["nees_band_high"]
        ),
    ),
    Metric(
        "nees_side_resolved_mean",
        "1",
        "mean NEES of the candidate nearest to the truth against that candidate's covariance "
        "(the returned one reflected across the track for the mirror image)",
        aggregate=("nees_side", "mean"),
    ),
    Metric(
        "nees_returned_incl_wrong_side_mean",
        "1",
        "mean NEES of the returned position against its covariance, wrong-side trials included "
        "(each a mirror image away: huge when the side is a coin toss)",
        aggregate=("nees", "mean"),
    ),
    Metric(
        "crlb_rmse_median_m",
        "m",
        "median over trials of √trace(CRLB); equals crlb_rmse_m in an open loop, and shows "
        "how skewed the per-trial bounds of a closed loop are",
        aggregate=("crlb", "median"),
    ),
    Metric(
        "verdict_basis",
        "text",
        "side-resolved where the estimator flagged any estimate of the row as ambiguous, else "
        "returned: the error the verdicts judge",
        rule=lambda g: np.where(g.side, "side-resolved", "returned"),
    ),
    Metric(
        "efficiency_judged",
        "1",
        "the efficiency of verdict_basis",
        rule=lambda g: g.per_bound(g.judged(g["rmse_side_resolved_m"], g["rmse_m"])),
    ),
    Metric(
        "efficiency_judged_ci_low",
        "1",
        "lower end of its 95% interval",
        rule=_judged_interval("low"),
    ),
    Metric(
        "efficiency_judged_ci_high",
        "1",
        "upper end of its 95% interval",
        rule=_judged_interval("high"),
    ),
    Metric(
        "bias_judged_x_m",
        "m",
        "mean x error of verdict_basis (side-resolved where ambiguous)",
        rule=lambda g: g.bias.mean_m[:, 0],
    ),
    Metric(
        "bias_judged_y_m",
        "m",
        "mean y error of verdict_basis",
        rule=lambda g: g.bias.mean_m[:, 1],
    ),
    Metric(
        "bias_judged_m",
        "m",
        "norm of the mean error of verdict_basis: the bias the verdict judges",
        rule=lambda g: g.bias.norm_m,
    ),
    Metric(
        "bias_ratio",
        "1",
        "bias_judged_m / crlb_rmse_m; attains needs its whole 95% interval at most 0.3, "
        "beyond 0.3 is biased",
        rule=lambda g: g.bias.ratio,
    ),
    Metric(
        "bias_ratio_ci_low",
        "1",
        "lower end of its 95% interval (Hotelling's region for the mean)",
        rule=lambda g: g.bias.low,
    ),
    Metric(
        "bias_ratio_ci_high",
        "1",
        "upper end of its 95% interval",
        rule=lambda g: g.bias.high,
    ),
    *_axis_metrics(
        "major",
        0,
        "RMSE/√CRLB along the CRLB's major principal axis (the judged error); an unbiased "
        "estimator is at or above 1 along every axis",
    ),
    *_axis_metrics("minor", -1, "RMSE/√CRLB along the CRLB's minor principal axis"),
    Metric(
        "tail_share",
        "1",
        "share of the judged squared error carried by the largest 1% of the trials",
        rule=lambda g: tail_share(g.judged_squared, g.group, g.n_groups),
    ),
    Metric(
        "verdict",
        "text",
        "attains, above, below, biased or inconclusive (comparison.verdicts)",
        rule=lambda g: g.once(_verdicts)[0],
    ),
    Metric(
        "verdict_reason",
        "text",
        "the numbers behind the verdict",
        rule=lambda g: g.once(_verdicts)[1],
    ),
    Metric(
        "fit_rejected_rate",
        "1",
        "fraction of the n_fit_judged estimates whose fit is rejected at 1%: the whitened "
        "residual χ² of the data at the answer above the 99% point of χ²(fit_dof) (MATH §17); "
        "about 1% when the model, its σ's and constants hold and the answer is the best fit, "
        "more with an outlier, a wrong σ or constant, or an answer far from the best fit",
        rule=_fit_rejected_rate,
        count="n_fit_judged",
    ),
    Metric(
        "n_fit_judged",
        "count",
        "successful estimates that report a goodness of fit with at least one degree of "
        "freedom: the count of fit_rejected_rate",
        rule=lambda g: g.once(_fit_counts)[0],
    ),
)
"""The columns that follow the contracted ones: counts beside the rates, intervals, verdicts."""

METRICS: tuple[Metric, ...] = CONTRACT_METRICS + EXTRA_METRICS
"""Every metric, in the order of the summary's columns."""

CONTRACT_METRIC_NAMES: tuple[str, ...] = tuple(m.name for m in CONTRACT_METRICS)
"""The metric columns every summary has, in this order."""

METRIC_NAMES: tuple[str, ...] = tuple(m.name for m in METRICS)
"""Every metric column a summary may have, in order (from ``n_trials`` on): those of the
height only in a 3-D run (:func:`metric_names`)."""


def metric_names(dimension: int) -> tuple[str, ...]:
    """The metric columns of a summary of positions of ``dimension`` coordinates, in order."""
    return tuple(m.name for m in METRICS if m.dimension <= dimension)


METRIC_DESCRIPTIONS: dict[str, str] = {m.name: m.description for m in METRICS}
"""One line per metric column, for captions and the report."""


def metrics_table_markdown() -> str:
    """The table of every metric in docs/writing-an-experiment.md (a test keeps them equal)."""
    lines = ["| column | unit | count beside it | meaning |", "|---|---|---|---|"]
    for metric in METRICS:
        count = f"`{metric.count}`" if metric.count else ""
        unit = UNITS[metric.unit]
        lines.append(f"| `{metric.name}` | {unit} | {count} | {metric.description} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(metrics_table_markdown(), end="")
