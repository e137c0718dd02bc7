"""An experiment's estimator and planner entries (comparison.specs): a name is resolved to a
class with the interface before anything of it is called, and the options are checked against
its constructor before it is built. Names of functions (``os:system``, ``builtins:eval``) and
of classes without the interface run nothing; ``emitterbench run`` exits 2 with one line."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest
from typer.testing import CliRunner

import estimators.registry as registry
from comparison.cli import app
from comparison.experiment import Experiment
from comparison.specs import EstimatorSpec, option_error
from scenarios.catalog import get_scenario
from scenarios.files import write_measurements
from scenarios.planners import get_planner
from scenarios.simulate import simulate

HERE = __name__
BASE: dict[str, Any] = {"name": "specs", "scenarios": ["turn"], "trials": 1, "seed": 1}
CLOSED: dict[str, Any] = {**BASE, "frames": 3, "per_frame": True, "estimators": ["cls"]}
BUILT: list[str] = []
"""Class names whose constructor ran (the classes below append to it)."""

runner = CliRunner()


@pytest.fixture(autouse=True)
def _nothing_built_yet() -> None:
    BUILT.clear()


def toml_value(value: Any) -> str:
    """A TOML value (JSON strings, numbers, arrays and booleans are TOML too)."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return json.dumps(value)


def experiment_file(folder: Path, estimator: dict[str, Any]) -> Path:
    path = folder / "experiment.toml"
    lines = [f"{key} = {toml_value(value)}" for key, value in BASE.items()]
    lines += ["", "[[estimators]]", *(f"{k} = {toml_value(v)}" for k, v in estimator.items())]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def run_line(folder: Path, estimator: dict[str, Any]) -> str:
    """``emitterbench run`` on a file with ``estimator``: exit 2, no run folder; its one line."""
    out = folder / "out"
    result = runner.invoke(app, ["run", str(experiment_file(folder, estimator)), "-o", str(out)])
    assert result.exit_code == 2, result.output
    assert not out.exists()
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


def refused(raw: dict[str, Any]) -> str:
    with pytest.raises(ValueError) as info:
        Experiment.from_dict(raw)
    message = str(info.value)
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------------------------
# names that are not estimator classes run nothing
# --------------------------------------------------------------------------------------------


def test_os_system_is_refused_before_it_runs_its_command(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    line = run_line(tmp_path, {"name": "os:system", "options": {"command": f"touch {marker}"}})
    assert not marker.exists()
    assert line.startswith(
        "error: estimators[0].name: 'os:system' is a function, not an estimator class; give "
        "'package.module:Class' of a class with the class attributes name and requires and "
        "estimate(data, *, rng=None)"
    )


def test_subprocess_popen_is_a_class_without_the_interface_and_is_never_built(
    tmp_path: Path,
) -> None:
    marker = tmp_path / "marker"
    entry = {"name": "subprocess:Popen", "options": {"args": ["touch", str(marker)]}}
    line = run_line(tmp_path, entry)
    assert not marker.exists()
    assert line.startswith(
        "error: estimators[0].name: 'subprocess:Popen' is the class Popen, which lacks the "
        "estimator interface: the class attribute name must be a non-empty string"
    )


def test_os_remove_does_not_remove_the_file(tmp_path: Path) -> None:
    keep = tmp_path / "keep.txt"
    keep.write_text("still here", encoding="utf-8")
    line = run_line(tmp_path, {"name": "os:remove", "options": {"path": str(keep)}})
    assert keep.read_text(encoding="utf-8") == "still here"
    assert line.startswith(
        "error: estimators[0].name: 'os:remove' is a function, not an estimator class"
    )


def test_import_module_does_not_import_what_the_options_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    marker = tmp_path / "marker"
    (tmp_path / "specs_tripwire_module.py").write_text(
        f"from pathlib import Path\nPath({str(marker)!r}).touch()\n", encoding="utf-8"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    entry = {"name": "importlib:import_module", "options": {"name": "specs_tripwire_module"}}
    message = refused({**BASE, "estimators": [entry]})
    assert message.startswith(
        "estimators[0].name: 'importlib:import_module' is a function, not an estimator class; "
        "give 'package.module:Class' of a class with the class attributes name and requires"
    )
    assert not marker.exists()


@pytest.mark.parametrize(
    ("name", "what"),
    [
        ("builtins:eval", "a function"),
        ("builtins:exec", "a function"),
        ("os:sep", "a str object"),
        (f"{HERE}:BUILT", "a list object"),
    ],
)
def test_anything_but_a_class_is_refused_saying_what_it_is(name: str, what: str) -> None:
    message = refused({**BASE, "estimators": [{"name": name, "options": {"source": "1"}}]})
    assert message.startswith(f"estimators[0].name: '{name}' is {what}, not an estimator class")


def test_a_module_that_does_not_import_is_one_line() -> None:
    message = refused({**BASE, "estimators": ["no_such_package_for_specs.module:Thing"]})
    assert message.startswith(
        "estimators[0].name: cannot import 'no_such_package_for_specs.module' "
        "(ModuleNotFoundError: "
    )


class RngLess:
    """Has name and requires, but its estimate cannot take the runner's rng."""

    name = "rng-less"
    requires = frozenset({"toa"})

    def __init__(self) -> None:
        BUILT.append("RngLess")

    def estimate(self, data):
        raise AssertionError("never called")


class BadRequires:
    name = "bad-requires"
    requires = ("toa", "sonar")

    def __init__(self) -> None:
        BUILT.append("BadRequires")

    def estimate(self, data, *, rng=None):
        raise AssertionError("never called")


@pytest.mark.parametrize(
    ("cls", "problem"),
    [
        (RngLess, "estimate must take the keyword rng"),
        (BadRequires, "the class attribute requires must be a frozenset of doppler, toa, rss"),
    ],
)
def test_a_class_without_the_interface_is_never_built(cls: type, problem: str) -> None:
    name = f"{HERE}:{cls.__name__}"
    message = refused({**BASE, "estimators": [name]})
    assert message.startswith(
        f"estimators[0].name: '{name}' is the class {cls.__name__}, which lacks the estimator "
        f"interface: {problem}; give a class with"
    )
    assert BUILT == []


def test_an_entry_point_gets_the_same_checks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    marker = tmp_path / "marker"
    evil = registry.RegistryEntry("evil", "os:system", "plug-in from os:system")
    monkeypatch.setattr(registry, "plugin_entries", lambda: {"evil": evil})
    entry = {"name": "evil", "options": {"command": f"touch {marker}"}}
    message = refused({**BASE, "estimators": [entry]})
    assert message.startswith("estimators[0].name: 'evil' is a function, not an estimator class")
    assert not marker.exists()
    with pytest.raises(ValueError, match=r"^estimator: 'evil' is a function"):
        registry.make_estimator("evil", command=f"touch {marker}")
    assert not marker.exists()


def test_the_estimate_command_refuses_os_system(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    data = tmp_path / "m.json"
    write_measurements(simulate(get_scenario("turn"), seed=1, snr_db=20.0), data)
    option = f"command=touch {marker}"
    result = runner.invoke(
        app, ["estimate", str(data), "--estimator", "os:system", "--option", option]
    )
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().startswith(
        "error: estimator: 'os:system' is a function, not an estimator class"
    )
    assert not marker.exists()


# --------------------------------------------------------------------------------------------
# planners
# --------------------------------------------------------------------------------------------


def test_a_planner_named_os_system_runs_nothing(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    planner = {"name": "os:system", "options": {"command": f"touch {marker}"}}
    message = refused({**CLOSED, "planners": [planner]})
    assert message.startswith("planners[0].name: 'os:system' is a function, not a planner class")
    assert not marker.exists()


class PlanLess:
    name = "plan-less"

    def __init__(self) -> None:
        BUILT.append("PlanLess")


def test_a_planner_class_without_plan_is_never_built() -> None:
    message = refused({**CLOSED, "planners": [f"{HERE}:PlanLess"]})
    assert message.startswith(
        f"planners[0].name: '{HERE}:PlanLess' is the class PlanLess, which lacks the planner "
        "interface: the method plan is missing"
    )
    assert BUILT == []


# --------------------------------------------------------------------------------------------
# options, checked against the constructor before it runs
# --------------------------------------------------------------------------------------------


def test_a_nested_side_prior_is_refused_at_load_by_emitterbench_run(tmp_path: Path) -> None:
    line = run_line(tmp_path, {"name": "cls", "options": {"side_prior_m": [[[[1]]]]}})
    assert line == (
        "error: estimators[0].options.side_prior_m: expected (x, y) in metres or None, "
        "got [[[[1]]]]"
    )


@pytest.mark.parametrize(
    ("name", "options", "message"),
    [
        ("cls", {"side_prior_m": [1, "a"]}, "side_prior_m: expected (x, y) in metres or None"),
        ("cls", {"side_prior_m": [1, 2, 3]}, "side_prior_m: expected (x, y) in metres or None"),
        ("cls", {"weighting": "bogus"}, "weighting: expected 'optimal' or 'none', got 'bogus'"),
        ("cls", {"frames": 1}, "frames: expected 'all' or 'last', got 1"),
        ("ml", {"doppler_start": "yes"}, "doppler_start: expected true, false or 'auto'"),
        ("ml", {"max_nfev": 2.5}, "max_nfev: expected a whole number, got 2.5"),
        ("ml", {"use_rss": 1}, "use_rss: expected true or false, got 1"),
        ("ml", {"cost_rtol": "small"}, "cost_rtol: expected a number, got 'small'"),
        ("ml", {"cost_rtol": True}, "cost_rtol: expected a number, got True"),
        ("lls-rss", {"reference": ["mean"]}, "reference: expected 'strongest' or 'mean'"),
        ("cls", {"colour": "red"}, "colour: not an option of estimator 'cls'; its options: "),
    ],
)
def test_bad_options_are_refused_at_load_naming_the_option(
    name: str, options: dict[str, Any], message: str
) -> None:
    refusal = refused({**BASE, "estimators": [{"name": name, "options": options}]})
    assert refusal.startswith(f"estimators[0].options.{message}"), refusal


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"radius_m": "big"}, "radius_m: expected a number in metres, got 'big'"),
        ({"direction": "up"}, "direction: expected 'ccw' or 'cw', got 'up'"),
        ({"radius_m": -1}, "radius_m: must be finite and > 0"),  # the constructor's own check
        ({"radius": 3}, "radius: not an option of planner 'orbit'"),
    ],
)
def test_bad_planner_options_name_the_option(options: dict[str, Any], message: str) -> None:
    refusal = refused({**CLOSED, "planners": [{"name": "orbit", "options": options}]})
    assert refusal.startswith(f"planners[0].options.{message}"), refusal


def test_fisher_modalities_are_checked_item_by_item() -> None:
    planner = {"name": "fisher", "options": {"modalities": ["toa", 3]}}
    refusal = refused({**CLOSED, "planners": [planner]})
    assert refusal.startswith(
        "planners[0].options.modalities: expected a list, each a string, got ['toa', 3]"
    )


def test_good_options_of_every_simple_type_still_build() -> None:
    cls = EstimatorSpec(name="cls", options={"side_prior_m": [30, 10.5]}).build()
    assert cls.side_prior_m == (30, 10.5)
    ml = EstimatorSpec(name="ml", options={"doppler_start": "auto", "max_nfev": 50}).build()
    assert (ml.doppler_start, ml.max_nfev) == ("auto", 50)
    assert EstimatorSpec(name="ml", options={"doppler_start": True}).build().doppler_start is True
    assert EstimatorSpec(name="ml", options={"cost_rtol": 1}).build().cost_rtol == 1
    fisher = get_planner("fisher", modalities=("toa",), speed_mps=5)
    assert fisher.modalities == ("toa",) and fisher.speed_mps == 5


@dataclass(frozen=True, kw_only=True)
class NeedsGrid:
    """A required option without a default."""

    name: ClassVar[str] = "needs-grid"
    requires: ClassVar[frozenset[str]] = frozenset({"toa"})
    grid: int

    def __post_init__(self) -> None:
        BUILT.append("NeedsGrid")

    def estimate(self, data, *, rng=None):
        raise AssertionError("never called")


class TakesKwargs:
    """Options only through ``**kwargs``: not introspectable, so none is accepted."""

    name = "takes-kwargs"
    requires = frozenset({"toa"})

    def __init__(self, **options: Any) -> None:
        BUILT.append("TakesKwargs")
        self.options = options

    def estimate(self, data, *, rng=None):
        raise AssertionError("never called")


def test_a_missing_required_option_is_refused_before_building() -> None:
    name = f"{HERE}:NeedsGrid"
    refusal = refused({**BASE, "estimators": [name]})
    assert refusal == (
        f"estimators[0].options.grid: required by estimator '{name}'; add it to the options"
    )
    refusal = refused({**BASE, "estimators": [{"name": name, "options": {"grid": "fine"}}]})
    assert refusal == "estimators[0].options.grid: expected a whole number, got 'fine'"
    assert BUILT == []
    assert registry.make_estimator(name, grid=3).grid == 3
    assert BUILT == ["NeedsGrid"]


def test_kwargs_take_no_option_but_build_without_any() -> None:
    name = f"{HERE}:TakesKwargs"
    refusal = refused({**BASE, "estimators": [{"name": name, "options": {"anything": 1}}]})
    assert refusal == (
        f"estimators[0].options.anything: not an option of estimator '{name}'; its options: "
        "none (**options takes none: name each option in the constructor)"
    )
    assert BUILT == []
    assert registry.make_estimator(name).options == {}


def test_option_errors_name_the_option_only_when_they_start_with_one() -> None:
    names = ["frames", "side_prior_m"]
    assert option_error("e[0]", "frames: bad", names) == "e[0].options.frames: bad"
    assert (
        option_error("e[0]", "side_prior_m[1]: nan", names) == "e[0].options.side_prior_m[1]: nan"
    )
    assert option_error("e[0]", "options: rejected", names) == "e[0].options: options: rejected"
