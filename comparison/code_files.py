"""Which code a run runs: every code file of emitterbench and of the plug-ins an experiment
names, with their SHA-256 digests, and the versions of the packages it uses.

A run records them per session in ``run.json`` (:func:`comparison.run_folder.session_info`)
so that a resume with other code than the rows already stored is refused, naming the files
(:func:`comparison.run_folder.check_code_change`). They are found from the experiment's names
and the import system's finders alone: nothing the experiment names is imported or run.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import platform
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path

from comparison.experiment import Experiment


def package_versions() -> dict[str, str | None]:
    """The versions of Python and of the packages whose code a run may run (None: absent)."""
    names = (
        "emitterbench",
        "numpy",
        "scipy",
        "cvxpy",
        "clarabel",
        "gtsam",
        "filterpy",
        "joblib",
        "pandas",
        "rich",
        "dask",
        "distributed",
    )
    found: dict[str, str | None] = {"python": platform.python_version()}
    for name in names:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


OWN_PACKAGES = ("scenarios", "estimators", "comparison")
"""emitterbench's own packages, whose every source file the code digest covers."""
CODE_SUFFIXES = (*importlib.machinery.SOURCE_SUFFIXES, *importlib.machinery.EXTENSION_SUFFIXES)
"""The files of a package that are code (sources and compiled extension modules)."""


def plugin_modules(experiment: Experiment) -> list[str]:
    """The top-level modules (or packages) of the plug-ins ``experiment`` names: the module of
    every ``package.module:Class`` estimator or planner and of every estimator registered by
    an installed package (entry point), emitterbench's own packages left out.

    Read from the names and the installed packages' metadata only: nothing is imported.
    """
    from estimators.registry import BUILTIN, plugin_entries

    targets = [spec.name for spec in (*experiment.estimators, *experiment.planners)]
    registered = [spec.name for spec in experiment.estimators if ":" not in spec.name]
    if any(name not in BUILTIN for name in registered):
        entries = plugin_entries()
        targets += [entries[n].target for n in registered if n in entries and n not in BUILTIN]
    tops = {t.partition(":")[0].strip().partition(".")[0] for t in targets if ":" in t}
    return sorted(tops - {"", *OWN_PACKAGES})


def _module_files(top: str) -> dict[str, Path]:
    """The code files of the top-level module or package ``top``, keyed ``top/path.py``, found
    without importing anything (a top-level name's spec is found by the import system's
    finders alone; a submodule's would import its parent package)."""
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        return {}
    files = {}
    for location in spec.submodule_search_locations or ():
        folder = Path(location)
        for path in sorted(folder.rglob("*")):
            if path.name.endswith(CODE_SUFFIXES) and path.is_file():
                files[f"{top}/{path.relative_to(folder).as_posix()}"] = path
    if spec.submodule_search_locations is None and spec.has_location and spec.origin:
        path = Path(spec.origin)
        if path.is_file():
            files[path.name] = path
    return files


def code_files(experiment: Experiment) -> dict[str, str]:
    """SHA-256 of every code file that a run of ``experiment`` runs: the sources of
    ``scenarios``, ``estimators`` and ``comparison``, and all the code files of the package
    (or the module, if it is not in a package) of each plug-in it names
    (:func:`plugin_modules`), keyed by path from the package's parent (``comparison/cli.py``,
    ``my_plugin/fast.py``), in order.

    Nothing is imported or run to find them. Recorded per session in ``run.json``
    (``code_files``) so that a resume tells which files changed (:func:`comparison.run_folder.check_code_change`).
    """
    found: dict[str, Path] = {}
    for package in OWN_PACKAGES:
        found.update(_module_files(package))
    for top in plugin_modules(experiment):
        found.update(_module_files(top))
    return {key: hashlib.sha256(found[key].read_bytes()).hexdigest() for key in sorted(found)}


def code_digest(files: Mapping[str, str]) -> str:
    """One SHA-256 of the code files ``files`` (:func:`code_files`): names and digests."""
    digest = hashlib.sha256()
    for name, file_digest in sorted(files.items()):
        digest.update(f"{name}\n{file_digest}\n".encode())
    return digest.hexdigest()
