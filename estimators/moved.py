"""Module paths from before the estimators were grouped into a folder per family.

Every estimator module used to sit directly in ``estimators/``; plug-ins and notebooks written
then import, for example, ``estimators.cls_rows`` or ``estimators.ekf``. Those paths
keep working: importing one gives the module at its new home (the same module object, so
``isinstance`` and patches agree) and a :class:`DeprecationWarning` naming that home.
:data:`MOVED_MODULES` is the whole table; nothing else depends on it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

_ROOMS = {
    "closed_form": (
        "cls",
        "cls_rows",
        "cls_batch",
        "constrained_ls",
        "gtrs",
        "gtrs_batch",
        "gtrs_indefinite",
        "pseudorange_cls",
    ),
    "sdp": ("sdp_cls", "sdp_lift", "sdp_solvers"),
    "ml": (
        "ml",
        "ml_batch",
        "ml_batch_audit",
        "ml_batch_starts",
        "ml_residuals",
        "ml_starts",
        "minpack_batch",
    ),
    "baselines": ("lls",),
    "sequential": (
        "ekf",
        "gtsam_smoother",
        "smoother_batch",
        "smoother_graph",
        "smoother_hypotheses",
        "smoother_nuisance",
        "nuisance_graph",
        "nuisance_starts",
        "nuisance_states",
        "mirror_hypotheses",
    ),
}

MOVED_MODULES: dict[str, str] = {
    f"estimators.{name}": f"estimators.{room}.{name}"
    for room, names in _ROOMS.items()
    for name in names
    if name != room
}
"""Old module path → the module's home now. ``estimators.ml`` is now the ML family's folder,
whose ``__init__`` exports what the old module did for plug-ins (``MaximumLikelihood``)."""


class _MovedModuleLoader(importlib.abc.Loader):
    """Hands out the module at its new home under its old name."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        home = MOVED_MODULES[spec.name]
        warnings.warn(
            f"{spec.name} moved to {home}; import it from there",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.import_module(home)

    def exec_module(self, module: ModuleType) -> None:
        """The module at its new home is already executed."""


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Finds the modules of :data:`MOVED_MODULES` under their old paths."""

    def find_spec(self, fullname, path, target=None):
        if fullname not in MOVED_MODULES:
            return None
        return importlib.machinery.ModuleSpec(fullname, _MovedModuleLoader())


def install() -> None:
    """Put the finder on ``sys.meta_path`` once (idempotent)."""
    if not any(isinstance(finder, MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(MovedModuleFinder())
