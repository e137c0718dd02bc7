"""Running the checks: which apply to an estimator, the outcomes, the one-call form and the
pytest parametrisation."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from estimators.base import Capabilities, capabilities_of
from estimators.checks.batch_and_streaming import (
    check_batch_matches_single,
    check_sequential_update_is_pure,
    check_streaming_matches_estimate,
)
from estimators.checks.contract import (
    check_capabilities_declared,
    check_class_attributes,
    check_constructor_stores_params,
    check_estimate_deterministic,
    check_estimate_does_not_modify_estimator,
    check_estimate_does_not_modify_inputs,
    check_estimate_ignores_truth,
    check_failed_estimate_is_data,
    check_missing_modality_raises,
    check_pickle_round_trip,
    check_rejects_wrong_data_type,
    check_rejects_wrong_rng_type,
    check_repr_shows_params,
    check_result_types,
)
from estimators.checks.exactness import (
    check_exact_far_from_origin,
    check_exact_on_random_geometry,
    check_exact_on_straight_frames,
    check_exact_on_turn,
    check_exact_with_climb,
    check_mirror_pair_reproduces_data,
    check_not_ambiguous_with_two_headings,
)
from estimators.checks.height import (
    check_exact_with_the_height_unknown,
    check_straight_track_cannot_fix_the_height,
)
from estimators.checks.invariance import (
    check_equivariant_under_rigid_motions,
    check_unit_invariant,
    check_unused_modalities_ignored,
    check_uses_the_declared_frames,
)
from estimators.checks.noisy import (
    check_estimate_moves_with_the_emitter,
    check_leaves_the_track,
    check_noisy_error_near_crlb,
)
from estimators.checks.results import constructor_parameters, is_sequential, same_value
from scenarios.nuisance import HEIGHT_UNKNOWN

Check = Callable[[Any], None]

CHECKS: tuple[Check, ...] = (
    check_constructor_stores_params,
    check_repr_shows_params,
    check_class_attributes,
    check_capabilities_declared,
    check_pickle_round_trip,
    check_estimate_deterministic,
    check_estimate_does_not_modify_estimator,
    check_estimate_does_not_modify_inputs,
    check_estimate_ignores_truth,
    check_exact_on_straight_frames,
    check_exact_on_turn,
    check_exact_far_from_origin,
    check_exact_with_climb,
    check_exact_on_random_geometry,
    check_mirror_pair_reproduces_data,
    check_not_ambiguous_with_two_headings,
    check_exact_with_the_height_unknown,
    check_straight_track_cannot_fix_the_height,
    check_equivariant_under_rigid_motions,
    check_unit_invariant,
    check_unused_modalities_ignored,
    check_uses_the_declared_frames,
    check_noisy_error_near_crlb,
    check_estimate_moves_with_the_emitter,
    check_leaves_the_track,
    check_missing_modality_raises,
    check_rejects_wrong_data_type,
    check_rejects_wrong_rng_type,
    check_result_types,
    check_failed_estimate_is_data,
    check_batch_matches_single,
    check_streaming_matches_estimate,
    check_sequential_update_is_pure,
)
"""Every check, in the order they run."""

CHECK_NAMES = tuple(check.__name__ for check in CHECKS)

_BATCH_CHECKS = frozenset({"check_batch_matches_single"})
_SEQUENTIAL_CHECKS = frozenset(
    {"check_streaming_matches_estimate", "check_sequential_update_is_pure"}
)
_HEIGHT_CHECKS = frozenset(
    {"check_exact_with_the_height_unknown", "check_straight_track_cannot_fix_the_height"}
)


def estimator_checks(estimator: Any) -> Iterator[Check]:
    """The checks that apply to ``estimator``: the batch and streaming ones only when it has
    those methods, the unit check only when it claims ``unit_invariant``, the two-headings
    check only when it declares ``frames="all"``, the height checks only when its
    ``Capabilities.unknowns`` contains ``"emitter_height_m"`` (a broken ``capabilities()`` runs
    them all but the unit and height checks, and ``check_capabilities_declared`` reports it)."""
    if isinstance(estimator, type):
        raise TypeError(
            f"estimator: got the class {estimator.__name__}; pass an instance, e.g. "
            f"{estimator.__name__}()"
        )
    batch = callable(getattr(estimator, "estimate_batch", None))
    sequential = is_sequential(estimator)
    try:
        capabilities: Capabilities | None = capabilities_of(estimator)
    except Exception:
        capabilities = None
    for check in CHECKS:
        if check.__name__ in _BATCH_CHECKS and not batch:
            continue
        if check.__name__ in _SEQUENTIAL_CHECKS and not sequential:
            continue
        if check is check_unit_invariant and not (capabilities and capabilities.unit_invariant):
            continue
        if check.__name__ in _HEIGHT_CHECKS and not (
            capabilities and HEIGHT_UNKNOWN in capabilities.unknowns
        ):
            continue
        if (
            check is check_not_ambiguous_with_two_headings
            and capabilities is not None
            and capabilities.frames != "all"
        ):
            continue
        yield check


def _expected(
    estimator: Any,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None,
) -> dict[str, str]:
    if expected_failed_checks is None:
        return {}
    reasons = (
        expected_failed_checks(estimator)
        if callable(expected_failed_checks)
        else expected_failed_checks
    )
    reasons = dict(reasons or {})
    unknown = sorted(set(reasons) - set(CHECK_NAMES))
    if unknown:
        raise ValueError(
            f"expected_failed_checks: unknown checks {unknown}; known: {', '.join(CHECK_NAMES)}"
        )
    return reasons


class EstimatorCheckError(AssertionError):
    """Raised by :func:`check_estimator`; ``failures`` maps each failed check to its message."""

    def __init__(self, estimator: Any, failures: dict[str, str], unexpected: list[str]) -> None:
        self.failures = failures
        self.unexpected_passes = unexpected
        lines = [f"{_estimator_id(estimator)} fails {len(failures)} conformance check(s):"]
        lines += [f"- {name}: {message}" for name, message in failures.items()]
        lines += [
            f"- {name}: expected to fail but passed; remove it from expected_failed_checks"
            for name in unexpected
        ]
        super().__init__("\n".join(lines))


@dataclass(frozen=True, slots=True)
class CheckOutcome:
    """The outcome of one check: ``passed``, or the failure message (and whether expected)."""

    name: str
    passed: bool
    message: str = ""
    expected_reason: str | None = None


def run_checks(
    estimator: Any,
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> list[CheckOutcome]:
    """Run every applicable check and return the outcomes (never raises for a failure)."""
    reasons = _expected(estimator, expected_failed_checks)
    outcomes = []
    for check in estimator_checks(estimator):
        try:
            check(estimator)
        except Exception as error:
            message = (
                str(error)
                if isinstance(error, AssertionError)
                else (f"{type(error).__name__}: {error}")
            )
            outcomes.append(
                CheckOutcome(check.__name__, False, message, reasons.get(check.__name__))
            )
        else:
            outcomes.append(CheckOutcome(check.__name__, True, "", reasons.get(check.__name__)))
    return outcomes


def check_estimator(
    estimator: Any,
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> list[CheckOutcome]:
    """Run every applicable check on ``estimator``; raise if any fails unexpectedly.

    Parameters
    ----------
    estimator : object
        An estimator instance (see :class:`estimators.base.Estimator`).
    expected_failed_checks : mapping or callable, optional
        ``{"check_name": "reason"}`` (or a function of the estimator returning one) for the
        checks the estimator fails by design; each must fail.

    Returns
    -------
    list of CheckOutcome
        Every check run, when none failed unexpectedly.

    Raises
    ------
    EstimatorCheckError
        An ``AssertionError`` listing every unexpected failure with what to fix, and every
        expected failure that passed.
    """
    outcomes = run_checks(estimator, expected_failed_checks=expected_failed_checks)
    failures = {o.name: o.message for o in outcomes if not o.passed and o.expected_reason is None}
    unexpected = [o.name for o in outcomes if o.passed and o.expected_reason is not None]
    if failures or unexpected:
        raise EstimatorCheckError(estimator, failures, unexpected)
    return outcomes


def _estimator_id(estimator: Any) -> str:
    """``Class(option=value, ...)`` with the options that differ from their defaults."""
    try:
        changed = []
        for p in constructor_parameters(estimator):
            if p.default is not p.empty and hasattr(estimator, p.name):
                value = getattr(estimator, p.name)
                if not same_value(value, p.default):
                    changed.append(f"{p.name}={value!r}")
    except (TypeError, ValueError):
        changed = []
    return f"{type(estimator).__name__}({', '.join(changed)})"


def parametrize_with_checks(
    estimators: Iterable[Any],
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> Any:
    """A ``pytest.mark.parametrize`` over every (estimator, applicable check) pair.

    Test ids read ``Class(non-default options)-check_name``. Checks listed in
    ``expected_failed_checks`` (a mapping, or a function of the estimator returning one) are
    marked ``xfail(strict=True)`` with the recorded reason: they must fail.

    Examples
    --------
    >>> @parametrize_with_checks([MyEstimator()])          # doctest: +SKIP
    ... def test_conformance(estimator, check):
    ...     check(estimator)
    """
    import pytest

    params = []
    for estimator in estimators:
        reasons = _expected(estimator, expected_failed_checks)
        for check in estimator_checks(estimator):
            marks = []
            if check.__name__ in reasons:
                marks.append(pytest.mark.xfail(strict=True, reason=reasons[check.__name__]))
            params.append(
                pytest.param(
                    estimator, check, id=f"{_estimator_id(estimator)}-{check.__name__}", marks=marks
                )
            )
    return pytest.mark.parametrize("estimator, check", params)
