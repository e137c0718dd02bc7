"""The run folder: its rules, its lock, safe writes, ``experiment.json`` and ``run.json``.

A run folder ``DIR`` holds ``experiment.json`` (the experiment, exact), ``run.json``
(versions, a digest of the code and of each of its files, machine, seed, start and end times,
workers; one entry per session in ``sessions``) and ``results.sqlite`` (:mod:`comparison.store`),
then the report's files. A new run needs an absent or empty folder; a resumed one the same
experiment (except ``trials``, which may grow) and the same code: emitterbench's own and every
plug-in the experiment names (:func:`comparison.code_files.code_files`), unless told to accept the change
(:func:`check_code_change`).

Three rules keep a folder sound:

- every file is written whole or not at all (:func:`atomic_file`: a temporary file beside it,
  fsync, ``os.replace``), and never through a symbolic link: a link where a run or a report
  would write is refused, its target left alone (the run folder itself may be a link);
- one session at a time: :func:`folder_session` holds an exclusive ``flock`` on
  ``DIR/.emitterbench.lock`` for the session's lifetime (the operating system releases it if
  the process dies), and so does a report while it writes (:func:`report_lock`; a run writes
  its own report before it lets go), so a second ``run --resume`` into the folder is refused,
  a report while a run writes too, and a run while a report writes;
- a session that fails before it stored a row leaves the folder as it found it
  (:func:`folder_session`): the engine works out everything that can fail from the experiment
  alone before it enters the folder.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import secrets
import socket
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, TypeVar

from comparison.code_files import code_digest, code_files, package_versions
from comparison.experiment import Experiment

try:
    import fcntl
except ImportError:  # Windows: no flock; a session records itself but does not exclude others
    fcntl = None  # type: ignore[assignment]

EXPERIMENT_FILE = "experiment.json"
RUN_FILE = "run.json"
RESULTS_FILE = "results.sqlite"
LOCK_FILE = ".emitterbench.lock"
"""Held (``flock``) by the session writing the folder; removed when it ends."""
SQLITE_COMPANIONS = ("-wal", "-shm", "-journal")
"""Files SQLite keeps beside ``results.sqlite`` (suffixes of its name)."""
T = TypeVar("T")
_SAFE_OPEN = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
"""Open flags: never through a link at the last component, never inherited by a program."""
REPORT_FILES = ("summary.csv", "thresholds.csv", "trials.csv", "flights.csv", "report.html")
"""The files a report writes beside the run's own (and ``figures/``)."""


def now_utc() -> str:
    """The time now, ISO 8601 in UTC to the millisecond."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


# --------------------------------------------------------------------------------------------
# writing files: whole or not at all, never through a link
# --------------------------------------------------------------------------------------------


def refuse_symlink(path: Path) -> None:
    """Raise when ``path`` is a symbolic link (what would be written is its target)."""
    if path.is_symlink():
        raise ValueError(
            f"{path.name}: {path} is a symbolic link; emitterbench writes only real files in "
            "a run folder, so remove the link (its target is left as it is) and retry"
        )


def sqlite_paths(database: Path) -> tuple[Path, ...]:
    """``results.sqlite`` and the files SQLite keeps beside it."""
    return (database, *(database.with_name(database.name + s) for s in SQLITE_COMPANIONS))


def _cannot_write(path: Path, error: OSError) -> ValueError:
    return ValueError(
        f"{path.name}: cannot write {path} ({error.strerror or error}); check that the folder "
        "exists, is writable and has free space"
    )


@contextmanager
def atomic_file(path: str | os.PathLike[str], *, binary: bool = False) -> Iterator[IO[Any]]:
    """A file handle whose content replaces ``path`` when the block ends without an error.

    The content goes to a new temporary file in ``path``'s folder, is flushed to disk
    (``fsync``) and renamed over ``path`` (``os.replace``): a reader or a crash sees the old
    file or the new one, never a part. ``path`` keeps its permissions; a new file gets the
    default ones. Text is UTF-8, lines as written.

    Raises
    ------
    ValueError
        ``path`` is a symbolic link (its target is not touched), or the file cannot be
        written (the message names the file; nothing is left behind).
    """
    target = Path(path)
    refuse_symlink(target)
    try:
        mode = target.stat().st_mode & 0o7777 if target.exists() else None
        while True:
            temporary = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
            try:
                flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | _SAFE_OPEN
                descriptor = os.open(temporary, flags, 0o666)
                break
            except FileExistsError:
                continue
    except OSError as error:
        raise _cannot_write(target, error) from None
    try:
        if mode is not None:
            os.chmod(temporary, mode)
        options = {} if binary else {"encoding": "utf-8", "newline": ""}
        with os.fdopen(descriptor, "wb" if binary else "w", **options) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        refuse_symlink(target)  # again, just before the swap
        os.replace(temporary, target)
    except BaseException as error:
        temporary.unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise _cannot_write(target, error) from None
        raise
    _sync_folder(target.parent)


def _sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every file system allows it)."""
    with suppress(OSError):
        descriptor = os.open(folder, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def write_atomic(
    path: str | os.PathLike[str], content: str | bytes | Callable[[IO[str]], Any]
) -> None:
    """Write ``content`` (text, bytes, or a function that writes to a text handle) to ``path``
    through :func:`atomic_file`."""
    with atomic_file(path, binary=isinstance(content, bytes)) as handle:
        if callable(content):
            content(handle)
        else:
            handle.write(content)


def write_csv(path: str | os.PathLike[str], frame: Any) -> None:
    """A pandas frame as CSV without its index, through :func:`atomic_file`; or frames of the
    same columns, one after another under one header (a table read a chunk at a time).

    No cell can run as a spreadsheet formula (:mod:`comparison.csv_cells`, OWASP): a text cell
    beginning with ``=``, ``+``, ``-`` (not a number), ``@``, tab, CR or LF gets a leading
    ``'``, every text cell is double-quoted, numbers are written bare and unchanged.
    :func:`comparison.csv_cells.original_text` gives a cell's text back.
    """
    from comparison.csv_cells import QUOTING, csv_text, neutralised_frame

    frames = [frame] if hasattr(frame, "to_csv") else frame

    def write(handle: IO[str]) -> None:
        for index, part in enumerate(frames):
            text = csv_text(part, header=index == 0)
            if text is None:  # a type csv_text leaves to pandas
                safe = neutralised_frame(part)
                safe.to_csv(handle, index=False, header=index == 0, quoting=QUOTING)
            else:
                handle.write(text)

    write_atomic(path, write)


# --------------------------------------------------------------------------------------------
# the lock: one session at a time
# --------------------------------------------------------------------------------------------


def _holder_text(descriptor: int) -> tuple[str, str]:
    """What holds a lock file, ``("run" or "report", "pid N on HOST, started T")``, from its
    content (``"pid unknown"`` if unreadable; a lock written by an older version is a run's)."""
    try:
        holder = json.loads(os.pread(descriptor, 4096, 0).decode())
        text = f"pid {int(holder['pid'])} on {holder['host']}, started {holder['started_utc']}"
        return ("report" if holder.get("command") == "report" else "run"), text
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "run", "pid unknown"


_HELD_HERE: dict[tuple[int, int], tuple[int, int]] = {}
"""The run folders whose lock a thread of this process holds: ``(st_dev, st_ino)`` of the
folder → (process id, thread id) (a forked child inherits the dict, not the lock)."""


def _folder_key(out: Path) -> tuple[int, int] | None:
    try:
        status = os.stat(out)
    except OSError:
        return None
    return status.st_dev, status.st_ino


def _holder_here() -> tuple[int, int]:
    return os.getpid(), threading.get_ident()


def _held_here(out: Path) -> bool:
    """Whether this thread holds the lock of ``out`` (a run writing its own report)."""
    key = _folder_key(out)
    return key is not None and _HELD_HERE.get(key) == _holder_here()


def _busy(out: Path, field: str, command: str, descriptor: int) -> ValueError:
    """The one line for a folder whose lock another process holds."""
    kind, holder = _holder_text(descriptor)
    if command == "report":
        fix = "wait for it to finish, then write the report"
    elif kind == "run":
        fix = "wait for it to finish, or stop it and rerun with resume=True"
    else:
        fix = "wait for it to finish, then run again"
    return ValueError(f"{field}: {out} is in use by another emitterbench {kind} ({holder}); {fix}")


@contextmanager
def folder_lock(out: Path, *, command: str = "run") -> Iterator[None]:
    """Hold the exclusive lock of the run folder ``out`` (which must exist) for the block.

    ``command`` (``"run"`` or ``"report"``) is recorded in the lock file with this process's
    id, host and start time, for the message another process gets.

    Raises
    ------
    ValueError
        Another process holds it: a run, a resume or a report is writing the folder (the
        message names it; its field is ``out_dir`` for a run, ``run_dir`` for a report).
    """
    field = "run_dir" if command == "report" else "out_dir"
    path = out / LOCK_FILE
    refuse_symlink(path)
    while True:
        try:
            flags = os.O_RDWR | os.O_CREAT | _SAFE_OPEN
            descriptor = os.open(path, flags, 0o644)
        except OSError as error:
            raise _cannot_write(path, error) from None
        try:
            if fcntl is not None:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            busy = _busy(out, field, command, descriptor)
            os.close(descriptor)
            raise busy from None
        except OSError as error:  # a file system without locks
            os.close(descriptor)
            raise ValueError(
                f"{field}: cannot lock {out} ({error.strerror or error}), so a second run "
                "could write it at the same time; choose a folder on a local disk"
            ) from None
        except BaseException:
            os.close(descriptor)
            raise
        try:  # the lock file may have been removed and made again between open and flock
            same = os.path.samestat(os.fstat(descriptor), os.stat(path, follow_symlinks=False))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(descriptor)
    key = _folder_key(out)
    try:
        holder = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started_utc": now_utc(),
            "command": command,
        }
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, json.dumps(holder).encode(), 0)
        if key is not None:
            _HELD_HERE[key] = _holder_here()
        yield
    finally:
        if key is not None:
            _HELD_HERE.pop(key, None)
        with suppress(OSError):
            path.unlink()  # before the lock goes: a newcomer re-checks the file it locked
        os.close(descriptor)


def running_session(out: Path) -> str | None:
    """``pid N on HOST, started T`` of the session (a run or a report) writing ``out`` now,
    or None."""
    if fcntl is None:
        return None
    try:
        descriptor = os.open(out / LOCK_FILE, os.O_RDONLY | _SAFE_OPEN)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder_text(descriptor)[1]
        fcntl.flock(descriptor, fcntl.LOCK_UN)
        return None
    finally:
        os.close(descriptor)


@contextmanager
def report_lock(run_dir: Path) -> Iterator[None]:
    """Hold ``run_dir``'s lock (:func:`folder_lock`) while a report writes it, so that a run
    cannot add rows between the report's reading and its last file; a run that writes its
    own report holds it already (in this thread), and keeps it. None of the files the report
    writes may be a symbolic link.

    Raises
    ------
    ValueError
        ``run_dir`` is not a folder; another process (a run or a report) is writing it; a
        report's file is a link.
    """
    if not run_dir.is_dir():
        raise ValueError(
            f"run_dir: {run_dir} is not a folder; give the folder of a finished run "
            "(the one holding experiment.json)"
        )
    for name in REPORT_FILES:
        refuse_symlink(run_dir / name)
    if _held_here(run_dir):
        yield
        return
    with folder_lock(run_dir, command="report"):
        yield


def holding_report_lock(write: Callable[..., T]) -> Callable[..., T]:
    """``write(run_dir, ...)`` (a report writer) run under :func:`report_lock`."""

    @functools.wraps(write)
    def locked(run_dir: str | os.PathLike[str], *args: Any, **kwargs: Any) -> T:
        with report_lock(Path(run_dir)):
            return write(run_dir, *args, **kwargs)

    return locked


# --------------------------------------------------------------------------------------------
# the folder's rules, and a session in it
# --------------------------------------------------------------------------------------------


def _left_by_a_session(name: str) -> bool:
    """The lock file, or a temporary file of :func:`atomic_file` (a killed session's)."""
    if name == LOCK_FILE:
        return True
    stem, _, token = name.removesuffix(".tmp").rpartition(".")
    return name.startswith(".") and name.endswith(".tmp") and len(token) == 8 and bool(stem)


def _run_files(out: Path) -> tuple[Path, ...]:
    return (out / EXPERIMENT_FILE, out / RUN_FILE, *sqlite_paths(out / RESULTS_FILE))


def check_folder(out: Path, experiment: Experiment, resume: bool) -> bool:
    """Check ``out`` against ``experiment`` and ``resume``, writing nothing; return True when
    it holds no files (a new run).

    Raises
    ------
    ValueError
        ``out`` is a file; it holds files but ``resume`` is false, or no ``experiment.json``;
        the stored experiment differs (or has more trials); a file of the run is a link.
    """
    if out.is_symlink() and not out.exists():
        raise ValueError(
            f"out_dir: {out} is a symbolic link to a missing folder; create its target or "
            "choose another folder"
        )
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} is a file; choose a folder for the run")
    try:
        existing = out.is_dir() and not all(_left_by_a_session(p.name) for p in out.iterdir())
    except OSError as error:
        raise ValueError(f"out_dir: cannot read {out} ({error.strerror or error})") from None
    if existing and not resume:
        raise ValueError(
            f"out_dir: {out} already holds files; pass resume=True to continue that run, or "
            "choose another folder"
        )
    for path in _run_files(out):
        refuse_symlink(path)
    if existing:
        stored_path = out / EXPERIMENT_FILE
        if not stored_path.is_file():
            raise ValueError(
                f"out_dir: {out} holds files but no {EXPERIMENT_FILE}, so it is not a run "
                "folder; choose another folder"
            )
        stored = read_experiment(out)
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
    return not existing


@dataclass
class FolderSession:
    """A session in a run folder (:func:`folder_session`); set ``keep`` once it may have stored
    a row, so that a failure no longer removes its files."""

    fresh: bool
    keep: bool = False


def _make_folder(out: Path) -> list[Path]:
    """Create ``out`` and its missing parents; return the ones created, innermost first."""
    missing = []
    folder = out
    while not folder.exists() and not folder.is_symlink():
        missing.append(folder)
        folder = folder.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(
            f"out_dir: cannot create {out} ({error.strerror or error}); choose a writable folder"
        ) from None
    return missing


@contextmanager
def folder_session(out: Path, experiment: Experiment, resume: bool) -> Iterator[FolderSession]:
    """A session in the run folder ``out``: checked, created if absent, locked.

    The folder is checked (:func:`check_folder`) before it is touched and again under its
    lock (:func:`folder_lock`), held until the block ends. If the block fails in a folder
    that held no files before, and before it set ``keep`` on the yielded
    :class:`FolderSession`, the session's files are removed, and so is the folder if this
    session created it: a failed start leaves no trace.
    """
    check_folder(out, experiment, resume)
    created = _make_folder(out)
    try:
        with folder_lock(out):
            session = FolderSession(fresh=check_folder(out, experiment, resume))
            try:
                yield session
            except BaseException:
                if session.fresh and not session.keep:
                    for path in _run_files(out):
                        with suppress(OSError):
                            path.unlink(missing_ok=True)
                raise
    except BaseException:
        for folder in created:  # only if empty: a kept session's files stay
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def write_experiment(out: Path, experiment: Experiment) -> None:
    """``experiment.json``: the experiment, exact."""
    write_atomic(out / EXPERIMENT_FILE, experiment.to_json())


@functools.lru_cache(maxsize=8)
def _experiment_of(path: str, mtime_ns: int, size: int) -> Experiment:
    """The experiment in the file at ``path``, read and validated once per version of the file
    (a report reads it several times; validating a 10,000-point sweep takes a second)."""
    return Experiment.from_json(Path(path).read_text(encoding="utf-8"))


def read_experiment(out_dir: str | os.PathLike[str]) -> Experiment:
    """The experiment of a run folder (its ``experiment.json``)."""
    path = Path(out_dir) / EXPERIMENT_FILE
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; is {out_dir} a run folder?")
    try:
        stat = path.stat()
        return _experiment_of(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    except (ValueError, OSError) as error:
        detail = " ".join(str(error).split())
        raise ValueError(
            f"{EXPERIMENT_FILE}: {path} is not a readable experiment ({detail}); restore it, "
            "or run the experiment into a new folder"
        ) from None


# --------------------------------------------------------------------------------------------
# run.json
# --------------------------------------------------------------------------------------------


def session_info(
    experiment: Experiment, workers: int, scheduler: str | None, resume: bool
) -> dict[str, Any]:
    """The ``run.json`` entry of this session (finished_utc is filled in at the end)."""
    started = now_utc()
    files = code_files(experiment)
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
        "versions": package_versions(),
        "code_digest": code_digest(files),
        "code_files": files,
    }


def _previous_sessions(out: Path) -> list[dict[str, Any]]:
    """The sessions recorded in ``out``'s ``run.json`` (none if it is absent or unreadable:
    it is a record, rewritten whole by every session)."""
    path = out / RUN_FILE
    try:
        sessions = json.loads(path.read_text(encoding="utf-8")).get("sessions", [])
    except (OSError, ValueError, AttributeError):
        return []
    return [s for s in sessions if isinstance(s, dict)] if isinstance(sessions, list) else []


ACCEPT_CODE_CHANGE = "accept_code_change=True"
"""How a resume is told to go on with changed code (``--accept-code-change`` on the CLI)."""


def changed_code_files(out: Path, files: Mapping[str, str]) -> list[str] | None:
    """The code files that differ (changed, added or gone) between ``files`` and the last
    session recorded in ``out``'s ``run.json`` (none recorded: None, nothing to compare); an
    older ``run.json`` without ``code_files`` gives ``["(files not recorded)"]`` when its
    ``code_digest`` differs."""
    previous = [s for s in _previous_sessions(out) if s.get("code_digest")]
    if not previous:
        return None
    last = previous[-1]
    theirs = last.get("code_files")
    if not isinstance(theirs, Mapping):
        same = last["code_digest"] == code_digest(files)
        return [] if same else ["(files not recorded)"]
    return sorted(k for k in {*files, *theirs} if files.get(k) != theirs.get(k))


def check_code_change(out: Path, session: dict[str, Any], accept: bool) -> None:
    """Refuse to resume the run in ``out`` with code other than the last session's, naming the
    changed files, unless ``accept`` (then the session records them in
    ``code_change_accepted``): its rows would come from another version of the code than
    the rows already stored, whether the change is emitterbench's or a plug-in's.

    Raises
    ------
    ValueError
        ``resume: the code differs ... (plug-in/file.py, ...)``, with the fix.
    """
    changed = changed_code_files(out, session["code_files"])
    if not changed:
        return
    if accept:
        session["code_change_accepted"] = changed
        return
    shown = ", ".join(changed[:5]) + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
    raise ValueError(
        f"resume: the code differs from the one that wrote the rows already in {out} "
        f"(changed: {shown}; code_files in run.json); the new rows would mix the two "
        f"versions, so run into a new folder, restore those files, or pass "
        f"{ACCEPT_CODE_CHANGE} to resume anyway"
    )


def write_run_info(out: Path, session: dict[str, Any]) -> None:
    """``run.json``: the latest session's fields at the top, every session in ``sessions``."""
    sessions = [s for s in _previous_sessions(out) if s.get("session_id") != session["session_id"]]
    sessions.append(session)
    write_atomic(out / RUN_FILE, json.dumps({**session, "sessions": sessions}, indent=2))
