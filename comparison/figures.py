r"""Figures of a comparison report, one function per figure, each returning the Figure.

Every function takes the tidy frames of :mod:`comparison.metrics` and
:mod:`comparison.engine` (a summary, the trial rows, the per-point bounds) and draws with
matplotlib's object API (``matplotlib.figure.Figure``, rendered by the Agg and SVG canvases):
nothing touches pyplot's global state or needs a display. :func:`save_figure` writes a
figure as PNG and SVG.

Conventions shared by all figures:

- one colour and one marker per estimator, the same in every figure (:func:`estimator_colors`,
  :func:`estimator_markers`, both from the order of the colour mapping);
- the swept parameter on the x axis (SNR by default; every σ is scaled by
  :math:`10^{-\mathrm{SNR}/20}`, MATH §2), one panel per scenario;
- panels in one order everywhere: scenarios in their order of first appearance in the frame
  drawn (the experiment's order, :func:`scenario_order`), then the other varying parameters
  ascending;
- the bound :math:`\sqrt{\operatorname{tr}\,\mathrm{CRLB}}` for ToA+Doppler as a solid black
  line, the bound of an estimator that uses other modalities dashed in its colour (MATH §8);
- curves that agree within :data:`COINCIDENCE_RTOL` at every point of a panel are named in
  the legend ("coincides with …") and drawn interleaved: alternating dash segments and
  markers, so that each stays visible;
- a rate or a mean backed by fewer than :data:`MIN_COUNT_FOR_RATE` values is not drawn
  (:data:`WRONG_SIDE_COUNT_NOTE`, :data:`NEES_COUNT_NOTE`);
- log axes label decades only (1-2-5 steps when the view spans less than two decades), as
  plain numbers from 0.001 to 10000 and as powers of ten beyond; minor ticks are unlabelled;
- per-frame runs are drawn at their last frame except in the figures against the frame.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib as mpl
import numpy as np
import pandas as pd
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import Formatter, Locator, LogLocator, MaxNLocator, NullFormatter

from comparison.metrics import (
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

MIN_COUNT_FOR_RATE = 20
"""Fewest values behind a drawn point of a rate or a mean.

A wrong-side rate is drawn only where its count ``n_side_judged`` (the successful estimates
off the track plane) is at least this, a mean NEES only where ``n_nees`` is: below it, a rate
of 0 or 1 from a handful of estimates says nothing. Nothing is drawn at such a point (the line
breaks there, its interval too), and the legend counts the points left out."""

WRONG_SIDE_COUNT_NOTE = (
    f"points backed by fewer than {MIN_COUNT_FOR_RATE} estimates off the track are not drawn"
)
"""What the caption of a wrong-side figure says about :data:`MIN_COUNT_FOR_RATE`."""

NEES_COUNT_NOTE = f"points backed by fewer than {MIN_COUNT_FOR_RATE} NEES values are not drawn"
"""What the caption of the NEES figure says about :data:`MIN_COUNT_FOR_RATE`."""

COINCIDENCE_RTOL = 0.02
"""Two curves of a panel coincide when they are drawn at the same x values and agree there
within this relative tolerance, ``|a − b| ≤ COINCIDENCE_RTOL · max(|a|, |b|)``, at every
point."""

COINCIDENCE_NOTE = "coincides with"
"""The legend note of a curve hidden by another: ``label (coincides with X, Y)``."""

ESTIMATOR_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")
"""Marker of the i-th estimator of the colour mapping (:func:`estimator_markers`)."""

MAX_LOG_LABELS = 6
"""Most labelled ticks on a log axis (decades are thinned to every second, third, … one)."""

PLAIN_NUMBER_RANGE = (1e-3, 1e5)
"""Log-axis labels are plain numbers when every labelled tick lies in this range, else powers
of ten."""


def estimator_label(name: str) -> str:
    """The legend label of an estimator (:data:`ESTIMATOR_LABELS`, else its name)."""
    return ESTIMATOR_LABELS.get(name, name)


def estimator_colors(names: Iterable[str]) -> dict[str, tuple[float, float, float, float]]:
    """One colour per estimator, in the given order (tab10, then tab20 beyond ten)."""
    unique = list(dict.fromkeys(names))
    palette = mpl.colormaps["tab10" if len(unique) <= 10 else "tab20"]
    return {name: palette(i % palette.N) for i, name in enumerate(unique)}


def estimator_markers(names: Iterable[str]) -> dict[str, str]:
    """One marker per estimator, in the given order (:data:`ESTIMATOR_MARKERS`).

    The figures take the order of their colour mapping, so that an estimator keeps its colour
    and its marker in every figure given the same mapping.
    """
    unique = list(dict.fromkeys(str(n) for n in names))
    return {name: ESTIMATOR_MARKERS[i % len(ESTIMATOR_MARKERS)] for i, name in enumerate(unique)}


def scenario_order(frame: pd.DataFrame) -> list[str]:
    """The scenarios of ``frame`` in their order of first appearance: the panel order."""
    return list(dict.fromkeys(frame["scenario"].astype(str)))


def _scenario_rank(frame: pd.DataFrame, order: Sequence[str] | None = None) -> pd.Series:
    """Position of each row's scenario in ``order`` (default :func:`scenario_order`)."""
    order = list(order) if order is not None else scenario_order(frame)
    rank = {name: i for i, name in enumerate(order)}
    return frame["scenario"].astype(str).map(lambda name: rank.get(name, len(rank)))


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
    """Split rows into panels: one per scenario and value of the other varying columns.

    Scenarios in their order of first appearance (:func:`scenario_order`), then the values
    of ``by`` ascending.
    """
    rank = _scenario_rank(frame)
    keyed = []
    for key, rows in frame.groupby(["scenario", *by], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        title = _panel_title(str(key[0]), dict(zip(by, key[1:], strict=True)))
        keyed.append(((int(rank.loc[rows.index[0]]), *key[1:]), title, rows))
    keyed.sort(key=lambda item: item[0])
    return [(title, rows) for _, title, rows in keyed][:MAX_PANELS]


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


def _legend(
    figure: Figure, axes: Sequence[Axes], curves: _Curves | None = None, *, wrap: int = 44
) -> None:
    """One legend for all panels, outside the data on the right.

    With ``curves``, the labels carry their coincidence notes and a curve restyled to be seen
    under another gets a handle in its own style; its extra entries (a style, the points left
    out) come last. Labels are wrapped to ``wrap`` characters.
    """
    entries: dict[str, Artist] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    labels = list(entries)
    handles = list(entries.values())
    if curves is not None:
        curves.interleave()
        handles = [curves.handles.get(label, handle) for label, handle in entries.items()]
        labels = [curves.legend_label(label) for label in labels]
        for handle, label in curves.extra:
            handles.append(handle if handle is not None else Line2D([], [], linestyle="none"))
            labels.append(label)
    if labels:
        labels = [_wrap(label, wrap) for label in labels]
        # Columns enough for the legend to fit the figure's height (small font: 8.3 pt lines,
        # half a line between entries).
        height_pt = sum(1.2 * 8.3 * (label.count("\n") + 1) + 0.5 * 8.3 for label in labels)
        ncols = max(1, math.ceil(height_pt / (0.92 * 72 * figure.get_figheight())))
        figure.legend(
            handles,
            labels,
            loc="outside right center",
            fontsize="small",
            frameon=False,
            ncols=ncols,
        )


def _wrap(text: str, width: int) -> str:
    """Fill each line of ``text`` to ``width``; lines after the first are indented."""
    first, *rest = text.split("\n")
    parts = [textwrap.fill(first, width, subsequent_indent="  ")]
    parts += [
        textwrap.fill(part, width, initial_indent="  ", subsequent_indent="  ") for part in rest
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------------------------
# coincident curves and counts
# --------------------------------------------------------------------------------------------

DASH_LENGTH = 4.0
"""Length of one dash segment, in line widths, where overlapping curves are interleaved."""

OVERLAP_IN = 0.04
"""Two lines of a panel overlap on the page when they are drawn at the same x values and lie
within this distance (inches, at the panel's nominal size) of each other at every point: they
are then interleaved, whatever :data:`COINCIDENCE_RTOL` says (on a log axis spanning several
decades, curves a few percent apart look like one)."""


@dataclass
class _Curve:
    """One curve of a panel, as drawn: its legend label, the short name that notes call it
    by, its points (sorted along ``grid``), and the line to interleave when it overlaps another
    (None: left as drawn). ``grid`` is the axis of the points both curves must share to be
    compared: ``"x"`` for a curve against the swept parameter, ``"y"`` for a CDF (compared as
    quantiles: the errors at the same fractions of trials)."""

    label: str
    name: str
    x: np.ndarray
    y: np.ndarray
    line: Line2D | None = None
    grid: str = "x"

    def grid_and_values(self) -> tuple[np.ndarray, np.ndarray]:
        x, y = np.asarray(self.x, dtype=float), np.asarray(self.y, dtype=float)
        return (x, y) if self.grid == "x" else (y, x)


def _shared_grid(first: _Curve, second: _Curve) -> tuple[np.ndarray, np.ndarray] | None:
    """The values of both curves where both are drawn, if they share the grid and the points
    drawn (else None)."""
    grid1, values1 = first.grid_and_values()
    grid2, values2 = second.grid_and_values()
    if first.grid != second.grid or grid1.shape != grid2.shape:
        return None
    if not np.allclose(grid1, grid2, rtol=1e-9, atol=0.0, equal_nan=True):
        return None
    drawn = np.isfinite(values1)
    if not drawn.any() or not np.array_equal(drawn, np.isfinite(values2)):
        return None
    return values1[drawn], values2[drawn]


def _coincide(first: _Curve, second: _Curve, rtol: float = COINCIDENCE_RTOL) -> bool:
    """Drawn at the same x values and within ``rtol`` of each other at every one of them."""
    shared = _shared_grid(first, second)
    if shared is None:
        return False
    a, b = shared
    return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(a), np.abs(b))))


def _overlap(ax: Axes, first: _Curve, second: _Curve, size_in: tuple[float, float]) -> bool:
    """Drawn at the same x values and within :data:`OVERLAP_IN` on the page at every one."""
    if _shared_grid(first, second) is None:
        return False
    to_axes = ax.transScale + ax.transLimits
    with np.errstate(invalid="ignore", divide="ignore"):
        a = to_axes.transform(np.column_stack([first.x, first.y]).astype(float))
        b = to_axes.transform(np.column_stack([second.x, second.y]).astype(float))
    column = 1 if first.grid == "x" else 0
    gap = np.abs(a[:, column] - b[:, column]) * size_in[column]
    gap = gap[np.isfinite(a[:, column]) | np.isfinite(b[:, column])]
    return bool(gap.size) and bool(np.all(gap <= OVERLAP_IN))


def _proxy(line: Line2D) -> Line2D:
    """A legend handle in the style ``line`` has before it is interleaved."""
    return Line2D(
        [],
        [],
        color=line.get_color(),
        linestyle=line.get_linestyle(),
        linewidth=line.get_linewidth(),
        marker=line.get_marker(),
        markersize=line.get_markersize(),
        markerfacecolor=line.get_markerfacecolor(),
        markeredgecolor=line.get_markeredgecolor(),
    )


def _has_marker(line: Line2D) -> bool:
    return line.get_marker() not in (None, "", " ", "None", "none")


def _is_solid(line: Line2D | None) -> bool:
    return line is not None and line.get_linestyle() in ("-", "solid")


@dataclass
class _Curves:
    """The curves of a figure, panel by panel: which coincide, and what the legend says.

    :meth:`panel` records a panel's curves and the pairs that coincide in the data
    (:func:`_coincide`, :data:`COINCIDENCE_RTOL`): :meth:`legend_label` names them in the
    legend. :meth:`interleave`, once the axes limits are final, interleaves each group of
    solid lines that overlap on the page (:func:`_overlap`): the first stays solid, the k-th
    of n draws only every n-th dash segment, shifted by k segments, and every n-th marker from
    the k-th on, so that every colour and marker of the group stays visible along the shared
    path.
    """

    partners: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    drawn: dict[str, list[str]] = field(default_factory=dict)
    seen: set[str] = field(default_factory=set)
    handles: dict[str, Artist] = field(default_factory=dict)
    extra: list[tuple[Artist | None, str]] = field(default_factory=list)
    panels: list[tuple[Axes, list[_Curve]]] = field(default_factory=list)
    notes: bool = True

    def panel(self, title: str, curves: Sequence[_Curve], ax: Axes | None = None) -> None:
        """Record the curves of one panel and the pairs that coincide in the data."""
        for curve in curves:
            self.seen.add(curve.label)
            if np.isfinite(np.asarray(curve.y, dtype=float)).any():
                self.drawn.setdefault(curve.label, []).append(title)
        for i, first in enumerate(curves):
            for second in curves[i + 1 :]:
                if not self.notes or first.label == second.label:
                    continue
                if not _coincide(first, second):
                    continue
                self.partners.setdefault(first.label, {}).setdefault(title, []).append(second.name)
                self.partners.setdefault(second.label, {}).setdefault(title, []).append(first.name)
        if ax is not None:
            self.panels.append((ax, list(curves)))

    def interleave(self) -> None:
        """Interleave the solid lines that overlap on the page, panel by panel (once the
        axes limits are final: :func:`_legend` calls it)."""
        for ax, curves in self.panels:
            lines = [c for c in curves if _is_solid(c.line)]
            box = ax.get_position()
            size_in = (box.width * ax.figure.get_figwidth(), box.height * ax.figure.get_figheight())
            parent = list(range(len(lines)))

            def root(i: int, parent: list[int] = parent) -> int:
                while parent[i] != i:
                    i = parent[i]
                return i

            for i, first in enumerate(lines):
                for j in range(i + 1, len(lines)):
                    if first.label != lines[j].label and _overlap(ax, first, lines[j], size_in):
                        parent[root(j)] = root(i)
            groups: dict[int, list[_Curve]] = {}
            for i, curve in enumerate(lines):
                groups.setdefault(root(i), []).append(curve)
            for together in groups.values():
                if len(together) > 1:
                    self._interleave(together)
        self.panels.clear()

    def _interleave(self, together: Sequence[_Curve]) -> None:
        n = len(together)
        for k, curve in enumerate(together):
            line = curve.line
            assert line is not None
            self.handles.setdefault(curve.label, _proxy(line))
            if _has_marker(line) and len(curve.x) >= n:
                line.set_markevery((k, n))
            if k:
                line.set_linestyle(((n - k) * DASH_LENGTH, (DASH_LENGTH, (n - 1) * DASH_LENGTH)))

    def legend_label(self, label: str) -> str:
        """``label``, with "(no point drawn)" or "(coincides with …)" where it applies.

        The panels are named when the partners differ between panels, or when the curve does
        not coincide in every panel where it is drawn.
        """
        if label in self.seen and label not in self.drawn:
            return f"{label}\n(no point drawn)"
        notes = self.partners.get(label)
        if not notes:
            return label
        by_partners: dict[tuple[str, ...], list[str]] = {}
        for title, names in notes.items():
            by_partners.setdefault(tuple(dict.fromkeys(names)), []).append(title)
        if len(by_partners) == 1:
            names, titles = next(iter(by_partners.items()))
            if set(titles) >= set(self.drawn.get(label, [])):
                return f"{label}\n({COINCIDENCE_NOTE} {', '.join(names)})"
        where = "; ".join(
            f"{', '.join(names)} in {', '.join(titles)}" for names, titles in by_partners.items()
        )
        return f"{label}\n({COINCIDENCE_NOTE} {where})"


def _counted(
    values: pd.Series | np.ndarray, counts: pd.Series | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``values`` as floats with NaN where ``counts`` is below :data:`MIN_COUNT_FOR_RATE`, and
    the mask of the finite values so left out."""
    shown = np.asarray(values, dtype=float).copy()
    few = np.asarray(counts, dtype=float) < MIN_COUNT_FOR_RATE
    left_out = few & np.isfinite(shown)
    shown[few] = np.nan
    return shown, left_out


def _left_out_note(n_left_out: int, what: str) -> str:
    """The legend entry counting the points not drawn (:data:`MIN_COUNT_FOR_RATE`)."""
    points = "point" if n_left_out == 1 else "points"
    return f"{n_left_out} {points} not drawn: fewer than {MIN_COUNT_FOR_RATE} {what}"


def _side_counts(rows: pd.DataFrame) -> pd.Series:
    """The wrong-side rate's count: ``n_side_judged`` (``n_successes`` in older summaries)."""
    return rows["n_side_judged"] if "n_side_judged" in rows else rows["n_successes"]


# --------------------------------------------------------------------------------------------
# log axes
# --------------------------------------------------------------------------------------------


class SparseLogLocator(Locator):
    """Major ticks of a log axis: few, and never crowded.

    Decades when three or more fall in the view, thinned to every second, third, … one
    beyond :data:`MAX_LOG_LABELS`; else 1-2-5 steps when they give at most that many; else
    the decades in view; else 1-2-5 or 1…9 mantissas, thinned; else a few linear steps. An
    axis so gets at least two labelled ticks, and no more than :data:`MAX_LOG_LABELS`.
    """

    def __init__(self, max_ticks: int = MAX_LOG_LABELS) -> None:
        self.max_ticks = max_ticks

    def __call__(self) -> np.ndarray:
        vmin, vmax = self.axis.get_view_interval()
        return self.tick_values(vmin, vmax)

    def tick_values(self, vmin: float, vmax: float) -> np.ndarray:
        vmin, vmax = sorted((float(vmin), float(vmax)))
        if not np.isfinite(vmax) or vmax <= 0:
            return np.array([])
        if not np.isfinite(vmin) or vmin <= 0:
            vmin = vmax * 1e-6
        low, high = math.floor(math.log10(vmin)), math.ceil(math.log10(vmax))

        def inside(mantissas: Sequence[float]) -> np.ndarray:
            ticks = np.array([m * 10.0**e for e in range(low, high + 1) for m in mantissas])
            return ticks[(ticks >= vmin * (1 - 1e-9)) & (ticks <= vmax * (1 + 1e-9))]

        decades = inside((1.0,))
        if decades.size >= 3:
            step = -(-decades.size // self.max_ticks)
            exponents = np.round(np.log10(decades)).astype(int)
            return decades[exponents % step == 0]
        steps = inside((1.0, 2.0, 5.0))
        if 2 <= steps.size <= self.max_ticks:
            return steps
        if decades.size == 2:
            return decades
        for ticks in (steps, inside(tuple(float(m) for m in range(1, 10)))):
            if ticks.size >= 2:
                return ticks[:: -(-ticks.size // self.max_ticks)]
        linear = MaxNLocator(nbins=3, steps=[1, 2, 2.5, 5, 10]).tick_values(vmin, vmax)
        return linear[(linear >= vmin) & (linear <= vmax) & (linear > 0)]


class PlainLogFormatter(Formatter):
    """Labels of a log axis: plain numbers (``20``, ``0.3``) when every labelled tick lies in
    :data:`PLAIN_NUMBER_RANGE`, else powers of ten (``10⁻⁶``, ``2×10⁵``)."""

    shown: Sequence[float] = ()

    def set_locs(self, locs: Sequence[float]) -> None:
        """Keep the ticks being labelled: plain numbers or powers of ten depends on them all."""
        super().set_locs(locs)
        self.shown = [float(v) for v in locs]

    def __call__(self, x: float, pos: int | None = None) -> str:
        if not np.isfinite(x) or x <= 0:
            return ""
        shown = [v for v in self.shown if v > 0] or [x]
        low, high = PLAIN_NUMBER_RANGE
        if all(low <= v < high for v in shown):
            return f"{x:g}"
        exponent = math.floor(math.log10(x) + 1e-9)
        mantissa = x / 10.0**exponent
        if abs(mantissa - round(mantissa)) < 1e-6:
            mantissa = round(mantissa)
        if mantissa == 1:
            return f"$10^{{{exponent}}}$"
        return f"${mantissa:g}\\times10^{{{exponent}}}$"


def plain_log_ticks(axis: Axis) -> None:
    """Label a log axis sparsely: :class:`SparseLogLocator` and :class:`PlainLogFormatter`
    for the major ticks, unlabelled minor ticks (every mantissa 2…9 where they fit)."""
    axis.set_major_locator(SparseLogLocator())
    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_locator(LogLocator(base=10.0, subs="auto", numticks=12))
    axis.set_minor_formatter(NullFormatter())


def _grid(ax: Axes) -> None:
    """Major grid lines, and faint minor ones (log axes)."""
    ax.grid(True, which="major", alpha=0.3)
    ax.grid(True, which="minor", alpha=0.08)


def _set_x_scale(ax: Axes, column: str, values: np.ndarray) -> None:
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
) -> list[_Curve]:
    """Solid black √CRLB for ToA+Doppler; dashed estimator-coloured bounds that differ.

    Returns the curves drawn (never interleaved: the black bound lies under the estimators,
    wider than their lines, and stays visible at their edges).
    """
    curves: list[_Curve] = []
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
        curves.append(
            _Curve("√CRLB, ToA+Doppler", "√CRLB", point_rows[x].to_numpy(float), reference)
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
            label = f"√CRLB, {estimator}'s modalities"
            ax.plot(own[x], bound, color="black", linewidth=2.4, label=label, zorder=1.9)
            curves.append(_Curve(label, "√CRLB", own[x].to_numpy(float), bound))
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
        curves.append(_Curve(label, f"√CRLB of {who}", x_values.to_numpy(float), bound))
    return curves


def _same_bound(first: np.ndarray, second: np.ndarray) -> bool:
    return len(first) == len(second) and bool(np.allclose(first, second, rtol=1e-3, equal_nan=True))


def _default_colors(
    frame: pd.DataFrame, colors: Mapping[str, tuple[float, ...]] | None
) -> Mapping[str, tuple[float, ...]]:
    return colors if colors is not None else estimator_colors(frame["estimator"].unique())


def _estimator_line(
    ax: Axes,
    x_values: pd.Series | np.ndarray,
    y_values: pd.Series | np.ndarray,
    estimator: str,
    colors: Mapping[str, tuple[float, ...]],
    **style: object,
) -> _Curve:
    """Draw one estimator's line in its colour and marker (:func:`estimator_markers` of the
    colour mapping's order); return it as a curve for :class:`_Curves`."""
    markers = estimator_markers(colors)
    label = estimator_label(estimator)
    style = {"marker": markers.get(estimator, "o"), "markersize": 4.0, **style}
    (line,) = ax.plot(x_values, y_values, color=colors[estimator], label=label, **style)
    x = np.asarray(x_values, dtype=float)
    return _Curve(label, estimator, x, np.asarray(y_values, dtype=float), line)


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
    curves = _Curves()
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values(x)
            color = colors[str(estimator)]
            drawn.append(_estimator_line(ax, own[x], own[value], str(estimator), colors))
            ax.fill_between(own[x], own[low], own[high], color=color, alpha=0.2, linewidth=0)
        drawn += _draw_bounds(ax, panel, _point_bounds(panel, points, x, columns), x, colors)
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        _set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        _grid(ax)
    what = (
        "Side-resolved RMSE (nearest candidate, MATH §7)"
        if side_resolved
        else "RMSE of the returned position"
    )
    figure.suptitle(f"{what}; shaded: 95% bootstrap interval", fontsize="medium")
    _legend(figure, axes, curves)
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
    colors = _default_colors(summary, colors)
    columns = parameter_columns(summary)
    x = x or sweep_axis(summary) or "snr_db"
    rows = last_frame(summary, columns)
    others = [c for c in varying_columns(rows, columns) if c != x]
    panels = _panels(rows, others)
    figure, axes = _figure_grid(len(panels), sharey=True)
    curves = _Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn, n_left_out = _plot_wrong_side(ax, panel, x, colors)
        curves.panel(title, drawn, ax)
        left_out += n_left_out
        _set_x_scale(ax, x, panel[x].to_numpy(float))
        ax.set_title(title, fontsize="medium")
    if left_out:
        curves.extra.append((None, _left_out_note(left_out, "estimates off the track")))
    figure.suptitle(
        "Estimates on the wrong side of the last frame's track; shaded: 95% Wilson interval",
        fontsize="medium",
    )
    _legend(figure, axes, curves)
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
    colors = _default_colors(summary, colors)
    panels = _frame_panels(summary, n_points)
    figure, axes = _figure_grid(len(panels), sharey=True)
    curves = _Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn, n_left_out = _plot_wrong_side(ax, panel, "frame", colors)
        curves.panel(title, drawn, ax)
        left_out += n_left_out
        ax.set_xlabel("last frame used (index)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize="medium")
    if left_out:
        curves.extra.append((None, _left_out_note(left_out, "estimates off the track")))
    figure.suptitle(
        "Wrong-side rate as frames accumulate; shaded: 95% Wilson interval", fontsize="medium"
    )
    _legend(figure, axes, curves)
    return figure


def _plot_wrong_side(
    ax: Axes, panel: pd.DataFrame, x: str, colors: Mapping[str, tuple[float, ...]]
) -> tuple[list[_Curve], int]:
    """One panel of wrong-side rate against ``x``, a line per estimator, 0.5 marked.

    Returns the curves and how many points were left out for their count
    (:data:`MIN_COUNT_FOR_RATE`).
    """
    curves = []
    left_out = 0
    for estimator, own in panel.groupby("estimator", sort=False):
        own = own.sort_values(x)
        counts = _side_counts(own)
        rate, few = _counted(own["wrong_side_rate"], counts)
        left_out += int(few.sum())
        low, high = wilson_interval(rate, counts)
        color = colors[str(estimator)]
        curves.append(_estimator_line(ax, own[x], rate, str(estimator), colors))
        ax.fill_between(own[x], low, high, color=color, alpha=0.15, linewidth=0)
    ax.axhline(0.5, color="grey", linestyle=":", linewidth=1, label="0.5 (a coin toss)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("wrong-side rate")
    ax.grid(True, alpha=0.3)
    return curves, left_out


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
    easiest, a middle and the hardest geometry. Scenarios in :func:`scenario_order`.
    """
    keys = trials.groupby(["scenario", "point"], sort=False).agg(
        **{c: (c, "first") for c in columns}, bound=("crlb_rmse_m", "mean")
    )
    keys = keys.reset_index()
    keys["scenario_rank"] = _scenario_rank(keys, scenario_order(trials))
    keys = keys.sort_values(["scenario_rank", x or "bound", "point"], kind="stable")
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
    colors = _default_colors(trials, colors)
    latest = trials.groupby(["scenario", "point"], sort=False)["frame"].transform("max")
    rows = trials[trials["frame"] == latest]
    columns = ["snr_db", *swept_columns_of(trials)]
    varying = varying_columns(rows, columns)
    chosen = _chosen_points(rows, x, n_points, columns)
    figure, axes = _figure_grid(len(chosen), ncols=min(len(chosen), n_points), sharey=True)
    curves = _Curves(notes=False)  # CDFs of one estimator family coincide by the dozen
    dashed = False
    for ax, (_, where) in zip(axes, chosen.iterrows(), strict=True):
        at = rows[(rows["scenario"] == where["scenario"]) & (rows["point"] == where["point"])]
        values = {c: float(where[c]) for c in (varying or ["snr_db"])}
        title = _panel_title(str(where["scenario"]), values)
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
                drawn.append(_Curve(label, name, errors, fraction, line, grid="y"))
        curves.panel(title, drawn, ax)
        ax.set_xscale("log")
        plain_log_ticks(ax.xaxis)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("distance error (m)")
        ax.set_ylabel("fraction of trials")
        ax.set_title(title, fontsize="medium")
        _grid(ax)
    figure.suptitle(
        "Distribution of the distance error (failed estimates count as infinite)", fontsize="medium"
    )
    if dashed:
        style = Line2D([], [], color="0.35", linestyle="--")
        curves.extra.append((style, "dashed: side-resolved error (nearest candidate, MATH §7)"))
    _legend(figure, axes, curves)
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
    plain_log_ticks(ax.xaxis)
    ax.set_xlabel("wall time per estimate (s)")
    ax.set_title(
        "Run time per estimate (median; whiskers: 5th to 95th percentile)", fontsize="medium"
    )
    ax.grid(True, axis="x", which="major", alpha=0.3)
    ax.grid(True, axis="x", which="minor", alpha=0.08)
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


def _frame_panels(
    summary: pd.DataFrame, n_points: int, order: Sequence[str] | None = None
) -> list[tuple[str, pd.DataFrame]]:
    """One panel per scenario and sweep point (up to ``n_points`` per scenario: lowest, middle,
    highest), scenarios in ``order`` (default :func:`scenario_order` of ``summary``)."""
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    keys = summary[["scenario", *columns]].drop_duplicates()
    keys = keys.assign(scenario_rank=_scenario_rank(keys, order or scenario_order(summary)))
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
    curves = _Curves()
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for estimator, own in panel.groupby("estimator", sort=False):
            own = own.sort_values("frame")
            color = colors[str(estimator)]
            drawn.append(_estimator_line(ax, own["frame"], own["rmse_m"], str(estimator), colors))
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
                    _Curve(
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
        drawn += _draw_bounds(ax, panel, bounds, "frame", colors)
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        _grid(ax)
    figure.suptitle("RMSE as frames accumulate, with the accumulated √CRLB", fontsize="medium")
    _legend(figure, axes, curves)
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
    curve shows covariance consistency rather than the mirror ambiguity. A consistent covariance gives a mean NEES of 2 (two dof), inside the 95% band of
    :func:`comparison.metrics.nees_band` (shaded grey: the widest band among the estimators
    of the panel, from their smallest count). A mean of fewer than :data:`MIN_COUNT_FOR_RATE`
    NEES values (``n_nees``) is not drawn (:data:`NEES_COUNT_NOTE`), and gives no band.
    """
    with_nees = summary[summary["n_nees"] > 0]
    if with_nees.empty:
        raise ValueError("summary: no estimator reports a covariance (n_nees is 0 everywhere)")
    colors = _default_colors(summary, colors)
    panels = _frame_panels(with_nees, n_points, scenario_order(summary))
    figure, axes = _figure_grid(len(panels))
    curves = _Curves()
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
            nees, few = _counted(own["nees_side_resolved_mean"], own["n_nees"])
            left_out += int(few.sum())
            drawn.append(_estimator_line(ax, own["frame"], nees, str(estimator), colors))
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
        _grid(ax)
    if left_out:
        curves.extra.append((None, _left_out_note(left_out, "NEES values")))
    figure.suptitle(
        "Covariance consistency: mean NEES (2 dof) as frames accumulate", fontsize="medium"
    )
    _legend(figure, axes, curves)
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
    """One panel per (scenario, sweep point, estimator): scenarios in :func:`scenario_order`,
    then sweep points ascending, then estimators in their order of first appearance."""
    columns = parameter_columns(summary)
    varying = varying_columns(summary, columns)
    rank = _scenario_rank(summary)
    estimators = {name: i for i, name in enumerate(dict.fromkeys(summary["estimator"]))}
    keyed = []
    for key, rows in summary.groupby(["scenario", *varying, "estimator"], sort=False):
        key = key if isinstance(key, tuple) else (key,)
        values = dict(zip(varying, key[1:-1], strict=True))
        order = (int(rank.loc[rows.index[0]]), *key[1:-1], estimators[key[-1]])
        keyed.append((order, f"{_panel_title(str(key[0]), values)}: {key[-1]}", rows))
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
    figure, axes = _figure_grid(len(panels), ncols=min(max(n_estimators, 1), 3))
    curves = _Curves()
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
            drawn.append(_Curve(label, f"{planner}", frames, own[value].to_numpy(float), line))
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
            drawn.append(_Curve(label, f"{planner}'s √CRLB", frames, bound))
        curves.panel(title, drawn, ax)
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("last frame used (index)")
        ax.set_ylabel("side-resolved RMSE (m)" if side_resolved else "RMSE (m)")
        ax.set_title(title, fontsize="medium")
        ax.xaxis.get_major_locator().set_params(integer=True)
        _grid(ax)
    what = "Side-resolved RMSE (MATH §7)" if side_resolved else "RMSE of the returned position"
    figure.suptitle(
        f"Closed loop: {what} per planner as frames accumulate; dashed: RMS over trials of "
        "√CRLB of each flown trajectory",
        fontsize="medium",
    )
    _legend(figure, axes, curves)
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
    figure, axes = _figure_grid(len(panels), sharey=True, ncols=min(max(n_estimators, 1), 3))
    curves = _Curves()
    left_out = 0
    for ax, (title, panel) in zip(axes, panels, strict=True):
        drawn = []
        for planner, own in panel.groupby("planner", sort=False):
            own = own.sort_values("frame")
            counts = _side_counts(own)
            rate, few = _counted(own["wrong_side_rate"], counts)
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
                _Curve(str(planner), str(planner), own["frame"].to_numpy(float), rate, line)
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
        curves.extra.append((None, _left_out_note(left_out, "estimates off the track")))
    _legend(figure, axes, curves)
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
