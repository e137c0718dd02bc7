"""Experiments as data: which scenarios, which sweep, which estimators, how many trials.

An :class:`Experiment` is a frozen, validated description of a Monte Carlo comparison. It is
loaded from a TOML file or a dict (:func:`load_experiment`, :meth:`Experiment.from_dict`),
written to JSON exactly and read back (:meth:`Experiment.to_json`, :meth:`Experiment.from_json`),
and run by :func:`comparison.engine.run_experiment`. Every check happens at load, before any
work: unknown keys (a typo), unknown scenarios or estimators, bad estimator options, bad ranges
and duplicate labels raise a ``ValueError`` whose message starts with the key path
(``sweep.valuez``, ``estimators[2].options``, ``trials``) and says how to fix it.

TOML format
-----------
A complete example (every key; the optional ones show their defaults)::

    name = "snr-sweep"                      # required; names the rows of the results
    description = "CLS vs ML against SNR"   # optional
    scenarios = ["paper-1m", "paper-10m"]   # required; names from scenarios.catalog
    trials = 500                            # required; Monte Carlo trials per point, >= 1
    seed = 12345                            # required; integer >= 0, drives every draw
    frames = 1                              # optional; frames flown in every scenario
    per_frame = false                       # optional; estimate after every frame
    metrics = ["rmse_m", "efficiency"]      # optional; comparison.metrics.METRIC_NAMES
    chunk_size = "auto"                     # optional; trials per parallel task, or "auto"
    time_limit_s = 60.0                     # optional; seconds one estimate may take

    [sweep]                                 # optional; without it: one point at 0 dB
    parameter = "snr_db"                    # snr_db, a scenarios.parameters.SWEEPABLE name,
    values = [-10, 0, 10, 20, 30]           #   or "emitter_m" (then x = [...], y = [...])

    [sweep.fixed]                           # optional; parameters held at one value
    range_sigma_m = 1.0

    [[estimators]]                          # required; one table per estimator
    name = "cls"                            # registry name or "package.module:Class"
    label = "cls"                           # optional (default: name); unique per experiment

    [[estimators]]
    name = "ml"
    label = "ml-rss"
    options = { use_rss = true }            # optional; keyword arguments of the estimator
    ignore_unknowns = false                 # optional; true or a list: unknowns taken as known

``estimators = ["cls", "ml"]`` (plain names) is shorthand for tables with only ``name``.

Closed loop (trajectory design, MATH §12-§13): with one or more ``[[planners]]`` every trial
flies ``frames`` frames, each planned from the estimate after the previous one
(:mod:`comparison.closed_loop`); every estimator runs after every frame (``per_frame`` must be
true) and each row carries its ``planner`` label (empty in open-loop experiments)::

    steering_estimator = "ml"               # optional; an estimator label (default: the first)

    [[planners]]                            # optional; names from scenarios.planners
    name = "fisher"
    label = "fisher-D"                      # optional (default: name); unique
    options = { criterion = "D" }           # optional; keyword arguments of the planner
    steering_estimator = "cls-last"         # optional; overrides the experiment's

``planners = ["constant", "paper"]`` is shorthand for tables with only ``name``.

The sweep has one parameter with a list of ``values``, or the 2-D grid ``parameter =
"emitter_m"`` with ``x = [...]`` and ``y = [...]`` (metres): point ``p`` is ``x[p // len(y)]``,
``y[p % len(y)]``, and the result rows get the columns ``emitter_x_m`` and ``emitter_y_m``.
``snr_db`` must lie in [-60, 100] dB; it is not a scenario parameter but scales every reference
σ by ``10^(−snr_db/20)`` (MATH §2), and it is 0 dB unless swept or fixed. The other parameters
are those of :data:`scenarios.parameters.SWEEPABLE`; :func:`scenarios.parameters.with_parameter`
applies them after ``frames``.

Resource limits, checked at load: at most :data:`MAX_TRIALS` trials per point,
:data:`MAX_POINTS` sweep points, :data:`MAX_ESTIMATES` estimates in all and, per trial, the
frames and samples of :mod:`scenarios.limits`; each error names the key and the environment
variable that raises the limit (``EMITTERBENCH_MAX_TRIALS=N``).

The built-in experiments (:mod:`comparison.experiment_catalog`) are written in the same format,
as dicts; :func:`load_experiment` takes their names as well as files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from comparison.experiment_catalog import builtin_definition, experiment_definition
from comparison.labels import check_label
from comparison.metrics import METRIC_NAMES
from comparison.specs import (
    EstimatorSpec,
    PlannerSpec,
    built_specs,
    check_estimator_fits,
    check_keys,
    specs_from_list,
)
from estimators.registry import estimator_class
from scenarios import fields
from scenarios.catalog import CATALOG, get_scenario
from scenarios.fields import FrozenDict
from scenarios.limits import FRAMES, SAMPLES, LongInteger, check_limit, count_text, load_json
from scenarios.parameters import SWEEPABLE, check_parameter_value, with_parameters
from scenarios.planners import planner_class
from scenarios.types import Scenario

SNR_RANGE_DB = (-60.0, 100.0)
"""The SNR values an experiment accepts, dB (inclusive)."""

GRID_PARAMETER = "emitter_m"
"""The 2-D sweep parameter: a grid of emitter positions given as ``x`` and ``y``."""

GRID_COLUMNS = ("emitter_x_m", "emitter_y_m")
"""The result columns of the ``emitter_m`` grid."""

MAX_TRIALS = 1_000_000
"""Most trials per point (``EMITTERBENCH_MAX_TRIALS``); 500 bound an efficiency to about ±5%."""
MAX_POINTS = 10_000
"""Most sweep points, ``values`` or the ``x`` × ``y`` grid (``EMITTERBENCH_MAX_POINTS``)."""
MAX_ESTIMATES = 100_000_000
"""Most estimates, i.e. result rows, of a run (``EMITTERBENCH_MAX_ESTIMATES``): some 30 GB."""
MAX_CHUNK_SAMPLES = 5_000_000
"""Most samples one task simulates at once, ``chunk_size`` × samples per trial (about 400 MB)."""

AUTO_CHUNK_SIZE = "auto"
"""The ``chunk_size`` that sizes the tasks from the work (:func:`comparison.tasks.auto_chunk_size`)."""

_TRIALS = (MAX_TRIALS, "EMITTERBENCH_MAX_TRIALS")
_POINTS = (MAX_POINTS, "EMITTERBENCH_MAX_POINTS")
_ESTIMATES = (MAX_ESTIMATES, "EMITTERBENCH_MAX_ESTIMATES")

_EXPERIMENT_KEYS = (
    "name",
    "description",
    "scenarios",
    "sweep",
    "estimators",
    "trials",
    "seed",
    "frames",
    "per_frame",
    "metrics",
    "chunk_size",
    "time_limit_s",
    "swept_columns",
    "planners",
    "steering_estimator",
)
_REQUIRED_KEYS = ("name", "scenarios", "estimators", "trials", "seed")
_SWEEP_KEYS = ("parameter", "values", "x", "y", "fixed")


# --------------------------------------------------------------------------------------------
# sweep values (keys: comparison.specs.check_keys; other fields: scenarios.fields); every
# message starts with the key path
# --------------------------------------------------------------------------------------------


def _count(value: Any, path: str, *, minimum: int) -> int:
    """A whole number ``>= minimum``; a huge one named by its size, never by 4000 digits."""
    if isinstance(value, LongInteger):
        raise ValueError(f"{path}: expected a whole number, got {value!r}")
    if isinstance(value, int) and not isinstance(value, bool) and value < min(minimum, -(10**15)):
        raise ValueError(f"{path}: must be a whole number >= {minimum}, got {count_text(value)}")
    return fields.whole(value, path, minimum=minimum)


def _check_parameter(name: str, value: float, path: str) -> float:
    """One sweep value: SNR range, the scenario parameter's own domain, the resource limits."""
    if isinstance(value, LongInteger):
        raise ValueError(f"{path}: {value!r} is too large for a float (above 1.8e308)")
    number = fields.number(value, path)
    if name == "snr_db":
        low, high = SNR_RANGE_DB
        if not low <= number <= high:
            raise ValueError(f"{path}: snr_db must lie in [{low:g}, {high:g}] dB, got {value!r}")
        return number
    try:
        number = check_parameter_value(name, number)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    if name == "frames":
        check_limit(int(number), path, "frames", FRAMES, "fly fewer frames")
    if name == "samples_per_frame":
        check_limit(int(number), path, "samples per frame", SAMPLES, "take fewer samples")
    return number


# --------------------------------------------------------------------------------------------
# the sweep and the experiment (the estimator and planner entries: comparison.specs)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Sweep:
    """The points of an experiment: one swept parameter (or an emitter grid) and fixed values.

    Parameters
    ----------
    parameter : str or None
        ``"snr_db"``, a name of :data:`scenarios.parameters.SWEEPABLE`, ``"emitter_m"`` (a grid of
        ``x_m`` × ``y_m``), or None for a single point made of the ``fixed`` values.
    values : sequence of float
        The values of ``parameter`` (not for ``emitter_m``); distinct.
    x_m, y_m : sequence of float
        The grid of ``emitter_m`` (TOML keys ``x`` and ``y``); point ``p`` is
        ``(x_m[p // len(y_m)], y_m[p % len(y_m)])``.
    fixed : mapping
        Values of other parameters held at every point, e.g. ``{"snr_db": 10.0}``. ``snr_db``
        is 0 dB unless swept or fixed.
    """

    parameter: str | None = None
    values: tuple[float, ...] = ()
    x_m: tuple[float, ...] = ()
    y_m: tuple[float, ...] = ()
    fixed: Mapping[str, float] = field(default_factory=FrozenDict)

    def __post_init__(self) -> None:
        known = ("snr_db", *SWEEPABLE, GRID_PARAMETER)
        parameter = self.parameter
        if parameter is not None and parameter not in known:
            raise ValueError(f"parameter: unknown {parameter!r}; choose one of {', '.join(known)}")
        grid = parameter == GRID_PARAMETER
        values = self._sequence(self.values, "values", parameter if not grid else None)
        x_m = self._sequence(self.x_m, "x", "emitter_x_m" if grid else None)
        y_m = self._sequence(self.y_m, "y", "emitter_y_m" if grid else None)
        if grid:
            if values:
                raise ValueError("values: the emitter_m grid takes x = [...] and y = [...]")
            for name, sequence in (("x", x_m), ("y", y_m)):
                if not sequence:
                    raise ValueError(f"{name}: the emitter_m grid needs a non-empty list (metres)")
        else:
            if x_m or y_m:
                raise ValueError(
                    f"{'x' if x_m else 'y'}: only the emitter_m grid takes x and y; "
                    "set parameter = 'emitter_m' or use values"
                )
            if parameter is not None and not values:
                raise ValueError(f"values: give at least one value of {parameter}")
            if parameter is None and values:
                raise ValueError("parameter: values are given but no parameter to sweep")
        if not isinstance(self.fixed, Mapping):
            raise ValueError(f"fixed: expected a table, got {type(self.fixed).__name__}")
        swept = set(GRID_COLUMNS) if grid else {parameter}
        fixed = {}
        for name, value in self.fixed.items():
            if name not in ("snr_db", *SWEEPABLE):
                raise ValueError(
                    f"fixed.{name}: unknown parameter; choose one of snr_db, {', '.join(SWEEPABLE)}"
                )
            if name in swept:
                raise ValueError(f"fixed.{name}: is also swept; remove it from one of the two")
            fixed[name] = _check_parameter(name, value, f"fixed.{name}")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "x_m", x_m)
        object.__setattr__(self, "y_m", y_m)
        object.__setattr__(self, "fixed", FrozenDict(fixed))

    @staticmethod
    def _sequence(raw: Any, key: str, parameter: str | None) -> tuple[float, ...]:
        raw = fields.number_list(raw, key)
        check_limit(len(raw), key, "values", _POINTS, "sweep fewer values")
        if parameter is None:
            return tuple(fields.number(v, key) for v in raw)
        values = tuple(_check_parameter(parameter, v, f"{key}[{i}]") for i, v in enumerate(raw))
        first: dict[float, int] = {}
        for index, value in enumerate(values):
            if value in first:
                raise ValueError(
                    f"{key}[{index}]: {value:g} repeats {key}[{first[value]}]; give distinct values"
                )
            first[value] = index
        return values

    @property
    def columns(self) -> tuple[str, ...]:
        """The swept columns of the result rows other than ``snr_db``."""
        if self.parameter == GRID_PARAMETER:
            return GRID_COLUMNS
        if self.parameter is None or self.parameter == "snr_db":
            return ()
        return (self.parameter,)

    @property
    def n_points(self) -> int:
        if self.parameter == GRID_PARAMETER:
            return len(self.x_m) * len(self.y_m)
        return len(self.values) if self.parameter is not None else 1

    def points(self) -> list[dict[str, float]]:
        """Every point's settings: ``snr_db`` and each fixed or swept scenario parameter."""
        return [self.point(index) for index in range(self.n_points)]

    def point(self, index: int) -> dict[str, float]:
        """Point ``index``'s settings (grid points x-major, as :meth:`points` lists them)."""
        base = {"snr_db": 0.0, **self.fixed}
        if self.parameter is None:
            return base
        if self.parameter == GRID_PARAMETER:
            i, j = divmod(index, len(self.y_m))
            return {**base, "emitter_x_m": self.x_m[i], "emitter_y_m": self.y_m[j]}
        return {**base, self.parameter: self.values[index]}

    def to_dict(self) -> dict[str, Any]:
        raw: dict[str, Any] = {}
        if self.parameter is not None:
            raw["parameter"] = self.parameter
        if self.parameter == GRID_PARAMETER:
            raw["x"] = list(self.x_m)
            raw["y"] = list(self.y_m)
        elif self.parameter is not None:
            raw["values"] = list(self.values)
        raw["fixed"] = dict(self.fixed)
        return raw

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any], *, path: str = "sweep") -> Sweep:
        check_keys(raw, _SWEEP_KEYS, path)
        try:
            return cls(
                parameter=raw.get("parameter"),
                values=raw.get("values", ()),
                x_m=raw.get("x", ()),
                y_m=raw.get("y", ()),
                fixed=raw.get("fixed", {}),
            )
        except ValueError as error:
            raise ValueError(f"{path}.{error}") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class Experiment:
    """A Monte Carlo comparison: scenarios × sweep points × estimators × trials.

    Parameters
    ----------
    name : str
        Names the result rows (column ``experiment``).
    description : str
    scenarios : sequence of str
        Names of :data:`scenarios.catalog.CATALOG`, distinct.
    sweep : Sweep
    estimators : sequence of EstimatorSpec
        Distinct labels; each is constructed once here, which checks its options, and must
        find the modalities it requires in every scenario.
    trials : int
        Monte Carlo trials per (scenario, point), >= 1.
    seed : int
        Root of every random draw (>= 0); see :mod:`comparison.tasks` for the seed tree.
    frames : int or None
        Frames flown in every scenario (extended at the last velocity); None keeps each
        scenario's own.
    per_frame : bool
        Estimate after every frame (on the data up to it) instead of once at the end.
    metrics : sequence of str or None
        Metric columns the report shows (:data:`comparison.metrics.METRIC_NAMES`); None: all.
    chunk_size : int or "auto"
        Trials per parallel task (>= 1), or ``"auto"`` (:data:`AUTO_CHUNK_SIZE`, the default):
        sized from the trials, points and workers when the run starts
        (:func:`comparison.tasks.auto_chunk_size`), the number then recorded in the run
        folder's ``experiment.json``. Results depend on it only to rounding.
    time_limit_s : float
        Seconds one estimator call may take (> 0); a longer one fails its row
        (:mod:`comparison.estimator_calls`).
    planners : sequence of PlannerSpec
        Closed loop: each planner flies every trial (distinct labels); empty for an
        open-loop experiment. Needs ``per_frame``.
    steering_estimator : str or None
        The estimator label whose estimate steers the planners (default: the first
        estimator); a planner may name its own.

    Raises
    ------
    ValueError
        Whose message starts with the key path, on any malformed field.
    """

    name: str
    description: str = ""
    scenarios: tuple[str, ...]
    sweep: Sweep = field(default_factory=Sweep)
    estimators: tuple[EstimatorSpec, ...]
    trials: int
    seed: int
    frames: int | None = None
    per_frame: bool = False
    metrics: tuple[str, ...] | None = None
    chunk_size: int | str = AUTO_CHUNK_SIZE
    time_limit_s: float = 60.0
    planners: tuple[PlannerSpec, ...] = ()
    steering_estimator: str | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        check_label(self.name, "name")
        fields.text(self.description, "description", allow_empty=True)
        set_(self, "trials", _count(self.trials, "trials", minimum=1))
        check_limit(self.trials, "trials", "trials per point", _TRIALS, "ask for fewer")
        set_(self, "seed", _count(self.seed, "seed", minimum=0))
        if self.chunk_size != AUTO_CHUNK_SIZE:
            set_(self, "chunk_size", _count(self.chunk_size, "chunk_size", minimum=1))
            check_limit(self.chunk_size, "chunk_size", "trials per task", _TRIALS, "use fewer")
        set_(self, "time_limit_s", fields.number(self.time_limit_s, "time_limit_s"))
        if self.time_limit_s <= 0:
            raise ValueError(f"time_limit_s: must be > 0 seconds, got {self.time_limit_s:g}")
        if self.frames is not None:
            set_(self, "frames", _count(self.frames, "frames", minimum=1))
            check_limit(self.frames, "frames", "frames", FRAMES, "fly fewer frames")
        if not isinstance(self.per_frame, bool):
            raise ValueError(f"per_frame: expected true or false, got {self.per_frame!r}")
        if not isinstance(self.sweep, Sweep):
            raise ValueError(f"sweep: expected a Sweep, got {type(self.sweep).__name__}")
        most_frames, most_samples = self._check_scenarios()
        self._check_metrics()
        self._check_estimators()
        self._check_planners()
        self._check_size(most_frames, most_samples)

    # -- validation ------------------------------------------------------------------------

    def _check_scenarios(self) -> tuple[int, int]:
        """Check the names and fly every point; the most frames and samples of a trial."""
        if isinstance(self.scenarios, str) or not isinstance(self.scenarios, Sequence):
            raise ValueError(f"scenarios: expected a list of names, got {self.scenarios!r}")
        names = tuple(self.scenarios)
        if not names:
            raise ValueError(f"scenarios: give at least one of {', '.join(CATALOG)}")
        for index, name in enumerate(names):
            if not isinstance(name, str) or name not in CATALOG:
                raise ValueError(
                    f"scenarios[{index}]: unknown scenario {name!r}; "
                    f"known scenarios: {', '.join(CATALOG)}"
                )
            if name in names[:index]:
                raise ValueError(f"scenarios[{index}]: {name!r} is listed twice; list it once")
        object.__setattr__(self, "scenarios", names)
        check_limit(self.sweep.n_points, "sweep", "points", _POINTS, "sweep fewer values")
        most_frames = most_samples = 0
        for index, name in enumerate(names):
            for point, settings in enumerate(self.sweep.points()):
                try:
                    flight = self._flight_of(name, settings)
                except ValueError as error:
                    raise ValueError(
                        f"{self._culprit(name, point)}: point {point} of the sweep cannot be "
                        f"flown in scenarios[{index}] ({name}): {error}"
                    ) from None
                most_frames = max(most_frames, flight.n_frames)
                most_samples = max(most_samples, flight.n_samples)
        return most_frames, most_samples

    def _flight_of(self, name: str, settings: Mapping[str, float]) -> Any:
        """The flight of ``name`` at ``settings``: within the limits, every σ in range (MATH §2)."""
        scenario = build_scenario(name, settings, frames=self.frames)
        fix = "fly fewer frames or samples per frame"
        check_limit(scenario.flight.n_samples, "samples", "samples per trial", SAMPLES, fix)
        scenario.noise.at_snr(settings.get("snr_db", 0.0))
        return scenario.flight

    def _culprit(self, name: str, point: int) -> str:
        """The key to fix for a point that cannot be flown: the first value failing alone."""
        sweep = self.sweep
        snr = {"snr_db": sweep.fixed.get("snr_db", 0.0)}
        alone: list[tuple[str, dict[str, float]]] = [("frames", {})] if self.frames else []
        alone += [(f"sweep.fixed.{key}", {**snr, key: value}) for key, value in sweep.fixed.items()]
        settings = sweep.point(point)
        if sweep.parameter == GRID_PARAMETER:
            i, j = divmod(point, len(sweep.y_m))
            alone.append((f"sweep.x[{i}]", {**snr, "emitter_x_m": settings["emitter_x_m"]}))
            alone.append((f"sweep.y[{j}]", {**snr, "emitter_y_m": settings["emitter_y_m"]}))
        elif sweep.parameter is not None:
            value = settings[sweep.parameter]
            alone.append((f"sweep.values[{point}]", {**snr, sweep.parameter: value}))
        for path, values in alone:
            try:
                self._flight_of(name, values)
            except ValueError:
                return path
        return "sweep"

    def _check_size(self, most_frames: int, most_samples: int) -> None:
        """The whole run within :data:`MAX_ESTIMATES`, a task within :data:`MAX_CHUNK_SAMPLES`."""
        counts = (self.trials, self.sweep.n_points, len(self.scenarios), len(self.estimators))
        counts += (max(1, len(self.planners)), most_frames if self.per_frame else 1)
        names = ("trials", "points", "scenarios", "estimators", "planners", "frames")
        product = " × ".join(
            f"{n:,} {what}" for what, n in zip(names, counts, strict=True) if n > 1
        )
        fix = "ask for fewer trials, points, estimators or frames"
        check_limit(math.prod(counts), "trials", f"estimates ({product})", _ESTIMATES, fix)
        if self.chunk_size == AUTO_CHUNK_SIZE:  # sized within the limit when the run starts
            return
        chunk = min(self.chunk_size, self.trials) * most_samples
        if chunk > MAX_CHUNK_SAMPLES:
            raise ValueError(
                f"chunk_size: {min(self.chunk_size, self.trials):,} trials of {most_samples:,} "
                f"samples, {chunk:,} samples simulated at once, more than the limit of "
                f"{MAX_CHUNK_SAMPLES:,}; set chunk_size <= {MAX_CHUNK_SAMPLES // most_samples}"
            )

    def _check_metrics(self) -> None:
        if self.metrics is None:
            return
        if isinstance(self.metrics, str) or not isinstance(self.metrics, Sequence):
            raise ValueError(f"metrics: expected a list of metric names, got {self.metrics!r}")
        metrics = tuple(self.metrics)
        for index, metric in enumerate(metrics):
            fields.text(metric, f"metrics[{index}]")
            if metric not in METRIC_NAMES:
                raise ValueError(
                    f"metrics[{index}]: unknown metric {metric!r}; "
                    f"choose from {', '.join(METRIC_NAMES)}"
                )
        object.__setattr__(self, "metrics", metrics)

    def _check_estimators(self) -> None:
        if isinstance(self.estimators, str | Mapping) or not isinstance(self.estimators, Sequence):
            raise ValueError("estimators: expected a list of estimator tables")
        specs = tuple(self.estimators)
        if not specs:
            raise ValueError("estimators: give at least one estimator, e.g. name = 'cls'")
        scenarios = {name: get_scenario(name, frames=self.frames) for name in self.scenarios}
        for path, spec, estimator in built_specs(
            specs, "estimators", EstimatorSpec, estimator_class
        ):
            check_estimator_fits(path, spec, estimator, scenarios)
        object.__setattr__(self, "estimators", specs)

    def _check_planners(self) -> None:
        if isinstance(self.planners, str | Mapping) or not isinstance(self.planners, Sequence):
            raise ValueError("planners: expected a list of planner tables")
        specs = tuple(self.planners)
        steering = self.steering_estimator
        if steering is not None:
            fields.text(steering, "steering_estimator")
        if not specs:
            if steering is not None:
                raise ValueError(
                    "steering_estimator: only a closed loop steers; add [[planners]] or "
                    "remove the key"
                )
            object.__setattr__(self, "planners", ())
            return
        if not self.per_frame:
            raise ValueError(
                "per_frame: a closed loop estimates after every frame; set per_frame = true"
            )
        for path, spec, _ in built_specs(specs, "planners", PlannerSpec, planner_class):
            own = spec.steering_estimator
            if own is not None and own not in self.labels:
                raise ValueError(
                    f"{path}.steering_estimator: {own!r} is not an estimator label; "
                    f"choose one of {', '.join(self.labels)}"
                )
        if steering is not None and steering not in self.labels:
            raise ValueError(
                f"steering_estimator: {steering!r} is not an estimator label; choose one of "
                f"{', '.join(self.labels)}"
            )
        object.__setattr__(self, "planners", specs)

    # -- derived -----------------------------------------------------------------------------

    @property
    def labels(self) -> tuple[str, ...]:
        """The estimator labels, in order."""
        return tuple(spec.label for spec in self.estimators)

    @property
    def planner_labels(self) -> tuple[str, ...]:
        """The planner labels, in order (empty for an open-loop experiment)."""
        return tuple(spec.label for spec in self.planners)

    @property
    def is_closed_loop(self) -> bool:
        """True when planners steer the flight (:mod:`comparison.closed_loop`)."""
        return bool(self.planners)

    def steering_label(self, planner_index: int) -> str:
        """The estimator label that steers planner ``planner_index``."""
        spec = self.planners[planner_index]
        return spec.steering_estimator or self.steering_estimator or self.labels[0]

    @property
    def swept_columns(self) -> tuple[str, ...]:
        """Swept columns of the result rows other than ``snr_db`` (see :class:`Sweep`)."""
        return self.sweep.columns

    def point_scenario(self, scenario_index: int, point: int) -> tuple[Scenario, float]:
        """The scenario of ``(scenario_index, point)`` and its SNR in dB."""
        settings = self.sweep.point(point)
        return build_scenario(self.scenarios[scenario_index], settings, frames=self.frames), (
            settings["snr_db"]
        )

    def with_trials(self, trials: int) -> Experiment:
        """This experiment with ``trials`` trials per point."""
        return Experiment.from_dict({**self.to_dict(), "trials": trials})

    # -- serialisation -------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """A JSON/TOML-ready dict; :meth:`from_dict` gives back an equal experiment."""
        return {
            "name": self.name,
            "description": self.description,
            "scenarios": list(self.scenarios),
            "sweep": self.sweep.to_dict(),
            "estimators": [spec.to_dict() for spec in self.estimators],
            "trials": self.trials,
            "seed": self.seed,
            "frames": self.frames,
            "per_frame": self.per_frame,
            "metrics": None if self.metrics is None else list(self.metrics),
            "chunk_size": self.chunk_size,
            "time_limit_s": self.time_limit_s,
            "swept_columns": list(self.swept_columns),
        } | self._closed_loop_dict()

    def _closed_loop_dict(self) -> dict[str, Any]:
        """The closed-loop keys, only when there are planners (open-loop JSON is unchanged)."""
        if not self.planners:
            return {}
        return {
            "planners": [spec.to_dict() for spec in self.planners],
            "steering_estimator": self.steering_estimator,
        }

    def to_json(self) -> str:
        """The experiment as JSON text (floats written exactly)."""
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"

    @classmethod
    def from_json(cls, text: str) -> Experiment:
        """The experiment of :meth:`to_json` (read within :mod:`scenarios.limits`)."""
        return cls.from_dict(load_json(text, source="experiment"))

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any]) -> Experiment:
        """Validate a dict in the TOML layout of the module docstring (``None`` = absent)."""
        check_keys(raw, _EXPERIMENT_KEYS, "")
        for key in _REQUIRED_KEYS:
            if key not in raw:
                raise ValueError(f"{key}: missing; see the example in comparison.experiment")
        sweep = Sweep.from_dict(raw.get("sweep", {}))
        estimators = specs_from_list(raw["estimators"], "estimators", EstimatorSpec)
        planners = specs_from_list(raw.get("planners") or (), "planners", PlannerSpec)
        experiment = cls(
            name=raw["name"],
            description=raw.get("description", ""),
            scenarios=raw["scenarios"],
            sweep=sweep,
            estimators=estimators,
            trials=raw["trials"],
            seed=raw["seed"],
            frames=raw.get("frames"),
            per_frame=raw.get("per_frame", False),
            metrics=raw.get("metrics"),
            chunk_size=raw.get("chunk_size", AUTO_CHUNK_SIZE),
            time_limit_s=raw.get("time_limit_s", 60.0),
            planners=planners,
            steering_estimator=raw.get("steering_estimator"),
        )
        if "swept_columns" in raw and list(raw["swept_columns"]) != list(sweep.columns):
            raise ValueError(
                f"swept_columns: {raw['swept_columns']!r} does not match the sweep "
                f"({list(sweep.columns)!r}); remove the key, it is derived from the sweep"
            )
        return experiment


def build_scenario(
    name: str, settings: Mapping[str, float], *, frames: int | None = None
) -> Scenario:
    """The catalog scenario ``name`` with ``frames`` frames and every setting but ``snr_db``."""
    scenario = get_scenario(name, frames=frames)
    return with_parameters(scenario, {k: v for k, v in settings.items() if k != "snr_db"})


# --------------------------------------------------------------------------------------------
# loading: a built-in by name, or a file
# --------------------------------------------------------------------------------------------


def builtin_experiment(name: str) -> Experiment:
    """The built-in experiment ``name`` (:data:`comparison.experiment_catalog.BUILTIN_EXPERIMENTS`)."""
    return Experiment.from_dict(builtin_definition(name))


def load_experiment(name_or_path: str | Path) -> Experiment:
    """A built-in experiment by name, or one read from a ``.toml`` (or ``.json``) file.

    Raises
    ------
    ValueError
        Unknown name, unreadable file, invalid TOML, or any invalid key (the message starts
        with the key path).
    """
    return Experiment.from_dict(experiment_definition(name_or_path))
