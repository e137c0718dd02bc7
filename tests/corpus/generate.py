"""Write the malformed and impossible inputs of tests/test_corpus.py into this folder.

Run from the repository root: ``python tests/corpus/generate.py``. Every file is derived from
the two valid measurement files in ``valid/`` (one straight frame of ``paper-1m``, and two
frames of ``turn``, both simulated at 20 dB with seed 1) and from the small experiment
``valid/experiment.toml``; the expected outcome of each file is in the table of
tests/test_corpus.py, which checks that the table and this folder list the same files.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
VALID = HERE / "valid"
MEASUREMENTS = HERE / "measurements"
EXPERIMENTS = HERE / "experiments"

BIG = "9" * 5000
"""An integer of 5000 digits: beyond Python's int-to-string limit of 4300 digits."""


def base(name: str = "paper-1m.json") -> dict[str, Any]:
    return json.loads((VALID / name).read_text(encoding="utf-8"))


def json_case(
    name: str, change: Callable[[dict[str, Any]], None], *, source: str = "paper-1m.json"
):
    obj = copy.deepcopy(base(source))
    change(obj)
    (MEASUREMENTS / f"{name}.json").write_text(json.dumps(obj, indent=1) + "\n", encoding="utf-8")


def raw_case(name: str, text: str | bytes) -> None:
    path = MEASUREMENTS / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")


def replace_number(obj: dict[str, Any], path: list[Any], literal: str) -> str:
    """The JSON text of ``obj`` with the value at ``path`` written as ``literal`` (raw)."""
    marker = "__corpus_marker__"
    target = obj
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = marker
    return json.dumps(obj, indent=1).replace(json.dumps(marker), literal) + "\n"


def nested(depth: int, inner: str = "1") -> str:
    return "[" * depth + inner + "]" * depth


def csv_text(obj: dict[str, Any]) -> str:
    header = "frame,time_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,doppler_hz,toa_s"
    lines = [header]
    for s in obj["samples"]:
        cells = [s["frame"], s["time_s"], *s["position_m"], *s["velocity_mps"]]
        cells += [s["doppler_hz"], s["toa_s"]]
        lines.append(",".join(repr(c) for c in cells))
    return "\n".join(lines) + "\n"


def csv_case(name: str, change: Callable[[list[str]], list[str]]) -> None:
    lines = csv_text(base()).splitlines()
    (MEASUREMENTS / f"{name}.csv").write_text("\n".join(change(lines)) + "\n", encoding="utf-8")


def cell(lines: list[str], row: int, column: int, value: str) -> list[str]:
    cells = lines[row].split(",")
    cells[column] = value
    lines[row] = ",".join(cells)
    return lines


def measurement_cases() -> None:
    def set_path(*path: Any, value: Any) -> Callable[[dict[str, Any]], None]:
        def change(obj: dict[str, Any]) -> None:
            target = obj
            for key in path[:-1]:
                target = target[key]
            target[path[-1]] = value

        return change

    def drop(*path: Any) -> Callable[[dict[str, Any]], None]:
        def change(obj: dict[str, Any]) -> None:
            target = obj
            for key in path[:-1]:
                target = target[key]
            del target[path[-1]]

        return change

    # resource and parsing limits
    raw_case("nesting-5000-deep.json", nested(5000) + "\n")
    raw_case(
        "nesting-5000-deep-in-a-sample.json",
        replace_number(base(), ["samples", 0, "toa_s"], nested(5000)),
    )
    raw_case(
        "nesting-40-deep-in-a-sample.json",
        replace_number(base(), ["samples", 0, "toa_s"], nested(40)),
    )
    raw_case("huge-integer-carrier.json", replace_number(base(), ["carrier_hz"], BIG))
    raw_case("huge-integer-frame.json", replace_number(base(), ["samples", 9, "frame"], BIG))
    raw_case(
        "huge-negative-integer-time.json",
        replace_number(base(), ["samples", 0, "time_s"], "-" + BIG),
    )
    raw_case(
        "integer-beyond-float-carrier.json", replace_number(base(), ["carrier_hz"], "1" + "0" * 400)
    )
    json_case("frame-2-to-the-64", set_path("samples", 9, "frame", value=2**64))
    json_case("frame-2-to-the-64-first", set_path("samples", 0, "frame", value=2**64))
    raw_case("float-1e400-toa.json", replace_number(base(), ["samples", 0, "toa_s"], "1e400"))
    json_case("sigma-doppler-1e200", set_path("noise", "doppler_hz", value=1e200))
    json_case("sigma-toa-1e200", set_path("noise", "toa_s", value=1e200))
    json_case("sigma-toa-1e-300", set_path("noise", "toa_s", value=1e-300))
    json_case("carrier-1e200", set_path("carrier_hz", value=1e200))
    json_case("position-1e200", set_path("samples", 3, "position_m", value=[1e200, 0.0, 50.0]))
    json_case(
        "velocity-1e200", lambda o: [s.update(velocity_mps=[1e200, 0.0, 0.0]) for s in o["samples"]]
    )
    json_case("emitter-height-1e300", set_path("emitter_height_m", value=1e300))
    json_case("truth-1e300", set_path("truth", "emitter_m", value=[1e300, 15.0]))
    # non-finite numbers
    raw_case("nan-toa.json", replace_number(base(), ["samples", 0, "toa_s"], "NaN"))
    raw_case(
        "infinity-doppler.json", replace_number(base(), ["samples", 4, "doppler_hz"], "Infinity")
    )
    raw_case(
        "minus-infinity-position.json",
        replace_number(base(), ["samples", 2, "position_m"], "[0, -Infinity, 50]"),
    )
    raw_case("nan-time.json", replace_number(base(), ["samples", 1, "time_s"], "NaN"))
    raw_case("nan-sigma.json", replace_number(base(), ["noise", "toa_s"], "NaN"))
    raw_case("nan-truth.json", replace_number(base(), ["truth", "emitter_m"], "[NaN, 15]"))
    # wrong shapes and types
    json_case("position-two-numbers", set_path("samples", 0, "position_m", value=[0.0, 0.0]))
    json_case("position-nested", set_path("samples", 0, "position_m", value=[[0.0, 0.0, 50.0]]))
    json_case("velocity-a-string", set_path("samples", 0, "velocity_mps", value="10,0,0"))
    json_case("truth-three-numbers", set_path("truth", "emitter_m", value=[35.0, 15.0, 0.0]))
    json_case("truth-a-list", set_path("truth", value=[35.0, 15.0]))
    json_case("samples-empty", set_path("samples", value=[]))
    json_case("samples-an-object", set_path("samples", value={"frame": 0}))
    json_case("sample-a-number", set_path("samples", 0, value=3))
    json_case("sample-null", set_path("samples", 5, value=None))
    json_case("noise-a-number", set_path("noise", value=0.1))
    json_case("carrier-a-boolean", set_path("carrier_hz", value=True))
    json_case("carrier-a-string", set_path("carrier_hz", value="3e8"))
    json_case("toa-a-list", set_path("samples", 2, "toa_s", value=[2e-7]))
    raw_case("top-level-array.json", "[]\n")
    raw_case("top-level-number.json", "42\n")
    # keys
    json_case("carrier-missing", drop("carrier_hz"))
    json_case("schema-missing", drop("schema"))
    json_case("schema-a-number", set_path("schema", value=1))
    json_case("unknown-key", set_path("carrier_freq", value=3e8))
    json_case("unknown-noise-key", set_path("noise", "toa", value=1e-9))
    json_case("rss-model-incomplete", drop("rss_model", "path_loss_exponent"))
    json_case("toa-on-some-samples", drop("samples", 3, "toa_s"))
    raw_case(
        "duplicate-key.json",
        json.dumps(base(), indent=1).replace(
            '"carrier_hz":', '"carrier_hz": 1.0, "carrier_hz":', 1
        ),
    )
    # values the types refuse
    json_case("sigma-negative", set_path("noise", "toa_s", value=-1e-9))
    json_case("sigma-zero", set_path("noise", "doppler_hz", value=0.0))
    json_case("carrier-zero", set_path("carrier_hz", value=0.0))
    json_case("speed-of-light-negative", set_path("speed_of_light_mps", value=-3e8))
    json_case(
        "rss-reference-distance-zero", set_path("rss_model", "reference_distance_m", value=0.0)
    )
    json_case("frame-negative", set_path("samples", 0, "frame", value=-1))
    json_case("frame-fractional", set_path("samples", 0, "frame", value=0.5))
    json_case(
        "frames-out-of-order", set_path("samples", 15, "frame", value=0), source="turn-2.json"
    )
    # syntax and encoding
    raw_case("invalid-syntax.json", '{"schema": ')
    raw_case("empty.json", "")
    raw_case(
        "not-utf8.json",
        json.dumps(base()).replace("measurements/1", "measurements/1\u00e9").encode("latin-1"),
    )
    raw_case("bom-and-unknown-key.json", "\ufeff" + json.dumps({**base(), "carrier_freq": 1.0}))
    # physically impossible (scenarios/types.py)
    json_case("toa-negated", lambda o: [s.update(toa_s=-s["toa_s"]) for s in o["samples"]])
    json_case("range-shorter-than-height", set_path("samples", 0, "toa_s", value=1e-7))
    json_case(
        "velocity-changes-inside-a-frame",
        set_path("samples", 5, "velocity_mps", value=[0.0, 10.0, 0.0]),
    )
    # CSV
    csv_case(
        "csv-bom-unknown-column",
        lambda ls: ["\ufeff" + ls[0].replace("doppler_hz", "dopler_hz"), *ls[1:]],
    )
    csv_case("csv-bom-nan-cell", lambda ls: cell(["\ufeff" + ls[0], *ls[1:]], 3, 9, "nan"))
    csv_case("csv-huge-integer-frame", lambda ls: cell(ls, 1, 0, BIG))
    csv_case("csv-frame-2-to-the-64", lambda ls: cell(ls, 10, 0, str(2**64)))
    csv_case("csv-float-1e400", lambda ls: cell(ls, 1, 2, "1e400"))
    csv_case("csv-position-1e200", lambda ls: cell(ls, 2, 2, "1e200"))
    csv_case("csv-not-a-number", lambda ls: cell(ls, 2, 8, "fast"))
    csv_case(
        "csv-missing-column",
        lambda ls: [",".join(line.split(",")[:7] + line.split(",")[8:]) for line in ls],
    )
    csv_case("csv-short-row", lambda ls: [*ls[:3], ",".join(ls[3].split(",")[:5]), *ls[4:]])
    csv_case("csv-duplicate-column", lambda ls: [ls[0] + ",x_m", *[line + ",0" for line in ls[1:]]])
    csv_case("csv-nul-byte", lambda ls: [*ls[:2], ls[2].replace(",", ",\0", 1), *ls[3:]])
    csv_case("csv-huge-cell", lambda ls: cell(ls, 2, 1, "1" * 200_000))
    csv_case("csv-unclosed-quote", lambda ls: [*ls[:4], '"' + ls[4]])
    csv_case(
        "csv-toa-negated",
        lambda ls: [ls[0], *[cell([line], 0, 9, "-" + line.split(",")[9])[0] for line in ls[1:]]],
    )
    raw_case("csv-empty.csv", "")
    raw_case("csv-header-only.csv", csv_text(base()).splitlines()[0] + "\n")


# --------------------------------------------------------------------------------------------
# experiments
# --------------------------------------------------------------------------------------------

EXPERIMENT = (VALID / "experiment.toml").read_text(encoding="utf-8") if VALID.exists() else ""


def toml_case(name: str, replacements: dict[str, str] | None = None, extra: str = "") -> None:
    text = EXPERIMENT
    for old, new in (replacements or {}).items():
        assert old in text, old
        text = text.replace(old, new, 1)
    (EXPERIMENTS / f"{name}.toml").write_text(text + extra, encoding="utf-8")


def experiment_cases() -> None:
    values = "values = [0, 10]"
    toml_case("trials-1e12", {"trials = 2": "trials = 1000000000000"})
    toml_case("trials-huge-integer", {"trials = 2": f"trials = {BIG}"})
    toml_case("trials-4000-digits", {"trials = 2": f"trials = {'9' * 4000}"})
    toml_case("trials-nan", {"trials = 2": "trials = nan"})
    toml_case("trials-infinite", {"trials = 2": "trials = inf"})
    toml_case("trials-negative", {"trials = 2": "trials = -5"})
    toml_case("trials-a-string", {"trials = 2": 'trials = "ten"'})
    toml_case("trials-1e300-float", {"trials = 2": "trials = 1e300"})
    toml_case("frames-1e8", {"seed = 1": "seed = 1\nframes = 100000000"})
    toml_case("chunk-size-1e12", {"seed = 1": "seed = 1\nchunk_size = 1000000000000"})
    toml_case(
        "sweep-emitter-x-1e160-1e200",
        {'parameter = "snr_db"': 'parameter = "emitter_x_m"', values: "values = [1e160, 1e200]"},
    )
    toml_case(
        "sweep-emitter-x-1e200-second",
        {'parameter = "snr_db"': 'parameter = "emitter_x_m"', values: "values = [30, 1e200]"},
    )
    toml_case(
        "sweep-grid-x-1e200",
        {'parameter = "snr_db"': 'parameter = "emitter_m"', values: "x = [0, 1e200]\ny = [15]"},
    )
    toml_case(
        "sweep-grid-1000-by-1000",
        {
            'parameter = "snr_db"': 'parameter = "emitter_m"',
            values: f"x = {list(range(1000))}\ny = {list(range(1, 1001))}",
        },
    )
    toml_case("sweep-20000-values", {values: f"values = {[v / 1000 for v in range(20000)]}"})
    toml_case(
        "sweep-frames-1e8",
        {'parameter = "snr_db"': 'parameter = "frames"', values: "values = [1, 100000000]"},
    )
    toml_case(
        "sweep-samples-per-frame-1e9",
        {
            'parameter = "snr_db"': 'parameter = "samples_per_frame"',
            values: "values = [1000000000]",
        },
    )
    toml_case("sweep-fixed-frames-1e8", extra="\n[sweep.fixed]\nframes = 100000000\n")
    toml_case("sweep-fixed-range-sigma-1e300", extra="\n[sweep.fixed]\nrange_sigma_m = 1e300\n")
    toml_case("sweep-fixed-speed-1e200", extra="\n[sweep.fixed]\nspeed_mps = 1e200\n")
    toml_case(
        "sweep-fixed-emitter-height-1e200", extra="\n[sweep.fixed]\nemitter_height_m = 1e200\n"
    )
    toml_case(
        "sweep-fixed-sample-interval-1e300", extra="\n[sweep.fixed]\nsample_interval_s = 1e300\n"
    )
    toml_case("sweep-value-nan", {values: "values = [0, nan]"})
    toml_case("sweep-snr-1e300", {values: "values = [1e300]"})
    toml_case(
        "too-many-estimates",
        {"trials = 2": "trials = 1000000", values: f"values = {list(range(-50, 100))}"},
    )
    toml_case(
        "options-nested-40-deep",
        {
            'estimators = ["cls"]': f'estimators = [{{ name = "cls", options = {{ side_prior_m = {nested(40)} }} }}]'
        },
    )
    toml_case("unknown-key", {"trials = 2": "trails = 2"})
    (EXPERIMENTS / "nesting-5000-deep.toml").write_text(
        EXPERIMENT + f"\n[extra]\nvalue = {nested(5000)}\n", encoding="utf-8"
    )
    (EXPERIMENTS / "invalid-syntax.toml").write_text(
        EXPERIMENT + "\ntrials = = 3\n", encoding="utf-8"
    )
    (EXPERIMENTS / "not-utf8.toml").write_bytes(
        EXPERIMENT.replace("corpus", "corpus \u00e9").encode("latin-1")
    )
    as_json = {
        "name": "corpus",
        "scenarios": ["paper-1m"],
        "trials": 2,
        "seed": 1,
        "estimators": ["cls"],
        "sweep": {"parameter": "snr_db", "values": [0, 10]},
    }
    (EXPERIMENTS / "json-nesting-5000-deep.json").write_text(
        json.dumps(as_json)[:-1] + f', "extra": {nested(5000)}}}\n', encoding="utf-8"
    )
    (EXPERIMENTS / "json-huge-integer-trials.json").write_text(
        json.dumps(as_json).replace('"trials": 2', f'"trials": {BIG}'), encoding="utf-8"
    )
    (EXPERIMENTS / "json-bom-unknown-key.json").write_text(
        "\ufeff" + json.dumps({**as_json, "trails": 3}), encoding="utf-8"
    )
    (EXPERIMENTS / "json-trials-1e12.json").write_text(
        json.dumps({**as_json, "trials": 10**12}), encoding="utf-8"
    )


def valid_with_bom() -> None:
    """Valid files that start with a UTF-8 byte order mark (as spreadsheet programs save)."""
    text = (VALID / "paper-1m.json").read_text(encoding="utf-8")
    (VALID / "paper-1m-bom.json").write_text("\ufeff" + text, encoding="utf-8")
    (VALID / "paper-1m-bom.csv").write_text("\ufeff" + csv_text(base()), encoding="utf-8")
    (VALID / "paper-1m.csv").write_text(csv_text(base()), encoding="utf-8")


if __name__ == "__main__":
    valid_with_bom()
    MEASUREMENTS.mkdir(exist_ok=True)
    EXPERIMENTS.mkdir(exist_ok=True)
    measurement_cases()
    experiment_cases()
