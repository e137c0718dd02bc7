r"""The maximum-likelihood reference estimator (MATH §10, with unknowns §15, the height §8).

:class:`MaximumLikelihood` minimises the whitened residuals ``‖e(s)‖²`` of the raw
measurements by Levenberg-Marquardt from every closed-form candidate; the method, its starts,
its convergence test and its minima are in :mod:`estimators.ml.ml_batch`, vectorised over
trials: :meth:`MaximumLikelihood.estimate` is the batch of one trial. The covariance is the
inverse Fisher information at the estimate, ``(JᵀJ)⁻¹`` with ``J`` the whitened Jacobian
(MATH §8): the CRLB evaluated at ``ŝ``. When the data declare the emitter's height unknown the
search, the answer and the covariance are in ``(x_s, y_s, z_s)`` (position (3,), covariance
3 × 3; MATH §8, §10).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.base import Capabilities, Estimate, check_side_prior, require_modalities
from estimators.batch import BatchEstimates, EstimatesOfColumns
from estimators.goodness_of_fit import with_fit, with_fit_columns
from estimators.ml.ml_batch import solve_batch
from estimators.ml.ml_residuals import ResidualModel
from scenarios.nuisance import HEIGHT_UNKNOWN, NUISANCE_PARAMETERS
from scenarios.types import MeasurementBatch, MeasurementSet

FloatArray = NDArray[np.float64]
Frames = Literal["all", "last"]
Method = Literal["lm"]
Rngs = Sequence[np.random.Generator | None] | None


def whitened_residuals(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False
) -> FloatArray:
    """``e(s)``: Doppler, ToA (and RSS) residuals divided by their σ (MATH §10).

    Rows are ordered Doppler block, ToA block, then the RSS block when ``use_rss``; each block
    has one row per sample. Measured minus predicted, Doppler with the physical sign (MATH §1).
    Vectorised: ``emitter_m`` of shape ``(..., d)`` gives residuals of shape ``(..., n_rows)``;
    ``d = 3`` is ``(x_s, y_s, z_s)``, the height a coordinate (MATH §8).
    """
    emitter = np.asarray(emitter_m, dtype=float)
    rss = data.rss_dbm if use_rss else None
    point = [emitter[..., axis, None] for axis in range(emitter.shape[-1])]
    blocks = _model(data, emitter).residuals(point, data.doppler_hz, data.toa_s, rss)
    return np.concatenate(blocks, axis=-1)


def whitened_residual_jacobian(
    data: MeasurementSet, emitter_m: ArrayLike, *, use_rss: bool = False
) -> FloatArray:
    """``∂e/∂s = −[∇f_k/σ_f; ∇τ_k/σ_τ; ∇P_k/σ_P]`` (MATH §8, §10).

    Shape ``(..., n_rows, d)`` for ``emitter_m`` of shape ``(..., d)`` (``d = 3``: the height
    a coordinate): minus the rows of :func:`scenarios.fisher.whitened_jacobian`, so its Gram
    matrix ``JᵀJ`` is the Fisher information of MATH §8 at ``emitter_m``.
    """
    emitter = np.asarray(emitter_m, dtype=float)
    point = [emitter[..., axis, None] for axis in range(emitter.shape[-1])]
    columns = _model(data, emitter).jacobian(point, use_rss)
    return np.stack([np.concatenate(c, axis=-1) for c in columns], axis=-1)


def _model(data: MeasurementSet, emitter: FloatArray) -> ResidualModel:
    """The data's residual model for emitters of ``emitter.shape[-1]`` coordinates."""
    model = ResidualModel.of(data)
    if model.dimension != emitter.shape[-1]:
        model = dataclasses.replace(model, dimension=emitter.shape[-1])
    return model


@dataclass(frozen=True, kw_only=True)
class MaximumLikelihood(EstimatesOfColumns):
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
        Also start from the Doppler-only fit of the last frame (:func:`~estimators.ml.ml_batch_starts.doppler_frame_starts`),
        which does not depend on the ranges; costs one more local search. ``"auto"``: only when
        the range noise ``c σ_τ`` exceeds the size of the geometry (:func:`~estimators.ml.ml_starts.ranges_uninformative`),
        e.g. the paper's printed ``c σ_τ = 300 km``, where the CLS start is meaningless.
    method : {"lm"}
        Levenberg-Marquardt (MINPACK's, vectorised: :mod:`estimators.ml.minpack_batch`).
    max_nfev : int
        Residual evaluations per start, at most; a start that uses them all has not converged
        (:mod:`estimators.ml.ml_batch`).
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
        if self.method != "lm":
            raise ValueError(
                f"method: expected 'lm' (Levenberg-Marquardt, the only method), got {self.method!r}"
            )
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
            # the nuisance parameters profiled out (MATH §15), the height estimated (MATH §8)
            unknowns=frozenset({*NUISANCE_PARAMETERS, HEIGHT_UNKNOWN}),
        )

    def estimate_columns(self, batch: MeasurementBatch, *, rngs: Rngs = None) -> BatchEstimates:
        """``estimate_batch`` as columns (:func:`estimators.ml.ml_batch.solve_batch`)."""
        columns, _ = solve_batch(self, batch, rngs)
        return with_fit_columns(self, columns, batch)

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """The answer, with its goodness of fit in ``diagnostics`` (MATH §10, §17): the batch
        of one trial (a failed one keeps its search's diagnostics)."""
        require_modalities(self, data)
        self.check_measurements(data.toa_s is not None, data.rss_dbm is not None)
        columns, failed = solve_batch(self, MeasurementBatch.of_one(data), [rng], checked=True)
        return with_fit(self, failed.get(0) or columns.estimate(0), data)

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
