"""The validity rules of an estimate (estimators/validity.py), in both places they apply.

Each rule on one :class:`Estimate`, at its tolerance from both sides; the columns of
:class:`BatchEstimates` refuse exactly the trials that the one-estimate path refuses, with the
same message (one function, vectorised, for both); the conformance suite names the rule a
plug-in breaks; and no built-in's covariance of a nearly singular problem is refused.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest

from estimators.base import Estimate
from estimators.batch import BatchEstimates
from estimators.checks import check_result_types
from estimators.closed_form.cls import Cls
from estimators.registry import make_estimator
from estimators.validity import COVARIANCE_RTOL, INVALID, POSITION_RTOL
from scenarios.catalog import get_scenario
from scenarios.parameters import with_parameters
from scenarios.simulate import simulate


def one(position, candidates, covariance=None, *, success=True, message="note") -> Estimate:
    return Estimate(
        estimator="x",
        position_m=position,
        candidates_m=candidates,
        ambiguous=len(candidates) > 1,
        covariance_m2=covariance,
        success=success,
        message=message,
        diagnostics={"iterations": 4},
    )


def assert_refused(estimate: Estimate, start: str) -> None:
    """A failed estimate: NaN position, no candidates or covariance, ``start`` then the
    estimator's own message; its diagnostics kept."""
    assert estimate.success is False and estimate.ambiguous is False
    assert np.isnan(estimate.position_m).all() and estimate.candidates_m.shape == (0, 2)
    assert estimate.covariance_m2 is None
    assert estimate.message.startswith(INVALID + start), estimate.message
    assert estimate.message.endswith("; note"), estimate.message
    assert estimate.diagnostics == {"iterations": 4}


# --------------------------------------------------------------------------------------------
# each rule
# --------------------------------------------------------------------------------------------


def test_a_position_931_m_from_both_candidates_is_refused():
    estimate = one([966.0, 15.0], [[35.0, 15.0], [35.0, -15.0]])
    assert_refused(
        estimate,
        "position_m (966, 15) is not one of its candidates_m (35, 15); (35, -15): 931 m from "
        "the nearest (tolerance 9.66e-07 m)",
    )


@pytest.mark.parametrize("where", [(0.3, 0.2), (2400.0, -1300.0), (-3.0e6, 5.0e6)])
def test_the_position_tolerance_is_relative_to_the_coordinates(where):
    """Within ``POSITION_RTOL × max(1 m, |x|, |y|)`` of a candidate: kept; twice that: refused."""
    candidate = np.array(where)
    limit = POSITION_RTOL * max(1.0, np.abs(candidate).max())
    kept = one(candidate + np.array([0.5 * limit, 0.0]), [candidate])
    assert kept.success and kept.message == "note"
    assert_refused(one(candidate + np.array([0.0, 2.0 * limit]), [candidate]), "position_m (")


def test_a_success_without_candidates_is_refused():
    assert_refused(one([1.0, 2.0], np.empty((0, 2))), "candidates_m is empty, so position_m")


def test_a_negative_definite_covariance_is_refused_with_its_smallest_eigenvalue():
    """``−[[4, 1], [1, 3]]``: eigenvalues −(7 ± √5)/2, the smallest −4.618; norm √27."""
    estimate = one([1.0, 2.0], [[1.0, 2.0]], -np.array([[4.0, 1.0], [1.0, 3.0]]))
    smallest = -(7.0 + np.sqrt(5.0)) / 2.0
    assert_refused(
        estimate,
        "covariance_m2 is not symmetric positive semi-definite (smallest eigenvalue "
        f"{smallest:.3g} m²; tolerance 1e-09 of its norm, {np.sqrt(27.0):.3g} m²)",
    )


def test_a_non_symmetric_covariance_is_refused():
    estimate = one([1.0, 2.0], [[1.0, 2.0]], [[4.0, 1.0], [3.0, 3.0]])
    assert_refused(
        estimate,
        "covariance_m2 is not symmetric positive semi-definite (covariance_m2[0, 1] = 1 but "
        "covariance_m2[1, 0] = 3 m²",
    )


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e12])
def test_the_covariance_tolerance_is_relative_to_its_norm(scale):
    """An eigenvalue of −0.5 × tolerance (singular to rounding) and an asymmetry of 0.5 ×
    tolerance are kept; twice the tolerance is refused (‖diag(1, 0)‖ = 1, times ``scale``)."""
    t = COVARIANCE_RTOL * scale
    kept = one([0.0, 0.0], [[0.0, 0.0]], [[scale, 0.5 * t], [0.0, -0.5 * t]])
    assert kept.success and kept.covariance_m2 is not None
    negative = one([0.0, 0.0], [[0.0, 0.0]], [[scale, 0.0], [0.0, -2.0 * t]])
    assert_refused(negative, "covariance_m2 is not symmetric positive semi-definite (smallest")
    skew = one([0.0, 0.0], [[0.0, 0.0]], [[scale, 2.0 * t], [0.0, scale]])
    assert_refused(skew, "covariance_m2 is not symmetric positive semi-definite (covariance_m2")


def test_a_partly_non_finite_covariance_is_refused_and_an_all_nan_one_is_none():
    assert_refused(
        one([0.0, 0.0], [[0.0, 0.0]], [[1.0, np.inf], [np.inf, 1.0]]),
        "covariance_m2 is not finite (1, inf, inf, 1)",
    )
    assert_refused(
        one([0.0, 0.0], [[0.0, 0.0]], [[1.0, 0.0], [0.0, np.nan]]),
        "covariance_m2 is not finite",
    )
    none = one([0.0, 0.0], [[0.0, 0.0]], np.full((2, 2), np.nan))  # the columns' "none"
    assert none.success and np.isnan(none.covariance_m2).all()


@pytest.mark.parametrize(
    ("field", "value", "start"),
    [
        ("position_m", np.array([1 + 2j, 3]), "position_m is not real (1+2j, 3+0j)"),
        ("position_m", [1 + 2j, 3], "position_m is not real (1+2j, 3+0j)"),
        ("candidates_m", [[1, 3], [1 - 1e-9j, -3]], "candidates_m is not real (1+0j, 3+0j)"),
        ("covariance_m2", [[1, 1j], [-1j, 1]], "covariance_m2 is not real (1+0j, 0+1j"),
    ],
)
def test_a_complex_value_is_refused_never_cast(field, value, start):
    fields = {"position_m": [1.0, 3.0], "candidates_m": [[1.0, 3.0], [1.0, -3.0]]}
    fields["covariance_m2"] = np.eye(2)
    fields[field] = value
    assert_refused(one(*fields.values()), start)
    failed = one(*fields.values(), success=False)  # a failure holds no complex value either
    assert_refused(failed, start)


def test_a_complex_value_with_a_zero_imaginary_part_is_its_real_value():
    estimate = one(np.array([1 + 0j, 3]), np.array([[1 + 0j, 3]]), np.eye(2) + 0j)
    assert estimate.success and estimate.message == "note"
    assert estimate.position_m.dtype == np.float64 and estimate.covariance_m2.dtype == np.float64
    np.testing.assert_array_equal(estimate.position_m, [1.0, 3.0])


def test_a_failure_is_checked_for_real_numbers_only():
    """A failure's position is NaN and nothing of it is scored: its candidates and a
    covariance that is not PSD are kept as reported."""
    failed = one([np.nan, np.nan], [[5.0, 6.0]], -np.eye(2), success=False)
    assert failed.message == "note" and failed.candidates_m.shape == (1, 2)
    assert failed.covariance_m2 is not None


def test_non_numbers_raise_naming_the_field():
    with pytest.raises(ValueError, match=r"^position_m: expected numbers, got"):
        one(["a", "b"], [[1.0, 2.0]])


# --------------------------------------------------------------------------------------------
# columns: the same rules, every trial at once
# --------------------------------------------------------------------------------------------


def random_trials(rng: np.random.Generator, n: int) -> list[dict]:
    """Trials valid or broken in every way the rules name, in random proportions."""
    trials = []
    for _ in range(n):
        position = rng.normal(size=2) * 10.0 ** rng.integers(-2, 7)
        candidates = np.array([position, position * [1.0, -1.0]])
        factor = rng.normal(size=(2, 2))
        covariance = factor @ factor.T * 10.0 ** rng.integers(-3, 8)
        success = bool(rng.random() < 0.9)
        kind = int(rng.integers(12))
        if kind == 1:
            position = position + rng.normal(size=2) * 10.0 ** rng.integers(-12, 3)
        elif kind == 2:
            covariance = -covariance
        elif kind == 3:
            covariance = covariance + np.array([[0.0, 1.0], [0.0, 0.0]]) * np.abs(covariance).max()
        elif kind == 4:
            position = position + np.array([0.0, 1j * rng.normal()])
        elif kind == 5:
            candidates = candidates + np.array([[0.0, 0.0], [1j, 0.0]])
        elif kind == 6:
            position = position * np.nan
        elif kind == 7:
            candidates = candidates[:0]
        elif kind == 8:
            covariance = np.full((2, 2), np.nan)
        elif kind == 9:
            covariance = covariance * [[1.0, np.inf], [np.inf, 1.0]]
        trials.append(
            {"position": position, "candidates": candidates, "cov": covariance, "ok": success}
        )
    return trials


def columns_of(trials: list[dict]) -> BatchEstimates:
    n, k = len(trials), 2
    position = np.zeros((n, 2), dtype=complex)
    candidates = np.full((n, k, 2), np.nan, dtype=complex)
    covariance = np.zeros((n, 2, 2), dtype=complex)
    count = np.zeros(n, dtype=np.int64)
    for i, trial in enumerate(trials):
        position[i] = trial["position"]
        count[i] = len(trial["candidates"])
        candidates[i, : count[i]] = trial["candidates"]
        covariance[i] = trial["cov"]
    return BatchEstimates(
        estimator="x",
        position_m=position,
        candidates_m=candidates,
        n_candidates=count,
        ambiguous=count > 1,
        success=np.array([trial["ok"] for trial in trials]),
        message_code=np.arange(n) % 2,
        messages=("note", "other"),
        covariance_m2=covariance,
    )


def test_columns_refuse_the_trials_an_estimate_refuses_with_the_same_message():
    trials = random_trials(np.random.default_rng(5), 600)
    columns = columns_of(trials)
    assert columns.position_m.dtype == np.float64 and columns.covariance_m2.dtype == np.float64
    refused = 0
    for i, trial in enumerate(trials):
        alone = Estimate(
            estimator="x",
            position_m=np.asarray(trial["position"], dtype=complex),
            candidates_m=np.asarray(trial["candidates"], dtype=complex).reshape(-1, 2),
            ambiguous=len(trial["candidates"]) > 1,
            covariance_m2=np.asarray(trial["cov"], dtype=complex),
            success=trial["ok"],
            message=("note", "other")[i % 2],
        )
        column = columns.estimate(i)
        assert column.message == alone.message, i
        assert column.success == alone.success
        refused += alone.message.startswith(INVALID)
        if alone.success:
            np.testing.assert_array_equal(column.position_m, alone.position_m)
            np.testing.assert_array_equal(column.candidates_m, alone.candidates_m)
        else:
            assert columns.n_candidates[i] == 0 or not alone.message.startswith(INVALID)
    assert 200 < refused < 500  # every kind drawn, valid trials too


def test_valid_columns_are_kept_as_they_are():
    """Nothing refused, floats given: the very arrays, made read-only (not copied)."""
    n = 50
    position = np.random.default_rng(1).normal(size=(n, 2)) * 1e3
    candidates = np.stack([position, position * [1.0, -1.0]], axis=1)
    columns = BatchEstimates(
        estimator="x",
        position_m=position,
        candidates_m=candidates,
        n_candidates=np.full(n, 2),
        ambiguous=np.ones(n, dtype=bool),
        success=np.ones(n, dtype=bool),
        message_code=np.zeros(n, dtype=np.int64),
        messages=("",),
    )
    assert columns.position_m is position and not position.flags.writeable
    assert columns.success.all()


# --------------------------------------------------------------------------------------------
# the conformance suite and the built-ins
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class NegativeCovariance:
    """``cls`` reporting ``−I`` as its covariance."""

    name: ClassVar[str] = "negative-covariance"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})

    def estimate(self, data, *, rng=None):
        return dataclasses.replace(
            Cls().estimate(data, rng=rng), estimator=self.name, covariance_m2=-np.eye(2)
        )


def test_the_conformance_suite_names_the_rule_a_plugin_breaks():
    with pytest.raises(AssertionError) as failure:
        check_result_types(NegativeCovariance())
    text = str(failure.value)
    assert "the Estimate was refused, 'invalid estimate: covariance_m2 is not symmetric" in text
    assert "smallest eigenvalue -1 m²" in text and "docs/writing-an-estimator.md" in text


def test_the_conformance_suite_names_a_rule_broken_after_the_estimate_was_built():
    estimate = Cls().estimate(simulate(get_scenario("turn"), snr_db=30.0, seed=1))
    object.__setattr__(estimate, "position_m", estimate.position_m + np.array([931.0, 0.0]))

    class Changed(NegativeCovariance):
        name: ClassVar[str] = "cls"

        def estimate(self, data, *, rng=None):
            return estimate

    with pytest.raises(AssertionError, match=r"is not one of its candidates_m .* 931 m from"):
        check_result_types(Changed())


@pytest.mark.parametrize("name", ["ml", "ekf"])
@pytest.mark.parametrize("snr_db", [0.0, 90.0])
def test_no_builtin_covariance_of_a_nearly_singular_problem_is_refused(name, snr_db):
    """An emitter 2.2×10⁵ m from a 3-sample frame: covariances of condition number above 10⁶
    (MATH §8), kept as reported."""
    world = with_parameters(
        get_scenario("paper-1m"),
        {"emitter_x_m": 2e5, "emitter_y_m": -1e5, "samples_per_frame": 3},
    )
    conditions = []
    for seed in range(4):
        data = simulate(world, snr_db=snr_db, seed=seed).without_truth()
        estimate = make_estimator(name).estimate(data, rng=np.random.default_rng(seed))
        assert not estimate.message.startswith(INVALID), estimate.message
        if estimate.covariance_m2 is not None and np.isfinite(estimate.covariance_m2).all():
            conditions.append(np.linalg.cond(estimate.covariance_m2))
    assert conditions and max(conditions) > 1e6
