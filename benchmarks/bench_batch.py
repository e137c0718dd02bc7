"""Per-estimate time of the closed-form CLS one trial at a time against a whole batch at once.

For ``cls`` (weighted, two stages) and ``cls-paper`` (the paper's per-frame rows, last frame),
on ``paper-1m`` (one straight frame: every trial is the hard case and draws its tie-break) and
on ``turn`` (two headings), with N = 1,000 and 10,000 trials:

- ``one-at-a-time``: ``estimate(batch.trial(i), rng=rngs[i])``, the path a run takes without a
  batch capability (for the closed forms the batch of one, so that its answer is the batch's
  to the bit);
- ``numpy``: a plain per-trial numpy transcription of the same mathematics written here, with
  no project code: the rows and whitening (MATH §3, §4, §6), the GTRS with its hard case and
  Newton on the secular equation (§5), the rank of the rows, and the answer of §7 (mirror
  images on a straight track, coincident points merged, the tie broken by the trial's
  generator): what a straightforward implementation of the same answer costs;
- ``columns``: ``estimate_columns(batch, rngs=rngs)``, the columnar batch result;
- ``list``: ``estimate_batch(batch, rngs=rngs)``, the same as one ``Estimate`` per trial.

Times are CPU seconds of this process (``time.process_time``) with BLAS held to one thread, so
that other work on the machine does not count; the paths are timed in turn, three times,
and the best of each is kept. The per-trial paths run on the first ``min(N, 400)`` trials
(their cost per trial does not depend on N); the batch paths on all N. The transcription gets
plain arrays taken out of the project's types beforehand, and the generators are made before
the clock starts. Printed: microseconds per estimate and the ratios ``numpy / columns`` and
``one-at-a-time / columns``, with a check that the transcription returns ``estimate``'s
position, candidates and rank.

ml. For ``ml`` (MATH §10; ``bench_ml``) on ``paper-1m``, ``turn`` and ``paper-1m-turn``
(ten frames, 100 samples: the batch's work grows with the samples, the per-trial paths' far
less), the same paths but ``numpy LM``: a plain per-trial transcription written here, the
CLS starts above (folded to one side of a straight track, with a copy off its plane for a
start on it), Marquardt's damped Gauss-Newton from each, the distinct minima, the answer of
§7 and the inverse Fisher information at it (§8), checked against ``estimate``'s position,
candidates and covariance. The per-trial paths run on the first ``min(N, 200)`` trials.

Run: ``python benchmarks/bench_batch.py`` (``--quick`` for N = 1,000 only; ``--only ml``).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core, before numpy loads its BLAS

import numpy as np  # noqa: E402

from estimators.closed_form.cls import Cls, ClsPaper  # noqa: E402
from estimators.ml.ml import MaximumLikelihood  # noqa: E402
from scenarios.catalog import get_scenario  # noqa: E402
from scenarios.simulate import simulate_trials, trial_seeds  # noqa: E402
from scenarios.types import MeasurementSet  # noqa: E402

PER_TRIAL = 400
PER_TRIAL_ML = 200
ML_SCENARIOS = ("paper-1m", "turn", "paper-1m-turn")
REPEATS = 3


# --------------------------------------------------------------------------------------------
# a plain numpy transcription of MATH §3-§6, one trial at a time
# --------------------------------------------------------------------------------------------


def _gtrs(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Every global minimiser (x, y) of ‖A (x, y, x²+y²) − b‖² (MATH §5), their costs, the
    rank of A and whether it is the hard case."""
    singular = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(singular > singular[0] * 1e-10))
    M = A.T @ A
    q = A.T @ b
    m, m33, q3 = M[:2, 2], M[2, 2], q[2]
    S = M[:2, :2] - np.outer(m, m) / m33
    mu, U = np.linalg.eigh(S)
    h = U.T @ (m / (2.0 * m33))
    e = U.T @ (q[:2] - m * q3 / m33) + mu * h
    gap = mu[1] - mu[0]
    base = h @ h + (q3 - 0.5 * mu[0]) / m33
    phi_pole = e[1] ** 2 / gap**2 - base

    def lift_and_cost(xy: np.ndarray) -> np.ndarray:
        lifted = np.column_stack([xy, np.sum(xy**2, axis=1)])
        return np.sum((lifted @ A.T - b) ** 2, axis=1)

    if phi_pole < 0.0 and abs(e[0]) <= 1e-10 * mu[1] * np.sqrt(-phi_pole):
        half = np.sqrt(-phi_pole)
        y2 = e[1] / gap - h[1]
        pair = np.array([[-h[0] + half, y2], [-h[0] - half, y2]]) @ U.T
        costs = lift_and_cost(pair)
        # equal to the rounding of their evaluation (gtrs._equal_to_rounding)
        r_norm = np.max(np.sqrt(np.sum(pair**2, axis=1) + np.sum(pair**2, axis=1) ** 2))
        delta = 2.2e-16 * np.sqrt(len(b)) * (np.linalg.norm(A) * r_norm + np.linalg.norm(b))
        best = costs.min()
        if costs.max() - best <= 1e-12 * best + 16 * (2 * np.sqrt(best) * delta + delta**2):
            return pair, costs, rank, True
    # φ(s) = e₁²/s² + e₂²/(g+s)² − base − s/(2 M₃₃), convex and decreasing: bracket, then
    # Newton from the left end (it stays left of the root)

    def phi(s: float) -> float:
        return e[0] ** 2 / s**2 + e[1] ** 2 / (gap + s) ** 2 - base - s / (2 * m33)

    s = 1.0
    while phi(s) > 0.0:
        s *= 2.0
    while phi(s) <= 0.0 and s > 1e-300:
        s *= 0.5
    for _ in range(200):
        value = phi(s)
        slope = 2 * e[0] ** 2 / s**3 + 2 * e[1] ** 2 / (gap + s) ** 3 + 1 / (2 * m33)
        step = value / slope
        if value <= 0 or step <= 4e-16 * s:
            break
        s += step
    point = (U @ (e / np.array([s, gap + s]) - h))[None, :]
    return point, lift_and_cost(point), rank, False


def _answer(
    d: Trial,
    used: np.ndarray,
    points: np.ndarray,
    costs: np.ndarray,
    hard: bool,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The returned position and candidates (MATH §7): the hard-case pair left of the last
    heading first at one cost, the mirror images on a straight track, coincident points
    merged, a tie broken by ``rng``."""
    p, v = d.position[used, :2], d.velocity[used, :2]
    if hard:
        left = np.array([-v[-1, 1], v[-1, 0]])
        if (points[0] - points[1]) @ left < 0:
            points = points[::-1]
        costs = np.full(2, costs.min())
    origin = p.mean(axis=0)
    spread = p - origin
    basis = spread if np.any(spread) else v
    _, singular, vt = np.linalg.svd(basis, full_matrices=False)
    direction = vt[0]
    cross = np.abs(v[:, 0] * direction[1] - v[:, 1] * direction[0])
    straight = (len(singular) < 2 or singular[1] <= 1e-9 * singular[0]) and np.all(
        cross <= 1e-9 * np.hypot(v[:, 0], v[:, 1])
    )
    if straight:
        offset = points - origin
        mirrored = origin + 2.0 * (offset @ direction)[:, None] * direction - offset
        points, costs = np.vstack([points, mirrored]), np.concatenate([costs, costs])
    scale = max(np.max(np.abs(points - origin)), 1e-300)
    kept: list[int] = []
    for i in np.argsort(costs, kind="stable"):
        if all(np.linalg.norm(points[i] - points[j]) > 1e-9 * scale for j in kept):
            kept.append(int(i))
    points = points[kept]
    index = int(rng.integers(len(points))) if len(points) > 1 else 0
    return points[index], points


@dataclass(frozen=True)
class Trial:
    """One trial's arrays and constants, taken out of the project's types before timing."""

    frame: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    ranges: np.ndarray
    doppler: np.ndarray
    gamma: float
    doppler_sigma: float
    range_sigma: float
    height: float

    @classmethod
    def of(cls, data: MeasurementSet) -> Trial:
        return cls(
            frame=np.array(data.frame),
            position=np.array(data.position_m),
            velocity=np.array(data.velocity_mps),
            ranges=np.array(data.range_m),
            doppler=np.array(data.doppler_hz),
            gamma=data.gamma_per_m,
            doppler_sigma=data.noise.doppler_hz,
            range_sigma=data.noise.toa_s * data.speed_of_light_mps,
            height=data.emitter_height_m,
        )


def _frame(p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Local frame: origin, scale, positions and ranges in its units."""
    origin = p[:, :2].mean(axis=0)
    scale = np.sqrt(np.mean(np.sum((p[:, :2] - origin) ** 2, axis=1)) + np.mean(r**2))
    local = p / scale
    local[:, :2] = (p[:, :2] - origin) / scale
    return origin, scale, local, r / scale


def numpy_cls(d: Trial, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
    """The weighted two-stage CLS (MATH §3-§7) in plain numpy: position, candidates, rank."""
    points, costs, rank, hard = _cls_points(d)
    everything = np.ones(len(d.frame), dtype=bool)
    return (*_answer(d, everything, points, costs, hard, rng), rank)


def _cls_points(d: Trial) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """The minimisers of the weighted two-stage CLS (MATH §3-§6) in metres, their costs, the
    rank of the rows and whether it is the hard case."""
    origin, scale, P, rho = _frame(d.position, d.ranges)
    v, f, gamma = d.velocity, d.doppler, d.gamma
    h = d.height / scale
    sf = d.doppler_sigma
    sr = d.range_sigma / scale
    speed = np.hypot(v[:, 0], v[:, 1])
    A_d = np.column_stack([v[:, :2] / speed[:, None], np.zeros(len(v))])
    b_d = (np.sum(v * P, axis=1) + rho * f / gamma - v[:, 2] * h) / speed
    A_t = np.column_stack([-2 * P[:, 0], -2 * P[:, 1], np.ones(len(v))])
    b_t = rho**2 - P[:, 0] ** 2 - P[:, 1] ** 2 - (P[:, 2] - h) ** 2

    def whitened(range_at: np.ndarray, doppler_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        gv = gamma * speed
        var_d = (range_at**2 * sf**2 + doppler_at**2 * sr**2 + sf**2 * sr**2) / gv**2
        var_t = 4 * range_at**2 * sr**2 + 2 * sr**4
        cov = 2 * range_at * doppler_at * sr**2 / gv
        l11 = np.sqrt(var_d)
        l21 = cov / l11
        l22 = np.sqrt(var_t - l21**2)
        Ad, bd = A_d / l11[:, None], b_d / l11
        At = (A_t - l21[:, None] * Ad) / l22[:, None]
        bt = (b_t - l21 * bd) / l22
        return np.vstack([Ad, At]), np.concatenate([bd, bt])

    points = _gtrs(*whitened(rho, f))[0]
    offset = P - np.array([points[0, 0], points[0, 1], h])
    distance = np.sqrt(np.sum(offset**2, axis=1))
    doppler = -gamma * np.sum(v * offset, axis=1) / distance
    points, costs, rank, hard = _gtrs(*whitened(distance, doppler))
    return points * scale + origin, costs, rank, hard


def numpy_cls_paper(d: Trial, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
    """The paper's CLS on the last frame (one K|v|²-scaled Doppler row, ToA rows, SI units):
    position, candidates, rank."""
    last = d.frame == d.frame[-1]
    origin, scale, P, rho = _frame(d.position[last], d.ranges[last])
    v, f, gamma = d.velocity[last], d.doppler[last], d.gamma
    h = d.height / scale
    speed = np.hypot(v[:, 0], v[:, 1])
    row = np.mean(v[:, :2] / speed[:, None], axis=0)
    rhs = np.mean((np.sum(v * P, axis=1) + rho * f / gamma - v[:, 2] * h) / speed)
    weight = len(v) * (v[0, 0] ** 2 + v[0, 1] ** 2) / scale
    A = np.vstack(
        [[row[0] * weight, row[1] * weight, 0.0], np.column_stack([-2 * P[:, :2], np.ones(len(v))])]
    )
    b = np.concatenate([[rhs * weight], rho**2 - P[:, 0] ** 2 - P[:, 1] ** 2 - (P[:, 2] - h) ** 2])
    points, costs, rank, hard = _gtrs(A, b)
    return (*_answer(d, last, points * scale + origin, costs, hard, rng), rank)


# --------------------------------------------------------------------------------------------
# a plain numpy maximum likelihood (MATH §10), one trial at a time
# --------------------------------------------------------------------------------------------


def _ml_rows(d: Trial, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened Doppler and range residuals at the emitter ``s`` and their Jacobian."""
    offset = d.position - np.array([s[0], s[1], d.height])
    distance = np.sqrt(np.sum(offset**2, axis=1))
    unit = offset / distance[:, None]
    radial = np.sum(d.velocity * unit, axis=1)
    e = np.concatenate(
        [(d.doppler + d.gamma * radial) / d.doppler_sigma, (d.ranges - distance) / d.range_sigma]
    )
    doppler_gradient = d.gamma * (d.velocity - radial[:, None] * unit)[:, :2] / distance[:, None]
    J = np.vstack([-doppler_gradient / d.doppler_sigma, unit[:, :2] / d.range_sigma])
    return e, J


def _levenberg_marquardt(d: Trial, start: np.ndarray, scale: float) -> tuple[np.ndarray, float]:
    """Plain Levenberg-Marquardt (Marquardt's diagonal damping) from ``start``: point, cost."""
    x = start.copy()
    e, J = _ml_rows(d, x)
    cost = e @ e
    damping = 1e-3
    for _ in range(100):
        A, g = J.T @ J, J.T @ e
        step = np.linalg.solve(A + damping * np.diag(np.diag(A)), -g)
        trial_e, trial_J = _ml_rows(d, x + step)
        trial_cost = trial_e @ trial_e
        if trial_cost < cost:
            x, e, J = x + step, trial_e, trial_J
            done = cost - trial_cost <= 1e-12 * cost or np.hypot(*step) <= 1e-10 * scale
            cost, damping = trial_cost, max(damping / 10.0, 1e-12)
            if done:
                break
        else:
            damping *= 10.0
            if damping > 1e12:
                break
    return x, cost


def numpy_ml(d: Trial, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximum likelihood (MATH §10) in plain numpy: the CLS candidates as starts (folded to
    one side of a straight track, with a copy off its plane for a start on it), Levenberg-
    Marquardt from each, the distinct minima, the answer of §7 and the inverse Fisher
    information at it: position, candidates, covariance."""
    points, _, _, _ = _cls_points(d)
    p, v = d.position[:, :2], d.velocity[:, :2]
    origin = p.mean(axis=0)
    scale = np.sqrt(np.mean(np.sum((p - origin) ** 2, axis=1)) + np.mean(d.ranges**2))
    spread = p - origin
    _, singular, vt = np.linalg.svd(spread if np.any(spread) else v, full_matrices=False)
    direction = vt[0]
    normal = np.array([-direction[1], direction[0]])
    straight = len(singular) < 2 or singular[1] <= 1e-9 * singular[0]
    if straight:
        cross = (points - origin) @ normal
        points = np.where((cross < 0)[:, None], points - 2.0 * cross[:, None] * normal, points)
        points = (
            points[:1]
            if len(points) == 2 and np.hypot(*(points[0] - points[1])) < 1e-6 * scale
            else points
        )
        cross = np.abs((points - origin) @ normal)
        for point in points[cross <= 1e-6 * scale]:
            along = (p - point) @ direction
            horizontal = d.ranges**2 - (d.position[:, 2] - d.height) ** 2
            offset = np.sqrt(max(np.mean(horizontal - along**2), (0.1 * scale) ** 2))
            points = np.vstack([points, point + offset * normal])
    minima, costs = [], []
    for start in points:
        x, cost = _levenberg_marquardt(d, start, scale)
        if all(np.hypot(*(x - m)) > 1e-6 * scale for m in minima):
            minima.append(x)
            costs.append(cost)
    order = np.argsort(costs)
    minima, costs = np.array(minima)[order], np.array(costs)[order]
    keep = costs <= costs[0] * (1.0 + 1e-6)
    everything = np.ones(len(d.frame), dtype=bool)
    position, candidates = _answer(d, everything, minima[keep], costs[keep], False, rng)
    _, J = _ml_rows(d, position)
    return position, candidates, np.linalg.inv(J.T @ J)


# --------------------------------------------------------------------------------------------
# timing
# --------------------------------------------------------------------------------------------


def _cpu_us(run: Callable[[], object], count: int) -> float:
    """CPU time of one call of ``run``, in microseconds per estimate."""
    start = time.process_time()
    run()
    return (time.process_time() - start) / count * 1e6


def _generators(n: int) -> list[np.random.Generator]:
    """One generator per trial, made afresh for every timed call (the draws then match)."""
    return [np.random.default_rng(i) for i in range(n)]


Path = Callable[[list[np.random.Generator]], object]


def _best_times(paths: dict[str, tuple[Path, int]], n: int) -> dict[str, float]:
    """Microseconds per estimate of each path ``(run(rngs), estimates per call)``: the best of
    ``REPEATS`` interleaved rounds, so that every path sees the same machine load."""
    best = dict.fromkeys(paths, np.inf)
    for _ in range(REPEATS):
        for key, (run, count) in paths.items():
            rngs = _generators(n)
            best[key] = min(best[key], _cpu_us(lambda r=run, g=rngs: r(g), count))
    return best


def _one_by_one(solve: Callable[..., object], inputs: list, *, keyword: bool = True) -> Path:
    """A path calling ``solve`` on each input with its trial's generator (``rng=`` or second
    argument)."""
    if keyword:
        return lambda g: [solve(x, rng=g[i]) for i, x in enumerate(inputs)]
    return lambda g: [solve(x, g[i]) for i, x in enumerate(inputs)]


def _agreements(
    estimator: Any,
    trials: list[MeasurementSet],
    answers: list,
    same_extra: Callable[..., bool],
) -> int:
    """How many trials ``estimator.estimate`` answers as the transcription did: the position
    (1e-6 m), the candidate set, and ``same_extra(estimate, answer[2])`` (rank, covariance)."""
    rngs = _generators(len(trials))
    agree = 0
    for i, (trial, (position, candidates, extra)) in enumerate(zip(trials, answers, strict=True)):
        estimate = estimator.estimate(trial, rng=rngs[i])
        agree += bool(
            np.allclose(estimate.position_m, position, rtol=0.0, atol=1e-6)
            and _same_sets(estimate.candidates_m, candidates)
            and same_extra(estimate, extra)
        )
    return agree


def _same_sets(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a).reshape(-1, 2), np.asarray(b).reshape(-1, 2)
    return len(a) == len(b) and all(np.min(np.linalg.norm(b - p, axis=1)) < 1e-6 for p in a)


def bench(scenario: str, n: int) -> None:
    batch = simulate_trials(get_scenario(scenario), snr_db=0.0, seeds=trial_seeds(2024, n))
    m = min(n, PER_TRIAL)
    trials = [batch.trial(i) for i in range(m)]
    arrays = [Trial.of(t) for t in trials]
    for estimator, transcription in ((Cls(), numpy_cls), (ClsPaper(), numpy_cls_paper)):
        agree = _agreements(
            estimator,
            trials,
            _one_by_one(transcription, arrays, keyword=False)(_generators(n)),
            lambda estimate, rank: estimate.diagnostics["rank"] == rank,
        )
        best = _best_times(
            {
                "single": (_one_by_one(estimator.estimate, trials), m),
                "numpy": (_one_by_one(transcription, arrays, keyword=False), m),
                "columns": (lambda g, e=estimator: e.estimate_columns(batch, rngs=g), n),
                "list": (lambda g, e=estimator: e.estimate_batch(batch, rngs=g), n),
            },
            n,
        )
        single, plain, columns_us = best["single"], best["numpy"], best["columns"]
        print(
            f"{scenario:9s} {estimator.name:9s} N={n:6d} | one-at-a-time {single:7.1f} us"
            f" | numpy {plain:6.1f} us"
            f" | columns {columns_us:5.2f} us"
            f" | list {best['list']:5.2f} us | numpy/columns {plain / columns_us:5.1f}x"
            f" | one-at-a-time/columns {single / columns_us:5.1f}x"
            f" | transcription agrees {agree}/{m}",
            flush=True,
        )


def bench_ml(scenario: str, n: int) -> None:
    """``ml`` one at a time, the plain numpy transcription, ``estimate_columns`` and
    ``estimate_batch`` (module text, "ml")."""
    batch = simulate_trials(get_scenario(scenario), snr_db=0.0, seeds=trial_seeds(2024, n))
    m = min(n, PER_TRIAL_ML)
    trials = [batch.trial(i) for i in range(m)]
    arrays = [Trial.of(t) for t in trials]
    estimator = MaximumLikelihood()
    agree = _agreements(
        estimator,
        trials,
        _one_by_one(numpy_ml, arrays, keyword=False)(_generators(n)),
        lambda estimate, covariance: np.allclose(estimate.covariance_m2, covariance, rtol=1e-6),
    )
    best = _best_times(
        {
            "single": (_one_by_one(estimator.estimate, trials), m),
            "numpy": (_one_by_one(numpy_ml, arrays, keyword=False), m),
            "columns": (lambda g: estimator.estimate_columns(batch, rngs=g), n),
            "list": (lambda g: estimator.estimate_batch(batch, rngs=g), n),
        },
        n,
    )
    single, plain, columns_us = best["single"], best["numpy"], best["columns"]
    print(
        f"{scenario:13s} ml N={n:6d} | one-at-a-time {single:7.1f} us"
        f" | numpy LM {plain:6.1f} us | columns {columns_us:5.2f} us"
        f" | list {best['list']:5.2f} us | numpy/columns {plain / columns_us:5.1f}x"
        f" | one-at-a-time/columns {single / columns_us:5.1f}x"
        f" | transcription agrees {agree}/{m}",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 1,000 only")
    parser.add_argument(
        "--only", choices=("cls", "ml"), default=None, help="one estimator family only"
    )
    args = parser.parse_args()
    sizes = (1_000,) if args.quick else (1_000, 10_000)
    if args.only in (None, "cls"):
        for scenario in ("paper-1m", "turn"):
            for n in sizes:
                bench(scenario, n)
    if args.only in (None, "ml"):
        for scenario in ML_SCENARIOS:
            for n in sizes:
                bench_ml(scenario, n)


if __name__ == "__main__":
    main()
