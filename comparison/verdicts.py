r"""Verdicts: does an estimator attain the CRLB, is its covariance consistent, and from which SNR.

Every verdict is computed from numbers that are printed beside it, and says ``inconclusive``
(with the reason) whenever those numbers cannot support a claim.

Efficiency verdict (one per summary row)
    The efficiency is ``η = RMSE / √CRLB`` (MATH §8), with the side-resolved RMSE (MATH §7)
    where the estimator flagged any estimate of the row as ambiguous. Its 95% interval comes
    from a studentized bootstrap of the mean squared error (:func:`comparison.intervals.studentized_bootstrap_interval`).
    The CRLB bounds unbiased estimators only, so two more numbers are judged: the bias
    ``β = ‖E[e]‖ / √CRLB`` with its interval (:func:`comparison.intervals.bias_intervals`),
    and the efficiency along each principal axis of the CRLB
    (:func:`comparison.intervals.axis_squared_errors`), since an unbiased estimator
    is at or above the bound in every direction (``E[eeᵀ] ⪰ CRLB``). The verdict is

    - ``attains``: the whole interval of η lies inside :data:`EFFICIENCY_BAND`, the whole
      interval of ``β`` at or below :data:`BIAS_LIMIT`, no axis wholly above the band, at least
      :data:`MIN_TRIALS` successful trials, a success rate of at least :data:`MIN_SUCCESS_RATE`,
      and no heavy tail (the largest 1% of the trials carry at most :data:`TAIL_SHARE_LIMIT` of
      the squared error);
    - ``biased``: the whole interval of ``β`` lies beyond :data:`BIAS_LIMIT`, or along an axis
      the whole interval lies below the band (only a biased estimator gets there): η is then
      no claim on the bound, whatever its value (unless η lies above the band by more than the
      bias explains, which stays ``above``);
    - ``above``: the whole interval of η, or of the efficiency along an axis, lies above the
      band;
    - ``below``: the whole interval of η lies below the band, with no bias resolved (only a
      biased estimator can be below the bound);
    - ``inconclusive``: anything else: too few trials, too many failures, heavy tails, an
      interval that straddles an edge of the band or a bias interval that reaches past the
      limit, or no finite bound.

The intervals (:mod:`comparison.intervals`): a studentized bootstrap of the mean squared
error, overall and along each principal axis of the CRLB, honest when a few trials land far
away; Hotelling's region for the mean error.

NEES verdict
    The mean NEES of ``n`` consistent values of ``d`` degrees of freedom (2, or 3 with the
    height estimated) lies in ``χ²_{dn}`` quantiles ``/ n``
    (:func:`comparison.intervals.nees_band`): ``consistent`` inside the band, ``optimistic`` above it (the reported
    covariance is too small), ``pessimistic`` below it, ``inconclusive`` with fewer than
    :data:`MIN_TRIALS` values, ``no covariance`` for an estimator that reports none.

Threshold SNR
    Per scenario and estimator of an SNR sweep: the lowest SNR from which every higher point
    ``attains`` (:func:`threshold_snr`); NaN when the highest point does not.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from comparison.intervals import (
    AxisEfficiencies,
    BiasIntervals,
    axis_names,
    short_number,
)

FloatArray = NDArray[np.float64]

EFFICIENCY_BAND: tuple[float, float] = (0.9, 1.1)
"""An estimator attains the CRLB when the 95% interval of its efficiency lies inside this."""

MIN_TRIALS = 30
"""Fewer successful trials than this give no verdict (``inconclusive``)."""

MIN_SUCCESS_RATE = 0.99
"""Smallest success rate at which an estimator can be said to attain the bound."""

TAIL_SHARE_LIMIT = 0.25
"""Heavy tail: the largest 1% of the trials carry more than this share of the squared error.
An efficient estimator's largest 1% carry about 6% (exponential squared errors, n ≥ 100)."""

BIAS_LIMIT = 0.3
"""``attains`` needs the whole 95% interval of the bias ``‖E[e]‖ / √trace(CRLB)`` at or below
this; a row whose whole interval lies beyond it is ``biased``. A bias of 0.3 √CRLB adds 9% of
the bound's mean squared error (docs/math.md §16)."""

VERDICTS = ("attains", "above", "below", "biased", "inconclusive")
NEES_VERDICTS = ("consistent", "optimistic", "pessimistic", "inconclusive", "no covariance")

# --------------------------------------------------------------------------------------------
# verdicts
# --------------------------------------------------------------------------------------------


def _above_along(axes: AxisEfficiencies, i: int, band_high: float) -> str:
    """Along which principal axis of the CRLB row ``i`` lies wholly above the band, in words;
    empty when along none. The trace efficiency can sit in the band while the error along the
    bound's thin axis is several times the bound there (a curved likelihood valley)."""
    return "; ".join(
        f"along the CRLB's {name} axis its RMSE is {short_number(axes.efficiency[i, k])} of the bound's, "
        f"95% interval [{short_number(axes.low[i, k])}, {short_number(axes.high[i, k])}], above {band_high:g}"
        for k, name in enumerate(axis_names(axes.efficiency.shape[1]))
        if axes.low[i, k] > band_high
    )


def _bias_explains(efficiency: float, bias: BiasIntervals, i: int, band_high: float) -> bool:
    """Whether the bias alone lifts row ``i`` above the band: without it (``η² − β²``, the
    variance's share of the efficiency) the row would not lie above ``band_high``."""
    return bool(efficiency**2 - bias.ratio[i] ** 2 <= band_high**2)


def efficiency_verdicts(
    *,
    n_judged: ArrayLike,
    n_trials: ArrayLike,
    efficiency: ArrayLike,
    low: ArrayLike,
    high: ArrayLike,
    tail: ArrayLike,
    bias: BiasIntervals,
    axes: AxisEfficiencies,
    band: tuple[float, float] = EFFICIENCY_BAND,
) -> tuple[NDArray[np.str_], list[str]]:
    """The efficiency verdict of every row and its reason (module docstring).

    Parameters
    ----------
    n_judged : (m,)
        Successful trials with a finite judged error.
    n_trials : (m,)
        Every trial, failed ones included (the success rate is ``n_judged / n_trials``).
    efficiency, low, high : (m,)
        The judged efficiency and its 95% interval (NaN: no finite bound or no estimate).
    tail : (m,)
        :func:`comparison.intervals.tail_share` of the judged squared errors.
    bias : BiasIntervals
        The judged error's mean and its interval, relative to √trace(CRLB)
        (:func:`comparison.intervals.bias_intervals`).
    axes : AxisEfficiencies
        The efficiency along each principal axis of the CRLB, with intervals.
    band : (low, high)

    Returns
    -------
    verdicts : (m,) str
        One of :data:`VERDICTS`.
    reasons : list of str
    """
    band_low, band_high = band
    if not 0 < band_low < 1 < band_high:
        raise ValueError(f"band: expected 0 < low < 1 < high, got {band!r}")
    n = np.asarray(n_judged, dtype=float)
    total = np.asarray(n_trials, dtype=float)
    eta = np.asarray(efficiency, dtype=float)
    lo, hi = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    share = np.asarray(tail, dtype=float)
    verdicts: list[str] = []
    reasons: list[str] = []
    for i in range(len(n)):
        interval = f"efficiency {short_number(eta[i])}, 95% interval [{short_number(lo[i])}, {short_number(hi[i])}]"
        counted = f"n = {int(n[i])}"
        heavy = bool(share[i] > TAIL_SHARE_LIMIT)
        tail_note = (
            f"heavy tail: the largest 1% of the trials carry {100 * share[i]:.0f}% of the "
            "squared error"
        )
        rate = n[i] / total[i] if total[i] > 0 else math.nan
        biased_by = _bias_finding(bias, axes, i, band_low)
        if n[i] == 0:
            verdict, reason = "inconclusive", "no successful estimate"
        elif not (np.isfinite(eta[i]) and np.isfinite(lo[i])):
            verdict, reason = "inconclusive", "no finite bound (singular Fisher information)"
        elif n[i] < MIN_TRIALS:
            verdict = "inconclusive"
            reason = f"too few trials: {int(n[i])} < {MIN_TRIALS} ({interval})"
        elif lo[i] > band_high and not (biased_by and _bias_explains(eta[i], bias, i, band_high)):
            verdict = "above"
            reason = f"{interval} lies above {band_high:g} ({counted})"
            reason += f"; {tail_note}" if heavy else ""
            reason += f"; also {biased_by}" if biased_by else ""
        elif biased_by:
            verdict = "biased"
            reason = (
                f"{biased_by}; the CRLB bounds only unbiased estimators, so its {interval} "
                f"says nothing about the bound ({counted})"
            )
        elif above_along := _above_along(axes, i, band_high):
            verdict = "above"
            reason = f"{above_along}, though its {interval} ({counted})"
        elif hi[i] < band_low:
            verdict = "below"
            reason = (
                f"{interval} lies below {band_low:g} ({counted}): only a biased estimator can "
                "be below the bound, and these trials do not resolve its bias"
            )
        elif rate < MIN_SUCCESS_RATE:
            verdict = "inconclusive"
            reason = (
                f"only {100 * rate:.1f}% of the estimates succeeded ({int(n[i])} of "
                f"{int(total[i])}; {100 * MIN_SUCCESS_RATE:g}% needed); {interval}"
            )
        elif heavy:
            verdict, reason = "inconclusive", f"{tail_note} ({interval}, {counted})"
        elif not bias.high[i] <= BIAS_LIMIT:
            verdict = "inconclusive"
            reason = (
                f"{bias.text(i)} may reach past {BIAS_LIMIT:g} √CRLB ({interval}, {counted}); "
                "more trials would tell whether it is negligible"
            )
        elif band_low <= lo[i] and hi[i] <= band_high:
            verdict = "attains"
            reason = (
                f"{interval} inside [{band_low:g}, {band_high:g}], {bias.text(i)} within "
                f"{BIAS_LIMIT:g} √CRLB ({counted})"
            )
        else:
            verdict = "inconclusive"
            reason = (
                f"{interval} straddles an edge of [{band_low:g}, {band_high:g}] ({counted}); "
                "more trials would narrow it"
            )
        verdicts.append(verdict)
        reasons.append(reason)
    return np.asarray(verdicts, dtype=str), reasons


def _bias_finding(bias: BiasIntervals, axes: AxisEfficiencies, i: int, band_low: float) -> str:
    """What shows row ``i``'s estimator biased, in words; empty when nothing does.

    Either its mean error is beyond :data:`BIAS_LIMIT` √CRLB (the whole interval), or along a
    principal axis of the CRLB its error is below the bound (the whole interval below the
    band's low edge), which no unbiased estimator can reach (``E[eeᵀ] ⪰ CRLB``).
    """
    found = []
    if bias.low[i] > BIAS_LIMIT:
        found.append(f"{bias.text(i)} lies beyond {BIAS_LIMIT:g} √CRLB")
    for k, name in enumerate(axis_names(axes.efficiency.shape[1])):
        if axes.high[i, k] < band_low:
            found.append(
                f"along the CRLB's {name} axis its RMSE is {short_number(axes.efficiency[i, k])} of the "
                f"bound's, 95% interval [{short_number(axes.low[i, k])}, {short_number(axes.high[i, k])}], "
                "below what any unbiased estimator reaches"
            )
    return "; ".join(found)


def nees_verdicts(
    nees_mean: ArrayLike, n_nees: ArrayLike, band_low: ArrayLike, band_high: ArrayLike
) -> NDArray[np.str_]:
    """``consistent``, ``optimistic``, ``pessimistic``, ``inconclusive`` or ``no covariance``."""
    mean = np.asarray(nees_mean, dtype=float)
    n = np.asarray(n_nees, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.select(
            [n == 0, n < MIN_TRIALS, mean > band_high, mean < band_low],
            ["no covariance", "inconclusive", "optimistic", "pessimistic"],
            default="consistent",
        ).astype(str)


def verdict_criterion(band: tuple[float, float] = EFFICIENCY_BAND) -> str:
    """The efficiency verdict's rule in words (for reports and captions)."""
    return (
        f"attains: the whole 95% interval of the efficiency (RMSE/√CRLB, side-resolved where "
        f"the estimator flags ambiguity, MATH §7) lies inside [{band[0]:g}, {band[1]:g}], the "
        f"bias (the mean error over √CRLB) is at most {BIAS_LIMIT:g} over its whole interval, "
        f"no principal axis of the CRLB is wholly above the band, with at least {MIN_TRIALS} "
        f"successful trials, {100 * MIN_SUCCESS_RATE:g}% successes and no heavy tail (the "
        f"largest 1% of the trials carrying more than {100 * TAIL_SHARE_LIMIT:g}% of the "
        f"squared error); biased: the bias lies beyond {BIAS_LIMIT:g}, or along an axis the "
        "error is below the bound (the CRLB bounds only unbiased estimators, so the efficiency "
        "of a biased one says nothing about it); above / below: the whole interval lies outside "
        "the band; inconclusive: anything else. The intervals are a studentized bootstrap of "
        "the mean squared error, honest when a few trials land far away, and Hotelling's region "
        "for the mean error (docs/math.md §16)."
    )


def threshold_snr(summary: pd.DataFrame, group_by: list[str], axis: str = "snr_db") -> pd.DataFrame:
    """The lowest SNR from which every higher point of an SNR sweep attains the bound (or the
    lowest C/N0 of a sweep of ``axis = "cn0_dbhz"``, MATH §18).

    Parameters
    ----------
    summary : pandas.DataFrame
        Rows with ``axis`` and ``verdict``, one per point within each group (the caller
        passes the last frame of each point, and only sweeps over that axis).
    group_by : list of str
        The columns naming a curve, e.g. ``["scenario", "estimator"]``.
    axis : ``"snr_db"`` or ``"cn0_dbhz"``
        The swept level.

    Returns
    -------
    pandas.DataFrame
        ``group_by`` columns, ``threshold_<axis>`` (NaN when the highest point does not
        attain), ``n_points`` and ``n_attains``, groups in order of first appearance.
    """
    rows = []
    for key, own in summary.groupby(group_by, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        ordered = own.sort_values(axis, ascending=False)
        attains = ordered["verdict"].to_numpy() == "attains"
        run = int(np.argmin(attains)) if not attains.all() else len(attains)
        threshold = float(ordered[axis].iloc[run - 1]) if run > 0 else math.nan
        rows.append((*key, threshold, len(own), int(attains.sum())))
    return pd.DataFrame(rows, columns=[*group_by, f"threshold_{axis}", "n_points", "n_attains"])
