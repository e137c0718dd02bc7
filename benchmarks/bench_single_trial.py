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
large batch costs per trial). With ``--stages`` the stages of the one-trial call are timed
alone (the checks, :class:`~estimators.closed_form.cls_batch.SharedGeometry`, the vectorised
solve and within it the two GTRS stages and the mirror rule, the goodness of fit, the
:class:`~estimators.base.Estimate`); with ``--profile`` the one-trial call is also profiled
(``cProfile``) and its most expensive functions printed.

Run: ``python benchmarks/bench_single_trial.py [--calls 2000] [--batch 20000] [--stages]
[--profile]``.
Timings depend on the machine and its load; nothing here is a pass/fail criterion.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
from collections.abc import Callable
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402
from bench_batch import Trial, numpy_cls  # noqa: E402
from cpu_time import best_cpu_us  # noqa: E402

from estimators.base import Estimate, require_modalities  # noqa: E402
from estimators.closed_form import cls_batch  # noqa: E402
from estimators.closed_form.gtrs_batch import solve_gtrs_batch  # noqa: E402
from estimators.mirror_rule import finalize_columns  # noqa: E402
from estimators.registry import make_estimator  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate, simulate_trials, trial_seeds  # noqa: E402
from scenarios.types import MeasurementSet  # noqa: E402

SCENARIO = "paper-1m"
SNR_DB = 20.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="one-trial calls per round")
    parser.add_argument("--batch", type=int, default=20_000, help="trials of the batch")
    parser.add_argument("--repeats", type=int, default=5, help="rounds; the least is kept")
    parser.add_argument("--stages", action="store_true", help="time the one-trial stages")
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
    if args.stages:
        for name, us in stage_times(estimator, data, args.calls, args.repeats).items():
            print(f"  {name:34s} {us:7.1f} us", flush=True)
    if args.profile:
        profile = cProfile.Profile()
        profile.runcall(one_trial)
        pstats.Stats(profile).sort_stats("tottime").print_stats(25)


def stage_times(estimator: Any, data: MeasurementSet, calls: int, repeats: int) -> dict[str, float]:
    """CPU microseconds of each stage of ``estimator.estimate(data, rng=...)`` timed alone, on
    the arrays the call hands it (the stages of :func:`cls_batch.estimate_trial`)."""
    shared = cls_batch.SharedGeometry.of(data, "all")
    ranges = shared.used.speed_of_light_mps * data.toa_s[None]
    doppler = data.doppler_hz[None]
    r, f = np.repeat(ranges.T, 2, axis=1), np.repeat(doppler.T, 2, axis=1)
    solved = cls_batch.solve_trials(shared, "weighted", ranges, doppler, None)
    with np.errstate(all="ignore"):
        world, solution = cls_batch.solve_chunk(shared, "weighted", r, f)
        scale = np.sqrt(shared.spread_sq + np.mean(r * r, axis=0))
        rows = cls_batch.RowsOfChunk(shared, r, f, scale)
        blocks = rows.blocks("weighted")
    first = solution.first()
    count = np.where(first.hard_case, 1, first.count)
    costs = np.where(first.hard_case[:, None], np.min(first.costs, axis=1)[:, None], first.costs)
    position = solved.candidates[:1, 0]
    estimate = estimator.estimate(data, rng=np.random.default_rng(0))
    stages = {
        "estimate (all)": lambda: estimator.estimate(data, rng=None),
        "checks (require_modalities)": lambda: require_modalities(estimator, data),
        "SharedGeometry.of": lambda: cls_batch.SharedGeometry.of(data, "all"),
        "solve_trials": lambda: cls_batch.solve_trials(shared, "weighted", ranges, doppler, None),
        "  solve_chunk (two stages)": lambda: cls_batch.solve_chunk(shared, "weighted", r, f),
        "    rows of one stage (whitened)": lambda: rows.blocks("weighted"),
        "    GTRS of one stage (with rank)": lambda: solve_gtrs_batch(
            blocks, 2, rank=True, rank_deficient=shared.collinear
        ),
        "  finalize_columns (mirror rule)": lambda: finalize_columns(
            world[:1], count, costs, shared.mean_xy, shared.line
        ),
        "goodness of fit": lambda: estimator._fit(data, position),
        "Estimate(...)": lambda: Estimate(
            estimator=estimate.estimator,
            position_m=estimate.position_m,
            candidates_m=estimate.candidates_m,
            ambiguous=estimate.ambiguous,
            message=estimate.message,
            diagnostics=estimate.diagnostics,
        ),
    }

    def repeated(stage: Callable[[], Any]) -> Callable[[], None]:
        def run() -> None:
            for _ in range(calls):
                stage()

        return run

    return {name: best_cpu_us(repeated(stage), calls, repeats) for name, stage in stages.items()}


if __name__ == "__main__":
    main()
