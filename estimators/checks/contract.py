"""The checks of the estimator contract: the constructor and the class, pickling, ``estimate``
as a pure and deterministic function, input validation and the result's types."""

from __future__ import annotations

import copy
import importlib
import json
import pickle
import re
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.base import Estimate
from estimators.checks.reference_problems import (
    FIXED_PROBLEMS,
    REFERENCE_PROBLEMS,
    degenerate_data,
    noisy_reference,
    reference_batch,
    reference_rng,
)
from estimators.checks.results import (
    FIELD_OF_MODALITY,
    check_failed,
    constructor_parameters,
    declared_capabilities,
    estimate_or_fail,
    failure_problems,
    is_sequential,
    object_state,
    params_of,
    require_success,
    result_differences,
    result_problems,
    same_value,
    streamed_estimate,
)
from estimators.checks.tolerances import (
    EXACT_TOLERANCE_M,
    MAX_NOISE_FREE_TOLERANCE,
    tolerance_cap_m,
)
from scenarios.types import MODALITIES

_FIELD_PREFIX = re.compile(r"^[A-Za-z_][\w.\[\]]*(?:(?:, |/)[A-Za-z_][\w.\[\]]*)*: ")


# --------------------------------------------------------------------------------------------
# the constructor and the class
# --------------------------------------------------------------------------------------------


def check_constructor_stores_params(estimator: Any) -> None:
    """The constructor only stores its keyword parameters, unchanged, under their own names.

    Introspects the signature (as scikit-learn's ``get_params`` does): no ``*args`` or
    ``**kwargs``; every parameter has a default (so ``make_estimator(name)`` works); building
    with the defaults stores each default itself; rebuilding with the stored values stores
    those very objects; and no other attribute is set.
    """
    cls = type(estimator)
    parameters = constructor_parameters(estimator)
    for p in parameters:
        if p.kind is p.VAR_POSITIONAL:
            check_failed(
                f"{cls.__name__}.__init__ takes *{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.kind is p.VAR_KEYWORD:
            check_failed(
                f"{cls.__name__}.__init__ takes **{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.default is p.empty:
            check_failed(
                f"parameter {p.name!r} has no default; give every option a default so that "
                "make_estimator(name) builds the estimator without options"
            )
        if not hasattr(estimator, p.name):
            check_failed(
                f"parameter {p.name!r} is not stored as the attribute {p.name!r}; store every "
                "constructor parameter unchanged under its own name"
            )
    names = {p.name for p in parameters}
    extra = sorted(set(object_state(estimator)) - names)
    if extra:
        check_failed(
            f"the constructor sets {extra}, which are not parameters; compute derived values "
            "inside estimate (or cache them at module level), the constructor only stores options"
        )
    defaults = cls()
    for p in parameters:
        stored = getattr(defaults, p.name)
        if not (
            stored is p.default
            or (type(stored) is type(p.default) and same_value(stored, p.default))
        ):
            check_failed(
                f"parameter {p.name!r}: the default {p.default!r} is stored as {stored!r}; store "
                "parameters unchanged (validate them, convert them inside estimate)"
            )
    params = params_of(estimator)
    rebuilt = cls(**params)
    for key, value in params.items():
        stored = getattr(rebuilt, key)
        if not (stored is value or (type(stored) is type(value) and same_value(stored, value))):
            check_failed(
                f"parameter {key!r}: {value!r} passed to the constructor is stored as "
                f"{stored!r}; store parameters unchanged (convert them inside estimate)"
            )


def check_repr_shows_params(estimator: Any) -> None:
    """``repr`` shows every parameter as ``name=value`` (a dataclass repr does)."""
    text = repr(estimator)
    missing = [f"{k}={v!r}" for k, v in params_of(estimator).items() if f"{k}={v!r}" not in text]
    if missing:
        check_failed(
            f"repr {text!r} does not show {missing}; make the estimator a dataclass or write a "
            "__repr__ listing every parameter as name=value"
        )


def check_class_attributes(estimator: Any) -> None:
    """``name`` (a str) and ``requires`` (a frozenset ⊆ {doppler, toa, rss}) are class attributes.

    A class attribute ``noise_free_tolerance_m`` (the old way to loosen the noise-free
    tolerance) is not read: it must be moved to ``capabilities()``.
    """
    cls = type(estimator)
    parameters = {p.name for p in constructor_parameters(estimator)}
    for attribute in ("name", "requires"):
        if attribute in parameters:
            check_failed(
                f"{attribute!r} is a constructor parameter; declare it as a class attribute "
                f"(typing.ClassVar in a dataclass)"
            )
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name or re.search(r"[\s:]", name):
        check_failed(
            f"name is {name!r}; declare name: ClassVar[str] = 'my-method', a non-empty string "
            "without spaces or ':' (':' marks module:Class paths)"
        )
    requires = getattr(cls, "requires", None)
    if not isinstance(requires, frozenset) or not requires <= set(MODALITIES):
        check_failed(
            f"requires is {requires!r}; declare requires: ClassVar[frozenset[str]] = "
            f"frozenset({{...}}) with modalities from {set(MODALITIES)}"
        )
    if hasattr(cls, "noise_free_tolerance_m"):
        value = cls.noise_free_tolerance_m
        declared = declared_capabilities(estimator).noise_free_tolerance_m
        if not (isinstance(value, int | float) and value == declared):
            check_failed(
                f"the class attribute noise_free_tolerance_m = {value!r} is not read (the "
                f"declared tolerance is {declared:g} m); declare it in capabilities(): "
                "Capabilities(..., noise_free_tolerance_m=..., tolerance_reason='why'), and "
                "remove the class attribute"
            )


def check_capabilities_declared(estimator: Any) -> None:
    """``capabilities()`` (or the default from the protocol) is consistent with the class.

    It returns a :class:`~estimators.base.Capabilities`; its modalities include ``requires``;
    ``batch`` and ``sequential`` match the methods present; every declared module imports; a
    ``noise_free_tolerance_m`` looser than :data:`EXACT_TOLERANCE_M` has a
    ``tolerance_reason`` and is at most :data:`MAX_NOISE_FREE_TOLERANCE` of the RMS slant
    range of every fixed reference problem.
    """
    capabilities = declared_capabilities(estimator)
    requires = frozenset(getattr(type(estimator), "requires", frozenset()))
    missing = sorted(requires - capabilities.modalities)
    if missing:
        check_failed(
            f"requires {sorted(requires)} but capabilities().modalities is "
            f"{sorted(capabilities.modalities)}, without {missing}; a required modality is "
            "used, so list it in Capabilities.modalities"
        )
    batch = callable(getattr(estimator, "estimate_batch", None))
    if capabilities.batch != batch:
        check_failed(
            f"capabilities().batch is {capabilities.batch} but the estimator "
            f"{'has' if batch else 'has no'} estimate_batch; declare batch={batch}"
        )
    sequential = is_sequential(estimator)
    if capabilities.sequential != sequential:
        check_failed(
            f"capabilities().sequential is {capabilities.sequential} but the estimator "
            f"{'has' if sequential else 'lacks'} init/update/estimate_state; declare "
            f"sequential={sequential}"
        )
    for module in capabilities.modules:
        try:
            importlib.import_module(module)
        except Exception as error:
            check_failed(
                f"capabilities().modules lists {module!r}, which does not import "
                f"({type(error).__name__}: {error}); install it, or list only the modules "
                "the estimator imports"
            )
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        check_failed(
            f"noise_free_tolerance_m = {declared:g} m is looser than the default "
            f"{EXACT_TOLERANCE_M:g} m without a tolerance_reason; say why the method is not "
            "exact (e.g. 'the refinement stops on a step of 1e-8 of the search radius'), or "
            "drop the declaration; until then the default applies"
        )
    for name in REFERENCE_PROBLEMS:
        problem = FIXED_PROBLEMS[name]()
        cap = tolerance_cap_m(problem)
        if declared > cap:
            check_failed(
                f"noise_free_tolerance_m = {declared:g} m exceeds the cap on {problem.label}: "
                f"{MAX_NOISE_FREE_TOLERANCE:g} of its RMS slant range {problem.rms_range_m():.1f}"
                f" m, i.e. {cap:.3g} m. A noise-free answer that far off is not exact: make "
                "the method converge (a tighter stopping tolerance, a local refinement) and "
                f"declare at most {cap:.3g} m; the checks use the cap meanwhile"
            )


def check_pickle_round_trip(estimator: Any) -> None:
    """The estimator pickles (worker processes need it); the copy has equal parameters and
    gives the same estimate as the original (when the original is itself deterministic)."""
    try:
        copy_ = pickle.loads(pickle.dumps(estimator))
    except Exception as error:
        check_failed(
            f"pickling failed ({type(error).__name__}: {error}); keep only picklable options "
            "on the estimator and build solver objects inside estimate"
        )
    if type(copy_) is not type(estimator):
        check_failed(f"unpickled a {type(copy_).__name__}, not a {type(estimator).__name__}")
    before, after = params_of(estimator), params_of(copy_)
    changed = sorted(k for k in before if not same_value(before[k], after.get(k)))
    if changed:
        check_failed(f"the unpickled copy has different parameters {changed}")
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        original = estimate_or_fail(estimator, noisy_reference(scenario), what, rng=reference_rng())
        again = estimate_or_fail(estimator, noisy_reference(scenario), what, rng=reference_rng())
        if not isinstance(original, Estimate) or result_differences(original, again, atol_m=None):
            continue  # not deterministic: check_estimate_deterministic reports it
        copied = estimate_or_fail(copy_, noisy_reference(scenario), what, rng=reference_rng())
        if not isinstance(copied, Estimate):
            check_failed(f"the unpickled copy returned {type(copied).__name__} on {what}")
        differences = result_differences(original, copied, atol_m=None)
        if differences:
            check_failed(
                f"the unpickled copy gives a different estimate on {what}: "
                f"{'; '.join(differences)}; an estimator's output may depend only on its "
                "parameters, the data and rng"
            )


# --------------------------------------------------------------------------------------------
# estimate as a pure function
# --------------------------------------------------------------------------------------------


def check_estimate_deterministic(estimator: Any) -> None:
    """The same data give the same estimate, bit for bit: twice without ``rng`` and twice with
    generators of the same seed (compare scikit-learn's ``check_fit_idempotent``)."""
    for scenario in ("paper-1m", "turn"):
        for seeded in (False, True):
            what = f"noisy '{scenario}' data" + (" with rng seeded alike" if seeded else "")
            first = estimate_or_fail(
                estimator, noisy_reference(scenario), what, rng=reference_rng() if seeded else None
            )
            second = estimate_or_fail(
                estimator, noisy_reference(scenario), what, rng=reference_rng() if seeded else None
            )
            require_success(first, what)
            differences = result_differences(first, second, atol_m=None)
            if differences:
                check_failed(
                    f"two calls on {what} differ: {'; '.join(differences)}; draw randomness "
                    "only from the rng argument and keep no state between calls"
                )


def check_estimate_does_not_modify_estimator(estimator: Any) -> None:
    """``estimate`` (and ``estimate_batch``, ``init``/``update``/``estimate_state``) leave
    every attribute of the estimator unchanged (compare scikit-learn's
    ``check_dict_unchanged``)."""
    before = object_state(estimator)
    for scenario in ("paper-1m", "turn"):
        estimate_or_fail(
            estimator, noisy_reference(scenario), f"noisy '{scenario}' data", rng=reference_rng()
        )
    if callable(getattr(estimator, "estimate_batch", None)):
        estimator.estimate_batch(reference_batch(), rngs=None)
    if is_sequential(estimator):
        streamed_estimate(estimator, noisy_reference("turn"), rng=reference_rng())
    after = object_state(estimator)
    changed = sorted(
        k for k in before.keys() | after.keys() if not same_value(before.get(k), after.get(k))
    )
    if changed:
        check_failed(
            f"estimating changed the estimator's attributes {changed}; keep results and caches "
            "out of the estimator (return them in the Estimate or a state value)"
        )


def _field_snapshot(data: Any) -> dict[str, tuple[Any, Any, bool | None]]:
    """``{field: (object, copy, writeable)}`` for every field of a data object."""
    snapshot = {}
    for field in data.__dataclass_fields__:
        value = getattr(data, field)
        writeable = value.flags.writeable if isinstance(value, np.ndarray) else None
        snapshot[field] = (value, copy.deepcopy(value), writeable)
    return snapshot


def _modified_fields(data: Any, snapshot: dict[str, tuple[Any, Any, bool | None]]) -> list[str]:
    changed = []
    for field, (original, saved, writeable) in snapshot.items():
        value = getattr(data, field)
        if value is not original:
            changed.append(f"{field} (replaced)")
        elif not same_value(value, saved):
            changed.append(f"{field} (values)")
        elif isinstance(value, np.ndarray) and value.flags.writeable != writeable:
            changed.append(f"{field} (made writeable)")
    return changed


def check_estimate_does_not_modify_inputs(estimator: Any) -> None:
    """``estimate`` changes no field of its :class:`MeasurementSet`: no array written in place,
    no flag flipped, no field replaced (``estimate_batch`` likewise for its batch)."""
    for scenario in ("paper-1m", "turn"):
        data = noisy_reference(scenario)
        snapshot = _field_snapshot(data)
        estimate_or_fail(estimator, data, f"noisy '{scenario}' data", rng=reference_rng())
        changed = _modified_fields(data, snapshot)
        if changed:
            check_failed(
                f"estimate modified its input on noisy '{scenario}' data: {changed}; work on "
                "copies (np.array(data.toa_s)) or on dataclasses.replace(data, ...)"
            )
    if callable(getattr(estimator, "estimate_batch", None)):
        batch = reference_batch()
        snapshot = _field_snapshot(batch)
        geometry = _field_snapshot(batch.geometry)
        estimator.estimate_batch(batch, rngs=None)
        changed = _modified_fields(batch, snapshot) + _modified_fields(batch.geometry, geometry)
        if changed:
            check_failed(f"estimate_batch modified its input batch: {changed}; work on copies")


def check_estimate_ignores_truth(estimator: Any) -> None:
    """The estimate does not depend on ``truth_emitter_m`` (simulations carry it; estimators
    must not read it): data with a wrong truth give the estimate of data without one."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        blind = estimate_or_fail(estimator, noisy_reference(scenario), what, rng=reference_rng())
        again = estimate_or_fail(estimator, noisy_reference(scenario), what, rng=reference_rng())
        if not isinstance(blind, Estimate) or result_differences(blind, again, atol_m=None):
            continue  # not deterministic: check_estimate_deterministic reports it
        told = replace(noisy_reference(scenario), truth_emitter_m=np.array([-1234.5, 678.9]))
        informed = estimate_or_fail(
            estimator, told, what + " with a truth attached", rng=reference_rng()
        )
        differences = result_differences(blind, informed, atol_m=None)
        if differences:
            check_failed(
                f"attaching a truth to {what} changed the estimate: {'; '.join(differences)}; "
                "never read data.truth_emitter_m inside an estimator"
            )


# --------------------------------------------------------------------------------------------
# input validation and results
# --------------------------------------------------------------------------------------------


def check_missing_modality_raises(estimator: Any) -> None:
    """Data without a required modality raise ``ValueError`` whose message starts with the
    missing field (``doppler_hz``, ``toa_s``, ``rss_dbm``); ``require_modalities`` does it."""
    for modality in sorted(getattr(type(estimator), "requires", ())):
        field = FIELD_OF_MODALITY[modality]
        data = noisy_reference().without(modality)
        try:
            estimator.estimate(data)
        except ValueError as error:
            head = str(error).split(": ", 1)[0]
            if field not in head:
                check_failed(
                    f"data without {field} raised ValueError({str(error)!r}); start the message "
                    f"with the field, '{field}: ...' (estimators.base.require_modalities)"
                )
            continue
        except Exception as error:
            check_failed(
                f"data without {field} raised {type(error).__name__}: {error}; raise ValueError "
                f"naming {field} (call estimators.base.require_modalities first)"
            )
        check_failed(
            f"data without {field} gave an estimate although requires contains {modality!r}; "
            "raise ValueError naming the field (estimators.base.require_modalities)"
        )


def check_rejects_wrong_data_type(estimator: Any) -> None:
    """Something that is not a :class:`MeasurementSet` (None, a dict, a path, a batch) raises
    ``TypeError`` or ``ValueError`` at once, not an ``AttributeError`` deep inside."""
    batch = reference_batch()
    for label, bad in (
        ("None", None),
        ("a dict", {"doppler_hz": [1.0, 2.0]}),
        ("a file name", "measurements.json"),
        ("a MeasurementBatch", batch),
    ):
        try:
            estimator.estimate(bad)
        except (TypeError, ValueError):
            continue
        except Exception as error:
            check_failed(
                f"estimate({label}) raised {type(error).__name__}: {error}; check the type "
                "first and raise TypeError('data: expected a MeasurementSet, ...') "
                "(estimators.base.require_modalities does)"
            )
        else:
            check_failed(
                f"estimate({label}) returned a result; it must raise TypeError or ValueError"
            )


def check_rejects_wrong_rng_type(estimator: Any) -> None:
    """An ``rng`` that is neither None nor a ``numpy.random.Generator`` raises ``TypeError``
    or ``ValueError`` (not an ``AttributeError``, and not silently ignored)."""
    try:
        estimator.estimate(noisy_reference(), rng="not a generator")
    except (TypeError, ValueError):
        return
    except Exception as error:
        check_failed(
            f"estimate(data, rng='not a generator') raised {type(error).__name__}: {error}; "
            "raise TypeError naming rng (estimators.base.check_rng)"
        )
    check_failed(
        "estimate(data, rng='not a generator') was accepted; raise TypeError naming rng "
        "(estimators.base.check_rng)"
    )


def check_result_types(estimator: Any) -> None:
    """The result is an :class:`Estimate` that the rules of :mod:`estimators.validity` accept
    (not refused when built, nor broken since): real numbers, ``position_m`` (2,) one of
    ``candidates_m`` (n, 2), ``covariance_m2`` (2, 2) symmetric positive semi-definite or None;
    and ``success`` bool, ``message`` str, ``diagnostics`` a mapping of JSON-able scalars (or
    flat lists of them), ``estimator`` equal to ``name``, several candidates only when
    ``ambiguous``. A refused estimate fails this check with the rule it broke."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        estimate = estimate_or_fail(estimator, noisy_reference(scenario), what, rng=reference_rng())
        problems = result_problems(estimate, estimator)
        if not problems and isinstance(estimate, Estimate):
            try:
                json.dumps(estimate.to_dict(), allow_nan=False)
            except (TypeError, ValueError) as error:
                problems.append(f"Estimate.to_dict() is not JSON ({error})")
        if problems:
            check_failed(f"on {what}: {'; '.join(problems)}")


def check_failed_estimate_is_data(estimator: Any) -> None:
    """Hopeless but valid data (a hovering UAV, ranges shorter than the height, one sample)
    give an :class:`Estimate` or a ``ValueError`` naming a field; a failed estimate has a NaN
    position, ``success=False`` and a message; a successful one a finite position.
    A sequential estimator's ``estimate_state(init())`` (no frame yet) must fail that way too.
    """
    outcomes: dict[str, Any] = {}
    for label, data in degenerate_data().items():
        try:
            outcomes[label] = estimator.estimate(data)
        except ValueError as error:
            if not _FIELD_PREFIX.match(str(error)):
                check_failed(
                    f"{label} data raised ValueError({str(error)!r}); start the message with "
                    "the field at fault and say the fix, e.g. 'velocity_mps: ...'"
                )
            continue
        except Exception as error:
            check_failed(
                f"{label} data raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, reason) or raise ValueError naming the field"
            )
    if is_sequential(estimator):
        try:
            before_any_frame = estimator.estimate_state(estimator.init())
        except Exception as error:
            check_failed(
                f"estimate_state(init()) raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        if getattr(before_any_frame, "success", None) is not False:
            check_failed(
                "estimate_state(init()) does not fail before any frame; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        outcomes["estimate_state(init())"] = before_any_frame
    for label, estimate in outcomes.items():
        problems = failure_problems(estimate)
        if problems:
            check_failed(f"on {label}: {'; '.join(problems)}")
