"""Tests of scenarios.parameters: one named parameter changed, everything else kept."""

import numpy as np
import pytest

from scenarios.catalog import get_scenario
from scenarios.parameters import SWEEPABLE, check_parameter_value, with_parameter, with_parameters
from scenarios.simulate import noise_free


def test_sweepable_names_are_the_documented_parameters():
    assert set(SWEEPABLE) == {
        "range_sigma_m",
        "doppler_sigma_hz",
        "rss_sigma_db",
        "samples_per_frame",
        "sample_interval_s",
        "frames",
        "speed_mps",
        "emitter_x_m",
        "emitter_y_m",
        "emitter_height_m",
    }
    assert "snr_db" not in SWEEPABLE


def test_range_sigma_sets_toa_sigma_through_the_scenario_speed_of_light():
    paper = get_scenario("paper")  # c = 3e8 in the paper (MATH §14)
    changed = with_parameter(paper, "range_sigma_m", 3.0)
    assert changed.noise.toa_s == 3.0 / 3.0e8
    assert changed.noise.doppler_hz == paper.noise.doppler_hz == 0.1
    assert changed.noise.rss_db == paper.noise.rss_db == 4.0
    assert paper.noise.toa_s == 1e-3  # the original is untouched
    assert changed.name == "paper"


def test_noise_sigmas_of_the_other_modalities():
    paper = get_scenario("paper-1m")
    assert with_parameter(paper, "doppler_sigma_hz", 0.5).noise.doppler_hz == 0.5
    assert with_parameter(paper, "rss_sigma_db", 2.0).noise.rss_db == 2.0
    # and they reach the simulated data, scaled by the SNR axis (MATH §2)
    data = noise_free(with_parameter(paper, "doppler_sigma_hz", 0.5), snr_db=20.0)
    assert data.noise.doppler_hz == pytest.approx(0.05, rel=1e-15)


def test_flight_parameters():
    paper = get_scenario("paper-1m")
    more = with_parameter(paper, "samples_per_frame", 25)
    assert more.flight.samples_per_frame == 25
    assert more.flight.n_samples == 25
    slower = with_parameter(paper, "sample_interval_s", 0.1)
    np.testing.assert_allclose(slower.flight.sample_positions_m()[-1], [9 * 0.1 * 10.0, 0, 50])
    three = with_parameter(paper, "frames", 3)
    assert three.flight.n_frames == 3
    np.testing.assert_array_equal(three.flight.frame_velocities_mps, [[10.0, 0.0, 0.0]] * 3)
    assert with_parameter(three, "frames", 1.0).flight.n_frames == 1


def test_speed_rescales_every_frame_and_keeps_the_headings():
    turn = get_scenario("turn")  # east, then north at 10 m/s
    slow = with_parameter(turn, "speed_mps", 4.0)
    np.testing.assert_allclose(
        slow.flight.frame_velocities_mps, [[4.0, 0, 0], [0, 4.0, 0]], atol=1e-15
    )
    np.testing.assert_array_equal(slow.flight.start_position_m, turn.flight.start_position_m)


def test_emitter_coordinates():
    paper = get_scenario("paper-1m")
    moved = with_parameters(
        paper, {"emitter_x_m": -20.0, "emitter_y_m": 45.0, "emitter_height_m": 2.0}
    )
    np.testing.assert_array_equal(moved.emitter_m, [-20.0, 45.0])
    assert moved.emitter_height_m == 2.0
    np.testing.assert_array_equal(noise_free(moved).truth_emitter_m, [-20.0, 45.0])
    np.testing.assert_array_equal(paper.emitter_m, [35.0, 15.0])


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"^speed: not a sweepable") as info:
        with_parameter(get_scenario("paper"), "speed", 3.0)
    for name in SWEEPABLE:
        assert name in str(info.value)
    with pytest.raises(ValueError, match=r"^snr_db: .*simulation time"):
        with_parameter(get_scenario("paper"), "snr_db", 3.0)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("range_sigma_m", -1.0),
        ("doppler_sigma_hz", 0.0),
        ("rss_sigma_db", float("nan")),
        ("sample_interval_s", 0.0),
        ("speed_mps", -5.0),
        ("frames", 2.5),
        ("frames", 0),
        ("samples_per_frame", True),
        ("emitter_x_m", "10"),
        ("emitter_y_m", float("inf")),
    ],
)
def test_bad_values_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=rf"^{name}: "):
        with_parameter(get_scenario("paper-1m"), name, value)
    with pytest.raises(ValueError, match=rf"^{name}: "):
        check_parameter_value(name, value)


def test_speed_of_a_hovering_frame_cannot_be_set():
    paper = get_scenario("paper-1m")
    hover = paper.replace(flight=paper.flight.with_frame([0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"^speed_mps: frame 1 .*zero velocity"):
        with_parameter(hover, "speed_mps", 5.0)
