"""Trials per task: ``chunk_size = "auto"`` sized from the work, recorded, and kept on resume."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from comparison.bounds import crlb_key, point_infos
from comparison.engine import run_experiment
from comparison.experiment import AUTO_CHUNK_SIZE, MAX_CHUNK_SAMPLES, Experiment
from comparison.run_folder import read_experiment
from comparison.store import read_trials
from comparison.tasks import (
    AUTO_TASK_ESTIMATES,
    AUTO_TASKS_PER_WORKER,
    auto_chunk_size,
    chunk_size_for,
    estimator_of,
    plan_tasks,
)
from scenarios.simulate import noise_free
from tests import paths
from tests.comparison.test_engine import smoke


def rows(out) -> pd.DataFrame:
    return read_trials(out).drop(columns="runtime_s")


def auto(**changes) -> Experiment:
    """``smoke`` (2 points, cls and cls-paper, 20 trials) with ``chunk_size = "auto"``."""
    return smoke(chunk_size=AUTO_CHUNK_SIZE, **changes)


def infos_of(experiment: Experiment):
    """Every (scenario, point)'s :class:`~comparison.bounds.PointInfo`, as a run works them out."""
    return point_infos(experiment, [crlb_key(estimator_of(s)) for s in experiment.estimators])


def test_chunk_size_for_is_the_smallest_size_of_the_fewest_chunks_the_bounds_allow():
    """Against a search over every number of chunks per point: the fewest that leave each
    worker AUTO_TASKS_PER_WORKER tasks (or one task per trial when there are fewer trials)
    with at most ``most`` trials each, then the smallest chunk that cuts a point into that
    many."""
    for trials in range(1, 41):
        for points in (1, 2, 3, 7, 27):
            for workers in (1, 2, 3, 8):
                for most in (1, 2, 5, 13, 100):
                    chunks = next(
                        k
                        for k in range(1, trials + 1)
                        if -(-trials // k) <= most
                        and (points * k >= AUTO_TASKS_PER_WORKER * workers or k == trials)
                    )
                    expected = -(-trials // chunks)
                    got = chunk_size_for(trials, points=points, workers=workers, most_trials=most)
                    assert got == expected, (trials, points, workers, most)


def test_auto_sizes_follow_the_workers_the_estimates_and_the_frames():
    """smoke with 500 trials (2 points, 2 estimators): one worker needs 4 tasks, 2 a point, of
    250 trials; two workers 8 tasks, of 125. Per frame over 10 frames a trial gives 2 × 10
    estimates: AUTO_TASK_ESTIMATES // 20 = 100 trials a task bind before the balance does."""
    wide = auto(trials=500)
    infos = infos_of(wide)
    assert auto_chunk_size(wide, infos, 1) == 250
    assert auto_chunk_size(wide, infos, 2) == 125
    framed = auto(trials=500, frames=10, per_frame=True)
    infos = infos_of(framed)
    assert AUTO_TASK_ESTIMATES // 20 == 100
    assert auto_chunk_size(framed, infos, 1) == 100
    most_samples = max(info.scenario.flight.n_samples for info in infos.values())
    assert MAX_CHUNK_SAMPLES // most_samples > 100  # the estimates bind, not the memory


def test_auto_is_the_default_and_survives_json():
    experiment = Experiment.from_dict(
        {k: v for k, v in smoke().to_dict().items() if k != "chunk_size"}
    )
    assert experiment.chunk_size == AUTO_CHUNK_SIZE
    assert Experiment.from_json(experiment.to_json()) == experiment
    with pytest.raises(ValueError, match=r"^chunk_size: expected a whole number >= 1, got 'big'"):
        smoke(chunk_size="big")
    infos = infos_of(experiment)
    with pytest.raises(ValueError, match="chunk_size: 'auto' must be resolved"):
        plan_tasks(experiment, infos, {})


@pytest.mark.paths
def test_an_auto_sized_run_gives_the_rows_of_one_trial_per_task(tmp_path):
    """On one worker smoke's 2 points need 2 chunks each: 10 trials a task, recorded in
    experiment.json. Its rows and those of chunks of one trial agree to rounding (other
    chunks are other arrays for the batch estimators, :mod:`tests.paths`)."""
    sized = run_experiment(auto(), tmp_path / "auto", workers=1, progress=False)
    assert read_experiment(sized).chunk_size == 10
    assert json.loads((sized / "experiment.json").read_text())["chunk_size"] == 10
    single = run_experiment(smoke(chunk_size=1), tmp_path / "one", workers=1, progress=False)
    kappa = paths.fisher_condition(noise_free(smoke().point_scenario(0, 0)[0]))
    assert len(rows(sized)) == 2 * 20 * 2
    assert paths.frame_problems(rows(sized), rows(single), kappa) == []


@pytest.mark.bits(
    "the resume reuses the recorded chunks of 4 trials: the same tasks on the same arrays as "
    "a run of chunk_size 4"
)
@pytest.mark.slow  # starting worker processes takes seconds on a busy machine
def test_a_resume_on_other_workers_keeps_the_run_s_chunks(tmp_path):
    """8 trials on one worker: chunks of 4 (2 points × 2 chunks = 4 tasks). Resumed to 20
    trials on two workers, where a new run would take chunks of 5 (8 tasks of 2 points), it
    keeps 4: its rows are those of an uninterrupted run in chunks of 4, to the bit."""
    out = tmp_path / "auto"
    run_experiment(auto(), out, workers=1, trials=8, progress=False)
    assert read_experiment(out).chunk_size == 4
    infos = infos_of(auto())
    assert auto_chunk_size(auto(), infos, 2) == 5  # what a new run on two workers takes
    run_experiment(auto(), out, workers=2, trials=20, resume=True, progress=False)
    assert read_experiment(out).chunk_size == 4
    whole = run_experiment(smoke(chunk_size=4), tmp_path / "four", workers=1, progress=False)
    pd.testing.assert_frame_equal(rows(out), rows(whole))


@pytest.mark.slow
def test_a_dask_run_sizes_its_tasks_for_the_cluster_s_threads(tmp_path):
    """Two dask workers of one thread each are two slots: smoke's 2 points need 4 chunks
    each, of 5 trials (one worker's run takes 10)."""
    distributed = pytest.importorskip(
        "dask.distributed", reason="dask.distributed is not installed (emitterbench[cluster])"
    )
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        out = run_experiment(
            auto(), tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False
        )
    assert read_experiment(out).chunk_size == 5
    assert len(read_trials(out)) == 2 * 20 * 2
