"""The Monte Carlo engine: run an :class:`~comparison.experiment.Experiment` into a run folder.

A run folder ``DIR`` holds ``experiment.json`` (the experiment, exact), ``run.json`` (versions,
a digest of the code, machine, seed, start and end times, workers; one entry per session in
``sessions``) and ``results.sqlite`` with the tables ``trials`` (one row per scenario × point ×
planner × estimator × frame × trial, primary key in that order; the planner is empty in an
open-loop experiment), ``points`` (truth and CRLB per scenario × point × frame, MATH §8, of the
scenario's own flight: in a closed loop that of the ``constant`` planner), ``flights``
(closed loop only: the velocity and start of every frame flown, per planner and trial) and
``tasks`` (wall time of every task). :func:`read_trials`, :func:`read_points` and
:func:`read_flights` return them as tidy pandas frames with the columns of the contract in
:mod:`comparison.metrics`; ``runtime_s`` is the only column that is not a function of the
experiment.

Seeds
    The data of (scenario index ``i``, point ``p``, trial ``t``) come from
    ``SeedSequence(seed, spawn_key=(i, p, t))``: every estimator sees the same data there
    (common random numbers), and no row depends on the number of workers, their order, the
    chunking, or the number of trials asked (more trials extend a run, never change it).
    Estimator ``L`` breaks ties (MATH §7) with
    ``default_rng(SeedSequence(seed, spawn_key=(i, p, t, 1 + crc32(L))))``, a fresh generator
    for every estimate (so with ``per_frame`` the last frame's row equals the row of a run
    without it). In a closed loop the noise block of the trial is drawn the same way (so every
    planner meets the same noise, and ``constant`` reproduces the open-loop data) and planner
    ``P`` gets the generator of the label ``"planner:" + P``.

Tasks
    A task is a chunk of ``chunk_size`` trials of one (scenario, point). It simulates the chunk
    once (:func:`scenarios.simulate.simulate_trials`) and runs every estimator on every trial; an
    estimator with ``estimate_batch`` gets the whole chunk, and falls back to one call per trial
    if the batch call raises, so that a row never depends on its neighbours. With
    ``per_frame`` every estimator runs on ``data.up_to_frame(l)`` for every frame ``l``;
    sequential estimators (``init``/``update``/``estimate_state``) are streamed frame by frame
    instead. A closed-loop task flies every trial once per planner
    (:func:`comparison.closed_loop.fly_closed_loop`), and each row carries the CRLB of the
    trajectory that trial flew; its wrong side is judged against the track of the first frame
    the estimator uses (:func:`_ambiguity_track`), the mirror ambiguity a turn must resolve.
    An exception inside an estimator becomes a failed row (``success`` false, the exception in
    ``message``); configuration errors are caught when the experiment loads.

Execution
    Local processes through joblib/loky by default (``workers`` defaults to
    ``os.cpu_count()``), ``workers=1`` in-process, or a dask cluster with
    ``scheduler="tcp://HOST:PORT"`` (``pip install 'emitterbench[cluster]'``; the workers need
    emitterbench installed too). The main process writes each task's rows in one SQLite
    transaction (WAL mode) as the task finishes, so a run killed at any moment loses at most
    the tasks in flight; ``resume=True`` runs only the missing trials and ends with exactly the
    rows of an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import platform
import socket
import sqlite3
import sys
import time
import warnings
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import ExitStack, closing
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from comparison.closed_loop import ClosedLoopTrial, fly_closed_loop, timed_call
from comparison.crlb import fisher_information_per_frame, rmse_bound_m
from comparison.experiment import EstimatorSpec, Experiment, PlannerSpec
from comparison.metrics import TRIAL_COLUMNS  # the row contract; swept columns follow snr_db
from estimators.base import Estimate, Estimator, capabilities_of
from scenarios.measurement_model import slant_range_m
from scenarios.planners import Planner
from scenarios.simulate import noise_free, simulate_trials
from scenarios.types import MeasurementBatch, MeasurementSet, Scenario

EXPERIMENT_FILE = "experiment.json"
RUN_FILE = "run.json"
RESULTS_FILE = "results.sqlite"

POINT_CRLB_SETS: dict[str, tuple[str, ...]] = {
    "crlb_rmse_toa_m": ("toa",),
    "crlb_rmse_doppler_m": ("doppler",),
    "crlb_rmse_rss_m": ("rss",),
    "crlb_rmse_toa_doppler_m": ("toa", "doppler"),
    "crlb_rmse_all_m": ("toa", "doppler", "rss"),
}
"""The CRLB columns of the points table and the modalities of each (MATH §8)."""


# Columns a worker fills for each estimate, in this order.
_ESTIMATE_COLUMNS = (
    "x_m",
    "y_m",
    "error_m",
    "error_side_resolved_m",
    "wrong_side",
    "ambiguous",
    "success",
    "n_candidates",
    "candidates_json",
    "cov_xx_m2",
    "cov_xy_m2",
    "cov_yy_m2",
    "nees",
    "nees_side_resolved",
    "runtime_s",
    "message",
    "diagnostics_json",
)
_CRLB_AT = _ESTIMATE_COLUMNS.index("runtime_s")  # crlb_rmse_m is stored before runtime_s
_KEY_COLUMNS = ("scenario", "point", "planner", "estimator", "frame", "trial")
_TABLE_COLUMNS = (
    *_KEY_COLUMNS,
    "scenario_index",
    "planner_index",
    "estimator_index",
    *_ESTIMATE_COLUMNS[:_CRLB_AT],
    "crlb_rmse_m",
    *_ESTIMATE_COLUMNS[_CRLB_AT:],
)
_FLOAT_COLUMNS = frozenset(
    {
        "snr_db",
        "truth_x_m",
        "truth_y_m",
        "x_m",
        "y_m",
        "error_m",
        "error_side_resolved_m",
        "wrong_side",
        "cov_xx_m2",
        "cov_xy_m2",
        "cov_yy_m2",
        "nees",
        "nees_side_resolved",
        "crlb_rmse_m",
        "runtime_s",
        "range_scale_m",
        *POINT_CRLB_SETS,
    }
)
_INT_COLUMNS = frozenset({"point", "frame", "trial", "n_candidates"})
_BOOL_COLUMNS = frozenset({"ambiguous", "success"})

FLIGHT_COLUMNS: tuple[str, ...] = (
    "scenario",
    "point",
    "planner",
    "trial",
    "frame",
    "start_x_m",
    "start_y_m",
    "start_z_m",
    "end_x_m",
    "end_y_m",
    "end_z_m",
    "vx_mps",
    "vy_mps",
    "vz_mps",
    "message",
    "diagnostics_json",
)
"""Columns of :func:`read_flights`: frame ``frame``'s first and last samples and velocity, and
the plan message that chose it (frame 0 is the scenario's own)."""


# --------------------------------------------------------------------------------------------
# seeds
# --------------------------------------------------------------------------------------------


def trial_seed(seed: int, scenario_index: int, point: int, trial: int) -> np.random.SeedSequence:
    """The seed of the data of one (scenario, point, trial): ``spawn_key=(i, p, t)``."""
    return np.random.SeedSequence(seed, spawn_key=(scenario_index, point, trial))


def tie_rng(
    seed: int, scenario_index: int, point: int, trial: int, label: str
) -> np.random.Generator:
    """The tie-breaking generator of estimator ``label`` at one (scenario, point, trial)."""
    key = (scenario_index, point, trial, 1 + zlib.crc32(label.encode()))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# --------------------------------------------------------------------------------------------
# tasks (run in the workers)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Task:
    """Trials of one (scenario, point) and everything a worker needs to run them."""

    seed: int
    scenario_index: int
    point: int
    scenario: Scenario
    snr_db: float
    trials: tuple[int, ...]
    estimators: tuple[EstimatorSpec, ...]
    per_frame: bool
    planners: tuple[PlannerSpec, ...] = ()
    steering: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskResult:
    """A task's rows, ``(planner_index, estimator_index, frame, trial, crlb, *estimate
    columns)`` each (``crlb`` None when the main process adds it), and its flights rows."""

    scenario_index: int
    point: int
    trials: tuple[int, ...]
    rows: list[tuple[Any, ...]]
    elapsed_s: float
    flights: list[tuple[Any, ...]] = dataclasses.field(default_factory=list)


@functools.lru_cache(maxsize=128)
def _estimator_of(spec: EstimatorSpec) -> Estimator:
    """One estimator object per spec and process (estimators are immutable)."""
    return spec.build()


def run_task(task: Task) -> TaskResult:
    """Simulate the task's trials and run every estimator on each; never raises for an estimator.

    Returns
    -------
    TaskResult
        Rows without the CRLB column, which the main process adds (a closed-loop task, with
        planners, is :func:`run_closed_loop_task`: its rows carry their own bounds).
    """
    if task.planners:
        return run_closed_loop_task(task)
    start = time.perf_counter()
    seeds = [trial_seed(task.seed, task.scenario_index, task.point, t) for t in task.trials]
    simulated = simulate_trials(task.scenario, snr_db=task.snr_db, seeds=seeds)
    # estimators never see the truth
    batch = dataclasses.replace(simulated, geometry=simulated.geometry.without_truth())
    truth = np.asarray(task.scenario.emitter_m, dtype=float)
    frames = [int(f) for f in batch.geometry.frames]
    eval_frames = frames if task.per_frame else frames[-1:]
    tracks = {frame: _frame_track(batch.geometry, frame) for frame in eval_frames}
    data = _TaskData(batch)
    rows: list[tuple[Any, ...]] = []
    for index, spec in enumerate(task.estimators):
        estimator = _estimator_of(spec)
        results = _run_estimator(estimator, spec.label, task, data, eval_frames)
        for (frame, position), (estimate, runtime_s) in results.items():
            trial = task.trials[position]
            values = estimate_columns(estimate, truth, tracks[frame], runtime_s)
            rows.append((0, index, frame, trial, None, *values))
    return TaskResult(
        scenario_index=task.scenario_index,
        point=task.point,
        trials=task.trials,
        rows=rows,
        elapsed_s=time.perf_counter() - start,
    )


@functools.lru_cache(maxsize=32)
def _planner_of(spec: PlannerSpec) -> Planner:
    """One planner object per spec and process (planners are immutable)."""
    return spec.build()


def run_closed_loop_task(task: Task) -> TaskResult:
    """Fly the task's trials once per planner (:mod:`comparison.closed_loop`) and score them.

    Every row carries ``crlb_rmse_m`` of the trajectory its trial flew, at the truth, for the
    estimator's modalities and frames (MATH §8).
    """
    start = time.perf_counter()
    truth = np.asarray(task.scenario.emitter_m, dtype=float)
    estimators = [(spec.label, _estimator_of(spec)) for spec in task.estimators]
    crlb_keys = [_crlb_key(estimator) for _, estimator in estimators]
    rows: list[tuple[Any, ...]] = []
    flights: list[tuple[Any, ...]] = []
    for planner_index, planner_spec in enumerate(task.planners):
        planner = _planner_of(planner_spec)
        for trial in task.trials:
            key = (task.scenario_index, task.point, trial)
            flown = fly_closed_loop(
                task.scenario,
                snr_db=task.snr_db,
                planner=planner,
                estimators=estimators,
                steering=task.steering[planner_index],
                seed=trial_seed(task.seed, *key),
                estimate_rng=lambda label, key=key: tie_rng(task.seed, *key, label),
                planner_rng=tie_rng(task.seed, *key, f"planner:{planner_spec.label}"),
            )
            information = _trial_information(flown.data, truth, {m for m, _ in crlb_keys})
            for frame in range(flown.n_frames):
                for index, (label, _) in enumerate(estimators):
                    estimate, runtime_s = flown.estimates[label][frame]
                    modalities, frames = crlb_keys[index]
                    track = _ambiguity_track(flown.data, frame, frames)
                    bound = _bound_of(information.get(modalities), frame, frames)
                    values = estimate_columns(estimate, truth, track, runtime_s)
                    rows.append((planner_index, index, frame, trial, bound, *values))
            flights.extend(_flight_rows(planner_index, trial, flown))
    return TaskResult(
        scenario_index=task.scenario_index,
        point=task.point,
        trials=task.trials,
        rows=rows,
        elapsed_s=time.perf_counter() - start,
        flights=flights,
    )


def _ambiguity_track(
    data: MeasurementSet, frame: int, frames: Any
) -> tuple[np.ndarray, np.ndarray] | None:
    """The track whose mirror ambiguity an estimator faces at ``frame`` (closed loop, MATH §7).

    The first frame the estimator uses: ``frame`` itself for ``frames="last"``, frame 0 for
    ``"all"``, the first listed frame up to ``frame`` otherwise. A cumulative estimator's side
    is judged against the first track, the ambiguity a turn must resolve: the side of a later
    track is ill-defined when a planner flies through the emitter's horizontal position (the
    truth then lies within centimetres of that track's plane).
    """
    if isinstance(frames, str) and frames == "last":
        first = frame
    elif isinstance(frames, Sequence) and not isinstance(frames, str):
        chosen = [int(f) for f in frames if 0 <= int(f) <= frame]
        if not chosen:
            return None
        first = min(chosen)
    else:
        first = 0
    return _frame_track(data, first)


def _trial_information(
    data: MeasurementSet, truth: np.ndarray, needed: Iterable[tuple[str, ...]]
) -> dict[tuple[str, ...], tuple[np.ndarray, np.ndarray] | None]:
    """Per-frame and accumulated Fisher information of one flown trial at the truth."""
    information: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray] | None] = {}
    for modalities in needed:
        try:
            information[modalities] = fisher_information_per_frame(data, truth, modalities)
        except ValueError:  # a σ or the RSS model is absent: no bound
            information[modalities] = None
    return information


def _flight_rows(planner_index: int, trial: int, flown: ClosedLoopTrial) -> list[tuple[Any, ...]]:
    """``(planner_index, trial, frame, start xyz, end xyz, velocity xyz, message,
    diagnostics)`` rows."""
    positions = flown.flight.sample_positions_m()
    k = flown.flight.samples_per_frame
    out = []
    for frame, (begin, end, velocity) in enumerate(
        zip(positions[::k], positions[k - 1 :: k], flown.flight.frame_velocities_mps, strict=True)
    ):
        plan = flown.plans[frame]
        message = "the scenario's initial velocity" if plan is None else plan.message
        diagnostics = {} if plan is None else dict(plan.diagnostics)
        out.append(
            (
                planner_index,
                trial,
                frame,
                *(float(v) for v in begin),
                *(float(v) for v in end),
                *(float(v) for v in velocity),
                message,
                json.dumps(_jsonable(diagnostics), sort_keys=True),
            )
        )
    return out


class _TaskData:
    """The task's data up to each evaluated frame, as a batch and as per-trial sets (cached)."""

    def __init__(self, batch: MeasurementBatch) -> None:
        self.full = batch
        self.final_frame = int(batch.geometry.frames[-1])
        self._batches: dict[int, MeasurementBatch] = {}
        self._trials: dict[int, list[MeasurementSet]] = {}

    def batch(self, frame: int) -> MeasurementBatch:
        if frame not in self._batches:
            self._batches[frame] = (
                self.full if frame == self.final_frame else _batch_up_to_frame(self.full, frame)
            )
        return self._batches[frame]

    def trials(self, frame: int) -> list[MeasurementSet]:
        if frame not in self._trials:
            self._trials[frame] = list(self.batch(frame))
        return self._trials[frame]


def _run_estimator(
    estimator: Estimator,
    label: str,
    task: Task,
    data: _TaskData,
    eval_frames: list[int],
) -> dict[tuple[int, int], tuple[Estimate, float]]:
    """``{(frame, trial position): (estimate, runtime_s)}`` for one estimator on one task."""

    def rngs() -> list[np.random.Generator]:
        return [tie_rng(task.seed, task.scenario_index, task.point, t, label) for t in task.trials]

    out: dict[tuple[int, int], tuple[Estimate, float]] = {}
    capabilities = capabilities_of(estimator)
    if task.per_frame and capabilities.sequential:
        for position, trial_data in enumerate(data.trials(data.final_frame)):
            trial = task.trials[position]

            def make_rng(trial: int = trial) -> np.random.Generator:
                return tie_rng(task.seed, task.scenario_index, task.point, trial, label)

            out.update(_stream(estimator, trial_data, eval_frames, position, make_rng))
        return out
    for frame in eval_frames:
        estimates = (
            _call_batch(estimator, data.batch(frame), rngs()) if capabilities.batch else None
        )
        if estimates is None:
            estimates = [
                timed_call(estimator.estimate, trial_data, rng=rng)
                for trial_data, rng in zip(data.trials(frame), rngs(), strict=True)
            ]
        for position, result in enumerate(estimates):
            out[(frame, position)] = result
    return out


def _call_batch(
    estimator: Estimator, batch: MeasurementBatch, rngs: list[np.random.Generator]
) -> list[tuple[Estimate, float]] | None:
    """``estimate_batch`` timed and split evenly, or None (it failed)."""
    start = time.perf_counter()
    try:
        estimates = list(estimator.estimate_batch(batch, rngs=rngs))
    except Exception:
        return None  # retried one trial at a time, so each row gets its own outcome
    runtime_s = (time.perf_counter() - start) / batch.n_trials
    if len(estimates) != batch.n_trials or not all(isinstance(e, Estimate) for e in estimates):
        return None
    return [(estimate, runtime_s) for estimate in estimates]


def _stream(
    estimator: Any,
    data: MeasurementSet,
    eval_frames: list[int],
    position: int,
    make_rng: Any,
) -> dict[tuple[int, int], tuple[Estimate, float]]:
    """A sequential estimator fed frame by frame (``init``, then ``update`` per frame).

    ``estimate_state`` gets a fresh tie-breaking ``rng=make_rng()``. A
    failed ``update`` fails that frame and every later one (the state is lost); a failed
    ``estimate_state`` fails only its frame. ``init``'s time is counted in the first frame.
    """
    out: dict[tuple[int, int], tuple[Estimate, float]] = {}
    start = time.perf_counter()
    failure: Estimate | None = None
    try:
        state = estimator.init()
    except Exception as error:
        failure = Estimate.failed("", f"{type(error).__name__} in init: {error}")
    carried_s = time.perf_counter() - start
    for frame in eval_frames:
        if failure is not None:
            out[(frame, position)] = (failure, carried_s)
            carried_s = 0.0
            continue
        start = time.perf_counter()
        try:
            state = estimator.update(state, data.take(data.frame == frame))
        except Exception as error:
            failure = Estimate.failed("", f"{type(error).__name__} in update: {error}")
            carried_s += time.perf_counter() - start
            out[(frame, position)] = (failure, carried_s)
            carried_s = 0.0
            continue
        update_s = time.perf_counter() - start
        estimate, estimate_s = timed_call(estimator.estimate_state, state, rng=make_rng())
        out[(frame, position)] = (estimate, carried_s + update_s + estimate_s)
        carried_s = 0.0
    return out


def _batch_up_to_frame(batch: MeasurementBatch, frame: int) -> MeasurementBatch:
    """The samples of frames ``<= frame`` of every trial."""
    mask = batch.geometry.frame <= frame
    return MeasurementBatch(
        geometry=batch.geometry.take(mask),
        doppler_hz=None if batch.doppler_hz is None else batch.doppler_hz[:, mask],
        toa_s=None if batch.toa_s is None else batch.toa_s[:, mask],
        rss_dbm=None if batch.rss_dbm is None else batch.rss_dbm[:, mask],
    )


def _frame_track(geometry: MeasurementSet, frame: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A point and the horizontal unit direction of ``frame``'s track, or None when hovering."""
    first = int(np.argmax(geometry.frame == frame))
    velocity = np.asarray(geometry.velocity_mps[first, :2], dtype=float)
    speed = float(np.hypot(*velocity))
    if speed == 0.0:
        return None
    return np.asarray(geometry.position_m[first, :2], dtype=float), velocity / speed


def estimate_columns(
    estimate: Estimate,
    truth_m: np.ndarray,
    track: tuple[np.ndarray, np.ndarray] | None,
    runtime_s: float,
) -> tuple[Any, ...]:
    """The per-estimate columns of a trial row (see the module docstring of the contract).

    ``error_side_resolved_m`` uses the candidate nearest to the truth (MATH §7). ``nees`` is
    the returned position's error against the estimator's covariance; ``nees_side_resolved``
    the nearest candidate's error against *that candidate's* covariance: the covariance
    reflected across ``track`` when the candidate lies on the other side of it than the
    returned position (its mirror image, MATH §7), else the covariance as given.
    ``wrong_side`` is 1.0 when the returned position and the truth are strictly on opposite
    sides of the vertical plane through ``track``, NaN when the position lies in that plane (on
    neither side). Every error column is NaN for a failed estimate.
    """
    nan = math.nan
    success = bool(estimate.success)
    truth = np.asarray(truth_m, dtype=float)[:2]
    position = np.asarray(estimate.position_m, dtype=float) if success else np.full(2, nan)
    candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    error_m = float(np.hypot(*(position - truth)))
    side_resolved_m, nearest = nan, position
    if success:
        pool = candidates if len(candidates) else position[None, :]
        distances = np.hypot(*(pool - truth).T)
        if np.isfinite(distances).any():
            nearest = pool[int(np.nanargmin(distances))]
            side_resolved_m = float(np.nanmin(distances))
    side_of = _signed_cross_track(track)
    wrong_side = nan
    if success and track is not None and np.isfinite(position).all():
        side_estimate, side_truth = side_of(position), side_of(truth)
        scale = max(abs(side_truth), float(np.hypot(*(position - track[0]))))
        on_plane = abs(side_estimate) <= 1e-9 * scale
        # an estimate in the track's vertical plane is on neither side: NaN, not a lucky 0
        wrong_side = nan if on_plane else (1.0 if side_estimate * side_truth < 0.0 else 0.0)
    cov = (nan, nan, nan)
    nees = nees_side_resolved = nan
    if estimate.covariance_m2 is not None:
        covariance = np.asarray(estimate.covariance_m2, dtype=float)
        cov = (float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1]))
        nees = normalized_error_squared(position - truth, covariance)
        if track is not None and side_of(nearest) * side_of(position) < 0.0:
            covariance = mirrored_covariance(covariance, track[1])
        nees_side_resolved = normalized_error_squared(nearest - truth, covariance)
    return (
        float(position[0]),
        float(position[1]),
        error_m,
        side_resolved_m,
        wrong_side,
        bool(estimate.ambiguous),
        success,
        len(candidates),
        json.dumps(_jsonable(candidates.tolist())),
        *cov,
        nees,
        nees_side_resolved,
        float(runtime_s),
        str(estimate.message),
        json.dumps(_jsonable(dict(estimate.diagnostics)), sort_keys=True),
    )


def _signed_cross_track(track: tuple[np.ndarray, np.ndarray] | None) -> Any:
    """``point ↦`` signed distance from the vertical plane through ``track`` (0 without one)."""
    if track is None:
        return lambda point: 0.0
    (ox, oy), (dx, dy) = track
    return lambda point: float(dx * (point[1] - oy) - dy * (point[0] - ox))


def mirrored_covariance(covariance_m2: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """``R P Rᵀ`` with ``R = 2 d dᵀ − I`` the reflection across a line of unit direction ``d``:
    the covariance of the mirror image of an estimate (MATH §7)."""
    d = np.asarray(direction, dtype=float).reshape(2)
    reflection = 2.0 * np.outer(d, d) - np.eye(2)
    return reflection @ covariance_m2 @ reflection.T


def normalized_error_squared(error_m: np.ndarray, covariance_m2: np.ndarray) -> float:
    """``eᵀ P⁻¹ e`` (NEES, 2 degrees of freedom); NaN when ``P`` is singular or not finite."""
    (a, b), (c, d) = covariance_m2
    det = a * d - b * c
    if not (math.isfinite(det) and det != 0.0) or not np.isfinite(error_m).all():
        return math.nan
    ex, ey = (float(v) for v in error_m)
    # eᵀ P⁻¹ e with the 2×2 inverse [[d, −b], [−c, a]] / det
    return float((ex * (d * ex - b * ey) + ey * (a * ey - c * ex)) / det)


def _jsonable(value: Any) -> Any:
    """JSON-ready: arrays to lists, numpy scalars to Python, non-finite floats to null."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


# --------------------------------------------------------------------------------------------
# the points table (main process)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _PointInfo:
    """One (scenario, point): its scenario, SNR, settings and Fisher information by modality."""

    scenario: Scenario
    snr_db: float
    settings: dict[str, float]
    information: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray] | None]

    @property
    def n_frames(self) -> int:
        return self.scenario.flight.n_frames

    def rmse_bound_m(self, modalities: tuple[str, ...], frame: int, frames: Any = "all") -> float:
        """√trace(CRLB) of ``modalities`` over the frames an estimator uses up to ``frame``."""
        return _bound_of(self.information.get(modalities), frame, frames)


def _bound_of(info: tuple[np.ndarray, np.ndarray] | None, frame: int, frames: Any = "all") -> float:
    """√trace(CRLB) from ``(per_frame, accumulated)`` information over the frames an
    estimator uses up to ``frame`` (``"all"``, ``"last"`` or listed frames; MATH §8)."""
    if info is None:
        return math.nan
    per_frame, accumulated = info
    if isinstance(frames, str) and frames == "last":
        information = per_frame[frame]
    elif isinstance(frames, Sequence) and not isinstance(frames, str):
        chosen = [f for f in frames if 0 <= int(f) <= frame]
        if not chosen:
            return math.nan
        information = per_frame[np.asarray(chosen, dtype=int)].sum(axis=0)
    else:
        information = accumulated[frame]
    return float(rmse_bound_m(information))


def _modality_key(modalities: Iterable[str]) -> tuple[str, ...]:
    return tuple(m for m in ("toa", "doppler", "rss") if m in set(modalities))


def _crlb_key(estimator: Estimator) -> tuple[tuple[str, ...], Any]:
    """The modalities and frames an estimator declares it uses: its bound's key (MATH §8)."""
    capabilities = capabilities_of(estimator)
    return _modality_key(capabilities.modalities), capabilities.frames


def _point_infos(experiment: Experiment) -> dict[tuple[int, int], _PointInfo]:
    """Fisher information per frame at the truth, for every modality set needed (MATH §8)."""
    needed = {_modality_key(m) for m in POINT_CRLB_SETS.values()}
    for spec in experiment.estimators:
        needed.add(_crlb_key(_estimator_of(spec))[0])
    infos = {}
    for i in range(len(experiment.scenarios)):
        for p, settings in enumerate(experiment.sweep.points()):
            scenario, snr_db = experiment.point_scenario(i, p)
            data = noise_free(scenario, snr_db=snr_db)
            information: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray] | None] = {}
            for modalities in sorted(needed):
                try:
                    information[modalities] = fisher_information_per_frame(
                        data, scenario.emitter_m, modalities
                    )
                except ValueError:  # a σ or the RSS model is absent: no bound
                    information[modalities] = None
            infos[(i, p)] = _PointInfo(
                scenario=scenario, snr_db=snr_db, settings=settings, information=information
            )
    return infos


# --------------------------------------------------------------------------------------------
# the results database
# --------------------------------------------------------------------------------------------


def _quote(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _connect(path: Path) -> sqlite3.Connection:
    connection = sqlite3.connect(path, timeout=60.0)
    connection.execute("PRAGMA journal_mode=WAL")
    connection.execute("PRAGMA synchronous=NORMAL")
    return connection


def _create_tables(connection: sqlite3.Connection, experiment: Experiment) -> None:
    real = {"x_m", "y_m", "error_m", "error_side_resolved_m", "wrong_side"}
    real |= {"cov_xx_m2", "cov_xy_m2", "cov_yy_m2", "nees", "nees_side_resolved"}
    real |= {"crlb_rmse_m", "runtime_s"}
    types = {
        "scenario": "TEXT",
        "planner": "TEXT NOT NULL DEFAULT ''",
        "planner_index": "INTEGER NOT NULL DEFAULT 0",
        "estimator": "TEXT",
        "candidates_json": "TEXT",
        "message": "TEXT",
        "diagnostics_json": "TEXT",
        **dict.fromkeys(real, "REAL"),
    }
    trial_columns = ", ".join(f"{c} {types.get(c, 'INTEGER')} " for c in _TABLE_COLUMNS)
    swept = "".join(f"{_quote(c)} REAL, " for c in experiment.swept_columns)
    crlb = ", ".join(f"{c} REAL" for c in POINT_CRLB_SETS)
    with connection:
        connection.execute(
            f"CREATE TABLE IF NOT EXISTS trials ({trial_columns}, "
            f"PRIMARY KEY ({', '.join(_KEY_COLUMNS)})) WITHOUT ROWID"
        )
        connection.execute(
            "CREATE TABLE IF NOT EXISTS points (scenario TEXT, point INTEGER, frame INTEGER, "
            f"scenario_index INTEGER, snr_db REAL, {swept}truth_x_m REAL, truth_y_m REAL, "
            f"range_scale_m REAL, {crlb}, PRIMARY KEY (scenario, point, frame)) WITHOUT ROWID"
        )
        connection.execute(
            "CREATE TABLE IF NOT EXISTS tasks (scenario TEXT, point INTEGER, "
            "first_trial INTEGER, n_trials INTEGER, elapsed_s REAL, finished_utc TEXT)"
        )
        connection.execute(
            "CREATE TABLE IF NOT EXISTS flights (scenario TEXT, point INTEGER, planner TEXT, "
            "trial INTEGER, frame INTEGER, scenario_index INTEGER, planner_index INTEGER, "
            "start_x_m REAL, start_y_m REAL, start_z_m REAL, end_x_m REAL, end_y_m REAL, "
            "end_z_m REAL, vx_mps REAL, vy_mps REAL, "
            "vz_mps REAL, message TEXT, diagnostics_json TEXT, "
            "PRIMARY KEY (scenario, point, planner, trial, frame)) WITHOUT ROWID"
        )
        # a results file written before planners or the side-resolved NEES existed
        present = {row[1] for row in connection.execute("PRAGMA table_info(trials)")}
        for column in ("planner", "planner_index", "nees_side_resolved"):
            if column not in present:
                connection.execute(f"ALTER TABLE trials ADD COLUMN {column} {types[column]}")
        present = {row[1] for row in connection.execute("PRAGMA table_info(points)")}
        if "range_scale_m" not in present:
            connection.execute("ALTER TABLE points ADD COLUMN range_scale_m REAL")


def _write_points(
    connection: sqlite3.Connection,
    experiment: Experiment,
    infos: Mapping[tuple[int, int], _PointInfo],
) -> None:
    columns = [
        "scenario",
        "point",
        "frame",
        "scenario_index",
        "snr_db",
        *experiment.swept_columns,
        "truth_x_m",
        "truth_y_m",
        "range_scale_m",
        *POINT_CRLB_SETS,
    ]
    rows = []
    for (i, p), info in infos.items():
        swept = [info.settings[c] for c in experiment.swept_columns]
        truth = [float(v) for v in info.scenario.emitter_m]
        flight = info.scenario.flight
        squared_range = (
            slant_range_m(flight.sample_positions_m(), truth, info.scenario.emitter_height_m) ** 2
        )
        for frame in range(info.n_frames):
            bounds = [info.rmse_bound_m(_modality_key(m), frame) for m in POINT_CRLB_SETS.values()]
            scale = math.sqrt(float(np.mean(squared_range[flight.sample_frames() <= frame])))
            rows.append(
                (experiment.scenarios[i], p, frame, i, info.snr_db, *swept, *truth, scale, *bounds)
            )
    marks = ", ".join("?" * len(columns))
    with connection:
        connection.execute("DELETE FROM points")
        connection.executemany(
            f"INSERT INTO points ({', '.join(map(_quote, columns))}) VALUES ({marks})", rows
        )


def _complete_trials(
    connection: sqlite3.Connection, experiment: Experiment, infos: Mapping[tuple[int, int], Any]
) -> dict[tuple[int, int], set[int]]:
    """The trials of each (scenario, point) whose rows are all in the database."""
    n_estimators = len(experiment.estimators) * max(len(experiment.planners), 1)
    complete: dict[tuple[int, int], set[int]] = {key: set() for key in infos}
    query = (
        "SELECT scenario_index, point, trial, COUNT(*) FROM trials "
        "GROUP BY scenario_index, point, trial"
    )
    for i, p, trial, count in connection.execute(query):
        info = infos.get((i, p))
        if info is None:
            continue
        frames = info.n_frames if experiment.per_frame else 1
        if count == n_estimators * frames:
            complete[(i, p)].add(trial)
    return complete


def _write_task(
    connection: sqlite3.Connection,
    experiment: Experiment,
    result: TaskResult,
    info: _PointInfo,
    crlb_frames: Sequence[tuple[tuple[str, ...], Any]],
) -> None:
    """One task's rows and its log entry, in one transaction."""
    scenario = experiment.scenarios[result.scenario_index]
    labels = experiment.labels
    planners = experiment.planner_labels or ("",)
    bounds: dict[tuple[int, int], float] = {}
    rows = []
    for planner_index, estimator_index, frame, trial, bound, *values in result.rows:
        if bound is None:  # open loop: the same flight in every trial
            key = (estimator_index, frame)
            if key not in bounds:
                modalities, frames = crlb_frames[estimator_index]
                bounds[key] = info.rmse_bound_m(modalities, frame, frames)
            bound = bounds[key]
        rows.append(
            (
                scenario,
                result.point,
                planners[planner_index],
                labels[estimator_index],
                frame,
                trial,
                result.scenario_index,
                planner_index,
                estimator_index,
                *values[:_CRLB_AT],
                bound,
                *values[_CRLB_AT:],
            )
        )
    flights = [
        (scenario, result.point, planners[p], trial, frame, result.scenario_index, p, *rest)
        for p, trial, frame, *rest in result.flights
    ]
    marks = ", ".join("?" * len(_TABLE_COLUMNS))
    with connection:
        connection.executemany(
            f"INSERT OR REPLACE INTO trials ({', '.join(_TABLE_COLUMNS)}) VALUES ({marks})", rows
        )
        if flights:
            connection.executemany(
                f"INSERT OR REPLACE INTO flights VALUES ({', '.join('?' * 18)})", flights
            )
        connection.execute(
            "INSERT INTO tasks VALUES (?, ?, ?, ?, ?, ?)",
            (
                scenario,
                result.point,
                min(result.trials),
                len(result.trials),
                result.elapsed_s,
                _now(),
            ),
        )


# --------------------------------------------------------------------------------------------
# the run folder
# --------------------------------------------------------------------------------------------


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _write_text_atomic(path: Path, text: str) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def _prepare_folder(out: Path, experiment: Experiment, resume: bool) -> None:
    """Check the folder against ``resume`` and write ``experiment.json``."""
    existing = out.is_dir() and any(out.iterdir())
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} is a file; choose a folder for the run")
    if existing and not resume:
        raise ValueError(
            f"out_dir: {out} already holds files; pass --resume (resume=True) to continue "
            "that run, or choose another folder"
        )
    if existing:
        stored_path = out / EXPERIMENT_FILE
        if not stored_path.is_file():
            raise ValueError(
                f"out_dir: {out} holds files but no {EXPERIMENT_FILE}, so it is not a run "
                "folder; choose another folder"
            )
        stored = Experiment.from_json(stored_path.read_text())
        mine = {k: v for k, v in experiment.to_dict().items() if k != "trials"}
        theirs = {k: v for k, v in stored.to_dict().items() if k != "trials"}
        if mine != theirs:
            differing = sorted(k for k in mine if mine[k] != theirs.get(k))
            raise ValueError(
                f"resume: the experiment differs from {stored_path} in "
                f"{', '.join(differing)}; resume with the same experiment or choose another "
                "folder"
            )
        if experiment.trials < stored.trials:
            raise ValueError(
                f"trials: the run in {out} has {stored.trials} trials per point; resume with "
                f"at least {stored.trials} (more trials extend the run)"
            )
    out.mkdir(parents=True, exist_ok=True)
    _write_text_atomic(out / EXPERIMENT_FILE, experiment.to_json())


def _versions() -> dict[str, str | None]:
    names = (
        "emitterbench",
        "numpy",
        "scipy",
        "cvxpy",
        "clarabel",
        "gtsam",
        "filterpy",
        "joblib",
        "pandas",
        "rich",
        "dask",
        "distributed",
    )
    found: dict[str, str | None] = {"python": platform.python_version()}
    for name in names:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def code_digest() -> str:
    """SHA-256 of the source of ``scenarios``, ``estimators`` and ``comparison`` (with their
    sub-packages).

    Recorded per session in ``run.json``: rows of sessions with different digests may come
    from different code, which a resume warns about.
    """
    import comparison
    import estimators
    import scenarios

    digest = hashlib.sha256()
    for package in (scenarios, estimators, comparison):
        folder = Path(package.__file__).parent
        for path in sorted(folder.rglob("*.py")):
            digest.update(f"{package.__name__}/{path.relative_to(folder).as_posix()}\n".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def _warn_on_code_change(out: Path, session: Mapping[str, Any]) -> None:
    path = out / RUN_FILE
    if not path.is_file():
        return
    try:
        previous = json.loads(path.read_text()).get("sessions", [])
    except (json.JSONDecodeError, AttributeError):
        return
    digests = {s.get("code_digest") for s in previous if s.get("code_digest")}
    if digests and digests != {session["code_digest"]}:
        warnings.warn(
            f"resume: the code differs from the one that wrote the rows already in {out} "
            "(code_digest in run.json); rows of the two sessions may not be comparable. "
            "Start a new folder to get one consistent run.",
            stacklevel=3,
        )


def _write_run_info(out: Path, session: dict[str, Any]) -> None:
    """``run.json``: the latest session's fields at the top, every session in ``sessions``."""
    path = out / RUN_FILE
    sessions: list[dict[str, Any]] = []
    if path.is_file():
        try:
            sessions = list(json.loads(path.read_text()).get("sessions", []))
        except (json.JSONDecodeError, AttributeError):
            sessions = []
    sessions = [s for s in sessions if s.get("session_id") != session["session_id"]]
    sessions.append(session)
    _write_text_atomic(out / RUN_FILE, json.dumps({**session, "sessions": sessions}, indent=2))


# --------------------------------------------------------------------------------------------
# execution
# --------------------------------------------------------------------------------------------


def _plan_tasks(
    experiment: Experiment,
    infos: Mapping[tuple[int, int], _PointInfo],
    complete: Mapping[tuple[int, int], set[int]],
) -> list[Task]:
    tasks = []
    size = experiment.chunk_size
    for (i, p), info in infos.items():
        done = complete.get((i, p), set())
        for first in range(0, experiment.trials, size):
            trials = tuple(
                t for t in range(first, min(first + size, experiment.trials)) if t not in done
            )
            if trials:
                tasks.append(
                    Task(
                        seed=experiment.seed,
                        scenario_index=i,
                        point=p,
                        scenario=info.scenario,
                        snr_db=info.snr_db,
                        trials=trials,
                        estimators=experiment.estimators,
                        per_frame=experiment.per_frame,
                        planners=experiment.planners,
                        steering=tuple(
                            experiment.steering_label(k) for k in range(len(experiment.planners))
                        ),
                    )
                )
    return tasks


def _connect_scheduler(scheduler: str, stack: ExitStack) -> None:
    """Connect a dask client to ``scheduler`` and route joblib through it, or raise clearly."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError(
            f"scheduler: running on {scheduler} needs dask.distributed; install it with "
            "pip install 'emitterbench[cluster]' (and emitterbench on every worker)"
        ) from None
    from joblib import parallel_config

    try:
        stack.enter_context(Client(scheduler, timeout=30))
    except (OSError, TimeoutError) as error:
        raise ValueError(
            f"scheduler: cannot reach {scheduler} ({error}); start it with "
            "'dask scheduler --port 8786' and workers with 'dask worker tcp://HOST:8786'"
        ) from None
    stack.enter_context(parallel_config(backend="dask"))


def _execute(tasks: list[Task], workers: int, scheduler: str | None) -> Iterator[TaskResult]:
    """Results in completion order: in-process, loky processes, or the connected dask cluster."""
    if not tasks:
        return iter(())
    if scheduler is None and workers == 1:
        return (run_task(task) for task in tasks)
    from joblib import Parallel, delayed

    # with a scheduler, parallel_config(backend="dask") is active and -1 means every worker
    n_jobs = -1 if scheduler is not None else min(workers, len(tasks))
    parallel = Parallel(n_jobs=n_jobs, return_as="generator_unordered")
    return parallel(delayed(run_task)(task) for task in tasks)


def _progress_bar(enabled: bool, stack: ExitStack, *, total: int, completed: int) -> Any:
    if not enabled:
        return None
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
    )
    stack.enter_context(progress)
    task_id = progress.add_task("running", total=total, completed=completed)
    return lambda n: progress.advance(task_id, n)


def run_experiment(
    experiment: Experiment,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    trials: int | None = None,
    progress: bool | None = None,
) -> Path:
    """Run ``experiment`` into the run folder ``out_dir``; return the folder.

    Parameters
    ----------
    experiment : Experiment
    out_dir : path
        The run folder. Must be absent or empty unless ``resume``.
    workers : int, optional
        Local worker processes (default ``os.cpu_count()``); 1 runs in this process.
        Ignored with ``scheduler``.
    scheduler : str, optional
        ``"tcp://HOST:PORT"`` of a dask scheduler: run the tasks on its cluster.
    resume : bool
        Continue the run in ``out_dir``: its ``experiment.json`` must match ``experiment``
        (except ``trials``, which may grow); only missing trials run.
    trials : int, optional
        Trials per point instead of ``experiment.trials``.
    progress : bool or None
        Show a progress bar on stderr; None shows it when stderr is a terminal.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ValueError
        A non-empty folder without ``resume``, a mismatching experiment on resume, bad
        ``workers``, or an unreachable or missing dask scheduler.
    """
    if not isinstance(experiment, Experiment):
        raise ValueError(f"experiment: expected an Experiment, got {type(experiment).__name__}")
    if trials is not None:
        experiment = experiment.with_trials(trials)
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers: expected a whole number >= 1, got {workers!r}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise ValueError(
            f"scheduler: expected an address such as tcp://host:8786, got {scheduler!r}"
        )
    out = Path(out_dir)
    with ExitStack() as stack:
        if scheduler is not None:  # fail before touching the folder
            _connect_scheduler(scheduler, stack)
        _prepare_folder(out, experiment, resume)
        session = _session_info(experiment, workers, scheduler, resume)
        if resume:
            _warn_on_code_change(out, session)
        _write_run_info(out, session)
        start = time.perf_counter()
        infos = _point_infos(experiment)
        crlb_frames = [_crlb_key(_estimator_of(spec)) for spec in experiment.estimators]
        connection = stack.enter_context(closing(_connect(out / RESULTS_FILE)))
        _create_tables(connection, experiment)
        _write_points(connection, experiment, infos)
        complete = _complete_trials(connection, experiment, infos)
        tasks = _plan_tasks(experiment, infos, complete)
        show = sys.stderr.isatty() if progress is None else bool(progress)
        advance = _progress_bar(
            show,
            stack,
            total=experiment.trials * len(infos),
            completed=sum(len(v) for v in complete.values()),
        )
        task_time_s = 0.0
        for result in _execute(tasks, workers, scheduler):
            info = infos[(result.scenario_index, result.point)]
            _write_task(connection, experiment, result, info, crlb_frames)
            task_time_s += result.elapsed_s
            if advance is not None:
                advance(len(result.trials))
    session.update(
        finished_utc=_now(),
        wall_time_s=time.perf_counter() - start,
        tasks_run=len(tasks),
        task_time_s=task_time_s,
    )
    _write_run_info(out, session)
    return out


def _session_info(
    experiment: Experiment, workers: int, scheduler: str | None, resume: bool
) -> dict[str, Any]:
    """The ``run.json`` entry of this session (finished_utc is filled in at the end)."""
    started = _now()
    return {
        "session_id": started,
        "experiment": experiment.name,
        "seed": experiment.seed,
        "trials": experiment.trials,
        "started_utc": started,
        "finished_utc": None,
        "workers": workers if scheduler is None else None,
        "scheduler": scheduler,
        "backend": "dask" if scheduler else ("in-process" if workers == 1 else "loky"),
        "resumed": resume,
        "machine": {
            "hostname": socket.gethostname(),
            "platform": platform.platform(),
            "machine": platform.machine(),
            "cpu_count": os.cpu_count(),
        },
        "versions": _versions(),
        "code_digest": code_digest(),
    }


# --------------------------------------------------------------------------------------------
# reading a run folder
# --------------------------------------------------------------------------------------------


def read_experiment(out_dir: str | os.PathLike[str]) -> Experiment:
    """The experiment of a run folder (its ``experiment.json``)."""
    path = Path(out_dir) / EXPERIMENT_FILE
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; is {out_dir} a run folder?")
    return Experiment.from_json(path.read_text())


def _read_table(out_dir: Path, query: str) -> pd.DataFrame:
    path = out_dir / RESULTS_FILE
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; run the experiment first")
    # a plain connection (query-only) so that closing it removes the empty WAL files
    with closing(sqlite3.connect(path, timeout=60.0)) as connection:
        connection.execute("PRAGMA query_only=ON")
        return pd.read_sql_query(query, connection)


def _fix_types(frame: pd.DataFrame, swept: Sequence[str]) -> pd.DataFrame:
    for column in frame.columns:
        if column in _FLOAT_COLUMNS or column in swept:
            frame[column] = frame[column].astype("float64")
        elif column in _INT_COLUMNS:
            frame[column] = frame[column].astype("int64")
        elif column in _BOOL_COLUMNS:
            frame[column] = frame[column].astype(bool)
    return frame


def read_trials(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """One row per estimator × scenario × point × frame × trial (the contract's columns).

    Sorted by scenario and estimator in the experiment's order, then point, frame and trial
    (``scenario, point, estimator, frame, trial``). NaN marks what a failed estimate or a
    missing covariance cannot give.
    """
    out = Path(out_dir)
    experiment = read_experiment(out)
    swept = list(experiment.swept_columns)
    point_columns = ["snr_db", *swept, "truth_x_m", "truth_y_m"]
    selected = ", ".join(
        [f"t.{c}" for c in _TABLE_COLUMNS] + [f"p.{_quote(c)}" for c in point_columns]
    )
    query = (
        f"SELECT {selected} FROM trials t JOIN points p ON t.scenario = p.scenario "
        "AND t.point = p.point AND t.frame = p.frame "
        "ORDER BY t.scenario_index, t.point, t.planner_index, t.estimator_index, t.frame, "
        "t.trial"
    )
    frame = _read_table(out, query)
    frame.insert(0, "experiment", experiment.name)
    columns = list(TRIAL_COLUMNS)
    columns[4:4] = swept
    frame = _fix_types(frame[columns].copy(), swept)
    return frame.reset_index(drop=True)


def read_points(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """One row per scenario × point × frame: truth, the accumulated CRLB (MATH §8) and
    ``range_scale_m``, the root mean square slant range of the samples flown so far (the size
    of the geometry a bound is compared with)."""
    out = Path(out_dir)
    experiment = read_experiment(out)
    swept = list(experiment.swept_columns)
    columns = [
        "scenario",
        "point",
        "snr_db",
        *swept,
        "frame",
        "truth_x_m",
        "truth_y_m",
        "range_scale_m",
        *POINT_CRLB_SETS,
    ]
    query = (
        f"SELECT {', '.join(map(_quote, columns))} FROM points "
        "ORDER BY scenario_index, point, frame"
    )
    frame = _read_table(out, query)
    frame.insert(0, "experiment", experiment.name)
    return _fix_types(frame, swept).reset_index(drop=True)


def read_task_times(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """Wall time of every task run (``scenario, point, first_trial, n_trials, elapsed_s``)."""
    return _read_table(Path(out_dir), "SELECT * FROM tasks ORDER BY finished_utc")


def read_flights(out_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """The frames flown in a closed loop, one row per scenario × point × planner × trial × frame.

    Columns :data:`FLIGHT_COLUMNS`: the first sample of each frame and its velocity, and the
    message of the plan that chose it. Empty (with those columns) for an open-loop run, whose
    flight is the scenario's own.
    """
    out = Path(out_dir)
    path = out / RESULTS_FILE
    if not path.is_file():
        raise ValueError(f"out_dir: {path} not found; run the experiment first")
    with closing(sqlite3.connect(path, timeout=60.0)) as connection:
        connection.execute("PRAGMA query_only=ON")
        tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master")}
        if "flights" not in tables:
            return pd.DataFrame({column: [] for column in FLIGHT_COLUMNS})
        frame = pd.read_sql_query(
            f"SELECT {', '.join(FLIGHT_COLUMNS)} FROM flights "
            "ORDER BY scenario_index, point, planner_index, trial, frame",
            connection,
        )
    for column in ("point", "trial", "frame"):
        frame[column] = frame[column].astype("int64")
    return frame.reset_index(drop=True)
