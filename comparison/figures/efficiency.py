r"""The efficiency figure: RMSE/√CRLB, the quantity every verdict is about, on a linear axis.

One panel per scenario (and value of any other varying parameter), the swept parameter on
the x axis (the frame for a per-frame run of one sweep point). Each estimator's judged
efficiency (side-resolved where the verdict is, MATH §7; :mod:`comparison.verdicts`) is a
point with its 95% interval as an error bar, the estimators side by side at each x so that
no bar hides another; the band ``[0.9, 1.1]`` is shaded and 1 drawn. The axis is linear
around 1 and spans at most :data:`EFFICIENCY_VIEW`: a point beyond it is drawn on the edge
as an open triangle pointing out of the chart, without its bar. A filled marker is a row
that attains the bound; an open one any other verdict. Colours are Okabe and Ito's and every
estimator has its own marker, so the figure reads in greyscale and for colour-blind readers.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from comparison.figures.panels import (
    default_colors,
    last_frame,
    parameter_columns,
    set_x_scale,
    split_panels,
    sweep_axis,
    varying_columns,
)
from comparison.figures.style import estimator_label, estimator_markers, figure_grid
from comparison.verdicts import EFFICIENCY_BAND

EFFICIENCY_VIEW = (0.5, 1.5)
"""The widest y range of the efficiency figure: points beyond it are drawn on its edge."""

EFFICIENCY_MIN_VIEW = (0.8, 1.2)
"""The narrowest y range: the band and some room around it, however close the points."""

DODGE_SHARE = 0.5
"""The share of the smallest x step that the estimators' points side by side span."""


def efficiency_figure(
    summary: pd.DataFrame,
    *,
    x: str | None = None,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """The judged efficiency against the swept parameter (module docstring).

    Parameters
    ----------
    summary : pandas.DataFrame
        From :func:`comparison.metrics.summarize`.
    x : str, optional
        The x column: a swept column (default :func:`sweep_axis`), or ``"frame"``.
    colors : mapping, optional
        Estimator → colour (default :func:`estimator_colors` in the summary's order).
    """
    colors = default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = summary if x == "frame" else last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = split_panels(rows, others)
    figure, axes = figure_grid(len(panels), sharey=True)
    view = _view(rows)
    clipped = False
    for ax, (title, panel) in zip(axes, panels, strict=True):
        clipped |= _panel(ax, panel, x, colors, view)
        ax.set_title(title, fontsize="medium", pad=9)  # above the triangles on the top edge
        if x == "frame":
            ax.set_xlabel("frame", fontsize="small")
        else:
            set_x_scale(ax, x, panel[x].to_numpy(float))
    side = (rows["verdict_basis"] == "side-resolved").to_numpy()
    basis = (
        "side-resolved"
        if side.all()
        else "side-resolved where the estimator flags ambiguity"
        if side.any()
        else "returned position"
    )
    for ax in axes[:1]:
        ax.set_ylabel("RMSE / √CRLB" + (" (side-resolved)" if side.all() else ""))
    figure.suptitle(
        f"Efficiency RMSE/√CRLB ({basis}) with its 95% interval; shaded: the band "
        f"[{EFFICIENCY_BAND[0]:g}, {EFFICIENCY_BAND[1]:g}]",
        fontsize="medium",
    )
    _legend(figure, rows, colors, clipped, view)
    return figure


def _view(rows: pd.DataFrame) -> tuple[float, float]:
    """The y range: the points and their intervals, within :data:`EFFICIENCY_VIEW`, at least
    :data:`EFFICIENCY_MIN_VIEW`."""
    values = rows[
        ["efficiency_judged", "efficiency_judged_ci_low", "efficiency_judged_ci_high"]
    ].to_numpy(float)
    inside = values[(values >= EFFICIENCY_VIEW[0]) & (values <= EFFICIENCY_VIEW[1])]
    low = min(EFFICIENCY_MIN_VIEW[0], inside.min()) if inside.size else EFFICIENCY_VIEW[0]
    high = max(EFFICIENCY_MIN_VIEW[1], inside.max()) if inside.size else EFFICIENCY_VIEW[1]
    margin = 0.04 * (high - low)
    return max(low - margin, EFFICIENCY_VIEW[0]), min(high + margin, EFFICIENCY_VIEW[1])


def _offsets(values: np.ndarray, n: int, log: bool) -> np.ndarray:
    """Where the ``n`` estimators sit around each x: a spread of :data:`DODGE_SHARE` of the
    smallest step (a factor on a log axis)."""
    steps = np.diff(np.unique(np.log10(values) if log else values))
    step = float(steps.min()) if steps.size else 1.0
    if n <= 1:
        return np.zeros(1)
    return (np.arange(n) - (n - 1) / 2) * DODGE_SHARE * step / (n - 1)


def _panel(
    ax: Axes,
    panel: pd.DataFrame,
    x: str,
    colors: Mapping[str, tuple[float, ...]],
    view: tuple[float, float],
) -> bool:
    """Draw one panel; True when a point lay beyond the view."""
    markers = estimator_markers(colors)
    ax.axhspan(*EFFICIENCY_BAND, color="0.88", zorder=0)
    ax.axhline(1.0, color="black", linewidth=0.8, zorder=0.5)
    names = [str(name) for name in panel["estimator"].unique()]
    positive = panel[x].to_numpy(float)
    log = x != "frame" and positive.min() > 0 and positive.max() / positive.min() >= 10
    offsets = _offsets(positive, len(names), log)
    clipped = False
    for k, name in enumerate(names):
        own = panel[panel["estimator"] == name].sort_values(x)
        at = own[x].to_numpy(float)
        at = at * 10 ** offsets[k] if log else at + offsets[k]
        value = own["efficiency_judged"].to_numpy(float)
        low = own["efficiency_judged_ci_low"].to_numpy(float)
        high = own["efficiency_judged_ci_high"].to_numpy(float)
        attains = (own["verdict"] == "attains").to_numpy()
        color, marker = colors[name], markers.get(name, "o")
        inside = (value >= view[0]) & (value <= view[1])
        shown = np.clip(value, *view)
        ax.plot(at, shown, color=color, linewidth=0.8, alpha=0.6, zorder=2)
        ax.errorbar(
            at[inside],
            value[inside],
            yerr=[
                value[inside] - np.clip(low[inside], view[0], None),
                np.clip(high[inside], None, view[1]) - value[inside],
            ],
            fmt="none",
            ecolor=color,
            elinewidth=1.0,
            capsize=2.0,
            zorder=3,
        )
        for filled in (True, False):
            chosen = inside & (attains == filled)
            ax.plot(
                at[chosen],
                value[chosen],
                linestyle="none",
                marker=marker,
                markersize=5.5,
                color=color,
                markerfacecolor=color if filled else "white",
                markeredgewidth=1.2,
                zorder=4,
            )
        for edge, sign, triangle in ((view[1], 1, "^"), (view[0], -1, "v")):
            beyond = np.isfinite(value) & (sign * (value - edge) > 0)
            if beyond.any():
                clipped = True
                ax.plot(
                    at[beyond],
                    np.full(beyond.sum(), edge),
                    linestyle="none",
                    marker=triangle,
                    markersize=7,
                    color=color,
                    markerfacecolor="white",
                    markeredgewidth=1.2,
                    clip_on=False,
                    zorder=5,
                )
    ax.set_ylim(*view)
    ax.grid(True, axis="x", alpha=0.3)
    return clipped


def _legend(
    figure: Figure,
    rows: pd.DataFrame,
    colors: Mapping[str, tuple[float, ...]],
    clipped: bool,
    view: tuple[float, float],
) -> None:
    """One short legend: an entry per estimator, then what the markers and the band mean."""
    markers = estimator_markers(colors)
    handles: list[object] = []
    labels: list[str] = []
    for name in dict.fromkeys(str(n) for n in rows["estimator"]):
        handles.append(
            Line2D([], [], color=colors[name], marker=markers.get(name, "o"), linewidth=0.8)
        )
        labels.append(estimator_label(name))
    handles.append(Line2D([], [], color="0.3", marker="o", linestyle="none"))
    labels.append("filled: attains")
    handles.append(
        Line2D([], [], color="0.3", marker="o", markerfacecolor="white", linestyle="none")
    )
    labels.append("open: any other verdict")
    handles.append(Patch(facecolor="0.88"))
    labels.append(f"band [{EFFICIENCY_BAND[0]:g}, {EFFICIENCY_BAND[1]:g}]")
    if clipped:
        handles.append(
            Line2D([], [], color="0.3", marker="^", markerfacecolor="white", linestyle="none")
        )
        labels.append(f"beyond the axis: below {view[0]:.3g} or above {view[1]:.3g}")
    figure.legend(handles, labels, loc="outside right center", fontsize="small", frameon=False)
