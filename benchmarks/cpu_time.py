"""The benchmarks' clock: the least CPU time of this process (``time.process_time``) over a few
runs, so that other processes on the machine count as little as they can."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def best_cpu_s(run: Callable[[], Any], repeats: int = 3) -> float:
    """Least CPU time of ``repeats`` calls of ``run``, in seconds."""
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        run()
        best = min(best, time.process_time() - start)
    return best


def best_cpu_us(run: Callable[[], Any], count: int, repeats: int = 3) -> float:
    """:func:`best_cpu_s` per item, in microseconds, when one call of ``run`` does ``count``."""
    return best_cpu_s(run, repeats) / count * 1e6
