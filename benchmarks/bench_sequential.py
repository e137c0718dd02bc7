"""Cost per update of the frame-by-frame estimators, streaming (``init``/``update``), by frame.

``paper-1m-turn`` flown for ``--frames`` frames (K = 10 samples per frame; east for 4 frames,
then north) at each ``--snr``. Each estimator streams the frames through ``update``; the wall time
of every update is taken, the median over ``--repeats`` runs (after one warm-up run) is averaged
over windows of 10 frames (frames 1-10, 11-20, ...), which shows whether the cost per update
grows with the number of frames. One core; timings are printed, never asserted.

``--baseline DIR`` also runs the same measurement on the package found in ``DIR`` (the code
before a change, e.g. ``mkdir /tmp/baseline && git archive HEAD | tar -x -C /tmp/baseline``) in
a subprocess and prints it above the current tree's ("before" and "after"). Load from other
processes moves both; compare runs made together.

Run::

    python benchmarks/bench_sequential.py --frames 40 --repeats 5 --baseline /tmp/baseline
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from estimators.sequential.ekf import Ekf
from estimators.sequential.gtsam_smoother import GtsamSmoother
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate
from scenarios.types import MeasurementSet

ESTIMATORS = {
    "ekf": Ekf,
    "gtsam-smoother": GtsamSmoother,
    "gtsam-smoother q=0.1 m/s": lambda: GtsamSmoother(process_noise_mps=0.1),
}
WINDOW = 10


def update_times_s(estimator, frames: list[MeasurementSet]) -> np.ndarray:
    """Wall time of every ``update`` of one streamed run (the final estimate must succeed)."""
    state = estimator.init()
    times = np.empty(len(frames))
    for index, frame in enumerate(frames):
        start = time.perf_counter()
        state = estimator.update(state, frame)
        times[index] = time.perf_counter() - start
    estimate = estimator.estimate_state(state)
    if not estimate.success:
        raise RuntimeError(f"{estimator.name} failed: {estimate.message}")
    return times


def measure(n_frames: int, snrs: list[float], repeats: int, seed: int) -> dict[str, list[float]]:
    """``"<estimator> @ <snr> dB"`` → mean ms per update in each window of 10 frames."""
    results = {}
    for snr in snrs:
        data = simulate(get_scenario("paper-1m-turn", frames=n_frames), snr_db=snr, seed=seed)
        frames = list(data.iter_frames())
        for label, make in ESTIMATORS.items():
            estimator = make()
            update_times_s(estimator, frames)  # warm-up: imports and first-call costs
            runs = np.stack([update_times_s(estimator, frames) for _ in range(repeats)])
            per_frame = np.median(runs, axis=0) * 1e3
            results[f"{label} @ {snr:g} dB"] = [
                float(np.mean(per_frame[start : start + WINDOW]))
                for start in range(0, n_frames, WINDOW)
            ]
    return results


def print_table(title: str, results: dict[str, list[float]], n_frames: int) -> None:
    windows = [
        f"{start + 1}-{min(start + WINDOW, n_frames)}" for start in range(0, n_frames, WINDOW)
    ]
    header = f"{title:<34}" + "".join(f"{window:>9}" for window in windows)
    print(header)
    print("-" * len(header))
    for label, values in results.items():
        print(f"{label:<34}" + "".join(f"{value:9.3f}" for value in values))
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames per run (>= 10)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per estimator")
    parser.add_argument("--snr", type=float, nargs="+", default=[0.0, -10.0], help="dB")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--baseline", help="directory of the package to compare against")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.frames < WINDOW:
        parser.error(f"--frames: needs at least {WINDOW} frames")
    if args.json:
        print(json.dumps(measure(args.frames, args.snr, args.repeats, args.seed)))
        return
    print(
        f"paper-1m-turn, {args.frames} frames x 10 samples, seed {args.seed}: ms per update, "
        f"median of {args.repeats} runs, mean over each window of frames"
    )
    print()
    if args.baseline:
        command = [sys.executable, os.path.abspath(__file__), "--json"]
        command += ["--frames", str(args.frames), "--repeats", str(args.repeats)]
        command += ["--seed", str(args.seed), "--snr", *map(str, args.snr)]
        env = {**os.environ, "PYTHONPATH": os.path.abspath(args.baseline)}
        output = subprocess.run(command, env=env, check=True, capture_output=True, text=True)
        print_table("before (--baseline)", json.loads(output.stdout), args.frames)
    print_table(
        "after (this tree)" if args.baseline else "this tree",
        measure(args.frames, args.snr, args.repeats, args.seed),
        args.frames,
    )


if __name__ == "__main__":
    main()
