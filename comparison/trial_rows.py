"""The row contract of a run: every column once, in order, with its SQLite and pandas types.

:data:`TRIALS` is the trial-row contract: the columns of
:func:`comparison.store.read_trials` in order (an experiment's swept-parameter columns follow
``snr_db``), each with its type in ``results.sqlite``, its type in the frame read, and where
its value comes from. Every other list of trial columns is derived from it: the ``trials``
table (:meth:`Table.stored`), the columns a worker computes for one estimate
(:data:`ESTIMATE_COLUMNS`, :func:`comparison.scoring.estimate_columns`), and the columns
:func:`comparison.metrics.summarize` needs (:data:`REQUIRED_TRIAL_COLUMNS`). :data:`POINTS`
and :data:`FLIGHTS` do the same for the ``points`` and ``flights`` tables
(:func:`comparison.store.read_points`, :func:`comparison.store.read_flights`).

A table is stored as its key columns (the primary key, in order), then its index columns
(``<key>_index``: the position of the scenario, planner or estimator in the experiment, by
which rows are sorted; never read back), then its other stored columns in contract order.

The dimension ``d`` of a position (MATH §8: ``(x_s, y_s)`` at a known emitter height; with the
height estimated ``(x_s, y_s, z_s)``) names its columns here and nowhere else: one column per
coordinate (:func:`coordinate_columns`: ``truth_x_m``, ``x_m``, ``x_side_resolved_m`` ...) and
per entry of the upper triangle of a covariance or CRLB (:func:`matrix_columns`: ``cov_xx_m2``,
``crlb_xy_m2`` ...; :func:`matrix_values` and :func:`matrix_of_values` convert). The tables of
a run whose scenarios all have the height known hold ``d = 2`` (:data:`TRIALS`,
:data:`POINTS`); a run with an emitter of unknown height has 3-D tables
(:func:`trials_table`, :func:`points_table` of ``3``), which keep these columns in their order
and add ``truth_z_m``, ``z_m``, ``z_side_resolved_m``, ``cov_xz_m2, cov_yz_m2, cov_zz_m2`` and
``crlb_xz_m2, crlb_yz_m2, crlb_zz_m2`` after their 2-D namesakes (NaN in the rows of a 2-D
scenario or of an estimator that assumes the height).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

SWEPT_AFTER = "snr_db"
"""An experiment's swept-parameter columns (REAL, float64) follow this column."""

SWEPT_SQL = "REAL"
SWEPT_DTYPE = "float64"


@dataclass(frozen=True, slots=True)
class Column:
    """One column.

    Attributes
    ----------
    name : str
    sql : str
        Its type in ``results.sqlite`` (empty for a column that is not stored).
    dtype : str or None
        The pandas dtype the readers give it; None keeps what SQLite returns (text).
    source : str
        ``"key"`` (primary key), ``"value"`` (stored), ``"estimate"`` (stored, computed per
        estimate), ``"bound"`` (stored, the CRLB), ``"points"`` (joined from the points table)
        or ``"run"`` (the experiment's name, added when read).
    required : bool
        Every trial frame must have it (:func:`comparison.metrics.summarize` reads it).
    """

    name: str
    sql: str
    dtype: str | None = None
    source: str = "value"
    required: bool = True

    @property
    def stored(self) -> bool:
        return self.source in ("key", "value", "estimate", "bound")


@dataclass(frozen=True, slots=True)
class Table:
    """A table of ``results.sqlite`` and the frame read from it."""

    name: str
    columns: tuple[Column, ...]
    """As read, in order (without the swept columns)."""
    indexes: tuple[Column, ...] = ()
    """Stored only: the experiment's order of the keys, for sorting."""

    def names(self, swept: Sequence[str] = ()) -> tuple[str, ...]:
        """The columns read, in order, the swept ones after ``snr_db``."""
        return with_swept([c.name for c in self.columns], swept)

    def keys(self) -> tuple[str, ...]:
        """The primary key, in order."""
        return tuple(c.name for c in self.columns if c.source == "key")

    def stored(self, swept: Sequence[str] = ()) -> tuple[tuple[str, str], ...]:
        """``(name, SQLite type)`` of the stored columns, in table order."""
        keys = [c for c in self.columns if c.source == "key"]
        rest = [c for c in self.columns if c.stored and c.source != "key"]
        types = {c.name: c.sql for c in (*keys, *self.indexes, *rest)}
        names = with_swept(list(types), swept)
        types.update(dict.fromkeys(swept, SWEPT_SQL))
        return tuple((name, types[name]) for name in names)

    def sort_order(self) -> tuple[str, ...]:
        """The keys in the experiment's order: a key with an index column gives way to it."""
        indexed = {c.name for c in self.indexes}
        return tuple(f"{k}_index" if f"{k}_index" in indexed else k for k in self.keys())

    def dtypes(self, swept: Sequence[str] = ()) -> dict[str, str]:
        """The pandas dtype of every read column that has one."""
        types = {c.name: c.dtype for c in self.columns if c.dtype is not None}
        return {**types, **dict.fromkeys(swept, SWEPT_DTYPE)}


def with_swept(names: Sequence[str], swept: Sequence[str]) -> tuple[str, ...]:
    """``names`` with ``swept`` inserted after ``snr_db`` (unchanged without ``snr_db``)."""
    out = list(names)
    if SWEPT_AFTER in out:
        at = out.index(SWEPT_AFTER) + 1
        out[at:at] = swept
    return tuple(out)


COORDINATES: tuple[str, ...] = ("x", "y", "z")
"""The names of a position's coordinates, in order: ``(x, y)`` at a known emitter height,
``(x, y, z)`` with the height estimated (``d = 2`` or ``3``)."""


SCORED_DIMENSION = 2
"""The coordinates the tables hold and the comparison scores: ``(x, y)``, every scenario's
emitter being at a known height (:func:`coordinate_columns` and :func:`matrix_columns` of this
``d`` name the columns of :data:`POINTS` and :data:`TRIALS`)."""


@functools.cache
def matrix_entries(dimension: int) -> tuple[tuple[int, int], ...]:
    """The ``(i, j)``, ``i ≤ j``, of a symmetric ``d × d`` matrix that its columns hold, in column
    order: the upper triangle column by column, ``(0, 0), (0, 1), (1, 1)`` then ``(0, 2), (1, 2),
    (2, 2)``. The entries of ``d = 2`` come first whatever ``d``, so a 3-D table adds columns
    after the 2-D ones and a 2-D row is the same row."""
    if not 1 <= dimension <= len(COORDINATES):
        raise ValueError(
            f"dimension: a position has 1 to {len(COORDINATES)} coordinates, got {dimension}"
        )
    return tuple((i, j) for j in range(dimension) for i in range(j + 1))


@functools.cache
def matrix_columns(prefix: str, dimension: int) -> tuple[str, ...]:
    """The column names of a symmetric ``d × d`` matrix in m² (a covariance ``"cov"``, a CRLB
    ``"crlb"``), one per entry of :func:`matrix_entries`: ``crlb_xx_m2, crlb_xy_m2,
    crlb_yy_m2`` for ``d = 2``; for ``d = 3`` those, then ``crlb_xz_m2, crlb_yz_m2,
    crlb_zz_m2``. The one home of these names."""
    return tuple(
        f"{prefix}_{COORDINATES[i]}{COORDINATES[j]}_m2" for i, j in matrix_entries(dimension)
    )


@functools.cache
def coordinate_columns(template: str, dimension: int) -> tuple[str, ...]:
    """The column names of a position's coordinates: ``template`` with ``{}`` replaced by each
    coordinate's name (``"truth_{}_m"`` → ``truth_x_m, truth_y_m`` and, for ``d = 3``,
    ``truth_z_m``)."""
    return tuple(template.format(name) for name in COORDINATES[:dimension])


@functools.cache
def dimension_columns(dimension: int) -> tuple[str, ...]:
    """The trial columns named per coordinate or matrix entry for positions of ``dimension``
    coordinates: the truth's, the position's and the side-resolved position's coordinates, the
    covariance's and the CRLB's entries. With ``d = 3`` these are the columns a trial frame may
    hold beyond :data:`TRIAL_COLUMNS` that are no swept parameter."""
    return (
        *coordinate_columns("truth_{}_m", dimension),
        *coordinate_columns("{}_m", dimension),
        *coordinate_columns("{}_side_resolved_m", dimension),
        *matrix_columns("cov", dimension),
        *matrix_columns("crlb", dimension),
    )


def padded(values: Sequence[float], names: Sequence[str]) -> tuple[float, ...]:
    """The leading ``values`` of columns ``names`` (a 2-D row's of a 3-D table: the CRLB's
    ``xx, xy, yy`` of ``xx, xy, yy, xz, yz, zz``), NaN for the rest."""
    return (*values, *[float("nan")] * (len(names) - len(values)))


def matrix_values(matrix: ArrayLike) -> list[NDArray[np.float64]]:
    """The entries of symmetric matrices ``(..., d, d)`` in the order of
    :func:`matrix_columns`, each of shape ``(...)``."""
    array = np.asarray(matrix, dtype=float)
    return [array[..., i, j] for i, j in matrix_entries(array.shape[-1])]


def matrix_of_values(values: Sequence[ArrayLike]) -> NDArray[np.float64]:
    """The symmetric matrices ``(..., d, d)`` whose entries, in the order of
    :func:`matrix_columns`, are ``values`` (``d (d + 1)/2`` arrays of one shape):
    :func:`matrix_values` inverted."""
    count = len(values)
    dimension = next((d for d in range(1, len(COORDINATES) + 1) if d * (d + 1) // 2 == count), 0)
    if not dimension:
        raise ValueError(
            f"values: {count} entries are not the upper triangle of a symmetric matrix of "
            f"1 to {len(COORDINATES)} rows"
        )
    arrays = [np.asarray(v, dtype=float) for v in values]
    matrix = np.empty((*np.broadcast_shapes(*(a.shape for a in arrays)), dimension, dimension))
    for (i, j), value in zip(matrix_entries(dimension), arrays, strict=True):
        matrix[..., i, j] = value
        matrix[..., j, i] = value
    return matrix


def _real(name: str, source: str = "value", *, required: bool = True) -> Column:
    return Column(name, "REAL", "float64", source, required)


POINT_CRLB_SETS: dict[str, tuple[str, ...]] = {
    "crlb_rmse_toa_m": ("toa",),
    "crlb_rmse_doppler_m": ("doppler",),
    "crlb_rmse_rss_m": ("rss",),
    "crlb_rmse_toa_doppler_m": ("toa", "doppler"),
    "crlb_rmse_all_m": ("toa", "doppler", "rss"),
}
"""The CRLB columns of the points table and the modalities of each (MATH §8), with the
scenario's nuisance parameters unknown where it declares them (MATH §15)."""

POINT_KNOWN_CRLB_SETS: dict[str, tuple[str, ...]] = {
    "crlb_rmse_known_doppler_m": ("doppler",),
    "crlb_rmse_known_toa_doppler_m": ("toa", "doppler"),
}
"""Bounds with every nuisance parameter known (MATH §15): beside their namesakes of
:data:`POINT_CRLB_SETS` they give the price of the scenario's unknowns (equal without any)."""

POINT_HEIGHT_CRLB: tuple[str, ...] = (
    "crlb_horizontal_toa_doppler_m",
    "crlb_vertical_toa_doppler_m",
)
"""A 3-D points table's parts of the ToA+Doppler bound (MATH §8): ``√(CRLB_xx + CRLB_yy)``
and ``√CRLB_zz`` (for a scenario with the height known, its whole bound and NaN)."""

_SCENARIO_INDEX = Column("scenario_index", "INTEGER")


@functools.cache
def points_table(dimension: int = SCORED_DIMENSION) -> Table:
    """The points table of positions of ``dimension`` coordinates (:data:`POINTS` at 2)."""
    return Table(
        "points",
        (
            Column("scenario", "TEXT", None, "key"),
            Column("point", "INTEGER", "int64", "key"),
            _real("snr_db"),
            Column("frame", "INTEGER", "int64", "key"),
            *(_real(name) for name in coordinate_columns("truth_{}_m", dimension)),
            _real("range_scale_m"),
            *(_real(name) for name in POINT_CRLB_SETS),
            *(_real(name, required=False) for name in POINT_KNOWN_CRLB_SETS),
            *(_real(name, required=False) for name in POINT_HEIGHT_CRLB if dimension > 2),
        ),
        indexes=(_SCENARIO_INDEX,),
    )


POINTS = points_table()
"""One row per scenario × point × frame: truth, accumulated CRLB, the size of the geometry."""


def _joined(name: str) -> Column:
    """A trial column taken from the points table."""
    return Column(name, "REAL", "float64", "points")


def _estimate(name: str, sql: str, dtype: str | None, *, required: bool = True) -> Column:
    return Column(name, sql, dtype, "estimate", required)


@functools.cache
def trials_table(dimension: int = SCORED_DIMENSION) -> Table:
    """The trials table of positions of ``dimension`` coordinates (:data:`TRIALS` at 2; at 3
    the same columns with each coordinate's and matrix entry's after their 2-D namesakes)."""
    return Table(
        "trials",
        (
            Column("experiment", "", None, "run", required=False),
            Column("scenario", "TEXT", None, "key"),
            Column("point", "INTEGER", "int64", "key"),
            _joined("snr_db"),
            Column("planner", "TEXT NOT NULL DEFAULT ''", None, "key", required=False),
            Column("estimator", "TEXT", None, "key"),
            Column("frame", "INTEGER", "int64", "key"),
            Column("trial", "INTEGER", "int64", "key", required=False),
            *(_joined(name) for name in coordinate_columns("truth_{}_m", dimension)),
            *(_real(name, "estimate") for name in coordinate_columns("{}_m", dimension)),
            _real("error_m", "estimate"),
            _real("error_side_resolved_m", "estimate"),
            *(
                _real(name, "estimate", required=False)
                for name in coordinate_columns("{}_side_resolved_m", dimension)
            ),
            _real("wrong_side", "estimate"),
            _estimate("ambiguous", "INTEGER", "bool"),
            _estimate("success", "INTEGER", "bool"),
            _estimate("n_candidates", "INTEGER", "int64", required=False),
            _estimate("candidates_json", "TEXT", None, required=False),
            *(_real(name, "estimate", required=False) for name in matrix_columns("cov", dimension)),
            _real("nees", "estimate"),
            _real("nees_side_resolved", "estimate"),
            _real("fit_chi2", "estimate", required=False),
            _real("fit_dof", "estimate", required=False),
            _real("crlb_rmse_m", "bound"),
            *(_real(name, "bound", required=False) for name in matrix_columns("crlb", dimension)),
            _real("runtime_s", "estimate"),
            _estimate("message", "TEXT", None, required=False),
            _estimate("diagnostics_json", "TEXT", None, required=False),
        ),
        indexes=(
            _SCENARIO_INDEX,
            Column("planner_index", "INTEGER NOT NULL DEFAULT 0"),
            Column("estimator_index", "INTEGER"),
        ),
    )


TRIALS = trials_table()
"""The trial-row contract: one row per scenario × point × planner × estimator × frame ×
trial. ``planner`` is empty in an open-loop run; ``runtime_s`` is the only column that is not
a function of the experiment. ``fit_chi2`` and ``fit_dof`` are the goodness of fit of the answer
(MATH §17; ``estimators.goodness_of_fit``), NaN for a failed estimate or an estimator that does
not report it."""


@functools.cache
def estimate_columns_of(dimension: int = SCORED_DIMENSION) -> tuple[str, ...]:
    """The columns computed from one estimate at ``dimension`` (:data:`ESTIMATE_COLUMNS`)."""
    return tuple(c.name for c in trials_table(dimension).columns if c.source == "estimate")


@functools.cache
def bound_columns_of(dimension: int = SCORED_DIMENSION) -> tuple[str, ...]:
    """The bound columns at ``dimension`` (:data:`BOUND_COLUMNS`)."""
    return tuple(c.name for c in trials_table(dimension).columns if c.source == "bound")


TRIAL_COLUMNS: tuple[str, ...] = TRIALS.names()
"""Every fixed column of a trial frame; the swept-parameter columns come on top of these.
``planner`` is optional (empty in open-loop runs)."""

REQUIRED_TRIAL_COLUMNS: tuple[str, ...] = tuple(c.name for c in TRIALS.columns if c.required)
"""The trial columns :func:`comparison.metrics.summarize` reads."""

ESTIMATE_COLUMNS: tuple[str, ...] = estimate_columns_of()
"""The columns computed from one estimate (:func:`comparison.scoring.estimate_columns`)."""

BOUND_COLUMNS: tuple[str, ...] = bound_columns_of()
"""The CRLB an estimate is scored against (MATH §8): ``√trace`` first, then the matrix's
entries ``xx, xy, yy`` (m², :func:`matrix_columns`), from which the verdicts take its principal
axes."""

POINT_COLUMNS: tuple[str, ...] = tuple(c.name for c in TRIALS.columns if c.source == "points")
"""The trial columns joined from the points table (on its key)."""

FLIGHTS = Table(
    "flights",
    (
        Column("scenario", "TEXT", None, "key"),
        Column("point", "INTEGER", "int64", "key"),
        Column("planner", "TEXT", None, "key"),
        Column("trial", "INTEGER", "int64", "key"),
        Column("frame", "INTEGER", "int64", "key"),
        Column("start_x_m", "REAL"),
        Column("start_y_m", "REAL"),
        Column("start_z_m", "REAL"),
        Column("end_x_m", "REAL"),
        Column("end_y_m", "REAL"),
        Column("end_z_m", "REAL"),
        Column("vx_mps", "REAL"),
        Column("vy_mps", "REAL"),
        Column("vz_mps", "REAL"),
        Column("message", "TEXT"),
        Column("diagnostics_json", "TEXT"),
    ),
    indexes=(_SCENARIO_INDEX, Column("planner_index", "INTEGER")),
)
"""Closed loop only: frame ``frame``'s first and last samples and velocity, and the plan
message that chose it (frame 0 is the scenario's own)."""

BURSTS = Table(
    "bursts",
    (
        Column("scenario", "TEXT", None, "key"),
        Column("point", "INTEGER", "int64", "key"),
        Column("trial", "INTEGER", "int64", "key"),
        Column("n_bursts", "INTEGER", "int64"),
        Column("flagged", "INTEGER", "int64"),
        Column("outliers", "INTEGER", "int64"),
        Column("unflagged_outliers", "INTEGER", "int64"),
        Column("mean_burst_snr_db", "REAL"),
    ),
    indexes=(_SCENARIO_INDEX,),
)
"""The signal level only (docs/math.md §20): per trial, its bursts, how many the front end
flagged below threshold, how many are outliers (a Doppler more than a bin ``1/T``, or a ToA
more than a chip, off the truth: :func:`estimators.frontend.outlier_rate`) and how many of
those it did not flag, and the mean estimated burst SNR."""

BURST_COLUMNS: tuple[str, ...] = BURSTS.names()
"""Columns of :func:`comparison.store.read_bursts`."""

BURST_VALUE_COLUMNS: tuple[str, ...] = tuple(c.name for c in BURSTS.columns if c.source == "value")
"""The columns computed from one trial's bursts (:func:`comparison.tasks.run_task`)."""

FLIGHT_COLUMNS: tuple[str, ...] = FLIGHTS.names()
"""Columns of :func:`comparison.store.read_flights`."""

FLIGHT_VALUE_COLUMNS: tuple[str, ...] = tuple(
    c.name for c in FLIGHTS.columns if c.source == "value"
)
"""The columns computed from one flown frame (:func:`comparison.tasks.run_task`)."""
