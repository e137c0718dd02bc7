"""The report's first screen: one verdict table, and notes for what the table cannot say.

The table has a row per estimator (per planner and estimator in a closed loop) and a column
per scenario. A cell of an SNR sweep holds the threshold SNR (the lowest SNR from which every
higher point attains the CRLB, :func:`comparison.verdicts.threshold_snr`) and the judged
efficiency at up to three SNRs, each coloured by its verdict (a C/N0 sweep of the signal level,
MATH §18, the same in dB-Hz); a cell of another sweep holds
how many points attain and the range of the efficiency. Per-frame runs are judged at the last
frame. The notes (:func:`first_screen_notes`) are computed from the summary and the points
table: a modality that carries no information, verdicts that rest on too few trials or on a few
trials far away, failures, covariance consistency, whether the data fit the model at the
answers (MATH §17), and which errors were judged side-resolved.
"""

from __future__ import annotations

import html
import math

import numpy as np
import pandas as pd
from scipy import special

from comparison.labels import label_html
from comparison.metrics import has_planners, parameter_label, summary_swept_columns
from comparison.trial_rows import POINT_HEIGHT_CRLB
from comparison.verdicts import (
    MIN_SUCCESS_RATE,
    MIN_TRIALS,
    TAIL_SHARE_LIMIT,
    threshold_snr,
    verdict_criterion,
)
from estimators.goodness_of_fit import FIT_TEST_LEVEL

FIT_EXCESS_LEVEL = 0.001
"""A share of rejected fits is more than chance allows when a binomial count of rejections
(each with probability ``FIT_TEST_LEVEL`` under the model) that large has probability at most
this."""

UNINFORMATIVE_RATIO = 100.0
"""A modality whose bound alone exceeds this many times the geometry's size carries no
usable information (the note says so)."""

VERDICT_COLOURS = {
    "attains": "#cdebc8",
    "above": "#f4c9c4",
    "below": "#d4d0f2",
    "biased": "#f2dca6",
    "inconclusive": "#e6e6e6",
}

STYLE = """
table.verdicts { border-collapse: collapse; font-size: 0.9em; margin: 0.5em 0; }
table.planners { font-size: 0.78em; }
table.verdicts th, table.verdicts td { border: 1px solid #ccc; padding: 3px 8px;
  text-align: left; vertical-align: top; white-space: nowrap; }
table.verdicts th small { font-weight: normal; color: #555; }
.threshold { font-weight: bold; }
.v { display: inline-block; padding: 0 4px; margin-right: 2px; border-radius: 3px; }
.strip { display: inline-block; margin-left: 6px; }
.strip .sq { display: inline-block; width: 8px; height: 11px; margin-right: 1px;
  border: 1px solid #999; }
.strip .ends { font-size: 0.75em; color: #555; margin: 0 3px; }
""" + "".join(
    f".v-{name} {{ background: {colour}; }}\n" for name, colour in VERDICT_COLOURS.items()
)


def _escape(value: object) -> str:
    return html.escape(str(value), quote=True)


def row_html(own: pd.DataFrame) -> str:
    """The label of the table row of ``own`` (rows of one estimator, or one planner and
    estimator) as XHTML, each label in ``<bdi>`` (:func:`comparison.labels.label_html`)."""
    first = own.iloc[0]
    estimator = label_html(first["estimator"])
    return f"{label_html(first['planner'])} · {estimator}" if "planner" in own else estimator


def judged_points(summary: pd.DataFrame) -> pd.DataFrame:
    """The summary at the last frame of every point, with a ``row`` label per table row."""
    swept = summary_swept_columns(summary)
    planners = has_planners(summary)
    keys = ["scenario", "snr_db", *swept, *(["planner"] if planners else []), "estimator"]
    latest = summary.groupby(keys, sort=False)["frame"].transform("max")
    rows = summary[summary["frame"] == latest].copy()
    if planners:
        rows["row"] = rows["planner"].astype(str) + " · " + rows["estimator"].astype(str)
    else:
        rows["row"] = rows["estimator"].astype(str)
    return rows


LEVEL_UNITS = {"snr_db": "dB", "cn0_dbhz": "dB-Hz"}
"""The levels a threshold is found along, and their units: the SNR of MATH §2, and the C/N0
of the signal level (MATH §18)."""


def level_axis(rows: pd.DataFrame, swept: list[str]) -> str | None:
    """The level the rows sweep alone (``snr_db``, or ``cn0_dbhz`` at the signal level),
    every other swept column constant; None for any other sweep."""
    for axis in LEVEL_UNITS:
        if axis not in rows.columns or rows[axis].nunique() <= 1:
            continue
        others = [c for c in ("snr_db", *swept) if c != axis and c in rows.columns]
        if all(rows[c].nunique() <= 1 for c in others):
            return axis
    return None


def thresholds(summary: pd.DataFrame) -> pd.DataFrame:
    """Threshold SNR per scenario and row (NaN threshold outside an SNR sweep); in a run
    that sweeps C/N0 (MATH §18), ``threshold_cn0_dbhz`` beside it.

    Columns ``scenario``, ``planner`` (closed loop only), ``estimator``,
    ``threshold_snr_db``, (``threshold_cn0_dbhz``), ``n_points``, ``n_attains``.
    """
    rows = judged_points(summary)
    swept = summary_swept_columns(summary)
    by = ["scenario", *(["planner"] if has_planners(summary) else []), "estimator"]
    parts = []
    for _, own in rows.groupby("scenario", sort=False):
        axis = level_axis(own, swept)
        table = threshold_snr(own, by, axis or "snr_db")
        if axis is None:
            table["threshold_snr_db"] = math.nan
        elif axis != "snr_db":
            table.insert(len(by), "threshold_snr_db", math.nan)
        parts.append(table)
    return pd.concat(parts, ignore_index=True)


def threshold_of(threshold: pd.DataFrame, match: pd.Series) -> np.ndarray:
    """The thresholds of the ``match`` rows, along the run's level (C/N0 in a run that sweeps
    it: every scenario of a signal-level run does)."""
    column = "threshold_cn0_dbhz" if "threshold_cn0_dbhz" in threshold else "threshold_snr_db"
    return threshold.loc[match, column].to_numpy(float)


def _shown_snrs(values: np.ndarray) -> list[float]:
    ordered = sorted(set(float(v) for v in values))
    if len(ordered) <= 3:
        return ordered
    return [ordered[0], ordered[(len(ordered) - 1) // 2], ordered[-1]]


def _span(value: float, verdict: str, reason: str) -> str:
    text = "–" if not math.isfinite(value) else f"{value:.3g}"
    return f'<span class="v v-{_escape(verdict)}" title="{_escape(verdict + ": " + reason)}">{text}</span>'


def verdict_table_html(summary: pd.DataFrame) -> str:
    """The first screen's table (module docstring), XHTML-compatible."""
    rows = judged_points(summary)
    swept = summary_swept_columns(summary)
    threshold = thresholds(summary)
    scenarios = list(rows["scenario"].unique())
    labels = ranked_rows(rows, threshold)
    header = ["<th>estimator<br/><small>best first</small></th>"]
    shown: dict[str, list[float] | None] = {}
    for scenario in scenarios:
        own = rows[rows["scenario"] == scenario]
        basis = own["verdict_basis"] == "side-resolved"
        efficiency = (
            "side-resolved efficiency"
            if basis.all()
            else "efficiency (side-resolved for †)"
            if basis.any()
            else "efficiency"
        )
        level = level_axis(own, swept)
        if level is not None:
            name, unit = parameter_label(level)[0], LEVEL_UNITS[level]
            shown[scenario] = _shown_snrs(own[level].to_numpy())
            axis = " / ".join(f"{v:g}" for v in shown[scenario]) + f" {unit}"
            snrs = sorted(own[level].unique())
            sub = (
                f"threshold; a square per {name}, {snrs[0]:g} to {snrs[-1]:g} {unit};\n"
                f"{efficiency} at {axis}"
            )
        elif len(own.groupby(["snr_db", *swept])) == 1:
            shown[scenario] = None
            last = int(own["frame"].max())
            sub = efficiency + (f" after frame {last}" if summary["frame"].nunique() > 1 else "")
        else:
            shown[scenario] = None
            varying = [c for c in ("snr_db", *swept) if own[c].nunique() > 1]
            sub = f"points attaining; {efficiency} range over " + ", ".join(
                parameter_label(c)[0] for c in varying
            )
        lines = "<br/>".join(_escape(line) for line in sub.split("\n"))
        header.append(f"<th>{_escape(scenario)}<br/><small>{lines}</small></th>")
    body = []
    for label in labels:
        cells = [f"<th>{row_html(rows[rows['row'] == label])}</th>"]
        for scenario in scenarios:
            own = rows[(rows["scenario"] == scenario) & (rows["row"] == label)]
            level = level_axis(rows[rows["scenario"] == scenario], swept) or "snr_db"
            cells.append(f"<td>{_cell(own, shown[scenario], threshold, scenario, level)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    legend = " ".join(f'<span class="v v-{name}">{name}</span>' for name in VERDICT_COLOURS)
    threshold_text = (
        "'from X dB': the bound is attained at every SNR from X dB up (the threshold SNR; "
        "'from X dB-Hz' the same in C/N0); 'never': not at the highest SNR; the squares beside "
        "it are the verdicts at every SNR point, lowest first. "
        if any(snrs is not None for snrs in shown.values())
        else ""
    )
    return (
        f'<table class="verdicts"><thead><tr>{"".join(header)}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table>"
        f"<p>Efficiency = RMSE/√CRLB. {threshold_text}"
        f"Colours: {legend}. {_escape(verdict_criterion())} "
        "Hover a number for its interval and reason; every verdict and its reason are in "
        "summary.csv (columns verdict, verdict_reason), the thresholds in thresholds.csv.</p>"
    )


def ranked_rows(rows: pd.DataFrame, threshold: pd.DataFrame) -> list[str]:
    """The table's row labels, best first: most points attaining, then the lowest threshold
    SNR on average ("never" last), then the median judged efficiency nearest to 1; ties keep
    the experiment's order."""
    keys = []
    for order, (label, own) in enumerate(rows.groupby("row", sort=False)):
        match = threshold["estimator"] == own["estimator"].iloc[0]
        if "planner" in threshold.columns and "planner" in own.columns:
            match &= threshold["planner"] == own["planner"].iloc[0]
        levels = threshold_of(threshold, match)
        level = float(np.mean(np.where(np.isnan(levels), np.inf, levels))) if levels.size else 0.0
        efficiency = own["efficiency_judged"].to_numpy(float)
        efficiency = efficiency[np.isfinite(efficiency) & (efficiency > 0)]
        distance = float(np.median(np.abs(np.log(efficiency)))) if efficiency.size else np.inf
        attains = int((own["verdict"] == "attains").sum())
        keys.append((-attains, level, distance, order, str(label)))
    return [key[-1] for key in sorted(keys)]


def _cell(
    own: pd.DataFrame,
    snrs: list[float] | None,
    threshold: pd.DataFrame,
    scenario: str,
    level: str = "snr_db",
) -> str:
    if own.empty:
        return ""
    mark = (
        "†"
        if (own["verdict_basis"] == "side-resolved").any()
        and not (own["verdict_basis"] == "side-resolved").all()
        else ""
    )
    if snrs is not None:
        estimator = own["estimator"].iloc[0]
        match = (threshold["scenario"] == scenario) & (threshold["estimator"] == estimator)
        if "planner" in threshold.columns:
            match &= threshold["planner"] == own["planner"].iloc[0]
        value = float(threshold_of(threshold, match)[0])
        unit = LEVEL_UNITS[level]
        head = "never" if math.isnan(value) else f"from {value:g} {unit}"
        if not math.isnan(value) and value == own[level].min():
            head = f"all (from {value:g} {unit})"
        spans = []
        for snr in snrs:
            row = own[own[level] == snr].iloc[0]
            spans.append(_span(row["efficiency_judged"], row["verdict"], row["verdict_reason"]))
        strip = _strip(own, level)
        return f'<div class="threshold">{_escape(head + mark)}{strip}</div>' + "".join(spans)
    if len(own) == 1:
        row = own.iloc[0]
        return _span(row["efficiency_judged"], row["verdict"], row["verdict_reason"])
    counts = own["verdict"].value_counts()
    efficiency = own["efficiency_judged"].to_numpy(float)
    finite = efficiency[np.isfinite(efficiency)]
    spread = f"{finite.min():.3g}–{finite.max():.3g}" if finite.size else "–"
    common = str(counts.index[0])
    return (
        f'<div class="threshold">{int(counts.get("attains", 0))} of {len(own)} attain</div>'
        f'<span class="v v-{_escape(common)}" title="most points: {_escape(common)}">'
        f"{_escape(spread)}</span>"
    )


def _strip(own: pd.DataFrame, level: str = "snr_db") -> str:
    """One small square per point of the level (SNR, or C/N0), lowest first, coloured by its
    verdict, between the lowest and highest; each square's own level, verdict and reason on
    hover."""
    unit = LEVEL_UNITS[level]
    ordered = own.sort_values(level)
    squares = "".join(
        f'<span class="sq v-{_escape(row["verdict"])}" '
        f'title="{row[level]:g} {unit}: '
        f'{_escape(row["verdict"] + ", " + row["verdict_reason"])}">'
        "</span>"
        for _, row in ordered.iterrows()
    )
    low, high = ordered[level].iloc[0], ordered[level].iloc[-1]
    return (
        f'<span class="strip" title="every {parameter_label(level)[0]} point, lowest first">'
        f'<span class="ends">{low:g}</span>{squares}<span class="ends">{high:g} {unit}</span>'
        "</span>"
    )


def _listing(values: list[float]) -> str:
    return ", ".join(f"{v:g}" for v in sorted(values))


def _thresholds_compared(summary: pd.DataFrame) -> list[str]:
    """In a C/N0 sweep (the signal level, MATH §18-§22), per scenario: each estimator's
    threshold C/N0 (the lowest from which it attains the bound at every higher point), and how
    far below the best of the others the lowest one holds; why one that never attains does
    not is its highest point's verdict reason."""
    threshold = thresholds(summary)
    if "threshold_cn0_dbhz" not in threshold.columns:
        return []
    rows = judged_points(summary)
    notes = []
    for scenario, own in threshold.groupby("scenario", sort=False):
        parts, levels = [], {}
        for _, entry in own.iterrows():
            label = entry["estimator"]
            level = float(entry["threshold_cn0_dbhz"])
            mine = rows[(rows["scenario"] == scenario) & (rows["estimator"] == label)]
            if math.isnan(level):
                top = mine.sort_values("cn0_dbhz").iloc[-1]
                parts.append(
                    f"{label_html(label)} never ({_escape(top['verdict'])} at "
                    f"{top['cn0_dbhz']:g} dB-Hz: {_escape(top['verdict_reason'])})"
                )
            else:
                levels[label] = level
                parts.append(f"{label_html(label)} from {level:g} dB-Hz")
        text = (
            f"Threshold C/N0 on {_escape(scenario)} (the lowest C/N0 from which the bound is "
            f"attained at every higher point): {'; '.join(parts)}."
        )
        if len(levels) >= 2:
            best = min(levels, key=levels.get)
            others = min(v for k, v in levels.items() if k != best)
            text += (
                f" {label_html(best)} holds the bound {others - levels[best]:g} dB lower than "
                "the next best."
            )
        notes.append(text)
    return notes


def first_screen_notes(summary: pd.DataFrame, points: pd.DataFrame | None) -> list[str]:
    """Sentences for what the verdict table cannot say, each computed from the data, as
    XHTML: every label in ``<bdi>`` (:func:`row_html`), every other value escaped."""
    rows = judged_points(summary)
    swept = summary_swept_columns(summary)
    notes = _price_of_unknowns(points) + _uninformative_modalities(rows, points)
    notes += _thresholds_compared(summary)
    few = rows[rows["verdict_reason"].str.startswith("too few trials")]
    if not few.empty:
        notes.append(
            f"{len(few)} of {len(rows)} verdicts are inconclusive for too few trials (fewer "
            f"than {MIN_TRIALS} successful ones at a point; the smallest count is "
            f"{int(few['n_successes'].min())}): rerun with more trials (--trials); an interval "
            "within ±5% of an efficient estimator's RMSE takes about 400."
        )
    wide = rows[rows["verdict_reason"].str.contains("straddles", regex=False)]
    if len(wide) >= max(3, len(rows) // 4):
        half = (wide["efficiency_judged_ci_high"] - wide["efficiency_judged_ci_low"]) / (
            2 * wide["efficiency_judged"]
        )
        notes.append(
            f"{len(wide)} of {len(rows)} verdicts are inconclusive because the 95% interval is "
            f"too wide to lie inside the band: its half-width is ±{100 * half.median():.0f}% "
            f"(median) with {int(wide['n_successes'].median())} trials per point, while the "
            "band allows ±10%; about 400 trials per point narrow it to ±5% (--trials)."
        )
    heavy = rows[rows["tail_share"] > TAIL_SHARE_LIMIT]
    if not heavy.empty:
        parts = [
            f"{row_html(own)} on {_escape(scenario)} at {_escape(_where(own, swept))}"
            for (_, scenario), own in heavy.groupby(["row", "scenario"], sort=False)
        ]
        notes.append(
            "Heavy tails (the largest 1% of the trials carry more than "
            f"{100 * TAIL_SHARE_LIMIT:g}% of the squared error, so a few estimates far away "
            f"set the RMSE): {'; '.join(parts)}."
        )
    failing = rows[rows["success_rate"] < MIN_SUCCESS_RATE]
    if not failing.empty:
        parts = [
            f"{row_html(own)} on {_escape(scenario)} at {_escape(_where(own, swept))} "
            "(success rate down to "
            f"{own['success_rate'].min():.3g}, {int(own['n_successes'].min())} of "
            f"{int(own.loc[own['success_rate'].idxmin(), 'n_trials'])})"
            for (_, scenario), own in failing.groupby(["row", "scenario"], sort=False)
        ]
        notes.append(f"Failed estimates: {'; '.join(parts)}.")
    notes.extend(_skewed_references(rows))
    notes.extend(_nees_notes(rows, swept))
    notes.extend(_fit_notes(rows, swept))
    side = rows[rows["verdict_basis"] == "side-resolved"]
    if not side.empty:
        parts = [
            f"on {_escape(scenario)}: "
            + ", ".join(row_html(mine) for _, mine in own.groupby("row", sort=False))
            for scenario, own in side.groupby("scenario", sort=False)
        ]
        rate = side["wrong_side_rate"].to_numpy(float)
        rate = rate[np.isfinite(rate)]
        spread = f" (wrong-side rate {rate.min():.2f} to {rate.max():.2f})" if rate.size else ""
        notes.append(
            "Judged on the side-resolved error (the candidate nearest to the truth, MATH §7), "
            "because they flag the mirror ambiguity of a straight track: "
            f"{'; '.join(parts)}. Their returned position is a coin toss between the mirror "
            f"candidates{spread}."
        )
    return notes


def _where(own: pd.DataFrame, swept: list[str]) -> str:
    """Words for the points of ``own``: SNRs in an SNR sweep, else the swept values."""
    if not swept:
        return f"SNR {_listing(own['snr_db'].unique().tolist())} dB"
    if len(own) > 3:
        return f"{len(own)} points"
    columns = [*(["snr_db"] if own["snr_db"].nunique() > 1 else []), *swept]
    return "; ".join(
        ", ".join(f"{parameter_label(c)[0]} {row[c]:g}" for c in columns)
        for _, row in own.iterrows()
    )


def _skewed_references(rows: pd.DataFrame) -> list[str]:
    """Closed loops whose reference (the RMS of per-trial bounds) a few trials dominate."""
    skewed = rows[rows["crlb_rmse_m"] > 3.0 * rows["crlb_rmse_median_m"]]
    if skewed.empty:
        return []
    parts = [
        f"{row_html(own)} on {_escape(scenario)} (RMS {own['crlb_rmse_m'].max():.3g} m, median "
        f"{own['crlb_rmse_median_m'].min():.3g} m)"
        for (_, scenario), own in skewed.groupby(["row", "scenario"], sort=False)
    ]
    return [
        "Each closed-loop trial flies its own path, and the reference is the root mean square "
        "of the trials' bounds; for these a few flown paths are nearly singular (a frame flown "
        "straight at the emitter) and set it, so a 'below' or 'biased' says more about those paths than "
        f"about the estimator: {'; '.join(parts)}."
    ]


def _nees_notes(rows: pd.DataFrame, swept: list[str]) -> list[str]:
    """One sentence on covariance consistency for the estimators that report a covariance."""
    with_cov = rows[~rows["nees_verdict"].fillna("no covariance").isin(["no covariance", ""])]
    if with_cov.empty:
        return []
    parts = []
    for _, own in with_cov.groupby("row", sort=False):
        counts = own["nees_verdict"].value_counts()
        text = (
            f"{row_html(own)} consistent at {int(counts.get('consistent', 0))} of {len(own)} points"
        )
        for kind in ("optimistic", "pessimistic", "inconclusive"):
            bad = own[own["nees_verdict"] == kind]
            if not bad.empty:
                places = "; ".join(
                    f"{_escape(scenario)} {_escape(_where(at, swept))}"
                    for scenario, at in bad.groupby("scenario", sort=False)
                )
                text += f", {kind} at {places}"
        parts.append(text)
    return [
        "Covariance (mean NEES against its 95% chi-square band, judged like the efficiency; "
        "optimistic: the reported covariance is too small): " + "; ".join(parts) + "."
    ]


def _fit_notes(rows: pd.DataFrame, swept: list[str]) -> list[str]:
    """One sentence on the goodness of fit (MATH §17): the points where even the best-fitting
    estimator's fit is rejected in more trials than chance allows (the data do not fit the
    model), and the estimators whose answers lie off a fit the data allow."""
    if "n_fit_judged" not in rows.columns:
        return []
    judged = rows[rows["n_fit_judged"] > 0].copy()
    if judged.empty:
        return []
    n = judged["n_fit_judged"].to_numpy(int)
    judged["n_rejected"] = np.rint(judged["fit_rejected_rate"].to_numpy(float) * n).astype(int)
    # P(X ≥ rejected) for X ~ Binomial(n, FIT_TEST_LEVEL): scipy.special's tail, not
    # scipy.stats (half a second of the report's start)
    tail = special.bdtrc(judged["n_rejected"].to_numpy() - 1, n, FIT_TEST_LEVEL)
    judged["excess"] = tail <= FIT_EXCESS_LEVEL
    point = ["scenario", "snr_db", *swept, *(["planner"] if "planner" in rows.columns else [])]
    best = judged.loc[judged.groupby(point, sort=False)["fit_rejected_rate"].idxmin()]
    level = f"{100 * FIT_TEST_LEVEL:g}%"
    intro = (
        f"Goodness of fit (the χ² of the whitened residuals at the answer, rejected at {level}, "
        f"so in about {level} of the trials by chance; MATH §17): "
    )
    unfit = best[best["excess"]]
    if unfit.empty:
        low, high = (f"{100 * best['fit_rejected_rate'].agg(f):.2g}%" for f in ("min", "max"))
        text = (
            "the data fit the model at every point (the best fit rejected in "
            f"{low if low == high else f'{low} to {high}'} of its trials)"
        )
    else:
        text = (
            "the data do not fit the model at "
            + "; ".join(
                f"{_escape(row['scenario'])} {_escape(_where(unfit.loc[[i]], swept))}, where even "
                f"the best fit, {row_html(unfit.loc[[i]])}, is rejected in {row['n_rejected']} of "
                f"{row['n_fit_judged']} trials"
                for i, row in unfit.iterrows()
            )
            + " (an outlier, a wrong noise σ or a wrong constant?)"
        )
    off = judged[judged["excess"] & ~judged.index.isin(unfit.index)]
    off = off[off.set_index(point).index.isin(best[~best["excess"]].set_index(point).index)]
    if not off.empty:
        parts = []
        for _, own in off.groupby("row", sort=False):
            places = [
                _escape(scenario)
                if len(at)
                == (judged["row"].eq(at["row"].iloc[0]) & judged["scenario"].eq(scenario)).sum()
                else f"{_escape(scenario)} at {_escape(_where(at, swept))}"
                for scenario, at in own.groupby("scenario", sort=False)
            ]
            worst = own.loc[own["n_rejected"].idxmax()]
            parts.append(
                f"{row_html(own)} on {', '.join(places)} (up to {worst['n_rejected']} of "
                f"{worst['n_fit_judged']})"
            )
        text += (
            "; answers off the fit the data allow, rejected in more trials than chance allows "
            "(a scenario named alone: at every point): " + "; ".join(parts)
        )
    return [intro + text + "."]


def _uninformative_modalities(rows: pd.DataFrame, points: pd.DataFrame | None) -> list[str]:
    """Scenarios where one modality's bound alone dwarfs the geometry at every point."""
    if points is None or "range_scale_m" not in points.columns:
        return []
    notes = []
    modalities = {
        "ToA": "crlb_rmse_toa_m",
        "Doppler": "crlb_rmse_doppler_m",
        "RSS": "crlb_rmse_rss_m",
    }
    latest = points.groupby(["scenario", "point"], sort=False)["frame"].transform("max")
    last = points[points["frame"] == latest]
    for scenario, own in last.groupby("scenario", sort=False):
        scale = own["range_scale_m"].to_numpy(float)
        for name, column in modalities.items():
            bound = own[column].to_numpy(float)
            if not np.isfinite(bound).any():
                continue
            ratio = bound / scale
            if not (np.isfinite(ratio).all() and ratio.min() > UNINFORMATIVE_RATIO):
                continue
            best = int(np.argmin(ratio))
            text = (
                f"On {_escape(scenario)}, {name} alone bounds the error at {bound[best]:.3g} m "
                f"even at its best point, {ratio[best]:.3g} times the size of the geometry (RMS range "
                f"{scale[best]:.3g} m): {name} carries no usable information there, and the "
                "bound of an estimator that uses it with other modalities is the bound of those."
            )
            above = rows[rows["scenario"] == scenario].groupby("row", sort=False)
            always = [row_html(own) for _, own in above if (own["verdict"] == "above").all()]
            if always:
                text += f" Above the bound at every point there: {', '.join(always)}."
            notes.append(text)
    return notes


def _price_of_unknowns(points: pd.DataFrame | None) -> list[str]:
    """Scenarios whose emitter's carrier offset, emission time or height is unknown (MATH §8,
    §15): the bounds every verdict is judged on, beside the bounds with them known, and the
    ratio; with the height unknown also the ratio of the bound's horizontal part alone."""
    pairs = {
        "ToA+Doppler": ("crlb_rmse_toa_doppler_m", "crlb_rmse_known_toa_doppler_m"),
        "Doppler": ("crlb_rmse_doppler_m", "crlb_rmse_known_doppler_m"),
    }
    if points is None or not {c for pair in pairs.values() for c in pair} <= set(points.columns):
        return []
    latest = points.groupby(["scenario", "point"], sort=False)["frame"].transform("max")
    last = points[points["frame"] == latest]
    parts = []
    for scenario, own in last.groupby("scenario", sort=False):
        prices = []
        horizontal = own.get(POINT_HEIGHT_CRLB[0])
        if horizontal is not None and own[POINT_HEIGHT_CRLB[1]].isna().all():
            horizontal = None  # a scenario with the height known: its bound is horizontal
        for name, (column, known) in pairs.items():
            bound = own[column].to_numpy(float)
            reference = own[known].to_numpy(float)
            ratio = bound / reference
            ratio = ratio[np.isfinite(ratio)]
            if ratio.size and ratio.max() > 1.0 + 1e-9:
                spread = (
                    f"{ratio.min():.3g}"
                    if np.ptp(ratio) < 5e-3 * ratio.min()
                    else (f"{ratio.min():.3g} to {ratio.max():.3g}")
                )
                part = ""
                if horizontal is not None and name == "ToA+Doppler":
                    flat = horizontal.to_numpy(float) / reference
                    part = f" ({np.nanmax(flat):.3g}×)"
                prices.append(f"{name} {spread}×{part}")
        if prices:
            parts.append(f"{_escape(scenario)}: {', '.join(prices)}")
    if not parts:
        return []
    height = POINT_HEIGHT_CRLB[1] in points.columns and points[POINT_HEIGHT_CRLB[1]].notna().any()
    if height:
        return [
            "Price of the unknowns (the carrier offset and emission time, MATH §15; the "
            "emitter's height, MATH §8): every bound here is the CRLB with them estimated; it "
            "is this many times the bound with all of them known, at the true height (√CRLB "
            "ratio at the last frame; in brackets the 3-D bound's horizontal part alone): "
            f"{'; '.join(parts)}."
        ]
    return [
        "Price of the unknown carrier offset and emission time (MATH §15): every bound here is "
        "the CRLB with them estimated too; it is this many times the bound with them known "
        f"(√CRLB ratio, at the last frame): {'; '.join(parts)}."
    ]
