"""The comparison scores (x, y): an estimate of the emitter's height too fails its own rows."""

from __future__ import annotations

import numpy as np

from comparison.scoring import Outcomes, score_outcomes
from estimators.base import Estimate
from estimators.batch import BatchEstimates


def estimate_3d() -> Estimate:
    return Estimate(
        estimator="three",
        position_m=[1.0, 2.0, 3.0],
        candidates_m=[[1.0, 2.0, 3.0]],
        ambiguous=False,
        covariance_m2=np.eye(3),
    )


def test_the_comparison_fails_only_the_rows_of_an_estimate_it_cannot_score() -> None:
    """Today's scenarios give the emitter's height: a 3-D estimate fails its own rows, saying
    why, through either path (estimates or columns), and a 2-D one beside it is scored."""
    flat = Estimate(
        estimator="two", position_m=[1.0, 2.0], candidates_m=[[1.0, 2.0]], ambiguous=False
    )
    outcomes = Outcomes.of_estimates([(estimate_3d(), 0.1), (flat, 0.1)])
    assert outcomes.columns.success.tolist() == [False, True]
    assert outcomes.columns.message(0).startswith("position_m: 3 coordinates")
    rows = score_outcomes(outcomes, [1.0, 2.0], None)
    assert len(rows) == 2
    columns = BatchEstimates.from_estimates("three", [estimate_3d()])
    failed = Outcomes.of_columns(columns, 0.1).columns
    assert not failed.success[0] and "comparison scores (x, y)" in failed.message(0)
