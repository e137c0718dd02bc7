"""The non-cooperative emitter's nuisance parameters (MATH §15): data model, files and bound."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios import get_scenario
from scenarios import measurement_model as model
from scenarios.files import measurements_from_json, measurements_to_json
from scenarios.fisher import (
    fisher_information,
    fisher_information_per_frame,
    inverse_2x2,
    rmse_bound_m,
)
from scenarios.nuisance import parse_unknowns, unknowns_used
from scenarios.simulate import noise_free, simulate

BOTH = ("carrier_offset_hz", "emission_time_s")


def noncooperative(name: str, unknowns=BOTH, offset_hz: float = 800.0, emission_s: float = 3e-4):
    return get_scenario(name).replace(
        unknowns=unknowns, carrier_offset_hz=offset_hz, emission_time_s=emission_s
    )


def finite_difference_bound(data, emitter, unknowns) -> np.ndarray:
    """The (x, y) block of the inverse of the information over (x, y, δ, b), every column by
    central differences of the forward model (no project Jacobian used)."""
    c, gamma, height = data.speed_of_light_mps, data.gamma_per_m, data.emitter_height_m
    columns = ["x", "y", *unknowns]

    def forward(theta):
        values = dict(zip(columns, theta, strict=True))
        xy = np.array([values["x"], values["y"]])
        doppler = model.doppler_hz(
            data.position_m,
            data.velocity_mps,
            xy,
            gamma,
            height,
            values.get("carrier_offset_hz", 0.0),
        )
        toa = model.toa_s(data.position_m, xy, c, height, values.get("emission_time_s", 0.0))
        return np.concatenate([doppler / data.noise.doppler_hz, toa / data.noise.toa_s])

    theta = np.array([*emitter, *(0.0 for _ in unknowns)])
    steps = np.array([1e-4, 1e-4, *(1e-3 if u == BOTH[0] else 1e-9 for u in unknowns)])
    jacobian = np.column_stack(
        [
            (forward(theta + step * e) - forward(theta - step * e)) / (2 * step)
            for step, e in zip(steps, np.eye(len(theta)), strict=True)
        ]
    )
    return np.linalg.inv(jacobian.T @ jacobian)[:2, :2]


@pytest.mark.parametrize("name", ["turn", "paper-1m", "paper-1m-turn"])
@pytest.mark.parametrize(
    "unknowns", [(), ("carrier_offset_hz",), ("emission_time_s",), BOTH], ids=str
)
def test_the_nuisance_crlb_equals_a_finite_difference_fisher_matrix(name, unknowns) -> None:
    scenario = noncooperative(name, unknowns)
    data = noise_free(scenario)
    expected = finite_difference_bound(data, scenario.emitter_m, unknowns)
    bound = inverse_2x2(fisher_information(data, scenario.emitter_m, "toa+doppler"))
    np.testing.assert_allclose(bound, expected, rtol=1e-5)


def test_an_unknown_never_lowers_the_bound_and_both_cost_most() -> None:
    data = noise_free(noncooperative("turn"))
    emitter = np.array([35.0, 15.0])
    rmse = {
        u: float(rmse_bound_m(fisher_information(data, emitter, unknowns=u)))
        for u in [(), ("carrier_offset_hz",), ("emission_time_s",), BOTH]
    }
    assert rmse[()] < rmse[("carrier_offset_hz",)] < rmse[BOTH]
    assert rmse[()] < rmse[("emission_time_s",)] < rmse[BOTH]
    # the known-parameter bound is the one of a cooperative emitter
    cooperative = noise_free(get_scenario("turn"))
    assert rmse[()] == pytest.approx(float(rmse_bound_m(fisher_information(cooperative, emitter))))


def test_accumulated_information_centres_over_the_samples_so_far() -> None:
    scenario = noncooperative("paper-1m-turn")
    data = noise_free(scenario)
    per_frame, accumulated = fisher_information_per_frame(data, scenario.emitter_m)
    for index, frame in enumerate(data.frames):
        direct = fisher_information(data.up_to_frame(frame), scenario.emitter_m)
        own = fisher_information(data.take(data.frame == frame), scenario.emitter_m)
        np.testing.assert_allclose(accumulated[index], direct, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(per_frame[index], own, rtol=1e-10, atol=1e-12)
    # unlike the known case, the accumulated information is not the sum over frames
    assert not np.allclose(accumulated[-1], per_frame.sum(axis=0))


def test_only_unknown_offsets_reach_the_measurements() -> None:
    known = noise_free(get_scenario("turn").replace(carrier_offset_hz=800.0, emission_time_s=1.0))
    cooperative = noise_free(get_scenario("turn"))
    np.testing.assert_array_equal(known.doppler_hz, cooperative.doppler_hz)
    np.testing.assert_array_equal(known.toa_s, cooperative.toa_s)
    data = noise_free(noncooperative("turn"))
    np.testing.assert_allclose(data.doppler_hz - cooperative.doppler_hz, 800.0, rtol=1e-12)
    np.testing.assert_allclose(data.toa_s - cooperative.toa_s, 3e-4, rtol=1e-9)
    assert (data.truth_carrier_offset_hz, data.truth_emission_time_s) == (800.0, 3e-4)
    assert known.truth_carrier_offset_hz is None and known.unknowns == ()


def test_a_file_round_trips_the_unknowns_and_their_truth() -> None:
    data = simulate(noncooperative("turn", ("emission_time_s",)), seed=3)
    text = measurements_to_json(data)
    assert '"unknowns": ["emission_time_s"]' in text
    back = measurements_from_json(text)
    assert back.unknowns == ("emission_time_s",)
    assert back.truth_emission_time_s == 3e-4 and back.truth_carrier_offset_hz is None
    np.testing.assert_array_equal(back.toa_s, data.toa_s)


def test_pseudo_ranges_shorter_than_the_height_load_when_the_emission_time_is_unknown() -> None:
    # an emission time of -1 ms puts every c·τ 300 km below the true range
    data = noise_free(noncooperative("paper-1m", ("emission_time_s",), emission_s=-1e-3))
    assert np.all(data.range_m < 0)
    text = measurements_to_json(data).replace('"unknowns": ["emission_time_s"]', '"unknowns": []')
    with pytest.raises(ValueError, match=r"toa_s\[0\]: the range"):
        measurements_from_json(text)


@pytest.mark.parametrize(
    ("value", "words"),
    [
        (["carrier_offset"], "unknowns: expected a list of any of"),
        ([3], "got 3"),
        ({"carrier_offset_hz": 1}, "got dict"),
        (7, "got int"),
    ],
)
def test_unknowns_are_names_of_nuisance_parameters(value, words) -> None:
    assert parse_unknowns(["emission_time_s", "carrier_offset_hz"]) == BOTH
    assert parse_unknowns("emission_time_s") == parse_unknowns(("emission_time_s",))
    with pytest.raises(ValueError, match=words):
        parse_unknowns(value)


def test_an_unknown_counts_only_in_the_modality_it_enters() -> None:
    assert unknowns_used(BOTH, {"doppler"}) == ("carrier_offset_hz",)
    assert unknowns_used(BOTH, {"toa", "rss"}) == ("emission_time_s",)
    assert unknowns_used(["emission_time_s", "carrier_offset_hz"], {"doppler", "toa"}) == BOTH


def test_a_nuisance_value_beyond_its_limit_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="carrier_offset_hz: 1e\\+13 Hz is outside"):
        get_scenario("turn").replace(carrier_offset_hz=1e13)
    text = measurements_to_json(simulate(noncooperative("turn"), seed=0))
    with pytest.raises(ValueError, match=r"truth\.emission_time_s"):
        measurements_from_json(text.replace('"emission_time_s": 0.0003', '"emission_time_s": 1e20'))
