"""CPU cost per update of ``ekf`` and ``gtsam-smoother`` with and without unknowns (MATH §15).

``paper-1m-turn`` flown for ``--frames`` frames (K = 10 samples per frame; east for 4 frames, then
north) at ``--snr`` dB, the emitter 800 Hz off its carrier with an emission time of 0.3 ms, and
the carrier offset, the emission time, both or neither declared unknown. Each estimator streams
``--trials`` seeded trials through ``init``/``update`` (the CPU time per update, averaged over
all frames, and over the last ``--frames // 2`` to show whether it grows with the frames) and
runs its ``estimate`` on them (the CPU time per estimate, what an experiment calls). Each number
is the least of ``--repeats`` runs (:func:`cpu_time.best_cpu_s`); the ratio is to the
cooperative emitter's. Timings are printed, never asserted.

A second table is the ``noncooperative`` experiment's rows: ``estimate`` on ``beacon-pass`` and
``turn-noncooperative`` at its SNRs (``--rows`` seeded trials each), with their unknowns
declared and with the same data declared cooperative: CPU ms per row and the ratio.

``--baseline DIR`` runs the same measurement on the package in ``DIR`` (the code before a change,
e.g. ``mkdir /tmp/baseline && git archive HEAD | tar -x -C /tmp/baseline``) in a subprocess and
prints it above this tree's.

Run::

    python benchmarks/bench_sequential_unknowns.py --frames 10 --trials 10 --baseline /tmp/b
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
if os.environ.get("PYTHONPATH") is None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cpu_time import best_cpu_s

from estimators.sequential.ekf import Ekf
from estimators.sequential.gtsam_smoother import GtsamSmoother
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate

ESTIMATORS = {"ekf": Ekf, "gtsam-smoother": GtsamSmoother}
UNKNOWNS = {
    "cooperative": (),
    "carrier offset": ("carrier_offset_hz",),
    "emission time": ("emission_time_s",),
    "both": ("carrier_offset_hz", "emission_time_s"),
}


def trials(unknowns: tuple[str, ...], n_frames: int, n_trials: int, snr_db: float) -> list:
    """Seeded trials of ``paper-1m-turn`` with δ = 800 Hz, b = 0.3 ms and ``unknowns``."""
    scenario = get_scenario("paper-1m-turn", frames=n_frames).replace(
        carrier_offset_hz=800.0, emission_time_s=3e-4, unknowns=unknowns
    )
    return [simulate(scenario, snr_db=snr_db, seed=seed) for seed in range(n_trials)]


def streamed_cpu_s(estimator, data_sets: list, repeats: int) -> tuple[float, float]:
    """CPU s per update over every frame, and over the later half of the frames (the states
    after the first half are made untimed)."""
    frame_lists = [list(data.iter_frames()) for data in data_sets]
    n_frames = len(frame_lists[0])
    first = n_frames - n_frames // 2

    def stream(frames: list, state):
        for frame in frames:
            state = estimator.update(state, frame)
        return state

    def stream_all() -> None:
        for frames in frame_lists:
            stream(frames, estimator.init())

    every = best_cpu_s(stream_all, repeats)
    late = float("inf")
    for _ in range(repeats):
        halfway = [stream(frames[:first], estimator.init()) for frames in frame_lists]
        start = time.process_time()
        for frames, state in zip(frame_lists, halfway, strict=True):
            stream(frames[first:], state)
        late = min(late, time.process_time() - start)
    count = len(frame_lists)
    return every / (count * n_frames), late / (count * (n_frames - first))


def measure(n_frames: int, n_trials: int, snr_db: float, repeats: int) -> dict[str, list[float]]:
    """``"<estimator> / <unknowns>"`` → ms per update (all frames, later half), ms per
    estimate."""
    results = {}
    for label, unknowns in UNKNOWNS.items():
        data_sets = trials(unknowns, n_frames, n_trials, snr_db)
        for name, make in ESTIMATORS.items():
            estimator = make()
            estimator.estimate(data_sets[0])  # warm-up: imports and first-call costs
            every, late = streamed_cpu_s(estimator, data_sets, repeats)
            batch = best_cpu_s(
                lambda e=estimator, ds=data_sets: [e.estimate(d) for d in ds], repeats
            )
            results[f"{name} / {label}"] = [every * 1e3, late * 1e3, batch / n_trials * 1e3]
    return results


ROW_SCENARIOS = ("beacon-pass", "turn-noncooperative")
"""The scenarios of the ``noncooperative`` experiment (comparison/experiment_catalog.py)."""

ROW_SNRS_DB = (-10.0, 0.0, 10.0, 20.0, 30.0)
"""Its SNR sweep."""


def measure_rows(n_rows: int, repeats: int) -> dict[str, list[float]]:
    """``"<estimator> / <scenario>"`` → CPU ms per ``estimate`` with the unknowns declared
    cooperative, and with them unknown (the experiment's rows)."""
    results = {}
    for scenario_name in ROW_SCENARIOS:
        scenario = get_scenario(scenario_name)
        cooperative = scenario.replace(unknowns=())
        data = {
            kind: [
                simulate(s, snr_db=snr, seed=seed) for snr in ROW_SNRS_DB for seed in range(n_rows)
            ]
            for kind, s in (("cooperative", cooperative), ("unknowns", scenario))
        }
        for name, make in ESTIMATORS.items():
            estimator = make()
            estimator.estimate(data["unknowns"][0])  # warm-up
            results[f"{name} / {scenario_name}"] = [
                best_cpu_s(lambda e=estimator, ds=ds: [e.estimate(d) for d in ds], repeats)
                / len(ds)
                * 1e3
                for ds in data.values()
            ]
    return results


def print_rows(title: str, results: dict[str, list[float]]) -> None:
    header = f"{title:<40}{'cooperative':>12}{'unknowns':>10}{'ratio':>7}"
    print(header)
    print("-" * len(header))
    for key, (cooperative, unknown) in results.items():
        print(f"{key:<40}{cooperative:12.2f}{unknown:10.2f}{unknown / cooperative:7.2f}")
    print()


def print_table(title: str, results: dict[str, list[float]]) -> None:
    header = (
        f"{title:<34}{'ms/update':>10}{'ratio':>7}{'later half':>11}{'ratio':>7}"
        f"{'ms/estimate':>12}{'ratio':>7}"
    )
    print(header)
    print("-" * len(header))
    for key, values in results.items():
        cooperative = results[f"{key.split(' / ')[0]} / cooperative"]
        cells = "".join(
            f"{value:{width}.2f}{value / base:7.2f}"
            for value, base, width in zip(values, cooperative, (10, 11, 12), strict=True)
        )
        print(f"{key:<34}{cells}")
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10, help="frames per trial (>= 2)")
    parser.add_argument("--trials", type=int, default=10, help="seeded trials")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs (the least counts)")
    parser.add_argument("--snr", type=float, default=10.0, help="dB")
    parser.add_argument(
        "--rows", type=int, default=4, help="trials per point of the experiment's table (0: none)"
    )
    parser.add_argument("--baseline", help="directory of the package to compare against")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.frames < 2:
        parser.error("--frames: needs at least 2 frames")
    if args.json:
        tables = [measure(args.frames, args.trials, args.snr, args.repeats)]
        if args.rows:
            tables.append(measure_rows(args.rows, args.repeats))
        print(json.dumps(tables))
        return
    print(
        f"paper-1m-turn, {args.frames} frames x 10 samples, {args.trials} trials at "
        f"{args.snr:g} dB: CPU ms, least of {args.repeats} runs; ratio to the cooperative"
    )
    print()
    if args.baseline:
        command = [sys.executable, os.path.abspath(__file__), "--json"]
        command += ["--frames", str(args.frames), "--trials", str(args.trials)]
        command += ["--repeats", str(args.repeats), "--snr", str(args.snr)]
        command += ["--rows", str(args.rows)]
        env = {**os.environ, "PYTHONPATH": os.path.abspath(args.baseline)}
        output = subprocess.run(command, env=env, check=True, capture_output=True, text=True)
        before = json.loads(output.stdout)
    this = "after (this tree)" if args.baseline else "this tree"
    if args.baseline:
        print_table("before (--baseline)", before[0])
    print_table(this, measure(args.frames, args.trials, args.snr, args.repeats))
    if args.rows:
        print(
            f"noncooperative's rows ({args.rows} trials at each of {len(ROW_SNRS_DB)} SNRs): "
            "CPU ms per estimate, the same data declared cooperative and with its unknowns"
        )
        print()
        if args.baseline:
            print_rows("before (--baseline)", before[1])
        print_rows(this, measure_rows(args.rows, args.repeats))


if __name__ == "__main__":
    main()
