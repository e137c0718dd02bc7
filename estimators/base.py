"""The common estimator interface and its one result type.

An estimator is any object with a ``name``, the set of modalities it ``requires`` and an
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
  with ``estimate_state(state) -> Estimate``; no mutable filter object leaks out.

Constructors take keyword-only hyper-parameters and only store them (scikit-learn's rule);
the built-ins are frozen dataclasses. A failure to estimate is data (``success=False`` and a
``message``), not an exception; malformed input raises ``ValueError`` naming the field.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
State = TypeVar("State")


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Estimate:
    """What an estimator returns (a frozen ``scipy.optimize.OptimizeResult``).

    Attributes
    ----------
    estimator : str
        Registry name of the estimator.
    position_m : (2,)
        The returned emitter position ``(x_s, y_s)``; NaN when ``success`` is false.
    candidates_m : (n, 2)
        Every minimiser of equal cost, ``position_m`` among them (MATH §7). Two mirror
        images on one straight frame, one point once a turn resolves the side.
    ambiguous : bool
        True when the data cannot tell the side of the track (MATH §7): every sample on one
        straight line, or several candidates of equal cost. ``position_m`` is then a guess,
        even when the single candidate lies on the track and is its own mirror image.
    covariance_m2 : (2, 2) or None
        The estimator's own error covariance, when it has one.
    success : bool
    message : str
        Why it failed, or notes on a success (rank deficiency, hard case, ...).
    diagnostics : mapping
        Scalars such as the Lagrange multiplier, hard case, rank, iterations.
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
        position = np.array(self.position_m, dtype=float).reshape(2)
        candidates = np.array(self.candidates_m, dtype=float).reshape(-1, 2)
        position.flags.writeable = False
        candidates.flags.writeable = False
        object.__setattr__(self, "position_m", position)
        object.__setattr__(self, "candidates_m", candidates)
        object.__setattr__(self, "ambiguous", bool(self.ambiguous))
        object.__setattr__(self, "success", bool(self.success))
        if self.covariance_m2 is not None:
            covariance = np.array(self.covariance_m2, dtype=float).reshape(2, 2)
            covariance.flags.writeable = False
            object.__setattr__(self, "covariance_m2", covariance)
        object.__setattr__(self, "diagnostics", dict(self.diagnostics))

    @classmethod
    def failed(cls, estimator: str, message: str, **diagnostics: Any) -> Estimate:
        """A failed estimate: NaN position, no candidates, the reason in ``message``."""
        return cls(
            estimator=estimator,
            position_m=np.full(2, np.nan),
            candidates_m=np.empty((0, 2)),
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


@dataclass(frozen=True, slots=True, kw_only=True)
class Capabilities:
    """What an estimator uses and claims, declared by the estimator (``capabilities()``).

    The comparison reads only this to score an estimator against the right bound (the CRLB of
    the modalities and frames it uses, MATH §8), to check what it needs is installed and to
    feed it batches or frames; the conformance suite (:mod:`estimators.checks`) checks every
    field against what the estimator does.

    Attributes
    ----------
    modalities : frozenset of {"doppler", "toa", "rss"}
        Every modality the estimate depends on: the required ones (``requires``) and the
        optional ones it uses when they are present (e.g. ``ml(use_rss=True)`` adds ``rss``).
    frames : "all", "last" or tuple of int
        The frames of the data it uses: every frame so far, only the last, or those listed.
    modules : tuple of str
        Importable modules it needs (``("gtsam",)``); checked before a run starts.
    batch : bool
        It has ``estimate_batch(batch, *, rngs)`` (:class:`BatchEstimator`).
    sequential : bool
        It has ``init``, ``update`` and ``estimate_state`` (:class:`SequentialEstimator`).
    unit_invariant : bool
        It claims the same answer, scaled, in any consistent unit system (MATH §6).
    noise_free_tolerance_m : float
        Distance from the emitter within which its noise-free candidates are exact; looser
        than the suite's default only with a ``tolerance_reason`` and within the suite's cap.
    tolerance_reason : str
        Why the tolerance is looser than the default (an iterative stop, a grid).
    """

    modalities: frozenset[str]
    frames: str | tuple[int, ...] = "all"
    modules: tuple[str, ...] = ()
    batch: bool = False
    sequential: bool = False
    unit_invariant: bool = False
    noise_free_tolerance_m: float = 1e-6
    tolerance_reason: str = ""

    def __post_init__(self) -> None:
        from scenarios.types import MODALITIES

        modalities = frozenset(self.modalities)
        unknown = sorted(modalities - set(MODALITIES))
        if unknown or not modalities:
            raise ValueError(
                f"modalities: expected a non-empty subset of {sorted(MODALITIES)}, got "
                f"{sorted(modalities)}"
            )
        object.__setattr__(self, "modalities", modalities)
        frames = self.frames
        if isinstance(frames, str):
            if frames not in ("all", "last"):
                raise ValueError(f"frames: expected 'all', 'last' or frame indices, got {frames!r}")
        else:
            object.__setattr__(self, "frames", tuple(int(f) for f in frames))
        object.__setattr__(self, "modules", tuple(str(m) for m in self.modules))
        if not (self.noise_free_tolerance_m > 0 and np.isfinite(self.noise_free_tolerance_m)):
            raise ValueError(
                f"noise_free_tolerance_m: must be a positive finite distance in metres, got "
                f"{self.noise_free_tolerance_m!r}"
            )


def capabilities_of(estimator: Any) -> Capabilities:
    """The estimator's declared :class:`Capabilities`.

    An estimator without a ``capabilities()`` method is taken at its protocol: it uses exactly
    its ``requires``, every frame, the modules of its class attribute ``required_modules``
    (default none), and it is batch or sequential when it has those methods. Nothing is
    inferred from option names.
    """
    declare = getattr(estimator, "capabilities", None)
    if callable(declare):
        declared = declare()
        if not isinstance(declared, Capabilities):
            raise TypeError(
                f"capabilities: {type(estimator).__name__}.capabilities() returned "
                f"{type(declared).__name__}; return an estimators.base.Capabilities"
            )
        return declared
    return Capabilities(
        modalities=frozenset(getattr(estimator, "requires", ())),
        modules=tuple(getattr(type(estimator), "required_modules", ())),
        batch=callable(getattr(estimator, "estimate_batch", None)),
        sequential=all(
            callable(getattr(estimator, m, None)) for m in ("init", "update", "estimate_state")
        ),
    )


def _takes_keyword(method: Any, keyword: str) -> bool:
    try:
        parameters = inspect.signature(method).parameters
    except (TypeError, ValueError):
        return False
    return keyword in parameters or any(
        p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()
    )


def protocol_problems(estimator: Any) -> list[str]:
    """What an object lacks to be used as an estimator by the comparison (empty: nothing).

    ``estimate(data, *, rng)`` (and ``estimate_state(state, *, rng)``,
    ``estimate_batch(batch, *, rngs)`` when declared) must take the generator the runner
    passes for tie-breaking (MATH §7); ``capabilities()`` must return :class:`Capabilities`.
    """
    problems = []
    for attribute in ("name", "requires"):
        if not hasattr(type(estimator), attribute):
            problems.append(f"the class attribute {attribute} is missing")
    if not callable(getattr(estimator, "estimate", None)):
        return [*problems, "estimate(data, *, rng=None) is missing"]
    if not _takes_keyword(estimator.estimate, "rng"):
        problems.append("estimate must take the keyword rng (a numpy Generator or None)")
    try:
        capabilities = capabilities_of(estimator)
    except (TypeError, ValueError) as error:
        return [*problems, str(error)]
    if capabilities.sequential:
        for method in ("init", "update", "estimate_state"):
            if not callable(getattr(estimator, method, None)):
                problems.append(f"capabilities says sequential, but {method}() is missing")
        state = getattr(estimator, "estimate_state", None)
        if callable(state) and not _takes_keyword(state, "rng"):
            problems.append("estimate_state must take the keyword rng")
    if capabilities.batch:
        batch = getattr(estimator, "estimate_batch", None)
        if not callable(batch):
            problems.append("capabilities says batch, but estimate_batch() is missing")
        elif not _takes_keyword(batch, "rngs"):
            problems.append("estimate_batch must take the keyword rngs")
    return problems


@runtime_checkable
class Estimator(Protocol):
    """Locates the emitter from one :class:`~scenarios.types.MeasurementSet`.

    ``rng`` breaks exact ties between equal-cost candidates (MATH §7) and drives any
    randomised method; the runner passes one generator per trial.
    """

    name: ClassVar[str]
    requires: ClassVar[frozenset[str]]

    def estimate(
        self, data: MeasurementSet, *, rng: np.random.Generator | None = None
    ) -> Estimate: ...


@runtime_checkable
class BatchEstimator(Estimator, Protocol):
    """An estimator that is faster on a whole batch of Monte Carlo trials at once."""

    def estimate_batch(
        self, batch: MeasurementBatch, *, rngs: list[np.random.Generator] | None = None
    ) -> list[Estimate]: ...


@runtime_checkable
class SequentialEstimator(Estimator, Protocol[State]):
    """An estimator fed one frame at a time, as a pure ``init``/``update`` pair."""

    def init(self) -> State: ...

    def update(self, state: State, frame: MeasurementSet) -> State: ...

    def estimate_state(
        self, state: State, *, rng: np.random.Generator | None = None
    ) -> Estimate: ...


# --------------------------------------------------------------------------------------------
# helpers shared by the built-in estimators
# --------------------------------------------------------------------------------------------


def require_modalities(estimator: Estimator, data: MeasurementSet) -> None:
    """Raise ``ValueError`` naming the missing measurement field, if any.

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
        fields = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_dbm"}
        names = ", ".join(fields[m] for m in missing)
        raise ValueError(
            f"{names}: estimator {estimator.name!r} needs {', '.join(missing)} measurements; "
            f"add them to the data or choose an estimator that works without them"
        )


def check_rng(rng: Any) -> np.random.Generator | None:
    """Return ``rng`` if it is None or a ``numpy.random.Generator``; else raise ``TypeError``."""
    if rng is None or isinstance(rng, np.random.Generator):
        return rng
    raise TypeError(
        f"rng: expected a numpy.random.Generator or None, got {type(rng).__name__}; "
        "pass numpy.random.default_rng(seed)"
    )


def choose_position(
    candidates_m: ArrayLike,
    costs: ArrayLike,
    *,
    rng: np.random.Generator | None,
    side_prior_m: ArrayLike | None = None,
    cost_rtol: float = 1e-6,
) -> tuple[FloatArray, FloatArray, bool]:
    """Order candidates and pick the returned position (MATH §7).

    Candidates whose cost is within ``cost_rtol`` (relative) of the best are kept, best first.
    With a ``side_prior_m`` the kept candidate nearest to it is returned; otherwise an exact tie
    is broken by ``rng`` (a fair coin: the data hold no side information) or, without one, by
    the lowest cost. Returns ``(position, kept_candidates, ambiguous)``.
    """
    check_rng(rng)
    points = np.asarray(candidates_m, dtype=float).reshape(-1, 2)
    cost = np.asarray(costs, dtype=float).reshape(-1)
    order = np.argsort(cost, kind="stable")
    points, cost = points[order], cost[order]
    best = cost[0]
    floor = np.finfo(float).eps * 64 * max(abs(best), 1.0)
    keep = cost <= best + cost_rtol * abs(best) + floor
    points = points[keep]
    ambiguous = len(points) > 1
    if side_prior_m is not None:
        prior = np.asarray(side_prior_m, dtype=float).reshape(2)
        index = int(np.argmin(np.linalg.norm(points - prior, axis=1)))
    elif ambiguous and rng is not None:
        index = int(rng.integers(len(points)))
    else:
        index = 0
    return points[index], points, ambiguous


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
    ambiguous. Coincident candidates are merged; see :func:`choose_position` for the pick.
    """
    from scenarios.geometry import mirror_across_line, straight_track_line

    points = np.asarray(candidates_m, dtype=float).reshape(-1, 2)
    cost = np.asarray(costs, dtype=float).reshape(-1)
    line = straight_track_line(data.position_m, data.velocity_mps)
    if line is not None:
        points = np.vstack([points, mirror_across_line(points, *line)])
        cost = np.concatenate([cost, cost])
    scale = max(float(np.max(np.abs(points - data.position_m[:, :2].mean(axis=0)))), 1e-300)
    keep: list[int] = []
    for index in np.argsort(cost, kind="stable"):
        if all(np.linalg.norm(points[index] - points[j]) > 1e-9 * scale for j in keep):
            keep.append(int(index))
    position, kept, tied = choose_position(
        points[keep], cost[keep], rng=rng, side_prior_m=side_prior_m, cost_rtol=cost_rtol
    )
    return Estimate(
        estimator=estimator,
        position_m=position,
        candidates_m=kept,
        ambiguous=tied or line is not None,
        covariance_m2=covariance_m2,
        success=True,
        message=message,
        diagnostics=dict(diagnostics or {}, straight_track=line is not None),
    )
