"""The command line as the CLI tests call it: one runner, ``invoke`` and the one-line error."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from typer.testing import CliRunner

from comparison.cli import app

runner = CliRunner()


def invoke(*args: str | Path | float) -> Any:
    """``emitterbench`` with ``args`` (anything printable), in process."""
    return runner.invoke(app, [str(a) for a in args])


def clean_error(result: Any, start: str) -> str:
    """Exit 2, nothing on stdout, one line ``error: <start>...`` on stderr; that line."""
    assert result.exit_code == 2, result.output
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"error: {start}"), lines[0]
    return lines[0]
