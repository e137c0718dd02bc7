"""The position's dimension is a parameter: ``(x, y)`` or ``(x, y, z)`` in an Estimate, in
its columns, in the validity rules, in the inverse of a covariance and in the NEES band."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from comparison.intervals import nees_band
from comparison.scoring import normalized_error_squared
from estimators.base import Estimate
from estimators.batch import BatchEstimates
from scenarios.fisher import inverse_2x2, inverse_symmetric

COVARIANCE_3D = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.2], [0.5, -0.2, 2.0]])


def estimate_3d(**changes: object) -> Estimate:
    fields = {
        "estimator": "three",
        "position_m": [1.0, 2.0, 3.0],
        "candidates_m": [[1.0, 2.0, 3.0], [1.0, -2.0, 3.0]],
        "ambiguous": True,
        "covariance_m2": COVARIANCE_3D,
    } | changes
    return Estimate(**fields)


def test_a_3d_estimate_keeps_its_three_coordinates() -> None:
    estimate = estimate_3d()
    assert estimate.success
    assert estimate.position_m.tolist() == [1.0, 2.0, 3.0]
    assert estimate.candidates_m.shape == (2, 3)
    assert estimate.covariance_m2.shape == (3, 3)
    failed = Estimate.failed("three", "no data", dimension=3)
    assert failed.position_m.shape == (3,) and failed.candidates_m.shape == (0, 3)


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"covariance_m2": np.diag([1.0, -2.0, 3.0])}, "smallest eigenvalue -2 m²"),
        (
            {"covariance_m2": COVARIANCE_3D + np.outer([0, 0, 1.0], [1.0, 0, 0])},
            "covariance_m2[0, 2] = 0.5 but covariance_m2[2, 0] = 1.5 m²",
        ),
        ({"position_m": [1.0, 2.0, 3.5]}, "is not one of its candidates_m"),
    ],
)
def test_the_validity_rules_hold_in_3d(changes: dict, named: str) -> None:
    estimate = estimate_3d(**changes)
    assert not estimate.success
    assert named in estimate.message
    assert np.isnan(estimate.position_m).all() and estimate.position_m.shape == (3,)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"position_m": [1.0, 2.0, 3.0, 4.0]}, "position_m: expected (x, y) or (x, y, z)"),
        ({"candidates_m": [[1.0, 2.0]]}, "candidates_m: expected shape (n, 3)"),
        ({"covariance_m2": np.eye(2)}, "covariance_m2: expected shape (3, 3)"),
    ],
)
def test_a_wrong_number_of_coordinates_is_one_line_naming_the_field(
    changes: dict, field: str
) -> None:
    with pytest.raises(ValueError) as error:
        estimate_3d(**changes)
    assert str(error.value).startswith(field)
    assert "\n" not in str(error.value)


def test_3d_columns_round_trip_and_refuse_mixed_dimensions() -> None:
    estimates = [estimate_3d(), Estimate.failed("three", "no fix", dimension=3)]
    columns = BatchEstimates.from_estimates("three", estimates)
    assert columns.position_m.shape == (2, 3)
    assert columns.candidates_m.shape == (2, 2, 3)
    assert columns.covariance_m2.shape == (2, 3, 3)
    back = columns.estimate(0)
    np.testing.assert_array_equal(back.candidates_m, estimates[0].candidates_m)
    np.testing.assert_array_equal(back.covariance_m2, COVARIANCE_3D)
    assert not columns.success[1] and columns.message(1) == "no fix"
    flat = Estimate(
        estimator="three", position_m=[1.0, 2.0], candidates_m=[[1.0, 2.0]], ambiguous=False
    )
    with pytest.raises(ValueError, match="position_m: the trials' positions have"):
        BatchEstimates.from_estimates("three", [estimates[0], flat])
    refused = BatchEstimates(
        estimator="three",
        position_m=np.array([[1.0, 2.0, 3.0]]),
        candidates_m=np.array([[[1.0, 2.0, 3.0]]]),
        n_candidates=np.array([1]),
        ambiguous=np.array([False]),
        success=np.array([True]),
        message_code=np.array([0]),
        messages=("",),
        covariance_m2=np.diag([1.0, 1.0, -1.0])[None],
    )
    assert not refused.success[0] and "smallest eigenvalue -1 m²" in refused.message(0)


def test_the_inverse_of_a_symmetric_matrix_in_any_dimension() -> None:
    np.testing.assert_allclose(
        inverse_symmetric(COVARIANCE_3D) @ COVARIANCE_3D, np.eye(3), atol=1e-14
    )
    two = np.array([[[2.0, 0.3], [0.3, 1.0]], [[1.0, 1.0], [1.0, 1.0]]])
    np.testing.assert_array_equal(inverse_symmetric(two), inverse_2x2(two))  # the same code
    singular = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.isnan(inverse_symmetric(np.stack([singular, COVARIANCE_3D]))[0]).all()
    assert np.isnan(inverse_symmetric(np.full((3, 3), np.inf))).all()


def test_nees_in_3d_against_its_definition_and_its_chi_square_band() -> None:
    error = np.array([1.0, -0.5, 2.0])
    expected = error @ np.linalg.solve(COVARIANCE_3D, error)
    assert normalized_error_squared(error[None], COVARIANCE_3D[None])[0] == pytest.approx(
        expected, rel=1e-13
    )
    low, high = nees_band(10, 0.95, dof=3)
    assert low == pytest.approx(stats.chi2.ppf(0.025, 30) / 10, rel=1e-12)
    assert high == pytest.approx(stats.chi2.ppf(0.975, 30) / 10, rel=1e-12)
    assert nees_band(10, 0.95) == nees_band(10, 0.95, dof=2)
    with pytest.raises(ValueError, match="dof"):
        nees_band(10, 0.95, dof=0)
