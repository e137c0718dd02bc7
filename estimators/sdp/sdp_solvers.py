r"""The conic program of MATH §11 and the two ways it is solved: Clarabel directly, or cvxpy.

The lifted problem over the symmetric ``W`` of size ``p = d + 2`` (4×4 with the emitter's
height known, 5×5 with it a coordinate; whitened data of
:func:`estimators.sdp.sdp_lift.whiten_relaxation`) is

.. math::

    \min_W \operatorname{tr}(H W) \quad\text{s.t.}\quad W_{44} = 1,\quad
    \operatorname{tr}(C W) = 0 \ (\text{or} \le 0),\quad W \succeq 0 .

**Clarabel, directly** (:func:`solve_with_clarabel`, ``solver="CLARABEL"``). The program is
tiny (10 variables and 12 rows for p = 4, 15 and 17 for p = 5) and its sparsity never changes,
so it is written for Clarabel's own API (``min qᵀx`` s.t. ``A x + s = b``, ``s ∈ K``) once per
relaxation and size and only its data
are filled per solve. It is the program cvxpy 1.9 compiles from the parametrised problem of
:func:`relaxation_problem`, entry for entry: ``x`` holds the lower triangle of ``W`` column by
column (cvxpy's order for a symmetric variable); ``q = (H_ii, 2H_ij)``; row 0 is ``W_pp = 1``
and row 1 ``tr(C W)`` (the zero cone for the equality relaxation, ``−tr(C W) ≥ 0`` in the
nonnegative cone for the inequality); the other rows are ``−svec(W)`` in
``PSDTriangleConeT(p)`` (upper triangle column by column, off-diagonals times √2). The dual
of row 1 is cvxpy's ``dual_value`` of the lifted constraint. The statuses are translated to
cvxpy's vocabulary with cvxpy's own table (``Solved`` → ``optimal``, ``AlmostSolved`` →
``optimal_inaccurate``, ``MaxIterations``/``MaxTime`` → ``user_limit``, ``NumericalError``,
``InsufficientProgress`` and anything unknown → ``solver_error``). Every solve builds a fresh
``DefaultSolver`` (Clarabel starts each solve from its own initial point) from a
``DefaultSettings`` holding every setting of its rung, which Clarabel copies: nothing of a
previous solve, settings or iterate, reaches the next one. The one shared piece, the values
of ``A``, is written under a lock and copied by Clarabel when the solver is built. This skips
cvxpy's per-solve work (parameter refill, reduction chain, inversion), some 90 % of a solve
through ``Problem.solve`` on a problem this small. Re-using one solver through
``DefaultSolver.update`` (clarabel 0.11) was measured and not adopted: it saves some 13 µs of
a 90 µs solve, but it keeps the equilibration of the data the solver was built on (the lift
moves by up to 1e−7, and a trial's answer would depend on the trial solved before it), and the
``solve_time`` it reports then exceeds the wall time of the call. A fresh solver's
``solve_time`` counts its setup, so building it costs little outside Clarabel's own time.

**cvxpy** (:func:`solve_with_cvxpy`, ``solver="SCS"``). SCS is only a cross-check (slower,
less accurate at its default tolerances), so it keeps the parametrised (DPP) cvxpy problem,
built once per process per relaxation and re-solved under a lock; writing SCS's own cone
conventions (lower triangle, its scaling) by hand is not worth it for a cross-check.

**Many systems** (:func:`solve_ladders`): each of ``n`` whitened systems climbs the tolerance
rungs of :func:`solver_attempts` on its own; its data for Clarabel are computed for all at
once, and this loop over systems is the only per-trial Python of a batch. Their answers, once
the status discipline of :mod:`estimators.sdp.sdp_cls` has read them, are :class:`SdpColumns`
(one :class:`SdpSolution` per system).

Neither :mod:`cvxpy` nor :mod:`clarabel` is imported before the first solve: the registry
reads ``SdpCls.required_modules`` before anything is imported.
"""

from __future__ import annotations

import functools
import math
import threading
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from estimators.sdp.sdp_lift import (
    IntArray,
    WhitenedBatch,
    WhitenedRelaxation,
    lift_spectra,
    object_column,
    z_rows,
)

if TYPE_CHECKING:
    import cvxpy as cp

FloatArray = NDArray[np.float64]
Relaxation = Literal["equality", "inequality"]
Solver = Literal["CLARABEL", "SCS"]

RELAXATIONS: tuple[str, ...] = ("equality", "inequality")
SOLVERS: tuple[str, ...] = ("CLARABEL", "SCS")

# cvxpy's status strings (cvxpy.OPTIMAL, ...), spelled out so that nothing here imports cvxpy.
OPTIMAL, OPTIMAL_INACCURATE, USER_LIMIT = "optimal", "optimal_inaccurate", "user_limit"
INFEASIBLE, INFEASIBLE_INACCURATE = "infeasible", "infeasible_inaccurate"
UNBOUNDED, UNBOUNDED_INACCURATE = "unbounded", "unbounded_inaccurate"
SOLVER_ERROR = "solver_error"

CLARABEL_STATUSES: dict[str, str] = {
    "Solved": OPTIMAL,
    "AlmostSolved": OPTIMAL_INACCURATE,
    "PrimalInfeasible": INFEASIBLE,
    "DualInfeasible": UNBOUNDED,
    "AlmostPrimalInfeasible": INFEASIBLE_INACCURATE,
    "AlmostDualInfeasible": UNBOUNDED_INACCURATE,
    "MaxIterations": USER_LIMIT,
    "MaxTime": USER_LIMIT,
    "NumericalError": SOLVER_ERROR,
    "InsufficientProgress": SOLVER_ERROR,
    "Unsolved": SOLVER_ERROR,
}
"""Clarabel's ``SolverStatus`` names to cvxpy's statuses (cvxpy 1.9's ``CLARABEL.STATUS_MAP``);
a name not listed is a ``solver_error``."""

_SOLUTION_PRESENT = frozenset({OPTIMAL, OPTIMAL_INACCURATE, USER_LIMIT})

CLARABEL_TOLERANCES: tuple[tuple[float, float], ...] = ((1e-10, 1e-9), (1e-8, 1e-8))
"""Clarabel's ``(tol_gap, tol_feas)`` rungs, tried in order while the status is
``optimal_inaccurate`` or a solver error. The whitened problem is of order one and its value at
least one, so the gap criterion is relative. On a few flat instances (about 1 in 4000 of the
validation families) the primal residual grows again after the gap falls below 1e−9 and the
tight rung ends ``AlmostSolved``; the second rung is Clarabel's default."""

SCS_TOLERANCES: tuple[tuple[float, float], ...] = ((1e-9, 1e-9),)
"""SCS's ``(eps_abs, eps_rel)``: one rung (SCS is a cross-check)."""

CLARABEL_MAX_ITER = 200
"""Clarabel's own default iteration limit."""

SCS_MAX_ITERS = 100_000
"""SCS's own default iteration limit."""


def solver_attempts(solver: Solver, max_iter: int | None) -> list[dict[str, Any]]:
    """The solver's settings, one dict per tolerance rung, tightest first.

    Every dict names every setting this module changes from the solver's defaults, and each
    solve applies all of them: a Clarabel solve starts from a fresh ``DefaultSettings``; the
    cvxpy path (SCS) passes them with ``warm_start=False``, since cvxpy keeps the solver object
    of the previous solve and only overrides the settings it is given (an omitted ``max_iters``
    would inherit the last call's, and SCS would start from the previous solution).
    """
    if solver == "CLARABEL":
        limit = CLARABEL_MAX_ITER if max_iter is None else int(max_iter)
        return [
            {
                "verbose": False,
                "tol_gap_abs": gap,
                "tol_gap_rel": gap,
                "tol_feas": feasibility,
                "max_iter": limit,
            }
            for gap, feasibility in CLARABEL_TOLERANCES
        ]
    if solver == "SCS":
        limit = SCS_MAX_ITERS if max_iter is None else int(max_iter)
        return [
            {"verbose": False, "eps_abs": eps_abs, "eps_rel": eps_rel, "max_iters": limit}
            for eps_abs, eps_rel in SCS_TOLERANCES
        ]
    raise ValueError(f"solver: expected one of {SOLVERS}, got {solver!r}")


@dataclass(frozen=True, slots=True, eq=False)
class SolveOutcome:
    """One solver call on the whitened problem: the status (cvxpy's vocabulary or
    ``solver_error``), the whitened lift ``W_w`` (p, p) or None when the solver returned no
    primal point, the multiplier of the lifted constraint row, the iterations, the solver's
    own time from its solve information (NaN when absent) and, for ``solver_error``, what went
    wrong."""

    status: str
    lift: FloatArray | None
    dual: float
    iterations: int | None
    solve_time_s: float
    error: str = ""


def _check_relaxation(relaxation: str) -> None:
    if relaxation not in RELAXATIONS:
        raise ValueError(f"relaxation: expected one of {RELAXATIONS}, got {relaxation!r}")


RETRIED: frozenset[str] = frozenset({OPTIMAL_INACCURATE, SOLVER_ERROR})
"""Statuses after which the next tolerance rung is tried (when there is one)."""


@dataclass(frozen=True, slots=True, eq=False)
class LadderOutcomes:
    """The last outcome of each of ``n`` systems' rung ladders, as columns.

    ``lift`` (n, p, p) is NaN where the solver returned no primal point (``has_lift``);
    ``rung`` is the rung of the last outcome (1: the tightest) and ``rungs_solve_time`` the
    solver's own time summed over every rung tried (a rung without a time adds nothing).
    """

    status: list[str]
    lift: FloatArray
    has_lift: NDArray[np.bool_]
    dual: FloatArray
    iterations: list[int | None]
    solve_time: FloatArray
    rung: NDArray[np.int64]
    rungs_solve_time: FloatArray
    error: list[str]


def solve_ladders(
    whitened: WhitenedBatch,
    relaxation: Relaxation,
    solver: Solver,
    attempts: list[dict[str, Any]],
) -> LadderOutcomes:
    """Solve each of ``n`` whitened systems, trying the rungs of ``attempts`` in order while
    its status is in :data:`RETRIED`: each system's ladder is its own.

    This loop is the only per-system Python of a batch. For Clarabel the data of every system
    (``q`` and the lifted-constraint row) are computed at once, and one ``DefaultSettings`` per
    rung serves every solve of the call (Clarabel copies it into each new solver); a solve
    whose data are not finite is :data:`NON_FINITE_DATA` without calling Clarabel. SCS goes
    through cvxpy system by system (:func:`solve_with_cvxpy`).
    """
    n, size = whitened.objective.shape[:2]
    if solver == "CLARABEL":
        program = clarabel_program(relaxation, size)
        q = inner_product_coefficients(whitened.objective)
        rows = inner_product_coefficients(whitened.constraint)
        finite = (np.isfinite(q).all(axis=1) & np.isfinite(rows).all(axis=1)).tolist()
        options = [clarabel_settings(settings) for settings in attempts]

        def solve(index: int, rung: int) -> SolveOutcome:
            if not finite[index]:
                return NON_FINITE_DATA
            return clarabel_outcome(program, q[index], rows[index], options[rung])

    else:

        def solve(index: int, rung: int) -> SolveOutcome:
            system = whitened.trial(index)
            return solve_with_cvxpy(system, relaxation, solver, attempts[rung])

    last = len(attempts) - 1
    outcomes, rungs, spent = [], [], []
    for index in range(n):
        total = 0.0
        for rung in range(len(attempts)):
            outcome = solve(index, rung)
            if math.isfinite(outcome.solve_time_s):
                total += outcome.solve_time_s
            if rung == last or outcome.status not in RETRIED:
                break
        outcomes.append(outcome)
        rungs.append(rung + 1)
        spent.append(total)
    lift = np.full((n, size, size), np.nan)
    has_lift = np.array([o.lift is not None for o in outcomes], dtype=bool)
    if has_lift.any():
        lift[has_lift] = [o.lift for o in outcomes if o.lift is not None]
    return LadderOutcomes(
        status=[o.status for o in outcomes],
        lift=lift,
        has_lift=has_lift,
        dual=np.array([o.dual for o in outcomes], dtype=float),
        iterations=[o.iterations for o in outcomes],
        solve_time=np.array([o.solve_time_s for o in outcomes], dtype=float),
        rung=np.array(rungs, dtype=np.int64),
        rungs_solve_time=np.array(spent, dtype=float),
        error=[o.error for o in outcomes],
    )


# --------------------------------------------------------------------------------------------
# Clarabel, directly
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class LiftLayout:
    """Where the entries of a symmetric lift of size ``p`` sit in the conic program.

    ``lower``: the variable ``x``, entries ``(i, j)``, ``i ≥ j``, of ``W`` column by column
    (cvxpy's order); ``upper``: Clarabel's ``PSDTriangleConeT`` order, the upper triangle
    column by column; ``tr(M W) = Σ_k (M[i_k, j_k] + M[j_k, i_k]) · half_weights_k · x_k``
    with the flat indices ``lower_flat``, ``upper_flat``; ``W = x[lift_index]``.
    """

    size: int
    lower: tuple[tuple[int, int], ...]
    upper: tuple[tuple[int, int], ...]
    lower_flat: NDArray[np.intp]
    upper_flat: NDArray[np.intp]
    half_weights: FloatArray
    lift_index: NDArray[np.intp]

    @property
    def n_variables(self) -> int:
        return len(self.lower)

    @property
    def n_rows(self) -> int:
        return 2 + len(self.upper)


@functools.cache
def lift_layout(size: int) -> LiftLayout:
    """The :class:`LiftLayout` of a lift of ``size`` (4: the height known; 5: a coordinate)."""
    lower = tuple((i, j) for j in range(size) for i in range(j, size))
    upper = tuple((i, j) for j in range(size) for i in range(j + 1))
    rows = np.array([i for i, _ in lower])
    cols = np.array([j for _, j in lower])
    index = [[lower.index((max(i, j), min(i, j))) for j in range(size)] for i in range(size)]
    return LiftLayout(
        size=size,
        lower=lower,
        upper=upper,
        lower_flat=size * rows + cols,
        upper_flat=size * cols + rows,
        half_weights=np.where(rows == cols, 0.5, 1.0),
        lift_index=np.array(index),
    )


_LIFTED_ROW = 1


@dataclass(frozen=True, slots=True, eq=False)
class ClarabelProgram:
    """The fixed part of the conic program for one relaxation and lift size, built once per
    process.

    ``A`` (12×10 CSC for the 4×4 lift) keeps its pattern for good: the slots of the lifted-constraint row
    (``constraint_slots``, in ``x`` order) are stored even when zero and are the only values
    written per solve, under ``lock`` and only until Clarabel has copied the data into a new
    solver (:func:`run_clarabel`).
    """

    relaxation: str
    P: Any
    A: Any
    b: FloatArray
    cones: list[Any]
    constraint_slots: NDArray[np.intp]
    layout: LiftLayout
    lock: threading.Lock = field(default_factory=threading.Lock)


@functools.cache
def clarabel_program(relaxation: Relaxation, size: int = 4) -> ClarabelProgram:
    """The conic program of MATH §11 for Clarabel's API over a lift of ``size``, built once
    per process and cached."""
    _check_relaxation(relaxation)
    import clarabel
    from scipy.sparse import csc_array

    layout = lift_layout(size)
    last = size - 1
    # each column of A: row 0 (W_pp = 1) for the last variable, row 1 (tr(C W)), its PSD row
    indptr, indices, values, slots = [0], [], [], []
    for i, j in layout.lower:
        if (i, j) == (last, last):
            indices.append(0)
            values.append(1.0)
        slots.append(len(values))
        indices.append(_LIFTED_ROW)
        values.append(0.0)
        indices.append(2 + layout.upper.index((j, i)))
        values.append(-1.0 if i == j else -math.sqrt(2.0))
        indptr.append(len(values))
    A = csc_array(
        (np.array(values), np.array(indices, dtype=np.int32), np.array(indptr, dtype=np.int32)),
        shape=(layout.n_rows, layout.n_variables),
    )
    b = np.zeros(layout.n_rows)
    b[0] = 1.0
    b.flags.writeable = False
    cone = clarabel.PSDTriangleConeT(size)
    if relaxation == "equality":
        cones = [clarabel.ZeroConeT(2), cone]
    else:
        cones = [clarabel.ZeroConeT(1), clarabel.NonnegativeConeT(1), cone]
    return ClarabelProgram(
        relaxation=relaxation,
        P=csc_array((layout.n_variables, layout.n_variables)),
        A=A,
        b=b,
        cones=cones,
        constraint_slots=np.array(slots, dtype=np.intp),
        layout=layout,
    )


def inner_product_coefficients(M: FloatArray) -> FloatArray:
    """``a`` with ``tr(M W) = a · x`` for the symmetric part of ``M`` (cvxpy's coefficients
    of a symmetric parameter: ``M_ii`` and ``M_ij + M_ji``); ``M`` (..., p, p), ``a`` (...,
    p(p + 1)/2)."""
    size = M.shape[-1]
    layout = lift_layout(size)
    flat = M.reshape(*M.shape[:-2], size * size)
    return (flat[..., layout.lower_flat] + flat[..., layout.upper_flat]) * layout.half_weights


def clarabel_settings(settings: dict[str, Any]) -> Any:
    """A fresh ``clarabel.DefaultSettings`` with every entry of ``settings`` applied.

    Raises
    ------
    TypeError
        For a setting Clarabel does not know or a value of the wrong type.
    """
    import clarabel

    result = clarabel.DefaultSettings()
    for name, value in settings.items():
        try:
            setattr(result, name, value)
        except AttributeError:
            raise TypeError(f"settings: Clarabel has no setting {name!r}") from None
    return result


def run_clarabel(
    program: ClarabelProgram, q: FloatArray, constraint_row: FloatArray, settings: Any
) -> Any:
    """Build a fresh ``clarabel.DefaultSolver`` on the data and solve: the one call into
    Clarabel. Returns Clarabel's ``DefaultSolution``."""
    import clarabel

    with program.lock:
        program.A.data[program.constraint_slots] = constraint_row
        solver = clarabel.DefaultSolver(program.P, q, program.A, program.b, program.cones, settings)
    return solver.solve()


def solve_with_clarabel(
    whitened: WhitenedRelaxation, relaxation: Relaxation, settings: dict[str, Any]
) -> SolveOutcome:
    """One Clarabel solve of the program of :func:`clarabel_program` with the whitened data.

    A status outside cvxpy's table, an exception from Clarabel or non-finite data is a
    ``solver_error`` outcome; nothing is raised for a solver failure.
    """
    q = inner_product_coefficients(whitened.objective)
    constraint_row = inner_product_coefficients(whitened.constraint)
    if not (np.isfinite(q).all() and np.isfinite(constraint_row).all()):
        return NON_FINITE_DATA
    program = clarabel_program(relaxation, len(whitened.objective))
    return clarabel_outcome(program, q, constraint_row, clarabel_settings(settings))


NON_FINITE_DATA = SolveOutcome(
    SOLVER_ERROR, None, math.nan, None, math.nan, "the whitened data are not finite"
)
"""The outcome of a solve whose whitened data are not finite: Clarabel is not called."""


def clarabel_outcome(
    program: ClarabelProgram, q: FloatArray, constraint_row: FloatArray, options: Any
) -> SolveOutcome:
    """One Clarabel solve on finite data ``q``, ``constraint_row`` (p(p + 1)/2,) with the
    ``DefaultSettings`` ``options`` (copied by Clarabel when the solver is built, so one object
    serves every solve of a rung): :func:`run_clarabel` and the translation of its answer."""
    try:
        solution = run_clarabel(program, q, constraint_row, options)
    except Exception as error:  # Clarabel's own errors: a failed solve, not a crash
        return SolveOutcome(SOLVER_ERROR, None, math.nan, None, math.nan, str(error))
    name = str(solution.status)
    status = CLARABEL_STATUSES.get(name, SOLVER_ERROR)
    iterations = int(solution.iterations)
    solve_time = float(solution.solve_time)
    if status == SOLVER_ERROR:
        return SolveOutcome(
            status, None, math.nan, iterations, solve_time, f"Clarabel stopped with {name}"
        )
    lift = None
    if status in _SOLUTION_PRESENT:
        lift = np.array(solution.x, dtype=float)[program.layout.lift_index]
    z = solution.z
    dual = float(z[_LIFTED_ROW]) if len(z) == program.layout.n_rows else math.nan
    return SolveOutcome(status, lift, dual, iterations, solve_time)


# --------------------------------------------------------------------------------------------
# cvxpy: the parametrised problem (SCS, and the reference for the direct program)
# --------------------------------------------------------------------------------------------


@dataclass(eq=False)
class RelaxationProblem:
    """A parametrised (DPP) cvxpy problem for one relaxation, shared within a process."""

    relaxation: str
    problem: cp.Problem
    lift: cp.Variable
    objective: cp.Parameter
    constraint: cp.Parameter
    lifted_constraint: cp.Constraint
    lock: threading.Lock = field(default_factory=threading.Lock)

    def set_data(self, whitened: WhitenedRelaxation) -> None:
        """Fill the parameters (symmetrised) with the whitened data."""
        H, C = whitened.objective, whitened.constraint
        self.objective.value = 0.5 * (H + H.T)
        self.constraint.value = 0.5 * (C + C.T)


@functools.cache
def relaxation_problem(relaxation: Relaxation, size: int = 4) -> RelaxationProblem:
    """The lifted problem of MATH §11 over a lift of ``size`` as a cvxpy problem, built once
    per process and cached.

    ``min tr(H W)`` s.t. ``W ⪰ 0``, ``W_pp = 1`` and ``tr(C W) = 0`` (``≤ 0`` for the
    inequality relaxation), ``H`` and ``C`` being ``cp.Parameter``\\ s so re-solving only
    refills the canonical data (DPP).
    """
    _check_relaxation(relaxation)
    import cvxpy as cp

    lift = cp.Variable((size, size), symmetric=True, name="W")
    objective = cp.Parameter((size, size), symmetric=True, name="H")
    constraint = cp.Parameter((size, size), symmetric=True, name="C")
    lifted = cp.trace(constraint @ lift)
    lifted_constraint = lifted == 0 if relaxation == "equality" else lifted <= 0
    problem = cp.Problem(
        cp.Minimize(cp.trace(objective @ lift)),
        [lift >> 0, lift[size - 1, size - 1] == 1, lifted_constraint],
    )
    assert problem.is_dpp(), "the lifted CLS must be DPP to be re-solved cheaply"
    return RelaxationProblem(
        relaxation=relaxation,
        problem=problem,
        lift=lift,
        objective=objective,
        constraint=constraint,
        lifted_constraint=lifted_constraint,
    )


def solve_with_cvxpy(
    whitened: WhitenedRelaxation,
    relaxation: Relaxation,
    solver: Solver,
    settings: dict[str, Any],
) -> SolveOutcome:
    """One ``Problem.solve`` of the shared cvxpy problem; a ``SolverError`` is an outcome."""
    from cvxpy.error import SolverError

    built = relaxation_problem(relaxation, len(whitened.objective))
    with built.lock:
        built.set_data(whitened)
        try:
            with warnings.catch_warnings():
                # reported through the status, not as a warning
                warnings.filterwarnings("ignore", "Solution may be inaccurate", UserWarning)
                built.problem.solve(solver=solver, warm_start=False, **settings)
        except SolverError as error:
            return SolveOutcome(SOLVER_ERROR, None, math.nan, None, math.nan, str(error))
        stats = built.problem.solver_stats
        dual = built.lifted_constraint.dual_value
        return SolveOutcome(
            status=str(built.problem.status),
            lift=None if built.lift.value is None else np.array(built.lift.value, dtype=float),
            dual=math.nan if dual is None else float(np.asarray(dual).reshape(-1)[0]),
            iterations=None if stats.num_iters is None else int(stats.num_iters),
            solve_time_s=math.nan if stats.solve_time is None else float(stats.solve_time),
        )


# --------------------------------------------------------------------------------------------
# the solved relaxations (filled by the status discipline of estimators.sdp.sdp_cls)
# --------------------------------------------------------------------------------------------


NON_FINITE = "non_finite"
"""Status of a solve whose solver claimed success but whose lift, points or value are not
finite (NaN or infinity): a failure, never an estimate (:mod:`estimators.sdp.sdp_cls`)."""

_TINY = float(np.finfo(float).tiny)


@dataclass(frozen=True, slots=True, eq=False)
class SdpSolution:
    """The solved relaxation of MATH §11 for one stacked system ``A r = b`` (local frame).

    Attributes
    ----------
    status : str
        cvxpy's vocabulary whichever solver ran (``optimal``, ``optimal_inaccurate``,
        ``user_limit``, ...; :data:`CLARABEL_STATUSES`), ``solver_error`` or
        :data:`NON_FINITE`.
    message : str
        Empty on ``optimal``; otherwise what happened and what to try.
    value : float
        Optimal value of the relaxation in the units of ``‖A r − b‖²`` (NaN on failure): a
        lower bound on the CLS optimum, equal to it when the relaxation is tight.
    points : (n, d + 1)
        ``r`` of the recovered minimisers (two in the rank-two case); for a non-tight
        inequality relaxation, the relaxation's own argmin (off the paraboloid).
    costs : (n,)
        ``‖A (s, ‖s‖²) − b‖²`` at each point's ``s`` (as ``‖R r − c‖² + ρ²``).
    lift : (d + 2, d + 2)
        ``W`` in the local frame over ``(s, r_w, 1)``; the rows and columns of ``s`` and 1
        are ``Z`` (0, 1, 3 in 2-D).
    rank : int
        Numerical rank of the lift (1: tight and unique; 2: the hard case).
    multiplier : float
        λ from the dual of the lifted constraint, in the convention of MATH §5.
    iterations : int or None
    solve_time_s : float
        The solver's own time for the last rung (its solve information, no Python).
    wall_time_s : float
        Time of the whole call, compression to recovery.
    rung : int
        The tolerance rung that produced the status (1: the tightest).
    rungs_solve_time_s : float
        The solver's own time summed over every rung tried.
    """

    status: str
    message: str
    value: float
    points: FloatArray
    costs: FloatArray
    lift: FloatArray
    rank: int
    multiplier: float
    iterations: int | None
    solve_time_s: float
    wall_time_s: float
    rung: int = 1
    rungs_solve_time_s: float = math.nan

    @property
    def optimal(self) -> bool:
        return self.status == OPTIMAL

    @property
    def has_solution(self) -> bool:
        """A lift was returned with status ``optimal`` or ``optimal_inaccurate``."""
        return self.status in (OPTIMAL, OPTIMAL_INACCURATE) and len(self.points) > 0

    @property
    def z_matrix(self) -> FloatArray:
        """MATH §11's ``Z = [[Y, y], [yᵀ, 1]]`` (local frame)."""
        rows = z_rows(len(self.lift))
        return self.lift[np.ix_(rows, rows)]

    @property
    def lift_eigenvalues(self) -> FloatArray:
        """Eigenvalues of the lift, descending (NaN on failure)."""
        return lift_spectra(self.lift[None])[0][0]

    @property
    def z_eigenvalues(self) -> FloatArray:
        """Eigenvalues of ``Z``, descending: one nonzero when tight and unique."""
        return lift_spectra(self.lift[None])[1][0]

    @property
    def relaxed_point(self) -> FloatArray:
        """``r`` read from the lift's last column (local frame)."""
        return self.lift[:-1, -1]

    @property
    def tightness_gap(self) -> float:
        """``(min cost of the points − value) / max(|value|, tiny)``: 0 when tight."""
        if not self.has_solution:
            return math.nan
        best = float(np.min(self.costs))
        return (best - self.value) / max(abs(self.value), _TINY)


@dataclass(frozen=True, slots=True, eq=False)
class SdpColumns:
    """The solved relaxations of ``n`` systems, field by field as in :class:`SdpSolution`
    (``points`` (n, 2, d + 1) and ``costs`` (n, 2) NaN past ``count``; a failed system has count
    0, NaN value, lift and multiplier, rank 0)."""

    status: list[str]
    message: list[str]
    value: FloatArray
    points: FloatArray
    count: IntArray
    costs: FloatArray
    lift: FloatArray
    rank: IntArray
    multiplier: FloatArray
    iterations: list[int | None]
    solve_time: FloatArray
    rung: IntArray
    rungs_solve_time: FloatArray

    def solution(self, index: int, *, wall_time_s: float = math.nan) -> SdpSolution:
        """System ``index`` as an :class:`SdpSolution`."""
        k = int(self.count[index])
        return SdpSolution(
            status=self.status[index],
            message=self.message[index],
            value=float(self.value[index]),
            points=self.points[index, :k].copy(),
            costs=self.costs[index, :k].copy(),
            lift=self.lift[index].copy(),
            rank=int(self.rank[index]),
            multiplier=float(self.multiplier[index]),
            iterations=self.iterations[index],
            solve_time_s=float(self.solve_time[index]),
            wall_time_s=wall_time_s,
            rung=int(self.rung[index]),
            rungs_solve_time_s=float(self.rungs_solve_time[index]),
        )

    def accepted(self, accept_inaccurate: bool) -> NDArray[np.bool_]:
        """``optimal`` (or ``optimal_inaccurate`` when accepted) with recovered points."""
        status = object_column(self.status)
        ok = status == OPTIMAL
        if accept_inaccurate:
            ok |= status == OPTIMAL_INACCURATE
        return ok & (self.count > 0)

    def diagnostic_columns(self) -> dict[str, NDArray[Any]]:
        """The diagnostics of each system as (n,) columns: the solver status, the relaxation
        value, the CLS cost of the points, the tightness gap, rank, λ, the eigenvalues of
        ``Z`` and of the lift (descending), the constraint residual of the relaxed point, the
        iterations and solver times and the tolerance rung."""
        present = self.count > 0
        costs = np.where(np.arange(2) < self.count[:, None], self.costs, np.inf)
        best = np.minimum(costs[:, 0], costs[:, 1])
        status = object_column(self.status)
        solved = present & ((status == OPTIMAL) | (status == OPTIMAL_INACCURATE))
        with np.errstate(all="ignore"):
            gap = (best - self.value) / np.maximum(np.abs(self.value), _TINY)
        lift_eigenvalues, z_eigenvalues, residual = lift_spectra(self.lift)
        return {
            "status": status,
            "relaxation_value": self.value,
            "cost_at_points": np.where(present, best, np.nan),
            "tightness_gap": np.where(solved, gap, np.nan),
            "rank": self.rank,
            "hard_case": self.rank >= 2,
            "multiplier": self.multiplier,
            "z_eigenvalues": object_column(z_eigenvalues.tolist()),
            "lift_eigenvalues": object_column(lift_eigenvalues.tolist()),
            "constraint_residual": residual,
            "iterations": object_column(self.iterations),
            "solve_time_s": self.solve_time,
            "rungs_solve_time_s": self.rungs_solve_time,
            "tolerance_rung": self.rung,
        }
