"""Time per estimate of ``sdp-cls`` (MATH §11), one trial at a time and as a batch, against
Clarabel's own solve time and ``cls``.

For every scenario, on the same trials:

- one at a time: ``SdpCls().estimate(trial)`` per trial, the median time per estimate and the
  median over trials of (time / Clarabel's own time for that estimate);
- batch: ``SdpCls().estimate_columns(batch)`` on all trials, repeated ``--repeats`` times; the
  time per estimate is the call's time over the number of trials, Clarabel's own time is the
  sum of ``diagnostics["estimate_solve_time_s"]`` (the solver's ``solve_time`` from its solve
  information, every stage and tolerance rung) over the trials, and the ratio is their
  quotient; the repeat with the median ratio is shown;
- ``cls``: the closed form of MATH §5 on the same rows, one at a time (median) and as a batch;
- cvxpy, for reference (on the first ``--cvxpy-trials`` trials): a plain transcription of the
  same two-stage estimate, each stage's program of MATH §11 written as a fresh
  ``cvxpy.Problem`` on the same whitened data and solved by Clarabel at the same settings
  (:func:`cvxpy_estimate`), the median time per estimate and of its ratio to Clarabel's own
  time as cvxpy reports it (``solver_stats.solve_time``);
- with ``--breakdown``, the batch path's time per estimate by part (a separate pass with
  timing wrappers, about a microsecond per wrapped call): the rows of every trial (the shared
  geometry and :class:`~estimators.sdp.sdp_lift.ChunkRows`), the QR compression and whitening,
  the Clarabel call (building the solver and solving), the recovery and costs, the mirror
  rule and draws, and the rest (the per-trial loop around Clarabel, status bookkeeping,
  diagnostics).

Run::

    python benchmarks/bench_sdp.py [--trials N] [--snr-db S] [--seed S] [--repeats R]
        [--cvxpy-trials N] [--breakdown] [--scenarios NAME ...]

Timings depend on the machine and its load; nothing here is a pass/fail criterion.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from unittest import mock

import numpy as np

import estimators.sdp.sdp_cls as sdp_cls
import estimators.sdp.sdp_lift as sdp_lift
import estimators.sdp.sdp_solvers as sdp_solvers
from estimators.closed_form.cls import Cls, cls_rows
from estimators.closed_form.cls_batch import SharedGeometry
from estimators.closed_form.cls_rows import LocalFrame
from estimators.sdp.sdp_cls import SdpCls
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds

SCENARIOS = ("paper-1m", "paper-1m-turn", "turn")


def _timed(call: Callable[[], object]) -> tuple[float, object]:
    started = time.perf_counter()
    result = call()
    return time.perf_counter() - started, result


PARTS: dict[str, tuple[tuple[object, str], ...]] = {
    "rows": ((SharedGeometry, "of"), (sdp_lift.ChunkRows, "systems")),
    "QR + whitening": ((sdp_cls, "compress_stacked"), (sdp_cls, "whiten_batch")),
    "Clarabel call": ((sdp_solvers, "run_clarabel"),),
    "recovery + costs": ((sdp_cls, "read_lifts"),),
    "mirror rule": ((sdp_cls, "_decide"),),
}
"""The parts of the batch path timed by ``--breakdown``: the functions each one covers."""


@contextlib.contextmanager
def timing_parts(spent: dict[str, float]) -> Iterator[None]:
    """Wrap the functions of :data:`PARTS`, adding their wall time to ``spent[part]``."""

    def timed(function, part):
        def wrapper(*args, **kwargs):
            started = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[part] += time.perf_counter() - started

        return wrapper

    with contextlib.ExitStack() as stack:
        for part, targets in PARTS.items():
            for owner, name in targets:
                function = getattr(owner, name)
                if isinstance(owner, type) and hasattr(function, "__func__"):
                    wrapped = classmethod(timed(function.__func__, part))  # a classmethod
                else:
                    wrapped = timed(function, part)
                stack.enter_context(mock.patch.object(owner, name, wrapped))
        yield


def breakdown(batch, trials: int) -> dict[str, float]:
    """The batch path's time per estimate by part of :data:`PARTS`, the rest, and the whole."""
    spent: dict[str, float] = defaultdict(float)
    with timing_parts(spent):
        seconds, _ = _timed(lambda: SdpCls().estimate_columns(batch))
    parts = {part: spent[part] / trials for part in PARTS}
    return parts | {"rest": seconds / trials - sum(parts.values()), "total": seconds / trials}


def cvxpy_estimate(data) -> tuple[float, float]:
    """One estimate through a plain cvxpy transcription: the wall time and Clarabel's own time.

    Both stages of ``SdpCls()`` (weighted rows, stage 2 weighted at the first stage-1
    point): the rows of :func:`estimators.closed_form.cls.cls_rows`, the same compression and
    whitening, then a new ``cvxpy.Problem`` over a symmetric 4×4 ``W`` with ``W ⪰ 0``, ``W₄₄ = 1``
    and ``tr(C W) = 0``, solved by Clarabel at the tight rung's settings, and the recovery of
    :mod:`estimators.sdp.sdp_lift`. The position is not kept: only the times are compared.
    """
    import cvxpy as cp

    settings = sdp_solvers.solver_attempts("CLARABEL", None)[0]
    started = time.perf_counter()
    solver_time, weights_at = 0.0, None
    frame = LocalFrame.fit(data.position_m, data.range_m)
    for _stage in range(2):
        A, b = cls_rows(data, frame, "weighted", weights_at_local_xy=weights_at)
        whitened = sdp_lift.whiten_relaxation(*sdp_lift.compress_rows(A, b))
        lift = cp.Variable((4, 4), symmetric=True)
        problem = cp.Problem(
            cp.Minimize(cp.trace(whitened.objective @ lift)),
            [lift >> 0, lift[3, 3] == 1, cp.trace(whitened.constraint @ lift) == 0],
        )
        problem.solve(solver="CLARABEL", **settings)
        solver_time += problem.solver_stats.solve_time
        points, _ = sdp_lift.recover_minimisers(lift.value, whitened)
        weights_at = points[0, :2]
    return time.perf_counter() - started, solver_time


def simulated(name: str, *, trials: int, snr_db: float, seed: int):
    return simulate_trials(get_scenario(name), snr_db=snr_db, seeds=trial_seeds(seed, trials))


def run_scenario(batch, *, trials: int, repeats: int, cvxpy_trials: int) -> dict[str, float]:
    """Times per estimate (s) and ratios of every column, and the successes of sdp-cls."""
    closed_form, relaxation = Cls(), SdpCls()
    first = batch.trial(0)
    # warm-up: imports, the cached programs, the first call of every path
    closed_form.estimate(first)
    relaxation.estimate(first)
    relaxation.estimate_columns(batch)
    closed_form.estimate_columns(batch)
    single, single_ratio, single_cls = [], [], []
    for index in range(trials):
        data = batch.trial(index)
        seconds, estimate = _timed(lambda data=data: relaxation.estimate(data))
        single.append(seconds)
        single_ratio.append(seconds / estimate.diagnostics["estimate_solve_time_s"])
        single_cls.append(_timed(lambda data=data: closed_form.estimate(data))[0])
    runs = []
    for _ in range(repeats):
        seconds, columns = _timed(lambda: relaxation.estimate_columns(batch))
        solver = float(np.sum(columns.diagnostics["estimate_solve_time_s"][columns.success]))
        runs.append((seconds / solver, seconds, solver, int(columns.success.sum())))
    ratio, seconds, solver, successes = sorted(runs)[len(runs) // 2]
    cls_batch = min(_timed(lambda: closed_form.estimate_columns(batch))[0] for _ in range(repeats))
    plain = [cvxpy_estimate(batch.trial(i)) for i in range(min(cvxpy_trials, trials))]
    return {
        "single": statistics.median(single),
        "single_ratio": statistics.median(single_ratio),
        "batch": seconds / trials,
        "solver": solver / trials,
        "ratio": ratio,
        "cls": statistics.median(single_cls),
        "cls_batch": cls_batch / trials,
        "cvxpy": statistics.median(seconds for seconds, _ in plain) if plain else np.nan,
        "cvxpy_ratio": statistics.median(s / c for s, c in plain) if plain else np.nan,
        "successes": successes,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1000, help="trials per scenario")
    parser.add_argument("--snr-db", type=float, default=10.0, help="SNR of MATH §2")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials")
    parser.add_argument("--repeats", type=int, default=3, help="batch calls per scenario")
    parser.add_argument(
        "--cvxpy-trials", type=int, default=100, help="trials of the cvxpy reference (0: none)"
    )
    parser.add_argument(
        "--breakdown", action="store_true", help="also time the parts of the batch path"
    )
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    args = parser.parse_args(argv)

    print(
        f"ms per estimate, {args.trials} trials; ratio = time / Clarabel's own solve time "
        "(one at a time: median over trials; batch: the whole call)"
    )
    print(
        f"{'':14s} {'sdp-cls one at a time':>22s}   {'sdp-cls batch':>26s}   "
        f"{'cvxpy (plain)':>17s}   {'cls':>17s}"
    )
    print(
        f"{'scenario':14s} {'ms':>9s} {'ratio':>12s}   {'ms':>7s} {'Clarabel':>9s} "
        f"{'ratio':>8s}   {'ms':>8s} {'ratio':>8s}   {'one':>8s} {'batch':>8s}  successes"
    )
    parts: dict[str, dict[str, float]] = {}
    for name in args.scenarios:
        batch = simulated(name, trials=args.trials, snr_db=args.snr_db, seed=args.seed)
        m = run_scenario(
            batch, trials=args.trials, repeats=args.repeats, cvxpy_trials=args.cvxpy_trials
        )
        if args.breakdown:
            parts[name] = breakdown(batch, args.trials)
        print(
            f"{name:14s} {m['single'] * 1e3:9.3f} {m['single_ratio']:12.2f}   "
            f"{m['batch'] * 1e3:7.3f} {m['solver'] * 1e3:9.3f} {m['ratio']:8.2f}   "
            f"{m['cvxpy'] * 1e3:8.3f} {m['cvxpy_ratio']:8.1f}   "
            f"{m['cls'] * 1e3:8.3f} {m['cls_batch'] * 1e3:8.4f}  "
            f"{m['successes']}/{args.trials}"
        )
    if parts:
        names = [*PARTS, "rest", "total"]
        print("\nsdp-cls batch path by part, ms per estimate (separate pass, timing wrappers)")
        print(f"{'scenario':14s}" + "".join(f" {part:>17s}" for part in names))
        for name, seconds in parts.items():
            print(f"{name:14s}" + "".join(f" {seconds[part] * 1e3:17.3f}" for part in names))


if __name__ == "__main__":
    main()
