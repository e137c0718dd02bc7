"""The README's promises: its test command is what CI runs, the files it names exist, and every
count and limit it states is the code's."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def readme_commands() -> list[str]:
    """The two commands of the README's first code block (lines that are not comments)."""
    block = README.split("```bash", 1)[1].split("```", 1)[0]
    return [line for line in block.strip().splitlines() if not line.startswith("#")]


def test_readme_starts_with_exactly_two_commands() -> None:
    commands = readme_commands()
    assert len(commands) == 2
    assert "emitterbench run paper-fig2" in commands[0]
    assert commands[1].rstrip().endswith("pytest -n 2")


def test_ci_runs_the_readme_test_command() -> None:
    ci_script = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert readme_commands()[1] in ci_script.splitlines()


def test_every_file_the_readme_names_exists() -> None:
    named = set(re.findall(r"`((?:scenarios|estimators|comparison|benchmarks)/[\w/]+\.py)", README))
    assert named, "the README names no source file"
    missing = sorted(path for path in named if not (ROOT / path).exists())
    assert not missing, f"README names missing files: {missing}"


# --------------------------------------------------------------------------------------------
# every count and limit the README states, against the code
# --------------------------------------------------------------------------------------------

NUMBER_WORDS = {
    "one": 1,
    "two": 2,
    "three": 3,
    "four": 4,
    "five": 5,
    "six": 6,
    "seven": 7,
    "eight": 8,
    "nine": 9,
    "ten": 10,
    "eleven": 11,
    "twelve": 12,
}
NUMBER = r"(\d[\d ,]*\d|\d|" + "|".join(NUMBER_WORDS) + ")"
"""A count as prose writes it: digits (with thousands spaced or comma'd) or a word."""

COUNTED = (
    r"(?:named |built-in )?(?:checks?|estimators?|scenarios?|experiments?|families|planners?|"
    r"verdicts?|import packages)\b"
)
"""The nouns whose counts are the code's: a number before one of them must be checked."""


def number_of(text: str) -> float:
    """``"1 000 000"``, ``"10,000"``, ``"four"``, ``"0.9"`` as a number."""
    word = text.strip().lower()
    if word in NUMBER_WORDS:
        return NUMBER_WORDS[word]
    return float(re.sub(r"[ ,]", "", word))


def flat(text: str) -> str:
    """The text with every run of whitespace one space (a claim may break across lines)."""
    return re.sub(r"\s+", " ", text)


def stated_counts(text: str, claims: dict[str, object]) -> tuple[dict[str, list], set]:
    """``{pattern: numbers it captures}`` in ``text``, and the spans of those numbers."""
    found, spans = {}, set()
    for pattern in claims:
        match = re.search(pattern, text)
        assert match, f"the text no longer says {pattern!r}: update the claim with the text"
        found[pattern] = [number_of(group) for group in match.groups()]
        spans |= {match.span(i) for i in range(1, len(match.groups()) + 1)}
    return found, spans


def assert_claims(text: str, claims: dict[str, object], where: str) -> None:
    """Each claim's numbers equal the code's, and every number before a counted noun in
    ``text`` is some claim's (a new count needs a test)."""
    found, spans = stated_counts(text, claims)
    for pattern, expected in claims.items():
        values = expected() if callable(expected) else expected
        values = list(values) if isinstance(values, tuple | list) else [values]
        assert found[pattern] == [float(v) for v in values], (where, pattern, found[pattern])
    # not a section (§14) nor a TOML value ahead of the next line's key ("frames = 1 estimators")
    counted = r"(?<![§\w.-])(?<!= )" + NUMBER + " " + COUNTED
    for match in re.finditer(counted, text, re.IGNORECASE):
        if match.group(1).lower() == "one":
            continue  # "one straight frame", "one estimator per row": not a count of the code's
        assert match.span(1) in spans, f"{where}: {match.group(0)!r} is checked by no test"


def applicable_checks() -> tuple[int, int]:
    """The fewest and most checks that apply to a built-in with default options."""
    from estimators.checks import estimator_checks
    from estimators.registry import BUILTIN, make_estimator

    counts = [
        len(list(estimator_checks(make_estimator(name))))
        for name, entry in BUILTIN.items()
        if entry.is_available()
    ]
    return min(counts), max(counts)


def readme_claims() -> dict[str, object]:
    from comparison.crosscheck.instances import FAMILIES
    from comparison.experiment import MAX_TRIALS, Experiment
    from comparison.experiment_catalog import BUILTIN_DEFINITIONS
    from comparison.intervals import TAIL_FRACTION
    from comparison.sweep import MAX_POINTS
    from comparison.verdicts import (
        BIAS_LIMIT,
        EFFICIENCY_BAND,
        MIN_SUCCESS_RATE,
        MIN_TRIALS,
        TAIL_SHARE_LIMIT,
    )
    from estimators.checks import CHECK_NAMES
    from scenarios.limits import MAX_FILE_MB, MAX_FRAMES, MAX_SAMPLES
    from scenarios.planners.base import DEFAULT_MAX_SPEED_MPS
    from scenarios.types import RANGE_DEFICIT_SIGMAS

    defaults = {f.name: f.default for f in dataclasses.fields(Experiment)}
    low, high = applicable_checks()
    return {
        rf"\({NUMBER} named checks": len(CHECK_NAMES),
        rf"{NUMBER} to {NUMBER} on the built-ins": (low, high),
        rf"paper-fig2 # accuracy vs SNR \(paper Fig\. 2\), {NUMBER} estimators": len(
            BUILTIN_DEFINITIONS["paper-fig2"]["estimators"]
        ),
        rf"run frames -o out/frames # {NUMBER} frames": BUILTIN_DEFINITIONS["frames"]["frames"],
        rf"the paper's Fig\. 3, {NUMBER} planners": len(
            BUILTIN_DEFINITIONS["paper-fig3"]["planners"]
        ),
        rf"random instances of {NUMBER} families": len(FAMILIES),
        (
            rf"a {NUMBER} MiB file, {NUMBER} samples or {NUMBER} frames, {NUMBER} trials per "
            rf"point, {NUMBER} sweep points"
        ): (MAX_FILE_MB, MAX_SAMPLES, MAX_FRAMES, MAX_TRIALS, MAX_POINTS),
        rf"beyond {NUMBER} σ": RANGE_DEFICIT_SIGMAS,
        rf"`time_limit_s`, {NUMBER} s by default": defaults["time_limit_s"],
        rf"`max_speed_mps` \({NUMBER} m/s by default\)": DEFAULT_MAX_SPEED_MPS,
        (
            r"inside \[(0\.\d+), (1\.\d+)\], the bias \(the mean error\) is at most (0\.\d+) √CRLB "
            r"over its whole interval, no principal axis of the CRLB is wholly above the band, "
            r"with ≥ (\d+) successful trials, ≥ (\d+)% successes"
        ): (*EFFICIENCY_BAND, BIAS_LIMIT, MIN_TRIALS, round(100 * MIN_SUCCESS_RATE)),
        r"the bias lies beyond (0\.\d+) √CRLB": BIAS_LIMIT,
        r"the largest (\d+)% of trials carry > (\d+)%": (
            round(100 * TAIL_FRACTION),
            round(100 * TAIL_SHARE_LIMIT),
        ),
        r"Python ≥ 3\.(\d+)": int(PYPROJECT_PYTHON.split(".")[1]),
    }


PYPROJECT_PYTHON = re.search(
    r'requires-python = ">=(\d+\.\d+)"', (ROOT / "pyproject.toml").read_text(encoding="utf-8")
).group(1)


def test_every_count_and_limit_the_readme_states_is_the_codes() -> None:
    """ "31 named checks", "7 estimators", "four planners", the limits and defaults: each
    against the code, and no count before a counted noun without its claim here."""
    assert_claims(flat(README), readme_claims(), "README.md")


def test_with_ten_trials_every_verdict_is_inconclusive_as_the_readme_says() -> None:
    from comparison.verdicts import MIN_TRIALS

    match = re.search(r"with (\d+) every verdict is `inconclusive`", flat(README))
    assert match and int(match.group(1)) < MIN_TRIALS
