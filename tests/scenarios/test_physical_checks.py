"""Measurements no flight can produce are refused by the data types, naming field and sample.

One table of impossible or malformed inputs (ranges shorter than the height, a velocity that
changes inside a frame, positions off ``v Δt``, time running backwards, huge frame indices,
σ's and positions beyond the limits, NaN, infinity...), each built from valid simulated data
by one change: every one raises a one-line ``ValueError`` starting with the field and sample.
Then the other side: simulated data of every named scenario load at -60, 0 and 100 dB, even
the paper's, whose 300 km ToA noise makes ranges negative.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from scenarios.catalog import CATALOG, get_scenario
from scenarios.simulate import noise_free, simulate_trials, trial_seeds
from scenarios.types import (
    RANGE_DEFICIT_SIGMAS,
    FlightPlan,
    MeasurementSet,
    NoiseSigmas,
)

C = 299_792_458.0


def valid() -> MeasurementSet:
    """``turn`` at 0 dB, exact: 2 frames of 10 samples (east, then north), 50 m up, ``c σ_τ =
    1 m``, Doppler, ToA and RSS, truth known."""
    return noise_free(get_scenario("turn"))


def with_entry(name: str, index: Any, value: float) -> Callable[[MeasurementSet], dict]:
    """A change: ``name[index] = value`` (on a copy)."""

    def change(data: MeasurementSet) -> dict:
        array = np.array(getattr(data, name), dtype=float)
        array[index] = value
        return {name: array}

    return change


def short_range(index: int, sigmas: float) -> Callable[[MeasurementSet], dict]:
    """Sample ``index``'s ToA range shorter than its height above the emitter by ``sigmas`` σ."""

    def change(data: MeasurementSet) -> dict:
        sigma_m = data.speed_of_light_mps * data.noise.toa_s
        height = data.position_m[index, 2] - data.emitter_height_m
        toa = np.array(data.toa_s)
        toa[index] = (height - sigmas * sigma_m) / data.speed_of_light_mps
        return {"toa_s": toa}

    return change


def shifted(**offsets: Any) -> Callable[[MeasurementSet], dict]:
    """Every sample's ``name`` plus an offset (a consistent change of the whole flight)."""
    return lambda data: {name: getattr(data, name) + value for name, value in offsets.items()}


def scaled(name: str, factor: float) -> Callable[[MeasurementSet], dict]:
    return lambda data: {name: getattr(data, name) * factor}


def constant(**values: Any) -> Callable[[MeasurementSet], dict]:
    return lambda data: values


IMPOSSIBLE: list[tuple[str, str, Callable[[MeasurementSet], dict]]] = [
    # ToA ranges shorter than the height of the UAV above the emitter (MATH §1)
    ("every ToA negated", "toa_s[0]", scaled("toa_s", -1.0)),
    ("every ToA zero", "toa_s[0]", scaled("toa_s", 0.0)),
    ("a range of 30 m, 50 m up", "toa_s[4]", with_entry("toa_s", 4, 30.0 / C)),
    ("a range 9 sigma short of the height", "toa_s[7]", short_range(7, 9.0)),
    ("the emitter 200 m up, above the UAV", "toa_s[0]", constant(emitter_height_m=200.0)),
    ("the emitter 200 m underground", "toa_s[0]", constant(emitter_height_m=-200.0)),
    ("the whole flight 1 km higher", "toa_s[0]", shifted(position_m=[0.0, 0.0, 1000.0])),
    # one velocity per frame, p[k+1] = p[k] + v[k] Δt within a frame (MATH §0)
    ("a turn inside frame 0", "velocity_mps[5]", with_entry("velocity_mps", (5, 1), 10.0)),
    ("a speed change of 0.1 %", "velocity_mps[3]", with_entry("velocity_mps", (3, 0), 10.01)),
    ("frame 1 reverses midway", "velocity_mps[15]", with_entry("velocity_mps", (15, 1), -10.0)),
    ("one position 1 m off", "position_m[3]", with_entry("position_m", (3, 0), 2.5)),
    ("one position 1 mm too high", "position_m[3]", with_entry("position_m", (3, 2), 50.001)),
    ("flying twice the velocity", "position_m[1]", scaled("velocity_mps", 0.5)),
    (
        "standing still while flying",
        "position_m[1]",
        lambda data: {"position_m": np.tile(data.position_m[0], (data.n_samples, 1))},
    ),
    ("time running at half speed", "position_m[1]", scaled("time_s", 2.0)),
    # time never decreases
    ("two samples swapped in time", "time_s[4]", with_entry("time_s", 4, 0.1)),
    ("time running backwards", "time_s[1]", scaled("time_s", -1.0)),
    ("a frozen clock", "time_s[1]", scaled("time_s", 0.0)),
    ("time 1e13 s", "time_s[0]", shifted(time_s=1e13)),
    ("a NaN time", "time_s", with_entry("time_s", 2, np.nan)),
    # frame indices: whole, 0 <= frame < 2^31, non-decreasing
    ("frame 2^64", "frame[19]", with_entry("frame", 19, 2.0**64)),
    ("frame 2^31", "frame[19]", with_entry("frame", 19, 2.0**31)),
    ("a negative frame", "frame[0]", with_entry("frame", slice(0, 10), -1)),
    ("a fractional frame", "frame[3]", with_entry("frame", 3, 0.5)),
    ("frames out of order", "frame[12]", with_entry("frame", 12, 0)),
    ("a NaN frame", "frame", with_entry("frame", 0, np.nan)),
    ("a frame beyond any float", "frame", lambda data: {"frame": [10**400] * data.n_samples}),
    # σ's beyond the limits, or not positive
    ("sigma_toa 1e200 s", "noise.toa_s", lambda d: {"noise": replace(d.noise, toa_s=1e200)}),
    (
        "sigma_doppler 1e200 Hz",
        "noise.doppler_hz",
        lambda d: {"noise": replace(d.noise, doppler_hz=1e200)},
    ),
    ("sigma_rss 1e200 dB", "noise.rss_db", lambda d: {"noise": replace(d.noise, rss_db=1e200)}),
    ("sigma_toa 1e-300 s", "noise.toa_s", lambda d: {"noise": replace(d.noise, toa_s=1e-300)}),
    ("sigma_toa zero", "noise.toa_s", lambda d: {"noise": replace(d.noise, toa_s=0.0)}),
    (
        "sigma_doppler negative",
        "noise.doppler_hz",
        lambda d: {"noise": replace(d.noise, doppler_hz=-0.1)},
    ),
    ("sigma_toa NaN", "noise.toa_s", lambda d: {"noise": replace(d.noise, toa_s=np.nan)}),
    ("no sigma_toa with ToA", "noise.toa_s", lambda d: {"noise": replace(d.noise, toa_s=None)}),
    # positions, speeds and measured values beyond the limits
    ("positions near 1e308", "position_m[0]", shifted(position_m=[1e308, 0.0, 0.0])),
    ("positions 2e9 m east", "position_m[0]", shifted(position_m=[2e9, 0.0, 0.0])),
    ("speeds of 1e200 m/s", "velocity_mps[0]", scaled("velocity_mps", 1e199)),
    ("a ToA of 1e300 s", "toa_s[2]", with_entry("toa_s", 2, 1e300)),
    ("a Doppler of 1e300 Hz", "doppler_hz[6]", with_entry("doppler_hz", 6, 1e300)),
    ("an RSS of -1e300 dBm", "rss_dbm[8]", with_entry("rss_dbm", 8, -1e300)),
    ("a carrier of 1e200 Hz", "carrier_hz", constant(carrier_hz=1e200)),
    ("a carrier of 1e-10 Hz", "carrier_hz", constant(carrier_hz=1e-10)),
    ("c 1e200 m/s", "speed_of_light_mps", constant(speed_of_light_mps=1e200)),
    ("c zero", "speed_of_light_mps", constant(speed_of_light_mps=0.0)),
    ("an emitter 1e300 m up", "emitter_height_m", constant(emitter_height_m=1e300)),
    ("a true emitter at 1e300 m", "truth.emitter_m[0]", constant(truth_emitter_m=[1e300, 0])),
    # not numbers at all
    ("a NaN position", "position_m", with_entry("position_m", (4, 2), np.nan)),
    ("an infinite position", "position_m", with_entry("position_m", (2, 1), -np.inf)),
    ("an infinite velocity", "velocity_mps", with_entry("velocity_mps", (0, 0), np.inf)),
    ("a NaN ToA", "toa_s", with_entry("toa_s", 0, np.nan)),
    ("an infinite ToA", "toa_s", with_entry("toa_s", 1, np.inf)),
    ("an infinite Doppler", "doppler_hz", with_entry("doppler_hz", 4, np.inf)),
    ("a NaN carrier", "carrier_hz", constant(carrier_hz=np.nan)),
    ("a NaN true emitter", "truth.emitter_m", constant(truth_emitter_m=[np.nan, 0.0])),
    ("noise as a dict", "noise", constant(noise={"toa_s": 1e-9})),
    ("an RSS model as a dict", "rss_model", constant(rss_model={"path_loss_exponent": 2.0})),
    (
        "no samples",
        "samples",
        lambda data: {
            name: np.empty((0, 3)) if name.endswith(("_m", "_mps")) else np.empty(0)
            for name in ("frame", "time_s", "position_m", "velocity_mps")
        },
    ),
]


def raises_at(field: str):
    """``pytest.raises(ValueError)`` whose message starts with ``field: ``."""
    return pytest.raises(ValueError, match="^" + re.escape(field) + ": ")


@pytest.mark.parametrize(("label", "field", "change"), IMPOSSIBLE, ids=[c[0] for c in IMPOSSIBLE])
def test_impossible_measurements_are_refused_naming_the_field(
    label: str, field: str, change: Callable[[MeasurementSet], dict]
) -> None:
    data = valid()
    with raises_at(field) as error:
        replace(data, **change(data))
    assert "\n" not in str(error.value)


def test_the_table_is_large_and_its_base_is_valid() -> None:
    assert len(IMPOSSIBLE) >= 40
    data = valid()
    assert replace(data).n_samples == 20  # rebuilding the valid data raises nothing


def negate_trial_1(toa: np.ndarray) -> np.ndarray:
    toa[1] = -toa[1]
    return toa


def huge_toa_in_trial_2(toa: np.ndarray) -> np.ndarray:
    toa[2, 13] = 1e300
    return toa


@pytest.mark.parametrize(
    ("field", "change"), [("toa_s[1][0]", negate_trial_1), ("toa_s[2][13]", huge_toa_in_trial_2)]
)
def test_a_batch_names_the_trial_and_the_sample(field: str, change) -> None:
    batch = simulate_trials(get_scenario("turn"), snr_db=20.0, seeds=trial_seeds(3, 3))
    with raises_at(field):
        replace(batch, toa_s=change(np.array(batch.toa_s)))


def test_a_batch_checks_every_modality_and_its_geometry() -> None:
    batch = simulate_trials(get_scenario("turn"), snr_db=20.0, seeds=trial_seeds(3, 3))
    doppler = np.array(batch.doppler_hz)
    doppler[2, 5] = 1e300
    with raises_at("doppler_hz[2][5]"):
        replace(batch, doppler_hz=doppler)
    with raises_at("rss_dbm"):
        replace(batch, rss_dbm=np.full((3, 20), np.nan))
    with raises_at("geometry"):
        replace(batch, geometry="turn")


# --------------------------------------------------------------------------------------------
# the thresholds, from both sides
# --------------------------------------------------------------------------------------------


def test_a_range_may_fall_short_of_the_height_by_up_to_eight_sigma() -> None:
    assert RANGE_DEFICIT_SIGMAS == 8.0
    data = valid()
    for sigmas in (0.0, 3.0, 7.9):
        accepted = replace(data, **short_range(7, sigmas)(data))
        assert accepted.range_m[7] == pytest.approx(50.0 - sigmas, abs=1e-9)
    with raises_at("toa_s[7]") as error:
        replace(data, **short_range(7, 8.1)(data))
    assert "8.1 σ" in str(error.value)


def test_the_kinematic_tolerance_is_one_in_a_million_of_the_step() -> None:
    data = valid()  # steps of 0.5 m
    for error_m, accepted in ((4e-7 * 0.5, True), (4e-6 * 0.5, False)):
        position = np.array(data.position_m)
        position[3:10, 1] += error_m  # one step off, then the frame continues straight
        if accepted:
            assert replace(data, position_m=position).position_m[3, 1] == error_m
        else:
            with raises_at("position_m[3]"):
                replace(data, position_m=position)


def test_frames_may_turn_and_pause_between_them() -> None:
    """Nothing is checked across a frame boundary: a turn, a gap in time, a jump of the log."""
    data = valid()
    time = np.array(data.time_s)
    time[10:] += 60.0  # a minute between the frames
    position = np.array(data.position_m)
    position[10:] += [3.0, -4.0, 0.0]
    moved = replace(data, time_s=time, position_m=position, toa_s=None, rss_dbm=None)
    assert moved.time_s[10] == pytest.approx(60.5)


def test_the_last_frame_index_is_accepted() -> None:
    data = valid()
    frame = np.array(data.frame)
    frame[10:] = 2**31 - 1
    assert replace(data, frame=frame).frame[-1] == 2**31 - 1


def test_noise_at_an_snr_that_leaves_the_sigma_range_names_the_snr() -> None:
    noise = NoiseSigmas(doppler_hz=0.1, toa_s=1e-3, rss_db=4.0)
    assert noise.at_snr(500.0).toa_s == pytest.approx(1e-28)
    with raises_at("snr_db"):
        noise.at_snr(700.0)
    with raises_at("snr_db"):
        noise.at_snr(-650.0)


def test_scenarios_and_flight_plans_have_the_same_limits() -> None:
    scenario = get_scenario("paper-1m")
    with raises_at("emitter_m[0]"):
        scenario.replace(emitter_m=[1e300, 0.0])
    with raises_at("carrier_hz"):
        scenario.replace(carrier_hz=1e200)
    with raises_at("speed_of_light_mps"):
        scenario.replace(speed_of_light_mps=1e-10)
    with raises_at("emitter_height_m"):
        scenario.replace(emitter_height_m=-2e9)
    with raises_at("noise"):
        scenario.replace(noise=None)
    flight = scenario.flight
    with raises_at("flight.start_position_m[2]"):
        replace(flight, start_position_m=[0.0, 0.0, 1e308])
    with raises_at("flight.frame_velocities_mps[0][0]"):
        replace(flight, frame_velocities_mps=[[1e200, 0.0, 0.0]])
    with raises_at("velocity_mps[1]"):
        flight.with_frame([0.0, 2e6, 0.0])
    with raises_at("flight.sample_interval_s"):
        replace(flight, sample_interval_s=1e20)
    assert isinstance(replace(flight, sample_interval_s=1e3), FlightPlan)


# --------------------------------------------------------------------------------------------
# simulated data always load
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(CATALOG))
@pytest.mark.parametrize("snr_db", [-60.0, 0.0, 100.0])
def test_simulated_data_of_every_named_scenario_load(name: str, snr_db: float) -> None:
    """500 trials per point, each checked as a batch and again as a one-trial view."""
    scenario = get_scenario(name)
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(2024, 500))
    assert batch.n_trials == 500
    for index in (0, 123, 499):
        trial = batch.trial(index)
        np.testing.assert_array_equal(trial.doppler_hz, batch.doppler_hz[index])
    if batch.toa_s is None or "emission_time_s" in scenario.unknowns:
        return  # no ranges, or pseudo-ranges: the height check does not apply (MATH §15)
    for index in (0, 123, 499):
        np.testing.assert_array_equal(batch.trial(index).toa_s, batch.toa_s[index])
    sigma_m = scenario.speed_of_light_mps * batch.geometry.noise.toa_s
    height = batch.geometry.position_m[:, 2] - scenario.emitter_height_m
    deficit = (height - scenario.speed_of_light_mps * batch.toa_s) / sigma_m
    assert deficit.max() < RANGE_DEFICIT_SIGMAS  # what the check bounds, directly


def test_the_papers_ranges_are_often_negative_and_still_load() -> None:
    """``c σ_τ = 300 km`` (as printed) against 62 m ranges: half the ranges are negative."""
    batch = simulate_trials(get_scenario("paper"), snr_db=0.0, seeds=trial_seeds(7, 200))
    negative = np.mean(batch.toa_s < 0.0)
    assert 0.45 < negative < 0.55
    assert batch.trial(0).n_samples == 10
