"""A position of ``d = 3`` coordinates through the generic functions: Fisher information →
CRLB → bound columns → scoring (NEES with 3 degrees of freedom) → intervals → the summary.

Every number is checked against an independent computation: a Fisher matrix over
``(x, y, z, b)`` by central differences of the time of arrival, numpy's inverse and
eigendecomposition, scipy's χ² and F quantiles, Hotelling's region written out. The 3-D
gradients are the measurement model's for an emitter of three coordinates (its own check:
tests/scenarios/test_height_coordinate.py).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from comparison.bounds import bound_columns, information_of
from comparison.intervals import (
    axis_names,
    axis_squared_errors,
    bias_intervals,
    largest_eigenvalue,
    nees_band,
)
from comparison.metric_groups import (
    SUMMARY_TRIAL_COLUMNS,
    position_dimension_of,
    summary_trial_columns,
)
from comparison.metric_registry import metric_names
from comparison.metrics import summarize, swept_columns_of
from comparison.scoring import Outcomes, normalized_error_squared, score_outcomes
from comparison.trial_rows import (
    BOUND_COLUMNS,
    ESTIMATE_COLUMNS,
    coordinate_columns,
    dimension_columns,
    matrix_columns,
    matrix_of_values,
    matrix_values,
)
from estimators.base import Estimate
from scenarios.catalog import get_scenario
from scenarios.fisher import (
    frame_statistics,
    inverse_2x2,
    inverse_symmetric,
    regular_2x2,
    regular_symmetric,
)
from scenarios.planners.base import check_covariance
from scenarios.simulate import noise_free
from tests.comparison.test_metrics import trial_rows

INFORMATION_3D = np.array([[5.0, 1.2, -0.4], [1.2, 3.0, 0.7], [-0.4, 0.7, 2.0]])
"""A positive definite information (1/m²)."""

COVARIANCE_3D = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.2], [0.5, -0.2, 2.0]])


# --------------------------------------------------------------------------------------------
# the column names: one home, d = 2 a prefix of d = 3
# --------------------------------------------------------------------------------------------


def test_the_3d_columns_follow_the_2d_ones_and_round_trip() -> None:
    assert matrix_columns("crlb", 2) == ("crlb_xx_m2", "crlb_xy_m2", "crlb_yy_m2")
    assert matrix_columns("cov", 3) == (
        "cov_xx_m2",
        "cov_xy_m2",
        "cov_yy_m2",
        "cov_xz_m2",
        "cov_yz_m2",
        "cov_zz_m2",
    )
    assert BOUND_COLUMNS == ("crlb_rmse_m", *matrix_columns("crlb", 2))
    assert coordinate_columns("truth_{}_m", 3) == ("truth_x_m", "truth_y_m", "truth_z_m")
    assert set(matrix_columns("cov", 2)) <= set(ESTIMATE_COLUMNS)
    np.testing.assert_array_equal(matrix_of_values(matrix_values(COVARIANCE_3D)), COVARIANCE_3D)
    entries = dict(zip(matrix_columns("cov", 3), matrix_values(COVARIANCE_3D), strict=True))
    assert (entries["cov_xz_m2"], entries["cov_yz_m2"], entries["cov_zz_m2"]) == (0.5, -0.2, 2.0)
    with pytest.raises(ValueError, match="values: 4 entries"):
        matrix_of_values([1.0, 2.0, 3.0, 4.0])


def test_the_summary_reads_the_3d_columns_and_takes_none_for_a_swept_parameter() -> None:
    assert summary_trial_columns(2) == SUMMARY_TRIAL_COLUMNS
    extra = set(summary_trial_columns(3)) - set(SUMMARY_TRIAL_COLUMNS)
    assert extra == {"truth_z_m", "z_m", "z_side_resolved_m", "crlb_xz_m2", "crlb_yz_m2"} | {
        "crlb_zz_m2"
    }
    assert position_dimension_of(["truth_x_m", "truth_y_m", "x_m"]) == 2
    assert position_dimension_of(dimension_columns(3)) == 3
    frame = pd.DataFrame(columns=[*dimension_columns(3), "range_sigma_m"])
    assert swept_columns_of(frame) == ["range_sigma_m"]


# --------------------------------------------------------------------------------------------
# the algebra of the bound: one rule of regularity
# --------------------------------------------------------------------------------------------


def test_the_inverse_of_a_3x3_information_is_numpy_s_and_exactly_symmetric() -> None:
    crlb = inverse_symmetric(INFORMATION_3D)
    np.testing.assert_allclose(crlb, np.linalg.inv(INFORMATION_3D), rtol=1e-13)
    np.testing.assert_array_equal(crlb, crlb.T)
    # units of each coordinate do not change regularity: D J D is regular, inverse D⁻¹ J⁻¹ D⁻¹
    scale = np.diag([1e-4, 1.0, 1e5])
    scaled = scale @ INFORMATION_3D @ scale
    assert regular_symmetric(scaled)
    unscale = np.diag(1.0 / np.diag(scale))
    np.testing.assert_allclose(inverse_symmetric(scaled), unscale @ crlb @ unscale, rtol=1e-10)


def test_the_rule_of_regularity_is_the_determinant_against_the_diagonal_in_any_dimension() -> None:
    """Regular where ``det J > 1e-12 |Π J_ii|``: a correlation determinant of 1e-13 is singular,
    1e-11 regular, whatever the units, in 2-D (the closed form) as in 3-D; NaN and inf entries
    are singular."""
    for d in (2, 3):
        for ratio, regular in ((1e-13, False), (1e-11, True)):
            correlation = np.eye(d)
            correlation[0, 1] = correlation[1, 0] = math.sqrt(1.0 - ratio)  # det 1 − r²
            units = np.diag([2.0, 1e3, 5e-2][:d])
            J = units @ correlation @ units
            assert bool(regular_symmetric(J)) is regular
            assert np.isnan(inverse_symmetric(J)).all() is not regular
    rng = np.random.default_rng(4)
    matrices = rng.normal(size=(200, 2, 2))
    matrices = matrices @ np.swapaxes(matrices, 1, 2)
    matrices[::7, 1] = matrices[::7, 0]  # singular rows
    np.testing.assert_array_equal(regular_symmetric(matrices), regular_2x2(matrices))
    np.testing.assert_array_equal(inverse_symmetric(matrices), inverse_2x2(matrices))
    cubes = rng.normal(size=(200, 3, 3))
    cubes = cubes @ np.swapaxes(cubes, 1, 2)
    cubes[::5, 2] = cubes[::5, 0] + cubes[::5, 1]  # rank 2
    cubes[::5, :, 2] = cubes[::5, :, 0] + cubes[::5, :, 1]
    expected = np.linalg.det(cubes) > 1e-12 * np.abs(np.prod(np.diagonal(cubes, 0, 1, 2), 1))
    np.testing.assert_array_equal(regular_symmetric(cubes), expected)
    assert not regular_symmetric(cubes[::5]).any()
    blocked = INFORMATION_3D.copy()
    blocked[2, 2] = np.inf
    assert not regular_symmetric(np.stack([blocked, INFORMATION_3D * np.nan])).any()


# --------------------------------------------------------------------------------------------
# Fisher information → CRLB → bound columns
# --------------------------------------------------------------------------------------------


def finite_difference_crlb_3d(data, truth, used) -> np.ndarray:
    """The ``(x, y, z)`` block of the inverse of the Fisher matrix over ``(x, y, z, b)`` of the
    ToA of the ``used`` samples, one emission time ``b`` shared by them, every column by
    central differences of ``τ = ‖p − s‖/c + b``."""
    position = data.position_m[used]
    sigma, c = data.noise.toa_s, data.speed_of_light_mps

    def forward(theta: np.ndarray) -> np.ndarray:
        return (np.linalg.norm(position - theta[:3], axis=1) / c + theta[3]) / sigma

    theta = np.array([*truth, 0.0])
    steps = np.array([1e-3, 1e-3, 1e-3, 1e-12])
    jacobian = np.column_stack(
        [
            (forward(theta + step * e) - forward(theta - step * e)) / (2 * step)
            for step, e in zip(steps, np.eye(4), strict=True)
        ]
    )
    return np.linalg.inv(jacobian.T @ jacobian)[:3, :3]


def test_the_3d_bound_of_chosen_frames_with_an_unknown_emission_time() -> None:
    """Beacon-pass with the emission time unknown: the bound of frames 0 and 2, shared ``b``,
    from :func:`frame_statistics` through :func:`bound_columns`, against finite differences
    (rtol 1e-6) in the order of :func:`matrix_columns`."""
    scenario = get_scenario("beacon-pass").replace(unknowns=("emission_time_s",))
    data = noise_free(scenario)
    truth = np.array([*scenario.emitter_m, scenario.emitter_height_m])
    statistics = frame_statistics(data, truth, "toa")
    assert statistics.dimension == 3
    frames = (0, 2)
    last = int(data.frame.max())
    expected = finite_difference_crlb_3d(data, truth, np.isin(data.frame, frames))
    bound = bound_columns(statistics, last, frames)
    assert len(bound) == 1 + len(matrix_columns("crlb", 3))
    np.testing.assert_allclose(bound[1:], matrix_values(expected), rtol=1e-6)
    assert bound[0] == pytest.approx(math.sqrt(np.trace(expected)), rel=1e-6)
    assert information_of(statistics, last, frames).shape == (3, 3)
    assert np.isnan(bound_columns(None, last, frames, dimension=3)).all()
    assert information_of(None, 0, "all", dimension=3).shape == (3, 3)
    with pytest.raises(ValueError, match="dimension: the information is of 3 coordinates"):
        information_of(statistics, last, frames, dimension=2)


# --------------------------------------------------------------------------------------------
# scoring: errors in 3-D, NEES with 3 degrees of freedom, the mirror covariance
# --------------------------------------------------------------------------------------------


def test_a_3d_estimate_scored_against_a_3d_truth() -> None:
    """Truth on the far side of the track y = 0 (heading +x): the returned position is on the
    wrong side, the side-resolved candidate is its mirror and its NEES uses the covariance
    reflected across the track's vertical plane, ``diag(1, −1, 1) P diag(1, −1, 1)``."""
    truth = np.array([30.0, -20.0, 5.0])
    position = np.array([31.0, 22.0, 4.0])
    mirror = position * [1.0, -1.0, 1.0]
    estimate = Estimate(
        estimator="three",
        position_m=position,
        candidates_m=[position, mirror],
        ambiguous=True,
        covariance_m2=COVARIANCE_3D,
    )
    track = (np.array([0.0, 0.0]), np.array([1.0, 0.0]))
    outcomes = Outcomes.of_estimates([(estimate, 0.5)], dimension=3)
    row = dict(zip(ESTIMATE_COLUMNS, score_outcomes(outcomes, truth, track)[0], strict=True))
    error = position - truth
    assert row["error_m"] == pytest.approx(np.linalg.norm(error), rel=1e-15)
    assert row["nees"] == pytest.approx(error @ np.linalg.solve(COVARIANCE_3D, error), rel=1e-12)
    reflection = np.diag([1.0, -1.0, 1.0])
    side_error = mirror - truth
    reflected = reflection @ COVARIANCE_3D @ reflection
    assert row["nees_side_resolved"] == pytest.approx(
        side_error @ np.linalg.solve(reflected, side_error), rel=1e-12
    )
    assert row["error_side_resolved_m"] == pytest.approx(np.linalg.norm(side_error), rel=1e-15)
    assert (row["x_side_resolved_m"], row["y_side_resolved_m"]) == (31.0, -22.0)
    assert row["wrong_side"] == 1.0
    assert [row[name] for name in matrix_columns("cov", 2)] == [4.0, 1.0, 3.0]
    assert json.loads(row["candidates_json"]) == [position.tolist(), mirror.tolist()]
    flat = Estimate(
        estimator="two", position_m=[1.0, 2.0], candidates_m=[[1.0, 2.0]], ambiguous=False
    )
    refused = Outcomes.of_estimates([(flat, 0.1)], dimension=3).columns
    assert not refused.success[0] and refused.message(0).startswith("position_m: 2 coordinates")
    with pytest.raises(ValueError, match="truth_m: 2 coordinates but the estimates have 3"):
        score_outcomes(outcomes, truth[:2], track)


def test_the_3d_nees_of_a_whitened_error_is_its_squared_norm_and_chi_square_3() -> None:
    """``e = L z`` with ``P = L Lᵀ``: the NEES is ``‖z‖²`` to rounding; for standard normal
    ``z`` its mean over n lies in the χ²(3n)/n band of :func:`nees_band` with ``dof=3``."""
    rng = np.random.default_rng(21)
    n = 2000
    z = rng.standard_normal((n, 3))
    cholesky = np.linalg.cholesky(COVARIANCE_3D)
    nees = normalized_error_squared(z @ cholesky.T, np.broadcast_to(COVARIANCE_3D, (n, 3, 3)))
    np.testing.assert_allclose(nees, np.sum(z**2, axis=1), rtol=1e-11, atol=1e-14)
    low, high = nees_band(n, 0.95, dof=3)
    assert low == pytest.approx(stats.chi2.ppf(0.025, 3 * n) / n, rel=1e-12)
    assert high == pytest.approx(stats.chi2.ppf(0.975, 3 * n) / n, rel=1e-12)
    assert low <= nees.mean() <= high
    assert nees_band(n, 0.95, dof=2)[1] < low  # a 2-dof band would call it optimistic


# --------------------------------------------------------------------------------------------
# intervals in 3-D
# --------------------------------------------------------------------------------------------


def test_3d_principal_axis_errors_against_numpy_s_eigendecomposition() -> None:
    rng = np.random.default_rng(3)
    errors = rng.normal(size=(50, 3))
    crlb = np.stack([COVARIANCE_3D, np.diag([0.5, 2.0, 1.0])] * 25)
    squared = axis_squared_errors(errors, crlb)
    assert squared.shape == (50, 3)
    for i in (0, 1):
        values, vectors = np.linalg.eigh(crlb[i])
        expected = (vectors.T @ errors[i]) ** 2 / values
        np.testing.assert_allclose(squared[i], expected[::-1], rtol=1e-12)
    # the axes' terms add up to the NEES against the CRLB
    nees = normalized_error_squared(errors, crlb)
    np.testing.assert_allclose(squared.sum(axis=1), nees, rtol=1e-12)
    assert axis_names(3) == ("major", "middle", "minor")
    np.testing.assert_allclose(
        largest_eigenvalue(crlb[:2]), [np.linalg.eigvalsh(COVARIANCE_3D)[-1], 2.0], rtol=1e-14
    )


def test_the_3d_bias_interval_is_hotelling_s_with_3_degrees_of_freedom() -> None:
    rng = np.random.default_rng(9)
    errors = rng.multivariate_normal([0.3, -0.2, 0.5], COVARIANCE_3D, size=40)
    groups = np.repeat([0, 1], [37, 3])  # group 1: 3 errors, fewer than d + 1
    bias = bias_intervals(errors, groups, 2, np.array([2.0, 2.0]))
    first = errors[:37]
    mean = first.mean(axis=0)
    n = len(first)
    t2 = 3 * (n - 1) / (n - 3) * stats.f.ppf(0.95, 3, n - 3)
    reach = math.sqrt(t2 * np.linalg.eigvalsh(np.cov(first.T))[-1] / n)
    norm = np.linalg.norm(mean)
    np.testing.assert_allclose(bias.mean_m[0], mean, rtol=1e-12)
    assert bias.norm_m[0] == pytest.approx(norm, rel=1e-14)
    assert bias.low_m[0] == pytest.approx(max(norm - reach, 0.0), rel=1e-10)
    assert bias.high_m[0] == pytest.approx(norm + reach, rel=1e-10)
    assert np.isnan([bias.low_m[1], bias.high_m[1]]).all()


# --------------------------------------------------------------------------------------------
# the summary of 3-D trial rows
# --------------------------------------------------------------------------------------------


def trial_rows_3d(errors_m: np.ndarray, crlb_m2: np.ndarray, covariance_m2: np.ndarray):
    """Contract rows of 3-D errors (truth (35, 15, 7), not ambiguous) with the z columns."""
    rows = trial_rows(errors_m[:, :2], crlb_rmse_m=math.sqrt(np.trace(crlb_m2)))
    truth_z = 7.0
    rows["truth_z_m"] = truth_z
    rows["z_m"] = rows["z_side_resolved_m"] = truth_z + errors_m[:, 2]
    rows["error_m"] = rows["error_side_resolved_m"] = np.linalg.norm(errors_m, axis=1)
    inverse = np.linalg.inv(covariance_m2)
    rows["nees"] = rows["nees_side_resolved"] = np.einsum(
        "ni,ij,nj->n", errors_m, inverse, errors_m
    )
    for name, value in zip(matrix_columns("cov", 3), matrix_values(covariance_m2), strict=True):
        rows[name] = value
    for name, value in zip(matrix_columns("crlb", 3), matrix_values(crlb_m2), strict=True):
        rows[name] = value
    return rows


def test_the_summary_of_3d_rows() -> None:
    """Errors N(b, P) in 3-D scored against a CRLB diag(0.5, 2, 1): the NEES band has 3n
    degrees of freedom, the bias is the 3-D mean, the major axis is y and the minor x."""
    rng = np.random.default_rng(17)
    n = 600
    errors = rng.multivariate_normal([0.1, 0.0, -0.2], COVARIANCE_3D, size=n)
    crlb = np.diag([0.5, 2.0, 1.0])
    rows = trial_rows_3d(errors, crlb, COVARIANCE_3D)
    summary = summarize(rows, n_bootstrap=50)
    assert len(summary) == 1
    flat = summarize(trial_rows(errors[:, :2]), n_bootstrap=50)
    # the z columns are no swept parameter; the height's metrics join the 2-D ones
    keys = list(flat.columns[: -len(metric_names(2))])
    assert list(summary.columns) == [*keys, *metric_names(3)]
    row = summary.iloc[0]
    assert row["bias_z_m"] == pytest.approx(errors[:, 2].mean(), rel=1e-12)
    horizontal = math.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2))
    assert row["rmse_horizontal_m"] == pytest.approx(horizontal, rel=1e-12)
    assert row["rmse_vertical_m"] == pytest.approx(math.sqrt(np.mean(errors[:, 2] ** 2)), rel=1e-12)
    assert row["crlb_horizontal_m"] == pytest.approx(math.sqrt(2.5), rel=1e-12)
    assert row["crlb_vertical_m"] == pytest.approx(1.0, rel=1e-12)
    assert row["n_nees"] == n
    assert row["nees_band_low"] == pytest.approx(stats.chi2.ppf(0.025, 3 * n) / n, rel=1e-12)
    assert row["nees_band_high"] == pytest.approx(stats.chi2.ppf(0.975, 3 * n) / n, rel=1e-12)
    assert row["nees_verdict"] == "consistent"
    assert row["bias_judged_x_m"] == pytest.approx(errors[:, 0].mean(), rel=1e-12)
    assert row["bias_judged_m"] == pytest.approx(np.linalg.norm(errors.mean(axis=0)), rel=1e-12)
    assert row["efficiency_major_axis"] == pytest.approx(
        math.sqrt(np.mean(errors[:, 1] ** 2) / 2.0), rel=1e-12
    )
    assert row["efficiency_minor_axis"] == pytest.approx(
        math.sqrt(np.mean(errors[:, 0] ** 2) / 0.5), rel=1e-12
    )
    assert row["rmse_m"] == pytest.approx(math.sqrt(np.mean(np.sum(errors**2, axis=1))), rel=1e-12)


@pytest.mark.bits(
    "the same summary code (Groups) on the same rows with the same trial sets' seeds, whether "
    "the 3-D table is split into its 2-D and 3-D groups or the rows come alone"
)
def test_a_3d_run_summarises_horizontal_answers_in_2d_beside_the_3d_ones() -> None:
    """A 3-D table holding an estimator of 3-D answers and one that assumes the height (its
    rows without z and vertical bound): the second's summary row is, to the bit, the summary
    of its rows in a 2-D table (the same trials keep their bootstrap seeds), without the
    height's metrics; the first's is that of its rows alone; the rows keep the groups' order."""
    rng = np.random.default_rng(23)
    n = 200
    errors = rng.multivariate_normal([0.0, 0.0, 0.0], COVARIANCE_3D, size=n)
    crlb = np.diag([0.5, 2.0, 1.0])
    height = trial_rows_3d(errors, crlb, COVARIANCE_3D)
    assumed = trial_rows(errors[:, :2] + 3.0, estimator="assumes")
    for name in height.columns.difference(assumed.columns):
        assumed[name] = np.nan
    assumed["truth_z_m"] = 7.0
    mixed = pd.concat([assumed, height[assumed.columns]], ignore_index=True)
    summary = summarize(mixed, n_bootstrap=50)
    assert summary["estimator"].tolist() == ["assumes", "est"]
    alone = summarize(trial_rows(errors[:, :2] + 3.0, estimator="assumes"), n_bootstrap=50)
    left = summary.iloc[[0]][alone.columns].reset_index(drop=True)
    pd.testing.assert_frame_equal(left, alone, check_exact=True)
    height_only = ["bias_z_m", "rmse_vertical_m", "crlb_vertical_m"]  # and the whole is horizontal
    assert summary.iloc[0][height_only].isna().all()
    assert summary.iloc[0]["rmse_horizontal_m"] == summary.iloc[0]["rmse_m"]
    assert summary.iloc[0]["crlb_horizontal_m"] == summary.iloc[0]["crlb_rmse_m"]
    own = summarize(height[assumed.columns], n_bootstrap=50)
    pd.testing.assert_frame_equal(summary.iloc[[1]].reset_index(drop=True), own, check_exact=True)


# --------------------------------------------------------------------------------------------
# planners
# --------------------------------------------------------------------------------------------


def test_a_planner_s_covariance_has_the_dimension_of_its_candidates() -> None:
    np.testing.assert_array_equal(check_covariance(COVARIANCE_3D, 3), COVARIANCE_3D)
    with pytest.raises(ValueError) as error:
        check_covariance(COVARIANCE_3D)
    assert str(error.value).startswith("covariance_m2: expected a (2, 2) matrix or None")
    assert "\n" not in str(error.value)
