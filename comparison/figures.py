r"""Figures of a comparison report, one function per figure, each returning the Figure.

Every function takes the tidy frames of :mod:`comparison.metrics` and
:mod:`comparison.engine` (a summary, the trial rows, the per-point bounds) and draws with
matplotlib's object API (``matplotlib.figure.Figure``, rendered by the Agg and SVG canvases):
nothing touches pyplot's global state or needs a display. :func:`save_figure` writes a
figure as PNG and SVG.

Conventions shared by all figures:

- one colour per estimator, the same in every figure (:func:`estimator_colors`);
- the swept parameter on the x axis (SNR by default; every σ is scaled by
  :math:`10^{-\mathrm{SNR}/20}`, MATH §2), one panel per scenario;
- the bound :math:`\sqrt{\operatorname{tr}\,\mathrm{CRLB}}` for ToA+Doppler as a solid black
  line, the bound of an estimator that uses other modalities dashed in its colour (MATH §8);
- per-frame runs are drawn at their last frame except in the figures against the frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import matplotlib as mpl
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter

from comparison.metrics import (
    judged_rmse,
    parameter_label,
    summary_swept_columns,
    swept_columns_of,
)

ESTIMATOR_LABELS: dict[str, str] = {
    "cls-as-printed": "cls-as-printed (paper's formulas as printed)",
}
"""Legend labels that say more than the registry name."""

SNR_AXIS_LABEL = r"SNR (dB): every σ scaled by $10^{-\mathrm{SNR}/20}$ (MATH §2)"
"""The x label of every figure against SNR."""

BOUND_COLUMNS: dict[str, str] = {
    "crlb_rmse_toa_doppler_m": "ToA+Doppler",
    "crlb_rmse_toa_m": "ToA only",
    "crlb_rmse_doppler_m": "Doppler only",
    "crlb_rmse_rss_m": "RSS only",
    "crlb_rmse_all_m": "ToA+Doppler+RSS",
}
"""The bound columns of ``read_points`` and the modalities they use (MATH §8)."""

REFERENCE_BOUND = "crlb_rmse_toa_doppler_m"
"""The bound drawn in solid black."""

PANEL_SIZE_IN = (4.6, 3.4)
LEGEND_WIDTH_IN = 3.4
MAX_PANELS = 12


def estimator_label(name: str) -> str:
    """The legend label of an estimator (:data:`ESTIMATOR_LABELS`, else its name)."""
    return ESTIMATOR_LABELS.get(name, name)


def estimator_colors(names: Iterable[str]) -> dict[str, tuple[float, float, float, float]]:
    """One colour per estimator, in the given order (tab10, then tab20 beyond ten)."""
    unique = list(dict.fromkeys(names))
    palette = mpl.colormaps["tab10" if len(unique) <= 10 else "tab20"]
    return {name: palette(i % palette.N) for i, name in enumerate(unique)}


def save_figure(figure: Figure, directory: str | Path, stem: str, *, dpi: int = 150) -> list[Path]:
    """Write ``figure`` as ``<stem>.png`` (``dpi``) and ``<stem>.svg``; return both paths."""
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{stem}.png", folder / f"{stem}.svg"]
    figure.savefig(paths[0], dpi=dpi)
    layout = figure.get_layout_engine()
    figure.set_layout_engine("none")  # keep the layout just computed: same positions in SVG
    figure.savefig(paths[1])
    figure.set_layout_engine(layout)
    return paths


# --------------------------------------------------------------------------------------------
# what is swept
# --------------------------------------------------------------------------------------------


def parameter_columns(summary: pd.DataFrame) -> list[str]:
    """``snr_db`` and the swept columns of a summary, in order."""
    return ["snr_db", *summary_swept_columns(summary)]


def varying_columns(frame: pd.DataFrame, columns: Sequence[str]) -> list[str]:
    """The columns among ``columns`` taking more than one value within some scenario."""
    counts = frame.groupby("scenario", sort=False)[list(columns)].nunique()
    return [c for c in columns if (counts[c] > 1).any()]


def is_geometry_sweep(summary: pd.DataFrame) -> bool:
    """True when the sweep moves the emitter over a grid (``emitter_x_m`` and ``emitter_y_m``)."""
    columns = parameter_columns(summary)
    if "emitter_x_m" not in columns or "emitter_y_m" not in columns:
        return False
    return {"emitter_x_m", "emitter_y_m"} <= set(varying_columns(summary, columns))


def is_per_frame(frame: pd.DataFrame) -> bool:
    """True when some sweep point has rows for several frames (a per-frame run)."""
    keys = ["scenario", *parameter_columns(frame), "estimator"]
    return bool((frame.groupby(keys, sort=False)["frame"].nunique() > 1).any())


def sweep_axis(summary: pd.DataFrame) -> str | None:
    """The x axis of the line figures: SNR if it varies, else the one varying parameter.

    ``None`` for an emitter-grid sweep (drawn by :func:`geometry_heatmap_figure`).
    """
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    if is_geometry_sweep(summary):
        return None
    if "snr_db" in varying or not varying:
        return "snr_db"
    return varying[0]


def last_frame(frame: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """The rows at the last frame of each (scenario, point, estimator)."""
    keys = ["scenario", *columns, "estimator"]
    latest = frame.groupby(keys, sort=False)["frame"].transform("max")
    return frame[frame["frame"] == latest]


def axis_label(column: str) -> str:
    """Axis label with unit; the SNR axis carries its definition (MATH §2)."""
    if column == "snr_db":
        return SNR_AXIS_LABEL
    name, unit = parameter_label(column)
    return f"{name} ({unit})" if unit else name


def _panel_title(scenario: str, values: Mapping[str, float]) -> str:
    extra = ", ".join(
        f"{parameter_label(c)[0]} = {v:g}{(' ' + parameter_label(c)[1]) if parameter_label(c)[1] else ''}"
        for c, v in values.items()
    )
    return f"{scenario}, {extra}" if extra else scenario


def _panels(frame: pd.DataFrame, by: Sequence[str]) -> list[tuple[str, pd.DataFrame]]:
    """Split rows into panels: one per scenario and value of the other varying columns."""
    panels = []
    for key, rows in frame.groupby(["scenario", *by], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        title = _panel_title(str(key[0]), dict(zip(by, key[1:], strict=True)))
        panels.append((title, rows))
    return panels[:MAX_PANELS]


def _figure_grid(
    n_panels: int, *, legend: bool = True, sharey: bool = False, ncols: int | None = None
) -> tuple[Figure, list[Axes]]:
    ncols = ncols or min(n_panels, 3)
    nrows = -(-n_panels // ncols)
    width = PANEL_SIZE_IN[0] * ncols + (LEGEND_WIDTH_IN if legend else 0.0)
    figure = Figure(figsize=(width, PANEL_SIZE_IN[1] * nrows + 0.6), layout="constrained")
    axes = figure.subplots(nrows, ncols, squeeze=False, sharey=sharey).ravel()
    for extra in axes[n_panels:]:
        extra.set_visible(False)
    return figure, list(axes[:n_panels])


def _legend(figure: Figure, axes: Sequence[Axes]) -> None:
    """One legend for all panels, outside the data on the right."""
    entries: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if entries:
        figure.legend(
            list(entries.values()),
            list(entries),
            loc="outside right center",
            fontsize="small",
            frameon=False,
        )


class PlainLogFormatter(LogFormatter):
    """Matplotlib's choice of labelled log ticks, written as plain numbers (``20``, ``0.3``)."""

    def __call__(self, x: float, pos: int | None = None) -> str:
        return f"{x:g}" if super().__call__(x, pos) else ""


def plain_log_ticks(axis: Axis) -> None:
    """Label a log axis with plain numbers, minor ticks too when it spans little."""
    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.5)))


def _set_x_scale(ax: Axes, column: str, values: np.ndarray) -> None:
    positive = values[np.isfinite(values)]
    if column != "snr_db" and positive.size and positive.min() > 0:
        if positive.max() / positive.min() >= 10:
            ax.set_xscale("log")
            plain_log_ticks(ax.xaxis)
    ax.set_xlabel(axis_label(column), fontsize="small")


def _bound_name(bound: np.ndarray, point_rows: pd.DataFrame | None) -> str | None:
    """Name the modalities of ``bound`` by matching it to a bound column of the points."""
    if point_rows is None:
        return None
    for column, name in BOUND_COLUMNS.items():
        if column in point_rows and np.allclose(
            point_rows[column].to_numpy(float), bound, rtol=1e-6, equal_nan=True
        ):
            return name
    return None


def _point_bounds(
    rows: pd.DataFrame, points: pd.DataFrame | None, x: str, columns: Sequence[str]
) -> pd.DataFrame | None:
    """The per-point bounds matching the x values of ``rows`` (last frame), sorted by x."""
    if points is None:
        return None
    keys = ["scenario", *columns, "frame"]
    present = [c for c in keys if c in points.columns]
    if len(present) != len(keys):
        return None
    wanted = rows[keys].drop_duplicates()
    matched = wanted.merge(points, on=keys, how="left")
    return matched.sort_values(x).reset_index(drop=True)


def _draw_bounds(
    ax: Axes,
    rows: pd.DataFrame,
    point_rows: pd.DataFrame | None,
    x: str,
    colors: Mapping[str, tuple[float, ...]],
) -> None:
    """Solid black √CRLB for ToA+Doppler; dashed estimator-coloured bounds that differ."""
    reference = None
    if point_rows is not None and REFERENCE_BOUND in point_rows:
        reference = point_rows[REFERENCE_BOUND].to_numpy(float)
        ax.plot(
            point_rows[x],
            reference,
            color="black",
            linewidth=2.4,
            label="√CRLB, ToA+Doppler",
            zorder=1.9,
        )
    # Bounds that differ from the reference, each drawn once for all estimators sharing it.
    groups: list[tuple[pd.Series, np.ndarray, list[str]]] = []
    for estimator, own in rows.groupby("estimator", sort=False):
        own = own.sort_values(x)
        bound = own["crlb_rmse_m"].to_numpy(float)
        if not np.isfinite(bound).any():
            continue
        if reference is None:
            reference = bound
            ax.plot(
                own[x],
                bound,
                color="black",
                linewidth=2.4,
                label=f"√CRLB, {estimator}'s modalities",
                zorder=1.9,
            )
            continue
        if _same_bound(bound, reference):
            continue
        for _, shared, names in groups:
            if _same_bound(bound, shared):
                names.append(str(estimator))
                break
        else:
            groups.append((own[x], bound, [str(estimator)]))
    for x_values, bound, names in groups:
        name = _bound_name(bound, point_rows)
        who = ", ".join(names)
        ax.plot(
            x_values,
            bound,
            color=colors[names[0]],
            linestyle="--",
            linewidth=1.2,
            label=f"√CRLB, {name} ({who})" if name else f"√CRLB of {who}",
            zorder=3,
        )


def _same_bound(first: np.ndarray, second: np.ndarray) -> bool:
    return len(first) == len(second) and bool(np.allclose(first, second, rtol=1e-3, equal_nan=True))


def _default_colors(
    frame: pd.DataFrame, colors: Mapping[str, tuple[float, ...]] | None
) -> Mapping[str, tuple[float, ...]]:
    return colors if colors is not None else estimator_colors(frame["estimator"].unique())


# --------------------------------------------------------------------------------------------
# figures against the swept parameter
# --------------------------------------------------------------------------------------------


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
    colors = _default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = _panels(rows, others)
    figure, axes = _figure_grid(len(panels))
    value, low, high = (
        ("rmse_side_resolved_m", "rmse_side_resolved_ci_low_m", "rmse_side_resolved_ci_high_m")
        if side_resolved
        else ("rmse_m", "rmse_ci_low_m", "rmse_ci_high_m")
    )
    for ax, (title, panel) in zip(axes, panels, strict=True):
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values(x)
            color = colors[str(estimator)]
            ax.plot(
                own[x],
                own[value],
                marker="o",
                markersize=3.5,
                color=color,
                label=estimator_label(str(estimator)),
            )
            ax.fill_between(own[x], own[low], own[high], color=color, alpha=0.2, linewidth=0)
        _draw_bounds(ax, panel, _point_bounds(panel, points, x, columns), x, colors)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        _set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.grid(True, which="both", alpha=0.3)
    what = (
        "Side-resolved RMSE (nearest candidate, MATH §7)"
        if side_resolved
        else "RMSE of the returned position"
    )
    figure.suptitle(f"{what}; shaded: 95% bootstrap interval", fontsize="medium")
    _legend(figure, axes)
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
    achieves at best.
    """
    colors = _default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = _panels(rows, others)
    figure, axes = _figure_grid(len(panels), sharey=True)
    for ax, (title, panel) in zip(axes, panels, strict=True):
        _plot_wrong_side(ax, panel, x, colors)
        _set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_title(title, fontsize="medium")
    figure.suptitle(
        "Estimates on the wrong side of the last frame's track; shaded: 95% Wilson interval",
        fontsize="medium",
    )
    _legend(figure, axes)
    return figure


def wrong_side_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Wrong-side rate against the last frame used (MATH §7): a turn should drive it to 0."""
    colors = _default_colors(summary, colors)
    panels = _frame_panels(summary, n_points)
    figure, axes = _figure_grid(len(panels), sharey=True)
    for ax, (title, panel) in zip(axes, panels, strict=True):
        _plot_wrong_side(ax, panel, "frame", colors)
        ax.set_xlabel("last frame used (index)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize="medium")
    figure.suptitle(
        "Wrong-side rate as frames accumulate; shaded: 95% Wilson interval", fontsize="medium"
    )
    _legend(figure, axes)
    return figure


def _plot_wrong_side(
    ax: Axes, panel: pd.DataFrame, x: str, colors: Mapping[str, tuple[float, ...]]
) -> None:
    """One panel of wrong-side rate against ``x``, a line per estimator, 0.5 marked."""
    for estimator, own in panel.groupby("estimator", sort=False):
        own = own.sort_values(x)
        low, high = wilson_interval(own["wrong_side_rate"], own["n_successes"])
        color = colors[str(estimator)]
        ax.plot(
            own[x],
            own["wrong_side_rate"],
            marker="o",
            markersize=3.5,
            color=color,
            label=estimator_label(str(estimator)),
        )
        ax.fill_between(own[x], low, high, color=color, alpha=0.15, linewidth=0)
    ax.axhline(0.5, color="grey", linestyle=":", linewidth=1, label="0.5 (a coin toss)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("wrong-side rate")
    ax.grid(True, alpha=0.3)


def wilson_interval(rate: pd.Series, n: pd.Series, z: float = 1.96) -> tuple[np.ndarray, ...]:
    """Wilson score interval of a binomial proportion (NaN where ``n`` is 0)."""
    p = np.asarray(rate, dtype=float)
    count = np.asarray(n, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        centre = (p + z**2 / (2 * count)) / (1 + z**2 / count)
        half = z * np.sqrt(p * (1 - p) / count + z**2 / (4 * count**2)) / (1 + z**2 / count)
    return centre - half, centre + half


# --------------------------------------------------------------------------------------------
# distributions and cost
# --------------------------------------------------------------------------------------------


def _chosen_points(
    trials: pd.DataFrame, x: str | None, n_points: int, columns: Sequence[str]
) -> pd.DataFrame:
    """Up to ``n_points`` sweep points per scenario: lowest, middle and highest ``x``.

    Without ``x`` (a grid), the points of smallest, median and largest mean √CRLB: the
    easiest, a middle and the hardest geometry.
    """
    keys = trials.groupby(["scenario", "point"], sort=False).agg(
        **{c: (c, "first") for c in columns}, bound=("crlb_rmse_m", "mean")
    )
    keys = keys.reset_index().sort_values(["scenario", x or "bound", "point"])
    chosen = []
    for _, rows in keys.groupby("scenario", sort=False):
        index = np.unique(np.linspace(0, len(rows) - 1, min(n_points, len(rows))).round())
        chosen.append(rows.iloc[index.astype(int)])
    return pd.concat(chosen)


def error_cdf_figure(
    trials: pd.DataFrame,
    *,
    x: str | None = "snr_db",
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Empirical CDFs of the distance error at a few sweep points (lowest, middle, highest).

    Solid: error of the returned position; dashed: side-resolved error (MATH §7), drawn for
    estimators that flag ambiguous answers. The CDF is over all trials: failed estimates
    count as infinite errors, so a curve that stays below 1 shows the failure rate.

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
    colors = _default_colors(trials, colors)
    latest = trials.groupby(["scenario", "point"], sort=False)["frame"].transform("max")
    rows = trials[trials["frame"] == latest]
    columns = ["snr_db", *swept_columns_of(trials)]
    varying = varying_columns(rows, columns)
    chosen = _chosen_points(rows, x, n_points, columns)
    figure, axes = _figure_grid(len(chosen), ncols=min(len(chosen), n_points), sharey=True)
    for ax, (_, where) in zip(axes, chosen.iterrows(), strict=True):
        at = rows[(rows["scenario"] == where["scenario"]) & (rows["point"] == where["point"])]
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
                ax.step(
                    errors,
                    np.arange(1, errors.size + 1) / n,
                    where="post",
                    color=color,
                    linestyle=style,
                    label=estimator_label(str(estimator)) + suffix,
                )
        ax.set_xscale("log")
        plain_log_ticks(ax.xaxis)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("distance error (m)")
        ax.set_ylabel("fraction of trials")
        values = {c: float(where[c]) for c in (varying or ["snr_db"])}
        ax.set_title(_panel_title(str(where["scenario"]), values), fontsize="medium")
        ax.grid(True, which="both", alpha=0.3)
    figure.suptitle(
        "Distribution of the distance error (failed estimates count as infinite)", fontsize="medium"
    )
    _legend(figure, axes)
    return figure


def runtime_figure(
    trials: pd.DataFrame, *, colors: Mapping[str, tuple[float, ...]] | None = None
) -> Figure:
    """Median wall time of one estimate per estimator (horizontal bars, log axis).

    The whiskers span the 5th to 95th percentiles over every estimate of the run.
    """
    colors = _default_colors(trials, colors)
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
    ax.set_xlabel("wall time per estimate (s)")
    ax.set_title(
        "Run time per estimate (median; whiskers: 5th to 95th percentile)", fontsize="medium"
    )
    ax.grid(True, axis="x", which="both", alpha=0.3)
    return figure


# --------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------


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

    The efficiency is the judged one of :func:`comparison.metrics.judged_rmse` (side-resolved
    where the estimator flags ambiguous answers, MATH §7) divided by the estimator's √CRLB.
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
    rows["judged_efficiency"] = judged_rmse(rows)["efficiency"].to_numpy()
    others = [c for c in varying_columns(rows, columns) if c not in ("emitter_x_m", "emitter_y_m")]
    panels = _panels(rows, others)
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
        _point_bounds(panel, points, "emitter_x_m", columns) if show_bound else None
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


# --------------------------------------------------------------------------------------------
# per-frame runs
# --------------------------------------------------------------------------------------------


def _frame_panels(summary: pd.DataFrame, n_points: int) -> list[tuple[str, pd.DataFrame]]:
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    keys = summary[["scenario", *columns]].drop_duplicates()
    panels = []
    for _, rows in keys.groupby("scenario", sort=False):
        order = rows.sort_values(varying or ["snr_db"])
        index = np.unique(np.linspace(0, len(order) - 1, min(n_points, len(order))).round())
        for _, key in order.iloc[index.astype(int)].iterrows():
            mask = np.ones(len(summary), dtype=bool)
            for column in ["scenario", *columns]:
                mask &= (summary[column] == key[column]).to_numpy()
            values = {c: float(key[c]) for c in varying} or {"snr_db": float(key["snr_db"])}
            panels.append((_panel_title(str(key["scenario"]), values), summary[mask]))
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
    colors = _default_colors(summary, colors)
    columns = parameter_columns(summary)
    panels = _frame_panels(summary, n_points)
    figure, axes = _figure_grid(len(panels))
    for ax, (title, panel) in zip(axes, panels, strict=True):
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values("frame")
            color = colors[str(estimator)]
            ax.plot(
                own["frame"],
                own["rmse_m"],
                marker="o",
                markersize=3.5,
                color=color,
                label=estimator_label(str(estimator)),
            )
            ax.fill_between(
                own["frame"],
                own["rmse_ci_low_m"],
                own["rmse_ci_high_m"],
                color=color,
                alpha=0.2,
                linewidth=0,
            )
            if not np.allclose(own["rmse_side_resolved_m"], own["rmse_m"], equal_nan=True):
                ax.plot(
                    own["frame"],
                    own["rmse_side_resolved_m"],
                    linestyle=":",
                    color=color,
                    label=f"{estimator_label(str(estimator))}, side-resolved",
                )
        bounds = None
        if points is not None:
            keys = ["scenario", *columns, "frame"]
            if all(c in points.columns for c in keys):
                bounds = panel[keys].drop_duplicates().merge(points, on=keys).sort_values("frame")
        _draw_bounds(ax, panel, bounds, "frame", colors)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(True, which="both", alpha=0.3)
    figure.suptitle("RMSE as frames accumulate, with the accumulated √CRLB", fontsize="medium")
    _legend(figure, axes)
    return figure


def nees_vs_frame_figure(
    summary: pd.DataFrame,
    *,
    n_points: int = 3,
    colors: Mapping[str, tuple[float, ...]] | None = None,
) -> Figure:
    """Mean NEES against the frame, for the estimators that report a covariance.

    A consistent covariance gives a mean NEES of 2 (two dof), inside the 95% band of
    :func:`comparison.metrics.nees_band` (shaded grey: the widest band among the estimators
    of the panel, from their smallest count).
    """
    with_nees = summary[summary["n_nees"] > 0]
    if with_nees.empty:
        raise ValueError("summary: no estimator reports a covariance (n_nees is 0 everywhere)")
    colors = _default_colors(summary, colors)
    panels = _frame_panels(with_nees, n_points)
    figure, axes = _figure_grid(len(panels))
    for ax, (title, panel) in zip(axes, panels, strict=True):
        band = panel.loc[panel.groupby("frame")["n_nees"].idxmin()].sort_values("frame")
        ax.fill_between(
            band["frame"],
            band["nees_band_low"],
            band["nees_band_high"],
            color="0.8",
            label="95% band of a consistent mean NEES",
        )
        ax.axhline(2.0, color="black", linewidth=1, label="2 (consistent)")
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values("frame")
            ax.plot(
                own["frame"],
                own["nees_mean"],
                marker="o",
                markersize=3.5,
                color=colors[str(estimator)],
                label=estimator_label(str(estimator)),
            )
        values = np.concatenate([panel["nees_mean"], band["nees_band_high"]])
        values = values[np.isfinite(values) & (values > 0)]
        if values.size and values.max() / values.min() > 20:
            ax.set_yscale("log")
            plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("mean NEES")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(True, which="both", alpha=0.3)
    figure.suptitle(
        "Covariance consistency: mean NEES (2 dof) as frames accumulate", fontsize="medium"
    )
    _legend(figure, axes)
    return figure


# --------------------------------------------------------------------------------------------
# closed loop: planners against the frame, and the trajectories (paper Fig. 3)
# --------------------------------------------------------------------------------------------


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
    """One panel per (scenario, sweep point, estimator), in the summary's order."""
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    panels = []
    for key, rows in summary.groupby(["scenario", *varying, "estimator"], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        values = dict(zip(varying, key[1:-1], strict=True))
        panels.append((f"{_panel_title(str(key[0]), values)}: {key[-1]}", rows))
    return panels[:MAX_PANELS]


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
    figure, axes = _figure_grid(len(panels), ncols=min(max(n_estimators, 1), 3))
    for ax, (title, panel) in zip(axes, panels, strict=True):
        for planner, own in panel.groupby("planner", sort=False):
            own = own.sort_values("frame")
            color = colors[str(planner)]
            ax.plot(
                own["frame"],
                own[value],
                marker=_planner_marker(summary, planner),
                markersize=4,
                color=color,
                label=f"{planner}: RMSE",
            )
            ax.fill_between(own["frame"], own[low], own[high], color=color, alpha=0.2, linewidth=0)
            ax.plot(
                own["frame"],
                own["crlb_rmse_m"],
                linestyle="--",
                linewidth=1.2,
                color=color,
                label=f"{planner}: √CRLB of the flown paths",
            )
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(True, which="both", alpha=0.3)
    what = "Side-resolved RMSE (MATH §7)" if side_resolved else "RMSE of the returned position"
    figure.suptitle(
        f"Closed loop: {what} per planner as frames accumulate; dashed: RMS over trials of "
        "√CRLB of each flown trajectory",
        fontsize="medium",
    )
    _legend(figure, axes)
    return figure


def planner_wrong_side_vs_frame_figure(
    summary: pd.DataFrame, *, colors: Mapping[str, tuple[float, ...]] | None = None
) -> Figure:
    """Wrong-side rate against the frame, one line per planner (95% Wilson interval, MATH §7).

    The rows judge the side against the first track an estimator uses, in each trial's own
    flight (:mod:`comparison.engine`).
    """
    if "planner" not in summary.columns:
        raise ValueError("summary: no planner column; this figure is for closed-loop runs")
    colors = colors if colors is not None else planner_colors(summary["planner"].unique())
    panels = _planner_panels(summary)
    n_estimators = summary["estimator"].nunique()
    figure, axes = _figure_grid(len(panels), sharey=True, ncols=min(max(n_estimators, 1), 3))
    for ax, (title, panel) in zip(axes, panels, strict=True):
        for planner, own in panel.groupby("planner", sort=False):
            own = own.sort_values("frame")
            low, high = wilson_interval(own["wrong_side_rate"], own["n_successes"])
            color = colors[str(planner)]
            ax.plot(
                own["frame"],
                own["wrong_side_rate"],
                marker=_planner_marker(summary, planner),
                markersize=5,
                markerfacecolor="none",
                color=color,
                label=str(planner),
            )
            ax.fill_between(own["frame"], low, high, color=color, alpha=0.15, linewidth=0)
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
    _legend(figure, axes)
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
    figure, axes = _figure_grid(2 * len(scenarios) * ncols, legend=True, ncols=ncols)
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
    _legend(figure, [axes[0], axes[ncols]])
    return figure
