"""Tests of comparison.experiment: loading, validation with key paths, exact serialisation."""

import copy
import json
import pickle
import textwrap

import pytest

import comparison.experiment as experiment_module
from comparison.experiment import (
    EstimatorSpec,
    Experiment,
    Sweep,
    builtin_experiment,
    load_experiment,
)
from comparison.experiment_catalog import BUILTIN_EXPERIMENTS

BASE = {
    "name": "unit",
    "scenarios": ["paper-1m"],
    "sweep": {"parameter": "snr_db", "values": [0, 10]},
    "estimators": [{"name": "cls"}, {"name": "cls-paper"}],
    "trials": 3,
    "seed": 1,
}


def modified(**changes):
    raw = copy.deepcopy(BASE)
    raw.update(changes)
    return raw


def docstring_example() -> str:
    """The complete TOML example of the module docstring."""
    doc = experiment_module.__doc__
    start = doc.index("A complete example")
    block = doc[doc.index("::", start) + 2 : doc.index("``estimators = [", start)]
    return textwrap.dedent(block).strip() + "\n"


def test_builtin_paper_fig2():
    experiment = load_experiment("paper-fig2")
    assert experiment.scenarios == ("paper", "paper-1m", "paper-10m")
    assert experiment.sweep.parameter == "snr_db"
    assert experiment.sweep.values == tuple(float(v) for v in range(-10, 31, 5))
    assert experiment.labels == (
        "lls-rss",
        "lls-toa",
        "cls-as-printed",
        "cls-paper",
        "cls",
        "sdp-cls",
        "ml",
    )
    assert experiment.trials == 500
    assert experiment.frames == 1
    assert experiment.swept_columns == ()


def test_builtin_frames_experiment_evaluates_every_frame():
    experiment = load_experiment("frames")
    assert experiment.scenarios == ("paper-1m-turn", "paper-1m")
    assert experiment.frames == 10 and experiment.per_frame
    assert experiment.labels == ("cls-last", "cls-all", "ml-all", "ekf", "gtsam-smoother")


def test_builtin_geometry_map_is_a_grid_beside_the_track():
    experiment = builtin_experiment("geometry-map")
    sweep = experiment.sweep
    assert experiment.scenarios == ("paper-1m",)
    assert experiment.labels == ("cls", "ml", "lls-toa")
    assert experiment.trials == 100
    assert experiment.swept_columns == ("emitter_x_m", "emitter_y_m")
    assert sweep.fixed == {"snr_db": 10.0}
    points = sweep.points()
    assert len(points) == sweep.n_points == 11 * 7
    # point p = (x[p // len(y)], y[p % len(y)])
    assert points[0] == {"snr_db": 10.0, "emitter_x_m": -40.0, "emitter_y_m": 5.0}
    assert points[8] == {"snr_db": 10.0, "emitter_x_m": -30.0, "emitter_y_m": 15.0}
    assert min(p["emitter_y_m"] for p in points) == 5.0  # the track is at y = 0
    scenario, snr_db = experiment.point_scenario(0, 8)
    assert list(scenario.emitter_m) == [-30.0, 15.0]
    assert snr_db == 10.0


def test_smoke_is_small():
    experiment = load_experiment("smoke")
    assert experiment.labels == ("cls", "cls-paper")
    assert experiment.sweep.n_points == 2
    assert experiment.trials == 20


@pytest.mark.parametrize("name", sorted(BUILTIN_EXPERIMENTS))
def test_json_round_trip_is_exact(name):
    experiment = load_experiment(name)
    text = experiment.to_json()
    again = Experiment.from_json(text)
    assert again == experiment
    assert again.to_json() == text
    assert pickle.loads(pickle.dumps(experiment)) == experiment
    assert hash(again) == hash(experiment)


def test_docstring_example_loads_from_a_toml_file(tmp_path):
    path = tmp_path / "example.toml"
    path.write_text(docstring_example())
    experiment = load_experiment(path)
    assert experiment.name == "snr-sweep"
    assert experiment.scenarios == ("paper-1m", "paper-10m")
    assert experiment.sweep.values == (-10.0, 0.0, 10.0, 20.0, 30.0)
    assert experiment.sweep.fixed == {"range_sigma_m": 1.0}
    assert experiment.swept_columns == ()
    assert experiment.labels == ("cls", "ml-rss")
    assert experiment.estimators[1].options == {"use_rss": True}
    assert experiment.metrics == ("rmse_m", "efficiency")
    assert experiment.frames == 1
    assert experiment.chunk_size == "auto"
    assert Experiment.from_json(experiment.to_json()) == experiment
    # a fixed range_sigma_m reaches the point's scenario: c σ_τ = 1 m with c = 3e8
    scenario, _ = experiment.point_scenario(1, 0)
    assert scenario.noise.toa_s == 1.0 / 3.0e8


def test_estimator_shorthand_and_default_label():
    short = Experiment.from_dict(modified(estimators=["cls", "cls-paper"]))
    assert short == Experiment.from_dict(BASE)
    assert short.estimators[0] == EstimatorSpec(name="cls", label="cls", options={})


def test_same_estimator_twice_with_distinct_labels():
    experiment = Experiment.from_dict(
        modified(
            estimators=[
                {"name": "cls"},
                {"name": "cls", "label": "cls-unweighted", "options": {"weighting": "none"}},
            ]
        )
    )
    assert experiment.labels == ("cls", "cls-unweighted")
    assert experiment.estimators[1].build().weighting == "none"


def test_sweep_without_parameter_is_one_point_of_fixed_values():
    experiment = Experiment.from_dict(modified(sweep={"fixed": {"snr_db": 5, "frames": 2}}))
    assert experiment.sweep.points() == [{"snr_db": 5.0, "frames": 2.0}]
    assert experiment.point_scenario(0, 0)[0].flight.n_frames == 2
    assert Experiment.from_dict(modified(sweep={})).sweep.points() == [{"snr_db": 0.0}]


def test_range_sigma_sweep_columns():
    experiment = Experiment.from_dict(
        modified(sweep={"parameter": "range_sigma_m", "values": [1, 10], "fixed": {"snr_db": 0}})
    )
    assert experiment.swept_columns == ("range_sigma_m",)
    assert experiment.sweep.points()[1] == {"snr_db": 0.0, "range_sigma_m": 10.0}


@pytest.mark.parametrize(
    ("changes", "prefix"),
    [
        ({"trails": 3}, "trails: unknown key"),
        ({"sweep": {"parameter": "snr_db", "valuez": [1]}}, "sweep.valuez: unknown key"),
        ({"sweep": {"parameter": "snr", "values": [1]}}, "sweep.parameter: unknown 'snr'"),
        ({"sweep": {"parameter": "snr_db", "values": []}}, "sweep.values: give at least one"),
        ({"sweep": {"parameter": "snr_db", "values": [0, "ten"]}}, "sweep.values[1]: expected"),
        ({"sweep": {"parameter": "snr_db", "values": [120]}}, "sweep.values[0]: snr_db must lie"),
        ({"sweep": {"parameter": "snr_db", "values": [-61]}}, "sweep.values[0]: snr_db must lie"),
        ({"sweep": {"parameter": "snr_db", "values": [5, 5]}}, "sweep.values[1]: 5 repeats"),
        (
            {"sweep": {"parameter": "range_sigma_m", "values": [1, -1]}},
            "sweep.values[1]: range_sigma_m: must be > 0",
        ),
        (
            {"sweep": {"parameter": "snr_db", "values": [0], "fixed": {"doppler_sigma_hz": -0.1}}},
            "sweep.fixed.doppler_sigma_hz: doppler_sigma_hz: must be > 0",
        ),
        (
            {"sweep": {"parameter": "snr_db", "values": [0], "fixed": {"snr_db": 3}}},
            "sweep.fixed.snr_db: is also swept",
        ),
        (
            {"sweep": {"parameter": "snr_db", "values": [0], "fixed": {"heading": 3}}},
            "sweep.fixed.heading: unknown parameter",
        ),
        ({"sweep": {"parameter": "emitter_m", "x": [1, 2]}}, "sweep.y: the emitter_m grid"),
        ({"sweep": {"parameter": "frames", "values": [1, 2.5]}}, "sweep.values[1]: frames:"),
        ({"scenarios": ["paper-1m", "paper-2m"]}, "scenarios[1]: unknown scenario 'paper-2m'"),
        ({"scenarios": ["paper-1m", "paper-1m"]}, "scenarios[1]: 'paper-1m' is listed twice"),
        ({"scenarios": []}, "scenarios: give at least one"),
        (
            {"estimators": [{"name": "cls"}, {"name": "clss"}]},
            "estimators[1].name: unknown name 'clss'",
        ),
        (
            {"estimators": [{"name": "cls", "options": {"weighting": "bogus"}}]},
            "estimators[0].options.weighting: expected 'optimal' or 'none'",
        ),
        (
            {"estimators": [{"name": "cls", "options": {"colour": "red"}}]},
            "estimators[0].options.colour: not an option of estimator 'cls'",
        ),
        ({"estimators": [{"name": "cls", "optoins": {}}]}, "estimators[0].optoins: unknown key"),
        (
            {"estimators": [{"name": "cls"}, {"name": "cls-paper", "label": "cls"}]},
            "estimators[1].label: duplicate label 'cls' (also estimators[0])",
        ),
        ({"estimators": []}, "estimators: give at least one"),
        ({"trials": 0}, "trials: must be a whole number >= 1"),
        ({"trials": 2.5}, "trials: expected a whole number"),
        ({"seed": -1}, "seed: must be a whole number >= 0"),
        ({"frames": 0}, "frames: must be a whole number >= 1"),
        ({"chunk_size": 0}, "chunk_size: must be a whole number >= 1"),
        ({"per_frame": "yes"}, "per_frame: expected true or false"),
        ({"metrics": ["rmse_m", "rmse"]}, "metrics[1]: unknown metric 'rmse'"),
        ({"swept_columns": ["snr_db"]}, "swept_columns:"),
        (
            {"estimators": [{"name": f"{__name__}:NoRng"}]},
            "estimators[0].name: 'tests.comparison.test_experiment:NoRng' is the class NoRng, "
            "which lacks the estimator interface: estimate must take the keyword rng",
        ),
        (
            {"estimators": [{"name": f"{__name__}:NeedsGhost"}]},
            "estimators[0]: 'tests.comparison.test_experiment:NeedsGhost' needs the module(s) "
            "no_such_backend",
        ),
    ],
)
def test_malformed_experiments_name_the_key_path(changes, prefix):
    with pytest.raises(ValueError) as info:
        Experiment.from_dict(modified(**changes))
    assert str(info.value).startswith(prefix), str(info.value)


class NoRng:
    """An estimator whose ``estimate`` takes no ``rng``: the runner could not break ties."""

    name = "no-rng"
    requires = frozenset({"toa"})

    def estimate(self, data):
        raise AssertionError("never called")


class NeedsGhost:
    """Declares a module that is not installed."""

    name = "needs-ghost"
    requires = frozenset({"toa"})
    required_modules = ("no_such_backend",)

    def estimate(self, data, *, rng=None):
        raise AssertionError("never called")


def test_missing_required_key():
    raw = modified()
    del raw["seed"]
    with pytest.raises(ValueError, match=r"^seed: missing"):
        Experiment.from_dict(raw)


def test_a_malformed_file_fails_at_load(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(
        docstring_example().replace('name = "ml"', 'name = "mll"'),
    )
    with pytest.raises(ValueError, match=r"^estimators\[1\]\.name: unknown name 'mll'"):
        load_experiment(path)
    path.write_text("name = \n")
    with pytest.raises(ValueError, match=r"^experiment: .*not valid TOML"):
        load_experiment(path)
    with pytest.raises(ValueError, match=r"^experiment: .*absent\.toml: no such file"):
        load_experiment(tmp_path / "absent.toml")


def test_unknown_builtin_lists_the_builtins():
    with pytest.raises(ValueError, match=r"^experiment: 'fig2' is neither a built-in") as info:
        load_experiment("fig2")
    for name in BUILTIN_EXPERIMENTS:
        assert name in str(info.value)


def test_direct_construction_validates_too():
    with pytest.raises(ValueError, match=r"^estimators\[0\]\.name"):
        Experiment(
            name="x",
            scenarios=("paper",),
            estimators=(EstimatorSpec(name="nope"),),
            trials=1,
            seed=0,
        )
    with pytest.raises(ValueError, match=r"^values\[0\]: snr_db must lie"):
        Sweep(parameter="snr_db", values=(200.0,))


def test_options_are_frozen():
    spec = EstimatorSpec(name="cls", options={"side_prior_m": [30.0, 10.0]})
    assert spec.options["side_prior_m"] == (30.0, 10.0)
    with pytest.raises(TypeError):
        spec.options["side_prior_m"] = (0.0, 0.0)
    assert spec.to_dict()["options"] == {"side_prior_m": [30.0, 10.0]}
    assert spec.build().side_prior_m == (30.0, 10.0)


# --------------------------------------------------------------------------------------------
# closed loop: planners
# --------------------------------------------------------------------------------------------

CLOSED = {**BASE, "frames": 3, "per_frame": True, "planners": ["constant", "fisher"]}


def test_builtin_paper_fig3_is_a_closed_loop():
    experiment = load_experiment("paper-fig3")
    assert experiment.is_closed_loop and experiment.per_frame and experiment.frames == 10
    assert experiment.scenarios == ("paper-1m", "paper-10m")
    assert experiment.planner_labels == ("constant", "paper", "fisher", "orbit")
    assert experiment.labels == ("ml", "cls-last")
    assert [experiment.steering_label(k) for k in range(4)] == ["ml"] * 4
    assert experiment.trials == 300
    assert [spec.options for spec in experiment.estimators] == [
        {"frames": "all"},
        {"frames": "last"},
    ]


def test_open_loop_json_has_no_planner_keys():
    raw = load_experiment("frames").to_dict()
    assert "planners" not in raw and "steering_estimator" not in raw
    assert not load_experiment("frames").is_closed_loop


def test_planner_shorthand_labels_and_own_steering():
    experiment = Experiment.from_dict(
        {
            **CLOSED,
            "planners": [
                "paper",
                {"name": "paper", "label": "paper-literal", "options": {"tie": "literal"}},
                {"name": "orbit", "steering_estimator": "cls-paper"},
            ],
            "steering_estimator": "cls",
        }
    )
    assert experiment.planner_labels == ("paper", "paper-literal", "orbit")
    assert [experiment.steering_label(k) for k in range(3)] == ["cls", "cls", "cls-paper"]
    assert experiment.planners[1].build().tie == "literal"
    again = Experiment.from_json(experiment.to_json())
    assert again == experiment and again.to_json() == experiment.to_json()


@pytest.mark.parametrize(
    ("changes", "prefix"),
    [
        ({"per_frame": False}, "per_frame: a closed loop estimates after every frame"),
        ({"planners": ["constant", "orbits"]}, "planners[1].name: unknown name 'orbits'"),
        (
            {"planners": [{"name": "orbit", "options": {"radius_m": -1}}]},
            "planners[0].options.radius_m: must be finite and > 0",
        ),
        ({"planners": [{"name": "orbit", "radius_m": 3}]}, "planners[0].radius_m: unknown key"),
        (
            {"planners": ["paper", {"name": "fisher", "label": "paper"}]},
            "planners[1].label: duplicate label 'paper' (also planners[0])",
        ),
        ({"steering_estimator": "ml"}, "steering_estimator: 'ml' is not an estimator label"),
        (
            {"planners": [{"name": "paper", "steering_estimator": "ekf"}]},
            "planners[0].steering_estimator: 'ekf' is not an estimator label",
        ),
        ({"planners": "paper"}, "planners: expected a list"),
    ],
)
def test_malformed_closed_loops_name_the_key_path(changes, prefix):
    with pytest.raises(ValueError) as info:
        Experiment.from_dict({**CLOSED, **changes})
    assert str(info.value).startswith(prefix), str(info.value)


def test_steering_without_planners_is_an_error():
    with pytest.raises(ValueError, match=r"^steering_estimator: only a closed loop steers"):
        Experiment.from_dict({**BASE, "steering_estimator": "cls"})


# --------------------------------------------------------------------------------------------
# resource limits, every point flown at load, files read within the parsing limits
# --------------------------------------------------------------------------------------------


def test_trials_beyond_the_limit_are_refused_and_a_variable_raises_it(monkeypatch):
    message = (
        "trials: 1,000,000,000,000 trials per point, more than the limit of 1,000,000; ask for "
        "fewer, or raise the limit with the environment variable EMITTERBENCH_MAX_TRIALS=N"
    )
    with pytest.raises(ValueError) as info:
        Experiment.from_dict(modified(trials=10**12))
    assert str(info.value) == message
    monkeypatch.setenv("EMITTERBENCH_MAX_TRIALS", str(2 * 10**6))
    assert Experiment.from_dict(modified(trials=1_500_000)).trials == 1_500_000


@pytest.mark.parametrize(
    ("changes", "prefix"),
    [
        ({"trials": 10**4000}, "trials: about 10^4000 trials per point, more than the limit"),
        ({"trials": -(10**4000)}, "trials: must be a whole number >= 1, got about -10^4000"),
        ({"trials": 1e300}, "trials: about 10^300 trials per point"),
        ({"frames": 10**8}, "frames: 100,000,000 frames, more than the limit of 10,000"),
        ({"chunk_size": 10**12}, "chunk_size: 1,000,000,000,000 trials per task"),
        (
            {"sweep": {"parameter": "snr_db", "values": list(range(10_001))}},
            "sweep.values: 10,001 values, more than the limit of 10,000",
        ),
        (
            {"sweep": {"parameter": "emitter_m", "x": list(range(200)), "y": list(range(1, 201))}},
            "sweep: 40,000 points, more than the limit of 10,000",
        ),
        (
            {"sweep": {"parameter": "frames", "values": [1, 10**8]}},
            "sweep.values[1]: 100,000,000 frames, more than the limit",
        ),
        (
            {"sweep": {"parameter": "samples_per_frame", "values": [10**9]}},
            "sweep.values[0]: 1,000,000,000 samples per frame, more than the limit",
        ),
        (
            {"frames": 10_000, "sweep": {"parameter": "samples_per_frame", "values": [10, 20]}},
            "sweep.values[1]: point 1 of the sweep cannot be flown in scenarios[0] (paper-1m): "
            "samples: 200,000 samples per trial, more than the limit of 100,000",
        ),
        (
            {"trials": 10**6, "sweep": {"parameter": "snr_db", "values": list(range(-50, 100))}},
            "trials: 300,000,000 estimates (1,000,000 trials × 150 points × 2 estimators), more "
            "than the limit of 100,000,000",
        ),
        (
            {"frames": 1000, "chunk_size": 10_000, "trials": 10_000},
            "chunk_size: 10,000 trials of 10,000 samples, 100,000,000 samples simulated at once",
        ),
    ],
    ids=lambda value: "" if isinstance(value, dict) else value.split(":")[0],
)
def test_requests_beyond_the_resource_limits_are_refused_at_load(changes, prefix):
    with pytest.raises(ValueError) as info:
        Experiment.from_dict(modified(**changes))
    assert str(info.value).startswith(prefix), str(info.value)


def test_a_repeated_value_far_down_a_long_sweep_is_found():
    sweep = {"parameter": "emitter_x_m", "values": [*range(5000), 0]}
    with pytest.raises(ValueError, match=r"^sweep\.values\[5000\]: 0 repeats values\[0\]"):
        Experiment.from_dict(modified(sweep=sweep))


@pytest.mark.parametrize(
    ("sweep", "prefix"),
    [
        ({"parameter": "emitter_x_m", "values": [30, 1e160]}, r"sweep\.values\[1\]: point 1 "),
        ({"parameter": "emitter_m", "x": [0, 1e200], "y": [15]}, r"sweep\.x\[1\]: point 1 "),
        ({"parameter": "emitter_m", "x": [0], "y": [15, -1e200]}, r"sweep\.y\[1\]: point 1 "),
        ({"fixed": {"speed_mps": 1e200}}, r"sweep\.fixed\.speed_mps: point 0 "),
        (
            {"parameter": "snr_db", "values": [0, -60], "fixed": {"doppler_sigma_hz": 1e28}},
            r"sweep: point 1 of the sweep cannot be flown in scenarios\[0\] \(paper-1m\): snr_db",
        ),
    ],
)
def test_every_point_is_flown_at_load_naming_the_key_to_fix(sweep, prefix):
    with pytest.raises(ValueError, match=f"^{prefix}"):
        Experiment.from_dict(modified(sweep=sweep))


def test_experiment_files_are_read_within_the_parsing_limits(tmp_path):
    toml = tmp_path / "e.toml"
    text = "\n".join(["name = 'limits'", "scenarios = ['paper-1m']", "estimators = ['cls']"])
    toml.write_text(text + f"\ntrials = {'9' * 5000}\nseed = 1\n")
    with pytest.raises(
        ValueError, match=r"^trials: an integer of 5000 digits \(.*e\.toml, line 4\)"
    ):
        load_experiment(toml)
    toml.write_text(text + "\ntrials = 3\nseed = 1\n[sweep]\nvalues = " + "[" * 5000 + "]" * 5000)
    with pytest.raises(ValueError, match=r"^experiment: .*e\.toml: arrays and objects nest more"):
        load_experiment(toml)
    toml.write_bytes(b"\xef\xbb\xbf" + (text + "\ntrials = 3\nseed = 1\n").encode())
    assert load_experiment(toml).trials == 3  # a byte order mark is no error
    toml.write_bytes(b"#" * 2**20 + b"\n" + (text + "\ntrials = 3\nseed = 1\n").encode())
    with pytest.raises(ValueError, match=r"^experiment: .*e\.toml: larger than the limit of 1 MiB"):
        load_experiment(toml)
    as_json = tmp_path / "e.json"
    raw = json.dumps(modified())
    as_json.write_text("\ufeff" + raw.replace('"trials": 3', f'"trials": {"9" * 5000}'))
    with pytest.raises(ValueError, match=r"^trials: expected a whole number, got an integer of"):
        load_experiment(as_json)
    nested = {"name": "cls", "options": {"side_prior_m": json.loads("[" * 40 + "]" * 40)}}
    as_json.write_text(json.dumps(modified(estimators=[nested])))
    with pytest.raises(ValueError, match=r"^estimators\[0\]\.options\.side_prior_m: arrays"):
        load_experiment(as_json)
