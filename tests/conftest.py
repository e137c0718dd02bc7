"""The suite's markers for comparisons of code paths (the rule is in :mod:`tests.paths`), and
the longest test first."""


def pytest_configure(config) -> None:
    config.addinivalue_line(
        "markers",
        "paths: compares two code paths through tests/paths.py (to rounding, at a tolerance "
        "from the problem's conditioning); run again under a second OpenBLAS kernel",
    )
    config.addinivalue_line(
        "markers",
        "bits(reason): asserts bit equality where the same code runs on the same arrays "
        "(worker counts, resume, the same call twice); the reason says which",
    )


def pytest_collection_modifyitems(config, items) -> None:
    """The rerun of the ``paths`` tests under a second kernel (tests/test_kernels.py, minutes
    in one process) goes first, so that the other worker runs the rest meanwhile."""
    items.sort(key=lambda item: "second_openblas_kernel" not in item.nodeid)
