"""The run folder: its rules, ``experiment.json`` and the provenance in ``run.json``.

A run folder ``DIR`` holds ``experiment.json`` (the experiment, exact), ``run.json``
(versions, a digest of the code, machine, seed, start and end times, workers; one entry per
session in ``sessions``) and ``results.sqlite`` (:mod:`comparison.store`). A new run needs an
absent or empty folder; a resumed one the same experiment (except ``trials``, which may grow),
and it warns when the code differs from the one that wrote the rows already there
(:func:`code_digest`).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import socket
import warnings
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from comparison.experiment import Experiment

EXPERIMENT_FILE = "experiment.json"
RUN_FILE = "run.json"
RESULTS_FILE = "results.sqlite"


def now_utc() -> str:
    """The time now, ISO 8601 in UTC to the millisecond."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _write_text_atomic(path: Path, text: str) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def prepare_folder(out: Path, experiment: Experiment, resume: bool) -> None:
    """Check the folder against ``resume`` and write ``experiment.json``."""
    existing = out.is_dir() and any(out.iterdir())
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} is a file; choose a folder for the run")
    if existing and not resume:
        raise ValueError(
            f"out_dir: {out} already holds files; pass --resume (resume=True) to continue "
            "that run, or choose another folder"
        )
    if existing:
        stored_path = out / EXPERIMENT_FILE
        if not stored_path.is_file():
            raise ValueError(
                f"out_dir: {out} holds files but no {EXPERIMENT_FILE}, so it is not a run "
                "folder; choose another folder"
            )
        stored = Experiment.from_json(stored_path.read_text())
        mine = {k: v for k, v in experiment.to_dict().items() if k != "trials"}
        theirs = {k: v for k, v in stored.to_dict().items() if k != "trials"}
        if mine != theirs:
            differing = sorted(k for k in mine if mine[k] != theirs.get(k))
            raise ValueError(
                f"resume: the experiment differs from {stored_path} in "
                f"{', '.join(differing)}; resume with the same experiment or choose another "
                "folder"
            )
        if experiment.trials < stored.trials:
            raise ValueError(
                f"trials: the run in {out} has {stored.trials} trials per point; resume with "
                f"at least {stored.trials} (more trials extend the run)"
            )
    out.mkdir(parents=True, exist_ok=True)
    _write_text_atomic(out / EXPERIMENT_FILE, experiment.to_json())


def read_experiment(out_dir: str | os.PathLike[str]) -> Experiment:
    """The experiment of a run folder (its ``experiment.json``)."""
    path = Path(out_dir) / EXPERIMENT_FILE
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; is {out_dir} a run folder?")
    return Experiment.from_json(path.read_text())


# --------------------------------------------------------------------------------------------
# run.json
# --------------------------------------------------------------------------------------------


def session_info(
    experiment: Experiment, workers: int, scheduler: str | None, resume: bool
) -> dict[str, Any]:
    """The ``run.json`` entry of this session (finished_utc is filled in at the end)."""
    started = now_utc()
    return {
        "session_id": started,
        "experiment": experiment.name,
        "seed": experiment.seed,
        "trials": experiment.trials,
        "started_utc": started,
        "finished_utc": None,
        "workers": workers if scheduler is None else None,
        "scheduler": scheduler,
        "backend": "dask" if scheduler else ("in-process" if workers == 1 else "loky"),
        "resumed": resume,
        "machine": {
            "hostname": socket.gethostname(),
            "platform": platform.platform(),
            "machine": platform.machine(),
            "cpu_count": os.cpu_count(),
        },
        "versions": _versions(),
        "code_digest": code_digest(),
    }


def _versions() -> dict[str, str | None]:
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


def code_digest() -> str:
    """SHA-256 of the source of ``scenarios``, ``estimators`` and ``comparison`` (with their
    sub-packages).

    Recorded per session in ``run.json``: rows of sessions with different digests may come
    from different code, which a resume warns about.
    """
    import comparison
    import estimators
    import scenarios

    digest = hashlib.sha256()
    for package in (scenarios, estimators, comparison):
        folder = Path(package.__file__).parent
        for path in sorted(folder.rglob("*.py")):
            digest.update(f"{package.__name__}/{path.relative_to(folder).as_posix()}\n".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def warn_on_code_change(out: Path, session: Mapping[str, Any]) -> None:
    """Warn (to the caller of :func:`~comparison.engine.run_experiment`) when a previous
    session of ``out`` ran other code."""
    path = out / RUN_FILE
    if not path.is_file():
        return
    try:
        previous = json.loads(path.read_text()).get("sessions", [])
    except (json.JSONDecodeError, AttributeError):
        return
    digests = {s.get("code_digest") for s in previous if s.get("code_digest")}
    if digests and digests != {session["code_digest"]}:
        warnings.warn(
            f"resume: the code differs from the one that wrote the rows already in {out} "
            "(code_digest in run.json); rows of the two sessions may not be comparable. "
            "Start a new folder to get one consistent run.",
            stacklevel=3,
        )


def write_run_info(out: Path, session: dict[str, Any]) -> None:
    """``run.json``: the latest session's fields at the top, every session in ``sessions``."""
    path = out / RUN_FILE
    sessions: list[dict[str, Any]] = []
    if path.is_file():
        try:
            sessions = list(json.loads(path.read_text()).get("sessions", []))
        except (json.JSONDecodeError, AttributeError):
            sessions = []
    sessions = [s for s in sessions if s.get("session_id") != session["session_id"]]
    sessions.append(session)
    _write_text_atomic(out / RUN_FILE, json.dumps({**session, "sessions": sessions}, indent=2))
