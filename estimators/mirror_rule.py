r"""The mirror rule of MATH §7, written once for every trial of a batch: how candidates become
an answer.

Every estimator finishes here, through :func:`estimators.base.finalize_estimate` (one trial,
the batch of one) or :func:`finalize_columns` (many):

0. with the emitter's height estimated (3-D candidates): on a flight in one plane (a level
   turn, any two straight legs) each candidate's reflection through it is added at the same
   cost when the caller gives the plane; a candidate above the UAV's highest sample is dropped
   (the emitter is below the UAV: a level flight's reflection goes so); on a single straight
   line nothing is an answer (every rotation about it fits: :data:`STRAIGHT_TRACK_HEIGHT`);
1. on a straight track (every sample on one line, flying along it) each 2-D candidate's
   mirror image across it is added, at the same cost: the data cannot tell the two apart;
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

EPS = float(np.finfo(float).eps)

MERGE_RTOL = 1e-9
"""Candidates closer than this times the scale of the points are one."""

STRAIGHT_TRACK_HEIGHT = (
    "position_m: every sample lies on one straight track, which leaves the emitter on a circle "
    "about it when its height is unknown (MATH §7); fly a second heading, or give the height"
)
"""Why a straight track locates nothing in 3-D (the one-line failure of every estimator)."""

COST_TIE_ULPS = 64.0
"""Costs within this many rounding units of ``max(|best|, 1)`` above the best tie, on top of
``cost_rtol``: a sum of a few hundred squares carries that much rounding."""


def cost_tie_level(best: ArrayLike, cost_rtol: float) -> Any:
    """The highest cost that ties ``best`` (a number or an array of them): ``cost_rtol``
    relative, plus rounding (``COST_TIE_ULPS``). The one tie level of MATH §7."""
    size = np.abs(best)
    return best + cost_rtol * size + EPS * COST_TIE_ULPS * np.maximum(size, 1.0)


@dataclass(frozen=True, slots=True, eq=False)
class FinalizedColumns:
    """What :func:`finalize_columns` decides for each of ``n`` trials.

    ``candidates`` (n, w, d) holds trial ``i``'s kept candidates, best first, in its first
    ``n_candidates[i]`` slots; ``source`` (n, w) the slot each came from (``j`` for candidate
    ``j``, ``k + j`` for the mirror image of candidate ``j`` of ``k`` slots, -1 for none).
    ``chosen`` is the returned slot unless ``draw`` (several kept, no prior: the caller draws
    ``rng.integers(n_candidates)``). ``invalid`` trials have no finite candidate; ``problem``
    says why when the geometry, not the candidates, leaves none (every trial then invalid).
    """

    candidates: FloatArray
    n_candidates: IntArray
    source: IntArray
    chosen: IntArray
    draw: BoolArray
    ambiguous: BoolArray
    invalid: BoolArray
    problem: str = ""


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
    ceiling_m: float | None = None,
    plane: tuple[FloatArray, FloatArray] | None = None,
) -> FinalizedColumns:
    """The mirror rule (module text) for ``n`` trials of one geometry.

    Parameters
    ----------
    candidates_m : (n, k, d)
        Each trial's candidates, the first ``count[i]`` given; ``d`` is 2, or 3 with the
        emitter's height estimated.
    costs : (n, k)
    centre_m : (2,)
        The centre of the track (its mean horizontal sample position): the reference of the
        merge's scale.
    line : the straight track's ``(origin, unit direction)``, or None.
    merge : bool
        Merge coincident candidates (step 2); off, the rule is the tie rule alone.
    ceiling_m : float
        In 3-D (and only there, where it is required): the UAV's highest sample height. A
        candidate above it is not an answer (step 0 of the module text).
    plane : the flight's plane ``(origin, unit normal)``, (3,) each, or None
        In 3-D: the plane every sample lies and flies in
        (:func:`scenarios.geometry.flight_plane`); each candidate's reflection through it is
        added at the same cost, and ``line`` (the flight then is no single line) is not read.
    side_prior_m : (2,) or (d,)
        A rough position; a horizontal one picks by horizontal distance.
    """
    n, k, d = candidates_m.shape
    problem = ""
    if d == 3 and ceiling_m is None:
        raise ValueError("ceiling_m: the 3-D mirror rule needs the UAV's highest sample height")
    # (w, n) arrays, one row per candidate slot (slot-major: numpy's loops run over the
    # trials): the candidates, then (a 2-D straight track, a 3-D flight in one plane) their
    # mirror images at equal costs
    coords = [candidates_m[:, :, j].T for j in range(d)]
    valid = (np.arange(k)[:, None] < count) & np.isfinite(sum(coords) + costs.T)
    if d == 3 and plane is not None:  # the reflections through the flight's plane, at equal cost
        origin, normal = (np.asarray(v, dtype=float) for v in plane)
        height = sum((c - o) * u for c, o, u in zip(coords, origin, normal, strict=True))
        coords = [
            np.concatenate([c, c - 2.0 * height * u]) for c, u in zip(coords, normal, strict=True)
        ]
        valid = np.concatenate([valid, valid])
        costs = np.concatenate([costs, costs], axis=1)
    if d == 3:
        z = coords[2]
        valid &= z <= ceiling_m + MERGE_RTOL * max(abs(ceiling_m), 1.0)
        if line is not None and plane is None:
            problem = STRAIGHT_TRACK_HEIGHT
            valid[:] = False
    cost = np.where(valid, costs.T, np.inf)
    if line is not None and d == 2:
        x, y = coords
        (ox, oy), (dx, dy) = (np.asarray(v, dtype=float) for v in line)
        along = (x - ox) * dx + (y - oy) * dy
        coords = [
            np.concatenate([x, ox + 2.0 * along * dx - (x - ox)]),
            np.concatenate([y, oy + 2.0 * along * dy - (y - oy)]),
        ]
        cost = np.concatenate([cost, cost])
        valid = np.concatenate([valid, valid])
    width = len(coords[0])
    trials = np.arange(n)

    # stable sort by cost, unless every trial's valid costs are in slot order already
    # (invalid slots, at cost inf, are skipped wherever they stand)
    source: IntArray | None = None  # (None: slot order)
    running = np.maximum.accumulate(np.where(valid, cost, -np.inf), axis=0)
    if not np.logical_and.reduce(cost[1:] >= running[:-1], axis=None):
        source = np.argsort(cost, axis=0, kind="stable")
        coords = [c[source, trials] for c in coords]
        cost, valid = cost[source, trials], valid[source, trials]

    kept = valid
    if merge and width > 1:  # greedy in cost order: a point near a kept one is dropped
        centre = np.asarray(centre_m, dtype=float)
        # the scale: the horizontal distance from the centre, in 3-D the depth below the UAV
        offsets = [coords[0] - centre[0], coords[1] - centre[1]]
        if d == 3:
            offsets.append(coords[2] - ceiling_m)
        spread = np.maximum.reduce([np.abs(o) for o in offsets])
        scale = np.maximum.reduce(np.where(valid, spread, -np.inf), axis=0)
        threshold = MERGE_RTOL * np.maximum(scale, 1e-300)
        # close[i, j]: slot i within the threshold of slot j (every pair at once)
        if d == 2:
            gap = np.hypot(coords[0][:, None] - coords[0], coords[1][:, None] - coords[1])
        else:
            gap = np.sqrt(sum((c[:, None] - c) ** 2 for c in coords))
        close = gap <= threshold
        kept = valid.copy()
        for i in range(1, width):  # slot i against the kept slots before it
            kept[i] &= ~np.logical_or.reduce(kept[:i] & close[i, :i], axis=0)

    # the kept points are in cost order; those above the tie level go
    best = np.minimum.reduce(cost, axis=0)  # the first valid slot's (always kept)
    best = np.where(best < np.inf, best, 0.0)
    final = kept & (cost <= cost_tie_level(best, cost_rtol))
    n_final = np.add.reduce(final, axis=0, dtype=np.int64)
    # the final slots moved to the front, in order
    slot, trial = np.nonzero(final)
    at = np.cumsum(final, axis=0)[slot, trial] - 1
    out = np.full((n, width, d), np.nan)
    for j, c in enumerate(coords):
        out[trial, at, j] = c[slot, trial]
    out_source = np.full((n, width), -1, dtype=np.int64)
    out_source[trial, at] = slot if source is None else source[slot, trial]
    filled = np.arange(width) < n_final[:, None]

    chosen = np.zeros(n, dtype=np.int64)
    draw = np.zeros(n, dtype=bool)
    if side_prior_m is not None:
        prior = np.asarray(side_prior_m, dtype=float).reshape(-1)
        if prior.size not in (2, d):
            raise ValueError(f"side_prior_m: expected 2 or {d} coordinates, got {prior.size}")
        distance = np.sqrt(sum((out[..., j] - prior[j]) ** 2 for j in range(prior.size)))
        distance = np.where(filled, distance, np.inf)
        chosen = np.argmin(distance, axis=1).astype(np.int64)
    else:
        draw = n_final > 1
    return FinalizedColumns(
        candidates=out,
        n_candidates=n_final,
        source=out_source,
        chosen=chosen,
        draw=draw,
        ambiguous=(n_final > 1) | ((line is not None) & (d == 2)),
        invalid=n_final == 0,
        problem=problem,
    )
