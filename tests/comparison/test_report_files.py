"""The report's figure files: the same bytes on every report, and each replaced whole."""

from __future__ import annotations

import pandas as pd
import pytest
from matplotlib.figure import Figure

from comparison.report import write_report
from tests.comparison.test_report import synthetic_run, write_run_folder


@pytest.fixture()
def run(tmp_path):
    trials, points, experiment = synthetic_run(
        [{"snr_db": s} for s in (0.0, 10.0, 20.0)], n_trials=30
    )
    write_run_folder(tmp_path, experiment)
    return tmp_path, {"trials": trials, "points": points, "experiment": experiment}


def figure_files(folder) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted((folder / "figures").iterdir())}


@pytest.mark.bits("the same report of the same rows written twice")
def test_two_reports_write_the_same_figure_bytes(run):
    folder, data = run
    write_report(folder, n_bootstrap=100, **data)
    first = figure_files(folder)
    write_report(folder, n_bootstrap=100, **data)
    assert {name.rpartition(".")[2] for name in first} == {"png", "svg"}
    assert figure_files(folder) == first
    assert b"<dc:date>" not in first["rmse.svg"]


def test_an_interrupted_report_keeps_every_old_figure_and_no_temporary_file(run, monkeypatch):
    folder, data = run
    write_report(folder, n_bootstrap=100, **data)
    stale = folder / "figures" / "geometry.svg"  # of an earlier report of another sweep
    stale.write_bytes(b"<svg/>")
    before = figure_files(folder)
    save = Figure.savefig
    calls = []

    def interrupted(self, handle, **options):
        calls.append(options["format"])
        if len(calls) == 3:  # the second figure's PNG: half written, then Ctrl-C (or SIGTERM)
            handle.write(b"\x89PNG half")
            raise KeyboardInterrupt
        return save(self, handle, **options)

    monkeypatch.setattr(Figure, "savefig", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_report(folder, n_bootstrap=100, **data)
    assert figure_files(folder) == before  # the stale one too: nothing deleted yet
    assert not [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]
    monkeypatch.setattr(Figure, "savefig", save)
    write_report(folder, n_bootstrap=100, **data)
    assert not stale.exists()  # gone once the new figures are in place
    assert pd.read_csv(folder / "summary.csv")["n_trials"].eq(30).all()
