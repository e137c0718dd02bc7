r"""The Shor SDP relaxation of the Doppler-ToA CLS (MATH §11), an independent witness for §5.

The CLS of MATH §5 (paper eq ``finalest``, corrected) is

.. math::

    f^\star = \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad r_x^2 + r_y^2 - r_z = 0,
    \qquad r = (x_s, y_s, x_s^2 + y_s^2)

(with the emitter's height a coordinate, ``r = (x_s, y_s, z_s, ‖s‖²)`` and the constraint
``‖s‖² = r_w``: every matrix below one size larger, the lift 5×5). Lifting ``(r, 1)`` to
``W = [[X, r], [rᵀ, 1]] ⪰ 0`` makes the objective and the constraint linear in ``W``:

.. math::

    \min_W \operatorname{tr}(H W) \quad\text{s.t.}\quad
    \operatorname{tr}(C W) = 0,\quad W_{44} = 1,\quad W \succeq 0,

with ``H = [[AᵀA, −Aᵀb], [−bᵀA, bᵀb]]`` and ``C`` the lifted constraint, ``tr(C W) =
X_xx + X_yy − r_z``. The principal submatrix of ``W`` over ``(x, y, 1)`` is MATH §11's
``Z = [[Y, y], [yᵀ, 1]]`` and the constraint reads ``r_z = trace Y``. The lift must carry
``r_z`` too: the objective is quartic in ``y``, and a lift of ``(y, 1)`` alone with
``r = (y, trace Y)`` inside a convex quadratic only enforces ``r_z ≥ ‖y‖²`` (it is the
inequality relaxation below, not tight when λ* < 0).

- ``relaxation="equality"``: ``tr(C W) = 0``. A GTRS has no duality gap (S-lemma), so the
  optimal value equals the closed form's on every instance; the argmin is the rank-one ``W``
  of the closed form's point when the minimiser is unique. In the hard case (MATH §5) ``W``
  has rank two, a convex combination of the lifts of the two mirror minimisers (the analytic
  centre of an interior-point method: their midpoint); both are recovered as the two points
  of the line through ``r`` along the principal direction of the Schur complement
  ``X − r rᵀ`` (the null direction of ``A`` in the hard case) that satisfy the constraint.
- ``relaxation="inequality"``: ``tr(C W) ≤ 0``, i.e. ``r_z ≥ trace Y ≥ ‖y‖²``. It is the
  relaxation of ``‖y‖² ≤ r_z``, tight only when λ* ≥ 0 (MATH §11); with λ* < 0 it returns the
  unconstrained least-squares point, strictly inside the paraboloid, at a value below f*.

Where things are. :mod:`estimators.sdp.sdp_lift` compresses the rows (QR) to a problem whose size
does not depend on the number of samples, whitens it around the least-squares point, and
recovers the minimisers from an optimal lift, for many systems at once.
:mod:`estimators.sdp.sdp_solvers` holds the conic program, its solvers (Clarabel called directly
on a program whose pattern is built once per process, the default; SCS through a parametrised
cvxpy problem) and the tolerance rungs each system climbs. This module holds the status
discipline (:func:`solve_relaxations`: only ``optimal`` is a success, ``optimal_inaccurate``
is retried at Clarabel's default tolerances, a success with non-finite numbers is
``non_finite``) and the estimator :class:`SdpCls`.

One trial or many. :meth:`SdpCls.estimate_columns` solves a whole
:class:`~scenarios.types.MeasurementBatch`: the rows of every trial come from
:mod:`estimators.closed_form.cls_batch` (the same code as ``cls``'s batch), the QR compression, the
whitening, the recovery and the mirror rule are vectorised over trials, and the only
per-trial Python is the solver call of each trial and stage (with its own rung ladder).
:meth:`SdpCls.estimate` is that same computation on a batch of one trial. Every per-trial
number of it depends on that trial alone, to the last bit (:mod:`estimators.sdp.sdp_lift`; a
chunk of one trial has its rows computed as two, since numpy sums a single column in another
order), so a trial gets exactly the same solver inputs, solves, statuses, candidates and
tie-break draws alone as in any batch.

References
----------
Beck, Stoica & Li, "Exact and approximate solutions of source localization problems",
IEEE TSP 56(5), 2008. Moré, "Generalizations of the trust region problem", 1993.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import (
    Capabilities,
    Estimate,
    check_side_prior,
    require_batch,
    require_modalities,
)
from estimators.batch import BatchEstimates, check_rngs
from estimators.closed_form.cls_batch import CHUNK_ELEMENTS, MAX_CHUNK, SharedGeometry
from estimators.goodness_of_fit import with_fit, with_fit_columns
from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT, FinalizedColumns, finalize_columns
from estimators.sdp.sdp_lift import (
    RANK_RTOL,
    ChunkRows,
    FloatArray,
    IntArray,
    compress_rows,
    compress_stacked,
    object_column,
    read_lifts,
    whiten_batch,
)
from estimators.sdp.sdp_solvers import (
    NON_FINITE,
    OPTIMAL,
    OPTIMAL_INACCURATE,
    RELAXATIONS,
    SOLVER_ERROR,
    SOLVERS,
    USER_LIMIT,
    Relaxation,
    SdpColumns,
    SdpSolution,
    Solver,
    solve_ladders,
    solver_attempts,
)
from scenarios.nuisance import HEIGHT_UNKNOWN, position_dimension
from scenarios.types import MeasurementBatch, MeasurementSet


def _python(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _row(columns: dict[str, NDArray[Any]], index: int) -> dict[str, Any]:
    """Entry ``index`` of every column, as Python values."""
    return {key: _python(column[index]) for key, column in columns.items()}


def _inaccurate_message(solver: str) -> str:
    return f"solver {solver} returned optimal_inaccurate: the witness is not certified"


def solve_relaxations(
    R: FloatArray,
    c: FloatArray,
    residual_sq: FloatArray,
    *,
    relaxation: Relaxation = "equality",
    solver: Solver = "CLARABEL",
    max_iter: int | None = None,
    rank_rtol: float = RANK_RTOL,
) -> SdpColumns:
    """Solve the relaxation of MATH §11 for ``n`` compressed systems ``(R, c, ρ²)``
    (:func:`estimators.sdp.sdp_lift.compress_stacked`; shapes (n, 3, 3), (n, 3), (n,), finite).

    Each system climbs its own rungs of :func:`solver_attempts` while its status is
    ``optimal_inaccurate`` or ``solver_error`` (:func:`estimators.sdp.sdp_solvers.solve_ladders`).
    Never raises for a solver failure: the status and message say what happened. A status
    ``optimal``/``optimal_inaccurate`` whose lift, recovered points, costs or value are not
    finite becomes ``non_finite``.
    """
    attempts = solver_attempts(solver, max_iter)
    if relaxation not in RELAXATIONS:
        raise ValueError(f"relaxation: expected one of {RELAXATIONS}, got {relaxation!r}")
    n = len(R)
    whitened = whiten_batch(R, c, residual_sq)
    out = solve_ladders(whitened, relaxation, solver, attempts)
    status, message = list(out.status), [""] * n
    statuses = object_column(status)
    solved = out.has_lift & ((statuses == OPTIMAL) | (statuses == OPTIMAL_INACCURATE))
    finite_lift = solved & np.isfinite(out.lift).all(axis=(1, 2))
    for i in np.flatnonzero(~finite_lift).tolist():
        if status[i] == SOLVER_ERROR:
            message[i] = (
                f"solver {solver} failed ({out.error[i]}); try solver='SCS' or check the rows"
            )
        elif not solved[i]:
            hint = " (raise max_iter)" if status[i] == USER_LIMIT else ""
            message[i] = f"solver {solver} stopped with status {status[i]}{hint}"
        else:
            message[i] = f"solver {solver} reported {status[i]} but its lift is not finite"
            status[i] = NON_FINITE
    read = read_lifts(out.lift, whitened, R, c, residual_sq, finite_lift, rank_rtol=rank_rtol)
    for i in np.flatnonzero(finite_lift & ~read.finite).tolist():
        message[i] = (
            f"solver {solver} reported {status[i]} but the recovered points or the value are "
            "not finite"
        )
        status[i] = NON_FINITE
    for i in np.flatnonzero(read.finite & (statuses == OPTIMAL_INACCURATE)).tolist():
        message[i] = _inaccurate_message(solver)
    # Lagrangian of the solver: tr(H W)/s + ν tr(C W)/κ  ⇔  ‖Ar − b‖² + ν (s/κ)(‖y‖² − r_z);
    # MATH §5 writes λ (‖y‖² − r_z) with the same sign.
    with np.errstate(all="ignore"):
        multiplier = out.dual * whitened.objective_scale / whitened.constraint_scale
    return SdpColumns(
        status=status,
        message=message,
        value=read.value,
        points=read.points,
        count=read.count,
        costs=read.costs,
        lift=read.lift,
        rank=read.rank,
        multiplier=np.where(read.finite, multiplier, np.nan),
        iterations=out.iterations,
        solve_time=out.solve_time,
        rung=out.rung,
        rungs_solve_time=out.rungs_solve_time,
    )


def solve_sdp_relaxation(
    A: ArrayLike,
    b: ArrayLike,
    *,
    relaxation: Relaxation = "equality",
    solver: Solver = "CLARABEL",
    max_iter: int | None = None,
    rank_rtol: float = RANK_RTOL,
) -> SdpSolution:
    """Solve the SDP relaxation of MATH §11 for the stacked rows ``A r = b`` of MATH §5.

    ``A`` (m, 3), or (m, 4) with the height a coordinate, and ``b`` (m,) in a frame scaled to
    order one
    (:class:`~estimators.closed_form.cls_rows.LocalFrame`); ``relaxation`` ``equality`` (``r_z =
    trace Y``, the Shor relaxation, tight) or ``inequality`` (``r_z ≥ trace Y``, tight only when
    λ* ≥ 0); ``solver`` Clarabel (called directly) or SCS (through cvxpy); ``max_iter`` the
    solver's iteration limit (None: its default); ``rank_rtol`` the relative eigenvalue
    threshold for the rank of the whitened lift. :func:`solve_relaxations` for one system:
    never raises for a solver failure. Raises ``ValueError`` for malformed ``A``/``b`` (shape,
    NaN) or an unknown ``relaxation``/``solver``.
    """
    started = time.perf_counter()
    R, c, residual_sq = compress_rows(A, b)
    columns = solve_relaxations(
        R[None],
        c[None],
        np.array([residual_sq]),
        relaxation=relaxation,
        solver=solver,
        max_iter=max_iter,
        rank_rtol=rank_rtol,
    )
    return columns.solution(0, wall_time_s=time.perf_counter() - started)


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------

RANK_TWO_NOTE = "rank-two lift: mirror pair recovered (MATH §5, §11)"
LOOSE_NOTE = "inequality relaxation not tight (λ* < 0, MATH §11)"
LOOSE_GAP = 1e-6
"""A tightness gap above this flags a loose inequality relaxation in the message."""


@dataclass(frozen=True, kw_only=True)
class SdpCls:
    """The CLS of MATH §3-§6 solved through its SDP relaxation (MATH §11).

    Same rows and two-stage weighting as ``cls`` (:mod:`estimators.closed_form.cls_batch`): stage 1
    weights from the data, stage 2 from each trial's stage-1 SDP estimate (its first
    recovered point). The returned ``diagnostics`` carry the solver status, the relaxation
    value, the CLS cost of the returned points (their difference is the tightness gap), the
    eigenvalues of ``Z`` and of the full lift, the rank and λ from the dual, ``stage_statuses``
    (one solver status per stage) and ``estimate_solve_time_s`` (the solver's own time over
    every solve of the estimate, stages and rungs). Only status ``optimal`` is a success
    (``optimal_inaccurate`` too with ``accept_inaccurate``, flagged in ``message``), after the
    tolerance rungs of :func:`solver_attempts` (the documented retry); a solve that reports
    success with a non-finite lift, point or value is a failure with status ``non_finite``.
    The program's fixed part is cached per process, so the estimator itself only stores
    options (and pickles).

    ``estimate_columns``/``estimate_batch`` solve a whole batch (module docstring); trial
    ``i`` gets exactly what ``estimate(batch.trial(i), rng=rngs[i])`` returns.

    Parameters
    ----------
    relaxation : {"equality", "inequality"}
        The Shor relaxation ``r_z = trace Y`` or the looser ``r_z ≥ trace Y`` (tight only
        when λ* ≥ 0).
    solver : {"CLARABEL", "SCS"}
    max_iter : int or None
        The solver's iteration limit; None keeps its default.
    weighting : {"optimal", "none"}
        As for ``cls``: two-stage whitening (MATH §6), or per-sample rows unweighted.
    frames : {"all", "last"}
    side_prior_m : (x, y) or None
        A rough emitter position; picks the nearer mirror candidate (MATH §7).
    accept_inaccurate : bool
        Accept status ``optimal_inaccurate`` as a success (flagged in ``message``). Off by
        default: only ``optimal`` certifies the witness.
    """

    name: ClassVar[str] = "sdp-cls"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    required_modules: ClassVar[tuple[str, ...]] = ("cvxpy", "clarabel")

    relaxation: Relaxation = "equality"
    solver: Solver = "CLARABEL"
    max_iter: int | None = None
    weighting: Literal["optimal", "none"] = "optimal"
    frames: Literal["all", "last"] = "all"
    side_prior_m: tuple[float, float] | None = None
    accept_inaccurate: bool = False

    def __post_init__(self) -> None:
        if self.relaxation not in RELAXATIONS:
            raise ValueError(
                f"relaxation: expected 'equality' or 'inequality', got {self.relaxation!r}"
            )
        if self.solver not in SOLVERS:
            raise ValueError(f"solver: expected 'CLARABEL' or 'SCS', got {self.solver!r}")
        if self.max_iter is not None and (
            isinstance(self.max_iter, bool)
            or int(self.max_iter) != self.max_iter
            or self.max_iter < 1
        ):
            raise ValueError(
                f"max_iter: expected a whole number >= 1 or None, got {self.max_iter!r}"
            )
        if self.weighting not in ("optimal", "none"):
            raise ValueError(f"weighting: expected 'optimal' or 'none', got {self.weighting!r}")
        if self.frames not in ("all", "last"):
            raise ValueError(f"frames: expected 'all' or 'last', got {self.frames!r}")
        check_side_prior(self.side_prior_m)
        if not isinstance(self.accept_inaccurate, bool):
            raise ValueError(
                f"accept_inaccurate: expected true or false, got {self.accept_inaccurate!r}"
            )

    def capabilities(self) -> Capabilities:
        """Like ``cls`` (unit-invariant when weighted), to the interior-point solver's accuracy."""
        return Capabilities(
            modalities=self.requires,
            frames=self.frames,
            modules=self.required_modules,
            batch=True,
            unit_invariant=self.weighting == "optimal",
            unknowns=frozenset({HEIGHT_UNKNOWN}),
            noise_free_tolerance_m=1e-5,
            tolerance_reason="the interior-point solver stops at a relative gap of about 1e-8",
        )

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        decided = _solve_batch(self, MeasurementBatch.of_one(data), [rng])
        if decided.index.size == 0:
            return decided.failures[0]
        if decided.redone:
            return with_fit(self, decided.redone[0], data)
        return with_fit(self, decided.estimate(0, self.name, self.solver), data)

    def estimate_batch(
        self,
        batch: MeasurementBatch,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> list[Estimate]:
        """``estimate`` of every trial (trial ``i`` with ``rngs[i]``), solved together; a
        failed trial is its failed estimate, diagnostics included."""
        batch = require_batch(self, batch)
        if batch.n_trials == 0:
            check_rngs(rngs, 0)
            return []
        decided = _solve_batch(self, batch, rngs)
        estimates = [
            decided.estimate(row, self.name, self.solver) for row in range(len(decided.index))
        ]
        out = dict(zip(decided.index.tolist(), estimates, strict=True))
        out |= decided.redone | decided.failures
        return [with_fit(self, out[i], batch.trial(i)) for i in range(batch.n_trials)]

    def estimate_columns(
        self,
        batch: MeasurementBatch,
        *,
        rngs: Sequence[np.random.Generator | None] | None = None,
    ) -> BatchEstimates:
        """``estimate_batch`` as columns, without an object per trial (a failed trial keeps
        its message, not its diagnostics)."""
        batch = require_batch(self, batch)
        if batch.n_trials == 0:
            check_rngs(rngs, 0)
            return BatchEstimates.from_estimates(self.name, [])
        columns = _columns(self, _solve_batch(self, batch, rngs), batch.n_trials)
        return with_fit_columns(self, columns, batch)


@dataclass(frozen=True, slots=True, eq=False)
class _Solved:
    """The trials of one chunk that passed every stage, in the local frame's world units."""

    index: IntArray
    world: FloatArray  # (k, 2, d)
    count: IntArray
    costs: FloatArray  # (k, 2)
    code: IntArray  # message code (_message)
    diagnostics: dict[str, NDArray[Any]]

    FIELDS: ClassVar[tuple[str, ...]] = ("index", "world", "count", "costs", "code")

    @staticmethod
    def join(parts: list[_Solved], dimension: int) -> _Solved:
        """The trials of every chunk, in order."""
        if len(parts) == 1:
            return parts[0]
        empty = np.empty(0, dtype=np.int64)
        if not parts:
            world = np.empty((0, 2, dimension))
            return _Solved(empty, world, empty, np.empty((0, 2)), empty, {})
        joined = (np.concatenate([getattr(p, name) for p in parts]) for name in _Solved.FIELDS)
        keys = list(parts[0].diagnostics)
        return _Solved(
            *joined, {key: np.concatenate([p.diagnostics[key] for p in parts]) for key in keys}
        )


def _message(code: int, solver: str) -> str:
    """The message of a success: bit 4 accepted ``optimal_inaccurate``, 2 rank two, 1 loose."""
    notes = [_inaccurate_message(solver)] if code & 4 else []
    notes += [RANK_TWO_NOTE] if code & 2 else []
    notes += [LOOSE_NOTE] if code & 1 else []
    return "; ".join(notes)


def _solve_batch(
    estimator: SdpCls,
    batch: MeasurementBatch,
    rngs: Sequence[np.random.Generator | None] | None,
) -> _Decided:
    """Every stage of every trial, chunk by chunk, then the mirror rule and the draws."""
    n = batch.n_trials
    generators = check_rngs(rngs, n)
    shared = SharedGeometry.of(
        batch, estimator.frames, dimension=position_dimension(batch.geometry.unknowns)
    )
    assert batch.toa_s is not None and batch.doppler_hz is not None
    ranges = shared.used.speed_of_light_mps * batch.toa_s[:, shared.columns]
    doppler = batch.doppler_hz[:, shared.columns]
    chunk = int(np.clip(CHUNK_ELEMENTS // max(shared.used.n_samples, 1), 256, MAX_CHUNK))
    failures: dict[int, Estimate] = {}
    if shared.dimension == 3 and shared.line is not None:  # a circle of minimisers (MATH §7)
        failure = Estimate.failed(estimator.name, STRAIGHT_TRACK_HEIGHT, dimension=3)
        failures = dict.fromkeys(range(n), failure)
        return _decide(estimator, shared, [], failures, generators)
    solved = [
        _solve_chunk(
            estimator,
            shared,
            ranges[start : start + chunk],
            doppler[start : start + chunk],
            start,
            failures,
        )
        for start in range(0, n, chunk)
    ]
    parts = [part for part in solved if part is not None]
    return _decide(estimator, shared, parts, dict(sorted(failures.items())), generators)


def _solve_chunk(
    estimator: SdpCls,
    shared: SharedGeometry,
    ranges: FloatArray,
    doppler: FloatArray,
    start: int,
    failures: dict[int, Estimate],
) -> _Solved | None:
    """Every stage of the trials ``start, start + 1, ...`` of ``ranges`` (m, K); failures go
    to ``failures`` (by trial index), the trials that pass every stage are returned (None when
    no trial does)."""
    name, solver = estimator.name, estimator.solver
    d = shared.dimension
    chunk = ChunkRows(shared, ranges, doppler)
    m = chunk.m
    rows = "weighted" if estimator.weighting == "optimal" else "per-sample"
    stages = 2 if rows == "weighted" else 1
    alive = np.ones(m, dtype=bool)
    statuses: list[list[str]] = [[] for _ in range(m)]
    spent = np.zeros(m)
    weights_at = None
    for stage in range(1, stages + 1):
        system = chunk.systems(rows, weights_at)
        finite = np.isfinite(system).all(axis=(1, 2))
        for i in np.flatnonzero(alive & ~finite).tolist():
            failures[start + i] = Estimate.failed(
                name,
                f"rows: the stage-{stage} CLS system has NaN or infinite entries "
                "(degenerate geometry or weights); check speeds, ranges and noise levels",
                dimension=d,
                stage=stage,
            )
        alive &= finite
        index = np.flatnonzero(alive)
        if index.size == 0:
            return None
        solved = solve_relaxations(
            *compress_stacked(system[index]),
            relaxation=estimator.relaxation,
            solver=solver,
            max_iter=estimator.max_iter,
        )
        spent[index] += np.where(np.isfinite(solved.rungs_solve_time), solved.rungs_solve_time, 0)
        for i, status in zip(index.tolist(), solved.status, strict=True):
            statuses[i].append(status)
        accepted = solved.accepted(estimator.accept_inaccurate)
        if stage == stages or not accepted.all():
            diagnostics = solved.diagnostic_columns()
        for j in np.flatnonzero(~accepted).tolist():
            i = int(index[j])
            message = solved.message[j] or (
                f"solver {solver} returned status {solved.status[j]}, not accepted"
            )
            failures[start + i] = Estimate.failed(
                name,
                f"stage {stage}: {message}",
                dimension=d,
                **_row(diagnostics, j),
                stage=stage,
                stage_statuses=list(statuses[i]),
                estimate_solve_time_s=float(spent[i]),
            )
        alive[index[~accepted]] = False
        if stage < stages:  # the weights of stage 2 at each trial's first stage-1 point
            weights_at = tuple(np.full(m, np.nan) for _ in range(d))
            for axis, values in enumerate(weights_at):
                values[index] = solved.points[:, 0, axis]

    # the trials that passed: world candidates, message, diagnostics
    final = index[accepted]
    if final.size == 0:
        return None
    every = final.size == index.size
    if not every:
        diagnostics = {key: column[accepted] for key, column in diagnostics.items()}
    count, points, costs = (
        (solved.count, solved.points, solved.costs)
        if every
        else (solved.count[accepted], solved.points[accepted], solved.costs[accepted])
    )
    world = points[:, :, :d] * chunk.scale[final, None, None]
    world[..., :2] += shared.origin  # (the frame's z is the world's, MATH §5)
    valid = np.arange(2) < count[:, None]
    good = (np.isfinite(world).all(axis=2) | ~valid).all(axis=1)
    rank_two = diagnostics["rank"] >= 2
    loose = np.zeros_like(rank_two)
    if estimator.relaxation == "inequality":
        loose = diagnostics["tightness_gap"] > LOOSE_GAP
    inaccurate = diagnostics["status"] == OPTIMAL_INACCURATE
    diagnostics |= {
        "relaxation": object_column([estimator.relaxation] * final.size),
        "solver": object_column([solver] * final.size),
        "stages": np.full(final.size, stages, dtype=np.int64),
        "stage_statuses": object_column([list(statuses[i]) for i in final.tolist()]),
        "estimate_solve_time_s": spent[final],
        "n_samples": np.full(final.size, shared.used.n_samples, dtype=np.int64),
    }
    for j in np.flatnonzero(~good).tolist():
        failures[start + int(final[j])] = Estimate.failed(
            name, "the recovered minimisers are not finite", dimension=d, **_row(diagnostics, j)
        )
    code = (4 * inaccurate + 2 * rank_two + loose).astype(np.int64)
    if not good.all():
        world, count, costs, code, final = (
            world[good],
            count[good],
            costs[good],
            code[good],
            final[good],
        )
        diagnostics = {key: column[good] for key, column in diagnostics.items()}
    return _Solved(start + final, world, count, costs, code, diagnostics)


@dataclass(frozen=True, slots=True, eq=False)
class _Decided:
    """Every trial's outcome. The trials that passed are rows of the arrays (trial ``index``),
    with their kept candidates in the mirror rule's order and the one chosen; ``redone`` holds
    those finalized one at a time and ``failures`` the failed ones, by trial."""

    index: IntArray
    candidates: FloatArray  # (k, width, d)
    n_kept: IntArray
    chosen: IntArray
    ambiguous: NDArray[np.bool_]
    code: IntArray
    diagnostics: dict[str, NDArray[Any]]
    redone: dict[int, Estimate]
    failures: dict[int, Estimate]

    def estimate(self, row: int, name: str, solver: str) -> Estimate:
        """The estimate of row ``row``, as :meth:`BatchEstimates.estimate` builds it."""
        return Estimate(
            estimator=name,
            position_m=self.candidates[row, self.chosen[row]],
            candidates_m=self.candidates[row, : self.n_kept[row]],
            ambiguous=bool(self.ambiguous[row]),
            success=True,
            message=_message(int(self.code[row]), solver),
            diagnostics=_row(self.diagnostics, row),
        )


def _decide(
    estimator: SdpCls,
    shared: SharedGeometry,
    parts: list[_Solved],
    failures: dict[int, Estimate],
    generators: Sequence[np.random.Generator | None],
) -> _Decided:
    """The mirror rule (:func:`~estimators.mirror_rule.finalize_columns`) for every trial that
    passed, and the tie-break draws in trial order."""
    d = shared.dimension
    solved = _Solved.join(parts, d)
    index, world, count, costs, code = (getattr(solved, name) for name in _Solved.FIELDS)
    found, keys = dict(solved.diagnostics), list(solved.diagnostics)
    if index.size:
        # with the height a coordinate, a flight in one plane (a level turn, two legs) leaves
        # the reflection through it: the rule adds it, whether the lift recovered one point or
        # both, and drops what lies above the UAV (MATH §7)
        ceiling = {} if d == 2 else {"ceiling_m": float(np.max(shared.z)), "plane": shared.plane}
        with np.errstate(all="ignore"):
            final = finalize_columns(
                world,
                count,
                costs,
                shared.mean_xy,
                shared.line,
                side_prior_m=estimator.side_prior_m,
                **ceiling,
            )
    else:  # no trial passed: every one is in failures
        none = np.zeros(0, dtype=bool)
        final = FinalizedColumns(
            np.empty((0, 1, d)), count, np.empty((0, 1), dtype=np.int64), count, none, none, none
        )
    chosen = final.chosen.copy()
    for j in np.flatnonzero(final.draw).tolist():  # rows are in trial order
        rng = generators[int(index[j])]
        if rng is not None:
            chosen[j] = rng.integers(final.n_candidates[j])
    redone = {
        int(index[j]): Estimate.failed(
            estimator.name, "no finite candidate (MATH §7)", dimension=d, **_row(found, j)
        )
        for j in np.flatnonzero(final.invalid).tolist()
    }
    if keys:
        found["straight_track"] = np.full(len(index), shared.line is not None)
    return _Decided(
        index=index,
        candidates=final.candidates,
        n_kept=final.n_candidates,
        chosen=chosen,
        ambiguous=final.ambiguous,
        code=code,
        diagnostics=found,
        redone=redone,
        failures=failures,
    )


def _columns(estimator: SdpCls, decided: _Decided, n: int) -> BatchEstimates:
    """The estimates of ``n`` trials as :class:`BatchEstimates` (a failed trial keeps its
    message, not its diagnostics)."""
    index = decided.index
    d = decided.candidates.shape[2]
    width = max(decided.candidates.shape[1], 1)
    candidates = np.full((n, width, d), np.nan)
    candidates[index, : decided.candidates.shape[1]] = decided.candidates
    n_kept = np.zeros(n, dtype=np.int64)
    n_kept[index] = decided.n_kept
    position = np.full((n, d), np.nan)
    position[index] = decided.candidates[np.arange(len(index)), decided.chosen]
    ambiguous = np.zeros(n, dtype=bool)
    ambiguous[index] = decided.ambiguous
    success = np.zeros(n, dtype=bool)
    success[index] = True
    messages = [_message(code, estimator.solver) for code in range(8)]
    message_code = np.zeros(n, dtype=np.int64)
    message_code[index] = decided.code
    for trial, failure in decided.failures.items():
        if failure.message not in messages:
            messages.append(failure.message)
        message_code[trial] = messages.index(failure.message)
    diagnostics: dict[str, NDArray[Any]] = {}
    for key, column in decided.diagnostics.items():
        full = np.empty(n, dtype=object) if column.dtype == object else np.zeros(n, column.dtype)
        full[index] = column
        diagnostics[key] = full
    columns = BatchEstimates(
        estimator=estimator.name,
        position_m=position,
        candidates_m=candidates,
        n_candidates=n_kept,
        ambiguous=ambiguous,
        success=success,
        message_code=message_code,
        messages=tuple(messages),
        diagnostics=diagnostics,
    )
    return columns.with_trials(list(decided.redone), list(decided.redone.values()))
