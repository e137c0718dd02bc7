"""A streaming plug-in written against the public API only, as a third-party author would.

Its ``estimate_state`` has no data: it keeps a :class:`scenarios.geometry.TrackSoFar` and its
rows in the state and finishes with :func:`estimators.base.finalize_from_track`. The mirror
rule must then give what :func:`estimators.base.finalize_estimate` gives on the data (MATH §7):
both mirror candidates and the ambiguity on a straight track, one candidate after a turn, the
same pick from the same generator. The two paths compute the track's line and the samples'
centre differently (from the first frame and a running mean, against every sample at once), so
the candidates agree to rounding of the mirror reflection, not to the bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pytest

from estimators.base import (
    Capabilities,
    Estimate,
    finalize_estimate,
    finalize_from_track,
    require_modalities,
)
from estimators.checks import check_estimator, reference_data
from estimators.closed_form.cls_rows import LocalFrame, toa_rows
from estimators.closed_form.gtrs import solve_gtrs
from scenarios import get_scenario, simulate
from scenarios.geometry import StraightTrack, TrackSoFar
from scenarios.types import MeasurementSet


@dataclass(frozen=True, slots=True)
class RowsState:
    """The squared-range rows so far (in the first frame's local frame) and the track."""

    local: LocalFrame | None
    A: np.ndarray
    b: np.ndarray
    track: TrackSoFar | None


@dataclass(frozen=True, kw_only=True)
class StreamingSquaredRangeLs:
    """SR-LS (MATH §4-§5) fed one frame at a time: the rows accumulate, the solve is exact."""

    name: ClassVar[str] = "streaming-sr-ls"
    requires: ClassVar[frozenset[str]] = frozenset({"toa"})

    def capabilities(self) -> Capabilities:
        return Capabilities(modalities=self.requires, sequential=True, unit_invariant=True)

    def init(self) -> RowsState:
        return RowsState(None, np.empty((0, 3)), np.empty(0), None)

    def update(self, state: RowsState, frame: MeasurementSet) -> RowsState:
        require_modalities(self, frame)
        local = state.local or LocalFrame.fit(frame.position_m, frame.range_m)
        A, b = toa_rows(
            local.positions(frame.position_m),
            frame.range_m / local.scale_m,
            frame.emitter_height_m / local.scale_m,
        )
        track = TrackSoFar.of(frame) if state.track is None else state.track.extended(frame)
        return RowsState(local, np.vstack([state.A, A]), np.concatenate([state.b, b]), track)

    def candidates(self, state: RowsState) -> tuple[np.ndarray, np.ndarray]:
        """Every global minimiser of the rows so far (two on a straight track) and its cost."""
        assert state.local is not None
        solution = solve_gtrs(state.A, state.b)
        return state.local.to_world(solution.points[:, :2]), solution.costs

    def estimate_state(self, state: RowsState, *, rng: Any = None) -> Estimate:
        if state.track is None:
            return Estimate.failed(self.name, "no frame has been processed yet")
        points, costs = self.candidates(state)
        return finalize_from_track(self.name, points, costs, state.track, rng=rng)

    def estimate(self, data: MeasurementSet, *, rng: Any = None) -> Estimate:
        require_modalities(self, data)
        state = self.init()
        for frame in data.iter_frames():
            state = self.update(state, frame)
        return self.estimate_state(state, rng=rng)


def streamed_and_finalized(data: MeasurementSet, seed: int) -> list[tuple[Estimate, Estimate]]:
    """After every frame: the plug-in's estimate, and finalize_estimate on the data so far with
    the same candidates, costs and generator seed."""
    plugin = StreamingSquaredRangeLs()
    state = plugin.init()
    pairs = []
    for frame in data.iter_frames():
        state = plugin.update(state, frame)
        seen = data.up_to_frame(int(frame.frame[0]))
        points, costs = plugin.candidates(state)
        streamed = plugin.estimate_state(state, rng=np.random.default_rng(seed))
        on_data = finalize_estimate(
            plugin.name, points, costs, seen, rng=np.random.default_rng(seed)
        )
        pairs.append((streamed, on_data))
    return pairs


def assert_same_estimate(streamed: Estimate, on_data: Estimate, extent_m: float) -> None:
    """Equal flags and counts; positions and candidates equal to the rounding of a reflection
    across a line computed from other samples (a few ulps of the extent, 1e-12 relative)."""
    assert streamed.success and on_data.success
    assert streamed.ambiguous == on_data.ambiguous
    assert streamed.diagnostics == on_data.diagnostics
    assert streamed.candidates_m.shape == on_data.candidates_m.shape
    atol = 1e-12 * extent_m
    np.testing.assert_allclose(streamed.candidates_m, on_data.candidates_m, rtol=0, atol=atol)
    np.testing.assert_allclose(streamed.position_m, on_data.position_m, rtol=0, atol=atol)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_on_a_straight_frame_both_paths_give_the_mirror_pair_and_the_same_pick(seed) -> None:
    data, _ = reference_data("paper-1m")
    ((streamed, on_data),) = streamed_and_finalized(data, seed)
    assert_same_estimate(streamed, on_data, 60.0)
    assert streamed.ambiguous and streamed.diagnostics["straight_track"]
    np.testing.assert_allclose(
        sorted(streamed.candidates_m.tolist()), [[35, -15], [35, 15]], atol=1e-6
    )
    assert any(np.allclose(streamed.position_m, c) for c in ([35, 15], [35, -15]))


def test_the_generator_picks_each_side_as_finalize_estimate_does() -> None:
    """Over 40 seeds the fair coin returns each mirror candidate, the same one on both paths."""
    data, _ = reference_data("paper-1m", noisy=True)
    sides = []
    for seed in range(40):
        ((streamed, on_data),) = streamed_and_finalized(data, seed)
        assert_same_estimate(streamed, on_data, 60.0)
        sides.append(bool(streamed.position_m[1] > 0))
    assert 0 < sum(sides) < 40


def test_frame_by_frame_on_a_track_that_turns() -> None:
    """paper-1m-turn at 10 dB: ambiguous while the frames continue one track (the plug-in's
    track extended frame by frame), one candidate from the turn on."""
    data = simulate(get_scenario("paper-1m-turn"), snr_db=10.0, seed=5).without_truth()
    pairs = streamed_and_finalized(data, seed=11)
    assert len(pairs) == 10
    for frame, (streamed, on_data) in enumerate(pairs):
        assert_same_estimate(streamed, on_data, 100.0)
        straight = frame < 4
        assert streamed.ambiguous == straight
        assert len(streamed.candidates_m) == (2 if straight else 1)
    assert np.linalg.norm(pairs[-1][0].position_m - [35.0, 15.0]) < 5.0


def test_the_track_kept_frame_by_frame_is_the_track_of_the_data() -> None:
    """TrackSoFar extended frame by frame: the data's sample count and centre (to rounding),
    and a straight track on the data's line until the turn, then None."""
    data = simulate(get_scenario("paper-1m-turn"), snr_db=10.0, seed=5).without_truth()
    track = None
    for frame in data.iter_frames():
        track = TrackSoFar.of(frame) if track is None else track.extended(frame)
        seen = data.up_to_frame(int(frame.frame[0]))
        whole = TrackSoFar.of(seen)
        assert track.n_samples == whole.n_samples == seen.n_samples
        np.testing.assert_allclose(track.centre_m, whole.centre_m, rtol=0, atol=1e-13 * 100)
        assert (track.straight is None) == (whole.straight is None)
        if whole.straight is not None:
            far = [[35.0, 15.0], [-20.0, 40.0]]
            np.testing.assert_allclose(
                track.straight.mirror_point(far), whole.straight.mirror_point(far), atol=1e-12
            )
    assert StraightTrack.of_frame(data) is None


def test_the_streaming_plugin_conforms() -> None:
    """Every applicable check, check_leaves_the_track and the streaming ones among them."""
    outcomes = check_estimator(StreamingSquaredRangeLs())
    ran = {o.name for o in outcomes}
    assert {
        "check_streaming_matches_estimate",
        "check_sequential_update_is_pure",
        "check_leaves_the_track",
        "check_mirror_pair_reproduces_data",
    } <= ran
