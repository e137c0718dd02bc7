"""The house rules of docs/architecture.md, checked on the source: imports flow one way
(scenarios → estimators → comparison), files stay small enough to read in one sitting, and
comparison/ learns what an estimator uses only from its declared capabilities."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("scenarios", "estimators", "comparison")
ALLOWED = {
    "scenarios": {"scenarios"},
    "estimators": {"scenarios", "estimators"},
    "comparison": {"scenarios", "estimators", "comparison"},
}
MAX_LINES = {"comparison": 700}
"""The longest file each package may hold (docs/architecture.md)."""


def modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def imported_packages(path: Path) -> set[str]:
    """Top-level project packages a module imports, at any depth of the file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found |= {name.split(".")[0] for name in names} & set(PACKAGES)
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_flow_one_way(package: str) -> None:
    wrong = {
        str(path.relative_to(ROOT)): sorted(imported_packages(path) - ALLOWED[package])
        for path in modules(package)
        if imported_packages(path) - ALLOWED[package]
    }
    assert not wrong, f"imports against the flow scenarios → estimators → comparison: {wrong}"


@pytest.mark.parametrize("package", sorted(MAX_LINES))
def test_files_are_small_enough_to_read(package: str) -> None:
    long = {
        str(path.relative_to(ROOT)): n
        for path in modules(package)
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES[package]
    }
    assert not long, f"files over {MAX_LINES[package]} lines: {long}"


def test_the_engine_reads_in_one_sitting() -> None:
    assert len((ROOT / "comparison" / "engine.py").read_text().splitlines()) <= 500


def test_comparison_reads_no_estimator_option_by_name() -> None:
    """What an estimator uses comes from capabilities(), never from getattr on an option."""
    options = {"use_rss", "frames", "weighting", "filter", "relaxation", "process_noise_mps"}
    guesses = []
    for path in modules("comparison"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in {"getattr", "hasattr"}
                and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and node.args[1].value in options
            ):
                guesses.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not guesses, f"option names guessed instead of capabilities(): {guesses}"
