r"""The maximum-likelihood reference estimator (MATH §10).

With independent Gaussian noise (MATH §1) the negative log-likelihood of the raw measurements
is, up to a constant, half the squared norm of the whitened residuals

.. math::

    e(s) = \Big[\frac{f_k - f_k(s)}{\sigma_f},\ \frac{\tau_k - \tau_k(s)}{\sigma_\tau},\
    \Big(\frac{P_k - P_k(s)}{\sigma_P}\Big)\Big]_k,\qquad
    \hat s = \arg\min_{(x_s, y_s)} \lVert e(s)\rVert^2

(Doppler with the physical sign, the RSS block optional). It is minimised by
``scipy.optimize.least_squares`` (Levenberg-Marquardt, analytic Jacobian from
:mod:`scenarios.measurement_model`) in the centred, scaled local frame of the CLS, started from
every candidate of the corrected CLS (:mod:`estimators.closed_form.cls`, MATH §5-§6). Every local
minimum within a relative cost gap ``cost_rtol`` of the best is reported as a candidate: on one
straight frame the mirror pair has exactly equal cost (MATH §7).

Starts. On a straight track the likelihood is mirror-symmetric, so starts are folded to one side
(the mirror minima are added by :func:`~estimators.base.finalize_estimate`); a start on the
track's vertical plane, where the cross-track gradient vanishes, gets a second start off it, so
that both the off-track mirror pair and the on-track minimum of MATH §5 are reachable. When the
CLS cannot start (e.g. a hovering sample) the search starts from LLS-ToA (MATH §9); optionally
also from a Doppler-only fit of the last frame, useful when the ranges are useless.

The covariance is the inverse Fisher information at the estimate,
``(JᵀJ)⁻¹`` with ``J`` the whitened Jacobian (MATH §8): the CRLB evaluated at ``ŝ``.

Convergence. How each start's Levenberg-Marquardt run ended is recorded per start in
``diagnostics["lm_status"]``: ``converged`` (a tolerance met, ``gtol``/``ftol``/``xtol``, *and*
the point stationary: its decrement, the smaller of the Gauss-Newton ``‖P_J e‖²`` and the
Newton ``gᵀH⁻¹g`` with the exact Hessian ``H`` where it is positive definite, at most
``DECREMENT_TOL``, i.e. within 0.01 σ of a minimum, :mod:`estimators.convergence`),
``iteration cap`` (all ``max_nfev`` evaluations used), ``stalled`` (a tolerance met away from
a stationary point: the trust region collapsed) or ``error``. Only converged starts give minima.
The estimate fails when no start converged, or when a start that did not converge ended below
every converged minimum (the optimum found is then not the best the data allow); starts that
did not converge but ended higher are counted in ``diagnostics`` and noted in ``message``.
The exact Hessian is the central difference of the analytic gradient ``Jᵀe`` (step
``HESSIAN_STEP_RTOL`` of the length scale: truncation and rounding both ~1e−11 relative).

Reproducibility. Each start is rounded to a grid of ``START_GRID`` local units (~1e−6 of the
length scale, far below any start's own error) and every cost is a left-to-right sum of
squares (:func:`~estimators.ml.minpack_batch.ordered_sum`): the search's path is then a function
of the data alone, not of the last bits of the CLS solve, and :mod:`estimators.ml.ml_batch`
performs ``estimate``'s operations in its order on a whole batch (``estimate_batch``),
equal to rounding (bit for bit where the linear-algebra kernels round alike). Two starts that
end at one minimum (closer than ``MERGE_RTOL`` of the scale) at costs equal within ``xtol``
keep the earlier start's point, not whichever rounding put lower: an on-plane start stays on
a straight track's plane, its off-plane copy stops a fraction of a micrometre off it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from estimators.base import (
    Capabilities,
    Estimate,
    check_side_prior,
    finalize_estimate,
    require_modalities,
)
from estimators.baselines.lls import solve_lls_toa
from estimators.batch import BatchEstimates
from estimators.closed_form.cls import solve_doppler_toa_cls
from estimators.closed_form.cls_rows import LocalFrame
from estimators.closed_form.pseudorange_cls import solve_pseudorange_cls
from estimators.convergence import DECREMENT_TOL, stationarity_decrement
from estimators.goodness_of_fit import with_fit, with_fit_columns
from estimators.ml.minpack_batch import ordered_sum
from estimators.ml.ml_batch import estimate_columns
from estimators.ml.ml_batch_audit import HESSIAN_STEP_RTOL
from estimators.ml.ml_batch_starts import MERGE_RTOL, ON_TRACK_RTOL, on_start_grid
from estimators.ml.ml_residuals import ResidualModel, profiled_offsets
from estimators.ml.ml_starts import doppler_frame_starts, doppler_grid_starts, ranges_uninformative
from scenarios.fisher import gram_information, inverse_2x2, regular_2x2
from scenarios.geometry import cross_track_m, mirror_across_line, straight_track_line
from scenarios.nuisance import NUISANCE_PARAMETERS
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
Frames = Literal["all", "last"]
Method = Literal["lm", "trf"]
Rngs = Sequence[np.random.Generator | None] | None

MINPACK_STATUS = {
    -1: "improper input",
    0: "max_nfev",
    1: "gtol",
    2: "ftol",
    3: "xtol",
    4: "ftol+xtol",
}
"""``scipy.optimize.least_squares`` status codes (1-4: a tolerance met; 0: the evaluation cap)."""


# --------------------------------------------------------------------------------------------
# the whitened residuals and their Jacobian
# --------------------------------------------------------------------------------------------


def whitened_residuals(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False
) -> FloatArray:
    """``e(s)``: Doppler, ToA (and RSS) residuals divided by their σ (MATH §10).

    Rows are ordered Doppler block, ToA block, then the RSS block when ``use_rss``; each block
    has one row per sample. Measured minus predicted, Doppler with the physical sign (MATH §1).
    Vectorised: ``emitter_m`` of shape ``(..., 2)`` gives residuals of shape ``(..., n_rows)``.
    """
    emitter = np.asarray(emitter_m, dtype=float)
    rss = data.rss_dbm if use_rss else None
    blocks = ResidualModel.of(data).residuals(
        emitter[..., 0, None], emitter[..., 1, None], data.doppler_hz, data.toa_s, rss
    )
    return np.concatenate(blocks, axis=-1)


def whitened_residual_jacobian(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False
) -> FloatArray:
    """``∂e/∂(x_s, y_s) = −[∇f_k/σ_f; ∇τ_k/σ_τ; ∇P_k/σ_P]`` (MATH §8, §10).

    Shape ``(..., n_rows, 2)`` for ``emitter_m`` of shape ``(..., 2)``: minus the rows of
    :func:`scenarios.fisher.whitened_jacobian`, so its Gram matrix ``JᵀJ`` is the Fisher
    information of MATH §8 at ``emitter_m``.
    """
    emitter = np.asarray(emitter_m, dtype=float)
    columns = ResidualModel.of(data).jacobian(emitter[..., 0, None], emitter[..., 1, None], use_rss)
    return np.stack([np.concatenate(c, axis=-1) for c in columns], axis=-1)


# --------------------------------------------------------------------------------------------
# the solver
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class MlSolution:
    """Distinct local minima of ``‖e(s)‖²`` found from the starts, best first.

    Attributes
    ----------
    minima_m : (n, 2)
        Converged points in world coordinates (empty when no start converged).
    costs : (n,)
        ``‖e‖²`` at each (−2 log-likelihood up to a constant; χ² with n_rows − 2 degrees of
        freedom at the true minimum).
    n_starts : int
        Starts tried.
    n_evaluations : int
        Residual evaluations over all starts (``nfev`` summed).
    messages : tuple of str
        The solver's message for every start that did not converge.
    statuses : tuple of str
        One per start: ``"converged (xtol)"``, ``"iteration cap (max_nfev=200)"``,
        ``"stalled (ftol, decrement 0.03)"``, ``"error"`` or ``"non-finite start"``.
    unconverged_best_cost : float
        The lowest ``‖e‖²`` at which a start that did not converge ended (inf if none).
    """

    minima_m: FloatArray
    costs: FloatArray
    n_starts: int
    n_evaluations: int
    messages: tuple[str, ...]
    statuses: tuple[str, ...] = ()
    unconverged_best_cost: float = float("inf")

    @property
    def n_converged(self) -> int:
        return sum(status.startswith("converged") for status in self.statuses)


def solve_maximum_likelihood(
    data: MeasurementSet,
    starts_m: ArrayLike,
    *,
    use_rss: bool = False,
    method: Method = "lm",
    frame: LocalFrame | None = None,
    cost_rtol: float = 1e-6,
    xtol: float = 1e-10,
    max_nfev: int = 200,
) -> MlSolution:
    """Minimise ``‖e(s)‖²`` (MATH §10) from each start; return the distinct local minima.

    The problem is solved in ``frame`` (default: centred on the track and scaled by the
    ranges, :meth:`LocalFrame.fit`), so that the unknowns are of order one.

    Parameters
    ----------
    data : MeasurementSet
        Needs Doppler and ToA (and RSS with ``use_rss``).
    starts_m : (n_starts, 2)
        Initial positions in world coordinates (rounded to ``START_GRID`` in ``frame``).
    use_rss : bool
        Include the RSS residuals.
    method : {"lm", "trf"}
        ``scipy.optimize.least_squares`` method.
    frame : LocalFrame or None
    cost_rtol : float
        Two minima whose costs tie within ``cost_rtol`` (relative) and with no cost barrier
        between them (the midpoint no higher than the tie level) are one flat minimum and are
        merged; so are minima closer than ``MERGE_RTOL`` times the length scale (the lower
        cost kept, or the earlier start's at a tie within ``xtol``: module text).
    xtol : float
        Relative step tolerance (``ftol`` and ``gtol`` use it too).
    max_nfev : int
        Evaluation budget per start; a start that exhausts it has not converged.

    A start gives a minimum only if it converged (module text, "Convergence"): a tolerance
    met and the point stationary (:func:`ml_decrement` at most ``DECREMENT_TOL``).
    """
    starts = np.asarray(starts_m, dtype=float).reshape(-1, 2)
    if frame is None:
        frame = LocalFrame.fit(data.position_m, data.range_m)
    scale = frame.scale_m

    def residual(u: FloatArray) -> FloatArray:
        return whitened_residuals(data, frame.to_world(u), use_rss=use_rss)

    def jacobian(u: FloatArray) -> FloatArray:
        return whitened_residual_jacobian(data, frame.to_world(u), use_rss=use_rss) * scale

    minima: list[FloatArray] = []
    costs: list[float] = []
    messages: list[str] = []
    statuses: list[str] = []
    unconverged_best = float("inf")
    n_evaluations = 0
    for start in on_start_grid(frame.to_local(starts)):
        if not np.all(np.isfinite(start)):
            messages.append("non-finite start")
            statuses.append("non-finite start")
            continue
        try:
            result = least_squares(
                residual,
                start,
                jac=jacobian,
                method=method,
                xtol=xtol,
                ftol=xtol,
                gtol=xtol,
                max_nfev=max_nfev,
            )
        except (ValueError, np.linalg.LinAlgError) as error:
            messages.append(str(error))
            statuses.append("error")
            continue
        n_evaluations += int(result.nfev)
        cost = 2.0 * float(result.cost)  # scipy's cost is ½‖e‖²
        code = MINPACK_STATUS.get(int(result.status), f"status {result.status}")
        if not (np.all(np.isfinite(result.x)) and np.isfinite(cost)):
            messages.append(f"{result.message} (non-finite result)")
            statuses.append(f"error ({code}, non-finite result)")
            continue
        point = frame.to_world(result.x)
        if result.status <= 0:
            status = (
                f"iteration cap (max_nfev={max_nfev})" if result.status == 0 else f"error ({code})"
            )
            messages.append(f"{result.message} ({status})")
        else:
            decrement = ml_decrement(data, point, use_rss=use_rss, scale_m=scale)
            if decrement <= DECREMENT_TOL:
                status = f"converged ({code})"
            else:
                status = f"stalled ({code}, decrement {decrement:.3g} > {DECREMENT_TOL:g})"
                messages.append(f"{result.message} but not at a minimum: {status}")
        statuses.append(status)
        if not status.startswith("converged"):
            unconverged_best = min(unconverged_best, cost)
            continue
        minima.append(point)
        costs.append(float(ordered_sum(result.fun**2)))  # the same, summed left to right
    points, values = _distinct_minima(np.reshape(minima, (-1, 2)), np.asarray(costs), scale, xtol)
    if len(values) > 1:
        points, values = _merge_flat_ties(data, points, values, use_rss, cost_rtol)
    return MlSolution(
        minima_m=points,
        costs=values,
        n_starts=len(starts),
        n_evaluations=n_evaluations,
        messages=tuple(messages),
        statuses=tuple(statuses),
        unconverged_best_cost=unconverged_best,
    )


def ml_decrement(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False, scale_m: float
) -> float:
    """The decrement of ``‖e‖²`` at ``emitter_m`` (χ² units; module text, "Convergence").

    ``min(‖P_J e‖², gᵀH⁻¹g)``: the Gauss-Newton decrement (``P_J`` the projection on the range
    of the whitened Jacobian ``J``, finite even where ``JᵀJ`` is singular) and the Newton
    decrement with the exact Hessian ``H`` (central differences of ``g = Jᵀe``, step
    ``HESSIAN_STEP_RTOL · scale_m``), the latter only where ``H`` is positive definite.
    """
    point = np.asarray(emitter_m, dtype=float)

    def gradient(at: FloatArray) -> FloatArray:
        J = whitened_residual_jacobian(data, at, use_rss=use_rss)
        return J.T @ whitened_residuals(data, at, use_rss=use_rss)

    e = whitened_residuals(data, point, use_rss=use_rss)
    J = whitened_residual_jacobian(data, point, use_rss=use_rss)
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(J))):
        return float("inf")
    step, *_ = np.linalg.lstsq(J, e, rcond=None)
    gauss_newton = float(np.sum((J @ step) ** 2))
    h = HESSIAN_STEP_RTOL * scale_m
    hessian = np.column_stack(
        [
            (gradient(point + h * axis) - gradient(point - h * axis)) / (2.0 * h)
            for axis in np.eye(2)
        ]
    )
    hessian = 0.5 * (hessian + hessian.T)
    information = J.T @ J
    return min(gauss_newton, stationarity_decrement(information, hessian - information, J.T @ e))


def _distinct_minima(
    points_m: FloatArray, costs: FloatArray, scale_m: float, tie_rtol: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Merge points closer than ``MERGE_RTOL · scale_m``, best first.

    In cost order, a point within the threshold of a kept one is merged into the first such,
    and the lower cost is kept; but costs within ``tie_rtol`` (relative) are one cost, and of
    tied points the one given first (the earlier start) is kept. One minimum reached from two
    starts ends at two costs that differ by the solver's tolerance: which is lower is chance.
    """
    order = np.argsort(costs, kind="stable")
    kept: list[int] = []
    for index in order.tolist():
        for at, j in enumerate(kept):
            if np.linalg.norm(points_m[index] - points_m[j]) <= MERGE_RTOL * scale_m:
                if index < j and costs[index] <= costs[j] + tie_rtol * abs(costs[j]):
                    kept[at] = index
                break
        else:
            kept.append(index)
    kept = [kept[i] for i in np.argsort(costs[kept], kind="stable")]
    return points_m[kept], costs[kept]


def _merge_flat_ties(
    data: MeasurementSet,
    points_m: FloatArray,
    costs: FloatArray,
    use_rss: bool,
    cost_rtol: float,
) -> tuple[FloatArray, FloatArray]:
    """Drop tied minima joined to a better one by a flat valley (no barrier at the midpoint).

    Near a straight track's vertical plane the cost can be almost flat across the track, and
    two starts stop at slightly different points of that valley: they are one minimum.
    ``points_m`` is sorted by cost; the better point of each merged pair is kept.
    """
    best = costs[0]
    tie_level = best + cost_rtol * abs(best) + np.finfo(float).eps * 64 * max(abs(best), 1.0)
    kept: list[int] = [0]
    for index in range(1, len(costs)):
        if costs[index] <= tie_level:
            flat = False
            for j in kept:
                middle = 0.5 * (points_m[index] + points_m[j])
                rows = whitened_residuals(data, middle, use_rss=use_rss)
                middle_cost = float(ordered_sum(rows**2))
                if middle_cost <= tie_level:
                    flat = True
                    break
            if flat:
                continue
        kept.append(index)
    return points_m[kept], costs[kept]


def fisher_covariance_m2(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False
) -> FloatArray | None:
    """``J⁻¹``, the CRLB at ``emitter_m`` of the modalities used (MATH §8); None if singular.

    ``J`` is :func:`scenarios.fisher.gram_information` of :func:`whitened_residual_jacobian`:
    the rows of :func:`scenarios.fisher.whitened_jacobian` up to sign, centred where a
    nuisance parameter is profiled (MATH §15), so ``J`` is the information of
    :func:`scenarios.fisher.fisher_information` to rounding; formed from the residual model so
    that :mod:`estimators.ml.ml_batch` forms it with the same operations (equal to rounding).
    """
    information = gram_information(whitened_residual_jacobian(data, emitter_m, use_rss=use_rss))
    if not regular_2x2(information):
        return None
    return inverse_2x2(information)


def straight_track_starts(
    data: MeasurementSet,
    starts_m: ArrayLike,
    line: tuple[FloatArray, FloatArray],
    scale_m: float,
) -> FloatArray:
    """Starts folded to the left of a straight track, with a second start for those on it.

    The likelihood is symmetric about the track's vertical plane (MATH §7), so a start and its
    mirror converge to mirror-image minima: one side suffices (the caller adds the mirrors).
    On the plane itself the cross-track gradient vanishes and a local method cannot leave it,
    so a start there also gets a copy moved off the plane by the cross-track distance the
    ranges imply, ``√mean(r_k² − (z_k − z_s)² − a_k²)`` with ``a_k`` the along-track offset
    (at least ``0.1 scale_m``). ``scale_m`` is the problem's length scale (``LocalFrame``).
    """
    origin, direction = line
    starts = np.asarray(starts_m, dtype=float).reshape(-1, 2)
    cross = cross_track_m(starts, origin, direction)
    starts = np.where((cross < 0.0)[:, None], mirror_across_line(starts, origin, direction), starts)
    scale = scale_m
    # a mirror pair of starts folds onto one point: keep it once
    starts, cross = _distinct_minima(starts, np.abs(cross), scale)
    on_track = np.abs(cross) <= ON_TRACK_RTOL * scale
    if not np.any(on_track):
        return starts
    normal = np.array([-direction[1], direction[0]])
    along = (data.position_m[:, :2] - starts[on_track][:, None, :]) @ direction
    horizontal_sq = data.range_m**2 - (data.position_m[:, 2] - data.emitter_height_m) ** 2
    offset_sq = np.mean(horizontal_sq - along**2, axis=1)
    offset = np.sqrt(np.maximum(offset_sq, (0.1 * scale) ** 2))
    return np.vstack([starts, starts[on_track] + offset[:, None] * normal])


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class MaximumLikelihood:
    """Maximum likelihood on the raw measurements, started from every CLS candidate (MATH §10).

    Parameters
    ----------
    frames : {"all", "last"}
        Use every frame so far, or only the last.
    use_rss : bool
        Add the RSS residuals (needs ``rss_dbm`` in the data).
    use_toa : bool
        Use the ToA residuals (the default; needs ``toa_s``). False: Doppler alone, started
        from the minima of the profiled Doppler cost on a grid (MATH §15).
    cost_rtol : float
        Minima within this relative cost gap of the best are all candidates (MATH §7).
    side_prior_m : (x, y) or None
        A rough emitter position; picks the nearer of equal-cost candidates (MATH §7).
    fallback_lls : bool
        When the CLS cannot give a start (e.g. a hovering sample), start from LLS-ToA.
    doppler_start : bool or "auto"
        Also start from the Doppler-only fit of the last frame (:func:`doppler_frame_starts`),
        which does not depend on the ranges; costs one more local search. ``"auto"``: only when
        the range noise ``c σ_τ`` exceeds the size of the geometry (:func:`ranges_uninformative`),
        e.g. the paper's printed ``c σ_τ = 300 km``, where the CLS start is meaningless.
    method : {"lm", "trf"}
        The ``scipy.optimize.least_squares`` method.
    max_nfev : int
        Residual evaluations per start, at most; a start that uses them all has not converged
        (module text, "Convergence").
    """

    name: ClassVar[str] = "ml"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler"})

    frames: Frames = "all"
    use_rss: bool = False
    use_toa: bool = True
    cost_rtol: float = 1e-6
    side_prior_m: tuple[float, float] | None = None
    fallback_lls: bool = True
    doppler_start: bool | Literal["auto"] = "auto"
    method: Method = "lm"
    max_nfev: int = 200

    def __post_init__(self) -> None:
        if self.frames not in ("all", "last"):
            raise ValueError(f"frames: expected 'all' or 'last', got {self.frames!r}")
        for option in ("use_rss", "use_toa", "fallback_lls"):
            if not isinstance(getattr(self, option), bool):
                raise ValueError(f"{option}: expected true or false, got {getattr(self, option)!r}")
        if not (isinstance(self.cost_rtol, int | float) and 0.0 <= self.cost_rtol < np.inf):
            raise ValueError(f"cost_rtol: expected a finite number >= 0, got {self.cost_rtol!r}")
        if self.doppler_start not in (True, False, "auto"):
            raise ValueError(
                f"doppler_start: expected True, False or 'auto', got {self.doppler_start!r}"
            )
        if self.method not in ("lm", "trf"):
            raise ValueError(f"method: expected 'lm' or 'trf', got {self.method!r}")
        n = self.max_nfev
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"max_nfev: expected a whole number >= 1, got {n!r}")
        check_side_prior(self.side_prior_m)

    def capabilities(self) -> Capabilities:
        """Doppler, ToA unless ``use_toa=False``, RSS with ``use_rss``; unit-invariant."""
        modalities = self.requires | ({"toa"} if self.use_toa else set())
        modalities |= {"rss"} if self.use_rss else set()
        return Capabilities(
            modalities=modalities,
            frames=self.frames,
            batch=True,
            unit_invariant=True,
            unknowns=frozenset(NUISANCE_PARAMETERS),  # profiled out (MATH §15)
        )

    def estimate_batch(self, batch: MeasurementBatch, *, rngs: Rngs = None) -> list[Estimate]:
        """``estimate`` of every trial (trial ``i`` with ``rngs[i]``), solved together."""
        return self.estimate_columns(batch, rngs=rngs).to_estimates()

    def estimate_columns(self, batch: MeasurementBatch, *, rngs: Rngs = None) -> BatchEstimates:
        """``estimate_batch`` as columns (:mod:`estimators.ml.ml_batch`): the same answers, bit
        for bit, with the trials the batch cannot reproduce solved one at a time."""
        return with_fit_columns(self, estimate_columns(self, batch, rngs), batch)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """The answer, with its goodness of fit in ``diagnostics`` (MATH §10, §17)."""
        return with_fit(self, self.estimate_without_fit(data, rng=rng), data)

    def estimate_without_fit(
        self, data: MeasurementSet, *, rng: np.random.Generator | None = None
    ) -> Estimate:
        """:meth:`estimate` before its goodness of fit is added: what the batch
        (:mod:`estimators.ml.ml_batch`) defers a trial to, before it adds the fit to every trial."""
        require_modalities(self, data)
        self.check_measurements(data.toa_s is not None, data.rss_dbm is not None)
        if not self.use_toa and data.toa_s is not None:
            data = data.without("toa")
        used = data.select_frames(self.frames)
        starts, start_method, start_note, frame = self.search_starts(used)
        if starts is None:
            return Estimate.failed(self.name, f"no starting point: {start_note}")
        solution = solve_maximum_likelihood(
            used,
            starts,
            use_rss=self.use_rss,
            method=self.method,
            frame=frame,
            cost_rtol=self.cost_rtol,
            max_nfev=self.max_nfev,
        )
        diagnostics = {
            "n_starts": solution.n_starts,
            "nfev": solution.n_evaluations,
            "max_nfev": self.max_nfev,
            "start_method": start_method,
            "n_samples": used.n_samples,
            "lm_status": list(solution.statuses),
            "n_converged": solution.n_converged,
        }
        reasons = "; ".join(dict.fromkeys(solution.messages))
        if len(solution.minima_m) == 0:
            return Estimate.failed(
                self.name,
                f"least squares did not converge from any start: {reasons or 'no start'}",
                **diagnostics,
            )
        best = float(solution.costs[0])
        if solution.unconverged_best_cost < best - self.cost_rtol * abs(best):
            return Estimate.failed(
                self.name,
                f"a start that did not converge ended below every converged minimum "
                f"(cost {solution.unconverged_best_cost:.6g} < {best:.6g}): the optimum was "
                f"not reached ({reasons})",
                **diagnostics,
            )
        unconverged = solution.n_starts - solution.n_converged
        if unconverged:
            note = (
                f"{unconverged} of {solution.n_starts} starts did not converge and were "
                f"dropped ({reasons})"
            )
            start_note = f"{start_note}; {note}" if start_note else note
        estimate = finalize_estimate(
            self.name,
            solution.minima_m,
            solution.costs,
            used,
            rng=rng,
            side_prior_m=self.side_prior_m,
            cost_rtol=self.cost_rtol,
            message=start_note,
            diagnostics=dict(
                diagnostics,
                cost=float(solution.costs[0]),
                n_minima=len(solution.minima_m),
                **profiled_offsets(used, solution.minima_m[0]),
            ),
        )
        if not (
            np.all(np.isfinite(estimate.position_m)) and np.all(np.isfinite(estimate.candidates_m))
        ):
            return Estimate.failed(
                self.name, "least squares returned a non-finite minimum", **diagnostics
            )
        covariance = fisher_covariance_m2(used, estimate.position_m, use_rss=self.use_rss)
        if covariance is None:
            note = "singular Fisher information at the estimate: no covariance"
            message = f"{estimate.message}; {note}" if estimate.message else note
            return dataclasses.replace(estimate, message=message)
        return dataclasses.replace(estimate, covariance_m2=covariance)

    def check_measurements(self, has_toa: bool, has_rss: bool) -> None:
        """Raise ``ValueError`` naming ``toa_s`` or ``rss_dbm`` when an option needs them."""
        if self.use_toa and not has_toa:
            raise ValueError(
                "toa_s: estimator 'ml' needs ToA measurements; add them or set use_toa=False "
                "to locate from Doppler alone"
            )
        if self.use_rss and not has_rss:
            raise ValueError(
                "rss_dbm: estimator 'ml' with use_rss=True needs RSS measurements; add them "
                "or set use_rss=False"
            )

    def search_starts(self, used: MeasurementSet) -> tuple[FloatArray | None, str, str, LocalFrame]:
        """The starts (world) ``estimate`` searches from, how they were found, a note, and the
        local frame: :meth:`_starts`, the Doppler pair (``doppler_start``) and, on a straight
        track, :func:`straight_track_starts` (module text, "Starts")."""
        starts, start_method, start_note = self._starts(used)
        ranges = used.range_m
        if ranges is None:  # Doppler alone: the height sets the scale
            ranges = used.position_m[:, 2] - used.emitter_height_m
        frame = LocalFrame.fit(used.position_m, ranges)
        if starts is None or used.toa_s is None:
            return starts, start_method, start_note, frame
        if self.doppler_start is True or (
            self.doppler_start == "auto" and ranges_uninformative(used)
        ):
            last = used.take(used.frame == used.frame[-1])
            starts = np.vstack([starts, doppler_frame_starts(last)])
        line = straight_track_line(used.position_m, used.velocity_mps)
        if line is not None:
            starts = straight_track_starts(used, starts, line, frame.scale_m)
        return starts, start_method, start_note, frame

    def _starts(self, data: MeasurementSet) -> tuple[FloatArray | None, str, str]:
        """The CLS candidates, or the LLS-ToA solution when the CLS fails and fallback is on;
        with an unknown emission time the pseudo-range closed form's; from Doppler alone the
        local minima of the profiled cost on a grid (MATH §15)."""
        if data.toa_s is None:
            return doppler_grid_starts(data), "doppler-grid", ""
        try:
            if "emission_time_s" in data.unknowns:
                unknown_offset = "carrier_offset_hz" in data.unknowns
                solution = solve_pseudorange_cls(data, carrier_offset_unknown=unknown_offset)
                candidates = solution.candidates_m
            else:
                candidates = solve_doppler_toa_cls(data).candidates_m
            if np.all(np.isfinite(candidates)) and len(candidates):
                return candidates, "cls", ""
            reason = "CLS returned no finite candidate"
        except (ValueError, np.linalg.LinAlgError) as error:
            reason = f"CLS failed ({error})"
        if not self.fallback_lls or "emission_time_s" in data.unknowns:
            return None, "none", reason
        lls = solve_lls_toa(data.position_m, data.range_m, data.emitter_height_m)
        if not np.all(np.isfinite(lls.position_m)):
            return None, "none", f"{reason}; LLS-ToA returned a non-finite solution"
        return lls.position_m[None, :], "lls-toa", f"{reason}; started from LLS-ToA"
