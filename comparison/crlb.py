r"""Fisher information and the Cramér-Rao lower bound for the emitter's position (MATH §8).

.. math::

    J = \sum_k \Big( \frac{\nabla\tau_k \nabla\tau_k^\top}{\sigma_\tau^2}
        + \frac{\nabla f_k \nabla f_k^\top}{\sigma_f^2}
        + \frac{\nabla P_k \nabla P_k^\top}{\sigma_P^2} \Big),
    \qquad \mathrm{CRLB} = J^{-1},\qquad \text{RMSE bound} = \sqrt{\operatorname{tr} J^{-1}}

over the samples and the modalities used. The comparison's names for what
:mod:`scenarios.fisher` computes (the one implementation, which planners and estimators use
too): ``emitter_m`` of shape ``(..., d)`` evaluates many emitter positions (a geometry map) in
one call, ``d`` its coordinates (``(x_s, y_s)`` at a known height); per-frame and accumulated information come from :func:`fisher_information_per_frame`.

Doppler alone gives a nonsingular ``J``: the paper's claim that one UAV cannot localise from
Doppler alone is false (MATH §8).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from scenarios.fisher import (
    MODALITY_SETS,
    FloatArray,
    fisher_information,
    fisher_information_per_frame,
    inverse_symmetric,
    rmse_bound_m,
    whitened_jacobian,
)
from scenarios.nuisance import position_dimension
from scenarios.types import MeasurementSet

__all__ = [
    "MODALITY_SETS",
    "crlb_m2",
    "crlb_table",
    "fisher_information",
    "fisher_information_per_frame",
    "rmse_bound_m",
    "whitened_jacobian",
]


def crlb_m2(information: ArrayLike) -> FloatArray:
    """``J⁻¹``; NaN where ``J`` is singular (an unobservable geometry), shape ``(..., d, d)``.

    :func:`scenarios.fisher.inverse_symmetric` of the information (MATH §8).
    """
    return inverse_symmetric(information)


def crlb_parts_m(crlb_m2: np.ndarray) -> tuple[float, float]:
    """The horizontal and vertical parts of a bound (MATH §8): ``√(CRLB_xx + CRLB_yy)`` and
    ``√CRLB_zz`` of a 3×3 one; a 2×2 one is all horizontal (``√trace``, NaN)."""
    horizontal = float(np.sqrt(crlb_m2[0, 0] + crlb_m2[1, 1]))
    return horizontal, float(np.sqrt(crlb_m2[2, 2])) if len(crlb_m2) > 2 else math.nan


def crlb_table(data: MeasurementSet, at_m: Any) -> dict[str, Any]:
    """RMSE bound and CRLB matrix at ``at_m`` for each of ``MODALITY_SETS`` (MATH §8).

    A set whose σ (or RSS model) is missing, or whose information is singular, is ``None``
    with a note saying why. With unknowns in ``data.unknowns`` the bounds are those with them
    unknown (MATH §15, §8), and ``unknowns`` names them; ``known_rmse_bound_m`` holds the bounds
    of ``(x, y)`` with every unknown known and ``price`` the ratio of the two, per set (1 where
    an unknown does not enter the set's modalities).

    With the height unknown (``at_m`` then ``(x, y, z)``, the truth of such data) the CRLB is
    3×3 and ``horizontal_rmse_bound_m`` and ``vertical_rmse_bound_m`` split its trace; the
    known bound then holds the height at ``at_m``'s ``z``.
    """
    point = np.asarray(at_m, dtype=float)
    if position_dimension(data.unknowns) == 3 and point.shape == (2,):
        point = np.append(point, data.emitter_height_m)  # at the height the data assume
    table: dict[str, Any] = {
        "at_m": point.tolist(),
        "n_samples": data.n_samples,
        "unknowns": list(data.unknowns),
        "rmse_bound_m": {},
        "crlb_m2": {},
        "notes": {},
    }
    three_d = point.shape == (3,)
    if three_d:
        table["horizontal_rmse_bound_m"], table["vertical_rmse_bound_m"] = {}, {}
    if data.unknowns:
        table["known_rmse_bound_m"], table["price"] = {}, {}
    for name, modalities in MODALITY_SETS.items():
        try:
            with np.errstate(divide="ignore", invalid="ignore"):
                information = fisher_information(data, point, modalities)
        except ValueError as error:
            table["rmse_bound_m"][name] = table["crlb_m2"][name] = None
            table["notes"][name] = str(error)
            continue
        bound = float(rmse_bound_m(information))
        if not math.isfinite(bound):
            table["rmse_bound_m"][name] = table["crlb_m2"][name] = None
            table["notes"][name] = "singular Fisher information: unobservable from these samples"
            continue
        table["rmse_bound_m"][name] = bound
        bound_m2 = crlb_m2(information)
        table["crlb_m2"][name] = bound_m2.tolist()
        if three_d:
            horizontal, vertical = crlb_parts_m(bound_m2)
            table["horizontal_rmse_bound_m"][name] = horizontal
            table["vertical_rmse_bound_m"][name] = vertical
        if data.unknowns:
            # every unknown known: no nuisance column, and the height fixed (the (x, y) block)
            known_information = fisher_information(data, point, modalities, unknowns=())
            known = float(rmse_bound_m(known_information[:2, :2]))
            table["known_rmse_bound_m"][name] = known
            table["price"][name] = bound / known
    return table
