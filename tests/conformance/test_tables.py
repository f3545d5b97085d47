"""The conformance tables hold together: every row names a test that exists, and the docs
carry each table exactly as its rows say (docs/instruments.md, between its markers)."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from tests.conformance.table import DOCS, Table, docs_block, markdown, tables

TABLES = tables()


def _test_functions(table: Table) -> set[str]:
    module = importlib.import_module(table.module)
    tree = ast.parse(Path(module.__file__ or "").read_text(encoding="utf-8"))
    return {node.name for node in tree.body
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
            and node.name.startswith("test_")}


@pytest.mark.parametrize("table", TABLES, ids=[t.family for t in TABLES])
def test_every_row_names_a_test_of_its_module(table: Table) -> None:
    known = _test_functions(table)
    missing = [r.item for r in table.rows if r.test not in known]
    assert not missing, f"{table.family}: rows whose test is not in {table.module}: {missing}"


@pytest.mark.parametrize("table", TABLES, ids=[t.family for t in TABLES])
def test_docs_carry_the_table(table: Table) -> None:
    held = docs_block(DOCS.read_text(encoding="utf-8"), table.family)
    assert held is not None, (f"docs/instruments.md has no <!-- conformance: {table.family} --> "
                              "block; add the markers and run python -m tests.conformance.table")
    assert held == markdown(table), ("docs/instruments.md's table is stale: "
                                     "python -m tests.conformance.table rewrites it")
