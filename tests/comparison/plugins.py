"""Test plug-in estimators shared by the engine's tests (named ``tests.comparison.plugins:Name``
in experiments)."""

from __future__ import annotations

import dataclasses
import os
import sys
from typing import ClassVar

from estimators.closed_form.cls import Cls
from estimators.sequential.ekf import Ekf


@dataclasses.dataclass(frozen=True)
class PerTrialCls:
    """``cls`` one trial at a time (no batch capability): what a wrapper calling
    ``Cls().estimate`` records; the batch's rows equal it to the bit."""

    name: ClassVar[str] = "per-trial-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        return Cls().estimate(data, rng=rng)


PER_TRIAL_CLS = [
    {"name": "tests.comparison.plugins:PerTrialCls", "label": "cls"},
    {"name": "cls-paper"},
]
"""The smoke experiment's estimators with ``cls`` called one trial at a time."""


# --------------------------------------------------------------------------------------------
# estimators that change the data they are given (tests/comparison/test_isolation.py)
# --------------------------------------------------------------------------------------------


def _writable(values):
    """``values`` made writeable, through its ``.base`` when it is a view of one."""
    target = values if values.base is None else values.base
    target.flags.writeable = True
    return target


@dataclasses.dataclass(frozen=True)
class SetsAttribute(PerTrialCls):
    """``cls`` one trial at a time, after replacing the data's Doppler (``object.__setattr__``)."""

    name: ClassVar[str] = "sets-attribute"

    def estimate(self, data, *, rng=None):
        object.__setattr__(data, "doppler_hz", data.doppler_hz + 5.0)
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True)
class WritesThroughBase(PerTrialCls):
    """``cls`` one trial at a time, after adding 1 µs to the ToA of every trial in place, made
    writeable through the array's ``.base`` when it has one."""

    name: ClassVar[str] = "writes-through-base"

    def estimate(self, data, *, rng=None):
        toa = _writable(data.toa_s)
        toa += 1e-6
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True)
class ChangesNoise(PerTrialCls):
    """``cls`` one trial at a time, after doubling the geometry's Doppler σ (a part of the data
    every trial shares)."""

    name: ClassVar[str] = "changes-noise"

    def estimate(self, data, *, rng=None):
        object.__setattr__(data.noise, "doppler_hz", 2.0 * data.noise.doppler_hz)
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ChangesColumns(Cls):
    """``cls`` on columns, after adding 1 Hz to the whole batch's Doppler in place."""

    def estimate_columns(self, batch, *, rngs=None):
        doppler = _writable(batch.doppler_hz)
        doppler += 1.0
        return super().estimate_columns(batch, rngs=rngs)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ChangesBatch(Cls):
    """``cls`` through ``estimate_batch`` (no columns), after moving the geometry's UAV
    positions 1 m east in place."""

    estimate_columns = None  # the engine then calls estimate_batch

    def estimate_batch(self, batch, *, rngs=None):
        position = _writable(batch.geometry.position_m)
        position[:, 0] += 1.0
        return Cls().estimate_batch(batch, rngs=rngs)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ChangesInUpdate(Ekf):
    """``ekf``, whose ``update`` doubles its frame's ToA σ (the noise every frame shares)
    before using it."""

    def update(self, state, frame):
        object.__setattr__(frame.noise, "toa_s", 2.0 * frame.noise.toa_s)
        return super().update(state, frame)


# --------------------------------------------------------------------------------------------
# estimators that change the process they run in (tests/comparison/test_isolation.py)
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ChangesDirectory(PerTrialCls):
    """``cls`` one trial at a time, after moving the process to the root folder."""

    name: ClassVar[str] = "changes-directory"

    def estimate(self, data, *, rng=None):
        os.chdir("/")
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True)
class ClosesStdout(PerTrialCls):
    """``cls`` one trial at a time, after closing ``sys.stdout``."""

    name: ClassVar[str] = "closes-stdout"

    def estimate(self, data, *, rng=None):
        sys.stdout.close()
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True)
class LowersRecursionLimit(PerTrialCls):
    """``cls`` one trial at a time, after lowering the recursion limit to 5 frames above the
    current depth (the least Python accepts)."""

    name: ClassVar[str] = "lowers-recursion-limit"

    def estimate(self, data, *, rng=None):
        estimate = Cls().estimate(data, rng=rng)
        depth, frame = 0, sys._getframe()
        while frame is not None:
            depth, frame = depth + 1, frame.f_back
        sys.setrecursionlimit(depth + 5)
        return estimate


@dataclasses.dataclass(frozen=True)
class Talks(PerTrialCls):
    """``cls`` one trial at a time, printing a line before it estimates."""

    name: ClassVar[str] = "talks"

    def estimate(self, data, *, rng=None):
        print("a line the estimator prints")
        return Cls().estimate(data, rng=rng)
