"""The README's promises: its test command is what CI runs, and the files it names exist."""

from __future__ import annotations

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
