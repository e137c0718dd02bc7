"""The estimator conformance suite: small named checks that every estimator must pass.

Like scikit-learn's ``sklearn.utils.estimator_checks``, the suite ships inside the package so
that a plug-in author can run it on a new estimator::

    from estimators.checks import check_estimator
    check_estimator(MyEstimator())            # raises AssertionError listing every failure

or, in a pytest module, one test per (estimator, check) pair::

    from estimators.checks import parametrize_with_checks

    @parametrize_with_checks([MyEstimator(), MyEstimator(step_m=0.5)])
    def test_conformance(estimator, check):
        check(estimator)

A check is a function ``check_<what>(estimator)`` that returns nothing or raises
``AssertionError`` whose message names the problem and the fix. :func:`estimator_checks`
yields the checks that apply: the batch check only when the estimator has ``estimate_batch``,
the streaming checks only for a :class:`~estimators.base.SequentialEstimator`, the unit
check only when it claims ``unit_invariant``, the two-headings check only when it uses
every frame and the height checks only when it estimates the emitter's height. What an estimator uses and claims is read from its declared
:class:`~estimators.base.Capabilities` (:func:`~estimators.base.capabilities_of`), and the
checks hold it to that declaration. A check that an estimator fails *by design* is recorded
with its reason in ``expected_failed_checks={"check_name": "reason"}``; it then must fail (a
strict xfail), so the record cannot go stale.

Where things are
    :mod:`~estimators.checks.reference_problems`: the geometries with recorded optima, their data
    and the check seed (its docstring lists the problems); :mod:`~estimators.checks.tolerances`:
    how close is exact and what an estimator may declare (its docstring states every tolerance);
    :mod:`~estimators.checks.forward_model`: how well a candidate reproduces data, and the CRLB;
    :mod:`~estimators.checks.results`: running an estimator and judging its result; the checks by
    theme, :mod:`~estimators.checks.contract`, :mod:`~estimators.checks.exactness`,
    :mod:`~estimators.checks.invariance`, :mod:`~estimators.checks.noisy`,
    :mod:`~estimators.checks.height` and
    :mod:`~estimators.checks.batch_and_streaming`; :mod:`~estimators.checks.runner`: which checks
    apply, :func:`run_checks`, :func:`check_estimator`, :func:`parametrize_with_checks`.
    Everything public is importable from ``estimators.checks``.
"""

from __future__ import annotations

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
from estimators.checks.forward_model import crlb_rmse_m, data_misfit, whitened_misfit
from estimators.checks.height import (
    check_exact_with_the_height_unknown,
    check_straight_track_cannot_fix_the_height,
)
from estimators.checks.invariance import (
    check_equivariant_under_rigid_motions,
    check_unit_invariant,
    check_unused_modalities_ignored,
    check_uses_the_declared_frames,
    in_kilometres,
    moved,
    rigid_motions,
)
from estimators.checks.noisy import (
    check_estimate_moves_with_the_emitter,
    check_leaves_the_track,
    check_noisy_error_near_crlb,
)
from estimators.checks.reference_problems import (
    CHECK_SEED_ENV,
    DATA_SEED,
    HEIGHT_PROBLEMS,
    NOISE_FREE_SNR_DB,
    NOISY_SNR_DB,
    ON_TRACK_START_SHORTFALL_M,
    ON_TRACK_START_SNR_DB,
    RANDOM_PROBLEMS,
    REFERENCE_PROBLEMS,
    REFERENCE_SCENARIOS,
    RNG_SEED,
    ReferenceProblem,
    check_seed,
    degenerate_data,
    on_track_start_data,
    random_problem,
    reference_data,
    reference_problem,
    reference_problems,
    select_frames,
)
from estimators.checks.results import (
    FIELD_OF_MODALITY,
    constructor_parameters,
    failure_problems,
    params_of,
    result_problems,
)
from estimators.checks.runner import (
    CHECK_NAMES,
    CHECKS,
    CheckOutcome,
    EstimatorCheckError,
    check_estimator,
    estimator_checks,
    parametrize_with_checks,
    run_checks,
)
from estimators.checks.tolerances import (
    AGREEMENT_TOLERANCE_M,
    CRLB_FACTOR,
    CRLB_SNR_DB,
    CRLB_TRIALS,
    EXACT_RTOL,
    EXACT_TOLERANCE_M,
    MAX_NOISE_FREE_TOLERANCE,
    MISFIT_LIMIT,
    noise_free_tolerance_m,
    problem_tolerance_m,
    tolerance_cap_m,
)

__all__ = [
    "AGREEMENT_TOLERANCE_M",
    "CHECKS",
    "CHECK_NAMES",
    "CHECK_SEED_ENV",
    "CRLB_FACTOR",
    "CRLB_SNR_DB",
    "CRLB_TRIALS",
    "DATA_SEED",
    "EXACT_RTOL",
    "EXACT_TOLERANCE_M",
    "FIELD_OF_MODALITY",
    "HEIGHT_PROBLEMS",
    "MAX_NOISE_FREE_TOLERANCE",
    "MISFIT_LIMIT",
    "NOISE_FREE_SNR_DB",
    "NOISY_SNR_DB",
    "ON_TRACK_START_SHORTFALL_M",
    "ON_TRACK_START_SNR_DB",
    "RANDOM_PROBLEMS",
    "REFERENCE_PROBLEMS",
    "REFERENCE_SCENARIOS",
    "RNG_SEED",
    "CheckOutcome",
    "EstimatorCheckError",
    "ReferenceProblem",
    "check_batch_matches_single",
    "check_capabilities_declared",
    "check_class_attributes",
    "check_constructor_stores_params",
    "check_equivariant_under_rigid_motions",
    "check_estimate_deterministic",
    "check_estimate_does_not_modify_estimator",
    "check_estimate_does_not_modify_inputs",
    "check_estimate_ignores_truth",
    "check_estimate_moves_with_the_emitter",
    "check_estimator",
    "check_exact_far_from_origin",
    "check_exact_on_random_geometry",
    "check_exact_on_straight_frames",
    "check_exact_on_turn",
    "check_exact_with_climb",
    "check_exact_with_the_height_unknown",
    "check_failed_estimate_is_data",
    "check_leaves_the_track",
    "check_mirror_pair_reproduces_data",
    "check_missing_modality_raises",
    "check_noisy_error_near_crlb",
    "check_not_ambiguous_with_two_headings",
    "check_pickle_round_trip",
    "check_rejects_wrong_data_type",
    "check_rejects_wrong_rng_type",
    "check_repr_shows_params",
    "check_result_types",
    "check_seed",
    "check_sequential_update_is_pure",
    "check_straight_track_cannot_fix_the_height",
    "check_streaming_matches_estimate",
    "check_unit_invariant",
    "check_unused_modalities_ignored",
    "check_uses_the_declared_frames",
    "constructor_parameters",
    "crlb_rmse_m",
    "data_misfit",
    "degenerate_data",
    "estimator_checks",
    "failure_problems",
    "in_kilometres",
    "moved",
    "noise_free_tolerance_m",
    "on_track_start_data",
    "parametrize_with_checks",
    "params_of",
    "problem_tolerance_m",
    "random_problem",
    "reference_data",
    "reference_problem",
    "reference_problems",
    "result_problems",
    "rigid_motions",
    "run_checks",
    "select_frames",
    "tolerance_cap_m",
    "whitened_misfit",
]
