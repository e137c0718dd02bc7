"""Cost of the validity rules of an estimate (:mod:`estimators.validity`).

- ``columns``: :func:`~estimators.validity.invalid_estimates` on the columns of 10,000 valid
  ``ml``-like trials (two candidates each, a covariance), the check every
  :class:`~estimators.batch.BatchEstimates` runs when it is built; and the whole construction
  of those columns, the check included;
- ``one Estimate``: building one :class:`~estimators.base.Estimate` with two candidates and a
  covariance (the check on a stack of one included), and the check alone.

CPU time of this process (``time.process_time``), BLAS on one thread, best of five. Printed:
microseconds per trial.

Run: ``python benchmarks/bench_validity.py``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402
from cpu_time import best_cpu_us  # noqa: E402

from estimators.base import Estimate  # noqa: E402
from estimators.batch import BatchEstimates  # noqa: E402
from estimators.validity import invalid_estimates  # noqa: E402

REPEATS = 5


def _cpu_us(run: Callable[[], Any], count: int) -> float:
    """:func:`cpu_time.best_cpu_us` of ``REPEATS`` runs."""
    return best_cpu_us(run, count, REPEATS)


N = 10_000


def valid_columns(n: int) -> dict[str, Any]:
    """``n`` valid trials: a mirror pair each (the position the first), a covariance."""
    rng = np.random.default_rng(0)
    position = rng.normal(size=(n, 2)) * 100.0
    candidates = np.stack([position, position * [1.0, -1.0]], axis=1)
    factor = rng.normal(size=(n, 2, 2))
    covariance = factor @ np.swapaxes(factor, 1, 2) + np.eye(2)
    return {
        "estimator": "bench",
        "position_m": position,
        "candidates_m": candidates,
        "n_candidates": np.full(n, 2, dtype=np.int64),
        "ambiguous": np.ones(n, dtype=bool),
        "success": np.ones(n, dtype=bool),
        "message_code": np.zeros(n, dtype=np.int64),
        "messages": ("",),
        "covariance_m2": covariance,
    }


def main() -> None:
    columns = valid_columns(N)
    fields = {key: columns[key] for key in ("position_m", "candidates_m", "n_candidates")}
    check = _cpu_us(
        lambda: invalid_estimates(
            **fields, covariance_m2=columns["covariance_m2"], success=columns["success"]
        ),
        N,
    )
    build = _cpu_us(
        lambda: BatchEstimates(
            **{k: np.array(v) if k != "messages" else v for k, v in columns.items()}
        ),
        N,
    )
    print(f"columns of {N} trials: the check {check:.3f} µs a trial, building them {build:.3f}")
    one = {
        key: np.array(value[0])
        for key, value in columns.items()
        if key not in ("estimator", "messages")
    }

    def build_one() -> None:
        for _ in range(2000):
            Estimate(
                estimator="bench",
                position_m=one["position_m"],
                candidates_m=one["candidates_m"],
                ambiguous=True,
                covariance_m2=one["covariance_m2"],
            )

    def check_one() -> None:
        for _ in range(2000):
            invalid_estimates(
                one["position_m"][None],
                one["candidates_m"][None],
                [2],
                one["covariance_m2"][None],
                [True],
            )

    print(
        f"one Estimate: building it {_cpu_us(build_one, 2000):.1f} µs, "
        f"the check alone {_cpu_us(check_one, 2000):.1f} µs"
    )


if __name__ == "__main__":
    main()
