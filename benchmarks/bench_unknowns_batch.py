"""Per-estimate time of ``cls`` with unknown emission time and/or carrier offset (MATH §15):
one trial at a time against the whole batch's columns.

On ``beacon-pass`` (a 406 MHz beacon, 40 samples) and ``turn-noncooperative`` (the paper's turn,
20 samples), both with the carrier offset and the emission time unknown, at 10 dB, N = 2,000
trials, with the relaxed closed form (``offset_method="relaxed"``, the default), with the
profiled offset (``"profile"``: a root search over δ, one GTRS per step) and with the two-stage
closed form (``"two-stage"``: the relaxed answer corrected by the measurement model linearised
about it, MATH §15); and on both with the
carrier offset alone unknown (``-offset``: δ's column of the CLS rows, projected out in the
GTRS's normal equations, :mod:`estimators.closed_form.gtrs_batch`). The same for ``ml`` (the
relaxed cases), whose batch takes its starts from those closed forms:

- ``one-at-a-time``: ``estimate(batch.trial(i), rng=rngs[i])``: the pseudo-range closed form
  on one trial (its batch of one); the columns were this call per trial before they were
  vectorised;
- ``columns``: ``estimate_columns(batch, rngs=rngs)``: the relaxed pseudo-range closed form of
  every trial at once (``estimators.closed_form.pseudorange_cls.solve_pseudorange_batch``).

Times are CPU seconds of this process (``benchmarks/cpu_time.py``) with BLAS held to one thread;
each path is timed three times and the best kept. The one-at-a-time path runs on the first
``min(N, 300)`` trials (60 for the profile; its cost per trial does not depend on N).
Printed: microseconds per estimate, the ratio ``one-at-a-time / columns``, the successes and
the largest distance between the two paths' positions (the same code: zero, or rounding); for
the profile and the two-stage form also the ratio of their columns' time per estimate to the
relaxed form's on the same trials (the two-stage form's budget: at most 2×).

With the emitter's height unknown too (``roof-beacon``: ``beacon-pass`` with the beacon 25 m up,
offset, emission time and height unknown) the pseudo-range closed forms estimate ``(x, y, z)``
(MATH §15, "The emitter's height unknown"): 2-D (``beacon-pass``) against 3-D
(``roof-beacon``) per offset method, ``cls``'s columns of the batch of N and its ``estimate``
one trial at a time (in 3-D the columns of a batch of one), on the same flight and noise.

Run: ``python benchmarks/bench_unknowns_batch.py`` (``--trials N``; ``--part height`` for the
2-D against 3-D comparison alone).
"""

from __future__ import annotations

import argparse
import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402
from cpu_time import best_cpu_us  # noqa: E402

from estimators.closed_form.cls import Cls  # noqa: E402
from estimators.registry import make_estimator  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate_trials, trial_seeds  # noqa: E402

PER_TRIAL = 300
PER_TRIAL_PROFILE = 60
SNR_DB = 10.0
SCENARIOS = ("beacon-pass", "turn-noncooperative")


def bench(scenario_name: str, n: int, offset_method: str, estimator_name: str = "cls") -> float:
    """Print the two paths' times and agreement; return the columns' µs per estimate."""
    scenario = get_scenario(scenario_name.removesuffix("-offset"))
    if scenario_name.endswith("-offset"):  # the carrier offset alone unknown
        scenario = scenario.replace(unknowns=("carrier_offset_hz",))
    batch = simulate_trials(scenario, snr_db=SNR_DB, seeds=trial_seeds(2026, n))
    estimator = (
        Cls(offset_method=offset_method) if estimator_name == "cls" else make_estimator("ml")
    )
    single = min(n, PER_TRIAL if offset_method != "profile" else PER_TRIAL_PROFILE)
    trials = [batch.trial(i) for i in range(single)]

    def rngs(count: int) -> list[np.random.Generator]:
        return [np.random.default_rng(i) for i in range(count)]

    def one_at_a_time() -> list:
        generators = rngs(single)
        return [estimator.estimate(t, rng=g) for t, g in zip(trials, generators, strict=True)]

    def columns():
        return estimator.estimate_columns(batch, rngs=rngs(n))

    per_trial_us = best_cpu_us(one_at_a_time, single)
    columns_us = best_cpu_us(columns, n)
    result = columns()
    singles = one_at_a_time()
    positions = np.array([e.position_m for e in singles])
    distance = np.nanmax(np.linalg.norm(positions - result.position_m[:single], axis=1))
    print(
        f"{estimator_name:>3} {scenario_name:>26}  N={n:>6,}  offset_method={offset_method}  "
        f"unknowns={','.join(scenario.unknowns)}\n"
        f"{'':>22}one-at-a-time {per_trial_us:9.1f} µs/estimate\n"
        f"{'':>22}columns       {columns_us:9.1f} µs/estimate  "
        f"(×{per_trial_us / columns_us:.1f}; success {int(result.success.sum())}/{n})\n"
        f"{'':>22}largest position difference columns vs one-at-a-time: {distance:.2e} m"
    )
    return columns_us


def bench_height(n: int) -> None:
    """2-D (``beacon-pass``) against 3-D (``roof-beacon``): µs per estimate of ``cls``, its
    columns of a batch of ``n`` and one trial at a time, per offset method."""
    for method in ("relaxed", "two-stage", "profile"):
        times = {}
        estimator = Cls(offset_method=method)
        for name in ("beacon-pass", "roof-beacon"):
            batch = simulate_trials(get_scenario(name), snr_db=SNR_DB, seeds=trial_seeds(2026, n))
            single = min(n, PER_TRIAL)
            ones = [batch.trial(i) for i in range(single)]
            batch_us = best_cpu_us(lambda: estimator.estimate_columns(batch), n)  # noqa: B023
            one_us = best_cpu_us(
                lambda: [estimator.estimate(one) for one in ones],  # noqa: B023
                single,
            )
            success = int(estimator.estimate_columns(batch).success.sum())
            times[name] = batch_us, one_us
            print(
                f"cls {name:>12} ({'3-D' if name == 'roof-beacon' else '2-D'})  "
                f"offset_method={method:9s} batch N={n:,}: {batch_us:7.1f} µs/estimate "
                f"(success {success}/{n}); one trial: {one_us:7.1f} µs/estimate"
            )
        (batch2, one2), (batch3, one3) = times["beacon-pass"], times["roof-beacon"]
        print(f"{'':>22}3-D / 2-D: batch ×{batch3 / batch2:.2f}, one trial ×{one3 / one2:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=2_000, help="N (default 2,000)")
    parser.add_argument("--part", choices=("all", "height"), default="all")
    args = parser.parse_args()
    bench_height(args.trials)
    if args.part == "height":
        return
    for name in SCENARIOS:
        relaxed_us = bench(name, args.trials, "relaxed")
        for method in ("two-stage", "profile"):
            ratio = bench(name, args.trials, method) / relaxed_us
            print(f"{'':>22}{method} / relaxed, columns: ×{ratio:.2f} per estimate")
        bench(f"{name}-offset", args.trials, "relaxed")
    for name in SCENARIOS:
        bench(name, args.trials, "relaxed", "ml")
        bench(f"{name}-offset", args.trials, "relaxed", "ml")


if __name__ == "__main__":
    main()
