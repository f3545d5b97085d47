"""Building a reproducible PDF with page furniture on every page.

Every page carries a running header (title and identity), "page N of M" and, when the data
came from the simulated bench, a SIMULATED BENCH mark. Output is byte-identical for the same
inputs: reportlab's invariant mode, the document date taken from the caller (the run's own
time, never now), and no machine-dependent fonts.
"""

from __future__ import annotations

import io
import os
import re
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.units import mm
from reportlab.pdfgen.canvas import Canvas
from reportlab.platypus import Flowable, SimpleDocTemplate

from procedures.runtime.record import new_file_mode
from reports.styles import FONT, FONT_BOLD, RULE_GREY, SIM_MAGENTA, UNVERIFIED_RED

PAGE_SIZE = A4
MARGIN = 14 * mm
TOP_MARGIN = 20 * mm
BOTTOM_MARGIN = 16 * mm


@dataclass(frozen=True)
class PageFurniture:
    title: str  # left of the running header
    identity: str  # right of the running header (e.g. serial and run id)
    simulated: bool
    document_time: datetime  # written as the PDF's creation date
    author: str = ""
    subject: str = ""
    unverified: str = ""  # when set: UNVERIFIED and this reason on every page


def parse_utc(text: str | None) -> datetime | None:
    """An ISO-8601 time as an aware UTC datetime; None when absent or unreadable."""
    if not text:
        return None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.astimezone(UTC)


def _pdf_date(t: datetime) -> str:
    t = t.astimezone(UTC)
    return f"D:{t:%Y%m%d%H%M%S}+00'00'"


def _canvas_class(furniture: PageFurniture) -> type[Canvas]:
    class _FurnishedCanvas(Canvas):
        """Holds pages back until the end so each can say 'page N of M'."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self._held_pages: list[dict[str, Any]] = []
            stamp = _pdf_date(furniture.document_time)
            self.setDateFormatter(lambda *_a: stamp)
            self.setTitle(f"{furniture.title} {furniture.identity}")
            self.setAuthor(furniture.author)
            self.setSubject(furniture.subject)
            self.setCreator("gyrocal station reports")

        def showPage(self) -> None:  # noqa: N802 (reportlab's name)
            self._held_pages.append(dict(self.__dict__))
            self._startPage()

        def save(self) -> None:
            total = len(self._held_pages)
            for number, state in enumerate(self._held_pages, start=1):
                self.__dict__.update(state)
                _draw_furniture(self, furniture, number, total)
                Canvas.showPage(self)
            Canvas.save(self)

    return _FurnishedCanvas


def _draw_furniture(c: Canvas, f: PageFurniture, number: int, total: int) -> None:
    width, height = PAGE_SIZE
    c.saveState()
    c.setStrokeColor(RULE_GREY)
    c.setLineWidth(0.5)
    c.line(MARGIN, height - 14 * mm, width - MARGIN, height - 14 * mm)
    c.line(MARGIN, 11 * mm, width - MARGIN, 11 * mm)
    c.setFillColor(colors.black)
    c.setFont(FONT_BOLD, 8)
    c.drawString(MARGIN, height - 12.5 * mm, f.title)
    c.setFont(FONT, 8)
    c.drawRightString(width - MARGIN, height - 12.5 * mm, f.identity)
    c.setFont(FONT, 7.5)
    c.drawString(MARGIN, 7.5 * mm, f"Issued {f.document_time:%Y-%m-%d %H:%M:%S} UTC")
    c.drawRightString(width - MARGIN, 7.5 * mm, f"page {number} of {total}")
    if f.simulated:
        _draw_simulated_mark(c)
    if f.unverified:
        _draw_unverified_mark(c, f.unverified)
    c.restoreState()


def _draw_unverified_mark(c: Canvas, reason: str) -> None:
    """A red diagonal UNVERIFIED across the page and the reason along its foot."""
    width, height = PAGE_SIZE
    c.saveState()
    c.setFillColor(UNVERIFIED_RED)
    c.setFont(FONT_BOLD, 9)
    c.drawCentredString(width / 2, 3.2 * mm, f"UNVERIFIED: {reason}"[:140])
    c.translate(width / 2, height / 2)
    c.rotate(52)
    c.setFillAlpha(0.25)
    c.setFont(FONT_BOLD, 92)
    c.drawCentredString(0, -30, "UNVERIFIED")
    c.restoreState()


def _draw_simulated_mark(c: Canvas) -> None:
    """A magenta frame and banner on every page; kept off the text so extraction stays clean."""
    width, height = PAGE_SIZE
    c.setStrokeColor(SIM_MAGENTA)
    c.setLineWidth(2.5)
    c.rect(5 * mm, 5 * mm, width - 10 * mm, height - 10 * mm, stroke=1, fill=0)
    c.setFillColor(SIM_MAGENTA)
    c.rect(width / 2 - 48 * mm, height - 10 * mm, 96 * mm, 5 * mm, stroke=0, fill=1)
    c.setFillColor(colors.white)
    c.setFont(FONT_BOLD, 9)
    c.drawCentredString(width / 2, height - 8.7 * mm, "SIMULATED BENCH - NOT A REAL PART")
    c.setFillColor(SIM_MAGENTA)
    c.drawCentredString(width / 2, 7.5 * mm, "SIMULATED BENCH")


def build_pdf(story: Sequence[Flowable], furniture: PageFurniture) -> bytes:
    """Lay out the story on A4 with the page furniture; returns the PDF bytes."""
    buffer = io.BytesIO()
    doc = SimpleDocTemplate(
        buffer,
        pagesize=PAGE_SIZE,
        leftMargin=MARGIN,
        rightMargin=MARGIN,
        topMargin=TOP_MARGIN,
        bottomMargin=BOTTOM_MARGIN,
        invariant=1,
        initialFontName=FONT,  # else the page starts in Helvetica, referenced but not embedded
        title=f"{furniture.title} {furniture.identity}",
        author=furniture.author,
        subject=furniture.subject,
        creator="gyrocal station reports",
    )
    doc.build(list(story), canvasmaker=_canvas_class(furniture))
    return buffer.getvalue()


def write_atomic(path: Path, data: bytes) -> Path:
    """Write a file by temp + rename, so a reader never sees half a PDF."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), new_file_mode())  # mkstemp's 0600 would hide it from quality
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def page_count(pdf: bytes) -> int:
    """Number of pages of a PDF written by build_pdf (counts its page objects)."""
    return len(re.findall(rb"/Type /Page(?![a-zA-Z])", pdf))
