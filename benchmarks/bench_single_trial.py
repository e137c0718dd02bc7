"""One ``cls`` trial against a plain numpy transcription of the same mathematics, in one run.

On ``paper-1m`` at 20 dB (one straight frame: the hard case, a mirror pair and a tie-break),
one trial from :func:`scenarios.simulate.simulate`:

- ``cls``: ``make_estimator("cls").estimate(data, rng=rng)``, the public one-trial call;
- ``numpy``: :func:`bench_batch.numpy_cls`, the weighted two-stage CLS (MATH §3, §4, §6), its
  GTRS (§5) and the answer of §7 written in plain numpy, on arrays taken out of the project's
  types beforehand;
- ``columns``: ``estimate_columns`` of a batch of ``--batch`` trials of the same scenario,
  per trial.

Printed: microseconds per estimate (the least CPU time of ``--repeats`` rounds of ``--calls``
calls, :func:`cpu_time.best_cpu_us`, BLAS held to one thread), the ratio ``cls / numpy`` and
the batch ratio ``cls / columns`` (what one trial at a time costs per trial over what a
large batch costs per trial). With ``--profile`` the one-trial call is also profiled
(``cProfile``) and its most expensive functions printed.

Run: ``python benchmarks/bench_single_trial.py [--calls 2000] [--batch 20000] [--profile]``.
Timings depend on the machine and its load; nothing here is a pass/fail criterion.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402
from bench_batch import Trial, numpy_cls  # noqa: E402
from cpu_time import best_cpu_us  # noqa: E402

from estimators.registry import make_estimator  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate, simulate_trials, trial_seeds  # noqa: E402

SCENARIO = "paper-1m"
SNR_DB = 20.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="one-trial calls per round")
    parser.add_argument("--batch", type=int, default=20_000, help="trials of the batch")
    parser.add_argument("--repeats", type=int, default=5, help="rounds; the least is kept")
    parser.add_argument("--profile", action="store_true", help="profile the one-trial call")
    args = parser.parse_args()

    scenario = get_scenario(SCENARIO)
    data = simulate(scenario, snr_db=SNR_DB, seed=1)
    arrays = Trial.of(data)
    estimator = make_estimator("cls")
    rngs = [np.random.default_rng(i) for i in range(args.calls)]
    estimate = estimator.estimate(data, rng=np.random.default_rng(0))
    position, _, _ = numpy_cls(arrays, np.random.default_rng(0))
    agree = np.allclose(estimate.position_m, position, rtol=0.0, atol=1e-6)

    def one_trial() -> None:
        for rng in rngs:
            estimator.estimate(data, rng=rng)

    def transcription() -> None:
        for rng in rngs:
            numpy_cls(arrays, rng)

    batch = simulate_trials(scenario, snr_db=SNR_DB, seeds=trial_seeds(2024, args.batch))
    batch_rngs = [np.random.default_rng(i) for i in range(args.batch)]
    best = dict.fromkeys(("cls", "numpy", "columns"), np.inf)
    for _ in range(args.repeats):  # interleaved, so that every path sees the same load
        best["cls"] = min(best["cls"], best_cpu_us(one_trial, args.calls, repeats=1))
        best["numpy"] = min(best["numpy"], best_cpu_us(transcription, args.calls, repeats=1))
        best["columns"] = min(
            best["columns"],
            best_cpu_us(
                lambda: estimator.estimate_columns(batch, rngs=batch_rngs), args.batch, repeats=1
            ),
        )
    print(
        f"{SCENARIO} {SNR_DB:g} dB | cls one trial {best['cls']:7.1f} us"
        f" | numpy {best['numpy']:6.1f} us | cls/numpy {best['cls'] / best['numpy']:5.2f}"
        f" | columns N={args.batch} {best['columns']:5.2f} us/trial"
        f" | batch ratio {best['cls'] / best['columns']:6.1f}x"
        f" | same position as numpy: {agree}",
        flush=True,
    )
    if args.profile:
        profile = cProfile.Profile()
        profile.runcall(one_trial)
        pstats.Stats(profile).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
