"""A cross-check over families: per-family summaries, the result, and the command lines
that replay one of its instances."""

from __future__ import annotations

import json
import math
import shlex
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import MISSING, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from comparison.crosscheck.compare import (
    NOT_RUN,
    InstanceResult,
    check_protocol,
    estimator_label,
    validate_estimator_instance,
    validate_instance,
)
from comparison.crosscheck.instances import (
    FAMILIES,
    FAMILY_DIMENSION,
    check_family,
    instance_seeds,
    make_instance,
)
from comparison.crosscheck.reports import write_reports
from comparison.crosscheck.result import FamilySummary, ValidationResult, json_clean
from estimators.base import params_of, unknowns_problem
from scenarios.nuisance import HEIGHT_UNKNOWN

Progress = Callable[[int, int, str], None]
"""``progress(done, total, family)``, called after every instance."""


# --------------------------------------------------------------------------------------------
# the command line that rebuilds an estimator and replays an instance
# --------------------------------------------------------------------------------------------


def _option_text(value: Any) -> str:
    """A value as ``--option key=<text>`` parses it back (JSON where it must be)."""
    if isinstance(value, str):
        try:
            json.loads(value)
        except json.JSONDecodeError:
            return value
        return json.dumps(value)
    try:
        return json.dumps(json_clean(value), separators=(",", ":"))
    except TypeError:
        return repr(value)


def _changed_options(estimator: Any) -> dict[str, Any]:
    """Constructor parameters that differ from their defaults (all of them if unknown)."""
    if not is_dataclass(estimator):
        return params_of(estimator)
    changed = {}
    for item in fields(estimator):
        if not item.init:
            continue
        value = getattr(estimator, item.name)
        if item.default is not MISSING:
            default = item.default
        elif item.default_factory is not MISSING:
            default = item.default_factory()
        else:
            changed[item.name] = value
            continue
        try:
            same = bool(value == default)
        except Exception:  # an array option: compare as arrays
            same = bool(np.array_equal(value, default))
        if not same:
            changed[item.name] = value
    return changed


def estimator_cli_args(estimator: Any) -> str:
    """``--estimator NAME [--option key=value ...]`` that rebuilds ``estimator`` on the CLI.

    ``NAME`` is the registered name when it resolves to the estimator's class, else
    ``module:Class``; the options are the constructor parameters that differ from the defaults.
    """
    from estimators.registry import estimator_class

    kind = type(estimator)
    target = f"{kind.__module__}:{kind.__qualname__}"
    name = getattr(kind, "name", None)
    if isinstance(name, str):
        try:
            if estimator_class(name) is kind:
                target = name
        except ValueError:
            pass
    parts = ["--estimator", target]
    for key, value in _changed_options(estimator).items():
        parts += ["--option", f"{key}={_option_text(value)}"]
    return " ".join(shlex.quote(part) for part in parts)


def _nanmax(values: Sequence[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return max(finite) if finite else float("nan")


MULTIPLIER_ZERO_RTOL = 1e-9
"""λ*/‖A_xy‖₂² above −this counts as λ* >= 0 (the hard case has λ* = −μ₁ = 0 to rounding)."""


def summarise_family(
    family: str, results: Sequence[InstanceResult], rtol_objective: float = 1e-6
) -> FamilySummary:
    """Per-family counts, worst gaps and distances, statuses and median times.

    Also the inequality relaxation's tightness split by the sign of λ* (MATH §11): tight means
    its value is within ``rtol_objective`` (relative) of the closed form's.
    """
    hard = [r for r in results if r.hard_case]
    unique = [r for r in results if not r.hard_case]
    checks = [r.candidates for r in results if r.candidates is not None]
    nonnegative = [r for r in results if r.multiplier_rel >= -MULTIPLIER_ZERO_RTOL]
    negative = [r for r in results if r.multiplier_rel < -MULTIPLIER_ZERO_RTOL]
    return FamilySummary(
        family=family,
        dimension=FAMILY_DIMENSION[family],
        n=len(results),
        n_hard=len(hard),
        n_unique=len(unique),
        n_disagreements=sum(not r.agrees for r in results),
        max_rel_objective_gap=_nanmax([r.rel_objective_gap for r in results]),
        max_argmin_distance_m=_nanmax([r.argmin_distance_m for r in unique]),
        max_argmin_distance_rel=_nanmax([r.argmin_distance_rel for r in unique]),
        max_candidate_pair_distance_m=_nanmax([r.pair_distance_m for r in hard]),
        max_candidate_pair_distance_rel=_nanmax([r.pair_distance_rel for r in hard]),
        statuses=dict(Counter(r.status for r in results)),
        tolerance_rungs={
            str(rung): count
            for rung, count in sorted(Counter(r.tolerance_rung for r in results).items())
        },
        median_closed_form_time_s=float(np.median([r.closed_form_time_s for r in results]))
        if results
        else float("nan"),
        median_sdp_time_s=float(np.median([r.sdp_time_s for r in results]))
        if results
        else float("nan"),
        n_multiplier_nonnegative=len(nonnegative),
        n_inequality_tight_when_nonnegative=sum(
            r.inequality_rel_gap <= rtol_objective for r in nonnegative
        ),
        max_inequality_gap_when_nonnegative=_nanmax([r.inequality_rel_gap for r in nonnegative]),
        n_multiplier_negative=len(negative),
        n_inequality_loose_when_negative=sum(
            r.inequality_rel_gap > rtol_objective for r in negative
        ),
        min_inequality_gap_when_negative=-_nanmax([-r.inequality_rel_gap for r in negative]),
        n_sdp_failed=sum(r.sdp_failed for r in results),
        n_estimator_failed=sum(r.status == NOT_RUN for r in results)
        + sum(not c.estimate_success for c in checks),
        max_estimator_rel_cost_gap=_nanmax([c.max_rel_cost_gap for c in checks]),
        max_estimator_distance_m=_nanmax([c.max_distance_m for c in checks]),
        max_estimator_distance_rel=_nanmax([c.max_distance_rel for c in checks]),
        n_estimator_missing=sum(c.n_missing for c in checks),
        n_estimator_extra=sum(c.n_extra for c in checks),
    )


def _families_for(
    estimator: Any, families: tuple[str, ...]
) -> tuple[tuple[str, ...], dict[str, str]]:
    """The families ``estimator`` can be judged on, and why each other is skipped: a 3-D
    family leaves the emitter's height unknown, which an estimator that takes it as known
    refuses (:func:`estimators.base.unknowns_problem`). Raises ``ValueError`` when none is
    left."""
    if unknowns_problem(estimator, (HEIGHT_UNKNOWN,), ("doppler", "toa")) is None:
        return families, {}
    why = (
        f"{estimator_label(estimator)} takes the emitter's height as known; these instances "
        "leave it unknown (r = (x, y, z, x² + y² + z²), MATH §5)"
    )
    skipped = {family: why for family in families if FAMILY_DIMENSION[family] == 3}
    kept = tuple(family for family in families if family not in skipped)
    if not kept:
        raise ValueError(
            f"families: {', '.join(skipped)} leave the emitter's height unknown and "
            f"{estimator_label(estimator)!r} takes it as known; choose a family of dimension 2 "
            "or an estimator that estimates the height (cls)"
        )
    return kept, skipped


def run_validation(
    *,
    instances: int,
    families: Sequence[str] = FAMILIES,
    seed: int = 0,
    out_dir: str | Path | None = None,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    progress: Progress | None = None,
    estimator: Any = None,
) -> ValidationResult:
    """Validate the closed form against the SDP on ``instances`` seeded instances per family.

    Parameters
    ----------
    instances : int
        Instances per family (the acceptance uses >= 1000).
    families : sequence of str
        A subset of :data:`FAMILIES`.
    seed : int
        Root seed; instance ``i`` of a family has its own seed (:func:`instance_seeds`),
        listed with every disagreement for :func:`replay`.
    out_dir : path or None
        Where to write ``validate.json``, ``validate.md``, ``validate.html`` and
        ``validate_gaps.png``; None writes nothing.
    rtol_objective : float
        Largest accepted ``|v_sdp − v_cf| / v_cf``.
    rtol_argmin : float
        Largest accepted argmin (unique case) or mirror-pair (hard case) distance, relative to
        the problem's length scale.
    progress : callable or None
        ``progress(done, total, family)`` after each instance.
    estimator : estimator, str or None
        None: the built-in closed form on the families' rows. Otherwise an estimator (or a
        name for :func:`estimators.registry.make_estimator`) with ``constrained_ls(data)``
        (:mod:`estimators.closed_form.constrained_ls`): it is run on each instance's measurements
        and judged on its own rows (:func:`validate_estimator_instance`). The families of
        dimension 3 are skipped (``skipped`` of the result says why) for an estimator that
        takes the emitter's height as known.

    Returns
    -------
    ValidationResult
        ``ok`` is false when any instance disagrees beyond tolerance or the solver did not
        reach status ``optimal``.

    Raises
    ------
    ValueError
        A bad option, or an estimator without ``constrained_ls`` (the message names it).
    """
    if int(instances) != instances or instances < 1:
        raise ValueError(f"instances: expected a whole number >= 1, got {instances!r}")
    families = tuple(families)
    if not families:
        raise ValueError(f"families: choose at least one of {', '.join(FAMILIES)}")
    for family in families:
        check_family(family)
    for name, value in (("rtol_objective", rtol_objective), ("rtol_argmin", rtol_argmin)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a positive tolerance, got {value!r}")
    if isinstance(estimator, str):
        from estimators.registry import make_estimator

        estimator = make_estimator(estimator)
    skipped: dict[str, str] = {}
    if estimator is not None:
        check_protocol(estimator)
        families, skipped = _families_for(estimator, families)
    total = instances * len(families)
    done = 0
    results: list[InstanceResult] = []
    summaries: dict[str, FamilySummary] = {}
    for family in families:
        family_results = []
        for instance_seed in instance_seeds(seed, family, int(instances)):
            instance = make_instance(family, instance_seed)
            if estimator is None:
                result, _, _ = validate_instance(
                    instance, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
                )
            else:
                result, _ = validate_estimator_instance(
                    instance, estimator, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
                )
            family_results.append(result)
            done += 1
            if progress is not None:
                progress(done, total, family)
        summaries[family] = summarise_family(family, family_results, rtol_objective)
        results.extend(family_results)
    validation = ValidationResult(
        seed=int(seed),
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
        families=summaries,
        results=tuple(results),
        estimator=None if estimator is None else estimator_label(estimator),
        estimator_args="" if estimator is None else estimator_cli_args(estimator),
        skipped=skipped,
    )
    if out_dir is None:
        return validation
    return replace(validation, files=write_reports(validation, Path(out_dir)))
