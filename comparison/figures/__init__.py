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
- curves that overlap are drawn interleaved (alternating dash segments and markers), so that
  each stays visible; the legend names those that agree within :data:`COINCIDENCE_RTOL` at
  every point of every panel ("coincides with …"), and no note that holds in some panels
  only;
- a rate or a mean backed by fewer than :data:`MIN_COUNT_FOR_RATE` values is not drawn
  (:data:`WRONG_SIDE_COUNT_NOTE`, :data:`NEES_COUNT_NOTE`);
- log axes label decades only (1-2-5 steps when the view spans less than two decades), as
  plain numbers from 0.001 to 10000 and as powers of ten beyond; minor ticks are unlabelled,
  and drawn only on axes of at most three decades (:data:`MAX_MINOR_TICK_DECADES`);
- per-frame runs are drawn at their last frame except in the figures against the frame.

The figures by family: :mod:`~comparison.figures.sweep` (against the swept parameter, the
error CDF, the run time), :mod:`~comparison.figures.efficiency` (the efficiency with its intervals, first in a
report), :mod:`~comparison.figures.frames` (against the frame),
:mod:`~comparison.figures.geometry` (the efficiency heatmap) and
:mod:`~comparison.figures.closed_loop` (planners, trajectories). What they share:
:mod:`~comparison.figures.style` (labels, colours, markers, legend, log ticks, saving),
:mod:`~comparison.figures.curves` (coincident curves, counted rates) and
:mod:`~comparison.figures.panels` (what is swept, the panels, the bounds).
"""

from __future__ import annotations

from comparison.figures.closed_loop import (
    PLANNER_MARKERS,
    covariance_ellipse_m,
    planner_colors,
    planner_rmse_vs_frame_figure,
    planner_wrong_side_vs_frame_figure,
    trajectory_figure,
)
from comparison.figures.curves import (
    COINCIDENCE_NOTE,
    COINCIDENCE_RTOL,
    DASH_LENGTH,
    MIN_COUNT_FOR_RATE,
    NEES_COUNT_NOTE,
    OVERLAP_IN,
    WRONG_SIDE_COUNT_NOTE,
    wilson_interval,
)
from comparison.figures.efficiency import EFFICIENCY_VIEW, efficiency_figure
from comparison.figures.frames import (
    nees_vs_frame_figure,
    rmse_vs_frame_figure,
    wrong_side_vs_frame_figure,
)
from comparison.figures.geometry import CONTOUR_CELLS, centred_log_norm, geometry_heatmap_figure
from comparison.figures.panels import (
    BOUND_COLUMNS,
    MAX_PANELS,
    REFERENCE_BOUND,
    SNR_AXIS_LABEL,
    axis_label,
    is_geometry_sweep,
    is_per_frame,
    last_frame,
    parameter_columns,
    scenario_order,
    sweep_axis,
    varying_columns,
)
from comparison.figures.style import (
    ESTIMATOR_LABELS,
    ESTIMATOR_MARKERS,
    LEGEND_WIDTH_IN,
    MAX_LOG_LABELS,
    MAX_MINOR_TICK_DECADES,
    PANEL_SIZE_IN,
    PLAIN_NUMBER_RANGE,
    PlainLogFormatter,
    SparseLogLocator,
    estimator_colors,
    estimator_label,
    estimator_markers,
    plain_log_ticks,
    save_figure,
)
from comparison.figures.sweep import (
    error_cdf_figure,
    rmse_figure,
    runtime_figure,
    side_resolved_rmse_figure,
    wrong_side_figure,
)

__all__ = [
    "BOUND_COLUMNS",
    "COINCIDENCE_NOTE",
    "COINCIDENCE_RTOL",
    "CONTOUR_CELLS",
    "DASH_LENGTH",
    "EFFICIENCY_VIEW",
    "ESTIMATOR_LABELS",
    "ESTIMATOR_MARKERS",
    "LEGEND_WIDTH_IN",
    "MAX_LOG_LABELS",
    "MAX_MINOR_TICK_DECADES",
    "MAX_PANELS",
    "MIN_COUNT_FOR_RATE",
    "NEES_COUNT_NOTE",
    "OVERLAP_IN",
    "PANEL_SIZE_IN",
    "PLAIN_NUMBER_RANGE",
    "PLANNER_MARKERS",
    "REFERENCE_BOUND",
    "SNR_AXIS_LABEL",
    "WRONG_SIDE_COUNT_NOTE",
    "PlainLogFormatter",
    "SparseLogLocator",
    "axis_label",
    "centred_log_norm",
    "covariance_ellipse_m",
    "efficiency_figure",
    "error_cdf_figure",
    "estimator_colors",
    "estimator_label",
    "estimator_markers",
    "geometry_heatmap_figure",
    "is_geometry_sweep",
    "is_per_frame",
    "last_frame",
    "nees_vs_frame_figure",
    "parameter_columns",
    "plain_log_ticks",
    "planner_colors",
    "planner_rmse_vs_frame_figure",
    "planner_wrong_side_vs_frame_figure",
    "rmse_figure",
    "rmse_vs_frame_figure",
    "runtime_figure",
    "save_figure",
    "scenario_order",
    "side_resolved_rmse_figure",
    "sweep_axis",
    "trajectory_figure",
    "varying_columns",
    "wilson_interval",
    "wrong_side_figure",
    "wrong_side_vs_frame_figure",
]
