"""The common estimator interface and its one result type.

The protocols and :class:`Capabilities` are defined in :mod:`estimators.interface` and
importable from here. An estimator is any object with a ``name``, the set of modalities it ``requires`` and an
``estimate(data, *, rng=None)`` method returning an :class:`Estimate`. No inheritance is
needed (a ``typing.Protocol``, as optax does). It declares what the comparison needs to know
in ``capabilities() -> Capabilities`` (the modalities and frames it uses, the modules it needs,
whether it is batch or sequential, what it claims); :func:`capabilities_of` reads it, with a
default from the protocol for an estimator that declares nothing. Two optional capabilities
extend it:

- :class:`BatchEstimator`: ``estimate_batch(batch)`` takes a whole
  :class:`~scenarios.types.MeasurementBatch` of Monte Carlo trials at once;
- :class:`SequentialEstimator`: an optax-style pure pair ``init() -> state`` and
  ``update(state, frame) -> state``, fed one frame at a time (EKF, factor-graph smoother),
  with ``estimate_state(state) -> Estimate``; no mutable filter object leaks out. Without the
  data there, :func:`finalize_from_track` applies the mirror rule of :func:`finalize_estimate`
  to what the state keeps of the samples (:class:`~scenarios.geometry.TrackSoFar`).

Constructors take keyword-only hyper-parameters and only store them (scikit-learn's rule);
the built-ins are frozen dataclasses. A failure to estimate is data (``success=False`` and a
``message``), not an exception; malformed input raises ``ValueError`` naming the field.

Two rules hold for every estimator, built-in or plug-in, in one place each:

- An estimate is valid (:mod:`estimators.validity`): real numbers; a success finite, its
  position one of its candidates, its covariance symmetric positive semi-definite.
  :class:`Estimate` itself turns an estimate that breaks a rule into a failed estimate whose
  message names the rule and quotes what was reported (rather than raising: the caller gets
  the one result type either way, and the row says why); :class:`~estimators.batch.
  BatchEstimates` does the same to its columns.
- Data with no baseline locate nothing. :func:`require_modalities`, which every built-in calls
  first, raises ``ValueError`` naming ``position_m`` or ``velocity_mps`` when every sample is
  at one horizontal point and the modalities used cannot fix a point from there
  (:func:`baseline_problem`): a hovering UAV, or ranges or powers alone from one point. Such
  data are valid measurements, but an answer would be a guess reported as a success; refused
  here, the estimate never says otherwise, and the engine records the refusal as a failed row
  with this message. One point with Doppler and ToA (a single moving sample) still fixes a
  mirror pair, which the estimators report as ambiguous (MATH §7).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.interface import BatchEstimator as BatchEstimator
from estimators.interface import Capabilities as Capabilities
from estimators.interface import Estimator, capabilities_of
from estimators.interface import SequentialEstimator as SequentialEstimator
from estimators.interface import protocol_problems as protocol_problems
from estimators.mirror_rule import COST_TIE_ULPS as COST_TIE_ULPS
from estimators.mirror_rule import MERGE_RTOL as MERGE_RTOL
from estimators.mirror_rule import FinalizedColumns, finalize_columns
from estimators.mirror_rule import cost_tie_level as cost_tie_level
from estimators.registry import estimators_handling
from estimators.validity import (
    invalid_estimates,
    numeric_array,
    position_dimension,
    real_part,
    refused_message,
)
from scenarios.fields import vector_text
from scenarios.geometry import TrackSoFar, moves_horizontally, single_horizontal_point
from scenarios.nuisance import describe_unknowns, math_sections, unknowns_used
from scenarios.types import MEASURED_FIELD, MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
State = TypeVar("State")


def _shaped(array: NDArray[Any], shape: tuple[int, ...], field: str = "") -> NDArray[Any]:
    """``array`` reshaped to ``shape`` (``-1``: any length), or one line naming the field."""
    try:
        return array.reshape(shape)
    except ValueError:
        want = ", ".join("n" if n == -1 else str(n) for n in shape)
        raise ValueError(
            f"{field}: expected shape ({want}) for a position of {shape[-1]} coordinates, "
            f"got {array.shape}"
        ) from None


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Estimate:
    """What an estimator returns (a frozen ``scipy.optimize.OptimizeResult``).

    Attributes
    ----------
    estimator : str
        Registry name of the estimator.
    position_m : (2,) or (3,)
        The returned emitter position ``(x_s, y_s)``, or ``(x_s, y_s, z_s)`` when the
        estimator estimates the height too (:data:`~estimators.validity.POSITION_DIMENSIONS`);
        NaN when ``success`` is false.
    candidates_m : (n, 2) or (n, 3)
        Every minimiser of equal cost, ``position_m`` among them (MATH §7). Two mirror
        images on one straight frame, one point once a turn resolves the side.
    ambiguous : bool
        True when the data cannot tell the side of the track (MATH §7): every sample on one
        straight line, or several candidates of equal cost. ``position_m`` is then a guess,
        even when the single candidate lies on the track and is its own mirror image.
    covariance_m2 : (2, 2), (3, 3) or None
        The estimator's own error covariance of ``position_m``, when it has one: the error
        given that the returned side is right. The comparison reflects it across the track,
        ``R P Rᵀ``, for a mirror candidate (MATH §7, §16).
    success : bool
    message : str
        Why it failed, or notes on a success (rank deficiency, hard case, ...).
    diagnostics : mapping
        Scalars such as the Lagrange multiplier, hard case, rank, iterations.

    Built, it is valid (:func:`estimators.validity.invalid_estimates`): the position, the
    candidates and the covariance are real, and a success has a finite position that is one
    of its candidates and a symmetric positive semi-definite covariance (or none), to rounding.
    An estimate that breaks a rule is built as a failed one whose message starts with
    ``"invalid estimate: "`` and names the rule; ``dataclasses.replace`` checks again.
    """

    estimator: str
    position_m: FloatArray
    candidates_m: FloatArray
    ambiguous: bool
    covariance_m2: FloatArray | None = None
    success: bool = True
    message: str = ""
    diagnostics: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        position = numeric_array(self.position_m, "position_m").reshape(-1)
        dim = position_dimension(position.size)
        candidates = _shaped(
            numeric_array(self.candidates_m, "candidates_m"), (-1, dim), "candidates_m"
        )
        covariance = (
            None
            if self.covariance_m2 is None
            else _shaped(
                numeric_array(self.covariance_m2, "covariance_m2"), (dim, dim), "covariance_m2"
            )
        )
        set_(self, "ambiguous", bool(self.ambiguous))
        set_(self, "success", bool(self.success))
        set_(self, "diagnostics", dict(self.diagnostics))
        reasons = invalid_estimates(
            position[None],
            candidates[None],
            [len(candidates)],
            None if covariance is None else covariance[None],
            [self.success],
        )
        if reasons:
            set_(self, "message", refused_message(reasons[0], self.message))
            set_(self, "success", False)
            set_(self, "ambiguous", False)
            position, candidates, covariance = np.full(dim, np.nan), np.empty((0, dim)), None
        position, candidates = real_part(position), real_part(candidates)
        position.flags.writeable = False
        candidates.flags.writeable = False
        set_(self, "position_m", position)
        set_(self, "candidates_m", candidates)
        if covariance is not None:
            covariance = real_part(covariance)
            covariance.flags.writeable = False
        set_(self, "covariance_m2", covariance)

    @classmethod
    def failed(
        cls, estimator: str, message: str, *, dimension: int = 2, **diagnostics: Any
    ) -> Estimate:
        """A failed estimate: NaN position (of ``dimension`` coordinates), no candidates, the
        reason in ``message``."""
        return cls(
            estimator=estimator,
            position_m=np.full(dimension, np.nan),
            candidates_m=np.empty((0, dimension)),
            ambiguous=False,
            success=False,
            message=message,
            diagnostics=diagnostics,
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (NaN becomes None)."""

        def clean(value: Any) -> Any:
            if isinstance(value, np.ndarray):
                return clean(value.tolist())
            if isinstance(value, list | tuple):
                return [clean(v) for v in value]
            if isinstance(value, float | np.floating):
                return None if not np.isfinite(value) else float(value)
            if isinstance(value, np.integer | np.bool_):
                return value.item()
            return value

        return {
            "estimator": self.estimator,
            "position_m": clean(self.position_m),
            "candidates_m": clean(self.candidates_m),
            "ambiguous": self.ambiguous,
            "covariance_m2": None if self.covariance_m2 is None else clean(self.covariance_m2),
            "success": self.success,
            "message": self.message,
            "diagnostics": {key: clean(value) for key, value in self.diagnostics.items()},
        }


# --------------------------------------------------------------------------------------------
# helpers shared by the built-in estimators
# --------------------------------------------------------------------------------------------


_MODALITY_NAMES = {"doppler": "Doppler", "toa": "ToA", "rss": "RSS"}


def baseline_problem(modalities: frozenset[str] | set[str], data: MeasurementSet) -> str | None:
    """Why ``data`` cannot locate the emitter with ``modalities``, or None when they can.

    Only a geometry with no horizontal baseline, every sample at one horizontal point
    (:func:`~scenarios.geometry.single_horizontal_point`), is refused, when:

    - no sample moves horizontally (a hovering or climbing UAV): every bearing fits the data
      equally, whatever the modalities;
    - ToA or RSS alone: from one point they fix only a circle around it;
    - Doppler alone: from one point and one velocity it fixes only a curve.

    Doppler with ToA (or RSS) from one moving point fixes a mirror pair (MATH §7) and is not
    refused. The reason starts with the field at fault (``position_m:``, ``velocity_mps:``).
    """
    if not single_horizontal_point(data.position_m):
        return None
    hovering = hovering_problem(data)
    if hovering is not None:
        return hovering
    where = vector_text(data.position_m[0, :2])
    used = set(modalities) or set(data.modalities)
    if "doppler" not in used:
        names = " and ".join(_MODALITY_NAMES[m] for m in sorted(used))
        return (
            f"position_m: every sample is at one horizontal point {where} m, from which "
            f"{names} {'fix' if len(used) > 1 else 'alone fixes'} only a circle around it; give "
            "samples from at least two points (fly a track) or an estimator that also uses Doppler"
        )
    if used == {"doppler"}:
        return (
            f"position_m: every sample is at one horizontal point {where} m, from which Doppler "
            "alone fixes only a curve; give samples from at least two points (fly a track) or "
            "add ToA"
        )
    return None


def hovering_problem(data: MeasurementSet) -> str | None:
    """The reason of :func:`baseline_problem` for a hovering or climbing UAV, else None: the
    samples ``finalize_estimate`` refuses whatever the candidates."""
    if not single_horizontal_point(data.position_m) or moves_horizontally(data.velocity_mps):
        return None
    return (
        f"velocity_mps: every sample is at one horizontal point "
        f"{vector_text(data.position_m[0, :2])} m with no horizontal motion (a hovering or "
        "climbing UAV), so every bearing to the emitter fits the data equally; give samples "
        "flown along a horizontal track"
    )


def _used_modalities(estimator: Any, data: MeasurementSet) -> frozenset[str]:
    """The modalities ``estimator`` uses on ``data``: declared ones present, else required."""
    try:
        declared = capabilities_of(estimator).modalities
    except (TypeError, ValueError):
        declared = frozenset(estimator.requires)
    return (declared & data.modalities) | frozenset(estimator.requires)


def require_modalities(estimator: Estimator, data: MeasurementSet) -> None:
    """Raise ``ValueError`` naming the missing measurement field, or the field at fault when
    the data span no baseline for the modalities the estimator uses (:func:`baseline_problem`).

    Anything but a :class:`~scenarios.types.MeasurementSet` raises ``TypeError`` naming
    ``data``, before any attribute of it is read.
    """
    if not isinstance(data, MeasurementSet):
        hint = (
            "; estimate one trial at a time, batch.trial(i)"
            if isinstance(data, MeasurementBatch)
            else "; read a file with scenarios.files.read_measurements"
        )
        raise TypeError(
            f"data: expected a scenarios.types.MeasurementSet, got {type(data).__name__}{hint}"
        )
    missing = sorted(estimator.requires - data.modalities)
    if missing:
        names = ", ".join(MEASURED_FIELD[m] for m in missing)
        raise ValueError(
            f"{names}: estimator {estimator.name!r} needs {', '.join(missing)} measurements; "
            f"add them to the data or choose an estimator that works without them"
        )
    used = _used_modalities(estimator, data)
    problem = unknowns_problem(estimator, data.unknowns, used)
    if problem is not None:
        raise ValueError(problem)
    problem = baseline_problem(used, data)
    if problem is not None:
        raise ValueError(problem)


def require_batch(estimator: Estimator, batch: MeasurementBatch) -> MeasurementBatch:
    """:func:`require_modalities` for a whole batch: ``TypeError`` naming ``batch`` for
    anything but a :class:`~scenarios.types.MeasurementBatch`, then the checks of its first
    trial (the trials share their geometry and modalities). Returns the batch."""
    if not isinstance(batch, MeasurementBatch):
        raise TypeError(
            f"batch: expected a scenarios.types.MeasurementBatch, got {type(batch).__name__}"
        )
    require_modalities(estimator, batch.trial(0) if batch.n_trials else batch.geometry)
    return batch


def unknowns_problem(
    estimator: Any,
    unknowns: Iterable[str],
    modalities: Iterable[str],
    *,
    ignore_hint: str = "data.assuming_known() in Python",
) -> str | None:
    """Why ``estimator`` cannot take data with these nuisance ``unknowns`` (MATH §15), or None.

    An unknown counts only in a modality the estimator uses (δ with Doppler, b with ToA). The
    reason names the built-in estimators that do handle it, and how to see what ignoring it
    costs (``ignore_hint``: ``MeasurementSet.assuming_known()``, or in an experiment
    ``ignore_unknowns = true``).
    """
    needed = unknowns_used(unknowns, modalities)
    try:
        handled = capabilities_of(estimator).unknowns
    except (TypeError, ValueError):
        handled = frozenset()
    missing = [name for name in needed if name not in handled]
    if not missing:
        return None
    able = estimators_handling(missing)
    use = f"use {', '.join(repr(name) for name in able)}, or " if able else ""
    them = "it" if len(missing) == 1 else "them"
    return (
        f"unknowns: the data declare the emitter's {describe_unknowns(missing)} unknown, but "
        f"{getattr(estimator, 'name', type(estimator).__name__)!r} takes {them} as known "
        f"({math_sections(missing)}); {use}ignore {them} on purpose to see the bias that costs "
        f"({ignore_hint})"
    )


def check_side_prior(side_prior_m: Any, *, field: str = "side_prior_m") -> None:
    """Raise ``ValueError`` naming ``field`` unless ``side_prior_m`` is None or a finite
    ``(x, y)`` in metres (any option that is a horizontal point)."""
    if side_prior_m is None:
        return
    try:
        point = np.asarray(side_prior_m, dtype=float)
    except (TypeError, ValueError):
        point = np.full(0, np.nan)
    if point.shape != (2,) or not np.all(np.isfinite(point)):
        raise ValueError(
            f"{field}: expected a finite (x, y) in metres or None, got {side_prior_m!r}"
        )


def check_rng(rng: Any) -> np.random.Generator | None:
    """Return ``rng`` if it is None or a ``numpy.random.Generator``; else raise ``TypeError``."""
    if rng is None or isinstance(rng, np.random.Generator):
        return rng
    raise TypeError(
        f"rng: expected a numpy.random.Generator or None, got {type(rng).__name__}; "
        "pass numpy.random.default_rng(seed)"
    )


def choose_candidate(
    candidates_m: ArrayLike,
    costs: ArrayLike,
    *,
    rng: np.random.Generator | None,
    side_prior_m: ArrayLike | None = None,
    cost_rtol: float = 1e-6,
) -> tuple[int, IntArray]:
    """The tie rule of MATH §7 as indices: ``(chosen, kept)`` into ``candidates_m``.

    ``kept`` are the candidates whose cost is within ``cost_rtol`` (relative) of the best, best
    first (a stable sort: equal costs keep their order). ``chosen`` is the kept candidate
    nearest to ``side_prior_m`` when one is given; otherwise an exact tie is broken by ``rng``
    (a fair coin, ``rng.integers(len(kept))``: the data hold no side information) or, without
    one, by the lowest cost. :func:`~estimators.mirror_rule.finalize_columns` of one trial
    without the merge; the filters' choice among their hypotheses
    (:func:`estimators.sequential.mirror_hypotheses.hypotheses_estimate`).
    """
    check_rng(rng)
    points = candidate_points(candidates_m)
    cost = np.asarray(costs, dtype=float).reshape(-1)
    final = finalize_columns(
        points[None],
        np.array([len(points)]),
        cost[None],
        np.zeros(2),
        None,
        side_prior_m=side_prior_m,
        cost_rtol=cost_rtol,
        merge=False,
        ceiling_m=np.inf,
    )
    chosen = _drawn(final, rng)
    kept = final.source[0, : final.n_candidates[0]]
    return int(kept[chosen]), kept


_BELOW = {2: "", 3: " below the UAV"}
"""What a candidate must be, besides finite, in 2-D and in 3-D (the mirror rule, MATH §7)."""


def candidate_points(candidates_m: ArrayLike) -> FloatArray:
    """``candidates_m`` as a (k, d) array of points, ``d`` its last axis (2, or 3 with the
    height estimated; one point may be given flat)."""
    points = np.asarray(candidates_m, dtype=float)
    d = position_dimension(points.shape[-1] if points.ndim else 0, "candidates_m")
    return points.reshape(-1, d)


def _drawn(final: FinalizedColumns, rng: np.random.Generator | None) -> int:
    """The returned slot of a batch of one: ``rng.integers(n_candidates)`` when it draws."""
    if final.draw[0] and rng is not None:
        return int(rng.integers(final.n_candidates[0]))
    return int(final.chosen[0])


def params_of(estimator: Any) -> dict[str, Any]:
    """The constructor parameters of a dataclass estimator."""
    if dataclasses.is_dataclass(estimator):
        return {f.name: getattr(estimator, f.name) for f in dataclasses.fields(estimator)}
    return dict(getattr(estimator, "__dict__", {}))


def finalize_estimate(
    estimator: str,
    candidates_m: ArrayLike,
    costs: ArrayLike,
    data: MeasurementSet,
    *,
    rng: np.random.Generator | None = None,
    side_prior_m: ArrayLike | None = None,
    cost_rtol: float = 1e-6,
    covariance_m2: ArrayLike | None = None,
    message: str = "",
    diagnostics: Mapping[str, Any] | None = None,
) -> Estimate:
    """Build an :class:`Estimate`, applying the mirror rule of MATH §7 the same way for all.

    On a straight track (every sample on one line, flying along it) each candidate's mirror
    image across the track has exactly the same cost, so it is added, and the answer is
    ambiguous. Coincident candidates are merged; see :func:`finalize_from_track` for the pick.
    ``data`` are the samples used: when they hover at one point (an estimator that uses only
    the last frame, and the UAV hovered in it), the estimate is failed, with the reason of
    :func:`baseline_problem`, whatever the candidates. Otherwise it is
    :func:`finalize_from_track` with the track of ``data``
    (:meth:`scenarios.geometry.TrackSoFar.of`).
    """
    hovering = hovering_problem(data)
    if hovering is not None:
        return Estimate.failed(estimator, hovering, **dict(diagnostics or {}))
    return finalize_from_track(
        estimator,
        candidates_m,
        costs,
        TrackSoFar.of(data),
        rng=rng,
        side_prior_m=side_prior_m,
        cost_rtol=cost_rtol,
        covariance_m2=covariance_m2,
        message=message,
        diagnostics=diagnostics,
    )


def finalize_from_track(
    estimator: str,
    candidates_m: ArrayLike,
    costs: ArrayLike,
    track: TrackSoFar,
    *,
    rng: np.random.Generator | None = None,
    side_prior_m: ArrayLike | None = None,
    cost_rtol: float = 1e-6,
    covariance_m2: ArrayLike | None = None,
    message: str = "",
    diagnostics: Mapping[str, Any] | None = None,
) -> Estimate:
    """:func:`finalize_estimate` from what a state keeps of the samples, not the samples.

    A streaming estimator (:class:`SequentialEstimator`) has no data in ``estimate_state``: it
    keeps a :class:`~scenarios.geometry.TrackSoFar` in its state (``TrackSoFar.of(frame)`` on
    the first frame, ``track.extended(frame)`` on each next one) with its candidates and their
    costs, and finishes here exactly as :func:`finalize_estimate` does on the data (MATH §7):

    1. on a straight track (``track.straight`` not None) each candidate's mirror image across
       it is added, at the same cost, and the answer is ambiguous;
    2. candidates closer than ``MERGE_RTOL`` (1e-9) of their largest distance from
       ``track.centre_m`` are one point (the cheaper, or the first given, is kept);
    3. the candidates within ``cost_rtol`` of the best cost are kept, best first, and the
       returned one is picked by :func:`choose_candidate` (``side_prior_m``, else a fair coin
       from ``rng`` on a tie, else the best).

    ``covariance_m2`` belongs to the returned position (the error covariance given its side is
    right; the comparison reflects it, ``R P Rᵀ``, for the mirror candidate, MATH §7 and §16).
    ``diagnostics`` gain ``straight_track``.
    """
    check_rng(rng)
    points = candidate_points(candidates_m)
    cost = np.asarray(costs, dtype=float).reshape(-1)
    line = track.straight
    final = finalize_columns(
        points[None],
        np.array([len(points)]),
        cost[None],
        track.centre_m,
        None if line is None else (line.origin_m, line.direction),
        side_prior_m=side_prior_m,
        cost_rtol=cost_rtol,
        ceiling_m=track.highest_m,
    )
    if final.invalid[0]:
        return Estimate.failed(
            estimator,
            final.problem
            or f"no finite candidate{_BELOW[points.shape[1]]} among {len(points)} (MATH §7)",
            **dict(diagnostics or {}),
        )
    kept = final.candidates[0, : final.n_candidates[0]]
    position = kept[_drawn(final, rng)]
    return Estimate(
        estimator=estimator,
        position_m=position,
        candidates_m=kept,
        ambiguous=bool(final.ambiguous[0]),
        covariance_m2=covariance_m2,
        success=True,
        message=message,
        diagnostics=dict(diagnostics or {}, straight_track=line is not None),
    )
