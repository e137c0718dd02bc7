"""Estimates of a whole batch of trials as columns.

:class:`BatchEstimates` holds what a list of :class:`~estimators.base.Estimate` holds, one
array per field with the trials along the first axis, so that a run can store a batch's
results without building an object per trial. :meth:`BatchEstimates.estimate` builds the
per-trial :class:`~estimators.base.Estimate` on demand; ``estimate_batch`` of a batch-capable
estimator returns :meth:`BatchEstimates.to_estimates`.
The mirror rule applied to columns is :func:`estimators.mirror_rule.finalize_columns`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate, check_rng
from estimators.validity import (
    invalid_estimates,
    numeric_array,
    position_dimension,
    real_part,
    refused_message,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

_ARRAYS = (
    "position_m",
    "candidates_m",
    "n_candidates",
    "ambiguous",
    "success",
    "message_code",
    "covariance_m2",
)
"""The per-trial columns of :class:`BatchEstimates` (the diagnostics besides)."""


@dataclass(frozen=True, slots=True, eq=False)
class BatchEstimates:
    """The estimates of ``n`` trials, field by field (see :class:`~estimators.base.Estimate`).

    Attributes
    ----------
    estimator : str
    position_m : (n, d)
        NaN where ``success`` is false; ``d`` is 2, or 3 with the height estimated
        (:data:`~estimators.validity.POSITION_DIMENSIONS`).
    candidates_m : (n, k, d)
        Trial ``i``'s candidates are ``candidates_m[i, :n_candidates[i]]``; NaN beyond.
    n_candidates : (n,)
    ambiguous, success : (n,) bool
    message_code : (n,) int
        Trial ``i``'s message is ``messages[message_code[i]]``.
    messages : tuple of str
    diagnostics : mapping of str to (n,) arrays
        One column per diagnostics key, in the estimator's key order; a failed trial has
        no diagnostics. Every successful trial has the same keys (those of the columns); an
        estimator whose successful trials differ in their keys cannot be held as columns.
    covariance_m2 : (n, d, d) or None

    The arrays are made read-only (not copied): a result is a value. Built, the columns obey
    the rules of :mod:`estimators.validity`, checked on every trial at once: a trial that
    breaks one is a failure whose message names the rule, as :class:`~estimators.base.Estimate`
    makes it (the columns are then copied, as they are when a value is complex or an integer).
    """

    estimator: str
    position_m: FloatArray
    candidates_m: FloatArray
    n_candidates: IntArray
    ambiguous: BoolArray
    success: BoolArray
    message_code: IntArray
    messages: tuple[str, ...]
    diagnostics: Mapping[str, NDArray[Any]] = field(default_factory=dict)
    covariance_m2: FloatArray | None = None

    def __post_init__(self) -> None:
        n = len(self.position_m)
        d = position_dimension(np.shape(self.position_m)[-1]) if np.ndim(self.position_m) else 2
        columns = {
            "position_m": (self.position_m, (n, d)),
            "candidates_m": (self.candidates_m, (n, None, d)),
            "n_candidates": (self.n_candidates, (n,)),
            "ambiguous": (self.ambiguous, (n,)),
            "success": (self.success, (n,)),
            "message_code": (self.message_code, (n,)),
        }
        if self.covariance_m2 is not None:
            columns["covariance_m2"] = (self.covariance_m2, (n, d, d))
        for key, value in self.diagnostics.items():
            columns[f"diagnostics[{key!r}]"] = (value, (n,))
        for name, (value, shape) in columns.items():
            if np.ndim(value) != len(shape) or any(
                want is not None and got != want
                for got, want in zip(np.shape(value), shape, strict=True)
            ):
                raise ValueError(f"{name}: expected shape {shape}, got {np.shape(value)}")
        if np.any(self.n_candidates > self.candidates_m.shape[1]):
            raise ValueError("n_candidates: more candidates than candidates_m holds")
        if len(self.message_code) and (
            np.min(self.message_code) < 0 or np.max(self.message_code) >= len(self.messages)
        ):
            raise ValueError("message_code: an index outside messages")
        self._refuse_invalid()
        for name in _ARRAYS:
            value = getattr(self, name)
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
        for value in self.diagnostics.values():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False

    def _refuse_invalid(self) -> None:
        """Apply the rules of :mod:`estimators.validity` to every trial: a trial that breaks
        one becomes a failure (NaN position, no candidates, NaN covariance, no diagnostics)
        whose message names the rule, as :class:`~estimators.base.Estimate` does to itself.
        The columns are copied only when a trial is refused or a value is not a float."""
        set_ = object.__setattr__
        for name in ("position_m", "candidates_m", "covariance_m2"):
            value = getattr(self, name)
            if value is not None:
                array = np.asarray(value)
                set_(self, name, array if array.dtype.kind in "fc" else numeric_array(value, name))
        reasons = invalid_estimates(
            self.position_m, self.candidates_m, self.n_candidates, self.covariance_m2, self.success
        )
        if reasons:
            refused = np.fromiter(reasons, dtype=np.int64, count=len(reasons))
            messages = list(self.messages)
            known: dict[str, int] = {}
            for code, text in enumerate(messages):
                known.setdefault(text, code)
            codes = np.array(self.message_code, dtype=np.int64)
            for i, reason in reasons.items():
                text = refused_message(reason, messages[codes[i]])
                if text not in known:
                    known[text] = len(messages)
                    messages.append(text)
                codes[i] = known[text]
            changes: dict[str, Any] = {"message_code": codes, "messages": tuple(messages)}
            for name, blank in (
                ("position_m", np.nan),
                ("candidates_m", np.nan),
                ("covariance_m2", np.nan),
                ("n_candidates", 0),
                ("ambiguous", False),
                ("success", False),
            ):
                value = getattr(self, name)
                if value is not None:
                    changes[name] = np.array(value)
                    changes[name][refused] = blank
            for name, value in changes.items():
                set_(self, name, value)
        for name in ("position_m", "candidates_m", "covariance_m2"):
            value = getattr(self, name)
            if value is not None and value.dtype != np.float64:
                set_(self, name, real_part(value))

    @classmethod
    def failed(
        cls,
        n: int,
        message: str = "",
        *,
        estimator: str = "",
        covariance: bool = False,
        dimension: int = 2,
    ) -> BatchEstimates:
        """The columns of ``n`` failed estimates of positions of ``dimension`` coordinates,
        each with ``message`` (and a NaN covariance column when ``covariance``):
        :meth:`Estimate.failed <estimators.base.Estimate.failed>` for a whole batch."""
        d = dimension
        return cls(
            estimator=estimator,
            position_m=np.full((n, d), np.nan),
            candidates_m=np.full((n, 0, d), np.nan),
            n_candidates=np.zeros(n, dtype=np.int64),
            ambiguous=np.zeros(n, dtype=bool),
            success=np.zeros(n, dtype=bool),
            message_code=np.zeros(n, dtype=np.int64),
            messages=(message,),
            covariance_m2=np.full((n, d, d), np.nan) if covariance else None,
        )

    @classmethod
    def from_estimates(cls, estimator: str, estimates: Sequence[Estimate]) -> BatchEstimates:
        """The columns of per-trial estimates of one estimator (the diagnostics keys of the
        successful ones must agree: :meth:`with_trials`)."""
        n = len(estimates)
        covariance = any(e.covariance_m2 is not None for e in estimates)
        dimensions = {len(e.position_m) for e in estimates} or {2}
        if len(dimensions) > 1:
            raise ValueError(
                f"position_m: the trials' positions have {sorted(dimensions)} coordinates; one "
                "estimator returns the same number for every trial"
            )
        empty = cls.failed(
            n, estimator=estimator, covariance=covariance, dimension=dimensions.pop()
        )
        return empty.with_trials(range(n), estimates)

    def __len__(self) -> int:
        return len(self.position_m)

    def message(self, index: int) -> str:
        return self.messages[int(self.message_code[index])]

    def estimate(self, index: int) -> Estimate:
        """Trial ``index`` as an :class:`~estimators.base.Estimate`."""
        success = bool(self.success[index])
        diagnostics = (
            {key: _python_scalar(value[index]) for key, value in self.diagnostics.items()}
            if success
            else {}
        )
        return Estimate(
            estimator=self.estimator,
            position_m=self.position_m[index],
            candidates_m=self.candidates_m[index, : self.n_candidates[index]],
            ambiguous=bool(self.ambiguous[index]),
            covariance_m2=None if self.covariance_m2 is None else self.covariance_m2[index],
            success=success,
            message=self.message(index),
            diagnostics=diagnostics,
        )

    def to_estimates(self) -> list[Estimate]:
        """One :class:`~estimators.base.Estimate` per trial, in trial order."""
        return [self.estimate(index) for index in range(len(self))]

    def with_trials(self, index: Sequence[int], estimates: Sequence[Estimate]) -> BatchEstimates:
        """A copy with trials ``index`` replaced by ``estimates`` (e.g. failures found late).

        A successful replacement must carry the same diagnostics keys as every other
        successful trial: those of the columns while a trial not replaced keeps its
        diagnostics, else those of the first successful replacement (when every success is
        replaced, the columns' own keys describe no trial). Raises ``ValueError`` naming the
        trial otherwise.
        """
        if len(index) == 0:
            return self
        width = max([self.candidates_m.shape[1], *(len(e.candidates_m) for e in estimates)])
        candidates = np.full((len(self), width, self.position_m.shape[1]), np.nan)
        candidates[:, : self.candidates_m.shape[1]] = self.candidates_m
        position = self.position_m.copy()
        n_candidates = self.n_candidates.copy()
        ambiguous = self.ambiguous.copy()
        success = self.success.copy()
        code = self.message_code.copy()
        messages = list(self.messages)
        diagnostics = {key: value.copy() for key, value in self.diagnostics.items()}
        kept = self.success.copy()
        kept[np.asarray(index, dtype=np.int64)] = False
        successes = [e.diagnostics for e in estimates if e.success]
        if successes and not kept.any():
            diagnostics = {
                key: _column([d.get(key) for d in successes], len(self)) for key in successes[0]
            }
        covariance = None if self.covariance_m2 is None else self.covariance_m2.copy()
        for i, estimate in zip(index, estimates, strict=True):
            position[i] = estimate.position_m
            count = len(estimate.candidates_m)
            candidates[i] = np.nan
            candidates[i, :count] = estimate.candidates_m
            n_candidates[i] = count
            ambiguous[i] = estimate.ambiguous
            success[i] = estimate.success
            if estimate.message not in messages:
                messages.append(estimate.message)
            code[i] = messages.index(estimate.message)
            if covariance is not None:
                covariance[i] = np.nan if estimate.covariance_m2 is None else estimate.covariance_m2
            if estimate.success:
                if set(estimate.diagnostics) != set(diagnostics):
                    raise ValueError(
                        f"diagnostics: trial {i} has keys {sorted(estimate.diagnostics)}, "
                        f"the columns {sorted(diagnostics)}"
                    )
                for key, value in estimate.diagnostics.items():
                    diagnostics[key][i] = value
        return BatchEstimates(
            estimator=self.estimator,
            position_m=position,
            candidates_m=candidates,
            n_candidates=n_candidates,
            ambiguous=ambiguous,
            success=success,
            message_code=code,
            messages=tuple(messages),
            diagnostics=diagnostics,
            covariance_m2=covariance,
        )


def _column(examples: Sequence[Any], n: int) -> NDArray[Any]:
    """An empty diagnostics column for values like ``examples``: typed when they are numbers
    of one type, else objects (which hold any value as it is)."""
    types = {type(example) for example in examples}
    if len(types) == 1 and issubclass(types.pop(), bool | int | float | np.bool_ | np.number):
        return np.zeros(n, dtype=np.asarray(examples[0]).dtype)
    return np.zeros(n, dtype=object)


def _python_scalar(value: Any) -> Any:
    """A numpy scalar as Python's; a list (a column may share one among trials) copied."""
    if isinstance(value, list):
        return list(value)
    return value.item() if isinstance(value, np.generic) else value


class TrialGenerators(Sequence[np.random.Generator]):
    """One tie-breaking generator per trial, each made when it is first read.

    What a run hands to a batch of ``n`` trials as ``rngs``: a sequence (``len``, indexing,
    iteration) whose item ``i`` is ``make(i)``, made once and kept. A generator costs some
    12 µs to seed (:class:`numpy.random.SeedSequence` and PCG64), more than a closed form's
    estimate in batch, and most trials never draw (a draw breaks a tie of the mirror rule,
    MATH §7): the generators of the trials that do not are never made. Trial ``i`` reads the
    same generator, in the same state, as from a list made in advance."""

    __slots__ = ("_made", "_make")

    def __init__(self, n: int, make: Callable[[int], np.random.Generator]) -> None:
        self._make = make
        self._made: list[np.random.Generator | None] = [None] * n

    def __len__(self) -> int:
        return len(self._made)

    @overload
    def __getitem__(self, index: int) -> np.random.Generator: ...

    @overload
    def __getitem__(self, index: slice) -> list[np.random.Generator]: ...

    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return [self[i] for i in range(len(self._made))[index]]
        i = range(len(self._made))[index]  # an IndexError as a list's, negatives counted back
        made = self._made[i]
        if made is None:
            made = self._made[i] = self._make(i)
        return made


def check_rngs(
    rngs: Sequence[np.random.Generator | None] | None, n: int
) -> Sequence[np.random.Generator | None]:
    """One generator (or None) per trial; ``None`` for all when ``rngs`` is None. A
    :class:`TrialGenerators` is taken as it is (its items are generators by construction),
    so that the generators no trial reads are never made."""
    if rngs is None:
        return [None] * n
    if isinstance(rngs, TrialGenerators):
        if len(rngs) != n:
            raise ValueError(f"rngs: expected one generator per trial ({n}), got {len(rngs)}")
        return rngs
    if isinstance(rngs, np.random.Generator) or not isinstance(rngs, Sequence):
        raise TypeError(
            f"rngs: expected a list of numpy.random.Generator (one per trial) or None, got "
            f"{type(rngs).__name__}"
        )
    if len(rngs) != n:
        raise ValueError(f"rngs: expected one generator per trial ({n}), got {len(rngs)}")
    if not set(map(type, rngs)) <= {np.random.Generator, type(None)}:
        for rng in rngs:
            check_rng(rng)
    return list(rngs)


class EstimatesOfColumns:
    """``estimate_batch`` of an estimator that computes ``estimate_columns``: the same columns
    as one :class:`~estimators.base.Estimate` per trial (written once for the built-ins)."""

    def estimate_columns(
        self,
        batch: Any,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> BatchEstimates:
        raise NotImplementedError

    def estimate_batch(
        self,
        batch: Any,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> list[Estimate]:
        """``estimate`` of every trial (trial ``i`` with ``rngs[i]``), solved together."""
        return self.estimate_columns(batch, rngs=rngs).to_estimates()
