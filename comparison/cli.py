"""The ``emitterbench`` command line: ``simulate``, ``estimate``, ``crlb``, ``fly``, ``list``, ``run``, ``report``.

Adding a command is one function registered with ``@command("name")``: its parameters are
typed ``Annotated`` typer options, it imports the heavy modules it needs inside its body (so
that ``emitterbench --help`` stays quick), and any ``ValueError`` it raises (the library's
errors name the field and the fix) becomes the one line ``error: <message>`` on stderr with
exit status 2, without a traceback. Measurement files are read with :func:`load_measurements`,
which takes the CSV constants of the ``*Option`` aliases below.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer

if TYPE_CHECKING:
    from estimators.base import Estimate
    from scenarios.types import MeasurementSet

USAGE_ERROR_STATUS = 2
"""Exit status of a malformed file, an unknown name or a bad option."""

app = typer.Typer(
    name="emitterbench",
    help=(
        "Locate a radio emitter from one UAV's Doppler and time-of-arrival measurements, "
        "and compare estimators against the Cramér-Rao bound."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)


@app.callback()
def emitterbench() -> None:
    """Locate a radio emitter from one UAV's Doppler and ToA measurements (see docs/math.md)."""


# --------------------------------------------------------------------------------------------
# shared helpers: clean errors, measurement files, output
# --------------------------------------------------------------------------------------------

Command = TypeVar("Command", bound=Callable[..., Any])


def fail(message: str) -> NoReturn:
    """Print ``error: <message>`` on one line to stderr and exit with status 2."""
    typer.echo(f"error: {' '.join(message.split())}", err=True)
    raise typer.Exit(USAGE_ERROR_STATUS)


def exit_on_value_error(function: Command) -> Command:
    """Turn a ``ValueError`` escaping ``function`` into :func:`fail` (no traceback)."""

    @functools.wraps(function)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return function(*args, **kwargs)
        except ValueError as error:
            fail(str(error))

    return run  # type: ignore[return-value]


def command(name: str, **typer_options: Any) -> Callable[[Command], Command]:
    """Register ``function`` as the sub-command ``name`` of :data:`app`, with clean errors."""

    def register(function: Command) -> Command:
        app.command(name, **typer_options)(exit_on_value_error(function))
        return function

    return register


_CSV_PANEL = "CSV constants (a JSON file carries its own)"

CarrierOption = Annotated[
    float | None,
    typer.Option("--carrier-hz", help="Carrier frequency f0, Hz.", rich_help_panel=_CSV_PANEL),
]
SpeedOfLightOption = Annotated[
    float | None,
    typer.Option(
        "--speed-of-light-mps",
        help="Propagation speed c, m/s (default 299792458).",
        rich_help_panel=_CSV_PANEL,
    ),
]
EmitterHeightOption = Annotated[
    float | None,
    typer.Option(
        "--emitter-height-m",
        help="Known emitter height z_s, m (default 0).",
        rich_help_panel=_CSV_PANEL,
    ),
]
SigmaDopplerOption = Annotated[
    float | None,
    typer.Option("--sigma-doppler-hz", help="Doppler noise σ, Hz.", rich_help_panel=_CSV_PANEL),
]
SigmaToaOption = Annotated[
    float | None,
    typer.Option("--sigma-toa-s", help="ToA noise σ, s.", rich_help_panel=_CSV_PANEL),
]
SigmaRssOption = Annotated[
    float | None,
    typer.Option("--sigma-rss-db", help="RSS noise σ, dB.", rich_help_panel=_CSV_PANEL),
]
RssPowerOption = Annotated[
    float | None,
    typer.Option(
        "--rss-reference-power-dbm", help="RSS model P0, dBm.", rich_help_panel=_CSV_PANEL
    ),
]
RssDistanceOption = Annotated[
    float | None,
    typer.Option("--rss-reference-distance-m", help="RSS model d0, m.", rich_help_panel=_CSV_PANEL),
]
RssExponentOption = Annotated[
    float | None,
    typer.Option("--rss-path-loss-exponent", help="RSS model η.", rich_help_panel=_CSV_PANEL),
]
JsonFlag = Annotated[
    bool, typer.Option("--json", help="Print exactly one JSON object instead of a summary.")
]
MeasurementFile = Annotated[
    Path, typer.Argument(help="Measurement file, .json or .csv (CSV needs the constants).")
]

_OPTION_OF_FIELD = {
    "carrier_hz": "--carrier-hz",
    "speed_of_light_mps": "--speed-of-light-mps",
    "emitter_height_m": "--emitter-height-m",
    "noise.doppler_hz": "--sigma-doppler-hz",
    "noise.toa_s": "--sigma-toa-s",
    "noise.rss_db": "--sigma-rss-db",
    "rss_model.reference_power_dbm": "--rss-reference-power-dbm",
    "rss_model.reference_distance_m": "--rss-reference-distance-m",
    "rss_model.path_loss_exponent": "--rss-path-loss-exponent",
    "rss_model": "--rss-reference-power-dbm/--rss-reference-distance-m/--rss-path-loss-exponent",
}


def load_measurements(
    file: Path,
    *,
    carrier_hz: float | None = None,
    speed_of_light_mps: float | None = None,
    emitter_height_m: float | None = None,
    sigma_doppler_hz: float | None = None,
    sigma_toa_s: float | None = None,
    sigma_rss_db: float | None = None,
    rss_reference_power_dbm: float | None = None,
    rss_reference_distance_m: float | None = None,
    rss_path_loss_exponent: float | None = None,
) -> MeasurementSet:
    """Read a measurement file; for CSV, build the constants from the CLI options.

    Errors about a CSV constant name the command-line option to fix (``--sigma-toa-s``).
    """
    from scenarios.files import read_measurements
    from scenarios.types import NoiseSigmas, RssModel

    options = {
        "carrier_hz": carrier_hz,
        "speed_of_light_mps": speed_of_light_mps,
        "emitter_height_m": emitter_height_m,
        "noise.doppler_hz": sigma_doppler_hz,
        "noise.toa_s": sigma_toa_s,
        "noise.rss_db": sigma_rss_db,
        "rss_model.reference_power_dbm": rss_reference_power_dbm,
        "rss_model.reference_distance_m": rss_reference_distance_m,
        "rss_model.path_loss_exponent": rss_path_loss_exponent,
    }
    given = [field for field, value in options.items() if value is not None]
    if file.suffix.lower() != ".csv":
        if given:
            raise ValueError(
                f"{_OPTION_OF_FIELD[given[0]]}: only for CSV files; {file} carries its own "
                "constants (drop the option or edit the file)"
            )
        return read_measurements(file)
    if carrier_hz is None:
        raise ValueError(f"--carrier-hz: required to read the CSV file {file}")
    rss_fields = [field for field in options if field.startswith("rss_model.")]
    rss_given = [field for field in rss_fields if options[field] is not None]
    if rss_given and len(rss_given) < len(rss_fields):
        missing = next(field for field in rss_fields if options[field] is None)
        raise ValueError(f"{_OPTION_OF_FIELD[missing]}: give all three RSS-model options")
    try:
        return read_measurements(
            file,
            carrier_hz=carrier_hz,
            speed_of_light_mps=speed_of_light_mps,
            emitter_height_m=emitter_height_m,
            noise=NoiseSigmas(doppler_hz=sigma_doppler_hz, toa_s=sigma_toa_s, rss_db=sigma_rss_db),
            rss_model=None
            if not rss_given
            else RssModel(
                reference_power_dbm=rss_reference_power_dbm,
                reference_distance_m=rss_reference_distance_m,
                path_loss_exponent=rss_path_loss_exponent,
            ),
        )
    except ValueError as error:
        field, separator, rest = str(error).partition(": ")
        if separator and field in _OPTION_OF_FIELD:
            raise ValueError(f"{_OPTION_OF_FIELD[field]}: {rest}") from None
        raise


def parse_estimator_options(pairs: list[str]) -> dict[str, Any]:
    """``key=value`` strings to keyword arguments; values are JSON where they parse.

    ``side_prior_m=[30,10]`` gives the tuple ``(30, 10)`` (JSON arrays become tuples, so the
    frozen estimator stays hashable), ``frames=last`` the string ``"last"``.
    """

    def frozen(value: Any) -> Any:
        return tuple(frozen(item) for item in value) if isinstance(value, list) else value

    options: dict[str, Any] = {}
    for pair in pairs:
        key, separator, text = pair.partition("=")
        key = key.strip()
        if not separator or not key.isidentifier():
            raise ValueError(f"--option: expected key=value, got {pair!r}")
        if key in options:
            raise ValueError(f"--option: {key!r} given twice; keep one")
        try:
            options[key] = frozen(json.loads(text))
        except json.JSONDecodeError:
            options[key] = text
    return options


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


def _console() -> Any:
    from rich.console import Console

    return Console(highlight=False, soft_wrap=True)


def _point_text(point: Any) -> str:
    return "(" + ", ".join("nan" if not math.isfinite(v) else f"{v:.4f}" for v in point) + ")"


# --------------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------------


@command("simulate")
def simulate_command(
    scenario: Annotated[str, typer.Argument(help="Scenario name (see `emitterbench list`).")],
    seed: Annotated[int, typer.Option("--seed", help="Seed of the noise draw.")],
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Measurement file to write (.json).")
    ],
    snr_db: Annotated[
        float, typer.Option("--snr-db", help="SNR: every σ times 10^(−snr_db/20) (MATH §2).")
    ] = 0.0,
    frames: Annotated[
        int | None, typer.Option("--frames", help="Number of frames (extends the last).")
    ] = None,
) -> None:
    """Simulate one noisy trial of a named scenario and write it, truth included."""
    from scenarios.catalog import get_scenario
    from scenarios.files import write_measurements
    from scenarios.simulate import simulate

    if output.suffix.lower() != ".json":
        raise ValueError(f"--output: {output} must end in .json")
    chosen = get_scenario(scenario, frames=frames)
    data = simulate(chosen, snr_db=snr_db, seed=seed)
    write_measurements(data, output)
    typer.echo(
        f"wrote {output}: {chosen.name}, {data.n_samples} samples in {len(data.frames)} "
        f"frame(s), SNR {snr_db:g} dB, seed {seed}"
    )


def estimate_to_dict(estimate: Estimate, truth_emitter_m: Any | None) -> dict[str, Any]:
    """``Estimate.to_dict()`` plus ``error_m`` and ``error_side_resolved_m`` given a truth.

    ``error_side_resolved_m`` is the distance from the truth to the nearest candidate: the
    error with the mirror side resolved (MATH §7).
    """
    import numpy as np

    result = estimate.to_dict()
    if truth_emitter_m is not None:
        truth = np.asarray(truth_emitter_m, dtype=float)
        error = float(np.linalg.norm(estimate.position_m - truth))
        candidates = estimate.candidates_m
        result["error_m"] = error if math.isfinite(error) else None
        result["error_side_resolved_m"] = (
            float(np.min(np.linalg.norm(candidates - truth, axis=1))) if len(candidates) else None
        )
    return result


@command("estimate")
def estimate_command(
    file: MeasurementFile,
    estimator: Annotated[
        str,
        typer.Option(
            "--estimator", "-e", help="Estimator name (see `emitterbench list`) or module:Class."
        ),
    ] = "cls",
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            help="Estimator option key=value, repeatable; JSON values, e.g. side_prior_m=[30,10].",
        ),
    ] = None,
    as_json: JsonFlag = False,
    carrier_hz: CarrierOption = None,
    speed_of_light_mps: SpeedOfLightOption = None,
    emitter_height_m: EmitterHeightOption = None,
    sigma_doppler_hz: SigmaDopplerOption = None,
    sigma_toa_s: SigmaToaOption = None,
    sigma_rss_db: SigmaRssOption = None,
    rss_reference_power_dbm: RssPowerOption = None,
    rss_reference_distance_m: RssDistanceOption = None,
    rss_path_loss_exponent: RssExponentOption = None,
) -> None:
    """Locate the emitter from a measurement file with one estimator (rng seeded with 0)."""
    import numpy as np

    from estimators.registry import make_estimator

    options = parse_estimator_options(option or [])
    chosen = make_estimator(estimator, **options)
    data = load_measurements(
        file,
        carrier_hz=carrier_hz,
        speed_of_light_mps=speed_of_light_mps,
        emitter_height_m=emitter_height_m,
        sigma_doppler_hz=sigma_doppler_hz,
        sigma_toa_s=sigma_toa_s,
        sigma_rss_db=sigma_rss_db,
        rss_reference_power_dbm=rss_reference_power_dbm,
        rss_reference_distance_m=rss_reference_distance_m,
        rss_path_loss_exponent=rss_path_loss_exponent,
    )
    estimate = chosen.estimate(data.without_truth(), rng=np.random.default_rng(0))
    result = estimate_to_dict(estimate, data.truth_emitter_m)
    if as_json:
        print_json(result)
        return
    _print_estimate(result, file, data)


def _print_estimate(result: dict[str, Any], file: Path, data: MeasurementSet) -> None:
    from rich.table import Table

    def point(value: list[float | None] | None) -> str:
        return "-" if value is None else _point_text([math.nan if v is None else v for v in value])

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    table.add_row("estimator", result["estimator"])
    table.add_row(
        "data",
        f"{file}: {data.n_samples} samples, {len(data.frames)} frame(s), "
        f"{', '.join(sorted(data.modalities))}",
    )
    table.add_row("success", "yes" if result["success"] else "NO")
    table.add_row("position_m", point(result["position_m"]))
    table.add_row("candidates_m", "  ".join(point(c) for c in result["candidates_m"]) or "-")
    if result["ambiguous"]:
        table.add_row("ambiguous", "yes: the data cannot tell these candidates apart (MATH §7)")
    if result["covariance_m2"] is not None:
        table.add_row("covariance_m2", str(result["covariance_m2"]))
    if "error_m" in result:
        table.add_row(
            "error_m",
            f"{_number_text(result['error_m'])} (side resolved: "
            f"{_number_text(result['error_side_resolved_m'])})",
        )
    if result["message"]:
        table.add_row("message", result["message"])
    for key, value in result["diagnostics"].items():
        table.add_row(f"  {key}", str(value))
    _console().print(table)


def _number_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def crlb_table(data: MeasurementSet, at_m: Any) -> dict[str, Any]:
    """RMSE bound and CRLB matrix at ``at_m`` for each of ``MODALITY_SETS`` (MATH §8).

    A set whose σ (or RSS model) is missing, or whose information is singular, is ``None``
    with a note saying why.
    """
    import numpy as np

    from comparison.crlb import MODALITY_SETS, crlb_m2, fisher_information, rmse_bound_m

    table: dict[str, Any] = {
        "at_m": [float(v) for v in at_m],
        "n_samples": data.n_samples,
        "rmse_bound_m": {},
        "crlb_m2": {},
        "notes": {},
    }
    for name, modalities in MODALITY_SETS.items():
        try:
            with np.errstate(divide="ignore", invalid="ignore"):
                information = fisher_information(data, at_m, modalities)
        except ValueError as error:
            table["rmse_bound_m"][name] = table["crlb_m2"][name] = None
            table["notes"][name] = str(error)
            continue
        bound = float(rmse_bound_m(information))
        if not math.isfinite(bound):
            table["rmse_bound_m"][name] = table["crlb_m2"][name] = None
            table["notes"][name] = "singular Fisher information: unobservable from these samples"
            continue
        table["rmse_bound_m"][name] = bound
        table["crlb_m2"][name] = crlb_m2(information).tolist()
    return table


@command("crlb")
def crlb_command(
    file: MeasurementFile,
    at: Annotated[
        tuple[float, float] | None,
        typer.Option("--at", help="Emitter position X Y, m (default: the truth in the file)."),
    ] = None,
    as_json: JsonFlag = False,
    carrier_hz: CarrierOption = None,
    speed_of_light_mps: SpeedOfLightOption = None,
    emitter_height_m: EmitterHeightOption = None,
    sigma_doppler_hz: SigmaDopplerOption = None,
    sigma_toa_s: SigmaToaOption = None,
    sigma_rss_db: SigmaRssOption = None,
    rss_reference_power_dbm: RssPowerOption = None,
    rss_reference_distance_m: RssDistanceOption = None,
    rss_path_loss_exponent: RssExponentOption = None,
) -> None:
    """Cramér-Rao bound for (x_s, y_s) per modality set: toa, doppler, rss, toa+doppler.

    Needs only the geometry and the σ's of the file, not the measured values (MATH §8).
    """
    data = load_measurements(
        file,
        carrier_hz=carrier_hz,
        speed_of_light_mps=speed_of_light_mps,
        emitter_height_m=emitter_height_m,
        sigma_doppler_hz=sigma_doppler_hz,
        sigma_toa_s=sigma_toa_s,
        sigma_rss_db=sigma_rss_db,
        rss_reference_power_dbm=rss_reference_power_dbm,
        rss_reference_distance_m=rss_reference_distance_m,
        rss_path_loss_exponent=rss_path_loss_exponent,
    )
    if at is not None:
        if not all(math.isfinite(v) for v in at):
            raise ValueError(f"--at: expected two finite numbers X Y, got {at}")
        at_m: Any = at
    elif data.truth_emitter_m is not None:
        at_m = data.truth_emitter_m
    else:
        raise ValueError(f"--at: {file} has no truth; give the emitter position as --at X Y")
    table = crlb_table(data, at_m)
    if as_json:
        print_json(table)
        return
    from rich.table import Table

    view = Table(title=f"CRLB at {_point_text(table['at_m'])} m, {data.n_samples} samples")
    for heading in ("modalities", "√trace CRLB (m)", "CRLB (m²)", "note"):
        view.add_column(heading)
    for name in table["rmse_bound_m"]:
        bound, matrix = table["rmse_bound_m"][name], table["crlb_m2"][name]
        view.add_row(
            name,
            _number_text(bound),
            "-" if matrix is None else "; ".join(" ".join(f"{v:.3g}" for v in r) for r in matrix),
            table["notes"].get(name, ""),
        )
    _console().print(view)


@command("fly")
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
        typer.Option(
            "--estimator", "-e", help="Estimator whose estimate steers the planner (default ml)."
        ),
    ] = "ml",
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            help="Planner option key=value, repeatable; JSON values, e.g. radius_m=25.",
        ),
    ] = None,
    estimator_option: Annotated[
        list[str] | None,
        typer.Option(
            "--estimator-option",
            help="Estimator option key=value, repeatable (as `estimate --option`).",
        ),
    ] = None,
    as_json: JsonFlag = False,
    carrier_hz: CarrierOption = None,
    speed_of_light_mps: SpeedOfLightOption = None,
    emitter_height_m: EmitterHeightOption = None,
    sigma_doppler_hz: SigmaDopplerOption = None,
    sigma_toa_s: SigmaToaOption = None,
    sigma_rss_db: SigmaRssOption = None,
    rss_reference_power_dbm: RssPowerOption = None,
    rss_reference_distance_m: RssDistanceOption = None,
    rss_path_loss_exponent: RssExponentOption = None,
) -> None:
    """The next frame's velocity, from the measurements of the frames flown so far.

    The flight is reconstructed from the samples (frames of K samples at one constant velocity,
    one sample interval); the estimator locates the emitter (rng seeded with 0, as `estimate`)
    and the planner turns its estimate into the velocity of the next frame (MATH §12-§13).
    """
    import numpy as np

    from estimators.registry import make_estimator
    from scenarios.planners import get_planner

    chosen_planner = get_planner(planner, **parse_estimator_options(option or []))
    chosen_estimator = make_estimator(estimator, **parse_estimator_options(estimator_option or []))
    data = load_measurements(
        file,
        carrier_hz=carrier_hz,
        speed_of_light_mps=speed_of_light_mps,
        emitter_height_m=emitter_height_m,
        sigma_doppler_hz=sigma_doppler_hz,
        sigma_toa_s=sigma_toa_s,
        sigma_rss_db=sigma_rss_db,
        rss_reference_power_dbm=rss_reference_power_dbm,
        rss_reference_distance_m=rss_reference_distance_m,
        rss_path_loss_exponent=rss_path_loss_exponent,
    )
    plan, estimate, flight = plan_next_velocity(
        data, chosen_planner, chosen_estimator, rng=np.random.default_rng(0)
    )
    result = {
        **plan.to_dict(),
        "flight": {
            "frames": flight.n_frames,
            "samples_per_frame": flight.samples_per_frame,
            "sample_interval_s": flight.sample_interval_s,
            "next_frame_start_m": (
                flight.sample_positions_m()[-1]
                + flight.sample_interval_s * flight.frame_velocities_mps[-1]
            ).tolist(),
        },
        "estimate": estimate_to_dict(estimate, data.truth_emitter_m),
    }
    if as_json:
        print_json(result)
        return
    _print_plan(result, file)


def plan_next_velocity(data: MeasurementSet, planner: Any, estimator: Any, *, rng: Any) -> Any:
    """``(plan, estimate, flight)``: estimate on ``data``, then plan the next frame.

    The flight is :func:`scenarios.planners.flight_from_measurements`; the planner gets the
    estimate's candidates with the returned position first, and its covariance.

    Raises
    ------
    ValueError
        When the estimator fails (the planner needs a position), or from the planner.
    """
    from comparison.closed_loop import steering_candidates_m
    from scenarios.planners import flight_from_measurements

    flight = flight_from_measurements(data)
    estimate = estimator.estimate(data.without_truth(), rng=rng)
    if not estimate.success:
        raise ValueError(
            f"estimator: {estimator.name!r} failed ({estimate.message}); the planner needs a "
            "position: choose another estimator or fly more frames"
        )
    plan = planner.plan(
        flight,
        steering_candidates_m(estimate),
        data.without_truth(),
        covariance_m2=estimate.covariance_m2,
    )
    return plan, estimate, flight


def _print_plan(result: dict[str, Any], file: Path) -> None:
    from rich.table import Table

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    table.add_row("planner", result["planner"])
    flight = result["flight"]
    table.add_row(
        "flight",
        f"{file}: {flight['frames']} frame(s) of {flight['samples_per_frame']} samples, "
        f"Δ = {flight['sample_interval_s']:g} s",
    )
    table.add_row("velocity_mps", _point_text(result["velocity_mps"]))
    table.add_row(
        "speed, heading",
        f"{result['speed_mps']:.4g} m/s, {result['heading_deg']:.4g}° (from east, counter-clockwise)",
    )
    table.add_row("next frame from", _point_text(flight["next_frame_start_m"]))
    table.add_row("message", result["message"] or "-")
    estimate = result["estimate"]
    others = [c for c in estimate["candidates_m"] if c != estimate["position_m"]]
    table.add_row(
        "estimate",
        f"{estimate['estimator']}: {_point_text(estimate['position_m'])}"
        + (f"; mirror {'  '.join(_point_text(c) for c in others)}" if others else "")
        + (" (ambiguous, MATH §7: the planner uses the first)" if estimate["ambiguous"] else ""),
    )
    _console().print(table)


@command("list")
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

    from comparison.experiment import BUILTIN_EXPERIMENTS
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


@command("run")
def run_command(
    experiment: Annotated[
        str, typer.Argument(help="A built-in experiment (see `emitterbench list`) or a .toml file.")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Run folder to write.")],
    trials: Annotated[
        int | None, typer.Option("--trials", min=1, help="Trials per point (overrides the file).")
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", min=1, help="Local worker processes [all cores].")
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Finish an interrupted run in the same folder.")
    ] = False,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            envvar="DASK_SCHEDULER_ADDRESS",
            help="Run on a Dask cluster at tcp://HOST:PORT (extra emitterbench[cluster]).",
        ),
    ] = None,
) -> None:
    """Run a Monte Carlo comparison into a run folder, then write its report.

    Rows are stored as they arrive (results.sqlite): a killed run loses at most the trials in
    flight, and --resume finishes it with exactly the rows of an uninterrupted run.
    """
    from comparison.engine import run_experiment
    from comparison.experiment import load_experiment
    from comparison.report import write_report

    definition = load_experiment(experiment)
    run_dir = run_experiment(
        definition, output, workers=workers, scheduler=scheduler, resume=resume, trials=trials
    )
    html = write_report(run_dir)
    typer.echo(f"report: {html}")
    typer.echo(f"tables: {run_dir / 'summary.csv'}, {run_dir / 'trials.csv'}")


@command("report")
def report_command(
    run_dir: Annotated[Path, typer.Argument(help="A run folder written by `emitterbench run`.")],
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", min=100, help="Bootstrap resamples for intervals.")
    ] = 1000,
) -> None:
    """(Re)write summary.csv, trials.csv, figures/ and report.html of a run folder."""
    from comparison.report import write_report

    if not (run_dir / "results.sqlite").exists():
        raise ValueError(
            f"run_dir: {run_dir} holds no results.sqlite; run `emitterbench run` first"
        )
    typer.echo(f"report: {write_report(run_dir, n_bootstrap=bootstrap)}")


@command("validate")
def validate_command(
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Folder for validate.json and reports.")
    ] = None,
    instances: Annotated[
        int, typer.Option("--instances", min=1, help="Seeded instances per family.")
    ] = 1000,
    families: Annotated[
        list[str] | None,
        typer.Option("--families", help="Instance families (repeat); default: all."),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the instance draws.")] = 0,
    replay_seed: Annotated[
        int | None,
        typer.Option("--replay", help="Re-run one instance verbosely (give one --families)."),
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
        list[str] | None,
        typer.Option(
            "--option",
            help="Estimator option key=value, repeatable (with --estimator); JSON values.",
        ),
    ] = None,
) -> None:
    """Check the closed-form CLS against its SDP relaxation on seeded random instances.

    With --estimator, the estimator runs on each instance's measurements and is judged on the
    rows it exposes (constrained_ls): every candidate must attain the exact optimum, both mirror
    minimisers are due in the hard case, and the SDP value must equal the optimum. Exit status
    1 when any instance disagrees beyond tolerance or its SDP is not optimal (MATH §5, §11).
    """
    from comparison.validate import FAMILIES, check_protocol, replay_with_verdict, run_validation

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
    import sys

    from rich.progress import Progress

    with Progress(disable=not sys.stderr.isatty(), transient=True) as bar:
        task = bar.add_task("validating", total=instances * len(chosen))
        result = run_validation(
            instances=instances,
            families=chosen,
            seed=seed,
            out_dir=output,
            progress=lambda done, total, family: bar.update(
                task, completed=done, total=total, description=family
            ),
            estimator=validated,
        )
    if result.estimator is not None:
        typer.echo(f"estimator {result.estimator}: its own rows (constrained_ls) on each instance")
    for name, summary in result.families.items():
        if result.estimator is None:
            typer.echo(
                f"{name:<14} n={summary.n:<5} hard={summary.n_hard:<5} "
                f"max rel. gap {summary.max_rel_objective_gap:.1e}  "
                f"max argmin dist. {summary.max_argmin_distance_rel:.1e}  "
                f"max pair dist. {summary.max_candidate_pair_distance_rel:.1e} "
                "(of the length scale)  "
                f"disagreements {summary.n_disagreements}"
            )
        else:
            typer.echo(
                f"{name:<14} n={summary.n:<5} hard={summary.n_hard:<5} "
                f"max rel. cost gap {summary.max_estimator_rel_cost_gap:.1e}  "
                f"max dist. {summary.max_estimator_distance_m:.1e} m "
                f"({summary.max_estimator_distance_rel:.1e} of the length scale)  "
                f"missing {summary.n_estimator_missing}  extra {summary.n_estimator_extra}  "
                f"SDP: max rel. gap {summary.max_rel_objective_gap:.1e}, "
                f"failed {summary.n_sdp_failed}  "
                f"disagreements {summary.n_disagreements}"
            )
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
    """Console-script entry point ``emitterbench``."""
    app(prog_name="emitterbench")


if __name__ == "__main__":
    main()
