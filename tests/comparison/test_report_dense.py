"""The report of a dense emitter grid: tables summarised, trials.csv left out, a legible map."""

from __future__ import annotations

import json
import re
import sys
import types
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import FuncNorm

import comparison
import comparison.report as report
from comparison import figures
from comparison.experiment import load_experiment
from comparison.experiment_catalog import BUILTIN_DEFINITIONS
from comparison.figures import geometry
from comparison.metrics import format_number
from comparison.report import scenario_tracks_m, write_report
from comparison.report_figures import geometry_caption, report_figures
from tests.comparison.test_report import stand_in_store, synthetic_run, write_run_folder

XS = [float(x) for x in range(-20, 100, 10)]  # 12 columns
YS = [float(y) for y in range(5, 125, 10)]  # 12 rows: 144 points × 4 estimators
TRIALS = 12


@pytest.fixture(scope="module")
def grid_run():
    grid = [{"snr_db": 10.0, "emitter_x_m": x, "emitter_y_m": y} for y in YS for x in XS]
    trials, points, experiment = synthetic_run(grid, n_trials=TRIALS, seed=11)
    # the reference bound grows towards the track (y = 0), from 0.3 m to 6 m
    points["crlb_rmse_toa_doppler_m"] = 30.0 / points["emitter_y_m"]
    return trials, points, experiment


@pytest.fixture(scope="module")
def dense_report(tmp_path_factory, grid_run):
    """The report of the grid run with a page limit of 100 summary rows and of 1000 trial rows
    for trials.csv, over a stale trials.csv of an earlier report."""
    trials, points, experiment = grid_run
    folder = tmp_path_factory.mktemp("dense-run")
    write_run_folder(folder, experiment)
    (folder / "trials.csv").write_text("stale\n")
    engine = types.ModuleType("comparison.engine")
    engine.read_points = lambda run_dir: points.copy()
    engine.read_experiment = lambda run_dir: json.loads((run_dir / "experiment.json").read_text())
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(sys.modules, "comparison.engine", engine)
        patch.setattr(comparison, "engine", engine, raising=False)
        stand_in_store(patch, trials)
        patch.setattr(report, "MAX_TABLE_ROWS", 100)
        patch.setattr(geometry, "RASTER_CELLS", 100)
        html_path = write_report(folder, n_bootstrap=50, max_trials_csv_rows=1000)
    return folder, html_path, trials


def test_a_dense_sweep_gets_one_overview_line_per_estimator(dense_report):
    folder, html_path, _ = dense_report
    root = ET.parse(html_path).getroot()
    tables = root.find(".//section[@id='tables']")
    assert tables.find(".//section[@class='scenario-tables']") is None  # no row per point
    (overview,) = tables.findall(".//section[@class='scenario-overview']")
    assert overview.get("data-scenario") == "paper-1m"
    sentence = "".join(overview.find("p").itertext())
    assert sentence.startswith("576 summary rows on paper-1m (144 points), more than the 100")
    table = overview.find(".//table")
    header = [th.text for th in table.find("thead").iter("th")]
    assert header == [
        "estimator",
        "points",
        "attains",
        "above",
        "below",
        "biased",
        "inconclusive",
        "efficiency_min",
        "efficiency_median",
        "efficiency_max",
    ]
    body = [
        ["".join(td.itertext()) for td in tr.iter("td")] for tr in table.find("tbody").iter("tr")
    ]
    summary = pd.read_csv(folder / "summary.csv")
    assert [row[0] for row in body] == list(summary["estimator"].unique())
    for row in body:
        own = summary[summary["estimator"] == row[0]]
        counts = own["verdict"].value_counts()
        assert row[1:7] == [
            "144",
            *(
                str(counts.get(v, 0))
                for v in ("attains", "above", "below", "biased", "inconclusive")
            ),
        ]
        efficiency = own["efficiency_judged"]
        expected = [efficiency.min(), efficiency.median(), efficiency.max()]
        assert row[7:] == [format_number(value) for value in expected]
    # the whole page stays short: the verdict table, the overview, the definitions
    assert len(list(root.iter("tr"))) < 60


def test_too_many_trial_rows_leave_trials_csv_out_and_say_so(dense_report):
    folder, html_path, trials = dense_report
    assert not (folder / "trials.csv").exists()  # the stale one is gone too
    assert len(pd.read_csv(folder / "summary.csv")) == 576
    notes = [
        "".join(p.itertext())
        for p in ET.parse(html_path).getroot().iter("p")
        if p.get("class") == "file-note"
    ]
    assert notes == [
        f"trials.csv is not written: this run has {len(trials):,} trial rows, more than the "
        "1,000 written as text (EMITTERBENCH_MAX_TRIALS_CSV_ROWS). Every row is in "
        "results.sqlite, which comparison.engine.read_trials reads; to have the file, raise "
        "the limit and run emitterbench report again."
    ]


def test_the_map_is_written_as_png_and_svg_with_its_caption(dense_report):
    folder, html_path, _ = dense_report
    png = folder / "figures" / "geometry.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = ET.parse(folder / "figures" / "geometry.svg").getroot()
    # more cells than RASTER_CELLS: the meshes are images in the SVG, not a path per cell
    assert len([e for e in svg.iter() if e.tag.endswith("}image")]) >= 3
    caption = next(
        "".join(f.find("figcaption").itertext())
        for f in ET.parse(html_path).getroot().iter("figure")
        if "geometry.png" in "".join(f.find("figcaption").itertext())
    )
    assert f"one cell per emitter position ({TRIALS} trials each)" in caption
    assert "white where the bound is attained, blue below it, red above it" in caption
    assert re.search(r"a cell's efficiency is ±\d+% wide \(median over cells\)", caption)


@pytest.fixture(scope="module")
def grid_figure(grid_run):
    from comparison.metrics import summarize

    trials, points, experiment = grid_run
    summary = summarize(trials, n_bootstrap=50, swept_columns=experiment["swept_columns"])
    track = scenario_tracks_m(experiment)["paper-1m"]
    made = {stem: f for stem, _, f in report_figures(summary, trials, points, {"paper-1m": track})}
    return made["geometry"], summary, track


def test_the_map_has_metre_axes_the_track_and_a_scale_centred_on_one(grid_figure):
    figure, summary, track = grid_figure
    bound_ax, cls_ax = figure.axes[0], figure.axes[1]
    assert bound_ax.get_xlabel() == "emitter x (m)" and bound_ax.get_ylabel() == "emitter y (m)"
    assert cls_ax.get_title() == "paper-1m\ncls"
    # the view holds the grid's cells (10 m wide) and the track, which lies on y = 0
    assert cls_ax.get_xlim() == pytest.approx((-25.0, 95.0))
    low, high = cls_ax.get_ylim()
    assert low < float(track[:, 1].min()) <= 0.0 and high == pytest.approx(120.0)
    drawn = [line for line in cls_ax.get_lines() if line.get_label() == "UAV track"]
    assert drawn[0].get_xdata() == pytest.approx(track[:, 0])
    legend_texts = [t.get_text() for legend in figure.legends for t in legend.get_texts()]
    assert legend_texts == [geometry.TRACK_LABEL]
    mesh = cls_ax.collections[0]
    assert isinstance(mesh.norm, FuncNorm)
    assert float(mesh.norm(1.0)) == pytest.approx(0.5)  # white: the bound attained
    cls = summary[summary["estimator"] == "cls"]
    assert mesh.norm.vmin == pytest.approx(min(summary["efficiency_judged"].min(), 0.5))
    image = mesh.get_array().reshape(len(YS), len(XS))
    at = cls.set_index(["emitter_y_m", "emitter_x_m"])["efficiency_judged"]
    assert image[2, 3] == pytest.approx(at[(YS[2], XS[3])])
    # the efficiency colour bar is labelled at 1
    bar_ax = next(ax for ax in figure.axes if "RMSE / √CRLB" in ax.get_ylabel())
    assert 1.0 in list(bar_ax.yaxis.get_majorticklocs())


def test_the_bound_panel_of_a_dense_grid_has_labelled_contours(grid_figure):
    figure, _, _ = grid_figure
    bound_ax = figure.axes[0]
    assert len(bound_ax.collections) == 2  # the mesh, then the contour set
    levels = bound_ax.collections[1].levels
    assert list(levels) == pytest.approx([0.5, 1.0, 2.0, 5.0])  # 1-2-5 steps in 0.24…6 m
    labels = {t.get_text() for t in bound_ax.texts if t.get_text()}  # not the track's arrow
    assert len(labels) >= 2 and labels <= {"0.5 m", "1 m", "2 m", "5 m"}


def test_a_coarse_grid_gets_no_contours():
    grid = [(x, y) for y in (-10.0, 20.0) for x in (0.0, 30.0)]
    rows = [
        {"scenario": "s", "snr_db": 10.0, "emitter_x_m": x, "emitter_y_m": y, "frame": 0}
        | {"estimator": "cls", "efficiency_judged": 1.0 + 0.1 * i}
        for i, (x, y) in enumerate(grid)
    ]
    points = pd.DataFrame(
        [
            {"scenario": "s", "snr_db": 10.0, "emitter_x_m": x, "emitter_y_m": y, "frame": 0}
            | {"crlb_rmse_toa_doppler_m": 1.0 + i}
            for i, (x, y) in enumerate(grid)
        ]
    )
    figure = figures.geometry_heatmap_figure(pd.DataFrame(rows), points=points)
    assert len(figure.axes[0].collections) == 1
    assert not figure.legends  # no track, no legend for it


def test_centred_log_norm_puts_one_in_the_middle_of_either_range():
    norm = figures.centred_log_norm(0.01, 4.0)
    positions = np.asarray(norm(np.array([0.01, 0.1, 1.0, 2.0, 4.0])))
    assert positions == pytest.approx([0, 0.25, 0.5, 0.75, 1])
    assert norm.inverse(0.25) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="vmin < 1 < vmax"):
        figures.centred_log_norm(1.0, 2.0)


def test_geometry_caption_counts_trials_and_the_interval_width():
    summary = pd.DataFrame(
        {
            "frame": [0, 0, 0],
            "n_trials": [100, 100, 100],
            "efficiency_judged": [1.0, 1.0, 2.0],
            "efficiency_judged_ci_low": [0.9, 0.8, 1.6],
            "efficiency_judged_ci_high": [1.1, 1.2, 2.4],
        }
    )
    caption = geometry_caption(summary)
    assert "(100 trials each)" in caption
    assert "is ±20% wide (median over cells)" in caption  # widths 10%, 20%, 20%
    caption = geometry_caption(summary.assign(n_trials=[50, 100, 100]))
    assert "(50 to 100 trials each)" in caption


def test_the_dense_builtin_is_a_100_by_100_grid_of_100_trials():
    definition = BUILTIN_DEFINITIONS["geometry-map-dense"]
    assert definition["estimators"] == ["cls", "cls-paper"]
    experiment = load_experiment("geometry-map-dense")
    assert experiment.trials == 100
    assert experiment.sweep.n_points == 100 * 100
    sweep = definition["sweep"]
    assert (min(sweep["x"]), max(sweep["x"])) == (-40.0, 59.0)  # cells -40.5 … 59.5 m
    assert (min(sweep["y"]), max(sweep["y"])) == (0.5, 99.5)  # cells 0 … 100 m
    assert "x = -40.5 to 59.5 m" in definition["description"]
