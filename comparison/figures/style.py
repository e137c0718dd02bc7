"""How every figure looks: labels, colours and markers, the grid of panels, the legend,
log-axis ticks, grid lines, and saving as PNG and SVG."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Sequence
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import Formatter, Locator, LogLocator, MaxNLocator, NullFormatter

from comparison.figures.curves import Curves
from comparison.run_folder import atomic_file

ESTIMATOR_LABELS: dict[str, str] = {}
"""Legend labels that say more than the registry name (none: legends stay short, and the
captions and docs say what each estimator is)."""

PANEL_SIZE_IN = (4.6, 3.4)
"""Width and height of one panel (inches)."""

LEGEND_WIDTH_IN = 3.4
"""Width added on the right of a figure for its legend (inches)."""

ESTIMATOR_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")
"""Marker of the i-th estimator of the colour mapping (:func:`estimator_markers`)."""

MAX_LOG_LABELS = 6
"""Most labelled ticks on a log axis (decades are thinned to every second, third, … one)."""

MAX_MINOR_TICK_DECADES = 3.0
"""Most decades a log axis spans and still has its minor ticks (and their faint grid lines):
over more, eight unlabelled ticks a decade are a grey wash, and each costs a figure's drawing
as much as a labelled one (the error CDFs' panels span up to 12 decades)."""

PLAIN_NUMBER_RANGE = (1e-3, 1e5)
"""Log-axis labels are plain numbers when every labelled tick lies in this range, else powers
of ten."""


def estimator_label(name: str) -> str:
    """The legend label of an estimator (:data:`ESTIMATOR_LABELS`, else its name)."""
    return ESTIMATOR_LABELS.get(name, name)


OKABE_ITO = ("#E69F00", "#56B4E9", "#009E73", "#0072B2", "#D55E00", "#CC79A7", "#999999", "#F0E442")
"""Okabe and Ito's colours (Color Universal Design, 2008) without black, which the bound
lines use, and with their yellow last (faint on white): told apart by colour-blind readers;
with :data:`ESTIMATOR_MARKERS`, in greyscale too."""


def estimator_colors(names: Iterable[str]) -> dict[str, tuple[float, float, float, float]]:
    """One colour per estimator, in the given order (:data:`OKABE_ITO`, then tab20 beyond
    eight)."""
    unique = list(dict.fromkeys(names))
    if len(unique) <= len(OKABE_ITO):
        return {name: mpl.colors.to_rgba(OKABE_ITO[i]) for i, name in enumerate(unique)}
    palette = mpl.colormaps["tab20"]
    return {name: palette(i % palette.N) for i, name in enumerate(unique)}


def estimator_markers(names: Iterable[str]) -> dict[str, str]:
    """One marker per estimator, in the given order (:data:`ESTIMATOR_MARKERS`).

    The figures take the order of their colour mapping, so that an estimator keeps its colour
    and its marker in every figure given the same mapping.
    """
    unique = list(dict.fromkeys(str(n) for n in names))
    return {name: ESTIMATOR_MARKERS[i % len(ESTIMATOR_MARKERS)] for i, name in enumerate(unique)}


SVG_HASH_SALT = "emitterbench"
"""Salt of the ids in an SVG file (matplotlib's ``svg.hashsalt``): fixed, so that the same
figure gives the same bytes on every report (the default is a random salt per file)."""


def save_figure(figure: Figure, directory: str | Path, stem: str, *, dpi: int = 150) -> list[Path]:
    """Write ``figure`` as ``<stem>.png`` (``dpi``) and ``<stem>.svg``; return both paths.

    The SVG is vector graphics, with any rasterized artist (a dense heatmap) at ``dpi`` too.
    Both files are reproducible: the same figure gives the same bytes (the SVG without a date,
    its ids salted by :data:`SVG_HASH_SALT`; the PNG carries no date, only matplotlib's
    version). Each file is replaced whole (:func:`comparison.run_folder.atomic_file`): an
    interrupted write leaves the old file and no temporary one; a symbolic link in the place
    of either is refused and its target left alone."""
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{stem}.png", folder / f"{stem}.svg"]
    with atomic_file(paths[0], binary=True) as handle:  # whole or not at all, never a link
        figure.savefig(handle, dpi=dpi, format="png")
    layout = figure.get_layout_engine()
    figure.set_layout_engine("none")  # keep the layout just computed: same positions in SVG
    try:
        with mpl.rc_context({"svg.hashsalt": SVG_HASH_SALT}):
            with atomic_file(paths[1], binary=True) as handle:
                figure.savefig(handle, dpi=dpi, format="svg", metadata={"Date": None})
    finally:
        figure.set_layout_engine(layout)
    return paths


# --------------------------------------------------------------------------------------------
# panels and the legend
# --------------------------------------------------------------------------------------------


def figure_grid(
    n_panels: int, *, legend: bool = True, sharey: bool = False, ncols: int | None = None
) -> tuple[Figure, list[Axes]]:
    """A figure of ``n_panels`` axes, ``ncols`` (default up to three) to a row, with room on
    the right for the legend; the axes left over in the last row are hidden."""
    ncols = ncols or min(n_panels, 3)
    nrows = -(-n_panels // ncols)
    width = PANEL_SIZE_IN[0] * ncols + (LEGEND_WIDTH_IN if legend else 0.0)
    figure = Figure(figsize=(width, PANEL_SIZE_IN[1] * nrows + 0.6), layout="constrained")
    axes = figure.subplots(nrows, ncols, squeeze=False, sharey=sharey).ravel()
    for extra in axes[n_panels:]:
        extra.set_visible(False)
    return figure, list(axes[:n_panels])


def figure_legend(
    figure: Figure, axes: Sequence[Axes], curves: Curves | None = None, *, wrap: int = 44
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


class SparseMinorLocator(LogLocator):
    """Minor ticks of a log axis: matplotlib's (every mantissa 2…9 where they fit) on a view of
    at most :data:`MAX_MINOR_TICK_DECADES` decades, none on a wider one."""

    def __init__(self) -> None:
        super().__init__(base=10.0, subs="auto", numticks=12)

    def tick_values(self, vmin: float, vmax: float) -> np.ndarray:
        low, high = sorted((float(vmin), float(vmax)))
        if low > 0 and np.isfinite(high) and math.log10(high / low) > MAX_MINOR_TICK_DECADES:
            return np.array([])
        return super().tick_values(vmin, vmax)


def plain_log_ticks(axis: Axis) -> None:
    """Label a log axis sparsely: :class:`SparseLogLocator` and :class:`PlainLogFormatter`
    for the major ticks, unlabelled minor ticks on a view of a few decades
    (:class:`SparseMinorLocator`)."""
    axis.set_major_locator(SparseLogLocator())
    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_locator(SparseMinorLocator())
    axis.set_minor_formatter(NullFormatter())


def grid_lines(ax: Axes) -> None:
    """Major grid lines, and faint minor ones (log axes)."""
    ax.grid(True, which="major", alpha=0.3)
    ax.grid(True, which="minor", alpha=0.08)
