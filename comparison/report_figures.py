"""The figures of a report: which apply to a run, in what order, each with its caption.

:func:`figure_plans` picks them from the summary (an SNR or other sweep, an emitter grid,
per-frame rows, a closed loop), each with the call of :mod:`comparison.figures` that draws
it; :func:`report_figures` draws them. :func:`write_figures` draws and writes each as
``figures/<stem>.png`` and ``.svg`` (:func:`comparison.figures.save_figure`), one process per
CPU when there are several figures (:func:`figure_processes`); the report shows each with its
caption.

Parallel figures
    Matplotlib draws a report's figures in Python, mostly their axes, ticks and text
    (paper-fig2's ten files took 5-9 s in one process), so :func:`write_figures` forks worker
    processes, which inherit the data, and each draws and writes whole figures; only the
    figure's index goes to a worker and its paths come back. The files are those of one
    process, byte for byte (the same calls, the SVG's salt and no date), each written whole.
    Forking needs ``os.fork`` and a process that runs no other thread (a dask client's, for
    instance): elsewhere the figures are drawn here, one after another.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from comparison import figures
from comparison.labels import LABEL_COLUMNS, has_bidi_controls, plain_label

FIGURE_STEMS: tuple[str, ...] = (
    "efficiency",
    "rmse",
    "rmse_side_resolved",
    "wrong_side",
    "geometry",
    "error_cdf",
    "runtime",
    "rmse_vs_frame",
    "wrong_side_vs_frame",
    "nees_vs_frame",
    "planner_rmse_vs_frame",
    "planner_rmse_side_resolved_vs_frame",
    "planner_wrong_side_vs_frame",
    "trajectories",
)
"""File names (without suffix) of every figure a report can write under ``figures/``."""


def figure_trial_columns(*, closed_loop: bool) -> tuple[str, ...]:
    """The trial columns the figures read (with the swept ones): those of the error CDF and
    the run time, and in a closed loop those of the trajectories."""
    columns = ("scenario", "point", "snr_db", "estimator", "frame", "success", "ambiguous")
    columns += ("error_m", "error_side_resolved_m", "crlb_rmse_m", "runtime_s")
    if closed_loop:
        columns += ("planner", "trial", "truth_x_m", "truth_y_m", "x_m", "y_m")
        columns += ("wrong_side", "cov_xx_m2", "cov_xy_m2", "cov_yy_m2")
    return columns


def _count_caption(note: str) -> str:
    """A note of :mod:`comparison.figures` on the points left out, as a caption's sentence."""
    return f"{note[0].upper()}{note[1:]} (the legend counts them)."


COUNT_CAPTION = _count_caption(figures.WRONG_SIDE_COUNT_NOTE)

OVERLAP_CAPTION = (
    "Curves that overlap alternate their dash segments and markers; the legend says which "
    f"agree within {100 * figures.COINCIDENCE_RTOL:g}% at every point of every panel "
    '("coincides with ..."); the efficiency figure separates them.'
)


FigurePlan = tuple[str, str, Callable[[], Figure]]
"""``(stem, caption, draw)``: a figure of the report, drawn by calling ``draw()``."""


def closed_loop_figures(
    summary: pd.DataFrame,
    trials: pd.DataFrame,
    flights: pd.DataFrame | None,
    *,
    estimator: str | None = None,
) -> list[FigurePlan]:
    """``(stem, caption, draw)`` of the closed-loop figures (planners against the frame)."""
    colors = figures.planner_colors(summary["planner"].unique())
    made = [
        (
            "planner_rmse_vs_frame",
            "RMSE of the returned position per planner as frames accumulate, one panel per "
            "scenario and estimator; shaded: 95% studentized-bootstrap interval; dashed, same "
            "colour: the root mean square over trials of √CRLB of each trial's flown "
            f"trajectory (MATH §8). {OVERLAP_CAPTION}",
            functools.partial(figures.planner_rmse_vs_frame_figure, summary, colors=colors),
        ),
        (
            "planner_rmse_side_resolved_vs_frame",
            "Side-resolved RMSE (nearest candidate to the truth, MATH §7) per planner; same "
            "layout. It shows what the estimates are worth once the mirror side is known.",
            functools.partial(
                figures.planner_rmse_vs_frame_figure, summary, side_resolved=True, colors=colors
            ),
        ),
        (
            "planner_wrong_side_vs_frame",
            "Wrong-side rate per planner as frames accumulate: the fraction of the successful "
            "estimates off the track plane that lie on the other side from the truth of the "
            "first track the estimator uses (frame 0 for a cumulative estimator, the current "
            "frame for a per-frame one); 0.5 is a coin toss, and a turn should drive it to 0 "
            f"(MATH §7). {COUNT_CAPTION}",
            functools.partial(figures.planner_wrong_side_vs_frame_figure, summary, colors=colors),
        ),
    ]
    if flights is not None and not flights.empty:
        label = estimator or str(summary["estimator"].iloc[0])
        made.append(
            (
                "trajectories",
                "The paper's Fig. 3 in closed loop: UAV paths of a few trials per planner "
                "(one colour per trial, the same trials in every panel), the emitter (star), "
                "the estimate after every frame of the estimator the figure names (dots); below "
                "each, a zoom on the truth with every trial's last estimate (grey) and, for the drawn trials, the last "
                "estimate (cross) with its 2σ covariance ellipse and the wrong-side count.",
                functools.partial(figures.trajectory_figure, flights, trials, estimator=label),
            )
        )
    return made


def efficiency_caption(x: str) -> str:
    """The caption of the efficiency figure against ``x``."""
    what = "the frame" if x == "frame" else figures.axis_label(x).split(":")[0]
    low, high = figures.EFFICIENCY_VIEW
    return (
        f"Efficiency RMSE/√CRLB against {what}, the quantity every verdict judges: side-resolved "
        "(the candidate nearest to the truth, MATH §7) for estimators that flag the mirror "
        "ambiguity, against the bound of the modalities and frames each uses (MATH §8). Bars: "
        "95% studentized-bootstrap intervals; estimators side by side at each point. Filled "
        "marker: the row attains the bound (its interval inside the shaded band, its bias "
        "negligible, MATH §16); open: any other verdict (the verdict table and summary.csv say "
        f"which and why). Linear axis around 1, at most {low:g} to {high:g}: a point beyond it "
        "is an open triangle on the edge, its value in summary.csv."
    )


def geometry_caption(summary: pd.DataFrame) -> str:
    """The caption of the emitter-grid heatmap, with its trials per cell and the width of a
    cell's interval: what the speckle from cell to cell is made of."""
    rows = summary[summary["frame"] == summary["frame"].max()]
    low, high = int(rows["n_trials"].min()), int(rows["n_trials"].max())
    trials = f"{low} trials" if low == high else f"{low} to {high} trials"
    with np.errstate(divide="ignore", invalid="ignore"):
        width = (rows["efficiency_judged_ci_high"] - rows["efficiency_judged_ci_low"]) / (
            2 * rows["efficiency_judged"]
        )
    width = width[np.isfinite(width)]
    noise = (
        f" Much of the speckle from cell to cell is Monte Carlo noise: the 95% interval of a "
        f"cell's efficiency is ±{100 * float(width.median()):.0f}% wide (median over cells)."
        if width.size
        else ""
    )
    return (
        f"Efficiency RMSE/√CRLB over the emitter grid, one cell per emitter position ({trials} "
        "each), on a logarithmic colour scale centred on 1: white where the bound is attained, "
        "blue below it, red above it, grey where a cell has no value (side-resolved RMSE for "
        "estimators that flag ambiguous answers, MATH §7). Black line and arrow: the UAV track "
        "where known. The first panel is the ToA+Doppler √CRLB in metres (MATH §8), with "
        f"labelled contours on grids of {figures.CONTOUR_CELLS} × {figures.CONTOUR_CELLS} "
        f"cells or more.{noise}"
    )


def _plain_labels(frame: pd.DataFrame | None) -> pd.DataFrame | None:
    """``frame`` with its label columns as a figure draws them (:func:`plain_label`); the
    frame itself when no label holds a direction control."""
    if frame is None:
        return None
    changed = {}
    for column in LABEL_COLUMNS:
        if column in frame.columns:
            shown = {
                label: plain_label(label)
                for label in pd.unique(frame[column])
                if isinstance(label, str) and has_bidi_controls(label)
            }
            if shown:
                changed[column] = frame[column].replace(shown)
    return frame.assign(**changed) if changed else frame


def report_figures(
    summary: pd.DataFrame,
    trials: pd.DataFrame,
    points: pd.DataFrame | None,
    tracks_m: Mapping[str, np.ndarray] | None,
    flights: pd.DataFrame | None = None,
    *,
    steering_estimator: str | None = None,
) -> list[tuple[str, str, Figure]]:
    """``(stem, caption, figure)`` of every figure of :func:`figure_plans`, drawn here."""
    plans = figure_plans(
        summary, trials, points, tracks_m, flights, steering_estimator=steering_estimator
    )
    return [(stem, caption, draw()) for stem, caption, draw in plans]


def figure_plans(
    summary: pd.DataFrame,
    trials: pd.DataFrame,
    points: pd.DataFrame | None,
    tracks_m: Mapping[str, np.ndarray] | None,
    flights: pd.DataFrame | None = None,
    *,
    steering_estimator: str | None = None,
) -> list[FigurePlan]:
    """``(stem, caption, draw)`` of every figure that applies to this sweep, undrawn.

    A closed-loop run (a ``planner`` column in the summary) gets :func:`closed_loop_figures`
    and the run-time figure: the open-loop figures would mix the planners. Labels are drawn
    as :func:`comparison.labels.plain_label` gives them (direction controls shown as U+FFFD);
    no caption holds a label.
    """
    summary, trials, flights = (_plain_labels(frame) for frame in (summary, trials, flights))
    if steering_estimator is not None:
        steering_estimator = plain_label(steering_estimator)
    if "planner" in summary.columns:
        made = closed_loop_figures(summary, trials, flights, estimator=steering_estimator)
        colors = figures.estimator_colors(summary["estimator"].unique())
        made.append(
            (
                "runtime",
                "Wall time of one estimate per estimator over the whole run, every planner and "
                "frame (median and 5th to 95th percentiles; log axis).",
                functools.partial(figures.runtime_figure, trials, colors=colors),
            )
        )
        return made
    colors = figures.estimator_colors(summary["estimator"].unique())
    x = figures.sweep_axis(summary)
    made: list[FigurePlan] = []
    along = x if x is not None and summary[x].nunique() > 1 else None
    if along is None and x is not None and figures.is_per_frame(summary):
        along = "frame"  # one sweep point flown over frames: the efficiency as they accumulate
    if along is not None:
        made.append(
            (
                "efficiency",
                efficiency_caption(along),
                functools.partial(figures.efficiency_figure, summary, x=along, colors=colors),
            )
        )
    if x is not None and summary[x].nunique() > 1:  # a one-point sweep has no curve to draw
        what = figures.axis_label(x).split(":")[0]
        made.append(
            (
                "rmse",
                f"RMSE of the returned position against {what}, one panel per scenario; "
                "shaded: 95% studentized-bootstrap interval; solid black: √CRLB for "
                "ToA+Doppler; dashed: the bound of an estimator that uses other modalities. "
                f"{OVERLAP_CAPTION}",
                functools.partial(figures.rmse_figure, summary, points=points, x=x, colors=colors),
            )
        )
        if not np.allclose(
            summary["rmse_side_resolved_m"], summary["rmse_m"], rtol=1e-12, equal_nan=True
        ):
            made.append(
                (
                    "rmse_side_resolved",
                    f"Side-resolved RMSE (nearest candidate to the truth, MATH §7) against "
                    f"{what}; same layout as the RMSE figure.",
                    functools.partial(
                        figures.side_resolved_rmse_figure,
                        summary,
                        points=points,
                        x=x,
                        colors=colors,
                    ),
                )
            )
        made.append(
            (
                "wrong_side",
                f"Wrong-side rate against {what}: the fraction of the successful estimates off "
                "the track plane that lie on the other side of the last frame's track from the "
                f"truth; 0.5 is a coin toss. {COUNT_CAPTION}",
                functools.partial(figures.wrong_side_figure, summary, x=x, colors=colors),
            )
        )
    if figures.is_geometry_sweep(summary):
        made.append(
            (
                "geometry",
                geometry_caption(summary),
                functools.partial(
                    figures.geometry_heatmap_figure, summary, points=points, tracks_m=tracks_m
                ),
            )
        )
    made.append(
        (
            "error_cdf",
            "Empirical CDF of the distance error at the lowest, middle and highest sweep "
            "points; failed estimates count as infinite errors. Dashed: side-resolved error.",
            functools.partial(figures.error_cdf_figure, trials, x=x, colors=colors),
        )
    )
    made.append(
        (
            "runtime",
            "Wall time of one estimate per estimator over the whole run (median and 5th to "
            "95th percentiles; log axis). Timings depend on the machine in the run section.",
            functools.partial(figures.runtime_figure, trials, colors=colors),
        )
    )
    if figures.is_per_frame(summary):
        made.append(
            (
                "rmse_vs_frame",
                "RMSE as frames accumulate, with the √CRLB accumulated over the same frames "
                f"(MATH §8); dotted: side-resolved RMSE where it differs. {OVERLAP_CAPTION}",
                functools.partial(
                    figures.rmse_vs_frame_figure, summary, points=points, colors=colors
                ),
            )
        )
        made.append(
            (
                "wrong_side_vs_frame",
                "Wrong-side rate as frames accumulate: the fraction of the successful estimates "
                "off the track plane that lie on the other side of the last frame's track from "
                "the truth; 0.5 is a coin toss, and a turn should drive it to 0 (MATH §7). "
                f"{COUNT_CAPTION}",
                functools.partial(figures.wrong_side_vs_frame_figure, summary, colors=colors),
            )
        )
        if (summary["n_nees"] > 0).any():
            made.append(
                (
                    "nees_vs_frame",
                    "Mean side-resolved NEES against the frame for estimators with a "
                    "covariance (each trial's nearest candidate against its own, mirrored "
                    "covariance); grey: the 95% chi-square band of the mean of n consistent "
                    "NEES values of 2 degrees of freedom (3 with the height estimated). "
                    f"{_count_caption(figures.NEES_COUNT_NOTE)}",
                    functools.partial(figures.nees_vs_frame_figure, summary, colors=colors),
                )
            )
    return made


# --------------------------------------------------------------------------------------------
# drawn and written, in parallel when it pays
# --------------------------------------------------------------------------------------------

FIGURE_COSTS: dict[str, float] = {
    "error_cdf": 2.1,
    "geometry": 2.0,
    "trajectories": 2.0,
    "rmse": 1.0,
    "rmse_side_resolved": 0.9,
    "planner_rmse_vs_frame": 0.9,
    "planner_rmse_side_resolved_vs_frame": 0.9,
    "efficiency": 0.6,
}
"""CPU seconds of a figure's drawing and files, measured on paper-fig2 (the geometry heatmap
and the trajectories guessed like the error CDF, the heaviest measured); 0.5 for any other.
:func:`write_figures` hands the figures to its workers heaviest first, so that no worker is
left with the heaviest while the others are done."""


def figure_cost(stem: str) -> float:
    """The expected cost of figure ``stem`` (:data:`FIGURE_COSTS`)."""
    return FIGURE_COSTS.get(stem, 0.5)


_PLANS: list[FigurePlan] = []
"""The plans a forked worker of :func:`write_figures` draws from, by index (set before the
workers are forked, so that they inherit it and no data is pickled)."""


def figure_processes(n_figures: int) -> int:
    """Worker processes for ``n_figures`` figures: one per CPU this process may use, at most
    one per figure; 1 (draw here) for a single figure, a single CPU, no ``os.fork``, or a
    process running other threads, which a fork would copy in whatever state they are."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    if not hasattr(os, "fork") or threading.active_count() > 1:
        return 1
    return max(1, min(n_figures, cpus))


def _draw_and_save(index: int, directory: Path, dpi: int) -> Path:
    """Draw plan ``index`` of :data:`_PLANS` and write its files; the PNG's path."""
    stem, _, draw = _PLANS[index]
    png_path, _ = figures.save_figure(draw(), directory, stem, dpi=dpi)
    return png_path


def write_figures(
    plans: list[FigurePlan],
    directory: str | Path,
    *,
    dpi: int = 150,
    meanwhile: Callable[[], object] | None = None,
) -> list[tuple[str, str, Path]]:
    """Draw every plan and write it as ``<stem>.png`` and ``<stem>.svg`` in ``directory``
    (:func:`comparison.figures.save_figure`); ``(stem, caption, PNG path)`` in the plans' order.

    With :func:`figure_processes` above 1 the figures are drawn in forked worker processes
    (module docstring), handed out heaviest first (:func:`figure_cost`), while this process
    calls ``meanwhile`` (the report writes trials.csv then, or waits for the process writing
    it); else ``meanwhile`` is called first and the figures drawn here. An error in a figure
    is raised here once the figures under way are done (the others are dropped).
    """
    directory = Path(directory)
    processes = figure_processes(len(plans))
    if processes == 1:
        if meanwhile is not None:
            meanwhile()
        return [
            (stem, caption, figures.save_figure(draw(), directory, stem, dpi=dpi)[0])
            for stem, caption, draw in plans
        ]
    _PLANS[:] = plans
    pool = ProcessPoolExecutor(processes, mp_context=get_context("fork"))
    try:
        futures = {
            index: pool.submit(_draw_and_save, index, directory, dpi)
            for index in sorted(range(len(plans)), key=lambda i: -figure_cost(plans[i][0]))
        }
        if meanwhile is not None:
            meanwhile()
        paths = [futures[index].result() for index in range(len(plans))]
    finally:  # on an error or Ctrl-C the figures not started are dropped
        pool.shutdown(wait=True, cancel_futures=True)
        _PLANS.clear()
    return [(stem, caption, path) for (stem, caption, _), path in zip(plans, paths, strict=True)]
