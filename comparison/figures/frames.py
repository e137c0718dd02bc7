"""Figures of per-frame runs against the last frame used: RMSE, wrong-side rate, NEES."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from comparison.figures.curves import MIN_COUNT_FOR_RATE, Curve, Curves, left_out_note, mask_few
from comparison.figures.panels import (
    MAX_PANELS,
    default_colors,
    draw_bounds,
    estimator_line,
    panel_title,
    parameter_columns,
    scenario_order,
    scenario_rank,
    varying_columns,
)
from comparison.figures.style import (
    estimator_label,
    figure_grid,
    figure_legend,
    grid_lines,
    plain_log_ticks,
)
from comparison.figures.sweep import plot_wrong_side


def _frame_panels(
    summary: pd.DataFrame, n_points: int, order: Sequence[str] | None = None
) -> list[tuple[str, pd.DataFrame]]:
    """One panel per scenario and sweep point (up to ``n_points`` per scenario: lowest, middle,
    highest), scenarios in ``order`` (default :func:`scenario_order` of ``summary``)."""
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    keys = summary[["scenario", *columns]].drop_duplicates()
    keys = keys.assign(scenario_rank=scenario_rank(keys, order or scenario_order(summary)))
    keys = keys.sort_values("scenario_rank", kind="stable")
    panels = []
    for _, rows in keys.groupby("scenario_rank", sort=True):
        order = rows.sort_values(varying or ["snr_db"])
        index = np.unique(np.linspace(0, len(order) - 1, min(n_points, len(order))).round())
        for _, key in order.iloc[index.astype(int)].iterrows():
            mask = np.ones(len(summary), dtype=bool)
            for column in ["scenario", *columns]:
                mask &= (summary[column] == key[column]).to_numpy()
            values = {c: float(key[c]) for c in varying} or {"snr_db": float(key["snr_db"])}
            panels.append((panel_title(str(key["scenario"]), values), summary[mask]))
    return panels[:MAX_PANELS]


def rmse_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    points: pd.DataFrame | None = None,
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """RMSE against the last frame used, with the accumulated √CRLB (MATH §8).

    Solid: RMSE of the returned position with its bootstrap interval; dotted: side-resolved
    RMSE where it differs (MATH §7). One panel per scenario and sweep point (up to
    ``n_points`` points: lowest, middle, highest).
    """
    colors = default_colors(summary, colors)
    columns = parameter_columns(summary)
    panels = _frame_panels(summary, n_points)
    figure, axes = figure_grid(len(panels))
    curves = Curves()
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values("frame")
            color = colors[str(estimator)]
            drawn.append(estimator_line(ax, own["frame"], own["rmse_m"], str(estimator), colors))
            ax.fill_between(
                own["frame"],
                own["rmse_ci_low_m"],
                own["rmse_ci_high_m"],
                color=color,
                alpha=0.2,
                linewidth=0,
            )
            if not np.allclose(own["rmse_side_resolved_m"], own["rmse_m"], equal_nan=True):
                label = f"{estimator_label(str(estimator))}, side-resolved"
                (line,) = ax.plot(
                    own["frame"],
                    own["rmse_side_resolved_m"],
                    linestyle=":",
                    linewidth=1.8,
                    color=color,
                    label=label,
                )
                drawn.append(
                    Curve(
                        label,
                        f"{estimator} side-resolved",
                        own["frame"].to_numpy(float),
                        own["rmse_side_resolved_m"].to_numpy(float),
                        line,
                    )
                )
        bounds = None
        if points is not None:
            keys = ["scenario", *columns, "frame"]
            if all(c in points.columns for c in keys):
                bounds = panel[keys].drop_duplicates().merge(points, on=keys).sort_values("frame")
        drawn += draw_bounds(ax, panel, bounds, "frame", colors)
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        grid_lines(ax)
    figure.suptitle("RMSE as frames accumulate, with the accumulated √CRLB", fontsize="medium")
    figure_legend(figure, axes, curves)
    return figure


def wrong_side_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Wrong-side rate against the last frame used (MATH §7): a turn should drive it to 0.

    Points backed by fewer than :data:`MIN_COUNT_FOR_RATE` estimates off the track are not
    drawn, as in :func:`wrong_side_figure`.
    """
    colors = default_colors(summary, colors)
    panels = _frame_panels(summary, n_points)
    figure, axes = figure_grid(len(panels), sharey=True)
    curves = Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn, n_left_out = plot_wrong_side(ax, panel, "frame", colors)
        curves.panel(title, drawn, ax)
        left_out += n_left_out
        ax.set_xlabel("last frame used (index)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize="medium")
    if left_out:
        curves.extra.append((None, left_out_note(left_out, "estimates off the track")))
    figure.suptitle(
        "Wrong-side rate as frames accumulate; shaded: 95% Wilson interval", fontsize="medium"
    )
    figure_legend(figure, axes, curves)
    return figure


def nees_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Mean side-resolved NEES against the frame, for the estimators that report a covariance.

    Each trial's nearest candidate is scored against its own covariance (mirrored with the
    candidate, MATH §7): for an unambiguous estimate that is the returned position, so the
    curve shows covariance consistency rather than the mirror ambiguity. A consistent
    covariance gives a mean NEES of 2 (two dof), inside the 95% band of
    :func:`comparison.intervals.nees_band` (shaded grey: the widest band among the estimators
    of the panel, from their smallest count). A mean of fewer than :data:`MIN_COUNT_FOR_RATE`
    NEES values (``n_nees``) is not drawn (:data:`NEES_COUNT_NOTE`), and gives no band.
    """
    with_nees = summary[summary["n_nees"] > 0]
    if with_nees.empty:
        raise ValueError("summary: no estimator reports a covariance (n_nees is 0 everywhere)")
    colors = default_colors(summary, colors)
    panels = _frame_panels(with_nees, n_points, scenario_order(summary))
    figure, axes = figure_grid(len(panels))
    curves = Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        counted = panel[panel["n_nees"] >= MIN_COUNT_FOR_RATE]
        band = counted.loc[counted.groupby("frame")["n_nees"].idxmin()].sort_values("frame")
        if not band.empty:
            ax.fill_between(
                band["frame"],
                band["nees_band_low"],
                band["nees_band_high"],
                color="0.8",
                label="95% band of a consistent mean NEES",
            )
        ax.axhline(2.0, color="black", linewidth=1, label="2 (consistent)")
        drawn = []
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values("frame")
            nees, few = mask_few(own["nees_side_resolved_mean"], own["n_nees"])
            left_out += int(few.sum())
            drawn.append(estimator_line(ax, own["frame"], nees, str(estimator), colors))
        curves.panel(title, drawn, ax)
        values = np.concatenate([*(c.y for c in drawn), band["nees_band_high"].to_numpy(float)])
        values = values[np.isfinite(values) & (values > 0)]
        if values.size and values.max() / values.min() > 20:
            ax.set_yscale("log")
            plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("mean NEES")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        grid_lines(ax)
    if left_out:
        curves.extra.append((None, left_out_note(left_out, "NEES values")))
    figure.suptitle(
        "Covariance consistency: mean NEES (2 dof) as frames accumulate", fontsize="medium"
    )
    figure_legend(figure, axes, curves)
    return figure
