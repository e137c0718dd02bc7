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


def private_imports(path: Path) -> list[str]:
    """``module:name`` for each private name (``_x``, not ``__x__``) that ``path`` imports
    from another module of the project."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] not in PACKAGES:
                continue
            found += [
                f"{node.module}:{alias.name}"
                for alias in node.names
                if alias.name.startswith("_") and not alias.name.endswith("__")
            ]
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_imports_another_modules_private_names(package: str) -> None:
    reaching = {
        str(path.relative_to(ROOT)): names
        for path in modules(package)
        if (names := private_imports(path))
    }
    assert not reaching, (
        f"private names imported from another module (make them public): {reaching}"
    )


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


# --------------------------------------------------------------------------------------------
# the tests themselves: two code paths agree to rounding (tests/paths.py), and no clock
# --------------------------------------------------------------------------------------------

ENTRY_POINTS = frozenset(
    {
        "estimate",
        "estimate_batch",
        "estimate_columns",
        "estimate_state",
        "least_squares",
        "lmder_batch",
        "run_task",
        "run_experiment",
        "score_outcomes",
        "fly_closed_loop",
        "solve_sdp_relaxation",
    }
)
"""Calls that compute estimates, their rows or their scores: a test reaching two of them
(or one twice) may compare two code paths."""
EXACT_CALLS = frozenset(
    {"array_equal", "assert_array_equal", "assert_equal", "assert_frame_equal", "bits"}
    | {"assert_series_equal", "without_runtime"}
)
"""Exact comparisons of arrays, frames or rows (``bits``: a float by its bytes)."""
ESTIMATE_FIELDS = frozenset({"position_m", "candidates_m", "covariance_m2", "diagnostics"})
"""Compared with ``==`` or ``!=``, these are exact comparisons of estimates."""
PATH_HELPERS = frozenset(
    {"estimate_problems", "path_problems", "frame_problems", "row_problems"}
    | {"position_problems", "covariance_problems", "number_problems", "minpack_problems"}
)
"""The comparisons of :mod:`tests.paths` (and the tests' wrappers of them)."""
CLOCKS = frozenset(
    {"monotonic", "perf_counter", "process_time", "thread_time", "time_ns", "monotonic_ns"}
    | {"perf_counter_ns", "process_time_ns", "now", "utcnow", "today"}
)
"""Calls that read a clock (``time.time`` is matched as ``time.time``)."""


def modules_under_tests() -> dict[str, ast.Module]:
    """Every module under tests/ by its dotted name (tests.paths, the rule's home, included)."""
    return {
        ".".join(path.relative_to(ROOT).with_suffix("").parts): ast.parse(path.read_text())
        for path in sorted((ROOT / "tests").rglob("*.py"))
    }


def call_name(node: ast.Call) -> str | None:
    function = node.func
    if isinstance(function, ast.Attribute):
        return function.attr
    return function.id if isinstance(function, ast.Name) else None


def functions_in(modules: dict[str, ast.Module]) -> dict[tuple[str, str], ast.FunctionDef]:
    """``(module, name) → definition`` of every module-level function under tests/."""
    return {
        (module, node.name): node
        for module, tree in modules.items()
        for node in tree.body
        if isinstance(node, ast.FunctionDef)
    }


def resolver(module: str, tree: ast.Module, functions) -> dict[str, tuple[str, str]]:
    """The names a module can call that are functions under tests/: its own and imported."""
    names = {name: (m, name) for (m, name) in functions if m == module}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tests"):
            for alias in node.names:
                if (node.module, alias.name) in functions:
                    names[alias.asname or alias.name] = (node.module, alias.name)
    return names


def reached(test: ast.FunctionDef, module: str, modules, functions) -> list[tuple[str, ast.AST]]:
    """The test's body and every test helper it calls, transitively (tests.paths excluded:
    it is the rule), as ``(module, node)``."""
    out, todo, seen = [], [(module, test)], set()
    while todo:
        where, node = todo.pop()
        out.append((where, node))
        names = resolver(where, modules[where], functions)
        for call in (n for n in ast.walk(node) if isinstance(n, ast.Call)):
            target = names.get(call_name(call) or "")
            if target and target not in seen and target[0] != "tests.paths":
                seen.add(target)
                todo.append((target[0], functions[target]))
    return out


def literal(node: ast.AST) -> bool:
    """A value written in the test (``[35.0, 15.0]``, ``0.0``, ``-1``): a hand value."""
    if isinstance(node, ast.Constant):
        return True
    if isinstance(node, ast.UnaryOp):
        return literal(node.operand)
    if isinstance(node, ast.List | ast.Tuple):
        return all(literal(e) for e in node.elts)
    if isinstance(node, ast.BinOp):
        return literal(node.left) and literal(node.right)
    return False


def estimate_field(node: ast.AST) -> bool:
    """An estimate's values (not their shape, length, or a tolerance's ``approx``)."""
    if isinstance(node, ast.Attribute) and node.attr in {"shape", "size", "ndim"}:
        return False
    if isinstance(node, ast.Call) and call_name(node) in {"len", "approx", "type", "isinstance"}:
        return False
    return any(isinstance(n, ast.Attribute) and n.attr in ESTIMATE_FIELDS for n in ast.walk(node))


def exact_comparisons(node: ast.AST) -> list[int]:
    """Lines of exact comparisons of two computed arrays, frames, rows or estimates in
    ``node`` (a comparison with a value written in the test is a hand value, not a path)."""
    lines = []
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call) and call_name(sub) in EXACT_CALLS:
            if not any(literal(arg) for arg in sub.args[:2]):
                lines.append(sub.lineno)
        elif isinstance(sub, ast.Compare) and any(
            isinstance(op, ast.Eq | ast.NotEq) for op in sub.ops
        ):
            operands = [sub.left, *sub.comparators]
            if sum(estimate_field(operand) for operand in operands) >= 2:
                lines.append(sub.lineno)
    return lines


def markers(test: ast.FunctionDef) -> dict[str, list[ast.expr]]:
    """``pytest.mark`` names on a test, with their arguments."""
    found = {}
    for decorator in test.decorator_list:
        call = decorator if isinstance(decorator, ast.Call) else None
        target = call.func if call else decorator
        if (
            isinstance(target, ast.Attribute)
            and isinstance(target.value, ast.Attribute)
            and target.value.attr == "mark"
        ):
            found[target.attr] = list(call.args) if call else []
    return found


def path_comparison_problems(modules: dict[str, ast.Module]) -> list[str]:
    """Tests that compare two code paths exactly, or mark it wrongly (tests/paths.py's rule).

    A test that reaches two entry-point calls (:data:`ENTRY_POINTS`) and compares arrays,
    frames, rows or estimates exactly must say why bits are right there:
    ``@pytest.mark.bits("reason")`` (the same code on the same arrays). A test that compares
    through :mod:`tests.paths` is marked ``@pytest.mark.paths`` (so the second OpenBLAS kernel
    runs it) and holds no exact comparison.
    """
    functions = functions_in(modules)
    problems = []
    for (module, name), test in functions.items():
        if not name.startswith("test_"):
            continue
        where = f"{module.replace('.', '/')}.py::{name}"
        bodies = reached(test, module, modules, functions)
        calls = [
            call_name(n)
            for _, body in bodies
            for n in ast.walk(body)
            if isinstance(n, ast.Call) and call_name(n) in ENTRY_POINTS
        ]
        exact = sorted({line for _, body in bodies for line in exact_comparisons(body)})
        helpers = any(
            isinstance(n, ast.Call) and call_name(n) in PATH_HELPERS
            for _, body in bodies
            for n in ast.walk(body)
        )
        marks = markers(test)
        if "paths" in marks and "bits" in marks:
            problems.append(f"{where}: marked both paths and bits")
        elif "paths" in marks and exact:
            problems.append(f"{where}: a paths test compares exactly (lines {exact})")
        elif "bits" in marks and not (
            marks["bits"]
            and isinstance(marks["bits"][0], ast.Constant)
            and str(marks["bits"][0].value).strip()
        ):
            problems.append(f"{where}: bits needs a reason (which code, which same arrays)")
        elif helpers and "paths" not in marks:
            problems.append(f"{where}: compares through tests/paths.py but is not marked paths")
        elif len(calls) >= 2 and exact and "bits" not in marks:
            problems.append(
                f"{where}: reaches {sorted(set(calls))} and compares exactly (lines {exact}): "
                "two code paths agree to rounding (tests/paths.py, @pytest.mark.paths); "
                "@pytest.mark.bits(reason) only where the same code runs on the same arrays"
            )
    return problems


def test_two_code_paths_are_compared_through_the_rule() -> None:
    problems = path_comparison_problems(modules_under_tests())
    assert not problems, "\n".join(problems)


BROKEN_TESTS = """
import numpy as np
import pytest
from estimators.ml.ml import MaximumLikelihood
from tests.estimators.batch_support import path_problems

def test_batch_to_the_bit(batch):
    columns = MaximumLikelihood().estimate_columns(batch)
    single = MaximumLikelihood().estimate(batch.trial(0))
    assert np.array_equal(single.position_m, columns.estimate(0).position_m)

@pytest.mark.paths
def test_marked_but_exact(batch):
    columns = MaximumLikelihood().estimate_columns(batch)
    single = MaximumLikelihood().estimate(batch.trial(0))
    assert single.covariance_m2.tolist() == columns.estimate(0).covariance_m2.tolist()

def test_helper_unmarked(batch):
    columns = MaximumLikelihood().estimate_columns(batch)
    single = MaximumLikelihood().estimate(batch.trial(0))
    assert path_problems(MaximumLikelihood(), batch.trial(0), single, columns.estimate(0)) == []

@pytest.mark.bits()
def test_bits_without_a_reason(batch):
    one, two = MaximumLikelihood().estimate(batch), MaximumLikelihood().estimate(batch)
    assert one.diagnostics == two.diagnostics
"""


def test_the_rule_check_finds_each_way_to_break_it() -> None:
    modules = {"tests.estimators.test_broken": ast.parse(BROKEN_TESTS)} | {
        name: tree for name, tree in modules_under_tests().items() if name.endswith("batch_support")
    }
    problems = path_comparison_problems(modules)
    assert [p.split(": ")[1] for p in problems] == [
        "reaches ['estimate', 'estimate_columns'] and compares exactly (lines [10])",
        "a paths test compares exactly (lines [16])",
        "compares through tests/paths.py but is not marked paths",
        "bits needs a reason (which code, which same arrays)",
    ]
    assert clock_reads(ast.parse("import time\nfrom time import perf_counter\nperf_counter()")) == [
        3
    ]
    assert clock_reads(ast.parse("import time, datetime\ntime.time()\ndatetime.datetime.now()"))


def clock_reads(tree: ast.Module) -> list[int]:
    """Lines that read a clock: ``time.time()``, ``time.monotonic()``, ``perf_counter()``,
    ``datetime.now()``, ... (a name imported from ``time`` or ``datetime`` included)."""
    imported = {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.module in {"time", "datetime"}
        for alias in node.names
    }
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        function = node.func
        if isinstance(function, ast.Attribute):
            owner = function.value
            owner_name = owner.id if isinstance(owner, ast.Name) else getattr(owner, "attr", "")
            if function.attr in CLOCKS or (function.attr == "time" and owner_name == "time"):
                lines.append(node.lineno)
        elif isinstance(function, ast.Name) and function.id in imported & (CLOCKS | {"time"}):
            lines.append(node.lineno)
    return lines


def test_no_test_reads_a_clock() -> None:
    """Timings belong in benchmarks/: a test that reads a clock passes or fails with the load."""
    found = {
        module: lines
        for module, tree in modules_under_tests().items()
        if (lines := clock_reads(tree))
    }
    assert not found, f"tests that read a clock (module: lines): {found}"


# --------------------------------------------------------------------------------------------
# estimators/: a folder per family, a small shared core, no module circles
# --------------------------------------------------------------------------------------------

ESTIMATOR_CORE = frozenset(
    {
        "__init__",
        "base",
        "batch",
        "convergence",
        "frame_model",
        "mirror_rule",
        "goodness_of_fit",
        "interface",
        "moved",
        "registry",
        "validity",
    }
)
"""The modules shared by every family, directly in ``estimators/`` (docs/architecture.md)."""

ESTIMATOR_FAMILIES = frozenset(
    {"baselines", "checks", "closed_form", "dpd", "frontend", "ml", "sdp", "sequential"}
)
"""The folders of ``estimators/``: one per family of methods, the conformance suite, the
per-burst front end (samples to measurements) and direct position determination (samples to a
position)."""


def test_estimators_are_a_core_and_a_folder_per_family() -> None:
    top = {path.stem for path in (ROOT / "estimators").glob("*.py")}
    folders = {
        path.name
        for path in (ROOT / "estimators").iterdir()
        if path.is_dir() and (path / "__init__.py").exists()
    }
    assert top == ESTIMATOR_CORE, (
        f"estimators/ holds modules outside the core: {top ^ ESTIMATOR_CORE}"
    )
    assert folders == ESTIMATOR_FAMILIES, (
        f"unexpected family folders: {folders ^ ESTIMATOR_FAMILIES}"
    )


def test_every_family_states_its_public_api_and_reference() -> None:
    for family in sorted(ESTIMATOR_FAMILIES - {"checks"}):
        init = ast.parse((ROOT / "estimators" / family / "__init__.py").read_text("utf-8"))
        exported = next(
            (
                node.value
                for node in init.body
                if isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
            ),
            None,
        )
        assert ast.get_docstring(init), f"estimators/{family}/__init__.py has no docstring"
        assert isinstance(exported, ast.List) and exported.elts, f"{family} exports nothing"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Every import of a module at any depth, except under ``if TYPE_CHECKING:``."""
    found: list[ast.Import | ast.ImportFrom] = []
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack += node.orelse
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        stack += ast.iter_child_nodes(node)
    return found


def import_graph() -> dict[str, set[str]]:
    """Project module → the project modules it imports (``from package import module`` is an
    edge to the module, not to the package's ``__init__``)."""
    paths = {_module_name(path): path for package in PACKAGES for path in modules(package)}
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        edges = set()
        for node in _runtime_imports(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                edges |= {alias.name for alias in node.names if alias.name in paths}
            elif node.level == 0 and node.module in paths:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    edges.add(sub if sub in paths else node.module)
        graph[name] = edges - {name}
    return graph


def module_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    circles.append(sorted(component))
    return circles


def test_module_circles_are_found() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert module_circles(graph) == [["a", "b", "c"]]


def test_no_module_circles() -> None:
    circles = module_circles(import_graph())
    assert not circles, f"modules that import each other, directly or around a circle: {circles}"
