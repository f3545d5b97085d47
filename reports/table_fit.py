"""Tables whose columns are as wide as their content, so no two values ever touch.

A cell is either a plain string (a number, a verdict: drawn on one line, never broken) or a
Paragraph (text: wraps at word boundaries). Each column gets at least the width of its widest
unbreakable piece (a whole string cell; a Paragraph's longest word), measured in the font the
cell is drawn in (the table style's FONT for a string, the paragraph's own style otherwise),
plus its padding; the rest of the table's width goes to the columns whose text would
otherwise wrap. Fixed widths could not hold: a number's width depends on its value
(-0.00017712 against 0.5), and a string wider than its column is drawn over the next cell
(`-0.00177125.56e-05` on a certificate).

Only when even the unbreakable pieces cannot share the width (text far beyond anything the
product's limits allow) do text columns give way, breaking a word inside; numbers never do.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from reportlab.pdfbase.pdfmetrics import stringWidth
from reportlab.platypus import Flowable, Paragraph, Table, TableStyle

from reports.styles import FONT

DEFAULT_SIZE = 7.5
DEFAULT_PADDING = 6.0  # reportlab's default left + right padding
FLOOR = 40.0  # points: the narrowest a text column is squeezed to
SLACK = 0.5  # points: a word exactly as wide as its cell must not wrap on rounding
_SPACES = re.compile(r"[^\S\xa0]+")  # where reportlab breaks a line: not at a no-break space


def _covers(cmd: tuple[Any, ...], col: int, row: int, ncols: int, nrows: int) -> bool:
    (c0, r0), (c1, r1) = cmd[1], cmd[2]
    c0, c1 = (c % ncols if c < 0 else c for c in (c0, c1))
    r0, r1 = (r % nrows if r < 0 else r for r in (r0, r1))
    return c0 <= col <= c1 and r0 <= row <= r1


def _setting(cmds: Sequence[tuple[Any, ...]], op: str, col: int, row: int, ncols: int,
             nrows: int) -> tuple[Any, ...] | None:
    """The last command `op` of the style that covers the cell (the one reportlab applies)."""
    found = None
    for cmd in cmds:
        if cmd[0] == op and _covers(cmd, col, row, ncols, nrows):
            found = cmd
    return found


def _paragraph_widths(p: Paragraph) -> tuple[float, float]:
    """(longest word, whole text on one line) of a paragraph, in points."""
    words: list[float] = []
    whole = 0.0
    for frag in p.frags:
        text = getattr(frag, "text", "")
        if not text:
            continue
        size = frag.fontSize
        whole += stringWidth(text, frag.fontName, size)
        words += [stringWidth(w, frag.fontName, size) for w in _SPACES.split(text) if w]
    return (max(words, default=0.0), whole)


def cell_widths(cell: object, font: str, size: float) -> tuple[float, float]:
    """(narrowest, natural) width of one cell's content, in points."""
    if isinstance(cell, Paragraph):
        return _paragraph_widths(cell)
    if isinstance(cell, Flowable):
        w, _ = cell.wrap(1e6, 1e6)
        return w, w
    if cell is None:
        return 0.0, 0.0
    widest = max((stringWidth(line, font, size) for line in str(cell).split("\n")), default=0.0)
    return widest, widest


def column_widths(rows: Sequence[Sequence[object]], width: float,
                  cmds: Sequence[tuple[Any, ...]] = ()) -> list[float]:
    """Widths (points) summing to `width` that give every column its content (see module)."""
    nrows, ncols = len(rows), max(len(r) for r in rows)
    need, natural = [0.0] * ncols, [0.0] * ncols
    breakable = [False] * ncols
    for r, row in enumerate(rows):
        for c, cell in enumerate(row):
            font_cmd = _setting(cmds, "FONT", c, r, ncols, nrows)
            font = font_cmd[3] if font_cmd else FONT
            size = font_cmd[4] if font_cmd and len(font_cmd) > 4 else DEFAULT_SIZE
            pads = sum(
                float(cmd[3]) if (cmd := _setting(cmds, op, c, r, ncols, nrows)) else 3.0
                for op in ("LEFTPADDING", "RIGHTPADDING"))
            lo, nat = cell_widths(cell, font, size)
            if lo + pads + SLACK > need[c]:
                need[c] = lo + pads + SLACK
                # the column's narrowest width is set by text, which may break in a word
                breakable[c] = isinstance(cell, Paragraph)
            natural[c] = max(natural[c], nat + pads + SLACK)
    return _share(width, need, natural, breakable)


def _share(width: float, need: list[float], natural: list[float],
           breakable: list[bool]) -> list[float]:
    if sum(need) > width:
        return _squeeze(width, need, breakable)
    if sum(natural) <= width:
        spare = width - sum(natural)
        total = sum(natural) or 1.0
        return [n + spare * n / total for n in natural]
    # water-filling: every column grows toward its natural width by the same amount at most,
    # so short labels stay on one line and the long texts share what is left
    grow = [nat - n for nat, n in zip(natural, need, strict=True)]
    spare = width - sum(need)
    extra = [0.0] * len(need)
    open_cols = sorted(range(len(need)), key=lambda c: grow[c])
    while open_cols:
        level = spare / len(open_cols)
        c = open_cols[0]
        if grow[c] <= level:
            extra[c] = grow[c]
            spare -= grow[c]
            open_cols.pop(0)
            continue
        for c in open_cols:
            extra[c] = level
        break
    return [n + e for n, e in zip(need, extra, strict=True)]


def _squeeze(width: float, need: list[float], breakable: list[bool]) -> list[float]:
    """Text columns give way (breaking inside a word), down to FLOOR each; string columns
    keep their width unless even that cannot fit (input far beyond the product's bounds,
    such as a 600-character word), when every column shrinks alike so the page still
    renders."""
    floor = [min(n, FLOOR) if b else n for n, b in zip(need, breakable, strict=True)]
    if sum(floor) > width:
        return [f * width / sum(floor) for f in floor]
    fixed = sum(n for n, b in zip(need, breakable, strict=True) if not b)
    flexible = sum(n for n, b in zip(need, breakable, strict=True) if b)
    scale = (width - fixed) / flexible
    return [max(n * scale, f) if b else n
            for n, f, b in zip(need, floor, breakable, strict=True)]


def fitted_table(rows: list[list[Any]], width: float, style: TableStyle,
                 **kwargs: Any) -> Table:
    """A Table of `rows` styled with `style`, its columns sized by column_widths."""
    cmds = list(style.getCommands())
    table = Table(rows, colWidths=column_widths(rows, width, cmds), **kwargs)
    table.setStyle(style)
    return table
