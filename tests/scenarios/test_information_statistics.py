"""The statistics of the Fisher information of groups of samples (MATH §8, §15) and the
``fisher`` planner's information of a planned frame with a non-cooperative emitter (MATH §13).

The reference is :func:`scenarios.fisher.fisher_information` of the union of the samples, which
centres each affected modality over all of them at once (one δ and one b); its own agreement
with a finite-difference Fisher matrix over ``(x, y, δ, b)`` is tested in
``tests/scenarios/test_nuisance.py``.
"""

import math

import numpy as np
import pytest

from scenarios.catalog import get_scenario
from scenarios.fisher import (
    fisher_information,
    frame_statistics,
    information_statistics,
)
from scenarios.planners.base import next_frame_start_m
from scenarios.planners.fisher import (
    FisherPlanner,
    design_criterion,
    heading_objective,
    level_velocity_mps,
    past_statistics,
)
from scenarios.simulate import noise_free

BOTH = ("carrier_offset_hz", "emission_time_s")
UNKNOWNS = [(), ("carrier_offset_hz",), ("emission_time_s",), BOTH]


def assert_information_close(actual, expected, rtol):
    """Equal to ``rtol`` of the largest entry of each 2×2 matrix (an off-diagonal entry may
    be near zero)."""
    scale = np.abs(expected).max(axis=(-2, -1), keepdims=True)
    assert np.all(np.abs(actual - expected) <= rtol * scale)


@pytest.mark.parametrize("unknowns", UNKNOWNS, ids=str)
@pytest.mark.parametrize("name", ["paper-1m-turn", "beacon-pass", "orbit"])
def test_every_union_of_frames_is_the_information_of_its_samples(name, unknowns):
    scenario = get_scenario(name).replace(unknowns=unknowns)
    data = noise_free(scenario)
    used = "+".join(m for m in ("toa", "doppler", "rss") if data.noise.for_modality(m))
    statistics = frame_statistics(data, scenario.emitter_m, used)
    rng = np.random.default_rng(len(unknowns))
    subsets = [tuple(rng.choice(data.frames, size=k, replace=False)) for k in (1, 2, 3)]
    for frames in [*subsets, tuple(data.frames)]:
        expected = fisher_information(data.select_frames(list(frames)), scenario.emitter_m, used)
        assert_information_close(statistics.information(frames), expected, 1e-12)
    accumulated = statistics.accumulated()
    for index, frame in enumerate(data.frames):
        expected = fisher_information(data.up_to_frame(frame), scenario.emitter_m, used)
        assert_information_close(accumulated[index], expected, 1e-12)


def test_statistics_over_many_emitter_positions_equal_a_loop():
    scenario = get_scenario("beacon-pass")
    data = noise_free(scenario)
    grid = scenario.emitter_m + np.stack(
        np.meshgrid(np.linspace(-30, 30, 3), np.linspace(-20, 20, 4), indexing="ij"), axis=-1
    )
    many = frame_statistics(data, grid, "toa+doppler").information((0, 2))
    assert many.shape == (3, 4, 2, 2)
    for i in range(3):
        for j in range(4):
            one = frame_statistics(data, grid[i, j], "toa+doppler").information((0, 2))
            assert_information_close(many[i, j], one, 1e-12)


def test_joined_statistics_broadcast_and_are_the_union():
    scenario = get_scenario("turn-noncooperative")
    data = noise_free(scenario)
    first, second = (data.take(data.frame == f) for f in (0, 1))
    points = np.array([[35.0, 15.0], [30.0, -10.0]])

    def statistics(part, at):
        return information_statistics(
            part.position_m, part.velocity_mps, at, data, "toa+doppler", unknowns=BOTH
        )

    # (2, 1) against (2, 3): three copies of the second frame's samples' statistics
    at = np.broadcast_to(points[:, None, :], (2, 3, 2))
    joined = statistics(first, points[:, None, :]).joined(statistics(second, at))
    assert joined.n_groups == 2
    union = joined.information()
    assert union.shape == (2, 3, 2, 2)
    for c in range(2):
        expected = fisher_information(data, points[c], "toa+doppler")
        for copy in range(3):
            assert_information_close(union[c, copy], expected, 1e-12)


def test_no_group_is_no_information():
    scenario = get_scenario("beacon-pass")
    statistics = frame_statistics(noise_free(scenario), scenario.emitter_m)
    np.testing.assert_array_equal(statistics.information([]), np.zeros((2, 2)))


# --------------------------------------------------------------------------------------------
# the fisher planner: the next frame shares the flown frames' δ and b (MATH §13, §15)
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("unknowns", UNKNOWNS, ids=str)
@pytest.mark.parametrize("name", ["turn-noncooperative", "beacon-pass"])
def test_the_heading_objective_is_the_bound_of_the_flight_with_that_frame(name, unknowns):
    """The planner's criterion at a heading equals that of the information of the whole
    flight with the planned frame appended, computed from scratch."""
    scenario = get_scenario(name).replace(unknowns=unknowns)
    flight = scenario.flight.with_n_frames(2)
    data = noise_free(scenario.replace(flight=flight))
    candidates = np.array([scenario.emitter_m, np.add(scenario.emitter_m, [4.0, -3.0])])
    headings = np.radians([-170.0, -60.0, 0.0, 45.0, 100.0])
    speed = float(np.linalg.norm(flight.frame_velocities_mps[-1]))
    for criterion in ("A", "D"):
        got = heading_objective(
            headings,
            past_information=past_statistics(data, candidates),
            candidates_m=candidates,
            start_m=next_frame_start_m(flight),
            speed_mps=speed,
            samples_per_frame=flight.samples_per_frame,
            sample_interval_s=flight.sample_interval_s,
            data=data,
            criterion=criterion,
        )
        for heading, value in zip(headings, got, strict=True):
            three = flight.with_frame(level_velocity_mps(speed, heading))
            whole = noise_free(scenario.replace(flight=three))
            expected = design_criterion(fisher_information(whole, candidates), criterion).max()
            assert value == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_the_planner_with_unknowns_plans_for_one_shared_offset():
    """The plan minimises the bound of the flight with its frame appended (one δ and one b):
    no heading of a fine grid does better by more than the search's resolution."""
    scenario = get_scenario("turn-noncooperative")
    flight = scenario.flight.with_n_frames(1)
    data = noise_free(scenario.replace(flight=flight))
    candidates = np.array([scenario.emitter_m])
    plan = FisherPlanner().plan(flight, candidates, data)
    speed = float(np.linalg.norm(plan.velocity_mps))

    def bound(heading):
        whole = noise_free(
            scenario.replace(flight=flight.with_frame(level_velocity_mps(speed, heading)))
        )
        return float(design_criterion(fisher_information(whole, candidates), "A").max())

    chosen = math.atan2(plan.velocity_mps[1], plan.velocity_mps[0])
    assert plan.diagnostics["objective"] == pytest.approx(bound(chosen), rel=1e-9)
    grid = [bound(h) for h in np.radians(np.arange(0.0, 360.0, 2.0))]
    assert bound(chosen) <= min(grid) * (1 + 1e-6)
