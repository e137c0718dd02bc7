"""The efficiency over an emitter grid: one heatmap per estimator, and the bound's."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from comparison.figures.panels import (
    REFERENCE_BOUND,
    is_geometry_sweep,
    last_frame,
    parameter_columns,
    point_bounds,
    split_panels,
    varying_columns,
)
from comparison.figures.style import estimator_label, plain_log_ticks


def _cell_edges(centres: np.ndarray) -> np.ndarray:
    if centres.size == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    middle = (centres[1:] + centres[:-1]) / 2
    return np.concatenate(
        [
            [centres[0] - (middle[0] - centres[0])],
            middle,
            [centres[-1] + (centres[-1] - middle[-1])],
        ]
    )


def geometry_heatmap_figure(
    summary: pd.DataFrame,
    *,
    points: pd.DataFrame | None = None,
    tracks_m: Mapping[str, np.ndarray] | None = None,
) -> Figure:
    """Efficiency over an emitter grid, one panel per estimator (log colour scale).

    The efficiency is the summary's ``efficiency_judged`` (side-resolved where the estimator
    flags ambiguous answers, MATH §7): the judged RMSE divided by the estimator's √CRLB.
    A first panel shows the ToA+Doppler √CRLB in metres when ``points`` is given. One row of
    panels per scenario (and per value of any other varying parameter).

    Parameters
    ----------
    summary : pandas.DataFrame
        From :func:`comparison.metrics.summarize`, swept over ``emitter_x_m`` and
        ``emitter_y_m``.
    points : pandas.DataFrame, optional
        From :func:`comparison.engine.read_points`.
    tracks_m : mapping, optional
        Scenario name → UAV positions ``(n, 2)`` or ``(n, 3)`` in metres, drawn as the track.
    """
    if not is_geometry_sweep(summary):
        raise ValueError(
            "summary: the geometry heatmap needs a sweep over emitter_x_m and emitter_y_m"
        )
    columns = parameter_columns(summary)
    rows = last_frame(summary, columns).copy()
    rows["judged_efficiency"] = rows["efficiency_judged"].to_numpy(float)
    others = [c for c in varying_columns(rows, columns) if c not in ("emitter_x_m", "emitter_y_m")]
    panels = split_panels(rows, others)
    estimators = list(rows["estimator"].unique())
    show_bound = points is not None and REFERENCE_BOUND in points.columns
    ncols = len(estimators) + int(show_bound)
    figure = Figure(figsize=(3.3 * ncols + 1.2, 3.2 * len(panels) + 0.8), layout="constrained")
    axes = figure.subplots(len(panels), ncols, squeeze=False, sharex=True, sharey=True)
    finite = rows["judged_efficiency"][
        np.isfinite(rows["judged_efficiency"]) & (rows["judged_efficiency"] > 0)
    ]
    norm = LogNorm(
        vmin=min(float(finite.min()), 1.0) if finite.size else 0.5,
        vmax=max(float(finite.max()), 2.0) if finite.size else 2.0,
    )
    bounds = [
        point_bounds(panel, points, "emitter_x_m", columns) if show_bound else None
        for _, panel in panels
    ]
    bound_values = np.concatenate(
        [b[REFERENCE_BOUND].to_numpy(float) for b in bounds if b is not None] or [np.ones(0)]
    )
    bound_values = bound_values[np.isfinite(bound_values) & (bound_values > 0)]
    bound_norm = (
        LogNorm(vmin=float(bound_values.min()), vmax=float(bound_values.max()))
        if bound_values.size
        else None
    )
    mesh = bound_mesh = None
    for row_axes, (title, panel), bound in zip(axes, panels, bounds, strict=True):
        xs = np.sort(panel["emitter_x_m"].unique())
        ys = np.sort(panel["emitter_y_m"].unique())
        x_edges, y_edges = _cell_edges(xs), _cell_edges(ys)

        def grid(values: pd.DataFrame, column: str, xs=xs, ys=ys) -> np.ma.MaskedArray:
            image = np.full((ys.size, xs.size), np.nan)
            ix = np.searchsorted(xs, values["emitter_x_m"].to_numpy(float))
            iy = np.searchsorted(ys, values["emitter_y_m"].to_numpy(float))
            image[iy, ix] = values[column].to_numpy(float)
            return np.ma.masked_invalid(image)

        targets: list[tuple[Axes, str]] = []
        start = 0
        if show_bound:
            ax = row_axes[0]
            if bound is not None and bound_norm is not None:
                bound_mesh = ax.pcolormesh(
                    x_edges, y_edges, grid(bound, REFERENCE_BOUND), cmap="magma", norm=bound_norm
                )
            targets.append((ax, "√CRLB, ToA+Doppler (m)"))
            start = 1
        for ax, estimator in zip(row_axes[start:], estimators, strict=True):
            own = panel[panel["estimator"] == estimator]
            mesh = ax.pcolormesh(
                x_edges, y_edges, grid(own, "judged_efficiency"), cmap="viridis", norm=norm
            )
            targets.append((ax, estimator_label(str(estimator))))
        for ax, name in targets:
            scenario = str(panel["scenario"].iloc[0])
            track = None if tracks_m is None else tracks_m.get(scenario)
            if track is not None:
                track = np.asarray(track, dtype=float)
                ax.plot(track[:, 0], track[:, 1], color="white", linewidth=3)
                ax.plot(track[:, 0], track[:, 1], color="red", linewidth=1.5, label="UAV track")
                ax.annotate(
                    "",
                    xy=track[-1, :2],
                    xytext=track[max(len(track) - 2, 0), :2],
                    arrowprops={"arrowstyle": "-|>", "color": "red"},
                )
            ax.set_title(f"{title}\n{name}", fontsize="small")
            ax.set_aspect("equal", adjustable="box")
            ax.set_xlim(x_edges[0], x_edges[-1])
            ax.set_ylim(y_edges[0], y_edges[-1])
        row_axes[0].set_ylabel("emitter y (m)")
    for ax in axes[-1]:
        ax.set_xlabel("emitter x (m)")
    if mesh is not None:
        bar = figure.colorbar(
            mesh,
            ax=axes[:, int(show_bound) :].ravel().tolist(),
            shrink=0.9,
            label="RMSE / √CRLB",
        )
        plain_log_ticks(bar.ax.yaxis)
    if bound_mesh is not None:
        bar = figure.colorbar(
            bound_mesh,
            ax=axes[:, 0].tolist(),
            location="left",
            shrink=0.9,
            label="√CRLB (m)",
        )
        plain_log_ticks(bar.ax.yaxis)
    figure.suptitle(
        "Efficiency RMSE / √CRLB over emitter positions (side-resolved RMSE where ambiguous; "
        "1 attains the bound; grey: no value)",
        fontsize="medium",
    )
    for ax in axes.ravel():
        ax.set_facecolor("0.85")
    return figure
