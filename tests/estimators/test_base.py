"""The two rules of estimators/base.py that hold for every estimator, built-in or plug-in.

``success`` means a finite answer: :class:`Estimate` turns a success with a non-finite
position or candidate into a failed estimate that quotes what was reported (the other rules
of :mod:`estimators.validity` are tested in ``tests/estimators/test_validity.py``). Data with no
baseline locate nothing: :func:`require_modalities`, which every built-in calls first, refuses
them naming the field, so no built-in ever reports an unambiguous success on a hovering UAV, a
single sample or a burst at one point. And the limits of scenarios/types.py keep every
built-in's arithmetic finite at their extremes.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import replace

import numpy as np
import pytest

from estimators.base import Estimate, baseline_problem, require_modalities
from estimators.registry import BUILTIN, make_estimator
from scenarios.catalog import get_scenario
from scenarios.simulate import noise_free, simulate
from scenarios.types import SIGMA_RANGE, MeasurementSet, NoiseSigmas

AVAILABLE = [name for name, entry in BUILTIN.items() if entry.is_available()]
FIELD = re.compile(r"^[A-Za-z_][\w.\[\]]*: \S")


# --------------------------------------------------------------------------------------------
# success means a finite answer
# --------------------------------------------------------------------------------------------


def test_a_success_with_a_nan_position_is_a_failed_estimate() -> None:
    estimate = Estimate(
        estimator="plug-in",
        position_m=[np.nan, 0.0],
        candidates_m=[[np.nan, 0.0]],
        ambiguous=True,
        covariance_m2=np.eye(2),
        success=True,
        message="converged",
        diagnostics={"iterations": 3},
    )
    assert estimate.success is False
    assert estimate.ambiguous is False
    assert estimate.covariance_m2 is None
    assert np.all(np.isnan(estimate.position_m))
    assert estimate.candidates_m.shape == (0, 2)
    assert estimate.message == ("invalid estimate: position_m is not finite (nan, 0); converged")
    assert estimate.diagnostics == {"iterations": 3}
    json.dumps(estimate.to_dict(), allow_nan=False)


def test_a_success_with_an_infinite_candidate_is_a_failed_estimate() -> None:
    estimate = Estimate(
        estimator="cls",
        position_m=[35.0, 15.0],
        candidates_m=[[35.0, 15.0], [np.inf, -15.0]],
        ambiguous=True,
    )
    assert not estimate.success
    assert estimate.message == (
        "invalid estimate: candidates_m is not finite: (35, 15); (inf, -15)"
    )
    assert np.all(np.isnan(estimate.position_m))


def test_finite_successes_and_failures_are_kept_as_they_are() -> None:
    good = Estimate(
        estimator="cls", position_m=[35.0, 15.0], candidates_m=[[35.0, 15.0]], ambiguous=False
    )
    assert good.success and good.message == ""
    np.testing.assert_array_equal(good.position_m, [35.0, 15.0])
    failed = Estimate.failed("cls", "no starting point")
    assert not failed.success and failed.message == "no starting point"
    # the rule holds for a copy too: replace() validates again
    broken = replace(good, position_m=[np.inf, 15.0], candidates_m=[[np.inf, 15.0]])
    assert not broken.success
    assert broken.message == "invalid estimate: position_m is not finite (inf, 15)"


# --------------------------------------------------------------------------------------------
# no baseline
# --------------------------------------------------------------------------------------------


def paper_frame() -> MeasurementSet:
    """One noisy straight frame of ``paper-1m`` with Doppler, ToA and RSS (10 samples)."""
    return simulate(get_scenario("paper-1m"), snr_db=10.0, seed=3).without_truth()


def hovering(data: MeasurementSet) -> MeasurementSet:
    n = data.n_samples
    return replace(
        data,
        position_m=np.tile(data.position_m[0], (n, 1)),
        velocity_mps=np.zeros((n, 3)),
        doppler_hz=np.zeros(n),
        toa_s=np.full(n, data.toa_s[0]),
        rss_dbm=np.full(n, data.rss_dbm[0]),
    )


def climbing(data: MeasurementSet) -> MeasurementSet:
    """Straight up at 2 m/s from the first sample: no horizontal baseline, no horizontal motion."""
    n = data.n_samples
    climb = np.outer(data.time_s - data.time_s[0], [0.0, 0.0, 2.0])
    return replace(
        data,
        position_m=data.position_m[0] + climb,
        velocity_mps=np.tile([0.0, 0.0, 2.0], (n, 1)),
    )


def one_sample(data: MeasurementSet) -> MeasurementSet:
    return data.take(np.arange(data.n_samples) == 0)


def burst(data: MeasurementSet) -> MeasurementSet:
    """Every sample at one instant and one point, flying east."""
    n = data.n_samples
    return replace(data, position_m=np.tile(data.position_m[0], (n, 1)), time_s=np.zeros(n))


NO_BASELINE = {"hovering": hovering, "climbing": climbing, "one-sample": one_sample, "burst": burst}


@pytest.mark.parametrize(
    ("modalities", "geometry", "field"),
    [
        ({"doppler", "toa"}, "hovering", "velocity_mps"),
        ({"toa"}, "climbing", "velocity_mps"),
        ({"rss"}, "hovering", "velocity_mps"),
        ({"toa"}, "one-sample", "position_m"),
        ({"rss"}, "burst", "position_m"),
        ({"toa", "rss"}, "one-sample", "position_m"),
        ({"doppler"}, "one-sample", "position_m"),
        ({"doppler", "toa"}, "one-sample", None),  # a mirror pair (MATH §7)
        ({"doppler", "rss"}, "burst", None),
        ({"doppler", "toa", "rss"}, "burst", None),
        ({"toa"}, "track", None),
        ({"doppler"}, "track", None),
    ],
)
def test_which_geometries_have_no_baseline(modalities, geometry: str, field) -> None:
    data = paper_frame() if geometry == "track" else NO_BASELINE[geometry](paper_frame())
    problem = baseline_problem(frozenset(modalities), data)
    if field is None:
        assert problem is None
    else:
        assert problem is not None and problem.startswith(f"{field}: every sample is at one")


@pytest.mark.parametrize("name", AVAILABLE)
@pytest.mark.parametrize("geometry", list(NO_BASELINE))
def test_no_builtin_succeeds_unambiguously_without_a_baseline(name: str, geometry: str) -> None:
    estimator = make_estimator(name)
    data = NO_BASELINE[geometry](paper_frame())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            estimate = estimator.estimate(data, rng=np.random.default_rng(0))
        except ValueError as error:
            assert FIELD.match(str(error)), str(error)
            assert "\n" not in str(error)
            return
    assert isinstance(estimate, Estimate)
    assert not estimate.success or estimate.ambiguous, estimate
    if estimate.success:  # a mirror pair from one moving point: both sides reported
        assert len(estimate.candidates_m) == 2
        assert np.all(np.isfinite(estimate.candidates_m))
    else:
        assert estimate.message


@pytest.mark.parametrize("name", AVAILABLE)
def test_every_builtin_refuses_a_hovering_uav_naming_the_velocity(name: str) -> None:
    """The check runs first, in require_modalities, whatever the estimator does after."""
    with pytest.raises(ValueError, match=r"^velocity_mps: every sample is at one horizontal"):
        make_estimator(name).estimate(hovering(paper_frame()))


def test_require_modalities_passes_a_track_and_names_what_is_missing() -> None:
    cls = make_estimator("cls")
    require_modalities(cls, paper_frame())  # a straight frame has a baseline
    with pytest.raises(ValueError, match=r"^toa_s: estimator 'cls' needs toa"):
        require_modalities(cls, paper_frame().without("toa"))
    with pytest.raises(ValueError, match=r"^position_m: every sample is at one horizontal point"):
        require_modalities(make_estimator("lls-toa"), one_sample(paper_frame()))
    require_modalities(cls, one_sample(paper_frame()))  # Doppler and ToA: a mirror pair
    with pytest.raises(TypeError, match=r"^data: expected a scenarios.types.MeasurementSet"):
        require_modalities(cls, "paper-1m.json")


def test_an_estimator_of_the_last_frame_fails_when_the_uav_hovered_in_it() -> None:
    """The whole flight has a baseline, the frame used has none: finalize_estimate fails it."""
    data = noise_free(get_scenario("turn")).without_truth()  # east, then north
    last = data.frame == 1
    changes = {name: np.array(getattr(data, name)) for name in ("position_m", "velocity_mps")}
    changes["position_m"][last] = data.position_m[10]
    changes["velocity_mps"][last] = 0.0
    for name in ("toa_s", "rss_dbm"):
        changes[name] = np.where(last, getattr(data, name)[10], getattr(data, name))
    changes["doppler_hz"] = np.where(last, 0.0, data.doppler_hz)
    hovered = replace(data, **changes)
    for name in ("lls-toa", "lls-rss"):
        estimate = make_estimator(name, frames="last").estimate(hovered)
        assert not estimate.success
        assert estimate.message.startswith("velocity_mps: every sample is at one horizontal point")
        assert make_estimator(name).estimate(hovered).success  # every frame: a baseline


# --------------------------------------------------------------------------------------------
# the limits keep the arithmetic finite
# --------------------------------------------------------------------------------------------


def extremes() -> dict[str, MeasurementSet]:
    """Exact ``turn`` data at the edges of the limits of scenarios/types.py."""
    base = noise_free(get_scenario("turn")).without_truth()
    low, high = SIGMA_RANGE
    return {
        "largest sigmas": replace(
            base, noise=NoiseSigmas(doppler_hz=high, toa_s=high, rss_db=high)
        ),
        "smallest sigmas": replace(base, noise=NoiseSigmas(doppler_hz=low, toa_s=low, rss_db=low)),
        "a million km away": replace(
            base, position_m=base.position_m + np.array([1e9 - 100, -1e9 + 100, 0.0])
        ),
    }


@pytest.mark.parametrize("name", AVAILABLE)
@pytest.mark.parametrize("label", list(extremes()))
def test_the_limits_keep_every_builtin_finite(name: str, label: str) -> None:
    """No OverflowError (σ² of 1e200 once raised one), and a success is finite."""
    data = extremes()[label]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            estimate = make_estimator(name).estimate(data, rng=np.random.default_rng(0))
        except ValueError as error:
            assert FIELD.match(str(error)), str(error)
            return
    if estimate.success:
        assert np.all(np.isfinite(estimate.position_m))
        assert np.all(np.isfinite(estimate.candidates_m))
    if label == "a million km away" and name not in ("cls-as-printed", "lls-rss"):
        # exact data (the printed formulas and the de-biased RSS distances are not exact on
        # them): the emitter is found where it was put, 1e9 m out, to the float resolution there
        assert estimate.success
        nearest = np.min(np.linalg.norm(estimate.candidates_m - [1e9 - 65, -1e9 + 115], axis=1))
        assert nearest < 1e-6
