"""The built-in experiments, and the definition behind an experiment's name or file.

Each built-in is written in the TOML layout of :mod:`comparison.experiment` (its module
docstring is the reference), as a dict. :func:`experiment_definition` finds the definition
that ``emitterbench run NAME_OR_FILE`` means: a built-in by name, or a ``.toml`` (or ``.json``)
file read into a dict. :func:`comparison.experiment.load_experiment` validates it into an
:class:`~comparison.experiment.Experiment`. This module holds no schema and imports neither the
estimators nor the scenarios, so ``emitterbench list`` reads the summaries at once.
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path
from typing import Any

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
    "paper-fig3": "closed loop: 4 planners x 10 frames, ml and per-frame cls vs flown CRLB",
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
        Unknown name, unreadable file, invalid TOML or JSON.
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
    try:
        content = path.read_bytes()
    except OSError as error:
        raise ValueError(f"experiment: cannot read {path} ({error.strerror})") from None
    if path.suffix == ".json":
        try:
            return json.loads(content.decode())
        except json.JSONDecodeError as error:
            raise ValueError(f"experiment: not valid JSON ({error})") from None
    try:
        return tomllib.loads(content.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"experiment: {path} is not valid TOML ({error})") from None
