"""The conformance table of an instrument family: each documented register or command, where
its maker's document states it, whether the station's driver uses it, whether the simulated
bench's twin serves it, and the test that checks it.

The rows are written from the maker's documents (manuals, datasheets, the maker's own public
client's register and command tables), never from our driver. A row's `test` names a test
function in the family's module (`tests/conformance/<module>.py::<function>`), which
`test_tables.py` finds; the docs' table between the markers

    <!-- conformance: <role>.<family> -->
    ...
    <!-- /conformance -->

in docs/instruments.md is `markdown(table)` exactly (`python -m tests.conformance.table`
rewrites them), and `benchmarks/bench_instruments.py --conformance` counts the rows.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs" / "instruments.md"


@dataclass(frozen=True)
class Row:
    item: str  # the register or command as the maker writes it ("300", "*OPC?", "TEMP?")
    meaning: str  # what it is, in a few words
    section: str  # where the maker's document states it ("F4 user's manual, ch. 9, Modbus")
    driver_uses: bool  # the station's driver sends or reads it
    twin_serves: bool  # the simulated bench's twin answers it as the instrument does
    test: str  # the test function in the family's module that checks it


@dataclass(frozen=True)
class Table:
    family: str  # registered name, "<role>.<name>" ("chamber.watlow-f4")
    instrument: str  # the product it follows ("Watlow Series F4 controller")
    sources: tuple[str, ...]  # the documents the rows come from
    rows: tuple[Row, ...] = field(default_factory=tuple)
    module: str = ""  # filled by `tables()`: the module that holds the rows' tests

    def counts(self) -> dict[str, int]:
        return {"documented": len(self.rows),
                "driver_uses": sum(r.driver_uses for r in self.rows),
                "twin_serves": sum(r.twin_serves for r in self.rows),
                "tested": sum(bool(r.test) for r in self.rows)}


def tables() -> list[Table]:
    """Every family's table, from the modules of this package that define `TABLE`."""
    found: list[Table] = []
    package = sys.modules[__package__]
    for info in pkgutil.iter_modules(package.__path__):
        if info.name in {"table", "test_tables"}:
            continue
        module = importlib.import_module(f"{__package__}.{info.name}")
        table = getattr(module, "TABLE", None)
        if isinstance(table, Table):
            found.append(Table(table.family, table.instrument, table.sources, table.rows,
                               module=module.__name__))
    return sorted(found, key=lambda t: t.family)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown(table: Table) -> str:
    """The docs' table of one family (what docs/instruments.md holds between its markers)."""
    path = table.module.replace(".", "/") + ".py"
    lines = [f"Follows: {table.instrument}. Sources: {'; '.join(table.sources)}.", "",
             "| register or command | meaning | maker's document | driver uses | twin serves "
             "| test |",
             "|---|---|---|---|---|---|"]
    for r in table.rows:
        lines.append(f"| `{_cell(r.item)}` | {_cell(r.meaning)} | {_cell(r.section)} | "
                     f"{'yes' if r.driver_uses else 'no'} | {'yes' if r.twin_serves else 'no'} "
                     f"| `{path}::{r.test}` |")
    return "\n".join(lines)


def _marked(family: str) -> re.Pattern[str]:
    start = rf"<!-- conformance: {re.escape(family)} -->\n"
    return re.compile(rf"({start})(.*?)(\n<!-- /conformance -->)", re.DOTALL)


def docs_block(text: str, family: str) -> str | None:
    """What the docs hold between a family's markers, or None without markers."""
    found = _marked(family).search(text)
    return None if found is None else found.group(2)


def rewrite_docs() -> list[str]:
    """Rewrite every marked table in docs/instruments.md; returns the families rewritten."""
    text = DOCS.read_text(encoding="utf-8")
    done = []
    for table in tables():
        pattern = _marked(table.family)
        if pattern.search(text):
            body = markdown(table)
            text = pattern.sub(lambda m, b=body: m.group(1) + b + m.group(3), text)
            done.append(table.family)
    DOCS.write_text(text, encoding="utf-8")
    return done


if __name__ == "__main__":
    # run as a script this module is __main__, whose Table is not the one the family modules
    # import: rewrite through the imported module, or no table is found
    from tests.conformance import table as imported

    print("rewrote:", ", ".join(imported.rewrite_docs()) or "nothing (no markers)")
