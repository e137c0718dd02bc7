"""The Python examples of docs/ run as written (each page's blocks in order, one namespace).

A page's blocks build on each other, as a reader would type them: the namespace is a module
named after the file the page tells the reader to save (``my_estimators``), so that classes
defined in it pickle, as the conformance suite requires.
"""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

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
