"""Finding estimators by name: built-ins, ``module:Class`` paths and entry points.

Built-ins are listed explicitly (as cvxpy's solver map) and imported lazily, so that listing
them never imports an optional back-end. Third-party packages register classes under the
entry-point group ``emitterbench.estimators``::

    [project.entry-points."emitterbench.estimators"]
    my-method = "my_package.module:MyEstimator"

and anywhere an estimator name is accepted, ``package.module:Class`` works too.

A ``package.module:Class`` path or an entry point is resolved by importing its module, which
runs the module's code (that is why an experiment file is code, docs/writing-an-experiment.md).
What it names is then used only if it is a class with the estimator interface
(:func:`estimator_class_problems`, read without calling anything of it), and its options are
checked against the constructor (:func:`scenarios.plugins.check_options`) before it
is built: ``os:system`` or ``builtins:eval`` are refused, never called.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import inspect
import os
import sys
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

from estimators.interface import Estimator, capabilities_of, protocol_problems
from scenarios.plugins import check_options, checked_class, import_target, method_takes
from scenarios.types import MODALITIES

ENTRY_POINT_GROUP = "emitterbench.estimators"


@dataclass(frozen=True)
class RegistryEntry:
    """A registered estimator: its name, ``module:Class`` target and a one-line summary.

    What it needs to run is declared on the class (``required_modules``, read without
    constructing it: a module that wraps an optional back-end imports it only when used).
    """

    name: str
    target: str  # "module:attribute"
    summary: str

    @property
    def required_modules(self) -> tuple[str, ...]:
        """The class's ``required_modules``, plus the class's own module if it cannot be found."""
        module = self.target.partition(":")[0]
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            return (module,)
        return tuple(inspect.getattr_static(_load(self.target), "required_modules", ()))

    def missing_modules(self) -> list[str]:
        """The required modules that are not installed."""
        missing = []
        for module in self.required_modules:
            try:
                if importlib.util.find_spec(module) is None:
                    missing.append(module)
            except (ImportError, ValueError):
                missing.append(module)
        return missing

    def is_available(self) -> bool:
        return not self.missing_modules()


BUILTIN: dict[str, RegistryEntry] = {
    entry.name: entry
    for entry in (
        RegistryEntry(
            "cls",
            "estimators.closed_form.cls:Cls",
            "corrected closed-form Doppler-ToA CLS, weighted (MATH §3-§6)",
        ),
        RegistryEntry(
            "cls-paper",
            "estimators.closed_form.cls:ClsPaper",
            "paper's unweighted CLS with errata fixed",
        ),
        RegistryEntry(
            "cls-as-printed",
            "estimators.closed_form.cls:ClsAsPrinted",
            "paper's CLS as printed (wrong: no height term)",
        ),
        RegistryEntry(
            "lls-toa",
            "estimators.baselines.lls:LlsToa",
            "conventional linear LS on squared ranges (MATH §9)",
        ),
        RegistryEntry(
            "lls-rss",
            "estimators.baselines.lls:LlsRss",
            "So & Lin linear LS on RSS distances (MATH §9)",
        ),
        RegistryEntry(
            "sdp-cls",
            "estimators.sdp.sdp_cls:SdpCls",
            "Shor SDP relaxation of the CLS, cvxpy + Clarabel (MATH §11)",
        ),
        RegistryEntry(
            "ekf",
            "estimators.sequential.ekf:Ekf",
            "iterated EKF (or UKF) over frames, one filter per mirror hypothesis (MATH §7-§8)",
        ),
        RegistryEntry(
            "gtsam-smoother",
            "estimators.sequential.gtsam_smoother:GtsamSmoother",
            "GTSAM factor-graph smoother: LM in batch, ISAM2 streaming, mirror hypotheses",
        ),
        RegistryEntry(
            "ml",
            "estimators.ml.ml:MaximumLikelihood",
            "maximum likelihood, Gauss-Newton from the CLS candidates (MATH §10)",
        ),
    )
}


SAMPLE_LEVEL: dict[str, RegistryEntry] = {
    entry.name: entry
    for entry in (
        RegistryEntry(
            "dpd",
            "estimators.dpd:DirectPosition",
            "direct position determination from the received samples (MATH §22; "
            "[signal] experiments and recordings)",
        ),
    )
}
"""Estimators of the received samples, not of measurements (:func:`reads_samples`): they run
in experiments with a ``[signal]`` table and on recordings, and are not in :data:`BUILTIN`
(whose estimators all read measurement sets)."""


def reads_samples(estimator: Any) -> bool:
    """True for an estimator of the received samples: it has
    ``estimate_iq_batch(geometry, plan, samples, schedule_s)`` (docs/math.md §22)."""
    return callable(getattr(estimator, "estimate_iq_batch", None))


ESTIMATOR_INTERFACE = (
    "a class with the class attributes name and requires and estimate(data, *, rng=None) "
    "(docs/writing-an-estimator.md)"
)


def _load(target: str) -> Any:
    """What ``module:attribute`` names (the module is imported), not yet checked."""
    return import_target(target, "estimator")


def estimator_class_problems(cls: type) -> list[str]:
    """What a class lacks to be an estimator (empty: nothing), read without calling any of it.

    The class level of :func:`estimators.base.protocol_problems`: ``name`` a non-empty string,
    ``requires`` a set of modalities, ``estimate`` a method taking the keyword ``rng``.
    """
    problems = []
    name = inspect.getattr_static(cls, "name", None)
    if not isinstance(name, str) or not name:
        problems.append("the class attribute name must be a non-empty string")
    requires = inspect.getattr_static(cls, "requires", None)
    if not isinstance(requires, frozenset | set) or not requires <= set(MODALITIES):
        problems.append(
            f"the class attribute requires must be a frozenset of {', '.join(MODALITIES)}"
        )
    return problems + method_takes(cls, "estimate", ("rng",))


def plugin_entries() -> dict[str, RegistryEntry]:
    """Estimators registered by installed packages under ``emitterbench.estimators``.

    Read once for each state of the search path (its folders and their modification times),
    so that a package installed meanwhile is found: reading every installed package's
    metadata takes some 5 ms, and a run asks for each estimator of its experiment several
    times."""
    folders = []
    for folder in sys.path:
        try:
            folders.append((folder, os.stat(folder or ".").st_mtime_ns))
        except OSError:
            folders.append((folder, None))
    return dict(_plugin_entries_on(tuple(folders)))


@functools.lru_cache(maxsize=4)
def _plugin_entries_on(
    search_path: tuple[tuple[str, int | None], ...],
) -> tuple[tuple[str, RegistryEntry], ...]:
    """:func:`plugin_entries` for this state of the search path (the cache's key)."""
    found = {}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        found[point.name] = RegistryEntry(point.name, point.value, f"plug-in from {point.value}")
    return tuple(found.items())


def all_entries() -> dict[str, RegistryEntry]:
    """Built-ins first, then plug-ins (a plug-in cannot shadow a built-in: it is warned of)."""
    entries = dict(plugin_entries())
    for name in sorted(set(entries) & (BUILTIN.keys() | SAMPLE_LEVEL.keys())):
        warnings.warn(
            f"estimator: plug-in {entries[name].target!r} is registered as {name!r}, the name of "
            "a built-in, and is ignored; register it under another name",
            stacklevel=2,
        )
    entries.update(BUILTIN)
    entries.update(SAMPLE_LEVEL)
    built_in = BUILTIN.keys() | SAMPLE_LEVEL.keys()
    return dict(sorted(entries.items(), key=lambda item: (item[0] not in built_in, item[0])))


def estimator_class(name: str) -> type:
    """The class registered as ``name``, or the class at ``module:Class``, checked.

    Raises ``ValueError`` (one line, starting ``estimator:``) for an unknown name, a module
    that does not import, or anything but a class with the estimator interface.
    """
    if ":" in name:
        return checked_class(
            name, _load(name), "estimator", estimator_class_problems, ESTIMATOR_INTERFACE
        )
    entries = all_entries()
    if name not in entries:
        known = ", ".join(entries)
        raise ValueError(
            f"estimator: unknown name {name!r}; known estimators: {known} "
            "(or give 'package.module:Class')"
        )
    entry = entries[name]
    missing = entry.missing_modules()
    if missing:
        raise ValueError(f"estimator: {name!r} needs {', '.join(missing)}, which is not installed")
    return checked_class(
        name, _load(entry.target), "estimator", estimator_class_problems, ESTIMATOR_INTERFACE
    )


def estimators_handling(unknowns: Iterable[str]) -> list[str]:
    """The installed built-in estimators whose default options estimate every nuisance
    parameter in ``unknowns`` (MATH §15), by name: what to suggest when one does not."""
    wanted = set(unknowns)
    able = []
    for name, entry in BUILTIN.items():
        if not entry.is_available():
            continue
        if wanted <= capabilities_of(make_estimator(name)).unknowns:
            able.append(name)
    return able


def make_estimator(name: str, **options: Any) -> Estimator:
    """Construct the estimator ``name`` with keyword ``options``; errors name the option.

    The class is checked first (:func:`estimator_class`), then the options against its
    constructor (:func:`scenarios.plugins.check_options`), and only then is it built.
    """
    cls = estimator_class(name)
    check_options(cls, options, f"estimator {name!r}")
    try:
        estimator = cls(**options)
    except ValueError:
        raise  # the constructor's own check, naming the option
    except Exception as error:  # a plug-in may fail in any way: one line, not a traceback
        raise ValueError(
            f"options: estimator {name!r} rejected {sorted(options)} "
            f"({type(error).__name__}: {error})"
        ) from None
    problems = protocol_problems(estimator)
    if problems or not isinstance(estimator, Estimator):
        raise ValueError(
            f"estimator: {name!r} built a {cls.__name__} that lacks the estimator interface: "
            f"{'; '.join(problems) or 'needs name, requires and estimate(data, *, rng=None)'} "
            "(docs/writing-an-estimator.md)"
        )
    return estimator
