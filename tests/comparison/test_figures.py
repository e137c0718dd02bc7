"""The figures of a report: panel order, counts behind rates, coincident curves, log ticks."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from comparison import figures
from comparison.figures import MIN_COUNT_FOR_RATE, wilson_interval

SCENARIOS = ("zeta", "alpha", "mid")
"""Not alphabetical: the panels must follow this order (first appearance), not a sort."""

SNRS = (0.0, 10.0, 20.0)
ESTIMATORS = ("cls", "ml", "lls-toa")


def summary_frame(
    *,
    scenarios=SCENARIOS,
    estimators=ESTIMATORS,
    snrs=SNRS,
    frames: int = 1,
    planners=None,
    grid=None,
    n: int = 200,
) -> pd.DataFrame:
    """A summary as :func:`comparison.metrics.summarize` lays it out, rows interleaved by SNR.

    √CRLB is ``10^(−SNR/20)/√(frame + 1)``; estimator i has RMSE ``(2 + i)`` times it (no two
    curves coincide), wrong-side rate ``0.1 (i + 1)`` and mean NEES ``2 + i``, each from ``n``
    values. ``grid`` gives ``(x, y)`` emitter positions, swept between ``snr_db`` and
    ``frame``.
    """
    rows = []
    for snr in snrs:
        for position in grid or [None]:
            for scenario in scenarios:
                for frame in range(frames):
                    for planner in planners or [None]:
                        for i, estimator in enumerate(estimators):
                            bound = 10 ** (-snr / 20) / math.sqrt(frame + 1)
                            row = {"scenario": scenario, "snr_db": snr}
                            if position is not None:
                                row["emitter_x_m"], row["emitter_y_m"] = position
                            row["frame"] = frame
                            if planner is not None:
                                row["planner"] = planner
                            rmse = (2 + i) * bound
                            row |= {
                                "estimator": estimator,
                                "n_trials": n,
                                "rmse_m": rmse,
                                "rmse_ci_low_m": 0.9 * rmse,
                                "rmse_ci_high_m": 1.1 * rmse,
                                "rmse_side_resolved_m": rmse,
                                "rmse_side_resolved_ci_low_m": 0.9 * rmse,
                                "rmse_side_resolved_ci_high_m": 1.1 * rmse,
                                "crlb_rmse_m": bound,
                                "efficiency": 1.0 + i,
                                "efficiency_judged": 1.0 + i,
                                "efficiency_judged_ci_low": 0.95 * (1.0 + i),
                                "efficiency_judged_ci_high": 1.05 * (1.0 + i),
                                "verdict": "attains" if i == 0 else "above",
                                "verdict_basis": "side-resolved",
                                "wrong_side_rate": 0.1 * (i + 1),
                                "n_successes": n,
                                "n_side_judged": n,
                                "nees_mean": 2.0 + i,
                                "nees_side_resolved_mean": 2.0 + i,
                                "n_nees": n,
                                "nees_band_low": 1.6,
                                "nees_band_high": 2.4,
                            }
                            rows.append(row)
    return pd.DataFrame(rows)


def trial_frame(*, scenarios=SCENARIOS, estimators=ESTIMATORS, snrs=SNRS, n: int = 30):
    """Trial rows with the contract's columns only (no swept column beyond ``snr_db``)."""
    rng = np.random.default_rng(1)
    rows = []
    for scenario in scenarios:
        for point, snr in enumerate(snrs):
            for i, estimator in enumerate(estimators):
                errors = (1 + i) * 10 ** (-snr / 20) * rng.rayleigh(size=n)
                for trial, error in enumerate(errors):
                    rows.append(
                        {
                            "scenario": scenario,
                            "point": point,
                            "snr_db": snr,
                            "estimator": estimator,
                            "frame": 0,
                            "trial": trial,
                            "truth_x_m": 35.0,
                            "truth_y_m": 15.0,
                            "x_m": 35.0 + error,
                            "y_m": 15.0,
                            "error_m": error,
                            "error_side_resolved_m": error,
                            "wrong_side": 0.0,
                            "ambiguous": False,
                            "success": True,
                            "cov_xx_m2": np.nan,
                            "cov_xy_m2": np.nan,
                            "cov_yy_m2": np.nan,
                            "crlb_rmse_m": 10 ** (-snr / 20),
                        }
                    )
    return pd.DataFrame(rows)


def flight_frame(*, scenarios=SCENARIOS, planners=("constant", "orbit"), n: int = 2):
    rows = []
    for scenario in scenarios:
        for planner in planners:
            for trial in range(n):
                for frame in range(2):
                    rows.append(
                        {
                            "scenario": scenario,
                            "point": 0,
                            "planner": planner,
                            "trial": trial,
                            "frame": frame,
                            "start_x_m": 5.0 * frame,
                            "start_y_m": 0.0,
                            "end_x_m": 5.0 * frame + 4.5,
                            "end_y_m": 1.0 * frame,
                        }
                    )
    return pd.DataFrame(rows)


def closed_loop_trials(flights: pd.DataFrame, estimator: str = "ml") -> pd.DataFrame:
    rows = flights[["scenario", "point", "planner", "trial", "frame"]].copy()
    return rows.assign(
        estimator=estimator,
        truth_x_m=35.0,
        truth_y_m=15.0,
        x_m=35.0 + 0.1 * rows["trial"],
        y_m=15.0 - 0.1 * rows["frame"],
        success=True,
        cov_xx_m2=0.04,
        cov_xy_m2=0.0,
        cov_yy_m2=0.04,
        wrong_side=0.0,
    )


def panels(figure: Figure) -> list:
    return [ax for ax in figure.axes if ax.get_visible() and ax.get_title()]


def scenario_of(title: str) -> str:
    return re.split(r"[,:\n]", title)[0]


def scenarios_in_order(figure: Figure) -> list[str]:
    return list(dict.fromkeys(scenario_of(ax.get_title()) for ax in panels(figure)))


def legend_texts(figure: Figure) -> list[str]:
    (legend,) = figure.legends
    return [" ".join(text.get_text().split()) for text in legend.get_texts()]


def line(ax, label: str):
    return next(ln for ln in ax.get_lines() if ln.get_label() == label)


def drawn_points(ax, label: str) -> dict[float, float]:
    """The finite points of the line labelled ``label``: x → y."""
    found = line(ax, label)
    xs, ys = (np.asarray(v, dtype=float) for v in found.get_data())
    return {float(x): float(y) for x, y in zip(xs, ys, strict=True) if np.isfinite(y)}


# --------------------------------------------------------------------------------------------
# one panel order everywhere
# --------------------------------------------------------------------------------------------


def _open_loop(function):
    return lambda: function(summary_frame())


def _per_frame(function):
    return lambda: function(summary_frame(snrs=(10.0,), frames=3))


def _closed_loop(function):
    return lambda: function(summary_frame(snrs=(10.0,), frames=3, planners=("paper", "orbit")))


def _geometry():
    grid = [(x, y) for y in (-10.0, 20.0) for x in (0.0, 30.0)]
    return figures.geometry_heatmap_figure(summary_frame(snrs=(10.0,), grid=grid))


def _trajectories():
    flights = flight_frame()
    return figures.trajectory_figure(flights, closed_loop_trials(flights), estimator="ml")


FIGURES = {
    "efficiency": _open_loop(figures.efficiency_figure),
    "efficiency_vs_frame": lambda: figures.efficiency_figure(
        summary_frame(snrs=(10.0,), frames=3), x="frame"
    ),
    "rmse": _open_loop(figures.rmse_figure),
    "rmse_side_resolved": _open_loop(figures.side_resolved_rmse_figure),
    "wrong_side": _open_loop(figures.wrong_side_figure),
    "error_cdf": lambda: figures.error_cdf_figure(trial_frame()),
    "geometry": _geometry,
    "rmse_vs_frame": _per_frame(figures.rmse_vs_frame_figure),
    "wrong_side_vs_frame": _per_frame(figures.wrong_side_vs_frame_figure),
    "nees_vs_frame": _per_frame(figures.nees_vs_frame_figure),
    "planner_rmse_vs_frame": _closed_loop(figures.planner_rmse_vs_frame_figure),
    "planner_wrong_side_vs_frame": _closed_loop(figures.planner_wrong_side_vs_frame_figure),
    "trajectories": _trajectories,
}


@pytest.mark.parametrize("name", list(FIGURES))
def test_panels_follow_the_scenarios_first_appearance(name):
    figure = FIGURES[name]()
    assert scenarios_in_order(figure) == list(SCENARIOS)
    titles = [scenario_of(ax.get_title()) for ax in panels(figure)]
    # each scenario's panels together, never interleaved with another's
    assert titles == sorted(titles, key=SCENARIOS.index)


def test_error_cdf_panels_keep_the_order_within_a_scenario():
    titles = [ax.get_title() for ax in panels(figures.error_cdf_figure(trial_frame()))]
    assert titles[:3] == ["zeta, SNR = 0 dB", "zeta, SNR = 10 dB", "zeta, SNR = 20 dB"]
    assert titles[3] == "alpha, SNR = 0 dB"


def test_scenario_order_is_the_first_appearance():
    frame = pd.DataFrame({"scenario": ["b", "c", "b", "a", "c"]})
    assert figures.scenario_order(frame) == ["b", "c", "a"]


# --------------------------------------------------------------------------------------------
# counts beside rates
# --------------------------------------------------------------------------------------------


def test_wrong_side_points_with_few_estimates_off_the_track_are_not_drawn():
    summary = summary_frame(scenarios=("paper-1m",))
    cls = summary["estimator"] == "cls"
    # 2 of 500 estimates off the track, both on the wrong side: a rate of 1 that says nothing.
    summary.loc[cls & (summary["snr_db"] == 0.0), ["wrong_side_rate", "n_side_judged"]] = [1.0, 2]
    summary.loc[cls & (summary["snr_db"] == 10.0), "n_side_judged"] = MIN_COUNT_FOR_RATE
    summary.loc[cls & (summary["snr_db"] == 20.0), "n_side_judged"] = MIN_COUNT_FOR_RATE - 1
    figure = figures.wrong_side_figure(summary)
    (ax,) = panels(figure)
    assert drawn_points(ax, "cls") == {10.0: pytest.approx(0.1)}
    assert drawn_points(ax, "ml") == {0.0: 0.2, 10.0: 0.2, 20.0: 0.2}
    assert 1.0 not in drawn_points(ax, "cls").values()
    assert "2 points not drawn: fewer than 20 estimates off the track" in legend_texts(figure)


def test_wilson_interval_counts_the_estimates_off_the_track():
    summary = summary_frame(scenarios=("paper-1m",), estimators=("cls",))
    summary["n_successes"] = 500
    summary["n_side_judged"] = 40
    (ax,) = panels(figures.wrong_side_figure(summary))
    band = np.concatenate([p.vertices[:, 1] for p in ax.collections[0].get_paths()])
    low, high = wilson_interval(pd.Series([0.1]), pd.Series([40]))
    wrong_low, _ = wilson_interval(pd.Series([0.1]), pd.Series([500]))
    assert np.isclose(band, low[0]).any() and np.isclose(band, high[0]).any()
    assert not np.isclose(band, wrong_low[0]).any()


def test_per_frame_wrong_side_and_nees_leave_out_points_with_few_values():
    summary = summary_frame(scenarios=("paper-1m",), snrs=(10.0,), frames=3)
    ml = summary["estimator"] == "ml"
    summary.loc[ml & (summary["frame"] == 0), "n_side_judged"] = 3
    summary.loc[ml & (summary["frame"] == 1), "n_nees"] = MIN_COUNT_FOR_RATE - 1
    (ax,) = panels(figures.wrong_side_vs_frame_figure(summary))
    assert set(drawn_points(ax, "ml")) == {1.0, 2.0}
    assert set(drawn_points(ax, "cls")) == {0.0, 1.0, 2.0}
    figure = figures.nees_vs_frame_figure(summary)
    (ax,) = panels(figure)
    assert set(drawn_points(ax, "ml")) == {0.0, 2.0}
    assert set(drawn_points(ax, "lls-toa")) == {0.0, 1.0, 2.0}
    assert "1 point not drawn: fewer than 20 NEES values" in legend_texts(figure)


def test_closed_loop_wrong_side_leaves_out_points_with_few_estimates():
    summary = summary_frame(
        scenarios=("paper-1m",), estimators=("ml",), snrs=(10.0,), frames=3, planners=("a", "b")
    )
    summary.loc[(summary["planner"] == "b") & (summary["frame"] == 2), "n_side_judged"] = 5
    (ax,) = panels(figures.planner_wrong_side_vs_frame_figure(summary))
    assert set(drawn_points(ax, "a")) == {0.0, 1.0, 2.0}
    assert set(drawn_points(ax, "b")) == {0.0, 1.0}


def test_caption_notes_name_the_minimum():
    assert figures.WRONG_SIDE_COUNT_NOTE == (
        f"points backed by fewer than {MIN_COUNT_FOR_RATE} estimates off the track are not drawn"
    )
    assert str(MIN_COUNT_FOR_RATE) in figures.NEES_COUNT_NOTE


# --------------------------------------------------------------------------------------------
# coincident curves
# --------------------------------------------------------------------------------------------


def test_coincident_curves_are_noted_in_the_legend_and_interleaved():
    summary = summary_frame(scenarios=("paper-1m",))
    ml = summary["estimator"] == "ml"
    cls = summary.loc[summary["estimator"] == "cls", "rmse_m"].to_numpy()
    summary.loc[ml, "rmse_m"] = cls * 1.01  # within 2% at every point
    figure = figures.rmse_figure(summary)
    texts = legend_texts(figure)
    assert "cls (coincides with ml)" in texts
    assert "ml (coincides with cls)" in texts
    assert "lls-toa" in texts  # 2 × cls: no note
    assert not any("lls-toa" in t and "coincides" in t for t in texts)
    (ax,) = panels(figure)
    # Interleaved: the second line draws every second marker and every second dash segment.
    assert line(ax, "cls").get_markevery() == (0, 2)
    assert line(ax, "cls").get_linestyle() == "-"
    assert line(ax, "ml").get_markevery() == (1, 2)
    assert line(ax, "ml").get_linestyle() == "--"  # a custom dash pattern reports as "--"
    assert line(ax, "lls-toa").get_linestyle() == "-"


def test_curves_that_differ_at_one_point_do_not_coincide():
    summary = summary_frame(scenarios=("paper-1m",), estimators=("cls", "ml"))
    ml = summary["estimator"] == "ml"
    summary.loc[ml, "rmse_m"] = summary.loc[summary["estimator"] == "cls", "rmse_m"].to_numpy()
    summary.loc[ml & (summary["snr_db"] == 20.0), "rmse_m"] *= 1.05
    texts = legend_texts(figures.rmse_figure(summary))
    assert not any("coincides" in text for text in texts)


def test_an_estimator_on_the_bound_is_noted_with_the_bound():
    summary = summary_frame(scenarios=("paper-1m",), estimators=("ml",))
    points = summary[["scenario", "snr_db", "frame"]].drop_duplicates()
    points = points.assign(crlb_rmse_toa_doppler_m=10 ** (-points["snr_db"] / 20))
    summary["rmse_m"] = summary["crlb_rmse_m"]
    texts = legend_texts(figures.rmse_figure(summary, points=points))
    assert "ml (coincides with √CRLB)" in texts
    assert "√CRLB, ToA+Doppler (coincides with ml)" in texts


def test_a_coincidence_in_some_panels_only_is_not_written_in_the_legend():
    """cls and ml coincide in alpha, not in zeta: one legend serves both panels, so it says
    nothing of it (the lines are interleaved where they overlap)."""
    summary = summary_frame(scenarios=("zeta", "alpha"), estimators=("cls", "ml"))
    same = (summary["scenario"] == "alpha") & (summary["estimator"] == "ml")
    summary.loc[same, "rmse_m"] = summary.loc[
        (summary["scenario"] == "alpha") & (summary["estimator"] == "cls"), "rmse_m"
    ].to_numpy()
    figure = figures.rmse_figure(summary)
    texts = legend_texts(figure)
    assert "cls" in texts and "ml" in texts
    assert not any("coincides" in text for text in texts)
    alpha = next(ax for ax in panels(figure) if ax.get_title() == "alpha")
    assert line(alpha, "ml").get_markevery() == (1, 2)  # still interleaved there


def test_estimator_colours_and_markers_follow_the_mapping_in_every_figure():
    summary = summary_frame(scenarios=("paper-1m",), frames=2)
    colors = figures.estimator_colors(["lls-toa", "ml", "cls"])
    markers = figures.estimator_markers(colors)
    for figure in (
        figures.rmse_figure(summary, colors=colors),
        figures.wrong_side_figure(summary, colors=colors),
        figures.rmse_vs_frame_figure(summary, colors=colors),
    ):
        ax = panels(figure)[0]
        for name in ESTIMATORS:
            drawn = line(ax, name)
            assert drawn.get_color() == colors[name]
            assert drawn.get_marker() == markers[name]
    assert len(set(markers.values())) == 3


# --------------------------------------------------------------------------------------------
# log axes
# --------------------------------------------------------------------------------------------


def rendered_labels(ax, *, minor: bool, axis: str = "y") -> list[str]:
    which = ax.yaxis if axis == "y" else ax.xaxis
    low, high = sorted(ax.get_ylim() if axis == "y" else ax.get_xlim())
    ticks = which.get_minor_ticks() if minor else which.get_major_ticks()
    locations = which.get_minorticklocs() if minor else which.get_majorticklocs()
    return [
        tick.label1.get_text()
        for tick, at in zip(ticks, locations, strict=False)
        if low <= at <= high and tick.label1.get_visible()
    ]


def drawn_log_axis(low: float, high: float):
    """A panel with a log y axis from ``low`` to ``high``, ticked as the figures tick it, drawn."""
    figure = Figure(figsize=figures.PANEL_SIZE_IN)
    ax = figure.subplots()
    ax.plot([0, 1], [low, high])
    ax.set_yscale("log")
    figures.plain_log_ticks(ax.yaxis)
    ax.set_ylim(low, high)
    FigureCanvasAgg(figure).draw()
    return ax


@pytest.mark.parametrize(
    ("low", "high", "expected"),
    [
        (0.0015, 0.0065, ["0.002", "0.005"]),  # not 0.002 0.003 0.004 0.006
        (0.15, 12.0, ["0.2", "0.5", "1", "2", "5", "10"]),
        (0.03, 3e4, ["0.1", "1", "10", "100", "1000", "10000"]),
        (1.0, 1e11, [f"$10^{{{e}}}$" for e in range(0, 11, 2)]),
    ],
)
def test_log_axes_label_few_major_ticks_and_no_minor_ones(low, high, expected):
    ax = drawn_log_axis(low, high)
    assert isinstance(ax.yaxis.get_minor_formatter(), NullFormatter)
    assert set(rendered_labels(ax, minor=True)) <= {""}
    assert [t for t in rendered_labels(ax, minor=False) if t] == expected


@pytest.mark.parametrize(
    ("low", "high", "expected"),
    [
        (1.0, 500.0, [m * 10.0**e for e in range(3) for m in range(2, 10) if m * 10**e <= 500]),
        (0.02, 20.0, [m * 10.0**e for e in range(-2, 1) for m in range(2, 10)] + [20.0]),
        (1.0, 1.001e3, None),  # just over three decades: none
        (1e-2, 1e12, None),
    ],
)
def test_log_axes_have_minor_ticks_over_three_decades_at_most(low, high, expected):
    ax = drawn_log_axis(low, high)
    shown = [at for at in ax.yaxis.get_minorticklocs() if low <= at <= high]
    if expected is None:
        assert shown == []
    else:
        np.testing.assert_allclose(shown, expected, rtol=1e-12)


@pytest.mark.parametrize("name", ["rmse", "rmse_vs_frame", "nees_vs_frame", "error_cdf"])
def test_log_axes_of_the_figures_have_no_minor_tick_labels(name):
    figure = {
        **FIGURES,
        "nees_vs_frame": lambda: figures.nees_vs_frame_figure(
            summary_frame(snrs=(10.0,), frames=3).assign(
                nees_side_resolved_mean=lambda f: 2 + 100 * f["frame"]
            )
        ),
    }[name]()
    FigureCanvasAgg(figure).draw()
    checked = 0
    for ax in panels(figure):
        for axis in ("x", "y"):
            scale = ax.get_yscale() if axis == "y" else ax.get_xscale()
            if scale != "log":
                continue
            which = ax.yaxis if axis == "y" else ax.xaxis
            assert isinstance(which.get_minor_formatter(), NullFormatter)
            assert set(rendered_labels(ax, minor=True, axis=axis)) <= {""}
            shown = [t for t in rendered_labels(ax, minor=False, axis=axis) if t]
            assert 2 <= len(shown) <= figures.MAX_LOG_LABELS
            checked += 1
    assert checked >= len(panels(figure))


# --------------------------------------------------------------------------------------------
# the efficiency figure
# --------------------------------------------------------------------------------------------


def test_the_efficiency_figure_draws_each_point_with_its_interval_on_a_linear_axis_around_1():
    """cls at 1 (attains: filled), ml at 2 and lls-toa at 3, beyond the axis: open triangles
    on its top edge, no bar; the band shaded; estimators side by side at each SNR."""
    summary = summary_frame(scenarios=("paper-1m",))
    figure = figures.efficiency_figure(summary)
    (ax,) = panels(figure)
    assert ax.get_yscale() == "linear"
    low, high = ax.get_ylim()
    assert figures.EFFICIENCY_VIEW[0] <= low < 0.9 and 1.1 < high <= figures.EFFICIENCY_VIEW[1]
    markers = [
        line
        for line in ax.get_lines()
        if line.get_linestyle() == "None" and len(line.get_xdata()) and line.get_marker() != "_"
    ]  # the points and triangles, not the bars' caps
    filled = [m for m in markers if m.get_markerfacecolor() != "white"]
    (cls,) = filled  # only cls attains
    assert list(cls.get_ydata()) == [1.0, 1.0, 1.0]
    # side by side: cls sits left of each SNR point
    assert all(x < snr for x, snr in zip(cls.get_xdata(), SNRS, strict=True))
    top = [m for m in markers if m.get_marker() == "^"]
    assert len(top) == 2 and all(np.allclose(m.get_ydata(), high) for m in top)
    # the 95% interval of cls as an error bar from 0.95 to 1.05
    segments = [seg for coll in ax.collections for seg in getattr(coll, "get_segments", list)()]
    spans = {(round(seg[0][1], 6), round(seg[1][1], 6)) for seg in segments if len(seg) == 2}
    assert (0.95, 1.05) in spans
    band = [p for p in ax.patches if p.get_facecolor()[:3] == pytest.approx((0.88,) * 3)]
    assert band
    texts = legend_texts(figure)
    assert "filled: attains" in texts
    assert any(t.startswith("beyond the axis") for t in texts)
    assert not any("coincides" in t for t in texts)  # the legend stays short
    assert "side-resolved" in figure.get_suptitle()


def test_estimators_keep_distinct_markers_and_colour_blind_safe_colours():
    names = [f"e{i}" for i in range(8)]
    colors = figures.estimator_colors(names)
    assert len({tuple(c) for c in colors.values()}) == 8
    assert [tuple(round(v, 4) for v in colors[n][:3]) for n in names[:3]] == [
        (0.902, 0.6235, 0.0),
        (0.3373, 0.7059, 0.9137),
        (0.0, 0.6196, 0.451),
    ]  # Okabe and Ito's orange, sky blue, bluish green
    markers = figures.estimator_markers(colors)
    assert len(set(markers.values())) == 8  # in greyscale, the markers tell them apart


def test_a_long_error_cdf_is_drawn_at_evenly_spaced_ranks_on_the_exact_curve(monkeypatch):
    from comparison.figures import sweep

    monkeypatch.setattr(sweep, "MAX_CDF_STEPS", 7)
    trials = trial_frame(scenarios=("paper-1m",), estimators=("cls",), snrs=(10.0,), n=30)
    (ax,) = panels(figures.error_cdf_figure(trials))
    (line,) = [line for line in ax.get_lines() if line.get_label() == "cls"]
    exact = np.sort(trials["error_m"].to_numpy())
    ranks = np.array([0, 5, 10, 14, 19, 24, 29])  # 0 to 29 in 7 steps, rounded
    drawn_x, drawn_y = line.get_data()  # the corners of the steps
    assert np.array_equal(drawn_x, exact[ranks])
    assert np.array_equal(drawn_y, (ranks + 1) / 30)  # the exact CDF at those errors
