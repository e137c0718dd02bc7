"""The ``emitterbench`` command line: ``simulate``, ``estimate``, ``crlb``, ``fly``, ``list``, ``run``, ``report``;
``simulate-iq`` and ``measure`` on SigMF recordings (:mod:`comparison.cli_recordings`).

Adding a command is one function registered with ``@command("name", field=...)``: its
parameters are typed ``Annotated`` typer options, it imports the heavy modules it needs inside
its body (so that ``emitterbench --help`` stays quick), and any ``ValueError`` it raises (the
library's errors name the field and the fix) becomes the one line ``error: <field>: <message>``
on stderr with exit status 2, without a traceback; a message without a field gets ``field``.
Usage errors, Ctrl-C (exit 130) and unexpected exceptions (exit 1, ``error: internal: ...``)
are one line too (:mod:`comparison.cli_support`). A command that reads a measurement file takes
the options of its CSV constants with ``@with_csv_options`` and reads the file with
:func:`load_measurements`. Help texts are rich markup: write a literal ``[`` as ``\\[``. An
option that takes a value other than a number or a path gets a ``metavar`` saying what to
write (``KEY=VALUE``, ``X Y``), so the help shows no Python type; ``-h`` is ``--help``.

Resource-sized requests are refused before any work, with the limit and the environment
variable that raises it: ``--frames`` and the samples of a measurement set
(:mod:`scenarios.limits`), ``--trials`` and the size of a run (:mod:`comparison.experiment`),
``--workers`` (:data:`WORKERS_PER_CORE` per core), ``--instances``, ``--bootstrap``.
"""

from __future__ import annotations

import gc
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from comparison.cli_recordings import measure_command, simulate_iq_command
from comparison.cli_support import (
    CLUSTER_FAILED_STATUS,
    INTERNAL_ERROR_STATUS,
    INTERRUPTED_STATUS,
    USAGE_ERROR_STATUS,
    CsvConstants,
    DopplerSearchOption,
    OneLineErrors,
    Subcommand,
    clean_errors,
    estimate_of,
    fail,
    flags_for,
    known_scenario,
    load_measurements,
    parse_estimator_options,
    print_json,
    with_csv_options,
)
from comparison.cli_views import (
    ambiguity_text,
    print_crlb_table,
    print_estimate,
    print_plan,
    validation_lines,
    version_text,
)

__all__ = [
    "INTERNAL_ERROR_STATUS",
    "INTERRUPTED_STATUS",
    "USAGE_ERROR_STATUS",
    "app",
    "fail",
    "main",
]

WORKERS_PER_CORE = 4
"""Most local worker processes per core: more only add memory, each holds the numerics."""
MAX_INSTANCES = 1_000_000
"""Most ``validate`` instances per family (an SDP each, some milliseconds)."""
MAX_BOOTSTRAP = 100_000
"""Most bootstrap resamples of ``report`` (the intervals settle within a few thousand)."""

app = typer.Typer(
    cls=OneLineErrors,
    name="emitterbench",
    help=(
        "Locate a radio emitter from one UAV's Doppler and time-of-arrival measurements, "
        "and compare estimators against the Cramér-Rao bound."
    ),
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
    add_completion=False,
    pretty_exceptions_show_locals=False,
)


def _print_version(asked: bool) -> None:
    if asked:
        typer.echo(version_text())
        raise typer.Exit()


@app.callback()
def emitterbench(
    version: Annotated[
        bool,
        typer.Option(
            "--version", is_eager=True, callback=_print_version, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Locate a radio emitter from one UAV's Doppler and ToA measurements (see docs/math.md)."""


# --------------------------------------------------------------------------------------------
# shared helpers: clean errors, measurement files, output
# --------------------------------------------------------------------------------------------

Command = TypeVar("Command", bound=Callable[..., Any])


def command(
    name: str,
    *,
    field: str,
    interrupted: Callable[[dict[str, Any]], str] | None = None,
    late_help: dict[str, Callable[[], str]] | None = None,
    **typer_options: Any,
) -> Callable[[Command], Command]:
    """Register ``function`` as the sub-command ``name`` of :data:`app`, with clean errors.

    ``field`` names a message that has none (the command's main input); ``interrupted``
    says, from the command's arguments, what to do after Ctrl-C; ``late_help`` writes the
    help of a parameter when the help is shown (:class:`~comparison.cli_support.Subcommand`).
    """

    def register(function: Command) -> Command:
        wrapped = clean_errors(function, field=field, interrupted=interrupted)
        kind = type(f"{name.title()}Command", (Subcommand,), {"late_help": late_help or {}})
        app.command(name, cls=kind, **typer_options)(wrapped)
        return function

    return register


JsonFlag = Annotated[
    bool, typer.Option("--json", help="Print exactly one JSON object instead of a summary.")
]
KeyValues = list[str] | None
"""The type of a repeatable ``--option key=value``; its ``metavar`` is :data:`KEY_VALUE`."""
KEY_VALUE = "KEY=VALUE"
MeasurementFile = Annotated[
    Path, typer.Argument(help="Measurements .json, .csv (with the constants) or .sigmf-meta.")
]


# --------------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------------


@command("simulate", field="scenario")
def simulate_command(
    scenario: Annotated[
        str,
        typer.Argument(help="Scenario name (see `emitterbench list`).", callback=known_scenario),
    ],
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the noise draw.")],
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Measurement file to write (.json).")
    ],
    snr_db: Annotated[
        float, typer.Option("--snr-db", help="SNR: every σ times 10^(−snr_db/20) (MATH §2).")
    ] = 0.0,
    frames: Annotated[
        int | None,
        typer.Option(
            "--frames", min=1, help="Number of frames (extends the last) \\[the scenario's]."
        ),
    ] = None,
) -> None:
    """Simulate one noisy trial of a named scenario and write it, truth included."""
    from comparison.sweep import SNR_RANGE_DB
    from scenarios.catalog import get_scenario
    from scenarios.files import write_measurements
    from scenarios.limits import FRAMES, SAMPLES, check_limit
    from scenarios.simulate import simulate

    if output.suffix.lower() != ".json":
        raise ValueError(f"--output: {output} must end in .json")
    low, high = SNR_RANGE_DB
    if not low <= snr_db <= high:
        raise ValueError(f"--snr-db: must lie in [{low:g}, {high:g}] dB, got {snr_db:g}")
    if frames is not None:
        check_limit(frames, "--frames", "frames", FRAMES, "fly fewer frames")
    chosen = get_scenario(scenario, frames=frames)
    fix = "fly fewer frames"
    check_limit(chosen.flight.n_samples, "--frames", "samples", SAMPLES, fix)
    data = simulate(chosen, snr_db=snr_db, seed=seed)
    with flags_for({"output": "--output"}):
        write_measurements(data, output)
    typer.echo(
        f"wrote {output}: {chosen.name}, {data.n_samples} samples in {len(data.frames)} "
        f"frame(s), SNR {snr_db:g} dB, seed {seed}"
    )


command("simulate-iq", field="scenario")(simulate_iq_command)
command("measure", field="recording")(measure_command)


@command("estimate", field="file")
@with_csv_options
def estimate_command(
    file: MeasurementFile,
    estimator: Annotated[
        str,
        typer.Option(
            "--estimator", "-e", help="Estimator name (see `emitterbench list`) or module:Class."
        ),
    ] = "cls",
    option: Annotated[
        KeyValues,
        typer.Option(
            "--option",
            metavar=KEY_VALUE,
            help="Estimator option, repeatable; JSON values, e.g. side_prior_m=[30,10].",
        ),
    ] = None,
    ignore_unknowns: Annotated[
        bool,
        typer.Option(
            "--ignore-unknowns",
            help="Take the file's unknown carrier offset and emission time as zero, to see the "
            "bias that costs (MATH §15).",
        ),
    ] = False,
    doppler_search_hz: DopplerSearchOption = None,
    as_json: JsonFlag = False,
    *,
    constants: CsvConstants,
) -> None:
    """Locate the emitter from a measurement file with one estimator (rng seeded with 0)."""
    from comparison.scoring import estimate_to_dict
    from estimators.base import capabilities_of
    from estimators.goodness_of_fit import fit_warning
    from estimators.registry import make_estimator

    options = parse_estimator_options(option or [])
    chosen = make_estimator(estimator, **options)
    estimate, data = estimate_of(
        chosen, estimator, file, constants, doppler_search_hz, ignore_unknowns
    )
    misfit = fit_warning(estimate.diagnostics)
    if misfit is not None:
        typer.echo(f"warning: {misfit}", err=True)
    result = estimate_to_dict(estimate, data.truth_emitter_m)
    if as_json:
        print_json(result)
        return
    seen = data.select_frames(capabilities_of(chosen).frames)
    print_estimate(result, file, data, ambiguity_text(estimate.candidates_m, seen))


@command("crlb", field="file")
@with_csv_options
def crlb_command(
    file: MeasurementFile,
    at: Annotated[
        tuple[float, float] | None,
        typer.Option("--at", metavar="X Y", help="Emitter position, m \\[the truth in the file]."),
    ] = None,
    doppler_search_hz: DopplerSearchOption = None,
    as_json: JsonFlag = False,
    *,
    constants: CsvConstants,
) -> None:
    """Cramér-Rao bound for the emitter's position per modality set: toa, doppler, rss,
    toa+doppler.

    Needs only the geometry and the σ's of the file, not the measured values (MATH §8). With
    the height unknown the bound is 3×3 (horizontal and vertical parts; --at X Y is taken at
    the file's emitter_height_m).
    """
    from scenarios.types import MAX_COORDINATE_M

    data = load_measurements(file, constants, doppler_search_hz)
    if at is not None:
        if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_M for v in at):
            raise ValueError(
                f"--at: expected two finite numbers X Y within ±{MAX_COORDINATE_M:g} m, got "
                f"{' '.join(f'{v:g}' for v in at)}"
            )
        at_m: Any = at
    elif data.truth_emitter_m is not None:
        at_m = data.truth_emitter_m
    else:
        raise ValueError(f"--at: {file} has no truth; give the emitter position as --at X Y")
    from comparison.crlb import crlb_table

    table = crlb_table(data, at_m)
    if as_json:
        print_json(table)
        return
    print_crlb_table(table, data)


@command("fly", field="file")
@with_csv_options
def fly_command(
    file: MeasurementFile,
    planner: Annotated[
        str,
        typer.Option(
            "--planner",
            "-p",
            help="Planner: constant, paper, fisher, orbit (see `emitterbench list`) or module:Class.",
        ),
    ],
    estimator: Annotated[
        str,
        typer.Option("--estimator", "-e", help="Estimator whose estimate steers the planner."),
    ] = "ml",
    option: Annotated[
        KeyValues,
        typer.Option(
            "--option",
            metavar=KEY_VALUE,
            help="Planner option, repeatable; JSON values, e.g. radius_m=25.",
        ),
    ] = None,
    estimator_option: Annotated[
        KeyValues,
        typer.Option(
            "--estimator-option",
            metavar=KEY_VALUE,
            help="Estimator option, repeatable (as `estimate --option`).",
        ),
    ] = None,
    doppler_search_hz: DopplerSearchOption = None,
    as_json: JsonFlag = False,
    *,
    constants: CsvConstants,
) -> None:
    """The next frame's velocity, from the measurements of the frames flown so far.

    The flight is reconstructed from the samples (frames of K samples at one constant velocity,
    one sample interval); the estimator locates the emitter (rng seeded with 0, as `estimate`)
    and the planner turns its estimate into the velocity of the next frame (MATH §12-§13).
    """
    import numpy as np

    from comparison.closed_loop import next_frame_plan
    from estimators.registry import make_estimator
    from scenarios.planners import get_planner

    chosen_planner = get_planner(planner, **parse_estimator_options(option or []))
    chosen_estimator = make_estimator(
        estimator, **parse_estimator_options(estimator_option or [], "--estimator-option")
    )
    data = load_measurements(file, constants, doppler_search_hz)
    result = next_frame_plan(data, chosen_planner, chosen_estimator, rng=np.random.default_rng(0))
    if as_json:
        print_json(result)
        return
    print_plan(result, file)


@command("list", field="list")
def list_command() -> None:
    """The built-in experiments, named scenarios and estimators, one line each."""

    from estimators.registry import all_entries
    from scenarios.catalog import CATALOG

    def unavailable(entry: Any) -> str:
        try:
            missing = entry.missing_modules()
        except ValueError as error:  # a plug-in that fails on import
            return f"  [unavailable: {error}]"
        return f"  [unavailable: needs {', '.join(missing)}]" if missing else ""

    from comparison.experiment_catalog import BUILTIN_EXPERIMENTS
    from scenarios.planners import PLANNER_SUMMARIES

    width = max(
        len(name) for name in (*CATALOG, *all_entries(), *BUILTIN_EXPERIMENTS, *PLANNER_SUMMARIES)
    )
    typer.echo("experiments (emitterbench run NAME -o DIR):")
    for name, summary in BUILTIN_EXPERIMENTS.items():
        typer.echo(f"  {name:<{width}}  {summary}")
    typer.echo("scenarios:")
    for name, entry in CATALOG.items():
        typer.echo(f"  {name:<{width}}  {entry.summary}")
    typer.echo("estimators:")
    for name, entry in all_entries().items():
        typer.echo(f"  {name:<{width}}  {entry.summary}{unavailable(entry)}")
    typer.echo("planners (emitterbench fly FILE --planner NAME):")
    for name, summary in PLANNER_SUMMARIES.items():
        typer.echo(f"  {name:<{width}}  {summary}")


RUN_FLAGS = {
    "out_dir": "--output",
    "trials": "--trials",
    "workers": "--workers",
    "resume": "--resume",
    "scheduler": "--scheduler",
    "worker_wait_s": "--worker-wait-s",
    "accept_code_change": "--accept-code-change",
}
"""The parameters of :func:`comparison.engine.run_experiment` that ``run`` takes as flags."""


def _resume_hint(arguments: dict[str, Any]) -> str:
    command = f"emitterbench run {arguments['experiment']} -o {arguments['output']} --resume"
    return f"the rows stored so far are kept; finish the run with `{command}`"


def _worker_wait_help() -> str:
    from comparison.execution import WORKER_WAIT_S

    return (
        "With --scheduler: seconds to wait for a first Dask worker before giving up "
        f"\\[{WORKER_WAIT_S:g}]."
    )


@command(
    "run",
    field="experiment",
    interrupted=_resume_hint,
    late_help={"worker_wait_s": _worker_wait_help},
)
def run_command(
    experiment: Annotated[
        str, typer.Argument(help="A built-in experiment (see `emitterbench list`) or a .toml file.")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Run folder to write.")],
    trials: Annotated[
        int | None,
        typer.Option(
            "--trials",
            min=1,
            help="Trials per point (overrides the file; with --resume, the run's own).",
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", min=1, help="Local worker processes \\[all cores].")
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Finish an interrupted run in the same folder.")
    ] = False,
    accept_code_change: Annotated[
        bool,
        typer.Option(
            "--accept-code-change",
            help="With --resume: go on although emitterbench's code or a plug-in's files "
            "changed since the rows already stored (refused otherwise; run.json records it).",
        ),
    ] = False,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            envvar="DASK_SCHEDULER_ADDRESS",
            help="Run on a Dask cluster at tcp://HOST:PORT (extra emitterbench\\[cluster]).",
        ),
    ] = None,
    worker_wait_s: Annotated[float | None, typer.Option("--worker-wait-s")] = None,
) -> None:
    """Run a Monte Carlo comparison into a run folder, then write its report.

    Rows are stored as they arrive (results.sqlite): a killed run loses at most the trials in
    flight, and --resume finishes it with exactly the rows of an uninterrupted run, with the
    number of trials it was started with unless --trials asks for more. A resume with other
    code than the rows already stored (emitterbench's or a plug-in's) is refused, naming the
    changed files, unless --accept-code-change. The report is written before the run lets go
    of the folder's lock. Ctrl-C and SIGTERM stop it the same way (exit 130 and 143), as does
    a Dask cluster that fails (exit 3): the last line says how to finish the run.
    """
    from comparison.engine import run_experiment
    from comparison.execution import ClusterError
    from comparison.experiment import load_experiment
    from comparison.report import write_report
    from comparison.run_folder import EXPERIMENT_FILE, read_experiment

    cores = os.cpu_count() or 1
    if workers is not None and workers > WORKERS_PER_CORE * cores:
        raise ValueError(
            f"--workers: {workers} is more than {WORKERS_PER_CORE} per core ({cores} cores "
            "here); more processes than cores only add memory"
        )
    definition = load_experiment(experiment)
    if trials is None and resume and (output / EXPERIMENT_FILE).is_file():
        trials = read_experiment(output).trials  # the run keeps its own number of trials
    if trials is not None and trials != definition.trials:
        try:
            definition = definition.with_trials(trials)
        except ValueError as error:
            raise ValueError(f"--trials: {str(error).partition(': ')[2]}") from None
    waiting = {} if worker_wait_s is None else {"worker_wait_s": worker_wait_s}
    with flags_for(RUN_FLAGS):
        try:
            run_dir = run_experiment(
                definition,
                output,
                workers=workers,
                scheduler=scheduler,
                resume=resume,
                accept_code_change=accept_code_change,
                write_report=write_report,
                **waiting,
            )
        except ClusterError as error:
            what = error.what.replace("(worker_wait_s)", "(--worker-wait-s)")
            hint = _resume_hint({"experiment": experiment, "output": output})
            fail(f"--scheduler: {what}; {hint}", CLUSTER_FAILED_STATUS)
    typer.echo(f"report: {run_dir / 'report.html'}")
    tables = [run_dir / name for name in ("summary.csv", "trials.csv")]
    typer.echo(f"tables: {', '.join(str(path) for path in tables if path.is_file())}")


@command("report", field="run_dir")
def report_command(
    run_dir: Annotated[Path, typer.Argument(help="A run folder written by `emitterbench run`.")],
    bootstrap: Annotated[
        int | None,
        typer.Option(
            "--bootstrap",
            min=100,
            max=MAX_BOOTSTRAP,
            help="Bootstrap resamples for intervals (default: as run).",
        ),
    ] = None,
) -> None:
    """(Re)write summary.csv, trials.csv, figures/ and report.html of a run folder.

    The report holds the folder's lock while it writes: a report while a run (or another
    report) writes the folder is refused with one line naming it (exit status 2).
    """
    from comparison.report import write_report

    if not run_dir.is_dir():
        raise ValueError(
            f"run_dir: {run_dir} is not a folder; give the folder of a run "
            "(`emitterbench run EXPERIMENT -o DIR`)"
        )
    if not (run_dir / "results.sqlite").exists():
        raise ValueError(
            f"run_dir: {run_dir} holds no results.sqlite; run `emitterbench run` first"
        )
    options = {} if bootstrap is None else {"n_bootstrap": bootstrap}
    with flags_for({"resume": "--resume"}):  # a damaged store: rerun with --resume
        html = write_report(run_dir, **options)
    typer.echo(f"report: {html}")


def _families_help() -> str:
    from comparison.crosscheck import FAMILIES

    return f"Instance family, repeatable: {', '.join(FAMILIES)} \\[all]."


@command("validate", field="validate", late_help={"families": _families_help})
def validate_command(
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Folder for validate.json and reports.")
    ] = None,
    instances: Annotated[
        int,
        typer.Option("--instances", min=1, max=MAX_INSTANCES, help="Seeded instances per family."),
    ] = 1000,
    families: Annotated[
        list[str] | None,
        typer.Option("--families", metavar="NAME", help="Instance family, repeatable \\[all]."),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the instance draws.")] = 0,
    replay_seed: Annotated[
        int | None,
        typer.Option(
            "--replay", min=0, help="Re-run one instance verbosely (give one --families)."
        ),
    ] = None,
    estimator: Annotated[
        str | None,
        typer.Option(
            "--estimator",
            "-e",
            help=(
                "Validate this estimator's own closed form instead of the built-in one: a name "
                "(see `emitterbench list`) or module:Class with a constrained_ls(data) method "
                "(docs/writing-an-estimator.md)."
            ),
        ),
    ] = None,
    option: Annotated[
        KeyValues,
        typer.Option(
            "--option",
            metavar=KEY_VALUE,
            help="Estimator option, repeatable (with --estimator); JSON values.",
        ),
    ] = None,
) -> None:
    """Check the closed-form CLS against its SDP relaxation on seeded random instances.

    With --estimator, the estimator runs on each instance's measurements and is judged on the
    rows it exposes (constrained_ls): every candidate must attain the exact optimum, both mirror
    minimisers are due in the hard case, and the SDP value must equal the optimum. Exit status
    1 when any instance disagrees beyond tolerance or its SDP is not optimal (MATH §5, §11).
    """
    from comparison.crosscheck import FAMILIES, check_protocol, replay_with_verdict, run_validation

    chosen = tuple(families) if families else FAMILIES
    unknown = sorted(set(chosen) - set(FAMILIES))
    if unknown:
        raise ValueError(f"--families: unknown {unknown}; choose from {', '.join(FAMILIES)}")
    validated = None
    if estimator is not None:
        from estimators.registry import make_estimator

        validated = make_estimator(estimator, **parse_estimator_options(option or []))
        check_protocol(validated)
    elif option:
        raise ValueError("--option: estimator options need --estimator NAME")
    if replay_seed is not None:
        if len(chosen) != 1:
            raise ValueError("--families: --replay needs exactly one family")
        text, agrees = replay_with_verdict(replay_seed, chosen[0], estimator=validated)
        typer.echo(text)
        if not agrees:
            raise typer.Exit(1)
        return
    if output is None:
        raise ValueError("--output: give the folder for validate.json (-o DIR)")
    if output.exists() and not output.is_dir():
        raise ValueError(f"--output: {output} is a file; choose a folder for validate.json")
    try:  # before the instances, which may take hours
        output.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(
            f"--output: cannot create {output} ({error.strerror or error}); choose a writable "
            "folder"
        ) from None
    from contextlib import ExitStack

    from comparison.progress import progress_display

    with ExitStack() as stack:
        total = instances * len(chosen)
        bar = progress_display(stack, total=total, unit="instances")
        counted = 0

        def progress(done: int, total: int, family: str) -> None:
            nonlocal counted
            bar.describe(family)
            bar.advance(done - counted)
            counted = done

        result = run_validation(
            instances=instances,
            families=chosen,
            seed=seed,
            out_dir=output,
            progress=progress,
            estimator=validated,
        )
        bar.finish()
    for line in validation_lines(result):
        typer.echo(line)
    typer.echo(f"report: {output / 'validate.html'}")
    if not result.ok:
        shown = result.disagreements[:10]
        for r in shown:
            typer.echo(
                f"{r.family} seed {r.seed}: replay with {result.replay_command(r)}", err=True
            )
        more = len(result.disagreements) - len(shown)
        tail = f" ({more} more not shown)" if more else ""
        typer.echo(
            f"{len(result.disagreements)} instance(s) disagree{tail}; see {output}", err=True
        )
        raise typer.Exit(1)


def main() -> None:
    """Console-script entry point ``emitterbench``.

    What the command made lives until the process ends, so the cyclic garbage collector is
    told to leave it (``gc.freeze``) once the command is done: the interpreter's last
    collection at exit over a run's objects (pandas, matplotlib, scipy) took 0.2-0.4 s after
    the report was written. Files are closed by then (every one is written in a ``with``)."""
    try:
        app(prog_name="emitterbench")
    finally:
        gc.freeze()


if __name__ == "__main__":
    main()
