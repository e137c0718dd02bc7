"""Figures against the swept parameter (RMSE, side-resolved RMSE, wrong-side rate), the
distribution of the errors at a few sweep points, and the run time per estimate."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from comparison.figures.curves import (
    Curve,
    Curves,
    left_out_note,
    mask_few,
    side_counts,
    wilson_interval,
)
from comparison.figures.panels import (
    default_colors,
    draw_bounds,
    estimator_line,
    last_frame,
    panel_title,
    parameter_columns,
    point_bounds,
    scenario_order,
    scenario_rank,
    set_x_scale,
    split_panels,
    sweep_axis,
    varying_columns,
)
from comparison.figures.style import (
    estimator_label,
    figure_grid,
    figure_legend,
    grid_lines,
    plain_log_ticks,
)
from comparison.metrics import swept_columns_of


def rmse_figure(
    summary: pd.DataFrame,
    *,
    points: pd.DataFrame | None = None,
    x: str | None = None,
    side_resolved: bool = False,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """RMSE against the swept parameter, one panel per scenario, with √CRLB (MATH §8).

    Each estimator is a line with its 95% bootstrap interval shaded. ``side_resolved`` draws
    the RMSE of the candidate nearest to the truth instead (MATH §7).

    Parameters
    ----------
    summary : pandas.DataFrame
        From :func:`comparison.metrics.summarize`.
    points : pandas.DataFrame, optional
        From :func:`comparison.engine.read_points`: gives the ToA+Doppler bound (solid black)
        and names the modalities of the other bounds.
    x : str, optional
        The swept column on the x axis (default :func:`sweep_axis`).
    side_resolved : bool
    colors : mapping, optional
        Estimator → colour (default :func:`estimator_colors` in the summary's order).
    """
    colors = default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = split_panels(rows, others)
    figure, axes = figure_grid(len(panels))
    value, low, high = (
        ("rmse_side_resolved_m", "rmse_side_resolved_ci_low_m", "rmse_side_resolved_ci_high_m")
        if side_resolved
        else ("rmse_m", "rmse_ci_low_m", "rmse_ci_high_m")
    )
    curves = Curves()
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values(x)
            color = colors[str(estimator)]
            drawn.append(estimator_line(ax, own[x], own[value], str(estimator), colors))
            ax.fill_between(own[x], own[low], own[high], color=color, alpha=0.2, linewidth=0)
        drawn += draw_bounds(ax, panel, point_bounds(panel, points, x, columns), x, colors)
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        grid_lines(ax)
    what = (
        "Side-resolved RMSE (nearest candidate, MATH §7)"
        if side_resolved
        else "RMSE of the returned position"
    )
    figure.suptitle(f"{what}; shaded: 95% bootstrap interval", fontsize="medium")
    figure_legend(figure, axes, curves)
    return figure


def side_resolved_rmse_figure(
    summary: pd.DataFrame,
    *,
    points: pd.DataFrame | None = None,
    x: str | None = None,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """:func:`rmse_figure` of the side-resolved RMSE (MATH §7)."""
    return rmse_figure(summary, points=points, x=x, side_resolved=True, colors=colors)


def wrong_side_figure(
    summary: pd.DataFrame,
    *,
    x: str | None = None,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Wrong-side rate against the swept parameter, with a 95% Wilson interval (MATH §7).

    0.5 is a coin toss: what an estimator that cannot tell the side of a straight track
    achieves at best. The rate and its interval are over the ``n_side_judged`` estimates off
    the track plane; where fewer than :data:`MIN_COUNT_FOR_RATE` back a point, nothing is
    drawn there (:data:`WRONG_SIDE_COUNT_NOTE`) and the legend counts such points.
    """
    colors = default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = split_panels(rows, others)
    figure, axes = figure_grid(len(panels), sharey=True)
    curves = Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn, n_left_out = plot_wrong_side(ax, panel, x, colors)
        curves.panel(title, drawn, ax)
        left_out += n_left_out
        set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_title(title, fontsize="medium")
    if left_out:
        curves.extra.append((None, left_out_note(left_out, "estimates off the track")))
    figure.suptitle(
        "Estimates on the wrong side of the last frame's track; shaded: 95% Wilson interval",
        fontsize="medium",
    )
    figure_legend(figure, axes, curves)
    return figure


def plot_wrong_side(
    ax: Axes, panel: pd.DataFrame, x: str, colors: Mapping[str, tuple[float, ...]]
) -> tuple[list[Curve], int]:
    """One panel of wrong-side rate against ``x``, a line per estimator, 0.5 marked.

    Returns the curves and how many points were left out for their count
    (:data:`MIN_COUNT_FOR_RATE`).
    """
    curves = []
    left_out = 0
    for estimator, own in panel.groupby("estimator", sort=False):
        own = own.sort_values(x)
        counts = side_counts(own)
        rate, few = mask_few(own["wrong_side_rate"], counts)
        left_out += int(few.sum())
        low, high = wilson_interval(rate, counts)
        color = colors[str(estimator)]
        curves.append(estimator_line(ax, own[x], rate, str(estimator), colors))
        ax.fill_between(own[x], low, high, color=color, alpha=0.15, linewidth=0)
    ax.axhline(0.5, color="grey", linestyle=":", linewidth=1, label="0.5 (a coin toss)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("wrong-side rate")
    ax.grid(True, alpha=0.3)
    return curves, left_out


# --------------------------------------------------------------------------------------------
# distributions and cost
# --------------------------------------------------------------------------------------------


def _point_keys(rows: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """One line per sweep point of ``rows`` (which carry ``scenario_code``, the scenario's
    integer code): its scenario, ``columns`` and mean √CRLB (``bound``). Grouped by the code,
    not the name: a dense run has millions of rows."""
    keys = rows.groupby(["scenario_code", "point"], sort=False).agg(
        scenario=("scenario", "first"),
        **{c: (c, "first") for c in columns},
        bound=("crlb_rmse_m", "mean"),
    )
    return keys.reset_index()


def _chosen_points(
    keys: pd.DataFrame, x: str | None, n_points: int, order: Sequence[str]
) -> pd.DataFrame:
    """Up to ``n_points`` sweep points per scenario of ``keys`` (:func:`_point_keys`): lowest,
    middle and highest ``x``.

    Without ``x`` (a grid), the points of smallest, median and largest mean √CRLB: the
    easiest, a middle and the hardest geometry. Scenarios in ``order``.
    """
    keys = keys.copy()
    keys["scenario_rank"] = scenario_rank(keys, order)
    keys = keys.sort_values(["scenario_rank", x or "bound", "point"], kind="stable")
    chosen = []
    for _, rows in keys.groupby("scenario", sort=False):
        index = np.unique(np.linspace(0, len(rows) - 1, min(n_points, len(rows))).round())
        chosen.append(rows.iloc[index.astype(int)])
    return pd.concat(chosen)


MAX_CDF_STEPS = 4096
"""Most steps drawn of one empirical CDF: a run of more trials is drawn at 4096 evenly spaced
ranks (fractions 1/4096 apart, finer than a pixel), the first and last among them."""


def error_cdf_figure(
    trials: pd.DataFrame,
    *,
    x: str | None = "snr_db",
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Empirical CDFs of the distance error at a few sweep points (lowest, middle, highest).

    Solid: error of the returned position; dashed: side-resolved error (MATH §7), drawn for
    estimators that flag ambiguous answers (one legend entry per estimator, and one for the
    dashed style). The CDF is over all trials: failed estimates count as infinite errors, so a
    curve that stays below 1 shows the failure rate. CDFs that overlap on the page are
    interleaved like the lines of the other figures; no "coincides with" notes here.

    Parameters
    ----------
    trials : pandas.DataFrame
        From :func:`comparison.engine.read_trials` (the last frame of each point is used).
    x : str or None
        The swept column ordering the points; ``None`` orders them by their mean √CRLB
        (grid sweeps).
    n_points : int
    colors : mapping, optional
    """
    colors = default_colors(trials, colors)
    columns = ["snr_db", *swept_columns_of(trials)]
    drawn_columns = ["scenario", "point", "frame", "estimator", "success", "ambiguous"]
    drawn_columns += ["error_m", "error_side_resolved_m", "crlb_rmse_m", *columns]
    # only these columns, and the scenario as an integer code: a run has millions of rows
    rows = trials[list(dict.fromkeys(drawn_columns))]
    rows = rows.assign(scenario_code=pd.factorize(rows["scenario"], sort=False)[0])
    latest = rows.groupby(["scenario_code", "point"], sort=False)["frame"].transform("max")
    rows = rows[rows["frame"] == latest]
    keys = _point_keys(rows, columns)  # the columns are constant within a point
    varying = varying_columns(keys, columns)
    chosen = _chosen_points(keys, x, n_points, scenario_order(keys))
    code, point = rows["scenario_code"].to_numpy(), rows["point"].to_numpy()
    figure, axes = figure_grid(len(chosen), ncols=min(len(chosen), n_points), sharey=True)
    curves = Curves(notes=False)  # CDFs of one estimator family coincide by the dozen
    dashed = False
    for ax, (_, where) in zip(axes, chosen.iterrows(), strict=True):
        at = rows[(code == where["scenario_code"]) & (point == where["point"])]
        values = {c: float(where[c]) for c in (varying or ["snr_db"])}
        title = panel_title(str(where["scenario"]), values)
        drawn = []
        for estimator, own in at.groupby("estimator", sort=False):
            color = colors[str(estimator)]
            n = len(own)
            ok = own[own["success"].astype(bool)]
            for column, style, suffix in (
                ("error_m", "-", ""),
                ("error_side_resolved_m", "--", ", side-resolved"),
            ):
                if column == "error_side_resolved_m" and not ok["ambiguous"].astype(bool).any():
                    continue
                errors = np.sort(ok[column].to_numpy(float))
                errors = errors[np.isfinite(errors)]
                if errors.size == 0:
                    continue
                fraction = np.arange(1, errors.size + 1) / n
                ranks = np.unique(
                    np.linspace(0, errors.size - 1, MAX_CDF_STEPS).round().astype(int)
                )
                errors, fraction = errors[ranks], fraction[ranks]  # at most MAX_CDF_STEPS
                label = estimator_label(str(estimator)) + suffix
                dashed |= bool(suffix)
                (line,) = ax.step(
                    errors,
                    fraction,
                    where="post",
                    color=color,
                    linestyle=style,
                    label=f"_{label}" if suffix else label,  # one legend entry per estimator
                )
                name = f"{estimator}{suffix.replace(',', '')}"
                drawn.append(Curve(label, name, errors, fraction, line, grid="y"))
        curves.panel(title, drawn, ax)
        ax.set_xscale("log")
        plain_log_ticks(ax.xaxis)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("distance error (m)")
        ax.set_ylabel("fraction of trials")
        ax.set_title(title, fontsize="medium")
        grid_lines(ax)
    figure.suptitle(
        "Distribution of the distance error (failed estimates count as infinite)", fontsize="medium"
    )
    if dashed:
        style = Line2D([], [], color="0.35", linestyle="--")
        curves.extra.append((style, "dashed: side-resolved error (nearest candidate, MATH §7)"))
    figure_legend(figure, axes, curves)
    return figure


def runtime_figure(
    trials: pd.DataFrame, *, colors: Mapping[str, tuple[float, ...]] | None = None
) -> Figure:
    """Median wall time of one estimate per estimator (horizontal bars, log axis).

    The whiskers span the 5th to 95th percentiles over every estimate of the run.
    """
    colors = default_colors(trials, colors)
    runtime = trials.groupby("estimator", sort=False)["runtime_s"]
    table = pd.DataFrame(
        {
            "median": runtime.median(),
            "p05": runtime.quantile(0.05),
            "p95": runtime.quantile(0.95),
        }
    ).sort_values("median")
    labels = [estimator_label(str(name)) for name in table.index]
    figure = Figure(figsize=(8.5, 0.45 * len(table) + 1.6), layout="constrained")
    ax = figure.subplots()
    positions = np.arange(len(table))
    # Bars start one decade below the fastest 5th percentile, so lengths compare on log scale.
    left = 10 ** np.floor(np.log10(max(float(table["p05"].min()), 1e-9)) - 1)
    ax.barh(
        positions,
        table["median"] - left,
        left=left,
        color=[colors[str(name)] for name in table.index],
        xerr=[table["median"] - table["p05"], table["p95"] - table["median"]],
        capsize=3,
        error_kw={"elinewidth": 1},
    )
    for position, (median, high) in enumerate(zip(table["median"], table["p95"], strict=True)):
        ax.annotate(
            f"median {median * 1e3:.3g} ms",
            (high, position),
            xytext=(6, 0),
            textcoords="offset points",
            va="center",
            fontsize="small",
        )
    ax.set_xlim(left, float(table["p95"].max()) * 8)
    ax.set_yticks(positions, labels)
    ax.set_xscale("log")
    plain_log_ticks(ax.xaxis)
    ax.set_xlabel("wall time per estimate (s)")
    ax.set_title(
        "Run time per estimate (median; whiskers: 5th to 95th percentile)", fontsize="medium"
    )
    ax.grid(True, axis="x", which="major", alpha=0.3)
    ax.grid(True, axis="x", which="minor", alpha=0.08)
    return figure
