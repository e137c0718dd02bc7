"""The plug-in passes emitterbench's conformance suite and attains the Doppler CRLB."""

from __future__ import annotations

import numpy as np
import pytest
from emitterbench_gridsearch import DopplerGridSearch

from comparison.crlb import crlb_m2, fisher_information
from estimators.base import capabilities_of
from estimators.checks import (
    EXACT_TOLERANCE_M,
    check_estimator,
    noise_free_tolerance_m,
    parametrize_with_checks,
    reference_data,
)


@parametrize_with_checks([DopplerGridSearch(), DopplerGridSearch(grid_points=21, n_starts=1)])
def test_conformance(estimator, check) -> None:
    check(estimator)


def test_check_estimator_passes() -> None:
    """The one-call form of the same suite (what a plug-in's CI can run)."""
    outcomes = check_estimator(DopplerGridSearch())
    assert all(outcome.passed for outcome in outcomes)


def test_capabilities_are_declared() -> None:
    """Doppler only, batch, and a looser noise-free tolerance with its reason; the old class
    attribute is gone (the suite no longer reads it)."""
    declared = capabilities_of(DopplerGridSearch())
    assert declared.modalities == {"doppler"}
    assert declared.frames == "all" and declared.batch and not declared.sequential
    assert not declared.unit_invariant  # search_radius_m is in metres
    assert declared.noise_free_tolerance_m == 1e-5 > EXACT_TOLERANCE_M
    assert "stops" in declared.tolerance_reason
    assert noise_free_tolerance_m(DopplerGridSearch()) == 1e-5
    assert not hasattr(DopplerGridSearch, "noise_free_tolerance_m")


@pytest.mark.parametrize("scenario", ["turn", "orbit", "far-turn", "climb"])
def test_noise_free_two_headings_give_the_emitter_and_its_crlb(scenario: str) -> None:
    data, truth = reference_data(scenario)
    estimate = DopplerGridSearch().estimate(data)
    assert not estimate.ambiguous
    np.testing.assert_allclose(estimate.position_m, truth, atol=1e-5)
    bound = crlb_m2(fisher_information(data, truth, "doppler"))
    np.testing.assert_allclose(estimate.covariance_m2, bound, rtol=1e-6)


def test_options_are_validated_with_the_field_name() -> None:
    with pytest.raises(ValueError, match=r"^grid_points: expected a whole number >= 3"):
        DopplerGridSearch(grid_points=2)
    with pytest.raises(ValueError, match=r"^search_radius_m: must be finite and > 0"):
        DopplerGridSearch(search_radius_m=-1.0)
