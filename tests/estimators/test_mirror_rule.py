"""The mirror rule of MATH §7 (:func:`estimators.mirror_rule.finalize_columns`) against a
plain-Python statement of it, trial by trial, and the batch against its trials one at a time."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.mirror_rule import MERGE_RTOL, cost_tie_level, finalize_columns


def _rule_of_one_trial(candidates, count, costs, centre, line, cost_rtol=1e-6):
    """The rule as the module text states it, one trial in plain Python: (kept points best
    first, their source slots)."""
    slots = len(candidates)
    points = []  # (x, y, cost, source, valid), in slot order: the candidates, then mirrors
    for j in range(slots):
        x, y, c = (float(v) for v in (*candidates[j], costs[j]))
        valid = j < count and np.isfinite(x + y + c)
        points.append((x, y, c if valid else np.inf, j, valid))
    if line is not None:
        (ox, oy), (dx, dy) = line
        for x, y, c, j, valid in points[:slots]:
            along = (x - ox) * dx + (y - oy) * dy
            mirrored = (ox + 2.0 * along * dx - (x - ox), oy + 2.0 * along * dy - (y - oy))
            points.append((*mirrored, c, slots + j, valid))
    points = sorted(points, key=lambda p: p[2])  # stable: equal costs keep their order
    spread = [max(abs(x - centre[0]), abs(y - centre[1])) for x, y, _, _, v in points if v]
    threshold = MERGE_RTOL * max(max(spread, default=-np.inf), 1e-300)
    kept = []
    for point in points:
        near = any(np.hypot(point[0] - k[0], point[1] - k[1]) <= threshold for k in kept)
        if point[4] and not near:
            kept.append(point)
    best = min((p[2] for p in points), default=np.inf)
    level = cost_tie_level(best if best < np.inf else 0.0, cost_rtol)
    final = [p for p in kept if p[2] <= level]
    return [(p[0], p[1]) for p in final], [p[3] for p in final]


def _random_trials(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Two candidate slots per trial with coincident points, tied costs and NaNs mixed in."""
    candidates = rng.normal(0.0, 50.0, size=(n, 2, 2)) + np.array([30.0, 10.0])
    near = rng.random(n) < 0.3  # the second a hair away from the first: one point
    candidates[near, 1] = candidates[near, 0] + rng.normal(0.0, 1e-9, size=(near.sum(), 2))
    costs = rng.exponential(10.0, size=(n, 2))
    tied = rng.random(n) < 0.4
    costs[tied, 1] = costs[tied, 0] * (1.0 + rng.choice([0.0, 1e-9, 1e-3], size=tied.sum()))
    candidates[rng.random(n) < 0.05, rng.integers(0, 2)] = np.nan
    count = rng.integers(0, 3, size=n)
    return candidates, count, costs


@pytest.mark.parametrize("straight", [False, True])
def test_the_batch_follows_the_rule_trial_by_trial(straight: bool) -> None:
    rng = np.random.default_rng(21 + straight)
    n = 400
    candidates, count, costs = _random_trials(rng, n)
    centre = np.array([5.0, -2.0])
    line = (centre, np.array([0.6, 0.8])) if straight else None
    final = finalize_columns(candidates, count, costs, centre, line)
    for i in range(n):
        points, sources = _rule_of_one_trial(candidates[i], count[i], costs[i], centre, line)
        m = int(final.n_candidates[i])
        assert m == len(points)
        np.testing.assert_array_equal(final.candidates[i, :m], np.reshape(points, (m, 2)))
        assert np.isnan(final.candidates[i, m:]).all()
        assert final.source[i, :m].tolist() == sources
        assert bool(final.draw[i]) == (m > 1)
        assert bool(final.ambiguous[i]) == (m > 1 or straight)
        assert bool(final.invalid[i]) == (m == 0)


def test_a_point_near_a_dropped_one_is_kept() -> None:
    """The merge is greedy in cost order: B is dropped for lying near A, and C, near B but
    not near A, stays (the threshold is MERGE_RTOL times the points' spread, here 1 µm)."""
    step = 0.6e-9 * 1000.0
    candidates = np.array([[[1000.0, 0.0], [1000.0 + step, 0.0], [1000.0 + 2 * step, 0.0]]])
    final = finalize_columns(candidates, np.array([3]), np.ones((1, 3)), [0.0, 0.0], None)
    assert final.n_candidates.tolist() == [2]
    assert final.source[0, :2].tolist() == [0, 2]


def test_a_batch_is_its_trials_one_at_a_time() -> None:
    rng = np.random.default_rng(23)
    candidates, count, costs = _random_trials(rng, 200)
    line = (np.array([1.0, 2.0]), np.array([1.0, 0.0]))
    batch = finalize_columns(candidates, count, costs, [1.0, 2.0], line, side_prior_m=(0.0, 9.0))
    for i in range(200):
        one = finalize_columns(
            candidates[i : i + 1],
            count[i : i + 1],
            costs[i : i + 1],
            [1.0, 2.0],
            line,
            side_prior_m=(0.0, 9.0),
        )
        for name in ("candidates", "n_candidates", "source", "chosen", "draw", "ambiguous"):
            np.testing.assert_array_equal(getattr(one, name)[0], getattr(batch, name)[i])


def test_in_3d_the_reflection_above_the_uav_goes_and_a_straight_track_locates_nothing() -> None:
    """3-D candidates (the height estimated, MATH §7): an emitter 120 m up and its reflection
    through a level flight at 300 m (at 480 m, the same cost) leave one answer; a point a hair
    from the emitter is merged with it; on a straight track no candidate is an answer."""
    emitter, reflection = np.array([40.0, -25.0, 120.0]), np.array([40.0, -25.0, 480.0])
    hair = emitter + np.array([0.0, 0.0, 1e-8])
    candidates = np.stack([reflection, emitter, hair])[None]
    costs = np.array([[2.5, 2.5, 2.5 + 1e-12]])
    final = finalize_columns(candidates, np.array([3]), costs, np.zeros(2), None, ceiling_m=300.0)
    assert final.n_candidates.tolist() == [1] and not final.ambiguous[0]
    np.testing.assert_array_equal(final.candidates[0, 0], emitter)
    assert final.source[0, 0] == 1 and final.problem == ""

    # the prior may be horizontal: two candidates below the UAV, the prior picks by (x, y)
    other = np.array([-40.0, 25.0, 110.0])
    two = finalize_columns(
        np.stack([emitter, other])[None],
        np.array([2]),
        np.array([[1.0, 1.0]]),
        np.zeros(2),
        None,
        ceiling_m=300.0,
        side_prior_m=[-30.0, 20.0],
    )
    assert two.n_candidates[0] == 2 and two.ambiguous[0] and two.chosen[0] == 1

    line = (np.zeros(2), np.array([1.0, 0.0]))
    straight = finalize_columns(
        candidates, np.array([3]), costs, np.zeros(2), line, ceiling_m=300.0
    )
    assert straight.invalid[0] and straight.n_candidates[0] == 0
    assert straight.problem.startswith("position_m: every sample lies on one straight track")
    with pytest.raises(ValueError, match="ceiling_m"):
        finalize_columns(candidates, np.array([3]), costs, np.zeros(2), None)


def test_an_estimate_of_3d_candidates_follows_the_track() -> None:
    """``finalize_from_track`` in 3-D: the track's highest sample is the ceiling; a straight
    track fails the estimate with the one-line reason."""
    from estimators.base import finalize_from_track
    from estimators.mirror_rule import STRAIGHT_TRACK_HEIGHT
    from scenarios.geometry import TrackSoFar

    class Samples:
        def __init__(self, position, velocity):
            self.position_m, self.velocity_mps = np.asarray(position), np.asarray(velocity)

    t = np.linspace(0.0, 1.0, 5)[:, None]
    leg = np.hstack([10.0 * t, 0.0 * t, 300.0 + 0.0 * t])
    along = np.tile([10.0, 0.0, 0.0], (5, 1))
    turn = np.vstack([leg, leg[-1] + np.hstack([0.0 * t, 10.0 * t, 0.0 * t])])
    turning = TrackSoFar.of(Samples(turn, np.vstack([along, np.tile([0.0, 10.0, 0.0], (5, 1))])))
    assert turning.highest_m == 300.0
    candidates = [[40.0, -25.0, 480.0], [40.0, -25.0, 120.0]]
    estimate = finalize_from_track("x", candidates, [1.0, 1.0], turning)
    assert estimate.success and estimate.position_m.tolist() == [40.0, -25.0, 120.0]
    assert estimate.candidates_m.shape == (1, 3) and not estimate.ambiguous

    above = finalize_from_track("x", candidates[:1], [1.0], turning)
    assert not above.success and "below the UAV" in above.message

    straight = TrackSoFar.of(Samples(leg, along))
    failed = finalize_from_track("x", candidates, [1.0, 1.0], straight)
    assert not failed.success and failed.message == STRAIGHT_TRACK_HEIGHT


def test_in_3d_a_flight_in_one_plane_adds_each_candidate_s_reflection_through_it() -> None:
    """The flight's plane (scenarios.geometry.flight_plane): horizontal for a level turn,
    tilted for two legs with a climb, none for a single line or three legs off any plane; the
    rule adds each candidate's reflection through it at the same cost, and the ceiling keeps the
    one below the UAV."""
    from scenarios.geometry import flight_plane, reflect_through_plane

    t = np.linspace(0.0, 1.0, 6)[:, None]

    def legs(*velocities):
        position, velocity, start = [], [], np.array([0.0, 0.0, 300.0])
        for v in velocities:
            position.append(start + t * np.asarray(v) * 10.0)
            velocity.append(np.tile(v, (len(t), 1)))
            start = position[-1][-1]
        return np.vstack(position), np.vstack(velocity)

    level = flight_plane(*legs([10.0, 0.0, 0.0], [0.0, 10.0, 0.0]))
    assert level is not None and abs(abs(level[1][2]) - 1.0) < 1e-12
    tilted = flight_plane(*legs([10.0, 0.0, 0.0], [0.0, 10.0, 3.0]))
    assert tilted is not None
    np.testing.assert_allclose(np.abs(tilted[1]), np.array([0.0, 3.0, 10.0]) / np.hypot(3, 10))
    assert flight_plane(*legs([10.0, 0.0, 1.0], [10.0, 0.0, 1.0])) is None  # one line
    assert flight_plane(*legs([10.0, 0.0, 0.0], [0.0, 10.0, 3.0], [-10.0, 0.0, -1.0])) is None

    emitter = np.array([40.0, -25.0, 120.0])
    final = finalize_columns(
        emitter[None, None],
        np.array([1]),
        np.array([[2.0]]),
        np.zeros(2),
        None,
        ceiling_m=300.0,
        plane=level,
    )
    assert final.n_candidates.tolist() == [1]
    np.testing.assert_array_equal(final.candidates[0, 0], emitter)
    above = reflect_through_plane(emitter, *level)  # the solve found only the one above
    np.testing.assert_allclose(above, [40.0, -25.0, 480.0], rtol=1e-15)
    final = finalize_columns(
        above[None, None],
        np.array([1]),
        np.array([[2.0]]),
        np.zeros(2),
        None,
        ceiling_m=300.0,
        plane=level,
    )
    assert final.n_candidates.tolist() == [1] and final.source[0, 0] == 1
    np.testing.assert_allclose(final.candidates[0, 0], emitter, rtol=1e-15)
