"""The metric registry: one entry per summary column, its docs table, and metrics computed
from hand-made trial tables whose answers are worked out by hand."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from comparison import metrics
from comparison.metric_groups import SHARED_AGGREGATES, SUMMARY_TRIAL_COLUMNS, TRIAL_QUANTITIES
from comparison.metric_registry import (
    METRIC_NAMES,
    METRICS,
    UNITS,
    Metric,
    metric_names,
    metrics_table_markdown,
)
from comparison.metrics import summarize
from comparison.report import COMPACT_COLUMNS
from tests.comparison.test_metrics import trial_rows

DOCS = Path(__file__).resolve().parents[2] / "docs" / "writing-an-experiment.md"
KEYS = ["scenario", "snr_db", "frame", "estimator"]


def hand_table() -> pd.DataFrame:
    """Four trials of one estimator: errors (3, 0), (0, 4) and (12, 0) m, then a failure;
    covariance 4 I m², √trace CRLB 2 m, fit χ² 1, 20 and 5 on 2 degrees of freedom."""
    rows = trial_rows(
        np.array([[3.0, 0.0], [0.0, 4.0], [12.0, 0.0], [1.0, 1.0]]),
        success=np.array([True, True, True, False]),
        crlb_rmse_m=2.0,
        covariance_m2=4.0 * np.eye(2),
    )
    rows["fit_chi2"] = [1.0, 20.0, 5.0, np.nan]
    rows["fit_dof"] = 2.0
    return rows


def test_every_metric_is_one_entry_and_one_column_of_its_unit():
    summary = summarize(hand_table(), n_bootstrap=20)
    assert list(summary.columns) == [*KEYS, *metric_names(2)]
    assert len(set(METRIC_NAMES)) == len(METRIC_NAMES)
    kinds = {"count": "i", "text": "O"}
    flat = [m for m in METRICS if m.dimension == 2]  # a 2-D run's: the height's only in 3-D
    assert {m.name: summary[m.name].dtype.kind for m in flat} == {
        m.name: kinds.get(m.unit, "f") for m in flat
    }


def test_every_entry_names_what_exists():
    names = set(METRIC_NAMES)
    assert not names & set(SHARED_AGGREGATES)
    for metric in METRICS:
        assert metric.unit in UNITS
        if metric.aggregate is not None:
            assert metric.aggregate[0] in TRIAL_QUANTITIES, metric.name
        if metric.count is not None:  # the count beside a rate is itself a count column
            assert next(m for m in METRICS if m.name == metric.count).unit == "count"
        if metric.name.endswith("_rate"):
            assert metric.count is not None, f"{metric.name}: a rate has its count beside it"
    assert {q for q, _ in SHARED_AGGREGATES.values()} <= set(TRIAL_QUANTITIES)
    assert set(COMPACT_COLUMNS) <= names


def test_an_entry_says_how_it_is_computed_exactly_once():
    with pytest.raises(ValueError, match="max_error_m: give exactly one of aggregate and rule"):
        Metric("max_error_m", "m", "largest distance error")
    with pytest.raises(ValueError, match="unit 'km'"):
        Metric("max_error_m", "km", "largest distance error", aggregate=("error", "max"))


def test_a_new_entry_is_a_new_column(monkeypatch):
    largest = Metric("max_error_m", "m", "largest distance error", aggregate=("error", "max"))
    relative = Metric(
        "max_over_rmse", "1", "max_error_m / rmse_m", rule=lambda g: g["max_error_m"] / g["rmse_m"]
    )
    monkeypatch.setattr(metrics, "METRICS", (*METRICS, largest, relative))
    summary = summarize(hand_table(), n_bootstrap=20)
    assert list(summary.columns[-2:]) == ["max_error_m", "max_over_rmse"]
    assert summary["max_error_m"].item() == 12.0
    assert summary["max_over_rmse"].item() == pytest.approx(12 / math.sqrt(169 / 3), rel=1e-15)


def test_metrics_of_a_hand_made_table():
    row = summarize(hand_table(), n_bootstrap=20).iloc[0]
    near = pytest.approx  # to rounding: the sums run in another order than written here
    assert (row["n_trials"], row["n_successes"], row["success_rate"]) == (4, 3, 0.75)
    rmse_m = math.sqrt((9 + 16 + 144) / 3)
    assert row["rmse_m"] == near(rmse_m, rel=1e-15)
    assert row["rmse_side_resolved_m"] == near(rmse_m, rel=1e-15)
    assert row["mean_error_m"] == near(19 / 3, rel=1e-15)
    assert (row["median_error_m"], row["cep50_m"]) == (4.0, 4.0)
    assert row["p95_error_m"] == near(11.2, rel=1e-15)  # 4 + 0.9 (12 - 4), linear
    assert (row["bias_x_m"], row["bias_y_m"]) == (5.0, near(4 / 3, rel=1e-15))
    assert row["verdict_basis"] == "returned"  # nothing flagged ambiguous
    assert row["bias_judged_x_m"] == 5.0
    assert row["bias_judged_m"] == near(math.hypot(5, 4 / 3), rel=1e-15)
    assert row["bias_ratio"] == near(math.hypot(5, 4 / 3) / 2, rel=1e-15)
    assert (row["crlb_rmse_m"], row["crlb_rmse_median_m"]) == (2.0, 2.0)
    assert row["efficiency"] == near(rmse_m / 2, rel=1e-15)
    assert row["efficiency_judged"] == near(rmse_m / 2, rel=1e-15)
    assert (row["wrong_side_rate"], row["n_side_judged"]) == (0.0, 3)
    assert row["ambiguous_rate"] == 0.0
    assert row["nees_judged_mean"] == near((9 + 16 + 144) / 4 / 3, rel=1e-15)
    assert row["n_nees"] == 3
    # χ²(2)'s 99% point is −2 ln 0.01 ≈ 9.21: 20 is rejected, 1 and 5 are not
    assert row["fit_rejected_rate"] == near(1 / 3, rel=1e-15)
    assert row["n_fit_judged"] == 3


def test_a_closed_loop_bound_is_the_root_mean_square_of_the_trials_bounds():
    rows = hand_table()
    rows["crlb_rmse_m"] = [1.0, 2.0, 2.0, 2.0]  # each trial its own flight, the failed one too
    row = summarize(rows, n_bootstrap=20).iloc[0]
    assert row["crlb_rmse_m"] == pytest.approx(math.sqrt(13 / 4), rel=1e-15)  # √((1+4+4+4)/4)
    assert row["crlb_rmse_median_m"] == 2.0
    assert row["efficiency"] == pytest.approx(math.sqrt(169 / 3) / math.sqrt(13 / 4), rel=1e-15)


def test_the_summary_reads_only_the_summary_trial_columns():
    rows = pd.concat(
        [hand_table(), hand_table().assign(estimator="other", ambiguous=True)], ignore_index=True
    )
    kept = rows[[c for c in rows.columns if c in SUMMARY_TRIAL_COLUMNS]]
    assert len(kept.columns) < len(rows.columns)
    pd.testing.assert_frame_equal(
        summarize(kept, n_bootstrap=20), summarize(rows, n_bootstrap=20), check_exact=True
    )


def test_the_docs_table_is_the_registry():
    page = DOCS.read_text(encoding="utf-8")
    table = re.search(
        r"<!-- metrics table: python -m comparison.metric_registry -->\n(.*?)"
        r"<!-- end of metrics table -->",
        page,
        re.DOTALL,
    )
    assert table is not None, "docs/writing-an-experiment.md: the metrics table's markers"
    documented = re.findall(r"^\| `(\w+)` \|", table.group(1), re.MULTILINE)
    assert documented == list(METRIC_NAMES)
    assert table.group(1) == metrics_table_markdown(), (
        "run python -m comparison.metric_registry and paste its table into the docs"
    )
