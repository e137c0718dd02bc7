"""What an estimator is: the protocols it satisfies and the capabilities it declares.

An estimator is any object with a ``name``, the set of modalities it ``requires`` and an
``estimate(data, *, rng=None)`` method returning an :class:`~estimators.base.Estimate`
(a ``typing.Protocol``: no inheritance needed). :class:`BatchEstimator` and
:class:`SequentialEstimator` are its two optional extensions; :class:`Capabilities` is what it
declares to the comparison, read by :func:`capabilities_of`, and :func:`protocol_problems`
says in words what an object lacks. These names are also importable from
:mod:`estimators.base`, where plug-ins have always found them.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeVar, runtime_checkable

import numpy as np

from scenarios.nuisance import parse_unknowns
from scenarios.types import MeasurementBatch, MeasurementSet

if TYPE_CHECKING:
    from estimators.base import Estimate

State = TypeVar("State")


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
    unknowns : frozenset of {"carrier_offset_hz", "emission_time_s"}
        The nuisance parameters of a non-cooperative emitter it estimates alongside the
        emitter (MATH §15). Data declaring an unknown it does not handle, in a modality it
        uses, are refused (:func:`require_modalities`).
    """

    modalities: frozenset[str]
    frames: str | tuple[int, ...] = "all"
    modules: tuple[str, ...] = ()
    batch: bool = False
    sequential: bool = False
    unit_invariant: bool = False
    noise_free_tolerance_m: float = 1e-6
    tolerance_reason: str = ""
    unknowns: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        from scenarios.types import MODALITIES

        object.__setattr__(self, "unknowns", frozenset(parse_unknowns(self.unknowns)))

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
    """An estimator that is faster on a whole batch of Monte Carlo trials at once.

    Trial ``i`` of ``estimate_batch(batch, rngs=rngs)`` must equal
    ``estimate(batch.trial(i), rng=rngs[i])``, tie-break included, and must not depend on the
    other trials of the batch. The built-ins equal it to rounding, at a tolerance from the
    problem's conditioning (``estimate`` of the closed forms is their batch of one, ``ml``'s
    batch performs MINPACK's operations in MINPACK's order, ``sdp-cls`` solves each trial
    alone; a batch of one and a batch of many, or two CPUs, may still round a sum otherwise),
    so a run's rows depend on its chunking or on a fallback to one call per trial only in
    their last digits, a plug-in's as the built-ins'. An estimator may also offer
    ``estimate_columns(batch, *, rngs)`` returning :class:`estimators.batch.BatchEstimates`:
    the same results as columns (one array per field, diagnostics as arrays, messages as
    codes), with no object per trial; the engine stores those directly.

    ``rngs`` is a sequence with one generator per trial (a run passes
    :class:`estimators.batch.TrialGenerators`: indexed, iterated and measured as a list, each
    generator made when first read).
    """

    def estimate_batch(
        self, batch: MeasurementBatch, *, rngs: Sequence[np.random.Generator] | None = None
    ) -> list[Estimate]: ...


@runtime_checkable
class SequentialEstimator(Estimator, Protocol[State]):
    """An estimator fed one frame at a time, as a pure ``init``/``update`` pair.

    ``estimate_state`` has no data: it finishes with :func:`finalize_from_track` on the
    :class:`~scenarios.geometry.TrackSoFar` the state keeps (the mirror rule of MATH §7, as
    :func:`finalize_estimate` applies it to data).
    """

    def init(self) -> State: ...

    def update(self, state: State, frame: MeasurementSet) -> State: ...

    def estimate_state(
        self, state: State, *, rng: np.random.Generator | None = None
    ) -> Estimate: ...
