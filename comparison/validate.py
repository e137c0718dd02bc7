"""Validate the closed-form CLS against its SDP relaxation on seeded instances (MATH §5, §11).

The SDP relaxation (:func:`estimators.sdp_cls.solve_sdp_relaxation`) is an independent witness
for the closed form (:func:`estimators.gtrs.solve_gtrs`): on the same stacked rows its optimal
value must equal the closed form's on every instance, and its argmin must equal the closed
form's minimiser when that is unique; in the hard case (MATH §5) the mirror pair recovered from
the rank-two lift must equal the closed form's pair. Where they part, the report says why, with
the instance's own seed so :func:`replay` can re-run it verbosely.

Families of instances (each drawn from its own ``SeedSequence``):

``straight``
    One straight frame: random heading, speed, K, sample interval, height, carrier, emitter and
    noise levels; weighted rows (MATH §6, stage 1). Mostly the hard case.
``turn``
    Two frames at different headings, unweighted per-sample rows (SI units).
``turn-weighted``
    The same geometries with weighted rows.
``paper``
    The paper's geometry (MATH §14) with the ``paper-1m`` or ``paper-10m`` constants at a
    random SNR (MATH §2), weighted rows.

Length scale: every distance is also given relative to the problem's length scale, the
:class:`~estimators.cls_rows.LocalFrame` scale (RMS of the track spread and the ranges).

Another closed form (``run_validation(estimator=...)``, ``emitterbench validate --estimator
NAME``). An estimator that exposes the constrained least squares it minimises,
``constrained_ls(data) -> ConstrainedLS`` (:mod:`estimators.constrained_ls`), is run on every
instance's measurements (the same geometry and noise draws). Its own rows replace the family's:
the closed form and the SDP are compared on them as above, and every candidate the estimator
returns is lifted onto the paraboloid and must attain the closed-form optimum (relative cost
gap ``<= rtol_objective``, within ``rtol_argmin`` of the length scale of a closed-form
minimiser), and every closed-form minimiser must be among its candidates (both mirror images in
the hard case, MATH §5). A disagreement is replayed with ``--replay SEED --families F
--estimator NAME``.
"""

from __future__ import annotations

import base64
import io
import json
import math
import shlex
import time
import zlib
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Estimate, params_of
from estimators.cls import Rows, cls_rows
from estimators.cls_rows import LocalFrame
from estimators.constrained_ls import PROTOCOL_METHOD, ConstrainedLS
from estimators.gtrs import GtrsSolution, constrained_cost, solve_gtrs
from estimators.sdp_cls import SdpSolution, solve_sdp_relaxation
from scenarios.catalog import heading_velocities_mps, paper_scenario
from scenarios.simulate import simulate
from scenarios.types import FlightPlan, MeasurementSet, NoiseSigmas, Scenario

FloatArray = NDArray[np.float64]

FAMILIES: tuple[str, ...] = ("straight", "turn", "turn-weighted", "paper")
"""The instance families, in report order."""

Progress = Callable[[int, int, str], None]
"""``progress(done, total, family)``, called after every instance."""


# --------------------------------------------------------------------------------------------
# instances
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class ValidationInstance:
    """One stacked system ``A r = b`` (local frame) and how it was drawn."""

    family: str
    seed: int
    data: MeasurementSet
    frame: LocalFrame
    rows: str
    A: FloatArray
    b: FloatArray
    parameters: dict[str, Any]

    @property
    def length_scale_m(self) -> float:
        return self.frame.scale_m


def instance_seeds(seed: int, family: str, instances: int) -> list[int]:
    """``instances`` integer seeds for ``family``: instance ``i`` does not depend on the count."""
    _check_family(family)
    words = np.random.SeedSequence([int(seed), zlib.crc32(family.encode())]).generate_state(
        instances, dtype=np.uint64
    )
    return [int(word) for word in words]


def _check_family(family: str) -> None:
    if family not in FAMILIES:
        raise ValueError(f"families: unknown family {family!r}; choose from {', '.join(FAMILIES)}")


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _random_flight_scenario(rng: np.random.Generator, n_frames: int) -> tuple[Scenario, dict]:
    """A random level flight of ``n_frames`` straight frames and a random ground emitter."""
    speed = rng.uniform(2.0, 40.0)
    heading = rng.uniform(0.0, 360.0)
    headings = [heading]
    for _ in range(n_frames - 1):
        turn = rng.uniform(20.0, 160.0) * rng.choice([-1.0, 1.0])
        headings.append(headings[-1] + turn)
    samples = int(rng.integers(3, 41))
    interval = _log_uniform(rng, 0.01, 0.5)
    height = rng.uniform(5.0, 200.0)
    track_m = speed * interval * samples * n_frames
    distance = _log_uniform(rng, 10.0, 2000.0) + 0.1 * track_m
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    emitter = distance * np.array([np.cos(bearing), np.sin(bearing)])
    carrier = _log_uniform(rng, 1e8, 6e9)
    doppler_sigma = _log_uniform(rng, 1e-3, 10.0)
    range_sigma = _log_uniform(rng, 1e-2, 30.0)
    scenario = Scenario(
        name="validate",
        emitter_m=emitter,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, height],
            frame_velocities_mps=heading_velocities_mps(speed, headings),
            samples_per_frame=samples,
            sample_interval_s=interval,
        ),
        carrier_hz=carrier,
        noise=NoiseSigmas(doppler_hz=doppler_sigma, toa_s=range_sigma / 299_792_458.0),
        modalities=("doppler", "toa"),
    )
    parameters = {
        "speed_mps": speed,
        "headings_deg": headings,
        "samples_per_frame": samples,
        "sample_interval_s": interval,
        "uav_height_m": height,
        "emitter_m": emitter.tolist(),
        "carrier_hz": carrier,
        "doppler_sigma_hz": doppler_sigma,
        "range_sigma_m": range_sigma,
    }
    return scenario, parameters


def make_instance(family: str, seed: int) -> ValidationInstance:
    """The instance ``seed`` of ``family``: every draw from ``SeedSequence(seed)``."""
    _check_family(family)
    geometry_seed, noise_seed = np.random.SeedSequence(int(seed)).spawn(2)
    rng = np.random.default_rng(geometry_seed)
    rows: Rows
    if family == "paper":
        range_sigma = float(rng.choice([1.0, 10.0]))
        snr_db = float(rng.uniform(-10.0, 40.0))
        scenario = paper_scenario(range_sigma_m=range_sigma, name=f"paper-{range_sigma:g}m")
        scenario = scenario.replace(modalities=("doppler", "toa"))
        parameters: dict[str, Any] = {"scenario": scenario.name, "snr_db": snr_db}
        rows = "weighted"
    else:
        n_frames = 1 if family == "straight" else 2
        scenario, parameters = _random_flight_scenario(rng, n_frames)
        snr_db = 0.0
        rows = "per-sample" if family == "turn" else "weighted"
    data = simulate(scenario, snr_db=snr_db, seed=noise_seed)
    frame = LocalFrame.fit(data.position_m, data.range_m)
    A, b = cls_rows(data, frame, rows)
    return ValidationInstance(
        family=family,
        seed=int(seed),
        data=data,
        frame=frame,
        rows=rows,
        A=A,
        b=b,
        parameters=dict(parameters, rows=rows, n_rows=len(b)),
    )


# --------------------------------------------------------------------------------------------
# comparing one instance
# --------------------------------------------------------------------------------------------


NOT_RUN = "not_run"
"""Status of an instance on which the estimator raised: no rows, no SDP."""


@dataclass(frozen=True, slots=True)
class CandidateCheck:
    """An estimator's candidates on its own rows against the closed-form minimisers.

    Attributes
    ----------
    estimate_success : bool
        The estimate succeeded (a failed estimate has no candidates).
    n_candidates : int
        Candidates the estimator returned.
    n_minimisers : int
        Global minimisers of the closed form (2 in the hard case).
    max_rel_cost_gap : float
        Largest ``|cost − f*| / f*`` over the candidates, each lifted onto the paraboloid;
        NaN without candidates.
    max_distance_m, max_distance_rel : float
        Hausdorff distance between the candidates and the closed-form minimisers, in metres
        and of the length scale (inf without candidates).
    n_missing : int
        Closed-form minimisers with no candidate within the distance tolerance.
    n_extra : int
        Candidates that are not global minimisers (cost above the optimum beyond the
        tolerance, or away from every minimiser).
    n_below : int
        Candidates whose cost is below the closed-form optimum beyond the tolerance.
    """

    estimate_success: bool
    n_candidates: int
    n_minimisers: int
    max_rel_cost_gap: float
    max_distance_m: float
    max_distance_rel: float
    n_missing: int
    n_extra: int
    n_below: int = 0


@dataclass(frozen=True, slots=True)
class InstanceResult:
    """The closed form and the SDP on one instance, and where they disagree.

    Distances are in metres; ``*_rel`` divides by the length scale. ``argmin_distance_m`` is
    NaN on hard instances, ``pair_distance_m`` NaN on unique-minimiser ones. ``candidates``
    is set when an estimator was validated (:func:`check_candidates`).
    """

    family: str
    seed: int
    status: str
    hard_case: bool
    sdp_rank: int
    multiplier: float
    sdp_multiplier: float
    closed_form_value: float
    sdp_value: float
    rel_objective_gap: float
    argmin_distance_m: float
    argmin_distance_rel: float
    pair_distance_m: float
    pair_distance_rel: float
    length_scale_m: float
    closed_form_time_s: float
    sdp_time_s: float
    tolerance_rung: int = 1
    reasons: tuple[str, ...] = ()
    multiplier_rel: float = float("nan")
    inequality_rel_gap: float = float("nan")
    candidates: CandidateCheck | None = None

    @property
    def sdp_failed(self) -> bool:
        return self.status not in ("optimal", NOT_RUN)

    @property
    def agrees(self) -> bool:
        return not self.reasons


def relative_objective_gap(sdp_value: float, closed_form_value: float) -> float:
    """``|v_sdp − v_cf| / max(|v_cf|, tiny)``."""
    return abs(sdp_value - closed_form_value) / max(abs(closed_form_value), np.finfo(float).tiny)


def point_set_distance(first: FloatArray, second: FloatArray) -> float:
    """Hausdorff distance between two point sets (n, 2) and (m, 2); inf if one is empty."""
    first = np.asarray(first, dtype=float).reshape(-1, 2)
    second = np.asarray(second, dtype=float).reshape(-1, 2)
    if len(first) == 0 or len(second) == 0:
        return float("inf")
    pairwise = np.linalg.norm(first[:, None, :] - second[None, :, :], axis=-1)
    return float(max(pairwise.min(axis=1).max(), pairwise.min(axis=0).max()))


def compare_solutions(
    instance: ValidationInstance,
    closed_form: GtrsSolution,
    sdp: SdpSolution,
    *,
    closed_form_time_s: float,
    rtol_objective: float,
    rtol_argmin: float,
) -> InstanceResult:
    """Judge one instance: objective gap, argmin or mirror-pair distance, solver status."""
    scale = instance.length_scale_m
    value = float(np.min(closed_form.costs))
    reasons: list[str] = []
    gap = argmin = pair = float("nan")
    if not sdp.optimal:
        reasons.append(f"SDP failed: solver status {sdp.status}: {sdp.message}")
    if sdp.has_solution:
        gap = relative_objective_gap(sdp.value, value)
        if not gap <= rtol_objective:
            reasons.append(f"relative objective gap {gap:.3g} > {rtol_objective:g}")
        cf_points = closed_form.points[:, :2]
        if closed_form.hard_case:
            pair = point_set_distance(sdp.points[:, :2], cf_points)
            if not pair <= rtol_argmin:
                reasons.append(
                    f"hard case: SDP pair ({len(sdp.points)} points, rank {sdp.rank}) is "
                    f"{pair:.3g} (of the length scale) from the closed-form mirror pair"
                )
        else:
            best = sdp.points[int(np.argmin(sdp.costs)), :2]
            argmin = float(np.min(np.linalg.norm(cf_points - best, axis=1)))
            if not argmin <= rtol_argmin:
                reasons.append(
                    f"unique minimiser: SDP argmin is {argmin:.3g} (of the length scale) from "
                    f"the closed form's (SDP rank {sdp.rank})"
                )
    return InstanceResult(
        family=instance.family,
        seed=instance.seed,
        status=sdp.status,
        hard_case=bool(closed_form.hard_case),
        sdp_rank=sdp.rank,
        multiplier=closed_form.multiplier,
        sdp_multiplier=sdp.multiplier,
        closed_form_value=value,
        sdp_value=sdp.value,
        rel_objective_gap=gap,
        argmin_distance_m=argmin * scale,
        argmin_distance_rel=argmin,
        pair_distance_m=pair * scale,
        pair_distance_rel=pair,
        length_scale_m=scale,
        closed_form_time_s=closed_form_time_s,
        sdp_time_s=sdp.wall_time_s,
        tolerance_rung=sdp.rung,
        reasons=tuple(reasons),
    )


def validate_instance(
    instance: ValidationInstance,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    solver: str = "CLARABEL",
) -> tuple[InstanceResult, GtrsSolution, SdpSolution]:
    """Run the closed form and the SDP on the instance's rows.

    The equality (Shor) relaxation is judged against the closed form. The inequality relaxation
    ``r_z >= ‖y‖²`` is solved too, for the report only: it is tight exactly when λ* >= 0
    (MATH §11). ``multiplier_rel = λ*/‖A_xy‖₂²`` (λ* acts on the xy block only) and
    ``inequality_rel_gap`` (its value below the closed form's, relative) record it.
    """
    started = time.perf_counter()
    closed_form = solve_gtrs(instance.A, instance.b)
    closed_form_time = time.perf_counter() - started
    sdp = solve_sdp_relaxation(instance.A, instance.b, relaxation="equality", solver=solver)
    result = compare_solutions(
        instance,
        closed_form,
        sdp,
        closed_form_time_s=closed_form_time,
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
    )
    inequality = solve_sdp_relaxation(
        instance.A, instance.b, relaxation="inequality", solver=solver
    )
    value = float(np.min(closed_form.costs))
    result = replace(
        result,
        multiplier_rel=closed_form.multiplier / np.linalg.norm(instance.A[:, :2], 2) ** 2,
        inequality_rel_gap=(value - inequality.value) / max(abs(value), np.finfo(float).tiny)
        if inequality.has_solution
        else float("nan"),
    )
    return result, closed_form, sdp


# --------------------------------------------------------------------------------------------
# an estimator's own closed form
# --------------------------------------------------------------------------------------------


def estimator_label(estimator: Any) -> str:
    """The estimator's ``name``, else its class name."""
    name = getattr(estimator, "name", None)
    return name if isinstance(name, str) else type(estimator).__name__


def check_protocol(estimator: Any) -> None:
    """Raise ``ValueError`` naming the method to add when ``estimator`` cannot be validated."""
    kind = type(estimator)
    where = f"{kind.__module__}:{kind.__qualname__}"
    if not callable(getattr(estimator, "estimate", None)):
        raise ValueError(f"estimator: {where} has no estimate(data) method; it is not an estimator")
    if not callable(getattr(estimator, PROTOCOL_METHOD, None)):
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r} ({where}) does not expose the constrained "
            f"least squares it minimises; add a method {PROTOCOL_METHOD}(self, data) returning "
            "an estimators.constrained_ls.ConstrainedLS (the rows A, b and their local frame "
            "whose minimisers estimate(data) returns; see docs/writing-an-estimator.md)"
        )
    requires = frozenset(getattr(estimator, "requires", ()))
    extra = sorted(requires - {"doppler", "toa"})
    if extra:
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r} requires {', '.join(extra)}; the "
            "validation instances carry Doppler and ToA measurements only"
        )


def _option_text(value: Any) -> str:
    """A value as ``--option key=<text>`` parses it back (JSON where it must be)."""
    if isinstance(value, str):
        try:
            json.loads(value)
        except json.JSONDecodeError:
            return value
        return json.dumps(value)
    try:
        return json.dumps(_json_clean(value), separators=(",", ":"))
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


def replay_command(result: InstanceResult, estimator_args: str = "") -> str:
    """The command line that re-runs ``result``'s instance verbosely."""
    command = f"emitterbench validate --replay {result.seed} --families {result.family}"
    return f"{command} {estimator_args}" if estimator_args else command


def check_candidates(
    problem: ConstrainedLS,
    estimate: Estimate,
    closed_form: GtrsSolution,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
) -> tuple[CandidateCheck, tuple[str, ...]]:
    """Judge the estimator's candidates on its own rows ``problem`` (MATH §5).

    Each candidate ``(x, y)`` is lifted to ``r = (x, y, x² + y²)`` in the rows' frame, so it
    lies on the constraint surface, and its cost is compared with the closed-form optimum
    ``f*``. A candidate is a global minimiser when ``|cost − f*| <= rtol_objective · f*`` and it
    lies within ``rtol_argmin`` (of the length scale) of a closed-form minimiser; every
    closed-form minimiser must have such a candidate (both mirror images in the hard case).
    Returns the check and the reasons it fails (empty when it passes).
    """
    minimisers = closed_form.points[:, :2]
    optimum = float(np.min(closed_form.costs))
    if not estimate.success or len(estimate.candidates_m) == 0:
        check = CandidateCheck(
            estimate_success=bool(estimate.success),
            n_candidates=0,
            n_minimisers=len(minimisers),
            max_rel_cost_gap=float("nan"),
            max_distance_m=float("inf"),
            max_distance_rel=float("inf"),
            n_missing=len(minimisers),
            n_extra=0,
        )
        why = estimate.message or "no candidates"
        return check, (f"estimate failed: {why}",)
    local = problem.to_local(estimate.candidates_m)
    costs = constrained_cost(problem.A, problem.b, local)
    gaps = (costs - optimum) / max(abs(optimum), np.finfo(float).tiny)
    distances = np.linalg.norm(local[:, None, :] - minimisers[None, :, :], axis=-1)
    near = distances <= rtol_argmin
    below = gaps < -rtol_objective
    extra = ~below & ((gaps > rtol_objective) | ~near.any(axis=1))
    missing = ~near.any(axis=0)
    hausdorff = point_set_distance(local, minimisers)
    check = CandidateCheck(
        estimate_success=True,
        n_candidates=len(local),
        n_minimisers=len(minimisers),
        max_rel_cost_gap=float(np.max(np.abs(gaps))),
        max_distance_m=hausdorff * problem.scale_m,
        max_distance_rel=hausdorff,
        n_missing=int(missing.sum()),
        n_extra=int(extra.sum()),
        n_below=int(below.sum()),
    )
    reasons = []
    if extra.any():
        reasons.append(
            f"{check.n_extra} of {check.n_candidates} candidate(s) not a global minimiser: "
            f"relative cost gap up to {float(np.max(gaps[extra])):.3g} (tolerance "
            f"{rtol_objective:g}), {float(np.max(distances[extra].min(axis=1))):.3g} of the "
            "length scale from the nearest closed-form minimiser"
        )
    if missing.any():
        kind = (
            "hard case: both mirror minimisers must be returned"
            if closed_form.hard_case
            else "unique minimiser"
        )
        reasons.append(
            f"{check.n_missing} of {check.n_minimisers} closed-form minimiser(s) not among the "
            f"candidates ({kind}; the nearest candidate is "
            f"{float(np.max(distances[:, missing].min(axis=0))):.3g} of the length scale away)"
        )
    if below.any():
        reasons.append(
            f"{check.n_below} candidate(s) below the closed-form optimum by up to "
            f"{float(-np.min(gaps)):.3g} (relative): the closed form missed the global minimum"
        )
    return check, tuple(reasons)


@dataclass(frozen=True, slots=True, eq=False)
class EstimatorRun:
    """Everything computed on one instance for an estimator (what :func:`replay` prints)."""

    instance: ValidationInstance
    estimate: Estimate | None
    problem: ConstrainedLS | None
    closed_form: GtrsSolution | None
    sdp: SdpSolution | None
    error: str = ""


def _not_run_result(instance: ValidationInstance, reason: str) -> InstanceResult:
    nan = float("nan")
    return InstanceResult(
        family=instance.family,
        seed=instance.seed,
        status=NOT_RUN,
        hard_case=False,
        sdp_rank=0,
        multiplier=nan,
        sdp_multiplier=nan,
        closed_form_value=nan,
        sdp_value=nan,
        rel_objective_gap=nan,
        argmin_distance_m=nan,
        argmin_distance_rel=nan,
        pair_distance_m=nan,
        pair_distance_rel=nan,
        length_scale_m=nan,
        closed_form_time_s=nan,
        sdp_time_s=nan,
        reasons=(reason,),
    )


def validate_estimator_instance(
    instance: ValidationInstance,
    estimator: Any,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    solver: str = "CLARABEL",
) -> tuple[InstanceResult, EstimatorRun]:
    """Run ``estimator`` on the instance's measurements and judge it on its own rows.

    ``estimate(data)`` and ``constrained_ls(data)`` see the measurements without the truth.
    The closed form and the SDP are compared on the returned rows as in
    :func:`validate_instance`, and the candidates as in :func:`check_candidates`. An exception
    raised by the estimator is recorded as a disagreement; ``constrained_ls`` returning
    anything but a :class:`~estimators.constrained_ls.ConstrainedLS` raises ``ValueError``.
    """
    data = instance.data.without_truth()
    try:
        estimate = estimator.estimate(data)
        problem = getattr(estimator, PROTOCOL_METHOD)(data)
    except Exception as error:
        reason = f"estimator raised {type(error).__name__}: {error}"
        return _not_run_result(instance, reason), EstimatorRun(
            instance, None, None, None, None, error=reason
        )
    if not isinstance(problem, ConstrainedLS):
        raise ValueError(
            f"estimator: {estimator_label(estimator)!r}.{PROTOCOL_METHOD}(data) returned "
            f"{type(problem).__name__}; return an estimators.constrained_ls.ConstrainedLS"
        )
    on_rows = replace(
        instance,
        frame=problem.frame,
        rows=f"{estimator_label(estimator)}.{PROTOCOL_METHOD}",
        A=problem.A,
        b=problem.b,
        parameters=dict(
            instance.parameters,
            rows=f"{estimator_label(estimator)}.{PROTOCOL_METHOD}",
            n_rows=len(problem.b),
        ),
    )
    result, closed_form, sdp = validate_instance(
        on_rows, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin, solver=solver
    )
    check, reasons = check_candidates(
        problem, estimate, closed_form, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
    )
    result = replace(result, candidates=check, reasons=reasons + result.reasons)
    return result, EstimatorRun(on_rows, estimate, problem, closed_form, sdp)


# --------------------------------------------------------------------------------------------
# a run over families
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FamilySummary:
    """Aggregates of one family (the per-family block of ``validate.json``).

    ``n_sdp_failed`` counts instances whose SDP did not end with status ``optimal`` (each is a
    disagreement). The ``*estimator*`` fields are set when an estimator was validated: instances
    where it failed or raised, the largest relative cost gap and distance of its candidates,
    and the total of missing and extra candidates (:class:`CandidateCheck`).
    """

    family: str
    n: int
    n_hard: int
    n_unique: int
    n_disagreements: int
    max_rel_objective_gap: float
    max_argmin_distance_m: float
    max_argmin_distance_rel: float
    max_candidate_pair_distance_m: float
    max_candidate_pair_distance_rel: float
    statuses: dict[str, int]
    tolerance_rungs: dict[str, int]
    median_closed_form_time_s: float
    median_sdp_time_s: float
    n_multiplier_nonnegative: int = 0
    n_inequality_tight_when_nonnegative: int = 0
    max_inequality_gap_when_nonnegative: float = float("nan")
    n_multiplier_negative: int = 0
    n_inequality_loose_when_negative: int = 0
    min_inequality_gap_when_negative: float = float("nan")
    n_sdp_failed: int = 0
    n_estimator_failed: int = 0
    max_estimator_rel_cost_gap: float = float("nan")
    max_estimator_distance_m: float = float("nan")
    max_estimator_distance_rel: float = float("nan")
    n_estimator_missing: int = 0
    n_estimator_extra: int = 0


@dataclass(frozen=True, slots=True, eq=False)
class ValidationResult:
    """What :func:`run_validation` found; ``ok`` is false when any instance disagrees.

    ``estimator`` is the validated estimator's name (None: the built-in closed form on the
    families' rows) and ``estimator_args`` the ``--estimator ... --option ...`` arguments that
    rebuild it in a replay command.
    """

    seed: int
    rtol_objective: float
    rtol_argmin: float
    families: dict[str, FamilySummary]
    results: tuple[InstanceResult, ...]
    files: dict[str, Path] = field(default_factory=dict)
    estimator: str | None = None
    estimator_args: str = ""

    def replay_command(self, result: InstanceResult) -> str:
        """The command line that re-runs one instance of this validation verbosely."""
        return replay_command(result, self.estimator_args)

    @property
    def disagreements(self) -> tuple[InstanceResult, ...]:
        return tuple(result for result in self.results if not result.agrees)

    @property
    def ok(self) -> bool:
        return not self.disagreements

    def to_dict(self) -> dict[str, Any]:
        """The content of ``validate.json`` (NaN becomes None)."""
        import cvxpy

        try:
            from importlib.metadata import version

            clarabel_version = version("clarabel")
        except Exception:  # pragma: no cover - metadata missing
            clarabel_version = None
        return _json_clean(
            {
                "ok": self.ok,
                "seed": self.seed,
                "estimator": None
                if self.estimator is None
                else {"name": self.estimator, "args": self.estimator_args},
                "tolerances": {
                    "rel_objective_gap": self.rtol_objective,
                    "argmin_distance_rel": self.rtol_argmin,
                },
                "relaxation": "equality (Shor, MATH §11)",
                "versions": {"cvxpy": cvxpy.__version__, "clarabel": clarabel_version},
                "families": {name: asdict(summary) for name, summary in self.families.items()},
                "disagreements": [
                    {
                        "family": r.family,
                        "seed": r.seed,
                        "reasons": list(r.reasons),
                        "status": r.status,
                        "hard_case": r.hard_case,
                        "rel_objective_gap": r.rel_objective_gap,
                        "argmin_distance_m": r.argmin_distance_m,
                        "pair_distance_m": r.pair_distance_m,
                        "candidates": None if r.candidates is None else asdict(r.candidates),
                        "replay": self.replay_command(r),
                    }
                    for r in self.disagreements
                ],
            }
        )


def _json_clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_clean(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return value


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
        (:mod:`estimators.constrained_ls`): it is run on each instance's measurements and
        judged on its own rows (:func:`validate_estimator_instance`).

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
        _check_family(family)
    for name, value in (("rtol_objective", rtol_objective), ("rtol_argmin", rtol_argmin)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a positive tolerance, got {value!r}")
    if isinstance(estimator, str):
        from estimators.registry import make_estimator

        estimator = make_estimator(estimator)
    if estimator is not None:
        check_protocol(estimator)
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
    )
    if out_dir is None:
        return validation
    return replace(validation, files=write_reports(validation, Path(out_dir)))


# --------------------------------------------------------------------------------------------
# reports
# --------------------------------------------------------------------------------------------

_COLUMNS = (
    ("family", "family"),
    ("n", "n"),
    ("n_hard", "hard"),
    ("max_rel_objective_gap", "max rel. objective gap"),
    ("max_argmin_distance_m", "max argmin dist. (m)"),
    ("max_argmin_distance_rel", "(rel.)"),
    ("max_candidate_pair_distance_m", "max pair dist. (m)"),
    ("max_candidate_pair_distance_rel", "(rel.)"),
    ("statuses", "solver statuses"),
    ("tolerance_rungs", "tolerance rungs"),
    ("median_sdp_time_s", "median SDP time (ms)"),
    ("median_closed_form_time_s", "median closed-form time (ms)"),
    ("n_disagreements", "disagreements"),
)


_ESTIMATOR_COLUMNS = (
    ("family", "family"),
    ("n", "n"),
    ("n_hard", "hard"),
    ("n_sdp_failed", "SDP failed"),
    ("n_estimator_failed", "estimate failed"),
    ("max_estimator_rel_cost_gap", "max rel. cost gap of candidates"),
    ("max_estimator_distance_m", "max dist. to the minimisers (m)"),
    ("max_estimator_distance_rel", "(rel.)"),
    ("n_estimator_missing", "missing"),
    ("n_estimator_extra", "extra"),
    ("n_disagreements", "disagreements"),
)


def _estimator_caption(result: ValidationResult) -> str:
    return (
        f"The candidates of {result.estimator} ({result.estimator_args}) on its own constrained "
        "least squares, constrained_ls(data), for each instance's measurements: each candidate "
        "lifted onto the paraboloid and compared with the exact optimum of the same rows (MATH "
        f"§5). Tolerances: relative cost gap {result.rtol_objective:g}; distance to a "
        f"closed-form minimiser {result.rtol_argmin:g} of the length scale. Missing: "
        "closed-form minimisers not returned (both mirror images are due in the hard case); "
        "extra: candidates that are not global minimisers. The table above compares the closed "
        "form and the SDP on the same rows."
    )


_INEQUALITY_COLUMNS = (
    ("family", "family"),
    ("n_multiplier_nonnegative", "λ* ≥ 0"),
    ("n_inequality_tight_when_nonnegative", "tight"),
    ("max_inequality_gap_when_nonnegative", "max gap"),
    ("n_multiplier_negative", "λ* < 0"),
    ("n_inequality_loose_when_negative", "not tight"),
    ("min_inequality_gap_when_negative", "min gap"),
)

_INEQUALITY_CAPTION = (
    "The inequality relaxation (r_z ≥ x² + y², MATH §11) on the same instances: it is tight (value "
    "within the objective tolerance of the closed form's) when the Lagrange multiplier λ* ≥ 0, "
    "and strictly below the optimum when λ* < 0, by a gap that vanishes as λ* → 0⁻ (so a "
    "barely negative λ* can fall within the tolerance). Gaps are relative to the closed form's "
    "value."
)


def _cell(key: str, value: Any) -> str:
    if key in ("statuses", "tolerance_rungs"):
        return ", ".join(f"{k} {v}" for k, v in sorted(value.items()))
    if key.endswith("time_s"):
        return f"{value * 1e3:.2f}"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.2e}"
    return str(value)


def _table_rows(
    result: ValidationResult, columns: Sequence[tuple[str, str]] = _COLUMNS
) -> list[list[str]]:
    return [
        [_cell(key, getattr(summary, key)) for key, _ in columns]
        for summary in result.families.values()
    ]


def _title(result: ValidationResult) -> str:
    if result.estimator is None:
        return "Closed form vs SDP relaxation"
    return f"{result.estimator}: closed form vs SDP relaxation"


def _caption(result: ValidationResult) -> str:
    rows = (
        "the same stacked rows"
        if result.estimator is None
        else f"the rows of {result.estimator}.constrained_ls(data)"
    )
    return (
        f"Closed-form CLS (MATH §5) against its Shor SDP relaxation (MATH §11, cvxpy + "
        f"Clarabel) on {rows}; root seed {result.seed}. Tolerances: relative "
        f"objective gap {result.rtol_objective:g}; argmin distance (unique minimiser) and "
        f"mirror-pair distance (hard case) {result.rtol_argmin:g} of the length scale (RMS of "
        "the track spread and the ranges). Noise levels follow the SNR axis of MATH §2. "
        "Tolerance rung 1: Clarabel at gap 1e-10, feasibility 1e-9; rung 2 (used when rung 1 "
        "ends optimal_inaccurate): Clarabel's defaults, 1e-8."
    )


def write_reports(result: ValidationResult, out_dir: Path) -> dict[str, Path]:
    """Write ``validate.json``, ``validate.md``, ``validate_gaps.png`` and ``validate.html``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {
        "json": out_dir / "validate.json",
        "md": out_dir / "validate.md",
        "png": out_dir / "validate_gaps.png",
        "html": out_dir / "validate.html",
    }
    files["json"].write_text(json.dumps(result.to_dict(), indent=2) + "\n", encoding="utf-8")
    png = gap_scatter_png(result)
    files["png"].write_bytes(png)
    files["md"].write_text(markdown_report(result), encoding="utf-8")
    files["html"].write_text(html_report(result, png), encoding="utf-8")
    return files


def _disagreement_lines(result: ValidationResult, limit: int = 200) -> list[str]:
    lines = []
    for r in result.disagreements[:limit]:
        lines.append(
            f"{r.family} seed {r.seed}: {'; '.join(r.reasons)} (replay: {result.replay_command(r)})"
        )
    if len(result.disagreements) > limit:
        lines.append(f"... and {len(result.disagreements) - limit} more (see validate.json)")
    return lines


def markdown_report(result: ValidationResult) -> str:
    """A short Markdown summary: verdict, the per-family table, every disagreement."""
    headers = [title for _, title in _COLUMNS]
    lines = [
        f"# {_title(result)}",
        "",
        f"**{'PASS' if result.ok else 'FAIL'}**: {len(result.results)} instances, "
        f"{len(result.disagreements)} disagreements.",
        "",
        _caption(result),
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---" for _ in headers) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result)]
    if result.estimator is not None:
        estimator_headers = [title for _, title in _ESTIMATOR_COLUMNS]
        lines += [
            "",
            "## The estimator's candidates",
            "",
            _estimator_caption(result),
            "",
            "| " + " | ".join(estimator_headers) + " |",
            "|" + "|".join("---" for _ in estimator_headers) + "|",
        ]
        lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result, _ESTIMATOR_COLUMNS)]
    inequality_headers = [title for _, title in _INEQUALITY_COLUMNS]
    lines += [
        "",
        "## The inequality relaxation",
        "",
        _INEQUALITY_CAPTION,
        "",
        "| " + " | ".join(inequality_headers) + " |",
        "|" + "|".join("---" for _ in inequality_headers) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result, _INEQUALITY_COLUMNS)]
    lines += ["", "## Disagreements", ""]
    found = _disagreement_lines(result)
    lines += [f"- {line}" for line in found] if found else ["None."]
    lines += ["", "Objective gaps: `validate_gaps.png`.", ""]
    return "\n".join(lines)


def html_report(result: ValidationResult, png: bytes) -> str:
    """The same content as HTML, the gap scatter embedded as a PNG data URI."""
    from html import escape

    head = "".join(f"<th>{escape(title)}</th>" for _, title in _COLUMNS)
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
        for row in _table_rows(result)
    )
    inequality_head = "".join(f"<th>{escape(title)}</th>" for _, title in _INEQUALITY_COLUMNS)
    inequality_body = "".join(
        "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
        for row in _table_rows(result, _INEQUALITY_COLUMNS)
    )
    estimator_block = ""
    if result.estimator is not None:
        estimator_head = "".join(f"<th>{escape(title)}</th>" for _, title in _ESTIMATOR_COLUMNS)
        estimator_body = "".join(
            "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
            for row in _table_rows(result, _ESTIMATOR_COLUMNS)
        )
        estimator_block = (
            "<h2>The estimator's candidates</h2>\n"
            f"<p>{escape(_estimator_caption(result))}</p>\n"
            f"<table><tr>{estimator_head}</tr>{estimator_body}</table>\n"
        )
    found = _disagreement_lines(result)
    items = "".join(f"<li>{escape(line)}</li>" for line in found) or "<li>None.</li>"
    image = base64.b64encode(png).decode("ascii")
    verdict = "PASS" if result.ok else "FAIL"
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{escape(_title(result))}</title>"
        "<style>body{font-family:sans-serif;max-width:70em;margin:2em auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #999;padding:.2em .5em}"
        "</style></head><body>\n"
        f"<h1>{escape(_title(result))}: {verdict}</h1>\n"
        f"<p>{len(result.results)} instances, {len(result.disagreements)} disagreements.</p>\n"
        f"<p>{escape(_caption(result))}</p>\n"
        f"<table><tr>{head}</tr>{body}</table>\n"
        f"{estimator_block}"
        "<h2>The inequality relaxation</h2>\n"
        f"<p>{escape(_INEQUALITY_CAPTION)}</p>\n"
        f"<table><tr>{inequality_head}</tr>{inequality_body}</table>\n"
        f"<h2>Disagreements</h2><ul>{items}</ul>\n"
        f"<h2>Objective gaps</h2><img alt='relative objective gap per instance' "
        f"src='data:image/png;base64,{image}'>\n"
        "</body></html>\n"
    )


def gap_scatter_png(result: ValidationResult) -> bytes:
    """Scatter of the relative objective gaps per instance, by family, hard vs unique (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    floor = 1e-17
    figure, axes = plt.subplots(figsize=(9.5, 4.5), dpi=100)
    offset = 0
    for index, family in enumerate(result.families):
        rows = [r for r in result.results if r.family == family]
        x = offset + np.arange(len(rows))
        gaps = np.array([r.rel_objective_gap for r in rows], dtype=float)
        gaps = np.where(np.isfinite(gaps), np.maximum(gaps, floor), np.nan)
        hard = np.array([r.hard_case for r in rows], dtype=bool)
        for mask, marker, kind in ((hard, "o", "hard case"), (~hard, "x", "unique")):
            if mask.any():
                axes.scatter(
                    x[mask],
                    gaps[mask],
                    s=8,
                    marker=marker,
                    color=f"C{index}",
                    label=f"{family} ({kind})",
                )
        offset += len(rows)
    axes.axhline(result.rtol_objective, color="k", linestyle="--", linewidth=1, label="tolerance")
    axes.set_yscale("log")
    axes.set_xlabel("instance (grouped by family)")
    axes.set_ylabel(f"|v_sdp − v_cf| / v_cf (floored at {floor:g})")
    axes.set_title("SDP relaxation vs closed form: relative objective gap")
    axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    plt.close(figure)
    return buffer.getvalue()


# --------------------------------------------------------------------------------------------
# replay
# --------------------------------------------------------------------------------------------


def _matrix_text(matrix: FloatArray) -> str:
    return np.array2string(
        np.asarray(matrix), precision=6, suppress_small=False, max_line_width=100
    )


def replay(
    instance_seed: int,
    family: str,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    estimator: Any = None,
) -> str:
    """Re-run one instance verbosely: the draw, the closed form, the SDP and the verdict.

    With an ``estimator`` (an object or a registry name), the rows are its
    ``constrained_ls(data)`` and its candidates are listed with their costs and gaps.
    """
    text, _ = replay_with_verdict(
        instance_seed,
        family,
        rtol_objective=rtol_objective,
        rtol_argmin=rtol_argmin,
        estimator=estimator,
    )
    return text


def replay_with_verdict(
    instance_seed: int,
    family: str,
    *,
    rtol_objective: float = 1e-6,
    rtol_argmin: float = 1e-3,
    estimator: Any = None,
) -> tuple[str, bool]:
    """:func:`replay`'s text and whether the instance agrees."""
    if isinstance(estimator, str):
        from estimators.registry import make_estimator

        estimator = make_estimator(estimator)
    if estimator is not None:
        check_protocol(estimator)
    instance = make_instance(family, instance_seed)
    lines = [
        f"instance {family} seed {instance_seed}",
        f"  parameters: {json.dumps(_json_clean(instance.parameters))}",
        f"  truth emitter (m): {_matrix_text(instance.data.truth_emitter_m)}",
    ]
    run: EstimatorRun | None = None
    if estimator is None:
        result, closed_form, sdp = validate_instance(
            instance, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
        )
    else:
        result, run = validate_estimator_instance(
            instance, estimator, rtol_objective=rtol_objective, rtol_argmin=rtol_argmin
        )
        lines.append(f"estimator {estimator_label(estimator)} ({estimator_cli_args(estimator)})")
        if run.error:
            lines += ["verdict", f"  DISAGREE: {run.error}"]
            return "\n".join(lines) + "\n", False
        assert run.closed_form is not None and run.sdp is not None
        instance, closed_form, sdp = run.instance, run.closed_form, run.sdp
    frame = instance.frame
    lines += [
        f"  local frame: origin {_matrix_text(frame.origin_m)} m, "
        f"length scale {frame.scale_m:.6g} m",
        f"  rows: {instance.rows}, A {instance.A.shape}, numerical rank {closed_form.rank}",
        "closed form (MATH §5)",
        f"  lambda* = {closed_form.multiplier:.10g}, hard case {closed_form.hard_case}",
    ]
    for point, cost in zip(closed_form.points, closed_form.costs, strict=True):
        lines.append(f"  minimiser (m) {_matrix_text(frame.to_world(point[:2]))}  cost {cost:.12g}")
    lines += [
        "SDP relaxation (MATH §11, equality)",
        f"  status {sdp.status} (tolerance rung {sdp.rung}), iterations {sdp.iterations}, "
        f"solver time "
        f"{sdp.solve_time_s * 1e3:.3f} ms, call {sdp.wall_time_s * 1e3:.3f} ms",
    ]
    if sdp.message:
        lines.append(f"  message: {sdp.message}")
    if sdp.has_solution:
        lines += [
            f"  value {sdp.value:.12g}, lambda (dual) {sdp.multiplier:.10g}, rank {sdp.rank}",
            f"  eigenvalues of Z: {_matrix_text(sdp.z_eigenvalues)}",
            f"  eigenvalues of the lift: {_matrix_text(sdp.lift_eigenvalues)}",
            f"  relaxed r (local): {_matrix_text(sdp.relaxed_point)}",
        ]
        for point, cost in zip(sdp.points, sdp.costs, strict=True):
            lines.append(
                f"  recovered point (m) {_matrix_text(frame.to_world(point[:2]))}  cost {cost:.12g}"
            )
    if run is not None:
        lines += _estimate_lines(run, float(np.min(closed_form.costs)))
    lines += [
        "verdict",
        f"  relative objective gap {result.rel_objective_gap:.3e} (tolerance {rtol_objective:g})",
    ]
    if result.hard_case:
        lines.append(
            f"  mirror-pair distance {result.pair_distance_m:.3e} m "
            f"({result.pair_distance_rel:.3e} of the length scale; tolerance {rtol_argmin:g})"
        )
    else:
        lines.append(
            f"  argmin distance {result.argmin_distance_m:.3e} m "
            f"({result.argmin_distance_rel:.3e} of the length scale; tolerance {rtol_argmin:g})"
        )
    if result.candidates is not None:
        check = result.candidates
        lines.append(
            f"  candidates: {check.n_candidates} for {check.n_minimisers} minimiser(s), "
            f"max relative cost gap {check.max_rel_cost_gap:.3e}, max distance "
            f"{check.max_distance_m:.3e} m ({check.max_distance_rel:.3e} of the length scale), "
            f"missing {check.n_missing}, extra {check.n_extra}"
        )
    lines.append("  AGREE" if result.agrees else "  DISAGREE: " + "; ".join(result.reasons))
    return "\n".join(lines) + "\n", result.agrees


def _estimate_lines(run: EstimatorRun, optimum: float) -> list[str]:
    """The estimator's answer on one instance, each candidate with its lifted cost and gap."""
    estimate, problem = run.estimate, run.problem
    assert estimate is not None and problem is not None
    lines = [
        f"estimate ({estimate.estimator})",
        f"  success {estimate.success}, ambiguous {estimate.ambiguous}"
        + (f", message: {estimate.message}" if estimate.message else ""),
    ]
    tiny = np.finfo(float).tiny
    for point in estimate.candidates_m:
        cost = float(problem.cost(point))
        lines.append(
            f"  candidate (m) {_matrix_text(point)}  cost {cost:.12g}  "
            f"relative gap {(cost - optimum) / max(abs(optimum), tiny):.3e}"
        )
    return lines
