"""How a run calls an estimator: timed, and never raising.

An exception inside an estimator becomes a failed estimate (``success`` false, the exception
in ``message``), so a failure costs one row and never a run; configuration errors are caught
when the experiment loads. Three ways to call:

- :func:`timed_call`, one call of ``estimate`` (or any estimator method);
- :func:`call_batch`, ``estimate_batch`` on a whole chunk, or None when it fails (the caller
  then falls back to one call per trial, so that a row never depends on its neighbours);
- :class:`Stream`, a sequential estimator (``init``/``update``/``estimate_state``) fed frame
  by frame, in the per-frame open loop (:mod:`comparison.tasks`) and in the closed loop
  (:mod:`comparison.closed_loop`) alike.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from estimators.base import Estimate, Estimator
from scenarios.types import MeasurementBatch, MeasurementSet


def timed_call(method: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Estimate, float]:
    """Call an estimator method; an exception or a non-Estimate becomes a failed estimate."""
    start = time.perf_counter()
    try:
        estimate = method(*args, **kwargs)
    except Exception as error:
        estimate = Estimate.failed("", f"{type(error).__name__}: {error}")
    runtime_s = time.perf_counter() - start
    if not isinstance(estimate, Estimate):
        estimate = Estimate.failed(
            "", f"TypeError: returned {type(estimate).__name__}, not an Estimate"
        )
    return estimate, runtime_s


def call_batch(
    estimator: Estimator, batch: MeasurementBatch, rngs: list[np.random.Generator]
) -> list[tuple[Estimate, float]] | None:
    """``estimate_batch`` timed and split evenly, or None (it failed)."""
    start = time.perf_counter()
    try:
        estimates = list(estimator.estimate_batch(batch, rngs=rngs))
    except Exception:
        return None  # retried one trial at a time, so each row gets its own outcome
    runtime_s = (time.perf_counter() - start) / batch.n_trials
    if len(estimates) != batch.n_trials or not all(isinstance(e, Estimate) for e in estimates):
        return None
    return [(estimate, runtime_s) for estimate in estimates]


class Stream:
    """A sequential estimator fed frame by frame: ``init`` now, then :meth:`step` per frame.

    A failed ``init`` fails every frame; a failed ``update`` fails that frame and every later
    one (the state is lost); a failed ``estimate_state`` fails only its frame. ``init``'s time
    is counted in the first frame.
    """

    def __init__(self, estimator: Any) -> None:
        self._estimator = estimator
        self._failure: Estimate | None = None
        self._state: Any = None
        start = time.perf_counter()
        try:
            self._state = estimator.init()
        except Exception as error:
            self._failure = Estimate.failed("", f"{type(error).__name__} in init: {error}")
        self._carried_s = time.perf_counter() - start

    def step(
        self, frame_data: MeasurementSet, rng: np.random.Generator | None
    ) -> tuple[Estimate, float]:
        """``update`` with the samples of the next frame, then ``estimate_state(rng=rng)``.

        Returns the frame's ``(estimate, runtime_s)``.
        """
        carried_s, self._carried_s = self._carried_s, 0.0
        if self._failure is not None:
            return self._failure, carried_s
        start = time.perf_counter()
        try:
            self._state = self._estimator.update(self._state, frame_data)
        except Exception as error:
            self._failure = Estimate.failed("", f"{type(error).__name__} in update: {error}")
            return self._failure, carried_s + time.perf_counter() - start
        update_s = time.perf_counter() - start
        estimate, estimate_s = timed_call(self._estimator.estimate_state, self._state, rng=rng)
        return estimate, carried_s + update_s + estimate_s
