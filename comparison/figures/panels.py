"""What a figure's rows sweep, how they split into panels, and what every panel draws: the
√CRLB curves and an estimator's line."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.ticker import MaxNLocator

from comparison.figures.curves import Curve
from comparison.figures.style import (
    estimator_colors,
    estimator_label,
    estimator_markers,
    plain_log_ticks,
)
from comparison.metrics import parameter_label, summary_swept_columns

SNR_AXIS_LABEL = r"SNR (dB): every σ scaled by $10^{-\mathrm{SNR}/20}$ (MATH §2)"
CN0_AXIS_LABEL = "C/N0 (dB-Hz): the bursts received with white noise (MATH §18)"
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

KNOWN_BOUND = "crlb_rmse_known_toa_doppler_m"
"""The same bound with a non-cooperative emitter's offsets known (MATH §15), dotted grey where
it differs: the gap is the price of the unknowns."""

MAX_PANELS = 12
"""Most panels a figure draws: the first ones in panel order."""


def scenario_order(frame: pd.DataFrame) -> list[str]:
    """The scenarios of ``frame`` in their order of first appearance: the panel order."""
    return [str(name) for name in pd.unique(frame["scenario"].astype(str))]


def scenario_rank(frame: pd.DataFrame, order: Sequence[str] | None = None) -> pd.Series:
    """Position of each row's scenario in ``order`` (default :func:`scenario_order`)."""
    order = list(order) if order is not None else scenario_order(frame)
    rank = {name: i for i, name in enumerate(order)}
    return frame["scenario"].astype(str).map(rank).fillna(len(rank)).astype(np.int64)


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
    """Axis label with unit; the SNR and C/N0 axes carry their definitions (MATH §2, §18)."""
    if column == "snr_db":
        return SNR_AXIS_LABEL
    if column == "cn0_dbhz":
        return CN0_AXIS_LABEL
    name, unit = parameter_label(column)
    return f"{name} ({unit})" if unit else name


def panel_title(scenario: str, values: Mapping[str, float]) -> str:
    extra = ", ".join(
        f"{parameter_label(c)[0]} = {v:g}{(' ' + parameter_label(c)[1]) if parameter_label(c)[1] else ''}"
        for c, v in values.items()
    )
    return f"{scenario}, {extra}" if extra else scenario


def split_panels(frame: pd.DataFrame, by: Sequence[str]) -> list[tuple[str, pd.DataFrame]]:
    """Split rows into panels: one per scenario and value of the other varying columns.

    Scenarios in their order of first appearance (:func:`scenario_order`), then the values
    of ``by`` ascending.
    """
    rank = scenario_rank(frame)
    keyed = []
    for key, rows in frame.groupby(["scenario", *by], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        title = panel_title(str(key[0]), dict(zip(by, key[1:], strict=True)))
        keyed.append(((int(rank.loc[rows.index[0]]), *key[1:]), title, rows))
    keyed.sort(key=lambda item: item[0])
    return [(title, rows) for _, title, rows in keyed][:MAX_PANELS]


def set_x_scale(ax: Axes, column: str, values: np.ndarray) -> None:
    """Log x axis for a positive parameter spanning a decade or more; SNR ticks on whole
    steps of 1, 2, 5 or 10 dB."""
    if column == "snr_db":
        ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", steps=[1, 2, 5, 10]))
    positive = values[np.isfinite(values)]
    if column != "snr_db" and positive.size and positive.min() > 0:
        if positive.max() / positive.min() >= 10:
            ax.set_xscale("log")
            plain_log_ticks(ax.xaxis)
    ax.set_xlabel(axis_label(column), fontsize="small")


# --------------------------------------------------------------------------------------------
# what every panel draws
# --------------------------------------------------------------------------------------------


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


def point_bounds(
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


def draw_bounds(
    ax: Axes,
    rows: pd.DataFrame,
    point_rows: pd.DataFrame | None,
    x: str,
    colors: Mapping[str, tuple[float, ...]],
) -> list[Curve]:
    """Solid black √CRLB for ToA+Doppler; dashed estimator-coloured bounds that differ.

    Returns the curves drawn (never interleaved: the black bound lies under the estimators,
    wider than their lines, and stays visible at their edges).
    """
    curves: list[Curve] = []
    reference = None
    if point_rows is not None and REFERENCE_BOUND in point_rows:
        reference = point_rows[REFERENCE_BOUND].to_numpy(float)
        # an emitter of unknown height: the 3-D bound, and the bound with it known (MATH §8)
        height = "truth_z_m" in point_rows and bool(point_rows["truth_z_m"].notna().any())
        name = "√CRLB, ToA+Doppler, (x, y, z)" if height else "√CRLB, ToA+Doppler"
        ax.plot(point_rows[x], reference, color="black", linewidth=2.4, label=name, zorder=1.9)
        curves.append(Curve(name, "√CRLB", point_rows[x].to_numpy(float), reference))
        known = point_rows.get(KNOWN_BOUND)
        if known is not None and not _same_bound(known.to_numpy(float), reference):
            label = (
                "√CRLB, ToA+Doppler, height and every offset known (MATH §8, §15)"
                if height
                else "√CRLB, ToA+Doppler, carrier and clock known (MATH §15)"
            )
            ax.plot(point_rows[x], known, color="grey", linewidth=1.6, linestyle=":", label=label)
            curves.append(Curve(label, "√CRLB", point_rows[x].to_numpy(float), known.to_numpy()))
    # Bounds that differ from the reference, each drawn once for all estimators sharing it.
    groups: list[tuple[pd.Series, np.ndarray, list[str]]] = []
    for estimator, own in rows.groupby("estimator", sort=False):
        own = own.sort_values(x)
        bound = own["crlb_rmse_m"].to_numpy(float)
        if not np.isfinite(bound).any():
            continue
        if reference is None:
            reference = bound
            label = f"√CRLB, {estimator}'s modalities"
            ax.plot(own[x], bound, color="black", linewidth=2.4, label=label, zorder=1.9)
            curves.append(Curve(label, "√CRLB", own[x].to_numpy(float), bound))
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
        label = f"√CRLB, {name} ({who})" if name else f"√CRLB of {who}"
        ax.plot(
            x_values,
            bound,
            color=colors[names[0]],
            linestyle="--",
            linewidth=1.2,
            label=label,
            zorder=3,
        )
        curves.append(Curve(label, f"√CRLB of {who}", x_values.to_numpy(float), bound))
    return curves


def _same_bound(first: np.ndarray, second: np.ndarray) -> bool:
    return len(first) == len(second) and bool(np.allclose(first, second, rtol=1e-3, equal_nan=True))


def default_colors(
    frame: pd.DataFrame, colors: Mapping[str, tuple[float, ...]] | None
) -> Mapping[str, tuple[float, ...]]:
    return colors if colors is not None else estimator_colors(frame["estimator"].unique())


def estimator_line(
    ax: Axes,
    x_values: pd.Series | np.ndarray,
    y_values: pd.Series | np.ndarray,
    estimator: str,
    colors: Mapping[str, tuple[float, ...]],
    **style: object,
) -> Curve:
    """Draw one estimator's line in its colour and marker (:func:`estimator_markers` of the
    colour mapping's order); return it as a curve for :class:`Curves`."""
    markers = estimator_markers(colors)
    label = estimator_label(estimator)
    style = {"marker": markers.get(estimator, "o"), "markersize": 4.0, **style}
    (line,) = ax.plot(x_values, y_values, color=colors[estimator], label=label, **style)
    x = np.asarray(x_values, dtype=float)
    return Curve(label, estimator, x, np.asarray(y_values, dtype=float), line)
