"""The numbers the estimators' design is judged by, printed in one run.

Runs, one after another in fresh processes (so that no script's caches or imports time
another), the benchmarks that measure:

1. ``cls`` on one trial against a plain numpy transcription of the same mathematics, and its
   batch ratio (``bench_single_trial.py``);
2. ``ml`` on one trial against a plain numpy Levenberg-Marquardt from one start, and its batch
   ratio (``bench_single_trial_ml.py``);
3. ``cls`` columns with unknown emission time and carrier offset against one trial at a time
   (``bench_unknowns_batch.py``);
4. ``ekf`` and ``gtsam-smoother`` per update with each unknown against the cooperative
   emitter (``bench_sequential_unknowns.py``);
5. the ``noncooperative`` and ``paper-fig2`` experiments end to end on 2 workers, the rows and
   the report apart (``bench_speed.py``).

Run: ``python benchmarks/bench_overview.py [--quick]``. ``--quick`` passes each script its
smaller setting. Timings depend on the machine and its load; nothing here is a pass/fail
criterion.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

SCRIPTS: tuple[tuple[str, tuple[str, ...], tuple[str, ...]], ...] = (
    ("bench_single_trial.py", (), ("--batch", "5000")),
    ("bench_single_trial_ml.py", (), ("--quick",)),
    ("bench_unknowns_batch.py", (), ("--trials", "500")),
    ("bench_sequential_unknowns.py", (), ()),
    ("bench_speed.py", ("--experiment", "noncooperative"), ("--repeats", "1")),
    ("bench_speed.py", ("--experiment", "paper-fig2"), ("--repeats", "1")),
)
"""Each script, its arguments, and what ``--quick`` adds."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="each script's smaller setting")
    args = parser.parse_args()
    for script, arguments, quick in SCRIPTS:
        command = [sys.executable, str(HERE / script), *arguments, *(quick if args.quick else ())]
        print(f"\n=== {script} {' '.join(command[2:])}", flush=True)
        started = time.monotonic()
        finished = subprocess.run(command, check=False)
        status = "" if finished.returncode == 0 else f", exit status {finished.returncode}"
        print(f"--- {script}: {time.monotonic() - started:.0f} s wall{status}", flush=True)


if __name__ == "__main__":
    main()
