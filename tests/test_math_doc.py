"""docs/math.md: every cited section exists, and its errata numbers are what the code computes.

The code, the docs and the reports cite "MATH §N" for section §N of ``docs/math.md``. The page
quotes the errata with the snippets that compute them, each ``python`` block followed by a
``text`` block with what it prints; the snippets are run here and their output must equal the
page's, so the page cannot drift from the code silently. The main errata are also checked
directly, independently of the page's wording.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
MATH = ROOT / "docs" / "math.md"
PAGE = MATH.read_text(encoding="utf-8")
CITING_DIRECTORIES = ("scenarios", "estimators", "comparison", "docs", "tests", "examples")
CITATION = re.compile(r"§ ?(\d+)")
SECTION_HEADING = re.compile(r"^## §(\d+) \S.*$", re.MULTILINE)
SNIPPET = re.compile(r"^```python\n(.*?)^```\n\n```text\n(.*?)^```$", re.DOTALL | re.MULTILINE)


def citing_files() -> list[Path]:
    files = [ROOT / "README.md"]
    for directory in CITING_DIRECTORIES:
        for suffix in ("*.py", "*.md"):
            files.extend((ROOT / directory).rglob(suffix))
    return sorted(path for path in files if path.is_file())


def cited_sections() -> dict[int, str]:
    """Every section number cited, with one place that cites it: the project has one document
    with numbered sections, docs/math.md, so every ``§N`` anywhere is one of its sections."""
    cited: dict[int, str] = {}
    for path in citing_files():
        text = path.read_text(encoding="utf-8")
        for match in CITATION.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            cited.setdefault(int(match.group(1)), f"{path.relative_to(ROOT)}:{line}")
    return cited


def heading_sections() -> set[int]:
    """The section numbers of the page's headings (lines starting with ``#``)."""
    headings = [line for line in PAGE.splitlines() if line.startswith("#")]
    return {int(number) for line in headings for number in CITATION.findall(line)}


def snippets() -> list[tuple[str, str, str]]:
    """``(id, code, printed)`` of every snippet, the id naming its section."""
    found = []
    for index, match in enumerate(SNIPPET.finditer(PAGE)):
        sections = SECTION_HEADING.findall(PAGE, 0, match.start())
        found.append((f"section{sections[-1]}-{index}", match.group(1), match.group(2)))
    return found


# --------------------------------------------------------------------------------------------
# structure
# --------------------------------------------------------------------------------------------


def test_every_cited_section_is_a_heading_of_the_page() -> None:
    cited = cited_sections()
    assert len(cited) >= 10, "the citation scan found almost nothing: check the paths"
    headings = heading_sections()
    missing = {f"§{number}": where for number, where in cited.items() if number not in headings}
    assert not missing, f"sections cited but not in docs/math.md: {missing}"


def test_the_sections_are_numbered_from_0_in_order() -> None:
    numbers = [int(number) for number in SECTION_HEADING.findall(PAGE)]
    assert numbers == list(range(len(numbers))) and len(numbers) >= 18
    assert PAGE.rindex("\n## §") == PAGE.index(f"\n## §{numbers[-1]} ")  # the last is last


def test_every_python_block_is_a_snippet_with_its_output() -> None:
    assert PAGE.count("```python\n") == len(snippets()) >= 10


# --------------------------------------------------------------------------------------------
# the snippets print what the page shows
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("code", "printed"),
    [pytest.param(code, printed, id=name) for name, code, printed in snippets()],
)
def test_snippet_prints_what_the_page_shows(code: str, printed: str) -> None:
    output = io.StringIO()
    with contextlib.redirect_stdout(output):
        exec(compile(code, str(MATH), "exec"), {"__name__": "math_doc_snippet"})
    assert output.getvalue() == printed


# --------------------------------------------------------------------------------------------
# the errata, checked directly
# --------------------------------------------------------------------------------------------


def test_the_printed_rows_put_the_paper_emitter_at_52_2() -> None:
    """§4: without the height term the noise-free answer is (35, ±52.2), not (35, ±15)."""
    from estimators import make_estimator
    from scenarios import get_scenario, noise_free

    data = noise_free(get_scenario("paper"), snr_db=0.0)
    printed = make_estimator("cls-as-printed").estimate(data).candidates_m
    fixed = make_estimator("cls-paper").estimate(data).candidates_m
    assert np.allclose(np.sort(printed[:, 1]), [-52.2, 52.2], atol=0.1)
    assert np.allclose(printed[:, 0], 35.0, atol=1e-6)
    assert np.allclose(np.sort(fixed[:, 1]), [-15.0, 15.0], atol=1e-6)
    assert "(35, ±52.2) instead of (35, ±15)" in PAGE


def test_the_printed_doppler_line_vanishes_flying_north() -> None:
    """§3: the first row of the rank-one system is all zeros when v_x = 0 (cls-as-printed's
    Doppler row, the first of its system, on a northbound frame)."""
    from estimators.closed_form.cls import cls_rows
    from estimators.closed_form.cls_rows import LocalFrame
    from scenarios import FlightPlan, get_scenario, noise_free

    north = get_scenario("paper-1m").replace(
        emitter_m=[-15.0, 35.0],
        flight=FlightPlan(
            start_position_m=[0, 0, 50],
            frame_velocities_mps=[[0, 10, 0]],
            samples_per_frame=10,
            sample_interval_s=0.05,
        ),
    )
    data = noise_free(north)
    A, b = cls_rows(data, LocalFrame.fit(data.position_m, data.range_m), "as-printed")
    assert len(A) == 11  # one Doppler row for the frame, then ten ToA rows
    assert np.array_equal(A[0], np.zeros(3)) and b[0] == 0.0
    assert "printed row [0.0, 0.0, 0.0] = 0" in PAGE


def test_one_straight_frame_is_the_hard_case_with_two_minimisers() -> None:
    """§5: rank B⁺ = 2, λ* = 0 and the emitter and its mirror at equal cost."""
    from estimators.closed_form.gtrs import solve_gtrs
    from estimators.registry import make_estimator
    from scenarios import get_scenario, noise_free, simulate

    scenario = get_scenario("paper-1m")
    paper = make_estimator("cls-paper")
    exact = paper.estimate(noise_free(scenario))
    info = exact.diagnostics
    assert info["rank"] == 2 and info["hard_case"] and info["multiplier"] == 0.0
    assert np.allclose(
        sorted(exact.candidates_m.tolist()), [[35.0, -15.0], [35.0, 15.0]], atol=1e-6
    )
    system = paper.constrained_ls(simulate(scenario, seed=0))
    noisy = solve_gtrs(system.A, system.b)
    assert noisy.hard_case and len(noisy.points) == 2
    assert noisy.costs[0] == pytest.approx(noisy.costs[1], rel=1e-12)
    assert "rank 2, hard case True, lambda* = 0" in PAGE


def test_toa_alone_is_useless_on_paper_and_doppler_alone_localises() -> None:
    """§8/§14: c σ_τ = 300 km bounds ToA alone at ~1e7 m; Doppler alone is nonsingular."""
    from comparison.crlb import fisher_information, rmse_bound_m
    from scenarios import get_scenario, noise_free

    def bound(name: str, modalities: str) -> float:
        scenario = get_scenario(name)
        data = noise_free(scenario, snr_db=0.0)
        return float(rmse_bound_m(fisher_information(data, scenario.emitter_m, modalities)))

    assert bound("paper", "toa") > 1e6
    assert np.isfinite(bound("paper", "doppler")) and bound("paper", "doppler") < 100.0
    assert bound("paper", "toa+doppler") == pytest.approx(bound("paper", "doppler"), rel=1e-6)
    assert bound("paper-1m", "toa+doppler") == pytest.approx(1.06, abs=0.005)
    assert "9.78e+06" in PAGE and "34.9" in PAGE


def test_the_paper_trajectory_rule_is_an_exact_tie() -> None:
    """§12: both circle roots are equally far from ŝ at every horizon; one is the old velocity."""
    from scenarios import get_scenario, noise_free
    from scenarios.planners.paper import circle_roots_mps, predict_next_rhs_m2ps

    scenario = get_scenario("paper-1m")
    data = noise_free(scenario)
    b = data.position_m[-1, :2] - np.array([35.0, 15.0])
    delta = scenario.flight.sample_interval_s
    d = predict_next_rhs_m2ps(scenario.flight, data) - delta * 10.0**2
    roots = circle_roots_mps(b, d, 10.0)
    assert roots is not None
    for t in (delta, 0.5, 2.0, 10.0):
        near, far = np.linalg.norm(b + t * roots, axis=1)
        assert near == pytest.approx(far, rel=1e-12)
    assert np.allclose(roots[0], [10.0, 0.0], atol=1e-9)
    assert "paper's rule, tied: True" in PAGE
