"""The closed-form Doppler-ToA CLS (MATH §3-§6): exact answers, invariances, efficiency."""

from __future__ import annotations

import numpy as np
import pytest

from comparison.crlb import fisher_information, rmse_bound_m
from estimators.checks.invariance import in_kilometres
from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper
from estimators.registry import make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from scenarios.types import FlightPlan, Scenario


def sorted_rows(points: np.ndarray) -> np.ndarray:
    """Candidates in a canonical order (by y, then x) so that sets compare row by row."""
    points = np.asarray(points)
    return points[np.lexsort((points[:, 0], points[:, 1]))]


# --------------------------------------------------------------------------------------------
# noise-free answers
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "paper-1m"])
@pytest.mark.parametrize("estimator", [Cls(), ClsPaper()])
def test_noise_free_straight_frame_returns_emitter_and_its_mirror(name, estimator) -> None:
    """One straight frame along y = 0: candidates (35, 15) and its mirror (35, −15) (MATH §7)."""
    data = noise_free(get_scenario(name))
    estimate = estimator.estimate(data)
    assert estimate.success
    assert estimate.ambiguous
    np.testing.assert_allclose(
        sorted_rows(estimate.candidates_m), [[35.0, -15.0], [35.0, 15.0]], atol=1e-6
    )
    assert estimate.diagnostics["hard_case"]
    assert estimate.diagnostics["rank"] == 2


@pytest.mark.parametrize("name", ["turn", "orbit"])
@pytest.mark.parametrize("estimator", [Cls(), ClsPaper(frames="all")])
def test_noise_free_turn_and_orbit_return_the_emitter_alone(name, estimator) -> None:
    """A second heading removes the mirror (MATH §7): one candidate, the truth."""
    scenario = get_scenario(name)
    estimate = estimator.estimate(noise_free(scenario))
    assert estimate.success
    assert not estimate.ambiguous
    assert estimate.candidates_m.shape == (1, 2)
    np.testing.assert_allclose(estimate.position_m, scenario.emitter_m, atol=1e-6)
    assert estimate.diagnostics["rank"] == 3


@pytest.mark.parametrize("estimator", [Cls(), Cls(weighting="none"), ClsPaper()])
def test_noise_free_emitter_in_the_track_plane(estimator) -> None:
    """Emitter at (35, 0), under the track: the least-squares line touches the paraboloid, the
    two mirror points merge (to √rounding) and no warning is raised (pyproject turns warnings
    from ``estimators`` into errors)."""
    data = noise_free(get_scenario("paper-1m").replace(emitter_m=[35.0, 0.0]))
    estimate = estimator.estimate(data)
    assert estimate.success
    np.testing.assert_allclose(
        estimate.candidates_m, [[35.0, 0.0]] * len(estimate.candidates_m), atol=1e-5
    )


def test_side_prior_picks_the_nearer_mirror_candidate() -> None:
    data = noise_free(get_scenario("paper-1m"))
    for prior in ([30.0, -10.0], [40.0, 10.0]):
        estimate = Cls(side_prior_m=tuple(prior)).estimate(data)
        np.testing.assert_allclose(estimate.position_m, [35.0, np.sign(prior[1]) * 15.0], atol=1e-6)


def test_as_printed_rows_put_the_height_into_r_z() -> None:
    """Without the height term (paper eq ``Beq`` as printed) the ToA rows read
    ``−2x_k x + r_z = (x_k − 35)² + 15² + 50² − x_k²``, so ``x = 35`` and
    ``r_z = 35² + 15² + 50²``; on the paraboloid ``y = ±√(15² + 50²) ≈ ±52.2`` m (MATH §4)."""
    estimate = ClsAsPrinted().estimate(noise_free(get_scenario("paper")))
    candidates = sorted_rows(estimate.candidates_m)
    exact_y = np.sqrt(15.0**2 + 50.0**2)
    np.testing.assert_allclose(candidates, [[35.0, -exact_y], [35.0, exact_y]], atol=1e-6)
    np.testing.assert_allclose(np.round(candidates, 1), [[35.0, -52.2], [35.0, 52.2]])


# --------------------------------------------------------------------------------------------
# invariances of the weighted CLS (MATH §6)
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper-1m", "turn", "orbit"])
def test_weighted_cls_is_unit_invariant(name: str) -> None:
    data = simulate(get_scenario(name), snr_db=0.0, seed=3)
    metres = Cls().estimate(data)
    kilometres = Cls().estimate(in_kilometres(data))
    np.testing.assert_allclose(
        sorted_rows(1000.0 * kilometres.candidates_m),
        sorted_rows(metres.candidates_m),
        rtol=1e-9,
    )
    # the unweighted rows mix m and m²: in km they give another answer (MATH §6)
    unweighted_m = Cls(weighting="none").estimate(data).candidates_m
    unweighted_km = Cls(weighting="none").estimate(in_kilometres(data)).candidates_m
    assert np.max(np.abs(sorted_rows(1000.0 * unweighted_km) - sorted_rows(unweighted_m))) > 1e-3


@pytest.mark.parametrize("name", ["paper-1m", "turn"])
def test_paper_cls_depends_on_the_unit_system(name: str) -> None:
    """cls-paper keeps the paper's row scale K|v|² (MATH §3): a Doppler residual in m³/s² against
    a ToA residual in m². In km the first shrinks by 1e9 and the second by 1e6, so the relative
    weight of the Doppler row drops by 1e3 and the answer moves; the weighted cls does not."""
    data = simulate(get_scenario(name), snr_db=0.0, seed=3)
    frames = "all" if name == "turn" else "last"
    metres = ClsPaper(frames=frames).estimate(data).candidates_m
    kilometres = ClsPaper(frames=frames).estimate(in_kilometres(data)).candidates_m
    moved = np.max(np.abs(sorted_rows(1000.0 * kilometres) - sorted_rows(metres)))
    assert moved > 1e-2
    cls_m = Cls().estimate(data).candidates_m
    cls_km = Cls().estimate(in_kilometres(data)).candidates_m
    np.testing.assert_allclose(sorted_rows(1000.0 * cls_km), sorted_rows(cls_m), rtol=1e-9)


def test_paper_cls_row_has_the_paper_scale() -> None:
    """On the paper's track (v = (10, 0, 0) m/s, K = 10) the projected row is ``K|v|² = 1000``
    times the unit row, i.e. exactly the paper's ``[k1, k2, 0]`` with ``k1 = Σ v_x² = 1000``; on
    ``turn`` each frame's row is its own ``K|v|²`` times its unit heading (SI units: a frame
    with origin 0 and unit 1 m)."""
    from estimators.closed_form.cls import cls_rows
    from estimators.closed_form.cls_rows import LocalFrame

    si = LocalFrame(origin_m=np.zeros(2), scale_m=1.0)
    data = noise_free(get_scenario("paper-1m"))
    A, _ = cls_rows(data, si, "per-frame")
    np.testing.assert_allclose(A[0], [1000.0, 0.0, 0.0], rtol=1e-12)
    turn = noise_free(get_scenario("turn"))
    A, _ = cls_rows(turn, si, "per-frame")
    for frame in np.unique(turn.frame):
        v = turn.velocity_mps[turn.frame == frame]
        speed_sq = np.sum(v[:, :2] ** 2, axis=1)
        expected = np.sum(speed_sq) * np.append(v[0, :2] / np.sqrt(speed_sq[0]), 0.0)
        np.testing.assert_allclose(A[frame], expected, rtol=1e-12, atol=1e-9)


def rotated(scenario: Scenario, angle_rad: float) -> Scenario:
    """The whole scenario turned by ``angle_rad`` about the vertical axis through the origin."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    flight = scenario.flight
    return scenario.replace(
        emitter_m=turn[:2, :2] @ scenario.emitter_m,
        flight=FlightPlan(
            start_position_m=turn @ flight.start_position_m,
            frame_velocities_mps=flight.frame_velocities_mps @ turn.T,
            samples_per_frame=flight.samples_per_frame,
            sample_interval_s=flight.sample_interval_s,
        ),
    )


@pytest.mark.parametrize("name", ["paper-1m", "turn"])
@pytest.mark.parametrize("angle_deg", [37.0, 90.0, 200.0])
def test_weighted_cls_rotates_with_the_scenario(name: str, angle_deg: float) -> None:
    """Same seed, rotated geometry: the noise-free values are rotation invariant, so the data
    are the same and the candidates rotate with the scenario."""
    scenario = get_scenario(name)
    angle = np.deg2rad(angle_deg)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    original = Cls().estimate(simulate(scenario, snr_db=0.0, seed=11))
    turned = Cls().estimate(simulate(rotated(scenario, angle), snr_db=0.0, seed=11))
    np.testing.assert_allclose(
        sorted_rows(turned.candidates_m),
        sorted_rows(original.candidates_m @ turn.T),
        rtol=1e-9,
        atol=1e-9,
    )


@pytest.mark.bits("frames='last' is Cls().estimate of the last frame's arrays")
def test_frames_last_uses_the_last_frame_only() -> None:
    scenario = get_scenario("turn")
    data = simulate(scenario, snr_db=10.0, seed=5)
    last = Cls(frames="last").estimate(data)
    alone = Cls().estimate(data.select_frames([1]))
    np.testing.assert_array_equal(last.candidates_m, alone.candidates_m)
    assert last.diagnostics["n_samples"] == scenario.flight.samples_per_frame
    assert last.ambiguous
    # noise-free, the northbound frame at x = 5 m leaves the emitter and its mirror (−25, 15)
    exact = Cls(frames="last").estimate(noise_free(scenario))
    np.testing.assert_allclose(
        sorted_rows(exact.candidates_m), [[-25.0, 15.0], [35.0, 15.0]], atol=1e-6
    )
    assert not Cls(frames="all").estimate(noise_free(scenario)).ambiguous


@pytest.mark.bits("the registry builds the same class: the same call on the same data")
def test_registry_builds_the_same_estimators() -> None:
    data = simulate(get_scenario("turn"), snr_db=0.0, seed=2)
    for name, cls in (("cls", Cls), ("cls-paper", ClsPaper), ("cls-as-printed", ClsAsPrinted)):
        from_registry = make_estimator(name).estimate(data)
        np.testing.assert_array_equal(from_registry.candidates_m, cls().estimate(data).candidates_m)


def test_bad_options_and_missing_modalities_raise_naming_the_field() -> None:
    with pytest.raises(ValueError, match=r"^weighting: "):
        Cls(weighting="heavy")
    with pytest.raises(ValueError, match=r"^frames: "):
        ClsPaper(frames="first")
    data = noise_free(get_scenario("paper-1m"))
    with pytest.raises(ValueError, match=r"^toa_s: "):
        Cls().estimate(data.without("toa"))


# --------------------------------------------------------------------------------------------
# efficiency (MATH §6, §8)
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("snr_db", [0.0, 20.0])
def test_weighted_cls_attains_the_crlb_on_paper_1m(snr_db: float) -> None:
    """Side-resolved RMSE (nearest candidate, MATH §7) over 2000 trials is within 5 % of
    √trace(CRLB); the sampling error of the ratio is about 1.6 %."""
    scenario = get_scenario("paper-1m")
    batch = simulate_trials(scenario, snr_db=snr_db, seeds=trial_seeds(2024, 2000))
    estimator = Cls()
    errors = []
    for data in batch:
        estimate = estimator.estimate(data)
        assert estimate.success
        errors.append(np.min(np.linalg.norm(estimate.candidates_m - scenario.emitter_m, axis=1)))
    rmse = np.sqrt(np.mean(np.square(errors)))
    bound = rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m, "toa+doppler"))
    assert rmse / bound <= 1.05
    assert rmse / bound >= 0.9


@pytest.mark.slow
def test_paper_cls_is_near_efficient_on_paper_1m() -> None:
    """With the paper's row scale (MATH §3) the errata-fixed paper CLS is near-efficient on
    paper-1m at 0 dB: side-resolved RMSE over 1000 trials within 10 % of √trace(CRLB) (the
    unit row gave 16.7 m against √CRLB 1.06 m, efficiency 16)."""
    scenario = get_scenario("paper-1m")
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(2025, 1000))
    estimator = ClsPaper()
    errors = []
    for data in batch:
        estimate = estimator.estimate(data)
        assert estimate.success
        errors.append(np.min(np.linalg.norm(estimate.candidates_m - scenario.emitter_m, axis=1)))
    rmse = np.sqrt(np.mean(np.square(errors)))
    bound = rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m, "toa+doppler"))
    assert rmse / bound <= 1.1
    assert rmse / bound >= 0.9
