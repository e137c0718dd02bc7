"""What the commands of :mod:`comparison.cli` share: one-line errors, ``key=value`` options, JSON.

Every failure a user sees is one line on stderr, ``error: <field>: <what is wrong and the fix>``,
never a traceback, and nothing is printed before it (numpy's floating-point warnings are
silenced; any other warning is one line ``warning: ...``). The exit statuses:

====  ==========================================================================================
0     success
1     ``validate`` found a disagreement; or an internal error, a bug of emitterbench or of an
      estimator: ``error: internal: <type>: <message> (please report ...)``
      (``EMITTERBENCH_TRACEBACK=1`` prints the traceback before that line)
2     a usage or input error: a bad option, a malformed file, a request beyond a limit, no
      command at all (the usage is printed once); a run folder another run or report is
      writing; a ``--resume`` with changed code (without ``--accept-code-change``)
3     ``run`` on a dask cluster that failed: its scheduler was lost, or no worker joined within
      ``--worker-wait-s``; the rows stored so far are kept, and the line says how to finish the
      run with ``--resume``
130   interrupted (Ctrl-C); ``run`` says how to finish the run with ``--resume``
141   the reader of stdout went away (``emitterbench list | head -1``): quietly, nothing on
      stderr, as a command that SIGPIPE ends (``yes | head -1``)
143   stopped by SIGTERM (``kill``, a batch system's time limit), handled as Ctrl-C: the workers
      are stopped, the stored rows kept, the same line with ``terminated (SIGTERM)``
====  ==========================================================================================

SIGTERM is turned into :class:`Terminated`, a ``KeyboardInterrupt``, for as long as a command
runs (:func:`sigterm_as_interrupt`), so everything Ctrl-C does on its way out runs for it too:
``finally`` blocks, the worker pool's shutdown, the folder's lock released, temporary files
removed. A second SIGTERM during that is ignored.

:class:`OneLineErrors` is the command group of :data:`comparison.cli.app`: it turns click's
usage errors (an unknown option, a value out of range, a missing argument) into the same one
line, which points at the help of the sub-command that failed, and any exception a command lets
escape into the internal error. Every sub-command is a :class:`Subcommand`: its flags show no
value type in the help, and an option's help may be written when the help is asked for (names
that live in a module too heavy to import for ``emitterbench --help``). :func:`clean_errors`
wraps each command: a ``ValueError`` (the library's errors name the field and the fix) becomes
the one line, a message without a field gets the command's main input as its field;
:func:`flags_for` renames a library parameter (``out_dir``, ``resume=True``) as the flag the
user typed (``--output``, ``--resume``).

:func:`parse_estimator_options` reads the ``--option key=value`` pairs (JSON values within the
limits of :mod:`scenarios.limits`), :func:`print_json` prints the one JSON object of ``--json``;
``@with_csv_options`` gives a command the options of a CSV file's constants
(:data:`CSV_OPTIONS`), and :func:`load_measurements` reads a measurement file with them, or
measures a SigMF recording of bursts (:func:`measured_recording`).
"""

from __future__ import annotations

import difflib
import functools
import inspect
import json
import math
import os
import re
import signal
import sys
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer
from typer.core import TyperCommand, TyperGroup

try:  # typer 0.2x carries its own copy of click
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover - an older typer runs on click itself
    from click import exceptions as click_errors  # type: ignore[no-redef]

if TYPE_CHECKING:
    from scenarios.types import MeasurementSet

USAGE_ERROR_STATUS = 2
"""Exit status of a malformed file, an unknown name, a bad option or a request over a limit."""
INTERNAL_ERROR_STATUS = 1
"""Exit status of an unexpected exception (a bug): ``error: internal: ...``."""
INTERRUPTED_STATUS = 130
"""Exit status after Ctrl-C (128 + SIGINT, as shells report it)."""
TERMINATED_STATUS = 128 + signal.SIGTERM
"""Exit status after SIGTERM (143), which is handled as Ctrl-C."""
CLUSTER_FAILED_STATUS = 3
"""Exit status of a run whose dask cluster failed (scheduler lost, no workers)."""
READER_GONE_STATUS = 128 + signal.SIGPIPE
"""Exit status when the reader of stdout went away (141, as shells report a command that
SIGPIPE ended: ``yes | head -1``)."""
TRACEBACK_VARIABLE = "EMITTERBENCH_TRACEBACK"
"""Set to 1 to print the traceback of an internal error before its line."""
MAX_LINE = 2000
"""Longest error line printed, characters; a longer message is cut."""

_FIELD = re.compile(r'(?:[^\s"]|"(?:[^"\\]|\\.)*")+(?: \([^)]*\))?: \S')
"""A message that starts with its field: ``samples[2].toa_s: ``, ``x_m (CSV line 3): ``,
``noise["a b"]: ``."""

Command = TypeVar("Command", bound=Callable[..., Any])


def one_line(text: str) -> str:
    """``text`` on one line: whitespace runs as one space, unprintable characters escaped."""
    text = " ".join(text.split())
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= MAX_LINE else text[:MAX_LINE] + "... (cut)"


def fail(message: str, status: int = USAGE_ERROR_STATUS) -> NoReturn:
    """Print ``error: <message>`` on one line to stderr and exit with ``status`` (2)."""
    typer.echo(f"error: {one_line(message)}", err=True)
    raise typer.Exit(status)


def with_field(message: str, field: str) -> str:
    """``message`` if it starts with a field, else ``field: message``."""
    return message if _FIELD.match(message) else f"{field}: {message}"


def unknown_name(name: str, known: Iterable[str], kind: str) -> str:
    """``unknown name 'paper1m'; did you mean paper-1m? known scenarios: ...``."""
    known = list(known)
    close = difflib.get_close_matches(name[:100], known, n=3, cutoff=0.6)
    hint = f"did you mean {' or '.join(close)}? " if close else ""
    return f"unknown name {name[:100]!r}; {hint}known {kind}: {', '.join(known)}"


@contextmanager
def flags_for(flags: Mapping[str, str]) -> Iterator[None]:
    """Re-raise a ``ValueError`` of the block naming the flags the user typed.

    ``flags`` maps a library parameter to its flag (``{"out_dir": "--output"}``): a message
    whose field is the parameter gets the flag as its field, and ``resume=True`` (how the
    Python API asks for a boolean) reads ``--resume``.
    """
    try:
        yield
    except ValueError as error:
        message = str(error)
        field, separator, rest = message.partition(": ")
        if separator and field in flags:
            message = f"{flags[field]}: {rest}"
        for parameter, flag in flags.items():
            message = message.replace(f"{parameter}=True", flag)
        raise ValueError(message) from None


@contextmanager
def blame(field: str, what: str) -> Iterator[None]:
    """Re-raise a ``ValueError`` of the block as ``field: what (message)``.

    For a step whose errors are not the user's fields, e.g. an estimator that rejects the
    data it was given: the user learns which choice to change.
    """
    try:
        yield
    except ValueError as error:
        raise ValueError(f"{field}: {what} ({error})") from None


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's ``KeyboardInterrupt`` would be, so that the same
    cleanup runs; its exit status is :data:`TERMINATED_STATUS`."""


def interrupted_status(interrupt: BaseException) -> tuple[int, str]:
    """The exit status and the line's first words after ``interrupt`` (Ctrl-C or SIGTERM)."""
    if isinstance(interrupt, Terminated):
        return TERMINATED_STATUS, "terminated (SIGTERM)"
    return INTERRUPTED_STATUS, "interrupted"


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (once; a second
    SIGTERM during the cleanup is ignored). Outside the main thread, nothing changes."""

    def terminate(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated

    try:
        previous = signal.signal(signal.SIGTERM, terminate)
    except ValueError:  # not the main thread: signals cannot be handled here
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def clean_errors(
    function: Command, *, field: str, interrupted: Callable[[dict[str, Any]], str] | None = None
) -> Command:
    """``function`` with :func:`fail` for a ``ValueError`` and exit 130 on Ctrl-C (143 on
    SIGTERM).

    A message without a field gets ``field``; ``interrupted(kwargs)`` says what to do after
    Ctrl-C or SIGTERM. Numpy's warnings are silenced (an input they come from fails cleanly or is a
    failed estimate); any other warning is printed as one line.
    """

    @functools.wraps(function)
    def run(*args: Any, **kwargs: Any) -> Any:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            warnings.showwarning = _show_warning
            try:
                return function(*args, **kwargs)
            except ValueError as error:
                fail(with_field(str(error), field))
            except KeyboardInterrupt as interrupt:
                status, what = interrupted_status(interrupt)
                hint = interrupted(kwargs) if interrupted else "stopped before the end"
                fail(f"{what}: {hint}", status)

    return run  # type: ignore[return-value]


def _show_warning(message: Any, category: Any, *args: Any, **kwargs: Any) -> None:
    typer.echo(f"warning: {one_line(str(message))}", err=True)


@contextmanager
def usage_errors_of(ctx: Any) -> Iterator[None]:
    """Give ``ctx`` to a usage error of the block that has none (click's parser raises
    ``--at: requires 2 arguments`` without one), so that its line points at that command."""
    try:
        yield
    except click_errors.UsageError as error:
        if error.ctx is None:
            error.ctx = ctx
        raise


class Subcommand(TyperCommand):
    """A sub-command: usage errors point at its own help, flags show no value type.

    ``late_help`` (set on a subclass, see :func:`comparison.cli.command`) maps a parameter to
    a function that writes its help when the help is shown.
    """

    late_help: Mapping[str, Callable[[], str]] = {}

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        with usage_errors_of(ctx):
            return super().parse_args(ctx, args)

    def format_help(self, ctx: Any, formatter: Any) -> None:
        plain_flags(self.get_params(ctx))
        for parameter in self.get_params(ctx):
            if parameter.name in self.late_help:
                parameter.help = self.late_help[parameter.name]()
        super().format_help(ctx, formatter)


def plain_flags(parameters: Iterable[Any]) -> None:
    """Show a flag (``--resume``, ``--help``) without a value type: typer >= 0.2x writes
    ``<bool>`` beside it, as if it took a value."""
    for parameter in parameters:
        if getattr(parameter, "is_flag", False) and parameter.metavar is None:
            parameter.metavar = ""


class ReaderGone(Exception):
    """The reader of stdout went away (a broken pipe) while a command printed."""


class OneLineErrors(TyperGroup):
    """The command group: usage errors and unexpected exceptions as one line each."""

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except BrokenPipeError:  # before click's own handling, which exits 1
            raise ReaderGone from None

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        with usage_errors_of(ctx):
            return super().parse_args(ctx, args)

    def format_help(self, ctx: Any, formatter: Any) -> None:
        plain_flags(self.get_params(ctx))
        super().format_help(ctx, formatter)

    def main(  # type: ignore[override]
        self,
        args: Any = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        parent = super()

        def invoke() -> Any:
            return parent.main(args, prog_name, complete_var, standalone_mode=False, **extra)

        with sigterm_as_interrupt():
            status = run_guarded(invoke)
        if standalone_mode:
            sys.exit(status)
        return status


def run_guarded(invoke: Callable[[], Any]) -> int:
    """Call ``invoke`` (click's ``main`` with ``standalone_mode=False``); its exit status.

    Nothing escapes: a usage error, Ctrl-C outside a command and any exception become one
    line on stderr.
    """
    try:
        status = invoke()
    except ReaderGone:
        # what is still buffered for stdout goes nowhere, rather than failing again at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return READER_GONE_STATUS
    except click_errors.NoArgsIsHelpError as error:
        # the error made the help: rich printed it then (its message is empty), click's plain
        # formatter made it the message, which click prints on stderr
        if error.message:
            typer.echo(error.message, err=True)
        return USAGE_ERROR_STATUS
    except click_errors.UsageError as error:
        typer.echo(f"error: {one_line(usage_message(error))}", err=True)
        return USAGE_ERROR_STATUS
    except click_errors.ClickException as error:
        typer.echo(f"error: {one_line(with_field(error.format_message(), 'input'))}", err=True)
        return USAGE_ERROR_STATUS
    except (KeyboardInterrupt, typer.Abort) as interrupt:
        status, what = interrupted_status(interrupt)
        typer.echo(f"error: {what}: stopped before the end", err=True)
        return status
    except Exception as error:
        if os.environ.get(TRACEBACK_VARIABLE) == "1":
            traceback.print_exc()
        text = one_line(f"{type(error).__name__}: {error}")
        typer.echo(
            f"error: internal: {text} (please report it with the command that caused it; "
            f"{TRACEBACK_VARIABLE}=1 prints where it happened)",
            err=True,
        )
        return INTERNAL_ERROR_STATUS
    return status if isinstance(status, int) and not isinstance(status, bool) else 0


def usage_message(error: Any) -> str:
    """``<field>: <what is wrong> (see `emitterbench CMD --help`)`` for a click usage error."""
    command = error.ctx.command_path if error.ctx else "emitterbench"
    text = error.message.rstrip(".")
    if isinstance(error, click_errors.MissingParameter) and error.param is not None:
        field, text = _parameter_name(error.param), "missing; it is required"
    elif isinstance(error, click_errors.BadParameter) and error.param is not None:
        field = _parameter_name(error.param)
    elif isinstance(error, click_errors.NoSuchOption):
        field, text = error.option_name, "no such option"
        if error.possibilities:
            text += f"; did you mean {' or '.join(sorted(error.possibilities))}?"
    elif isinstance(error, click_errors.BadOptionUsage):
        field = error.option_name
        text = text.removeprefix(f"Option {field!r} ")
    elif text.startswith("No such command"):
        field = "command"
    else:
        field = "arguments"
    if text[:1].isupper() and text[1:2].islower():  # click's "Got ...", pydantic's "Input ..."
        text = text[0].lower() + text[1:]
    return f"{field}: {text} (see `{command} --help`)"


def _parameter_name(parameter: Any) -> str:
    """``--workers`` for an option (its longest name), ``file`` for an argument."""
    names = [name for name in getattr(parameter, "opts", ()) if name.startswith("-")]
    return max(names, key=len) if names else parameter.name or "argument"


# --------------------------------------------------------------------------------------------
# options and output
# --------------------------------------------------------------------------------------------


def parse_estimator_options(pairs: list[str], flag: str = "--option") -> dict[str, Any]:
    """``key=value`` strings to keyword arguments; values are JSON where they parse.

    ``side_prior_m=[30,10]`` gives the tuple ``(30, 10)`` (JSON arrays become tuples, so the
    frozen estimator stays hashable), ``frames=last`` the string ``"last"``. Errors name
    ``flag``, the option the pairs were given with.
    """

    def frozen(value: Any) -> Any:
        return tuple(frozen(item) for item in value) if isinstance(value, list) else value

    from scenarios.limits import TOO_DEEP, check_nesting, clip

    options: dict[str, Any] = {}
    for pair in pairs:
        key, separator, text = pair.partition("=")
        key = key.strip()
        if not separator or not key.isidentifier():
            raise ValueError(f"{flag}: expected key=value, got {clip(pair)!r}")
        if key in options:
            raise ValueError(f"{flag}: {key!r} given twice; keep one")
        try:
            value = json.loads(text, parse_int=_option_integer)
            check_nesting(value)
        except json.JSONDecodeError:
            options[key] = text  # not JSON: the text itself, e.g. frames=last
            continue
        except RecursionError:
            raise ValueError(f"{flag}: {key}: {TOO_DEEP}") from None
        except ValueError as error:  # too deep, or an integer too long
            problem = str(error).partition(": ")[2] or str(error)
            raise ValueError(f"{flag}: {key}: {problem}") from None
        options[key] = frozen(value)
    return options


def _option_integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:  # beyond sys.get_int_max_str_digits()
        raise ValueError(f"value: an integer of {len(text)} digits; write a smaller one") from None


def json_ready(value: Any) -> Any:
    """Nested dicts, sequences and numpy values as plain JSON; non-finite floats as null."""
    import numpy as np

    if isinstance(value, dict):
        return {str(key): json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [json_ready(item) for item in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, bool | int | str):
        return value
    return str(value)


def print_json(obj: Any) -> None:
    """Print one JSON object on stdout (strict: NaN was already turned into null)."""
    typer.echo(json.dumps(json_ready(obj), allow_nan=False))


# --------------------------------------------------------------------------------------------
# the constants of a CSV file, as options
# --------------------------------------------------------------------------------------------

_CSV_PANEL = "CSV constants (a JSON file carries its own)"

CSV_OPTIONS: dict[str, tuple[str, str]] = {
    "carrier_hz": ("--carrier-hz", "Carrier frequency f0, Hz."),
    "speed_of_light_mps": ("--speed-of-light-mps", "Propagation speed c, m/s (default 299792458)."),
    "emitter_height_m": ("--emitter-height-m", "Known emitter height z_s, m (default 0)."),
    "noise.doppler_hz": ("--sigma-doppler-hz", "Doppler noise σ, Hz."),
    "noise.toa_s": ("--sigma-toa-s", "ToA noise σ, s."),
    "noise.rss_db": ("--sigma-rss-db", "RSS noise σ, dB."),
    "rss_model.reference_power_dbm": ("--rss-reference-power-dbm", "RSS model P0, dBm."),
    "rss_model.reference_distance_m": ("--rss-reference-distance-m", "RSS model d0, m."),
    "rss_model.path_loss_exponent": ("--rss-path-loss-exponent", "RSS model η."),
}
"""The options that give a CSV file its constants: field of the file (JSON path) → option, help."""

CsvConstants = dict[str, float | None]
"""The CSV options a command was given: field of the file → value (None: not given)."""

_CSV_PARAMETERS = {
    field: inspect.Parameter(
        option.lstrip("-").replace("-", "_"),
        inspect.Parameter.KEYWORD_ONLY,
        default=None,
        annotation=Annotated[
            float | None, typer.Option(option, help=text, rich_help_panel=_CSV_PANEL)
        ],
    )
    for field, (option, text) in CSV_OPTIONS.items()
}
_OPTION_OF_FIELD = {field: option for field, (option, _) in CSV_OPTIONS.items()}
_OPTION_OF_FIELD["rss_model"] = "/".join(
    option for field, option in _OPTION_OF_FIELD.items() if field.startswith("rss_model.")
)


def with_csv_options(function: Command) -> Command:
    """Give a command the options of :data:`CSV_OPTIONS`, after its own.

    ``function`` ends with the keyword-only parameter ``constants: CsvConstants``; typer sees the
    nine options in its place, and ``function`` receives their values in that one mapping.
    """
    signature = inspect.signature(function, eval_str=True)
    parameters = [p for p in signature.parameters.values() if p.name != "constants"]
    parameters += _CSV_PARAMETERS.values()

    @functools.wraps(function)
    def run(*args: Any, **kwargs: Any) -> Any:
        constants = {field: kwargs.pop(p.name) for field, p in _CSV_PARAMETERS.items()}
        return function(*args, constants=constants, **kwargs)

    run.__signature__ = signature.replace(parameters=parameters)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in parameters}
    return run  # type: ignore[return-value]


def known_scenario(name: str) -> str:
    """The ``scenario`` argument, checked as click reads it: before the options that follow
    it, so that a misspelt name is the first thing said (with the close names)."""
    from scenarios.catalog import CATALOG

    if name not in CATALOG:
        raise typer.BadParameter(unknown_name(name, CATALOG, "scenarios"))
    return name


RECORDING_SUFFIX = ".sigmf-meta"
"""A file named so is a SigMF recording of bursts (:mod:`scenarios.recording`)."""

DopplerSearchOption = Annotated[
    float | None,
    typer.Option(
        "--doppler-search-hz",
        metavar="HZ",
        help="A recording's BPSK bursts: search their first delay pass over the Doppler "
        "within ±HZ (MATH §20; 0: no search) \\[γ·max|v| of the track when the carrier offset "
        "is known; required when the recording declares it unknown: its bound plus γ·max|v|, "
        "e.g. 1200 for beacon-pass's 1 kHz].",
    ),
]
"""The ``--doppler-search-hz`` of the commands that measure a recording."""


def load_measurements(
    file: Path, constants: CsvConstants, doppler_search_hz: float | None = None
) -> MeasurementSet:
    """Read a measurement file; a CSV one with the constants of the CSV options; a recording
    (``.sigmf-meta``) measured by the front end with the Doppler search ``doppler_search_hz``
    (:data:`DopplerSearchOption`), which says on stderr how many bursts it flagged below
    threshold (:func:`measured_recording`).

    Errors about a CSV constant name the command-line option to fix (``--sigma-toa-s``).
    """
    from scenarios.files import read_measurements_with

    if not file.name.lower().endswith(RECORDING_SUFFIX) and doppler_search_hz is not None:
        raise ValueError(
            f"--doppler-search-hz: only for a recording (.sigmf-meta); {file} holds "
            "measurements already (drop the option)"
        )
    if file.name.lower().endswith(RECORDING_SUFFIX):
        given = [field for field, value in constants.items() if value is not None]
        if given:
            raise ValueError(
                f"{_OPTION_OF_FIELD[given[0]]}: only for CSV files; {file} carries its own "
                "constants (drop the option)"
            )
        data, line = measured_recording(file, doppler_search_hz)
        typer.echo(line, err=True)
        return data
    return read_measurements_with(file, constants, names=_OPTION_OF_FIELD)


def estimate_of(
    estimator: Any,
    name: str,
    file: Path,
    constants: CsvConstants,
    doppler_search_hz: float | None = None,
    ignore_unknowns: bool = False,
) -> tuple[Any, MeasurementSet]:
    """What ``emitterbench estimate`` computes: ``estimator``'s (given as ``name``) from ``file`` (ties
    drawn from a generator seeded with 0, its prints sent to stderr) and the data it read. An
    estimator of measurements reads them (:func:`load_measurements`; with ``ignore_unknowns``
    the file's unknowns taken as known, MATH §15); one of the received samples reads the
    recording's (:func:`estimate_from_samples`)."""
    import numpy as np

    from comparison.estimator_calls import kept_process
    from estimators.base import capabilities_of, unknowns_problem
    from estimators.registry import reads_samples

    if reads_samples(estimator):  # from the recording's samples (MATH §22)
        with kept_process():
            return estimate_from_samples(file, estimator)
    data = load_measurements(file, constants, doppler_search_hz)
    if ignore_unknowns:
        data = data.assuming_known()
    used = capabilities_of(estimator).modalities & data.modalities
    problem = unknowns_problem(estimator, data.unknowns, used, ignore_hint="--ignore-unknowns")
    if problem is not None:
        raise ValueError(problem)
    with (
        blame("--estimator", f"{name} cannot estimate from {file}; try another estimator"),
        kept_process(),  # the estimator's prints go to stderr: stdout carries only the result
    ):
        return estimator.estimate(data.without_truth(), rng=np.random.default_rng(0)), data


def estimate_from_samples(file: Path, estimator: Any) -> tuple[Any, MeasurementSet]:
    """The estimate of an estimator of the received samples (``dpd``, docs/math.md §22) from
    the recording ``file``, read a block of bursts at a time, its ties drawn from a generator
    seeded with 0; and the recording's geometry (with its truth, when it holds one). A file
    that is not a recording is one line naming ``--estimator``."""
    import numpy as np

    from scenarios.recording import open_recording

    if not file.name.lower().endswith(RECORDING_SUFFIX):
        raise ValueError(
            f"--estimator: {estimator.name} locates from the received samples, which {file} "
            "does not hold; give it a recording (.sigmf-meta, emitterbench simulate-iq)"
        )
    recording = open_recording(file)
    samples = np.concatenate([block for _, block in recording.bursts()])
    geometry = recording.geometry
    estimate = estimator.estimate_iq(
        geometry.without_truth(),
        recording.plan,
        samples,
        recording.emission_time_s,
        rng=np.random.default_rng(0),
    )
    return estimate, geometry


def measured_recording(
    file: Path, doppler_search_hz: float | None = None
) -> tuple[MeasurementSet, str]:
    """The measurements of the recording ``file`` by the front end, read from disk a block of
    bursts at a time (:func:`estimators.frontend.recording.measure_recording`, the Doppler
    search ``doppler_search_hz``, None: the track's), and a line saying what was measured, how
    many bursts were flagged below threshold and the Doppler searched (BPSK: its cells; a
    tone: its frequency's band)."""
    import numpy as np

    from estimators.frontend import track_doppler_search_hz
    from estimators.frontend.measure import doppler_cells_hz
    from estimators.frontend.recording import measure_recording
    from scenarios.recording import open_recording

    recording = open_recording(file)
    with flags_for({"doppler_search_hz": "--doppler-search-hz"}):
        data, measured = measure_recording(recording, doppler_search_hz=doppler_search_hz)
    flagged = int(np.count_nonzero(measured.below_threshold))
    line = (
        f"measured {file}: {recording.n_bursts} {recording.plan.waveform} bursts, {flagged} of "
        f"{recording.n_bursts} flagged below threshold (median burst SNR "
        f"{10 * np.log10(np.median(measured.burst_snr)):.1f} dB)"
    )
    search_hz = doppler_search_hz
    if search_hz is None:
        search_hz = track_doppler_search_hz(recording.geometry)
    if recording.plan.waveform == "bpsk":
        cells = doppler_cells_hz(search_hz, recording.plan).size
        line += f"; Doppler searched within ±{search_hz:.4g} Hz ({cells} cell{'s' * (cells > 1)})"
    elif search_hz:
        line += f"; frequency searched within ±{search_hz:.4g} Hz"
    return data, line
