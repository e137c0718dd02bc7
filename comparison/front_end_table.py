"""The report's table of the front end at the signal level (docs/math.md §19-§20): per
scenario and C/N0, the bursts it flagged below threshold, its outliers, and the burst SNR
against its estimate of it (from the run's ``bursts`` table)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from comparison.metrics import format_number


def front_end_table(bursts: pd.DataFrame, experiment: Mapping[str, Any]) -> pd.DataFrame:
    """Per scenario and C/N0, what the front end made of the bursts (docs/math.md §20): the
    bursts, the shares it flagged below threshold, of outliers and of outliers not flagged
    (each with its count), the burst SNR (C/N0 times the burst's length) and the mean of the
    front end's estimates of it (above the truth below threshold, where the largest noise peak
    is taken for the burst)."""
    values = experiment.get("sweep", {}).get("values") or []
    fixed = experiment.get("sweep", {}).get("fixed", {})
    burst_s = float(experiment["signal"]["burst_s"])
    rows = []
    for (scenario, point), group in bursts.groupby(["scenario", "point"], sort=False):
        cn0 = float(values[point]) if values else float(fixed["cn0_dbhz"])
        total = int(group["n_bursts"].sum())
        row = {"scenario": scenario, "cn0_dbhz": cn0, "trials": len(group), "bursts": total}
        for column in ("flagged", "outliers", "unflagged_outliers"):
            count = int(group[column].sum())
            row[column] = f"{count / total:.3g} ({count})"
        row["burst_snr_db"] = cn0 + 10.0 * float(np.log10(burst_s))
        row["estimated_burst_snr_db"] = float(group["mean_burst_snr_db"].mean())
        rows.append(row)
    return pd.DataFrame(rows)


def front_end_section_html(bursts: pd.DataFrame | None, experiment: Mapping[str, Any]) -> str:
    """The report's section on the front end at the signal level, XHTML-compatible (empty
    at the measurement level, where ``bursts`` is None or empty)."""
    if bursts is None or bursts.empty:
        return ""
    table = front_end_table(bursts, experiment)
    numbers = {c: format_number for c in table.columns if pd.api.types.is_numeric_dtype(table[c])}
    rows = table.to_html(
        index=False,
        formatters=numbers,
        border=0,
        table_id="front-end-table",
        classes="summary",
        escape=True,
    )
    return (
        '<section id="front-end"><h2>The front end: bursts below threshold</h2>'
        "<p>Every trial's bursts measured by the front end (docs/math.md §19-§20): the share "
        "it flagged below threshold, the share of outliers (a Doppler more than a bin 1/T, or "
        "a ToA more than a chip, off the truth: no local bound describes them) and of those "
        "it did not flag, each with its count; the burst SNR and the mean of the front end's "
        "estimates of it; every trial is in bursts.csv.</p>"
        f"{rows}</section>"
    )
