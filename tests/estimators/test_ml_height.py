"""``ml`` with the emitter's height unknown (MATH §8, §10, §7): the search in ``(x, y, z)``.

Noise-free data give the truth on climbing and level turns (a level turn's reflection through
the flight plane a candidate at the same cost until the mirror rule keeps the one below the
UAV); on noisy climbing data the answer is the best of a brute-force multi-start search with
scipy; the covariance is the inverse Fisher information; the Jacobian's height column matches
central differences; MINPACK's engine with three unknowns ends where scipy's does; one trial is
the batch of one; one straight track is refused in one line.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

import estimators.ml.ml_batch as ml_batch
from estimators.base import capabilities_of
from estimators.closed_form.cls_rows import LocalFrame
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
from estimators.ml.minpack_batch import lmder_batch
from estimators.ml.ml import MaximumLikelihood, whitened_residual_jacobian, whitened_residuals
from scenarios import get_scenario
from scenarios.fisher import fisher_information, inverse_symmetric
from scenarios.geometry import reflect_through_plane
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free, simulate_trials, trial_seeds
from scenarios.types import MeasurementSet
from tests.estimators.batch_support import generators
from tests.estimators.test_ml_batch import estimate_differences
from tests.scenarios.random_flights import random_data

CLIMBS_MPS = (1.5, -2.0, 4.0)


def height_unknown(data: MeasurementSet) -> MeasurementSet:
    """``data`` with the emitter's height declared unknown: the truth ``(x, y, z)`` at the
    height the data were made with, the assumed height 0 (which ``ml`` must not need)."""
    truth = np.array([*data.truth_emitter_m, data.emitter_height_m])
    return dataclasses.replace(
        data, unknowns=(*data.unknowns, HEIGHT_UNKNOWN), truth_emitter_m=truth, emitter_height_m=0.0
    )


def noisy(data: MeasurementSet, seed: int) -> MeasurementSet:
    """``data`` with Gaussian noise of its σ's on the Doppler and the ToA."""
    rng = np.random.default_rng(seed)
    return dataclasses.replace(
        data,
        doppler_hz=data.doppler_hz + data.noise.doppler_hz * rng.standard_normal(data.n_samples),
        toa_s=data.toa_s + data.noise.toa_s * rng.standard_normal(data.n_samples),
    )


def cost(data: MeasurementSet, point) -> float:
    return float(np.sum(whitened_residuals(data, point) ** 2))


def scale_m(data: MeasurementSet) -> float:
    """The size of the problem: the largest distance from the truth to a sample."""
    return float(np.max(np.linalg.norm(data.position_m - data.truth_emitter_m, axis=1)))


def candidates_before_the_rule(monkeypatch, data: MeasurementSet, estimator=None):
    """The estimate, and the candidates the mirror rule weighs for ``ml`` (with their costs):
    those ``ml`` hands it and, on a flight in one plane (``plane``), their reflections through
    it, which the rule adds at the same costs (MATH §7)."""
    seen = []
    real = ml_batch.finalize_columns

    def recording(candidates_m, count, costs, *args, **kwargs):
        points, cost = candidates_m[0, : count[0]].copy(), costs[0, : count[0]].copy()
        if kwargs.get("plane") is not None:
            points = np.vstack([points, reflect_through_plane(points, *kwargs["plane"])])
            cost = np.concatenate([cost, cost])
        seen.append((points, cost))
        return real(candidates_m, count, costs, *args, **kwargs)

    monkeypatch.setattr(ml_batch, "finalize_columns", recording)
    estimate = (estimator or MaximumLikelihood()).estimate(data)
    assert len(seen) == 1
    return estimate, seen[0]


def test_ml_declares_the_height_and_keeps_its_nuisance_parameters() -> None:
    unknowns = capabilities_of(MaximumLikelihood()).unknowns
    assert {HEIGHT_UNKNOWN, "carrier_offset_hz", "emission_time_s"} <= unknowns


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("climb_mps", CLIMBS_MPS)
def test_noise_free_climbing_turns_give_the_emitter_exactly(seed: int, climb_mps: float) -> None:
    """A climbing turn leaves one minimum (MATH §7): the truth, to the search's tolerance, as
    the only candidate, with a 3 × 3 covariance."""
    data = height_unknown(random_data(seed, climb_mps=climb_mps))
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    tolerance = 1e-7 * scale_m(data)
    np.testing.assert_allclose(estimate.position_m, data.truth_emitter_m, rtol=0, atol=tolerance)
    assert estimate.candidates_m.shape == (1, 3) and not estimate.ambiguous
    assert estimate.covariance_m2.shape == (3, 3)
    assert estimate.diagnostics["fit_chi2"] < 1e-12


@pytest.mark.parametrize("seed", range(12))
def test_a_level_turn_leaves_the_reflection_until_the_mirror_rule(monkeypatch, seed: int) -> None:
    """On a level turn the reflection through the flight plane has the emitter's cost: ``ml``
    finds both, and the mirror rule keeps the one below the UAV (MATH §7)."""
    data = height_unknown(random_data(seed))
    plane_m = data.position_m[0, 2]
    estimate, (candidates, costs) = candidates_before_the_rule(monkeypatch, data)
    truth = data.truth_emitter_m
    reflection = np.array([*truth[:2], 2.0 * plane_m - truth[2]])
    tolerance = 1e-7 * scale_m(data)
    for point in (truth, reflection):
        gaps = np.linalg.norm(candidates - point, axis=1)
        assert gaps.min() <= tolerance, (point, candidates)
    assert np.all(costs <= 1e-12)
    assert estimate.success and estimate.candidates_m.shape == (1, 3)
    np.testing.assert_allclose(estimate.position_m, truth, rtol=0, atol=tolerance)


@pytest.mark.parametrize("name", ["hill", "hill-climb", "roof-beacon"])
def test_noise_free_height_scenarios_and_their_covariance(name: str) -> None:
    """The catalogue's elevated emitters (the non-cooperative beacon with its carrier offset
    and emission time profiled): the truth, and the covariance is the inverse Fisher
    information there (MATH §8, §15)."""
    data = noise_free(get_scenario(name))
    assert HEIGHT_UNKNOWN in data.unknowns
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    truth = data.truth_emitter_m
    np.testing.assert_allclose(estimate.position_m, truth, rtol=0, atol=1e-7 * scale_m(data))
    bound = inverse_symmetric(fisher_information(data, truth))
    np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6)


def test_the_covariance_is_the_inverse_fisher_information_at_the_truth_to_first_order() -> None:
    """At 20 dB the estimate is near the truth: its covariance (the inverse information at the
    estimate) is the CRLB at the truth to the relative size of the error."""
    scenario = get_scenario("hill-climb")
    batch = simulate_trials(scenario, snr_db=20.0, seeds=trial_seeds(3, 20))
    columns = MaximumLikelihood().estimate_columns(batch)
    assert columns.success.all()
    truth = noise_free(scenario).truth_emitter_m
    bound = inverse_symmetric(fisher_information(batch.geometry, truth))
    error = np.linalg.norm(columns.position_m - truth, axis=1)
    nearest = np.min(np.linalg.norm(batch.geometry.position_m - truth, axis=1))
    for i in range(batch.n_trials):
        gap = np.abs(columns.covariance_m2[i] - bound).max() / np.abs(bound).max()
        assert gap <= 20.0 * error[i] / nearest, (i, gap, error[i])


@pytest.mark.parametrize("seed", range(6))
def test_noisy_climbing_data_reach_the_brute_force_optimum(seed: int) -> None:
    """Noisy climbing turns: ``ml``'s answer has the lowest cost scipy finds from a grid of 150
    starts around the track (below the UAV), at the same point."""
    data = noisy(height_unknown(random_data(100 + seed, climb_mps=CLIMBS_MPS[seed % 3])), seed)
    estimate = MaximumLikelihood().estimate(data)
    assert estimate.success, estimate.message
    xy = data.position_m[:, :2]
    centre, half = xy.mean(axis=0), 2.0 * max(float(np.ptp(xy, axis=0).max()), 100.0)
    top = float(data.position_m[:, 2].min())
    best_cost, best = np.inf, None
    for x in np.linspace(-half, half, 6):
        for y in np.linspace(-half, half, 5):
            for z in np.linspace(top - 1.5 * half, top - 1.0, 5):
                found = least_squares(
                    lambda s: whitened_residuals(data, s),
                    [centre[0] + x, centre[1] + y, z],
                    jac=lambda s: whitened_residual_jacobian(data, s),
                    method="lm",
                    xtol=1e-12,
                    ftol=1e-12,
                    gtol=1e-12,
                )
                value = 2.0 * found.cost
                if found.x[2] <= data.position_m[:, 2].max() and value < best_cost:
                    best_cost, best = value, found.x
    own = cost(data, estimate.position_m)
    assert own <= best_cost * (1.0 + 1e-9) + 1e-12
    np.testing.assert_allclose(estimate.position_m, best, rtol=0, atol=1e-5 * scale_m(data))


@pytest.mark.parametrize("use_rss", [False, True])
@pytest.mark.parametrize("unknowns", [(), ("carrier_offset_hz", "emission_time_s")])
def test_the_height_column_of_the_jacobian_matches_central_differences(use_rss, unknowns) -> None:
    """``∂e/∂(x, y, z)`` against central differences of the residuals (profiled where the
    nuisance parameters are unknown), climbing flights."""
    for seed in range(4):
        data = height_unknown(random_data(seed, climb_mps=2.0))
        data = dataclasses.replace(data, unknowns=(*unknowns, *data.unknowns))
        rng = np.random.default_rng(seed)
        points = data.truth_emitter_m + rng.normal(0.0, 40.0, (5, 3))
        analytic = whitened_residual_jacobian(data, points, use_rss=use_rss)
        assert analytic.shape[-1] == 3
        step = 1e-4
        for axis in range(3):
            shift = np.zeros(3)
            shift[axis] = step
            plus = whitened_residuals(data, points + shift, use_rss=use_rss)
            minus = whitened_residuals(data, points - shift, use_rss=use_rss)
            numeric = (plus - minus) / (2.0 * step)
            np.testing.assert_allclose(
                analytic[..., axis], numeric, rtol=1e-6, atol=1e-7 * np.abs(numeric).max()
            )


def test_the_engine_with_three_unknowns_ends_where_least_squares_ends() -> None:
    """MINPACK's engine (:func:`lmder_batch`) on the 3-D residuals of noisy climbing turns from
    far starts: the same end point and cost as scipy's MINPACK, which solves each alone."""
    problems = []
    offsets = np.random.default_rng(7).normal(0.0, 150.0, (12, 3))
    for seed in range(12):  # one geometry per seed of the flight, each noisy twice
        data = noisy(height_unknown(random_data(200 + seed // 2, climb_mps=1.0)), seed)
        frame = LocalFrame.fit(data.position_m, data.range_m)
        scale = frame.scale_m
        origin = np.array([*frame.origin_m, data.position_m[:, 2].mean()])
        start = (data.truth_emitter_m + offsets[seed] - origin) / scale
        problems.append((data, origin, scale, start))

    for pair in range(0, len(problems), 2):  # two problems of one geometry at once
        two = problems[pair : pair + 2]

        def residuals(index, local, two=two):
            return np.stack(
                [
                    whitened_residuals(two[i][0], u * two[i][2] + two[i][1])
                    for i, u in zip(index, local, strict=True)
                ],
                axis=1,
            )

        def jacobian(index, local, two=two):
            blocks = [
                whitened_residual_jacobian(two[i][0], u * two[i][2] + two[i][1]) * two[i][2]
                for i, u in zip(index, local, strict=True)
            ]
            return [np.stack([b[:, axis] for b in blocks], axis=1) for axis in range(3)]

        starts = np.array([p[3] for p in two])
        result = lmder_batch(
            residuals, jacobian, starts, ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200
        )
        assert not result.odd.any()
        for i, (data, origin, scale, start) in enumerate(two):
            _same_end(result, i, data, origin, scale, start)


def _same_end(result, i, data, origin, scale, start) -> None:
    """Search ``i`` of ``result`` ends where ``least_squares`` ends from ``start``."""
    expected = least_squares(
        lambda u: whitened_residuals(data, u * scale + origin),
        start,
        jac=lambda u: whitened_residual_jacobian(data, u * scale + origin) * scale,
        method="lm",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=200,
    )
    assert 1 <= result.info[i] <= 4 and expected.status >= 1
    np.testing.assert_allclose(result.x[i], expected.x, rtol=0, atol=1e-8)
    got = float(np.sum(result.fvec[:, i] ** 2))
    assert abs(got - 2.0 * expected.cost) <= 1e-9 * max(2.0 * expected.cost, 1.0)


@pytest.mark.paths
def test_one_trial_is_the_batch_of_one_with_the_height_unknown() -> None:
    scenario = get_scenario("hill-climb")
    batch = simulate_trials(scenario, snr_db=0.0, seeds=trial_seeds(5, 40))
    estimator = MaximumLikelihood()
    columns = estimator.estimate_columns(batch, rngs=generators(batch.n_trials))
    assert columns.position_m.shape == (40, 3) and columns.covariance_m2.shape == (40, 3, 3)
    rngs = generators(batch.n_trials)
    for i in range(batch.n_trials):
        single = estimator.estimate(batch.trial(i), rng=rngs[i])
        got = columns.estimate(i)
        assert estimate_differences(estimator, batch.trial(i), single, got) == [], i


def test_one_straight_track_cannot_fix_the_height() -> None:
    """A straight track leaves a circle of equal cost about it (MATH §7): refused in one line,
    for one trial and a batch alike."""
    scenario = get_scenario("paper-1m").replace(unknowns=(HEIGHT_UNKNOWN,), emitter_height_m=10.0)
    estimate = MaximumLikelihood().estimate(noise_free(scenario))
    assert not estimate.success and estimate.message == STRAIGHT_TRACK_HEIGHT
    assert estimate.position_m.shape == (3,) and "\n" not in estimate.message
    batch = simulate_trials(scenario, snr_db=10.0, seeds=trial_seeds(1, 3))
    columns = MaximumLikelihood().estimate_columns(batch)
    assert not columns.success.any()
    assert {columns.message(i) for i in range(3)} == {STRAIGHT_TRACK_HEIGHT}


def test_with_the_height_known_the_search_stays_in_the_plane() -> None:
    """The same turn with its height known: two coordinates, as before the height was
    estimable; the 3-D answer on the same measurements has the same horizontal position to
    the search's tolerance."""
    data = random_data(3, climb_mps=1.0)
    known = MaximumLikelihood().estimate(data)
    assert known.position_m.shape == (2,) and known.covariance_m2.shape == (2, 2)
    unknown = MaximumLikelihood().estimate(height_unknown(data))
    np.testing.assert_allclose(unknown.position_m[:2], known.position_m, atol=1e-6)


@pytest.mark.parametrize("name", ["hill", "hill-climb", "roof-beacon"])
def test_the_answer_does_not_depend_on_the_height_the_data_assume(name: str) -> None:
    """The data's ``emitter_height_m`` (the ground an estimator ignoring the height assumes)
    places only the lowest start: other assumed heights give the same minimum on noisy data."""
    data = simulate_trials(get_scenario(name), snr_db=0.0, seeds=trial_seeds(9, 1)).trial(0)
    answers = [
        MaximumLikelihood().estimate(dataclasses.replace(data, emitter_height_m=height))
        for height in (-200.0, 0.0, 60.0)
    ]
    assert all(answer.success for answer in answers)
    for answer in answers[1:]:
        np.testing.assert_allclose(
            answer.position_m, answers[0].position_m, rtol=0, atol=1e-7 * scale_m(data)
        )
