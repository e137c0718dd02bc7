"""Invalid estimates in a run and in ``emitterbench estimate``: each is a failed row naming the
rule (:mod:`estimators.validity`), through the per-trial path and the columnar one alike.

The plug-ins below are ``cls`` with one field broken, as the issue measured it: a position
931 m from both its candidates, a negative-definite covariance, a non-symmetric one, a complex
position. :class:`Broken` returns one ``Estimate`` per trial; :class:`BrokenColumns` returns
its chunk as :class:`~estimators.batch.BatchEstimates` (``estimate_columns``), whose trials
never become objects on the run's path. Both have the covariance ``I`` when nothing is broken.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd
import pytest

from comparison.engine import read_trials, run_experiment
from comparison.experiment import Experiment, load_experiment
from estimators.base import Capabilities, Estimate
from estimators.batch import BatchEstimates
from estimators.closed_form.cls import Cls
from estimators.validity import INVALID
from scenarios.catalog import get_scenario
from scenarios.files import write_measurements
from scenarios.simulate import simulate, simulate_trials, trial_seeds
from tests import paths
from tests.comparison.cli_support import invoke

HERE = "tests.comparison.test_validity"
OFFSET_M = 931.0
NEGATIVE = -np.array([[4.0, 1.0], [1.0, 3.0]])
ASYMMETRIC = np.array([[4.0, 1.0], [3.0, 3.0]])
KINDS = ("off-candidates", "negative", "asymmetric", "complex", "none")

SAYS = {
    "off-candidates": (
        INVALID + "position_m (",
        "is not one of its candidates_m (",
        "931 m from the nearest",
    ),
    "negative": (
        INVALID + "covariance_m2 is not symmetric positive semi-definite (smallest eigenvalue "
        f"{np.linalg.eigvalsh(NEGATIVE)[0]:.3g} m²",
    ),
    "asymmetric": (
        INVALID + "covariance_m2 is not symmetric positive semi-definite "
        "(covariance_m2[0, 1] = 1 but covariance_m2[1, 0] = 3 m²",
    ),
    "complex": (INVALID + "position_m is not real (", "+2j, "),
}
"""What the message of each broken kind says, in that order."""


def broken(kind: str, position: np.ndarray, covariance: np.ndarray) -> dict[str, Any]:
    """The fields of ``kind`` broken, for one trial (``(2,)``, ``(2, 2)``) or columns."""
    if kind == "off-candidates":  # off the track's normal: far from both mirror candidates
        return {"position_m": position + np.array([OFFSET_M, 0.0])}
    if kind == "negative":
        return {"covariance_m2": np.broadcast_to(NEGATIVE, covariance.shape).copy()}
    if kind == "asymmetric":
        return {"covariance_m2": np.broadcast_to(ASYMMETRIC, covariance.shape).copy()}
    if kind == "complex":
        return {"position_m": position + np.array([2j, 0.0])}
    return {}


@dataclasses.dataclass(frozen=True, kw_only=True)
class Broken:
    """``cls`` one trial at a time with the covariance ``I``, the field ``kind`` broken."""

    name: ClassVar[str] = "broken"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    kind: str = "negative"

    def estimate(self, data, *, rng=None):
        good = Cls().estimate(data, rng=rng)
        fields = {"position_m": good.position_m, "covariance_m2": np.eye(2)}
        fields.update(broken(self.kind, good.position_m, np.eye(2)))
        return Estimate(
            estimator=self.name,
            candidates_m=good.candidates_m,
            ambiguous=good.ambiguous,
            success=good.success,
            message="cls, then broken",
            **fields,
        )


@dataclasses.dataclass(frozen=True, kw_only=True)
class BrokenColumns:
    """``cls`` on the whole chunk as columns with the covariance ``I``, ``kind`` broken."""

    name: ClassVar[str] = "broken-columns"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    kind: str = "negative"

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, batch=True)

    def estimate(self, data, *, rng=None):
        return Broken(kind=self.kind).estimate(data, rng=rng)

    def estimate_batch(self, batch, *, rngs=None):
        return self.estimate_columns(batch, rngs=rngs).to_estimates()

    def estimate_columns(self, batch, *, rngs=None) -> BatchEstimates:
        good = Cls().estimate_columns(batch, rngs=rngs)
        n = len(good)
        covariance = np.tile(np.eye(2), (n, 1, 1))
        fields = {"position_m": good.position_m, "covariance_m2": covariance}
        fields.update(broken(self.kind, good.position_m, covariance))
        return BatchEstimates(
            estimator=self.name,
            candidates_m=good.candidates_m,
            n_candidates=good.n_candidates,
            ambiguous=good.ambiguous,
            success=good.success,
            message_code=np.zeros(n, dtype=np.int64),
            messages=("cls, then broken",),
            **fields,
        )


def experiment() -> Experiment:
    """``smoke`` at 20 dB (one straight frame: every ``cls`` answer is a mirror pair) with
    ``cls`` and both plug-ins for every kind."""
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    estimators = [{"name": "cls"}]
    for kind in KINDS:
        for plugin in ("Broken", "BrokenColumns"):
            label = f"{plugin}-{kind}"
            options = {"kind": kind}
            estimators.append({"name": f"{HERE}:{plugin}", "label": label, "options": options})
    raw.update(sweep={"parameter": "snr_db", "values": [20]}, trials=6, chunk_size=3)
    raw.update(estimators=estimators)
    return Experiment.from_dict(raw)


@pytest.fixture(scope="module")
def trials(tmp_path_factory) -> pd.DataFrame:
    out = tmp_path_factory.mktemp("validity") / "run"
    return read_trials(run_experiment(experiment(), out, workers=1))


def assert_says(message: str, parts: tuple[str, ...]) -> None:
    """``message`` starts with ``parts[0]`` and holds the others after it, in order."""
    assert message.startswith(parts[0]), message
    at = len(parts[0])
    for part in parts[1:]:
        found = message.find(part, at)
        assert found >= 0, (part, message)
        at = found + len(part)
    assert message.endswith("; cls, then broken"), message


@pytest.mark.parametrize("plugin", ["Broken", "BrokenColumns"])
@pytest.mark.parametrize("kind", [kind for kind in KINDS if kind != "none"])
def test_each_invalid_estimate_is_a_failed_row_naming_the_rule(trials, plugin, kind):
    """Every trial of every broken kind, per-trial objects and columns alike: a failed row,
    no position, no candidates, no covariance, no side verdict, the rule in the message."""
    cls = trials[trials.estimator == "cls"]
    rows = trials[trials.estimator == f"{plugin}-{kind}"]
    assert len(rows) == len(cls) == 6 and cls.success.all() and cls.ambiguous.all()
    assert not rows.success.any()
    assert not rows.ambiguous.any()
    assert (rows.n_candidates == 0).all() and (rows.candidates_json == "[]").all()
    for column in ("x_m", "error_m", "wrong_side", "cov_xx_m2", "cov_xy_m2", "nees"):
        assert rows[column].isna().all(), column
    for message in rows.message:
        assert_says(message, SAYS[kind])


@pytest.mark.parametrize("plugin", ["Broken", "BrokenColumns"])
def test_an_unbroken_plugin_scores_as_cls(trials, plugin):
    """The plug-ins are ``cls`` when nothing is broken: the rules refuse nothing of it (the
    side returned differs: another label draws other coins, MATH §7)."""
    cls = trials[trials.estimator == "cls"].reset_index(drop=True)
    rows = trials[trials.estimator == f"{plugin}-none"].reset_index(drop=True)
    assert rows.success.all() and (rows.message == "cls, then broken").all()
    for column in ("error_side_resolved_m", "x_side_resolved_m", "y_side_resolved_m"):
        pd.testing.assert_series_equal(rows[column], cls[column])
    assert (rows.cov_xx_m2 == 1.0).all() and (rows.cov_xy_m2 == 0.0).all()


@pytest.mark.paths
@pytest.mark.parametrize("kind", KINDS)
def test_both_paths_refuse_the_same_trials_with_the_same_message(kind):
    """The same trials, generators and plug-in: refused as objects (``Estimate``) and as
    columns (``BatchEstimates``), the same estimates by the rule of :mod:`tests.paths`
    (``success`` and the message equal; a refused estimate has no number to round)."""
    batch = simulate_trials(get_scenario("turn"), snr_db=10.0, seeds=trial_seeds(3, 40))
    one = [
        Broken(kind=kind).estimate(data, rng=np.random.default_rng(i))
        for i, data in enumerate(batch)
    ]
    rngs = [np.random.default_rng(i) for i in range(40)]
    columns = BrokenColumns(kind=kind).estimate_columns(batch, rngs=rngs).to_estimates()
    problems = []
    for i, (alone, column) in enumerate(zip(one, columns, strict=True)):
        length_m = paths.length_scale_m(batch.trial(i), "all", alone.position_m)
        alone = dataclasses.replace(alone, estimator=column.estimator)
        problems += [f"trial {i}: {p}" for p in paths.estimate_problems(alone, column, length_m)]
    assert not problems, "\n".join(problems[:5])
    assert all(e.success for e in one) == (kind == "none")
    assert all(e.message.startswith(INVALID) for e in columns) == (kind != "none")


@pytest.mark.parametrize("kind", ["off-candidates", "negative", "asymmetric", "complex"])
def test_estimate_json_refuses_an_invalid_estimate(tmp_path: Path, kind: str) -> None:
    """``emitterbench estimate --json`` with a broken plug-in: a failed estimate naming the
    rule, with no position, candidates or covariance (the non-symmetric covariance no longer
    passes through)."""
    path = tmp_path / "paper.json"
    write_measurements(simulate(get_scenario("paper-1m"), snr_db=20.0, seed=1), path)
    result = invoke(
        "estimate", path, "--estimator", f"{HERE}:Broken", "--option", f'kind="{kind}"', "--json"
    )
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["success"] is False
    assert out["position_m"] == [None, None]
    assert out["candidates_m"] == [] and out["covariance_m2"] is None
    assert_says(out["message"], SAYS[kind])
