"""The Python examples of docs/ run as written (each page's blocks in order, one namespace).

A page's blocks build on each other, as a reader would type them: the namespace is a module
named after the file the page tells the reader to save (``my_estimators``), so that classes
defined in it pickle, as the conformance suite requires.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from tests.test_readme import NUMBER, assert_claims, flat

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = sorted(DOCS.glob("*.md"))


def python_blocks(page: Path) -> list[str]:
    """The ``python`` fenced blocks of a Markdown page, indentation of list items removed."""
    text = page.read_text(encoding="utf-8")
    blocks = []
    for match in re.finditer(r"^( *)```python\n(.*?)^\1```", text, re.DOTALL | re.MULTILINE):
        indent = len(match.group(1))
        blocks.append("\n".join(line[indent:] for line in match.group(2).splitlines()))
    return blocks


def test_the_docs_exist_and_link_to_each_other() -> None:
    names = {page.name for page in PAGES}
    assert {
        "architecture.md",
        "measurement-model.md",
        "writing-an-estimator.md",
        "writing-an-experiment.md",
        "dask-cluster.md",
    } <= names
    for page in PAGES:
        for target in re.findall(r"\]\(([\w.-]+\.md)\)", page.read_text(encoding="utf-8")):
            assert target in names, f"{page.name} links to missing {target}"


@pytest.mark.parametrize("page", [p for p in PAGES if python_blocks(p)], ids=lambda p: p.name)
def test_python_examples_run(page: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    module = types.ModuleType("my_estimators")
    monkeypatch.setitem(sys.modules, "my_estimators", module)
    for index, block in enumerate(python_blocks(page)):
        code = compile(block, f"{page.name}[python block {index}]", "exec")
        exec(code, module.__dict__)
    capsys.readouterr()


def test_the_estimator_page_has_its_example_and_runs_the_suite() -> None:
    blocks = "\n".join(python_blocks(DOCS / "writing-an-estimator.md"))
    assert "class SquaredRangeLs" in blocks
    assert "check_estimator(SquaredRangeLs())" in blocks
    assert "parametrize_with_checks(" in blocks


def test_every_check_is_documented() -> None:
    from estimators.checks import CHECK_NAMES

    page = (DOCS / "writing-an-estimator.md").read_text(encoding="utf-8")
    missing = [name for name in CHECK_NAMES if f"`{name}`" not in page]
    assert not missing, f"writing-an-estimator.md does not list {missing}"


def test_every_file_the_docs_name_exists() -> None:
    root = DOCS.parent
    pattern = r"`((?:scenarios|estimators|comparison|tests|examples)/[\w/.-]*\w)"
    named = {
        path for page in PAGES for path in re.findall(pattern, page.read_text(encoding="utf-8"))
    }
    assert len(named) > 20
    missing = sorted(path for path in named if not (root / path).exists())
    assert not missing, f"the docs name missing files: {missing}"


# --------------------------------------------------------------------------------------------
# every count and constant the docs state, against the code
# --------------------------------------------------------------------------------------------

DECIMAL = r"(\d+(?:\.\d+)?)"


def times_its_tolerance_unweighted() -> float:
    """How far ``cls(weighting="none")`` lands from the emitter on the data of
    ``check_leaves_the_track``, in units of that check's tolerance."""
    from estimators.checks import (
        crlb_rmse_m,
        noise_free_tolerance_m,
        on_track_start_data,
        whitened_misfit,
    )
    from estimators.closed_form.cls import Cls

    estimator = Cls(weighting="none")
    data, exact, truth = on_track_start_data()
    modalities = ("doppler", "toa")
    tolerance = whitened_misfit(data, truth, modalities) * crlb_rmse_m(exact, truth, modalities)
    tolerance += noise_free_tolerance_m(estimator)
    error = np.min(np.linalg.norm(estimator.estimate(data).candidates_m - truth, axis=1))
    return round(float(error / tolerance))


def doc_claims() -> dict[str, dict[str, object]]:
    """``{page: {pattern: the code's numbers}}`` for every count and constant the docs state."""
    import tomllib

    from comparison.experiment import AUTO_CHUNK_SIZE, MAX_CHUNK_SAMPLES, Experiment
    from comparison.tasks import AUTO_TASK_ESTIMATES, AUTO_TASKS_PER_WORKER
    from comparison.verdicts import VERDICTS
    from estimators.checks import (
        CRLB_FACTOR,
        CRLB_SNR_DB,
        CRLB_TRIALS,
        EXACT_RTOL,
        EXACT_TOLERANCE_M,
        MAX_NOISE_FREE_TOLERANCE,
        NOISE_FREE_SNR_DB,
        ON_TRACK_START_SHORTFALL_M,
        RANDOM_PROBLEMS,
        reference_problem,
        tolerance_cap_m,
    )
    from scenarios.catalog import get_scenario

    root = DOCS.parent
    packages = re.search(r"include = \[(.*?)\]", (root / "pyproject.toml").read_text()).group(1)
    chunk = {f.name: f.default for f in dataclasses.fields(Experiment)}["chunk_size"]
    assert chunk == AUTO_CHUNK_SIZE
    experiment_page = (DOCS / "writing-an-experiment.md").read_text(encoding="utf-8")
    small = re.search(r'```toml\n(name = "frames-small".*?)```', experiment_page, re.DOTALL)
    turning = get_scenario("paper-1m-turn").flight.frame_velocities_mps
    orbit, beacon = get_scenario("orbit").flight, get_scenario("beacon-pass").flight
    paper = get_scenario("paper-1m").flight
    orbit_turn = np.degrees(
        np.arctan2(orbit.frame_velocities_mps[1, 1], orbit.frame_velocities_mps[1, 0])
    )
    return {
        "architecture.md": {
            rf"emitterbench has {NUMBER} import packages": len(packages.split(",")),
        },
        "math.md": {rf"\*\*The {NUMBER} verdicts\.\*\*": len(VERDICTS)},
        "writing-an-estimator.md": {
            rf"{NUMBER} seeded trials at {NUMBER} dB of `paper-1m` and `far-turn`: side-resolved "
            rf"RMSE at most {NUMBER} ×": (CRLB_TRIALS, CRLB_SNR_DB, CRLB_FACTOR),
            rf"labelled with the σ's of {NUMBER} dB SNR": NOISE_FREE_SNR_DB,
            r'"Exact" means within (1e-\d+) m \(or (1e-\d+) of the': (
                EXACT_TOLERANCE_M,
                EXACT_RTOL,
            ),
            rf"caps a declared tolerance at (1e-\d+) of the problem's RMS slant range \({NUMBER} "
            r"cm on `paper-1m`\)": (
                MAX_NOISE_FREE_TOLERANCE,
                round(100 * tolerance_cap_m(reference_problem("paper-1m"))),
            ),
            rf"and {NUMBER} drawn anew on every run": len(RANDOM_PROBLEMS),
            rf"the first frame's ranges {NUMBER} m short": ON_TRACK_START_SHORTFALL_M,
            rf"{NUMBER} times its tolerance from the emitter": times_its_tolerance_unweighted,
            rf'\(`chunk_size`, "auto" by default: up to {NUMBER} estimates a task\)': (
                AUTO_TASK_ESTIMATES
            ),
        },
        "writing-an-experiment.md": {
            rf'\| `chunk_size` \| no \| `"auto"` \| .* every worker gets at least {NUMBER} '
            rf"tasks and a task holds at most {NUMBER} estimates .* and {NUMBER} simulated "
            "samples": (AUTO_TASKS_PER_WORKER, AUTO_TASK_ESTIMATES, MAX_CHUNK_SAMPLES),
            rf"Per-frame estimates over {NUMBER} frames": tomllib.loads(small.group(1))["frames"],
        },
        "dask-cluster.md": {
            rf'chunks of `chunk_size` trials \("auto" by default.* at least {NUMBER} tasks each': (
                AUTO_TASKS_PER_WORKER
            ),
        },
        "measurement-model.md": {
            rf"`paper-1m-turn` \|[^|]*\|[^|]*\|[^|]*\| {NUMBER} frames east, then {NUMBER} north": (
                int(np.sum(np.abs(turning[:, 1]) < 1e-9 * np.abs(turning[:, 0]))),  # east
                int(np.sum(np.abs(turning[:, 0]) < 1e-9 * np.abs(turning[:, 1]))),  # north
            ),
            rf"`orbit` \|[^|]*\|[^|]*\|[^|]*\| {NUMBER} frames around the emitter, {NUMBER}° per": (
                orbit.n_frames,
                round(orbit_turn),
            ),
            rf"Δ = {DECIMAL} s between samples \({DECIMAL} s on the orbit\) and K = {NUMBER} "
            "samples per frame": (
                paper.sample_interval_s,
                orbit.sample_interval_s,
                paper.samples_per_frame,
            ),
            rf"Δ = {DECIMAL} s, K = {NUMBER} and {NUMBER} frames": (
                beacon.sample_interval_s,
                beacon.samples_per_frame,
                beacon.n_frames,
            ),
        },
    }


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_count_the_docs_state_is_the_codes(page: Path) -> None:
    """The checks' trial counts and tolerances, the defaults, the scenarios' frames and
    samples, the numbers of verdicts and packages: each against the code; and no number before
    a counted noun (checks, estimators, scenarios, planners, ...) without its claim here."""
    claims = doc_claims().get(page.name, {})
    assert_claims(flat(page.read_text(encoding="utf-8")), claims, page.name)


def test_the_guide_names_every_data_field_its_examples_use() -> None:
    """Every ``MeasurementSet`` field, property or view that the guide's code and
    ``examples/plugin`` read is in the guide's data table (``range_m`` and ``gamma_per_m``
    were missing from it once)."""
    from scenarios.types import MeasurementSet

    members = {name for name in dir(MeasurementSet) if not name.startswith("_")}
    guide = DOCS / "writing-an-estimator.md"
    plugin = DOCS.parent / "examples" / "plugin"
    code = "\n".join(
        [*python_blocks(guide), *(path.read_text() for path in sorted(plugin.rglob("*.py")))]
    )
    names = r"\b(?:data|used|frame|seen|geometry|trial_data)\.(\w+)"
    used = {name for name in re.findall(names, code) if name in members}
    assert {"range_m", "gamma_per_m", "position_m", "noise", "iter_frames"} <= used
    text = guide.read_text(encoding="utf-8")
    table = text.split("The data, `scenarios.types.MeasurementSet`", 1)[1].split("## ", 1)[0]
    missing = sorted(n for n in used if f"`{n}`" not in table and f"`{n}(" not in table)
    assert not missing, f"writing-an-estimator.md's data table does not name {missing}"
