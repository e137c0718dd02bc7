"""Peak memory (resident set) of ``write_report`` on one point of many trials, by stage.

The run: ``lls-toa`` on ``paper-1m`` at 10 dB, one frame, ``--trials`` trials (default
100,000; the limit is 1,000,000), run once into ``--folder`` with 2 workers unless the folder
already holds a finished run (about 45 s per 100,000 trials on an idle core pair). The report
is then written in a fresh process, which prints the process's resident set before and after
each stage and its peak so far (``ru_maxrss``): reading the points, the summary (the trial rows
read a few points at a time), summary.csv, thresholds.csv, trials.csv (a batch at a time),
drawing and saving the figures (here, one after another: the report draws them in worker
processes, whose memory is their own), the page.

Run: ``python benchmarks/bench_report_memory.py [--trials N] [--folder DIR]``.
"""

from __future__ import annotations

import argparse
import functools
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def resident_mb() -> float:
    """The process's resident set now, MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def peak_mb() -> float:
    """The process's largest resident set so far, MB (Linux gives ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def ensure_run(folder: Path, trials: int) -> None:
    """A finished one-point run of ``trials`` trials in ``folder`` (run now when absent)."""
    if (folder / "results.sqlite").is_file() and (folder / "run.json").is_file():
        return
    from comparison.engine import run_experiment
    from comparison.experiment import Experiment

    experiment = Experiment.from_dict(
        {
            "name": "one-point",
            "scenarios": ["paper-1m"],
            "estimators": ["lls-toa"],
            "sweep": {"parameter": "snr_db", "values": [10]},
            "trials": trials,
            "seed": 7,
            "frames": 1,
        }
    )
    start = time.perf_counter()
    run_experiment(experiment, folder, workers=2, progress=False)
    print(f"ran {trials:,} trials into {folder} in {time.perf_counter() - start:.0f} s")


def report_by_stage(folder: Path) -> None:
    """Write the report of ``folder`` here, printing the memory around every stage."""
    import comparison.report as report

    def watched(owner: Any, name: str, label: Any, then: Any = None) -> None:
        function = getattr(owner, name)

        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            before = resident_mb()
            result = function(*args, **kwargs)
            stage = label(*args) if callable(label) else label
            print(
                f"  {stage:<22} resident {before:6.0f} -> {resident_mb():6.0f} MB, "
                f"peak so far {peak_mb():6.0f} MB",
                flush=True,
            )
            if then is not None:
                then()
            return result

        setattr(owner, name, wrapper)

    watched(report, "_load", "points, experiment")

    def watch_figures() -> None:  # matplotlib is imported after the summary, as the report does
        import comparison.report_figures as report_figures
        from comparison import figures

        # drawn here, one after another, so that each is seen (the report forks workers)
        report_figures.figure_processes = lambda n_figures: 1
        watched(report_figures, "figure_plans", "plan figures")
        watched(figures, "save_figure", lambda _figure, _folder, stem, **_: f"save {stem}")

    watched(report, "_summary", "summary", then=watch_figures)
    watched(report, "write_csv", lambda path, *_: Path(path).name)
    watched(report, "render_html", "page")
    print(f"  {'imports':<22} resident {resident_mb():6.0f} MB")
    report.write_report(folder)
    print(json.dumps({"peak_mb": round(peak_mb())}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100_000)
    parser.add_argument("--folder", type=Path, help="run folder (run here when absent)")
    parser.add_argument("--stages-of", type=Path, help=argparse.SUPPRESS)  # the child
    options = parser.parse_args()
    if options.stages_of is not None:
        report_by_stage(options.stages_of)
        return
    folder = options.folder or Path(tempfile.mkdtemp(prefix="bench_memory_")) / "run"
    ensure_run(folder, options.trials)
    print(f"write_report of {folder} ({options.trials:,} trials of one estimator on one point):")
    child = [sys.executable, __file__, "--stages-of", str(folder)]
    lines = subprocess.run(child, check=True, capture_output=True, text=True).stdout
    print(lines, end="")


if __name__ == "__main__":
    main()
