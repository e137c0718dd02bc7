"""The closed loop of the paper's Algorithm 1: fly a frame, estimate, plan the next, repeat.

For ``L`` frames (the scenario's own first frame, then ``L − 1`` planned ones):

1. measure frame ``l`` (seeded noise, see below);
2. run every estimator on the data so far (each with its own ``frames`` option: cumulative
   ``"all"`` or the paper's per-frame ``"last"``); sequential estimators are streamed;
3. the *steering* estimator's estimate (its candidates, the returned position first, and its
   covariance) goes to the planner, which returns frame ``l + 1``'s velocity.

Noise
    One trial draws its whole standard-normal block ``(3, L·K)`` (Doppler, ToA, RSS rows) from
    its seed up front (:func:`scenarios.simulate.standard_noise`); frame ``l`` uses columns
    ``lK … (l+1)K − 1``. The noise of a frame therefore never depends on the planner or on the
    estimates of earlier frames (common random numbers across planners), and the ``constant``
    planner reproduces the open-loop simulation of the same seed sample for sample.

Failures
    A failed steering estimate, or a planner that raises ``ValueError`` (zero speed, an
    estimate directly below the UAV, ...), holds the last velocity for the next frame; the
    reason is recorded in that frame's plan message. An estimator that raises, or changes
    the copy of the data it is given, gives a failed estimate
    (:mod:`comparison.estimator_calls`); the planner gets a copy of the data too, so neither
    changes what the others see or the flown data the bound is computed from.

Data flows one way: this module imports ``scenarios``, ``estimators`` and
:mod:`comparison.estimator_calls`, and is called by :mod:`comparison.tasks`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from comparison.estimator_calls import Stream, call_estimate, kept_process, private_copy
from estimators.base import Estimate, Estimator, capabilities_of
from scenarios.planners.base import Plan, Planner
from scenarios.simulate import SeedLike, noise_free, standard_noise
from scenarios.types import MODALITIES, FlightPlan, MeasurementSet, Scenario

FloatArray = NDArray[np.float64]

HOLD_PREFIX = "held the last velocity: "
"""Start of the plan message when the loop had to hold the velocity (a documented fallback)."""


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ClosedLoopTrial:
    """One trial of the closed loop.

    Attributes
    ----------
    flight : FlightPlan
        The frames flown.
    data : MeasurementSet
        Every measurement, truth included.
    estimates : mapping
        Estimator label → one ``(Estimate, runtime_s)`` per frame (on the data up to it).
    plans : tuple
        ``plans[l]`` chose frame ``l``'s velocity; ``plans[0]`` is None (the scenario's own
        first frame).
    """

    flight: FlightPlan
    data: MeasurementSet
    estimates: Mapping[str, tuple[tuple[Estimate, float], ...]]
    plans: tuple[Plan | None, ...] = field(default_factory=tuple)

    @property
    def n_frames(self) -> int:
        return self.flight.n_frames


def measure_flight(
    scenario: Scenario, flight: FlightPlan, *, snr_db: float, draws: FloatArray
) -> MeasurementSet:
    """The measurements of ``flight``: noise-free values plus σ times ``draws[:, :N]``.

    ``draws`` is a standard-normal block with rows Doppler, ToA, RSS and at least
    ``flight.n_samples`` columns (MATH §1-§2: the same order as :mod:`scenarios.simulate`).
    """
    exact = noise_free(scenario.replace(flight=flight), snr_db=snr_db)
    n = exact.n_samples
    noisy: dict[str, Any] = {}
    for row, (modality, name) in enumerate(
        zip(MODALITIES, ("doppler_hz", "toa_s", "rss_dbm"), strict=True)
    ):
        value = getattr(exact, name)
        noisy[name] = (
            None if value is None else value + exact.noise.for_modality(modality) * draws[row, :n]
        )
    return dataclasses.replace(exact, **noisy)


def steering_candidates_m(estimate: Estimate) -> FloatArray:
    """The estimate's candidates with the returned position first, ``(n, 2)``."""
    position = np.asarray(estimate.position_m, dtype=float).reshape(1, 2)
    others = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    scale = max(float(np.max(np.abs(position))), 1.0)
    keep = np.linalg.norm(others - position, axis=1) > 1e-12 * scale
    return np.vstack([position, others[keep]])


def fly_closed_loop(
    scenario: Scenario,
    *,
    snr_db: float,
    planner: Planner,
    estimators: Sequence[tuple[str, Estimator]],
    steering: str,
    seed: SeedLike,
    n_frames: int | None = None,
    estimate_rng: Callable[[str], np.random.Generator | None] | None = None,
    planner_rng: np.random.Generator | None = None,
    assuming: Mapping[str, tuple[str, ...]] | None = None,
) -> ClosedLoopTrial:
    """Fly ``n_frames`` frames of ``scenario``, steering each by ``planner`` (module docstring).

    Parameters
    ----------
    scenario : Scenario
        Its flight's first frame (start position, initial velocity ``v0``, K, Δ) starts the
        loop; ``n_frames`` defaults to its number of frames.
    snr_db : float
        Every σ times ``10^(−snr_db/20)`` (MATH §2).
    planner : Planner
    estimators : sequence of (label, Estimator)
        Run on the data up to every frame; labels distinct.
    steering : str
        The label (among ``estimators``) whose estimate steers the planner.
    seed : int or SeedSequence
        The trial's seed: its noise block is ``standard_noise(seed, n_frames · K)``.
    estimate_rng : callable, optional
        ``label → Generator`` for tie-breaking (MATH §7), called afresh for every estimate;
        None gives ``rng=None``.
    planner_rng : Generator, optional
        Passed to the planner (the built-ins are deterministic and do not draw from it).
    assuming : mapping of label to tuple of str, optional
        The unknowns each estimator is fed as known (``MeasurementSet.assuming_known``,
        MATH §15, §8); none by default.

    Returns
    -------
    ClosedLoopTrial
    """
    labels = [label for label, _ in estimators]
    if len(set(labels)) != len(labels):
        raise ValueError(f"estimators: labels must be distinct, got {labels}")
    if steering not in labels:
        raise ValueError(
            f"steering: {steering!r} is not among the estimators ({', '.join(labels)}); "
            "name one of their labels"
        )
    total = scenario.flight.n_frames if n_frames is None else int(n_frames)
    if total < 1:
        raise ValueError(f"n_frames: must be >= 1, got {n_frames!r}")
    first = scenario.flight.with_n_frames(1)
    draws = standard_noise(seed, total * first.samples_per_frame)

    def rng_for(label: str) -> np.random.Generator | None:
        return None if estimate_rng is None else estimate_rng(label)

    streams = {
        label: Stream(estimator)
        for label, estimator in estimators
        if capabilities_of(estimator).sequential
    }
    results: dict[str, list[tuple[Estimate, float]]] = {label: [] for label in labels}
    plans: list[Plan | None] = [None]
    flight = first
    data = measure_flight(scenario, flight, snr_db=snr_db, draws=draws)
    for frame in range(total):
        if frame > 0:
            data = measure_flight(scenario, flight, snr_db=snr_db, draws=draws)
        seen = data.without_truth()
        for label, estimator in estimators:
            assumed = (assuming or {}).get(label, ())
            fed = seen.assuming_known(assumed) if assumed else seen
            if label in streams:
                newest = fed.take(fed.frame == frame)
                results[label].append(streams[label].step(newest, rng_for(label)))
            else:
                results[label].append(call_estimate(estimator, fed, rng=rng_for(label)))
        if frame == total - 1:
            break
        steering_estimate = results[steering][-1][0]
        plan = _plan_next(planner, flight, private_copy(seen), steering_estimate, planner_rng)
        plans.append(plan)
        flight = flight.with_frame(plan.velocity_mps)
    return ClosedLoopTrial(
        flight=flight,
        data=data,
        estimates={label: tuple(values) for label, values in results.items()},
        plans=tuple(plans),
    )


def _plan_next(
    planner: Planner,
    flight: FlightPlan,
    data: MeasurementSet,
    estimate: Estimate,
    rng: np.random.Generator | None,
) -> Plan:
    """The planner's next velocity, or the last velocity held with the reason (a fallback)."""
    name = str(getattr(planner, "name", type(planner).__name__))
    old = np.array(flight.frame_velocities_mps[-1], dtype=float)
    if not estimate.success or not np.all(np.isfinite(estimate.position_m)):
        reason = f"the steering estimate failed ({estimate.message})"
        return Plan(planner=name, velocity_mps=old, message=HOLD_PREFIX + reason)
    try:
        plan = planner.plan(
            flight,
            steering_candidates_m(estimate),
            data,
            covariance_m2=estimate.covariance_m2,
            rng=rng,
        )
    except ValueError as error:
        return Plan(planner=name, velocity_mps=old, message=HOLD_PREFIX + str(error))
    if not isinstance(plan, Plan):
        raise TypeError(f"planner {name!r} returned {type(plan).__name__}, not a Plan")
    return plan


def plan_next_velocity(data: MeasurementSet, planner: Any, estimator: Any, *, rng: Any) -> Any:
    """``(plan, estimate, flight)``: estimate on ``data``, then plan the next frame.

    The flight is :func:`scenarios.planners.flight_from_measurements`; the planner gets the
    estimate's candidates with the returned position first, and its covariance. Both run
    with their prints on stderr and the process put back after
    (:func:`comparison.estimator_calls.kept_process`).

    Raises
    ------
    ValueError
        When the estimator fails (the planner needs a position), or from the planner.
    """
    from scenarios.planners import flight_from_measurements

    flight = flight_from_measurements(data)
    with kept_process():
        estimate = estimator.estimate(data.without_truth(), rng=rng)
    if not estimate.success:
        raise ValueError(
            f"estimator: {estimator.name!r} failed ({estimate.message}); the planner needs a "
            "position: choose another estimator or fly more frames"
        )
    with kept_process():
        plan = planner.plan(
            flight,
            steering_candidates_m(estimate),
            data.without_truth(),
            covariance_m2=estimate.covariance_m2,
        )
    return plan, estimate, flight


def next_frame_plan(
    data: MeasurementSet, planner: Any, estimator: Any, *, rng: Any
) -> dict[str, Any]:
    """What `emitterbench fly` reports: the plan, the flight so far and the estimate.

    ``plan.to_dict()`` plus ``flight`` (frames, K, Δ, where the next frame starts) and
    ``estimate`` (:func:`comparison.scoring.estimate_to_dict`).
    """
    from comparison.scoring import estimate_to_dict

    plan, estimate, flight = plan_next_velocity(data, planner, estimator, rng=rng)
    return {
        **plan.to_dict(),
        "flight": {
            "frames": flight.n_frames,
            "samples_per_frame": flight.samples_per_frame,
            "sample_interval_s": flight.sample_interval_s,
            "next_frame_start_m": (
                flight.sample_positions_m()[-1]
                + flight.sample_interval_s * flight.frame_velocities_mps[-1]
            ).tolist(),
        },
        "estimate": estimate_to_dict(estimate, data.truth_emitter_m),
    }
