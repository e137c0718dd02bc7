"""Test plug-in estimators shared by the engine's tests (named ``tests.comparison.plugins:Name``
in experiments)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from estimators.cls import Cls


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
