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

The signal level (docs/math.md §18-§20): with a ``[signal]`` table every trial receives the
bursts of :class:`scenarios.signal.BurstPlan` (complex samples with white noise at a C/N0) and
the per-burst front end measures them (:mod:`estimators.frontend`); the measurement-level
estimators read what it measured, and an estimator of the samples (``dpd``) reads the samples.
The axis is then the physical one, ``cn0_dbhz`` (swept or fixed; ``snr_db`` is refused), and
the bound at each point is that of the σ's the bursts allow at that C/N0, the signal-level
bound above the threshold (§21)::

    [signal]                                # optional; the BurstPlan without its C/N0
    waveform = "bpsk"                       # a known chip sequence (a tone gives no ToA)
    burst_s = 0.01
    sample_rate_hz = 102400.0
    chip_rate_hz = 25600.0
    guard_s = 0.0001                        # optional; chip_seed, received_power_w too
    doppler_search_hz = 1200.0              # optional; the front end's Doppler search (±Hz);
                                            #   default γ·max|v|, required with δ unknown

    [sweep]
    parameter = "cn0_dbhz"
    values = [25, 30, 35, 40]

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
:data:`~comparison.sweep.MAX_POINTS` sweep points, :data:`MAX_ESTIMATES` estimates in all and, per trial, the
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
from comparison.experiment_signal import (
    SIGNAL_PARAMETER,
    burst_plan,
    check_doppler_search,
    checked_signal,
    doppler_search_of,
    received_scenario,
)
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
from comparison.sweep import GRID_PARAMETER, POINTS_LIMIT, Sweep
from estimators.registry import estimator_class, reads_samples
from scenarios import fields
from scenarios.catalog import CATALOG, get_scenario
from scenarios.limits import FRAMES, SAMPLES, LongInteger, check_limit, count_text, load_json
from scenarios.parameters import with_parameters
from scenarios.planners import planner_class
from scenarios.signal import BurstPlan
from scenarios.types import Scenario

MAX_TRIALS = 1_000_000
"""Most trials per point (``EMITTERBENCH_MAX_TRIALS``); 500 bound an efficiency to about ±5%."""
MAX_ESTIMATES = 100_000_000
"""Most estimates, i.e. result rows, of a run (``EMITTERBENCH_MAX_ESTIMATES``): some 30 GB."""
MAX_CHUNK_SAMPLES = 5_000_000
"""Most samples one task simulates at once, ``chunk_size`` × samples per trial (about 400 MB)."""

AUTO_CHUNK_SIZE = "auto"
"""The ``chunk_size`` that sizes the tasks from the work (:func:`comparison.tasks.auto_chunk_size`)."""

_TRIALS = (MAX_TRIALS, "EMITTERBENCH_MAX_TRIALS")
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
    "signal",
)
_REQUIRED_KEYS = ("name", "scenarios", "estimators", "trials", "seed")


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


# --------------------------------------------------------------------------------------------
# the sweep and the experiment (the estimator and planner entries: comparison.specs)
# --------------------------------------------------------------------------------------------


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
    signal : mapping or None
        The bursts and the receiver of a signal-level experiment (module text): the fields of
        :class:`scenarios.signal.BurstPlan` but its C/N0, which is the point's ``cn0_dbhz``.
        None: the measurement level, on the σ's of ``snr_db``.

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
    signal: Mapping[str, Any] | None = None

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
        self._check_signal()
        most_frames, most_samples = self._check_scenarios()
        if self.signal is not None:
            check_doppler_search(self.signal, self.scenarios)
        self._check_metrics()
        self._check_estimators()
        self._check_planners()
        self._check_size(most_frames, most_samples)

    # -- validation ------------------------------------------------------------------------

    def _check_signal(self) -> None:
        """The ``[signal]`` table (:func:`comparison.experiment_signal.checked_signal`); the
        ``cn0_dbhz`` axis only with it."""
        sweep = self.sweep
        swept = {sweep.parameter, *sweep.fixed}
        if self.signal is None:
            if SIGNAL_PARAMETER in swept:
                raise ValueError(
                    "sweep: cn0_dbhz is the axis of the signal level; add a [signal] table "
                    "(the bursts and the receiver) or sweep snr_db"
                )
            return
        if self.per_frame:
            raise ValueError("per_frame: a [signal] experiment estimates once; set it false")
        signal = checked_signal(self.signal, swept, sweep.points(), bool(self.planners))
        object.__setattr__(self, "signal", signal)

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
        check_limit(self.sweep.n_points, "sweep", "points", POINTS_LIMIT, "sweep fewer values")
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
        if self.signal is not None:  # the Doppler within the band
            received_scenario(scenario, burst_plan(self.signal, settings))
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
            if reads_samples(estimator) and self.signal is None:
                raise ValueError(
                    f"{path}: {spec.label!r} reads the received samples; add a [signal] "
                    "table (the bursts and the receiver) or drop it"
                )
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
        """The scenario of ``(scenario_index, point)`` and its SNR in dB; at the signal level
        the scenario's σ's are those the bursts allow at the point's C/N0 (the bounds of
        MATH §18, :func:`received_scenario`), at 0 dB."""
        settings = self.sweep.point(point)
        scenario = build_scenario(self.scenarios[scenario_index], settings, frames=self.frames)
        plan = self.point_plan(point)
        if plan is not None:
            return received_scenario(scenario, plan), 0.0
        return scenario, settings["snr_db"]

    def doppler_search_hz(self, scenario: Scenario) -> float | None:
        """The front end's Doppler search at the signal level (MATH §20,
        :func:`comparison.experiment_signal.doppler_search_of`); None at the measurement
        level."""
        return None if self.signal is None else doppler_search_of(self.signal, scenario)

    def point_plan(self, point: int) -> BurstPlan | None:
        """The bursts and the receiver at ``point`` (None at the measurement level)."""
        return None if self.signal is None else burst_plan(self.signal, self.sweep.point(point))

    def with_trials(self, trials: int) -> Experiment:
        """This experiment with ``trials`` trials per point."""
        return Experiment.from_dict({**self.to_dict(), "trials": trials})

    # -- serialisation -------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """A JSON/TOML-ready dict; :meth:`from_dict` gives back an equal experiment."""
        return (
            {
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
            }
            | self._closed_loop_dict()
            | self._signal_dict()
        )

    def _closed_loop_dict(self) -> dict[str, Any]:
        """The closed-loop keys, only when there are planners (open-loop JSON is unchanged)."""
        if not self.planners:
            return {}
        return {
            "planners": [spec.to_dict() for spec in self.planners],
            "steering_estimator": self.steering_estimator,
        }

    def _signal_dict(self) -> dict[str, Any]:
        """The ``signal`` key, only at the signal level (other JSON is unchanged)."""
        return {} if self.signal is None else {"signal": dict(self.signal)}

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
            signal=raw.get("signal"),
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
    """The catalog scenario ``name`` with ``frames`` frames and every setting but ``snr_db``
    and ``cn0_dbhz`` (which set the noise, not the scenario)."""
    scenario = get_scenario(name, frames=frames)
    noise = ("snr_db", SIGNAL_PARAMETER)
    return with_parameters(scenario, {k: v for k, v in settings.items() if k not in noise})


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
