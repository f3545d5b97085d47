"""House conventions (STYLE.md): the tree stays ruff- and mypy-clean."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["common", "station", "drivers", "procedures", "reports"]


def _tool(name: str) -> list[str]:
    exe = Path(sys.executable).with_name(name)
    if exe.exists():
        return [str(exe)]
    found = shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (python3 dev.py test installs it)")
    return [found]


def test_ruff_finds_nothing() -> None:
    done = subprocess.run([*_tool("ruff"), "check", "."], cwd=ROOT, capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_mypy_finds_nothing() -> None:
    done = subprocess.run([*_tool("mypy"), *PACKAGES], cwd=ROOT, capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_lint_imports_keeps_every_contract() -> None:
    """The layering as a contract (pyproject.toml [tool.importlinter]): station -> reports ->
    procedures -> drivers, no drivers.sim below the station, the rules inside procedures, no
    cycle between the siblings of any package."""
    done = subprocess.run([*_tool("lint-imports"), "--no-cache"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout, done.stdout


# Import cycles still in the tree, each named by one of its modules (issue 27 emptied it). The
# list may only shrink: a new cycle fails this test, and so does one fixed but still listed.
KNOWN_CYCLES: dict[str, str] = {}


def test_import_cycles_only_shrink() -> None:
    from tests.import_graph import cycles, graph

    found = cycles(graph(ROOT, PACKAGES))
    unknown = [sorted(c) for c in found if not c & KNOWN_CYCLES.keys()]
    assert not unknown, f"new import cycles: {unknown}"
    gone = [k for k in KNOWN_CYCLES if not any(k in c for c in found)]
    assert not gone, f"cycles fixed: take {gone} out of KNOWN_CYCLES"


def test_import_graph_counts_imports_in_function_bodies(tmp_path: Path) -> None:
    """An import inside a function is an edge of the graph (it can close a cycle at run
    time); one under `if TYPE_CHECKING:` is not (never run)."""
    from tests.import_graph import cycles, graph

    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("import pkg.b\n")
    (pkg / "b.py").write_text("def f():\n    from pkg import a\n    return a\n")
    (pkg / "c.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import a\n")
    g = graph(tmp_path, ["pkg"])
    assert "pkg.a" in g["pkg.b"] and "pkg.a" not in g["pkg.c"]
    assert cycles(g) == [frozenset({"pkg.a", "pkg.b"})]


# each may import only those before it
LAYERS = ("common", "drivers", "procedures", "reports", "station")


def test_dependencies_run_one_way() -> None:
    """station -> reports -> procedures -> drivers -> common: no module imports a layer
    above its own, not even inside a function body (reports read records, never the station)."""
    from tests.import_graph import graph

    rank = {name: i for i, name in enumerate(LAYERS)}
    upward = sorted(
        f"{module} -> {dep}"
        for module, deps in graph(ROOT, PACKAGES).items()
        for dep in deps
        if rank[dep.split(".")[0]] > rank[module.split(".")[0]]
    )
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


LONG_FUNCTION_LINES = 80  # a function this long or longer does more than one thing
# Functions still that long (issue 27), being split by other changes. The list may only
# shrink: a new long function fails this test, and so does one shortened but still listed.
KNOWN_LONG: set[str] = set()


def test_every_name_is_imported_from_the_module_that_defines_it() -> None:
    """One import path per name: no module re-exports another's names (issue 27)."""
    from tests.import_graph import reexports_used

    readers = [p for d in (*PACKAGES, "tests", "benchmarks", "scripts")
               for p in (ROOT / d).rglob("*.py")]
    found = reexports_used(ROOT, PACKAGES, readers)
    assert not found, "import these from the module that defines them:\n" + "\n".join(found)


def _long_functions() -> dict[str, int]:
    """file:function -> its length in lines (def to last line, decorators excluded) for every
    function of LONG_FUNCTION_LINES or more in the packages and the benchmarks."""
    import ast

    found: dict[str, int] = {}
    for package in (*PACKAGES, "benchmarks"):
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    length = (node.end_lineno or node.lineno) - node.lineno + 1
                    if length >= LONG_FUNCTION_LINES:
                        found[f"{path.relative_to(ROOT).as_posix()}:{node.name}"] = length
    return found


def test_no_function_of_80_lines_or_more() -> None:
    found = _long_functions()
    new = sorted(f"{name}:{length}" for name, length in found.items() if name not in KNOWN_LONG)
    assert not new, f"functions of {LONG_FUNCTION_LINES} lines or more: split them:\n" + "\n".join(
        new
    )
    fixed = sorted(KNOWN_LONG - found.keys())
    assert not fixed, f"shortened below {LONG_FUNCTION_LINES} lines: take {fixed} out of KNOWN_LONG"


_IMPORT_EVERY_MODULE = """
import importlib, pkgutil, warnings
warnings.simplefilter("error")
for top in {packages!r}:
    for info in pkgutil.walk_packages(importlib.import_module(top).__path__, top + "."):
        # __main__ runs the CLI; alembic's env.py runs only inside alembic
        if not info.name.endswith(("__main__", "migrations.env")):
            importlib.import_module(info.name)
"""


def test_every_module_imports_without_a_warning() -> None:
    """A warning raised on import prints before every `station` command's own output (and
    broke the one-line error tests on a fresh install with cryptography 51): none may be
    raised with today's newest allowed versions of the dependencies."""
    done = subprocess.run([sys.executable, "-W", "error", "-c",
                           _IMPORT_EVERY_MODULE.format(packages=PACKAGES)],
                          cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stderr == "", done.stderr
