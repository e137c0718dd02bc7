"""Estimates scored against the truth: the per-estimate columns of trial rows.

:func:`score_outcomes` gives the :data:`~comparison.trial_rows.ESTIMATE_COLUMNS` of every
trial of a task at once, from an estimator's :class:`Outcomes` (its results as
:class:`~estimators.batch.BatchEstimates` columns, whether the estimator returned them so or
one :class:`~estimators.base.Estimate` per trial): the position and its error, the error once
the mirror ambiguity is resolved (MATH §7), the side of the track, the covariance and the two
NEES (the second with the covariance reflected for a candidate across the track), and the JSON
columns written by an exact formatter (the text of ``json.dumps``). A column-returning
estimator's trials never become ``Estimate`` objects. :func:`estimate_columns` is the same for
one estimate (a closed-loop frame). The track is that of one frame (:func:`frame_track`); in a
closed loop, that of the first frame the estimator uses (:func:`ambiguity_track`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from comparison.trial_rows import (
    ESTIMATE_COLUMNS,
    SCORED_DIMENSION,
    coordinate_columns,
    dimension_columns,
    matrix_columns,
    matrix_values,
)
from estimators.base import Estimate
from estimators.batch import BatchEstimates
from estimators.goodness_of_fit import FIT_KEYS
from scenarios.fisher import inverse_symmetric
from scenarios.types import MeasurementSet

Track = tuple[np.ndarray, np.ndarray]
"""A point of a frame's track and its horizontal unit direction."""


def frame_track(geometry: MeasurementSet, frame: int) -> Track | None:
    """A point and the horizontal unit direction of ``frame``'s track, or None when hovering."""
    first = int(np.argmax(geometry.frame == frame))
    velocity = np.asarray(geometry.velocity_mps[first, :2], dtype=float)
    speed = float(np.hypot(*velocity))
    if speed == 0.0:
        return None
    return np.asarray(geometry.position_m[first, :2], dtype=float), velocity / speed


def ambiguity_track(data: MeasurementSet, frame: int, frames: Any) -> Track | None:
    """The track whose mirror ambiguity an estimator faces at ``frame`` (closed loop, MATH §7).

    The first frame the estimator uses: ``frame`` itself for ``frames="last"``, frame 0 for
    ``"all"``, the first listed frame up to ``frame`` otherwise. A cumulative estimator's side
    is judged against the first track, the ambiguity a turn must resolve: the side of a later
    track is ill-defined when a planner flies through the emitter's horizontal position (the
    truth then lies within centimetres of that track's plane).
    """
    if isinstance(frames, str) and frames == "last":
        first = frame
    elif isinstance(frames, Sequence) and not isinstance(frames, str):
        chosen = [int(f) for f in frames if 0 <= int(f) <= frame]
        if not chosen:
            return None
        first = min(chosen)
    else:
        first = 0
    return frame_track(data, first)


def estimate_columns(
    estimate: Estimate,
    truth_m: np.ndarray,
    track: Track | None,
    runtime_s: float,
    columns: Sequence[str] = ESTIMATE_COLUMNS,
) -> tuple[Any, ...]:
    """The per-estimate ``columns`` of a trial row (by default
    :data:`~comparison.trial_rows.ESTIMATE_COLUMNS`): :func:`score_outcomes` of one estimate
    (a closed-loop frame, which is scored as it is flown)."""
    outcomes = Outcomes.of_estimates([(estimate, runtime_s)], dimension=np.size(truth_m))
    return score_outcomes(outcomes, truth_m, track, columns)[0]


def jsonable(value: Any) -> Any:
    """JSON-ready: arrays to lists, numpy scalars to Python, non-finite floats to null."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def estimate_to_dict(estimate: Estimate, truth_emitter_m: Any | None) -> dict[str, Any]:
    """``Estimate.to_dict()`` plus ``error_m`` and ``error_side_resolved_m`` given a truth.

    ``error_side_resolved_m`` is the distance from the truth to the nearest candidate: the
    error with the mirror side resolved (MATH §7).
    """
    result = estimate.to_dict()
    if truth_emitter_m is not None:
        truth = np.asarray(truth_emitter_m, dtype=float)
        error = float(np.linalg.norm(estimate.position_m - truth))
        candidates = estimate.candidates_m
        result["error_m"] = error if math.isfinite(error) else None
        result["error_side_resolved_m"] = (
            float(np.min(np.linalg.norm(candidates - truth, axis=1))) if len(candidates) else None
        )
    return result


# --------------------------------------------------------------------------------------------
# every trial of a task at once
# --------------------------------------------------------------------------------------------

_SORTED_JSON = json.JSONEncoder(sort_keys=True)
"""``json.dumps(value, sort_keys=True)``, without building an encoder per call."""


def diagnostics_text(diagnostics: Mapping[str, Any]) -> str:
    """The ``diagnostics_json`` of one estimate (as :func:`estimate_columns` writes it)."""
    return _SORTED_JSON.encode(jsonable(dict(diagnostics)))


def dimension_message(dimension: int, scored: int = SCORED_DIMENSION) -> str:
    """Why an estimate of ``dimension`` coordinates is not scored where the emitter has
    ``scored`` (:data:`~comparison.trial_rows.SCORED_DIMENSION`: ``(x, y)``, its height known)."""
    if scored == 2:
        return (
            f"position_m: {dimension} coordinates, but the scenario's emitter height is known "
            "and the comparison scores (x, y); return the horizontal position"
        )
    return (
        f"position_m: {dimension} coordinates, but the scenario's emitter has {scored} and the "
        f"comparison scores those; return {scored} coordinates"
    )


def distance_m(offset_m: ArrayLike) -> NDArray[np.float64]:
    """The Euclidean length of offsets ``(..., d)``, ``d ≥ 2``, shape ``(...)``: ``hypot``
    folded over the coordinates, ``hypot(hypot(x, y), z)`` (no overflow or underflow of the
    squares)."""
    offset = np.asarray(offset_m, dtype=float)
    length = np.hypot(offset[..., 0], offset[..., 1])
    for k in range(2, offset.shape[-1]):
        length = np.hypot(length, offset[..., k])
    return length


def mirror_reflection(direction: ArrayLike, dimension: int) -> NDArray[np.float64]:
    """The ``d × d`` reflection across the vertical plane through a horizontal track of unit
    ``direction`` (MATH §7): ``2 u uᵀ − I`` on ``(x, y)``, the height (``d = 3``) unchanged."""
    u = np.asarray(direction, dtype=float).reshape(2)
    reflection = np.eye(dimension)
    reflection[:2, :2] = 2.0 * np.outer(u, u) - np.eye(2)
    return reflection


@dataclass(frozen=True, slots=True, eq=False)
class Outcomes:
    """One estimator's results on the trials of a task at one frame, ready to be scored.

    Attributes
    ----------
    columns : BatchEstimates
    runtime_s : (n,)
        Each trial's share of the estimator's time.
    diagnostics_json : tuple of str, optional
        Each trial's ``diagnostics_json`` when the results came as ``Estimate`` objects (their
        diagnostics can be anything; the columns of :meth:`of_estimates` hold only the fit), else
        None: the text is then written from ``columns.diagnostics``.
    """

    columns: BatchEstimates
    runtime_s: NDArray[np.float64]
    diagnostics_json: tuple[str, ...] | None = None

    @classmethod
    def of_columns(
        cls, columns: BatchEstimates, runtime_s: float, dimension: int = SCORED_DIMENSION
    ) -> Outcomes:
        """A column-returning estimator's results, every trial given ``runtime_s`` (failed
        when they are not of the scored ``dimension``, the emitter's coordinates:
        :data:`~comparison.trial_rows.SCORED_DIMENSION` at a known height)."""
        if columns.position_m.shape[1] != dimension:
            failed = BatchEstimates.failed(
                len(columns),
                dimension_message(columns.position_m.shape[1], dimension),
                estimator=columns.estimator,
                dimension=dimension,
            )
            # a failure has no position: it keeps its own message in any dimension
            columns = dataclasses.replace(
                failed,
                message_code=np.where(columns.success, len(columns.messages), columns.message_code),
                messages=(*columns.messages, failed.messages[0]),
            )
        return cls(columns, np.full(len(columns), float(runtime_s)))

    @classmethod
    def of_estimates(
        cls, results: Sequence[tuple[Estimate, float]], dimension: int = SCORED_DIMENSION
    ) -> Outcomes:
        """``(estimate, runtime_s)`` per trial, as columns (the diagnostics as their text); an
        estimate not of the scored ``dimension`` (as in :meth:`of_columns`) fails.

        Unlike :meth:`BatchEstimates.from_estimates` it keeps whatever the diagnostics hold:
        those of a failed estimate, keys that differ between trials, nested values.
        """
        n, d = len(results), dimension
        estimates = [
            estimate
            if len(estimate.position_m) == d
            else Estimate.failed(
                estimate.estimator,
                # a failure has no position: it keeps its own message in any dimension
                estimate.message
                if not estimate.success
                else dimension_message(len(estimate.position_m), d),
                dimension=d,
            )
            for estimate, _ in results
        ]
        counts = [len(estimate.candidates_m) for estimate in estimates]
        candidates = np.full((n, max(counts, default=0), d), np.nan)
        position = np.full((n, d), np.nan)
        success = np.array([estimate.success for estimate in estimates], dtype=bool)
        with_covariance = any(estimate.covariance_m2 is not None for estimate in estimates)
        covariance = np.full((n, d, d), np.nan) if with_covariance else None
        codes: dict[str, int] = {}
        for i, estimate in enumerate(estimates):
            if counts[i]:
                candidates[i, : counts[i]] = estimate.candidates_m
            if success[i]:
                position[i] = estimate.position_m
            if covariance is not None and estimate.covariance_m2 is not None:
                covariance[i] = estimate.covariance_m2
        message_code = [codes.setdefault(str(e.message), len(codes)) for e in estimates]
        columns = BatchEstimates(
            estimator=estimates[0].estimator if estimates else "",
            position_m=position,
            candidates_m=candidates,
            n_candidates=np.array(counts, dtype=np.int64),
            ambiguous=np.array([estimate.ambiguous for estimate in estimates], dtype=bool),
            success=success,
            message_code=np.array(message_code, dtype=np.int64),
            messages=tuple(codes) or ("",),
            covariance_m2=covariance,
            diagnostics={
                key: np.array([fit_value(e.diagnostics, key) for e in estimates])
                for key in FIT_KEYS
            },
        )
        runtime_s = np.array([runtime for _, runtime in results], dtype=float)
        texts = tuple(diagnostics_text(estimate.diagnostics) for estimate in estimates)
        return cls(columns, runtime_s, texts)


def score_outcomes(
    outcomes: Outcomes,
    truth_m: ArrayLike,
    track: Track | None,
    columns: Sequence[str] = ESTIMATE_COLUMNS,
) -> list[tuple[Any, ...]]:
    """The per-estimate ``columns`` of every trial of ``outcomes`` (one row each, by default
    :data:`~comparison.trial_rows.ESTIMATE_COLUMNS`), computed on columns; those of a larger
    dimension than the truth's (``z_m`` of a horizontal answer in a 3-D run) are NaN.

    The position has the truth's ``d`` coordinates (those of ``outcomes``, built with that
    ``dimension``); errors are Euclidean in ``d`` (:func:`distance_m`), the NEES has ``d``
    degrees of freedom, the side of the track is judged on ``(x, y)``.

    ``error_side_resolved_m`` uses the candidate nearest to the truth (MATH §7), whose
    coordinates are ``x_side_resolved_m`` and ``y_side_resolved_m``. ``nees`` is the returned
    position's error against the estimator's covariance; ``nees_side_resolved`` the nearest
    candidate's error against *that candidate's* covariance: the covariance reflected across
    ``track`` when the candidate lies on the other side of it than the returned position (its
    mirror image, MATH §7), else the covariance as given. ``wrong_side`` is 1.0 when the
    returned position and the truth are strictly on opposite sides of the vertical plane
    through ``track``, NaN when the position lies in that plane (on neither side). Every error
    column is NaN for a failed estimate; the JSON columns are ``json.dumps``'s text. The columns
    are valid (:mod:`estimators.validity`, applied when
    :class:`~estimators.batch.BatchEstimates` is built): every success has a finite position
    among its finite candidates.
    """
    names = columns
    columns = outcomes.columns
    n = len(columns)
    if n == 0:
        return []
    nan = math.nan
    truth = np.asarray(truth_m, dtype=float).reshape(-1)
    d = len(truth)
    if columns.position_m.shape[1] != d:
        raise ValueError(
            f"truth_m: {d} coordinates but the estimates have {columns.position_m.shape[1]}; "
            f"build the outcomes with dimension={d}"
        )
    success = np.asarray(columns.success, dtype=bool)
    count = np.asarray(columns.n_candidates, dtype=np.int64)
    k = columns.candidates_m.shape[1]
    slot = np.arange(k)[None, :] < count[:, None]
    candidates = np.where(slot[..., None], columns.candidates_m, nan)
    position = np.where(success[:, None], columns.position_m, nan)
    finite_position = np.isfinite(position).all(axis=1)
    rows = np.arange(n)
    with np.errstate(invalid="ignore", over="ignore"):
        error_m = distance_m(position - truth)
        # the nearest candidate (the position when there is none), as np.nanargmin picks it
        pool = np.full((n, max(k, 1), d), nan)
        pool[:, :k] = candidates
        empty = count == 0
        pool[empty, 0] = position[empty]
        distances = distance_m(pool - truth)
        found = success & np.isfinite(distances).any(axis=1)
        distances = np.where(np.isnan(distances), np.inf, distances)
        best = np.argmin(distances, axis=1)
        side_resolved_m = np.where(found, distances[rows, best], nan)
        nearest = np.where(found[:, None], pool[rows, best], position)
        wrong_side = np.full(n, nan)
        mirror = np.zeros(n, dtype=bool)
        if track is not None:
            (ox, oy), (dx, dy) = track
            side_estimate = dx * (position[:, 1] - oy) - dy * (position[:, 0] - ox)
            side_truth = dx * (truth[1] - oy) - dy * (truth[0] - ox)
            origin = np.asarray(track[0], dtype=float)
            reach = np.hypot(position[:, 0] - origin[0], position[:, 1] - origin[1])
            bound = abs(side_truth)
            scale = np.where(reach > bound, reach, bound)  # Python's max(bound, reach)
            on_plane = np.abs(side_estimate) <= 1e-9 * scale
            opposite = np.where(side_estimate * side_truth < 0.0, 1.0, 0.0)
            judged = success & finite_position
            wrong_side = np.where(judged & ~on_plane, opposite, nan)
            side_nearest = dx * (nearest[:, 1] - oy) - dy * (nearest[:, 0] - ox)
            mirror = side_nearest * side_estimate < 0.0
        if columns.covariance_m2 is None:
            nees = nees_side_resolved = np.full(n, nan)
            covariance_entries = [nees] * len(matrix_columns("cov", d))
        else:
            covariance = np.asarray(columns.covariance_m2, dtype=float)
            covariance_entries = matrix_values(covariance)
            nees = normalized_error_squared(position - truth, covariance)
            if track is not None and mirror.any():
                reflection = mirror_reflection(track[1], d)
                covariance = covariance.copy()
                covariance[mirror] = np.matmul(
                    np.matmul(reflection, covariance[mirror]), reflection.T
                )
            nees_side_resolved = normalized_error_squared(nearest - truth, covariance)
    messages = [str(message) for message in columns.messages]
    side_resolved = np.where(found[:, None], nearest, nan)
    values = {
        **_coordinate_values("{}_m", position),
        "error_m": error_m.tolist(),
        "error_side_resolved_m": side_resolved_m.tolist(),
        **_coordinate_values("{}_side_resolved_m", side_resolved),
        "wrong_side": wrong_side.tolist(),
        "ambiguous": np.asarray(columns.ambiguous, dtype=bool).tolist(),
        "success": success.tolist(),
        "n_candidates": count.tolist(),
        "candidates_json": _candidates_texts(candidates, count),
        **{
            name: value.tolist()
            for name, value in zip(matrix_columns("cov", d), covariance_entries, strict=True)
        },
        "nees": nees.tolist(),
        "nees_side_resolved": nees_side_resolved.tolist(),
        **{key: _fit_column(columns, key, success).tolist() for key in FIT_KEYS},
        "runtime_s": np.asarray(outcomes.runtime_s, dtype=float).tolist(),
        "message": [messages[code] for code in columns.message_code.tolist()],
        "diagnostics_json": (
            list(outcomes.diagnostics_json)
            if outcomes.diagnostics_json is not None
            else _diagnostics_texts(columns, success)
        ),
    }
    absent = [nan] * n
    unknown = [c for c in names if c not in values and c not in dimension_columns(3)]
    if unknown:
        raise ValueError(f"columns: {unknown} are not estimate columns")
    return list(zip(*(values.get(column, absent) for column in names), strict=True))


def _coordinate_values(template: str, points: NDArray[np.float64]) -> dict[str, list[float]]:
    """The columns of points ``(n, d)`` named by ``template`` (``"{}_m"``: ``x_m, y_m`` ...)."""
    names = coordinate_columns(template, points.shape[1])
    return {name: points[:, k].tolist() for k, name in enumerate(names)}


def fit_value(diagnostics: Mapping[str, Any], key: str) -> float:
    """The number an estimate reports under ``key`` (``fit_chi2``, ``fit_dof``: MATH §17), NaN
    when it reports none (a plug-in need not)."""
    value = diagnostics.get(key)
    number = isinstance(value, int | float | np.integer | np.floating)
    return float(value) if number and not isinstance(value, bool | np.bool_) else math.nan


def _fit_column(columns: BatchEstimates, key: str, success: NDArray[np.bool_]) -> NDArray[Any]:
    """:func:`fit_value` of every trial, from the diagnostics column ``key``."""
    column = columns.diagnostics.get(key)
    if column is None or column.dtype.kind not in "iuf":
        return np.full(len(columns), math.nan)
    return np.where(success, column.astype(float), math.nan)


def normalized_error_squared(
    error_m: NDArray[np.float64], covariance_m2: NDArray[np.float64]
) -> NDArray[Any]:
    """The NEES ``eᵀ P⁻¹ e`` of each row, errors (n, d) and covariances (n, d, d) (as many
    degrees of freedom as ``e`` has coordinates); NaN where ``P`` is singular or not finite
    (:func:`scenarios.fisher.inverse_symmetric`)."""
    left = np.matmul(error_m[:, None, :], inverse_symmetric(covariance_m2))
    return np.matmul(left, error_m[:, :, None])[:, 0, 0]


def _float_texts(values: NDArray[np.float64]) -> list[str]:
    """The JSON text of each float, as ``json.dumps(jsonable(v))``: ``repr``, or ``null``."""
    texts = list(map(float.__repr__, values.tolist()))
    for i in np.flatnonzero(~np.isfinite(values)).tolist():
        texts[i] = "null"
    return texts


def _candidates_texts(candidates: NDArray[np.float64], count: NDArray[np.int64]) -> list[str]:
    """``candidates_json`` of each row: ``json.dumps`` of its ``count`` points of ``d``
    coordinates, ``[[x, y], ...]`` (``[[x, y, z], ...]``)."""
    k, d = candidates.shape[1], candidates.shape[2]
    slot = np.arange(k)[None, :] < count[:, None]
    texts = _float_texts(candidates[slot].reshape(-1))
    coordinates = zip(*(texts[c::d] for c in range(d)), strict=True)
    points = list(map("[{}]".format, map(", ".join, coordinates)))
    ends = np.cumsum(count).tolist()
    starts = [0, *ends[:-1]]
    return ["[" + ", ".join(points[a:b]) + "]" for a, b in zip(starts, ends, strict=True)]


def _value_texts(column: NDArray[Any]) -> list[str]:
    """The JSON text of each value of a diagnostics column, as :func:`diagnostics_text`."""
    kind = column.dtype.kind
    if kind == "b":
        return ["true" if value else "false" for value in column.tolist()]
    if kind in "iu":
        return list(map(int.__repr__, column.tolist()))
    if kind == "f":
        return _float_texts(column.astype(float))
    values = [_scalar(value) for value in column]
    widths = {len(value) if _floats_only(value) else -1 for value in values}
    if len(widths) == 1 and widths.pop() > 0:  # vectors of one length (a solver's eigenvalues)
        return _vector_texts(np.array(values, dtype=float))
    texts, known = [], {}
    for value in values:  # labels and statuses repeat: each distinct one encoded once
        key = _hashable_key(value)
        text = known.get(key) if key is not None else None
        if text is None:
            text = _SORTED_JSON.encode(jsonable(value))
            if key is not None:
                known[key] = text
        texts.append(text)
    return texts


def _scalar(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _floats_only(value: Any) -> bool:
    """Whether ``value`` is a list, tuple or 1-D array of floats alone (no int, no bool)."""
    if isinstance(value, np.ndarray):
        return value.ndim == 1 and value.dtype.kind == "f"
    return isinstance(value, list | tuple) and all(isinstance(x, float) for x in value)


def _vector_texts(rows: NDArray[np.float64]) -> list[str]:
    """The JSON text of each row of ``rows`` (n, width): ``[x, y, ...]``, each number as
    :func:`_float_texts` writes it."""
    width = rows.shape[1]
    texts = _float_texts(rows.reshape(-1))
    columns = (texts[c::width] for c in range(width))
    return ["[" + ", ".join(row) + "]" for row in zip(*columns, strict=True)]


def _hashable_key(value: Any) -> tuple[Any, ...] | None:
    """A key telling apart the values :func:`jsonable` writes differently (``True`` and ``1``
    too), for a text, whole number, truth value or None, or a list or tuple of those; None for
    anything else (a float: ``0.0`` and ``-0.0`` are equal keys but different texts)."""
    if value is None or isinstance(value, str | bool | int):
        return (type(value), value)
    if isinstance(value, list | tuple) and all(
        x is None or isinstance(x, str | bool | int) for x in value
    ):
        return (list, tuple((type(x), x) for x in value))
    return None


def _diagnostics_texts(columns: BatchEstimates, success: NDArray[np.bool_]) -> list[str]:
    """``diagnostics_json`` of each row from the diagnostics columns (``{}`` for a failure,
    which has none, as :meth:`BatchEstimates.estimate` gives it)."""
    n = len(success)
    keys = list(columns.diagnostics)
    if not keys or not all(isinstance(key, str) for key in keys):
        return [
            diagnostics_text(
                {key: _scalar(value[i]) for key, value in columns.diagnostics.items()}
                if success[i]
                else {}
            )
            for i in range(n)
        ]
    parts = []
    for key in sorted(keys):
        prefix = json.dumps(key) + ": "
        parts.append([prefix + text for text in _value_texts(np.asarray(columns.diagnostics[key]))])
    return [
        "{" + ", ".join(row) + "}" if ok else "{}"
        for ok, row in zip(success.tolist(), zip(*parts, strict=True), strict=True)
    ]
