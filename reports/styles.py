"""House look of every PDF the station writes: fonts, colours, paragraph and table styles.

The fonts are DejaVu Sans (regular, bold) and DejaVu Sans Mono, TrueType files shipped in
reports/fonts/ with their licence and embedded (subset) in every PDF: nothing depends on
the machine's font files or on a viewer's substitute for Helvetica.
"""

from __future__ import annotations

import math
from pathlib import Path

from reportlab.graphics import shapes
from reportlab.lib import colors
from reportlab.lib.enums import TA_CENTER, TA_LEFT
from reportlab.lib.styles import ParagraphStyle
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont
from reportlab.platypus import TableStyle, tables

FONT_DIR = Path(__file__).resolve().parent / "fonts"
FONT = "DejaVuSans"
FONT_BOLD = "DejaVuSans-Bold"
FONT_MONO = "DejaVuSansMono"


def register_fonts() -> None:
    """Register the shipped TrueType fonts with reportlab (once; embedded when used)."""
    registered = set(pdfmetrics.getRegisteredFontNames())
    for name in (FONT, FONT_BOLD, FONT_MONO):
        if name not in registered:
            pdfmetrics.registerFont(TTFont(name, str(FONT_DIR / f"{name}.ttf")))
    pdfmetrics.registerFontFamily(FONT, normal=FONT, bold=FONT_BOLD, italic=FONT,
                                  boldItalic=FONT_BOLD)
    # reportlab's graphics start every drawing in Times-Roman: make it ours, so that no
    # unembedded standard font is ever referenced
    shapes.STATE_DEFAULTS["fontName"] = FONT
    tables.CellStyle.fontname = FONT  # likewise every table cell (Helvetica)


register_fonts()

PASS_GREEN = colors.HexColor("#1b7a2f")
FAIL_RED = colors.HexColor("#b3141b")
ERROR_ORANGE = colors.HexColor("#c25700")
MARGINAL_AMBER = colors.HexColor("#fff1b8")
FAIL_ROW = colors.HexColor("#fbd5d5")
HEADER_GREY = colors.HexColor("#e6e8eb")
RULE_GREY = colors.HexColor("#9aa1a9")
SIM_MAGENTA = colors.HexColor("#a0007a")
UNVERIFIED_RED = colors.HexColor("#d0000f")

VERDICT_COLOURS = {
    "PASS": PASS_GREEN,
    "FAIL": FAIL_RED,
    "ERROR": ERROR_ORANGE,
    "ABORTED": ERROR_ORANGE,
    "RUNNING": ERROR_ORANGE,
}

BODY = ParagraphStyle("body", fontName=FONT, fontSize=8.5, leading=10.5, alignment=TA_LEFT)
SMALL = ParagraphStyle("small", parent=BODY, fontSize=7, leading=8.5)
CELL = ParagraphStyle("cell", parent=BODY, fontSize=7.5, leading=9)
CELL_MONO = ParagraphStyle("cellmono", parent=CELL, fontName=FONT_MONO, fontSize=6.3)
H1 = ParagraphStyle("h1", parent=BODY, fontName=FONT_BOLD, fontSize=15, leading=18)
H2 = ParagraphStyle(
    "h2", parent=BODY, fontName=FONT_BOLD, fontSize=10.5, leading=13, spaceBefore=7, spaceAfter=3
)
NOTE = ParagraphStyle("note", parent=SMALL, textColor=colors.HexColor("#555555"))
WARNING = ParagraphStyle(
    "warning", parent=BODY, fontName=FONT_BOLD, textColor=FAIL_RED, fontSize=9, leading=11
)


def verdict_style(verdict: str) -> ParagraphStyle:
    return ParagraphStyle(
        f"verdict-{verdict}",
        parent=BODY,
        fontName=FONT_BOLD,
        fontSize=30,
        leading=34,
        alignment=TA_CENTER,
        textColor=colors.white,
    )


def grid_style(header_rows: int = 1) -> TableStyle:
    """Thin grid, grey header, small type."""
    cmds = [
        ("FONT", (0, 0), (-1, -1), FONT, 7.5),
        ("GRID", (0, 0), (-1, -1), 0.3, RULE_GREY),
        ("VALIGN", (0, 0), (-1, -1), "MIDDLE"),
        ("TOPPADDING", (0, 0), (-1, -1), 1.5),
        ("BOTTOMPADDING", (0, 0), (-1, -1), 1.5),
        ("LEFTPADDING", (0, 0), (-1, -1), 3),
        ("RIGHTPADDING", (0, 0), (-1, -1), 3),
    ]
    if header_rows:
        cmds += [
            ("BACKGROUND", (0, 0), (-1, header_rows - 1), HEADER_GREY),
            ("FONT", (0, 0), (-1, header_rows - 1), FONT_BOLD, 7.5),
        ]
    return TableStyle(cmds)


def fmt(value: float | None, digits: int = 5) -> str:
    """A number for a person: significant digits, no spurious precision, '-' when absent."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if not math.isfinite(value):
        return str(value)
    if value == 0:
        return "0"
    return f"{value:.{digits}g}"


DIMENSIONLESS = ("1", "")


def unit_label(units: str) -> str:
    """Units for a column or an axis: '(ratio)' for a dimensionless quantity (units "1"),
    which a reader would otherwise take for a stray digit."""
    return "(ratio)" if units.strip() == "1" else units


def with_units(value: float | None, units: str, digits: int = 5) -> str:
    """A value followed by its units; a dimensionless value ("1") carries none."""
    text = fmt(value, digits)
    return text if units.strip() in DIMENSIONLESS else f"{text} {units}"


def titled(label: str, units: str) -> str:
    """'label (units)' for a chart title or axis; just the label when dimensionless."""
    return label if units.strip() in DIMENSIONLESS else f"{label} ({units})"


MAX_TEXT_CHARS = 600  # longer text from a record is cut: layout time grows with its length


def bounded(text: object, limit: int = MAX_TEXT_CHARS) -> str:
    """`text` as a string of at most about `limit` characters: a longer one is cut, saying
    how much was left out (a record's text is input: a 2 MB name must not stall a render)."""
    s = str(text)
    if len(s) <= limit:
        return s
    return f"{s[:limit]}... ({len(s) - limit} more characters not shown)"


def escape(text: object) -> str:
    """Text safe inside a reportlab Paragraph (which parses a little XML), bounded in length."""
    return bounded(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
