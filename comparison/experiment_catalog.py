"""The built-in experiments, and the definition behind an experiment's name or file.

Each built-in is written in the TOML layout of :mod:`comparison.experiment` (its module
docstring is the reference), as a dict. :func:`experiment_definition` finds the definition
that ``emitterbench run NAME_OR_FILE`` means: a built-in by name, or a ``.toml`` (or ``.json``)
file read into a dict. :func:`comparison.experiment.load_experiment` validates it into an
:class:`~comparison.experiment.Experiment`. This module holds no schema and imports neither the
estimators nor the scenarios, so ``emitterbench list`` reads the summaries at once.

A file is read within the limits of :mod:`scenarios.limits`: at most :data:`MAX_EXPERIMENT_MB`
MiB, UTF-8 with or without a byte order mark, nesting at most 32 levels, integers of at most
4300 digits; each refusal names the key or the line.
"""

from __future__ import annotations

import copy
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

MAX_EXPERIMENT_MB = 1
"""Largest experiment file read, MiB: an experiment is a few dozen lines, and a sweep of the
largest number of points allowed (comparison.sweep.MAX_POINTS) fits in a tenth of it."""

CALIBRATION = "comparison.calibration:KnownEfficiency"
"""The estimator of known efficiency and bias the ``calibration`` experiment runs."""

BUILTIN_DEFINITIONS: dict[str, dict[str, Any]] = {
    "paper-fig2": {
        "name": "paper-fig2",
        "description": (
            "accuracy vs SNR on one frame of the paper's track (paper Fig. 2), with the printed "
            "c*sigma_tau = 300 km and the meaningful 1 m and 10 m (MATH §14)"
        ),
        "scenarios": ["paper", "paper-1m", "paper-10m"],
        "sweep": {"parameter": "snr_db", "values": [-10, -5, 0, 5, 10, 15, 20, 25, 30]},
        "estimators": ["lls-rss", "lls-toa", "cls-as-printed", "cls-paper", "cls", "sdp-cls", "ml"],
        "trials": 500,
        "seed": 20_240_602,
        "frames": 1,
    },
    "geometry-map": {
        "name": "geometry-map",
        "description": (
            "RMSE against the CRLB over a grid of emitter positions beside the paper's track "
            "(paper-1m at 10 dB, one frame)"
        ),
        "scenarios": ["paper-1m"],
        "sweep": {
            "parameter": "emitter_m",
            "x": [-40, -30, -20, -10, 0, 10, 20, 30, 40, 50, 60],
            "y": [5, 15, 25, 35, 45, 55, 65],
            "fixed": {"snr_db": 10},
        },
        "estimators": ["cls", "ml", "lls-toa"],
        "trials": 100,
        "seed": 20_240_603,
        "frames": 1,
    },
    "geometry-map-dense": {
        "name": "geometry-map-dense",
        "description": (
            "the geometry map at 1 m resolution: RMSE against the CRLB of the two closed forms "
            "over a 100 x 100 grid of emitter positions beside the paper's track, cells from "
            "x = -40.5 to 59.5 m and y = 0 (the track) to 100 m (paper-1m at 10 dB, one frame)"
        ),
        "scenarios": ["paper-1m"],
        "sweep": {
            "parameter": "emitter_m",
            "x": [float(x) for x in range(-40, 60)],
            "y": [y + 0.5 for y in range(100)],
            "fixed": {"snr_db": 10},
        },
        "estimators": ["cls", "cls-paper"],
        "trials": 100,
        "seed": 20_240_606,
        "frames": 1,
        "chunk_size": 100,
    },
    "frames": {
        "name": "frames",
        "description": (
            "10 frames of the paper geometry at c*sigma_tau = 1 m and 0 dB, with a turn after "
            "frame 3 (paper-1m-turn) and without (paper-1m): per-frame RMSE against the "
            "accumulated CRLB, NEES and wrong-side rate (MATH §7, §8)"
        ),
        "scenarios": ["paper-1m-turn", "paper-1m"],
        "sweep": {"parameter": "snr_db", "values": [0]},
        "estimators": [
            {"name": "cls", "label": "cls-last", "options": {"frames": "last"}},
            {"name": "cls", "label": "cls-all", "options": {"frames": "all"}},
            {"name": "ml", "label": "ml-all", "options": {"frames": "all"}},
            "ekf",
            "gtsam-smoother",
        ],
        "trials": 500,
        "seed": 20_240_604,
        "frames": 10,
        "per_frame": True,
    },
    "paper-fig3": {
        "name": "paper-fig3",
        "description": (
            "the paper's Fig. 3 in closed loop: 10 frames of K = 10 on the paper geometry at "
            "c*sigma_tau = 1 m and 10 m, 0 dB; each frame's velocity chosen by a planner "
            "(none, the paper's rule corrected MATH §12, Fisher-optimal MATH §13, an orbit) "
            "from the cumulative ml estimate; RMSE per frame of cumulative ml and of the "
            "paper's per-frame cls against the CRLB of the flown trajectory"
        ),
        "scenarios": ["paper-1m", "paper-10m"],
        "sweep": {"parameter": "snr_db", "values": [0]},
        "estimators": [
            {"name": "ml", "label": "ml", "options": {"frames": "all"}},
            {"name": "cls", "label": "cls-last", "options": {"frames": "last"}},
        ],
        "planners": ["constant", "paper", "fisher", "orbit"],
        "steering_estimator": "ml",
        "trials": 300,
        "seed": 20_240_605,
        "frames": 10,
        "per_frame": True,
    },
    "noncooperative": {
        "name": "noncooperative",
        "description": (
            "non-cooperative emitters (MATH §15): a 406 MHz beacon 1 kHz off its carrier and on "
            "its own clock, and the paper's turn with both unknown; every estimator that "
            "estimates the carrier offset and emission time against the CRLB with them unknown, "
            "beside the bound with them known; ml-doppler locates from Doppler alone"
        ),
        "scenarios": ["beacon-pass", "turn-noncooperative"],
        "sweep": {"parameter": "snr_db", "values": [-10, 0, 10, 20, 30]},
        "estimators": [
            "cls",
            {"name": "cls", "label": "cls-profile", "options": {"offset_method": "profile"}},
            {"name": "cls", "label": "cls-two-stage", "options": {"offset_method": "two-stage"}},
            "ml",
            {"name": "ml", "label": "ml-doppler", "options": {"use_toa": False}},
            "ekf",
            "gtsam-smoother",
        ],
        "trials": 500,
        "seed": 20_240_607,
    },
    "iq-threshold": {
        "name": "iq-threshold",
        "description": (
            "from received samples to a position (MATH §18-§22): 100 ms BPSK bursts at "
            "10.24 kHz from the emitter of the orbit (its first 6 frames, 60 bursts), C/N0 "
            "swept through the front end's threshold; two-step estimators (the front end's Doppler and ToA, then cls or ml; "
            "ml-doppler from the Doppler alone) against direct position determination from the "
            "samples (dpd), all against the signal-level bound"
        ),
        "scenarios": ["orbit"],
        "frames": 6,
        "signal": {
            "waveform": "bpsk",
            "burst_s": 0.1,
            "sample_rate_hz": 10240.0,
            "chip_rate_hz": 2560.0,
            "guard_s": 4.0 / 10240.0,
        },
        "sweep": {"parameter": "cn0_dbhz", "values": [14, 18, 22, 26, 30]},
        "estimators": [
            "cls",
            "ml",
            {"name": "ml", "label": "ml-doppler", "options": {"use_toa": False}},
            "dpd",
        ],
        "trials": 400,
        "seed": 20_261_205,
    },
    "height": {
        "name": "height",
        "description": (
            "an emitter above the take-off ground at a height the receiver does not know "
            "(MATH §8): on a hill under a level turn, under a turn with a climb, and on a roof "
            "as a non-cooperative beacon; every estimator that estimates (x, y, z) against the "
            "3-D bound (its horizontal and vertical parts beside it; cls-two-stage differs from "
            "cls on the beacon only, MATH §15), and ml and cls assuming "
            "the take-off ground against the (x, y) part: the bias of assuming it; on the hill "
            "with its shape known (hill-terrain) the bound holds the terrain prior, which ml "
            "alone uses (MATH §8)"
        ),
        "scenarios": ["hill", "hill-climb", "roof-beacon", "hill-terrain"],
        "sweep": {"parameter": "snr_db", "values": [0, 10, 20, 30]},
        "estimators": [
            "cls",
            {"name": "cls", "label": "cls-two-stage", "options": {"offset_method": "two-stage"}},
            "ml",
            "ekf",
            "gtsam-smoother",
            {"name": "ml", "label": "ml-ground", "ignore_unknowns": ["emitter_height_m"]},
            {"name": "cls", "label": "cls-ground", "ignore_unknowns": ["emitter_height_m"]},
        ],
        "trials": 500,
        "seed": 20_261_205,
    },
    "calibration": {
        "name": "calibration",
        "description": (
            "the verdicts' own check: estimators of known efficiency and bias (the truth plus "
            "N(0, scale^2 CRLB) plus bias_ratio sqrt(trace CRLB) along the CRLB's major axis; "
            "comparison.calibration) on one straight frame and on a turn; how often does the "
            "suite say attains for an efficient estimator, and never for a biased one"
        ),
        "scenarios": ["paper-1m", "turn"],
        "sweep": {"parameter": "snr_db", "values": [-10, -5, 0, 5, 10, 15, 20, 25, 30]},
        "estimators": [
            {"name": CALIBRATION, "label": "efficient", "options": {}},
            {
                "name": CALIBRATION,
                "label": "biased (s=0.8, b=0.6)",
                "options": {"scale": 0.8, "bias_ratio": 0.6},
            },
            {
                "name": CALIBRATION,
                "label": "small bias (s=0.98, b=0.2)",
                "options": {"scale": 0.98, "bias_ratio": 0.2},
            },
            {"name": CALIBRATION, "label": "above (s=1.2)", "options": {"scale": 1.2}},
            {"name": CALIBRATION, "label": "below (s=0.8)", "options": {"scale": 0.8}},
        ],
        "trials": 500,
        "seed": 20_261_204,
    },
    "smoke": {
        "name": "smoke",
        "description": "a tiny run for tests: two SNR points, two CLS variants, 20 trials",
        "scenarios": ["paper-1m"],
        "sweep": {"parameter": "snr_db", "values": [0, 20]},
        "estimators": ["cls", "cls-paper"],
        "trials": 20,
        "seed": 7,
        "chunk_size": 5,
    },
}
"""Each built-in experiment in the TOML layout of :mod:`comparison.experiment`, as a dict."""

BUILTIN_EXPERIMENTS: dict[str, str] = {
    "paper-fig2": "accuracy vs SNR, one frame, paper/paper-1m/paper-10m, 7 estimators, 500 trials",
    "frames": "per-frame RMSE, NEES, wrong side over 10 frames, with and without a turn",
    "geometry-map": "RMSE/CRLB of cls, ml, lls-toa over an emitter grid, paper-1m at 10 dB",
    "geometry-map-dense": "RMSE/CRLB of cls, cls-paper over a 100 x 100 emitter grid, 100 trials",
    "paper-fig3": "closed loop: 4 planners x 10 frames, ml and per-frame cls vs flown CRLB",
    "noncooperative": "unknown carrier offset and emission time: a beacon pass and a turn",
    "height": (
        "an emitter of unknown height: hill, hill-climb, roof-beacon, hill-terrain against the "
        "3-D bound"
    ),
    "iq-threshold": (
        "from IQ samples: the front end's threshold, two-step cls and ml against dpd, over C/N0"
    ),
    "calibration": "the verdicts checked: estimators of known efficiency and bias, 500 trials",
    "smoke": "2 SNR points, cls and cls-paper, 20 trials (for tests)",
}
"""Built-in experiments by name: one-line summaries (``emitterbench list``)."""


def builtin_definition(name: str) -> dict[str, Any]:
    """A copy of the definition of the built-in experiment ``name`` (:data:`BUILTIN_EXPERIMENTS`)."""
    if name not in BUILTIN_DEFINITIONS:
        raise ValueError(
            f"experiment: unknown built-in {name!r}; built-ins: {', '.join(BUILTIN_EXPERIMENTS)}"
        )
    return copy.deepcopy(BUILTIN_DEFINITIONS[name])


def experiment_definition(name_or_path: str | Path) -> Any:
    """The definition of a built-in experiment by name, or of a ``.toml`` or ``.json`` file.

    A file's content is returned as parsed, unchecked: the keys are the schema's to check.

    Raises
    ------
    ValueError
        Unknown name, unreadable or oversized file, invalid TOML or JSON, nesting too deep, an
        integer too long to read.
    """
    text = str(name_or_path)
    if text in BUILTIN_DEFINITIONS:
        return builtin_definition(text)
    path = Path(name_or_path)
    if path.suffix not in (".toml", ".json"):
        raise ValueError(
            f"experiment: {text!r} is neither a built-in ({', '.join(BUILTIN_EXPERIMENTS)}) "
            "nor a .toml file"
        )
    from scenarios.limits import TOO_DEEP, check_nesting, load_json, read_text

    text = read_text(path, field="experiment", limit_mb=(MAX_EXPERIMENT_MB, ""))
    if path.suffix == ".json":
        return load_json(text, source=f"experiment: {path}")
    try:
        definition = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"experiment: {path} is not valid TOML ({error})") from None
    except RecursionError:
        raise ValueError(f"experiment: {path}: {TOO_DEEP}") from None
    except ValueError:  # an integer longer than Python converts (sys.get_int_max_str_digits)
        raise ValueError(_long_integer(text, path)) from None
    check_nesting(definition)
    return definition


def _long_integer(text: str, path: Path) -> str:
    """The message for the first integer of ``text`` too long for Python to read, by key."""
    limit = sys.get_int_max_str_digits()
    table = ""
    for number, line in enumerate(text.splitlines(), start=1):
        header = re.match(r"\s*\[\[?\s*([\w.\-]+)\s*\]", line)
        if header:
            table = header.group(1)
        digits = max(
            (len(run.replace("_", "")) for run in re.findall(r"\d[\d_]*", line)), default=0
        )
        if digits > limit:
            key = re.match(r"\s*([\w\-]+)\s*=", line)
            field = ".".join(part for part in (table, key.group(1) if key else "") if part)
            return (
                f"{field or 'experiment'}: an integer of {digits} digits ({path}, line {number}); "
                f"Python reads at most {limit} digits, so write a smaller number"
            )
    return f"experiment: {path} holds a number Python cannot read; fix it"
