"""A record's text is input too: a certificate of a record holding megabytes of text (a
2 MB procedure name, reason, operator, serial) renders in about the time of a normal one,
each long text cut with a note of how much was left out."""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

from procedures.runtime.record import read_record, write_record
from reports.certificate import certificate_bytes
from reports.styles import MAX_TEXT_CHARS, bounded, escape
from tests.tools import need

HUGE = "<b>" + "N" * 2_000_000  # markup too: escaped, never parsed


def test_bounded_cuts_and_says_how_much() -> None:
    assert bounded("short") == "short"
    text = bounded("x" * 10_000)
    assert len(text) < MAX_TEXT_CHARS + 60
    assert text.endswith(f"({10_000 - MAX_TEXT_CHARS} more characters not shown)")
    assert escape("<" * 5_000).count("&lt;") == MAX_TEXT_CHARS


def test_megabytes_of_text_in_a_record_render_promptly(pass_run: Path, tmp_path: Path) -> None:
    t0 = time.monotonic()
    certificate_bytes(pass_run)
    normal_s = time.monotonic() - t0
    folder = tmp_path / "run"
    shutil.copytree(pass_run, folder)
    rec = read_record(pass_run)
    write_record(folder, rec.model_copy(update={
        "procedure": rec.procedure.model_copy(update={"name": HUGE, "version": HUGE}),
        "reason": HUGE,
        "operator": HUGE,
        "station": {"id": HUGE, "name": HUGE},
    }))
    t0 = time.monotonic()
    pdf = certificate_bytes(folder)
    long_s = time.monotonic() - t0
    assert pdf.startswith(b"%PDF")
    assert long_s < 3 * normal_s + 5.0, (normal_s, long_s)
    out = tmp_path / "c.pdf"
    out.write_bytes(pdf)
    need("pdftotext")
    text = subprocess.run(["pdftotext", str(out), "-"], capture_output=True,
                          text=True, check=True).stdout
    assert "more characters not shown" in text
    assert "<b>" in text  # shown as text, not taken as markup
