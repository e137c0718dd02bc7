"""The estimator and planner entries of an experiment: name, label, options, built and checked.

An experiment file lists ``[[estimators]]`` and ``[[planners]]`` tables (or bare names);
:class:`EstimatorSpec` and :class:`PlannerSpec` hold one entry each, validated on construction
(every message starts with the key path), and build the object through the registries
(:func:`estimators.registry.make_estimator`, :func:`scenarios.planners.get_planner`).

:func:`built_specs` checks an entry in the order that runs the least code: the name must
resolve to a class with the estimator (or planner) interface, found without calling anything
of it, then the options must fit the constructor's signature and simple annotations
(:func:`scenarios.plugins.check_options`); only then is the class built. Errors
name ``estimators[i].name`` or ``estimators[i].options.<option>``.
"""

from __future__ import annotations

import importlib.util
import inspect
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from comparison.labels import check_label, visible_label
from estimators.base import Estimator, capabilities_of, unknowns_problem
from estimators.registry import make_estimator
from scenarios import fields
from scenarios.fields import FrozenDict, thaw
from scenarios.nuisance import parse_unknowns
from scenarios.planners import Planner, get_planner

ESTIMATOR_KEYS = ("name", "label", "options", "ignore_unknowns")
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
    fix = "give a shorter one"
    if spec.label is None:
        object.__setattr__(spec, "label", spec.name)
        fix = "give the entry a shorter label (without one, the label is the name)"
    check_label(spec.label, "label", fix=fix)
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
    ignore_unknowns : bool or list of str
        Feed it the data as if the emitter's unknowns were known (MATH §15, §8): the nuisance
        parameters zero, the height that of the take-off ground; ``true`` every one a scenario
        declares, or a list of those to assume (``["emitter_height_m"]``: the height only,
        the others estimated). To show the bias that costs. Without it an estimator that does
        not estimate a scenario's unknowns is refused at load.
    """

    name: str
    label: str | None = None
    options: Mapping[str, Any] = field(default_factory=FrozenDict)
    ignore_unknowns: bool | tuple[str, ...] = False

    def __post_init__(self) -> None:
        _check_spec_fields(self)
        value = self.ignore_unknowns
        if isinstance(value, list | tuple):
            value = parse_unknowns(value, "ignore_unknowns")
            object.__setattr__(self, "ignore_unknowns", value or False)
        elif not isinstance(value, bool):
            raise ValueError(
                "ignore_unknowns: expected true, false or a list of unknowns such as "
                f'["emitter_height_m"], got {value!r}'
            )

    def assumed(self, unknowns: Iterable[str]) -> tuple[str, ...]:
        """Which of a scenario's ``unknowns`` the estimator is fed as known."""
        if self.ignore_unknowns is True:
            return tuple(unknowns)
        return tuple(u for u in unknowns if u in (self.ignore_unknowns or ()))

    def build(self) -> Estimator:
        """A new estimator object (:func:`estimators.registry.make_estimator`)."""
        return make_estimator(self.name, **thaw(self.options, sequence=tuple))

    def to_dict(self) -> dict[str, Any]:
        raw = {"name": self.name, "label": self.label, "options": thaw(self.options)}
        if self.ignore_unknowns:
            value = self.ignore_unknowns
            raw["ignore_unknowns"] = True if value is True else list(value)
        return raw

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any] | str, *, path: str = "estimator") -> EstimatorSpec:
        """From a table ``{name, label?, options?, ignore_unknowns?}`` or a bare name."""
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


def option_error(path: str, message: str, parameters: Sequence[str]) -> str:
    """``message`` of a constructor or option check under ``path.options``.

    A message that starts with the name of a parameter or given option (``side_prior_m: ...``,
    ``modalities[1]: ...``) names that option: ``estimators[0].options.side_prior_m: ...``.
    """
    match = re.match(r"([A-Za-z_]\w*)(?=[:\[])", message)
    if match and match.group(1) in parameters:
        return f"{path}.options.{message}"
    return f"{path}.options: {message}"


def built_specs(
    specs: Sequence[Any], key: str, spec_type: type, find_class: Any
) -> Iterator[tuple[str, Any, Any]]:
    """Check a list of estimator or planner specs; yield ``(key path, spec, built object)``.

    Each entry must be a ``spec_type`` with a label unique in the list, a name that
    ``find_class`` resolves to a checked class (nothing of it called), and options its
    constructor accepts; only then is it built. Errors name the key path.
    """
    labels: dict[str, int] = {}  # by what a reader sees of them (comparison.labels)
    for index, spec in enumerate(specs):
        path = f"{key}[{index}]"
        if not isinstance(spec, spec_type):
            raise ValueError(f"{path}: expected a {spec_type.__name__}, got {type(spec).__name__}")
        seen = visible_label(spec.label)
        if seen in labels:
            other = specs[labels[seen]].label
            same = (
                ""
                if other == spec.label
                else f", read as {other!r}: they differ only in direction controls"
            )
            raise ValueError(
                f"{path}.label: duplicate label {spec.label!r} (also "
                f"{key}[{labels[seen]}]{same}); give each entry a distinct label"
            )
        labels[seen] = index
        kind = f"{key.rstrip('s')}: "  # the registries' own field, named by the path here
        try:
            cls = find_class(spec.name)
        except ValueError as error:
            raise ValueError(f"{path}.name: {str(error).removeprefix(kind)}") from None
        try:
            parameters = [*inspect.signature(cls).parameters, *spec.options]
        except (TypeError, ValueError):
            parameters = list(spec.options)
        try:
            built = spec.build()
        except ValueError as error:
            message = str(error)
            if message.startswith(kind):  # the object built lacks the interface
                raise ValueError(f"{path}.name: {message.removeprefix(kind)}") from None
            raise ValueError(option_error(path, message, parameters)) from None
        yield path, spec, built


def check_estimator_fits(
    path: str, spec: EstimatorSpec, estimator: Any, scenarios: Mapping[str, Any]
) -> None:
    """Raise ``ValueError`` (naming ``path``) unless the estimator can run on every scenario:
    its modules installed, the modalities it uses simulated, and every nuisance parameter a
    scenario declares unknown (MATH §15) estimated, or ``ignore_unknowns`` set."""
    capabilities = capabilities_of(estimator)
    absent = [m for m in capabilities.modules if importlib.util.find_spec(m) is None]
    if absent:
        raise ValueError(
            f"{path}: {spec.label!r} needs the module(s) {', '.join(absent)}, which "
            "are not installed; install them or drop the estimator"
        )
    hint = "ignore_unknowns = true on the estimator"
    for name, scenario in scenarios.items():
        missing = sorted(capabilities.modalities - set(scenario.modalities))
        if missing:
            raise ValueError(
                f"{path}: {spec.label!r} needs {', '.join(missing)} measurements, "
                f"which scenario {name!r} does not simulate; drop one of the two"
            )
        assumed = spec.assumed(scenario.unknowns)
        unknowns = [u for u in scenario.unknowns if u not in assumed]
        used = capabilities.modalities & set(scenario.modalities)
        problem = unknowns_problem(estimator, unknowns, used, ignore_hint=hint)
        if problem is not None:
            raise ValueError(f"{path}: scenario {name!r}: {problem}")
