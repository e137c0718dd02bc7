"""The conformance suite's 3-D reference problems and checks (MATH §7, §8): their optima are
minimisers of the noise-free data, the checks run only for estimators that estimate the
height, ``ml`` passes them, and estimators that break their rules fail them with the fix."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from estimators import make_estimator
from estimators.base import Estimate
from estimators.checks import (
    HEIGHT_PROBLEMS,
    check_exact_with_the_height_unknown,
    check_straight_track_cannot_fix_the_height,
    estimator_checks,
    reference_problem,
)
from estimators.ml.ml import MaximumLikelihood, whitened_residuals
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.simulate import noise_free

HEIGHT_CHECKS = {
    "check_exact_with_the_height_unknown",
    "check_straight_track_cannot_fix_the_height",
}


def misfit(data, point) -> float:
    """The whitened RMS residual of the noise-free data at ``point`` (x, y, z)."""
    return float(np.sqrt(np.mean(whitened_residuals(data, point) ** 2)))


@pytest.mark.parametrize("name", ["climb-height", "turn-height"])
def test_the_optima_fit_the_noise_free_data_and_the_reflection_only_on_the_level_turn(name):
    problem = reference_problem(name)
    data = noise_free(problem.scenario)
    assert HEIGHT_UNKNOWN in data.unknowns and problem.dimension == 3
    (optimum,) = problem.optima_m
    np.testing.assert_array_equal(optimum, problem.emitter_m)
    np.testing.assert_array_equal(optimum, data.truth_emitter_m)
    assert misfit(data, optimum) < 1e-9
    plane = data.position_m[:, 2].mean()
    reflection = np.array([*optimum[:2], 2.0 * plane - optimum[2]])
    if name == "turn-height":  # level: the reflection fits exactly, above the UAV
        assert misfit(data, reflection) < 1e-9 and reflection[2] > data.position_m[:, 2].max()
    else:  # the climb breaks the symmetry: the reflection misses the data by 3 σ RMS at 0 dB
        assert misfit(data, reflection) > 2.0


def test_one_straight_track_has_a_circle_of_equal_cost_and_no_optimum() -> None:
    problem = reference_problem("climb-straight-height")
    assert problem.optima_m.shape == (0, 3)
    data = noise_free(problem.scenario)
    emitter = data.truth_emitter_m
    # rotate the emitter about the track (through p_0 along the unit velocity): the same data
    p0, v = data.position_m[0], data.velocity_mps[0] / np.linalg.norm(data.velocity_mps[0])
    offset = emitter - p0
    along = (offset @ v) * v
    radial = offset - along
    other = np.cross(v, radial)
    for angle in (0.7, 2.0, -1.1):
        point = p0 + along + np.cos(angle) * radial + np.sin(angle) * other
        assert misfit(data, point) < 1e-6
        assert np.linalg.norm(point - emitter) > 1.0


def test_the_height_checks_run_only_for_estimators_that_estimate_the_height() -> None:
    assert HEIGHT_CHECKS <= {c.__name__ for c in estimator_checks(MaximumLikelihood())}
    assert HEIGHT_CHECKS <= {c.__name__ for c in estimator_checks(make_estimator("cls"))}
    assert not HEIGHT_CHECKS & {c.__name__ for c in estimator_checks(make_estimator("cls-paper"))}
    assert set(HEIGHT_PROBLEMS) == {"climb-height", "turn-height", "climb-straight-height"}


@pytest.mark.parametrize("options", [{}, {"frames": "last"}, {"use_rss": True}])
def test_ml_passes_the_height_checks(options) -> None:
    estimator = MaximumLikelihood(**options)
    check_exact_with_the_height_unknown(estimator)
    check_straight_track_cannot_fix_the_height(estimator)


@dataclass(frozen=True, kw_only=True)
class ReflectedMl(MaximumLikelihood):
    """Answers with the reflection of ml's answer through the UAV's mean altitude."""

    def estimate(self, data, *, rng=None) -> Estimate:
        found = super().estimate(data, rng=rng)
        if not found.success:
            return found
        point = np.array(found.position_m)
        point[2] = 2.0 * data.position_m[:, 2].mean() - point[2]
        return dataclasses.replace(found, position_m=point, candidates_m=point[None])


@dataclass(frozen=True, kw_only=True)
class FlatMl(MaximumLikelihood):
    """Claims the height but answers in the plane."""

    def estimate(self, data, *, rng=None) -> Estimate:
        found = super().estimate(data, rng=rng)
        if not found.success:
            return found
        return dataclasses.replace(
            found,
            position_m=found.position_m[:2],
            candidates_m=found.candidates_m[:, :2],
            covariance_m2=None,
        )


@dataclass(frozen=True, kw_only=True)
class GuessingMl(MaximumLikelihood):
    """Answers on a straight track too: the point 50 m under its first sample."""

    def estimate(self, data, *, rng=None) -> Estimate:
        found = super().estimate(data, rng=rng)
        if found.success:
            return found
        point = data.position_m[0] - np.array([0.0, 0.0, 50.0])
        return Estimate(
            estimator=self.name, position_m=point, candidates_m=point[None], ambiguous=True
        )


@dataclass(frozen=True, kw_only=True)
class TalkativeMl(MaximumLikelihood):
    """Fails on a straight track with a message of two lines."""

    def estimate(self, data, *, rng=None) -> Estimate:
        found = super().estimate(data, rng=rng)
        if found.success:
            return found
        return Estimate.failed(self.name, "no answer\nthe track is straight", dimension=3)


@pytest.mark.parametrize(
    ("estimator", "check", "words"),
    [
        (ReflectedMl(), check_exact_with_the_height_unknown, "no candidate is at the optimum"),
        (FlatMl(), check_exact_with_the_height_unknown, "position_m has shape (2,)"),
        (GuessingMl(), check_straight_track_cannot_fix_the_height, "estimate succeeded"),
        (TalkativeMl(), check_straight_track_cannot_fix_the_height, "one-line message"),
    ],
)
def test_an_estimator_that_breaks_a_height_rule_fails_its_check(estimator, check, words) -> None:
    with pytest.raises(AssertionError) as caught:
        check(estimator)
    assert words in str(caught.value)
    assert "\n" not in str(caught.value)
