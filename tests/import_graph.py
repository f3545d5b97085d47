"""The import graph of the product's packages, read from the source (ast): every import,
at module level or inside a function body (but not under `if TYPE_CHECKING:`), of one
product module by another (a module also depends on the packages it sits in, whose __init__
runs first). Used by test_code_quality."""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path


def modules(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    found: dict[str, Path] = {}
    for pkg in packages:
        for path in (root / pkg).rglob("*.py"):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def _targets(node: ast.Import | ast.ImportFrom, name: str, is_package: bool) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:
        here = name.split(".") if is_package else name.split(".")[:-1]
        here = here[: len(here) - (node.level - 1)]
        base = ".".join([*here, *([node.module] if node.module else [])])
    return [base] + [f"{base}.{a.name}" for a in node.names]


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of the module except those under `if TYPE_CHECKING:` (read
    by the type checker only, never run)."""
    found: list[ast.Import | ast.ImportFrom] = []
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            todo.extend(node.orelse)
        else:
            todo.extend(ast.iter_child_nodes(node))
    return found


def graph(root: Path, packages: Iterable[str]) -> dict[str, set[str]]:
    mods = modules(root, packages)
    out: dict[str, set[str]] = {}
    for name, path in mods.items():
        deps: set[str] = set()
        for node in _imports(ast.parse(path.read_text(encoding="utf-8"))):
            for target in _targets(node, name, path.name == "__init__.py"):
                parts = target.split(".")
                deps |= {q for i in range(1, len(parts) + 1)
                         if (q := ".".join(parts[:i])) in mods}
        deps.discard(name)
        out[name] = deps
    return out


def cycles(g: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []
    for start in sorted(g):
        if start in index:
            continue
        work = [(start, iter(sorted(g[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(g[child]))))
                elif child in on_stack:
                    low[v] = min(low[v], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(frozenset(comp))
    return found


def _defined(tree: ast.Module) -> set[str]:
    """The names a module binds itself: its classes, functions and assignments, at top level
    or inside a top-level `if`/`try` (an optional dependency's fallback)."""
    names: set[str] = set()
    for top in tree.body:
        for node in ast.walk(top) if isinstance(top, ast.If | ast.Try) else [top]:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return names


def reexports_used(root: Path, packages: Iterable[str], readers: Iterable[Path]) -> list[str]:
    """`from M import name` in `readers` where M is a product module that does not define
    `name` itself (nor has a submodule of that name): a name reached through a re-export.
    Each as 'file:line: M.name'."""
    mods = modules(root, packages)
    defined: dict[str, set[str]] = {}
    found: list[str] = []
    for path in readers:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom) or node.level or node.module not in mods:
                continue
            if node.module not in defined:
                defined[node.module] = _defined(ast.parse(mods[node.module].read_text("utf-8")))
            for alias in node.names:
                if alias.name not in defined[node.module] and \
                        f"{node.module}.{alias.name}" not in mods:
                    found.append(f"{path.relative_to(root)}:{node.lineno}: "
                                 f"{node.module}.{alias.name}")
    return found
