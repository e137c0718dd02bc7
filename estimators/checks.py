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
yields the checks that apply (the batch check only when the estimator has ``estimate_batch``,
the streaming checks only for a :class:`~estimators.base.SequentialEstimator`).
A check that an estimator fails *by design* is recorded with its reason in
``expected_failed_checks={"check_name": "reason"}``; it then must fail (a strict xfail), so the
record cannot go stale.

Reference data
    Named scenarios of :mod:`scenarios.catalog` (MATH §14): ``paper-1m`` (one straight frame),
    ``turn`` (east, then north) and ``orbit`` (12 headings). *Noise-free* data are exact
    measurements labelled with the σ's of :data:`NOISE_FREE_SNR_DB` = 100 dB (MATH §2), the
    limit of vanishing noise, so that weights and de-biasing factors that depend on σ are
    those of noise-free data. *Noisy* data are one seeded trial at :data:`NOISY_SNR_DB`. Every
    call gets freshly built data, so that a check never sees what another call did to them.

Tolerances
    An exact method must put a candidate within :data:`EXACT_TOLERANCE_M` = 1e-6 m of the
    emitter on noise-free data. An iterative or biased method (a grid search, a method with a
    stopping tolerance) declares a looser bound as a class attribute
    ``noise_free_tolerance_m: ClassVar[float]``, documented in its docstring. Batch and
    streaming results must agree with ``estimate`` within :data:`AGREEMENT_TOLERANCE_M` (or that
    declared bound, if looser). Diagnostics whose key names a time (``*time*_s``, e.g.
    ``solve_time_s``) are exempt from the equality checks.
"""

from __future__ import annotations

import copy
import inspect
import json
import math
import pickle
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any

import numpy as np

from estimators.base import Estimate
from scenarios.catalog import get_scenario
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.simulate import noise_free, simulate, simulate_trials
from scenarios.types import MODALITIES, MeasurementBatch, MeasurementSet

Check = Callable[[Any], None]

EXACT_TOLERANCE_M = 1e-6
"""Default distance (m) from the emitter within which a noise-free candidate counts as exact."""

AGREEMENT_TOLERANCE_M = 1e-6
"""Distance (m) within which batch or streaming positions must equal ``estimate``'s."""

NOISE_FREE_SNR_DB = 100.0
"""The SNR whose σ's label the noise-free reference data (MATH §2): vanishing noise."""

NOISY_SNR_DB = 10.0
"""The SNR of the noisy reference trials."""

DATA_SEED = 20_240_601
"""Seed of the noisy reference trials."""

RNG_SEED = 7
"""Seed of the tie-breaking generators the checks pass as ``rng``."""

REFERENCE_SCENARIOS = ("paper-1m", "turn", "orbit")
"""The named scenarios of the noise-free checks: one straight frame, two headings, an orbit."""

FIELD_OF_MODALITY = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_dbm"}
"""The :class:`~scenarios.types.MeasurementSet` field of each modality."""

_FIELD_PREFIX = re.compile(r"^[A-Za-z_][\w.\[\]]*(?:(?:, |/)[A-Za-z_][\w.\[\]]*)*: ")


# --------------------------------------------------------------------------------------------
# reference data
# --------------------------------------------------------------------------------------------


def reference_data(
    scenario: str = "paper-1m", *, noisy: bool = False, frames: int | None = None
) -> tuple[MeasurementSet, np.ndarray]:
    """Fresh reference measurements (truth removed) and the true emitter position (2,).

    Parameters
    ----------
    scenario : str
        A name of :data:`scenarios.catalog.CATALOG`, e.g. one of :data:`REFERENCE_SCENARIOS`.
    noisy : bool
        False: the exact measurements labelled with the σ's of :data:`NOISE_FREE_SNR_DB`.
        True: one trial at :data:`NOISY_SNR_DB` drawn from :data:`DATA_SEED`.
    frames : int or None
        Frames flown (None: the scenario's own).
    """
    built = get_scenario(scenario, frames=frames)
    if noisy:
        data = simulate(built, snr_db=NOISY_SNR_DB, seed=DATA_SEED)
    else:
        data = noise_free(built, snr_db=NOISE_FREE_SNR_DB)
    return data.without_truth(), np.array(built.emitter_m, dtype=float)


def _noisy(scenario: str = "paper-1m", frames: int | None = None) -> MeasurementSet:
    return reference_data(scenario, noisy=True, frames=frames)[0]


def _rng() -> np.random.Generator:
    return np.random.default_rng(RNG_SEED)


def degenerate_data() -> dict[str, MeasurementSet]:
    """Valid but hopeless measurement sets: what a failure path must handle as data.

    ``hovering``: every sample at one point with zero velocity (no Doppler, no baseline);
    ``short-ranges``: every ToA range (1 m) shorter than the UAV's 50 m height;
    ``one-sample``: a single sample.
    """
    data = _noisy()
    n = data.n_samples
    return {
        "hovering": replace(
            data,
            position_m=np.tile(data.position_m[0], (n, 1)),
            velocity_mps=np.zeros((n, 3)),
            doppler_hz=np.zeros(n),
        ),
        "short-ranges": replace(data, toa_s=np.full(n, 1.0 / data.speed_of_light_mps)),
        "one-sample": data.take(np.arange(n) == 0),
    }


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------


def _name_of(estimator: Any) -> str:
    return str(getattr(estimator, "name", type(estimator).__name__))


def _fail(message: str) -> None:
    raise AssertionError(" ".join(message.split()))


def _run(
    estimator: Any,
    data: MeasurementSet,
    what: str,
    *,
    rng: np.random.Generator | None = None,
) -> Any:
    """``estimator.estimate(data, rng=rng)``; an exception becomes a failure naming ``what``."""
    try:
        return estimator.estimate(data, rng=rng)
    except Exception as error:
        raise AssertionError(
            f"estimate raised {type(error).__name__} on {what}: {error}; valid data must give an "
            "Estimate (a failure to estimate is Estimate.failed(...), not an exception)"
        ) from error


def _succeeded(estimate: Any, what: str) -> None:
    if not isinstance(estimate, Estimate):
        _fail(
            f"estimate returned {type(estimate).__name__} on {what}, not an "
            "estimators.base.Estimate; build the result with Estimate(...) or finalize_estimate"
        )
    if not estimate.success:
        _fail(f"estimate failed on {what} (message: {estimate.message!r}); it should succeed there")


def constructor_parameters(estimator: Any) -> list[inspect.Parameter]:
    """The parameters of ``type(estimator)``'s constructor, ``self`` excluded."""
    return list(inspect.signature(type(estimator)).parameters.values())


def params_of(estimator: Any) -> dict[str, Any]:
    """``{parameter: stored value}`` for every constructor parameter stored under its name."""
    return {
        p.name: getattr(estimator, p.name)
        for p in constructor_parameters(estimator)
        if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and hasattr(estimator, p.name)
    }


def noise_free_tolerance_m(estimator: Any) -> float:
    """The estimator's declared ``noise_free_tolerance_m``, else :data:`EXACT_TOLERANCE_M`."""
    value = getattr(type(estimator), "noise_free_tolerance_m", EXACT_TOLERANCE_M)
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        return EXACT_TOLERANCE_M
    return float(value) if math.isfinite(value) else EXACT_TOLERANCE_M


def _agreement_m(estimator: Any) -> float:
    return max(AGREEMENT_TOLERANCE_M, noise_free_tolerance_m(estimator))


def _same(a: Any, b: Any) -> bool:
    """Deep equality for parameters and states: arrays by value, dtype and shape; NaN == NaN."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return False
        if a.shape != b.shape or a.dtype != b.dtype:
            return False
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if type(a) is not type(b):
        return False
    if isinstance(a, Mapping):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return True
    try:
        return bool(a == b)
    except Exception:
        return False


def _object_state(obj: Any) -> dict[str, Any]:
    """Every instance attribute (``__dict__`` and ``__slots__``), deep-copied."""
    state = dict(getattr(obj, "__dict__", {}))
    for klass in type(obj).__mro__:
        slots = klass.__dict__.get("__slots__", ())
        for slot in (slots,) if isinstance(slots, str) else slots:
            if slot not in ("__dict__", "__weakref__") and hasattr(obj, slot):
                state[slot] = getattr(obj, slot)
    return copy.deepcopy(state)


def _estimate_differences(a: Estimate, b: Estimate, *, atol_m: float | None) -> list[str]:
    """How two estimates differ: bit for bit (``atol_m=None``) or within ``atol_m``.

    With a tolerance, candidates compare as sets and messages and diagnostics are ignored;
    without, everything but timing diagnostics must be identical.
    """
    out = []
    for field in ("estimator", "success", "ambiguous"):
        if getattr(a, field) != getattr(b, field):
            out.append(f"{field} {getattr(a, field)!r} vs {getattr(b, field)!r}")
    pa, pb = np.asarray(a.position_m, dtype=float), np.asarray(b.position_m, dtype=float)
    ca = np.asarray(a.candidates_m, dtype=float).reshape(-1, 2)
    cb = np.asarray(b.candidates_m, dtype=float).reshape(-1, 2)
    if atol_m is None:
        if not _same(pa, pb):
            out.append(f"position_m {pa.tolist()} vs {pb.tolist()}")
        if not _same(ca, cb):
            out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()}")
        ka, kb = a.covariance_m2, b.covariance_m2
        if (ka is None) != (kb is None) or (ka is not None and not _same(ka, kb)):
            out.append("covariance_m2 differs")
        if a.message != b.message:
            out.append(f"message {a.message!r} vs {b.message!r}")
        da = {k: v for k, v in dict(a.diagnostics).items() if not _is_timing(k)}
        db = {k: v for k, v in dict(b.diagnostics).items() if not _is_timing(k)}
        keys = sorted(k for k in da.keys() | db.keys() if not _same(da.get(k), db.get(k)))
        if keys:
            out.append(f"diagnostics {keys} differ")
        return out
    if pa.shape != pb.shape or not np.allclose(pa, pb, rtol=0.0, atol=atol_m, equal_nan=True):
        out.append(f"position_m {pa.tolist()} vs {pb.tolist()} (tolerance {atol_m:g} m)")
    if ca.shape != cb.shape or not np.allclose(
        _sorted_rows(ca), _sorted_rows(cb), rtol=0.0, atol=atol_m
    ):
        out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()} (tolerance {atol_m:g} m)")
    return out


def _is_timing(key: Any) -> bool:
    """A diagnostics key naming a time in seconds (``solve_time_s``): exempt from equality."""
    return isinstance(key, str) and "time" in key and key.endswith("_s")


def _sorted_rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort((points[:, 0], points[:, 1]))] if len(points) else points


def _is_json_scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | bool | int | float | np.bool_ | np.number)


def result_problems(estimate: Any, estimator: Any) -> list[str]:
    """Everything wrong with one result's types, shapes and consistency (empty: conforms)."""
    if not isinstance(estimate, Estimate):
        return [_not_an_estimate(estimate)]
    problems = []
    name = getattr(estimator, "name", None)
    if estimate.estimator != name:
        problems.append(
            f"estimator is {estimate.estimator!r} but the class name is {name!r}; "
            "pass self.name to Estimate/finalize_estimate"
        )
    position = estimate.position_m
    if not isinstance(position, np.ndarray) or position.shape != (2,):
        problems.append(
            f"position_m has shape {np.shape(position)}; expected (2,): (x_s, y_s) in metres, "
            "the emitter height is known (MATH §0)"
        )
    candidates = estimate.candidates_m
    if not isinstance(candidates, np.ndarray) or candidates.ndim != 2 or candidates.shape[1] != 2:
        problems.append(f"candidates_m has shape {np.shape(candidates)}; expected (n, 2)")
    if type(estimate.ambiguous) is not bool:
        problems.append(f"ambiguous is {type(estimate.ambiguous).__name__}; expected bool")
    problems += _covariance_problems(estimate.covariance_m2)
    problems += _diagnostics_problems(estimate.diagnostics)
    problems += failure_problems(estimate)
    if problems or not estimate.success:
        return problems
    if len(candidates) == 0:
        problems.append("candidates_m is empty on a success; it must hold position_m (MATH §7)")
    else:
        scale = 1e-9 * max(1.0, float(np.max(np.abs(position))))
        if np.min(np.linalg.norm(candidates - position, axis=1)) > scale:
            problems.append(
                f"position_m {position.tolist()} is not among candidates_m "
                f"{candidates.tolist()}; the returned position is one of the candidates"
            )
    if len(candidates) > 1 and not estimate.ambiguous:
        problems.append(
            f"{len(candidates)} equal-cost candidates but ambiguous is False; several "
            "candidates mean the data cannot choose (MATH §7)"
        )
    return problems


def failure_problems(estimate: Any) -> list[str]:
    """What breaks "a failed estimate is data": ``success`` a bool, ``message`` a str, a NaN
    position and a message when it failed, a finite position when it succeeded."""
    if not isinstance(estimate, Estimate):
        return [_not_an_estimate(estimate)]
    if type(estimate.success) is not bool:
        return [f"success is {type(estimate.success).__name__}; expected bool"]
    if not isinstance(estimate.message, str):
        return [f"message is {type(estimate.message).__name__}; expected str"]
    position = np.asarray(estimate.position_m, dtype=float)
    if not estimate.success:
        problems = []
        if not np.all(np.isnan(position)):
            problems.append(
                f"success is False but position_m is {position.tolist()}; a failed estimate "
                "has a NaN position (use Estimate.failed)"
            )
        if not estimate.message.strip():
            problems.append("success is False with an empty message; say why it failed")
        return problems
    if not np.all(np.isfinite(position)):
        return [
            f"success is True but position_m is {position.tolist()}; return "
            "Estimate.failed(name, reason) when there is no finite answer"
        ]
    return []


def _not_an_estimate(result: Any) -> str:
    return (
        f"returned {type(result).__name__}, not an estimators.base.Estimate; build the "
        "result with Estimate(...), Estimate.failed(...) or finalize_estimate(...)"
    )


def _covariance_problems(covariance: Any) -> list[str]:
    if covariance is None:
        return []
    matrix = np.asarray(covariance)
    if matrix.shape != (2, 2) or matrix.dtype.kind != "f":
        return [f"covariance_m2 has shape {matrix.shape}; expected a (2, 2) float array or None"]
    if not np.all(np.isfinite(matrix)):
        return ["covariance_m2 has non-finite entries; report None when there is no covariance"]
    scale = float(np.max(np.abs(matrix))) or 1.0
    if abs(matrix[0, 1] - matrix[1, 0]) > 1e-9 * scale:
        return ["covariance_m2 is not symmetric; symmetrise it, 0.5 * (P + P.T)"]
    if np.min(np.linalg.eigvalsh(matrix)) < -1e-9 * scale:
        return [
            f"covariance_m2 is not positive semi-definite (eigenvalues "
            f"{np.linalg.eigvalsh(matrix).tolist()}); report None when it is not a covariance"
        ]
    return []


def _diagnostics_problems(diagnostics: Any) -> list[str]:
    if not isinstance(diagnostics, Mapping):
        return [f"diagnostics is {type(diagnostics).__name__}; expected a mapping"]
    problems = []
    for key, value in diagnostics.items():
        if not isinstance(key, str):
            problems.append(f"diagnostics key {key!r} is not a string")
        elif not (
            _is_json_scalar(value)
            or (isinstance(value, list | tuple) and all(_is_json_scalar(v) for v in value))
        ):
            problems.append(
                f"diagnostics[{key!r}] is {type(value).__name__}; diagnostics hold JSON-able "
                "scalars (str, bool, int, float, None) or flat lists of them"
            )
    return problems


# --------------------------------------------------------------------------------------------
# the checks: the constructor and the class
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
            _fail(
                f"{cls.__name__}.__init__ takes *{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.kind is p.VAR_KEYWORD:
            _fail(
                f"{cls.__name__}.__init__ takes **{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.default is p.empty:
            _fail(
                f"parameter {p.name!r} has no default; give every option a default so that "
                "make_estimator(name) builds the estimator without options"
            )
        if not hasattr(estimator, p.name):
            _fail(
                f"parameter {p.name!r} is not stored as the attribute {p.name!r}; store every "
                "constructor parameter unchanged under its own name"
            )
    names = {p.name for p in parameters}
    extra = sorted(set(_object_state(estimator)) - names)
    if extra:
        _fail(
            f"the constructor sets {extra}, which are not parameters; compute derived values "
            "inside estimate (or cache them at module level), the constructor only stores options"
        )
    defaults = cls()
    for p in parameters:
        stored = getattr(defaults, p.name)
        if not (
            stored is p.default or (type(stored) is type(p.default) and _same(stored, p.default))
        ):
            _fail(
                f"parameter {p.name!r}: the default {p.default!r} is stored as {stored!r}; store "
                "parameters unchanged (validate them, convert them inside estimate)"
            )
    params = params_of(estimator)
    rebuilt = cls(**params)
    for key, value in params.items():
        stored = getattr(rebuilt, key)
        if not (stored is value or (type(stored) is type(value) and _same(stored, value))):
            _fail(
                f"parameter {key!r}: {value!r} passed to the constructor is stored as "
                f"{stored!r}; store parameters unchanged (convert them inside estimate)"
            )


def check_repr_shows_params(estimator: Any) -> None:
    """``repr`` shows every parameter as ``name=value`` (a dataclass repr does)."""
    text = repr(estimator)
    missing = [f"{k}={v!r}" for k, v in params_of(estimator).items() if f"{k}={v!r}" not in text]
    if missing:
        _fail(
            f"repr {text!r} does not show {missing}; make the estimator a dataclass or write a "
            "__repr__ listing every parameter as name=value"
        )


def check_class_attributes(estimator: Any) -> None:
    """``name`` (a str) and ``requires`` (a frozenset ⊆ {doppler, toa, rss}) are class attributes.

    An optional ``noise_free_tolerance_m`` must be a positive finite number.
    """
    cls = type(estimator)
    parameters = {p.name for p in constructor_parameters(estimator)}
    for attribute in ("name", "requires", "noise_free_tolerance_m"):
        if attribute in parameters:
            _fail(
                f"{attribute!r} is a constructor parameter; declare it as a class attribute "
                f"(typing.ClassVar in a dataclass)"
            )
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name or re.search(r"[\s:]", name):
        _fail(
            f"name is {name!r}; declare name: ClassVar[str] = 'my-method', a non-empty string "
            "without spaces or ':' (':' marks module:Class paths)"
        )
    requires = getattr(cls, "requires", None)
    if not isinstance(requires, frozenset) or not requires <= set(MODALITIES):
        _fail(
            f"requires is {requires!r}; declare requires: ClassVar[frozenset[str]] = "
            f"frozenset({{...}}) with modalities from {set(MODALITIES)}"
        )
    if hasattr(cls, "noise_free_tolerance_m"):
        value = cls.noise_free_tolerance_m
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not (math.isfinite(value) and value > 0)
        ):
            _fail(
                f"noise_free_tolerance_m is {value!r}; declare a positive finite number of metres"
            )


def check_pickle_round_trip(estimator: Any) -> None:
    """The estimator pickles (worker processes need it); the copy has equal parameters and
    gives the same estimate as the original (when the original is itself deterministic)."""
    try:
        copy_ = pickle.loads(pickle.dumps(estimator))
    except Exception as error:
        _fail(
            f"pickling failed ({type(error).__name__}: {error}); keep only picklable options "
            "on the estimator and build solver objects inside estimate"
        )
    if type(copy_) is not type(estimator):
        _fail(f"unpickled a {type(copy_).__name__}, not a {type(estimator).__name__}")
    before, after = params_of(estimator), params_of(copy_)
    changed = sorted(k for k in before if not _same(before[k], after.get(k)))
    if changed:
        _fail(f"the unpickled copy has different parameters {changed}")
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        original = _run(estimator, _noisy(scenario), what, rng=_rng())
        again = _run(estimator, _noisy(scenario), what, rng=_rng())
        if not isinstance(original, Estimate) or _estimate_differences(
            original, again, atol_m=None
        ):
            continue  # not deterministic: check_estimate_deterministic reports it
        copied = _run(copy_, _noisy(scenario), what, rng=_rng())
        if not isinstance(copied, Estimate):
            _fail(f"the unpickled copy returned {type(copied).__name__} on {what}")
        differences = _estimate_differences(original, copied, atol_m=None)
        if differences:
            _fail(
                f"the unpickled copy gives a different estimate on {what}: "
                f"{'; '.join(differences)}; an estimator's output may depend only on its "
                "parameters, the data and rng"
            )


# --------------------------------------------------------------------------------------------
# the checks: estimate as a pure function
# --------------------------------------------------------------------------------------------


def check_estimate_deterministic(estimator: Any) -> None:
    """The same data give the same estimate, bit for bit: twice without ``rng`` and twice with
    generators of the same seed (compare scikit-learn's ``check_fit_idempotent``)."""
    for scenario in ("paper-1m", "turn"):
        for seeded in (False, True):
            what = f"noisy '{scenario}' data" + (" with rng seeded alike" if seeded else "")
            first = _run(estimator, _noisy(scenario), what, rng=_rng() if seeded else None)
            second = _run(estimator, _noisy(scenario), what, rng=_rng() if seeded else None)
            _succeeded(first, what)
            differences = _estimate_differences(first, second, atol_m=None)
            if differences:
                _fail(
                    f"two calls on {what} differ: {'; '.join(differences)}; draw randomness "
                    "only from the rng argument and keep no state between calls"
                )


def check_estimate_does_not_modify_estimator(estimator: Any) -> None:
    """``estimate`` (and ``estimate_batch``, ``init``/``update``/``estimate_state``) leave
    every attribute of the estimator unchanged (compare scikit-learn's
    ``check_dict_unchanged``)."""
    before = _object_state(estimator)
    for scenario in ("paper-1m", "turn"):
        _run(estimator, _noisy(scenario), f"noisy '{scenario}' data", rng=_rng())
    if callable(getattr(estimator, "estimate_batch", None)):
        estimator.estimate_batch(_batch(), rngs=None)
    if _is_sequential(estimator):
        _stream(estimator, _noisy("turn"), rng=_rng())
    after = _object_state(estimator)
    changed = sorted(
        k for k in before.keys() | after.keys() if not _same(before.get(k), after.get(k))
    )
    if changed:
        _fail(
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
        elif not _same(value, saved):
            changed.append(f"{field} (values)")
        elif isinstance(value, np.ndarray) and value.flags.writeable != writeable:
            changed.append(f"{field} (made writeable)")
    return changed


def check_estimate_does_not_modify_inputs(estimator: Any) -> None:
    """``estimate`` changes no field of its :class:`MeasurementSet`: no array written in place,
    no flag flipped, no field replaced (``estimate_batch`` likewise for its batch)."""
    for scenario in ("paper-1m", "turn"):
        data = _noisy(scenario)
        snapshot = _field_snapshot(data)
        _run(estimator, data, f"noisy '{scenario}' data", rng=_rng())
        changed = _modified_fields(data, snapshot)
        if changed:
            _fail(
                f"estimate modified its input on noisy '{scenario}' data: {changed}; work on "
                "copies (np.array(data.toa_s)) or on dataclasses.replace(data, ...)"
            )
    if callable(getattr(estimator, "estimate_batch", None)):
        batch = _batch()
        snapshot = _field_snapshot(batch)
        geometry = _field_snapshot(batch.geometry)
        estimator.estimate_batch(batch, rngs=None)
        changed = _modified_fields(batch, snapshot) + _modified_fields(batch.geometry, geometry)
        if changed:
            _fail(f"estimate_batch modified its input batch: {changed}; work on copies")


def check_estimate_ignores_truth(estimator: Any) -> None:
    """The estimate does not depend on ``truth_emitter_m`` (simulations carry it; estimators
    must not read it): data with a wrong truth give the estimate of data without one."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        blind = _run(estimator, _noisy(scenario), what, rng=_rng())
        again = _run(estimator, _noisy(scenario), what, rng=_rng())
        if not isinstance(blind, Estimate) or _estimate_differences(blind, again, atol_m=None):
            continue  # not deterministic: check_estimate_deterministic reports it
        told = replace(_noisy(scenario), truth_emitter_m=np.array([-1234.5, 678.9]))
        informed = _run(estimator, told, what + " with a truth attached", rng=_rng())
        differences = _estimate_differences(blind, informed, atol_m=None)
        if differences:
            _fail(
                f"attaching a truth to {what} changed the estimate: {'; '.join(differences)}; "
                "never read data.truth_emitter_m inside an estimator"
            )


# --------------------------------------------------------------------------------------------
# the checks: answers on reference scenarios (MATH §7, §14)
# --------------------------------------------------------------------------------------------


def _check_exact(estimator: Any, scenario: str) -> None:
    data, truth = reference_data(scenario)
    what = f"noise-free '{scenario}' data"
    estimate = _run(estimator, data, what)
    _succeeded(estimate, what)
    tolerance = noise_free_tolerance_m(estimator)
    candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    if len(candidates) == 0:
        _fail(f"no candidate on {what}; candidates_m must hold every equal-cost minimiser")
    distance = np.linalg.norm(candidates - truth, axis=1)
    nearest = int(np.argmin(distance))
    if not distance[nearest] <= tolerance:
        _fail(
            f"no candidate within {tolerance:g} m of the emitter {truth.tolist()} on {what}: "
            f"the nearest, {candidates[nearest].tolist()}, is {distance[nearest]:.3g} m away. "
            "Noise-free data determine the emitter (up to its mirror image); an iterative or "
            "biased method may declare a looser class attribute noise_free_tolerance_m"
        )


def check_exact_on_noise_free_straight_frame(estimator: Any) -> None:
    """On one straight noise-free frame (``paper-1m``) a candidate is the emitter, within
    ``noise_free_tolerance_m`` (default 1e-6 m)."""
    _check_exact(estimator, "paper-1m")


def check_exact_on_noise_free_turn(estimator: Any) -> None:
    """On noise-free data with two headings (``turn``) a candidate is the emitter."""
    _check_exact(estimator, "turn")


def check_exact_on_noise_free_orbit(estimator: Any) -> None:
    """On noise-free data of a 12-frame orbit (``orbit``) a candidate is the emitter."""
    _check_exact(estimator, "orbit")


def check_mirror_pair_on_straight_frame(estimator: Any) -> None:
    """One straight frame: ``ambiguous`` is True and every candidate comes with its mirror
    image across the track (MATH §7: every likelihood is mirror-symmetric there).

    A candidate on the track is its own mirror image. ``finalize_estimate`` adds the mirrors.
    """
    tolerance = _agreement_m(estimator)
    for label, data in (
        ("noise-free", reference_data("paper-1m")[0]),
        ("noisy", _noisy("paper-1m")),
    ):
        what = f"one straight frame ({label} 'paper-1m')"
        estimate = _run(estimator, data, what)
        _succeeded(estimate, what)
        if estimate.ambiguous is not True:
            _fail(
                f"ambiguous is {estimate.ambiguous!r} on {what}; one straight frame cannot tell "
                "the side of the track (MATH §7): report ambiguous=True (finalize_estimate does)"
            )
        line = straight_track_line(data.position_m, data.velocity_mps)
        assert line is not None  # the reference frame is straight
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        mirrors = mirror_across_line(candidates, *line)
        for point, mirror in zip(candidates, mirrors, strict=True):
            if np.min(np.linalg.norm(candidates - mirror, axis=1)) > tolerance:
                _fail(
                    f"on {what} the candidate {point.tolist()} comes without its mirror image "
                    f"{mirror.tolist()} across the track; report both mirror candidates "
                    "(MATH §7; finalize_estimate adds them)"
                )


def check_not_ambiguous_with_two_headings(estimator: Any) -> None:
    """Noise-free data with a second heading (``turn``, ``orbit``) resolve the side: the
    estimate is not ``ambiguous`` (MATH §7)."""
    for scenario in ("turn", "orbit"):
        what = f"noise-free '{scenario}' data"
        estimate = _run(estimator, reference_data(scenario)[0], what)
        _succeeded(estimate, what)
        if estimate.ambiguous is not False:
            _fail(
                f"ambiguous is {estimate.ambiguous!r} on {what} (candidates "
                f"{np.asarray(estimate.candidates_m).tolist()}); a second heading removes the "
                "mirror ambiguity (MATH §7): use every frame, and report one candidate"
            )


# --------------------------------------------------------------------------------------------
# the checks: input validation and results
# --------------------------------------------------------------------------------------------


def check_missing_modality_raises(estimator: Any) -> None:
    """Data without a required modality raise ``ValueError`` whose message starts with the
    missing field (``doppler_hz``, ``toa_s``, ``rss_dbm``); ``require_modalities`` does it."""
    for modality in sorted(getattr(type(estimator), "requires", ())):
        field = FIELD_OF_MODALITY[modality]
        data = _noisy().without(modality)
        try:
            estimator.estimate(data)
        except ValueError as error:
            head = str(error).split(": ", 1)[0]
            if field not in head:
                _fail(
                    f"data without {field} raised ValueError({str(error)!r}); start the message "
                    f"with the field, '{field}: ...' (estimators.base.require_modalities)"
                )
            continue
        except Exception as error:
            _fail(
                f"data without {field} raised {type(error).__name__}: {error}; raise ValueError "
                f"naming {field} (call estimators.base.require_modalities first)"
            )
        _fail(
            f"data without {field} gave an estimate although requires contains {modality!r}; "
            "raise ValueError naming the field (estimators.base.require_modalities)"
        )


def check_requires_is_enough(estimator: Any) -> None:
    """Data with only the ``requires`` modalities give an estimate (or a ``ValueError``
    naming a removed field, e.g. an option that needs RSS): ``requires`` lists all it reads."""
    requires = set(getattr(type(estimator), "requires", ()))
    removed = [m for m in MODALITIES if m not in requires]
    data = _noisy().without(*removed)
    try:
        estimator.estimate(data)
    except ValueError as error:
        head = str(error).split(": ", 1)[0]
        if any(FIELD_OF_MODALITY[m] in head for m in removed):
            return
        _fail(
            f"data with only {sorted(requires)} raised ValueError({str(error)!r}); add every "
            "modality estimate reads to requires"
        )
    except Exception as error:
        _fail(
            f"data with only {sorted(requires)} raised {type(error).__name__}: {error}; add "
            "every modality estimate reads to requires"
        )


def check_rejects_wrong_data_type(estimator: Any) -> None:
    """Something that is not a :class:`MeasurementSet` (None, a dict, a path, a batch) raises
    ``TypeError`` or ``ValueError`` at once, not an ``AttributeError`` deep inside."""
    batch = _batch()
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
            _fail(
                f"estimate({label}) raised {type(error).__name__}: {error}; check the type "
                "first and raise TypeError('data: expected a MeasurementSet, ...') "
                "(estimators.base.require_modalities does)"
            )
        else:
            _fail(f"estimate({label}) returned a result; it must raise TypeError or ValueError")


def check_rejects_wrong_rng_type(estimator: Any) -> None:
    """An ``rng`` that is neither None nor a ``numpy.random.Generator`` raises ``TypeError``
    or ``ValueError`` (not an ``AttributeError``, and not silently ignored)."""
    try:
        estimator.estimate(_noisy(), rng="not a generator")
    except (TypeError, ValueError):
        return
    except Exception as error:
        _fail(
            f"estimate(data, rng='not a generator') raised {type(error).__name__}: {error}; "
            "raise TypeError naming rng (estimators.base.check_rng)"
        )
    _fail(
        "estimate(data, rng='not a generator') was accepted; raise TypeError naming rng "
        "(estimators.base.check_rng)"
    )


def check_result_types(estimator: Any) -> None:
    """The result is an :class:`Estimate`: ``position_m`` (2,) among ``candidates_m`` (n, 2),
    ``covariance_m2`` (2, 2) symmetric PSD or None, ``success`` bool, ``message`` str,
    ``diagnostics`` a mapping of JSON-able scalars (or flat lists of them), ``estimator``
    equal to ``name``, several candidates only when ``ambiguous``."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        estimate = _run(estimator, _noisy(scenario), what, rng=_rng())
        problems = result_problems(estimate, estimator)
        if not problems and isinstance(estimate, Estimate):
            try:
                json.dumps(estimate.to_dict(), allow_nan=False)
            except (TypeError, ValueError) as error:
                problems.append(f"Estimate.to_dict() is not JSON ({error})")
        if problems:
            _fail(f"on {what}: {'; '.join(problems)}")


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
                _fail(
                    f"{label} data raised ValueError({str(error)!r}); start the message with "
                    "the field at fault and say the fix, e.g. 'velocity_mps: ...'"
                )
            continue
        except Exception as error:
            _fail(
                f"{label} data raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, reason) or raise ValueError naming the field"
            )
    if _is_sequential(estimator):
        try:
            before_any_frame = estimator.estimate_state(estimator.init())
        except Exception as error:
            _fail(
                f"estimate_state(init()) raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        if getattr(before_any_frame, "success", None) is not False:
            _fail(
                "estimate_state(init()) does not fail before any frame; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        outcomes["estimate_state(init())"] = before_any_frame
    for label, estimate in outcomes.items():
        problems = failure_problems(estimate)
        if problems:
            _fail(f"on {label}: {'; '.join(problems)}")


# --------------------------------------------------------------------------------------------
# the checks: optional capabilities
# --------------------------------------------------------------------------------------------


def _batch() -> MeasurementBatch:
    """Four noisy trials of one straight frame (``paper-1m``)."""
    scenario = get_scenario("paper-1m")
    seeds = np.random.SeedSequence(DATA_SEED).spawn(4)
    batch = simulate_trials(scenario, snr_db=NOISY_SNR_DB, seeds=seeds)
    return replace(batch, geometry=batch.geometry.without_truth())


def _is_sequential(estimator: Any) -> bool:
    return all(callable(getattr(estimator, m, None)) for m in ("init", "update", "estimate_state"))


def _stream(estimator: Any, data: MeasurementSet, *, rng: np.random.Generator | None) -> Any:
    state = estimator.init()
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
    return estimator.estimate_state(state, rng=rng)


def check_batch_matches_single(estimator: Any) -> None:
    """``estimate_batch`` returns one estimate per trial, each equal (within the agreement
    tolerance) to ``estimate`` on that trial with the same ``rng``."""
    batch = _batch()
    rngs = [np.random.default_rng(RNG_SEED + i) for i in range(batch.n_trials)]
    results = list(estimator.estimate_batch(batch, rngs=rngs))
    if len(results) != batch.n_trials:
        _fail(f"estimate_batch returned {len(results)} estimates for {batch.n_trials} trials")
    for index, result in enumerate(results):
        problems = result_problems(result, estimator)
        if problems:
            _fail(f"estimate_batch, trial {index}: {'; '.join(problems)}")
        single = _run(
            estimator,
            batch.trial(index),
            f"trial {index}",
            rng=np.random.default_rng(RNG_SEED + index),
        )
        differences = _estimate_differences(result, single, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"estimate_batch differs from estimate on trial {index}: "
                f"{'; '.join(differences)}; a trial's result may not depend on its batch"
            )


def check_streaming_matches_estimate(estimator: Any) -> None:
    """``init``, ``update`` per frame of ``iter_frames`` and ``estimate_state`` give
    ``estimate``'s answer (within the agreement tolerance), with and without a turn."""
    for scenario, frames in (("turn", None), ("paper-1m", 2)):
        data = _noisy(scenario, frames)
        what = f"noisy '{scenario}' data, {data.frames.size} frames"
        whole = _run(estimator, data, what, rng=_rng())
        streamed = _stream(estimator, _noisy(scenario, frames), rng=_rng())
        problems = result_problems(streamed, estimator)
        if problems:
            _fail(f"estimate_state on {what}: {'; '.join(problems)}")
        differences = _estimate_differences(whole, streamed, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"streaming differs from estimate on {what}: {'; '.join(differences)}; "
                "estimate(data) should equal init/update over data.iter_frames()/estimate_state"
            )


def check_sequential_update_is_pure(estimator: Any) -> None:
    """``update(state, frame)`` returns a new state and leaves ``state`` usable: updating one
    state twice gives the same estimate, and an old state still gives its old estimate."""
    frames = list(_noisy("turn").iter_frames())
    first = estimator.update(estimator.init(), frames[0])
    before = estimator.estimate_state(first, rng=_rng())
    second = estimator.update(first, frames[1])
    again = estimator.update(first, frames[1])
    for label, a, b in (
        (
            "the first state after a second update",
            before,
            estimator.estimate_state(first, rng=_rng()),
        ),
        (
            "two updates of the same state",
            estimator.estimate_state(second, rng=_rng()),
            estimator.estimate_state(again, rng=_rng()),
        ),
    ):
        differences = _estimate_differences(a, b, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"{label} changed the estimate: {'; '.join(differences)}; update must return "
                "a new state and never modify the one it is given (an optax-style pure pair)"
            )


# --------------------------------------------------------------------------------------------
# running the checks
# --------------------------------------------------------------------------------------------

CHECKS: tuple[Check, ...] = (
    check_constructor_stores_params,
    check_repr_shows_params,
    check_class_attributes,
    check_pickle_round_trip,
    check_estimate_deterministic,
    check_estimate_does_not_modify_estimator,
    check_estimate_does_not_modify_inputs,
    check_estimate_ignores_truth,
    check_exact_on_noise_free_straight_frame,
    check_exact_on_noise_free_turn,
    check_exact_on_noise_free_orbit,
    check_mirror_pair_on_straight_frame,
    check_not_ambiguous_with_two_headings,
    check_missing_modality_raises,
    check_requires_is_enough,
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


def estimator_checks(estimator: Any) -> Iterator[Check]:
    """The checks that apply to ``estimator`` (batch and streaming ones only when it has them)."""
    if isinstance(estimator, type):
        raise TypeError(
            f"estimator: got the class {estimator.__name__}; pass an instance, e.g. "
            f"{estimator.__name__}()"
        )
    batch = callable(getattr(estimator, "estimate_batch", None))
    sequential = _is_sequential(estimator)
    for check in CHECKS:
        if check.__name__ in _BATCH_CHECKS and not batch:
            continue
        if check.__name__ in _SEQUENTIAL_CHECKS and not sequential:
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
                if not _same(value, p.default):
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


__all__ = [
    "AGREEMENT_TOLERANCE_M",
    "CHECKS",
    "CHECK_NAMES",
    "EXACT_TOLERANCE_M",
    "NOISE_FREE_SNR_DB",
    "REFERENCE_SCENARIOS",
    "CheckOutcome",
    "EstimatorCheckError",
    "check_estimator",
    "estimator_checks",
    "parametrize_with_checks",
    "reference_data",
    "result_problems",
    "run_checks",
    *CHECK_NAMES,
]
