"""The tests that compare two code paths (``@pytest.mark.paths``, :mod:`tests.paths`) pass
under a second OpenBLAS kernel the CPU supports, not only under the one OpenBLAS picks.

OpenBLAS chooses its kernels by the CPU (``SkylakeX`` with AVX-512, ``Haswell`` with AVX2,
...), and a sum rounds otherwise under each; a bit-equality between two paths that holds
under one fails under another. This test forces the next kernel down
(``OPENBLAS_CORETYPE``), checks that numpy's and scipy's OpenBLAS both run it (the run fails
loudly otherwise), and runs the ``paths`` tests again in a subprocess.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SECOND_KERNEL = (("avx512f", "Haswell"), ("avx2", "Sandybridge"), ("avx", "Nehalem"))
"""The CPU flag of the kernel OpenBLAS picks by default, and the kernel below it to force
(with none of these, ``Prescott``: SSE3, which every x86-64 CPU but the first has)."""
REPORT = (
    "import json, numpy, scipy.linalg; from threadpoolctl import threadpool_info; "
    "print(json.dumps([(i['filepath'], i.get('architecture')) for i in threadpool_info() "
    "if i['internal_api'] == 'openblas']))"
)


def cpu_flags() -> set[str]:
    """The flags of the first CPU in ``/proc/cpuinfo``."""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def second_kernel(flags: set[str]) -> str:
    return next((kernel for flag, kernel in SECOND_KERNEL if flag in flags), "Prescott")


def openblas_kernels(env: dict[str, str]) -> list[tuple[str, str]]:
    """``(library, architecture)`` of every OpenBLAS numpy and scipy load, run with ``env``."""
    out = subprocess.run(
        [sys.executable, "-c", REPORT], env=env, capture_output=True, text=True, check=True
    )
    return [tuple(entry) for entry in json.loads(out.stdout)]


def test_second_kernel_is_the_one_below_the_default() -> None:
    assert second_kernel({"avx512f", "avx2", "avx"}) == "Haswell"
    assert second_kernel({"avx2", "avx", "sse4_2"}) == "Sandybridge"
    assert second_kernel({"sse4_2"}) == "Prescott"


def test_path_comparisons_pass_under_a_second_openblas_kernel(tmp_path: Path) -> None:
    if sys.platform != "linux" or not Path("/proc/cpuinfo").exists():
        pytest.skip("reads the CPU's flags from /proc/cpuinfo (Linux)")
    kernel = second_kernel(cpu_flags())
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
    running = openblas_kernels(env)
    assert running, "numpy and scipy load no OpenBLAS: this test cannot force a kernel"
    wrong = [(library, arch) for library, arch in running if arch != kernel]
    assert not wrong, f"OPENBLAS_CORETYPE={kernel}, but OpenBLAS runs {wrong}"
    command = [sys.executable, "-m", "pytest", "-q", "-m", "paths", "-p", "no:cacheprovider"]
    command.append(f"--basetemp={tmp_path / 'paths'}")  # its own, inside this test's
    result = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    assert result.returncode == 0, (
        f"the paths tests fail under OPENBLAS_CORETYPE={kernel}:\n{result.stdout[-6000:]}"
    )
