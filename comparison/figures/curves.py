"""Curves that coincide or overlap, and rates drawn only where enough values back them.

A figure records each panel's curves in a :class:`Curves`; the legend then names the curves
that agree within :data:`COINCIDENCE_RTOL` and interleaves those that overlap on the page.
A rate or a mean backed by fewer than :data:`MIN_COUNT_FOR_RATE` values is not drawn
(:func:`mask_few`), and the legend counts the points so left out (:func:`left_out_note`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.lines import Line2D

COINCIDENCE_RTOL = 0.02
"""Two curves of a panel coincide when they are drawn at the same x values and agree there
within this relative tolerance, ``|a − b| ≤ COINCIDENCE_RTOL · max(|a|, |b|)``, at every
point."""

COINCIDENCE_NOTE = "coincides with"
"""The legend note of a curve hidden by another: ``label (coincides with X, Y)``."""

DASH_LENGTH = 4.0
"""Length of one dash segment, in line widths, where overlapping curves are interleaved."""

OVERLAP_IN = 0.04
"""Two lines of a panel overlap on the page when they are drawn at the same x values and lie
within this distance (inches, at the panel's nominal size) of each other at every point: they
are then interleaved, whatever :data:`COINCIDENCE_RTOL` says (on a log axis spanning several
decades, curves a few percent apart look like one)."""


@dataclass
class Curve:
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


def _shared_grid(first: Curve, second: Curve) -> tuple[np.ndarray, np.ndarray] | None:
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


def _coincide(first: Curve, second: Curve, rtol: float = COINCIDENCE_RTOL) -> bool:
    """Drawn at the same x values and within ``rtol`` of each other at every one of them."""
    shared = _shared_grid(first, second)
    if shared is None:
        return False
    a, b = shared
    return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(a), np.abs(b))))


def _overlap(ax: Axes, first: Curve, second: Curve, size_in: tuple[float, float]) -> bool:
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
class Curves:
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
    panels: list[tuple[Axes, list[Curve]]] = field(default_factory=list)
    notes: bool = True

    def panel(self, title: str, curves: Sequence[Curve], ax: Axes | None = None) -> None:
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
        axes limits are final: :func:`figure_legend` calls it)."""
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
            groups: dict[int, list[Curve]] = {}
            for i, curve in enumerate(lines):
                groups.setdefault(root(i), []).append(curve)
            for together in groups.values():
                if len(together) > 1:
                    self._interleave(together)
        self.panels.clear()

    def _interleave(self, together: Sequence[Curve]) -> None:
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

        A coincidence is noted only when the curve coincides with the same curves in every
        panel where it is drawn: a legend serves every panel, and a note that holds in some of
        them only would mislead in the others (the curves stay interleaved, so each remains
        visible where they overlap).
        """
        if label in self.seen and label not in self.drawn:
            return f"{label}\n(no point drawn)"
        notes = self.partners.get(label)
        if not notes:
            return label
        partners = {tuple(dict.fromkeys(names)) for names in notes.values()}
        if len(partners) == 1 and set(notes) >= set(self.drawn.get(label, [])):
            return f"{label}\n({COINCIDENCE_NOTE} {', '.join(next(iter(partners)))})"
        return label


# --------------------------------------------------------------------------------------------
# counts
# --------------------------------------------------------------------------------------------


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


def mask_few(
    values: pd.Series | np.ndarray, counts: pd.Series | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``values`` as floats with NaN where ``counts`` is below :data:`MIN_COUNT_FOR_RATE`, and
    the mask of the finite values so left out."""
    shown = np.asarray(values, dtype=float).copy()
    few = np.asarray(counts, dtype=float) < MIN_COUNT_FOR_RATE
    left_out = few & np.isfinite(shown)
    shown[few] = np.nan
    return shown, left_out


def left_out_note(n_left_out: int, what: str) -> str:
    """The legend entry counting the points not drawn (:data:`MIN_COUNT_FOR_RATE`)."""
    points = "point" if n_left_out == 1 else "points"
    return f"{n_left_out} {points} not drawn: fewer than {MIN_COUNT_FOR_RATE} {what}"


def side_counts(rows: pd.DataFrame) -> pd.Series:
    """The wrong-side rate's count: ``n_side_judged`` (``n_successes`` in older summaries)."""
    return rows["n_side_judged"] if "n_side_judged" in rows else rows["n_successes"]


def wilson_interval(rate: pd.Series, n: pd.Series, z: float = 1.96) -> tuple[np.ndarray, ...]:
    """Wilson score interval of a binomial proportion (NaN where ``n`` is 0)."""
    p = np.asarray(rate, dtype=float)
    count = np.asarray(n, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        centre = (p + z**2 / (2 * count)) / (1 + z**2 / count)
        half = z * np.sqrt(p * (1 - p) / count + z**2 / (4 * count**2)) / (1 + z**2 / count)
    return centre - half, centre + half
