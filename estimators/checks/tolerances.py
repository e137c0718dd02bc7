"""How close is exact, and what the checks allow an estimator to declare.

A noise-free candidate is *exact* within :data:`EXACT_TOLERANCE_M` = 1e-6 m, or
:data:`EXACT_RTOL` = 1e-9 of the problem's extent (its largest coordinate) when that is larger
(rounding far from the origin). An iterative or grid method may loosen it only by declaring
``Capabilities(noise_free_tolerance_m=..., tolerance_reason="...")``, with a non-empty reason,
and never beyond :data:`MAX_NOISE_FREE_TOLERANCE` = 1e-3 of the problem's RMS UAV-emitter slant
range (6 cm on ``paper-1m``); a looser declaration fails ``check_capabilities_declared``, and
the exact checks use the cap instead. A class attribute ``noise_free_tolerance_m`` is not read.
Batch and streaming results must agree with ``estimate`` within :data:`AGREEMENT_TOLERANCE_M`
(or the honoured declared tolerance, if looser); answers on moved or rescaled geometries within
the noise-free tolerance (rounding at the moved geometry's largest coordinate included). A
candidate *reproduces* the noise-free data when the Gauss-Newton step from it to the data
(whitened by the σ's) is within the tolerance and leaves at most :data:`MISFIT_LIMIT` σ RMS
unexplained. Noisy answers must be within :data:`CRLB_FACTOR` = 5 times the Cramér-Rao bound
√trace(J⁻¹) (MATH §8) of the modalities and frames the estimator declares, side resolved
(nearest candidate), over :data:`CRLB_TRIALS` seeded trials at :data:`CRLB_SNR_DB` = 30 dB. On
the on-track start of ``check_leaves_the_track`` the nearest candidate must be within
``χ √trace(J⁻¹)`` of the emitter plus the noise-free tolerance (``χ`` the data's whitened misfit
at the emitter: how far, to first order, such data move the maximum likelihood), and no
candidate within the noise-free tolerance of the first frame's track.
Diagnostics whose key names a time (``*time*_s``, e.g. ``solve_time_s``) are exempt from the
equality checks.
"""

from __future__ import annotations

import functools
from typing import Any

from estimators.base import Capabilities, capabilities_of
from estimators.checks.reference_problems import (
    FIXED_PROBLEMS,
    REFERENCE_PROBLEMS,
    ReferenceProblem,
)

EXACT_TOLERANCE_M = 1e-6
"""Default distance (m) from an optimum within which a noise-free candidate counts as exact."""

EXACT_RTOL = 1e-9
"""The default tolerance relative to a problem's extent, when that is larger (rounding)."""

MAX_NOISE_FREE_TOLERANCE = 1e-3
"""Cap on a declared ``noise_free_tolerance_m``, relative to the RMS slant range (6 cm on
``paper-1m``): a noise-free answer further off is not exact, whatever is declared."""

AGREEMENT_TOLERANCE_M = 1e-6
"""Distance (m) within which batch or streaming positions must equal ``estimate``'s."""

MISFIT_LIMIT = 1.0
"""Unexplained whitened residual (σ, RMS) allowed after the Gauss-Newton step to the data."""

CRLB_SNR_DB = 30.0
"""The SNR of the trials compared with the Cramér-Rao bound."""

CRLB_TRIALS = 24
"""Seeded trials per problem in the comparison with the Cramér-Rao bound."""

CRLB_FACTOR = 5.0
"""The side-resolved RMSE may be at most this multiple of √trace(J⁻¹) (MATH §8)."""


def _honoured_tolerance_m(capabilities: Capabilities) -> float:
    """The declared tolerance if it is the default or tighter, or looser with a reason."""
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        return EXACT_TOLERANCE_M
    return declared


def tolerance_cap_m(problem: ReferenceProblem) -> float:
    """The most a declared tolerance counts on ``problem``: :data:`MAX_NOISE_FREE_TOLERANCE`
    times its RMS slant range."""
    return MAX_NOISE_FREE_TOLERANCE * problem.rms_range_m()


def problem_tolerance_m(capabilities: Capabilities, problem: ReferenceProblem) -> float:
    """The noise-free tolerance on ``problem``: the default (1e-6 m, or 1e-9 of the extent),
    loosened by an honoured declaration up to the cap."""
    default = max(EXACT_TOLERANCE_M, EXACT_RTOL * problem.extent_m())
    return max(default, min(_honoured_tolerance_m(capabilities), tolerance_cap_m(problem)))


def tolerance_text(capabilities: Capabilities, problem: ReferenceProblem) -> str:
    """The tolerance on ``problem`` in words, with why it is what it is (declared, capped)."""
    tolerance = problem_tolerance_m(capabilities, problem)
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        return f"{tolerance:.3g} m: the declared {declared:.3g} m needs a tolerance_reason"
    if declared > tolerance_cap_m(problem):
        return (
            f"{tolerance:.3g} m: the declared {declared:.3g} m capped at "
            f"{MAX_NOISE_FREE_TOLERANCE:g} of the RMS range {problem.rms_range_m():.1f} m"
        )
    if declared > EXACT_TOLERANCE_M and capabilities.tolerance_reason.strip():
        return f"{tolerance:.3g} m, as declared ({capabilities.tolerance_reason.strip()})"
    return f"{tolerance:.3g} m"


@functools.cache
def _smallest_cap_m() -> float:
    return min(tolerance_cap_m(FIXED_PROBLEMS[name]()) for name in REFERENCE_PROBLEMS)


def noise_free_tolerance_m(estimator: Any, problem: ReferenceProblem | None = None) -> float:
    """The tolerance the checks apply to ``estimator``'s noise-free candidates on ``problem``
    (None: on the problem with the smallest cap), from its declared capabilities only."""
    try:
        capabilities = capabilities_of(estimator)
    except Exception:
        return EXACT_TOLERANCE_M
    if problem is None:
        return max(EXACT_TOLERANCE_M, min(_honoured_tolerance_m(capabilities), _smallest_cap_m()))
    return problem_tolerance_m(capabilities, problem)


def agreement_tolerance_m(estimator: Any) -> float:
    """How far two answers of ``estimator`` on the same data may lie apart, m."""
    return max(AGREEMENT_TOLERANCE_M, noise_free_tolerance_m(estimator))
