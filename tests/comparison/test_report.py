"""The report of a synthetic run folder that follows the engine's contract exactly."""

from __future__ import annotations

import base64
import contextlib
import json
import math
import multiprocessing
import sys
import types
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import comparison
import comparison.report_figures as report_figures_module
from comparison import store
from comparison.intervals import nees_band
from comparison.metrics import CONTRACT_METRIC_NAMES, format_number, summarize
from comparison.report import render_html, scenario_tracks_m, write_report
from comparison.report_figures import report_figures
from comparison.verdict_table import first_screen_notes

# name: (RMSE / √CRLB, ambiguous on one straight frame, has a covariance, bound factor)
ESTIMATORS = {
    "cls": (1.0, True, False, 1.0),
    "cls-as-printed": (3.0, True, False, 1.0),
    "lls-toa": (1.0, False, False, 3.0),
    "ml": (1.0, False, True, 1.0),
}
BOUND_FACTORS = {
    "crlb_rmse_toa_m": 3.0,
    "crlb_rmse_doppler_m": 2.0,
    "crlb_rmse_rss_m": 10.0,
    "crlb_rmse_toa_doppler_m": 1.0,
    "crlb_rmse_all_m": 0.95,
}
RUN_INFO = {
    "packages": {"numpy": "2.4.6", "pandas": "3.0.0", "emitterbench": "0.1.0"},
    "machine": {"cpu": "synthetic-cpu", "cores": 2},
    "seed": 20240611,
    "start": "2025-01-01T00:00:00Z",
    "end": "2025-01-01T00:01:00Z",
    "workers": 2,
}


def synthetic_run(
    sweep: list[dict[str, float]], *, n_trials: int, frames: int = 1, seed: int = 0
) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Trial rows, point rows and experiment.json of a run, per the engine's contract.

    √CRLB(ToA+Doppler) is ``10^(−SNR/20)/√(frame + 1)`` m; each estimator's errors are
    circular Gaussian with RMSE its factor times its own bound. Ambiguous estimators return
    the mirror image across the track (y = 0) in half the trials of frame 0; ``lls-toa`` fails
    in a fifth of the trials at SNR < 0 dB.
    """
    rng = np.random.default_rng(seed)
    swept = [c for c in sweep[0] if c != "snr_db"]
    names = list(ESTIMATORS)
    point, estimator, frame, trial = (
        a.ravel()
        for a in np.meshgrid(
            np.arange(len(sweep)),
            np.arange(len(names)),
            np.arange(frames),
            np.arange(n_trials),
            indexing="ij",
        )
    )
    table = pd.DataFrame(sweep)
    snr = table["snr_db"].to_numpy(float)[point]
    truth = np.column_stack(
        [
            table.get("emitter_x_m", pd.Series([35.0] * len(sweep))).to_numpy(float)[point],
            table.get("emitter_y_m", pd.Series([15.0] * len(sweep))).to_numpy(float)[point],
        ]
    )
    scale, ambiguous, has_cov, factor = (
        np.array([ESTIMATORS[n][i] for n in names])[estimator] for i in range(4)
    )
    base_bound = 10 ** (-snr / 20) / np.sqrt(frame + 1)
    bound = base_bound * factor
    sigma = scale * bound / math.sqrt(2)
    errors = rng.normal(size=(len(point), 2)) * sigma[:, None]
    estimate = truth + errors
    mirror = estimate * [1.0, -1.0]
    ambiguous = ambiguous.astype(bool) & (frame == 0)
    flip = ambiguous & (rng.random(len(point)) < 0.5)
    returned = np.where(flip[:, None], mirror, estimate)
    success = ~(
        (np.array(names)[estimator] == "lls-toa") & (snr < 0) & (rng.random(len(point)) < 0.2)
    )
    error = np.linalg.norm(returned - truth, axis=1)
    side = np.where(
        ambiguous,
        np.minimum(np.linalg.norm(errors, axis=1), np.linalg.norm(mirror - truth, axis=1)),
        error,
    )
    variance = np.where(has_cov.astype(bool), sigma**2, np.nan)
    nees = np.sum(errors**2, axis=1) / variance

    def ok(values):
        return np.where(success, values, np.nan)

    trials = pd.DataFrame({"experiment": "synthetic", "scenario": "paper-1m", "point": point})
    trials["snr_db"] = snr
    for column in swept:
        trials[column] = table[column].to_numpy(float)[point]
    trials = trials.assign(
        estimator=np.array(names)[estimator],
        frame=frame,
        trial=trial,
        truth_x_m=truth[:, 0],
        truth_y_m=truth[:, 1],
        x_m=ok(returned[:, 0]),
        y_m=ok(returned[:, 1]),
        error_m=ok(error),
        error_side_resolved_m=ok(side),
        wrong_side=ok((np.sign(returned[:, 1]) != np.sign(truth[:, 1])).astype(float)),
        ambiguous=ambiguous & success,
        success=success,
        n_candidates=np.where(success, np.where(ambiguous, 2, 1), 0),
        candidates_json=[json.dumps([r.tolist()]) for r in returned],
        cov_xx_m2=ok(variance),
        cov_xy_m2=ok(np.where(has_cov.astype(bool), 0.0, np.nan)),
        cov_yy_m2=ok(variance),
        nees=ok(nees),
        nees_side_resolved=ok(nees),
        crlb_rmse_m=bound,
        runtime_s=1e-4 * np.where(has_cov.astype(bool), 30.0, 1.0) * (1 + rng.random(len(point))),
        message=np.where(success, "", "rank deficient"),
        diagnostics_json="{}",
    )
    trials = trials.sort_values(["scenario", "point", "estimator", "frame", "trial"])
    points = (
        trials[
            ["experiment", "scenario", "point", "snr_db", *swept, "frame", "truth_x_m", "truth_y_m"]
        ]
        .drop_duplicates(["scenario", "point", "frame"])
        .reset_index(drop=True)
    )
    reference = 10 ** (-points["snr_db"] / 20) / np.sqrt(points["frame"] + 1)
    for column, bound_factor in BOUND_FACTORS.items():
        points[column] = reference * bound_factor
    experiment = {
        "name": "synthetic-comparison",
        "description": "synthetic rows with known error distributions",
        "scenarios": ["paper-1m"],
        "sweep": {c: sorted({float(p[c]) for p in sweep}) for c in sweep[0]},
        "estimators": names,
        "trials": n_trials,
        "seed": 7,
        "swept_columns": swept,
    }
    return trials.reset_index(drop=True), points, experiment


def stand_in_store(patch: pytest.MonkeyPatch, trials: pd.DataFrame) -> None:
    """The store's readers of trial rows (:mod:`comparison.store`) over ``trials``."""
    planners = trials["planner"] if "planner" in trials.columns else pd.Series([""])
    layout = store.TrialLayout(
        n_rows=len(trials),
        n_trial_sets=len(trials[["scenario", "point", "frame"]].drop_duplicates()),
        orders={
            "scenario": tuple(pd.unique(trials["scenario"])),
            "planner": tuple(pd.unique(planners)),
            "estimator": tuple(pd.unique(trials["estimator"])),
        },
    )
    patch.setattr(store, "count_trials", lambda run_dir: len(trials))
    patch.setattr(store, "trial_layout", lambda run_dir: layout)
    patch.setattr(store, "iter_trials", lambda run_dir, columns=None, **_: iter([trials.copy()]))
    patch.setattr(store, "read_trials", lambda run_dir, columns=None: trials.copy())


def write_run_folder(folder: Path, experiment: dict) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "experiment.json").write_text(json.dumps(experiment))
    (folder / "run.json").write_text(json.dumps(RUN_INFO))


@pytest.fixture(scope="module")
def snr_run(tmp_path_factory):
    """An SNR sweep reported through the engine's readers (a stand-in engine module)."""
    folder = tmp_path_factory.mktemp("snr-run")
    trials, points, experiment = synthetic_run(
        [{"snr_db": s} for s in (-10.0, 0.0, 10.0, 20.0, 30.0)], n_trials=80
    )
    write_run_folder(folder, experiment)
    engine = types.ModuleType("comparison.engine")
    engine.read_points = lambda run_dir: points.copy()
    engine.read_experiment = lambda run_dir: json.loads(
        (Path(run_dir) / "experiment.json").read_text()
    )
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(sys.modules, "comparison.engine", engine)
        patch.setattr(comparison, "engine", engine, raising=False)
        stand_in_store(patch, trials)
        html_path = write_report(folder, n_bootstrap=200)
    return folder, html_path, trials


@contextlib.contextmanager
def stand_in_run(folder: Path) -> Iterator[pytest.MonkeyPatch]:
    """A small SNR sweep in ``folder``, read through stand-in readers while the block runs."""
    trials, points, experiment = synthetic_run([{"snr_db": s} for s in (0.0, 10.0)], n_trials=20)
    write_run_folder(folder, experiment)
    engine = types.ModuleType("comparison.engine")
    engine.read_points = lambda run_dir: points.copy()
    engine.read_experiment = lambda run_dir: experiment
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(sys.modules, "comparison.engine", engine)
        patch.setattr(comparison, "engine", engine, raising=False)
        stand_in_store(patch, trials)
        # a process for trials.csv even where other tests left threads running
        patch.setattr(report_figures_module, "figure_processes", lambda n: min(n, 2))
        yield patch


def child_ids() -> set[int]:
    """The process ids of this process's children (an earlier test's pool among them)."""
    return {process.pid for process in multiprocessing.active_children()}


def test_an_error_writing_trials_csv_is_raised_by_the_report_and_no_process_is_left(tmp_path):
    """trials.csv is written from results.sqlite while the summary is worked out (in a
    process of its own where one may be forked): its error reaches the caller whole."""
    folder = tmp_path / "run"
    children = child_ids()
    with stand_in_run(folder) as patch:
        rows = store.iter_trials

        def failing(run_dir, columns=None, **options):
            if columns is None:  # every column: the rows of trials.csv
                raise ValueError("results.sqlite: the rows cannot be read; rerun the experiment")
            return rows(run_dir, columns, **options)

        patch.setattr(store, "iter_trials", failing)
        with pytest.raises(ValueError, match=r"^results.sqlite: the rows cannot be read; rerun"):
            write_report(folder, n_bootstrap=50)
    assert child_ids() <= children
    assert not (folder / "trials.csv").exists()
    assert not list(folder.glob(".trials.csv.*"))  # no temporary file left


def test_an_error_after_the_summary_leaves_trials_csv_whole_and_no_process(tmp_path):
    folder = tmp_path / "run"
    children = child_ids()
    with stand_in_run(folder) as patch:

        def failing(*args, **kwargs):
            raise ValueError("figures: cannot be drawn")

        patch.setattr(report_figures_module, "figure_plans", failing)
        with pytest.raises(ValueError, match=r"^figures: cannot be drawn$"):
            write_report(folder, n_bootstrap=50)
        expected = store.iter_trials(folder)
        assert len(pd.read_csv(folder / "trials.csv")) == len(next(expected)) == 2 * 4 * 20
    assert child_ids() <= children


def parse_html(path: Path) -> ET.Element:
    return ET.parse(path).getroot()


def text_of(element: ET.Element) -> str:
    """The text of ``element`` and everything inside it (a label is inside ``<bdi>``)."""
    return "".join(element.itertext())


def as_xml(fragment: str) -> str:
    """An XHTML fragment as ElementTree writes it back."""
    return ET.tostring(ET.fromstring(fragment), encoding="unicode")


def test_report_writes_summary_trials_and_every_figure(snr_run):
    folder, html_path, trials = snr_run
    assert html_path == folder / "report.html"
    summary = pd.read_csv(folder / "summary.csv")
    assert list(summary.columns[: 4 + len(CONTRACT_METRIC_NAMES)]) == [
        "scenario",
        "snr_db",
        "frame",
        "estimator",
        *CONTRACT_METRIC_NAMES,
    ]
    assert len(summary) == 5 * 4  # points × estimators
    assert summary["n_trials"].tolist() == [80] * 20
    assert len(pd.read_csv(folder / "trials.csv")) == len(trials) == 5 * 4 * 80
    stems = {"efficiency", "rmse", "rmse_side_resolved", "wrong_side", "error_cdf", "runtime"}
    assert {p.name for p in (folder / "figures").iterdir()} == {
        f"{stem}.{ext}" for stem in stems for ext in ("png", "svg")
    }
    for stem in stems:
        assert (folder / "figures" / f"{stem}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert ET.parse(folder / "figures" / f"{stem}.svg").getroot().tag.endswith("svg")


def test_html_is_well_formed_self_contained_and_embeds_every_figure(snr_run):
    folder, html_path, _ = snr_run
    root = parse_html(html_path)  # raises on any unclosed or mismatched tag
    assert root.tag == "html"
    assert not [e for e in root.iter() if e.tag in {"link", "script", "iframe", "object"}]
    images = list(root.iter("img"))
    assert all(img.get("src").startswith("data:image/png;base64,") for img in images)
    embedded = {base64.b64decode(img.get("src").split(",", 1)[1]) for img in images}
    on_disk = {p.read_bytes() for p in (folder / "figures").glob("*.png")}
    assert embedded == on_disk and len(images) == 6
    # the efficiency, what every verdict is about, is the first figure
    assert next(root.iter("figure")).get("id") == "figure-efficiency"
    assert "http://" not in html_path.read_text() and "https://" not in html_path.read_text()


def test_every_table_number_equals_summary_csv(snr_run):
    folder, html_path, _ = snr_run
    summary = pd.read_csv(folder / "summary.csv")
    keys = ["snr_db", "frame", "estimator"]
    by_key = {
        (
            row["scenario"],
            *(format_number(row[k]) if k != "estimator" else row[k] for k in keys),
        ): row
        for _, row in summary.iterrows()
    }
    checked = 0
    for section in parse_html(html_path).iter("section"):
        if section.get("class") != "scenario-tables":
            continue
        for table in section.iter("table"):
            header = [th.text for th in table.find("thead").iter("th")]
            for tr in table.find("tbody").iter("tr"):
                cells = dict(zip(header, (text_of(td) for td in tr.iter("td")), strict=True))
                key = (section.get("data-scenario"), *(cells[k] for k in keys))
                row = by_key[key]
                for column, text in cells.items():
                    value = row[column]
                    expected = value if isinstance(value, str) else format_number(value)
                    assert text == expected, (key, column)
                    checked += 1
    # compact (20 rows × (3 keys + the compact metrics)) and full tables
    from comparison.report import COMPACT_COLUMNS

    assert checked == 20 * (3 + len(COMPACT_COLUMNS)) + 20 * (len(summary.columns) - 1)


def own_verdicts(summary: pd.DataFrame, estimator: str) -> list[str]:
    return summary[summary["estimator"] == estimator].sort_values("snr_db")["verdict"].tolist()


def test_first_screen_is_the_verdict_table_with_computed_notes(snr_run):
    folder, html_path, _ = snr_run
    root = parse_html(html_path)
    section = next(s for s in root.iter("section") if s.get("id") == "verdicts")
    assert section is next(s for s in root.iter("section"))  # the first section of the page
    summary = pd.read_csv(folder / "summary.csv")
    table = next(t for t in section.iter("table") if t.get("class") == "verdicts")
    rows = {text_of(tr.find("th")): tr.findall("td") for tr in table.find("tbody").iter("tr")}
    # best first: most points attaining, then the lowest threshold, then nearest to 1
    thresholds = pd.read_csv(folder / "thresholds.csv").set_index("estimator")
    rank = {
        name: (
            -int((own["verdict"] == "attains").sum()),
            np.nan_to_num(thresholds.loc[name, "threshold_snr_db"], nan=np.inf),
            float(np.median(np.abs(np.log(own["efficiency_judged"])))),
        )
        for name, own in summary.groupby("estimator")
    }
    assert list(rows) == sorted(rank, key=rank.get)
    assert list(rows)[-1] == "cls-as-printed"  # 3× its bound everywhere
    for estimator, (cell,) in rows.items():
        spans = [span for span in cell.iter("span") if span.get("class", "").startswith("v ")]
        squares = [span for span in cell.iter("span") if span.get("class", "").startswith("sq ")]
        # one square per SNR point, lowest first, coloured by its verdict
        assert [sq.get("class") for sq in squares] == [
            f"sq v-{verdict}" for verdict in own_verdicts(summary, estimator)
        ]
        own = summary[summary["estimator"] == estimator].set_index("snr_db")
        # efficiency at −10, 10 and 30 dB, each coloured by its own verdict
        for span, snr in zip(spans, (-10.0, 10.0, 30.0), strict=True):
            assert span.text == f"{own.loc[snr, 'efficiency_judged']:.3g}"
            assert span.get("class") == f"v v-{own.loc[snr, 'verdict']}"
        # the strip's ends name its SNR range; each square's own SNR is in its title
        ends = [span.text for span in cell.iter("span") if span.get("class") == "ends"]
        assert ends == ["-10", "30 dB"]
        assert [sq.get("title").split(":")[0] for sq in squares] == [
            "-10 dB",
            "0 dB",
            "10 dB",
            "20 dB",
            "30 dB",
        ]
    header = [" ".join(" ".join(th.itertext()).split()) for th in table.find("thead").iter("th")]
    mixed = "efficiency (side-resolved for †)"  # some estimators flag ambiguity, some do not
    assert header[1] == (
        f"paper-1m threshold; a square per SNR, -10 to 30 dB; {mixed} at -10 / 10 / 30 dB"
    )
    # cls-as-printed is 3× its bound everywhere: above at every point, threshold "never"
    assert "never" in "".join(rows["cls-as-printed"][0].itertext())
    assert (summary.loc[summary["estimator"] == "cls-as-printed", "verdict"] == "above").all()
    items = list(section.iter("li"))
    for li in items:
        li.tail = None
    notes = [ET.tostring(li, encoding="unicode") for li in items]
    assert notes == [as_xml(f"<li>{note}</li>") for note in first_screen_notes(summary, None)]
    thresholds = pd.read_csv(folder / "thresholds.csv")
    assert list(thresholds["estimator"]) == ["cls", "cls-as-printed", "lls-toa", "ml"]  # as run
    assert math.isnan(thresholds["threshold_snr_db"].iloc[1])
    text = "".join(root.itertext())
    assert "multiplied by 10^(−SNR/20)" in text and "MATH §2" in text and "MATH §7" in text
    assert "docs/math.md" in text
    assert "lies inside [0.9, 1.1]" in text and "studentized bootstrap" in text
    for fragment in ("synthetic-comparison", "20240611", "synthetic-cpu", "3.0.0"):
        assert fragment in text
    run_section = next(s for s in root.iter("section") if s.get("id") == "run")
    assert "workers" in "".join(run_section.itertext())


def test_notes_name_an_uninformative_modality_and_too_few_trials():
    trials, points, _ = synthetic_run([{"snr_db": s} for s in (0.0, 10.0)], n_trials=12)
    summary = summarize(trials, n_bootstrap=50)
    points = points.assign(range_scale_m=62.0, crlb_rmse_toa_m=3e5)
    notes = first_screen_notes(summary, points)
    assert notes[0].startswith("On paper-1m, ToA alone bounds the error at 3e+05 m")
    assert "4.84e+03 times the size of the geometry" in notes[0]
    assert notes[1].startswith("8 of 8 verdicts are inconclusive for too few trials")
    # a modality within 100× the geometry gets no note
    assert not first_screen_notes(summary, points.assign(crlb_rmse_toa_m=600.0))[0].startswith(
        "On paper-1m"
    )


def test_fit_note_tells_data_that_do_not_fit_from_answers_off_the_fit():
    trials, _, _ = synthetic_run([{"snr_db": s} for s in (0.0, 10.0)], n_trials=12)
    summary = summarize(trials, n_bootstrap=50).assign(n_fit_judged=1000)
    best, worse, *_ = summary["estimator"].unique()
    scenario = summary["scenario"].iloc[0]

    def fit_note(rejected: dict[tuple[str, float], int]) -> str:
        # rejected fits per (estimator, SNR), of 1000 trials; the others 10 (1%, chance)
        rates = [
            rejected.get((row.estimator, row.snr_db), 10) / 1000 for row in summary.itertuples()
        ]
        notes = first_screen_notes(summary.assign(fit_rejected_rate=rates), None)
        (note,) = [n for n in notes if n.startswith("Goodness of fit")]
        return note

    # 21 of 1000 rejected is within chance at the 0.1% level (P(≥ 21) = 0.0015), 22 is not
    # (P(≥ 22) = 0.00065, binomial with p = 1%)
    note = fit_note({(worse, 0.0): 21})
    assert (
        "the data fit the model at every point (the best fit rejected in 1% of its trials)." in note
    )
    assert "answers off" not in note
    note = fit_note({(worse, 0.0): 22, (worse, 10.0): 500})
    assert f"<bdi>{worse}</bdi> on {scenario} (up to 500 of 1000)" in note  # at every point
    note = fit_note({(worse, 10.0): 500})
    assert f"<bdi>{worse}</bdi> on {scenario} at SNR 10 dB (up to 500 of 1000)" in note
    # every estimator rejected at 0 dB: the data, not an answer, do not fit there
    note = fit_note({(e, 0.0): 300 + i for i, e in enumerate(summary["estimator"].unique())})
    assert note.endswith(
        f"the data do not fit the model at {scenario} SNR 0 dB, where even the best fit, "
        f"<bdi>{best}</bdi>, is rejected in 300 of 1000 trials (an outlier, a wrong noise σ or "
        "a wrong constant?)."
    )


def test_geometry_sweep_draws_the_efficiency_heatmap_with_the_track():
    grid = [
        {"snr_db": 10.0, "emitter_x_m": x, "emitter_y_m": y}
        for y in (-40.0, 15.0, 60.0)
        for x in (-20.0, 35.0, 90.0)
    ]
    trials, points, experiment = synthetic_run(grid, n_trials=30, seed=3)
    summary = summarize(trials, n_bootstrap=50, swept_columns=experiment["swept_columns"])
    track = scenario_tracks_m(experiment)["paper-1m"]
    assert track.shape == (10, 3)
    assert track[-1] == pytest.approx([4.5, 0.0, 50.0])  # 10 m/s east for 9 × 0.05 s
    made = dict(
        (stem, figure)
        for stem, _, figure in report_figures(summary, trials, points, {"paper-1m": track})
    )
    assert list(made) == ["geometry", "error_cdf", "runtime"]  # no line plots over a grid

    bound_axes, cls_axes = made["geometry"].axes[0], made["geometry"].axes[1]
    assert cls_axes.get_title().endswith("cls")
    drawn = [line for line in cls_axes.get_lines() if line.get_label() == "UAV track"]
    assert drawn[0].get_xdata() == pytest.approx(track[:, 0])
    # The cls cell at emitter (35, 15) holds its side-resolved efficiency (cls is ambiguous).
    image = cls_axes.collections[0].get_array().reshape(3, 3)
    cls = summary[summary["estimator"] == "cls"].set_index(["emitter_y_m", "emitter_x_m"])
    assert image[1, 1] == pytest.approx(cls.loc[(15.0, 35.0), "efficiency_side_resolved"])
    assert image[1, 1] != pytest.approx(cls.loc[(15.0, 35.0), "efficiency"])
    bound_image = bound_axes.collections[0].get_array().reshape(3, 3)
    assert bound_image[0, 2] == pytest.approx(10 ** (-10 / 20))


def test_per_frame_run_draws_rmse_and_nees_against_the_frame():
    trials, points, _ = synthetic_run(
        [{"snr_db": 0.0}, {"snr_db": 20.0}], n_trials=40, frames=3, seed=4
    )
    summary = summarize(trials, n_bootstrap=50)
    made = dict((stem, figure) for stem, _, figure in report_figures(summary, trials, points, None))
    assert {"rmse_vs_frame", "nees_vs_frame", "rmse"} <= set(made)
    ml = summary[(summary["estimator"] == "ml") & (summary["snr_db"] == 0)]
    assert ml["crlb_rmse_m"].tolist() == pytest.approx([1, 1 / math.sqrt(2), 1 / math.sqrt(3)])
    # RMSE panel at SNR 0 dB: the accumulated ToA+Doppler bound from the points, per frame.
    rmse_axes = made["rmse_vs_frame"].axes[0]
    bound = next(ln for ln in rmse_axes.get_lines() if ln.get_label() == "√CRLB, ToA+Doppler")
    assert bound.get_ydata() == pytest.approx([1, 1 / math.sqrt(2), 1 / math.sqrt(3)])
    nees_axes = made["nees_vs_frame"].axes[0]
    line = next(ln for ln in nees_axes.get_lines() if ln.get_label() == "ml")
    assert line.get_ydata() == pytest.approx(ml["nees_side_resolved_mean"].to_numpy())
    low, high = nees_band(40)
    band = nees_axes.collections[0].get_paths()[0].vertices[:, 1]
    assert band.min() == pytest.approx(low) and band.max() == pytest.approx(high)


def test_experiment_metrics_choose_the_compact_columns(snr_run):
    folder, _, _ = snr_run
    summary = pd.read_csv(folder / "summary.csv")
    page = render_html(
        summary=summary,
        experiment={"metrics": ["efficiency", "rmse_m"]},
        run_info={},
        figure_entries=[],
        notes=[],
    )
    table = ET.fromstring(page.split("\n", 1)[1]).find(".//table[@id='summary-0-compact']")
    header = [th.text for th in table.find("thead").iter("th")]
    assert header == ["snr_db", "frame", "estimator", "efficiency", "rmse_m"]
    with pytest.raises(ValueError, match=r"^metrics: unknown metric columns \['rmse'\]"):
        render_html(
            summary=summary,
            experiment={"metrics": ["rmse"]},
            run_info={},
            figure_entries=[],
            notes=[],
        )


def test_missing_run_folder_names_the_field(tmp_path):
    with pytest.raises(ValueError, match=r"^run_dir: .* is not a folder"):
        write_report(tmp_path / "absent")


# --------------------------------------------------------------------------------------------
# a closed-loop run (planners)
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def closed_report(tmp_path_factory):
    from comparison.engine import run_experiment
    from comparison.experiment import Experiment

    experiment = Experiment.from_dict(
        {
            "name": "closed-report",
            "scenarios": ["paper-1m"],
            "estimators": [
                {"name": "ml"},
                {"name": "cls", "label": "cls-last", "options": {"frames": "last"}},
            ],
            "planners": ["constant", "paper", "orbit"],
            "steering_estimator": "ml",
            "trials": 6,
            "seed": 3,
            "frames": 3,
            "per_frame": True,
        }
    )
    folder = run_experiment(experiment, tmp_path_factory.mktemp("closed") / "run", workers=1)
    return folder, write_report(folder, n_bootstrap=100)


def test_closed_loop_report_has_planner_rows_figures_and_tables(closed_report):
    folder, html_path = closed_report
    summary = pd.read_csv(folder / "summary.csv")
    assert list(summary.columns[:5]) == ["scenario", "snr_db", "frame", "planner", "estimator"]
    assert len(summary) == 3 * 3 * 2  # frames × planners × estimators
    assert summary["n_trials"].eq(6).all()
    flights = pd.read_csv(folder / "flights.csv")
    assert len(flights) == 3 * 6 * 3  # planners × trials × frames
    stems = {
        "planner_rmse_vs_frame",
        "planner_rmse_side_resolved_vs_frame",
        "planner_wrong_side_vs_frame",
        "trajectories",
        "runtime",
    }
    assert {p.stem for p in (folder / "figures").glob("*.png")} == stems
    root = parse_html(html_path)
    (section,) = [s for s in root.iter("section") if s.get("id") == "closed-loop"]
    tables = {t.get("id"): t for t in section.iter("table")}
    last = tables["closed-loop-last"]
    header = [th.text for th in last.find("thead").iter("th")]
    body = [
        dict(zip(header, (text_of(td) for td in tr.iter("td")), strict=True))
        for tr in last.find("tbody").iter("tr")
    ]
    assert len(body) == 3 * 2
    final = summary[summary["frame"] == 2].set_index(["planner", "estimator"])
    for row in body:
        expected = final.loc[(row["planner"], row["estimator"])]
        assert row["rmse_m"] == format_number(expected["rmse_m"])
        assert row["crlb_rmse_m"] == format_number(expected["crlb_rmse_m"])
    frames = tables["closed-loop-frames"]
    assert [th.text for th in frames.find("thead").iter("th")][-3:] == [
        "frame 0",
        "frame 1",
        "frame 2",
    ]


def test_a_closed_loop_report_first_ranks_its_flights_by_the_error_after_each_frame(
    closed_report,
):
    """The question of a planner comparison, answered first: planner · estimator ranked by the
    returned position's RMSE after the last frame, with the RMSE after every frame, the
    wrong-side rate with its count and the bound of the flown paths; the verdicts second."""
    folder, html_path = closed_report
    summary = pd.read_csv(folder / "summary.csv")
    sections = [s.get("id") for s in parse_html(html_path).iter("section")]
    assert sections[:2] == ["flights", "verdicts"]
    section = next(s for s in parse_html(html_path).iter("section") if s.get("id") == "flights")
    (table,) = section.iter("table")
    rows = list(table.find("tbody").iter("tr"))
    last = summary[summary["frame"] == 2]
    assert len(rows) == len(last) == 6
    names = [text_of(tr.find("th")) for tr in rows]
    expected = last.sort_values("rmse_m", kind="stable")
    pairs = zip(expected["planner"], expected["estimator"], strict=True)
    assert names == [f"{planner} · {estimator}" for planner, estimator in pairs]
    for tr, (_, row) in zip(rows, expected.iterrows(), strict=True):
        cells = [td for td in tr.iter("td")]
        own = summary[
            (summary["planner"] == row["planner"]) & (summary["estimator"] == row["estimator"])
        ]
        by_frame = [f"{value:.3g}" for value in own.sort_values("frame")["rmse_m"]]
        assert [td.text for td in cells[1:4]] == by_frame  # after frames 0, 1, 2
        assert "".join(cells[4].itertext()).startswith(f"{row['rmse_m']:.3g} [")
        assert cells[5].text == f"{row['wrong_side_rate']:.3g} ({int(row['n_side_judged'])})"
        assert cells[6].text.startswith(f"{row['crlb_rmse_m']:.3g} (")


def test_closed_loop_figures_draw_the_summary(closed_report):
    from comparison import engine, figures

    folder, _ = closed_report
    trials = engine.read_trials(folder)
    summary = summarize(trials, n_bootstrap=50)
    figure = figures.planner_rmse_vs_frame_figure(summary)
    axes = [ax for ax in figure.axes if ax.get_visible()]
    assert [ax.get_title() for ax in axes] == ["paper-1m: ml", "paper-1m: cls-last"]
    line = next(ln for ln in axes[0].get_lines() if ln.get_label() == "orbit: RMSE")
    orbit = summary[(summary["planner"] == "orbit") & (summary["estimator"] == "ml")]
    assert line.get_ydata() == pytest.approx(orbit["rmse_m"].to_numpy())
    bound = next(
        ln for ln in axes[0].get_lines() if ln.get_label() == "orbit: √CRLB of the flown paths"
    )
    assert bound.get_ydata() == pytest.approx(orbit["crlb_rmse_m"].to_numpy())
    flights = engine.read_flights(folder)
    paths = figures.trajectory_figure(flights, trials, estimator="ml", n_paths=2)
    panels = [ax for ax in paths.axes if ax.get_visible()]
    assert len(panels) == 2 * 3  # paths and zoom rows, one column per planner
    path = next(ln for ln in panels[0].get_lines() if ln.get_label() == "trial 0")
    own = flights[(flights["planner"] == "constant") & (flights["trial"] == 0)]
    assert path.get_xdata() == pytest.approx(np.ravel(own[["start_x_m", "end_x_m"]].to_numpy()))
    with pytest.raises(ValueError, match=r"^estimator: 'ekf' has no rows"):
        figures.trajectory_figure(flights, trials, estimator="ekf")


def test_covariance_ellipse_is_the_n_sigma_contour():
    from comparison.figures import covariance_ellipse_m

    covariance = np.array([[4.0, 1.0], [1.0, 2.0]])
    ring = covariance_ellipse_m((1.0, -2.0), covariance, n_sigma=2.0)
    offsets = ring - [1.0, -2.0]
    mahalanobis = np.einsum("ij,jk,ik->i", offsets, np.linalg.inv(covariance), offsets)
    assert mahalanobis == pytest.approx(np.full(len(ring), 4.0))


def test_the_verdict_table_says_side_resolved_where_the_efficiency_is(snr_run):
    from comparison.verdict_table import verdict_table_html

    folder, _, _ = snr_run
    summary = pd.read_csv(folder / "summary.csv")
    header = lambda html: " ".join(" ".join(ET.fromstring(html).find("thead").itertext()).split())  # noqa: E731
    everywhere = summary.assign(verdict_basis="side-resolved")
    assert "dB; side-resolved efficiency at -10 / 10 / 30 dB" in header(
        verdict_table_html(everywhere).split("<p>")[0]
    )
    some = summary.assign(
        verdict_basis=np.where(summary["estimator"] == "ml", "side-resolved", "returned")
    )
    html = verdict_table_html(some).split("<p>")[0]
    assert "dB; efficiency (side-resolved for †) at" in header(html)
    marked = [
        tr.find("th").text
        for tr in ET.fromstring(html).find("tbody").iter("tr")
        if "†" in "".join(tr.itertext())
    ]
    assert marked == []  # ml is side-resolved at every point: its row is not mixed
    assert "biased" in verdict_table_html(summary)  # the legend names every verdict
