"""Tests of comparison.closed_loop and of closed-loop experiments in the engine (MATH §12-§13).

The plug-ins at the top are referred to by experiments as
``tests.comparison.test_closed_loop:Name``.
"""

import dataclasses
import math
from typing import ClassVar

import numpy as np
import pandas as pd
import pytest

from comparison.closed_loop import HOLD_PREFIX, fly_closed_loop, steering_candidates_m
from comparison.crlb import fisher_information, rmse_bound_m
from comparison.engine import run_experiment
from comparison.experiment import Experiment, load_experiment
from comparison.metrics import summarize
from comparison.store import read_flights, read_trials
from comparison.tasks import tie_rng
from comparison.trial_rows import FLIGHT_COLUMNS
from estimators.base import Estimate
from estimators.closed_form.cls import Cls
from estimators.registry import make_estimator
from scenarios.catalog import get_scenario
from scenarios.planners import get_planner
from scenarios.simulate import noise_free, simulate
from scenarios.types import FlightPlan
from tests import paths

HERE = "tests.comparison.test_closed_loop"


@dataclasses.dataclass(frozen=True, kw_only=True)
class NeverCls:
    """Fails on every call, to exercise the loop's fallback."""

    name: ClassVar[str] = "never"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        return Estimate.failed(self.name, "fails on purpose")


@dataclasses.dataclass(frozen=True, kw_only=True)
class RefusingPlanner:
    """A planner that always refuses with a ValueError."""

    name: ClassVar[str] = "refusing"

    def plan(self, flight, candidates_m, data, *, covariance_m2=None, rng=None):
        raise ValueError("candidates_m: refused on purpose")


def run_loop(planner, *, frames=3, seed=5, estimators=None, steering="cls"):
    scenario = get_scenario("paper-1m", frames=frames)
    estimators = estimators or [("cls", Cls()), ("ml", make_estimator("ml"))]
    return scenario, fly_closed_loop(
        scenario,
        snr_db=0.0,
        planner=planner,
        estimators=estimators,
        steering=steering,
        seed=np.random.SeedSequence(seed),
        estimate_rng=lambda label: tie_rng(seed, 0, 0, 0, label),
    )


@pytest.mark.bits(
    "the closed loop simulates with simulate's code and calls Cls().estimate on those arrays"
)
def test_constant_planner_reproduces_the_open_loop_simulation():
    scenario, trial = run_loop(get_planner("constant"))
    open_loop = simulate(scenario, seed=np.random.SeedSequence(5))
    for name in ("frame", "time_s", "position_m", "velocity_mps", "doppler_hz", "toa_s", "rss_dbm"):
        assert np.array_equal(getattr(trial.data, name), getattr(open_loop, name)), name
    for frame in range(3):
        seen = open_loop.up_to_frame(frame).without_truth()
        expected = Cls().estimate(seen, rng=tie_rng(5, 0, 0, 0, "cls"))
        got, _ = trial.estimates["cls"][frame]
        assert np.array_equal(got.candidates_m, expected.candidates_m)
        assert np.array_equal(got.position_m, expected.position_m)
    assert trial.plans[0] is None and trial.plans[1].message == "held the last velocity"


def test_every_planner_meets_the_same_noise():
    residuals = []
    for name in ("paper", "fisher", "orbit"):
        scenario, trial = run_loop(get_planner(name), frames=4, seed=9)
        exact = noise_free(scenario.replace(flight=trial.flight))
        residuals.append((trial.data.doppler_hz - exact.doppler_hz) / exact.noise.doppler_hz)
        assert not np.allclose(trial.flight.frame_velocities_mps[1:], [10.0, 0.0, 0.0])
    draws = np.random.default_rng(np.random.SeedSequence(9)).standard_normal((3, 40))
    for residual in residuals:
        assert residual == pytest.approx(draws[0], abs=1e-6)


def test_the_loop_is_deterministic_and_steers_from_the_returned_position():
    planner = get_planner("fisher")
    _, one = run_loop(planner, frames=4, steering="ml")
    _, two = run_loop(planner, frames=4, steering="ml")
    assert np.array_equal(one.flight.frame_velocities_mps, two.flight.frame_velocities_mps)
    # the plan after frame 0 is the planner's answer to the ml estimate of frame 0
    estimate, _ = one.estimates["ml"][0]
    candidates = steering_candidates_m(estimate)
    assert np.array_equal(candidates[0], estimate.position_m) and len(candidates) == 2
    direct = planner.plan(
        one.flight.with_n_frames(1),
        candidates,
        one.data.up_to_frame(0).without_truth(),
        covariance_m2=estimate.covariance_m2,
    )
    assert np.array_equal(direct.velocity_mps, one.flight.frame_velocities_mps[1])


def test_a_failed_steering_estimate_or_a_refusing_planner_holds_the_velocity():
    _, failed = run_loop(get_planner("paper"), estimators=[("never", NeverCls())], steering="never")
    assert np.array_equal(failed.flight.frame_velocities_mps, [[10.0, 0.0, 0.0]] * 3)
    assert (
        failed.plans[1].message == HOLD_PREFIX + "the steering estimate failed (fails on purpose)"
    )
    _, refused = run_loop(RefusingPlanner())
    assert refused.plans[2].message == HOLD_PREFIX + "candidates_m: refused on purpose"
    with pytest.raises(ValueError, match=r"^steering: 'ekf' is not among the estimators"):
        run_loop(RefusingPlanner(), steering="ekf")


# --------------------------------------------------------------------------------------------
# closed-loop experiments in the engine
# --------------------------------------------------------------------------------------------


def closed(**changes) -> Experiment:
    raw = {
        "name": "closed",
        "scenarios": ["paper-1m"],
        "estimators": [
            {"name": "ml", "label": "ml"},
            {"name": "cls", "label": "cls-last", "options": {"frames": "last"}},
        ],
        "planners": ["constant", "fisher"],
        "steering_estimator": "ml",
        "trials": 4,
        "seed": 11,
        "frames": 3,
        "per_frame": True,
        "chunk_size": 2,
    }
    raw.update(changes)
    return Experiment.from_dict(raw)


def rows(out) -> pd.DataFrame:
    return read_trials(out).drop(columns="runtime_s")


@pytest.fixture(scope="module")
def closed_run(tmp_path_factory):
    return run_experiment(closed(), tmp_path_factory.mktemp("closed") / "run", workers=1)


def test_closed_loop_rows_flights_and_their_bounds(closed_run):
    trials, flights = read_trials(closed_run), read_flights(closed_run)
    assert len(trials) == 2 * 2 * 3 * 4  # planners × estimators × frames × trials
    assert list(trials.planner.unique()) == ["constant", "fisher"]
    assert list(flights.columns) == list(FLIGHT_COLUMNS) and len(flights) == 2 * 4 * 3
    scenario = get_scenario("paper-1m", frames=3)
    for (planner, trial), path in flights.groupby(["planner", "trial"]):
        flight = FlightPlan(
            start_position_m=path[["start_x_m", "start_y_m", "start_z_m"]].iloc[0],
            frame_velocities_mps=path[["vx_mps", "vy_mps", "vz_mps"]].to_numpy(),
            samples_per_frame=10,
            sample_interval_s=0.05,
        )
        positions = flight.sample_positions_m()
        assert positions[::10] == pytest.approx(path[["start_x_m", "start_y_m", "start_z_m"]])
        data = noise_free(scenario.replace(flight=flight))
        mine = trials[(trials.planner == planner) & (trials.trial == trial)]
        for frame in range(3):
            cumulative = bound(data.up_to_frame(frame))
            last = bound(data.take(data.frame == frame))
            at = mine[mine.frame == frame].set_index("estimator").crlb_rmse_m
            assert at["ml"] == pytest.approx(cumulative, rel=1e-12)
            assert at["cls-last"] == pytest.approx(last, rel=1e-12)
    # the fisher flights turn; the constant ones do not, and frame 0 is the scenario's own
    turned = flights[(flights.planner == "fisher") & (flights.frame > 0)]
    assert (np.abs(turned.vy_mps) > 1.0).any()
    assert (flights[flights.planner == "constant"].vy_mps == 0.0).all()
    assert (flights[flights.frame == 0].message == "the scenario's initial velocity").all()


def bound(data):
    return float(rmse_bound_m(fisher_information(data, [35.0, 15.0], ("toa", "doppler"))))


@pytest.mark.paths
def test_constant_rows_equal_the_open_loop_per_frame_rows(closed_run, tmp_path):
    """The open loop runs cls and ml in batch (estimate_columns), the closed loop one
    estimate at a time: two paths, whose rows agree to rounding (:mod:`tests.paths`)."""
    open_loop = closed().to_dict()
    for key in ("planners", "steering_estimator", "swept_columns"):
        open_loop.pop(key)
    reference = rows(run_experiment(Experiment.from_dict(open_loop), tmp_path / "open", workers=1))
    constant = rows(closed_run)
    constant = constant[constant.planner == "constant"].reset_index(drop=True)
    columns = [c for c in reference.columns if c not in ("experiment", "planner")]
    kappa = paths.fisher_condition(noise_free(get_scenario("paper-1m")))
    assert paths.frame_problems(reference[columns], constant[columns], kappa) == []
    assert (reference.planner == "").all()


def test_summary_has_planner_rows_and_the_rms_of_the_flown_bounds(closed_run):
    trials = read_trials(closed_run)
    summary = summarize(trials, n_bootstrap=20)
    assert list(summary.columns[:5]) == ["scenario", "snr_db", "frame", "planner", "estimator"]
    assert len(summary) == 3 * 2 * 2
    fisher = trials[(trials.planner == "fisher") & (trials.estimator == "ml") & (trials.frame == 2)]
    row = summary[
        (summary.planner == "fisher") & (summary.estimator == "ml") & (summary.frame == 2)
    ]
    assert fisher.crlb_rmse_m.nunique() > 1  # every trial flew its own path
    expected = math.sqrt(float(np.mean(fisher.crlb_rmse_m**2)))
    assert row.crlb_rmse_m.item() == pytest.approx(expected, rel=1e-12)


@pytest.mark.bits(
    "a closed loop estimates one trial at a time: chunks and resume hand it the same arrays"
)
def test_closed_loop_resume_and_chunking_give_the_same_rows(closed_run, tmp_path):
    part = tmp_path / "part"
    run_experiment(closed(trials=3, chunk_size=1), part, workers=1)
    run_experiment(closed(chunk_size=1), part, workers=1, resume=True)
    pd.testing.assert_frame_equal(rows(part), rows(closed_run))
    pd.testing.assert_frame_equal(read_flights(part), read_flights(closed_run))


@pytest.mark.bits("worker counts: the same tasks on the same arrays")
@pytest.mark.slow  # starting worker processes takes seconds on a busy machine
def test_closed_loop_rows_do_not_depend_on_the_number_of_workers(closed_run, tmp_path):
    two = run_experiment(closed(), tmp_path / "two", workers=2)
    pd.testing.assert_frame_equal(rows(two), rows(closed_run))
    pd.testing.assert_frame_equal(read_flights(two), read_flights(closed_run))


@pytest.mark.slow  # about half a minute on one core
def test_acceptance_paper_fig3(tmp_path):
    """Turning planners resolve the side; Fisher is no worse than the paper's rule. 50 trials:
    Fisher's final RMSE is 0.98 and 1.01 √CRLB (paper-1m, paper-10m), its ±10% sampling error
    leaves the 1.25 bound 2.5 standard deviations away."""
    experiment = load_experiment("paper-fig3").with_trials(50)
    trials = read_trials(run_experiment(experiment, tmp_path / "fig3", workers=1))
    summary = summarize(trials, n_bootstrap=400, seed=1)
    ml = summary[summary.estimator == "ml"].set_index(["scenario", "planner", "frame"]).sort_index()
    for scenario in ("paper-1m", "paper-10m"):
        for planner in ("paper", "fisher", "orbit"):
            later = ml.loc[(scenario, planner)].loc[2:]
            assert (later.wrong_side_rate == 0.0).all(), (scenario, planner)
        final = {p: ml.loc[(scenario, p, 9)] for p in ("constant", "paper", "fisher", "orbit")}
        assert final["fisher"].rmse_m <= final["paper"].rmse_ci_high_m
        assert final["fisher"].rmse_m < final["constant"].rmse_m / 20
        assert final["fisher"].rmse_m <= 1.25 * final["fisher"].crlb_rmse_m
        assert final["constant"].wrong_side_rate > 0.3  # a straight track never resolves it
