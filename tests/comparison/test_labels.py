"""Hostile labels: no CSV cell runs as a spreadsheet formula, no direction control escapes its
label in the report, and a label that is too long or holds a control character is refused at
load in one line.

The estimator classes at the top are test plug-ins (``tests.comparison.test_labels:Name``).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
import pytest
from matplotlib.text import Text

from comparison.csv_cells import (
    FORMULA_TRIGGERS,
    QUOTING,
    csv_text,
    neutralised_frame,
    original_text,
)
from comparison.engine import run_experiment
from comparison.experiment import Experiment, load_experiment
from comparison.labels import BIDI_CONTROLS, MAX_LABEL_CHARS, PLAIN_MARK
from comparison.metrics import summarize
from comparison.report import write_report
from comparison.report_figures import report_figures
from comparison.run_folder import write_csv
from comparison.store import read_trials
from estimators.closed_form.cls import Cls
from tests.comparison.cli_support import clean_error, invoke
from tests.comparison.test_report import synthetic_run

HERE = "tests.comparison.test_labels"
FORMULAS = ("=cmd|' /C calc'!A0", "+SUM(1,1)", '@HYPERLINK("x")', "-x")
RLO = "\u202e"  # right-to-left override
LONG_NAME = "a_package.with_a_rather_long_module_path.for_estimators:AndAVeryLongClassName"


@dataclasses.dataclass(frozen=True, kw_only=True)
class LeadingMessage:
    """``cls`` with a message that begins with ``lead`` (a plug-in's text in trials.csv)."""

    name: ClassVar[str] = "leading-message"
    requires: ClassVar[frozenset[str]] = frozenset({"doppler", "toa"})
    lead: str = "\t"

    def estimate(self, data, *, rng=None):
        return dataclasses.replace(Cls().estimate(data, rng=rng), message=f"{self.lead}=1+1")


def is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_cells(path: Path) -> list[list[str]]:
    with path.open(newline="", encoding="utf-8") as file:
        return list(csv.reader(file))


# --------------------------------------------------------------------------------------------
# CSV
# --------------------------------------------------------------------------------------------


def test_write_csv_quotes_formula_cells_and_leaves_numbers_alone(tmp_path):
    texts = [*FORMULAS, "\tx", "\rx", "\nx", "-3.5", "-inf", "'=x", "''@x", "x;=1+2", "cls", ""]
    numbers = [-3.5, -np.inf, np.nan, -1e-300, 2.0, 0.1, -0.0, np.inf, 7.0, -12.25, 1e308, 5.0]
    numbers += [-2.5e-7, 3.0]
    frame = pd.DataFrame(
        {"label": texts, "value": numbers, "count": range(-7, 7), "ok": [True, False] * 7}
    )
    # a column of mixed objects: only its text is changed
    frame["mixed"] = pd.Series(["=x", -2.5, None, "-1", "@", *[1.0] * 9], dtype=object)
    write_csv(tmp_path / "t.csv", frame)
    header, *rows = read_cells(tmp_path / "t.csv")
    assert header == ["label", "value", "count", "ok", "mixed"]
    assert [row[4] for row in rows][:5] == ["'=x", "-2.5", "", "-1", "'@"]
    expected = [
        "'=cmd|' /C calc'!A0",
        "'+SUM(1,1)",
        '\'@HYPERLINK("x")',
        "'-x",
        "'\tx",
        "'\rx",
        "'\nx",
        "-3.5",  # a number that is text stays as written
        "-inf",
        "''=x",  # a quote already there: one more, so that the change is invertible
        "'''@x",
        "x;=1+2",
        "cls",
        "",
    ]
    assert [row[0] for row in rows] == expected
    assert [original_text(row[0]) for row in rows] == texts
    # the numbers as pandas writes them, negative ones and infinities included
    assert [row[1] for row in rows] == [
        "-3.5",
        "-inf",
        "",
        "-1e-300",
        "2.0",
        "0.1",
        "-0.0",
        "inf",
        "7.0",
        "-12.25",
        "1e+308",
        "5.0",
        "-2.5e-07",
        "3.0",
    ]
    assert [row[2] for row in rows] == [str(n) for n in range(-7, 7)]
    assert [row[3] for row in rows] == ["True", "False"] * 7
    # a text cell is quoted, so a ';' separator (many locales) cannot start a new cell
    assert '"x;=1+2"' in (tmp_path / "t.csv").read_text(encoding="utf-8")


def pandas_csv(frame: pd.DataFrame, *, header: bool = True) -> str:
    return neutralised_frame(frame).to_csv(index=False, header=header, quoting=QUOTING)


def test_csv_text_is_what_pandas_writes_byte_for_byte():
    rng = np.random.default_rng(5)
    n = 400
    texts = [*FORMULAS, "'=x", 'say "hi"', "a,b", "line\nbreak", "-3.5", "", "plain", "\t"]
    numbers = rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)
    numbers[:8] = [0.0, -0.0, np.nan, np.inf, -np.inf, 1e16, 1e-5, 5e-324]
    frame = pd.DataFrame(
        {
            "label": pd.array([texts[i % len(texts)] for i in range(n)], dtype="str"),
            "value": numbers,
            "repeated": np.repeat([0.5, -0.0, 0.0, np.nan], n // 4),
            "count": rng.integers(-(2**62), 2**62, n),
            "small": rng.integers(0, 3, n).astype(np.int32),
            "ok": rng.random(n) < 0.5,
            "text": pd.Series([None, "=1", np.nan, "x"] * (n // 4), dtype=object),
            "missing": pd.array([pd.NA, "@y"] * (n // 2), dtype="string"),
            "=formula name": 1.25,
        }
    )
    assert csv_text(frame) == pandas_csv(frame)
    assert csv_text(frame.iloc[:0]) == pandas_csv(frame.iloc[:0])
    assert csv_text(frame.iloc[5:9], header=False) == pandas_csv(frame.iloc[5:9], header=False)
    # types it leaves to pandas
    mixed = pd.DataFrame({"mixed": pd.Series(["a", 1.0, True], dtype=object)})
    assert csv_text(mixed) is None
    assert csv_text(pd.DataFrame({"f": np.ones(2, np.float32)})) is None
    assert csv_text(pd.DataFrame({0: [1.0]})) is None


def test_the_csv_files_of_a_run_hold_no_live_formula(tmp_path):
    leads = [
        {"name": f"{HERE}:LeadingMessage", "label": "tab", "options": {"lead": "\t"}},
        {"name": f"{HERE}:LeadingMessage", "label": "cr", "options": {"lead": "\r"}},
    ]
    estimators = [{"name": "cls", "label": label} for label in FORMULAS] + leads
    raw = load_experiment("smoke").to_dict()
    raw.pop("swept_columns")
    experiment = Experiment.from_dict({**raw, "name": "+formula", "estimators": estimators})
    out = run_experiment(experiment, tmp_path / "run", workers=1)
    write_report(out, n_bootstrap=100)
    stored = read_trials(out)
    labels = [*FORMULAS, "tab", "cr"]
    for name in ("summary.csv", "trials.csv", "thresholds.csv"):
        header, *rows = read_cells(out / name)
        for cell in (c for row in [header, *rows] for c in row):
            # no cell begins with a trigger, but a number
            assert not cell.startswith(FORMULA_TRIGGERS) or is_number(cell), (name, cell)
        column = header.index("estimator")
        assert {row[column] for row in rows} == {"'" + label for label in FORMULAS} | {"tab", "cr"}
        assert {original_text(row[column]) for row in rows} == set(labels)
    header, *rows = read_cells(out / "trials.csv")
    assert len(rows) == len(stored) == 6 * 2 * 20
    message = {row[header.index("estimator")]: row[header.index("message")] for row in rows}
    assert message["tab"] == "'\t=1+1" and message["cr"] == "'\r=1+1"
    assert {row[header.index("experiment")] for row in rows} == {"'+formula"}
    # every number of the store, negative ones included, reads back the same
    negatives = 0
    for name in stored.columns:
        if not pd.api.types.is_float_dtype(stored[name]):
            continue
        cells = [row[header.index(name)] for row in rows]
        values = stored[name].to_numpy(float)
        assert [math.nan if c == "" else float(c) for c in cells] == pytest.approx(
            values, rel=0, abs=0, nan_ok=True
        )
        negatives += int(np.sum(values < 0))
    assert negatives > 100  # x_m, y_m: some estimates lie west or south of the origin


# --------------------------------------------------------------------------------------------
# HTML and figures
# --------------------------------------------------------------------------------------------


def isolated_labels(root: ET.Element, labels: set[str]) -> list[str]:
    """The labels holding a direction control, each where the page shows it; fails if such a
    control appears anywhere but as the whole text of a ``<bdi>``."""
    found = []
    for element in root.iter():
        assert not any(c in value for value in element.attrib.values() for c in BIDI_CONTROLS)
        if element.text and any(c in element.text for c in BIDI_CONTROLS):
            assert element.tag == "bdi" and len(element) == 0, (element.tag, element.text)
            assert element.text in labels
            found.append(element.text)
        assert not (element.tail and any(c in element.tail for c in BIDI_CONTROLS)), element.tail
    return found


def test_a_label_with_a_direction_control_is_isolated_everywhere_the_report_shows_it(tmp_path):
    trials, points, experiment = synthetic_run(
        [{"snr_db": s} for s in (-10.0, 0.0, 10.0)], n_trials=60
    )
    # lls-toa fails in a fifth of the trials below 0 dB: named in a note; ml flags ambiguity
    renamed = {"lls-toa": f"{RLO}lls-toa", "ml": f"ml{RLO}"}
    trials = trials.replace({"estimator": renamed})
    experiment = {
        **experiment,
        "name": f"{RLO}synthetic",
        "estimators": [renamed.get(n, n) for n in experiment["estimators"]],
    }
    html_path = write_report(
        tmp_path, trials=trials, points=points, experiment=experiment, run_info={}, dpi=40
    )
    root = ET.parse(html_path).getroot()
    found = isolated_labels(root, {*renamed.values(), experiment["name"]})
    notes = next(s for s in root.iter("section") if s.get("id") == "verdicts").find("ul")
    in_notes = [b.text for li in notes for b in li.iter("bdi")]
    assert f"{RLO}lls-toa" in in_notes and f"ml{RLO}" in in_notes  # failures, side-resolved
    # the heading, the verdict table, the notes, the summary tables, the experiment overview
    assert found.count(f"{RLO}lls-toa") >= 5 and found.count(experiment["name"]) == 2
    assert root.find(".//title").text == f"emitterbench report: {PLAIN_MARK}synthetic"
    # the figures draw each control as U+FFFD
    texts = [
        text.get_text()
        for _, _, figure in report_figures(summarize(trials, n_bootstrap=50), trials, points, None)
        for text in figure.findobj(Text)
    ]
    assert not any(c in t for t in texts for c in BIDI_CONTROLS)
    assert any(f"{PLAIN_MARK}lls-toa" in t for t in texts)


def test_planner_and_estimator_labels_of_a_closed_loop_are_isolated(tmp_path):
    experiment = Experiment.from_dict(
        {
            "name": "closed",
            "scenarios": ["paper-1m"],
            "estimators": [{"name": "cls", "label": f"=cls{RLO}"}],
            "planners": [{"name": "constant", "label": f"@line{RLO}"}],
            "trials": 3,
            "seed": 3,
            "frames": 2,
            "per_frame": True,
        }
    )
    out = run_experiment(experiment, tmp_path / "run", workers=1)
    root = ET.parse(write_report(out, n_bootstrap=100, dpi=40)).getroot()
    found = isolated_labels(root, {f"=cls{RLO}", f"@line{RLO}"})
    flights = next(s for s in root.iter("section") if s.get("id") == "flights")
    assert [b.text for b in flights.iter("bdi")] == [f"@line{RLO}", f"=cls{RLO}"]
    assert found.count(f"@line{RLO}") >= 4  # planner table, steering, tables, overview
    header, *rows = read_cells(out / "flights.csv")
    assert {row[header.index("planner")] for row in rows} == {f"'@line{RLO}"}


# --------------------------------------------------------------------------------------------
# refused at load
# --------------------------------------------------------------------------------------------


def experiment_file(tmp_path: Path, tables: str, name: str = "labels") -> Path:
    """An experiment file: ``name``, then the ``[[estimators]]`` and ``[[planners]]`` tables."""
    head = f'name = "{name}"\nscenarios = ["paper-1m"]\ntrials = 2\nseed = 1\n'
    if "[[planners]]" in tables:
        head += 'per_frame = true\n[[estimators]]\nname = "cls"\n'
    path = tmp_path / "e.toml"
    path.write_text(head + tables, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("estimators", "start", "fix"),
    [
        (
            f'[[estimators]]\nname = "cls"\nlabel = "{"x" * 10_000}"\n',
            "estimators[0].label: 10,000 characters ('xxxxxxxxxxxxxxxxxxxx'...), more than "
            f"the limit of {MAX_LABEL_CHARS}",
            "give a shorter one",
        ),
        (
            f'[[estimators]]\nname = "{LONG_NAME}"\n',
            f"estimators[0].label: {len(LONG_NAME)} characters ('a_package.with_a_rat'...), "
            f"more than the limit of {MAX_LABEL_CHARS}",
            "give the entry a shorter label (without one, the label is the name)",
        ),
        (
            '[[estimators]]\nname = "cls"\nlabel = "a\\nb"\n',
            "estimators[0].label: 'a\\nb' holds the control character U+000A at position 1",
            "a label is one line of printable text, remove it",
        ),
        (
            '[[planners]]\nname = "constant"\nlabel = "\\u0085next"\n',
            "planners[0].label: '\\x85next' holds the control character U+0085 at position 0",
            "remove it",
        ),
        (
            '[[estimators]]\nname = "cls"\nlabel = "ab"\n'
            '[[estimators]]\nname = "ml"\nlabel = "a\\u202eb"\n',
            "estimators[1].label: duplicate label 'a\\u202eb' (also estimators[0], read as "
            "'ab': they differ only in direction controls)",
            "give each entry a distinct label",
        ),
    ],
)
def test_a_bad_label_is_refused_at_load_in_one_line(tmp_path, estimators, start, fix):
    path = experiment_file(tmp_path, estimators)
    line = clean_error(invoke("run", path, "-o", tmp_path / "out"), start)
    assert line.endswith(fix)
    assert not (tmp_path / "out").exists()


def test_the_experiment_name_is_a_label_too(tmp_path):
    path = experiment_file(tmp_path, '[[estimators]]\nname = "cls"\n', name="n" * 65)
    line = clean_error(invoke("run", path, "-o", tmp_path / "out"), "name: 65 characters")
    assert line.endswith("give a shorter one")
    # at the limit it loads
    assert (
        Experiment.from_dict(
            {
                "name": "n" * MAX_LABEL_CHARS,
                "scenarios": ["paper-1m"],
                "estimators": ["cls"],
                "trials": 1,
                "seed": 0,
            }
        ).name
        == "n" * MAX_LABEL_CHARS
    )
