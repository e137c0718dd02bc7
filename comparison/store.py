"""``results.sqlite``: the tables of a run, written by the main process and read back as frames.

Tables, their columns as :mod:`comparison.trial_rows` defines them:

``trials``
    One row per scenario × point × planner × estimator × frame × trial, primary key in that
    order (the planner is empty in an open-loop experiment).
``points``
    Truth and CRLB per scenario × point × frame (MATH §8) of the scenario's own flight: in a
    closed loop that of the ``constant`` planner.
``flights``
    Closed loop only: the velocity and start of every frame flown, per planner and trial.
``tasks``
    Wall time of every task, a log.

The main process writes each task's rows in one SQLite transaction (WAL mode) as the task
finishes (:func:`write_task`), so a run killed at any moment loses at most the tasks in
flight; :func:`complete_trials` tells a resume which trials are done. A file written before
planners, the side-resolved NEES or ``range_scale_m`` existed gets those columns on resume.
:func:`read_trials`, :func:`read_points` and :func:`read_flights` return the tables as tidy
pandas frames with the columns of the contract.

A damaged file (truncated, overwritten, not SQLite at all) is found when it is opened
(:func:`check_store`, SQLite's ``quick_check``) and reported as one line naming
``results.sqlite`` and the way out (:func:`store_errors`); so is any SQLite error later. A
``results.sqlite`` (or its ``-wal``, ``-shm``) that is a symbolic link is refused.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import operator
import os
import sqlite3
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import closing, contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from comparison.bounds import CrlbKey, PointInfo
from comparison.experiment import Experiment
from comparison.run_folder import (
    RESULTS_FILE,
    now_utc,
    read_experiment,
    refuse_symlink,
    sqlite_paths,
)
from comparison.tasks import TaskResult
from comparison.trial_rows import (
    BURST_VALUE_COLUMNS,
    BURSTS,
    FLIGHT_VALUE_COLUMNS,
    FLIGHTS,
    POINTS,
    SCORED_DIMENSION,
    TRIALS,
    Table,
    bound_columns_of,
    coordinate_columns,
    estimate_columns_of,
    matrix_columns,
    padded,
    points_table,
    trials_table,
    with_swept,
)
from scenarios.nuisance import HEIGHT_UNKNOWN

_ADDED_LATER: tuple[tuple[Table, tuple[str, ...]], ...] = (
    (
        TRIALS,
        (
            "planner",
            "planner_index",
            "nees_side_resolved",
            *coordinate_columns("{}_side_resolved_m", SCORED_DIMENSION),
            *matrix_columns("crlb", SCORED_DIMENSION),
            "fit_chi2",
            "fit_dof",
        ),
    ),
    (POINTS, ("range_scale_m",)),
)
"""Columns that files written by earlier versions lack, added when such a run is resumed."""


def _readable(
    connection: sqlite3.Connection, table: Table, names: Sequence[str], alias: str = ""
) -> list[str]:
    """``names`` for a SELECT from ``table`` (prefixed ``alias``, e.g. ``"t."``); a column added
    since the store was written (:data:`_ADDED_LATER`) and absent from it reads as NULL (NaN),
    as when the run is resumed (:func:`create_tables`), so that a run of an earlier version can
    still be reported."""
    present = {row[1] for row in connection.execute(f"PRAGMA table_info({table.name})")}
    later = {name for added, names in _ADDED_LATER if added.name == table.name for name in names}
    return [
        f"NULL AS {_quote(n)}" if n in later and n not in present else f"{alias}{_quote(n)}"
        for n in names
    ]


def _quote(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _names(columns: Sequence[str]) -> str:
    return ", ".join(map(_quote, columns))


# --------------------------------------------------------------------------------------------
# opening: links, damage, errors
# --------------------------------------------------------------------------------------------


_DAMAGED = ("SQLITE_CORRUPT", "SQLITE_NOTADB")
_DAMAGED_TEXT = ("malformed", "not a database", "no such table", "no such column")


def store_error(path: Path, error: sqlite3.Error) -> ValueError | None:
    """The one-line error of a SQLite failure on the store ``path`` (None for a misuse of
    the API, which is a bug to show as it is)."""
    detail = " ".join(str(error).split())[:300] or type(error).__name__
    code = getattr(error, "sqlite_errorname", None) or ""
    if code.startswith(_DAMAGED) or any(sign in detail for sign in _DAMAGED_TEXT):
        return _damaged(path, detail)
    if isinstance(error, sqlite3.OperationalError):  # locked, read-only, disk full, I/O
        return ValueError(
            f"{RESULTS_FILE}: cannot use {path} ({detail}); check that its folder is "
            "writable and has free space and that no other program holds the file, then retry"
        )
    return None


def _damaged(path: Path, detail: str) -> ValueError:
    return ValueError(
        f"{RESULTS_FILE}: {path} is not a readable SQLite database of a run ({detail}); move "
        "it away and rerun the experiment with resume=True (its trials run again), or restore it "
        "from a backup"
    )


@contextmanager
def store_errors(path: Path) -> Iterator[None]:
    """Turn a SQLite error in the block (also as pandas wraps it) into :func:`store_error`."""
    try:
        yield
    except (sqlite3.Error, pd.errors.DatabaseError) as error:
        cause = error.__cause__ if isinstance(error.__cause__, sqlite3.Error) else error
        translated = store_error(path, cause) if isinstance(cause, sqlite3.Error) else None
        if translated is None:
            raise
        raise translated from None


def _refuse_links(path: Path) -> None:
    for each in sqlite_paths(path):
        refuse_symlink(each)


def _signature(path: Path) -> tuple[tuple[int, int], ...]:
    def stat(each: Path) -> tuple[int, int]:
        with suppress(OSError):
            info = each.stat()
            return info.st_size, info.st_mtime_ns
        return -1, -1

    return tuple(stat(each) for each in sqlite_paths(path)[:2])


_SOUND: dict[Path, tuple[tuple[int, int], ...]] = {}
"""Stores found sound by :func:`check_store`, with the sizes and times they had then."""


def _quick_check(connection: sqlite3.Connection, path: Path) -> None:
    with store_errors(path):
        found = [row[0] for row in connection.execute("PRAGMA quick_check")]
    if found != ["ok"]:
        detail = " ".join(" ".join(found[:2]).split())[:300] if found else "no answer"
        raise _damaged(path, f"quick_check: {detail}")


def check_store(path: Path) -> None:
    """Raise the one-line :func:`store_error` unless ``path`` is absent or a sound SQLite
    database (SQLite's ``quick_check``; repeated only when the file has changed)."""
    _refuse_links(path)
    if not path.exists():
        return
    signature = _signature(path)
    if _SOUND.get(path.resolve()) == signature:
        return
    with store_errors(path), closing(_open_existing(path)) as connection:
        _quick_check(connection, path)
    _SOUND[path.resolve()] = signature


def _open_existing(path: Path) -> sqlite3.Connection:
    """A query-only connection to the existing file ``path`` (never creates one)."""
    connection = sqlite3.connect(f"{path.resolve().as_uri()}?mode=rw", uri=True, timeout=60.0)
    connection.execute("PRAGMA query_only=ON")
    return connection


WAL_LIMIT_BYTES = 16 * 2**20
"""Size the write-ahead log (``results.sqlite-wal``) is cut back to after each checkpoint
(SQLite's ``journal_size_limit``); SQLite checkpoints every 1000 pages (4 MB) written, so the
log stays near one task's rows instead of keeping its largest size for the whole run."""


def connect(path: Path) -> sqlite3.Connection:
    """A connection for writing, in WAL mode, the log bounded by :data:`WAL_LIMIT_BYTES` (the
    engine checks the file first, :func:`check_store`)."""
    _refuse_links(path)
    with store_errors(path):
        connection = sqlite3.connect(path, timeout=60.0)
        try:
            connection.execute("PRAGMA journal_mode=WAL")
            connection.execute("PRAGMA synchronous=NORMAL")
            connection.execute(f"PRAGMA journal_size_limit={WAL_LIMIT_BYTES}")
        except BaseException:
            connection.close()
            raise
    return connection


# --------------------------------------------------------------------------------------------
# writing (main process)
# --------------------------------------------------------------------------------------------


def _create(connection: sqlite3.Connection, table: Table, swept: Sequence[str] = ()) -> None:
    columns = ", ".join(f"{_quote(name)} {sql}" for name, sql in table.stored(swept))
    connection.execute(
        f"CREATE TABLE IF NOT EXISTS {table.name} ({columns}, "
        f"PRIMARY KEY ({_names(table.keys())})) WITHOUT ROWID"
    )


def create_tables(
    connection: sqlite3.Connection, experiment: Experiment, dimension: int = SCORED_DIMENSION
) -> None:
    """Create the tables of positions of ``dimension`` coordinates
    (:func:`comparison.bounds.run_dimension`), or add what an older file lacks."""
    with connection:
        _create(connection, trials_table(dimension))
        _create(connection, points_table(dimension), experiment.swept_columns)
        connection.execute(
            "CREATE TABLE IF NOT EXISTS tasks (scenario TEXT, point INTEGER, "
            "first_trial INTEGER, n_trials INTEGER, elapsed_s REAL, finished_utc TEXT)"
        )
        _create(connection, FLIGHTS)
        _create(connection, BURSTS)
        for table, names in _ADDED_LATER:
            present = {row[1] for row in connection.execute(f"PRAGMA table_info({table.name})")}
            types = dict(table.stored())
            for name in names:
                if name not in present:
                    connection.execute(
                        f"ALTER TABLE {table.name} ADD COLUMN {_quote(name)} {types[name]}"
                    )


def _insert(table: Table, columns: Sequence[str], *, replace: bool = False) -> str:
    marks = ", ".join("?" * len(columns))
    verb = "INSERT OR REPLACE" if replace else "INSERT"
    return f"{verb} INTO {table.name} ({_names(columns)}) VALUES ({marks})"


def write_points(
    connection: sqlite3.Connection,
    experiment: Experiment,
    rows: Sequence[Mapping[str, Any]],
    dimension: int = SCORED_DIMENSION,
) -> None:
    """Replace the points table by ``rows`` (:func:`comparison.bounds.point_rows`)."""
    columns = [name for name, _ in points_table(dimension).stored(experiment.swept_columns)]
    values = [tuple(row[c] for c in columns) for row in rows]
    with connection:
        connection.execute(f"DELETE FROM {POINTS.name}")
        connection.executemany(_insert(POINTS, columns), values)


def complete_trials(
    connection: sqlite3.Connection,
    experiment: Experiment,
    infos: Mapping[tuple[int, int], PointInfo],
) -> dict[tuple[int, int], set[int]]:
    """The trials of each (scenario, point) whose rows are all in the database."""
    n_estimators = len(experiment.estimators) * max(len(experiment.planners), 1)
    complete: dict[tuple[int, int], set[int]] = {key: set() for key in infos}
    query = (
        "SELECT scenario_index, point, trial, COUNT(*) FROM trials "
        "GROUP BY scenario_index, point, trial"
    )
    for i, p, trial, count in connection.execute(query):
        info = infos.get((i, p))
        if info is None:
            continue
        frames = info.n_frames if experiment.per_frame else 1
        if count == n_estimators * frames:
            complete[(i, p)].add(trial)
    return complete


_ROW_KEYS = (
    "scenario",
    "point",
    "planner",
    "estimator",
    "frame",
    "trial",
    "scenario_index",
    "planner_index",
    "estimator_index",
)
"""The fields of a trial row that :func:`write_task` takes from the task and the row's keys."""


def write_task(
    connection: sqlite3.Connection,
    experiment: Experiment,
    result: TaskResult,
    info: PointInfo,
    crlb_keys: Sequence[CrlbKey],
    dimension: int = SCORED_DIMENSION,
) -> None:
    """One task's rows, flights and log entry, in one transaction.

    An open-loop row gets the bound of the common flight here (``info``), by the modalities
    and frames of its estimator (``crlb_keys``, in the experiment's order).
    """
    scenario = experiment.scenarios[result.scenario_index]
    labels = experiment.labels
    planners = experiment.planner_labels or ("",)
    bounds: dict[tuple[int, int], tuple[float, ...]] = {}
    table = trials_table(dimension)
    trial_columns = [name for name, _ in table.stored()]
    estimate_names, bound_names = estimate_columns_of(dimension), bound_columns_of(dimension)
    # each row's fields in this order, then picked in the table's order
    fields = (*_ROW_KEYS, *estimate_names, *bound_names)
    pick = operator.itemgetter(*(fields.index(c) for c in trial_columns))
    rows = []
    for row in result.rows:
        bound = row.bound
        if bound is None:  # open loop: the same flight in every trial
            key = (row.estimator_index, row.frame)
            if key not in bounds:
                modalities, frames = crlb_keys[row.estimator_index]
                spec = experiment.estimators[row.estimator_index]
                kept = 2 if HEIGHT_UNKNOWN in spec.assumed(info.scenario.unknowns) else None
                bound = info.bound_columns(modalities, row.frame, frames, kept=kept)
                bounds[key] = padded(bound, bound_names)
            bound = bounds[key]
        if len(row.values) != len(estimate_names):
            raise ValueError(
                f"a row of {len(row.values)} estimate columns, not {len(estimate_names)}"
            )
        keys = (
            scenario,
            result.point,
            planners[row.planner_index],
            labels[row.estimator_index],
            row.frame,
            row.trial,
            result.scenario_index,
            row.planner_index,
            row.estimator_index,
        )
        rows.append(pick((*keys, *row.values, *bound)))
    flight_columns = [name for name, _ in FLIGHTS.stored()]
    flights = []
    for flown in result.flights:
        fields = {
            "scenario": scenario,
            "point": result.point,
            "planner": planners[flown.planner_index],
            "trial": flown.trial,
            "frame": flown.frame,
            "scenario_index": result.scenario_index,
            "planner_index": flown.planner_index,
            **dict(zip(FLIGHT_VALUE_COLUMNS, flown.values, strict=True)),
        }
        flights.append(tuple(fields[c] for c in flight_columns))
    burst_columns = [name for name, _ in BURSTS.stored()]
    bursts = []
    for trial, values in result.bursts:
        fields = {
            "scenario": scenario,
            "point": result.point,
            "trial": trial,
            "scenario_index": result.scenario_index,
            **dict(zip(BURST_VALUE_COLUMNS, values, strict=True)),
        }
        bursts.append(tuple(fields[c] for c in burst_columns))
    with connection:
        connection.executemany(_insert(table, trial_columns, replace=True), rows)
        if flights:
            connection.executemany(_insert(FLIGHTS, flight_columns, replace=True), flights)
        if bursts:
            connection.executemany(_insert(BURSTS, burst_columns, replace=True), bursts)
        connection.execute(
            "INSERT INTO tasks VALUES (?, ?, ?, ?, ?, ?)",
            (
                scenario,
                result.point,
                min(result.trials),
                len(result.trials),
                result.elapsed_s,
                now_utc(),
            ),
        )


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------


@contextmanager
def _reading(out_dir: Path) -> Iterator[sqlite3.Connection]:
    path = out_dir / RESULTS_FILE
    _refuse_links(path)
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; run the experiment first")
    check_store(path)
    # a plain connection (query-only) so that closing it removes the empty WAL files
    with store_errors(path), closing(_open_existing(path)) as connection:
        yield connection


def _order_by(table: Table, alias: str = "") -> str:
    return ", ".join(alias + column for column in table.sort_order())


def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None (another C library, another system)."""
    if not sys.platform.startswith("linux"):
        return None
    with suppress(OSError, AttributeError):
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    return None


_TRIM = _malloc_trim()


def release_freed_memory() -> None:
    """Hand the memory freed so far back to the system (glibc's ``malloc_trim``; nothing
    elsewhere). Rows read in batches free as much as they keep, and glibc would otherwise
    keep the freed blocks between the kept ones: a million trial rows read left twice their
    size resident."""
    if _TRIM is not None:
        _TRIM(0)


TRIAL_BATCH_ROWS = 20_000
"""Rows fetched from SQLite at a time by :func:`iter_trials`: the text of a batch's rows
(messages, diagnostics) is held only while the batch is converted."""

TRIAL_CHUNK_ROWS = 250_000
"""Rows of whole points :func:`iter_trials` yields at a time by default."""

_KEYS = ("scenario", "planner", "estimator")
"""The text keys of a trial row: read into one string object per label, not one per row."""


@dataclass(frozen=True)
class TrialLayout:
    """What a reader of the trial rows needs before the first row (:func:`trial_layout`).

    Attributes
    ----------
    n_rows : int
        Trial rows.
    n_trial_sets : int
        Distinct (scenario, point, frame): the trials every estimator and planner of a point
        saw alike.
    orders : dict
        ``scenario``, ``planner``, ``estimator``: the labels in the experiment's order (the
        order of :func:`read_trials`' rows).
    dimension : int
        The coordinates of the positions the tables hold (:func:`stored_dimension`).
    """

    n_rows: int
    n_trial_sets: int
    orders: dict[str, tuple[str, ...]]
    dimension: int = SCORED_DIMENSION


def count_trials(out_dir: str | os.PathLike[str]) -> int:
    """The trial rows of a run folder."""
    with _reading(Path(out_dir)) as connection:
        (n_rows,) = connection.execute("SELECT COUNT(*) FROM trials").fetchone()
    return int(n_rows)


def trial_layout(out_dir: str | os.PathLike[str]) -> TrialLayout:
    """Count the trial rows and trial sets of a run folder and order its labels."""
    with _reading(Path(out_dir)) as connection:
        (n_rows,) = connection.execute("SELECT COUNT(*) FROM trials").fetchone()
        (n_sets,) = connection.execute(
            "SELECT COUNT(*) FROM (SELECT DISTINCT scenario_index, point, frame FROM trials)"
        ).fetchone()
        orders = {}
        for key in _KEYS:
            index = f"{key}_index"
            query = f"SELECT DISTINCT {index}, {key} FROM trials ORDER BY {index}, {key}"
            labels = [label for _, label in connection.execute(query)]
            orders[key] = tuple(dict.fromkeys(labels))
        dimension = stored_dimension(connection)
    return TrialLayout(int(n_rows), int(n_sets), orders, dimension)


def iter_trials(
    out_dir: str | os.PathLike[str],
    columns: Sequence[str] | None = None,
    *,
    chunk_rows: int = TRIAL_CHUNK_ROWS,
    whole_points: bool = True,
) -> Iterator[pd.DataFrame]:
    """The rows of :func:`read_trials`, in its order and types, a chunk at a time.

    ``columns`` (default: all) picks the columns read, in the contract's order, the swept ones
    always among them; text columns that are not asked for are never fetched. A chunk holds about ``chunk_rows`` rows; with
    ``whole_points`` every (scenario, point) lies in one chunk (a point of more rows is a
    chunk of its own). The labels of a chunk are one string object per label, shared, so a
    chunk of numbers costs its numbers. No rows: one empty frame.
    """
    if int(chunk_rows) != chunk_rows or chunk_rows < 1:
        raise ValueError(f"chunk_rows: must be a whole number >= 1, got {chunk_rows!r}")
    out = Path(out_dir)
    experiment = read_experiment(out)
    swept = list(experiment.swept_columns)
    with _reading(out) as connection:
        dimension = stored_dimension(connection)
    trials, points = trials_table(dimension), points_table(dimension)
    names = list(trials.names(swept))
    wanted = names if columns is None else [c for c in names if c in {*columns, *swept}]
    unknown = sorted(set(columns or ()) - set(names))
    if unknown:
        raise ValueError(f"columns: {unknown} are not trial columns; choose from {names}")
    joined = set(with_swept([c.name for c in trials.columns if c.source == "points"], swept))
    # the point's key always, to cut chunks between points
    fetched = [c for c in names if c in wanted or c in ("scenario", "point")]
    fetched = [c for c in fetched if c != "experiment"]
    on = " AND ".join(f"t.{key} = p.{key}" for key in points.keys())
    kinds = {c: trials.dtypes(swept).get(c) for c in fetched}  # None: text
    labels: dict[str, str] = {}

    def fill(columns: dict[str, np.ndarray], at: int, rows: list[tuple[Any, ...]]) -> None:
        """Copy ``rows`` into ``columns`` from row ``at`` (NULL: NaN; one object per label)."""
        end = at + len(rows)
        for name, values in zip(fetched, zip(*rows, strict=True), strict=True):
            if name in _KEYS:
                values = tuple(labels.setdefault(v, v) for v in values)
            columns[name][at:end] = np.array(values, dtype=kinds[name] or object)

    def frame_of(columns: dict[str, np.ndarray]) -> pd.DataFrame:
        n_rows = len(columns["point"])
        data: dict[str, Any] = {}
        for name in wanted:
            if name == "experiment":
                data[name] = pd.array(np.full(n_rows, experiment.name, dtype=object), dtype="str")
            elif kinds[name] is None:
                data[name] = pd.array(columns.pop(name), dtype="str")
            else:
                data[name] = columns.pop(name)
        return pd.DataFrame(data, copy=False)

    with _reading(out) as connection:
        connection.execute("BEGIN")  # one snapshot for the sizes and the rows
        own = _readable(connection, trials, fetched, "t.")
        selected = ", ".join(
            f"p.{_quote(c)}" if c in joined else column
            for c, column in zip(fetched, own, strict=True)
        )
        query = (
            f"SELECT {selected} FROM trials t JOIN points p ON {on} "
            f"ORDER BY {_order_by(trials, 't.')}"
        )
        if whole_points:  # the chunks' sizes: whole points, chunk_rows or more
            sizes = [0]
            counts = connection.execute(
                f"SELECT COUNT(*) FROM trials t JOIN points p ON {on} "
                "GROUP BY t.scenario_index, t.point ORDER BY t.scenario_index, t.point"
            )
            for (count,) in counts:
                if sizes[-1] >= chunk_rows:
                    sizes.append(0)
                sizes[-1] += int(count)
        else:
            (n_rows,) = connection.execute(
                f"SELECT COUNT(*) FROM trials t JOIN points p ON {on}"
            ).fetchone()
            sizes = [min(int(chunk_rows), n_rows - at) for at in range(0, n_rows, int(chunk_rows))]
            sizes = sizes or [0]
        cursor = connection.execute(query)
        for size in sizes:  # each chunk's columns allocated once and filled a batch at a time
            columns = {name: np.empty(size, dtype=kinds[name] or object) for name in fetched}
            at = 0
            while at < size and (rows := cursor.fetchmany(min(TRIAL_BATCH_ROWS, size - at))):
                fill(columns, at, rows)
                at += len(rows)
                del rows
            release_freed_memory()
            yield frame_of(columns)
            del columns


def read_trials(
    out_dir: str | os.PathLike[str], columns: Sequence[str] | None = None
) -> pd.DataFrame:
    """One row per estimator × scenario × point × frame × trial (the contract's columns,
    :data:`comparison.trial_rows.TRIALS`; ``columns`` picks some, :func:`iter_trials`).

    Sorted by scenario and estimator in the experiment's order, then point, frame and trial
    (``scenario, point, estimator, frame, trial``). NaN marks what a failed estimate or a
    missing covariance cannot give.
    """
    chunks = list(iter_trials(out_dir, columns))
    return pd.concat(chunks, ignore_index=True) if len(chunks) > 1 else chunks[0]


def read_points(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """One row per scenario × point × frame: truth, the accumulated CRLB (MATH §8) and
    ``range_scale_m``, the root mean square slant range of the samples flown so far (the size
    of the geometry a bound is compared with)."""
    out = Path(out_dir)
    experiment = read_experiment(out)
    swept = list(experiment.swept_columns)
    with _reading(out) as connection:
        points = points_table(stored_dimension(connection))
        selected = ", ".join(_readable(connection, points, points.names(swept)))
        query = f"SELECT {selected} FROM points ORDER BY {_order_by(points)}"
        frame = pd.read_sql_query(query, connection)
    frame.insert(0, "experiment", experiment.name)
    return frame.astype(points.dtypes(swept)).reset_index(drop=True)


def stored_dimension(connection: sqlite3.Connection) -> int:
    """The coordinates of the positions a store holds: 3 when its points table has
    ``truth_z_m`` (a run with an emitter of unknown height), else 2."""
    present = {row[1] for row in connection.execute("PRAGMA table_info(points)")}
    return 3 if "truth_z_m" in present else SCORED_DIMENSION


def read_bursts(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """What the front end made of each trial's bursts, one row per scenario × point × trial
    (:data:`comparison.trial_rows.BURSTS`); empty (with those columns) for a run at the
    measurement level."""
    with _reading(Path(out_dir)) as connection:
        tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master")}
        if BURSTS.name not in tables:
            return pd.DataFrame({column: [] for column in BURSTS.names()})
        frame = pd.read_sql_query(
            f"SELECT {_names(BURSTS.names())} FROM bursts ORDER BY {_order_by(BURSTS)}",
            connection,
        )
    return frame.astype(BURSTS.dtypes()).reset_index(drop=True)


def read_flights(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """The frames flown in a closed loop, one row per scenario × point × planner × trial × frame.

    Columns :data:`comparison.trial_rows.FLIGHT_COLUMNS`: the first sample of each frame and
    its velocity, and the message of the plan that chose it. Empty (with those columns) for an
    open-loop run, whose flight is the scenario's own.
    """
    with _reading(Path(out_dir)) as connection:
        tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master")}
        if FLIGHTS.name not in tables:
            return pd.DataFrame({column: [] for column in FLIGHTS.names()})
        frame = pd.read_sql_query(
            f"SELECT {_names(FLIGHTS.names())} FROM flights ORDER BY {_order_by(FLIGHTS)}",
            connection,
        )
    return frame.astype(FLIGHTS.dtypes()).reset_index(drop=True)
