"""The emitter's height as an unknown (MATH §8, §7): the data model, files, the refusal of the
estimators that take it as known, and the 3-D bound of ``emitterbench crlb``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from comparison.crlb import crlb_table
from estimators import make_estimator
from estimators.interface import capabilities_of
from estimators.registry import BUILTIN
from scenarios import get_scenario
from scenarios import measurement_model as model
from scenarios.files import measurements_from_json, measurements_to_json, write_measurements
from scenarios.fisher import fisher_information, inverse_symmetric
from scenarios.nuisance import (
    HEIGHT_UNKNOWN,
    describe_unknowns,
    math_sections,
    nuisance_unknowns,
    parse_unknowns,
    position_dimension,
    unknowns_used,
)
from scenarios.simulate import noise_free, simulate
from tests.comparison.test_cli import invoke

HEIGHT_M = 30.0


def elevated(name: str = "turn", unknowns=(HEIGHT_UNKNOWN,)):
    """A named scenario with its emitter ``HEIGHT_M`` above the take-off ground, unknown."""
    return get_scenario(name).replace(unknowns=unknowns, emitter_height_m=HEIGHT_M)


def test_the_height_is_an_unknown_but_not_a_nuisance_parameter() -> None:
    both = ("carrier_offset_hz", "emission_time_s")
    assert parse_unknowns([HEIGHT_UNKNOWN, "emission_time_s"]) == (
        "emission_time_s",
        HEIGHT_UNKNOWN,
    )
    assert nuisance_unknowns([*both, HEIGHT_UNKNOWN]) == both
    assert (position_dimension([HEIGHT_UNKNOWN]), position_dimension(both)) == (3, 2)
    assert unknowns_used([HEIGHT_UNKNOWN], {"rss"}) == (HEIGHT_UNKNOWN,)
    assert unknowns_used([HEIGHT_UNKNOWN], set()) == ()
    assert describe_unknowns([HEIGHT_UNKNOWN, "carrier_offset_hz"]) == "carrier offset and height"
    assert math_sections([HEIGHT_UNKNOWN]) == "MATH §8"
    assert math_sections(["emission_time_s"]) == "MATH §15"
    assert math_sections([HEIGHT_UNKNOWN, "carrier_offset_hz"]) == "MATH §8, §15"
    with pytest.raises(ValueError, match=r"expected a list of any of .*'emitter_height_m'"):
        parse_unknowns(["height"])


def test_the_data_hold_the_true_emitter_in_3d_and_only_the_assumed_height() -> None:
    """Noise-free data of an unknown height are the model at the true (x, y, z); the data's
    ``emitter_height_m`` is the take-off ground an estimator ignoring it assumes."""
    data = noise_free(elevated())
    truth = np.array([*get_scenario("turn").emitter_m, HEIGHT_M])
    np.testing.assert_array_equal(data.truth_emitter_m, truth)
    assert data.emitter_height_m == 0.0
    p, v = data.position_m, data.velocity_mps
    np.testing.assert_allclose(
        data.toa_s, model.toa_s(p, truth, data.speed_of_light_mps), rtol=1e-12
    )
    np.testing.assert_allclose(
        data.doppler_hz, model.doppler_hz(p, v, truth, data.gamma_per_m), rtol=1e-12
    )
    # ignoring the height assumes the take-off ground: ranges shorter than the UAV's height
    # above it are that assumption's error (the bias an experiment measures), not refused; the
    # same values stated as a file's known height are physically impossible and refused by name
    assumed = data.assuming_known()
    assert assumed.height_assumed and assumed.unknowns == ()
    np.testing.assert_array_equal(assumed.toa_s, data.toa_s)
    assert np.any(data.speed_of_light_mps * data.toa_s < data.position_m[:, 2])
    with pytest.raises(ValueError, match=r"^toa_s\[\d+\]: the range c·τ = .* is shorter than"):
        dataclasses.replace(assumed, height_assumed=False)
    low = noise_free(get_scenario("turn").replace(unknowns=(HEIGHT_UNKNOWN,), emitter_height_m=5.0))
    ignoring = low.assuming_known()
    assert ignoring.unknowns == () and ignoring.emitter_height_m == 0.0
    np.testing.assert_array_equal(ignoring.truth_emitter_m, low.truth_emitter_m[:2])


def test_a_file_round_trips_the_3d_truth_and_a_2d_one_is_refused_naming_it() -> None:
    data = simulate(elevated(), snr_db=20.0, seed=4)
    text = measurements_to_json(data)
    back = measurements_from_json(text)
    assert back.unknowns == (HEIGHT_UNKNOWN,)
    np.testing.assert_array_equal(back.truth_emitter_m, data.truth_emitter_m)
    np.testing.assert_array_equal(back.toa_s, data.toa_s)
    flat = json.loads(text)
    flat["truth"]["emitter_m"] = flat["truth"]["emitter_m"][:2]
    with pytest.raises(ValueError, match=r"^truth\.emitter_m: expected 3 numbers, got 2$"):
        measurements_from_json(json.dumps(flat))


@pytest.mark.parametrize(
    "name",
    sorted(n for n in BUILTIN if HEIGHT_UNKNOWN not in capabilities_of(make_estimator(n)).unknowns),
)
def test_every_builtin_refuses_an_unknown_height_in_one_line(name) -> None:
    """Every built-in that does not declare the height in its ``Capabilities.unknowns``."""
    data = simulate(elevated(), snr_db=20.0, seed=1)
    with pytest.raises(ValueError) as caught:
        make_estimator(name).estimate(data)
    message = str(caught.value)
    assert message.startswith("unknowns: the data declare the emitter's height unknown, but ")
    assert "(MATH §8)" in message and "\n" not in message


def test_the_crlb_table_in_3d_splits_the_bound_and_prices_the_height() -> None:
    """beacon-pass with every unknown: the 3×3 bound is the inverse of the information at the
    3-D truth, its trace split into horizontal and vertical parts; the bound with everything
    known is the 2-D bound of the same data at the true height (another code path: tolerance)."""
    unknowns = ("carrier_offset_hz", "emission_time_s", HEIGHT_UNKNOWN)
    data = noise_free(elevated("beacon-pass", unknowns), snr_db=20.0)
    table = crlb_table(data, data.truth_emitter_m)
    assert table["at_m"] == data.truth_emitter_m.tolist()
    expected = inverse_symmetric(fisher_information(data, data.truth_emitter_m))
    bound = np.array(table["crlb_m2"]["toa+doppler"])
    np.testing.assert_array_equal(bound, expected)
    horizontal = table["horizontal_rmse_bound_m"]["toa+doppler"]
    vertical = table["vertical_rmse_bound_m"]["toa+doppler"]
    assert horizontal**2 + vertical**2 == pytest.approx(np.trace(bound), rel=1e-12)
    known_height = dataclasses.replace(
        data, unknowns=(), emitter_height_m=HEIGHT_M, truth_emitter_m=data.truth_emitter_m[:2]
    )
    plane = known_height.truth_emitter_m
    all_known = np.sqrt(np.trace(inverse_symmetric(fisher_information(known_height, plane))))
    assert table["known_rmse_bound_m"]["toa+doppler"] == pytest.approx(all_known, rel=1e-9)
    assert table["price"]["toa+doppler"] > 1.0


def test_crlb_json_of_a_file_with_the_height_unknown_is_3x3(tmp_path: Path) -> None:
    path = write_measurements(simulate(elevated(), snr_db=10.0, seed=2), tmp_path / "m.json")
    result = invoke("crlb", path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["unknowns"] == [HEIGHT_UNKNOWN] and len(out["at_m"]) == 3
    assert np.shape(out["crlb_m2"]["toa+doppler"]) == (3, 3)
    assert set(out["horizontal_rmse_bound_m"]) == set(out["vertical_rmse_bound_m"])
    table = invoke("crlb", path)
    assert table.exit_code == 0, table.output
    assert "vertical" in table.stdout and "the 3×3 CRLB matrices: --json" in table.stdout


def test_with_the_height_unknown_a_range_only_has_to_be_positive() -> None:
    """No height bounds the ranges from below any more, but a negative range is still refused
    by name."""
    obj = json.loads(measurements_to_json(noise_free(elevated())))
    obj["samples"][0]["toa_s"] = -1e-7
    with pytest.raises(ValueError, match=r"^toa_s\[0\]: the range c·τ = -30 m is shorter"):
        measurements_from_json(json.dumps(obj))
