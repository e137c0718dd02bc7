r"""The Shor SDP relaxation of the Doppler-ToA CLS (MATH §11), an independent witness for §5.

The CLS of MATH §5 (paper eq ``finalest``, corrected) is

.. math::

    f^\star = \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad r_x^2 + r_y^2 - r_z = 0,
    \qquad r = (x_s, y_s, x_s^2 + y_s^2).

Lifting ``(r, 1)`` to ``W = [[X, r], [rᵀ, 1]] ⪰ 0`` makes the objective and the constraint
linear in ``W``:

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

Numerics (MATH §11, DEPENDENCIES §3). The rows come in the :class:`~estimators.cls_rows.LocalFrame`
(order one). ``A = QR`` compresses the rows to the 3×3 triangle:
``‖A r − b‖² = ‖R r − Qᵀb‖² + ‖b − QQᵀb‖²``, so the solver's problem does not depend on the
number of samples. It is then written around the least-squares point ``r₀`` in whitened
coordinates ``r = r₀ + L w`` (``L = V diag(ℓ_i)`` from the SVD of ``R``), which makes the
objective ``O(1)`` in every direction; without it Clarabel stops with gaps near 1e−4 or with
``InsufficientProgress`` (seen on weighted two-heading rows). The problem is built once per
process per relaxation with ``cp.Parameter`` data (DPP) and re-solved; only status
``optimal`` is a success.

References
----------
Beck, Stoica & Li, "Exact and approximate solutions of source localization problems",
IEEE TSP 56(5), 2008. Moré, "Generalizations of the trust region problem", 1993.
"""

from __future__ import annotations

import functools
import math
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Capabilities, Estimate, finalize_estimate, require_modalities
from estimators.cls import cls_rows
from estimators.cls_rows import LocalFrame
from estimators.gtrs import constrained_cost
from scenarios.types import MeasurementSet

if TYPE_CHECKING:
    import cvxpy as cp

# cvxpy's status strings (cvxpy.OPTIMAL, ...), so that importing this module does not import
# cvxpy: the registry reads ``SdpCls.required_modules`` before anything is imported.
OPTIMAL, OPTIMAL_INACCURATE, USER_LIMIT = "optimal", "optimal_inaccurate", "user_limit"

FloatArray = NDArray[np.float64]
Relaxation = Literal["equality", "inequality"]
Solver = Literal["CLARABEL", "SCS"]

RELAXATIONS: tuple[str, ...] = ("equality", "inequality")
SOLVERS: tuple[str, ...] = ("CLARABEL", "SCS")

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

RANK_RTOL = 1e-6
"""An eigenvalue of the whitened lift below ``RANK_RTOL`` times the largest counts as zero."""

NON_FINITE = "non_finite"
"""Status of a solve whose solver claimed success but whose lift, points or value are not
finite (NaN or infinity): a failure, never an estimate."""

_SINGULAR_RTOL = 1e-12


# --------------------------------------------------------------------------------------------
# pure numpy: compression, whitening, recovery
# --------------------------------------------------------------------------------------------


def compress_rows(A: ArrayLike, b: ArrayLike) -> tuple[FloatArray, FloatArray, float]:
    """QR compression ``‖A r − b‖² = ‖R r − c‖² + ρ²`` (MATH §11).

    Parameters
    ----------
    A : (m, 3)
    b : (m,)

    Returns
    -------
    R : (3, 3)
        Upper triangle of ``A = QR`` (zero rows appended when ``m < 3``).
    c : (3,)
        ``Qᵀ b`` (zeros appended likewise).
    residual_sq : float
        ``ρ² = ‖b − Q Qᵀ b‖²``, the part of the cost no ``r`` can change.

    Raises
    ------
    ValueError
        If ``A`` is not (m, 3) with m >= 1, ``b`` not (m,), or an entry is not finite.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    if A.ndim != 2 or A.shape[1] != 3 or A.shape[0] < 1:
        raise ValueError(f"A: expected the stacked rows with shape (m, 3), m >= 1; got {A.shape}")
    if b.shape != (A.shape[0],):
        raise ValueError(f"b: expected shape ({A.shape[0]},) to match A, got {b.shape}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        raise ValueError("A/b: the stacked rows contain NaN or infinity; check the measurements")
    Q, R_top = np.linalg.qr(A, mode="reduced")
    c_top = Q.T @ b
    residual = b - Q @ c_top
    R = np.zeros((3, 3))
    c = np.zeros(3)
    R[: len(R_top)] = R_top
    c[: len(c_top)] = c_top
    return R, c, float(residual @ residual)


@dataclass(frozen=True, slots=True, eq=False)
class WhitenedRelaxation:
    """The relaxation's data in the solver's coordinates ``r = r₀ + L w`` (MATH §11).

    Attributes
    ----------
    objective : (4, 4)
        ``H_w / s``: ``tr(H_w W_w) = ‖A r − b‖²`` on rank-one lifts of ``(w, 1)``.
    constraint : (4, 4)
        ``C_w / κ``: ``tr(C_w W_w) = ‖y‖² − r_z`` on rank-one lifts.
    origin : (3,)
        ``r₀``, the minimum-norm least-squares point of ``R r = c``.
    basis : (3, 3)
        ``L``.
    objective_scale : float
        ``s``; the relaxation value is ``s · tr(objective · W_w)``.
    constraint_scale : float
        ``κ``.
    """

    objective: FloatArray
    constraint: FloatArray
    origin: FloatArray
    basis: FloatArray
    objective_scale: float
    constraint_scale: float

    def to_local(self, lift_w: ArrayLike) -> FloatArray:
        """The lift of ``(r, 1)`` from that of ``(w, 1)``: ``T W_w Tᵀ``, ``T = [[L, r₀], [0, 1]]``."""
        T = np.zeros((4, 4))
        T[:3, :3] = self.basis
        T[:3, 3] = self.origin
        T[3, 3] = 1.0
        return T @ np.asarray(lift_w, dtype=float) @ T.T

    def points(self, w: ArrayLike) -> FloatArray:
        """``r = r₀ + L w`` for rows ``w`` of shape (..., 3)."""
        return self.origin + np.asarray(w, dtype=float) @ self.basis.T


def paraboloid_residual(r: ArrayLike) -> FloatArray:
    """``‖y‖² − r_z`` for points ``r`` (..., 3): zero on the constraint of MATH §5."""
    r = np.asarray(r, dtype=float)
    return np.sum(r[..., :2] ** 2, axis=-1) - r[..., 2]


def whiten_relaxation(R: FloatArray, c: FloatArray, residual_sq: float) -> WhitenedRelaxation:
    """Write the lifted problem of MATH §11 around ``r₀`` in whitened coordinates.

    With ``R = U Σ Vᵀ``, ``r₀ = V Σ⁺ Uᵀ c`` and ``e = c − R r₀``, the cost is
    ``‖R L w − e‖² + ρ²``. Choosing ``L = V diag(ℓ_i)``, ``ℓ_i = min(√s / σ_i, ℓ_max)``, makes
    its quadratic part ``diag(min(1, σ_i² ℓ_max² / s))·s``: order one in every direction once
    divided by ``s``. The scale is the least-squares residual ``s = ρ² + ‖e‖²``, a lower bound
    on the optimum, so the solver sees ``f*/s ≥ 1`` and its relative gap criterion holds the
    value to a relative accuracy; when that residual vanishes (three rows, noise-free data) it
    is floored at 1e−9 times the excess cost of a cheap feasible point (the vertical projection
    of ``r₀`` or a crossing of the weakest direction ``v₃`` with the paraboloid).
    ``ℓ_max = 1 + ‖r₀‖`` bounds the weak directions by the frame's length scale.
    """
    U, sigma, Vt = np.linalg.svd(R)
    V = Vt.T
    keep = sigma > _SINGULAR_RTOL * max(sigma[0], np.finfo(float).tiny)
    inverse = np.where(keep, 1.0 / np.where(keep, sigma, 1.0), 0.0)
    origin = V @ (inverse * (U.T @ c))
    misfit = c - R @ origin

    def excess(r: FloatArray) -> float:
        residual = R @ r - c
        return float(residual @ residual - misfit @ misfit)

    feasible = [np.array([origin[0], origin[1], origin[0] ** 2 + origin[1] ** 2])]
    feasible += list(_line_paraboloid_points(origin, V[:, 2]))
    upper = min(excess(point) for point in feasible)
    floor = residual_sq + float(misfit @ misfit)
    scale = max(floor, 1e-9 * max(upper, 0.0), 1e-300)

    length_max = 1.0 + float(np.linalg.norm(origin))
    with np.errstate(divide="ignore"):
        ideal = np.sqrt(scale) / sigma
    lengths = np.minimum(np.where(sigma > 0.0, ideal, np.inf), length_max)
    basis = V * lengths

    RL = R @ basis
    H = np.zeros((4, 4))
    H[:3, :3] = RL.T @ RL
    H[:3, 3] = H[3, :3] = -(RL.T @ misfit)
    H[3, 3] = residual_sq + float(misfit @ misfit)

    L_y, L_z = basis[:2], basis[2]
    y0 = origin[:2]
    C = np.zeros((4, 4))
    C[:3, :3] = L_y.T @ L_y
    C[:3, 3] = C[3, :3] = L_y.T @ y0 - 0.5 * L_z
    C[3, 3] = float(paraboloid_residual(origin))
    constraint_scale = float(np.max(np.abs(C)))
    return WhitenedRelaxation(
        objective=H / scale,
        constraint=C / constraint_scale,
        origin=origin,
        basis=basis,
        objective_scale=scale,
        constraint_scale=constraint_scale,
    )


def _line_paraboloid_points(point: FloatArray, direction: FloatArray) -> FloatArray:
    """The (0 to 2) points ``point + t·direction`` with ``‖y‖² = r_z``, shape (n, 3)."""
    a = float(direction[:2] @ direction[:2])
    half_b = float(point[:2] @ direction[:2]) - 0.5 * float(direction[2])
    c = float(paraboloid_residual(point))
    roots = _quadratic_roots(a, half_b, c)
    return point + np.outer(roots, direction)


def _quadratic_roots(a: float, half_b: float, c: float) -> FloatArray:
    """Real roots of ``a t² + 2 half_b t + c = 0`` (cancellation-free), ascending."""
    if a <= 0.0:
        return np.array([-c / (2.0 * half_b)]) if half_b != 0.0 else np.empty(0)
    discriminant = half_b * half_b - a * c
    if discriminant < 0.0:
        return np.empty(0)
    q = -(half_b + math.copysign(math.sqrt(discriminant), half_b))
    if q == 0.0:
        return np.array([0.0])
    return np.sort(np.array([q / a, c / q]))


def recover_minimisers(
    lift_w: ArrayLike, whitened: WhitenedRelaxation, *, rank_rtol: float = RANK_RTOL
) -> tuple[FloatArray, int]:
    """The points of MATH §5 encoded in an optimal lift (MATH §11), and the lift's rank.

    Rank one: the single point ``r = r₀ + L w`` read from the last column. Rank two (the hard
    case): ``W_w = α ŵ₁ŵ₁ᵀ + (1 − α) ŵ₂ŵ₂ᵀ``, so the Schur complement ``W_ww − w wᵀ`` is
    ``α(1−α) (w₁ − w₂)(w₁ − w₂)ᵀ``; both minimisers are the points of the line through ``w``
    along its principal eigenvector that satisfy ``‖y‖² = r_z``. Since
    ``tr(C W) = ‖y‖² − r_z + tr(Schur_yy) ≤ 0`` holds for both relaxations, that line always
    crosses the paraboloid.

    Returns ``(points (n, 3) in the local frame, rank)``.
    """
    W = np.asarray(lift_w, dtype=float)
    W = 0.5 * (W + W.T)
    eigenvalues = np.linalg.eigvalsh(W)
    rank = int(np.sum(eigenvalues > rank_rtol * max(eigenvalues[-1], np.finfo(float).tiny)))
    w = W[:3, 3] / W[3, 3]
    centre = whitened.points(w)
    if rank < 2:
        return centre[None, :], max(rank, 1)
    schur = W[:3, :3] / W[3, 3] - np.outer(w, w)
    _, vectors = np.linalg.eigh(0.5 * (schur + schur.T))
    direction = whitened.basis @ vectors[:, -1]
    points = _line_paraboloid_points(centre, direction)
    if len(points) == 0:
        return centre[None, :], rank
    return points, rank


# --------------------------------------------------------------------------------------------
# the convex problem: built once per process per relaxation, re-solved with new parameters
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


@functools.cache
def relaxation_problem(relaxation: Relaxation) -> RelaxationProblem:
    """The lifted problem of MATH §11, built once per process and cached.

    ``min tr(H W)`` s.t. ``W ⪰ 0``, ``W₄₄ = 1`` and ``tr(C W) = 0`` (``≤ 0`` for the
    inequality relaxation), ``H`` and ``C`` being ``cp.Parameter``\\ s so re-solving only
    refills the canonical data (DPP).
    """
    if relaxation not in RELAXATIONS:
        raise ValueError(f"relaxation: expected one of {RELAXATIONS}, got {relaxation!r}")
    import cvxpy as cp

    lift = cp.Variable((4, 4), symmetric=True, name="W")
    objective = cp.Parameter((4, 4), symmetric=True, name="H")
    constraint = cp.Parameter((4, 4), symmetric=True, name="C")
    lifted = cp.trace(constraint @ lift)
    lifted_constraint = lifted == 0 if relaxation == "equality" else lifted <= 0
    problem = cp.Problem(
        cp.Minimize(cp.trace(objective @ lift)),
        [lift >> 0, lift[3, 3] == 1, lifted_constraint],
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


def solver_attempts(solver: Solver, max_iter: int | None) -> list[dict[str, Any]]:
    """Keyword arguments for ``Problem.solve``, one dict per tolerance rung, tightest first.

    Every setting is passed on every call: cvxpy keeps the solver object of the previous
    solve and only overrides the settings it is given, so an omitted ``max_iter`` would
    inherit the last call's. ``warm_start=False`` makes a result independent of the solves
    before it (SCS would otherwise start from the previous solution).
    """
    if solver == "CLARABEL":
        limit = CLARABEL_MAX_ITER if max_iter is None else int(max_iter)
        return [
            {
                "warm_start": False,
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
            {"warm_start": False, "eps_abs": eps_abs, "eps_rel": eps_rel, "max_iters": limit}
            for eps_abs, eps_rel in SCS_TOLERANCES
        ]
    raise ValueError(f"solver: expected one of {SOLVERS}, got {solver!r}")


@dataclass(frozen=True, slots=True, eq=False)
class SdpSolution:
    """The solved relaxation of MATH §11 for one stacked system ``A r = b`` (local frame).

    Attributes
    ----------
    status : str
        The cvxpy status (``optimal``, ``optimal_inaccurate``, ``user_limit``, ...),
        ``solver_error``, or ``non_finite`` (:data:`NON_FINITE`).
    message : str
        Empty on ``optimal``; otherwise what happened and what to try.
    value : float
        Optimal value of the relaxation in the units of ``‖A r − b‖²`` (NaN on failure): a
        lower bound on the CLS optimum, equal to it when the relaxation is tight.
    points : (n, 3)
        ``r`` of the recovered minimisers (two in the rank-two case); for a non-tight
        inequality relaxation, the relaxation's own argmin (off the paraboloid).
    costs : (n,)
        ``‖A (x, y, x² + y²) − b‖²`` at each point's ``(x, y)``: the CLS objective of §5.
    lift : (4, 4)
        ``W`` in the local frame, over ``(x, y, r_z, 1)``; ``lift[[0,1,3]][:, [0,1,3]]`` is
        MATH §11's ``Z``.
    rank : int
        Numerical rank of the lift (1: tight and unique; 2: the hard case).
    multiplier : float
        λ from the dual of the lifted constraint, in the convention of MATH §5.
    iterations : int or None
    solve_time_s : float
        Solver time as reported by cvxpy (excludes the Python wrapper).
    wall_time_s : float
        Time of the whole call, compression to recovery.
    rung : int
        The tolerance rung that produced the status (1: the tightest; see
        :data:`CLARABEL_TOLERANCES`).
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
        return self.lift[np.ix_([0, 1, 3], [0, 1, 3])]

    @property
    def lift_eigenvalues(self) -> FloatArray:
        """Eigenvalues of the lift, descending (NaN on failure)."""
        if not np.all(np.isfinite(self.lift)):
            return np.full(4, np.nan)
        return np.linalg.eigvalsh(self.lift)[::-1]

    @property
    def z_eigenvalues(self) -> FloatArray:
        """Eigenvalues of ``Z``, descending: one nonzero when tight and unique."""
        if not np.all(np.isfinite(self.lift)):
            return np.full(3, np.nan)
        return np.linalg.eigvalsh(self.z_matrix)[::-1]

    @property
    def relaxed_point(self) -> FloatArray:
        """``r`` read from the lift's last column (local frame)."""
        return self.lift[:3, 3]

    @property
    def tightness_gap(self) -> float:
        """``(min cost of the points − value) / max(|value|, tiny)``: 0 when tight."""
        if not self.has_solution:
            return float("nan")
        best = float(np.min(self.costs))
        return (best - self.value) / max(abs(self.value), np.finfo(float).tiny)

    def diagnostics(self) -> dict[str, Any]:
        """JSON-ready scalars and short lists for an :class:`~estimators.base.Estimate`."""
        return {
            "status": self.status,
            "relaxation_value": self.value,
            "cost_at_points": float(np.min(self.costs)) if len(self.costs) else float("nan"),
            "tightness_gap": self.tightness_gap,
            "rank": self.rank,
            "hard_case": self.rank >= 2,
            "multiplier": self.multiplier,
            "z_eigenvalues": [float(v) for v in self.z_eigenvalues],
            "lift_eigenvalues": [float(v) for v in self.lift_eigenvalues],
            "constraint_residual": float(paraboloid_residual(self.relaxed_point))
            if np.all(np.isfinite(self.lift))
            else float("nan"),
            "iterations": self.iterations,
            "solve_time_s": self.solve_time_s,
            "tolerance_rung": self.rung,
        }


@dataclass(frozen=True, slots=True, eq=False)
class _SolveOutcome:
    status: str
    lift: FloatArray | None
    dual: Any
    iterations: int | None
    solve_time_s: float
    error: str = ""


def _solve_built(
    built: RelaxationProblem,
    whitened: WhitenedRelaxation,
    solver: Solver,
    options: dict[str, Any],
) -> _SolveOutcome:
    """One solve of the shared problem with the whitened data; a solver error is an outcome."""
    from cvxpy.error import SolverError

    with built.lock:
        built.objective.value = 0.5 * (whitened.objective + whitened.objective.T)
        built.constraint.value = 0.5 * (whitened.constraint + whitened.constraint.T)
        try:
            with warnings.catch_warnings():
                # reported through the status, not as a warning
                warnings.filterwarnings("ignore", "Solution may be inaccurate", UserWarning)
                built.problem.solve(solver=solver, verbose=False, **options)
        except SolverError as error:
            return _SolveOutcome("solver_error", None, None, None, float("nan"), str(error))
        stats = built.problem.solver_stats
        return _SolveOutcome(
            status=str(built.problem.status),
            lift=None if built.lift.value is None else np.array(built.lift.value, dtype=float),
            dual=built.lifted_constraint.dual_value,
            iterations=None if stats.num_iters is None else int(stats.num_iters),
            solve_time_s=float("nan") if stats.solve_time is None else float(stats.solve_time),
        )


def _failed_solution(
    status: str,
    message: str,
    started: float,
    *,
    iterations: int | None = None,
    rung: int = 1,
) -> SdpSolution:
    return SdpSolution(
        status=status,
        message=message,
        value=float("nan"),
        points=np.empty((0, 3)),
        costs=np.empty(0),
        lift=np.full((4, 4), np.nan),
        rank=0,
        multiplier=float("nan"),
        iterations=iterations,
        solve_time_s=float("nan"),
        wall_time_s=time.perf_counter() - started,
        rung=rung,
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

    Parameters
    ----------
    A : (m, 3)
        Rows in a frame scaled to order one (:class:`~estimators.cls_rows.LocalFrame`).
    b : (m,)
    relaxation : {"equality", "inequality"}
        ``r_z = trace Y`` (the Shor relaxation, tight) or ``r_z ≥ trace Y`` (tight only when
        λ* ≥ 0).
    solver : {"CLARABEL", "SCS"}
    max_iter : int or None
        The solver's iteration limit (None: its default).
    rank_rtol : float
        Relative eigenvalue threshold for the rank of the whitened lift.

    Returns
    -------
    SdpSolution
        Never raises for a solver failure: the status and message say what happened.

    Raises
    ------
    ValueError
        Malformed ``A``/``b`` (shape, NaN) or an unknown ``relaxation``/``solver``.
    """
    started = time.perf_counter()
    R, c, residual_sq = compress_rows(A, b)
    attempts = solver_attempts(solver, max_iter)
    built = relaxation_problem(relaxation)
    whitened = whiten_relaxation(R, c, residual_sq)
    rung = 0
    for options in attempts:
        rung += 1
        outcome = _solve_built(built, whitened, solver, options)
        if outcome.status not in (OPTIMAL_INACCURATE, "solver_error"):
            break
    status, iterations, solve_time = outcome.status, outcome.iterations, outcome.solve_time_s
    if status == "solver_error":
        return _failed_solution(
            status,
            f"solver {solver} failed ({outcome.error}); try solver='SCS' or check the rows",
            started,
            rung=rung,
        )
    lift_w = outcome.lift
    if status not in (OPTIMAL, OPTIMAL_INACCURATE) or lift_w is None:
        hint = " (raise max_iter)" if status == USER_LIMIT else ""
        return _failed_solution(
            status,
            f"solver {solver} stopped with status {status}{hint}",
            started,
            iterations=iterations,
            rung=rung,
        )
    if not np.all(np.isfinite(lift_w)):
        return _failed_solution(
            NON_FINITE,
            f"solver {solver} reported {status} but its lift is not finite",
            started,
            iterations=iterations,
            rung=rung,
        )
    dual = outcome.dual
    points, rank = recover_minimisers(lift_w, whitened, rank_rtol=rank_rtol)
    costs = constrained_cost(A, b, points[:, :2])
    value = whitened.objective_scale * float(np.sum(whitened.objective * lift_w))
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(costs)) and np.isfinite(value)):
        return _failed_solution(
            NON_FINITE,
            f"solver {solver} reported {status} but the recovered points or the value are "
            "not finite",
            started,
            iterations=iterations,
            rung=rung,
        )
    # Lagrangian of the solver: tr(H W)/s + ν tr(C W)/κ  ⇔  ‖Ar − b‖² + ν (s/κ)(‖y‖² − r_z);
    # MATH §5 writes λ (‖y‖² − r_z) with the same sign.
    multiplier = (
        float(np.asarray(dual).reshape(-1)[0])
        * whitened.objective_scale
        / whitened.constraint_scale
        if dual is not None
        else float("nan")
    )
    message = ""
    if status == OPTIMAL_INACCURATE:
        message = f"solver {solver} returned optimal_inaccurate: the witness is not certified"
    return SdpSolution(
        status=status,
        message=message,
        value=value,
        points=points,
        costs=costs,
        lift=whitened.to_local(lift_w),
        rank=rank,
        multiplier=multiplier,
        iterations=iterations,
        solve_time_s=solve_time,
        wall_time_s=time.perf_counter() - started,
        rung=rung,
    )


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SdpCls:
    """The CLS of MATH §3-§6 solved through its SDP relaxation (MATH §11).

    Same rows and two-stage weighting as ``cls`` (:func:`estimators.cls.cls_rows`): stage 1
    weights from the data, stage 2 from the stage-1 SDP estimate. The returned
    ``diagnostics`` carry the solver status, the relaxation value, the CLS cost of the
    returned points (their difference is the tightness gap), the eigenvalues of ``Z`` and of
    the full lift, the rank and λ from the dual, and ``stage_statuses`` (one solver status per
    stage). Only status ``optimal`` is a success (``optimal_inaccurate`` too with
    ``accept_inaccurate``, flagged in ``message``), after the tolerance rungs of
    :func:`solver_attempts` (the documented retry); a solve that reports success with a
    non-finite lift, point or value is a failure with status ``non_finite``. The built problem
    is cached per process, so the estimator itself only stores options (and pickles).

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

    def capabilities(self) -> Capabilities:
        """Like ``cls`` (unit-invariant when weighted), to the interior-point solver's accuracy."""
        return Capabilities(
            modalities=self.requires,
            frames=self.frames,
            modules=self.required_modules,
            unit_invariant=self.weighting == "optimal",
            noise_free_tolerance_m=1e-5,
            tolerance_reason="the interior-point solver stops at a relative gap of about 1e-8",
        )

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        require_modalities(self, data)
        used = data.select_frames(self.frames)
        frame = LocalFrame.fit(used.position_m, used.range_m)
        rows = "weighted" if self.weighting == "optimal" else "per-sample"
        stages = 2 if rows == "weighted" else 1
        solution: SdpSolution | None = None
        statuses: list[str] = []
        for stage in range(stages):
            weights_at = None if solution is None else solution.points[0, :2]
            A, b = cls_rows(used, frame, rows, weights_at_local_xy=weights_at)
            if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
                return Estimate.failed(
                    self.name,
                    f"rows: the stage-{stage + 1} CLS system has NaN or infinite entries "
                    "(degenerate geometry or weights); check speeds, ranges and noise levels",
                    stage=stage + 1,
                )
            solution = solve_sdp_relaxation(
                A, b, relaxation=self.relaxation, solver=self.solver, max_iter=self.max_iter
            )
            statuses.append(solution.status)
            accepted = solution.optimal or (
                self.accept_inaccurate and solution.status == OPTIMAL_INACCURATE
            )
            if not (accepted and solution.has_solution):
                message = solution.message or (
                    f"solver {self.solver} returned status {solution.status}, not accepted"
                )
                return Estimate.failed(
                    self.name,
                    f"stage {stage + 1}: {message}",
                    **solution.diagnostics(),
                    stage=stage + 1,
                    stage_statuses=statuses,
                )
        assert solution is not None
        notes = [solution.message] if solution.message else []
        if solution.rank >= 2:
            notes.append("rank-two lift: mirror pair recovered (MATH §5, §11)")
        if self.relaxation == "inequality" and solution.tightness_gap > 1e-6:
            notes.append("inequality relaxation not tight (λ* < 0, MATH §11)")
        diagnostics = dict(
            solution.diagnostics(),
            relaxation=self.relaxation,
            solver=self.solver,
            stages=stages,
            stage_statuses=statuses,
            n_samples=used.n_samples,
        )
        points = frame.to_world(solution.points[:, :2])
        if not np.all(np.isfinite(points)):
            return Estimate.failed(
                self.name, "the recovered minimisers are not finite", **diagnostics
            )
        return finalize_estimate(
            self.name,
            points,
            solution.costs,
            used,
            rng=rng,
            side_prior_m=self.side_prior_m,
            message="; ".join(notes),
            diagnostics=diagnostics,
        )
