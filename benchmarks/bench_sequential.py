"""Cost per frame of the frame-by-frame estimators, streaming (``init``/``update``).

The paper geometry at ``c σ_τ = 1 m`` (10 samples per frame, 10 m/s, Δ = 0.05 s) flown as a
square circuit (4 frames per side), so that the mirror pair forks after frame 4 and later
frames keep turning. Each estimator streams the frames through ``update``; the first frame
(the closed form plus its iterated update) is timed apart from the rest, and the later frames
are reported early and late in the run, which shows whether the cost per frame grows with the
number of frames (the static smoother relinearises every frame's factor on its one variable).
Medians over ``--repeats`` runs after one warm-up run; timings are printed, never asserted.

Run::

    python benchmarks/bench_sequential.py --frames 40 --repeats 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators.ekf import Ekf
from estimators.gtsam_smoother import GtsamSmoother
from scenarios.catalog import heading_velocities_mps, paper_scenario
from scenarios.simulate import simulate
from scenarios.types import FlightPlan, MeasurementSet

ESTIMATORS = {
    "ekf (IEKF)": Ekf(),
    "ekf max_iterations=1": Ekf(max_iterations=1),
    "ekf filter=ukf": Ekf(filter="ukf"),
    "gtsam-smoother static": GtsamSmoother(),
    "gtsam-smoother q=0.1 m/s": GtsamSmoother(process_noise_mps=0.1),
}


def square_circuit(n_frames: int, seed: int) -> MeasurementSet:
    """``n_frames`` frames of 10 samples around a square, 4 frames per side, seeded noise."""
    headings = [90.0 * ((frame // 4) % 4) for frame in range(n_frames)]
    base = paper_scenario(range_sigma_m=1.0, name="paper-1m")
    scenario = base.replace(
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 50.0],
            frame_velocities_mps=heading_velocities_mps(10.0, headings),
            samples_per_frame=10,
            sample_interval_s=0.05,
        )
    )
    return simulate(scenario, seed=seed)


def frame_times_s(estimator, frames: list[MeasurementSet]) -> tuple[np.ndarray, float]:
    """Wall time of every ``update`` and of the final ``estimate_state``."""
    state = estimator.init()
    times = np.empty(len(frames))
    for index, frame in enumerate(frames):
        start = time.perf_counter()
        state = estimator.update(state, frame)
        times[index] = time.perf_counter() - start
    start = time.perf_counter()
    estimate = estimator.estimate_state(state)
    final = time.perf_counter() - start
    if not estimate.success:
        raise RuntimeError(f"{estimator.name} failed: {estimate.message}")
    return times, final


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames per run (>= 12)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per estimator")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.frames < 12:
        parser.error("--frames: needs at least 12 frames (early and late windows)")
    frames = list(square_circuit(args.frames, args.seed).iter_frames())
    late = slice(args.frames - 10, args.frames)
    print(
        f"{args.frames} frames x 10 samples, median of {args.repeats} runs; "
        f"ms per update (frame 1 | frames 2-11 | frames {late.start + 1}-{late.stop}) "
        "and per estimate_state"
    )
    header = f"{'estimator':<26} {'frame 1':>9} {'2-11':>9} {'late':>9} {'estimate':>9}"
    print(header)
    print("-" * len(header))
    for label, estimator in ESTIMATORS.items():
        frame_times_s(estimator, frames)  # warm-up: imports and first-call costs
        runs = [frame_times_s(estimator, frames) for _ in range(args.repeats)]
        per_frame = np.median(np.stack([times for times, _ in runs]), axis=0) * 1e3
        final = np.median([final for _, final in runs]) * 1e3
        print(
            f"{label:<26} {per_frame[0]:9.2f} {per_frame[1:11].mean():9.2f} "
            f"{per_frame[late].mean():9.2f} {final:9.3f}"
        )


if __name__ == "__main__":
    main()
