"""Finding estimators by name: built-ins, ``module:Class`` paths and entry points.

Built-ins are listed explicitly (as cvxpy's solver map) and imported lazily, so that listing
them never imports an optional back-end. Third-party packages register classes under the
entry-point group ``emitterbench.estimators``::

    [project.entry-points."emitterbench.estimators"]
    my-method = "my_package.module:MyEstimator"

and anywhere an estimator name is accepted, ``package.module:Class`` works too.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import warnings
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

from estimators.base import Estimator, protocol_problems

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
        return tuple(getattr(_load(self.target), "required_modules", ()))

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
            "estimators.cls:Cls",
            "corrected closed-form Doppler-ToA CLS, weighted (MATH §3-§6)",
        ),
        RegistryEntry(
            "cls-paper", "estimators.cls:ClsPaper", "paper's unweighted CLS with errata fixed"
        ),
        RegistryEntry(
            "cls-as-printed",
            "estimators.cls:ClsAsPrinted",
            "paper's CLS as printed (wrong: no height term)",
        ),
        RegistryEntry(
            "lls-toa", "estimators.lls:LlsToa", "conventional linear LS on squared ranges (MATH §9)"
        ),
        RegistryEntry(
            "lls-rss", "estimators.lls:LlsRss", "So & Lin linear LS on RSS distances (MATH §9)"
        ),
        RegistryEntry(
            "sdp-cls",
            "estimators.sdp_cls:SdpCls",
            "Shor SDP relaxation of the CLS, cvxpy + Clarabel (MATH §11)",
        ),
        RegistryEntry(
            "ekf",
            "estimators.ekf:Ekf",
            "iterated EKF (or UKF) over frames, one filter per mirror hypothesis (MATH §7-§8)",
        ),
        RegistryEntry(
            "gtsam-smoother",
            "estimators.gtsam_smoother:GtsamSmoother",
            "GTSAM factor-graph smoother: LM in batch, ISAM2 streaming, mirror hypotheses",
        ),
        RegistryEntry(
            "ml",
            "estimators.ml:MaximumLikelihood",
            "maximum likelihood, Gauss-Newton from the CLS candidates (MATH §10)",
        ),
    )
}


def _load(target: str) -> Any:
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"estimator: {target!r} is not of the form 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # a plug-in may fail in any way on import: report, don't crash
        raise ValueError(
            f"estimator: cannot import {module_name!r} ({type(error).__name__}: {error})"
        ) from None
    try:
        return getattr(module, attribute)
    except AttributeError:
        raise ValueError(f"estimator: module {module_name!r} has no {attribute!r}") from None


def plugin_entries() -> dict[str, RegistryEntry]:
    """Estimators registered by installed packages under ``emitterbench.estimators``."""
    found = {}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        found[point.name] = RegistryEntry(point.name, point.value, f"plug-in from {point.value}")
    return found


def all_entries() -> dict[str, RegistryEntry]:
    """Built-ins first, then plug-ins (a plug-in cannot shadow a built-in: it is warned of)."""
    entries = dict(plugin_entries())
    for name in sorted(set(entries) & set(BUILTIN)):
        warnings.warn(
            f"estimator: plug-in {entries[name].target!r} is registered as {name!r}, the name of "
            "a built-in, and is ignored; register it under another name",
            stacklevel=2,
        )
    entries.update(BUILTIN)
    return dict(sorted(entries.items(), key=lambda item: (item[0] not in BUILTIN, item[0])))


def estimator_class(name: str) -> type:
    """The class registered as ``name``, or the class at ``module:Class``."""
    if ":" in name:
        return _load(name)
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
    return _load(entry.target)


def make_estimator(name: str, **options: Any) -> Estimator:
    """Construct the estimator ``name`` with keyword ``options``; errors name the option."""
    cls = estimator_class(name)
    accepted = sorted(inspect.signature(cls).parameters)
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise ValueError(
            f"{unknown[0]}: not an option of estimator {name!r}; "
            f"its options: {', '.join(accepted) or 'none'}"
        )
    try:
        estimator = cls(**options)
    except TypeError as error:
        raise ValueError(
            f"options: estimator {name!r} rejected {sorted(options)} ({error})"
        ) from None
    problems = protocol_problems(estimator)
    if problems or not isinstance(estimator, Estimator):
        raise ValueError(
            f"estimator {name!r}: {cls.__name__} lacks the Estimator interface: "
            f"{'; '.join(problems) or 'needs name, requires and estimate(data, *, rng=None)'} "
            "(docs/writing-an-estimator.md)"
        )
    return estimator
