"""Median time per estimate of every registered estimator, on ``paper-1m`` and ``orbit``.

Usage::

    python benchmarks/bench_estimators.py [--trials N] [--snr-db S] [--seed K]

For each estimator in :func:`estimators.registry.all_entries` (built-ins and plug-ins) that can
be built with its default options, every trial of a seeded batch is estimated once and timed
with ``time.perf_counter``; the table gives the median per estimate in milliseconds and its
ratio to ``cls``. An estimator that cannot be imported or built, or that needs a modality the
scenario lacks, is listed with the reason instead. One untimed warm-up estimate per estimator
and scenario keeps import and cache costs out of the numbers.

This is a measurement script, not a test: timings depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from estimators.registry import all_entries, make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds
from scenarios.types import MeasurementSet

SCENARIOS = ("paper-1m", "orbit")
REFERENCE = "cls"


def median_estimate_time_s(
    estimator, trials: list[MeasurementSet], rng: np.random.Generator
) -> tuple[float, int]:
    """Median wall time of ``estimator.estimate`` over ``trials`` and the number of failures."""
    estimator.estimate(trials[0], rng=rng)  # warm-up, not timed
    times, failures = [], 0
    for data in trials:
        start = time.perf_counter()
        estimate = estimator.estimate(data, rng=rng)
        times.append(time.perf_counter() - start)
        failures += not estimate.success
    return statistics.median(times), failures


def benchmark(n_trials: int, snr_db: float, seed: int) -> tuple[dict, dict, dict]:
    """``{(estimator, scenario): (median_s, failures) or reason}``, ``{estimator: reason
    skipped}`` and ``{estimator: repr}`` of the estimators built (default options)."""
    batches = {
        name: list(
            simulate_trials(get_scenario(name), snr_db=snr_db, seeds=trial_seeds(seed, n_trials))
        )
        for name in SCENARIOS
    }
    results: dict[tuple[str, str], tuple[float, int] | str] = {}
    skipped: dict[str, str] = {}
    built: dict[str, str] = {}
    for name, entry in all_entries().items():
        if not entry.is_available():
            skipped[name] = f"needs {', '.join(entry.required_modules)}"
            continue
        try:
            estimator = make_estimator(name)
        except Exception as error:  # an estimator being written may not import yet
            skipped[name] = f"cannot build: {error}"
            continue
        built[name] = repr(estimator)
        for scenario in SCENARIOS:
            trials = batches[scenario]
            missing = set(getattr(estimator, "requires", ())) - trials[0].modalities
            if missing:
                results[(name, scenario)] = f"needs {', '.join(sorted(missing))}"
                continue
            try:
                results[(name, scenario)] = median_estimate_time_s(
                    estimator, trials, np.random.default_rng(seed)
                )
            except Exception as error:
                results[(name, scenario)] = f"raised {type(error).__name__}: {error}"
    return results, skipped, built


def format_table(results: dict, skipped: dict) -> str:
    """One row per estimator: median ms per estimate and the ratio to ``cls`` per scenario."""
    names = sorted({name for name, _ in results}, key=lambda n: (n != REFERENCE, n))
    header = f"{'estimator':<18}" + "".join(
        f"{scenario + ' ms':>14}{'x cls':>8}{'failed':>8}" for scenario in SCENARIOS
    )
    lines = [header, "-" * len(header)]
    notes = []
    for name in names:
        cells = []
        for scenario in SCENARIOS:
            value = results.get((name, scenario), "not run")
            reference = results.get((REFERENCE, scenario))
            if isinstance(value, str):
                cells.append(f"{'-':>14}{'-':>8}{'-':>8}")
                notes.append(f"{name} on {scenario}: {value}")
                continue
            median_s, failures = value
            ratio = f"{median_s / reference[0]:.2f}" if isinstance(reference, tuple) else "-"
            cells.append(f"{1e3 * median_s:>14.3f}{ratio:>8}{failures:>8d}")
        lines.append(f"{name:<18}" + "".join(cells))
    notes.extend(f"{name}: skipped ({reason})" for name, reason in skipped.items())
    if notes:
        lines += ["", "notes:", *(f"  {note}" for note in notes)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="trials per scenario (200)")
    parser.add_argument("--snr-db", type=float, default=0.0, help="SNR of MATH §2 (0 dB)")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials (0)")
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error("--trials: must be >= 1")
    results, skipped, built = benchmark(args.trials, args.snr_db, args.seed)
    print(
        f"median time per estimate, {args.trials} trials, snr {args.snr_db:g} dB, "
        f"scenarios {', '.join(SCENARIOS)} (paper-1m: one frame)"
    )
    print(format_table(results, skipped))
    print("\noptions (defaults):")
    for text in built.values():
        print(f"  {text}")


if __name__ == "__main__":
    main()
