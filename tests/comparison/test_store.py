"""results.sqlite: a damaged or linked store is one line with the way out, for a resume, a
report and every reader, and a refused resume changes nothing in the folder."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from comparison import store
from comparison.engine import run_experiment
from comparison.experiment import load_experiment
from comparison.metrics import SUMMARY_TRIAL_COLUMNS, summarize, summarize_chunks
from comparison.run_folder import write_csv
from comparison.store import (
    count_trials,
    iter_trials,
    read_flights,
    read_points,
    read_trials,
    store_error,
    trial_layout,
)
from tests.comparison.cli_support import clean_error, invoke

TRIALS = 4
DAMAGED = r"^results.sqlite: .* is not a readable SQLite database of a run \(.+\); move it away"


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished run of ``smoke`` with TRIALS trials (no report); copy it to change it."""
    out = tmp_path_factory.mktemp("store") / "run"
    return run_experiment(load_experiment("smoke"), out, workers=1, trials=TRIALS)


def copy_of(run: Path, folder: Path) -> Path:
    copy = folder / "run"
    copy.mkdir()
    for name, content in files(run).items():
        (copy / name).write_bytes(content)
    return copy


def damage(database: Path, how: str) -> None:
    size = database.stat().st_size
    page = 4096
    assert size >= 4 * page  # a header page, tables, rows: something to damage in the middle
    with database.open("r+b") as handle:
        if how == "truncated to half":
            handle.truncate(size // 2)
        elif how == "a garbage page in the middle":
            handle.seek((size // 2) // page * page)
            handle.write(bytes(range(256)) * (page // 256))
        elif how == "a zeroed header":
            handle.write(bytes(100))


HOW = ["truncated to half", "a garbage page in the middle", "a zeroed header"]


@pytest.mark.parametrize("how", HOW)
def test_a_damaged_store_is_one_line_for_resume_report_and_readers(finished_run, tmp_path, how):
    run = copy_of(finished_run, tmp_path)
    damage(run / "results.sqlite", how)
    before = files(run)
    resumed = invoke("run", "smoke", "-o", run, "--trials", TRIALS + 2, "--resume")
    line = clean_error(resumed, f"results.sqlite: {run / 'results.sqlite'} is not a readable")
    way_out = "move it away and rerun the experiment with --resume (its trials run again)"
    assert line.endswith(f"{way_out}, or restore it from a backup")
    assert files(run) == before  # not even experiment.json's trials or run.json changed
    clean_error(invoke("report", run), "results.sqlite: ")
    assert files(run) == before
    for read in (read_trials, read_points, read_flights):
        with pytest.raises(ValueError, match=DAMAGED):
            read(run)


def test_moving_a_damaged_store_away_and_resuming_gives_the_run_again(finished_run, tmp_path):
    run = copy_of(finished_run, tmp_path)
    damage(run / "results.sqlite", "a zeroed header")
    (run / "results.sqlite").rename(tmp_path / "damaged.sqlite")
    run_experiment(load_experiment("smoke"), run, workers=1, trials=TRIALS, resume=True)
    keep = [c for c in read_trials(run).columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(read_trials(run)[keep], read_trials(finished_run)[keep])


def test_a_store_without_tables_is_one_line(finished_run, tmp_path):
    run = copy_of(finished_run, tmp_path)
    (run / "results.sqlite").write_bytes(b"")  # SQLite reads an empty file as no tables
    clean_error(invoke("report", run), "results.sqlite: ")
    with pytest.raises(ValueError, match=r"\(no such table: trials\)"):
        read_trials(run)


def test_a_linked_store_is_refused_and_its_target_untouched(finished_run, tmp_path):
    run = copy_of(finished_run, tmp_path)
    target = tmp_path / "elsewhere.sqlite"
    (run / "results.sqlite").rename(target)
    (run / "results.sqlite").symlink_to(target)
    content = target.read_bytes()
    resumed = invoke("run", "smoke", "-o", run, "--trials", TRIALS + 2, "--resume")
    clean_error(resumed, f"results.sqlite: {run / 'results.sqlite'} is a symbolic link")
    clean_error(invoke("report", run), "results.sqlite: ")
    with pytest.raises(ValueError, match=r"^results.sqlite: .* is a symbolic link"):
        read_points(run)
    assert target.read_bytes() == content
    assert not any(p.name.startswith("elsewhere.sqlite-") for p in tmp_path.iterdir())


def test_only_sqlite_failures_of_the_file_are_turned_into_a_line(tmp_path):
    path = tmp_path / "results.sqlite"
    locked = store_error(path, sqlite3.OperationalError("database is locked"))
    assert str(locked).startswith(f"results.sqlite: cannot use {path} (database is locked)")
    damaged = store_error(path, sqlite3.DatabaseError("database disk image is malformed"))
    assert str(damaged).startswith(f"results.sqlite: {path} is not a readable SQLite database")
    assert (
        store_error(path, sqlite3.ProgrammingError("Cannot operate on a closed database.")) is None
    )


def test_readers_see_the_rows_of_a_sound_store(finished_run):
    assert len(read_trials(finished_run)) == 2 * TRIALS * 2
    assert len(read_points(finished_run)) == 2
    assert read_flights(finished_run).empty
    assert not any(name.endswith(("-wal", "-shm")) for name in os.listdir(finished_run))


def test_the_fit_columns_are_stored_and_added_to_a_folder_of_an_earlier_version(
    finished_run, tmp_path
):
    """MATH §17: every success of cls and cls-paper on smoke has its χ² and dof (paper-1m,
    one frame of 10 samples, Doppler and ToA: 18). A folder written before the columns
    existed gets them on --resume, NaN for its rows, and new rows fill them."""
    trials = read_trials(finished_run)
    assert trials["success"].all() and (trials["fit_dof"] == 18).all()
    assert (trials["fit_chi2"] > 0).all() and trials["fit_chi2"].notna().all()
    # the summary read from the store, a point at a time, judges every one of them
    layout = trial_layout(finished_run)
    assert count_trials(finished_run) == layout.n_rows == len(trials)
    chunks = iter_trials(finished_run, SUMMARY_TRIAL_COLUMNS)
    summary = summarize_chunks(chunks, orders=layout.orders, n_trial_sets=2, n_bootstrap=20)
    assert (summary["n_fit_judged"] == TRIALS).all()
    old = copy_of(finished_run, tmp_path)
    with sqlite3.connect(old / "results.sqlite") as connection:
        for column in ("fit_chi2", "fit_dof"):
            connection.execute(f"ALTER TABLE trials DROP COLUMN {column}")
    connection.close()
    # read and reported as it is: the columns added since read as NaN, the rest unchanged
    as_it_is = read_trials(old)
    assert as_it_is[["fit_chi2", "fit_dof"]].isna().all().all()
    fit = ["fit_chi2", "fit_dof"]
    pd.testing.assert_frame_equal(as_it_is.drop(columns=fit), trials.drop(columns=fit))
    reported = invoke("report", old)
    assert reported.exit_code == 0, reported.output
    assert (pd.read_csv(old / "summary.csv")["n_fit_judged"] == 0).all()
    resumed = invoke("run", "smoke", "-o", old, "--trials", TRIALS + 2, "--resume")
    assert resumed.exit_code == 0, resumed.output
    rows = read_trials(old)
    earlier = rows["trial"] < TRIALS
    assert rows.loc[earlier, ["fit_chi2", "fit_dof"]].isna().all().all()
    assert (rows.loc[~earlier, "fit_dof"] == 18).all() and (~earlier).sum() == 2 * 2 * 2


@pytest.mark.bits(
    "the same summary code on the same rows: read a point at a time from the store, and read "
    "whole then worked 7 rows (one point) at a time and all at once"
)
def test_the_summary_read_a_point_at_a_time_is_that_of_the_whole_frame(finished_run):
    trials = read_trials(finished_run)
    chunks = list(iter_trials(finished_run, SUMMARY_TRIAL_COLUMNS, chunk_rows=7))
    assert [len(chunk) for chunk in chunks] == [2 * TRIALS] * 2  # whole points
    assert "message" not in chunks[0].columns  # text not asked for is not read
    layout = trial_layout(finished_run)
    assert (layout.n_rows, layout.n_trial_sets) == (len(trials), 2)
    assert layout.orders["estimator"] == tuple(pd.unique(trials["estimator"]))
    streamed = summarize_chunks(
        iter(chunks), orders=layout.orders, n_trial_sets=2, n_bootstrap=300, seed=5
    )
    whole = summarize(trials, n_bootstrap=300, seed=5, chunk_rows=len(trials))
    pieces = summarize(trials, n_bootstrap=300, seed=5, chunk_rows=7)
    assert np.isfinite(whole["rmse_ci_low_m"]).all() and (whole["n_trials"] == TRIALS).all()
    pd.testing.assert_frame_equal(streamed, whole, check_exact=True)
    pd.testing.assert_frame_equal(pieces, whole, check_exact=True)


def test_trials_read_in_batches_are_the_rows_read_whole(finished_run, tmp_path):
    trials = read_trials(finished_run)
    batches = list(iter_trials(finished_run, chunk_rows=7, whole_points=False))
    assert [len(batch) for batch in batches[:-1]] == [7] * (len(batches) - 1)
    pd.testing.assert_frame_equal(pd.concat(batches, ignore_index=True), trials)
    whole, in_batches = tmp_path / "whole.csv", tmp_path / "batches.csv"
    write_csv(whole, trials)
    write_csv(in_batches, iter(batches))  # one header, the batches one after another
    assert in_batches.read_bytes() == whole.read_bytes()
    picked = read_trials(finished_run, ["error_m", "estimator"])
    assert list(picked.columns) == ["estimator", "error_m"]  # in the contract's order
    with pytest.raises(ValueError, match=r"columns: \['errors_m'\] are not trial columns"):
        read_trials(finished_run, ["errors_m"])


def test_the_write_ahead_log_is_cut_back_after_a_large_transaction(tmp_path, monkeypatch):
    monkeypatch.setattr(store, "WAL_LIMIT_BYTES", 2**20)
    database = tmp_path / "results.sqlite"
    connection = store.connect(database)
    wal = tmp_path / "results.sqlite-wal"
    with connection:
        connection.execute("CREATE TABLE t (a INTEGER, b TEXT)")
        connection.executemany(
            "INSERT INTO t VALUES (?, ?)", ((i, "x" * 500) for i in range(20000))
        )
    assert wal.stat().st_size > 8 * 2**20  # one transaction is in the log whole
    with connection:  # the next commit checkpoints and cuts the log back
        connection.execute("INSERT INTO t VALUES (1, 'y')")
    assert wal.stat().st_size <= 2**20
    connection.close()
