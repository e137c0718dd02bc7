"""The estimator and planner entries of an experiment: name, label, options, built and checked.

An experiment file lists ``[[estimators]]`` and ``[[planners]]`` tables (or bare names);
:class:`EstimatorSpec` and :class:`PlannerSpec` hold one entry each, validated on construction
(every message starts with the key path), and build the object through the registries
(:func:`estimators.registry.make_estimator`, :func:`scenarios.planners.get_planner`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from estimators.base import Estimator
from estimators.registry import make_estimator
from scenarios import fields
from scenarios.fields import FrozenDict, thaw
from scenarios.planners import Planner, get_planner

ESTIMATOR_KEYS = ("name", "label", "options")
PLANNER_KEYS = ("name", "label", "options", "steering_estimator")


def check_keys(raw: Mapping[str, Any], allowed: Sequence[str], path: str) -> None:
    if not isinstance(raw, Mapping):
        raise ValueError(f"{path or 'experiment'}: expected a table, got {type(raw).__name__}")
    for key in raw:
        if key not in allowed:
            where = f"{path}.{key}" if path else str(key)
            raise ValueError(f"{where}: unknown key; expected one of {', '.join(allowed)}")


def _check_spec_fields(spec: Any) -> None:
    """Validate an estimator or planner entry: ``name``, ``label`` (default: the name) and
    ``options`` (a table of JSON-like values, frozen)."""
    fields.text(spec.name, "name")
    if spec.label is None:
        object.__setattr__(spec, "label", spec.name)
    fields.text(spec.label, "label")
    object.__setattr__(spec, "options", fields.frozen_table(spec.options, "options"))


def _spec_from_dict(
    spec_type: type, raw: Mapping[str, Any] | str, path: str, keys: Sequence[str], example: str
) -> Any:
    """An estimator or planner entry from its table (``keys``) or a bare name."""
    if isinstance(raw, str):
        raw = {"name": raw}
    check_keys(raw, keys, path)
    if "name" not in raw:
        raise ValueError(f"{path}.name: missing; give {example}")
    try:
        return spec_type(**{key: raw[key] for key in keys if key in raw})
    except ValueError as error:
        raise ValueError(f"{path}.{error}") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimatorSpec:
    """One estimator of an experiment: registry ``name``, a unique ``label`` and its ``options``.

    Parameters
    ----------
    name : str
        A name of :func:`estimators.registry.all_entries` or ``"package.module:Class"``.
    label : str, optional
        What the result rows call it (default: ``name``); lets one estimator appear twice with
        different options.
    options : mapping
        Keyword arguments of the estimator's constructor (lists become tuples).
    """

    name: str
    label: str | None = None
    options: Mapping[str, Any] = field(default_factory=FrozenDict)

    def __post_init__(self) -> None:
        _check_spec_fields(self)

    def build(self) -> Estimator:
        """A new estimator object (:func:`estimators.registry.make_estimator`)."""
        return make_estimator(self.name, **thaw(self.options, sequence=tuple))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "label": self.label, "options": thaw(self.options)}

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any] | str, *, path: str = "estimator") -> EstimatorSpec:
        """From a table ``{name, label?, options?}`` or a bare name."""
        return _spec_from_dict(cls, raw, path, ESTIMATOR_KEYS, "a registry name such as 'cls'")


@dataclass(frozen=True, slots=True, kw_only=True)
class PlannerSpec:
    """One planner of a closed-loop experiment (:mod:`scenarios.planners`).

    Parameters
    ----------
    name : str
        A name of :data:`scenarios.planners.PLANNERS` or ``"package.module:Class"``.
    label : str, optional
        What the result rows call it (column ``planner``; default: ``name``).
    options : mapping
        Keyword arguments of the planner's constructor (lists become tuples).
    steering_estimator : str, optional
        The label of the estimator whose estimate steers this planner; default: the
        experiment's ``steering_estimator``.
    """

    name: str
    label: str | None = None
    options: Mapping[str, Any] = field(default_factory=FrozenDict)
    steering_estimator: str | None = None

    def __post_init__(self) -> None:
        _check_spec_fields(self)
        if self.steering_estimator is not None:
            fields.text(self.steering_estimator, "steering_estimator")

    def build(self) -> Planner:
        """A new planner object (:func:`scenarios.planners.get_planner`)."""
        return get_planner(self.name, **thaw(self.options, sequence=tuple))

    def to_dict(self) -> dict[str, Any]:
        raw = {"name": self.name, "label": self.label, "options": thaw(self.options)}
        if self.steering_estimator is not None:
            raw["steering_estimator"] = self.steering_estimator
        return raw

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any] | str, *, path: str = "planner") -> PlannerSpec:
        """From a table ``{name, label?, options?, steering_estimator?}`` or a bare name."""
        return _spec_from_dict(cls, raw, path, PLANNER_KEYS, "a planner name such as 'fisher'")


def specs_from_list(raw: Any, key: str, spec_type: Any) -> tuple[Any, ...]:
    """The ``[[key]]`` tables (or bare names) of an experiment file as ``spec_type`` entries."""
    if isinstance(raw, str | Mapping) or not isinstance(raw, Sequence):
        raise ValueError(f"{key}: expected a list of [[{key}]] tables or names")
    return tuple(spec_type.from_dict(entry, path=f"{key}[{i}]") for i, entry in enumerate(raw))


def built_specs(
    specs: Sequence[Any], key: str, spec_type: type, find_class: Any
) -> Iterator[tuple[str, Any, Any]]:
    """Check a list of estimator or planner specs; yield ``(key path, spec, built object)``.

    Each entry must be a ``spec_type`` with a label unique in the list, a name that
    ``find_class`` resolves, and options its class accepts; errors name the key path.
    """
    labels: dict[str, int] = {}
    for index, spec in enumerate(specs):
        path = f"{key}[{index}]"
        if not isinstance(spec, spec_type):
            raise ValueError(f"{path}: expected a {spec_type.__name__}, got {type(spec).__name__}")
        if spec.label in labels:
            raise ValueError(
                f"{path}.label: duplicate label {spec.label!r} (also "
                f"{key}[{labels[spec.label]}]); give each entry a distinct label"
            )
        labels[spec.label] = index
        try:
            find_class(spec.name)
        except ValueError as error:
            raise ValueError(f"{path}.name: {error}") from None
        try:
            built = spec.build()
        except ValueError as error:
            raise ValueError(f"{path}.options: {error}") from None
        yield path, spec, built
