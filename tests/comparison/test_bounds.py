"""The bound of the frames an estimator declares (MATH §8, §15): with a non-cooperative emitter
the chosen frames' samples share one carrier offset δ and one emission time b.

Checked against a Fisher matrix over ``(x, y, δ, b)`` built by central differences of the
forward model (no project Jacobian), its Schur complement onto ``(x, y)``; and in the engine,
open and closed loop, for a plug-in that declares a tuple of frames.

The plug-in at the top is referred to by experiments as ``tests.comparison.test_bounds:Name``.
"""

import dataclasses
from typing import ClassVar

import numpy as np
import pytest

from comparison.bounds import bound_of, information_at_truth
from comparison.engine import run_experiment
from comparison.experiment import Experiment
from comparison.store import read_flights, read_trials
from estimators.base import Capabilities, Estimate
from scenarios import measurement_model as model
from scenarios.catalog import get_scenario
from scenarios.fisher import frame_statistics, inverse_2x2, rmse_bound_m
from scenarios.nuisance import AFFECTED_MODALITY as AFFECTED
from scenarios.nuisance import NUISANCE_PARAMETERS
from scenarios.simulate import noise_free
from scenarios.types import FlightPlan

HERE = "tests.comparison.test_bounds"
BOTH = ("carrier_offset_hz", "emission_time_s")


@dataclasses.dataclass(frozen=True, kw_only=True)
class FrameSubsetProbe:
    """Declares a tuple of frames and both nuisance parameters; estimates nothing (its rows
    carry the bound of what it declares)."""

    name: ClassVar[str] = "frame-subset-probe"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    frames: tuple[int, ...] = (0, 3)

    def capabilities(self) -> Capabilities:
        return Capabilities(
            modalities=self.requires, frames=tuple(self.frames), unknowns=frozenset(BOTH)
        )

    def estimate(self, data, *, rng=None):
        return Estimate.failed(self.name, "a bound probe: no estimate")


# --------------------------------------------------------------------------------------------
# the finite-difference reference
# --------------------------------------------------------------------------------------------


def finite_difference_crlb(data, emitter, modalities, unknowns, groups) -> np.ndarray:
    """The ``(x, y)`` block of the inverse of the Fisher matrix over ``(x, y)`` and one δ and
    one b (those of ``unknowns`` that enter a modality used) per group of samples
    (``groups``: one label per sample of ``data``), every column by central differences of the
    forward model: the Schur complement onto ``(x, y)``, inverted."""
    c, gamma, height = data.speed_of_light_mps, data.gamma_per_m, data.emitter_height_m
    labels = np.unique(groups)
    per_group = [u for u in NUISANCE_PARAMETERS if u in unknowns and AFFECTED[u] in modalities]
    n_nuisance = len(per_group) * len(labels)

    def forward(theta):
        xy = theta[:2]
        nuisance = theta[2:].reshape(len(labels), len(per_group))
        offset = {name: np.zeros(data.n_samples) for name in BOTH}
        for g, label in enumerate(labels):
            for j, name in enumerate(per_group):
                offset[name][groups == label] = nuisance[g, j]
        rows = []
        if "doppler" in modalities:
            doppler = model.doppler_hz(data.position_m, data.velocity_mps, xy, gamma, height)
            rows.append((doppler + offset["carrier_offset_hz"]) / data.noise.doppler_hz)
        if "toa" in modalities:
            toa = model.toa_s(data.position_m, xy, c, height)
            rows.append((toa + offset["emission_time_s"]) / data.noise.toa_s)
        return np.concatenate(rows)

    theta = np.concatenate([emitter, np.zeros(n_nuisance)])
    unit = {"carrier_offset_hz": 1e-3, "emission_time_s": 1e-9}
    steps = np.array([1e-4, 1e-4, *([unit[u] for u in per_group] * len(labels))])
    jacobian = np.column_stack(
        [
            (forward(theta + step * e) - forward(theta - step * e)) / (2 * step)
            for step, e in zip(steps, np.eye(len(theta)), strict=True)
        ]
    )
    return np.linalg.inv(jacobian.T @ jacobian)[:2, :2]


def subset_case(name, unknowns, frames, modalities):
    scenario = get_scenario(name).replace(unknowns=unknowns)
    data = noise_free(scenario)
    used = data.select_frames(list(frames))
    return scenario, data, used


CASES = [
    ("beacon-pass", BOTH, (0, 1), ("toa", "doppler")),
    ("beacon-pass", BOTH, (0, 3), ("toa", "doppler")),
    ("beacon-pass", BOTH, (2,), ("toa", "doppler")),
    ("beacon-pass", BOTH, (1, 2, 3), ("doppler",)),
    ("beacon-pass", ("carrier_offset_hz",), (0, 3), ("toa", "doppler")),
    ("beacon-pass", ("emission_time_s",), (0, 2), ("toa",)),
    ("turn-noncooperative", BOTH, (0, 1), ("toa", "doppler")),
    ("turn-noncooperative", BOTH, (1,), ("toa", "doppler")),
    ("turn-noncooperative", ("carrier_offset_hz",), (0, 1), ("doppler",)),
    ("turn", (), (0, 1), ("toa", "doppler")),
]


@pytest.mark.parametrize(("name", "unknowns", "frames", "modalities"), CASES, ids=str)
def test_a_frame_subset_shares_one_offset_and_emission_time(name, unknowns, frames, modalities):
    """The information of the chosen frames is the finite-difference one with one (δ, b)
    shared by their samples; ``bound_of`` at the last frame is its √trace."""
    scenario, data, used = subset_case(name, unknowns, frames, modalities)
    expected = finite_difference_crlb(
        used, scenario.emitter_m, modalities, unknowns, np.zeros(used.n_samples)
    )
    statistics = frame_statistics(data, scenario.emitter_m, modalities)
    np.testing.assert_allclose(inverse_2x2(statistics.information(frames)), expected, rtol=1e-5)
    info = information_at_truth(data, scenario.emitter_m, [modalities])[modalities]
    last = scenario.flight.n_frames - 1
    assert bound_of(info, last, frames) == pytest.approx(
        float(np.sqrt(np.trace(expected))), rel=1e-5
    )


@pytest.mark.parametrize(("name", "unknowns", "frames", "modalities"), CASES[:8], ids=str)
def test_the_sum_of_frames_is_a_separate_offset_and_emission_time_per_frame(
    name, unknowns, frames, modalities
):
    """Each frame's own information is the one with its own (δ, b): their sum is the
    finite-difference bound with a separate (δ, b) per frame, which is larger than the shared
    one wherever more than one frame is chosen (the bound the estimator faces is the shared)."""
    scenario, data, used = subset_case(name, unknowns, frames, modalities)
    separate = finite_difference_crlb(used, scenario.emitter_m, modalities, unknowns, used.frame)
    statistics = frame_statistics(data, scenario.emitter_m, modalities)
    summed = statistics.per_group()[list(frames)].sum(axis=0)
    np.testing.assert_allclose(inverse_2x2(summed), separate, rtol=1e-5)
    shared = rmse_bound_m(statistics.information(frames))
    if len(frames) > 1:
        assert shared < 0.99 * rmse_bound_m(summed)


@pytest.mark.parametrize("name", ["paper-1m-turn", "orbit", "turn"])
def test_a_cooperative_subset_is_the_sum_of_its_frames(name):
    scenario = get_scenario(name)
    data = noise_free(scenario)
    statistics = frame_statistics(data, scenario.emitter_m, "toa+doppler")
    per_frame = statistics.per_group()
    for frames in [(0,), (0, 1), (1, data.frames[-1]), tuple(data.frames)]:
        chosen = sorted(set(frames))  # a frame listed twice is used once
        np.testing.assert_allclose(
            statistics.information(frames), per_frame[chosen].sum(axis=0), rtol=1e-12
        )


def test_all_last_and_a_tuple_are_one_function_of_the_frames():
    scenario = get_scenario("beacon-pass")
    data = noise_free(scenario)
    info = information_at_truth(data, scenario.emitter_m, [("toa", "doppler")])[("toa", "doppler")]
    for frame in range(4):
        assert bound_of(info, frame, "all") == bound_of(info, frame, tuple(range(frame + 1)))
        assert bound_of(info, frame, "last") == bound_of(info, frame, (frame,))
        # frames after the one evaluated are not used yet; none at all: no bound
        assert bound_of(info, frame, (frame, 3)) == bound_of(info, frame, (frame,))
    assert np.isnan(bound_of(info, 0, (2, 3)))
    assert np.isnan(bound_of(None, 0, "all"))


# --------------------------------------------------------------------------------------------
# in the engine: the bound of a plug-in that declares a tuple of frames
# --------------------------------------------------------------------------------------------


def probe_experiment(**changes) -> Experiment:
    raw = {
        "name": "subset",
        "scenarios": ["beacon-pass"],
        "sweep": {"parameter": "snr_db", "values": [0.0], "fixed": {}},
        "estimators": [
            {"name": f"{HERE}:FrameSubsetProbe", "label": "probe", "options": {"frames": [0, 3]}}
        ],
        "trials": 2,
        "seed": 3,
        "per_frame": True,
    }
    raw.update(changes)
    return Experiment.from_dict(raw)


def shared_bound_m(data, emitter, frames) -> float:
    """√trace of the finite-difference CRLB of ``frames``' samples, one (δ, b) over them."""
    used = data.select_frames(list(frames))
    crlb = finite_difference_crlb(
        used, emitter, ("toa", "doppler"), data.unknowns, np.zeros(used.n_samples)
    )
    return float(np.sqrt(np.trace(crlb)))


def test_the_engine_scores_a_declared_tuple_against_the_shared_nuisance_bound(tmp_path):
    trials = read_trials(run_experiment(probe_experiment(), tmp_path / "run", workers=1))
    scenario = get_scenario("beacon-pass")
    data = noise_free(scenario)
    for frame in range(4):
        used = [f for f in (0, 3) if f <= frame]
        expected = shared_bound_m(data, scenario.emitter_m, used)
        got = trials[trials.frame == frame].crlb_rmse_m
        assert len(got) == 2 and got.to_list() == pytest.approx([expected] * 2, rel=1e-5)


def test_a_closed_loop_scores_a_declared_tuple_on_the_flown_path(tmp_path):
    experiment = probe_experiment(
        scenarios=["turn-noncooperative"],
        estimators=[
            {"name": "ml", "label": "ml"},
            {"name": f"{HERE}:FrameSubsetProbe", "label": "probe", "options": {"frames": [0, 2]}},
        ],
        planners=["fisher"],
        steering_estimator="ml",
        frames=3,
    )
    out = run_experiment(experiment, tmp_path / "run", workers=1)
    trials, flights = read_trials(out), read_flights(out)
    scenario = get_scenario("turn-noncooperative", frames=3)
    for trial, path in flights.groupby("trial"):
        flight = FlightPlan(
            start_position_m=path[["start_x_m", "start_y_m", "start_z_m"]].iloc[0],
            frame_velocities_mps=path[["vx_mps", "vy_mps", "vz_mps"]].to_numpy(),
            samples_per_frame=scenario.flight.samples_per_frame,
            sample_interval_s=scenario.flight.sample_interval_s,
        )
        data = noise_free(scenario.replace(flight=flight))
        mine = trials[(trials.trial == trial) & (trials.estimator == "probe")]
        for frame in range(3):
            used = [f for f in (0, 2) if f <= frame]
            expected = shared_bound_m(data, scenario.emitter_m, used)
            got = mine[mine.frame == frame].crlb_rmse_m
            assert got.to_list() == pytest.approx([expected], rel=1e-5)
