"""``ml`` on one trial against a plain numpy Levenberg-Marquardt from one start, and the batch.

For ``paper-1m`` (one straight frame), ``turn`` and ``paper-1m-turn`` (ten frames, 100
samples), at 0 dB:

- ``ml one trial``: ``MaximumLikelihood().estimate(trial, rng=rng)``, the batch of one (its
  starts, the search from each, the convergence audit, the minima, the mirror rule, the
  covariance and the goodness of fit);
- ``plain LM``: a plain numpy transcription written here, with no project code in the clock:
  the whitened Doppler and ToA residuals and their Jacobian (MATH §1, §10), Marquardt's damped
  Gauss-Newton from one start (the first CLS candidate, found before the clock starts) in the
  centred, scaled local frame, stopped when the step or the cost's relative change is below
  ``1e-10``, and the inverse Fisher information at the end (MATH §8): what the bare search of
  one trial costs;
- ``columns``: ``estimate_columns`` of a 10,000-trial batch, per trial.

Printed per scenario: microseconds per trial, ``ml one trial / plain LM`` (target ≤ 2) and
``one trial / columns`` (target ≥ 20), with the largest distance between the plain LM's end
point and ``ml``'s nearest candidate (they solve the same problem). Times are CPU seconds of
this process (:mod:`benchmarks.cpu_time`) with BLAS held to one thread.

Run: ``python benchmarks/bench_single_trial_ml.py`` (``--quick``: 1,000 trials in the batch).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cpu_time import best_cpu_us  # noqa: E402

from estimators.closed_form.cls_batch import candidates_of_trial  # noqa: E402
from estimators.ml.ml import MaximumLikelihood  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate_trials, trial_seeds  # noqa: E402

PER_TRIAL = 200
"""Trials timed one at a time (their cost per trial does not depend on the batch size)."""


def plain_lm(
    p: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    r: np.ndarray,
    constants: tuple[float, float, float, float],
    start: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Marquardt's damped Gauss-Newton on the whitened Doppler and range residuals from
    ``start`` (world, metres), in the local frame; the end point and ``(JᵀJ)⁻¹`` there.

    ``p, v``: positions and velocities ``(K, 3)``; ``f``: Doppler (Hz); ``r``: ranges (m);
    ``constants``: ``γ``, ``σ_f``, ``σ_r`` and the emitter height."""
    gamma, sigma_f, sigma_r, height = constants
    origin = p[:, :2].mean(axis=0)
    scale = np.sqrt(np.mean(np.sum((p[:, :2] - origin) ** 2, axis=1)) + np.mean(r**2))
    dz = p[:, 2] - height

    def rows(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = origin + scale * u
        d = p[:, :2] - s
        rho = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + dz**2)
        radial = v[:, 0] * d[:, 0] + v[:, 1] * d[:, 1] + v[:, 2] * dz
        e = np.concatenate([(f + gamma * radial / rho) / sigma_f, (r - rho) / sigma_r])
        unit = d / rho[:, None]
        jf = -gamma * (v[:, :2] - (radial / rho)[:, None] * unit) / (rho[:, None] * sigma_f)
        jr = unit / sigma_r
        return e, np.vstack([jf, jr]) * scale

    u = (start - origin) / scale
    e, J = rows(u)
    cost = e @ e
    damping = 1e-3
    for _ in range(200):
        A, g = J.T @ J, J.T @ e
        step = np.linalg.solve(A + damping * np.diag(np.diag(A)), -g)
        trial_e, trial_J = rows(u + step)
        trial_cost = trial_e @ trial_e
        if trial_cost < cost:
            converged = (cost - trial_cost) <= 1e-10 * cost or np.linalg.norm(step) <= 1e-10 * (
                np.linalg.norm(u) + 1e-10
            )
            u, e, J, cost = u + step, trial_e, trial_J, trial_cost
            damping = max(damping / 10.0, 1e-12)
            if converged:
                break
        else:
            damping *= 10.0
    return origin + scale * u, np.linalg.inv(J.T @ J) * scale**2


def bench(scenario: str, n: int) -> None:
    batch = simulate_trials(get_scenario(scenario), snr_db=0.0, seeds=trial_seeds(2024, n))
    m = min(n, PER_TRIAL)
    trials = [batch.trial(i) for i in range(m)]
    estimator = MaximumLikelihood()
    arrays = [
        (
            np.array(t.position_m),
            np.array(t.velocity_mps),
            np.array(t.doppler_hz),
            np.array(t.range_m),
            (
                t.gamma_per_m,
                t.noise.doppler_hz,
                t.noise.toa_s * t.speed_of_light_mps,
                t.emitter_height_m,
            ),
            candidates_of_trial(t)[0],
        )
        for t in trials
    ]

    def one_at_a_time() -> None:
        for t, rng in zip(trials, [np.random.default_rng(i) for i in range(m)], strict=True):
            estimator.estimate(t, rng=rng)

    def plain() -> None:
        for a in arrays:
            plain_lm(*a)

    def columns() -> None:
        estimator.estimate_columns(batch, rngs=[np.random.default_rng(i) for i in range(n)])

    single_us = best_cpu_us(one_at_a_time, m)
    plain_us = best_cpu_us(plain, m)
    columns_us = best_cpu_us(columns, n)
    gap = 0.0
    for t, a in zip(trials, arrays, strict=True):
        point, _ = plain_lm(*a)
        candidates = estimator.estimate(t).candidates_m
        gap = max(gap, float(np.min(np.linalg.norm(candidates - point, axis=1))))
    print(
        f"{scenario:13s} | ml one trial {single_us:7.1f} us | plain LM {plain_us:6.1f} us"
        f" | one trial / plain {single_us / plain_us:4.2f}x"
        f" | columns (N={n}) {columns_us:6.2f} us | one trial / columns"
        f" {single_us / columns_us:5.1f}x | plain LM to ml {gap:.1e} m",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,000 trials in the batch")
    n = 1_000 if parser.parse_args().quick else 10_000
    for scenario in ("paper-1m", "turn", "paper-1m-turn"):
        bench(scenario, n)


if __name__ == "__main__":
    main()
