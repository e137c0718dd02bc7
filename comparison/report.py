"""The comparison report of a run folder: summary.csv, trials.csv, figures and report.html.

:func:`write_report` reads a run folder written by :mod:`comparison.engine`
(``experiment.json``, ``run.json``, ``results.sqlite``) and writes beside them:

- ``summary.csv``: :func:`comparison.metrics.summarize`, full precision, one row per
  (scenario, point, frame, estimator), and planner in a closed loop;
- ``trials.csv``: the tidy trial rows, one per estimator × scenario × point × frame × trial
  (× planner in a closed loop), for runs of at most
  :data:`~comparison.trials_csv.MAX_TRIALS_CSV_ROWS` rows (larger
  runs keep them in ``results.sqlite`` only, and the page says so); read again from
  ``results.sqlite`` and written in a forked process while the summary is worked out;
- ``flights.csv`` (closed loop): every frame flown, per planner and trial
  (:func:`comparison.engine.read_flights`);
- ``figures/<name>.png`` (150 dpi) and ``figures/<name>.svg`` for every figure of
  :mod:`comparison.figures` that applies to the sweep, chosen, captioned and drawn by
  :mod:`comparison.report_figures` (in worker processes, heaviest first);
- ``thresholds.csv``: per scenario and estimator of an SNR sweep, the threshold SNR from
  which every higher point attains the CRLB (:mod:`comparison.verdict_table`);
- ``report.html``: one self-contained file (figures embedded as base64 PNG, styles inline, no
  external resource). Its first screen is one verdict table (estimators × scenarios) with the
  notes the table cannot say (:mod:`comparison.verdict_table`); then the figures, the summary
  tables (one line per estimator instead for a scenario of more than :data:`MAX_TABLE_ROWS`
  summary rows), the metric definitions, the experiment definition and the run's
  provenance. The markup is XHTML-compatible, so any XML parser reads it.

The tables print every number with :func:`comparison.metrics.format_number` (4 significant
digits) from the same frame that is written to ``summary.csv``.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from comparison import verdict_table
from comparison.front_end_table import front_end_section_html
from comparison.intervals import DEFAULT_N_BOOTSTRAP
from comparison.labels import LABEL_COLUMNS, label_html, plain_label
from comparison.metric_groups import summary_trial_columns
from comparison.metric_registry import METRIC_NAMES, METRICS, UNITS
from comparison.metrics import (
    format_number,
    has_planners,
    summarize,
    summarize_chunks,
    summary_swept_columns,
    swept_columns_of,
)
from comparison.planner_table import planner_table_html
from comparison.run_folder import holding_report_lock, write_atomic, write_csv
from comparison.trials_csv import (
    TRIALS_CSV_LIMIT,
    trial_batches,
    trials_csv_forked,
    trials_csv_note,
)
from comparison.verdicts import VERDICTS
from scenarios.limits import configured_limit

BOOTSTRAP_STREAM = 2**31 + 7
"""Spawn key of the bootstrap's seed sequence under the experiment seed (no trial uses it)."""

MAX_TABLE_ROWS = 1000
"""Most summary rows of one scenario printed as tables in report.html. A scenario with more
(a dense sweep) gets one line per estimator instead: its verdicts counted and the range of
its judged efficiency; every row stays in summary.csv."""

HEIGHT_COLUMNS: tuple[str, ...] = (
    "rmse_horizontal_m",
    "crlb_horizontal_m",
    "rmse_vertical_m",
    "crlb_vertical_m",
    "bias_z_m",
)
"""The summary table's columns of a 3-D run (the height estimated, MATH §8), before
``efficiency``."""

COMPACT_COLUMNS: tuple[str, ...] = (
    "n_trials",
    "rmse_m",
    "rmse_ci_low_m",
    "rmse_ci_high_m",
    "rmse_side_resolved_m",
    "crlb_rmse_m",
    "efficiency",
    "efficiency_side_resolved",
    "verdict",
    "mean_error_m",
    "cep50_m",
    "wrong_side_rate",
    "n_side_judged",
    "success_rate",
    "nees_side_resolved_mean",
    "n_nees",
    "nees_verdict",
    "fit_rejected_rate",
    "n_fit_judged",
    "runtime_median_s",
)
"""Metric columns of the compact per-scenario tables unless the experiment lists its own
``metrics``; every column is in the full tables."""

SNR_CAPTION = (
    "SNR axis (MATH §2): each scenario has reference noise standard deviations "
    "(σ_f for Doppler, σ_τ for ToA, σ_P for RSS) at 0 dB; at a given SNR every one of them is "
    "multiplied by 10^(−SNR/20). The SNR is therefore a common scale of all noise levels, not "
    "the signal-to-noise ratio of a receiver."
)

CN0_CAPTION = (
    "C/N0 axis (MATH §18-§20): every trial receives the emitter's bursts as complex samples "
    "with white noise at the carrier-to-noise density C/N0 (dB-Hz); a burst's SNR is C/N0 "
    "times its length. The front end measures each burst's Doppler and ToA from them; the "
    "estimators of measurements read those, outliers below its threshold included, and dpd "
    "reads the samples; a two-step estimate's runtime holds its share of the front end's. "
    "√CRLB is the bound of the σ's the bursts allow at the point's C/N0 (Rife-Boorstyn for "
    "the frequency, the RMS-bandwidth bound for the delay), the signal-level bound (MATH §21)."
)

MATH_CAPTION = (
    "MATH §N everywhere in this report is section §N of docs/math.md, emitterbench's account "
    "of the corrected mathematics of the paper (the model, the closed form and its errata, "
    "the CRLB); §16 explains the verdicts and their intervals."
)

CLOSED_LOOP_CAPTION = (
    "Closed loop (MATH §12-§13): every trial flies the scenario's first frame, then each "
    "next frame at the velocity a planner chose from the steering estimator's estimate after "
    "the previous frame. Every planner meets the same noise (common random numbers), and "
    "constant reproduces the open-loop flight. Each trial flies its own trajectory, so its "
    "rows carry the CRLB of that trajectory at the truth; summaries show the root mean square "
    "of these over trials (a reference for the RMSE rather than a strict bound, since the "
    "trajectory depends on earlier noise). The wrong side is judged against the track of the "
    "first frame an estimator uses, in the trial's own flight: frame 0 for a cumulative "
    "estimator (the mirror ambiguity a turn must resolve), the current frame for a per-frame "
    "one. The side of a later track is ill-defined when a planner flies through the "
    "emitter's horizontal position."
)

SIDE_CAPTION = (
    "Side-resolved metrics (MATH §7): Doppler and ToA from one straight frame are identical "
    "for the emitter and its mirror image across the vertical plane through the track, so no "
    "estimator can tell the side. Estimators report every equal-cost candidate; the "
    "side-resolved error is that of the candidate nearest to the truth (what the paper's "
    "figures implicitly assume). The error of the returned position and the wrong-side rate "
    "(returned position and truth on opposite sides of the last frame's track) show what the "
    "ambiguity costs. √CRLB is the square root of the trace of the inverse Fisher information "
    "over the samples and modalities an estimator uses (MATH §8)."
)

_STYLE = (
    """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px;
       padding: 0 1em; color: #222; line-height: 1.45; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; margin-top: 2em; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; height: auto; }
figcaption { font-size: 0.92em; color: #444; }
.table-wrap { overflow-x: auto; margin: 0.8em 0; }
table { border-collapse: collapse; font-size: 0.82em; }
th, td { border: 1px solid #ddd; padding: 2px 6px; text-align: right; white-space: nowrap; }
th { background: #f3f3f3; }
td:nth-child(1), th:nth-child(1) { text-align: left; }
pre { background: #f7f7f7; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
.criterion { background: #f4f8ff; border-left: 4px solid #4a78c2; padding: 0.5em 0.8em; }
dt { font-family: monospace; font-weight: bold; } dd { margin: 0 0 0.4em 1.5em; }
.notes li { margin-bottom: 0.3em; }
"""
    + verdict_table.STYLE
)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path.name}: not valid JSON ({error}); rerun the experiment") from None


def _load(
    run_dir: Path,
    points: pd.DataFrame | None,
    experiment: Mapping[str, Any] | None,
    run_info: Mapping[str, Any] | None,
) -> tuple[pd.DataFrame | None, dict[str, Any], dict[str, Any]]:
    """The run's points, experiment and run.json: the given ones, else the engine's readers
    (imported only then). The trial rows are read a chunk at a time (:func:`_summary`)."""
    if points is None or experiment is None:
        from comparison import engine

        if experiment is None:
            experiment = engine.read_experiment(run_dir)
        if points is None:
            points = engine.read_points(run_dir)
    if run_info is None:
        run_path = run_dir / "run.json"
        run_info = _read_json(run_path) if run_path.exists() else {}
    return points, experiment_dict(experiment), dict(run_info)


def _summary(
    run_dir: Path,
    trials: pd.DataFrame | None,
    experiment: Mapping[str, Any],
    n_bootstrap: int,
    layout: Any = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """:func:`comparison.metrics.summarize` of the given rows, else of results.sqlite read a
    few points at a time (:func:`comparison.store.iter_trials`; ``layout`` is its
    :func:`comparison.store.trial_layout`), with the rows the figures read: the given ones,
    else their columns (:func:`comparison.report_figures.figure_trial_columns`) kept from the
    same reading."""
    seed = np.random.SeedSequence(int(experiment.get("seed", 0)), spawn_key=(BOOTSTRAP_STREAM,))
    swept = experiment.get("swept_columns")
    swept = None if swept is None else list(swept)
    if trials is not None:
        summary = summarize(trials, n_bootstrap=n_bootstrap, seed=seed, swept_columns=swept)
        return summary, trials
    from comparison import store
    from comparison.report_figures import figure_trial_columns

    closed = any(label != "" for label in layout.orders["planner"])
    readable = summary_trial_columns(layout.dimension)
    columns = [c for c in readable if closed or c != "planner"]
    shown = figure_trial_columns(closed_loop=closed)
    kept: list[pd.DataFrame] = []

    def chunks() -> Iterator[pd.DataFrame]:
        for chunk in store.iter_trials(run_dir, [*columns, *shown]):
            drawn = {*shown, *swept_columns_of(chunk)}  # store.read_trials(run_dir, shown)
            kept.append(chunk[[c for c in chunk.columns if c in drawn]])
            yield chunk

    summary = summarize_chunks(
        chunks(),
        orders=layout.orders,
        n_trial_sets=layout.n_trial_sets,
        swept_columns=swept,
        n_bootstrap=n_bootstrap,
        seed=seed,
    )
    figure_trials = pd.concat(kept, ignore_index=True) if len(kept) > 1 else kept[0]
    return summary, figure_trials


def experiment_dict(experiment: Any) -> dict[str, Any]:
    """The experiment definition as a plain dict (from a mapping or an ``Experiment``)."""
    if isinstance(experiment, Mapping):
        return dict(experiment)
    to_dict = getattr(experiment, "to_dict", None)
    if callable(to_dict):
        return dict(to_dict())
    raise ValueError(
        f"experiment: expected the parsed experiment.json (a dict) or an Experiment, "
        f"got {type(experiment).__name__}"
    )


def scenario_tracks_m(experiment: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """UAV positions ``(n, 3)`` of each catalogue scenario named in ``experiment``.

    Scenarios are catalogue names, flown for the experiment's ``frames`` when it gives them;
    an entry that is not a known name is skipped (no track is drawn for it).
    """
    from scenarios.catalog import get_scenario

    tracks: dict[str, np.ndarray] = {}
    for entry in experiment.get("scenarios", []) or []:
        if not isinstance(entry, str):
            continue
        try:
            scenario = get_scenario(entry, frames=experiment.get("frames"))
        except (ValueError, TypeError):
            continue
        tracks[entry] = scenario.flight.sample_positions_m()
    return tracks


def _png_data_uri(png_path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(png_path.read_bytes()).decode("ascii")


def _escape(value: object) -> str:
    return html.escape(str(value), quote=True)


def _table_html(frame: pd.DataFrame, table_id: str) -> str:
    """``frame`` as an XHTML-compatible table, numbers by :func:`format_number`, the labels
    (columns ``estimator`` and ``planner``) in ``<bdi>``, other text escaped."""
    formatters = {
        column: format_number
        if pd.api.types.is_numeric_dtype(frame[column])
        else label_html
        if column in LABEL_COLUMNS
        else _escape
        for column in frame.columns
    }
    return frame.to_html(
        index=False,
        formatters=formatters,
        na_rep="NaN",
        border=0,
        table_id=table_id,
        classes="summary",
        escape=False,
    )


def _value_html(value: Any) -> str:
    """A JSON value as nested XHTML tables and lists."""
    if isinstance(value, Mapping):
        if not value:
            return "<em>none</em>"
        rows = "".join(
            f"<tr><th>{_escape(k)}</th><td>{_value_html(v)}</td></tr>" for k, v in value.items()
        )
        return f'<table class="info">{rows}</table>'
    if isinstance(value, list | tuple):
        if all(not isinstance(v, Mapping | list | tuple) for v in value):
            return ", ".join(_value_html(v) for v in value)
        return "<ol>" + "".join(f"<li>{_value_html(v)}</li>" for v in value) + "</ol>"
    return label_html(value) if isinstance(value, str) else _escape(value)


def _summary_tables(summary: pd.DataFrame, metrics: Sequence[str] | None = None) -> str:
    """Per scenario: the chosen metrics at the last frame, and every metric in a fold."""
    from comparison.figures import is_per_frame

    chosen = list(COMPACT_COLUMNS if metrics is None else metrics)
    unknown = [m for m in chosen if m not in METRIC_NAMES]
    if unknown:
        raise ValueError(
            f"metrics: unknown metric columns {unknown}; choose from {', '.join(METRIC_NAMES)}"
        )
    if metrics is None:  # a 3-D run's horizontal and vertical parts beside the 3-D ones
        chosen[chosen.index("efficiency") : chosen.index("efficiency")] = HEIGHT_COLUMNS
    chosen = [m for m in chosen if m in summary.columns]  # the height's only in 3-D runs
    swept = summary_swept_columns(summary)
    planner = ["planner"] if "planner" in summary.columns else []
    key_columns = ["snr_db", *swept, "frame", *planner, "estimator"]
    latest = summary.groupby(["scenario", "snr_db", *swept, *planner, "estimator"], sort=False)[
        "frame"
    ].transform("max")
    parts = []
    for index, (scenario, rows) in enumerate(summary.groupby("scenario", sort=False)):
        if len(rows) > MAX_TABLE_ROWS:
            parts.append(_overview_html(str(scenario), rows, index))
            continue
        compact = rows[rows["frame"] == latest[rows.index]][[*key_columns, *chosen]]
        full = rows.drop(columns="scenario")
        note = " (last frame of each point)" if is_per_frame(rows) else ""
        parts.append(
            f'<section class="scenario-tables" data-scenario="{_escape(scenario)}">'
            f"<h3>{_escape(scenario)}{note}</h3>"
            f'<div class="table-wrap">{_table_html(compact, f"summary-{index}-compact")}</div>'
            f"<details><summary>every metric of {_escape(scenario)} "
            f"({len(full)} rows)</summary>"
            f'<div class="table-wrap">{_table_html(full, f"summary-{index}-full")}</div>'
            "</details></section>"
        )
    return "".join(parts)


def overview_table(rows: pd.DataFrame) -> pd.DataFrame:
    """One line per estimator (planner · estimator in a closed loop) over the last frame of
    every point of ``rows``: points, the count of each verdict, and the smallest, median and
    largest judged efficiency."""
    judged = verdict_table.judged_points(rows)
    efficiency = judged["efficiency_judged"].where(np.isfinite(judged["efficiency_judged"]))
    by_row = judged.assign(efficiency=efficiency).groupby("row", sort=False)
    counts = by_row["verdict"].value_counts().unstack(fill_value=0)
    table = pd.DataFrame({"points": by_row.size()})
    for verdict in VERDICTS:
        table[verdict] = counts[verdict] if verdict in counts.columns else 0
    table["efficiency_min"] = by_row["efficiency"].min()
    table["efficiency_median"] = by_row["efficiency"].median()
    table["efficiency_max"] = by_row["efficiency"].max()
    return table.rename_axis("estimator").reset_index()


def _overview_html(scenario: str, rows: pd.DataFrame, index: int) -> str:
    """The tables of a scenario of more than :data:`MAX_TABLE_ROWS` rows: a sentence saying
    where the rows are, and :func:`overview_table`."""
    n_points = len(rows.drop_duplicates(["snr_db", *summary_swept_columns(rows)]))
    sentence = (
        f"{len(rows):,} summary rows on {scenario} ({n_points:,} points), more than the "
        f"{MAX_TABLE_ROWS:,} this page prints: every row, with every metric, is in summary.csv. "
        "Here, one line per estimator over the last frame of every point: how many points get "
        "each verdict, and the smallest, median and largest judged efficiency (RMSE/√CRLB, "
        "side-resolved where the estimator flags ambiguity)."
    )
    table = _table_html(overview_table(rows), f"summary-{index}-overview")
    return (
        f'<section class="scenario-overview" data-scenario="{_escape(scenario)}">'
        f"<h3>{_escape(scenario)}</h3><p>{_escape(sentence)}</p>"
        f'<div class="table-wrap">{table}</div></section>'
    )


def closed_loop_table(summary: pd.DataFrame, *, from_frame: int = 2) -> pd.DataFrame:
    """The last frame of each (scenario, point, planner, estimator), with the worst wrong-side
    rate from frame ``from_frame`` (0-based) to the last.

    Columns ``scenario, snr_db, <swept>, planner, estimator, frame``, then ``rmse_m`` with its
    interval, ``rmse_side_resolved_m``, ``crlb_rmse_m``, ``efficiency``, ``wrong_side_rate``
    and ``max_wrong_side_rate_from_frame_<from_frame>``.
    """
    swept = summary_swept_columns(summary)
    keys = ["scenario", "snr_db", *swept, "planner", "estimator"]
    latest = summary.groupby(keys, sort=False)["frame"].transform("max")
    last = summary[summary["frame"] == latest]
    later = summary[summary["frame"] >= from_frame]
    worst = (
        later.groupby(keys, sort=False)["wrong_side_rate"]
        .max()
        .rename(f"max_wrong_side_rate_from_frame_{from_frame}")
    )
    columns = [
        "rmse_m",
        "rmse_ci_low_m",
        "rmse_ci_high_m",
        "rmse_side_resolved_m",
        "crlb_rmse_m",
        "efficiency",
        "wrong_side_rate",
    ]
    table = last[[*keys, "frame", *columns]].merge(worst.reset_index(), on=keys, how="left")
    return table.reset_index(drop=True)


def rmse_by_frame_table(summary: pd.DataFrame) -> pd.DataFrame:
    """RMSE per frame: one row per (scenario, point, planner, estimator), a column per frame."""
    swept = summary_swept_columns(summary)
    keys = ["scenario", "snr_db", *swept, "planner", "estimator"]
    table = summary.pivot_table(index=keys, columns="frame", values="rmse_m", sort=False)
    table.columns = [f"frame {int(c)}" for c in table.columns]
    return table.reset_index()


def _closed_loop_section(summary: pd.DataFrame, experiment: Mapping[str, Any]) -> str:
    """The closed-loop section: how to read it, the last-frame table, RMSE per frame."""
    if "planner" not in summary.columns:
        return ""
    steering = experiment.get("steering_estimator")
    planners = experiment.get("planners") or []
    steer_text = ", ".join(
        f"{label_html(p.get('label') or p.get('name'))} by "
        f"{label_html(p.get('steering_estimator') or steering)}"
        for p in planners
        if isinstance(p, Mapping)
    )
    last = _table_html(closed_loop_table(summary), "closed-loop-last")
    by_frame = _table_html(rmse_by_frame_table(summary), "closed-loop-frames")
    return (
        '<section id="closed-loop"><h2>Closed loop: planners</h2>'
        f"<p>{_escape(CLOSED_LOOP_CAPTION)}</p>"
        + (f"<p>Steering estimator per planner: {steer_text}.</p>" if steer_text else "")
        + "<h3>Last frame, and the worst wrong-side rate from frame 2 on</h3>"
        f'<div class="table-wrap">{last}</div>'
        "<h3>RMSE of the returned position (m) per frame</h3>"
        f'<div class="table-wrap">{by_frame}</div></section>'
    )


def _metric_definitions() -> str:
    """Every metric of :mod:`comparison.metric_registry`: its column, unit and meaning."""
    items = "".join(
        f"<dt>{_escape(m.name)} ({_escape(UNITS[m.unit])})</dt><dd>{_escape(m.description)}</dd>"
        for m in METRICS
    )
    return f"<dl>{items}</dl>"


def _experiment_overview(experiment: Mapping[str, Any], definition: str | None) -> str:
    shown = {
        key: experiment[key]
        for key in ("name", "description", "trials", "seed", "estimators", "scenarios", "sweep")
        if key in experiment
    }
    if definition is None:
        definition = json.dumps(experiment, indent=2, default=str)
    return (
        _value_html(shown)
        + "<details><summary>experiment.json</summary>"
        + f"<pre>{_escape(definition)}</pre></details>"
    )


def render_html(
    *,
    summary: pd.DataFrame,
    experiment: Mapping[str, Any],
    run_info: Mapping[str, Any],
    figure_entries: list[tuple[str, str, str]],
    notes: list[str],
    experiment_text: str | None = None,
    file_notes: Sequence[str] = (),
    bursts: pd.DataFrame | None = None,
) -> str:
    """The report page; ``figure_entries`` are ``(stem, caption, data URI)``, ``notes`` the
    XHTML sentences of :func:`comparison.verdict_table.first_screen_notes`.

    ``experiment_text`` is the text of experiment.json, shown verbatim (default: ``experiment``
    as JSON); ``file_notes`` are sentences about the files written, shown above the summary
    tables (:func:`~comparison.trials_csv.trials_csv_note`); ``bursts`` the front end's rows
    of a signal-level run (:func:`comparison.store.read_bursts`).
    """
    name = str(experiment.get("name", "experiment"))
    description = experiment.get("description", "")
    seed = experiment.get("seed", run_info.get("seed", ""))
    figures_html = "".join(
        f'<figure id="figure-{_escape(stem)}"><img src="{uri}" alt="{_escape(caption)}"/>'
        f"<figcaption><strong>{_escape(stem)}</strong> ({_escape(stem)}.png, "
        f"{_escape(stem)}.svg in figures/): {_escape(caption)}</figcaption></figure>"
        for stem, caption, uri in figure_entries
    )
    statements = "".join(f"<li>{note}</li>" for note in notes)
    files = "".join(f'<p class="file-note">{_escape(note)}</p>' for note in file_notes)
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8"/>'
        '<meta name="viewport" content="width=device-width, initial-scale=1"/>'
        f"<title>emitterbench report: {_escape(plain_label(name))}</title>"
        f"<style>{_STYLE}</style></head><body>"
        f"<h1>emitterbench report: {label_html(name)}</h1>"
        f"<p>{_escape(description)}</p>"
        f"<p>Seed {_escape(seed)}; {int(summary['n_trials'].sum())} estimates in "
        f"{len(summary)} summary rows (estimators: {summary['estimator'].nunique()}, "
        f"scenarios: {summary['scenario'].nunique()}).</p>"
        + (
            '<section id="flights"><h2>Which flight locates best</h2>'
            f"{planner_table_html(summary)}</section>"
            if has_planners(summary)
            else ""
        )
        + '<section id="verdicts"><h2>Verdicts</h2>'
        f"{verdict_table.verdict_table_html(summary)}"
        + (f'<ul class="notes">{statements}</ul>' if statements else "")
        + "</section>"
        + front_end_section_html(bursts, experiment)
        + '<section id="reading"><h2>How to read this report</h2>'
        f"<p>{_escape(CN0_CAPTION if experiment.get('signal') else SNR_CAPTION)}</p>"
        f"<p>{_escape(SIDE_CAPTION)}</p>"
        f"<p>{_escape(MATH_CAPTION)}</p></section>"
        f"{_closed_loop_section(summary, experiment)}"
        f'<section id="figures"><h2>Figures</h2>{figures_html}</section>'
        f'<section id="tables"><h2>Summary tables</h2>{files}'
        "<p>Every number below is the value in summary.csv printed to 4 significant digits; "
        "error metrics are over the successful trials, rates as fractions.</p>"
        f"{_summary_tables(summary, experiment.get('metrics'))}</section>"
        f'<section id="metrics"><h2>Metric definitions</h2>{_metric_definitions()}</section>'
        f'<section id="experiment"><h2>Experiment</h2>{_experiment_overview(experiment, experiment_text)}'
        "</section>"
        f'<section id="run"><h2>Run: versions, machine, times</h2>{_value_html(run_info)}'
        "</section></body></html>\n"
    )


@holding_report_lock
def write_report(
    run_dir: str | Path,
    *,
    trials: pd.DataFrame | None = None,
    points: pd.DataFrame | None = None,
    experiment: Mapping[str, Any] | None = None,
    run_info: Mapping[str, Any] | None = None,
    tracks_m: Mapping[str, np.ndarray] | None = None,
    flights: pd.DataFrame | None = None,
    n_bootstrap: int = DEFAULT_N_BOOTSTRAP,
    dpi: int = 150,
    max_trials_csv_rows: int | None = None,
) -> Path:
    """Write summary.csv, trials.csv, figures/ and report.html into ``run_dir``, holding its
    lock (:func:`comparison.run_folder.report_lock`): every file comes from one reading of
    the run, which no session changes meanwhile.

    Parameters
    ----------
    run_dir : str or Path
        The run folder (``experiment.json``, ``run.json``, ``results.sqlite``).
    trials, points, experiment, run_info : optional
        The run's data, bypassing :func:`comparison.engine.read_trials`,
        :func:`~comparison.engine.read_points`, :func:`~comparison.engine.read_experiment`
        and ``run.json``.
    tracks_m : mapping, optional
        Scenario → UAV positions ``(n, 2 or 3)`` for the geometry heatmap; by default the
        tracks of the catalogue scenarios named in the experiment (:func:`scenario_tracks_m`).
    flights : pandas.DataFrame, optional
        The frames flown in a closed loop, bypassing :func:`comparison.engine.read_flights`
        (written to ``flights.csv``; drawn in the trajectory figure).
    n_bootstrap : int
        Bootstrap resamples; the bootstrap is seeded from the experiment's seed.
    dpi : int
        Resolution of the PNG figures.
    max_trials_csv_rows : int, optional
        Most trial rows written to trials.csv (default
        :data:`~comparison.trials_csv.MAX_TRIALS_CSV_ROWS`, or the
        environment variable ``EMITTERBENCH_MAX_TRIALS_CSV_ROWS``); a run with more writes
        none, removes an earlier report's, and says so on the page.

    Returns
    -------
    Path
        The path of ``report.html``.
    """
    folder = Path(run_dir)
    limit = (
        configured_limit(TRIALS_CSV_LIMIT) if max_trials_csv_rows is None else max_trials_csv_rows
    )
    if trials is None:
        from comparison import store

        n_rows = store.count_trials(folder)
    else:
        n_rows = len(trials)
    # trials.csv from results.sqlite in a process of its own, started first: it overlaps the
    # reading of the run and the summary
    forked = trials is None and n_rows <= limit
    with trials_csv_forked(folder, forked) as csv_written:
        points, experiment, run_info = _load(folder, points, experiment, run_info)
        layout = None if trials is not None else store.trial_layout(folder)
        # the figures' columns kept from the summary's reading (matplotlib imported with them)
        summary, figure_trials = _summary(folder, trials, experiment, n_bootstrap, layout)
        write_csv(folder / "summary.csv", summary)
        write_csv(folder / "thresholds.csv", verdict_table.thresholds(summary))
        file_notes = []
        from comparison import figures
        from comparison.report_figures import FIGURE_STEMS, figure_plans, write_figures

        steering = None
        if "planner" in summary.columns:
            if flights is None and (folder / "results.sqlite").is_file():
                from comparison import engine

                flights = engine.read_flights(folder)
            if flights is not None:
                write_csv(folder / "flights.csv", flights)
            steering = experiment.get("steering_estimator")
            if steering is None and experiment.get("estimators"):
                first = experiment["estimators"][0]
                if isinstance(first, Mapping):
                    steering = first.get("label") or first.get("name")
                else:
                    steering = str(first)
        bursts = None
        if experiment.get("signal") and (folder / "results.sqlite").is_file():
            from comparison import store

            bursts = store.read_bursts(folder)
            write_csv(folder / "bursts.csv", bursts)
        if tracks_m is None and figures.is_geometry_sweep(summary):
            tracks_m = scenario_tracks_m(experiment)

        def write_trials_csv() -> None:
            """The rows as text, a batch at a time from results.sqlite (or none, said on the page);
            or wait for the process writing them."""
            if csv_written is not None:
                csv_written()
            elif n_rows <= limit:
                write_csv(
                    folder / "trials.csv", trials if trials is not None else trial_batches(folder)
                )
            else:
                (folder / "trials.csv").unlink(missing_ok=True)  # an earlier report's, now stale
                file_notes.append(trials_csv_note(n_rows, limit))

        figure_dir = folder / "figures"
        plans = figure_plans(
            summary, figure_trials, points, tracks_m, flights, steering_estimator=steering
        )
        # each file replaced whole, the old one kept till then; trials.csv written meanwhile
        made = write_figures(plans, figure_dir, dpi=dpi, meanwhile=write_trials_csv)
    entries = [(stem, caption, _png_data_uri(png_path)) for stem, caption, png_path in made]
    drawn = {stem for stem, _, _ in made}
    for stale in set(FIGURE_STEMS) - drawn:  # an earlier report's, once the new ones are in
        for suffix in (".png", ".svg"):
            (figure_dir / f"{stale}{suffix}").unlink(missing_ok=True)
    definition_path = folder / "experiment.json"
    page = render_html(
        summary=summary,
        experiment=experiment,
        run_info=run_info,
        figure_entries=entries,
        notes=verdict_table.first_screen_notes(summary, points),
        experiment_text=definition_path.read_text(encoding="utf-8")
        if definition_path.is_file()
        else None,
        file_notes=file_notes,
        bursts=bursts,
    )
    path = folder / "report.html"
    write_atomic(path, page)
    return path
