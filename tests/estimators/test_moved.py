"""The module paths from before the folders per family still import, as the same modules."""

from __future__ import annotations

import importlib
import sys

import pytest

import estimators
from estimators.moved import MOVED_MODULES


@pytest.mark.parametrize("old", sorted(MOVED_MODULES))
def test_an_old_path_gives_the_module_at_its_home_with_a_warning(old: str) -> None:
    home = importlib.import_module(MOVED_MODULES[old])
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=f"{old} moved to {MOVED_MODULES[old]}"):
        module = importlib.import_module(old)
    assert module is home


def test_the_documented_plugin_imports_keep_working() -> None:
    """docs/writing-an-estimator.md as it read before the folders: the same objects."""
    for old in ("estimators.cls_rows", "estimators.gtrs", "estimators.ekf", "estimators.cls"):
        sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning):
        from estimators.cls_rows import LocalFrame, toa_rows
        from estimators.ekf import Ekf
        from estimators.gtrs import solve_gtrs
    from estimators.closed_form import LocalFrame as frame_now
    from estimators.closed_form import solve_gtrs as gtrs_now
    from estimators.closed_form import toa_rows as rows_now
    from estimators.sequential import Ekf as ekf_now

    assert (LocalFrame, toa_rows, solve_gtrs, Ekf) == (frame_now, rows_now, gtrs_now, ekf_now)
    assert estimators.make_estimator("ekf").__class__ is Ekf


def test_a_path_that_never_existed_is_still_an_import_error() -> None:
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("estimators.no_such_module")
