"""Median time per estimate of ``cls`` (closed form, MATH §5) and ``sdp-cls`` (MATH §11).

Both estimators run the same two-stage weighted rows; ``sdp-cls`` re-solves one cached, DPP
cvxpy problem per relaxation (built before timing starts), so the ratio measures the solver
path against the closed form, not problem construction. Run::

    python benchmarks/bench_sdp.py [--trials N] [--snr-db S] [--seed S]

Timings depend on the machine and its load; nothing here is a pass/fail criterion.
"""

from __future__ import annotations

import argparse
import statistics
import time

from estimators.cls import Cls
from estimators.sdp_cls import SdpCls
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds

SCENARIOS = ("paper-1m", "turn")


def median_estimate_time_s(estimator, batch) -> tuple[float, int]:
    """Median wall time of ``estimator.estimate`` over the trials, and the successes."""
    times = []
    successes = 0
    for data in batch:
        started = time.perf_counter()
        estimate = estimator.estimate(data)
        times.append(time.perf_counter() - started)
        successes += estimate.success
    return statistics.median(times), successes


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="trials per scenario")
    parser.add_argument("--snr-db", type=float, default=10.0, help="SNR of MATH §2")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials")
    args = parser.parse_args(argv)

    closed_form, relaxation = Cls(), SdpCls()
    print(f"{'scenario':10s} {'cls (ms)':>10s} {'sdp-cls (ms)':>13s} {'ratio':>8s}  successes")
    for name in SCENARIOS:
        scenario = get_scenario(name)
        batch = simulate_trials(
            scenario, snr_db=args.snr_db, seeds=trial_seeds(args.seed, args.trials)
        )
        # warm-up: imports, the cached cvxpy problem and its first canonicalisation
        closed_form.estimate(batch.trial(0))
        relaxation.estimate(batch.trial(0))
        cls_s, cls_ok = median_estimate_time_s(closed_form, batch)
        sdp_s, sdp_ok = median_estimate_time_s(relaxation, batch)
        print(
            f"{name:10s} {cls_s * 1e3:10.3f} {sdp_s * 1e3:13.3f} {sdp_s / cls_s:8.1f}  "
            f"cls {cls_ok}/{args.trials}, sdp-cls {sdp_ok}/{args.trials}"
        )


if __name__ == "__main__":
    main()
