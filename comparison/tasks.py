"""Tasks, the unit of work a worker runs, and the seeds that make their rows reproducible.

Seeds
    The data of (scenario index ``i``, point ``p``, trial ``t``) come from
    ``SeedSequence(seed, spawn_key=(i, p, t))`` (:func:`trial_seed`): every estimator sees the
    same data there (common random numbers), and no row depends on the number of workers,
    their order, or the number of trials asked (more trials extend a run, never change it),
    nor on the chunking but to rounding (a batch of other trials is other arrays). Estimator ``L`` breaks ties (MATH §7) with
    ``default_rng(SeedSequence(seed, spawn_key=(i, p, t, 1 + crc32(L))))`` (:func:`tie_rng`), a
    fresh generator for every estimate (so with ``per_frame`` the last frame's row equals the
    row of a run without it). In a closed loop the noise block of the trial is drawn the same
    way (so every planner meets the same noise, and ``constant`` reproduces the open-loop data)
    and planner ``P`` gets the generator of the label ``"planner:" + P``.

Tasks
    A task is a chunk of ``chunk_size`` trials of one (scenario, point) (:func:`plan_tasks`),
    the unit a worker runs and the store keeps (a killed run loses the tasks in flight).
    ``chunk_size = "auto"`` (the default) is resolved once per run by :func:`auto_chunk_size`
    from the work: the largest chunks that still give every worker
    :data:`AUTO_TASKS_PER_WORKER` tasks, at most :data:`AUTO_TASK_ESTIMATES` estimates and
    :data:`~comparison.experiment.MAX_CHUNK_SAMPLES` samples each; the run folder's
    ``experiment.json`` records the number, which ``--resume`` reuses whatever its workers.
    It simulates the chunk once (:func:`scenarios.simulate.simulate_trials`) and runs every
    estimator on every trial; a batch estimator gets the whole chunk, through
    ``estimate_columns`` when it has one (its results stay columns, no object per trial),
    else ``estimate_batch``, and falls back to one call per trial if the batch call raises
    (:mod:`comparison.estimator_calls`). With ``per_frame`` every estimator runs on
    ``data.up_to_frame(l)`` for every frame ``l``; sequential estimators
    (``init``/``update``/``estimate_state``) are streamed frame by frame instead. A
    closed-loop task flies every trial once per planner
    (:func:`comparison.closed_loop.fly_closed_loop`), and each row carries the CRLB of the
    trajectory that trial flew; its wrong side is judged against the track of the first frame
    the estimator uses (:func:`comparison.scoring.ambiguity_track`), the mirror ambiguity a
    turn must resolve. An open-loop task scores each estimator's trials at once
    (:func:`comparison.scoring.score_outcomes`), a closed-loop one each estimate
    (:func:`comparison.scoring.estimate_columns`), to the same values; the main process
    stores them (:func:`comparison.store.write_task`).

Faults
    Every estimator call of a task runs under the experiment's ``time_limit_s``
    (:func:`comparison.estimator_calls.call_limits`), and whatever Python can catch becomes a
    failed row there (:mod:`comparison.estimator_calls`). A task whose worker process dies is
    rerun isolated, the call that ended the process replaced by a failure
    (:mod:`comparison.execution`); :func:`run_task` is the same code in both cases, so every
    other row is the same. The task's data are never given to an estimator: each call gets
    its own copy, checked after the call (:mod:`comparison.estimator_calls`), so what one
    estimator does to its data changes no other row.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from comparison.bounds import PointInfo, bound_columns, crlb_key, information_at_truth
from comparison.closed_loop import ClosedLoopTrial, fly_closed_loop
from comparison.estimator_calls import (
    Stream,
    call_batch,
    call_columns,
    call_estimate,
    call_limits,
    call_samples,
)
from comparison.scoring import (
    Outcomes,
    ambiguity_track,
    estimate_columns,
    frame_track,
    jsonable,
    score_outcomes,
)
from comparison.specs import EstimatorSpec, PlannerSpec
from comparison.trial_rows import (
    FLIGHT_VALUE_COLUMNS,
    SCORED_DIMENSION,
    bound_columns_of,
    estimate_columns_of,
    padded,
)
from estimators.base import Estimate, Estimator, capabilities_of
from estimators.batch import TrialGenerators
from estimators.frontend import (
    BurstMeasurements,
    measure_bursts,
    measurement_batch,
    outlier_rate,
)
from estimators.registry import reads_samples
from scenarios.nuisance import HEIGHT_UNKNOWN
from scenarios.planners import Planner
from scenarios.signal import BurstPlan, ReceivedBursts, burst_truth, received_bursts
from scenarios.simulate import noise_free, simulate_trials
from scenarios.types import MeasurementBatch, MeasurementSet, Scenario

if TYPE_CHECKING:  # annotations only: workers need not import the experiment schema
    from comparison.experiment import Experiment

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
# tasks and their results
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
    time_limit_s: float | None = None  # per estimator call (None: no limit)
    dimension: int = SCORED_DIMENSION  # the run's tables' coordinates (bounds.run_dimension)
    signal: BurstPlan | None = None  # the bursts received at this point (the signal level)
    doppler_search_hz: float | None = None  # the front end's Doppler search there (MATH §20)

    def scored_dimension(self, spec: EstimatorSpec) -> int:
        """The coordinates an estimator's answer is scored in: the scenario's (3 with the
        height unknown), 2 for one that assumes the unknowns known (its horizontal answer)."""
        if HEIGHT_UNKNOWN in spec.assumed(self.scenario.unknowns):
            return SCORED_DIMENSION
        return self.scenario.truth_emitter_m.size


class ScoredRow(NamedTuple):
    """One estimate of a task: its keys, its bound, and its
    :data:`~comparison.trial_rows.ESTIMATE_COLUMNS`."""

    planner_index: int
    estimator_index: int
    frame: int
    trial: int
    bound: tuple[float, ...] | None
    """:data:`~comparison.trial_rows.BOUND_COLUMNS` (``√trace``, then the CRLB's ``xx, xy,
    yy``); None in an open loop, where the main process adds the common bound."""
    values: tuple[Any, ...]


class FlightRow(NamedTuple):
    """One frame flown in a closed loop: its keys and its
    :data:`~comparison.trial_rows.FLIGHT_VALUE_COLUMNS`."""

    planner_index: int
    trial: int
    frame: int
    values: tuple[Any, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskResult:
    """A task's rows and, in a closed loop, the frames it flew."""

    scenario_index: int
    point: int
    trials: tuple[int, ...]
    rows: list[ScoredRow]
    elapsed_s: float
    flights: list[FlightRow] = dataclasses.field(default_factory=list)
    bursts: list[tuple[int, tuple[Any, ...]]] = dataclasses.field(default_factory=list)
    """At the signal level: per trial, its :data:`~comparison.trial_rows.BURST_VALUE_COLUMNS`."""


@functools.lru_cache(maxsize=128)
def estimator_of(spec: EstimatorSpec) -> Estimator:
    """One estimator object per spec and process (estimators are immutable)."""
    return spec.build()


@functools.lru_cache(maxsize=32)
def planner_of(spec: PlannerSpec) -> Planner:
    """One planner object per spec and process (planners are immutable)."""
    return spec.build()


AUTO_TASKS_PER_WORKER = 4
"""Tasks per worker, at least, that ``chunk_size = "auto"`` leaves for the balance (when the
trials allow): a worker that draws the slowest tasks still finishes with the others."""

AUTO_TASK_ESTIMATES = 2000
"""Most estimates in one task of ``chunk_size = "auto"`` (trials × estimators × planners ×
evaluated frames): the work a kill loses per task in flight. paper-fig2's estimates take
about 0.23 ms each in chunks of 250, simulation and scoring included, so such a task is about
half a second of work; at 20 ms an estimate (a filter with unknown nuisance parameters, one
trial at a time) it is 40 s."""


def estimates_per_trial(experiment: Experiment, n_frames: int) -> int:
    """The rows one trial gives: estimators × planners (1 in open loop) × evaluated frames
    (``n_frames`` with ``per_frame``, else 1)."""
    frames = n_frames if experiment.per_frame else 1
    return len(experiment.estimators) * max(1, len(experiment.planners)) * frames


def auto_chunk_size(
    experiment: Experiment, infos: Mapping[tuple[int, int], PointInfo], workers: int
) -> int:
    """Trials per task for ``chunk_size = "auto"``: :func:`chunk_size_for` of the run's
    trials, (scenario, point) pairs, estimates and samples per trial (the most of any point),
    and ``workers``. Used when a run starts; a resume reuses the number its run recorded."""
    from comparison.experiment import MAX_CHUNK_SAMPLES  # main process only

    n_frames = max(info.n_frames for info in infos.values())
    n_samples = max(  # at the signal level, every burst's window of samples
        info.scenario.flight.n_samples * (1 if info.plan is None else info.plan.n_samples)
        for info in infos.values()
    )
    return chunk_size_for(
        experiment.trials,
        points=len(infos),
        workers=workers,
        most_trials=min(
            AUTO_TASK_ESTIMATES // estimates_per_trial(experiment, n_frames),
            MAX_CHUNK_SAMPLES // n_samples,
        ),
    )


def chunk_size_for(trials: int, *, points: int, workers: int, most_trials: int) -> int:
    """The largest even chunk of a point's ``trials`` that leaves every one of ``workers``
    :data:`AUTO_TASKS_PER_WORKER` tasks of the ``points`` points (when there are trials
    enough) and holds at most ``most_trials`` (at least one).

    The chunks of a point are made even: 500 trials in chunks of at most 300 are two of 250,
    not 300 and 200. A batch estimator's cost per trial falls with its chunk (paper-fig2's
    rows in one process: 40 s of CPU in chunks of 25, 22 s in chunks of 250, 21 s in chunks
    of 500), which is why the chunks are as large as the bounds allow.
    """
    per_point = -(-AUTO_TASKS_PER_WORKER * workers // points)  # chunks each point needs
    size = max(1, min(-(-trials // per_point), most_trials))
    return -(-trials // -(-trials // size))  # ceil(trials / ceil(trials / size))


def plan_tasks(
    experiment: Experiment,
    infos: Mapping[tuple[int, int], PointInfo],
    complete: Mapping[tuple[int, int], set[int]],
    dimension: int = SCORED_DIMENSION,
) -> list[Task]:
    """Chunks of ``chunk_size`` trials per (scenario, point), without the ``complete`` ones
    (``chunk_size`` a number: :func:`auto_chunk_size` resolves ``"auto"`` first), their rows
    of positions of ``dimension`` coordinates."""
    tasks = []
    size = experiment.chunk_size
    if not isinstance(size, int):
        raise ValueError(f"chunk_size: {size!r} must be resolved to a number before planning")
    steering = tuple(experiment.steering_label(k) for k in range(len(experiment.planners)))
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
                        steering=steering,
                        time_limit_s=experiment.time_limit_s,
                        dimension=dimension,
                        signal=info.plan,
                        doppler_search_hz=experiment.doppler_search_hz(info.scenario),
                    )
                )
    return tasks


# --------------------------------------------------------------------------------------------
# open loop
# --------------------------------------------------------------------------------------------


def run_task(task: Task) -> TaskResult:
    """Simulate the task's trials and run every estimator on each, every call under
    ``task.time_limit_s``; never raises for an estimator.

    Returns
    -------
    TaskResult
        Rows without the bound, which the main process adds (a closed-loop task, with
        planners, is :func:`run_closed_loop_task`: its rows carry their own bounds).
    """
    with call_limits(task.time_limit_s):
        if task.planners:
            return run_closed_loop_task(task)
        return _run_open_loop_task(task)


def _run_open_loop_task(task: Task) -> TaskResult:
    """:func:`run_task` of an open-loop task (no planners)."""
    start = time.perf_counter()
    seeds = [trial_seed(task.seed, task.scenario_index, task.point, t) for t in task.trials]
    received, bursts, refused, front_end_s = None, [], {}, 0.0
    if task.signal is None:
        feeds = {"all": (task, simulate_trials(task.scenario, snr_db=task.snr_db, seeds=seeds))}
    else:
        received, measured, front_end_s = received_trials(
            task.scenario, task.signal, seeds, task.doppler_search_hz
        )
        bursts = list(
            zip(task.trials, burst_rows(task.scenario, task.signal, measured), strict=True)
        )
        feeds, refused = measured_feeds(task, measured)
    # estimators never see the truth
    geometry = noise_free(task.scenario).without_truth()
    truth = task.scenario.truth_emitter_m
    names = estimate_columns_of(task.dimension)
    frames = [int(f) for f in geometry.frames]
    eval_frames = frames if task.per_frame else frames[-1:]
    tracks = {frame: frame_track(geometry, frame) for frame in eval_frames}
    # each feed with some unknowns taken as known (MATH §15, §8), by the unknowns assumed
    data: dict[tuple[str, tuple[str, ...]], _TaskData] = {}
    rows: list[ScoredRow] = []

    def add_rows(index: int, frame: int, trials: tuple[int, ...], outcomes: Outcomes) -> None:
        scored = score_outcomes(outcomes, truth[:d], tracks[frame], names)
        rows.extend(
            ScoredRow(0, index, frame, trial, None, values)
            for trial, values in zip(trials, scored, strict=True)
        )

    for index, spec in enumerate(task.estimators):
        estimator = estimator_of(spec)
        d = task.scored_dimension(spec)
        if reads_samples(estimator):
            assert received is not None and task.signal is not None  # checked at load
            rngs = [
                tie_rng(task.seed, task.scenario_index, task.point, trial, spec.label)
                for trial in task.trials
            ]
            columns = call_samples(
                estimator, geometry, task.signal, received.samples, received.emission_time_s, rngs
            )
            add_rows(index, frames[-1], task.trials, Outcomes.of_columns(*columns, d))
            continue
        kind = "doppler" if "toa" not in capabilities_of(estimator).modalities else "toa"
        kind = kind if kind in feeds else "all"
        if kind == "toa":  # the trials whose ToAs were refused fail (measured_feeds), after
            for frame in eval_frames:  # the front end's time
                failed = [
                    (Estimate.failed(spec.label, text), front_end_s) for text in refused.values()
                ]
                add_rows(index, frame, tuple(refused), Outcomes.of_estimates(failed, d))
        fed_task, batch = feeds[kind]
        if batch is None:
            continue
        assumed = spec.assumed(batch.geometry.unknowns)
        if (kind, assumed) not in data:
            known = batch.geometry.without_truth().assuming_known(assumed)
            data[kind, assumed] = _TaskData(dataclasses.replace(batch, geometry=known))
        for frame, outcomes in _run_estimator(
            estimator, spec.label, fed_task, data[kind, assumed], eval_frames, d
        ):  # a two-step estimate's time holds its share of the front end's
            runtime_s = outcomes.runtime_s + front_end_s
            timed = dataclasses.replace(outcomes, runtime_s=runtime_s)
            add_rows(index, frame, fed_task.trials, timed)
    return TaskResult(
        scenario_index=task.scenario_index,
        point=task.point,
        trials=task.trials,
        rows=rows,
        elapsed_s=time.perf_counter() - start,
        bursts=bursts,
    )


def received_trials(
    scenario: Scenario,
    plan: BurstPlan,
    seeds: list[np.random.SeedSequence],
    doppler_search_hz: float | None = None,
) -> tuple[ReceivedBursts, BurstMeasurements, float]:
    """The bursts of ``seeds``' trials received (MATH §18), what the front end measures of
    them (§20), searching ``±doppler_search_hz``, and the front end's time per trial (s)."""
    received = received_bursts(scenario, plan, seeds)
    start = time.perf_counter()
    measured = measure_bursts(
        received.samples,
        plan,
        time_s=noise_free(scenario).time_s,
        emission_time_s=received.emission_time_s,
        doppler_search_hz=doppler_search_hz,
    )
    return received, measured, (time.perf_counter() - start) / len(seeds)


def measured_feeds(
    task: Task, measured: BurstMeasurements
) -> tuple[dict[str, tuple[Task, MeasurementBatch | None]], dict[int, str]]:
    """The front end's measurements of the task's trials as batches (MATH §20), with the σ's
    of the scenario (the bounds at the plan's C/N0,
    :func:`comparison.experiment_signal.received_scenario`), and, by trial, why its ToAs are refused.

    Below threshold a ToA outlier can be shorter than the UAV's height, which the measurement
    sets refuse (MATH §1): then ``"toa"`` is the batch of the trials whose data pass (None if
    none does), for the estimators that read the ToA (the others fail), and ``"doppler"`` the
    Doppler of every trial, for those that read it alone. Without a refusal: ``"all"``.
    """
    geometry, noise = noise_free(task.scenario), task.scenario.noise
    try:
        return {"all": (task, measurement_batch(geometry, measured, noise))}, {}
    except ValueError:
        pass
    refused = {}
    for position, trial in enumerate(task.trials):
        try:
            measurement_batch(geometry, measured.trial(np.array([position])), noise)
        except ValueError as error:
            refused[trial] = f"the front end's measurements are refused: {error}"
    kept = [p for p, t in enumerate(task.trials) if t not in refused]
    kept_task = dataclasses.replace(task, trials=tuple(task.trials[p] for p in kept))
    doppler = dataclasses.replace(measured, toa_s=None, toa_variance_s2=None)
    feeds = {
        "toa": (
            kept_task,
            measurement_batch(geometry, measured.trial(np.array(kept)), noise) if kept else None,
        ),
        "doppler": (task, measurement_batch(geometry, doppler, noise)),
    }
    return feeds, refused


def burst_rows(
    scenario: Scenario, plan: BurstPlan, measured: BurstMeasurements
) -> list[tuple[Any, ...]]:
    """Per trial, :data:`~comparison.trial_rows.BURST_VALUE_COLUMNS`: its bursts, those the
    front end flagged below threshold, its outliers (a Doppler a bin or a ToA a chip off the
    truth, :func:`estimators.frontend.outlier_rate`) and those of them not flagged, and the
    mean estimated burst SNR in dB."""
    truth = burst_truth(scenario, plan)
    rows = []
    for position in range(len(measured.doppler_hz)):
        trial = measured.trial(position)
        outliers, n_bursts = outlier_rate(trial, plan, truth.doppler_hz, truth.toa_s)
        missed, _ = outlier_rate(
            trial, plan, truth.doppler_hz, truth.toa_s, among=~trial.below_threshold
        )
        snr_db = 10.0 * np.log10(np.mean(trial.burst_snr))
        flagged = int(np.sum(trial.below_threshold))
        rows.append((n_bursts, flagged, outliers, missed, float(snr_db)))
    return rows


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


def _batch_up_to_frame(batch: MeasurementBatch, frame: int) -> MeasurementBatch:
    """The samples of frames ``<= frame`` of every trial."""
    mask = batch.geometry.frame <= frame
    return MeasurementBatch(
        geometry=batch.geometry.take(mask),
        doppler_hz=None if batch.doppler_hz is None else batch.doppler_hz[:, mask],
        toa_s=None if batch.toa_s is None else batch.toa_s[:, mask],
        rss_dbm=None if batch.rss_dbm is None else batch.rss_dbm[:, mask],
    )


def _run_estimator(
    estimator: Estimator,
    label: str,
    task: Task,
    data: _TaskData,
    eval_frames: list[int],
    dimension: int,
) -> list[tuple[int, Outcomes]]:
    """``[(frame, outcomes of every trial)]`` for one estimator on one task, its answers of
    ``dimension`` coordinates (another number is a failed estimate).

    ``estimate_columns`` when the estimator declares ``batch`` and has it, else
    ``estimate_batch``, else (or when the batch call fails) one call per trial.
    """

    def rng(trial: int) -> np.random.Generator:
        return tie_rng(task.seed, task.scenario_index, task.point, trial, label)

    def rngs() -> TrialGenerators:  # each made when an estimator reads it (a tie to break)
        return TrialGenerators(len(task.trials), lambda i: rng(task.trials[i]))

    capabilities = capabilities_of(estimator)
    if task.per_frame and capabilities.sequential:
        streamed: dict[int, list[Any]] = {frame: [] for frame in eval_frames}
        for position, trial_data in enumerate(data.trials(data.final_frame)):
            stream = Stream(estimator)
            for frame in eval_frames:
                newest = trial_data.take(trial_data.frame == frame)
                streamed[frame].append(stream.step(newest, rng(task.trials[position])))
        return [(frame, Outcomes.of_estimates(streamed[frame], dimension)) for frame in eval_frames]
    columnar = capabilities.batch and callable(getattr(estimator, "estimate_columns", None))
    out = []
    for frame in eval_frames:
        outcomes = None
        if columnar:
            columns = call_columns(estimator, data.batch(frame), rngs())
            outcomes = None if columns is None else Outcomes.of_columns(*columns, dimension)
        elif capabilities.batch:
            estimates = call_batch(estimator, data.batch(frame), rngs())
            outcomes = None if estimates is None else Outcomes.of_estimates(estimates, dimension)
        if outcomes is None:
            outcomes = Outcomes.of_estimates(
                [
                    call_estimate(estimator, trial_data, rng=trial_rng)
                    for trial_data, trial_rng in zip(data.trials(frame), rngs(), strict=True)
                ],
                dimension,
            )
        out.append((frame, outcomes))
    return out


# --------------------------------------------------------------------------------------------
# closed loop
# --------------------------------------------------------------------------------------------


def run_closed_loop_task(task: Task) -> TaskResult:
    """Fly the task's trials once per planner (:mod:`comparison.closed_loop`) and score them.

    Every row carries the CRLB of the trajectory its trial flew, at the truth, for the
    estimator's modalities and frames (MATH §8).
    """
    start = time.perf_counter()
    truth = task.scenario.truth_emitter_m
    names, bound_names = estimate_columns_of(task.dimension), bound_columns_of(task.dimension)
    kept = [task.scored_dimension(spec) for spec in task.estimators]
    estimators = [(spec.label, estimator_of(spec)) for spec in task.estimators]
    crlb_keys = [crlb_key(estimator) for _, estimator in estimators]
    rows: list[ScoredRow] = []
    flights: list[FlightRow] = []
    for planner_index, planner_spec in enumerate(task.planners):
        planner = planner_of(planner_spec)
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
                assuming={s.label: s.assumed(task.scenario.unknowns) for s in task.estimators},
            )
            information = information_at_truth(flown.data, truth, {m for m, _ in crlb_keys})
            for frame in range(flown.n_frames):
                for index, (label, _) in enumerate(estimators):
                    estimate, runtime_s = flown.estimates[label][frame]
                    modalities, frames = crlb_keys[index]
                    track = ambiguity_track(flown.data, frame, frames)
                    d = kept[index]
                    bound = bound_columns(information.get(modalities), frame, frames, kept=d)
                    bound = padded(bound, bound_names)
                    values = estimate_columns(estimate, truth[:d], track, runtime_s, names)
                    rows.append(ScoredRow(planner_index, index, frame, trial, bound, values))
            flights.extend(_flight_rows(planner_index, trial, flown))
    return TaskResult(
        scenario_index=task.scenario_index,
        point=task.point,
        trials=task.trials,
        rows=rows,
        elapsed_s=time.perf_counter() - start,
        flights=flights,
    )


def _flight_rows(planner_index: int, trial: int, flown: ClosedLoopTrial) -> list[FlightRow]:
    """Every frame flown: its first and last samples, its velocity, and the plan's message."""
    positions = flown.flight.sample_positions_m()
    k = flown.flight.samples_per_frame
    out = []
    for frame, (begin, end, velocity) in enumerate(
        zip(positions[::k], positions[k - 1 :: k], flown.flight.frame_velocities_mps, strict=True)
    ):
        plan = flown.plans[frame]
        diagnostics = {} if plan is None else dict(plan.diagnostics)
        (start_x, start_y, start_z), (end_x, end_y, end_z) = begin, end
        vx, vy, vz = velocity
        values = {
            "start_x_m": float(start_x),
            "start_y_m": float(start_y),
            "start_z_m": float(start_z),
            "end_x_m": float(end_x),
            "end_y_m": float(end_y),
            "end_z_m": float(end_z),
            "vx_mps": float(vx),
            "vy_mps": float(vy),
            "vz_mps": float(vz),
            "message": "the scenario's initial velocity" if plan is None else plan.message,
            "diagnostics_json": json.dumps(jsonable(diagnostics), sort_keys=True),
        }
        row = tuple(values[column] for column in FLIGHT_VALUE_COLUMNS)
        out.append(FlightRow(planner_index, trial, frame, row))
    return out
