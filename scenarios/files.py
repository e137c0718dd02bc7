"""Measurement files: JSON (everything) and CSV (the sample table, constants given apart).

JSON, schema ``emitterbench.measurements/1``::

    {"schema": "emitterbench.measurements/1",
     "carrier_hz": 3.0e8, "speed_of_light_mps": 3.0e8, "emitter_height_m": 0.0,
     "noise": {"doppler_hz": 0.1, "toa_s": 3.3e-9, "rss_db": 4.0},
     "rss_model": {"reference_power_dbm": 0.0, "reference_distance_m": 1.0,
                   "path_loss_exponent": 2.0},
     "truth": {"emitter_m": [35.0, 15.0]},
     "unknowns": [],
     "samples": [{"frame": 0, "time_s": 0.0, "position_m": [0, 0, 50],
                  "velocity_mps": [10, 0, 0], "doppler_hz": 5.57, "toa_s": 2.05e-7,
                  "rss_dbm": -30.7}]}

``doppler_hz`` is received minus carrier frequency, positive while closing (MATH §1);
``toa_s`` the one-way time of arrival (MATH §1); ``rss_dbm`` the received power of the
log-distance model of ``rss_model`` (MATH §1). ``speed_of_light_mps`` defaults to 299 792 458,
``emitter_height_m`` to 0 (MATH §0); ``noise`` holds the σ's the data were drawn with (MATH §2),
``truth`` the true emitter when known, and beside it the true ``carrier_offset_hz`` and
``emission_time_s`` of a non-cooperative emitter; ``unknowns`` lists which of those two the
receiver does not know (MATH §15; absent or empty: both known) and ``"emitter_height_m"`` when the
emitter's height is unknown too (MATH §8: ``truth.emitter_m`` then has three coordinates and
``emitter_height_m`` is the height an estimator that ignores the unknown assumes). ``terrain``
(absent: none) is the known ground, ``{"sigma_m": 5.0, "height_m": 0.0, "slope": [0.0, 0.0],
"hill_height_m": 139.9, "hill_centre_m": [200.0, 150.0], "hill_width_m": 100.0}`` (only
``sigma_m`` required; :class:`~scenarios.terrain.Terrain`), a prior on the height when it is
unknown (MATH §8); CSV files carry none. A modality
is present when every sample has it; a
modality on some samples only, an unknown key (a typo), a non-finite number, a wrong length or
type, an unknown schema, no samples, a negative σ or frames out of order are errors.

CSV has the header ``frame,time_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps`` plus any of
``doppler_hz,toa_s,rss_dbm``; an empty column means the modality is absent. The constants, σ's,
RSS model and truth are keyword arguments of :func:`read_measurements_csv`;
:func:`read_measurements_with` takes the constants one by one, as command-line options give them.

Every error is a ``ValueError`` whose message starts with the field's path
(``samples[2].position_m``, ``noise.toa_s``, ``schema``) or, for a CSV cell, its column and
line, and says how to fix it. Value checks that :class:`~scenarios.types.MeasurementSet`
already makes (σ > 0, RSS model, truth length) are left to it; this module adds the paths and
the structural checks. Floats are written with ``repr`` precision, so a round trip is exact.

The limits of :mod:`scenarios.limits` hold before the work they would cost: a file above
32 MiB is refused before it is read, more than 100 000 samples or 10 000 frames before they
are converted (each raised by an environment variable, ``EMITTERBENCH_MAX_SAMPLES``); JSON
nests at most 32 levels and an integer has at most 4300 digits. Text is UTF-8, with or without
a byte order mark (spreadsheet programs write one).
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from scenarios import fields
from scenarios.limits import (
    FRAMES,
    SAMPLES,
    LongInteger,
    check_limit,
    child_path,
    clip,
    configured_limit,
    key_path,
    load_json,
    read_text,
    write_text_atomically,
)
from scenarios.nuisance import parse_unknowns, position_dimension
from scenarios.terrain import Terrain
from scenarios.types import SPEED_OF_LIGHT_MPS, MeasurementSet, NoiseSigmas, RssModel

SCHEMA = "emitterbench.measurements/1"
"""The ``schema`` value of the JSON files this module reads and writes."""

_TOP_REQUIRED = ("schema", "carrier_hz", "samples")
_TOP_OPTIONAL = (
    "speed_of_light_mps",
    "emitter_height_m",
    "noise",
    "rss_model",
    "truth",
    "unknowns",
    "terrain",
)
_SAMPLE_REQUIRED = ("frame", "time_s", "position_m", "velocity_mps")
_MEASUREMENT_FIELDS = ("doppler_hz", "toa_s", "rss_dbm")
_NOISE_KEYS = ("doppler_hz", "toa_s", "rss_db")
_RSS_MODEL_KEYS = ("reference_power_dbm", "reference_distance_m", "path_loss_exponent")
_TRUTH_OPTIONAL = ("carrier_offset_hz", "emission_time_s")
_TERRAIN_OPTIONAL = ("height_m", "slope", "hill_height_m", "hill_centre_m", "hill_width_m")

CSV_COLUMNS = ("frame", "time_s", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")
"""The CSV columns every file must have."""
CSV_MEASUREMENT_COLUMNS = _MEASUREMENT_FIELDS
"""The optional CSV columns, one per modality."""
CSV_CONSTANTS = (
    "carrier_hz",
    "speed_of_light_mps",
    "emitter_height_m",
    *(f"noise.{key}" for key in _NOISE_KEYS),
    *(f"rss_model.{key}" for key in _RSS_MODEL_KEYS),
)
"""The constants a CSV file leaves out, by their JSON path (:func:`read_measurements_with`)."""


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def read_measurements(
    path: str | os.PathLike[str],
    *,
    carrier_hz: float | None = None,
    speed_of_light_mps: float | None = None,
    emitter_height_m: float | None = None,
    noise: NoiseSigmas | None = None,
    rss_model: RssModel | None = None,
    truth_emitter_m: ArrayLike | None = None,
) -> MeasurementSet:
    """Read a ``.json`` or ``.csv`` measurement file.

    The keyword constants are those of :func:`read_measurements_csv` and are only for CSV
    files: a JSON file carries its own, and giving them for one is an error rather than being
    silently ignored.
    """
    path = Path(path)
    csv_options = {
        "carrier_hz": carrier_hz,
        "speed_of_light_mps": speed_of_light_mps,
        "emitter_height_m": emitter_height_m,
        "noise": noise,
        "rss_model": rss_model,
        "truth_emitter_m": truth_emitter_m,
    }
    suffix = path.suffix.lower()
    if suffix == ".json":
        given = [name for name, value in csv_options.items() if value is not None]
        if given:
            raise ValueError(
                f"{given[0]}: only for CSV files; {path} is JSON and carries its own constants "
                "(edit the file instead)"
            )
        return measurements_from_json(read_text(path), source=str(path))
    if suffix == ".csv":
        if carrier_hz is None:
            raise ValueError(
                f"carrier_hz: required to read the CSV file {path}, which holds only samples"
            )
        return read_measurements_csv(
            path,
            carrier_hz=carrier_hz,
            speed_of_light_mps=SPEED_OF_LIGHT_MPS
            if speed_of_light_mps is None
            else speed_of_light_mps,
            emitter_height_m=0.0 if emitter_height_m is None else emitter_height_m,
            noise=NoiseSigmas() if noise is None else noise,
            rss_model=rss_model,
            truth_emitter_m=truth_emitter_m,
        )
    raise ValueError(
        f"{path}: unknown file type {path.suffix or '(no extension)'!r}; "
        "name the file .json or .csv"
    )


def read_measurements_with(
    path: str | os.PathLike[str],
    constants: Mapping[str, float | None],
    *,
    names: Mapping[str, str] | None = None,
) -> MeasurementSet:
    """Read a ``.json`` or ``.csv`` measurement file, with CSV constants given one by one.

    ``constants`` maps paths of :data:`CSV_CONSTANTS` to values (None: not given), as the
    options of a command line give them. A CSV file needs ``carrier_hz`` and takes the three
    ``rss_model`` values together or not at all; a file of another type carries its own
    constants, and giving one is an error. An error about a constant names it
    ``names[path]`` when given, e.g. the option ``--sigma-toa-s`` for ``noise.toa_s``
    (``names["rss_model"]`` names the model as a whole).
    """
    path = Path(path)
    names = names or {}
    unknown = sorted(set(constants) - set(CSV_CONSTANTS))
    if unknown:
        raise ValueError(
            f"{unknown[0]}: not a CSV constant; expected one of {', '.join(CSV_CONSTANTS)}"
        )
    value = {key: constants.get(key) for key in CSV_CONSTANTS}
    given = [key for key in CSV_CONSTANTS if value[key] is not None]
    if path.suffix.lower() != ".csv":
        if given:
            raise ValueError(
                f"{names.get(given[0], given[0])}: only for CSV files; {path} carries its own "
                "constants (drop the option or edit the file)"
            )
        return read_measurements(path)
    if value["carrier_hz"] is None:
        raise ValueError(
            f"{names.get('carrier_hz', 'carrier_hz')}: required to read the CSV file {path}"
        )
    rss_keys = [key for key in CSV_CONSTANTS if key.startswith("rss_model.")]
    rss_given = [key for key in rss_keys if key in given]
    if rss_given and len(rss_given) < len(rss_keys):
        missing = next(key for key in rss_keys if key not in given)
        raise ValueError(f"{names.get(missing, missing)}: give all three RSS-model options")
    try:
        return read_measurements(
            path,
            carrier_hz=value["carrier_hz"],
            speed_of_light_mps=value["speed_of_light_mps"],
            emitter_height_m=value["emitter_height_m"],
            noise=NoiseSigmas(**{key: value[f"noise.{key}"] for key in _NOISE_KEYS}),
            rss_model=None
            if not rss_given
            else RssModel(**{key: value[f"rss_model.{key}"] for key in _RSS_MODEL_KEYS}),
        )
    except ValueError as error:
        field, separator, rest = str(error).partition(": ")
        if separator and field in names:
            raise ValueError(f"{names[field]}: {rest}") from None
        raise


def measurements_from_json(text: str, *, source: str = "json") -> MeasurementSet:
    """Parse JSON text of schema :data:`SCHEMA`; ``source`` names the text in syntax errors."""
    return measurements_from_dict(load_json(text, source=source))


def measurements_from_dict(obj: Any) -> MeasurementSet:
    """Validate a parsed JSON object of schema :data:`SCHEMA` and build the measurements.

    Raises
    ------
    ValueError
        Naming the offending field by its path, e.g. ``samples[3].toa_s`` or ``noise.toa_s``.
    """
    if not isinstance(obj, dict):
        raise ValueError(
            f"measurements: expected a JSON object with keys {', '.join(_TOP_REQUIRED)}, "
            f"got {_kind(obj)}"
        )
    if "schema" not in obj:
        raise ValueError(f'schema: missing; add "schema": "{SCHEMA}"')
    if obj["schema"] != SCHEMA:
        raise ValueError(
            f"schema: unknown {obj['schema']!r}; this version reads {SCHEMA!r} "
            "(convert the file or upgrade emitterbench)"
        )
    _check_keys(obj, "", required=_TOP_REQUIRED, optional=_TOP_OPTIONAL)
    unknowns = parse_unknowns(obj.get("unknowns"), "unknowns")
    columns = _sample_columns_from_json(obj["samples"])
    return _measurement_set(
        columns,
        carrier_hz=_number(obj["carrier_hz"], "carrier_hz"),
        speed_of_light_mps=_number(
            obj.get("speed_of_light_mps", SPEED_OF_LIGHT_MPS), "speed_of_light_mps"
        ),
        emitter_height_m=_number(obj.get("emitter_height_m", 0.0), "emitter_height_m"),
        noise=_noise_from_json(obj.get("noise")),
        rss_model=_rss_model_from_json(obj.get("rss_model")),
        **_truth_from_json(obj.get("truth"), position_dimension(unknowns)),
        unknowns=unknowns,
        terrain=_terrain_from_json(obj.get("terrain")),
    )


def measurements_to_dict(data: MeasurementSet) -> dict[str, Any]:
    """The JSON object of schema :data:`SCHEMA` for ``data`` (plain Python floats and ints).

    Absent σ's, a missing RSS model and unknown truth are left out rather than written null.
    """
    if not isinstance(data, MeasurementSet):
        raise ValueError(f"data: expected a MeasurementSet, got {type(data).__name__}")
    obj: dict[str, Any] = {
        "schema": SCHEMA,
        "carrier_hz": data.carrier_hz,
        "speed_of_light_mps": data.speed_of_light_mps,
        "emitter_height_m": data.emitter_height_m,
        "noise": {k: v for k, v in data.noise.as_dict().items() if v is not None},
    }
    if data.rss_model is not None:
        obj["rss_model"] = data.rss_model.as_dict()
    if data.truth_emitter_m is not None:
        obj["truth"] = {"emitter_m": data.truth_emitter_m.tolist()}
        for name in _TRUTH_OPTIONAL:
            if getattr(data, f"truth_{name}") is not None:
                obj["truth"][name] = getattr(data, f"truth_{name}")
    if data.unknowns:
        obj["unknowns"] = list(data.unknowns)
    if data.terrain is not None:
        obj["terrain"] = data.terrain.as_dict()
    columns: dict[str, list[Any]] = {
        "frame": data.frame.tolist(),
        "time_s": data.time_s.tolist(),
        "position_m": data.position_m.tolist(),
        "velocity_mps": data.velocity_mps.tolist(),
    }
    for name in _MEASUREMENT_FIELDS:
        values = getattr(data, name)
        if values is not None:
            columns[name] = values.tolist()
    obj["samples"] = [
        {name: values[index] for name, values in columns.items()} for index in range(data.n_samples)
    ]
    return obj


def measurements_to_json(data: MeasurementSet) -> str:
    """The JSON text of ``data``: one line per constant and per sample, exact floats."""
    obj = measurements_to_dict(data)
    lines = [
        f"  {json.dumps(key)}: {json.dumps(value, allow_nan=False)}"
        for key, value in obj.items()
        if key != "samples"
    ]
    samples = ",\n".join("    " + json.dumps(sample, allow_nan=False) for sample in obj["samples"])
    lines.append(f'  "samples": [\n{samples}\n  ]')
    return "{\n" + ",\n".join(lines) + "\n}\n"


def write_measurements(data: MeasurementSet, path: str | os.PathLike[str]) -> Path:
    """Write ``data`` as JSON to ``path`` atomically; returns the path written.

    The text is built first, then written to a temporary file in the same folder and moved
    over ``path`` with ``os.replace``: on any failure ``path`` is left as it was.
    """
    path = Path(path)
    if path.suffix.lower() != ".json":
        raise ValueError(
            f"output: {path} must end in .json (the CSV form holds samples only; "
            "measurement files are written as JSON)"
        )
    text = measurements_to_json(data)
    write_text_atomically(text, path)
    return path


def read_measurements_csv(
    path: str | os.PathLike[str],
    *,
    carrier_hz: float,
    speed_of_light_mps: float = SPEED_OF_LIGHT_MPS,
    emitter_height_m: float = 0.0,
    noise: NoiseSigmas,
    rss_model: RssModel | None = None,
    truth_emitter_m: ArrayLike | None = None,
) -> MeasurementSet:
    """Read a CSV table of samples; the constants come as arguments.

    Parameters
    ----------
    path
        CSV with header ``frame,time_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps`` plus any of
        ``doppler_hz,toa_s,rss_dbm`` (MATH §1 conventions; Doppler received minus carrier).
    carrier_hz, speed_of_light_mps, emitter_height_m
        ``f0``, ``c`` and ``z_s`` of MATH §0.
    noise
        σ's of the modalities present (MATH §2).
    rss_model
        Required when the file has ``rss_dbm``.
    truth_emitter_m : (2,) or None
        The true emitter, when known.
    """
    text = read_text(Path(path))
    return _measurement_set(
        _sample_columns_from_csv(text),
        carrier_hz=carrier_hz,
        speed_of_light_mps=speed_of_light_mps,
        emitter_height_m=emitter_height_m,
        noise=noise,
        rss_model=rss_model,
        truth_emitter_m=truth_emitter_m,
    )


# --------------------------------------------------------------------------------------------
# JSON structure
# --------------------------------------------------------------------------------------------


def _sample_columns_from_json(samples: Any) -> dict[str, Any]:
    """Per-sample fields as columns; every value checked with its path ``samples[i].name``."""
    if not isinstance(samples, list):
        raise ValueError(f"samples: expected an array of sample objects, got {_kind(samples)}")
    if not samples:
        raise ValueError("samples: empty; give at least one sample")
    check_limit(len(samples), "samples", "samples", SAMPLES, "split the file")
    columns: dict[str, list[Any]] = {name: [] for name in _SAMPLE_REQUIRED}
    measured: dict[str, list[float]] = {name: [] for name in _MEASUREMENT_FIELDS}
    lacking: dict[str, list[int]] = {name: [] for name in _MEASUREMENT_FIELDS}
    for index, sample in enumerate(samples):
        path = f"samples[{index}]"
        if not isinstance(sample, dict):
            raise ValueError(f"{path}: expected a sample object, got {_kind(sample)}")
        _check_keys(sample, path, required=_SAMPLE_REQUIRED, optional=_MEASUREMENT_FIELDS)
        columns["frame"].append(_whole_number(sample["frame"], f"{path}.frame"))
        columns["time_s"].append(_number(sample["time_s"], f"{path}.time_s"))
        columns["position_m"].append(_vector(sample["position_m"], f"{path}.position_m", 3))
        columns["velocity_mps"].append(_vector(sample["velocity_mps"], f"{path}.velocity_mps", 3))
        for name in _MEASUREMENT_FIELDS:
            if name in sample:
                measured[name].append(_number(sample[name], f"{path}.{name}"))
            else:
                lacking[name].append(index)
    for name in _MEASUREMENT_FIELDS:
        if measured[name] and lacking[name]:
            first_lacking = lacking[name][0]
            lacking_set = set(lacking[name])
            first_having = next(i for i in range(len(samples)) if i not in lacking_set)
            raise ValueError(
                f"samples[{first_lacking}].{name}: missing, but samples[{first_having}] has it; "
                "a modality must be on every sample or on none"
            )
    _check_frame_order(columns["frame"], lambda i: f"samples[{i}].frame")
    _check_frame_count(columns["frame"], "samples")
    result: dict[str, Any] = dict(columns)
    for name in _MEASUREMENT_FIELDS:
        result[name] = measured[name] or None
    return result


def _noise_from_json(value: Any) -> NoiseSigmas:
    if value is None:
        return NoiseSigmas()
    if not isinstance(value, dict):
        raise ValueError(f"noise: expected an object of standard deviations, got {_kind(value)}")
    _check_keys(value, "noise", required=(), optional=_NOISE_KEYS)
    return NoiseSigmas(
        **{
            key: None if value.get(key) is None else _number(value[key], f"noise.{key}")
            for key in _NOISE_KEYS
        }
    )


def _rss_model_from_json(value: Any) -> RssModel | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ValueError(f"rss_model: expected an object, got {_kind(value)}")
    _check_keys(value, "rss_model", required=_RSS_MODEL_KEYS, optional=())
    return RssModel(**{key: _number(value[key], f"rss_model.{key}") for key in _RSS_MODEL_KEYS})


def _truth_from_json(value: Any, dimension: int) -> dict[str, Any]:
    """``truth_emitter_m`` (``dimension`` coordinates: ``(x, y)``, or ``(x, y, z)`` with the
    height unknown) and the true nuisance values (MATH §15) of the ``truth`` object."""
    if value is None:
        return {"truth_emitter_m": None}
    point = "[x, y, z]" if dimension == 3 else "[x, y]"
    if not isinstance(value, dict):
        raise ValueError(f'truth: expected an object {{"emitter_m": {point}}}, got {_kind(value)}')
    _check_keys(value, "truth", required=("emitter_m",), optional=_TRUTH_OPTIONAL)
    truth: dict[str, Any] = {
        "truth_emitter_m": _vector(value["emitter_m"], "truth.emitter_m", dimension)
    }
    for name in _TRUTH_OPTIONAL:
        if name in value:
            truth[f"truth_{name}"] = _number(value[name], f"truth.{name}")
    return truth


def _terrain_from_json(value: Any) -> Terrain | None:
    """The ``terrain`` object (:class:`~scenarios.terrain.Terrain`; absent: None): ``sigma_m``
    required, the plane's and the hill's numbers optional (default a level plane at 0 m)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ValueError(
            f'terrain: expected an object {{"sigma_m": ..., "height_m": ...}}, got {_kind(value)}'
        )
    _check_keys(value, "terrain", required=("sigma_m",), optional=_TERRAIN_OPTIONAL)
    numbers: dict[str, Any] = {}
    for key in ("sigma_m", *_TERRAIN_OPTIONAL):
        if key in ("slope", "hill_centre_m"):
            if key in value:
                numbers[key] = _vector(value[key], f"terrain.{key}", 2)
        elif key in value:
            numbers[key] = _number(value[key], f"terrain.{key}")
    return Terrain(**numbers)


# --------------------------------------------------------------------------------------------
# CSV structure
# --------------------------------------------------------------------------------------------


def _sample_columns_from_csv(text: str) -> dict[str, Any]:
    """The CSV table as columns; errors name the column and the file line."""
    reader = csv.reader(io.StringIO(text.removeprefix("\ufeff")))
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    max_rows = configured_limit(SAMPLES)
    start = 1  # the line the next row starts on
    try:
        for row in reader:
            cells = [cell.strip() for cell in row]
            if any("\n" in cell or "\r" in cell for cell in cells):
                raise ValueError(
                    f"samples (CSV line {start}): a quoted cell runs over several lines; "
                    "close the quote (cells are numbers)"
                )
            start = reader.line_num + 1
            if not any(cells):
                continue
            if header is None:
                header, header_line = cells, reader.line_num
            else:
                rows.append((reader.line_num, cells))
                if len(rows) > max_rows:
                    check_limit(len(rows), "samples", "rows or more", SAMPLES, "split the file")
    except csv.Error as error:
        problem = _CSV_PROBLEMS.get(str(error).split(" (")[0], str(error))
        raise ValueError(f"samples (CSV line {start}): {problem}") from None
    if header is None:
        raise ValueError(
            f"header: the CSV file is empty; give the header {','.join(CSV_COLUMNS)} "
            "(plus doppler_hz, toa_s or rss_dbm) and one row per sample"
        )
    allowed = CSV_COLUMNS + CSV_MEASUREMENT_COLUMNS
    for position, name in enumerate(header):
        if name not in allowed:
            raise ValueError(
                f"{key_path([name]) if name else f'column {position + 1}'}: unknown CSV column "
                f"(line {header_line})"
                f"{_suggestion(name, allowed)}; allowed columns: {', '.join(allowed)}"
            )
        if header.index(name) != position:
            raise ValueError(f"{name}: column appears twice in the CSV header; keep one")
    for name in CSV_COLUMNS:
        if name not in header:
            raise ValueError(
                f"{name}: missing CSV column (header on line {header_line}); "
                f"every file needs {','.join(CSV_COLUMNS)}"
            )
    if not rows:
        raise ValueError("samples: the CSV file has a header but no rows; give one per sample")
    values: dict[str, list[float | None]] = {name: [] for name in header}
    for line, cells in rows:
        if len(cells) != len(header):
            raise ValueError(
                f"samples (CSV line {line}): expected {len(header)} cells as in the header, "
                f"got {len(cells)}"
            )
        for name, cell in zip(header, cells, strict=True):
            values[name].append(
                _csv_number(cell, name, line, optional=name in CSV_MEASUREMENT_COLUMNS)
            )
    lines = [line for line, _ in rows]
    columns: dict[str, Any] = {
        "frame": [
            _whole_number(value, f"frame (CSV line {line})")
            for value, line in zip(values["frame"], lines, strict=True)
        ],
        "time_s": values["time_s"],
        "position_m": np.column_stack([values["x_m"], values["y_m"], values["z_m"]]),
        "velocity_mps": np.column_stack([values["vx_mps"], values["vy_mps"], values["vz_mps"]]),
    }
    _check_frame_order(columns["frame"], lambda i: f"frame (CSV line {lines[i]})")
    _check_frame_count(columns["frame"], "frame")
    for name in CSV_MEASUREMENT_COLUMNS:
        column = values.get(name)
        if column is None or all(value is None for value in column):
            columns[name] = None
            continue
        if any(value is None for value in column):
            lacking = lines[column.index(None)]
            having = lines[next(i for i, v in enumerate(column) if v is not None)]
            raise ValueError(
                f"{name} (CSV line {lacking}): empty, but line {having} has a value; "
                "a modality must be on every sample or on none"
            )
        columns[name] = column
    return columns


_CSV_PROBLEMS = {
    "line contains NUL": "a NUL byte; save the file as plain UTF-8 text",
    "field larger than field limit": (
        f"a cell longer than {csv.field_size_limit():,} characters; cells are numbers"
    ),
}


def _csv_number(cell: str, column: str, line: int, *, optional: bool) -> float | None:
    path = f"{column} (CSV line {line})"
    if not cell:
        if optional:
            return None
        raise ValueError(f"{path}: empty; every sample needs {column}")
    try:
        number = float(cell)
    except ValueError:
        raise ValueError(f"{path}: {clip(cell)!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(
            f"{path}: must be finite, got {clip(cell)!r}; drop the sample or the whole column"
        )
    return number


# --------------------------------------------------------------------------------------------
# shared checks
# --------------------------------------------------------------------------------------------


def _measurement_set(
    columns: Mapping[str, Any],
    *,
    carrier_hz: float,
    speed_of_light_mps: float,
    emitter_height_m: float,
    noise: NoiseSigmas,
    rss_model: RssModel | None,
    truth_emitter_m: ArrayLike | None,
    **nuisance: Any,
) -> MeasurementSet:
    """Build the :class:`MeasurementSet`; it checks the values (σ's, RSS model, truth).

    ``nuisance``: ``unknowns``, the true offsets (MATH §15) and the ``terrain`` (MATH §8), as
    the JSON file gives them."""
    if not isinstance(noise, NoiseSigmas):
        raise ValueError(f"noise: expected NoiseSigmas, got {type(noise).__name__}")
    if rss_model is not None and not isinstance(rss_model, RssModel):
        raise ValueError(f"rss_model: expected RssModel or None, got {type(rss_model).__name__}")
    return MeasurementSet(
        frame=np.asarray(columns["frame"], dtype=np.int64),
        time_s=np.asarray(columns["time_s"], dtype=float),
        position_m=np.asarray(columns["position_m"], dtype=float).reshape(-1, 3),
        velocity_mps=np.asarray(columns["velocity_mps"], dtype=float).reshape(-1, 3),
        doppler_hz=columns["doppler_hz"],
        toa_s=columns["toa_s"],
        rss_dbm=columns["rss_dbm"],
        carrier_hz=carrier_hz,
        speed_of_light_mps=speed_of_light_mps,
        emitter_height_m=emitter_height_m,
        noise=noise,
        rss_model=rss_model,
        truth_emitter_m=truth_emitter_m,
        **nuisance,
    )


def _check_keys(
    obj: Mapping[str, Any], path: str, *, required: Sequence[str], optional: Sequence[str]
) -> None:
    """Unknown keys (typos) and missing required keys are errors naming the key's path."""
    allowed = (*required, *optional)
    for key in obj:
        if key not in allowed:
            raise ValueError(
                f"{child_path(path, key)}: unknown key{_suggestion(key, allowed)}; fix the "
                f"name or remove it (allowed here: {', '.join(allowed)})"
            )
    for key in required:
        if key not in obj:
            raise ValueError(f"{child_path(path, key)}: missing; this field is required, add it")


def _check_frame_order(frames: Sequence[int], name_of: Any) -> None:
    """Frames must be non-decreasing; the error names the first sample out of order."""
    for index in range(1, len(frames)):
        if frames[index] < frames[index - 1]:
            raise ValueError(
                f"{name_of(index)}: frame {frames[index]} comes after frame "
                f"{frames[index - 1]}; order the samples by frame (non-decreasing)"
            )


def _check_frame_count(frames: Sequence[int], path: str) -> None:
    count = len(set(frames))
    check_limit(count, path, "frames", FRAMES, "split the file into shorter flights")


def _number(value: Any, path: str) -> float:
    """A finite JSON number (not a bool, not a string) as a float."""
    if isinstance(value, LongInteger):
        raise ValueError(f"{path}: {value!r} is too large for a float (above 1.8e308)")
    return fields.number(value, path, describe=_kind, fix="; replace it with a number")


def _whole_number(value: Any, path: str) -> int:
    """A frame index (:func:`scenarios.fields.frame_index`; an integral float is accepted)."""
    if isinstance(value, LongInteger):
        raise ValueError(f"{path}: {value!r} is too large; number the frames 0, 1, 2, ...")
    number = _number(value, path)
    return fields.frame_index(value if isinstance(value, int) else number, path)


def _vector(value: Any, path: str, length: int) -> list[float]:
    if not isinstance(value, list):
        raise ValueError(f"{path}: expected an array of {length} numbers, got {_kind(value)}")
    if len(value) != length:
        raise ValueError(f"{path}: expected {length} numbers, got {len(value)}")
    return [_number(item, f"{path}[{index}]") for index, item in enumerate(value)]


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, str):
        return f"the string {clip(value)!r}"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, int | float):
        return f"the number {value!r}"
    return type(value).__name__


def _suggestion(key: str, allowed: Iterable[str]) -> str:
    close = difflib.get_close_matches(key[:100], list(allowed), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""
