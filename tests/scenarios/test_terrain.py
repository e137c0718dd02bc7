"""The terrain prior (MATH §8, scenarios/terrain.py): the surface, its files and its bound.

The information with a terrain is that of the augmented whitened model, the measurements'
rows ``h_k(s)/σ`` and the prior's ``(z_s − h(x_s, y_s))/σ_m``: checked against central
differences of that model, and in its two limits, σ_m → ∞ (no prior) and σ_m → 0 (the bound
constrained to the surface; for a level plane through the emitter the known-height bound).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from scenarios import get_scenario
from scenarios import measurement_model as model
from scenarios.catalog import HILL_TERRAIN_OFFSET_M
from scenarios.files import (
    measurements_from_dict,
    measurements_to_dict,
    read_measurements,
    write_measurements,
)
from scenarios.fisher import (
    fisher_information,
    fisher_information_per_frame,
    frame_statistics,
    inverse_symmetric,
    terrain_row,
    whitened_jacobian,
)
from scenarios.simulate import noise_free, simulate
from scenarios.terrain import (
    Terrain,
    offset_above_surface_m,
    offset_gradient,
    surface_gradient,
    surface_height_m,
)
from scenarios.types import MeasurementSet

SLOPED_HILL = Terrain(
    sigma_m=3.0,
    height_m=4.0,
    slope=[0.05, -0.12],
    hill_height_m=90.0,
    hill_centre_m=[180.0, 60.0],
    hill_width_m=70.0,
)


def hill_data(terrain: Terrain | None, snr_db: float = 0.0) -> MeasurementSet:
    """``hill``'s noise-free data (the height unknown) carrying ``terrain``."""
    return dataclasses.replace(noise_free(get_scenario("hill"), snr_db=snr_db), terrain=terrain)


def through(terrain: Terrain, point_m) -> Terrain:
    """``terrain`` moved up or down so that its surface passes through ``point_m``."""
    offset = float(offset_above_surface_m(terrain, point_m))
    return dataclasses.replace(terrain, height_m=terrain.height_m + offset)


def augmented_model(data: MeasurementSet, point_m) -> np.ndarray:
    """The whitened predictions of MATH §8 at ``point_m`` (x, y, z): Doppler and ToA of every
    sample over their σ, and last the prior's ``(z − h(x, y))/σ_m``."""
    p, v = data.position_m, data.velocity_mps
    doppler = model.doppler_hz(p, v, point_m, data.gamma_per_m) / data.noise.doppler_hz
    toa = model.toa_s(p, point_m, data.speed_of_light_mps) / data.noise.toa_s
    prior = offset_above_surface_m(data.terrain, point_m) / data.terrain.sigma_m
    return np.concatenate([toa, doppler, [prior]])


def central_differences(function, point_m, step_m: float = 1e-4) -> np.ndarray:
    point = np.asarray(point_m, dtype=float)
    columns = []
    for axis in np.eye(len(point)):
        forward, backward = function(point + step_m * axis), function(point - step_m * axis)
        columns.append((forward - backward) / (2.0 * step_m))
    return np.stack(columns, axis=-1)


# --------------------------------------------------------------------------------------------
# the surface
# --------------------------------------------------------------------------------------------


def test_the_surface_and_its_gradient_against_central_differences() -> None:
    rng = np.random.default_rng(5)
    xy = rng.uniform(0.0, 300.0, (20, 2))
    height = surface_height_m(SLOPED_HILL, xy[:, 0], xy[:, 1])
    centre = SLOPED_HILL.hill_centre_m
    bump = 90.0 * np.exp(-np.sum((xy - centre) ** 2, axis=1) / (2 * 70.0**2))
    np.testing.assert_allclose(height, 4.0 + 0.05 * xy[:, 0] - 0.12 * xy[:, 1] + bump, rtol=1e-14)
    step = 1e-3
    numeric = np.stack(
        [
            (
                surface_height_m(SLOPED_HILL, *(xy + step * axis).T)
                - surface_height_m(SLOPED_HILL, *(xy - step * axis).T)
            )
            / (2 * step)
            for axis in np.eye(2)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(
        surface_gradient(SLOPED_HILL, xy[:, 0], xy[:, 1]), numeric, rtol=1e-6
    )
    points = np.column_stack([xy, rng.uniform(0.0, 200.0, 20)])
    gradient = offset_gradient(SLOPED_HILL, points)
    np.testing.assert_allclose(gradient[:, 2], 1.0)
    np.testing.assert_allclose(gradient[:, :2], -numeric, rtol=1e-6)
    np.testing.assert_allclose(offset_above_surface_m(SLOPED_HILL, points), points[:, 2] - height)


def test_far_from_the_hill_the_surface_is_the_plane() -> None:
    far = 1e8
    assert surface_height_m(SLOPED_HILL, far, 0.0) == pytest.approx(4.0 + 0.05 * far, rel=1e-15)
    np.testing.assert_array_equal(surface_gradient(SLOPED_HILL, far, 0.0), [0.05, -0.12])


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"sigma_m": 0.0}, "terrain.sigma_m"),
        ({"sigma_m": float("nan")}, "terrain.sigma_m"),
        ({"height_m": 2e9}, "terrain.height_m"),
        ({"slope": [0.0, 1e3]}, "terrain.slope[1]"),
        ({"slope": [0.0]}, "terrain.slope"),
        ({"hill_centre_m": [0.0, float("inf")]}, "terrain.hill_centre_m"),
        ({"hill_width_m": 0.1}, "terrain.hill_width_m"),
        ({"hill_height_m": "high"}, "terrain.hill_height_m"),
    ],
)
def test_a_bad_terrain_is_refused_in_one_line_naming_the_field(change, field) -> None:
    numbers = {**SLOPED_HILL.as_dict(), **change}
    with pytest.raises(ValueError) as error:
        Terrain(**numbers)
    message = str(error.value)
    assert message.startswith(f"{field}: ") and "\n" not in message


def test_scenarios_and_data_hold_a_terrain_or_none() -> None:
    assert get_scenario("hill").terrain is None
    assert noise_free(get_scenario("hill")).terrain is None
    scenario = get_scenario("hill-terrain")
    data = simulate(scenario, snr_db=0.0, seed=1)
    assert data.terrain is scenario.terrain
    truth = data.truth_emitter_m
    assert offset_above_surface_m(data.terrain, truth) == pytest.approx(HILL_TERRAIN_OFFSET_M)
    assert data.terrain.sigma_m == 5.0
    assert np.linalg.norm(surface_gradient(data.terrain, *truth[:2])) > 0.5  # on a slope
    for build in (
        lambda: scenario.replace(terrain={"sigma_m": 5.0}),
        lambda: dataclasses.replace(data, terrain=5.0),
    ):
        with pytest.raises(ValueError, match=r"^terrain: expected a Terrain"):
            build()


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------


def test_a_file_round_trips_the_terrain(tmp_path: Path) -> None:
    data = simulate(get_scenario("hill-terrain"), snr_db=0.0, seed=2)
    path = write_measurements(data, tmp_path / "hill.json")
    assert json.loads(path.read_text())["terrain"] == data.terrain.as_dict()
    back = read_measurements(path)
    assert back.terrain.as_dict() == data.terrain.as_dict()
    np.testing.assert_array_equal(
        fisher_information(back, back.truth_emitter_m),
        fisher_information(data, data.truth_emitter_m),
    )
    obj = measurements_to_dict(noise_free(get_scenario("hill")))
    assert "terrain" not in obj and measurements_from_dict(obj).terrain is None
    obj["terrain"] = {"sigma_m": 2.0}
    assert measurements_from_dict(obj).terrain.as_dict() == Terrain(sigma_m=2.0).as_dict()


@pytest.mark.parametrize(
    ("terrain", "start"),
    [
        ({"height_m": 3.0}, "terrain.sigma_m: missing"),
        ({"sigma_m": 2.0, "slopes": [0, 0]}, "terrain.slopes: unknown key (did you mean 'slope'?)"),
        ({"sigma_m": -2.0}, "terrain.sigma_m: "),
        ({"sigma_m": 2.0, "hill_centre_m": [1.0]}, "terrain.hill_centre_m: expected 2 numbers"),
        ({"sigma_m": True}, "terrain.sigma_m: expected a number"),
        ([2.0], "terrain: expected an object"),
    ],
)
def test_a_bad_terrain_in_a_file_is_named(terrain, start) -> None:
    obj = measurements_to_dict(noise_free(get_scenario("hill")))
    obj["terrain"] = terrain
    with pytest.raises(ValueError) as error:
        measurements_from_dict(obj)
    assert str(error.value).startswith(start) and "\n" not in str(error.value)


# --------------------------------------------------------------------------------------------
# the bound
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["hill-terrain", "sloped"])
def test_the_information_is_that_of_the_augmented_model_by_central_differences(name) -> None:
    if name == "sloped":
        data = hill_data(SLOPED_HILL)
    else:
        data = noise_free(get_scenario(name), snr_db=0.0)
    truth = data.truth_emitter_m
    for point in (truth, truth + np.array([14.0, -9.0, -25.0])):
        numeric = central_differences(lambda s: augmented_model(data, s), point)
        np.testing.assert_allclose(fisher_information(data, point), numeric.T @ numeric, rtol=1e-6)
        rows = whitened_jacobian(data, point)
        np.testing.assert_allclose(np.abs(rows[-1]), np.abs(numeric[-1]), rtol=1e-6)


def test_every_frame_set_has_the_prior_once() -> None:
    data = noise_free(get_scenario("hill-terrain"), snr_db=0.0)
    truth = data.truth_emitter_m
    prior = terrain_row(data, truth, data.unknowns)[0]
    bare = dataclasses.replace(data, terrain=None)
    prior_information = np.outer(prior, prior)
    per_frame, accumulated = fisher_information_per_frame(data, truth)
    bare_per_frame, bare_accumulated = fisher_information_per_frame(bare, truth)
    np.testing.assert_allclose(per_frame, bare_per_frame + prior_information, rtol=1e-12)
    np.testing.assert_allclose(accumulated, bare_accumulated + prior_information, rtol=1e-12)
    np.testing.assert_allclose(accumulated[-1], fisher_information(data, truth), rtol=1e-12)
    statistics = frame_statistics(data, truth)
    np.testing.assert_allclose(statistics.information([]), prior_information, rtol=1e-15)
    np.testing.assert_allclose(
        statistics.information([1, 3]),
        fisher_information(data.select_frames([1, 3]), truth),
        rtol=1e-12,
    )


def test_with_the_height_known_the_terrain_is_not_used() -> None:
    data = noise_free(get_scenario("hill-terrain"), snr_db=0.0)
    bare = dataclasses.replace(data, terrain=None)
    truth = data.truth_emitter_m
    for unknowns in ((), ("carrier_offset_hz",)):
        np.testing.assert_array_equal(
            fisher_information(data, truth, unknowns=unknowns),
            fisher_information(bare, truth, unknowns=unknowns),
        )
    known = data.assuming_known()
    np.testing.assert_array_equal(
        fisher_information(known, truth[:2]), fisher_information(bare.assuming_known(), truth[:2])
    )
    assert terrain_row(data, truth[:2], data.unknowns) is None


def test_a_vague_prior_gives_the_bound_without_it() -> None:
    data = hill_data(SLOPED_HILL)
    truth = data.truth_emitter_m
    bare = inverse_symmetric(fisher_information(dataclasses.replace(data, terrain=None), truth))
    vague = dataclasses.replace(SLOPED_HILL, sigma_m=1e6)
    np.testing.assert_allclose(
        inverse_symmetric(fisher_information(hill_data(vague), truth)), bare, rtol=1e-6
    )


def test_an_exact_level_ground_gives_the_known_height_bound() -> None:
    """σ_m → 0 for the level plane through the emitter: the horizontal bound is that with the
    height known (at the true height), the vertical one σ_m."""
    data = hill_data(None)
    truth = data.truth_emitter_m
    known = inverse_symmetric(fisher_information(data, truth, unknowns=())[:2, :2])
    level = Terrain(sigma_m=1e-6, height_m=truth[2])
    bound = inverse_symmetric(fisher_information(hill_data(level), truth))
    np.testing.assert_allclose(bound[:2, :2], known, rtol=1e-6)
    assert np.sqrt(bound[2, 2]) == pytest.approx(1e-6, rel=1e-6)


def test_an_exact_sloped_ground_gives_the_bound_constrained_to_it() -> None:
    """σ_m → 0 for a sloped plane through the emitter: the constrained CRLB ``U (Uᵀ J U)⁻¹ Uᵀ``
    with ``U = [I; g]`` the plane's tangent (Stoica & Ng 1998), not the known-height bound; the
    gap closes as σ_m² (below σ_m ≈ 1e-4 m here the 3 × 3 information is too ill-conditioned
    for the regularity rule of MATH §8)."""
    data = hill_data(None)
    truth = data.truth_emitter_m
    slope = np.array([0.3, -0.2])
    tangent = np.vstack([np.eye(2), slope])
    information = fisher_information(data, truth)
    constrained = tangent @ np.linalg.inv(tangent.T @ information @ tangent) @ tangent.T
    gaps = []
    for sigma_m in (1e-2, 1e-3):
        plane = through(Terrain(sigma_m=sigma_m, slope=slope), truth)
        bound = inverse_symmetric(fisher_information(hill_data(plane), truth))
        gaps.append(np.abs(bound - constrained).max() / np.abs(constrained).max())
    assert gaps[1] < 2e-6
    assert gaps[0] / gaps[1] == pytest.approx(100.0, rel=1e-2)
    known = inverse_symmetric(fisher_information(data, truth, unknowns=())[:2, :2])
    assert not np.allclose(constrained[:2, :2], known, rtol=1e-2)
