"""Closed-loop figures: each planner against the frame, and the trajectories (paper Fig. 3)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import matplotlib as mpl
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from comparison.figures.curves import (
    Curve,
    Curves,
    left_out_note,
    mask_few,
    side_counts,
    wilson_interval,
)
from comparison.figures.panels import (
    MAX_PANELS,
    panel_title,
    parameter_columns,
    scenario_rank,
    varying_columns,
)
from comparison.figures.style import figure_grid, figure_legend, grid_lines, plain_log_ticks


def planner_colors(names: Iterable[str]) -> dict[str, tuple[float, float, float, float]]:
    """One colour per planner, in the given order (Dark2, then tab20 beyond eight)."""
    unique = list(dict.fromkeys(str(n) for n in names))
    palette = mpl.colormaps["Dark2" if len(unique) <= 8 else "tab20"]
    return {name: palette(i % palette.N) for i, name in enumerate(unique)}


PLANNER_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")
"""Marker of the i-th planner, so that coinciding lines stay distinguishable."""


def _planner_marker(summary: pd.DataFrame, planner: object) -> str:
    order = list(dict.fromkeys(summary["planner"]))
    return PLANNER_MARKERS[order.index(planner) % len(PLANNER_MARKERS)]


def _planner_panels(summary: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """One panel per (scenario, sweep point, estimator): scenarios in :func:`scenario_order`,
    then sweep points ascending, then estimators in their order of first appearance."""
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    rank = scenario_rank(summary)
    estimators = {name: i for i, name in enumerate(dict.fromkeys(summary["estimator"]))}
    keyed = []
    for key, rows in summary.groupby(["scenario", *varying, "estimator"], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        values = dict(zip(varying, key[1:-1], strict=True))
        order = (int(rank.loc[rows.index[0]]), *key[1:-1], estimators[key[-1]])
        keyed.append((order, f"{panel_title(str(key[0]), values)}: {key[-1]}", rows))
    keyed.sort(key=lambda item: item[0])
    return [(title, rows) for _, title, rows in keyed][:MAX_PANELS]


def planner_rmse_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    side_resolved: bool = False,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """RMSE against the frame, one line per planner, with the √CRLB of the flown trajectories.

    One panel per scenario (and sweep point) and estimator. Solid: RMSE of the returned
    position (``side_resolved``: of the candidate nearest to the truth, MATH §7) with its 95%
    bootstrap interval; dashed, same colour: the root mean square over trials of √trace(CRLB)
    of the trajectory each trial flew (MATH §8), for that estimator's modalities and frames.
    """
    if "planner" not in summary.columns:
        raise ValueError("summary: no planner column; this figure is for closed-loop runs")
    colors = colors if colors is not None else planner_colors(summary["planner"].unique())
    value, low, high = (
        ("rmse_side_resolved_m", "rmse_side_resolved_ci_low_m", "rmse_side_resolved_ci_high_m")
        if side_resolved
        else ("rmse_m", "rmse_ci_low_m", "rmse_ci_high_m")
    )
    panels = _planner_panels(summary)
    n_estimators = summary["estimator"].nunique()
    figure, axes = figure_grid(len(panels), ncols=min(max(n_estimators, 1), 3))
    curves = Curves()
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for planner, own in panel.groupby("planner", sort=False):
            own = own.sort_values("frame")
            color = colors[str(planner)]
            frames = own["frame"].to_numpy(float)
            label = f"{planner}: RMSE"
            (line,) = ax.plot(
                own["frame"],
                own[value],
                marker=_planner_marker(summary, planner),
                markersize=4,
                color=color,
                label=label,
            )
            drawn.append(Curve(label, f"{planner}", frames, own[value].to_numpy(float), line))
            ax.fill_between(own["frame"], own[low], own[high], color=color, alpha=0.2, linewidth=0)
            label = f"{planner}: √CRLB of the flown paths"
            ax.plot(
                own["frame"],
                own["crlb_rmse_m"],
                linestyle="--",
                linewidth=1.2,
                color=color,
                label=label,
            )
            bound = own["crlb_rmse_m"].to_numpy(float)
            drawn.append(Curve(label, f"{planner}'s √CRLB", frames, bound))
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        grid_lines(ax)
    what = "Side-resolved RMSE (MATH §7)" if side_resolved else "RMSE of the returned position"
    figure.suptitle(
        f"Closed loop: {what} per planner as frames accumulate; dashed: RMS over trials of "
        "√CRLB of each flown trajectory",
        fontsize="medium",
    )
    figure_legend(figure, axes, curves)
    return figure


def planner_wrong_side_vs_frame_figure(
    summary: pd.DataFrame, *, colors: Mapping[str, tuple[float, ...]] | None = None
) -> Figure:
    """Wrong-side rate against the frame, one line per planner (95% Wilson interval, MATH §7).

    The rows judge the side against the first track an estimator uses, in each trial's own
    flight (:mod:`comparison.engine`). Points backed by fewer than :data:`MIN_COUNT_FOR_RATE`
    estimates off the track are not drawn (:data:`WRONG_SIDE_COUNT_NOTE`).
    """
    if "planner" not in summary.columns:
        raise ValueError("summary: no planner column; this figure is for closed-loop runs")
    colors = colors if colors is not None else planner_colors(summary["planner"].unique())
    panels = _planner_panels(summary)
    n_estimators = summary["estimator"].nunique()
    figure, axes = figure_grid(len(panels), sharey=True, ncols=min(max(n_estimators, 1), 3))
    curves = Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for planner, own in panel.groupby("planner", sort=False):
            own = own.sort_values("frame")
            counts = side_counts(own)
            rate, few = mask_few(own["wrong_side_rate"], counts)
            left_out += int(few.sum())
            low, high = wilson_interval(rate, counts)
            color = colors[str(planner)]
            (line,) = ax.plot(
                own["frame"],
                rate,
                marker=_planner_marker(summary, planner),
                markersize=5,
                markerfacecolor="none",
                color=color,
                label=str(planner),
            )
            drawn.append(
                Curve(str(planner), str(planner), own["frame"].to_numpy(float), rate, line)
            )
            ax.fill_between(own["frame"], low, high, color=color, alpha=0.15, linewidth=0)
        curves.panel(title, drawn, ax)
        ax.axhline(0.5, color="grey", linestyle=":", linewidth=1, label="0.5 (a coin toss)")
        ax.set_ylim(-0.03, 1.03)
        ax.set_ylabel("wrong-side rate")
        ax.set_xlabel("last frame used (index)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize="medium")
        ax.grid(True, alpha=0.3)
    figure.suptitle(
        "Closed loop: wrong-side rate per planner (side of the first track the estimator "
        "uses); shaded: 95% Wilson interval",
        fontsize="medium",
    )
    if left_out:
        curves.extra.append((None, left_out_note(left_out, "estimates off the track")))
    figure_legend(figure, axes, curves)
    return figure


def covariance_ellipse_m(
    centre_m: Sequence[float], covariance_m2: np.ndarray, n_sigma: float = 2.0, n_points: int = 73
) -> np.ndarray:
    """Points ``(n_points, 2)`` of the ellipse ``(x − c)ᵀ P⁻¹ (x − c) = n_sigma²``."""
    values, vectors = np.linalg.eigh(0.5 * (covariance_m2 + covariance_m2.T))
    radii = n_sigma * np.sqrt(np.clip(values, 0.0, None))
    angle = np.linspace(0.0, 2 * np.pi, n_points)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return np.asarray(centre_m, dtype=float) + (circle * radii) @ vectors.T


def trajectory_figure(
    flights: pd.DataFrame,
    trials: pd.DataFrame,
    *,
    estimator: str,
    n_paths: int = 5,
    n_sigma: float = 2.0,
) -> Figure:
    """The paper's Fig. 3 in closed loop: UAV paths per planner, the emitter, the estimates.

    Two rows of panels per scenario (its first sweep point), one column per planner. Upper
    row: for the first ``n_paths`` trials, the UAV path (a polyline through the first and
    last sample of every frame, one colour per trial) and the ``estimator``'s estimate after
    every frame (dots), with the emitter (star). Lower row: a zoom on the truth with the last
    estimate of every trial (grey) and, for the drawn trials, the last estimate (cross) with
    its ``n_sigma`` covariance ellipse when the estimator gives one. The zoom spans the
    drawn trials' ellipses and the central 90% of every trial's last errors; how many last
    estimates fall outside it (the wrong side of the track, typically) is written in it.

    Parameters
    ----------
    flights : pandas.DataFrame
        From :func:`comparison.engine.read_flights`.
    trials : pandas.DataFrame
        From :func:`comparison.engine.read_trials`.
    estimator : str
        The estimator label whose estimates are drawn (the steering estimator, typically).
    n_paths : int
        Trials drawn per panel (the first ones: the same trials in every panel).
    n_sigma : float
        The ellipse is ``(x − x̂)ᵀ P⁻¹ (x − x̂) = n_sigma²``.
    """
    if flights.empty:
        raise ValueError("flights: no frames flown; this figure is for closed-loop runs")
    if estimator not in set(trials["estimator"]):
        raise ValueError(f"estimator: {estimator!r} has no rows; choose one of the run's labels")
    first_point = flights.groupby("scenario", sort=False)["point"].transform("min")
    flights = flights[flights["point"] == first_point]
    planners = list(dict.fromkeys(flights["planner"]))
    scenarios = list(dict.fromkeys(flights["scenario"]))
    ncols = len(planners)
    figure, axes = figure_grid(2 * len(scenarios) * ncols, legend=True, ncols=ncols)
    palette = mpl.colormaps["tab10"]
    rows = trials[trials["estimator"] == estimator]
    chosen: list[int] = []
    for row, scenario in enumerate(scenarios):
        for column, planner in enumerate(planners):
            top = axes[2 * row * ncols + column]
            zoom = axes[(2 * row + 1) * ncols + column]
            own = flights[(flights["scenario"] == scenario) & (flights["planner"] == planner)]
            point = int(own["point"].iloc[0])
            estimates = rows[
                (rows["scenario"] == scenario)
                & (rows["planner"] == planner)
                & (rows["point"] == point)
            ]
            truth = estimates[["truth_x_m", "truth_y_m"]].iloc[0].to_numpy(float)
            last_frame_rows = estimates[estimates["frame"] == estimates["frame"].max()]
            finals = last_frame_rows[last_frame_rows["success"]]
            errors = np.hypot(finals["x_m"] - truth[0], finals["y_m"] - truth[1]).to_numpy()
            chosen = sorted(own["trial"].unique())[:n_paths]
            reach = [float(np.quantile(errors, 0.9))] if errors.size else []
            zoom.plot(
                finals["x_m"],
                finals["y_m"],
                ".",
                color="0.6",
                markersize=2.5,
                label=f"{estimator}: last estimate, every trial",
            )
            for number, trial in enumerate(chosen):
                color = palette(number % palette.N)
                path = own[own["trial"] == trial].sort_values("frame")
                xy = np.column_stack(
                    [
                        np.ravel(path[["start_x_m", "end_x_m"]].to_numpy()),
                        np.ravel(path[["start_y_m", "end_y_m"]].to_numpy()),
                    ]
                )
                top.plot(xy[:, 0], xy[:, 1], color=color, linewidth=1.2, label=f"trial {trial}")
                top.plot(*xy[0], marker="o", color=color, markersize=3)
                mine = estimates[estimates["trial"] == trial].sort_values("frame")
                ok = mine[mine["success"]]
                top.plot(ok["x_m"], ok["y_m"], ".", color=color, markersize=3, alpha=0.7)
                last = mine.iloc[-1]
                if not last["success"]:
                    continue
                centre = (float(last["x_m"]), float(last["y_m"]))
                zoom.plot(*centre, marker="x", color=color, markersize=6)
                covariance = np.array(
                    [
                        [last["cov_xx_m2"], last["cov_xy_m2"]],
                        [last["cov_xy_m2"], last["cov_yy_m2"]],
                    ],
                    dtype=float,
                )
                error = float(np.hypot(centre[0] - truth[0], centre[1] - truth[1]))
                if np.all(np.isfinite(covariance)):
                    ring = covariance_ellipse_m(centre, covariance, n_sigma)
                    zoom.plot(ring[:, 0], ring[:, 1], color=color, linewidth=0.9)
                    error = float(np.max(np.hypot(ring[:, 0] - truth[0], ring[:, 1] - truth[1])))
                if not errors.size or error <= 3 * float(np.quantile(errors, 0.9)):
                    reach.append(error)
            top.plot(
                *truth,
                marker="*",
                color="black",
                markersize=12,
                linestyle="none",
                label="emitter (truth)",
                zorder=5,
            )
            zoom.plot(  # hollow, so that the estimates under it stay visible
                *truth,
                marker="*",
                markerfacecolor="none",
                markeredgecolor="black",
                markersize=14,
                linestyle="none",
                zorder=5,
            )
            half = 1.1 * max(max(reach, default=0.0), 1e-3)
            zoom.set_xlim(truth[0] - half, truth[0] + half)
            zoom.set_ylim(truth[1] - half, truth[1] + half)
            outside = int(np.sum(errors > half))
            wrong = int(np.nansum(finals["wrong_side"].to_numpy(float)))
            notes = [f"wrong side: {wrong} of {len(errors)}"]
            if outside:
                notes.append(f"{outside} of {len(errors)} outside this zoom")
            zoom.text(
                0.02,
                0.02,
                "; ".join(notes),
                transform=zoom.transAxes,
                fontsize="x-small",
                bbox={"facecolor": "white", "alpha": 0.8, "linewidth": 0},
            )
            zoom.set_aspect("equal", adjustable="box")
            zoom.set_title(f"{scenario}: {planner}, last estimates", fontsize="medium")
            top.set_aspect("equal", adjustable="datalim")
            top.set_title(f"{scenario}: {planner}, UAV paths", fontsize="medium")
            for where in (top, zoom):
                where.set_xlabel("x east (m)")
                where.set_ylabel("y north (m)")
                where.grid(True, alpha=0.3)
    figure.suptitle(
        f"Closed loop (paper Fig. 3): UAV paths of {len(chosen)} trials per planner, "
        f"{estimator}'s estimate after every frame (dots); below, the last estimates, "
        f"{n_sigma:g}σ ellipses for the drawn trials",
        fontsize="medium",
    )
    figure_legend(figure, [axes[0], axes[ncols]])
    return figure
