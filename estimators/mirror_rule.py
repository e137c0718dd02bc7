r"""The mirror rule of MATH §7, written once for every trial of a batch: how candidates become
an answer.

Every estimator finishes here, through :func:`estimators.base.finalize_estimate` (one trial,
the batch of one) or :func:`finalize_columns` (many):

1. on a straight track (every sample on one line, flying along it) each candidate's mirror
   image across it is added, at the same cost: the data cannot tell the two apart;
2. candidates closer than :data:`MERGE_RTOL` times their largest distance from the centre of
   the track are one point (the cheaper, or the first given, is kept);
3. the candidates within ``cost_rtol`` of the best cost (:func:`cost_tie_level`) are kept,
   best first (a stable sort: equal costs keep their order); with a ``side_prior_m`` the kept
   candidate nearest to it is returned, otherwise the first, unless several are kept: then the
   trial's generator draws ``rng.integers(n_candidates)`` (a fair coin: the data hold no side
   information), which the caller does, in trial order.

A candidate that is not finite is not an answer: it is dropped before the rule, and a trial
left with none is ``invalid`` (its estimator fails it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

MERGE_RTOL = 1e-9
"""Candidates closer than this times the scale of the points are one."""

COST_TIE_ULPS = 64.0
"""Costs within this many rounding units of ``max(|best|, 1)`` above the best tie, on top of
``cost_rtol``: a sum of a few hundred squares carries that much rounding."""


def cost_tie_level(best: ArrayLike, cost_rtol: float) -> Any:
    """The highest cost that ties ``best`` (a number or an array of them): ``cost_rtol``
    relative, plus rounding (``COST_TIE_ULPS``). The one tie level of MATH §7."""
    size = np.abs(best)
    return best + cost_rtol * size + np.finfo(float).eps * COST_TIE_ULPS * np.maximum(size, 1.0)


@dataclass(frozen=True, slots=True, eq=False)
class FinalizedColumns:
    """What :func:`finalize_columns` decides for each of ``n`` trials.

    ``candidates`` (n, w, 2) holds trial ``i``'s kept candidates, best first, in its first
    ``n_candidates[i]`` slots; ``source`` (n, w) the slot each came from (``j`` for candidate
    ``j``, ``k + j`` for the mirror image of candidate ``j`` of ``k`` slots, -1 for none).
    ``chosen`` is the returned slot unless ``draw`` (several kept, no prior: the caller draws
    ``rng.integers(n_candidates)``). ``invalid`` trials have no finite candidate.
    """

    candidates: FloatArray
    n_candidates: IntArray
    source: IntArray
    chosen: IntArray
    draw: BoolArray
    ambiguous: BoolArray
    invalid: BoolArray


def finalize_columns(
    candidates_m: FloatArray,
    count: IntArray,
    costs: FloatArray,
    centre_m: ArrayLike,
    line: tuple[FloatArray, FloatArray] | None,
    *,
    side_prior_m: ArrayLike | None = None,
    cost_rtol: float = 1e-6,
    merge: bool = True,
) -> FinalizedColumns:
    """The mirror rule (module text) for ``n`` trials of one geometry.

    Parameters
    ----------
    candidates_m : (n, k, 2)
        Each trial's candidates, the first ``count[i]`` given.
    costs : (n, k)
    centre_m : (2,)
        The centre of the track (its mean horizontal sample position): the reference of the
        merge's scale.
    line : the straight track's ``(origin, unit direction)``, or None.
    merge : bool
        Merge coincident candidates (step 2); off, the rule is the tie rule alone.
    """
    n, k, _ = candidates_m.shape
    # one (n,) array per candidate slot: the candidates, then (straight track) their mirrors
    xs = [candidates_m[:, j, 0] for j in range(k)]
    ys = [candidates_m[:, j, 1] for j in range(k)]
    valid = [(count > j) & np.isfinite(xs[j] + ys[j] + costs[:, j]) for j in range(k)]
    cost = [np.where(valid[j], costs[:, j], np.inf) for j in range(k)]
    if line is not None:  # each candidate's mirror image, at its cost, after the candidates
        (ox, oy), (dx, dy) = (np.asarray(v, dtype=float) for v in line)
        for j in range(k):
            along = (xs[j] - ox) * dx + (ys[j] - oy) * dy
            xs.append(ox + 2.0 * along * dx - (xs[j] - ox))
            ys.append(oy + 2.0 * along * dy - (ys[j] - oy))
        cost, valid = cost + cost, valid + valid
    width = len(xs)
    source = [np.full(n, j, dtype=np.int64) for j in range(width)]

    # stable sort by cost, unless every trial's valid costs are in slot order already
    in_order = all(
        np.all(~valid[i] | ~valid[j] | (cost[i] <= cost[j])) for j in range(width) for i in range(j)
    )
    if not in_order:  # (invalid slots are skipped wherever they stand)
        order = np.argsort(np.column_stack(cost), axis=1, kind="stable")

        def sort(columns: list[NDArray[Any]]) -> list[NDArray[Any]]:
            stacked = np.take_along_axis(np.column_stack(columns), order, axis=1)
            return [stacked[:, j] for j in range(width)]

        xs, ys, cost, valid, source = sort(xs), sort(ys), sort(cost), sort(valid), sort(source)

    kept = [valid[0]]
    if merge:  # greedy in cost order: a point within the threshold of a kept one is dropped
        centre = np.asarray(centre_m, dtype=float)
        scale = np.full(n, -np.inf)
        for j in range(width):
            spread = np.maximum(np.abs(xs[j] - centre[0]), np.abs(ys[j] - centre[1]))
            scale = np.where(valid[j], np.maximum(scale, spread), scale)
        threshold = MERGE_RTOL * np.maximum(scale, 1e-300)
        for i in range(1, width):
            keep = valid[i].copy()
            for j in range(i):
                distance = np.hypot(xs[i] - xs[j], ys[i] - ys[j])
                keep &= ~(kept[j] & (distance <= threshold))
            kept.append(keep)
    else:
        kept += valid[1:]

    # the kept points are in cost order; those above the tie level go
    best = np.full(n, np.inf)
    for j in range(width):
        best = np.where(kept[j] & (best == np.inf), cost[j], best)
    limit = cost_tie_level(np.where(np.isfinite(best), best, 0.0), cost_rtol)
    out = np.full((n, width, 2), np.nan)
    out_source = np.full((n, width), -1, dtype=np.int64)
    n_final = np.zeros(n, dtype=np.int64)
    rows = np.arange(n)
    for j in range(width):
        final = kept[j] & (cost[j] <= limit)
        at, slot = rows[final], n_final[final]
        out[at, slot, 0] = xs[j][final]
        out[at, slot, 1] = ys[j][final]
        out_source[at, slot] = source[j][final]
        n_final += final

    chosen = np.zeros(n, dtype=np.int64)
    draw = np.zeros(n, dtype=bool)
    if side_prior_m is not None:
        prior = np.asarray(side_prior_m, dtype=float).reshape(2)
        distance = np.hypot(out[..., 0] - prior[0], out[..., 1] - prior[1])
        distance = np.where(np.arange(width)[None, :] < n_final[:, None], distance, np.inf)
        chosen = np.argmin(distance, axis=1).astype(np.int64)
    else:
        draw = n_final > 1
    return FinalizedColumns(
        candidates=out,
        n_candidates=n_final,
        source=out_source,
        chosen=chosen,
        draw=draw,
        ambiguous=(n_final > 1) | (line is not None),
        invalid=n_final == 0,
    )
