"""Measurement files: exact JSON round trip, CSV equal to JSON, and named errors."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scenarios.catalog import get_scenario
from scenarios.files import (
    SCHEMA,
    measurements_from_dict,
    measurements_from_json,
    measurements_to_dict,
    read_measurements,
    read_measurements_csv,
    write_measurements,
)
from scenarios.simulate import simulate
from scenarios.types import MeasurementSet, NoiseSigmas, RssModel

ARRAY_FIELDS = (
    "frame",
    "time_s",
    "position_m",
    "velocity_mps",
    "doppler_hz",
    "toa_s",
    "rss_dbm",
    "truth_emitter_m",
)


def assert_bit_identical(read: MeasurementSet, original: MeasurementSet) -> None:
    for name in ARRAY_FIELDS:
        got, want = getattr(read, name), getattr(original, name)
        if want is None:
            assert got is None, name
            continue
        assert got.dtype == want.dtype, name
        assert got.shape == want.shape, name
        assert got.tobytes() == want.tobytes(), name
    for name in ("carrier_hz", "speed_of_light_mps", "emitter_height_m"):
        assert getattr(read, name) == getattr(original, name), name
    assert read.noise.as_dict() == original.noise.as_dict()
    if original.rss_model is None:
        assert read.rss_model is None
    else:
        assert read.rss_model.as_dict() == original.rss_model.as_dict()


# --------------------------------------------------------------------------------------------
# round trips
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "frames", "snr_db"), [("paper-1m", 2, 7.3), ("orbit", None, -3)])
def test_json_round_trip_is_bit_exact(tmp_path: Path, name: str, frames, snr_db: float) -> None:
    data = simulate(get_scenario(name, frames=frames), snr_db=snr_db, seed=11)
    path = write_measurements(data, tmp_path / "m.json")
    read = read_measurements(path)
    assert_bit_identical(read, data)
    # a second write of what was read gives the same bytes
    again = write_measurements(read, tmp_path / "again.json")
    assert again.read_bytes() == path.read_bytes()
    assert {p.name for p in tmp_path.iterdir()} == {"m.json", "again.json"}  # no temporaries


def test_written_file_is_strict_json_with_one_sample_per_line(tmp_path: Path) -> None:
    data = simulate(get_scenario("turn"), snr_db=0.0, seed=2)
    path = write_measurements(data, tmp_path / "m.json")

    def reject(constant: str) -> None:
        raise AssertionError(f"non-standard JSON constant {constant}")

    obj = json.loads(path.read_text(), parse_constant=reject)
    assert obj["schema"] == SCHEMA
    assert obj["truth"] == {"emitter_m": [35.0, 15.0]}
    assert len(obj["samples"]) == data.n_samples == 20
    sample_lines = [line for line in path.read_text().splitlines() if '"frame"' in line]
    assert len(sample_lines) == data.n_samples


def test_optional_fields_are_left_out_and_read_back_as_absent(tmp_path: Path) -> None:
    full = simulate(get_scenario("paper-10m"), snr_db=3.0, seed=5)
    data = dataclasses.replace(
        full.without("rss"),
        noise=NoiseSigmas(doppler_hz=full.noise.doppler_hz, toa_s=full.noise.toa_s),
        rss_model=None,
        truth_emitter_m=None,
    )
    obj = measurements_to_dict(data)
    assert set(obj) == {
        "schema",
        "carrier_hz",
        "speed_of_light_mps",
        "emitter_height_m",
        "noise",
        "samples",
    }
    assert set(obj["noise"]) == {"doppler_hz", "toa_s"}
    assert "rss_dbm" not in obj["samples"][0]
    read = read_measurements(write_measurements(data, tmp_path / "m.json"))
    assert_bit_identical(read, data)
    assert read.modalities == {"doppler", "toa"}


def valid_dict() -> dict[str, Any]:
    """Four samples in two frames, every optional field present."""
    return {
        "schema": SCHEMA,
        "carrier_hz": 3.0e8,
        "speed_of_light_mps": 3.0e8,
        "emitter_height_m": 0.0,
        "noise": {"doppler_hz": 0.1, "toa_s": 3.3e-9, "rss_db": 4.0},
        "rss_model": {
            "reference_power_dbm": 0.0,
            "reference_distance_m": 1.0,
            "path_loss_exponent": 2.0,
        },
        "truth": {"emitter_m": [35.0, 15.0]},
        "samples": [
            {
                "frame": k // 2,
                "time_s": 0.05 * k,
                "position_m": [0.5 * k, 0, 50],
                "velocity_mps": [10, 0, 0],
                "doppler_hz": 5.57 - 0.1 * k,
                "toa_s": 2.05e-7 - 1e-10 * k,
                "rss_dbm": -30.7 + 0.1 * k,
            }
            for k in range(4)
        ],
    }


def test_valid_dict_reads_with_its_values() -> None:
    data = measurements_from_dict(valid_dict())
    np.testing.assert_array_equal(data.frame, [0, 0, 1, 1])
    np.testing.assert_array_equal(data.position_m[:, 0], [0.0, 0.5, 1.0, 1.5])
    np.testing.assert_array_equal(data.doppler_hz, [5.57 - 0.1 * k for k in range(4)])
    assert data.modalities == {"doppler", "toa", "rss"}
    assert data.noise.toa_s == 3.3e-9
    assert data.rss_model.path_loss_exponent == 2.0
    np.testing.assert_array_equal(data.truth_emitter_m, [35.0, 15.0])


def test_defaults_for_speed_of_light_height_and_optional_blocks() -> None:
    obj = valid_dict()
    for key in ("speed_of_light_mps", "emitter_height_m", "truth"):
        del obj[key]
    data = measurements_from_dict(obj)
    assert data.speed_of_light_mps == 299_792_458.0
    assert data.emitter_height_m == 0.0
    assert data.truth_emitter_m is None


# --------------------------------------------------------------------------------------------
# malformed JSON: every error names the field path
# --------------------------------------------------------------------------------------------


def mutated(change: Callable[[dict[str, Any]], object]) -> str:
    obj = valid_dict()
    change(obj)
    return json.dumps(obj)  # writes NaN / Infinity literally, as a careless producer would


def set_in(path: tuple[Any, ...], value: Any) -> Callable[[dict[str, Any]], None]:
    def change(obj: dict[str, Any]) -> None:
        target = obj
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


def delete(path: tuple[Any, ...]) -> Callable[[dict[str, Any]], None]:
    def change(obj: dict[str, Any]) -> None:
        target = obj
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return change


def drop_modalities(obj: dict[str, Any]) -> None:
    for sample in obj["samples"]:
        for name in ("doppler_hz", "toa_s", "rss_dbm"):
            del sample[name]


MALFORMED_JSON: list[tuple[str, str, str]] = [
    ("missing-carrier", mutated(delete(("carrier_hz",))), "carrier_hz"),
    ("missing-samples", mutated(delete(("samples",))), "samples"),
    ("missing-position", mutated(delete(("samples", 1, "position_m"))), "samples[1].position_m"),
    ("nan-doppler", mutated(set_in(("samples", 2, "doppler_hz"), float("nan"))), "samples[2].doppler_hz"),
    ("infinite-toa", mutated(set_in(("samples", 0, "toa_s"), float("inf"))), "samples[0].toa_s"),
    ("minus-infinite-carrier", mutated(set_in(("carrier_hz",), -float("inf"))), "carrier_hz"),
    ("overflowing-number", mutated(set_in(("emitter_height_m",), 10**400)), "emitter_height_m"),
    ("short-position", mutated(set_in(("samples", 2, "position_m"), [0, 0])), "samples[2].position_m"),
    ("long-velocity", mutated(set_in(("samples", 0, "velocity_mps"), [1, 2, 3, 4])), "samples[0].velocity_mps"),
    ("position-not-array", mutated(set_in(("samples", 3, "position_m"), 5)), "samples[3].position_m"),
    ("string-time", mutated(set_in(("samples", 1, "time_s"), "0.05")), "samples[1].time_s"),
    ("boolean-carrier", mutated(set_in(("carrier_hz",), True)), "carrier_hz"),
    ("string-coordinate", mutated(set_in(("samples", 0, "position_m", 2), "50")), "samples[0].position_m[2]"),
    ("null-toa", mutated(set_in(("samples", 1, "toa_s"), None)), "samples[1].toa_s"),
    ("unknown-schema", mutated(set_in(("schema",), "emitterbench.measurements/9")), "schema"),
    ("missing-schema", mutated(delete(("schema",))), "schema"),
    ("unknown-top-key", mutated(set_in(("carrier_frequency",), 1.0)), "carrier_frequency"),
    ("unknown-sample-key", mutated(set_in(("samples", 0, "toa"), 1e-7)), "samples[0].toa"),
    ("unknown-noise-key", mutated(set_in(("noise", "toa"), 1e-9)), "noise.toa"),
    ("empty-samples", mutated(set_in(("samples",), [])), "samples"),
    ("samples-not-array", mutated(set_in(("samples",), {"frame": 0})), "samples"),
    ("sample-not-object", mutated(set_in(("samples", 1), [0, 0.0])), "samples[1]"),
    ("negative-sigma", mutated(set_in(("noise", "toa_s"), -3.3e-9)), "noise.toa_s"),
    ("zero-sigma", mutated(set_in(("noise", "doppler_hz"), 0)), "noise.doppler_hz"),
    ("noise-not-object", mutated(set_in(("noise",), 0.1)), "noise"),
    ("sigma-missing-for-toa", mutated(delete(("noise", "toa_s"))), "noise.toa_s"),
    ("toa-on-some-samples", mutated(delete(("samples", 2, "toa_s"))), "samples[2].toa_s"),
    ("no-modality", mutated(drop_modalities), "doppler_hz/toa_s/rss_dbm"),
    ("frames-out-of-order", mutated(set_in(("samples", 2, "frame"), 2)), "samples[3].frame"),
    ("negative-frame", mutated(set_in(("samples", 0, "frame"), -1)), "samples[0].frame"),
    ("fractional-frame", mutated(set_in(("samples", 1, "frame"), 0.5)), "samples[1].frame"),
    ("rss-without-model", mutated(delete(("rss_model",))), "rss_model"),
    ("rss-model-incomplete", mutated(delete(("rss_model", "path_loss_exponent"))), "rss_model.path_loss_exponent"),
    ("rss-model-negative-exponent", mutated(set_in(("rss_model", "path_loss_exponent"), -2)), "rss_model.path_loss_exponent"),
    ("truth-length", mutated(set_in(("truth", "emitter_m"), [35.0, 15.0, 0.0])), "truth.emitter_m"),
    ("truth-unknown-key", mutated(set_in(("truth", "position_m"), [1, 2])), "truth.position_m"),
    ("zero-carrier", mutated(set_in(("carrier_hz",), 0)), "carrier_hz"),
    ("negative-speed-of-light", mutated(set_in(("speed_of_light_mps",), -3e8)), "speed_of_light_mps"),
    ("non-object-json", "[1, 2, 3]", "measurements"),
    ("invalid-json-text", '{"schema": "emitterbench.measurements/1", "carrier_hz": }', "json"),
    ("duplicate-key", '{"schema": "emitterbench.measurements/1", "carrier_hz": 1, "carrier_hz": 2}', "carrier_hz"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "field"),
    [case[1:] for case in MALFORMED_JSON],
    ids=[case[0] for case in MALFORMED_JSON],
)
def test_malformed_json_names_the_field(text: str, field: str) -> None:
    with pytest.raises(ValueError) as caught:
        measurements_from_json(text)
    message = str(caught.value)
    assert message.startswith(f"{field}: "), message
    assert "\n" not in message
    assert len(message) > len(field) + 10  # it says what is wrong, not just where


def test_unknown_key_suggests_the_close_name() -> None:
    with pytest.raises(ValueError, match=r"^samples\[0\]\.toa: unknown key \(did you mean 'toa_s'"):
        measurements_from_json(mutated(set_in(("samples", 0, "toa"), 1e-7)))


def test_partial_modality_names_a_sample_that_has_it() -> None:
    with pytest.raises(ValueError, match=r"^samples\[0\]\.rss_dbm: missing, but samples\[1\] has"):
        measurements_from_json(mutated(delete(("samples", 0, "rss_dbm"))))


def test_file_errors_name_the_file(tmp_path: Path) -> None:
    broken = tmp_path / "broken.json"
    broken.write_text('{"schema": ')
    with pytest.raises(ValueError, match=r"broken\.json: invalid JSON at line 1, column 12"):
        read_measurements(broken)
    with pytest.raises(ValueError, match=r"absent\.json: no such file"):
        read_measurements(tmp_path / "absent.json")
    wrong_type = tmp_path / "m.txt"
    wrong_type.write_text("{}")
    with pytest.raises(ValueError, match=r"m\.txt: unknown file type '\.txt'"):
        read_measurements(wrong_type)
    good = tmp_path / "good.json"
    good.write_text(json.dumps(valid_dict()))
    with pytest.raises(ValueError, match=r"^carrier_hz: only for CSV files"):
        read_measurements(good, carrier_hz=1e9)


# --------------------------------------------------------------------------------------------
# atomic writes
# --------------------------------------------------------------------------------------------


def test_failed_replace_leaves_the_old_file_and_no_temporary(tmp_path: Path, monkeypatch) -> None:
    data = simulate(get_scenario("paper-1m"), seed=1)
    path = tmp_path / "m.json"
    path.write_text("old contents")

    def refuse(source: str, target: str) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(ValueError, match=r"^output: cannot write"):
        write_measurements(data, path)
    assert path.read_text() == "old contents"
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


def test_bad_output_writes_nothing(tmp_path: Path) -> None:
    data = simulate(get_scenario("paper-1m"), seed=1)
    with pytest.raises(ValueError, match=r"^output: folder .*missing does not exist"):
        write_measurements(data, tmp_path / "missing" / "m.json")
    with pytest.raises(ValueError, match=r"^output: .*must end in \.json"):
        write_measurements(data, tmp_path / "m.csv")
    existing = tmp_path / "keep.json"
    existing.write_text("old contents")
    with pytest.raises(ValueError, match=r"^data: expected a MeasurementSet"):
        write_measurements({"not": "measurements"}, existing)  # type: ignore[arg-type]
    assert existing.read_text() == "old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.json"]


# --------------------------------------------------------------------------------------------
# CSV
# --------------------------------------------------------------------------------------------


def write_csv(data: MeasurementSet, path: Path, *, columns: tuple[str, ...] | None = None) -> Path:
    """The sample table by hand (``repr`` floats), independent of the library's writer."""
    table = {
        "frame": data.frame,
        "time_s": data.time_s,
        "x_m": data.position_m[:, 0],
        "y_m": data.position_m[:, 1],
        "z_m": data.position_m[:, 2],
        "vx_mps": data.velocity_mps[:, 0],
        "vy_mps": data.velocity_mps[:, 1],
        "vz_mps": data.velocity_mps[:, 2],
    }
    for name in ("doppler_hz", "toa_s", "rss_dbm"):
        if getattr(data, name) is not None:
            table[name] = getattr(data, name)
    names = columns or tuple(table)
    lines = [",".join(names)]
    lines += [",".join(repr(table[n][i].item()) for n in names) for i in range(data.n_samples)]
    path.write_text("\n".join(lines) + "\n")
    return path


def csv_constants(data: MeasurementSet) -> dict[str, Any]:
    return {
        "carrier_hz": data.carrier_hz,
        "speed_of_light_mps": data.speed_of_light_mps,
        "emitter_height_m": data.emitter_height_m,
        "noise": data.noise,
        "rss_model": data.rss_model,
        "truth_emitter_m": data.truth_emitter_m,
    }


def test_csv_reads_the_same_as_json(tmp_path: Path) -> None:
    data = simulate(get_scenario("turn"), snr_db=4.0, seed=9)
    from_json = read_measurements(write_measurements(data, tmp_path / "m.json"))
    csv_path = write_csv(data, tmp_path / "m.csv")
    from_csv = read_measurements_csv(csv_path, **csv_constants(data))
    assert_bit_identical(from_csv, from_json)
    assert measurements_to_dict(from_csv) == measurements_to_dict(from_json)
    via_dispatch = read_measurements(csv_path, **csv_constants(data))
    assert measurements_to_dict(via_dispatch) == measurements_to_dict(from_json)


def test_csv_columns_in_any_order_and_empty_column_means_absent(tmp_path: Path) -> None:
    data = simulate(get_scenario("paper-1m"), seed=4).without("rss")
    order = ("toa_s", "vz_mps", "z_m", "frame", "x_m", "vx_mps", "time_s", "y_m", "vy_mps")
    path = write_csv(data, tmp_path / "m.csv", columns=order)
    text = path.read_text().splitlines()
    # an all-empty doppler column: the modality is absent
    path.write_text("\n".join([text[0] + ",doppler_hz"] + [line + "," for line in text[1:]]))
    read = read_measurements_csv(
        path, carrier_hz=data.carrier_hz, speed_of_light_mps=3e8, noise=data.noise
    )
    assert read.modalities == {"toa"}
    assert read.toa_s.tobytes() == data.toa_s.tobytes()
    assert read.position_m.tobytes() == data.position_m.tobytes()
    assert read.emitter_height_m == 0.0


HEADER = "frame,time_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,doppler_hz,toa_s"
ROW = "{frame},{time},{x},0,50,10,0,0,5.5,2.0e-7"


def csv_text(*rows: str, header: str = HEADER) -> str:
    return "\n".join([header, *rows]) + "\n"


def rows(n: int = 3) -> list[str]:
    return [ROW.format(frame=k // 2, time=0.05 * k, x=0.5 * k) for k in range(n)]


MALFORMED_CSV: list[tuple[str, str, str]] = [
    ("unknown-column", csv_text(*rows(), header=HEADER.replace("toa_s", "toa")), "toa"),
    ("missing-column", csv_text(*[r.replace(",50,", ",") for r in rows()], header=HEADER.replace("z_m,", "")), "z_m"),
    ("duplicate-column", csv_text(*[r + ",0" for r in rows()], header=HEADER + ",x_m"), "x_m"),
    ("not-a-number", csv_text(rows()[0], rows()[1].replace(",0.5,", ",half,"), rows()[2]), "x_m (CSV line 3)"),
    ("nan-cell", csv_text(*rows()[:2], rows()[2].replace("2.0e-7", "nan")), "toa_s (CSV line 4)"),
    ("infinite-cell", csv_text(rows()[0].replace("5.5", "inf"), *rows()[1:]), "doppler_hz (CSV line 2)"),
    ("empty-required-cell", csv_text(rows()[0].replace("0.0,", ",", 1), *rows()[1:]), "time_s (CSV line 2)"),
    ("toa-on-some-rows", csv_text(rows()[0], rows()[1].replace(",2.0e-7", ","), rows()[2]), "toa_s (CSV line 3)"),
    ("short-row", csv_text(rows()[0], "1,0.05,0.5,0,50", rows()[2]), "samples (CSV line 3)"),
    ("frames-out-of-order", csv_text(*rows(), ROW.format(frame=0, time=0.2, x=2.0)), "frame (CSV line 5)"),
    ("fractional-frame", csv_text(ROW.format(frame=0.5, time=0, x=0)), "frame (CSV line 2)"),
    ("empty-file", "", "header"),
    ("header-only", csv_text(), "samples"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "field"), [case[1:] for case in MALFORMED_CSV], ids=[case[0] for case in MALFORMED_CSV]
)
def test_malformed_csv_names_the_column_and_line(tmp_path: Path, text: str, field: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text(text)
    noise = NoiseSigmas(doppler_hz=0.1, toa_s=1e-9)
    with pytest.raises(ValueError) as caught:
        read_measurements_csv(path, carrier_hz=3e8, noise=noise)
    assert str(caught.value).startswith(f"{field}: "), str(caught.value)


def test_csv_constants_are_checked_by_name(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    path.write_text(csv_text(*rows()))
    with pytest.raises(ValueError, match=r"^noise\.toa_s: toa measurements are present"):
        read_measurements_csv(path, carrier_hz=3e8, noise=NoiseSigmas(doppler_hz=0.1))
    with pytest.raises(ValueError, match=r"^carrier_hz: required to read the CSV file"):
        read_measurements(path, noise=NoiseSigmas(doppler_hz=0.1, toa_s=1e-9))
    with_rss = tmp_path / "rss.csv"
    with_rss.write_text(csv_text(*[r + ",-30" for r in rows()], header=HEADER + ",rss_dbm"))
    sigmas = NoiseSigmas(doppler_hz=0.1, toa_s=1e-9, rss_db=4.0)
    with pytest.raises(ValueError, match=r"^rss_model: RSS measurements are present"):
        read_measurements_csv(with_rss, carrier_hz=3e8, noise=sigmas)
    read = read_measurements_csv(with_rss, carrier_hz=3e8, noise=sigmas, rss_model=RssModel())
    np.testing.assert_array_equal(read.rss_dbm, [-30.0, -30.0, -30.0])


def test_reading_does_not_modify_the_input_dict() -> None:
    obj = valid_dict()
    before = copy.deepcopy(obj)
    measurements_from_dict(obj)
    assert obj == before


# --------------------------------------------------------------------------------------------
# parsing and resource limits (scenarios.limits)
# --------------------------------------------------------------------------------------------


def huge(digits: int) -> str:
    return "9" * digits


def raw_at(path: tuple[Any, ...], literal: str) -> str:
    """The valid file's JSON with the value at ``path`` written as the raw ``literal``."""
    return mutated(set_in(path, "@raw@")).replace('"@raw@"', literal)


@pytest.mark.parametrize(
    ("path", "literal", "message"),
    [
        (("carrier_hz",), huge(5000), "carrier_hz: an integer of 5000 digits is too large"),
        (("samples", 1, "frame"), huge(5000), r"samples\[1\]\.frame: an integer of 5000 digits"),
        (("samples", 0, "time_s"), "-" + huge(4400), r"samples\[0\]\.time_s: an integer of 4400"),
        (("samples", 3, "frame"), str(2**64), r"samples\[3\]\.frame: frame .* is too large"),
        (("carrier_hz",), "1" + "0" * 400, "carrier_hz: too large for a float"),
    ],
)
def test_huge_integers_name_their_field(path, literal: str, message: str) -> None:
    with pytest.raises(ValueError, match=f"^{message}") as caught:
        measurements_from_json(raw_at(path, literal))
    assert len(str(caught.value)) < 300  # the size, not the digits


def test_nesting_is_refused_at_a_documented_depth_without_recursion() -> None:
    from scenarios.limits import MAX_NESTING_DEPTH, check_nesting

    inner = "[" * 40 + "1" + "]" * 40
    with pytest.raises(
        ValueError, match=r"^samples\[0\]\.toa_s\[0\]: arrays and objects nest more"
    ):
        measurements_from_json(raw_at(("samples", 0, "toa_s"), inner))
    with pytest.raises(
        ValueError, match=rf"^json: arrays and objects nest more than {MAX_NESTING_DEPTH}"
    ):
        measurements_from_json("[" * 100_000 + "]" * 100_000)  # beyond Python's recursion limit
    deep: Any = 1
    for _ in range(200_000):  # deeper than any recursive walk could go
        deep = [deep]
    with pytest.raises(ValueError, match=r"^\[0\]\[0\]\[0\]\[0\]: arrays"):
        check_nesting(deep)
    check_nesting(json.loads(json.dumps(valid_dict())))  # the format itself is well inside


def test_a_key_with_spaces_is_quoted_as_its_field() -> None:
    with pytest.raises(ValueError, match=r'^noise\["a b"\]: unknown key'):
        measurements_from_json(mutated(set_in(("noise", "a b"), 1.0)))
    with pytest.raises(ValueError, match=r'^\[""\]: unknown key'):
        measurements_from_json(mutated(set_in(("",), 1.0)))


@pytest.mark.parametrize("suffix", [".json", ".csv"])
def test_a_byte_order_mark_is_ignored(tmp_path: Path, suffix: str) -> None:
    data = simulate(get_scenario("turn"), snr_db=4.0, seed=9)
    plain = tmp_path / f"plain{suffix}"
    if suffix == ".json":
        write_measurements(data, plain)
        constants: dict[str, Any] = {}
    else:
        write_csv(data, plain)
        constants = csv_constants(data)
    marked = tmp_path / f"marked{suffix}"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert_bit_identical(
        read_measurements(marked, **constants), read_measurements(plain, **constants)
    )


def test_an_oversized_file_is_refused_before_it_is_read(tmp_path: Path, monkeypatch) -> None:
    from scenarios.limits import MAX_FILE_MB

    path = tmp_path / "big.json"
    with path.open("wb") as handle:  # sparse, all NUL bytes: the size alone refuses it
        handle.truncate(MAX_FILE_MB * 2**20 + 1)
    with pytest.raises(ValueError, match=rf"big\.json: larger than the limit of {MAX_FILE_MB} MiB"):
        read_measurements(path)
    monkeypatch.setenv("EMITTERBENCH_MAX_FILE_MB", str(MAX_FILE_MB + 1))
    with pytest.raises(ValueError, match=r"big\.json: invalid JSON at line 1"):  # read now
        read_measurements(path)


def test_samples_and_frames_beyond_the_limits_are_refused(tmp_path: Path, monkeypatch) -> None:
    text = mutated(lambda obj: None)  # four samples in two frames
    measurements_from_json(text)
    monkeypatch.setenv("EMITTERBENCH_MAX_SAMPLES", "3")
    with pytest.raises(
        ValueError,
        match=r"^samples: 4 samples, more than the limit of 3; split the file, or "
        r"raise the limit with the environment variable EMITTERBENCH_MAX_SAMPLES=N",
    ):
        measurements_from_json(text)
    data = simulate(get_scenario("turn"), snr_db=4.0, seed=9)
    path = write_csv(data, tmp_path / "m.csv")
    with pytest.raises(ValueError, match=r"^samples: 4 rows or more, more than the limit of 3"):
        read_measurements_csv(path, **csv_constants(data))
    monkeypatch.setenv("EMITTERBENCH_MAX_SAMPLES", "4")
    monkeypatch.setenv("EMITTERBENCH_MAX_FRAMES", "1")
    with pytest.raises(ValueError, match=r"^samples: 2 frames, more than the limit of 1"):
        measurements_from_json(text)
    monkeypatch.setenv("EMITTERBENCH_MAX_FRAMES", "0")
    with pytest.raises(ValueError, match=r"^EMITTERBENCH_MAX_FRAMES: expected a whole number"):
        measurements_from_json(text)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (
            lambda lines: [*lines[:2], '"' + lines[2], *lines[3:]],
            r"samples \(CSV line 3\): a quoted",
        ),
        (
            lambda lines: [lines[0], lines[1].replace("0.0", "1" * 200_000, 1), *lines[2:]],
            r"samples \(CSV line 2\): a cell longer",
        ),
        (
            lambda lines: [lines[0], lines[1].replace("0.0", "x" * 5000, 1), *lines[2:]],
            r"time_s \(CSV line 2\): 'xxx",
        ),
    ],
    ids=["unclosed-quote", "cell-over-the-csv-limit", "long-cell"],
)
def test_csv_problems_name_the_line(tmp_path: Path, change, field: str) -> None:
    data = simulate(get_scenario("turn"), snr_db=4.0, seed=9)
    path = write_csv(data, tmp_path / "m.csv")
    path.write_text("\n".join(change(path.read_text().splitlines())) + "\n")
    with pytest.raises(ValueError, match=f"^{field}") as caught:
        read_measurements_csv(path, **csv_constants(data))
    assert len(str(caught.value)) < 400
