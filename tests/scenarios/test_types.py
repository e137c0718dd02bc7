"""The frozen data types validate themselves, name the bad field, and never change."""

from __future__ import annotations

import re
from dataclasses import FrozenInstanceError, replace

import numpy as np
import pytest

from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate_trials, trial_seeds
from scenarios.types import (
    FlightPlan,
    MeasurementBatch,
    MeasurementSet,
    NoiseSigmas,
    RssModel,
)


def raises_on(field: str):
    """``pytest.raises(ValueError)`` whose message starts with ``field:``."""
    return pytest.raises(ValueError, match="^" + re.escape(field) + ":")


def two_frame_plan() -> FlightPlan:
    return FlightPlan(
        start_position_m=[1.0, 2.0, 30.0],
        frame_velocities_mps=[[10.0, 0.0, 0.0], [0.0, 5.0, 1.0]],
        samples_per_frame=4,
        sample_interval_s=0.5,
    )


def measurement_kwargs(n: int = 3) -> dict:
    """A valid Doppler + ToA measurement set of ``n`` samples in one frame."""
    return {
        "frame": np.zeros(n, dtype=int),
        "time_s": np.arange(n, dtype=float),
        "position_m": np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.full(n, 50.0)]),
        "velocity_mps": np.tile([1.0, 0.0, 0.0], (n, 1)),
        "doppler_hz": np.ones(n),
        "toa_s": np.full(n, 2e-7),
        "carrier_hz": 1e9,
        "noise": NoiseSigmas(doppler_hz=0.1, toa_s=1e-9),
    }


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("position_m", {"position_m": [[0.0, 0.0, np.nan]] * 3}),
        ("position_m", {"position_m": np.zeros((3, 2))}),
        ("velocity_mps", {"velocity_mps": np.zeros((2, 3))}),
        ("velocity_mps", {"velocity_mps": [[1.0, 0.0, np.inf]] * 3}),
        ("time_s", {"time_s": [0.0, 1.0]}),
        ("doppler_hz", {"doppler_hz": [1.0, np.nan, 1.0]}),
        ("toa_s", {"toa_s": np.ones((3, 1))}),
        ("frame[1]", {"frame": [1, 0, 0]}),
        ("frame[1]", {"frame": [0, 0.5, 1]}),
        ("frame[0]", {"frame": [-1, 0, 0]}),
        ("carrier_hz", {"carrier_hz": 0.0}),
        ("speed_of_light_mps", {"speed_of_light_mps": -3e8}),
        ("emitter_height_m", {"emitter_height_m": np.nan}),
        ("noise.doppler_hz", {"noise": NoiseSigmas(toa_s=1e-9)}),
        ("noise.toa_s", {"noise": NoiseSigmas(doppler_hz=0.1)}),
        ("noise.rss_db", {"rss_dbm": np.zeros(3), "rss_model": RssModel()}),
        (
            "rss_model",
            {"rss_dbm": np.zeros(3), "noise": NoiseSigmas(doppler_hz=0.1, toa_s=1e-9, rss_db=4.0)},
        ),
        ("doppler_hz/toa_s/rss_dbm", {"doppler_hz": None, "toa_s": None}),
        ("truth.emitter_m", {"truth_emitter_m": [1.0, 2.0, 3.0]}),
    ],
)
def test_measurement_set_names_the_bad_field(field: str, change: dict) -> None:
    with raises_on(field):
        MeasurementSet(**(measurement_kwargs() | change))


@pytest.mark.parametrize("field", ["doppler_hz", "toa_s", "rss_db"])
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, np.inf, "loud"])
def test_noise_sigmas_must_be_positive_and_finite(field: str, value) -> None:
    with raises_on(f"noise.{field}"):
        NoiseSigmas(**{field: value})


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("flight.start_position_m", {"start_position_m": [0.0, 0.0]}),
        ("flight.start_position_m", {"start_position_m": [0.0, np.nan, 0.0]}),
        ("flight.frame_velocities_mps", {"frame_velocities_mps": [[1.0, 0.0]]}),
        ("flight.frame_velocities_mps", {"frame_velocities_mps": np.zeros((0, 3))}),
        ("flight.samples_per_frame", {"samples_per_frame": 0}),
        ("flight.samples_per_frame", {"samples_per_frame": 2.5}),
        ("flight.sample_interval_s", {"sample_interval_s": 0.0}),
    ],
)
def test_flight_plan_names_the_bad_field(field: str, change: dict) -> None:
    with raises_on(field):
        replace(two_frame_plan(), **change)


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("scenario.name", {"name": ""}),
        ("emitter_m", {"emitter_m": [1.0, 2.0, 0.0]}),
        ("emitter_m", {"emitter_m": [np.nan, 2.0]}),
        ("carrier_hz", {"carrier_hz": -1.0}),
        ("modalities", {"modalities": ("toa", "aoa")}),
        ("modalities", {"modalities": ()}),
        ("noise.rss_db", {"noise": NoiseSigmas(doppler_hz=0.1, toa_s=1e-9)}),
        ("rss_model.path_loss_exponent", {"rss_model": {"path_loss_exponent": 0.0}}),
        ("rss_model.reference_distance_m", {"rss_model": {"reference_distance_m": -1.0}}),
    ],
)
def test_scenario_names_the_bad_field(field: str, change: dict) -> None:
    scenario = get_scenario("paper-1m")
    with raises_on(field):
        if "rss_model" in change:
            RssModel(**change["rss_model"])
        else:
            scenario.replace(**change)


def test_scenario_without_rss_needs_no_rss_sigma() -> None:
    scenario = get_scenario("paper-1m").replace(
        noise=NoiseSigmas(doppler_hz=0.1, toa_s=1e-9), modalities=("toa", "doppler")
    )
    assert scenario.modalities == ("doppler", "toa")  # canonical order


def test_batch_needs_the_same_number_of_trials_per_modality() -> None:
    geometry = MeasurementSet(**measurement_kwargs())
    with raises_on("batch"):
        MeasurementBatch(
            geometry=geometry, doppler_hz=np.zeros((2, 3)), toa_s=np.zeros((3, 3)), rss_dbm=None
        )
    with raises_on("toa_s"):
        MeasurementBatch(
            geometry=geometry, doppler_hz=np.zeros((2, 3)), toa_s=np.zeros((2, 4)), rss_dbm=None
        )


# --------------------------------------------------------------------------------------------
# immutability
# --------------------------------------------------------------------------------------------


def test_arrays_are_read_only_copies() -> None:
    kwargs = measurement_kwargs()
    data = MeasurementSet(**kwargs)
    kwargs["position_m"][0, 0] = 99.0  # the caller's array changes, the data do not
    assert data.position_m[0, 0] == 0.0
    for name in ("frame", "time_s", "position_m", "velocity_mps", "doppler_hz", "toa_s"):
        array = getattr(data, name)
        assert not array.flags.writeable, name
        with pytest.raises(ValueError, match="read-only"):
            array[0] = array[0]
    with pytest.raises(FrozenInstanceError):
        data.carrier_hz = 2e9
    plan = two_frame_plan()
    assert not plan.frame_velocities_mps.flags.writeable
    assert not get_scenario("turn").emitter_m.flags.writeable
    batch = simulate_trials(get_scenario("turn"), snr_db=0.0, seeds=trial_seeds(0, 2))
    assert not batch.toa_s.flags.writeable
    assert not batch.trial(1).doppler_hz.flags.writeable


# --------------------------------------------------------------------------------------------
# views
# --------------------------------------------------------------------------------------------


def orbit_data() -> MeasurementSet:
    return noise_free(get_scenario("orbit"))


def test_select_frames() -> None:
    data = orbit_data()  # 12 frames of 10 samples
    assert data.select_frames("all") is data
    last = data.select_frames("last")
    np.testing.assert_array_equal(last.frame, np.full(10, 11))
    np.testing.assert_array_equal(last.position_m, data.position_m[110:])
    chosen = data.select_frames([0, 5])
    np.testing.assert_array_equal(chosen.frame, np.repeat([0, 5], 10))
    np.testing.assert_array_equal(
        chosen.toa_s, np.concatenate([data.toa_s[:10], data.toa_s[50:60]])
    )
    np.testing.assert_array_equal(chosen.truth_emitter_m, data.truth_emitter_m)
    with raises_on("frames"):
        data.select_frames("first")
    with raises_on("samples"):
        data.select_frames([99])


def test_up_to_frame_and_iter_frames() -> None:
    data = orbit_data()
    early = data.up_to_frame(2)
    assert early.n_samples == 30
    np.testing.assert_array_equal(early.doppler_hz, data.doppler_hz[:30])
    frames = list(data.iter_frames())
    assert len(frames) == 12
    for index, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.frame, np.full(10, index))
        np.testing.assert_array_equal(frame.rss_dbm, data.rss_dbm[10 * index : 10 * index + 10])
    np.testing.assert_array_equal(np.concatenate([f.position_m for f in frames]), data.position_m)


def test_without_removes_modalities() -> None:
    data = orbit_data()
    assert data.modalities == {"doppler", "toa", "rss"}
    assert data.without("rss", "toa").modalities == {"doppler"}
    assert data.without_truth().truth_emitter_m is None
    with raises_on("modalities"):
        data.without("aoa")


def test_batch_trial_is_one_row_of_every_modality() -> None:
    batch = simulate_trials(get_scenario("turn"), snr_db=0.0, seeds=trial_seeds(4, 3))
    assert len(batch) == batch.n_trials == 3
    for index, trial in enumerate(batch):
        np.testing.assert_array_equal(trial.doppler_hz, batch.doppler_hz[index])
        np.testing.assert_array_equal(trial.toa_s, batch.toa_s[index])
        np.testing.assert_array_equal(trial.rss_dbm, batch.rss_dbm[index])
        np.testing.assert_array_equal(trial.position_m, batch.geometry.position_m)
    assert not np.array_equal(batch.trial(0).toa_s, batch.trial(1).toa_s)


def test_sample_positions_follow_the_velocity_recursion() -> None:
    """``p_{n+1} = p_n + Δ v_n`` (paper Section 3), across the frame boundary too."""
    plan = two_frame_plan()
    positions = plan.sample_positions_m()
    velocities = plan.sample_velocities_mps()
    assert positions.shape == (8, 3)
    np.testing.assert_array_equal(positions[0], [1.0, 2.0, 30.0])
    np.testing.assert_allclose(positions[1:], positions[:-1] + 0.5 * velocities[:-1], atol=1e-12)
    # hand-computed: 4 samples east at 10 m/s (5 m apart), then 3 steps of (0, 2.5, 0.5)
    np.testing.assert_allclose(positions[3], [16.0, 2.0, 30.0])
    np.testing.assert_allclose(positions[4], [21.0, 2.0, 30.0])
    np.testing.assert_allclose(positions[7], [21.0, 9.5, 31.5])
    np.testing.assert_array_equal(plan.sample_frames(), [0, 0, 0, 0, 1, 1, 1, 1])
    np.testing.assert_allclose(plan.sample_times_s(), 0.5 * np.arange(8))


def test_flight_plan_extension() -> None:
    plan = two_frame_plan()
    assert plan.with_n_frames(1).n_frames == 1
    longer = plan.with_n_frames(4)
    np.testing.assert_array_equal(longer.frame_velocities_mps[2:], [[0.0, 5.0, 1.0]] * 2)
    added = plan.with_frame([3.0, 4.0, 0.0])
    assert added.n_samples == 12
    np.testing.assert_array_equal(added.frame_velocities_mps[-1], [3.0, 4.0, 0.0])
    with raises_on("frames"):
        plan.with_n_frames(0)


def test_noise_at_snr_scales_every_sigma() -> None:
    noise = NoiseSigmas(doppler_hz=0.1, toa_s=2e-9, rss_db=4.0).at_snr(20.0)
    assert noise.doppler_hz == pytest.approx(0.01, rel=1e-15)
    assert noise.toa_s == pytest.approx(2e-10, rel=1e-15)
    assert noise.rss_db == pytest.approx(0.4, rel=1e-15)
    assert NoiseSigmas(toa_s=1.0).at_snr(-6.0).doppler_hz is None
    assert get_scenario("paper").gamma_per_m == 1.0


def test_a_subset_of_samples_is_the_checked_subset_without_checking_again() -> None:
    """``take`` keeps the fields of a fresh MeasurementSet of those samples (which runs every
    check), read-only, and names the field of a mask of the wrong shape."""
    import dataclasses

    from scenarios.catalog import get_scenario
    from scenarios.simulate import simulate

    data = simulate(get_scenario("turn-noncooperative"), seed=3)
    mask = (data.frame == data.frame[-1]) & (np.arange(data.n_samples) % 2 == 0)
    subset = data.take(mask)
    fields = ("frame", "time_s", "position_m", "velocity_mps", "doppler_hz", "toa_s", "rss_dbm")
    fresh = dataclasses.replace(data, **{name: getattr(subset, name) for name in fields})
    for field in dataclasses.fields(MeasurementSet):
        np.testing.assert_array_equal(getattr(subset, field.name), getattr(fresh, field.name))
    assert not subset.position_m.flags.writeable and not subset.toa_s.flags.writeable
    assert data.n_samples == 20 and subset.n_samples == 5
    with pytest.raises(ValueError, match=r"^mask: expected shape \(20,\), got \(3,\)"):
        data.take(np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match=r"^samples: the selection is empty"):
        data.take(np.zeros(20, dtype=bool))
