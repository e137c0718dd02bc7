"""Malformed, oversized and impossible inputs through the command line, and a fuzz test.

Every file of ``tests/corpus/measurements`` goes through ``estimate``, ``crlb`` and ``fly``,
every file of ``tests/corpus/experiments`` through ``run``; each must end with exit status 2
and exactly one line on stderr, ``error: <field>: <what is wrong and the fix>``, naming the
field of the table below, with nothing on stdout and (for ``run``) no run folder written. The
files come from ``tests/corpus/generate.py``; ``valid/`` holds the files they derive from.

The fuzz test mutates the valid measurement file (values replaced by huge, negative,
non-finite, textual or nested ones, keys dropped or added) and checks that only a
``ValueError`` whose message starts with a field ever leaves the reader, and that the command
line exits 0, or 2 with one such line. It runs ``EMITTERBENCH_FUZZ_EXAMPLES`` examples (1,000
by default); ``test_fuzzed_measurement_files_long`` (marked slow) runs 10,000 when
``EMITTERBENCH_LONG_FUZZ=1``.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import pytest
import typer.main
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from comparison.cli import app
from scenarios.files import measurements_from_json

CORPUS = Path(__file__).resolve().parent / "corpus"
runner = CliRunner()

CSV_CONSTANTS = (
    "--carrier-hz", "3e8", "--speed-of-light-mps", "3e8",
    "--sigma-doppler-hz", "0.010000000000000002", "--sigma-toa-s", "3.3333333333333337e-10",
)  # fmt: skip
"""The constants of the corpus's CSV files (those of ``valid/paper-1m.json``)."""

COMMANDS: dict[str, tuple[str, ...]] = {
    "estimate": ("estimate", "{file}", "--json"),
    "crlb": ("crlb", "{file}", "--json", "--at", "35", "15"),
    "fly": ("fly", "{file}", "--planner", "constant", "--estimator", "cls", "--json"),
}
"""The commands every measurement file goes through; ``--at`` so that a CSV file needs no truth."""

# (file, the field the one-line error names: a regular expression; {path} is the file itself)
MEASUREMENT_CASES: list[tuple[str, str]] = [
    # parsing and resource limits (scenarios/files.py)
    ("nesting-5000-deep.json", "{path}"),
    ("nesting-5000-deep-in-a-sample.json", "{path}"),
    ("nesting-40-deep-in-a-sample.json", r"samples\[0\]\.toa_s\[0\]"),
    ("huge-integer-carrier.json", "carrier_hz"),
    ("huge-integer-frame.json", r"samples\[9\]\.frame"),
    ("huge-negative-integer-time.json", r"samples\[0\]\.time_s"),
    ("integer-beyond-float-carrier.json", "carrier_hz"),
    ("frame-2-to-the-64.json", r"samples\[9\]\.frame"),
    ("frame-2-to-the-64-first.json", r"samples\[0\]\.frame"),
    ("float-1e400-toa.json", r"samples\[0\]\.toa_s"),
    # numbers beyond the model (the limits of scenarios/types.py)
    ("sigma-doppler-1e200.json", r"noise\.doppler_hz"),
    ("sigma-toa-1e200.json", r"noise\.toa_s"),
    ("sigma-toa-1e-300.json", r"noise\.toa_s"),
    ("carrier-1e200.json", "carrier_hz"),
    ("position-1e200.json", r"(samples\[3\]\.)?position_m(\[3\])?(\[0\])?"),
    ("velocity-1e200.json", r"(samples\[0\]\.)?velocity_mps(\[0\])?(\[0\])?"),
    ("emitter-height-1e300.json", "emitter_height_m"),
    ("truth-1e300.json", r"truth(\.emitter_m|_emitter_m)(\[0\])?"),
    # non-finite numbers
    ("nan-toa.json", r"samples\[0\]\.toa_s"),
    ("infinity-doppler.json", r"samples\[4\]\.doppler_hz"),
    ("minus-infinity-position.json", r"samples\[2\]\.position_m\[1\]"),
    ("nan-time.json", r"samples\[1\]\.time_s"),
    ("nan-sigma.json", r"noise\.toa_s"),
    ("nan-truth.json", r"truth\.emitter_m\[0\]"),
    # shapes and types
    ("position-two-numbers.json", r"samples\[0\]\.position_m"),
    ("position-nested.json", r"samples\[0\]\.position_m"),
    ("velocity-a-string.json", r"samples\[0\]\.velocity_mps"),
    ("truth-three-numbers.json", r"truth\.emitter_m"),
    ("truth-a-list.json", "truth"),
    ("samples-empty.json", "samples"),
    ("samples-an-object.json", "samples"),
    ("sample-a-number.json", r"samples\[0\]"),
    ("sample-null.json", r"samples\[5\]"),
    ("noise-a-number.json", "noise"),
    ("carrier-a-boolean.json", "carrier_hz"),
    ("carrier-a-string.json", "carrier_hz"),
    ("toa-a-list.json", r"samples\[2\]\.toa_s"),
    ("top-level-array.json", "measurements"),
    ("top-level-number.json", "measurements"),
    # keys
    ("carrier-missing.json", "carrier_hz"),
    ("schema-missing.json", "schema"),
    ("schema-a-number.json", "schema"),
    ("unknown-key.json", "carrier_freq"),
    ("unknown-noise-key.json", r"noise\.toa"),
    ("rss-model-incomplete.json", r"rss_model\.path_loss_exponent"),
    ("toa-on-some-samples.json", r"samples\[3\]\.toa_s"),
    ("duplicate-key.json", "carrier_hz"),
    # values the data types refuse
    ("sigma-negative.json", r"noise\.toa_s"),
    ("sigma-zero.json", r"noise\.doppler_hz"),
    ("carrier-zero.json", "carrier_hz"),
    ("speed-of-light-negative.json", "speed_of_light_mps"),
    ("rss-reference-distance-zero.json", r"rss_model\.reference_distance_m"),
    ("frame-negative.json", r"samples\[0\]\.frame"),
    ("frame-fractional.json", r"samples\[0\]\.frame"),
    ("frames-out-of-order.json", r"samples\[15\]\.frame"),
    # syntax and encoding
    ("invalid-syntax.json", "{path}"),
    ("empty.json", "{path}"),
    ("not-utf8.json", "{path}"),
    ("bom-and-unknown-key.json", "carrier_freq"),
    # CSV
    ("csv-bom-unknown-column.csv", "dopler_hz"),
    ("csv-bom-nan-cell.csv", r"toa_s \(CSV line 4\)"),
    ("csv-huge-integer-frame.csv", r"frame \(CSV line 2\)"),
    ("csv-frame-2-to-the-64.csv", r"frame \(CSV line 11\)"),
    ("csv-float-1e400.csv", r"x_m \(CSV line 2\)"),
    ("csv-position-1e200.csv", r"(x_m \(CSV line 3\)|position_m\[1\])"),
    ("csv-not-a-number.csv", r"doppler_hz \(CSV line 3\)"),
    ("csv-missing-column.csv", "vz_mps"),
    ("csv-short-row.csv", r"samples \(CSV line 4\)"),
    ("csv-duplicate-column.csv", "x_m"),
    ("csv-nul-byte.csv", r"time_s \(CSV line 3\)"),
    ("csv-huge-cell.csv", r"samples \(CSV line 3\)"),
    ("csv-unclosed-quote.csv", r"samples \(CSV line 5\)"),
    ("csv-empty.csv", "header"),
    ("csv-header-only.csv", "samples"),
]

# (file, field, the impossibility): refused by the physical checks of scenarios/types.py
PHYSICAL_CASES: list[tuple[str, str, str]] = [
    ("toa-negated.json", r"(samples\[0\]\.)?toa_s(\[0\])?", "a negative time of arrival"),
    (
        "range-shorter-than-height.json",
        r"(samples\[0\]\.)?toa_s(\[0\])?",
        "a ToA range of 30 m under a UAV 50 m above the emitter",
    ),
    (
        "velocity-changes-inside-a-frame.json",
        r"(samples\[5\]\.)?velocity_mps(\[5\])?",
        "the velocity changes inside one straight frame",
    ),
    ("csv-toa-negated.csv", r"(toa_s \(CSV line 2\)|toa_s(\[0\])?)", "a negative time of arrival"),
]

# (file, field) for `emitterbench run FILE -o DIR`
EXPERIMENT_CASES: list[tuple[str, str]] = [
    ("trials-1e12.toml", "trials"),
    ("trials-huge-integer.toml", "trials"),
    ("trials-4000-digits.toml", "trials"),
    ("trials-nan.toml", "trials"),
    ("trials-infinite.toml", "trials"),
    ("trials-negative.toml", "trials"),
    ("trials-a-string.toml", "trials"),
    ("trials-1e300-float.toml", "trials"),
    ("frames-1e8.toml", "frames"),
    ("chunk-size-1e12.toml", "chunk_size"),
    ("sweep-emitter-x-1e160-1e200.toml", r"sweep\.values\[0\]"),
    ("sweep-emitter-x-1e200-second.toml", r"sweep\.values\[1\]"),
    ("sweep-grid-x-1e200.toml", r"sweep\.x\[1\]"),
    ("sweep-grid-1000-by-1000.toml", "sweep"),
    ("sweep-20000-values.toml", r"sweep\.values"),
    ("sweep-frames-1e8.toml", r"sweep\.values\[1\]"),
    ("sweep-samples-per-frame-1e9.toml", r"sweep\.values\[0\]"),
    ("sweep-fixed-frames-1e8.toml", r"sweep\.fixed\.frames"),
    ("sweep-fixed-range-sigma-1e300.toml", r"sweep\.fixed\.range_sigma_m"),
    ("sweep-fixed-speed-1e200.toml", r"sweep\.fixed\.speed_mps"),
    ("sweep-fixed-emitter-height-1e200.toml", r"sweep\.fixed\.emitter_height_m"),
    ("sweep-fixed-sample-interval-1e300.toml", r"sweep\.fixed\.sample_interval_s"),
    ("sweep-value-nan.toml", r"sweep\.values\[1\]"),
    ("sweep-snr-1e300.toml", r"sweep\.values\[0\]"),
    ("too-many-estimates.toml", "trials"),
    ("options-nested-40-deep.toml", r"estimators\[0\]\.options\.side_prior_m"),
    ("unknown-key.toml", "trails"),
    ("nesting-5000-deep.toml", "experiment"),
    ("invalid-syntax.toml", "experiment"),
    ("not-utf8.toml", "experiment"),
    ("json-nesting-5000-deep.json", "experiment"),
    ("json-huge-integer-trials.json", "trials"),
    ("json-bom-unknown-key.json", "trails"),
    ("json-trials-1e12.json", "trials"),
]


def invoke(*args: Any) -> Any:
    return runner.invoke(app, [str(a) for a in args])


def assert_one_line_error(result: Any, field: str) -> None:
    """Exit 2, no traceback, nothing on stdout, one line ``error: <field>: ...`` on stderr."""
    assert isinstance(result.exception, SystemExit | None), result.exc_info
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert re.match(rf"error: {field}: \S", lines[0]), lines[0]


def measurement_args(command: str, path: Path) -> list[str]:
    args = [a.format(file=path) for a in COMMANDS[command]]
    return args + list(CSV_CONSTANTS) if path.suffix == ".csv" else args


def field_of(pattern: str, path: Path) -> str:
    return re.escape(str(path)) if pattern == "{path}" else pattern


def test_the_table_lists_every_corpus_file() -> None:
    listed = {name for name, _ in MEASUREMENT_CASES} | {name for name, *_ in PHYSICAL_CASES}
    assert listed == {p.name for p in (CORPUS / "measurements").iterdir()}
    assert {name for name, _ in EXPERIMENT_CASES} == {
        p.name for p in (CORPUS / "experiments").iterdir()
    }
    assert len(MEASUREMENT_CASES) + len(PHYSICAL_CASES) + len(EXPERIMENT_CASES) >= 60


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize(
    ("name", "field"), MEASUREMENT_CASES, ids=[c[0] for c in MEASUREMENT_CASES]
)
def test_malformed_measurement_file(command: str, name: str, field: str) -> None:
    path = CORPUS / "measurements" / name
    assert_one_line_error(invoke(*measurement_args(command, path)), field_of(field, path))


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize(
    ("name", "field", "impossibility"), PHYSICAL_CASES, ids=[c[0] for c in PHYSICAL_CASES]
)
def test_physically_impossible_measurement_file(
    command: str, name: str, field: str, impossibility: str
) -> None:
    """Refused by the physical checks of scenarios/types.py, through every command."""
    path = CORPUS / "measurements" / name
    assert_one_line_error(invoke(*measurement_args(command, path)), field)


@pytest.mark.parametrize(("name", "field"), EXPERIMENT_CASES, ids=[c[0] for c in EXPERIMENT_CASES])
def test_malformed_experiment_file(tmp_path: Path, name: str, field: str) -> None:
    out = tmp_path / "run"
    assert_one_line_error(invoke("run", CORPUS / "experiments" / name, "-o", out), field)
    assert not out.exists()  # refused before any work


def test_an_oversized_measurement_file_is_refused_before_reading(tmp_path: Path) -> None:
    from scenarios.limits import MAX_FILE_MB

    path = tmp_path / "huge.json"
    with path.open("wb") as handle:  # sparse: the size is what counts
        handle.truncate(MAX_FILE_MB * 2**20 + 1)
    for command in COMMANDS:
        result = invoke(*measurement_args(command, path))
        assert_one_line_error(result, re.escape(str(path)))
        assert f"{MAX_FILE_MB} MiB" in result.stderr
        assert "EMITTERBENCH_MAX_FILE_MB" in result.stderr


def test_an_oversized_experiment_file_is_refused_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "huge.toml"
    with path.open("wb") as handle:
        handle.truncate(2**20 + 1)
    assert_one_line_error(invoke("run", path, "-o", tmp_path / "run"), "experiment")


@pytest.mark.parametrize("name", ["paper-1m.json", "paper-1m-bom.json"])
def test_valid_json_files_are_read_with_or_without_a_bom(name: str) -> None:
    reference = invoke("estimate", CORPUS / "valid" / "paper-1m.json", "--json")
    result = invoke("estimate", CORPUS / "valid" / name, "--json")
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    assert json.loads(result.stdout) == json.loads(reference.stdout)


def test_a_csv_file_with_a_bom_reads_like_the_json_file() -> None:
    """The CSV files hold the samples of the JSON file (no RSS): the same ToA+Doppler bound."""
    from_json = json.loads(invoke("crlb", CORPUS / "valid" / "paper-1m.json", "--json").stdout)
    for name in ("paper-1m.csv", "paper-1m-bom.csv"):
        result = invoke(
            "crlb", CORPUS / "valid" / name, "--json", "--at", "35", "15", *CSV_CONSTANTS
        )
        assert result.exit_code == 0, result.output
        bound = json.loads(result.stdout)["rmse_bound_m"]
        assert bound["toa+doppler"] == from_json["rmse_bound_m"]["toa+doppler"]
        assert bound["rss"] is None


# --------------------------------------------------------------------------------------------
# command-line options beyond a limit
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "field", "words"),
    [
        (
            ("simulate", "paper", "--seed", "1", "--frames", "100000000", "-o", "{tmp}/x.json"),
            "--frames",
            "EMITTERBENCH_MAX_FRAMES=N",
        ),
        (
            ("simulate", "paper", "--seed", "1", "--snr-db", "-1e308", "-o", "{tmp}/x.json"),
            "--snr-db",
            "[-60, 100] dB",
        ),
        (("crlb", "{m}", "--at", "1e200", "0"), "--at", "within ±1e+09 m"),
        (
            ("estimate", "{m}", "--option", "side_prior_m=" + "[" * 5000 + "]" * 5000),
            "--option",
            "side_prior_m: arrays",
        ),
        (
            ("estimate", "{m}", "--option", "side_prior_m=[1, " + "9" * 5000 + "]"),
            "--option",
            "5000 digits",
        ),
        (
            ("run", "smoke", "-o", "{tmp}/run", "--trials", "1000000000000"),
            "--trials",
            "EMITTERBENCH_MAX_TRIALS=N",
        ),
        (("run", "smoke", "-o", "{tmp}/run", "--workers", "100000"), "--workers", "per core"),
    ],
)
def test_requests_beyond_a_limit_are_refused_up_front(tmp_path, args, field, words) -> None:
    path = Path(shutil.copy(CORPUS / "valid" / "paper-1m.json", tmp_path / "m.json"))
    result = invoke(*(a.format(tmp=tmp_path, m=path) for a in args))
    assert_one_line_error(result, re.escape(field))
    assert words in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # nothing written


def test_an_environment_variable_sets_a_limit(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("EMITTERBENCH_MAX_FRAMES", "2")
    refused = invoke("simulate", "paper", "--seed", "1", "--frames", "3", "-o", tmp_path / "a.json")
    assert_one_line_error(refused, "--frames")
    assert "3 frames, more than the limit of 2" in refused.stderr
    accepted = invoke(
        "simulate", "paper", "--seed", "1", "--frames", "2", "-o", tmp_path / "b.json"
    )
    assert accepted.exit_code == 0, accepted.output
    monkeypatch.setenv("EMITTERBENCH_MAX_FRAMES", "many")
    assert_one_line_error(invoke("estimate", tmp_path / "b.json"), "EMITTERBENCH_MAX_FRAMES")


# --------------------------------------------------------------------------------------------
# fuzz
# --------------------------------------------------------------------------------------------

VALID = json.loads((CORPUS / "valid" / "paper-1m.json").read_text(encoding="utf-8"))
FIELD_PREFIX = re.compile(r'^(?:[^\s"]|"(?:[^"\\]|\\.)*")+(?: \([^)]*\))?: \S')
"""A message that starts with a field: ``samples[2].toa_s: ``, ``x_m (CSV line 3): `` or, for
a key with spaces, ``noise["a b"]: ``."""


def locations(value: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a JSON value, containers included."""
    found = [path]
    if isinstance(value, dict):
        for key, item in value.items():
            found += locations(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += locations(item, (*path, index))
    return found


PATHS = locations(VALID)[1:]


class Raw:
    """A value written into the JSON text as it is (huge integers, deep nesting)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return f"Raw({self.text[:30]!r}, {len(self.text)} characters)"


def nested(depth: int) -> Raw:
    return Raw("[" * depth + "1" + "]" * depth)


leaves = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e308, -1e308, 1e200, -1e200, 5e-324, 1e-300, 2.0**64, 0.0, -0.0, -1.0]),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([2**31, 2**53 + 1, 2**63, 2**64, -(2**63) - 1]),
    st.builds(lambda n: Raw("9" * n), st.integers(min_value=300, max_value=6000)),
    st.builds(lambda n: Raw("-" + "9" * n), st.integers(min_value=4300, max_value=5000)),
    st.builds(nested, st.integers(min_value=2, max_value=60)),
    st.just(nested(3000)),
    st.text(max_size=8),
    st.sampled_from(["NaN", "1e3", "emitterbench.measurements/1", "\ufeff", "\x00", ""]),
    st.booleans(),
    st.none(),
)
values = st.recursive(
    leaves,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=6,
)


def lookup(path: tuple[Any, ...], obj: Any = VALID) -> Any:
    for key in path:
        obj = obj[key]
    return obj


CONTAINERS = [p for p in [(), *PATHS] if isinstance(lookup(p), dict | list)]
mutation = st.one_of(
    st.tuples(st.just("replace"), st.sampled_from(PATHS), values),
    st.tuples(st.just("drop"), st.sampled_from(PATHS), st.none()),
    st.tuples(st.just("add"), st.sampled_from(CONTAINERS), st.tuples(st.text(max_size=12), values)),
)


def mutated_text(mutations: list[tuple[str, tuple[Any, ...], Any]], bom: bool) -> str:
    """The valid file with ``mutations`` applied, as JSON text (``Raw`` values spliced in)."""
    obj = json.loads(json.dumps(VALID))
    raws: dict[str, str] = {}

    def plain(value: Any) -> Any:
        if isinstance(value, Raw):
            marker = f"@raw{len(raws)}@"
            raws[marker] = value.text
            return marker
        if isinstance(value, list):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    for kind, path, value in mutations:
        try:
            parent = lookup(path[:-1], obj) if path else None
            if kind == "replace":
                parent[path[-1]] = plain(value)
            elif kind == "drop":
                del parent[path[-1]]
            else:
                container = lookup(path, obj)
                key, item = value
                if isinstance(container, dict):
                    container[key] = plain(item)
                else:
                    container.append(plain(item))
        except (KeyError, IndexError, TypeError, AttributeError):
            continue  # an earlier mutation removed or replaced the path
    text = json.dumps(obj)
    for marker, raw in raws.items():
        text = text.replace(json.dumps(marker), raw)
    return ("\ufeff" if bom else "") + text


COMMAND = typer.main.get_command(app)
"""The command behind the app, built once (a test runner builds it again on every call)."""


def run_command(*args: Any) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``emitterbench ARGS``; an exception propagates."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        status = COMMAND.main([str(a) for a in args], "emitterbench", standalone_mode=False)
    return status, out.getvalue(), err.getvalue()


def check_mutated_file(
    folder: Path, mutations: list[tuple[str, tuple[Any, ...], Any]], bom: bool
) -> None:
    text = mutated_text(mutations, bom)
    try:
        measurements_from_json(text.removeprefix("\ufeff"), source="fuzz.json")
    except ValueError as error:
        assert FIELD_PREFIX.match(str(error)), str(error)
    path = folder / "fuzz.json"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    for args in (("estimate", path, "--json"), ("crlb", path, "--json", "--at", "35", "15")):
        status, stdout, stderr = run_command(*args)
        assert status in (0, 2), stderr
        if status == 2:
            lines = stderr.splitlines()
            assert len(lines) == 1, lines
            assert lines[0].startswith("error: "), lines
            assert FIELD_PREFIX.match(lines[0].removeprefix("error: ")), lines
        else:  # a mutated sample may leave data the model does not fit: one warning line
            assert stderr == "" or (
                stderr.startswith("warning: the data do not fit the model at the answer")
                and stderr.count("\n") == 1
            ), stderr
            assert isinstance(json.loads(stdout), dict)


FUZZ = given(mutations=st.lists(mutation, min_size=1, max_size=4), bom=st.booleans())


@pytest.fixture(scope="module")
def fuzz_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@settings(
    max_examples=int(os.environ.get("EMITTERBENCH_FUZZ_EXAMPLES", "1000")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@FUZZ
def test_fuzzed_measurement_files_fail_cleanly(fuzz_folder, mutations, bom) -> None:
    check_mutated_file(fuzz_folder, mutations, bom)


@pytest.mark.slow
@pytest.mark.skipif(
    os.environ.get("EMITTERBENCH_LONG_FUZZ") != "1", reason="set EMITTERBENCH_LONG_FUZZ=1"
)
@settings(max_examples=10_000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@FUZZ
def test_fuzzed_measurement_files_long(fuzz_folder, mutations, bom) -> None:
    check_mutated_file(fuzz_folder, mutations, bom)
