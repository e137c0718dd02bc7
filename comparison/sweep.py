"""The points of an experiment (``[sweep]``): one swept parameter, or a grid of emitter
positions, and the parameters held fixed (the format: :mod:`comparison.experiment`). Every
message starts with the key path (``sweep.values[2]``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from comparison.experiment_signal import CN0_RANGE_DBHZ, SIGNAL_PARAMETER
from comparison.specs import check_keys
from scenarios import fields
from scenarios.fields import FrozenDict
from scenarios.limits import FRAMES, SAMPLES, LongInteger, check_limit
from scenarios.parameters import SWEEPABLE, check_parameter_value

SNR_RANGE_DB = (-60.0, 100.0)
"""The SNR values an experiment accepts, dB (inclusive)."""

GRID_PARAMETER = "emitter_m"
"""The 2-D sweep parameter: a grid of emitter positions given as ``x`` and ``y``."""

GRID_COLUMNS = ("emitter_x_m", "emitter_y_m")
"""The result columns of the ``emitter_m`` grid."""

MAX_POINTS = 10_000
"""Most sweep points, ``values`` or the ``x`` × ``y`` grid (``EMITTERBENCH_MAX_POINTS``)."""
POINTS_LIMIT = (MAX_POINTS, "EMITTERBENCH_MAX_POINTS")
"""The limit of the points and the environment variable that raises it."""
_SWEEP_KEYS = ("parameter", "values", "x", "y", "fixed")


def check_parameter(name: str, value: float, path: str) -> float:
    """One sweep value: SNR range, the scenario parameter's own domain, the resource limits."""
    if isinstance(value, LongInteger):
        raise ValueError(f"{path}: {value!r} is too large for a float (above 1.8e308)")
    number = fields.number(value, path)
    if name == "snr_db":
        low, high = SNR_RANGE_DB
        if not low <= number <= high:
            raise ValueError(f"{path}: snr_db must lie in [{low:g}, {high:g}] dB, got {value!r}")
        return number
    if name == SIGNAL_PARAMETER:
        low, high = CN0_RANGE_DBHZ
        if not low <= number <= high:
            raise ValueError(
                f"{path}: cn0_dbhz must lie in [{low:g}, {high:g}] dB-Hz, got {value!r}"
            )
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
        known = ("snr_db", SIGNAL_PARAMETER, *SWEEPABLE, GRID_PARAMETER)
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
            if name not in ("snr_db", SIGNAL_PARAMETER, *SWEEPABLE):
                raise ValueError(
                    f"fixed.{name}: unknown parameter; choose one of snr_db, "
                    f"{SIGNAL_PARAMETER}, {', '.join(SWEEPABLE)}"
                )
            if name in swept:
                raise ValueError(f"fixed.{name}: is also swept; remove it from one of the two")
            fixed[name] = check_parameter(name, value, f"fixed.{name}")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "x_m", x_m)
        object.__setattr__(self, "y_m", y_m)
        object.__setattr__(self, "fixed", FrozenDict(fixed))

    @staticmethod
    def _sequence(raw: Any, key: str, parameter: str | None) -> tuple[float, ...]:
        raw = fields.number_list(raw, key)
        check_limit(len(raw), key, "values", POINTS_LIMIT, "sweep fewer values")
        if parameter is None:
            return tuple(fields.number(v, key) for v in raw)
        values = tuple(check_parameter(parameter, v, f"{key}[{i}]") for i, v in enumerate(raw))
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
