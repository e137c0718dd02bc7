"""The command line: simulate, estimate, crlb, list, and clean errors with exit status 2."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

from comparison.cli import app
from comparison.crlb import MODALITY_SETS, crlb_m2, fisher_information, rmse_bound_m
from estimators.registry import all_entries, make_estimator
from scenarios.catalog import CATALOG, get_scenario
from scenarios.files import measurements_to_dict, read_measurements, write_measurements
from scenarios.simulate import simulate
from scenarios.types import MeasurementSet, NoiseSigmas
from tests.comparison.cli_support import clean_error, invoke, runner

ESTIMATE_KEYS = {
    "estimator",
    "position_m",
    "candidates_m",
    "ambiguous",
    "covariance_m2",
    "success",
    "message",
    "diagnostics",
}


def simulated(folder: Path, scenario: str = "paper-1m", *, seed: int = 1, snr_db: float = 20.0):
    path = folder / f"{scenario}.json"
    result = invoke("simulate", scenario, "--seed", seed, "--snr-db", snr_db, "-o", path)
    assert result.exit_code == 0, result.output
    return path


def assert_clean_error(result: Any, field: str) -> None:
    """Exit 2, nothing on stdout, one line ``error: <field>: ...`` on stderr."""
    clean_error(result, f"{field}: ")


def test_simulate_writes_the_library_simulation_with_truth(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    result = invoke("simulate", "turn", "--seed", 7, "--snr-db", 5, "--frames", 3, "-o", path)
    assert result.exit_code == 0, result.output
    expected = simulate(get_scenario("turn", frames=3), snr_db=5.0, seed=7)
    read = read_measurements(path)
    assert measurements_to_dict(read) == measurements_to_dict(expected)
    np.testing.assert_array_equal(read.truth_emitter_m, [35.0, 15.0])
    assert len(read.frames) == 3


def test_estimate_json_contains_the_truth_within_the_crlb(tmp_path: Path) -> None:
    path = simulated(tmp_path, "paper-1m", seed=1, snr_db=20.0)
    result = invoke("estimate", path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert set(out) == ESTIMATE_KEYS | {"error_m", "error_side_resolved_m"}
    data = read_measurements(path)
    truth = data.truth_emitter_m
    bound_m = float(rmse_bound_m(fisher_information(data, truth, "toa+doppler")))
    candidates = np.array(out["candidates_m"])
    distances = np.linalg.norm(candidates - truth, axis=1)
    assert out["success"] is True
    assert out["ambiguous"] is True  # one straight frame: the mirror pair (MATH §7)
    assert candidates.shape == (2, 2)
    assert distances.min() <= 6.0 * bound_m
    assert out["error_side_resolved_m"] == pytest.approx(distances.min(), rel=1e-12)
    assert out["error_m"] == pytest.approx(
        np.linalg.norm(np.array(out["position_m"]) - truth), rel=1e-12
    )
    # the two candidates mirror each other across the track y = 0
    np.testing.assert_allclose(candidates[0] * [1, -1], candidates[1], rtol=1e-9)


@pytest.mark.parametrize("name", ["cls", "cls-paper", "cls-as-printed"])
def test_estimate_json_is_the_library_estimate(tmp_path: Path, name: str) -> None:
    path = simulated(tmp_path, "paper-10m", seed=3, snr_db=10.0)
    result = invoke("estimate", path, "--estimator", name, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    data = read_measurements(path)
    direct = make_estimator(name).estimate(data.without_truth(), rng=np.random.default_rng(0))
    expected = json.loads(json.dumps(direct.to_dict()))
    assert {key: out[key] for key in ESTIMATE_KEYS} == expected
    assert out["estimator"] == name


def test_estimate_options_are_parsed_as_json(tmp_path: Path) -> None:
    path = simulated(tmp_path, "paper-1m", seed=2, snr_db=20.0)
    for prior_y, sign in (("10", 1.0), ("-10", -1.0)):
        result = invoke(
            "estimate", path, "--option", f"side_prior_m=[30,{prior_y}]", "--option",
            "frames=last", "--json",
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        out = json.loads(result.stdout)
        assert np.sign(out["position_m"][1]) == sign
        if sign > 0:  # the truth's side: the error is the side-resolved one
            assert out["error_m"] == out["error_side_resolved_m"]
        else:  # the mirror image, about 2 * 15 m from the truth
            assert out["error_m"] == pytest.approx(30.0, abs=0.5)


def test_estimate_summary_is_readable(tmp_path: Path) -> None:
    path = simulated(tmp_path, "turn", seed=3, snr_db=0.0)
    result = invoke("estimate", path)
    assert result.exit_code == 0, result.output
    out = json.loads(invoke("estimate", path, "--json").stdout)
    x, y = out["position_m"]
    assert f"({x:.4f}, {y:.4f})" in result.stdout
    assert "error_m" in result.stdout
    assert not out["ambiguous"]  # two headings resolve the side


@pytest.mark.parametrize(
    ("estimator", "fault"), [("cls", "outlier"), ("ml", "light"), ("ml", "outlier")]
)
def test_estimate_warns_when_the_data_do_not_fit(tmp_path: Path, estimator, fault) -> None:
    """MATH §17: one ToA sample 10⁴ σ off, or the speed of light ×100, makes χ² at the answer
    enormous; ``estimate`` still answers (stdout, ``--json`` intact) and warns on stderr."""
    data = read_measurements(simulated(tmp_path, "paper-1m", seed=4, snr_db=20.0))
    clean = invoke(
        "estimate", simulated(tmp_path, "paper-1m", seed=4, snr_db=20.0), "-e", estimator
    )
    assert clean.exit_code == 0 and clean.stderr == "", clean.output  # the same data, unspoilt
    if fault == "outlier":
        toa = np.array(data.toa_s)
        toa[5] += 1e4 * data.noise.toa_s
        spoilt = dataclasses.replace(data, toa_s=toa)
    else:
        spoilt = dataclasses.replace(data, speed_of_light_mps=100 * data.speed_of_light_mps)
    path = write_measurements(spoilt, tmp_path / "spoilt.json")
    for extra in ((), ("--json",)):
        result = invoke("estimate", path, "-e", estimator, *extra)
        assert result.exit_code == 0, result.output
        (line,) = result.stderr.strip().splitlines()
        assert line.startswith("warning: the data do not fit the model at the answer (χ² = ")
        assert "on 18 degrees of freedom, p < 1e-6; MATH §17)" in line
    out = json.loads(result.stdout)
    assert out["success"] is True
    assert out["diagnostics"]["fit_dof"] == 18  # 10 samples, Doppler and ToA, minus (x, y)
    assert out["diagnostics"]["fit_chi2"] > 1e5


def write_csv(data: MeasurementSet, path: Path) -> Path:
    columns = {
        "frame": data.frame,
        "time_s": data.time_s,
        **{axis: data.position_m[:, i] for i, axis in enumerate(("x_m", "y_m", "z_m"))},
        **{axis: data.velocity_mps[:, i] for i, axis in enumerate(("vx_mps", "vy_mps", "vz_mps"))},
        "doppler_hz": data.doppler_hz,
        "toa_s": data.toa_s,
    }
    lines = [",".join(columns)]
    lines += [",".join(repr(c[i].item()) for c in columns.values()) for i in range(data.n_samples)]
    path.write_text("\n".join(lines) + "\n")
    return path


def csv_options(data: MeasurementSet) -> list[str]:
    return [
        "--carrier-hz", repr(data.carrier_hz),
        "--speed-of-light-mps", repr(data.speed_of_light_mps),
        "--sigma-doppler-hz", repr(data.noise.doppler_hz),
        "--sigma-toa-s", repr(data.noise.toa_s),
    ]  # fmt: skip


def test_estimate_and_crlb_from_csv_match_json(tmp_path: Path) -> None:
    json_path = simulated(tmp_path, "turn", seed=4, snr_db=3.0)
    data = read_measurements(json_path)
    csv_path = write_csv(data, tmp_path / "m.csv")
    from_json = json.loads(invoke("estimate", json_path, "--json").stdout)
    result = invoke("estimate", csv_path, "--json", *csv_options(data))
    assert result.exit_code == 0, result.output
    from_csv = json.loads(result.stdout)
    assert from_csv == {key: from_json[key] for key in ESTIMATE_KEYS}  # CSV has no truth
    at = ["--at", "35", "15"]
    crlb_csv = json.loads(invoke("crlb", csv_path, "--json", *at, *csv_options(data)).stdout)
    crlb_json = json.loads(invoke("crlb", json_path, "--json", *at).stdout)
    for name in ("toa", "doppler", "toa+doppler"):
        assert crlb_csv["rmse_bound_m"][name] == crlb_json["rmse_bound_m"][name]


def test_crlb_json_equals_the_library(tmp_path: Path) -> None:
    path = simulated(tmp_path, "turn", seed=5, snr_db=10.0)
    data = read_measurements(path)
    for args, at in (((), data.truth_emitter_m), (("--at", "30", "-10"), np.array([30.0, -10.0]))):
        result = invoke("crlb", path, "--json", *args)
        assert result.exit_code == 0, result.output
        out = json.loads(result.stdout)
        assert out["at_m"] == at.tolist()
        assert set(out["rmse_bound_m"]) == set(out["crlb_m2"]) == set(MODALITY_SETS)
        for name, modalities in MODALITY_SETS.items():
            information = fisher_information(data, at, modalities)
            assert out["rmse_bound_m"][name] == float(rmse_bound_m(information))
            assert out["crlb_m2"][name] == crlb_m2(information).tolist()
        # information adds: the joint bound is below either modality alone
        joint = out["rmse_bound_m"]["toa+doppler"]
        assert joint < min(out["rmse_bound_m"]["toa"], out["rmse_bound_m"]["doppler"])


def test_crlb_reports_a_modality_without_sigma_as_null(tmp_path: Path) -> None:
    full = simulate(get_scenario("paper-1m"), seed=1)
    data = dataclasses.replace(
        full.without("rss"),
        noise=NoiseSigmas(doppler_hz=full.noise.doppler_hz, toa_s=full.noise.toa_s),
        rss_model=None,
    )
    path = write_measurements(data, tmp_path / "m.json")
    out = json.loads(invoke("crlb", path, "--json").stdout)
    assert out["rmse_bound_m"]["rss"] is None
    assert out["crlb_m2"]["rss"] is None
    assert out["notes"]["rss"].startswith("noise.rss_db: ")
    assert out["rmse_bound_m"]["toa"] == float(
        rmse_bound_m(fisher_information(data, data.truth_emitter_m, "toa"))
    )
    table = invoke("crlb", path)
    assert table.exit_code == 0, table.output
    assert "noise.rss_db" in table.stdout


def test_crlb_needs_a_position(tmp_path: Path) -> None:
    data = simulate(get_scenario("paper-1m"), seed=1).without_truth()
    path = write_measurements(data, tmp_path / "m.json")
    assert_clean_error(invoke("crlb", path, "--json"), "--at")


def test_list_names_every_scenario_and_estimator() -> None:
    result = invoke("list")
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    for name, entry in CATALOG.items():
        assert any(line.split()[:1] == [name] and entry.summary in line for line in lines), name
    for name, entry in all_entries().items():
        assert any(line.split()[:1] == [name] and entry.summary in line for line in lines), name
    assert lines.index("scenarios:") < lines.index("estimators:")


class NeedsBackend:
    """An estimator class that declares a back-end which is not installed."""

    name = "needy"
    requires = frozenset({"toa"})
    required_modules = ("no_such_backend",)


def test_list_marks_unavailable_estimators(monkeypatch) -> None:
    from estimators import registry

    ghost = registry.RegistryEntry("ghost", "no_such_package.module:Ghost", "a ghost")
    needy = registry.RegistryEntry("needy", f"{__name__}:NeedsBackend", "declares a back-end")
    monkeypatch.setitem(registry.BUILTIN, "ghost", ghost)
    monkeypatch.setitem(registry.BUILTIN, "needy", needy)
    lines = invoke("list").stdout.splitlines()
    (line,) = [line for line in lines if line.split()[:1] == ["ghost"]]
    assert line.endswith("[unavailable: needs no_such_package.module]")
    (line,) = [line for line in lines if line.split()[:1] == ["needy"]]
    assert line.endswith("[unavailable: needs no_such_backend]")
    (cls_line,) = [line for line in lines if line.split()[:1] == ["cls"]]
    assert "unavailable" not in cls_line


MALFORMED = [
    ("unknown-schema", '{"schema": "other/2"}', "schema"),
    ("unknown-key", None, "carrier_freq"),
    ("nan", None, "samples[0].toa_s"),
    ("invalid-json", '{"schema": ', "{path}"),
    ("non-object", "[]", "measurements"),
]


def malformed_text(case: str, text: str | None, valid: dict[str, Any]) -> str:
    if text is not None:
        return text
    obj = json.loads(json.dumps(valid))
    if case == "unknown-key":
        obj["carrier_freq"] = 1.0
    else:
        obj["samples"][0]["toa_s"] = float("nan")
    return json.dumps(obj)


@pytest.mark.parametrize("command", ["estimate", "crlb"])
@pytest.mark.parametrize(("case", "text", "field"), MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_file_exits_2_naming_the_field(tmp_path, command, case, text, field) -> None:
    valid = measurements_to_dict(simulate(get_scenario("paper-1m"), seed=1))
    path = tmp_path / "bad.json"
    path.write_text(malformed_text(case, text, valid))
    assert_clean_error(invoke(command, path, "--json"), field.format(path=path))


def test_bad_names_and_options_exit_2(tmp_path: Path) -> None:
    path = simulated(tmp_path)
    assert_clean_error(invoke("estimate", path, "-e", "no-such"), "estimator")
    assert_clean_error(invoke("estimate", path, "--option", "bogus=1"), "bogus")
    assert_clean_error(invoke("estimate", path, "--option", "frames=first"), "frames")
    assert_clean_error(invoke("estimate", path, "--option", "frames"), "--option")
    assert_clean_error(invoke("estimate", path, "--carrier-hz", "1e9"), "--carrier-hz")
    assert_clean_error(invoke("estimate", tmp_path / "absent.json"), str(tmp_path / "absent.json"))
    csv_path = write_csv(read_measurements(path), tmp_path / "m.csv")
    assert_clean_error(invoke("estimate", csv_path), "--carrier-hz")
    assert_clean_error(
        invoke("estimate", csv_path, "--carrier-hz", "3e8", "--sigma-doppler-hz", "0.1"),
        "--sigma-toa-s",
    )
    assert_clean_error(
        invoke("estimate", csv_path, *csv_options(read_measurements(path))[:-1], "-1"),
        "--sigma-toa-s",
    )


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (("no-such-scenario", "--seed", "1"), "scenario"),
        (("paper", "--seed", "1", "--frames", "0"), "--frames"),
        (("paper", "--seed", "1", "--snr-db", "nan"), "--snr-db"),
    ],
)
def test_simulate_failure_writes_nothing(tmp_path: Path, args: tuple[str, ...], field: str) -> None:
    output = tmp_path / "out.json"
    assert_clean_error(invoke("simulate", *args, "-o", output), field)
    assert list(tmp_path.iterdir()) == []


def test_simulate_refuses_a_non_json_output(tmp_path: Path) -> None:
    assert_clean_error(
        invoke("simulate", "paper", "--seed", "1", "-o", tmp_path / "m.csv"), "--output"
    )
    assert list(tmp_path.iterdir()) == []


def test_importing_the_cli_does_not_import_the_numerics() -> None:
    code = (
        "import sys, comparison.cli; "
        "print(sorted(m for m in ('numpy', 'scenarios', 'estimators') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def console_script() -> str | None:
    beside = Path(sys.executable).with_name("emitterbench")
    return str(beside) if beside.exists() else shutil.which("emitterbench")


def test_console_script_end_to_end(tmp_path: Path) -> None:
    script = console_script()
    if script is None:
        pytest.skip("the emitterbench console script is not installed (pip install -e .)")
    path = write_measurements(simulate(get_scenario("orbit"), seed=3), tmp_path / "orbit.json")
    done = subprocess.run(
        [script, "estimate", str(path), "--json"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert not out["ambiguous"]
    data = read_measurements(path)
    bound_m = float(rmse_bound_m(fisher_information(data, data.truth_emitter_m, "toa+doppler")))
    assert out["error_m"] <= 6.0 * bound_m
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "emitterbench.measurements/1", "carrier_hz": 1e9, "samples": []}')
    failed = subprocess.run([script, "crlb", str(bad)], capture_output=True, text=True, timeout=120)
    assert failed.returncode == 2
    assert failed.stdout == ""
    assert failed.stderr == "error: samples: empty; give at least one sample\n"


# --------------------------------------------------------------------------------------------
# fly: the next velocity for a ground station
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("planner", "options", "estimator"),
    [
        ("paper", [], "ml"),
        ("fisher", ["criterion=D"], "ml"),
        ("orbit", ["radius_m=20"], "cls"),
        ("constant", [], "ml"),
    ],
)
def test_fly_prints_the_library_velocity(
    tmp_path: Path, planner: str, options: list[str], estimator: str
) -> None:
    from comparison.closed_loop import steering_candidates_m
    from scenarios.planners import flight_from_measurements, get_planner

    path = tmp_path / "m.json"
    result = invoke("simulate", "turn", "--seed", 4, "--frames", 3, "-o", path)
    assert result.exit_code == 0, result.output
    args = ["fly", path, "--planner", planner, "--estimator", estimator, "--json"]
    for option in options:
        args += ["--option", option]
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    data = read_measurements(path)
    estimate = make_estimator(estimator).estimate(
        data.without_truth(), rng=np.random.default_rng(0)
    )
    parsed = {k: json.loads(v) if v[0].isdigit() else v for k, v in (o.split("=") for o in options)}
    flight = flight_from_measurements(data)
    candidates = steering_candidates_m(estimate)  # the returned position first
    plan = get_planner(planner, **parsed).plan(
        flight, candidates, data.without_truth(), covariance_m2=estimate.covariance_m2
    )
    assert out["velocity_mps"] == plan.velocity_mps.tolist()
    assert out["planner"] == planner and out["message"] == plan.message
    assert out["speed_mps"] == pytest.approx(float(np.hypot(*plan.velocity_mps[:2])))
    assert out["flight"] == {
        "frames": 3,
        "samples_per_frame": 10,
        "sample_interval_s": pytest.approx(0.05),
        "next_frame_start_m": pytest.approx([5.0, 10.0, 50.0]),
    }
    assert out["estimate"]["position_m"] == estimate.position_m.tolist()
    text = invoke("fly", path, "--planner", planner, "--estimator", estimator, *(
        x for o in options for x in ("--option", o)
    ))  # fmt: skip
    assert text.exit_code == 0 and "velocity_mps" in text.stdout


def test_fly_errors_name_the_field(tmp_path: Path) -> None:
    path = simulated(tmp_path, "paper-1m", seed=1)
    assert_clean_error(invoke("fly", path, "--planner", "orbits"), "planner")
    assert_clean_error(invoke("fly", path, "--planner", "orbit", "--option", "radius=3"), "radius")
    assert_clean_error(invoke("fly", path, "--planner", "paper", "--option", "tie=nearest"), "tie")
    assert_clean_error(
        invoke("fly", path, "--planner", "paper", "--estimator", "nope"), "estimator"
    )
    turned = tmp_path / "turn.json"
    assert invoke("simulate", "turn", "--seed", 1, "-o", turned).exit_code == 0
    data = read_measurements(turned)
    uneven = write_measurements(data.take(np.arange(data.n_samples) < 15), tmp_path / "u.json")
    assert_clean_error(invoke("fly", uneven, "--planner", "fisher"), "frame")
    partial = write_measurements(data.take(np.arange(data.n_samples) < 5), tmp_path / "p.json")
    assert invoke("fly", partial, "--planner", "fisher").exit_code == 0  # one frame of 5


def test_list_names_every_planner() -> None:
    from scenarios.planners import PLANNER_SUMMARIES

    lines = invoke("list").stdout.splitlines()
    assert lines.index("estimators:") < lines.index(
        "planners (emitterbench fly FILE --planner NAME):"
    )
    for name, summary in PLANNER_SUMMARIES.items():
        assert any(line.split()[:1] == [name] and summary in line for line in lines), name


def test_validate_bad_input_exits_2_naming_the_field(tmp_path: Path) -> None:
    out = tmp_path / "v"
    assert_clean_error(invoke("validate", "--estimator", "no-such", "-o", out), "estimator")
    refused = invoke("validate", "--estimator", "sdp-cls", "-o", out)
    assert_clean_error(refused, "estimator")
    assert "add a method constrained_ls(self, data)" in refused.stderr
    assert_clean_error(
        invoke("validate", "--estimator", "cls", "--option", "bogus=1", "-o", out), "bogus"
    )
    assert_clean_error(invoke("validate", "--option", "frames=all", "-o", out), "--option")
    assert_clean_error(
        invoke("validate", "-e", "cls", "--families", "spiral", "-o", out), "--families"
    )
    assert_clean_error(invoke("validate", "--estimator", "cls", "--replay", "1"), "--families")
    assert_clean_error(invoke("validate", "--estimator", "cls"), "--output")
    assert not out.exists()


# --------------------------------------------------------------------------------------------
# one line for every failure, the exit statuses, --version, help text, Ctrl-C, --resume
# --------------------------------------------------------------------------------------------

REPO_ROOT = Path(__file__).resolve().parents[2]
HERE = "tests.comparison.test_cli"
HELD_RUN = "EMITTERBENCH_TEST_HELD_RUN"
CONSOLE = (sys.executable, "-c", "from comparison.cli import main; main()")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Held:
    """``cls`` that waits while the file ``gate`` exists, having made ``<gate>.waiting``; only
    in a process started with ``HELD_RUN`` set (a run the test interrupts)."""

    name: ClassVar[str] = "held-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    gate: str = ""

    def estimate(self, data, *, rng=None):
        from estimators.closed_form.cls import Cls

        held = bool(os.environ.get(HELD_RUN)) and os.path.exists(self.gate)
        if held:
            Path(self.gate + ".waiting").touch()
        while held and os.path.exists(self.gate):
            time.sleep(0.01)
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Noisy:
    """``cls`` after a numpy warning (division by zero) and a two-line user warning."""

    name: ClassVar[str] = "noisy-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        import warnings

        from estimators.closed_form.cls import Cls

        np.ones(1) / np.zeros(1)
        warnings.warn("first line\nsecond line", UserWarning, stacklevel=1)
        return Cls().estimate(data, rng=rng)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Refusing:
    """Raises a library's message without a field, as numpy or cvxpy would."""

    name: ClassVar[str] = "refusing"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        raise ValueError("cannot reshape array of size 3 into shape (2,)")


def smoke_definition(folder: Path, **changes: Any) -> Path:
    from comparison.experiment import load_experiment

    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    raw.update(changes)
    path = folder / "smoke.json"
    path.write_text(json.dumps(raw))
    return path


def test_version_is_the_installed_distribution_version() -> None:
    from importlib.metadata import version

    result = invoke("--version")
    assert result.exit_code == 0
    assert result.stdout == f"emitterbench {version('emitterbench')}\n"


@pytest.mark.parametrize(
    ("args", "field", "command"),
    [
        (("run", "smoke", "-o", "{tmp}/run", "--workers", "0"), "--workers", "run"),
        (("run", "smoke", "-o", "{tmp}/run", "--trials", "0"), "--trials", "run"),
        (("run", "smoke"), "--output", "run"),
        (("estimate",), "file", "estimate"),
        (("estimate", "m.json", "--estimatr", "cls"), "--estimatr", "estimate"),
        (("simulate", "paper", "--seed", "-1", "-o", "{tmp}/m.json"), "--seed", "simulate"),
        (("validate", "--instances", "0"), "--instances", "validate"),
        (("validate", "--instances", "10000000"), "--instances", "validate"),
        (("report", "{tmp}", "--bootstrap", "1000000000000"), "--bootstrap", "report"),
        (("list", "extra"), "arguments", "list"),
        (("no-such-command",), "command", ""),
        # click's parser raises these without a command: they still point at theirs
        (("crlb", "m.json", "--at", "30"), "--at", "crlb"),
        (("estimate", "m.json", "--option"), "--option", "estimate"),
        (("validate", "--families"), "--families", "validate"),
        (("fly", "m.json", "--planner"), "--planner", "fly"),
        (
            ("simulate", "paper-1m", "--seed", "1", "--frames", "0", "-o", "m.json"),
            "--frames",
            "simulate",
        ),
    ],
)
def test_usage_errors_are_one_line(tmp_path: Path, args: tuple[str, ...], field: str, command):
    result = invoke(*(a.format(tmp=tmp_path) for a in args))
    assert_clean_error(result, field)
    assert result.stderr.rstrip().endswith(
        f"(see `{' '.join(['emitterbench', command]).strip()} --help`)"
    )
    assert list(tmp_path.iterdir()) == []


def test_help_shows_brackets_that_rich_would_take_for_markup() -> None:
    text = runner.invoke(app, ["run", "--help"], env={"COLUMNS": "200"}).stdout
    assert "Local worker processes [all cores]." in text
    assert "(extra emitterbench[cluster])" in text


def test_an_unexpected_exception_is_one_line_with_exit_1(tmp_path: Path, monkeypatch) -> None:
    import comparison.crlb

    def broken(*args: Any, **kwargs: Any) -> None:
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(comparison.crlb, "crlb_table", broken)
    path = simulated(tmp_path)
    result = invoke("crlb", path, "--json")
    assert result.exit_code == 1
    assert result.stdout == ""
    (line,) = result.stderr.splitlines()
    assert line.startswith(
        "error: internal: ZeroDivisionError: float division by zero (please report"
    )
    assert "Traceback" not in result.stderr
    monkeypatch.setenv("EMITTERBENCH_TRACEBACK", "1")
    traced = invoke("crlb", path, "--json")
    assert traced.exit_code == 1 and "Traceback" in traced.stderr
    assert traced.stderr.splitlines()[-1] == line


def test_numpy_warnings_are_silenced_and_others_are_one_line(tmp_path: Path) -> None:
    path = simulated(tmp_path)
    result = invoke("estimate", path, "-e", f"{HERE}:Noisy", "--json")
    assert result.exit_code == 0, result.output
    assert result.stderr == "warning: first line second line\n"
    assert json.loads(result.stdout)["success"] is True


def test_a_library_message_without_a_field_gets_one(tmp_path: Path) -> None:
    path = simulated(tmp_path)
    result = invoke("estimate", path, "-e", f"{HERE}:Refusing", "--json")
    assert_clean_error(result, "--estimator")
    assert f"{HERE}:Refusing cannot estimate from {path}; try another estimator" in result.stderr
    assert "(cannot reshape array of size 3 into shape (2,))" in result.stderr


def test_messages_are_one_printable_line() -> None:
    from comparison.cli_support import MAX_LINE, one_line

    assert one_line("a\n  b\tc\x1b[31m\ud800") == "a b c\\x1b[31m\\ud800"
    assert len(one_line("x" * 10 * MAX_LINE)) < MAX_LINE + 20


def test_resume_keeps_the_trials_the_run_was_started_with(tmp_path: Path) -> None:
    from comparison.engine import read_experiment, read_trials

    out = tmp_path / "run"
    assert invoke("run", "smoke", "-o", out, "--trials", "3", "--workers", "1").exit_code == 0
    resumed = invoke("run", "smoke", "-o", out, "--resume", "--workers", "1")
    assert resumed.exit_code == 0, resumed.output
    assert read_experiment(out).trials == 3  # not the 20 of the built-in
    assert len(read_trials(out)) == 3 * 2 * 2
    grown = invoke("run", "smoke", "-o", out, "--resume", "--trials", "4", "--workers", "1")
    assert grown.exit_code == 0, grown.output
    assert len(read_trials(out)) == 4 * 2 * 2


def test_ctrl_c_says_how_to_resume_and_exits_130(tmp_path: Path) -> None:
    from comparison.engine import read_trials

    gate = tmp_path / "gate"
    gate.write_text("hold the run")
    estimators = ["cls", {"name": f"{HERE}:Held", "options": {"gate": str(gate)}}]
    definition = smoke_definition(tmp_path, trials=4, estimators=estimators)
    out = tmp_path / "run"
    process = subprocess.Popen(
        [*CONSOLE, "run", str(definition), "-o", str(out), "--workers", "1"],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT), HELD_RUN: "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # Ctrl-C as at a terminal, even when the tests run where SIGINT is ignored (a shell's
        # background job): an ignored SIGINT is inherited, and Python then never raises it
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        for _ in range(6000):  # polls 0.02 s apart (2 minutes): a bound, not a clock
            if (tmp_path / "gate.waiting").exists():
                break
            assert process.poll() is None, process.stderr.read()
            time.sleep(0.02)
        else:
            pytest.fail("the run did not reach the held estimator in 6000 polls 0.02 s apart")
        process.send_signal(signal.SIGINT)
        _, errors = process.communicate(timeout=120)
    finally:
        gate.unlink(missing_ok=True)
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130
    resume = f"emitterbench run {definition} -o {out} --resume"
    lines = errors.splitlines()  # stderr is not a terminal: progress lines, then the error
    assert [line for line in lines if not line.startswith("progress: ")] == [
        f"error: interrupted: the rows stored so far are kept; finish the run with `{resume}`"
    ]
    assert lines[-1].startswith("error: interrupted: ")
    finished = invoke("run", definition, "-o", out, "--resume", "--workers", "1")
    assert finished.exit_code == 0, finished.output
    assert len(read_trials(out)) == 4 * 2 * 2


# --------------------------------------------------------------------------------------------
# the edges a user meets first: usage once, names before flags, each flag by its name
# --------------------------------------------------------------------------------------------


def test_bare_emitterbench_prints_the_usage_once_and_exits_2() -> None:
    result = invoke()
    assert result.exit_code == 2  # click's status for a usage error
    assert (result.stdout + result.stderr).count("Usage: emitterbench") == 1


def test_an_unknown_scenario_is_said_before_a_missing_seed(tmp_path: Path) -> None:
    line = clean_error(invoke("simulate", "paper1m", "-o", tmp_path / "x.json"), "scenario: ")
    assert line.startswith("error: scenario: unknown name 'paper1m'; did you mean paper-1m")
    assert "--seed" not in line
    assert line.endswith("(see `emitterbench simulate --help`)")
    assert all(name in line for name in CATALOG)
    assert list(tmp_path.iterdir()) == []


def test_frames_below_one_names_the_flag_and_the_bound(tmp_path: Path) -> None:
    args = ("simulate", "paper-1m", "--seed", "1", "--frames", "0", "-o", tmp_path / "x.json")
    line = clean_error(invoke(*args), "--frames: ")
    assert "greater than or equal to 1" in line or "x>=1" in line  # typer's or click's words


def test_a_wrong_number_of_values_points_at_the_command_help(tmp_path: Path) -> None:
    path = simulated(tmp_path)
    line = clean_error(invoke("crlb", path, "--at", "30"), "--at: ")
    assert line == "error: --at: requires 2 arguments (see `emitterbench crlb --help`)"


def test_run_says_resume_the_way_the_user_asks_for_it(tmp_path: Path) -> None:
    from comparison.engine import run_experiment
    from comparison.experiment import load_experiment

    out = tmp_path / "run"
    assert invoke("run", "smoke", "-o", out, "--trials", "1", "--workers", "1").exit_code == 0
    line = clean_error(invoke("run", "smoke", "-o", out, "--trials", "1"), "--output: ")
    assert line == (
        f"error: --output: {out} already holds files; pass --resume to continue that run, or "
        "choose another folder"
    )
    with pytest.raises(ValueError) as raised:
        run_experiment(load_experiment("smoke"), out, trials=1, workers=1)
    assert str(raised.value) == (
        f"out_dir: {out} already holds files; pass resume=True to continue that run, or choose "
        "another folder"
    )


def test_flags_for_names_the_flags_of_a_library_message() -> None:
    from comparison.cli_support import flags_for

    with pytest.raises(ValueError) as raised, flags_for({"out_dir": "--output"}):
        raise ValueError("out_dir: x is a file; choose a folder")
    assert str(raised.value) == "--output: x is a file; choose a folder"
    with pytest.raises(ValueError) as raised, flags_for({"resume": "--resume"}):
        raise ValueError("results.sqlite: damaged; move it away and rerun with resume=True")
    assert str(raised.value) == "results.sqlite: damaged; move it away and rerun with --resume"
    with pytest.raises(ValueError) as raised, flags_for({"resume": "--resume"}):
        raise ValueError("resumed: not a field of the table")  # only the whole field
    assert str(raised.value) == "resumed: not a field of the table"


def estimate_table(path: Path, estimator: str, *extra: str) -> tuple[dict[str, Any], str]:
    """The JSON estimate and the summary's ``ambiguous`` line (a wide console: one line)."""
    args = ["estimate", str(path), "--estimator", estimator, *extra]
    out = json.loads(invoke(*args, "--json").stdout)
    table = runner.invoke(app, args, env={"COLUMNS": "300"})
    assert table.exit_code == 0, table.output
    (line,) = [line for line in table.stdout.splitlines() if line.startswith("ambiguous")]
    return out, " ".join(line.split()[1:])


def test_one_candidate_on_the_track_is_not_called_these_candidates(tmp_path: Path) -> None:
    from scenarios.geometry import cross_track_m, straight_track_line

    beacon = tmp_path / "b.json"
    assert invoke("simulate", "beacon-pass", "--seed", 1, "-o", beacon).exit_code == 0
    paper = simulated(tmp_path, "paper-1m", seed=1)
    on_track = (
        "yes: the side of the track cannot be told from these data; the single candidate lies "
        "on the track (MATH §7)"
    )
    for path, estimator, extra in (
        (beacon, "cls-paper", ("--ignore-unknowns",)),  # its last frame: a straight track
        (paper, "lls-rss", ()),
    ):
        out, text = estimate_table(path, estimator, *extra)
        assert out["ambiguous"] is True
        (candidate,) = out["candidates_m"]
        data = read_measurements(path).select_frames("last")
        origin, direction = straight_track_line(data.position_m, data.velocity_mps)
        assert abs(cross_track_m(np.array(candidate), origin, direction)) < 1e-6 * max(
            np.linalg.norm(np.array(candidate) - origin), 1.0
        )
        assert text == on_track, (estimator, text)
    out, text = estimate_table(paper, "cls")
    assert len(out["candidates_m"]) == 2
    assert text == "yes: the data cannot tell these 2 candidates apart (MATH §7)"


def test_a_lone_candidate_off_the_track_is_not_said_to_lie_on_it() -> None:
    from comparison.cli_views import ambiguity_text

    data = simulate(get_scenario("paper-1m"), seed=1)  # one straight frame along y = 0
    assert ambiguity_text([[35.0, 0.0]], data).endswith("lies on the track (MATH §7)")
    off = ambiguity_text([[35.0, 15.0]], data)
    assert (
        off
        == "yes: the side of the track cannot be told from these data, says the estimator (MATH §7)"
    )
    turned = simulate(get_scenario("turn"), seed=1)  # no straight track: the estimator's word
    assert ambiguity_text([[35.0, 0.0]], turned) == off


def help_text(*command: str) -> str:
    result = runner.invoke(app, [*command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return result.stdout


def help_words(*command: str) -> str:
    """The help as words one space apart, without the panels' frames."""
    return " ".join(help_text(*command).replace("│", " ").split())


COMMANDS = ("simulate", "estimate", "crlb", "fly", "list", "run", "report", "validate")


@pytest.mark.parametrize("command", ["", *COMMANDS])
def test_help_shows_flags_without_a_type_and_h_is_help(command: str) -> None:
    text = help_text(*filter(None, [command]))
    assert "<bool>" not in text and "list[" not in text
    short = runner.invoke(app, [*filter(None, [command]), "-h"], env={"COLUMNS": "200"})
    assert short.exit_code == 0 and short.stdout == text


def test_help_says_what_to_write_for_options_and_flags() -> None:
    assert "--resume Finish an interrupted run" in help_words("run")
    assert "--json Print exactly one JSON object" in help_words("estimate")
    assert "--option KEY=VALUE Estimator option, repeatable" in help_words("estimate")
    assert "--at X Y Emitter position, m [the truth in the file]" in help_words("crlb")


def test_validate_help_lists_the_families() -> None:
    from comparison.crosscheck import FAMILIES

    listed = f"--families NAME Instance family, repeatable: {', '.join(FAMILIES)} [all]"
    assert listed in help_words("validate")


def test_a_closed_stdout_ends_quietly() -> None:
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line: `emitterbench list | head -0`
    try:
        done = subprocess.run(
            [*CONSOLE, "list"],
            cwd=REPO_ROOT,
            env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
        )
    finally:
        os.close(write_end)
    assert done.stderr == ""
    assert done.returncode == 141  # 128 + SIGPIPE, as a shell reports `yes | head -0`


def test_each_flag_is_named_as_typed(tmp_path: Path) -> None:
    path = simulated(tmp_path)
    line = clean_error(
        invoke("fly", path, "-p", "paper", "--estimator-option", "x"), "--estimator-option: "
    )
    assert line == "error: --estimator-option: expected key=value, got 'x'"
    clean_error(
        invoke("simulate", "paper", "--seed", 1, "-o", tmp_path / "no" / "m.json"),
        f"--output: folder {tmp_path / 'no'} does not exist",
    )
    clean_error(invoke("run", "smoke", "-o", path), f"--output: {path} is a file; choose a folder")
    line = clean_error(invoke("validate", "-o", path, "--instances", 1), "--output: ")
    assert line == f"error: --output: {path} is a file; choose a folder for validate.json"
    line = clean_error(invoke("estimate", path, "--json", "extra"), "arguments: ")
    assert line.startswith("error: arguments: got unexpected extra argument(s) (extra)")


def test_report_of_a_missing_folder_says_so(tmp_path: Path) -> None:
    for absent in (tmp_path / "absent", simulated(tmp_path)):
        line = clean_error(invoke("report", absent), "run_dir: ")
        assert line == (
            f"error: run_dir: {absent} is not a folder; give the folder of a run "
            "(`emitterbench run EXPERIMENT -o DIR`)"
        )
