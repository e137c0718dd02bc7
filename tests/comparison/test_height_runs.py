"""A run with an emitter of unknown height (MATH §8): 3-D tables, 3-D bounds and scores, and
the horizontal answers of an estimator that assumes the height beside them.

A probe estimator answers a fixed point with a fixed covariance, so every score of its rows is
known by hand; the bounds are checked against ``crlb_table`` (the 3×3 CRLB of the file view).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
import pytest

from comparison.crlb import crlb_table
from comparison.engine import run_experiment
from comparison.experiment import Experiment
from comparison.metric_registry import metric_names
from comparison.store import read_points, read_trials
from comparison.trial_rows import TRIALS, dimension_columns
from estimators.base import Capabilities, Estimate
from scenarios.catalog import get_scenario
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free

HERE = "tests.comparison.test_height_runs"
ANSWER_M = (151.0, 118.0, 122.0)
"""The probe's answer: 1, 2 and 2 m off hill's emitter at (150, 120, 120) m."""
COVARIANCE_M2 = np.diag([1.0, 4.0, 16.0])


@dataclasses.dataclass(frozen=True, kw_only=True)
class HeightProbe:
    """Declares the height unknown and answers ``ANSWER_M`` with ``COVARIANCE_M2``."""

    name: ClassVar[str] = "height-probe"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, unknowns=frozenset({HEIGHT_UNKNOWN}))

    def estimate(self, data, *, rng=None):
        if HEIGHT_UNKNOWN not in data.unknowns:
            return Estimate.failed(self.name, "a height probe: the height is known")
        point = np.array(ANSWER_M)
        return Estimate(
            estimator=self.name,
            position_m=point,
            candidates_m=point[None],
            covariance_m2=COVARIANCE_M2,
            ambiguous=False,
            success=True,
        )


@pytest.fixture(scope="module")
def height_run(tmp_path_factory):
    experiment = Experiment.from_dict(
        {
            "name": "height-probe",
            "scenarios": ["hill", "turn"],
            "estimators": [
                {"name": f"{HERE}:HeightProbe", "label": "probe"},
                {"name": "cls", "label": "cls-ground", "ignore_unknowns": [HEIGHT_UNKNOWN]},
            ],
            "sweep": {"parameter": "snr_db", "values": [20.0]},
            "trials": 4,
            "seed": 3,
        }
    )
    return run_experiment(experiment, tmp_path_factory.mktemp("height") / "run", workers=1)


def test_the_tables_of_a_3d_run_hold_the_height_after_the_2d_columns(height_run) -> None:
    trials = read_trials(height_run)
    added = [c for c in dimension_columns(3) if c not in dimension_columns(2)]
    assert [c for c in trials.columns if c not in added] == list(TRIALS.names())
    hill, turn = trials[trials.scenario == "hill"], trials[trials.scenario == "turn"]
    assert (hill.truth_z_m == 120.0).all() and turn.truth_z_m.isna().all()
    points = read_points(height_run)
    assert points.set_index("scenario").truth_z_m.to_dict() == pytest.approx(
        {"hill": 120.0, "turn": math.nan}, nan_ok=True
    )


def test_a_3d_answer_is_scored_in_3d_against_the_3d_bound(height_run) -> None:
    trials = read_trials(height_run)
    probe = trials[(trials.scenario == "hill") & (trials.estimator == "probe")]
    assert len(probe) == 4 and probe.success.all()
    error = np.array(ANSWER_M) - [150.0, 120.0, 120.0]
    assert probe.error_m.to_list() == pytest.approx([3.0] * 4, rel=1e-15)
    assert probe.z_m.to_list() == [122.0] * 4
    nees = float(error @ np.linalg.inv(COVARIANCE_M2) @ error)
    assert probe.nees.to_list() == pytest.approx([nees] * 4, rel=1e-12)
    assert probe.cov_zz_m2.to_list() == [16.0] * 4 and probe.cov_xz_m2.to_list() == [0.0] * 4

    data = noise_free(get_scenario("hill"), snr_db=20.0)
    table = crlb_table(data, data.truth_emitter_m)
    crlb = np.asarray(table["crlb_m2"]["toa+doppler"])
    row = probe.iloc[0]
    got = [row[f"crlb_{a}_m2"] for a in ("xx", "xy", "yy", "xz", "yz", "zz")]
    want = [crlb[0, 0], crlb[0, 1], crlb[1, 1], crlb[0, 2], crlb[1, 2], crlb[2, 2]]
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert row.crlb_rmse_m == pytest.approx(table["rmse_bound_m"]["toa+doppler"], rel=1e-9)
    # the probe's answer is not on the turn's 2-D data: there it fails, its rows 2-D
    turn = trials[(trials.scenario == "turn") & (trials.estimator == "probe")]
    assert not turn.success.any() and turn.crlb_zz_m2.isna().all()


def test_an_answer_assuming_the_height_is_scored_horizontally(height_run) -> None:
    """cls told to ignore the unknown height assumes the take-off ground: its (x, y) answer is
    scored against the (x, y) block of the 3-D bound (what the data allow when the height is
    unknown), its height columns empty; the known-height bound is the points table's."""
    trials = read_trials(height_run)
    ground = trials[(trials.scenario == "hill") & (trials.estimator == "cls-ground")]
    assert ground.success.all() and ground.z_m.isna().all() and ground.crlb_zz_m2.isna().all()
    horizontal = np.hypot(ground.x_m - 150.0, ground.y_m - 120.0)
    np.testing.assert_allclose(ground.error_m, horizontal, rtol=1e-15)
    data = noise_free(get_scenario("hill"), snr_db=20.0)
    table = crlb_table(data, data.truth_emitter_m)
    crlb = np.asarray(table["crlb_m2"]["toa+doppler"])
    assert ground.crlb_rmse_m.iloc[0] == pytest.approx(math.sqrt(crlb[0, 0] + crlb[1, 1]), rel=1e-9)
    points = read_points(height_run)
    last = points[points.frame == points.frame.max()].set_index("scenario")
    assert last.loc["hill", "crlb_rmse_known_toa_doppler_m"] == pytest.approx(
        table["known_rmse_bound_m"]["toa+doppler"], rel=1e-9
    )
    # assuming the ground 120 m below the emitter costs metres, hundreds of bounds
    assert horizontal.min() > 100 * math.sqrt(crlb[0, 0] + crlb[1, 1])


def test_the_summary_of_a_3d_run_has_the_height_s_metrics_where_there_is_a_height(
    height_run,
) -> None:
    import pandas as pd

    from comparison.report import write_report

    write_report(height_run)
    summary = pd.read_csv(height_run / "summary.csv")
    assert [c for c in summary.columns if c in metric_names(3)] == list(metric_names(3))
    probe = summary[(summary.scenario == "hill") & (summary.estimator == "probe")].iloc[0]
    assert probe.bias_z_m == pytest.approx(2.0, rel=1e-12)
    assert probe.rmse_vertical_m == pytest.approx(2.0, rel=1e-12)
    assert probe.rmse_horizontal_m == pytest.approx(math.sqrt(5.0), rel=1e-12)
    ground = summary[(summary.scenario == "hill") & (summary.estimator == "cls-ground")].iloc[0]
    assert math.isnan(ground.bias_z_m) and math.isnan(ground.crlb_vertical_m)
    assert ground.efficiency > 100.0 and ground.n_trials == 4


def test_an_estimator_may_assume_some_unknowns_and_estimate_the_others() -> None:
    """``ignore_unknowns`` as a list: the named unknowns are fed as known, the others must be
    estimated (roof-beacon: cls estimates the carrier offset and emission time, assumes the
    height); a name that is no unknown is one line naming the field."""
    from comparison.specs import EstimatorSpec

    spec = EstimatorSpec.from_dict(
        {"name": "cls", "label": "c", "ignore_unknowns": ["emitter_height_m"]}
    )
    assert spec.ignore_unknowns == (HEIGHT_UNKNOWN,)
    assert spec.to_dict()["ignore_unknowns"] == [HEIGHT_UNKNOWN]
    unknowns = get_scenario("roof-beacon").unknowns
    assert spec.assumed(unknowns) == (HEIGHT_UNKNOWN,)
    data = noise_free(get_scenario("roof-beacon")).assuming_known(spec.assumed(unknowns))
    assert data.unknowns == ("carrier_offset_hz", "emission_time_s") and data.height_assumed
    assert data.truth_emitter_m.shape == (2,)
    with pytest.raises(ValueError, match=r"^estimator.ignore_unknowns: expected a list of any"):
        EstimatorSpec.from_dict({"name": "cls", "ignore_unknowns": ["height"]})
    with pytest.raises(ValueError, match=r"ignore_unknowns: expected true, false or a list"):
        EstimatorSpec.from_dict({"name": "cls", "ignore_unknowns": "yes"})


def test_the_points_hold_the_parts_of_the_3d_bound_and_the_report_its_price(height_run) -> None:
    """The points table's horizontal and vertical parts of the ToA+Doppler bound are
    ``crlb_table``'s; the report prices the unknown height against the known-height bound,
    for the 3-D bound and its horizontal part."""
    from comparison.report import write_report

    points = read_points(height_run)
    last = points[points.frame == points.frame.max()].set_index("scenario")
    data = noise_free(get_scenario("hill"), snr_db=20.0)
    table = crlb_table(data, data.truth_emitter_m)
    hill = last.loc["hill"]
    assert hill.crlb_horizontal_toa_doppler_m == pytest.approx(
        table["horizontal_rmse_bound_m"]["toa+doppler"], rel=1e-9
    )
    assert hill.crlb_vertical_toa_doppler_m == pytest.approx(
        table["vertical_rmse_bound_m"]["toa+doppler"], rel=1e-9
    )
    turn = points[points.scenario == "turn"]
    assert turn.crlb_vertical_toa_doppler_m.isna().all()
    np.testing.assert_array_equal(turn.crlb_horizontal_toa_doppler_m, turn.crlb_rmse_toa_doppler_m)
    write_report(height_run)
    page = (height_run / "report.html").read_text(encoding="utf-8")
    price = table["rmse_bound_m"]["toa+doppler"] / table["known_rmse_bound_m"]["toa+doppler"]
    flat = (
        table["horizontal_rmse_bound_m"]["toa+doppler"] / table["known_rmse_bound_m"]["toa+doppler"]
    )
    assert f"hill: ToA+Doppler {price:.3g}× ({flat:.3g}×)" in page


@pytest.mark.parametrize("estimator", ["ml", "cls"])
def test_the_command_line_on_a_file_of_unknown_height(tmp_path, estimator) -> None:
    """``simulate hill``, ``crlb --json`` (the 3×3 bound and its parts) and ``estimate`` (three
    coordinates, as text and JSON) on the file; at 100 dB (the bound 0.02 mm) the answer is the emitter
    to the millimetre."""
    import json

    from tests.comparison.cli_support import invoke

    path = tmp_path / "hill.json"
    made = invoke("simulate", "hill", "--seed", 1, "--snr-db", 100, "-o", path)
    assert made.exit_code == 0, made.output
    bound = json.loads(invoke("crlb", path, "--json").stdout)
    assert np.shape(bound["crlb_m2"]["toa+doppler"]) == (3, 3)
    assert bound["at_m"] == [150.0, 120.0, 120.0]
    assert set(bound) >= {"horizontal_rmse_bound_m", "vertical_rmse_bound_m", "price"}
    answer = json.loads(invoke("estimate", path, "--estimator", estimator, "--json").stdout)
    np.testing.assert_allclose(answer["position_m"], [150.0, 120.0, 120.0], atol=1e-3)
    assert answer["error_m"] < 1e-3 and np.shape(answer["candidates_m"]) == (1, 3)
    text = invoke("estimate", path, "--estimator", estimator)
    assert text.exit_code == 0, text.output
    assert "(150.0000, 120.0000, 120.0000)" in text.stdout
