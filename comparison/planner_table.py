"""The first screen of a closed-loop run: which flight locates the emitter best.

A run that compares planners (MATH §12-§13) asks where the UAV should fly. Its first table
answers that, per scenario and sweep point: every planner · estimator, ranked by the RMSE of
the returned position after the last frame (the error a user of the estimate gets, the mirror
side included), with that RMSE after every frame (hover: its 95% interval and count), the
wrong-side rate with its count, and the bound of the paths actually flown (the root mean
square over trials of √CRLB of each trial's own trajectory, and its median). The efficiency
and its verdict come second, in the verdict table below it: with every trial flying its own
path the bound is a reference, and a planner that flies a poor path can be efficient on it.
"""

from __future__ import annotations

import html

import numpy as np
import pandas as pd

from comparison.labels import label_html
from comparison.metrics import summary_swept_columns


def _escape(value: object) -> str:
    return html.escape(str(value), quote=True)


def _number(value: float) -> str:
    return "–" if not np.isfinite(value) else f"{value:.3g}"


def ranked_flights(summary: pd.DataFrame) -> pd.DataFrame:
    """The last frame of every (scenario, point, planner, estimator), ranked within each
    (scenario, point) by the returned position's RMSE, lowest first; column ``rank`` from 1."""
    swept = summary_swept_columns(summary)
    point = ["scenario", "snr_db", *swept]
    keys = [*point, "planner", "estimator"]
    latest = summary.groupby(keys, sort=False)["frame"].transform("max")
    last = summary[summary["frame"] == latest].copy()
    last["order"] = np.arange(len(last))
    last = last.sort_values([*point, "rmse_m", "order"], kind="stable", na_position="last")
    last["rank"] = last.groupby(point, sort=False).cumcount() + 1
    scenario_order = {name: i for i, name in enumerate(pd.unique(summary["scenario"]))}
    last["scenario_order"] = last["scenario"].map(scenario_order)
    return last.sort_values(["scenario_order", *point[1:], "rank"], kind="stable").drop(
        columns=["order", "scenario_order"]
    )


def planner_table_html(summary: pd.DataFrame) -> str:
    """One table per scenario and sweep point (module docstring), XHTML-compatible."""
    swept = summary_swept_columns(summary)
    point = ["scenario", "snr_db", *swept]
    ranked = ranked_flights(summary)
    frames = sorted(summary["frame"].unique().tolist())
    parts = []
    for key, rows in ranked.groupby(point, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        where = ", ".join(
            [
                str(key[0]),
                f"SNR {key[1]:g} dB",
                *(f"{c} = {v:g}" for c, v in zip(swept, key[2:], strict=True)),
            ]
        )
        own = summary
        for column, value in zip(point, key, strict=True):
            own = own[own[column] == value]
        header = (
            "<tr><th>rank</th><th>planner · estimator</th>"
            + "".join(f"<th>{f}</th>" for f in frames)
            + "<th>RMSE (m) after the<br/>last frame, 95% interval</th>"
            "<th>wrong side<br/>(count)</th>"
            "<th>√CRLB (m) of the<br/>flown paths: RMS<br/>(median)</th></tr>"
        )
        body = []
        for _, row in rows.iterrows():
            mine = own[(own["planner"] == row["planner"]) & (own["estimator"] == row["estimator"])]
            by_frame = mine.set_index("frame")
            cells = []
            for frame in frames:
                if frame not in by_frame.index:
                    cells.append("<td></td>")
                    continue
                at = by_frame.loc[frame]
                title = (
                    f"frame {frame}: RMSE {_number(at['rmse_m'])} m, 95% interval "
                    f"[{_number(at['rmse_ci_low_m'])}, {_number(at['rmse_ci_high_m'])}], "
                    f"n = {int(at['n_successes'])}"
                )
                cells.append(f'<td title="{_escape(title)}">{_number(at["rmse_m"])}</td>')
            wrong = (
                f"{_number(row['wrong_side_rate'])} ({int(row['n_side_judged'])})"
                if row["n_side_judged"] > 0
                else "– (0)"
            )
            body.append(
                f"<tr><td>{int(row['rank'])}</td>"
                f"<th>{label_html(row['planner'])} · {label_html(row['estimator'])}</th>"
                + "".join(cells)
                + f"<td><strong>{_number(row['rmse_m'])}</strong> "
                f"[{_number(row['rmse_ci_low_m'])}, {_number(row['rmse_ci_high_m'])}]</td>"
                f"<td>{_escape(wrong)}</td>"
                f"<td>{_number(row['crlb_rmse_m'])} ({_number(row['crlb_rmse_median_m'])})</td>"
                "</tr>"
            )
        n_trials = int(rows["n_trials"].max())
        parts.append(
            f"<h3>{_escape(where)}: {n_trials} trials</h3>"
            '<table class="verdicts planners">'
            f'<thead><tr><th colspan="2"></th><th colspan="{len(frames)}">RMSE of the returned '
            'position (m) after frame</th><th colspan="3"></th></tr>'
            f"{header}</thead><tbody>{''.join(body)}</tbody></table>"
        )
    return (
        "<p>Which flight locates the emitter best: every planner and estimator, ranked by the "
        "RMSE of the returned position after the last frame (the error a user gets, the mirror "
        "side included), its RMSE after every frame (hover a number for its interval and "
        "count), the wrong-side rate with its count, and the bound of the paths each trial "
        "actually flew. The efficiency and its verdict come second, in the verdict table: "
        "each trial flies its own path, so the bound is a reference, and an estimator can be "
        "efficient on a poor path.</p>" + "".join(parts)
    )
