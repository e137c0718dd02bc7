"""Every result the README states comes from a named command, and is checked here against that
command's output (the main job's numbers are in tests/test_main_job.py).

"Checking the closed form against its convex relaxation": on the 2-D families, with
`emitterbench validate --estimator NAME --instances 200`, cls-paper and cls agree on every
instance with a relative
cost gap below 1e-10, and the midpoint form of docs/writing-an-estimator.md disagrees on every
hard-case instance and on no other.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
CLAIM = re.compile(
    r"With `--instances (\d+)` on the 2-D families\s+\((\d+) instances\), `cls-paper` and `cls` "
    r"agree on every instance, their largest relative cost gap\s+below ([\d.e-]+); the midpoint "
    r"form disagrees on every hard-case instance and on no other"
)
FAMILIES_2D = ("straight", "turn", "turn-weighted", "paper")


def validate(estimator: str, instances: int, folder: Path) -> dict:
    """``emitterbench validate --estimator ESTIMATOR --instances N -o FOLDER`` on the 2-D
    families, as a user runs it; its validate.json."""
    command = [
        *(sys.executable, "-m", "comparison.cli", "validate"),
        *("--estimator", estimator, "--instances", str(instances), "-o", str(folder)),
        *(word for family in FAMILIES_2D for word in ("--families", family)),
    ]
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=900)
    assert done.returncode in (0, 1), done.stderr  # 1: a disagreement, which the JSON lists
    return json.loads((folder / "validate.json").read_text(encoding="utf-8"))


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["cls-paper", "cls"])
def test_the_closed_forms_agree_with_their_relaxation_as_the_readme_says(estimator, tmp_path):
    claim = CLAIM.search(README)
    assert claim, "the README's validate sentence changed: update this test with it"
    instances, total, gap = int(claim.group(1)), int(claim.group(2)), float(claim.group(3))
    result = validate(estimator, instances, tmp_path)
    families = result["families"].values()
    assert sum(f["n"] for f in families) == total
    assert result["ok"] and not result["disagreements"]
    assert all(f["n_disagreements"] == 0 for f in families)
    assert max(f["max_estimator_rel_cost_gap"] for f in families) < gap


@pytest.mark.slow
def test_the_midpoint_form_disagrees_on_every_hard_case_and_no_other(tmp_path):
    instances = int(CLAIM.search(README).group(1))
    result = validate("tests.comparison.test_validate:MidpointCls", instances, tmp_path)
    assert not result["ok"]
    families = result["families"].values()
    assert sum(f["n_hard"] for f in families) >= instances  # one straight frame: mostly hard
    for family in families:
        assert family["n_disagreements"] == family["n_hard"]
